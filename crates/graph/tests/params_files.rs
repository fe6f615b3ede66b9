//! Params and launch files cut short, from the fixtures in `tests/data/params/`: a file that
//! ends without a line end (cut in the middle of a value, a key, a launch file's node) is
//! refused with the file, line, column and byte where it ends; a file cut after a whole line
//! reads (it cannot be told from a file that leaves parameters out on purpose), and the node
//! says once, naming the file, which of its parameters are at their defaults.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use oilfilm_graph::conditioner::ConditionerParams;
use oilfilm_graph::daq::DaqParams;
use oilfilm_graph::estimator::EstimatorParams;
use oilfilm_graph::params::{self, NodeArgs};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/params").join(name)
}

fn node(name: &str, files: Vec<PathBuf>) -> NodeArgs {
    NodeArgs { name: name.into(), namespace: "/oilfilm".into(), params_files: files, ..Default::default() }
}

#[test]
fn a_file_without_a_line_end_at_its_end_is_refused_with_where_it_ends() {
    for (file, line, column, last) in [
        ("invalid/cut-mid-value.yaml", 5, 13, "    hop: 125"),
        ("invalid/cut-mid-key.yaml", 5, 7, "    ho"),
        ("invalid/cut.launch.yaml", 9, 20, "    pkg: oilfilm_no"),
    ] {
        let path = fixture(file);
        let bytes = std::fs::metadata(&path).unwrap().len();
        let e = if file.ends_with(".launch.yaml") {
            oilfilm_graph::launch::read(&path).unwrap_err().to_string()
        } else {
            params::load::<EstimatorParams>(&node("estimator", vec![path.clone()])).unwrap_err().to_string()
        };
        let at = format!("line {line} column {column} (byte {bytes}): the file ends without a line end after `{last}`: cut short?");
        assert!(e.contains(file) && e.contains(&at), "{file}: {e}");
    }
    // The same text with its line end added reads: `hop: 125` is a valid value, which is
    // why a file ending without one is refused rather than read.
    let text = std::fs::read_to_string(fixture("invalid/cut-mid-value.yaml")).unwrap() + "\n";
    let texts = [("whole.yaml".to_string(), params::check_yaml(text.into_bytes(), "whole.yaml").unwrap())];
    let (p, _, _) = params::load_texts::<EstimatorParams>(&node("estimator", Vec::new()), &texts).unwrap();
    assert_eq!((p.window, p.hop), (25000, 125));
}

#[test]
fn parameters_a_files_section_leaves_out_are_named_with_the_file() {
    let some = fixture("valid/some-keys.yaml");
    let (p, _, sources) = params::load_located::<EstimatorParams>(&node("estimator", vec![some.clone()])).unwrap();
    assert_eq!((p.window, p.hop, p.model.as_str()), (25000, 12500, "kc"));
    let left: Vec<&str> = sources.defaulted().iter().map(|(k, _)| k.as_str()).collect();
    assert!(!left.is_empty() && !left.iter().any(|k| ["window", "hop", "model"].contains(k)), "{left:?}");
    let note = sources.defaults_note("/oilfilm/estimator").unwrap();
    assert!(note.starts_with("/oilfilm/estimator: ") && note.contains(&some.display().to_string()), "{note}");
    for (k, v) in sources.defaulted() {
        assert!(note.contains(&format!("{k}={v}")), "{note} lacks {k}={v}");
    }

    // Cut after a whole line: it reads, and the note names what the cut left out.
    let cut = fixture("valid/cut-after-a-whole-line.yaml");
    let (p, _, sources) = params::load_located::<EstimatorParams>(&node("estimator", vec![cut.clone()])).unwrap();
    assert_eq!((p.window, p.hop), (25000, EstimatorParams::default().hop));
    let note = sources.defaults_note("/oilfilm/estimator").unwrap();
    assert!(
        note.contains(&cut.display().to_string()) && note.contains(&format!("hop={}", EstimatorParams::default().hop)) && note.contains("model="),
        "{note}"
    );

    // An override gives what the file left out: no longer at its default.
    let mut args = node("estimator", vec![cut.clone()]);
    args.overrides.push(("hop".into(), "5000".into()));
    let (_, _, sources) = params::load_located::<EstimatorParams>(&args).unwrap();
    assert!(sources.defaulted().iter().all(|(k, _)| k != "hop" && k != "window"));

    // No note for a node the files have no section for (no file was meant for it), nor when
    // the section gives every parameter.
    let (_, _, sources) = params::load_located::<DaqParams>(&node("daq", vec![some.clone()])).unwrap();
    assert!(sources.defaulted().is_empty() && sources.defaults_note("/oilfilm/daq").is_none());
    let all = params::load::<ConditionerParams>(&node("conditioner", Vec::new())).unwrap().1;
    let full: String = all.iter().map(|(k, v)| format!("    {k}: {v}\n")).collect();
    let texts = [("full.yaml".to_string(), format!("conditioner:\n  ros__parameters:\n{full}"))];
    let (_, _, sources) = params::load_texts::<ConditionerParams>(&node("conditioner", Vec::new()), &texts).unwrap();
    assert!(sources.defaults_note("/oilfilm/conditioner").is_none(), "{:?}", sources.defaulted());
}

