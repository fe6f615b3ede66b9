//! `oilfilm identify FILE --stream`: a record identified window by window as it is read,
//! through the node graph of `launch_configs/replay.launch.yaml` (DAQ replaying the record ->
//! conditioner -> estimator) run in this process by the in-memory runner. Nothing holds the
//! record: the DAQ's reader reads ahead a bounded queue of frames, the conditioner and the
//! estimator keep what their filters and one window need, and each estimate is printed and
//! dropped as it comes. So a record of any length identifies in bounded memory, and a record
//! too large to hold whole is streamed without being asked ([`too_large_to_hold`]).
//!
//! What needs the whole record is not done: the correction for measurement effects (the
//! diagnosis's forward selection over the whole record) and the drift re-identification in
//! shorter windows.

use std::path::Path;

use anyhow::{bail, Context, Result};
use oilfilm_graph::conditioner::{Conditioner, ConditionerParams};
use oilfilm_graph::daq::{Daq, DaqParams};
use oilfilm_graph::estimator::{Estimator, EstimatorParams};
use oilfilm_graph::params::{self, NodeArgs, NodeParams};
use oilfilm_graph::runner::memory::Graph;
use oilfilm_graph::topics;
use oilfilm_msgs::{CoefficientEstimate, RigStatus};
use serde::Serialize;

use crate::records::IdentifyArgs;
use crate::Outcome;

/// Above this size a plain ASCII record is streamed by `identify` without `--stream`: held
/// whole, a record takes about three times its size in memory.
pub const STREAM_ABOVE_BYTES: u64 = 256 * 1024 * 1024;

/// How much smaller a gzip-compressed ASCII record is than its text, for the size above which
/// it is streamed (`STREAM_ABOVE_BYTES / GZIP_RATIO`): records of 16-bit amplifier codes
/// compress about three to four times; taking four streams the better compressed ones a
/// little early rather than hold them.
pub const GZIP_RATIO: u64 = 4;

/// The parameters of the replay graph, as `launch_configs/replay.launch.yaml` gives them
/// (compiled in, so that the command does not depend on where it is run from).
const REPLAY_PARAMS: &str = include_str!("../launch_configs/params/replay.yaml");
const REPLAY_PARAMS_NAME: &str = "launch_configs/params/replay.yaml";

/// What was left out of a streamed identification, and how to get it.
const LEFT_OUT: &str = "left out: the drift re-identification in shorter windows and the correction for measurement effects (both need the whole record); \
--no-stream identifies it whole (about three times its size in memory), or identify or diagnose a slice of it (its header and a range of its rows)";

/// Why `identify` (without `--stream` or `--no-stream`) streams `args.file`, or `None` when it
/// holds it whole: an ASCII record file over [`STREAM_ABOVE_BYTES`] (gzip: over a
/// [`GZIP_RATIO`]th of it). Bags and `--map` records are never switched.
pub fn too_large_to_hold(args: &IdentifyArgs) -> Result<Option<String>> {
    if args.no_stream || args.file.is_dir() || args.map.is_some() || args.replay {
        return Ok(None);
    }
    let name = args.file.display();
    let Ok(meta) = std::fs::metadata(&args.file) else { return Ok(None) };
    let above = args.stream_above_bytes.unwrap_or(STREAM_ABOVE_BYTES);
    let gzip = is_gzip(&args.file)?;
    let limit = if gzip { above / GZIP_RATIO } else { above };
    if meta.len() <= limit {
        return Ok(None);
    }
    let mb = |b: u64| b as f64 / (1024.0 * 1024.0);
    let what = if gzip { "gzip-compressed " } else { "" };
    if args.correct {
        bail!(
            "{name}: a {what}record of {:.0} MB, over the {:.0} MB identify holds whole, is streamed, and --correct needs the whole record: \
give --no-stream to identify it whole (about three times its size in memory), or correct a slice of it",
            mb(meta.len()),
            mb(limit)
        );
    }
    Ok(Some(format!(
        "{name} is a {what}record of {:.0} MB, over the {:.0} MB identify holds whole: streamed window by window through the node graph (as with --stream)",
        mb(meta.len()),
        mb(limit)
    )))
}

fn is_gzip(path: &Path) -> Result<bool> {
    use std::io::Read;
    let mut magic = [0u8; 2];
    let mut file = std::fs::File::open(path).with_context(|| format!("cannot read {}", path.display()))?;
    let n = file.read(&mut magic).with_context(|| format!("cannot read {}", path.display()))?;
    Ok(n == 2 && magic == [0x1f, 0x8b])
}

