//! The in-memory runner: a launch file's nodes in one process, on in-memory topics
//! ([`crate::ports::memory`]) and a mock clock, turned round-robin in the launch file's
//! order. Deterministic: the clock starts at [`EPOCH`] and moves only when every node is
//! idle, to the earliest time one of them asked to be woken at (a DAQ's next block), as
//! copper-rs's mock clock does; so a launch file's `rate_factor` costs nothing here.
//!
//! The graph comes from the same launch YAML `oilfilm launch` runs ([`Graph::from_launch`],
//! [`GraphParams::from_launch`]), with any parameter overridden as on a command line.

use std::any::Any;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use oilfilm_msgs::{CoefficientEstimate, ConditionedFrame, DaqFrame, ExciterCommand, RigStatus};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::operating_point::OperatingPoint;

use super::{wire_launched, Running, Wired};
use crate::conditioner::{Conditioner, ConditionerParams};
use crate::daq::{Daq, DaqParams};
use crate::error::NodeError;
use crate::estimator::{Estimator, EstimatorParams};
use crate::exciter::{Exciter, ExciterParams};
use crate::launch::{self, NodeLaunch};
use crate::node::{load_rig, Connect, Input, Message, Node, Output, RawTopic, Start};
use crate::params::{self, NodeArgs};
use crate::ports::memory::{Bus, Publisher, Subscriber};
use crate::ports::{Publish, RawCdr};
use crate::stamp::Stamp;
use crate::topics::{self, Topic};

/// Where the mock clock starts (2023-11-14 22:13:20 UTC): a DAQ without `start_stamp_ns`
/// stamps its scan 0 here.
pub const EPOCH: Stamp = Stamp(1_700_000_000_000_000_000);

/// One of this source tree's launch files (`launch_configs/NAME`), the files users run. The
/// path is the tree's, compiled in: for tests, benchmarks and examples run from the tree.
pub fn shipped(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../launch_configs").join(name)
}

/// The in-memory topics of a graph, by full name: the port kind of this runner.
pub struct Buses {
    namespace: String,
    typed: HashMap<String, Box<dyn Any>>,
    raw: HashMap<String, Bus<RawCdr>>,
}

impl Buses {
    pub fn new(namespace: &str) -> Self {
        Self { namespace: namespace.to_string(), typed: HashMap::new(), raw: HashMap::new() }
    }

    /// The bus of `topic`, made on first use; a topic carries one type.
    pub fn bus<M: Message>(&mut self, topic: &Topic) -> Result<Bus<M>, NodeError> {
        let name = topics::qualified(&self.namespace, topic);
        self.bus_named(&name)
    }

    fn bus_named<M: Message>(&mut self, name: &str) -> Result<Bus<M>, NodeError> {
        let bus = self.typed.entry(name.to_string()).or_insert_with(|| Box::new(Bus::<M>::new()));
        bus.downcast_ref::<Bus<M>>().cloned().ok_or_else(|| NodeError::parameter("topics", format!("{name} carries another type than {}", M::TYPE_NAME)))
    }

    /// For a raw writer of one of our types (a player): its typed readers' bus, fed by
    /// decoding what it sends, as DDS would hand it to them.
    fn typed_sink(&mut self, topic: &RawTopic) -> Result<Option<TypedSink>, NodeError> {
        fn sink<M: Message>(bus: Bus<M>) -> TypedSink {
            let mut p = bus.publisher();
            Box::new(move |cdr: &RawCdr| {
                let m: M =
                    oilfilm_msgs::decode(&cdr.0).map_err(|e| NodeError::BadMessage { topic: M::TYPE_NAME.into(), sequence: 0, reason: e.to_string() })?;
                p.publish(m)
            })
        }
        use oilfilm_msgs::RosMessage;
        Ok(Some(match topic.type_name.as_str() {
            ExciterCommand::TYPE_NAME => sink(self.bus_named::<ExciterCommand>(&topic.name)?),
            DaqFrame::TYPE_NAME => sink(self.bus_named::<DaqFrame>(&topic.name)?),
            RigStatus::TYPE_NAME => sink(self.bus_named::<RigStatus>(&topic.name)?),
            ConditionedFrame::TYPE_NAME => sink(self.bus_named::<ConditionedFrame>(&topic.name)?),
            CoefficientEstimate::TYPE_NAME => sink(self.bus_named::<CoefficientEstimate>(&topic.name)?),
            _ => return Ok(None),
        }))
    }

    fn raw_bus(&mut self, topic: &RawTopic) -> Bus<RawCdr> {
        self.raw.entry(topic.name.clone()).or_default().clone()
    }
}

