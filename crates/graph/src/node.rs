//! One trait for every node, as copper-rs has one task trait: a node is built from its typed
//! parameters, connects its ports to whatever carries the messages, and then takes turns.
//! A turn is given the time (`now`) and the ports; it takes what is waiting, runs the core
//! and publishes. Nothing inside a node reads a clock or knows its transport, so one runner
//! per port kind runs every node the same way:
//!
//! * DDS through ros2-client (`oilfilm-nodes`: one node per process, the wall clock, the
//!   ROS 2 parameter services);
//! * in memory ([`crate::runner::memory`]: the nodes of a launch file in one process on a
//!   mock clock, the tests' and benchmarks' graph);
//! * a bag's recorded messages ([`crate::runner::bag`]: offline re-analysis).
//!
//! The nodes: [`crate::exciter::Exciter`], [`crate::daq::Daq`],
//! [`crate::conditioner::Conditioner`], [`crate::estimator::Estimator`],
//! [`crate::recorder::Recorder`] and [`crate::player::Player`].

use oilfilm_msgs::RosMessage;
use oilfilm_physics::config::RigConfig;
use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::error::NodeError;
use crate::params::NodeParams;
use crate::ports::{Publish, RawCdr, Receive};
use crate::stamp::Stamp;
use crate::topics::Topic;

/// What a topic carries: a message of ours with its CDR (serde) form.
pub trait Message: RosMessage + Serialize + DeserializeOwned + Clone + 'static {}

impl<M: RosMessage + Serialize + DeserializeOwned + Clone + 'static> Message for M {}

/// An input port of a node (`'static` from a [`Connect`]; the bag runner lends ports that
/// borrow what it reads).
pub type Input<'a, M> = Box<dyn Receive<M> + 'a>;
/// An output port of a node.
pub type Output<'a, M> = Box<dyn Publish<M> + 'a>;

/// A topic known only when the node runs (the recorder's and player's, any type): its full
/// name, `pkg/msg/Type` and QoS (the bag's QoS profile, which says all DDS needs).
#[derive(Debug, Clone, PartialEq)]
pub struct RawTopic {
    pub name: String,
    pub type_name: String,
    pub qos: oilfilm_bag::QosProfile,
}

/// A port kind: makes a node's ports. Relative topic names are taken in the runner's
/// namespace; names starting with `/` are absolute (`/clock`).
pub trait Connect {
    fn input<M: Message>(&mut self, topic: &Topic) -> Result<Input<'static, M>, NodeError>;
    fn output<M: Message>(&mut self, topic: &Topic) -> Result<Output<'static, M>, NodeError>;
    /// An output whose [`Publish::flush`](crate::ports::Publish::flush) waits until every
    /// reliable reader has what was published: for a last message that must arrive before
    /// the node leaves (the exciter's ramp to zero). A port kind that delivers at once has
    /// nothing to wait for and gives its plain output.
    fn acknowledged_output<M: Message>(&mut self, topic: &Topic) -> Result<Output<'static, M>, NodeError> {
        self.output(topic)
    }
    /// Serialised messages as they arrive, any type (what a bag stores).
    fn raw_input(&mut self, topic: &RawTopic) -> Result<Input<'static, RawCdr>, NodeError>;
    /// Serialised messages sent as they are given.
    fn raw_output(&mut self, topic: &RawTopic) -> Result<Output<'static, RawCdr>, NodeError>;
}

/// What a node is built with besides its parameters.
pub struct Start<'a> {
    /// The runner's clock when the node starts.
    pub now: Stamp,
    /// The rig file a `rig` parameter names (empty: the built-in rig). The DDS runner reads
    /// the file; the in-memory runner may hand every node the same rig instead.
    pub rig: &'a dyn Fn(&str) -> Result<RigConfig, NodeError>,
    /// The node's namespace (`/oilfilm`): where its relative topics live.
    pub namespace: &'a str,
}

/// What one turn did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Turn {
    /// Messages taken plus messages published.
    pub handled: usize,
    /// The node has nothing more to do (a DAQ at the end of its duration or file, a player
    /// at the end of its bag): the runner stops it.
    pub finished: bool,
    /// The next time the node has something to do by the clock alone (a DAQ's next block,
    /// a player's next message). The in-memory runner's clock jumps there when every node
    /// is idle.
    pub wake: Option<Stamp>,
}

impl Turn {
    /// Combines two parts of one turn.
    pub fn and(self, other: Turn) -> Turn {
        let wake = match (self.wake, other.wake) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        Turn { handled: self.handled + other.handled, finished: self.finished || other.finished, wake }
    }
}

/// A node: built from its typed parameters, its ports connected once, then turned.
pub trait Node: Sized {
    /// The node's default name; its binary is `oilfilm-<NAME>`.
    const NAME: &'static str;
    /// Its typed ROS 2 parameters (a params file's `ros__parameters`, unknown names refused),
    /// each with its descriptor ([`NodeParams::specs`]).
    type Params: NodeParams;
    /// Its ports, one a topic.
    type Ports<'a>;

    /// Why the node cannot follow `/clock` (`use_sim_time` true is refused with this), when
    /// it is the clock itself; `None`: it follows `/clock` when asked.
    const CLOCK_SOURCE: Option<&'static str> = None;

    fn new(params: &Self::Params, start: &Start) -> Result<Self, NodeError>;

    fn connect<C: Connect>(&self, ports: &mut C) -> Result<Self::Ports<'static>, NodeError>;

    /// One turn at `now` (wall time on DDS, the mock clock in memory): take what is waiting,
    /// run the core, publish. A message the core cannot use is logged and skipped (the node
    /// keeps running); an error here is a port that failed.
    fn turn(&mut self, now: Stamp, ports: &mut Self::Ports<'_>) -> Result<Turn, NodeError>;

    /// Applies a changed parameter set while the node runs: all of it, or nothing and the
    /// reason (naming the parameter and the rule). The runner calls it only with a set whose
    /// values passed their rules and [`NodeParams::validate`], and in which only parameters
    /// whose spec is not read-only changed; what it accepts is what the parameter services
    /// then report, so no set is reported applied that the node did not apply.
    fn reconfigure(&mut self, _params: &Self::Params) -> Result<(), NodeError> {
        Err(NodeError::parameter("(parameters)", format!("the {} node's parameters are read-only while it runs: restart it with new ones", Self::NAME)))
    }

    /// The last turn, when the node is stopped (a signal, the end of the run, an error):
    /// the exciter ramps to zero, the recorder closes its bag.
    fn finish(&mut self, _now: Stamp, _ports: &mut Self::Ports<'_>) -> Result<(), NodeError> {
        Ok(())
    }
}

/// The rig file `path` names (empty: the built-in Zhou et al. (2004) rig).
pub fn load_rig(path: &str) -> Result<RigConfig, NodeError> {
    if path.is_empty() {
        return Ok(RigConfig::zhou2004()?);
    }
    read_rig_file(std::path::Path::new(path))
}

/// A rig file, read with the checks of every configuration file (bounded size, UTF-8, ending
/// with a line end: [`crate::params::read_config_text`]), parsed and validated.
pub fn read_rig_file(path: &std::path::Path) -> Result<RigConfig, NodeError> {
    let text = crate::params::read_config_text(path, "a rig file")?;
    Ok(RigConfig::from_toml_str(&text, &path.display().to_string())?)
}

/// Skipped input: logged as a warning with the node's name, and the node goes on.
pub fn skipped(node: &str, e: &NodeError) {
    tracing::warn!(node, "skipped: {e}");
}