/// The end of a streamed identification, one JSON line after the estimates' (`--json`).
#[derive(Debug, Serialize)]
struct Summary {
    record: String,
    /// Why the record was streamed without `--stream`, when it was.
    automatic: Option<String>,
    frames: u64,
    windows: usize,
    solved: usize,
    refused: usize,
    /// Means over the solved windows, row-major [xx, xy, yx, yy]; `null` when none was.
    mean_stiffness_n_m: Option<[f64; 4]>,
    mean_damping_n_s_m: Option<[f64; 4]>,
    /// The DAQ's last rig status message (malformed rows skipped, gaps, the speed's source).
    daq: String,
    left_out: &'static str,
}

/// Running sums of the solved windows' coefficients.
#[derive(Default)]
struct Tally {
    windows: usize,
    solved: usize,
    stiffness: [f64; 4],
    damping: [f64; 4],
}

impl Tally {
    fn add(&mut self, e: &CoefficientEstimate) {
        self.windows += 1;
        if e.solved {
            self.solved += 1;
            for k in 0..4 {
                self.stiffness[k] += e.stiffness_n_m[k];
                self.damping[k] += e.damping_n_s_m[k];
            }
        }
    }

    fn means(&self) -> Option<([f64; 4], [f64; 4])> {
        let n = self.solved as f64;
        (self.solved > 0).then(|| (self.stiffness.map(|v| v / n), self.damping.map(|v| v / n)))
    }
}

/// A node's parameters: the replay graph's, then `--params FILE`'s (as a later
/// `--params-file` does), then `overrides`.
fn node_params<P: NodeParams>(node: &str, params_file: Option<&Path>, overrides: Vec<(String, String)>) -> Result<P> {
    let mut texts = vec![(REPLAY_PARAMS_NAME.to_string(), REPLAY_PARAMS.to_string())];
    if let Some(f) = params_file {
        texts.push((f.display().to_string(), params::read_yaml(f)?));
    }
    let args = NodeArgs { name: node.into(), namespace: topics::NAMESPACE.into(), overrides, ..Default::default() };
    Ok(params::load_texts::<P>(&args, &texts)?.0)
}

