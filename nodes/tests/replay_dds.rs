//! The replay graph on real DDS: the `oilfilm-daq` binary replays an ASCII record with
//! malformed rows in it, the conditioner and estimator binaries identify. The bad rows are
//! skipped (each a gap the conditioner restarts at), the DAQ finishes the file and exits 0,
//! and the estimates after the damage are solved and near the film's coefficients: the
//! graph keeps running.

#[path = "../../tests/support/scratch.rs"]
mod scratch;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use scratch::Scratch;

use oilfilm_graph::exciter::ExciterParams;
use oilfilm_graph::launch::NodeLaunch;
use oilfilm_graph::params::NodeArgs;
use oilfilm_graph::ports::Receive;
use oilfilm_graph::topics;
use oilfilm_identification::ascii::{self, Units};
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_msgs::{CoefficientEstimate, ConditionedFrame};
use oilfilm_nodes::dds::RosNode;
use oilfilm_nodes::supervisor::Supervisor;
use oilfilm_physics::config::RigConfig;

fn bin_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_oilfilm-daq")).parent().unwrap().to_path_buf()
}

#[test]
fn a_damaged_record_replays_on_dds_and_still_identifies() {
    let rig = RigConfig::zhou2004().unwrap();
    let plan = ExciterParams { amplitude_n: 300.0, ..ExciterParams::default() }.plan().unwrap();
    let sim = simulate::simulate(&rig, &plan, 13.0, SimulateOptions::default(), &mut |_| {}).unwrap();
    let record = sim.to_ascii(&rig, Units::Volts).unwrap();
    let text = ascii::write(&record).unwrap();
    // Damage three rows early in the record: a ragged row, a bad number, a row cut short.
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let first_row = lines.iter().position(|l| l.starts_with("0 ") || l.starts_with("0\t")).expect("row of scan 0");
    let bad = [first_row + 2000, first_row + 2500, first_row + 3000];
    lines[bad[0]].push_str(" 1.0");
    lines[bad[1]] = lines[bad[1]].replacen(' ', " x", 2);
    let cut = lines[bad[2]].len() / 2;
    lines[bad[2]].truncate(cut);
    let file = Scratch::new("oilfilm-replay-dds", "damaged.txt");
    std::fs::write(&file, lines.join("\n") + "\n").unwrap();

    std::env::set_var("ROS_DOMAIN_ID", (40 + std::process::id() % 50).to_string());
    let me = NodeArgs { name: "replay_probe".into(), namespace: topics::NAMESPACE.into(), ..Default::default() };
    let mut ros = RosNode::new(&me).unwrap();
    let mut estimates = ros.subscription::<CoefficientEstimate>(&topics::ESTIMATES).unwrap();
    let mut conditioned = ros.subscription::<ConditionedFrame>(&topics::CONDITIONED).unwrap();
    let node = |name: &str, params: &[String]| {
        let mut args: Vec<String> = ["--ros-args", "-r", &format!("__node:={name}"), "-r", "__ns:=/oilfilm"].iter().map(|s| s.to_string()).collect();
        for p in params {
            args.extend(["-p".to_string(), p.clone()]);
        }
        NodeLaunch { exec: format!("oilfilm-{name}"), name: name.into(), namespace: "/oilfilm".into(), args }
    };
    let nodes = [
        node("daq", &["source:=ascii".into(), format!("file:={}", file.display()), "rate_factor:=10.0".into(), "block_scans:=500".into()]),
        node("conditioner", &["lowpass_cutoff_hz:=55.5".into(), "block_scans:=1000".into()]),
        node("estimator", &["window:=25000".into(), "hop:=25000".into()]),
    ];
    let mut graph = Supervisor::start(&nodes, &bin_dir()).unwrap();
    let (mut got, mut restarts) = (Vec::new(), Vec::new());
    let mut daq_done = None;
    let deadline = Instant::now() + Duration::from_secs(90);
    while Instant::now() < deadline {
        while let Some(e) = estimates.receive().unwrap() {
            got.push(e);
        }
        while let Some(c) = conditioned.receive().unwrap() {
            for f in c.flags.iter().filter(|f| f.contains("restarted")) {
                restarts.extend(f.split("; ").filter(|p| p.contains("restarted")).map(str::to_string));
            }
        }
        if let Some((name, status)) = graph.exited() {
            assert_eq!(name, "daq", "{name} died: {status}");
            assert!(status.success(), "the DAQ must finish the damaged file: {status}");
            daq_done = Some(Instant::now());
        }
        if daq_done.is_some_and(|t| t.elapsed() > Duration::from_secs(3)) {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    graph.stop(Duration::from_secs(5));
    drop((estimates, conditioned));
    ros.shutdown();
    assert!(daq_done.is_some(), "the DAQ did not finish the file");
    println!("restarts: {restarts:?}");
    assert_eq!(restarts.len(), 3, "one restart per skipped row: {restarts:?}");
    assert!(!got.is_empty(), "no estimate after the damaged rows");
    let kt = sim.truth.coefficients.stiffness_n_m;
    for e in &got {
        assert!(e.solved, "{}", e.refusal_reason);
        assert!(e.window_start_sample > 3000, "windows start after the last restart");
        for k in [0, 3] {
            let t = kt[(k / 2, k % 2)];
            assert!(((e.stiffness_n_m[k] - t) / t).abs() < 0.1, "k{k}: {} vs {t}", e.stiffness_n_m[k]);
        }
    }
}
