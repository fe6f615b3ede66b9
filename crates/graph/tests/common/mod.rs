//! What the node tests share.
#![allow(dead_code)]

use oilfilm_graph::runner::memory::GraphParams;
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_physics::config::RigConfig;

/// The Zhou rig with its displacement probes at 40 dB below the plan's motion (the
/// identification issue's accuracy condition).
pub fn rig_at_40_db(plan: &ExcitationPlan) -> RigConfig {
    let mut rig = RigConfig::zhou2004().unwrap();
    let mut quiet = rig.clone();
    quiet.daq.set_displacement_probe_noise(0.0);
    let rec = simulate::simulate(&quiet, plan, 4.0, SimulateOptions { keep_states: true }, &mut |_| {}).unwrap();
    let s = rec.states.unwrap();
    let s = &s[s.len() / 4..];
    let n = s.len() as f64;
    let (mx, my) = (s.iter().map(|v| v.relative_m.x).sum::<f64>() / n, s.iter().map(|v| v.relative_m.y).sum::<f64>() / n);
    let rms = (s.iter().map(|v| (v.relative_m.x - mx).powi(2) + (v.relative_m.y - my).powi(2)).sum::<f64>() / n).sqrt();
    rig.daq.set_displacement_probe_noise(0.01 * rms / std::f64::consts::SQRT_2);
    rig
}

/// The shipped sim_rig launch file's parameters (the low-pass at 1.5 x the highest line of
/// the two-tone, 37 Hz) for the accuracy tests: 10 s windows every 5 s.
pub fn params(duration_s: f64) -> GraphParams {
    GraphParams::sim_rig(duration_s, 50_000, 25_000).expect("the shipped sim_rig launch file loads")
}