/// Decodes a raw message onto a typed bus.
type TypedSink = Box<dyn FnMut(&RawCdr) -> Result<(), NodeError>>;

/// A raw writer (a player) whose messages also reach the typed readers of its topic.
struct RawBridged {
    raw: Publisher<RawCdr>,
    typed: Option<TypedSink>,
}

impl Publish<RawCdr> for RawBridged {
    fn publish(&mut self, message: RawCdr) -> Result<(), NodeError> {
        if let Some(t) = &mut self.typed {
            t(&message)?;
        }
        self.raw.publish(message)
    }

    fn readers(&mut self) -> Option<usize> {
        // The typed readers are not counted: a player waits for raw ones only when there
        // are no typed ones, which in memory are all there from the start.
        Some(self.raw.readers().unwrap_or(0) + usize::from(self.typed.is_some()))
    }
}

/// A typed writer that also hands raw readers of its topic (a recorder) the message's CDR,
/// as DDS would; encoded only while such a reader exists.
struct Bridged<M> {
    typed: Publisher<M>,
    raw: Publisher<RawCdr>,
}

impl<M: Message> Publish<M> for Bridged<M> {
    fn publish(&mut self, message: M) -> Result<(), NodeError> {
        if self.raw.readers().is_some_and(|n| n > 0) {
            self.raw.publish(RawCdr(oilfilm_msgs::encode(&message)))?;
        }
        self.typed.publish(message)
    }

    fn readers(&mut self) -> Option<usize> {
        Some(self.typed.readers().unwrap_or(0) + self.raw.readers().unwrap_or(0))
    }
}

impl Connect for Buses {
    fn input<M: Message>(&mut self, topic: &Topic) -> Result<Input<'static, M>, NodeError> {
        Ok(Box::new(self.bus::<M>(topic)?.subscriber()))
    }
    fn output<M: Message>(&mut self, topic: &Topic) -> Result<Output<'static, M>, NodeError> {
        let typed = self.bus::<M>(topic)?.publisher();
        let name = topics::qualified(&self.namespace, topic);
        let raw = self.raw.entry(name).or_default().publisher();
        Ok(Box::new(Bridged { typed, raw }))
    }
    /// A raw reader gets what typed and raw writers publish; a raw writer (a player) reaches
    /// raw readers and, for one of our types, typed readers too (decoded).
    fn raw_input(&mut self, topic: &RawTopic) -> Result<Input<'static, RawCdr>, NodeError> {
        Ok(Box::new(self.raw_bus(topic).subscriber()))
    }
    fn raw_output(&mut self, topic: &RawTopic) -> Result<Output<'static, RawCdr>, NodeError> {
        let typed = self.typed_sink(topic)?;
        Ok(Box::new(RawBridged { raw: self.raw_bus(topic).publisher(), typed }))
    }
}

/// Nodes on in-memory topics.
pub struct Graph {
    buses: Buses,
    nodes: Vec<Box<dyn Running>>,
    now: Stamp,
}

impl Graph {
    /// An empty graph in `namespace`, its clock at [`EPOCH`].
    pub fn new(namespace: &str) -> Self {
        Self { buses: Buses::new(namespace), nodes: Vec::new(), now: EPOCH }
    }

    /// The nodes of a launch file (its arguments `NAME:=VALUE` in `launch_args`), each with
    /// `overrides` `(node name, parameter, value as YAML)` appended to its `--ros-args` as
    /// `-p` would, and `rig` (if given) as every node's rig instead of the file its `rig`
    /// parameter names.
    pub fn from_launch(path: &Path, launch_args: &[(String, String)], overrides: &[(&str, &str, &str)], rig: Option<&RigConfig>) -> Result<Self, NodeError> {
        let nodes = with_overrides(launch::read_with(path, launch_args)?, overrides)?;
        let mut g = Self::new(nodes.first().map_or(topics::NAMESPACE, |n| n.namespace.as_str()));
        for n in &nodes {
            // Each node's relative topics in its own namespace, as on DDS.
            g.buses.namespace.clone_from(&n.namespace);
            let wired = wire_launched(n, g.now, rig, &mut g.buses)?;
            g.nodes.push(wired);
        }
        g.announce_parameters()?;
        Ok(g)
    }

