//! `oilfilm launch FILE`: the graph of a launch file on DDS, with the estimates printed as
//! they arrive, one line each (`--verbose`: every coefficient with its standard error and
//! every note; `--json`: one JSON object a line). Exits non-zero if a node dies, and when a
//! graph with an estimator produced no estimate, naming the node that stayed silent.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use oilfilm_graph::launch::{self, NodeLaunch};
use oilfilm_graph::params::NodeArgs;
use oilfilm_graph::ports::{RawCdr, Receive};
use oilfilm_graph::topics::{self, Topic};
use oilfilm_msgs::CoefficientEstimate;
use oilfilm_nodes::dds::{qos_of, shutdown_flag, RosNode};
use oilfilm_nodes::parameters::SimTime;
use oilfilm_nodes::supervisor::Supervisor;

#[derive(Debug, clap::Args)]
pub struct LaunchArgs {
    /// Launch file (ROS 2 launch YAML), e.g. launch_configs/sim_rig.launch.yaml.
    file: PathBuf,
    /// Stop the graph after this many seconds of wall time (0: run until Ctrl-C).
    #[arg(long, default_value_t = 0.0)]
    seconds: f64,
    /// Directory of the node binaries (default: next to this executable).
    #[arg(long, value_name = "DIR")]
    bin_dir: Option<PathBuf>,
    /// Every estimate in full: each coefficient with its standard error, every note.
    #[arg(long, conflicts_with = "json")]
    verbose: bool,
    /// Each estimate as one JSON object a line (all its fields), for other programs.
    #[arg(long)]
    json: bool,
    /// Launch arguments, `NAME:=VALUE` (as `ros2 launch` takes them), e.g. `file:=out/run.txt`.
    #[arg(value_name = "NAME:=VALUE")]
    launch_args: Vec<String>,
}

/// One stage of the identification chain the launcher watches, to say which node stayed
/// silent when no estimate came: the node, and the topic its output is counted on.
struct Stage {
    node: String,
    topic: String,
    input: Box<dyn Receive<RawCdr>>,
    count: u64,
}

/// What a stage published.
struct Counted {
    node: String,
    topic: String,
    count: u64,
}

/// The stages of `nodes` that feed the estimator, upstream first: the DAQ or player (its
/// `rig/status`), the conditioner (`conditioned`), and the estimator (`estimates`, counted
/// by the printer).
fn chain(nodes: &[NodeLaunch], ros: &mut RosNode) -> Result<Vec<Stage>> {
    let mut stages = Vec::new();
    let mut watch = |n: &NodeLaunch, topic: &Topic, ros: &mut RosNode| -> Result<()> {
        let full = topics::qualified(&n.namespace, topic);
        let input = ros.raw_subscription(&full, topic.type_name, qos_of(topic))?;
        stages.push(Stage { node: n.name.clone(), topic: full, input: Box::new(input), count: 0 });
        Ok(())
    };
    for n in nodes.iter().filter(|n| n.exec == "oilfilm-daq" || n.exec == "oilfilm-player") {
        watch(n, &topics::RIG_STATUS, ros)?;
    }
    for n in nodes.iter().filter(|n| n.exec == "oilfilm-conditioner") {
        watch(n, &topics::CONDITIONED, ros)?;
    }
    Ok(stages)
}

/// Notes (an estimate's flags) printed the first time, then counted.
#[derive(Default)]
struct Notes {
    seen: HashMap<String, u64>,
    order: Vec<String>,
}

/// What makes two notes the same note: the text before its first `: ` (the kind: "damping
/// from differentiated noisy displacement may be biased (errors in variables)"), whose
/// numbers change from estimate to estimate after it; the whole text when it has none.
fn note_kind(note: &str) -> &str {
    note.split_once(": ").map_or(note, |(kind, _)| kind)
}

impl Notes {
    /// True the first time a note of `note`'s kind is seen.
    fn first(&mut self, note: &str) -> bool {
        let kind = note_kind(note);
        let n = self.seen.entry(kind.to_string()).or_insert(0);
        *n += 1;
        if *n == 1 {
            self.order.push(kind.to_string());
        }
        *n == 1
    }

    /// The notes seen more than once, with their counts.
    fn repeated(&self) -> impl Iterator<Item = (&str, u64)> {
        self.order.iter().filter_map(|n| self.seen.get(n).filter(|c| **c > 1).map(|c| (n.as_str(), *c)))
    }
}

/// How estimates are printed (here and by `identify --stream`).
pub(crate) struct Printer {
    verbose: bool,
    json: bool,
    notes: Notes,
}

impl Printer {
    pub(crate) fn new(verbose: bool, json: bool) -> Self {
        Self { verbose, json, notes: Notes::default() }
    }

