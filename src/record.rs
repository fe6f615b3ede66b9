//! `oilfilm record` and `oilfilm play`: the recorder and player nodes on the DDS runner
//! (`oilfilm_nodes::runner::run`), with command-line options instead of ROS parameters.

use std::path::PathBuf;

use anyhow::Result;
use oilfilm_graph::params::NodeArgs;
use oilfilm_graph::player::PlayerParams;
use oilfilm_graph::recorder::RecorderParams;

#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    /// The bag directory (must not exist, or be empty). Default: rosbag2_YYYY_MM_DD-HH_MM_SS.
    #[arg(short, long, value_name = "DIR")]
    pub output: Option<PathBuf>,
    /// Topics to record (`daq/frames` or `/oilfilm/daq/frames`). Default: all six of ours.
    #[arg(value_name = "TOPIC")]
    pub topics: Vec<String>,
    /// Chunk compression: zstd, lz4 or none.
    #[arg(long, default_value = "zstd")]
    pub compression: String,
    /// Start a new file after this many MB (10^6 bytes).
    #[arg(long, value_name = "MB")]
    pub split_size_mb: Option<f64>,
    /// Start a new file after this many seconds of log time.
    #[arg(long, value_name = "S")]
    pub split_duration_s: Option<f64>,
    /// Seconds between status lines on stderr (0: none).
    #[arg(long, default_value_t = 1.0)]
    pub status_period_s: f64,
    /// The graph's namespace.
    #[arg(long, default_value = oilfilm_graph::topics::NAMESPACE)]
    pub namespace: String,
}

#[derive(Debug, clap::Args)]
pub struct PlayArgs {
    /// The bag directory.
    pub bag: PathBuf,
    /// Playback rate (1: real time).
    #[arg(long, default_value_t = 1.0)]
    pub rate: f64,
    /// As fast as the readers take it, without dropping (reliable, acknowledged batches).
    #[arg(long)]
    pub fast: bool,
    /// Start again at the end, until Ctrl-C.
    #[arg(long = "loop")]
    pub looped: bool,
    /// Do not publish /clock.
    #[arg(long)]
    pub no_clock: bool,
    /// /clock messages per second of wall time.
    #[arg(long, default_value_t = 100.0)]
    pub clock_hz: f64,
    /// Topics to play (full names, as in the bag). Default: all.
    #[arg(long, value_name = "TOPIC", num_args = 1..)]
    pub topics: Vec<String>,
    /// Seconds to wait for a subscriber on every played topic.
    #[arg(long, default_value_t = 10.0)]
    pub wait_s: f64,
}

fn node(name: &str, namespace: &str) -> NodeArgs {
    let namespace = if namespace.starts_with('/') { namespace.to_string() } else { format!("/{namespace}") };
    NodeArgs { name: name.into(), namespace, ..Default::default() }
}

fn params_map<P: serde::Serialize>(p: &P) -> Result<serde_json::Map<String, serde_json::Value>> {
    match serde_json::to_value(p)? {
        serde_json::Value::Object(m) => Ok(m),
        _ => anyhow::bail!("parameters must be a struct"),
    }
}

pub fn run_record(args: &RecordArgs) -> Result<()> {
    let p = RecorderParams {
        output: args.output.as_ref().map(|o| o.display().to_string()).unwrap_or_default(),
        topics: args.topics.clone(),
        compression: args.compression.clone(),
        split_size_mb: args.split_size_mb.unwrap_or(0.0),
        split_duration_s: args.split_duration_s.unwrap_or(0.0),
        status_period_s: args.status_period_s,
    };
    oilfilm_nodes::dds::init_logging();
    let recorder = oilfilm_nodes::runner::run::<oilfilm_graph::recorder::Recorder>(&node("recorder", &args.namespace), &p, &params_map(&p)?)?;
    println!("{}", recorder.closed().unwrap_or(recorder.dir()).display());
    Ok(())
}

pub fn run_play(args: &PlayArgs) -> Result<()> {
    let p = PlayerParams {
        bag: args.bag.display().to_string(),
        rate: args.rate,
        fast: args.fast,
        looped: args.looped,
        clock: !args.no_clock,
        clock_hz: args.clock_hz,
        topics: args.topics.clone(),
        wait_s: args.wait_s,
    };
    oilfilm_nodes::dds::init_logging();
    oilfilm_nodes::runner::run::<oilfilm_graph::player::Player>(&node("player", oilfilm_graph::topics::NAMESPACE), &p, &params_map(&p)?)?;
    Ok(())
}
