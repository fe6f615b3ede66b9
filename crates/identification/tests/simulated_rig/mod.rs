//! What the identification tests share: records from the simulated Zhou rig at a chosen probe
//! noise, and their identification through the whole pipeline. Each test binary uses a subset.
#![allow(dead_code)]

use oilfilm_identification::estimator::Coefficients;
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::{self, Identification, PipelineConfig, SpeedSource};
use oilfilm_identification::simulate::{self, SimulateOptions, SimulatedRecord};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::film::FilmModelConfig;

/// The Zhou rig with Ocvirk's short-bearing film (closed form with an exact Jacobian: a 10 s
/// record simulates in a fraction of a second, and the truth is the film's derivative itself).
pub fn short_rig() -> RigConfig {
    let mut rig = RigConfig::zhou2004().unwrap();
    rig.film = FilmModelConfig::Short;
    rig
}

/// Sets every displacement probe's (bearing and frame) noise to `rms_m`.
pub fn set_probe_noise(rig: &mut RigConfig, rms_m: f64) {
    rig.daq.set_displacement_probe_noise(rms_m);
}

/// RMS of the dynamic relative displacement (x and y together) on a noise-free pass, past the
/// excitation's ramp.
pub fn displacement_rms(rig: &RigConfig, plan: &ExcitationPlan, seconds: f64) -> f64 {
    let mut quiet = rig.clone();
    set_probe_noise(&mut quiet, 0.0);
    let rec = simulate::simulate(&quiet, plan, seconds, SimulateOptions { keep_states: true }, &mut |_| {}).unwrap();
    let s = rec.states.unwrap();
    let s = &s[s.len() / 5..];
    let n = s.len() as f64;
    let (mx, my) = (s.iter().map(|v| v.relative_m.x).sum::<f64>() / n, s.iter().map(|v| v.relative_m.y).sum::<f64>() / n);
    (s.iter().map(|v| (v.relative_m.x - mx).powi(2) + (v.relative_m.y - my).powi(2)).sum::<f64>() / n).sqrt()
}

/// Per-axis probe noise that puts x and y together at 40 dB below the motion: 1 % of its rms.
pub fn forty_db_noise(rms_m: f64) -> f64 {
    0.01 * rms_m / std::f64::consts::SQRT_2
}

/// A record identified through the whole pipeline on the rig DAQ's own schedule.
pub fn identify(rig: &RigConfig, rec: &SimulatedRecord, config: &PipelineConfig) -> Identification {
    let raw = rec.raw().unwrap();
    let cal = pipeline::calibration_for(rig, &raw, &pipeline::rig_offsets(rig, &raw).unwrap()).unwrap();
    pipeline::identify(&raw, &cal, rig, rec.speed_rpm, SpeedSource::Record, config).unwrap()
}

/// The coefficients of the only window of a record, or a panic with the refusal.
pub fn solved(id: &Identification) -> &Coefficients {
    assert_eq!(id.windows.len(), 1, "a 10 s record is one window");
    match &id.windows[0].estimate.result {
        Ok(c) => c,
        Err(r) => panic!("window refused: {r}"),
    }
}
