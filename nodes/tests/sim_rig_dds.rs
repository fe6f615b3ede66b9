//! End to end on real DDS: the four node binaries started as `oilfilm launch` starts them,
//! talking through ros2-client; the estimates the estimator publishes are received by a
//! ros2-client subscriber and must (1) match the simulated film's linear coefficients within
//! the identification tolerances (1 % stiffness, 2 % damping at 40 dB) and (2) equal, bit for
//! bit, what the same graph gives on in-memory topics: the transport changes nothing. The
//! paper's single sine gets refusals, not numbers.
//!
//! Each run uses its own ROS_DOMAIN_ID so concurrent test binaries cannot cross-talk.

#[path = "../../tests/support/scratch.rs"]
mod scratch;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use oilfilm_graph::launch::NodeLaunch;
use oilfilm_graph::params::NodeArgs;
use oilfilm_graph::ports::Receive;
use oilfilm_graph::runner::memory::{run_sim_rig, GraphParams};
use oilfilm_graph::topics;
use oilfilm_msgs::cdr::encode;
use oilfilm_msgs::CoefficientEstimate;
use oilfilm_nodes::dds::RosNode;
use oilfilm_nodes::supervisor::Supervisor;
use oilfilm_physics::config::RigConfig;
use scratch::Scratch;

#[path = "../../crates/graph/tests/common/mod.rs"]
mod common;
use common::{params, rig_at_40_db};

fn bin_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_oilfilm-daq")).parent().unwrap().to_path_buf()
}

/// Writes the rig file and a ROS 2 params file for `p` into `dir`.
fn write_params(dir: &Path, rig: &RigConfig, p: &GraphParams) -> PathBuf {
    let rig_path = dir.join("rig.toml");
    std::fs::write(&rig_path, rig.to_toml_string().unwrap()).unwrap();
    let mut p = p.clone();
    let rig_s = rig_path.display().to_string();
    p.exciter.rig = rig_s.clone();
    p.daq.rig = rig_s.clone();
    p.conditioner.rig = rig_s.clone();
    p.estimator.rig = rig_s;
    // Four times real time: 21 s of rig in ~5 s.
    p.daq.rate_factor = 4.0;
    // The rig clock starts where the in-memory graph's does (not at the wall clock), so the
    // stamps match too.
    p.daq.start_stamp_ns = oilfilm_graph::runner::memory::EPOCH.0;
    let mut doc = BTreeMap::new();
    let section = |v: serde_json::Value| serde_json::json!({ "ros__parameters": v });
    doc.insert("/oilfilm/exciter", section(serde_json::to_value(&p.exciter).unwrap()));
    doc.insert("/oilfilm/daq", section(serde_json::to_value(&p.daq).unwrap()));
    doc.insert("/oilfilm/conditioner", section(serde_json::to_value(&p.conditioner).unwrap()));
    doc.insert("/oilfilm/estimator", section(serde_json::to_value(&p.estimator).unwrap()));
    let path = dir.join("params.yaml");
    std::fs::write(&path, serde_yaml_ng::to_string(&doc).unwrap()).unwrap();
    path
}

