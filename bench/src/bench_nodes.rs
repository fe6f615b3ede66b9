//! `oilfilm-bench nodes`: the conditioner and estimator node binaries on loopback DDS, fed
//! DAQ frames at real-time pace by this process, which also receives what they publish.
//!
//! Reported per configuration: frame-to-conditioned and frame-to-estimate latency (median,
//! p99, max), sustained throughput, drops, and the CPU the two nodes used (from
//! /proc/PID/stat). Latency is measured from the publication of the DAQ frame that
//! completes the data an output needs (the conditioned block plus the filters' edge
//! samples; for an estimate, the last block of its window) to its reception here: it
//! includes transport, conditioning and estimation, not the waiting for data that the
//! block and window lengths impose by definition. Beside it, each row states that wait: the
//! conditioner's zero-phase edge (`edge scans / rate`: a block is filtered only once the
//! samples that far past its end are in) or, for the causal chain (ADR 0014), its fixed delay
//! (a sample is out that many scans after its own), and acquisition-to-estimate, from the
//! acquisition of a window's last sample to the estimate's reception (the edge or delay, the
//! rest of the last conditioner block, and frame-to-estimate).

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use oilfilm_graph::conditioner::{Chain, ConditionerParams};
use oilfilm_graph::params::NodeArgs;
use oilfilm_graph::ports::{Publish, Receive};
use oilfilm_graph::stamp::Stamp;
use oilfilm_graph::topics;
use oilfilm_identification::conditioning::{self};
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::calibration_for;
use oilfilm_identification::pipeline::mechanics_of;
use oilfilm_identification::record::{RawRecord, RawUnits};
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_msgs::{CoefficientEstimate, ConditionedFrame, DaqFrame};
use oilfilm_nodes::dds::RosNode;
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::ChannelId;

/// One benchmark configuration.
struct Case {
    label: &'static str,
    rate_hz: f64,
    channels: usize,
    daq_block: usize,
    conditioner_block: usize,
    window: usize,
    /// The estimator's `signal_band_hz` (0: standard errors from every sample).
    signal_band_hz: f64,
    /// The conditioner's `chain`.
    chain: Chain,
}

/// The conditioner's low-pass cutoff in every row (1.5 x the 37 Hz line).
const CUTOFF_HZ: f64 = 55.5;

const CASES: [Case; 6] = [
    Case {
        label: "5 kHz x 10 ch",
        rate_hz: 5_000.0,
        channels: 10,
        daq_block: 500,
        conditioner_block: 1_000,
        window: 25_000,
        signal_band_hz: CUTOFF_HZ,
        chain: Chain::ZeroPhase,
    },
    // Standard errors from every sample: the cost after a 200 000-sample window's end is
    // five 262 144-point FFTs.
    Case {
        label: "100 kHz x 16 ch, SE from every sample",
        rate_hz: 100_000.0,
        channels: 16,
        daq_block: 1_000,
        conditioner_block: 10_000,
        window: 200_000,
        signal_band_hz: 0.0,
        chain: Chain::ZeroPhase,
    },
    // Standard errors from every 10th sample (the signals are band-limited to 55.5 Hz).
    Case {
        label: "100 kHz x 16 ch",
        rate_hz: 100_000.0,
        channels: 16,
        daq_block: 1_000,
        conditioner_block: 10_000,
        window: 200_000,
        signal_band_hz: CUTOFF_HZ,
        chain: Chain::ZeroPhase,
    },
    // The same with the conditioner's blocks five times shorter: its edge (12 091 scans each side
    // at 100 kHz) dominates a block's compute either way (2.0 against 2.5 ms), so shorter blocks
    // cost CPU but cut the ConditionedFrame from 650 to 130 kB, and frame->conditioned with it.
    Case {
        label: "100 kHz x 16 ch, 2 000-scan blocks",
        rate_hz: 100_000.0,
        channels: 16,
        daq_block: 1_000,
        conditioner_block: 2_000,
        window: 200_000,
        signal_band_hz: CUTOFF_HZ,
        chain: Chain::ZeroPhase,
    },
    // The causal chain (ADR 0014): a sample is out 11 scans after its own (L + 2M = 1 + 10 on these schedules), no edge.
    Case {
        label: "causal: 5 kHz x 10 ch",
        rate_hz: 5_000.0,
        channels: 10,
        daq_block: 500,
        conditioner_block: 1_000,
        window: 25_000,
        signal_band_hz: CUTOFF_HZ,
        chain: Chain::Causal,
    },
    Case {
        label: "causal: 100 kHz x 16 ch, 2 000-scan blocks",
        rate_hz: 100_000.0,
        channels: 16,
        daq_block: 1_000,
        conditioner_block: 2_000,
        window: 200_000,
        signal_band_hz: CUTOFF_HZ,
        chain: Chain::Causal,
    },
];

fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// utime + stime of a process, s.
fn cpu_seconds(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which is in parentheses and may hold spaces).
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

pub fn run(seconds: f64) -> Result<()> {
    anyhow::ensure!(seconds.is_finite() && seconds >= 5.0, "--seconds must be >= 5, got {seconds}");
    let bin_dir = std::env::current_exe()?.parent().map(PathBuf::from).unwrap_or_default();
    for exe in ["oilfilm-conditioner", "oilfilm-estimator"] {
        if !bin_dir.join(exe).exists() {
            bail!("{exe} not found in {} (cargo build --release --workspace)", bin_dir.display());
        }
    }
    println!("oilfilm-bench nodes: conditioner and estimator binaries on loopback DDS (ros2-client), frames published at real-time pace, {seconds} s per row");
    println!("machine: {} cores; the publisher, the two nodes and this receiver share them", std::thread::available_parallelism().map_or(1, |n| n.get()));
    println!();
    println!("| configuration | frames/s | frame->conditioned median / p99 / max (ms) | frame->estimate median / p99 / max (ms) | zero-phase edge / causal delay wait (ms) | acquisition->estimate median / p99 (ms) | estimates | drops | CPU conditioner / estimator (% of a core) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for case in &CASES {
        let row = run_case(case, seconds, &bin_dir).with_context(|| case.label)?;
        println!("{row}");
    }
    println!();
    println!("targets (issue 4): p99 <= 20 ms, 0 drops at 100 kHz x 16 ch");
    Ok(())
}

