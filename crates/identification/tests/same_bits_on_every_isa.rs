//! An identification does not depend on the CPU's vector instructions: the whole pipeline
//! (conditioning, line search, least squares, standard errors, the frequency-domain
//! cross-check) run on every instruction set this CPU has gives the bits of the baseline
//! one, which uses neither AVX nor fused multiply-adds. `tests/run-all.sh` checks the same
//! on the command line, with `OILFILM_SIMD=scalar`.

use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::{self, PipelineConfig, SpeedSource};
use oilfilm_identification::simd::{self, Isa};
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_physics::config::RigConfig;

#[test]
fn the_identification_is_the_same_bits_on_every_instruction_set() {
    let rig = RigConfig::zhou2004().unwrap();
    let rec = simulate::simulate(&rig, &ExcitationPlan::two_tone(23.0, 37.0, 100.0), 4.0, SimulateOptions::default(), &mut |_| {}).unwrap();
    let raw = rec.raw().unwrap();
    let calibration = pipeline::calibration_for(&rig, &raw, &pipeline::rig_offsets(&rig, &raw).unwrap()).unwrap();
    let config = PipelineConfig { estimator: oilfilm_identification::estimator::EstimatorConfig { window: 10_000, hop: 5_000, ..Default::default() }, ..Default::default() };
    let identify = |isa| {
        simd::with_isa(isa, || {
            let id = pipeline::identify(&raw, &calibration, &rig, 1500.0, SpeedSource::User, &config).unwrap();
            serde_json::to_string(&id).unwrap()
        })
    };
    let scalar = identify(Isa::Scalar);
    let solved = scalar.matches("\"stiffness_n_m\"").count();
    assert!(solved >= 2, "the record must give solved windows to compare: {scalar}");
    for isa in Isa::available() {
        assert!(identify(isa) == scalar, "{isa:?} differs from the baseline");
    }
    println!("{solved} windows, identical bits on {:?}", Isa::available());
}
