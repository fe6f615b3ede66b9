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
            "replay_bag.launch.yaml" => vec![("bag".into(), dir.join("../bags/sim_rig_multisine").display().to_string())],
            _ => Vec::new(),
        };
        Graph::from_launch(&path, &args, &[], None).unwrap_or_else(|e| panic!("{name}: {e}"));
        let _ = std::fs::remove_dir_all(&bag);
    }
    assert!(seen >= 4);
}

/// replay.launch.yaml takes an ASCII record; given a bag directory it says so and names the
/// launch file that re-estimates a bag.
#[test]
fn replay_given_a_bag_points_at_replay_bag() {
    let bag = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../bags/sim_rig_multisine");
    let args = [("file".to_string(), bag.display().to_string())];
    let e = Graph::from_launch(&shipped("replay.launch.yaml"), &args, &[], None).err().expect("a bag is not an ASCII record").to_string();
    assert!(e.contains("is a directory") && e.contains("replay_bag.launch.yaml") && e.contains("file"), "{e}");
}

/// A bag recorded by record_sim_rig.launch.yaml says which parameters its conditioner and
/// estimator ran with (its /parameter_events), and re-estimating it with them, offline (the
/// path of `oilfilm identify BAG`) and through replay_bag.launch.yaml's player, conditioner
/// and estimator, gives the live estimates bit for bit.
#[test]
fn a_recorded_bag_holds_its_parameters_and_re_estimates_to_the_live_estimates() {
    use oilfilm_graph::conditioner::ConditionerParams;
    use oilfilm_graph::estimator::EstimatorParams;
    use oilfilm_graph::params::{load, parse_args};
    use oilfilm_graph::runner::bag::{reanalyse, recorded_parameters_of};
    let dir = scratch("params");
    let args = [("bag".to_string(), dir.display().to_string())];
    let mut g = Graph::from_launch(&shipped("record_sim_rig.launch.yaml"), &args, &[("daq", "duration_s", "11.0")], None).unwrap();
    let mut live = g.tap::<CoefficientEstimate>(&topics::ESTIMATES).unwrap();
    g.run().unwrap();
    let live = live.drain();
    assert!(live.len() >= 2 && live.iter().all(|e| e.solved), "{} live estimates", live.len());

    let bag = Bag::open(&dir).unwrap();
    let recorded = recorded_parameters_of(&bag).unwrap();
    assert_eq!(
        recorded.nodes.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>(),
        ["/oilfilm/recorder", "/oilfilm/exciter", "/oilfilm/daq", "/oilfilm/conditioner", "/oilfilm/estimator"]
    );
    assert!(recorded.changed_later.is_empty());
    let from_file =
        |node: &str| parse_args(node, ["--ros-args".to_string(), "--params-file".into(), shipped("params/sim_rig.yaml").display().to_string()]).unwrap();
    let (c, e) = (recorded.of::<ConditionerParams>("conditioner").unwrap().unwrap(), recorded.of::<EstimatorParams>("estimator").unwrap().unwrap());
    assert_eq!((c.0.as_str(), e.0.as_str()), ("/oilfilm/conditioner", "/oilfilm/estimator"));
    assert_eq!(c.1, load::<ConditionerParams>(&from_file("conditioner")).unwrap().0, "the conditioner's parameters as the params file gave them");
    assert_eq!(e.1, load::<EstimatorParams>(&from_file("estimator")).unwrap().0);
    assert_ne!(e.1, EstimatorParams::default(), "the file's are not the defaults, so the test can tell");

    let (mut frames, mut status) = (Vec::new(), Vec::new());
    for m in bag.messages().unwrap() {
        match m.decode_ours().unwrap() {
            OilfilmMessage::DaqFrame(f) => frames.push(f),
            OilfilmMessage::RigStatus(s) => status.push(s),
            _ => {}
        }
    }
    let offline = reanalyse(&RigConfig::zhou2004().unwrap(), &c.1, &e.1, &frames, &status).unwrap();
    assert_eq!(bytes(&offline.estimates), bytes(&live), "offline, with the recorded parameters");

    let mut g = Graph::from_launch(&shipped("replay_bag.launch.yaml"), &args, &[], None).unwrap();
    let mut replayed = g.tap::<CoefficientEstimate>(&topics::ESTIMATES).unwrap();
    g.run().unwrap();
    assert_eq!(bytes(&replayed.drain()), bytes(&live), "through replay_bag.launch.yaml's nodes");
    let _ = std::fs::remove_dir_all(&dir);
}
