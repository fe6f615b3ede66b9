//! Records the reference bag of `bags/`: the in-memory `sim_rig` graph (the nodes, as
//! `oilfilm launch` runs them) with the parameters of a ROS 2 params file, every topic
//! written to a rosbag2 MCAP bag (zstd chunks, one file).
//!
//!     write_reference_bag PARAMS_FILE DIR
//!
//! `bags/README.md` names the command that made the committed bag. Prints the bag's size and
//! each window's estimate beside the simulated film's own linear coefficients.

#[path = "common/sim_rig.rs"]
mod sim_rig;

use std::path::PathBuf;

use anyhow::Context;
use oilfilm_graph::runner::memory::{run_sim_rig, GraphParams};
use oilfilm_physics::config::RigConfig;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let (Some(params_file), Some(dir)) = (args.next().map(PathBuf::from), args.next().map(PathBuf::from)) else {
        anyhow::bail!("usage: write_reference_bag PARAMS_FILE DIR");
    };
    let p = GraphParams::from_params_file(&params_file)?;
    let rig = RigConfig::zhou2004()?;
    let (rec, truth) = run_sim_rig(&rig, &p).context("running the sim_rig graph")?;
    let msgs = sim_rig::published(&rec);
    sim_rig::write_bag(&dir, &msgs, oilfilm_bag::WriterOptions::default())?.close()?;
    let bytes: u64 = std::fs::read_dir(&dir)?.filter_map(|e| e.ok()?.metadata().ok()).map(|m| m.len()).sum();
    println!(
        "{}: {} messages, {} DAQ frames, {} estimates, {:.2} MB on disk",
        dir.display(),
        msgs.len(),
        rec.frames.len(),
        rec.estimates.len(),
        bytes as f64 / 1e6
    );
    let k = truth.coefficients.stiffness_n_m;
    let c = truth.coefficients.damping_n_s_m;
    println!(
        "film:   K [{:.4e} {:.4e} {:.4e} {:.4e}] N/m, C [{:.4e} {:.4e} {:.4e} {:.4e}] N s/m",
        k[(0, 0)],
        k[(0, 1)],
        k[(1, 0)],
        k[(1, 1)],
        c[(0, 0)],
        c[(0, 1)],
        c[(1, 0)],
        c[(1, 1)]
    );
    for e in &rec.estimates {
        let (k, c) = (e.stiffness_n_m, e.damping_n_s_m);
        if e.solved {
            println!(
                "window {}-{}: K [{:.4e} {:.4e} {:.4e} {:.4e}], C [{:.4e} {:.4e} {:.4e} {:.4e}]",
                e.window_start_sample, e.window_end_sample, k[0], k[1], k[2], k[3], c[0], c[1], c[2], c[3]
            );
        } else {
            println!("window {}-{}: REFUSED {}", e.window_start_sample, e.window_end_sample, e.refusal_reason);
        }
    }
    Ok(())
}
