//! The DDS runner: one node per process on ros2-client, the wall clock, the ROS 2 parameter
//! services. Every node binary's `main` is [`main`] for its node type; `oilfilm record` and
//! `oilfilm play` call [`run`] with parameters from their command line.

use std::process::ExitCode;
use std::sync::atomic::Ordering;
use std::time::Duration;

use oilfilm_graph::node::{load_rig, Node, Start};
use oilfilm_graph::params::{self, NodeArgs};
use oilfilm_graph::stamp::Stamp;
use oilfilm_graph::NodeError;
use serde_json::{Map, Value};

use crate::dds::{init_logging, shutdown_flag, RosNode, Validator};

/// The longest a turn that found nothing to do waits before the next.
const IDLE: Duration = Duration::from_micros(500);
/// The longest a node waits for the time it asked to be woken at (a DAQ's next block).
const MAX_NAP: Duration = Duration::from_millis(20);
/// After the last turn, before the node leaves DDS: reliable readers take what was last
/// published (the exciter's ramp to zero, a DAQ's last frames, the last estimate).
const LINGER: Duration = Duration::from_millis(500);

/// A node binary's `main`: parses `--ros-args`, loads the typed parameters, runs the node
/// until SIGINT/SIGTERM (or until it finishes), and exits non-zero with the error if any.
pub fn main<N: Node + 'static>() -> ExitCode {
    init_logging();
    let run = || -> Result<(), NodeError> {
        let args = params::parse_args(N::NAME, std::env::args().skip(1))?;
        let (p, map) = params::load::<N::Params>(&args)?;
        run::<N>(&args, &p, &map).map(|_| ())
    };
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("oilfilm-{}: {e}", N::NAME);
            ExitCode::FAILURE
        }
    }
}

/// Accepts the values the node started with (ros2-client validates declarations too) and
/// refuses any change.
fn read_only(node: &'static str, initial: Map<String, Value>) -> Validator {
    Box::new(move |m| {
        if *m == initial {
            Ok(())
        } else {
            Err(format!("the {node} node's parameters are read-only while it runs: restart it with new ones"))
        }
    })
}

/// Runs node `N` named by `args` with parameters `params` (`map`: the same, as the ROS
/// parameters it declares) on DDS until SIGINT/SIGTERM or until it finishes, then gives it
/// its last turn ([`Node::finish`], also after an error) and takes it off DDS. Returns the
/// node (the recorder says where its bag is).
pub fn run<N: Node + 'static>(args: &NodeArgs, params: &N::Params, map: &Map<String, Value>) -> Result<N, NodeError> {
    tracing::info!(node = %args.fully_qualified_name(), domain = crate::dds::domain_id()?, "starting");
    let mut node = N::new(params, &Start { now: Stamp::now(), rig: &load_rig, namespace: &args.namespace })?;
    let validator: Validator = match node.param_check() {
        Some(check) => Box::new(move |m: &Map<String, Value>| {
            let p: N::Params = params::typed(m).map_err(|e| e.to_string())?;
            check(&p).map_err(|e| e.to_string())
        }),
        None => read_only(N::NAME, map.clone()),
    };
    let mut ros = RosNode::new(args, map, validator)?;
    let mut ports = node.connect(&mut ros)?;
    let stop = shutdown_flag()?;
    let turned = (|| -> Result<(), NodeError> {
        while !stop.load(Ordering::SeqCst) {
            if let Some(m) = ros.parameter_change() {
                if let Err(e) = params::typed::<N::Params>(&m).and_then(|p| node.reconfigure(&p)) {
                    tracing::warn!("parameter change not applied: {e}");
                }
            }
            let now = Stamp::now();
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
    let finished = node.finish(Stamp::now(), &mut ports);
    std::thread::sleep(LINGER);
    // Entities go before their participant, or DDS cannot remove them cleanly.
    drop(ports);
    ros.shutdown();
    turned?;
    finished?;
    Ok(node)
}
