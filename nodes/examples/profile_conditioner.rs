//! Where the conditioner node's frame-to-conditioned time goes at 100 kHz x 16 channels:
//! the chain's compute per block (block plus the filters' edge on each side) and the CDR
//! serialisation of the ConditionedFrame (the encoder rustdds uses), per block size; then the
//! estimator node's push that completes a 200 000-sample window, and what is left after the
//! window's last block when its analysis was fed as the blocks arrived.
//!
//! `cargo run --release -p oilfilm-nodes --example profile_conditioner`

use std::time::Instant;

use oilfilm_graph::conditioner::{ConditionerCore, ConditionerParams};
use oilfilm_graph::estimator::{EstimatorCore, EstimatorParams};
use oilfilm_graph::stamp::Stamp;
use oilfilm_identification::estimator::solve::ScaledFactor;
use oilfilm_identification::estimator::spectrum::LineSearch;
use oilfilm_identification::estimator::window::SummaryBuilder;
use oilfilm_identification::estimator::{estimate_window_fed, se_decimation, uncertainty, Signals, Solver, WindowFeed};
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::{window_report_fed, ReportFeed};
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_physics::config::RigConfig;

fn main() -> anyhow::Result<()> {
    let (rate, channels, daq_block, seconds) = (100_000.0, 16usize, 1_000usize, 4.5);
    let mut rig = RigConfig::zhou2004()?;
    rig.daq.sample_rate_hz = rate;
    rig.daq.channel_interval_s = 1.0 / (rate * channels as f64);
    let rec = simulate::simulate(&rig, &ExcitationPlan::two_tone(23.0, 37.0, 300.0), seconds, SimulateOptions::default(), &mut |_| {})?;
    let frames = oilfilm_graph::daq::frames_of_scans(&rig, &rec.scans, daq_block, channels, Stamp(0))?;
    println!("{} frames of {daq_block} scans x {channels} channels at {rate} Hz", frames.len());
    for block in [10_000i64, 5_000, 2_000, 1_000] {
        let params = ConditionerParams { lowpass_cutoff_hz: 55.5, block_scans: block, ..ConditionerParams::default() };
        let mut core = ConditionerCore::new(rig.clone(), &params)?;
        let (mut push_idle, mut push_out, mut ser) = (Vec::new(), Vec::new(), Vec::new());
        let mut bytes = 0;
        for f in &frames {
            let t0 = Instant::now();
            let out = core.push(f)?;
            let dt = t0.elapsed().as_secs_f64() * 1e3;
            if out.is_empty() {
                push_idle.push(dt)
            } else {
                push_out.push(dt)
            }
            for c in &out {
                let t0 = Instant::now();
                let v = ros2_client::dds::rustdds::cdr_encoding::to_vec::<_, byteorder::LittleEndian>(c)?;
                ser.push(t0.elapsed().as_secs_f64() * 1e3);
                bytes = v.len();
            }
        }
        let med = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
        };
        let max = |v: &Vec<f64>| v.iter().copied().fold(f64::NAN, f64::max);
        println!(
            "block {block:>6}: edge {:?} scans; push producing a block median {:.2} ms (max {:.2}), other pushes {:.3} ms; CDR serialisation {:.2} ms (max {:.2}) for {bytes} bytes",
            core.edge_scans(),
            med(&mut push_out), max(&push_out), med(&mut push_idle), med(&mut ser), max(&ser)
        );
    }
    // The estimator node on the conditioned stream (2 000-scan blocks): the push that
    // completes a 200 000-sample window, with the standard errors from every sample and
    // decimated (signal_band_hz = the 55.5 Hz cutoff), and everything else it pushes.
    let params = ConditionerParams { lowpass_cutoff_hz: 55.5, block_scans: 2_000, ..ConditionerParams::default() };
    let mut core = ConditionerCore::new(rig.clone(), &params)?;
    let mut conditioned = Vec::new();
    for f in &frames {
        conditioned.extend(core.push(f)?);
    }
    for band in [0.0, 55.5] {
        let ep = EstimatorParams { window: 200_000, hop: 200_000, speed_rpm: 1500.0, signal_band_hz: band, ..EstimatorParams::default() };
        let mut times = Vec::new();
        for _ in 0..5 {
            let mut est = EstimatorCore::new(rig.clone(), ep.clone())?;
            for c in &conditioned {
                let t0 = Instant::now();
                let out = est.push(c)?;
                if !out.is_empty() {
                    times.push(t0.elapsed().as_secs_f64() * 1e3);
                }
            }
        }
        times.sort_by(f64::total_cmp);
        println!(
            "estimator, signal_band_hz {band}: push completing a 200 000-sample window median {:.2} ms (min {:.2}, {} runs)",
            times.get(times.len() / 2).copied().unwrap_or(f64::NAN),
            times.first().copied().unwrap_or(f64::NAN),
            times.len()
        );
    }
    // The stages of that push on the same window, outside the node.
    let cat = |f: fn(&oilfilm_msgs::ConditionedFrame) -> &Vec<f64>| -> Vec<f64> { conditioned.iter().flat_map(|c| f(c).iter().copied()).collect() };
    let (x, y, vx, vy, fx, fy) = (cat(|c| &c.x_m), cat(|c| &c.y_m), cat(|c| &c.x_dot_m_s), cat(|c| &c.y_dot_m_s), cat(|c| &c.fx_n), cat(|c| &c.fy_n));
    let w = 200_000;
    let signals = Signals { x_m: &x[..w], y_m: &y[..w], vx_m_s: &vx[..w], vy_m_s: &vy[..w], ax_m_s2: None, ay_m_s2: None, fx_n: &fx[..w], fy_n: &fy[..w] };
    let cfg = EstimatorParams { window: 200_000, hop: 200_000, speed_rpm: 1500.0, signal_band_hz: 55.5, ..EstimatorParams::default() }.config(rate)?;
    // After the last sample: the feeds (fed while the window's first 198 000 samples arrived)
    // take the last 2 000-scan block, then the estimate and the report.
    let (mut t_feed, mut t_est, mut t_rep) = (Vec::new(), Vec::new(), Vec::new());
    let head =
        |k: usize| Signals { x_m: &x[..k], y_m: &y[..k], vx_m_s: &vx[..k], vy_m_s: &vy[..k], ax_m_s2: None, ay_m_s2: None, fx_n: &fx[..k], fy_n: &fy[..k] };
    let last = w - 2_000;
    for _ in 0..5 {
        let mut wf = WindowFeed::new(&cfg);
        wf.advance(&head(last));
        let mut rf = ReportFeed::default();
        rf.advance(&x[..last], &y[..last], &fx[..last], &fy[..last]);
        let t0 = Instant::now();
        wf.advance(&signals);
        rf.advance(&x[last..w], &y[last..w], &fx[last..w], &fy[last..w]);
        t_feed.push(t0.elapsed().as_secs_f64() * 1e3);
        let t0 = Instant::now();
        let e = estimate_window_fed(&signals, 0..w, &cfg, wf)?;
        t_est.push(t0.elapsed().as_secs_f64() * 1e3);
        let t0 = Instant::now();
        std::hint::black_box(window_report_fed(rf, &x[..w], &y[..w], e, 40.0, &rig, 1500.0, [0.0, 2.0])?);
        t_rep.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    // Its stages: the search's finish (last segment), the solve from the fed factor, the
    // decimated errors from the kept samples.
    let cols: Vec<&[f64]> = vec![&x[..w], &y[..w], &vx[..w], &vy[..w], &fx[..w], &fy[..w]];
    let q = se_decimation(w, rate, Some(55.5));
    let decimated: Vec<Vec<f64>> = cols.iter().map(|c| c.iter().step_by(q).copied().collect()).collect();
    let dec: Vec<&[f64]> = decimated.iter().map(|c| c.as_slice()).collect();
    let (mut t_fin, mut t_qr, mut t_se) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..5 {
        let mut ls = LineSearch::new(w, rate);
        ls.advance(&x[..last], &y[..last], &vx[..last], &vy[..last]);
        let t0 = Instant::now();
        std::hint::black_box(ls.finish(&x[..w], &y[..w], &vx[..w], &vy[..w]));
        t_fin.push(t0.elapsed().as_secs_f64() * 1e3);
        let mut builder = SummaryBuilder::new(6);
        let head_cols: Vec<&[f64]> = cols.iter().map(|c| &c[..last]).collect();
        builder.push(&head_cols);
        let t0 = Instant::now();
        let tail_cols: Vec<&[f64]> = cols.iter().map(|c| &c[last..]).collect();
        builder.push(&tail_cols);
        let summary = builder.finish();
        let factor = ScaledFactor::new(&summary, 4).ok_or_else(|| anyhow::anyhow!("factor"))?;
        let sol = factor.solve(Solver::Qr).ok_or_else(|| anyhow::anyhow!("solve"))?;
        t_qr.push(t0.elapsed().as_secs_f64() * 1e3);
        let t0 = Instant::now();
        std::hint::black_box(uncertainty::spectral_of_decimated(&dec, w, 4, &factor.mean, &factor.scale, &sol.coef, &sol.inverse_gram_scaled, q));
        t_se.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    for v in [&mut t_feed, &mut t_est, &mut t_rep, &mut t_fin, &mut t_qr, &mut t_se] {
        v.sort_by(f64::total_cmp);
    }
    println!(
        "  after the last 2 000-scan block (medians of 5): feeds take the block {:.2} ms, estimate_window_fed {:.2} ms, window_report_fed {:.2} ms",
        t_feed[2], t_est[2], t_rep[2]
    );
    println!(
        "  stages: line search finish (last segment) {:.2} ms, last QR chunks + solve {:.2} ms, decimated spectral SE {:.2} ms",
        t_fin[2], t_qr[2], t_se[2]
    );
    Ok(())
}