    pub(crate) fn print(&mut self, e: &CoefficientEstimate) {
        if self.json {
            match serde_json::to_string(e) {
                Ok(line) => println!("{line}"),
                Err(err) => eprintln!("estimate #{}: not printable as JSON: {err}", e.sequence),
            }
            return;
        }
        if self.verbose {
            print_estimate(e);
            return;
        }
        println!("{}", estimate_line(e));
        for f in &e.flags {
            if self.notes.first(f) {
                println!("    note: {f}");
            }
        }
    }

    pub(crate) fn summary(&self) {
        for (note, n) in self.notes.repeated() {
            let short: String = note.chars().take(100).collect();
            println!("note repeated on {n} estimates: {short}{}", if short.len() < note.len() { "..." } else { "" });
        }
    }
}

pub fn run(args: &LaunchArgs) -> Result<()> {
    anyhow::ensure!(args.seconds.is_finite() && args.seconds >= 0.0, "--seconds must be >= 0, got {}", args.seconds);
    let mut launch_args = Vec::new();
    for a in &args.launch_args {
        let (k, v) = a.split_once(":=").with_context(|| format!("launch argument `{a}`: write NAME:=VALUE"))?;
        launch_args.push((k.to_string(), v.to_string()));
    }
    let nodes = launch::read_with(&args.file, &launch_args)?;
    let bin_dir = match &args.bin_dir {
        Some(d) => d.clone(),
        None => std::env::current_exe().context("locating this executable")?.parent().map(PathBuf::from).unwrap_or_default(),
    };
    for n in &nodes {
        if !bin_dir.join(&n.exec).exists() {
            bail!("{}: node executable {} not found in {} (build them: cargo build --release --workspace)", args.file.display(), n.exec, bin_dir.display());
        }
    }
    let namespace = nodes.first().map_or_else(|| topics::NAMESPACE.to_string(), |n| n.namespace.clone());
    let stop = shutdown_flag()?;
    let me = NodeArgs { name: "oilfilm_launch".into(), namespace: namespace.clone(), ..Default::default() };
    let mut ros = RosNode::new(&me)?;
    ros.declare_parameters(Vec::new(), serde_json::Map::new(), false, SimTime::Follows)?;
    let mut estimates = ros.subscription::<CoefficientEstimate>(&topics::ESTIMATES)?;
    let mut stages = chain(&nodes, &mut ros)?;
    let estimator = nodes.iter().find(|n| n.exec == "oilfilm-estimator").map(|n| n.name.clone());
    let mut graph = Supervisor::start(&nodes, &bin_dir)?;
    let say = |line: String| if args.json { eprintln!("{line}") } else { println!("{line}") };
    say(format!("launched {} from {} in namespace {namespace}; estimates print as they arrive", graph.names().join(", "), args.file.display()));
    say(format!("frame: {}", oilfilm_identification::pipeline::FRAME));
    let mut printer = Printer::new(args.verbose, args.json);
    let started = Instant::now();
    let mut failure = None;
    let mut count = 0u64;
    // A node that finishes cleanly (a replay at the end of its file, a DAQ at the end of its
    // duration) ends the run once the rest have drained: no estimate for DRAIN.
    const DRAIN: Duration = Duration::from_secs(3);
    let mut finished: Option<Instant> = None;
    let mut last_output = Instant::now();
    while !stop.load(Ordering::SeqCst) {
        if args.seconds > 0.0 && started.elapsed().as_secs_f64() >= args.seconds {
            break;
        }
        if finished.is_some_and(|f| f.elapsed() >= DRAIN && last_output.elapsed() >= DRAIN) {
            break;
        }
        if let Some((name, status)) = graph.exited() {
            if !status.success() {
                failure = Some(format!("node {name} died ({status})"));
                break;
            }
            if finished.is_none() {
                say(format!("node {name} finished; stopping the graph once it has drained"));
                finished = Some(Instant::now());
            }
        }
        ros.serve_parameters(&mut |_| Err("the launcher has no parameters but use_sim_time".into()))?;
        for s in &mut stages {
            while s.input.receive()?.is_some() {
                s.count += 1;
                last_output = Instant::now();
            }
        }
        match estimates.receive()? {
            Some(e) => {
                count += 1;
                last_output = Instant::now();
                printer.print(&e);
            }
            None => std::thread::sleep(Duration::from_millis(5)),
        }
    }
    graph.stop(Duration::from_secs(5));
    while let Some(e) = estimates.receive()? {
        count += 1;
        printer.print(&e);
    }
    for s in &mut stages {
        while s.input.receive()?.is_some() {
            s.count += 1;
        }
    }
    // Entities go before their participant.
    drop(estimates);
    let counted: Vec<Counted> = stages.into_iter().map(|s| Counted { node: s.node, topic: s.topic, count: s.count }).collect();
    ros.shutdown();
    printer.summary();
    say(format!("{count} estimate(s) received"));
    if let Some(f) = failure {
        bail!(f);
    }
    if let (0, Some(estimator)) = (count, estimator) {
        bail!(silent(&counted, &estimator, started.elapsed()));
    }
    Ok(())
}

