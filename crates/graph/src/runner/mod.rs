//! Runners: what turns nodes. One per port kind; the DDS runner is in `oilfilm-nodes`.
//!
//! * [`memory`]: a launch file's nodes in one process on in-memory topics and a mock clock,
//!   deterministic (tests, benchmarks, the reference bags).
//! * [`bag`]: recorded DAQ frames and rig status (a bag's) through the conditioner and
//!   estimator nodes: offline re-analysis, equal to live bit for bit.

pub mod bag;
pub mod memory;

use std::any::Any;

use serde_json::{Map, Value};

use oilfilm_physics::config::RigConfig;

use crate::conditioner::Conditioner;
use crate::daq::Daq;
use crate::error::NodeError;
use crate::estimator::Estimator;
use crate::exciter::Exciter;
use crate::launch::NodeLaunch;
use crate::node::{load_rig, Connect, Node, Start, Turn};
use crate::params::{self, NodeArgs};
use crate::player::Player;
use crate::recorder::Recorder;
use crate::stamp::Stamp;

/// A node with its ports, behind one interface, so a runner holds nodes of every kind.
pub trait Running {
    fn name(&self) -> &str;
    fn turn(&mut self, now: Stamp) -> Result<Turn, NodeError>;
    fn finish(&mut self, now: Stamp) -> Result<(), NodeError>;
    /// The node itself, for [`memory::Graph::node`].
    fn node(&self) -> &dyn Any;
    /// Its fully qualified name and the parameters it was built with (what it announces on
    /// `/parameter_events`).
    fn parameters(&self) -> (&str, &Map<String, Value>);
}

/// A node connected to its ports.
pub struct Wired<N: Node> {
    pub name: String,
    pub node: N,
    pub ports: N::Ports<'static>,
    /// `/namespace/name`.
    pub fully_qualified: String,
    /// Its parameters as ROS parameters.
    pub params: Map<String, Value>,
}

impl<N: Node + 'static> Wired<N> {
    /// Builds `N` from `params` and connects it.
    pub fn new<C: Connect>(name: &str, params: &N::Params, start: &Start, connect: &mut C) -> Result<Self, NodeError> {
        let node = N::new(params, start)?;
        let ports = node.connect(connect)?;
        let map = match serde_json::to_value(params) {
            Ok(Value::Object(m)) => m,
            _ => Map::new(),
        };
        let fully_qualified = format!("{}/{name}", start.namespace.trim_end_matches('/'));
        Ok(Self { name: name.to_string(), node, ports, fully_qualified, params: map })
    }
}

impl<N: Node + 'static> Running for Wired<N> {
    fn name(&self) -> &str {
        &self.name
    }
    fn turn(&mut self, now: Stamp) -> Result<Turn, NodeError> {
        self.node.turn(now, &mut self.ports)
    }
    fn finish(&mut self, now: Stamp) -> Result<(), NodeError> {
        self.node.finish(now, &mut self.ports)
    }
    fn node(&self) -> &dyn Any {
        &self.node
    }
    fn parameters(&self) -> (&str, &Map<String, Value>) {
        (&self.fully_qualified, &self.params)
    }
}

/// The node a launch entry names (`exec: oilfilm-daq`), with the parameters its `--ros-args`
/// give (params files, `-p` overrides), built and connected. `rig`: every node's rig
/// instead of the file its `rig` parameter names.
pub fn wire_launched<C: Connect>(n: &NodeLaunch, now: Stamp, rig: Option<&RigConfig>, connect: &mut C) -> Result<Box<dyn Running>, NodeError> {
    let args = params::parse_args(&n.name, n.args.clone())?;
    let load = |path: &str| match rig {
        Some(r) => Ok(r.clone()),
        None => load_rig(path),
    };
    let start = Start { now, rig: &load, namespace: &args.namespace };
    fn wire<N: Node + 'static, C: Connect>(args: &NodeArgs, start: &Start, connect: &mut C) -> Result<Box<dyn Running>, NodeError> {
        let (p, _) = params::load::<N::Params>(args)?;
        Ok(Box::new(Wired::<N>::new(&args.name, &p, start, connect)?))
    }
    match n.exec.as_str() {
        "oilfilm-exciter" => wire::<Exciter, C>(&args, &start, connect),
        "oilfilm-daq" => wire::<Daq, C>(&args, &start, connect),
        "oilfilm-conditioner" => wire::<Conditioner, C>(&args, &start, connect),
        "oilfilm-estimator" => wire::<Estimator, C>(&args, &start, connect),
        "oilfilm-recorder" => wire::<Recorder, C>(&args, &start, connect),
        "oilfilm-player" => wire::<Player, C>(&args, &start, connect),
        other => Err(NodeError::parameter(
            "exec",
            format!("`{other}` is not one of our nodes (oilfilm-exciter, -daq, -conditioner, -estimator, -recorder, -player)"),
        )),
    }
}