    /// Every node's declared parameters on `/parameter_events`, as each node does on DDS when
    /// it starts (a recorder of the graph keeps them).
    pub fn announce_parameters(&mut self) -> Result<(), NodeError> {
        let t = &topics::PARAMETER_EVENTS;
        let topic = RawTopic { name: t.name.into(), type_name: t.type_name.into(), qos: crate::recorder::bag_qos(&t.qos) };
        let mut events = self.buses.raw_bus(&topic).publisher();
        for n in &self.nodes {
            let (name, params) = n.parameters();
            events.publish(RawCdr(oilfilm_msgs::encode(&params::declaration_event(name, params, false, self.now))))?;
        }
        Ok(())
    }

    /// Adds node `N` named `name` with `params`; `rig` (if given) instead of the rig file
    /// its parameters name.
    pub fn add<N: Node + 'static>(&mut self, name: &str, params: &N::Params, rig: Option<&RigConfig>) -> Result<&mut Self, NodeError> {
        let load = |path: &str| match rig {
            Some(r) => Ok(r.clone()),
            None => load_rig(path),
        };
        let namespace = self.buses.namespace.clone();
        let start = Start { now: self.now, rig: &load, namespace: &namespace };
        let wired = Wired::<N>::new(name, params, &start, &mut self.buses)?;
        self.nodes.push(Box::new(wired));
        Ok(self)
    }

    /// A subscriber of `topic` that gets every message published from now on.
    pub fn tap<M: Message>(&mut self, topic: &Topic) -> Result<Subscriber<M>, NodeError> {
        Ok(self.buses.bus::<M>(topic)?.subscriber())
    }

    /// A publisher on `topic` (a request to a node, a bag's messages).
    pub fn inject<M: Message>(&mut self, topic: &Topic) -> Result<Publisher<M>, NodeError> {
        Ok(self.buses.bus::<M>(topic)?.publisher())
    }

    /// The node named `name`, if it is an `N`.
    pub fn node<N: Node + 'static>(&self, name: &str) -> Option<&N> {
        self.nodes.iter().find(|n| n.name() == name).and_then(|n| n.node().downcast_ref::<N>())
    }

    /// The mock clock.
    pub fn now(&self) -> Stamp {
        self.now
    }

    /// Turns every node until one has finished (a DAQ at the end of its duration or file,
    /// a player at the end of its bag) and the rest have drained, then finishes them all
    /// (as `oilfilm launch` stops a graph: the exciter ramps down, the recorder closes its
    /// bag). A graph that would wait for ever (no node finished, none busy, none with a time
    /// to wake at) is an error.
    pub fn run(&mut self) -> Result<(), NodeError> {
        self.run_with(&mut || Ok(()))
    }

    /// [`Graph::run`], calling `between` after every round of turns (and once after the
    /// nodes are finished): to take what a tap holds as it comes, so that a long run keeps
    /// nothing it has no more use for. An error from it stops the run.
    pub fn run_with(&mut self, between: &mut dyn FnMut() -> Result<(), NodeError>) -> Result<(), NodeError> {
        let mut finished = vec![false; self.nodes.len()];
        loop {
            let (mut handled, mut wake) = (0, None::<Stamp>);
            for (node, done) in self.nodes.iter_mut().zip(finished.iter_mut()) {
                if *done {
                    continue;
                }
                let turn = node.turn(self.now)?;
                handled += turn.handled;
                *done = turn.finished;
                wake = match (wake, turn.wake) {
                    (Some(a), Some(b)) => Some(a.min(b)),
                    (a, b) => a.or(b),
                };
            }
            between()?;
            if handled > 0 {
                continue;
            }
            if finished.iter().any(|f| *f) {
                break;
            }
            match wake {
                Some(w) if w > self.now => self.now = w,
                _ => return Err(NodeError::Closed("in-memory graph stalled: no node busy, none finished, none waiting for a time".into())),
            }
        }
        // Last started, first stopped: what a node publishes as it stops (the exciter's ramp
        // to zero) still reaches a recorder listed before it.
        for node in self.nodes.iter_mut().rev() {
            node.finish(self.now)?;
        }
        between()
    }
}

/// `overrides` appended to the nodes' `--ros-args`; each must name a node of the file.
fn with_overrides(mut nodes: Vec<NodeLaunch>, overrides: &[(&str, &str, &str)]) -> Result<Vec<NodeLaunch>, NodeError> {
    for (node, key, value) in overrides {
        let n = nodes
            .iter_mut()
            .find(|n| n.name == *node)
            .ok_or_else(|| NodeError::parameter(*key, format!("no node `{node}` in the launch file to set it on")))?;
        n.args.extend(["-p".to_string(), format!("{key}:={value}")]);
    }
    Ok(nodes)
}