/// Runs the graph on DDS until `expected` estimates arrived (or a minute passed).
fn run_on_dds(tag: &str, rig: &RigConfig, p: &GraphParams, expected: usize) -> Vec<CoefficientEstimate> {
    // The rig and params files, removed when the run's checks pass.
    let dir = Scratch::new(&format!("oilfilm-dds-{tag}"), "files");
    std::fs::create_dir_all(&*dir).unwrap();
    let params = write_params(&dir, rig, p);
    // 100..170: the interop tests, which tests/run-all.sh runs beside these, take 170..220.
    let domain = 100 + (std::process::id() % 35) as u16 + if tag == "sine" { 35 } else { 0 };
    // SAFETY of the environment: set before any DDS context of this test exists; the two tests
    // of this file run one after the other (see the mutex below).
    std::env::set_var("ROS_DOMAIN_ID", domain.to_string());
    let me = NodeArgs { name: format!("e2e_{tag}"), namespace: topics::NAMESPACE.into(), ..Default::default() };
    let mut ros = RosNode::new(&me).unwrap();
    let mut sub = ros.subscription::<CoefficientEstimate>(&topics::ESTIMATES).unwrap();
    let nodes: Vec<NodeLaunch> = ["exciter", "daq", "conditioner", "estimator"]
        .iter()
        .map(|n| NodeLaunch {
            exec: format!("oilfilm-{n}"),
            name: n.to_string(),
            namespace: "/oilfilm".into(),
            args: ["--ros-args", "-r", &format!("__node:={n}"), "-r", "__ns:=/oilfilm", "--params-file", &params.display().to_string()]
                .iter()
                .map(|s| s.to_string())
                .collect(),
        })
        .collect();
    let mut graph = Supervisor::start(&nodes, &bin_dir()).unwrap();
    let mut got = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(90);
    while got.len() < expected && Instant::now() < deadline {
        match sub.receive().unwrap() {
            Some(e) => got.push(e),
            None => std::thread::sleep(Duration::from_millis(5)),
        }
        if let Some((name, status)) = graph.exited() {
            assert!(status.success() || name == "daq", "node {name} died: {status}");
        }
    }
    graph.stop(Duration::from_secs(5));
    ros.shutdown();
    got
}

static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn sim_rig_on_dds_matches_the_film_and_the_in_memory_graph_bit_for_bit() {
    on_dds_as_in_memory("zero_phase");
}

/// The same with the causal conditioning chain (ADR 0014; the launch configs' default).
#[test]
fn sim_rig_on_dds_with_the_causal_chain_matches_the_film_and_the_in_memory_graph_bit_for_bit() {
    on_dds_as_in_memory("causal");
}

fn on_dds_as_in_memory(chain: &str) {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let mut p = params(21.0);
    p.conditioner.chain = chain.into();
    let rig = rig_at_40_db(&p.exciter.plan().unwrap());
    let (memory, truth) = run_sim_rig(&rig, &p).unwrap();
    assert_eq!(memory.estimates.len(), 2);
    let dds = run_on_dds(&format!("two_tone_{chain}"), &rig, &p, memory.estimates.len());
    assert_eq!(dds.len(), memory.estimates.len(), "estimates received over DDS");
    let kt = truth.coefficients.stiffness_n_m;
    let ct = truth.coefficients.damping_n_s_m;
    for (d, m) in dds.iter().zip(&memory.estimates) {
        assert!(d.solved, "{}", d.refusal_reason);
        for k in 0..4 {
            let (i, j) = (k / 2, k % 2);
            let ke = (d.stiffness_n_m[k] - kt[(i, j)]) / kt[(i, j)];
            let ce = (d.damping_n_s_m[k] - ct[(i, j)]) / ct[(i, j)];
            println!("{chain}: DDS window {}: coefficient {k}: stiffness {:+.3} %, damping {:+.3} %", d.window_start_sample, 100.0 * ke, 100.0 * ce);
            assert!(ke.abs() < 0.01 && ce.abs() < 0.02);
        }
        assert_eq!(encode(d), encode(m), "window {}: the DDS graph differs from the in-memory graph", d.window_start_sample);
    }
}

#[test]
fn the_papers_single_sine_on_dds_gets_refusals() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let mut p = params(16.0);
    p.exciter.plan = "sine".into();
    p.exciter.frequency_1_hz = 37.0;
    let rig = RigConfig::zhou2004().unwrap();
    let dds = run_on_dds("sine", &rig, &p, 1);
    assert!(!dds.is_empty(), "no estimate arrived");
    for e in &dds {
        assert!(!e.solved && e.stiffness_n_m.iter().all(|v| v.is_nan()), "a single sine must be refused: {:?}", e.stiffness_n_m);
        println!("DDS refusal: {}", e.refusal_reason);
    }
}
