//! `oilfilm bench diagnose`: what `oilfilm diagnose` costs, its report included, per 10 s,
//! 5 kHz record (issue 23's target: at most 3 s on a 2-core machine), split into its stages:
//! preparing the record (its one conditioning, the post-filter, the windowed identification),
//! the verdict (forward selection, structure tests, model update), the show (the model against
//! the measurement) and the report (figures and Markdown). Rows: three simulated records, and
//! the outside records of `tests/data/measured-records` (every case, or those given).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use oilfilm_diagnosis::{diagnose_prepared, evidence, show, DiagnosisOptions, ShowConfig};
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::{self, SpeedSource};
use oilfilm_identification::record::RawRecord;
use oilfilm_identification::simulate::{self, simulate, SimulateOptions};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::Calibration;
use oilfilm_physics::effects::{ChannelDelay, Effects, FluidInertia};

/// Issue 23's target, seconds per 10 s record with the report.
const TARGET_S: f64 = 3.0;

/// One record's stage times, s.
struct Times {
    prepare: f64,
    verdict: f64,
    show: f64,
    report: f64,
    named: String,
}

impl Times {
    fn total(&self) -> f64 {
        self.prepare + self.verdict + self.show + self.report
    }
}

fn time_one(raw: &RawRecord, calibration: &Calibration, rig: &RigConfig, speed_rpm: f64, out: &Path) -> Result<Times> {
    let options = DiagnosisOptions::default();
    let t = Instant::now();
    let p = evidence::prepare(raw, calibration, rig, speed_rpm, SpeedSource::Record, &options.prepare)?.map_err(|e| anyhow::anyhow!("{}", e.0))?;
    let prepare = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let d = diagnose_prepared(&p, rig, &options)?;
    let verdict = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let s = show(&p, rig, d.model_update.as_ref(), &ShowConfig::default())?;
    let show_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    crate::diagnose_report::write_report(out, "bench", &s, Some(&d))?;
    let report = t.elapsed().as_secs_f64();
    Ok(Times { prepare, verdict, show: show_s, report, named: d.cause.name().to_string() })
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn row(label: &str, runs: &[Times]) {
    let m = |f: &dyn Fn(&Times) -> f64| median(runs.iter().map(f).collect());
    let total = m(&|t| t.total());
    println!(
        "{label:<30} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>8}  {}",
        m(&|t| t.prepare),
        m(&|t| t.verdict),
        m(&|t| t.show),
        m(&|t| t.report),
        total,
        if total <= TARGET_S { "met" } else { "MISSED" },
        runs.last().map_or("", |t| t.named.as_str())
    );
}

/// The outside records' directories (`case-NN` holding `record.txt.gz` and `rig.toml`).
fn outside_cases(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut cases: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot list {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("record.txt.gz").is_file())
        .collect();
    cases.sort();
    Ok(cases)
}

pub fn run(repeats: usize, seconds: f64, records: Option<&Path>) -> Result<()> {
    let out = std::env::temp_dir().join(format!("oilfilm-bench-diagnose-{}", std::process::id()));
    println!(
        "oilfilm bench diagnose: median of {} run(s) per record; seconds per stage; one thread; target {TARGET_S} s per record with the report",
        repeats.max(1)
    );
    println!("{:<30} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}  named", "record", "prepare", "verdict", "show", "report", "total", "target");
    let base = RigConfig::zhou2004()?;
    let cases: [(&str, Effects); 3] = [
        ("sim: no effect", Effects::default()),
        ("sim: fluid_inertia 90 kg", Effects { fluid_inertia: Some(FluidInertia { added_mass_kg: 90.0 }), ..Effects::default() }),
        ("sim: channel_delay f1 300 us", Effects { channel_delay: Some(ChannelDelay { channel: "f1".into(), delay_s: 300e-6 }), ..Effects::default() }),
    ];
    for (label, effects) in cases {
        let mut rig = base.clone();
        rig.effects = effects;
        let record = simulate(&rig, &ExcitationPlan::multisine([5.0, 80.0], 1.0, 60.0), seconds, SimulateOptions::default(), &mut |_| {})?;
        let raw = record.raw()?;
        let mut nominal = rig.clone();
        nominal.effects = Effects::default();
        let calibration = pipeline::calibration_for(&nominal, &raw, &pipeline::rig_offsets(&nominal, &raw)?)?;
        let runs = (0..repeats.max(1)).map(|_| time_one(&raw, &calibration, &nominal, record.speed_rpm, &out)).collect::<Result<Vec<_>>>()?;
        row(label, &runs);
    }
    let dir = records.map(Path::to_path_buf).unwrap_or_else(|| PathBuf::from("tests/data/measured-records"));
    match outside_cases(&dir) {
        Ok(cases) if !cases.is_empty() => {
            let mut all = Vec::new();
            for case in &cases {
                let input = crate::ascii_input::load(&case.join("record.txt.gz"), None)?;
                let raw = simulate::raw_from_ascii(&input.record)?;
                let offsets: Vec<f64> = (0..input.record.header.channels.len())
                    .map(|p| input.record.header.channel_offset_s(p).ok_or_else(|| anyhow::anyhow!("{}: no offset for channel {p}", case.display())))
                    .collect::<Result<_>>()?;
                let calibration = pipeline::calibration_for(&input.rig, &raw, &offsets)?;
                let speed = input.record.header.speed_rpm.unwrap_or(input.rig.operating.speed_rpm);
                let runs = (0..repeats.max(1)).map(|_| time_one(&raw, &calibration, &input.rig, speed, &out)).collect::<Result<Vec<_>>>()?;
                all.push(runs.into_iter().min_by(|a, b| a.total().total_cmp(&b.total())).ok_or_else(|| anyhow::anyhow!("no run"))?);
            }
            let worst = all.iter().map(Times::total).fold(0.0, f64::max);
            let met = all.iter().filter(|t| t.total() <= TARGET_S).count();
            row(&format!("outside records ({}), median", all.len()), &all);
            println!(
                "{:<30} {:>53.3} {:>8}  {met} of {} within {TARGET_S} s",
                "outside records, slowest",
                worst,
                if worst <= TARGET_S { "met" } else { "MISSED" },
                all.len()
            );
        }
        _ => println!("(no outside records in {}: pass --records DIR)", dir.display()),
    }
    let _ = std::fs::remove_dir_all(&out);
    Ok(())
}