/// The messages of the events logged on this thread while it is the default subscriber.
struct Lines(Arc<Mutex<Vec<String>>>);

impl tracing::Subscriber for Lines {
    fn enabled(&self, _: &tracing::Metadata<'_>) -> bool {
        true
    }
    fn new_span(&self, _: &tracing::span::Attributes<'_>) -> tracing::span::Id {
        tracing::span::Id::from_u64(1)
    }
    fn record(&self, _: &tracing::span::Id, _: &tracing::span::Record<'_>) {}
    fn record_follows_from(&self, _: &tracing::span::Id, _: &tracing::span::Id) {}
    fn event(&self, event: &tracing::Event<'_>) {
        struct Message(String);
        impl tracing::field::Visit for Message {
            fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
                if field.name() == "message" {
                    self.0 = format!("{value:?}");
                }
            }
        }
        let mut m = Message(String::new());
        event.record(&mut m);
        self.0.lock().unwrap().push(m.0);
    }
    fn enter(&self, _: &tracing::span::Id) {}
    fn exit(&self, _: &tracing::span::Id) {}
}

/// A node's parameters are loaded twice in one process when a launch file is checked and
/// then run: the note is one line all the same.
#[test]
fn the_defaults_note_is_logged_once_per_process() {
    // A file of this test's own, so no other test has logged its note already.
    let dir = std::env::temp_dir().join(format!("oilfilm-params-note-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("once.yaml");
    std::fs::copy(fixture("valid/cut-after-a-whole-line.yaml"), &file).unwrap();
    let lines = Arc::new(Mutex::new(Vec::new()));
    tracing::subscriber::with_default(Lines(Arc::clone(&lines)), || {
        for _ in 0..2 {
            params::load::<EstimatorParams>(&node("estimator", vec![file.clone()])).unwrap();
        }
    });
    let lines = lines.lock().unwrap();
    let notes: Vec<&String> = lines.iter().filter(|l| l.contains(&file.display().to_string())).collect();
    assert_eq!(notes.len(), 1, "{lines:?}");
    assert!(notes[0].contains("at their defaults") && notes[0].contains("hop="), "{}", notes[0]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_rig_file_without_a_line_end_at_its_end_is_refused_by_every_reader() {
    // The shipped rig cut inside its last value: `linear_range = [0.0, 100.0]` would parse
    // as a different rig if a number were cut, so the missing line end is what tells.
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../launch_configs/rigs/zhou2004.toml");
    let text = std::fs::read_to_string(&shipped).unwrap();
    assert!(text.ends_with('\n'), "the shipped rig ends with a line end");
    let dir = std::env::temp_dir().join(format!("oilfilm-rig-cut-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cut = dir.join("cut.toml");
    let cut_text = text.trim_end_matches('\n');
    std::fs::write(&cut, cut_text).unwrap();
    let line = cut_text.matches('\n').count() + 1;
    let e = oilfilm_graph::node::read_rig_file(&cut).unwrap_err().to_string();
    assert!(
        e.contains(&cut.display().to_string())
            && e.contains(&format!("line {line} column "))
            && e.contains("cut short?")
            && e.contains("a rig file ends with a line end"),
        "{e}"
    );
    // The launch path (a node's `rig_file` parameter) reads through the same check.
    let e = oilfilm_graph::node::load_rig(&cut.display().to_string()).unwrap_err().to_string();
    assert!(e.contains("cut short?"), "{e}");
    // With its line end the same text is the shipped rig.
    let whole = dir.join("whole.toml");
    std::fs::write(&whole, &text).unwrap();
    let rig = oilfilm_graph::node::read_rig_file(&whole).unwrap();
    assert_eq!(rig, oilfilm_physics::config::RigConfig::zhou2004().unwrap());
    std::fs::remove_dir_all(&dir).unwrap();
}