/// `oilfilm identify FILE --stream` (`automatic`: why it was streamed without being asked).
pub fn run(args: &IdentifyArgs, automatic: Option<&str>) -> Result<Outcome> {
    let name = args.file.display().to_string();
    // What needs the whole record, or is for bags, is refused with the reason.
    if args.file.is_dir() {
        bail!("{name} is a directory (a bag?): --stream is for a record file; `identify BAG --replay` re-runs the node graph on a bag's frames");
    }
    anyhow::ensure!(!args.replay, "--replay is for bags and re-runs the node graph on their frames; --stream runs it on a record file: give one of them");
    anyhow::ensure!(
        !args.correct,
        "{name}: --correct needs the whole record (it diagnoses the record's measurement effects over all of it), and --stream never holds it: drop --stream (or give --no-stream)"
    );
    anyhow::ensure!(!args.allow_partial, "--allow-partial applies to bags; --stream reads a record file, skipping (and counting) its malformed rows");
    let max = oilfilm_identification::estimator::MAX_WINDOW_SAMPLES;
    for (flag, v, least) in [("--window", args.window, 2), ("--hop", args.hop, 1)] {
        if let Some(v) = v.filter(|v| !(least..=max).contains(v)) {
            bail!("{flag} {v}: must be {least} to {max} samples");
        }
    }
    // The rig: `--rig`; for an ASCII record, else the one its header names.
    let (rig, rig_source, source) = match &args.map {
        Some(map) => {
            let rig = args.source.load()?;
            let from = args.source.path().map_or_else(|| "built-in zhou2004".to_string(), |p| format!("{} (--rig)", p.display()));
            (rig, from, ("foreign", map.display().to_string()))
        }
        None => {
            let header = crate::ascii_input::read_header(&args.file)?;
            let (rig, from) = crate::ascii_input::rig_of(&args.file, &header, args.source.path())?;
            (rig, from, ("ascii", String::new()))
        }
    };
    let params_file = args.params.as_deref();
    // The launch file's own values: the record, its kind (as YAML strings); as fast as the
    // nodes take it, to its end.
    let yaml = |text: &str| serde_json::Value::String(text.into()).to_string();
    let daq_overrides =
        [("file", yaml(&name)), ("source", yaml(source.0)), ("map", yaml(&source.1)), ("rate_factor", "0.0".into()), ("duration_s", "0.0".into())];
    let daq: DaqParams = node_params("daq", params_file, daq_overrides.into_iter().map(|(k, v)| (k.to_string(), v)).collect())?;
    let conditioner_overrides = if args.no_deskew { vec![("deskew".to_string(), "false".to_string())] } else { Vec::new() };
    let conditioner: ConditionerParams = node_params("conditioner", params_file, conditioner_overrides)?;
    let mut estimator: EstimatorParams = node_params("estimator", params_file, Vec::new())?;
    crate::records::set_estimator_options(args, &mut estimator);
    let with_params = |e: oilfilm_graph::NodeError| anyhow::Error::new(e).context(format!("{name}: the replay graph's parameters"));
    let mut graph = Graph::new(topics::NAMESPACE);
    graph
        .add::<Daq>("daq", &daq, Some(&rig))
        .and_then(|g| g.add::<Conditioner>("conditioner", &conditioner, Some(&rig)))
        .and_then(|g| g.add::<Estimator>("estimator", &estimator, Some(&rig)))
        .map_err(with_params)?;
    let mut estimates = graph.tap::<CoefficientEstimate>(&topics::ESTIMATES)?;
    let mut status = graph.tap::<RigStatus>(&topics::RIG_STATUS)?;
    // The nodes' warnings (a malformed row, named by line and column) on stderr.
    oilfilm_nodes::logging::init_with("warn");

    let say = |line: &str| if args.json { eprintln!("{line}") } else { println!("{line}") };
    if let Some(why) = automatic {
        say(&format!("{why}; {LEFT_OUT}"));
    }
    say(&format!(
        "record: {name} streamed through the replay graph's DAQ, conditioner ({} chain, low-pass {} Hz) and estimator (windows of {} scans every {}), rig `{}` ({rig_source})",
        conditioner.chain, conditioner.lowpass_cutoff_hz, estimator.window, estimator.hop, rig.name
    ));
    say(&format!("frame: {}", oilfilm_identification::pipeline::FRAME));

    let mut printer = crate::launch::Printer::new(false, args.json);
    let mut tally = Tally::default();
    let (mut frames, mut last_status) = (0u64, String::new());
    graph
        .run_with(&mut || {
            for e in estimates.drain() {
                tally.add(&e);
                printer.print(&e);
            }
            for s in status.drain() {
                frames += 1;
                last_status = s.message;
            }
            Ok(())
        })
        .with_context(|| format!("streaming {name} through the replay graph"))?;
    if !args.json {
        printer.summary();
    }

    let means = tally.means();
    let summary = Summary {
        record: name.clone(),
        automatic: automatic.map(str::to_string),
        frames,
        windows: tally.windows,
        solved: tally.solved,
        refused: tally.windows - tally.solved,
        mean_stiffness_n_m: means.map(|m| m.0),
        mean_damping_n_s_m: means.map(|m| m.1),
        daq: last_status.clone(),
        left_out: LEFT_OUT,
    };
    if args.json {
        println!("{}", serde_json::to_string(&serde_json::json!({ "summary": summary }))?);
    } else {
        match last_status.as_str() {
            "" => println!("{frames} DAQ frame(s)"),
            status => println!("{frames} DAQ frame(s): {status}"),
        }
        println!("{} window(s): {} solved, {} refused", tally.windows, tally.solved, tally.windows - tally.solved);
        if let Some((k, c)) = means {
            let m = |v: [f64; 4]| format!("[{:.4e} {:.4e}; {:.4e} {:.4e}]", v[0], v[1], v[2], v[3]);
            println!("mean of the solved windows: K {} N/m, C {} N s/m", m(k), m(c));
        }
        if automatic.is_none() {
            println!("{LEFT_OUT}");
        }
    }
    Ok(match (tally.windows, tally.solved) {
        (0, _) => {
            Outcome::Refused(format!("{name}: no window: the record ({frames} frame(s)) is shorter than one window of {} scans (--window)", estimator.window))
        }
        (n, 0) => Outcome::Refused(format!("{name}: every one of {n} window(s) refused")),
        _ => Outcome::Done,
    })
}