/// Which node stayed silent when no estimate came: the first stage upstream that published
/// nothing, else the estimator.
fn silent(stages: &[Counted], estimator: &str, after: Duration) -> String {
    let upstream: Vec<String> = stages.iter().take_while(|s| s.count > 0).map(|s| format!("{} published {} on {}", s.node, s.count, s.topic)).collect();
    let context = if upstream.is_empty() { String::new() } else { format!(" ({})", upstream.join("; ")) };
    match stages.iter().find(|s| s.count == 0) {
        Some(s) => format!("no estimate in {:.0} s: node `{}` published nothing on {}{context}", after.as_secs_f64(), s.node, s.topic),
        None => format!("no estimate in {:.0} s: node `{estimator}` published nothing (its windows may be longer than the run){context}", after.as_secs_f64()),
    }
}

/// `[a b; c d]` of a row-major 2x2.
fn matrix(m: &[f64; 4]) -> String {
    format!("[{:.3e} {:.3e}; {:.3e} {:.3e}]", m[0], m[1], m[2], m[3])
}

/// One estimate on one line: the window, both matrices, the worst relative standard error
/// of a direct term, F_Y; or the refusal.
pub fn estimate_line(e: &CoefficientEstimate) -> String {
    let t = |x: &oilfilm_msgs::Time| x.as_seconds();
    let span = t(&e.window_end) - t(&e.window_start);
    if !e.solved {
        return format!("#{} samples {}..{} ({span:.1} s): REFUSED: {}", e.sequence, e.window_start_sample, e.window_end_sample, e.refusal_reason);
    }
    let rel = |v: f64, se: f64| if v != 0.0 { (se / v).abs() } else { f64::INFINITY };
    let worst =
        [0, 3].iter().flat_map(|&k| [rel(e.stiffness_n_m[k], e.stiffness_se_n_m[k]), rel(e.damping_n_s_m[k], e.damping_se_n_s_m[k])]).fold(0.0, f64::max);
    format!(
        "#{} samples {}..{} ({span:.1} s)  K {} N/m  C {} N s/m  direct se <= {:.1} %  F_Y {:.3}",
        e.sequence,
        e.window_start_sample,
        e.window_end_sample,
        matrix(&e.stiffness_n_m),
        matrix(&e.damping_n_s_m),
        100.0 * worst,
        e.load_parameter_fy
    )
}

/// One estimate in full: each coefficient with its standard error, and every note.
pub fn print_estimate(e: &CoefficientEstimate) {
    let t = |x: &oilfilm_msgs::Time| x.as_seconds();
    let span = t(&e.window_end) - t(&e.window_start);
    if !e.solved {
        println!("#{} samples {}..{} ({span:.1} s): REFUSED: {}", e.sequence, e.window_start_sample, e.window_end_sample, e.refusal_reason);
        return;
    }
    println!(
        "#{} samples {}..{} ({span:.1} s)  F_Y {:.3}  d {:.3}  cond {:.1}  T {:.1} C",
        e.sequence, e.window_start_sample, e.window_end_sample, e.load_parameter_fy, e.amplitude_d, e.condition_number, e.bearing_temperature_degc
    );
    for (k, name) in ["xx", "xy", "yx", "yy"].iter().enumerate() {
        println!(
            "    k{name} {:>12.4e} ± {:>9.2e} N/m    d{name} {:>12.4e} ± {:>9.2e} N s/m",
            e.stiffness_n_m[k], e.stiffness_se_n_m[k], e.damping_n_s_m[k], e.damping_se_n_s_m[k]
        );
    }
    for f in &e.flags {
        println!("    note: {f}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_note_prints_once_and_is_then_counted() {
        let mut notes = Notes::default();
        assert!(notes.first("noise bias"));
        assert!(!notes.first("noise bias"));
        assert!(notes.first("other"));
        assert!(!notes.first("noise bias"));
        // The same kind of note with other numbers is the same note.
        assert!(notes.first("bias: dyy -0.650 % (-1.5 SE)"));
        assert!(!notes.first("bias: dyy -0.620 % (-1.4 SE), kyx +1.1 %"));
        assert_eq!(notes.repeated().collect::<Vec<_>>(), [("noise bias", 3), ("bias", 2)]);
    }

    #[test]
    fn an_estimate_is_one_line() {
        let e = CoefficientEstimate {
            solved: true,
            stiffness_n_m: [8.28e7, 7.13e7, -1.89e8, 8.1e7],
            stiffness_se_n_m: [8.28e5, 0.0, 0.0, 1.62e6],
            damping_n_s_m: [1.05e6, -6.1e5, -6.1e5, 2.36e6],
            damping_se_n_s_m: [1.05e4, 0.0, 0.0, 2.36e4],
            ..Default::default()
        };
        let line = estimate_line(&e);
        assert!(!line.contains('\n') && line.contains("K [8.280e7 7.130e7; -1.890e8 8.100e7] N/m") && line.contains("direct se <= 2.0 %"), "{line}");
    }
}
