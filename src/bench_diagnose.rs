//! `oilfilm bench diagnose`: the whole catalog on a 10 s, 5 kHz record (issue 6's target:
//! under 5 s on one core). The diagnosis is single-threaded, so wall time is one core's time.

use std::time::Instant;

use anyhow::Result;
use oilfilm_diagnosis::{diagnose, show, DiagnosisOptions, ShowConfig};
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::{self, SpeedSource};
use oilfilm_identification::simulate::{simulate, SimulateOptions};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::effects::{ChannelDelay, Effects, FluidInertia};

/// Target of issue 6, seconds for the whole catalog on 10 s at 5 kHz.
const TARGET_S: f64 = 5.0;

pub fn run(repeats: usize, seconds: f64) -> Result<()> {
    let base = RigConfig::zhou2004()?;
    let cases: [(&str, Effects); 3] = [
        ("no effect", Effects::default()),
        ("fluid_inertia 90 kg", Effects { fluid_inertia: Some(FluidInertia { added_mass_kg: 90.0 }), ..Effects::default() }),
        ("channel_delay f1 300 us", Effects { channel_delay: Some(ChannelDelay { channel: "f1".into(), delay_s: 300e-6 }), ..Effects::default() }),
    ];
    println!("oilfilm bench diagnose: {seconds} s records at {} Hz, 60 N rms multisine 5-80 Hz; median of {repeats} runs; one thread", base.daq.sample_rate_hz);
    println!("{:<26} {:>12} {:>12} {:>12} {:>10}  named", "record", "diagnose s", "show s", "simulate s", "target");
    for (label, effects) in cases {
        let mut rig = base.clone();
        rig.effects = effects;
        let t0 = Instant::now();
        let record = simulate(&rig, &ExcitationPlan::multisine([5.0, 80.0], 1.0, 60.0), seconds, SimulateOptions::default(), &mut |_| {})?;
        let sim_s = t0.elapsed().as_secs_f64();
        let raw = record.raw()?;
        let mut nominal = rig.clone();
        nominal.effects = Effects::default();
        let calibration = pipeline::calibration_for(&nominal, &raw, &pipeline::rig_offsets(&nominal, &raw)?)?;
        let (mut diag_times, mut show_times) = (Vec::new(), Vec::new());
        let mut named = String::new();
        for _ in 0..repeats.max(1) {
            let t = Instant::now();
            let d = diagnose(&raw, &calibration, &nominal, record.speed_rpm, SpeedSource::Record, &DiagnosisOptions::default())?;
            diag_times.push(t.elapsed().as_secs_f64());
            named = d.cause.name().to_string();
            let t = Instant::now();
            show(&raw, &calibration, &nominal, record.speed_rpm, SpeedSource::Record, &ShowConfig { window_s: Some(1.0), ..ShowConfig::default() })?;
            show_times.push(t.elapsed().as_secs_f64());
        }
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let d = median(diag_times);
        println!(
            "{label:<26} {d:>12.3} {:>12.3} {sim_s:>12.3} {:>10}  {named}",
            median(show_times),
            if d < TARGET_S { format!("< {TARGET_S} met") } else { format!("< {TARGET_S} MISSED") }
        );
    }
    Ok(())
}
