//! The estimator node's share of an offline re-analysis (`oilfilm identify BAG` on the
//! sim_rig graph): 60 s of the simulated rig at 5 kHz conditioned once (1 000-scan blocks,
//! 55.5 Hz low-pass), then the estimator core (25 000-sample windows every 12 500, standard
//! errors with `signal_band_hz` 55.5, the sim_rig params) pushed every conditioned frame,
//! best and median of several passes. A loop to profile (`perf record`) the estimator alone.
//!
//! `cargo run --release -p oilfilm-graph --example profile_reanalysis [PASSES]`
//! (with `ONLY_CAUSAL=1`: the causal conditioner alone, e.g. under `perf record`)

use std::time::Instant;

use oilfilm_graph::conditioner::{Chain, ConditionerCore, ConditionerParams};
use oilfilm_graph::estimator::{EstimatorCore, EstimatorParams};
use oilfilm_graph::stamp::Stamp;
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_physics::config::RigConfig;

fn main() -> anyhow::Result<()> {
    let passes: usize = std::env::args().nth(1).map(|a| a.parse()).transpose()?.unwrap_or(10);
    let (seconds, block) = (60.0, 500usize);
    let rig = RigConfig::zhou2004()?;
    let rate = rig.daq.sample_rate_hz;
    let rec = simulate::simulate(&rig, &ExcitationPlan::two_tone(23.0, 37.0, 100.0), seconds, SimulateOptions::default(), &mut |_| {})?;
    let frames = oilfilm_graph::daq::frames_of_scans(&rig, &rec.scans, block, rig.daq.calibration().scan_order().len(), Stamp(0))?;
    // The conditioner's share, both chains, timed the same way as the estimator below.
    let mut conditioned = Vec::new();
    let only_causal = std::env::var_os("ONLY_CAUSAL").is_some();
    for chain in [Chain::ZeroPhase, Chain::Causal] {
        if only_causal && chain == Chain::ZeroPhase {
            continue;
        }
        let params = ConditionerParams { lowpass_cutoff_hz: 55.5, block_scans: 1_000, chain: chain.name().into(), ..ConditionerParams::default() };
        let mut times = Vec::new();
        for _ in 0..passes {
            let mut cond = ConditionerCore::new(rig.clone(), &params)?;
            let t0 = Instant::now();
            let mut out = Vec::new();
            for frame in &frames {
                out.extend(cond.push(frame)?);
            }
            times.push(t0.elapsed().as_secs_f64() * 1e3);
            if chain == Chain::ZeroPhase {
                conditioned = out;
            }
        }
        times.sort_by(f64::total_cmp);
        println!(
            "{seconds} s at {rate} Hz, {} DAQ frames of {block} scans: conditioner core ({}) best {:.1} ms, median {:.1} ms ({passes} passes): {:.0}x real time",
            frames.len(),
            chain.name(),
            times[0],
            times[times.len() / 2],
            seconds * 1e3 / times[0]
        );
    }
    let ep = EstimatorParams { window: 25_000, hop: 12_500, signal_band_hz: 55.5, ..EstimatorParams::default() };
    let mut times = Vec::new();
    let mut estimates = 0;
    for _ in 0..passes {
        let mut est = EstimatorCore::new(rig.clone(), ep.clone())?;
        let t0 = Instant::now();
        estimates = 0;
        for c in &conditioned {
            estimates += est.push(c)?.len();
        }
        times.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    println!(
        "{seconds} s at {rate} Hz, {} conditioned frames: estimator core {estimates} estimates in best {:.1} ms, median {:.1} ms ({passes} passes): {:.0}x real time",
        conditioned.len(),
        times[0],
        times[times.len() / 2],
        seconds * 1e3 / times[0]
    );
    Ok(())
}
