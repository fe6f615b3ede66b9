//! The DAQ node's foreign source in the replay launch file: a simulated record written as an
//! interleaved, multi-group TDMS file and read through a channel map gives, in the in-memory
//! graph, the very frames (values, stamps, schedule) and estimates of the same record
//! replayed from our ASCII format; a map naming a channel the file lacks stops the node
//! before it publishes, with the file and the channel named.

use oilfilm_foreign::fixtures::{self, TdmsChannel, TdmsLayout};
use oilfilm_graph::runner::memory::{shipped, Graph};
use oilfilm_graph::topics;
use oilfilm_identification::ascii::{self, Units};
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::simulate::{simulate, SimulateOptions};
use oilfilm_msgs::{CoefficientEstimate, DaqFrame};
use oilfilm_physics::config::RigConfig;

fn run(args: &[(&str, String)]) -> Result<(Vec<DaqFrame>, Vec<CoefficientEstimate>), oilfilm_graph::NodeError> {
    let args: Vec<(String, String)> = args.iter().map(|(k, v)| (k.to_string(), v.clone())).chain([("rate_factor".to_string(), "0".to_string())]).collect();
    let overrides = [("estimator", "window", "10000"), ("estimator", "hop", "5000")];
    let mut g = Graph::from_launch(&shipped("replay.launch.yaml"), &args, &overrides, None)?;
    let mut frames = g.tap::<DaqFrame>(&topics::DAQ_FRAMES)?;
    let mut estimates = g.tap::<CoefficientEstimate>(&topics::ESTIMATES)?;
    g.run()?;
    Ok((frames.drain(), estimates.drain()))
}

#[test]
fn a_tdms_record_replays_as_its_ascii_twin() {
    let rig = RigConfig::zhou2004().unwrap();
    let sim = simulate(&rig, &ExcitationPlan::two_tone(23.0, 37.0, 100.0), 6.0, SimulateOptions::default(), &mut |_| {}).unwrap();
    let record = sim.to_ascii(&rig, Units::Volts).unwrap();
    let dir = std::env::temp_dir().join(format!("oilfilm-foreign-source-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let txt = dir.join("run.txt");
    std::fs::write(&txt, ascii::write(&record).unwrap()).unwrap();
    let groups = ["Journal", "Journal", "Journal", "Journal", "Housing", "Housing", "Loads", "Loads", "Loads", "Thermal"];
    let chans: Vec<TdmsChannel> = record
        .header
        .channels
        .iter()
        .enumerate()
        .map(|(k, name)| TdmsChannel { group: groups[k], name, values: &record.columns[k], properties: vec![] })
        .collect();
    let tdms = dir.join("run.tdms");
    fixtures::tdms(&tdms, &chans, TdmsLayout { segments: 6, interleaved: true, big_endian: false }).unwrap();
    let mut map = String::from("[timing]\nsample_rate_hz = 5000\nmultiplexer = \"sequential\"\nchannel_interval_s = 1e-5\n[speed]\nrpm = 1500\n");
    for (k, name) in record.header.channels.iter().enumerate() {
        map.push_str(&format!("[[channel]]\nrig = \"{name}\"\nfrom = \"{}/{name}\"\nunit = \"V\"\n", groups[k]));
    }
    let map_path = dir.join("run.map.toml");
    std::fs::write(&map_path, &map).unwrap();

    let (ascii_frames, ascii_estimates) = run(&[("file", txt.display().to_string())]).unwrap();
    let (frames, estimates) = run(&[("file", tdms.display().to_string()), ("source", "foreign".into()), ("map", map_path.display().to_string())]).unwrap();
    assert_eq!(frames.len(), ascii_frames.len());
    for (f, a) in frames.iter().zip(&ascii_frames) {
        // The rig name differs (the ASCII header's against the rig file's): all else is equal.
        assert_eq!(DaqFrame { rig: String::new(), ..f.clone() }, DaqFrame { rig: String::new(), ..a.clone() }, "frame {}", f.sequence);
    }
    assert!(
        estimates.len() >= 2 && estimates.iter().all(|e| e.solved),
        "{} estimates, solved: {:?}",
        estimates.len(),
        estimates.iter().map(|e| (e.solved, e.refusal_reason.clone())).collect::<Vec<_>>()
    );
    assert_eq!(estimates, ascii_estimates, "the same estimates");

    // A map naming a channel the file does not have: the node does not start.
    std::fs::write(&map_path, map.replace("Loads/f2", "Loads/F2")).unwrap();
    let err =
        run(&[("file", tdms.display().to_string()), ("source", "foreign".into()), ("map", map_path.display().to_string())]).expect_err("refused").to_string();
    assert!(err.contains("run.tdms") && err.contains("`Loads/F2` (f2)") && err.contains("no such channel"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