/// Everything the sim graph published.
#[derive(Debug, Default, Clone)]
pub struct Recording {
    pub commands: Vec<ExciterCommand>,
    pub frames: Vec<DaqFrame>,
    pub status: Vec<RigStatus>,
    pub conditioned: Vec<ConditionedFrame>,
    pub estimates: Vec<CoefficientEstimate>,
}

/// The typed parameters of the sim graph's four nodes (exciter, DAQ, conditioner,
/// estimator), as a launch file gives them.
#[derive(Debug, Clone, Default)]
pub struct GraphParams {
    pub exciter: ExciterParams,
    pub daq: DaqParams,
    pub conditioner: ConditionerParams,
    pub estimator: EstimatorParams,
}

impl GraphParams {
    /// The parameters a launch file gives its exciter, DAQ, conditioner and estimator
    /// (other nodes, a recorder say, are left out); each missing node keeps its defaults.
    pub fn from_launch(path: &Path, launch_args: &[(String, String)]) -> Result<Self, NodeError> {
        let mut p = Self::default();
        for n in launch::read_with(path, launch_args)? {
            let args = params::parse_args(&n.name, n.args.clone())?;
            match n.exec.as_str() {
                "oilfilm-exciter" => p.exciter = params::load(&args)?.0,
                "oilfilm-daq" => p.daq = params::load(&args)?.0,
                "oilfilm-conditioner" => p.conditioner = params::load(&args)?.0,
                "oilfilm-estimator" => p.estimator = params::load(&args)?.0,
                _ => {}
            }
        }
        Ok(p)
    }

    /// The parameters of a ROS 2 params file (every node's section), as `--params-file`
    /// gives them.
    pub fn from_params_file(file: &Path) -> Result<Self, NodeError> {
        let node =
            |name: &str| NodeArgs { name: name.into(), namespace: topics::NAMESPACE.into(), params_files: vec![file.to_path_buf()], ..Default::default() };
        Ok(Self {
            exciter: params::load(&node("exciter"))?.0,
            daq: params::load(&node("daq"))?.0,
            conditioner: params::load(&node("conditioner"))?.0,
            estimator: params::load(&node("estimator"))?.0,
        })
    }

    /// `launch_configs/sim_rig.launch.yaml`, the file the README's first command runs, for
    /// `duration_s` of rig time, with estimator windows of `window` samples every `hop`.
    pub fn sim_rig(duration_s: f64, window: i64, hop: i64) -> Result<Self, NodeError> {
        let mut p = Self::from_launch(&shipped("sim_rig.launch.yaml"), &[])?;
        p.daq.duration_s = duration_s;
        p.estimator.window = window;
        p.estimator.hop = hop;
        Ok(p)
    }
}

/// Runs the sim graph for `params.daq.duration_s` of rig time (which must be > 0) on `rig`.
/// Returns what every topic carried and the simulated film's operating point (its linear
/// coefficients are the truth tests judge against; no node reads it).
pub fn run_sim_rig(rig: &RigConfig, params: &GraphParams) -> Result<(Recording, OperatingPoint), NodeError> {
    if params.daq.duration_s.is_nan() || params.daq.duration_s <= 0.0 {
        return Err(NodeError::parameter("duration_s", "the in-memory graph needs a finite run (> 0 s)"));
    }
    let mut g = Graph::new(topics::NAMESPACE);
    g.add::<Exciter>("exciter", &params.exciter, Some(rig))?
        .add::<Daq>("daq", &params.daq, Some(rig))?
        .add::<Conditioner>("conditioner", &params.conditioner, Some(rig))?
        .add::<Estimator>("estimator", &params.estimator, Some(rig))?;
    let mut taps = (
        g.tap::<ExciterCommand>(&topics::EXCITER_COMMAND)?,
        g.tap::<DaqFrame>(&topics::DAQ_FRAMES)?,
        g.tap::<RigStatus>(&topics::RIG_STATUS)?,
        g.tap::<ConditionedFrame>(&topics::CONDITIONED)?,
        g.tap::<CoefficientEstimate>(&topics::ESTIMATES)?,
    );
    g.run()?;
    let truth = *g
        .node::<Daq>("daq")
        .and_then(Daq::sim)
        .ok_or_else(|| NodeError::parameter("source", "the sim graph's DAQ must simulate the rig (source: sim)"))?
        .operating_point();
    let recording =
        Recording { commands: taps.0.drain(), frames: taps.1.drain(), status: taps.2.drain(), conditioned: taps.3.drain(), estimates: taps.4.drain() };
    Ok((recording, truth))
}
