//! Hidden-effect cases: a simulated record of the rig with one effect injected at a seeded
//! random size and operating point. The diagnosis gets the record and the NOMINAL rig (effects
//! cleared); the truth stays here, with the test.

#![allow(dead_code)]

use oilfilm_diagnosis::{diagnose, Diagnosis, DiagnosisOptions};
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::{self, SpeedSource};
use oilfilm_identification::simulate::{simulate, SimulateOptions};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::effects::*;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// What was hidden.
#[derive(Debug, Clone)]
pub struct Truth {
    pub effect: &'static str,
    /// The contract key and value of the hidden size, where one applies.
    pub parameter: Option<(&'static str, f64)>,
    pub channel: Option<String>,
    pub speed_rpm: f64,
    pub load_n: f64,
}

pub struct Case {
    pub rig: RigConfig,
    pub truth: Truth,
    pub seconds: f64,
    pub plan: ExcitationPlan,
}

/// The default multisine of the tests: 5-80 Hz, 1 s period, `rms_n` per exciter.
pub fn multisine(rms_n: f64) -> ExcitationPlan {
    ExcitationPlan::multisine([5.0, 80.0], 1.0, rms_n)
}

/// A random operating point and seed on the Zhou rig.
pub fn base_case(rng: &mut ChaCha8Rng, seed: u64) -> (RigConfig, f64, f64) {
    let mut rig = RigConfig::zhou2004().expect("built-in rig");
    let speed = rng.random_range(1000.0..2500.0_f64).round();
    let load = rng.random_range(3000.0..8000.0_f64).round();
    rig.operating.speed_rpm = speed;
    rig.operating.bearing_load_n = load;
    rig.simulation.seed = seed;
    (rig, speed, load)
}

/// Simulates and diagnoses a case with the nominal rig.
pub fn run(case: &Case) -> Diagnosis {
    let record = simulate(&case.rig, &case.plan, case.seconds, SimulateOptions::default(), &mut |_| {}).expect("simulate");
    let raw = record.raw().expect("raw record");
    let mut nominal = case.rig.clone();
    nominal.effects = Effects::default();
    let offsets = pipeline::rig_offsets(&nominal, &raw).expect("offsets");
    let calibration = pipeline::calibration_for(&nominal, &raw, &offsets).expect("calibration");
    diagnose(&raw, &calibration, &nominal, record.speed_rpm, SpeedSource::Record, &DiagnosisOptions::default()).expect("diagnose")
}

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// The rows of both confusion matrices: the seven catalogue effects, a null and an effect
/// outside the catalogue.
pub const CLASSES: [&str; 9] = [
    "amplitude_nonlinearity",
    "fluid_inertia",
    "channel_delay",
    "thermal_drift",
    "synchronous_runout",
    "probe_saturation",
    "support_friction",
    "none",
    "unexplained",
];

/// The columns: every class, and the verdict that no class could be judged.
pub fn named_classes() -> Vec<&'static str> {
    CLASSES.iter().copied().chain(["insufficient_data"]).collect()
}

/// Prints a confusion matrix: `counts[r][c]` records of class `rows[r]` named `columns[c]`.
pub fn print_confusion(title: &str, rows: &[&str], columns: &[&str], counts: &[Vec<usize>]) {
    println!("\nconfusion matrix ({title})");
    print!("{:<24}", "");
    for c in columns {
        print!(" {:>5}", &c[..5.min(c.len())]);
    }
    println!();
    for (r, row) in counts.iter().enumerate() {
        print!("{:<24}", rows[r]);
        for v in row {
            print!(" {v:>5}");
        }
        println!();
    }
}
