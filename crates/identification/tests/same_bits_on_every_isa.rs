//! An identification does not depend on the CPU's vector instructions beyond the FFT's
//! rounding (ADR 0023). The whole pipeline (conditioning, line search, least squares,
//! standard errors, the frequency-domain cross-check) run on every instruction set this CPU
//! has: the AVX2 and AVX-512 sets give the same bits (neither the conditioning nor the least
//! squares use a fused multiply-add; both use `rustfft`'s AVX transforms), and the baseline
//! set, whose transforms are `rustfft`'s scalar ones (what a CPU without AVX2 and FMA runs),
//! agrees with them to [`TOLERANCE`] in every number, with the same lines, flags and
//! refusals. `tests/run-all.sh` checks the same on the command line with `OILFILM_SIMD=scalar`.

use oilfilm_identification::estimator::EstimatorConfig;
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::{self, PipelineConfig, SpeedSource};
use oilfilm_identification::simd::{self, Isa};
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_physics::config::RigConfig;
use serde_json::Value;

use crate::json_difference;
use json_difference::largest_difference;

/// Largest relative difference allowed between the baseline's numbers and the AVX sets':
/// the transforms' rounding (a few ulps of each bin) reaches the line frequencies, the
/// standard errors and the frequency-domain estimate through sums over many bins.
const TOLERANCE: f64 = 1e-12;

#[test]
fn the_identification_is_the_same_on_every_instruction_set() {
    let rig = RigConfig::zhou2004().unwrap();
    let rec = simulate::simulate(&rig, &ExcitationPlan::two_tone(23.0, 37.0, 100.0), 4.0, SimulateOptions::default(), &mut |_| {}).unwrap();
    let raw = rec.raw().unwrap();
    let calibration = pipeline::calibration_for(&rig, &raw, &pipeline::rig_offsets(&rig, &raw).unwrap()).unwrap();
    let config = PipelineConfig { estimator: EstimatorConfig { window: 10_000, hop: 5_000, ..Default::default() }, ..Default::default() };
    let identify = |isa| {
        simd::with_isa(isa, || {
            let id = pipeline::identify(&raw, &calibration, &rig, 1500.0, SpeedSource::User, &config).unwrap();
            serde_json::to_value(&id).unwrap()
        })
    };
    let scalar = identify(Isa::Scalar);
    let solved = scalar["windows"].as_array().map_or(0, |w| w.iter().filter(|w| w["estimate"]["result"].get("Ok").is_some()).count());
    assert!(solved >= 2, "the record must give solved windows to compare: {scalar}");
    let wide: Vec<(Isa, Value)> = Isa::available().into_iter().filter(|&i| i != Isa::Scalar).map(|i| (i, identify(i))).collect();
    for (isa, v) in &wide {
        assert!(v == &wide[0].1, "{isa:?} differs from {:?}", wide[0].0);
        let d = largest_difference(&scalar, v, "identification").unwrap_or_else(|e| panic!("{isa:?} against the baseline: {e}"));
        println!("{isa:?} against the baseline: largest relative difference {d:.1e} ({solved} windows)");
        assert!(d <= TOLERANCE, "{isa:?}: {d:e}");
    }
}
