//! `oilfilm launch FILE`: the graph of a launch file on DDS, with the estimates printed as
//! they arrive. Exits non-zero if a node dies.

use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use oilfilm_msgs::CoefficientEstimate;
use oilfilm_nodes::dds::{shutdown_flag, RosNode};
use oilfilm_graph::launch;
use oilfilm_nodes::supervisor::Supervisor;
use oilfilm_graph::params::NodeArgs;
use oilfilm_graph::ports::Receive;
use oilfilm_graph::topics;

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
    /// Launch arguments, `NAME:=VALUE` (as `ros2 launch` takes them), e.g. `file:=out/run.txt`.
    #[arg(value_name = "NAME:=VALUE")]
    launch_args: Vec<String>,
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
    let mut estimates = ros.subscription::<CoefficientEstimate>(&topics::ESTIMATES)?;
    let mut graph = Supervisor::start(&nodes, &bin_dir)?;
    println!("launched {} from {} in namespace {namespace}; estimates print as they arrive", graph.names().join(", "), args.file.display());
    println!("frame: {}", oilfilm_identification::pipeline::FRAME);
    let started = Instant::now();
    let mut failure = None;
    let mut count = 0;
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
                println!("node {name} finished; stopping the graph once it has drained");
                finished = Some(Instant::now());
            }
        }
        match estimates.receive()? {
            Some(e) => {
                count += 1;
                last_output = Instant::now();
                print_estimate(&e);
            }
            None => std::thread::sleep(Duration::from_millis(5)),
        }
    }
    graph.stop(Duration::from_secs(5));
    while let Some(e) = estimates.receive()? {
        count += 1;
        print_estimate(&e);
    }
    drop(estimates);
    ros.shutdown();
    println!("{count} estimate(s) received");
    if let Some(f) = failure {
        bail!(f);
    }
    Ok(())
}

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