fn run_case(case: &Case, seconds: f64, bin_dir: &Path) -> Result<String> {
    // The record: the Zhou rig at this rate (the multiplexer paced to fit the channels).
    let mut rig = RigConfig::zhou2004()?;
    rig.daq.sample_rate_hz = case.rate_hz;
    rig.daq.channel_interval_s = 1.0 / (case.rate_hz * case.channels as f64);
    let plan = ExcitationPlan::two_tone(23.0, 37.0, 300.0);
    eprint!("simulating {seconds} s at {} Hz ... ", case.rate_hz);
    let rec = simulate::simulate(&rig, &plan, seconds, SimulateOptions::default(), &mut |_| {})?;
    eprintln!("done");
    let cal = rig.daq.calibration();
    let order = cal.scan_order();
    let offsets: Vec<f64> = order.iter().map(|&c| cal.sample_offset_s(c)).collect::<Result<_, _>>()?;
    let epoch = Stamp::now();
    let frames = oilfilm_graph::daq::frames_of_scans(&rig, &rec.scans, case.daq_block, case.channels, epoch)?;

    // The conditioner's edge (zero-phase: the scans past a block it waits for; causal: the
    // scans past a sample) and its first sample, as it will compute them.
    let cp = ConditionerParams {
        lowpass_cutoff_hz: CUTOFF_HZ,
        block_scans: case.conditioner_block as i64,
        chain: case.chain.name().into(),
        ..ConditionerParams::default()
    };
    let kept: Vec<ChannelId> = order.clone();
    let probe =
        RawRecord { sample_rate_hz: case.rate_hz, start_time_s: 0.0, channels: kept.clone(), units: RawUnits::Volts, columns: vec![Vec::new(); kept.len()] };
    let calibration = calibration_for(&rig, &probe, &offsets[..kept.len()])?;
    let (edge, s0) = match case.chain {
        Chain::ZeroPhase => {
            let edge = conditioning::Chain::new(&calibration, &mechanics_of(&rig), &cp.conditioning()?, case.rate_hz)?.edge();
            (edge, edge as u64)
        }
        Chain::Causal => {
            // Its blocks start at multiples of the block length (crates/graph/src/conditioner.rs).
            let d = conditioning::causal::delays(&calibration, &cp.conditioning()?, case.rate_hz)?;
            (d.delay_scans(), (d.first_index() as u64).div_ceil(case.conditioner_block as u64) * case.conditioner_block as u64)
        }
    };

    let dir = std::env::temp_dir().join(format!("oilfilm-bench-nodes-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let rig_path = dir.join(format!("rig_{}.toml", case.rate_hz as u64));
    std::fs::write(&rig_path, rig.to_toml_string()?)?;
    let domain = 150 + (std::process::id() % 50) as u16;
    // SAFETY of the environment: set before this process's DDS context and the children.
    std::env::set_var("ROS_DOMAIN_ID", domain.to_string());
    let rig_arg = format!("rig:={}", rig_path.display());
    let spawn = |exe: &str, name: &str, params: &[String]| -> Result<Child> {
        let mut args: Vec<String> = vec!["--ros-args".into(), "-r".into(), format!("__node:={name}"), "-r".into(), "__ns:=/oilfilm".into()];
        for p in params {
            args.extend(["-p".into(), p.clone()]);
        }
        Command::new(bin_dir.join(exe)).args(&args).env("RUST_LOG", "warn").spawn().with_context(|| format!("starting {exe}"))
    };
    let mut conditioner = spawn(
        "oilfilm-conditioner",
        "conditioner",
        &[
            rig_arg.clone(),
            format!("lowpass_cutoff_hz:={CUTOFF_HZ}"),
            format!("block_scans:={}", case.conditioner_block),
            format!("chain:={}", case.chain.name()),
        ],
    )?;
    let mut estimator = spawn(
        "oilfilm-estimator",
        "estimator",
        &[
            rig_arg,
            format!("window:={}", case.window),
            format!("hop:={}", case.window),
            "speed_rpm:=1500.0".into(),
            format!("signal_band_hz:={:?}", case.signal_band_hz),
        ],
    )?;

    let me = NodeArgs { name: "bench_nodes".into(), namespace: topics::NAMESPACE.into(), ..Default::default() };
    let mut ros = RosNode::new(&me)?;
    let mut out = ros.publisher::<DaqFrame>(&topics::DAQ_FRAMES)?;
    let mut cond_in = ros.subscription::<ConditionedFrame>(&topics::CONDITIONED)?;
    let mut est_in = ros.subscription::<CoefficientEstimate>(&topics::ESTIMATES)?;
    // Discovery: give the nodes time to start and match.
    std::thread::sleep(Duration::from_secs(3));

    let cpu0 = (cpu_seconds(conditioner.id()), cpu_seconds(estimator.id()));
    let period = Duration::from_secs_f64(case.daq_block as f64 / case.rate_hz);
    let mut published: Vec<Instant> = Vec::with_capacity(frames.len());
    let mut conditioned: Vec<(ConditionedFrame, Instant)> = Vec::new();
    let mut estimates: Vec<(CoefficientEstimate, Instant)> = Vec::new();
    let start = Instant::now();
    let mut next = 0;
    let drain = |cond_in: &mut dyn Receive<ConditionedFrame>,
                 est_in: &mut dyn Receive<CoefficientEstimate>,
                 c: &mut Vec<(ConditionedFrame, Instant)>,
                 e: &mut Vec<(CoefficientEstimate, Instant)>|
     -> Result<usize> {
        let mut n = 0;
        while let Some(m) = cond_in.receive()? {
            c.push((m, Instant::now()));
            n += 1;
        }
        while let Some(m) = est_in.receive()? {
            e.push((m, Instant::now()));
            n += 1;
        }
        Ok(n)
    };
    while next < frames.len() {
        let due = start + period * next as u32;
        if Instant::now() >= due {
            out.publish(frames[next].clone())?;
            published.push(Instant::now());
            next += 1;
        }
        if drain(&mut cond_in, &mut est_in, &mut conditioned, &mut estimates)? == 0 {
            std::thread::sleep(Duration::from_micros(200));
        }
    }
    let wall = start.elapsed().as_secs_f64();
    // Let the last outputs arrive.
    let settle = Instant::now();
    while settle.elapsed() < Duration::from_secs(3) {
        if drain(&mut cond_in, &mut est_in, &mut conditioned, &mut estimates)? == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    let cpu1 = (cpu_seconds(conditioner.id()), cpu_seconds(estimator.id()));
    for c in [&mut conditioner, &mut estimator] {
        let _ = Command::new("kill").args(["-INT", &c.id().to_string()]).status();
    }
    let _ = conditioner.wait();
    let _ = estimator.wait();
    drop((out, cond_in, est_in));
    ros.shutdown();

    // The frame holding raw scan `s`, and when it was published.
    let frame_of = |s: u64| -> Option<Instant> { published.get((s / case.daq_block as u64) as usize).copied() };
    // `s0`: the first conditioned sample (the stream starts at scan 0).
    let mut cond_lat = Vec::new();
    for (c, t) in &conditioned {
        let trigger = c.first_sample + c.x_m.len() as u64 + edge as u64 - 1;
        if let Some(p) = frame_of(trigger) {
            cond_lat.push(t.duration_since(p).as_secs_f64() * 1e3);
        }
    }
    let bc = case.conditioner_block as u64;
    let mut est_lat = Vec::new();
    let mut acq_lat = Vec::new();
    for (e, t) in &estimates {
        let last = e.window_end_sample - 1;
        let block_end = s0 + ((last - s0) / bc + 1) * bc;
        let trigger = block_end + edge as u64 - 1;
        if let Some(p) = frame_of(trigger) {
            let lat = t.duration_since(p).as_secs_f64() * 1e3;
            est_lat.push(lat);
            // The trigger scan is acquired (trigger - last) scans after the window's last.
            acq_lat.push(lat + (trigger - last) as f64 / case.rate_hz * 1e3);
        }
    }
    // Drops: every conditioned block must follow the previous one, none restarted.
    let mut drops = 0;
    for w in conditioned.windows(2) {
        if w[1].0.first_sample != w[0].0.first_sample + w[0].0.x_m.len() as u64 {
            drops += 1;
        }
    }
    drops += conditioned.iter().filter(|(c, _)| c.flags.iter().any(|f| f.contains("restarted"))).count();
    let expected_blocks = (frames.len() * case.daq_block).saturating_sub(s0 as usize + edge) / case.conditioner_block;
    drops += expected_blocks.saturating_sub(conditioned.len());
    let solved = estimates.iter().filter(|(e, _)| e.solved).count();
    let cpu = |a: Option<f64>, b: Option<f64>| match (a, b) {
        (Some(a), Some(b)) => format!("{:.1}", 100.0 * (b - a) / wall),
        _ => "n/a".into(),
    };
    let (m1, p1, x1) = (percentile(&mut cond_lat.clone(), 0.5), percentile(&mut cond_lat.clone(), 0.99), percentile(&mut cond_lat, 1.0));
    let (m2, p2, x2) = (percentile(&mut est_lat.clone(), 0.5), percentile(&mut est_lat.clone(), 0.99), percentile(&mut est_lat, 1.0));
    let (m3, p3) = (percentile(&mut acq_lat.clone(), 0.5), percentile(&mut acq_lat, 0.99));
    Ok(format!(
        "| {} | {:.0} ({:.1} M samples/s) | {m1:.2} / {p1:.2} / {x1:.2} | {m2:.2} / {p2:.2} / {x2:.2} | {:.1} ({edge} scans) | {m3:.1} / {p3:.1} | {} ({} solved) | {drops} of {expected_blocks} blocks | {} / {} |",
        case.label,
        frames.len() as f64 / wall,
        (frames.len() * case.daq_block * case.channels) as f64 / wall / 1e6,
        edge as f64 / case.rate_hz * 1e3,
        estimates.len(),
        solved,
        cpu(cpu0.0, cpu1.0),
        cpu(cpu0.1, cpu1.1),
    ))
}
