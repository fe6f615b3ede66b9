//! Every shipped launch file runs in the in-memory runner as `oilfilm launch` runs it on DDS:
//! the same YAML, the same params files, the same nodes; only the run's length (and where a
//! file needs one, an input) given on top, as on a command line.

use std::path::{Path, PathBuf};

use oilfilm_bag::{Bag, OilfilmMessage};
use oilfilm_graph::runner::memory::{run_sim_rig, shipped, Graph, GraphParams};
use oilfilm_graph::topics;
use oilfilm_identification::ascii::{self, Units};
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::simulate::{simulate, SimulateOptions};
use oilfilm_msgs::{encode, CoefficientEstimate, DaqFrame, ExciterCommand};
use oilfilm_physics::config::RigConfig;

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("oilfilm-launch-files-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn bytes<M: oilfilm_msgs::RosMessage + serde::Serialize>(v: &[M]) -> Vec<Vec<u8>> {
    v.iter().map(encode).collect()
}

#[test]
fn sim_rig_from_its_launch_file_is_the_sim_graph() {
    let rig = RigConfig::zhou2004().unwrap();
    let mut g = Graph::from_launch(&shipped("sim_rig.launch.yaml"), &[], &[("daq", "duration_s", "11.0")], Some(&rig)).unwrap();
    let mut estimates = g.tap::<CoefficientEstimate>(&topics::ESTIMATES).unwrap();
    let mut frames = g.tap::<DaqFrame>(&topics::DAQ_FRAMES).unwrap();
    g.run().unwrap();
    let (estimates, frames) = (estimates.drain(), frames.drain());
    assert_eq!(frames.len(), 110, "11 s of 0.1 s frames");
    assert!(!estimates.is_empty() && estimates.iter().all(|e| e.solved));
    // The typed parameters read from the same file give the same graph, bit for bit.
    let (rec, _) = run_sim_rig(&rig, &GraphParams::sim_rig(11.0, 25_000, 12_500).unwrap()).unwrap();
    assert_eq!(bytes(&rec.frames), bytes(&frames));
    assert_eq!(bytes(&rec.estimates), bytes(&estimates));
}

#[test]
fn record_sim_rig_records_what_the_graph_published() {
    let dir = scratch("record");
    let args = [("bag".to_string(), dir.display().to_string())];
    let mut g = Graph::from_launch(&shipped("record_sim_rig.launch.yaml"), &args, &[("daq", "duration_s", "11.0")], None).unwrap();
    let mut commands = g.tap::<ExciterCommand>(&topics::EXCITER_COMMAND).unwrap();
    let mut frames = g.tap::<DaqFrame>(&topics::DAQ_FRAMES).unwrap();
    let mut estimates = g.tap::<CoefficientEstimate>(&topics::ESTIMATES).unwrap();
    g.run().unwrap();
    let (commands, frames, estimates) = (commands.drain(), frames.drain(), estimates.drain());
    let bag = Bag::open(&dir).unwrap();
    let (mut got_frames, mut got_estimates, mut got_commands) = (Vec::new(), Vec::new(), Vec::new());
    for m in bag.messages().unwrap() {
        match m.decode_ours().unwrap() {
            OilfilmMessage::DaqFrame(f) => got_frames.push(f),
            OilfilmMessage::CoefficientEstimate(e) => got_estimates.push(e),
            OilfilmMessage::ExciterCommand(c) => got_commands.push(c),
            _ => {}
        }
    }
    assert_eq!(frames.len(), 110);
    assert!(!estimates.is_empty());
    assert_eq!(bytes(&got_frames), bytes(&frames), "the bag holds every frame, byte for byte");
    assert_eq!(bytes(&got_estimates), bytes(&estimates));
    // The recorder, listed first, stops last: the exciter's ramp to zero is in the bag too.
    assert!(commands.last().is_some_and(|c| c.stop));
    assert_eq!(bytes(&got_commands), bytes(&commands));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn replay_runs_an_ascii_record_through_the_graph() {
    let rig = RigConfig::zhou2004().unwrap();
    let sim = simulate(&rig, &ExcitationPlan::two_tone(23.0, 37.0, 100.0), 4.0, SimulateOptions::default(), &mut |_| {}).unwrap();
    let dir = scratch("replay");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("run.txt");
    std::fs::write(&file, ascii::write(&sim.to_ascii(&rig, Units::Volts).unwrap()).unwrap()).unwrap();
    let args = [("file".to_string(), file.display().to_string()), ("rate_factor".to_string(), "0".to_string())];
    // 2 s windows: the file's 10 s would not fit a 4 s record.
    let overrides = [("estimator", "window", "10000"), ("estimator", "hop", "5000")];
    let mut g = Graph::from_launch(&shipped("replay.launch.yaml"), &args, &overrides, None).unwrap();
    let mut frames = g.tap::<DaqFrame>(&topics::DAQ_FRAMES).unwrap();
    let mut estimates = g.tap::<CoefficientEstimate>(&topics::ESTIMATES).unwrap();
    g.run().unwrap();
    let (frames, estimates) = (frames.drain(), estimates.drain());
    assert_eq!(frames.iter().map(|f| f.scan_count as usize).sum::<usize>(), sim.scans.len(), "every scan of the record");
    assert!(!estimates.is_empty() && estimates.iter().all(|e| e.solved), "{:?}", estimates.iter().map(|e| &e.refusal_reason).collect::<Vec<_>>());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn every_shipped_launch_file_builds_in_memory() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../launch_configs");
    let bag = scratch("build");
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let Some(name) = path.file_name().and_then(|n| n.to_str()).filter(|n| n.ends_with(".launch.yaml")) else { continue };
        seen += 1;
        // Inputs a file needs: a bag directory to create, a record to read (not read here).
        let args: Vec<(String, String)> = match name {
            "record_sim_rig.launch.yaml" => vec![("bag".into(), bag.display().to_string())],
            "replay.launch.yaml" => vec![("file".into(), path.display().to_string())],
            _ => Vec::new(),
        };
        Graph::from_launch(&path, &args, &[], None).unwrap_or_else(|e| panic!("{name}: {e}"));
        let _ = std::fs::remove_dir_all(&bag);
    }
    assert!(seen >= 4);
}
