//! The DDS runner: one node per process on ros2-client, the wall clock, the ROS 2 parameter
//! services. Every node binary's `main` is [`main`] for its node type; `oilfilm record` and
//! `oilfilm play` call [`run`] with parameters from their command line.

use std::process::ExitCode;
use std::sync::atomic::Ordering;
use std::time::Duration;

use oilfilm_graph::node::{load_rig, Node, Start};
use oilfilm_graph::params::{self, NodeArgs, NodeParams, Sources, USE_SIM_TIME};
use oilfilm_graph::stamp::Stamp;
use oilfilm_graph::NodeError;
use serde_json::{Map, Value};

use crate::dds::{init_logging, shutdown_flag, RosNode};
use crate::parameters::{Change, SimTime};

/// The longest a turn that found nothing to do waits before the next (also the latency of a
/// parameter request).
const IDLE: Duration = Duration::from_micros(500);
/// The longest a node waits for the time it asked to be woken at (a DAQ's next block).
const MAX_NAP: Duration = Duration::from_millis(20);
/// After the last turn, before the node leaves DDS: reliable readers take what was last
/// published (the exciter's ramp to zero, a DAQ's last frames, the last estimate). Longer
/// than RustDDS's slow heartbeat (1 s), so a sample whose first sending was lost (every node
/// of a graph stopping at once on a loaded machine) is repaired before the writer goes.
const LINGER: Duration = Duration::from_millis(1500);

/// A node binary's `main`: parses `--ros-args`, loads the typed parameters (a bad value is
/// named with the file and key, or the `-p`, that gave it), runs the node until
/// SIGINT/SIGTERM (or until it finishes), and exits non-zero with the error if any.
pub fn main<N: Node + 'static>() -> ExitCode {
    init_logging();
    let run = || -> Result<(), NodeError> {
        let args = params::parse_args(N::NAME, std::env::args().skip(1))?;
        let (p, map, sources) = params::load_located::<N::Params>(&args)?;
        run_located::<N>(&args, &p, &map, &sources).map(|_| ())
    };
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("oilfilm-{}: {e}", N::NAME);
            ExitCode::FAILURE
        }
    }
}

/// Whether node `N` can follow `/clock`.
fn sim_time_of<N: Node>() -> SimTime {
    match N::CLOCK_SOURCE {
        Some(why) => SimTime::Refused(why),
        None => SimTime::Follows,
    }
}

/// Runs node `N` named by `args` with parameters `params` (`map`: the same, as the ROS
/// parameters it declares) on DDS until SIGINT/SIGTERM or until it finishes, then gives it
/// its last turn ([`Node::finish`], also after an error) and takes it off DDS. Returns the
/// node (the recorder says where its bag is).
pub fn run<N: Node + 'static>(args: &NodeArgs, params: &N::Params, map: &Map<String, Value>) -> Result<N, NodeError> {
    run_located::<N>(args, params, map, &Sources::default())
}

/// [`run`], errors about a parameter value found when the node is built (against its rig
/// file) named with the file and key that gave it (`sources`).
pub fn run_located<N: Node + 'static>(args: &NodeArgs, params: &N::Params, map: &Map<String, Value>, sources: &Sources) -> Result<N, NodeError> {
    // The command line's tools (`oilfilm record`, `play`) build their parameters in code:
    // the same rules as a params file.
    params::checked::<N::Params>(map)?;
    let use_sim_time = params::use_sim_time(args)?;
    if let (true, Some(why)) = (use_sim_time, N::CLOCK_SOURCE) {
        return Err(NodeError::parameter(USE_SIM_TIME, format!("cannot be true: {why}")));
    }
    tracing::info!(node = %args.fully_qualified_name(), domain = crate::dds::domain_id()?, "starting");
    let start_now = if use_sim_time { Stamp(0) } else { Stamp::now() };
    let mut node = N::new(params, &Start { now: start_now, rig: &load_rig, namespace: &args.namespace }).map_err(|e| sources.locate(e))?;
    // The declared values as the typed parameters hold them (a whole number given for a
    // double parameter is declared a double).
    let declared = match serde_json::to_value(params) {
        Ok(Value::Object(m)) => m,
        _ => map.clone(),
    };
    let mut ros = RosNode::new(args)?;
    ros.declare_parameters(N::Params::specs(), declared, use_sim_time, sim_time_of::<N>())?;
    let mut ports = node.connect(&mut ros)?;
    // Tests and tools wait for this line: the parameter services and the ports exist from here.
    tracing::info!(node = %args.fully_qualified_name(), "ready: {} parameters served, topics connected", N::Params::specs().len() + 1);
    let stop = shutdown_flag()?;
    let turned = (|| -> Result<(), NodeError> {
        while !stop.load(Ordering::SeqCst) {
            ros.serve_parameters(&mut |change: &Change| {
                let p = params::checked::<N::Params>(change.params).map_err(|e| e.to_string())?;
                if change.changed.iter().any(|c| c != USE_SIM_TIME) {
                    node.reconfigure(&p).map_err(|e| e.to_string())?;
                }
                Ok(())
            })?;
            let now = ros.now()?;
            let turn = node.turn(now, &mut ports)?;
            if turn.finished {
                break;
            }
            if turn.handled == 0 {
                let until_wake = turn.wake.map_or(IDLE, |w| Duration::from_nanos(u64::try_from(w.0 - now.0).unwrap_or(0)));
                std::thread::sleep(until_wake.clamp(IDLE, MAX_NAP));
            }
        }
        Ok(())
    })();
    let now = ros.now().unwrap_or_else(|_| Stamp::now());
    let finished = node.finish(now, &mut ports);
    std::thread::sleep(LINGER);
    // Entities go before their participant, or DDS cannot remove them cleanly.
    drop(ports);
    ros.shutdown();
    turned?;
    finished?;
    Ok(node)
}
