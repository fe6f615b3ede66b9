//! Channel skew: the multiplexed card samples the force channels 40-90 us after the probes.
//!    Left in, that lag makes the force look like it leads to an apparent added mass of about
//!    C x tau (and extra damping K x tau); the de-skew stage removes it. At 40 dB probe SNR:
//!    with the rig's default 0.1 um probe noise and a small excitation, the twice-differentiated
//!    displacement regressor is so noisy that the 12-coefficient fit is biased by errors in
//!    variables far more than by skew (tens of kg); the estimator flags that.

use crate::simulated_rig;

use simulated_rig::*;

use oilfilm_identification::estimator::ModelOrder;
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::PipelineConfig;
use oilfilm_identification::simulate::{self, SimulateOptions};

#[test]
fn de_skew_removes_the_apparent_added_mass_that_multiplex_skew_creates() {
    let base = short_rig();
    // A multisine puts several lines in each direction, so the 12-coefficient model can tell
    // stiffness from mass.
    let plan = ExcitationPlan::multisine([5.0, 80.0], 1.0, 40.0);
    let mut rig = base.clone();
    set_probe_noise(&mut rig, forty_db_noise(displacement_rms(&base, &plan, 10.0)));
    let rec = simulate::simulate(&rig, &plan, 10.0, SimulateOptions::default(), &mut |_| {}).unwrap();
    let mut config = PipelineConfig::default();
    config.estimator.model = ModelOrder::Kcm;
    let with = identify(&rig, &rec, &config);
    config.conditioning.deskew = false;
    let without = identify(&rig, &rec, &config);
    let (a, b) = (solved(&with), solved(&without));
    let (ma, mb) = (a.added_mass_kg.unwrap(), b.added_mass_kg.unwrap());
    let (sa, sb) = (a.added_mass_se.unwrap(), b.added_mass_se.unwrap());
    let ct = rec.truth.coefficients.damping_n_s_m;
    println!(
        "apparent added mass with de-skew    [{:.2} {:.2}; {:.2} {:.2}] kg (SE [{:.2} {:.2}; {:.2} {:.2}])",
        ma[(0, 0)],
        ma[(0, 1)],
        ma[(1, 0)],
        ma[(1, 1)],
        sa[(0, 0)],
        sa[(0, 1)],
        sa[(1, 0)],
        sa[(1, 1)]
    );
    println!(
        "apparent added mass without de-skew [{:.2} {:.2}; {:.2} {:.2}] kg (SE [{:.2} {:.2}; {:.2} {:.2}])",
        mb[(0, 0)],
        mb[(0, 1)],
        mb[(1, 0)],
        mb[(1, 1)],
        sb[(0, 0)],
        sb[(0, 1)],
        sb[(1, 0)],
        sb[(1, 1)]
    );
    // The force channels (f1, f2, f3 at 60-80 us, frame probes at 40-50 us) lag the bearing
    // probes (0-30 us) by tau ~ 50 us: apparent mass ~ C tau.
    let tau = 50e-6;
    println!("C x 50 us = [{:.1} {:.1}; {:.1} {:.1}] kg: the scale skew predicts", ct[(0, 0)] * tau, ct[(0, 1)] * tau, ct[(1, 0)] * tau, ct[(1, 1)] * tau);
    let housing = rig.housing.mass_kg;
    for (i, j) in [(0, 0), (1, 1)] {
        assert!(ma[(i, j)].abs() < (3.0 * sa[(i, j)]).max(0.02 * housing), "with de-skew, M{i}{j} = {:.2} kg should vanish", ma[(i, j)]);
        assert!(mb[(i, j)].abs() > 10.0 * sb[(i, j)] && mb[(i, j)].abs() > 0.2 * housing, "without de-skew, M{i}{j} = {:.2} kg should be large", mb[(i, j)]);
        let predicted = ct[(i, j)] * tau;
        assert!((mb[(i, j)].abs() / predicted.abs() - 1.0).abs() < 0.6, "M{i}{j} = {:.1} kg is not of the order of C tau = {predicted:.1} kg", mb[(i, j)]);
    }
}
