//! The graph's topics, their types and their QoS, in one place.
//!
//! Every topic lives under the graph's namespace (default `/oilfilm`); the node binaries
//! take `-r __ns:=/other` like any ROS 2 node. QoS is stated per topic because
//! ros2-client's defaults are not rclcpp's: all reliable, keep-last with an explicit depth,
//! volatile; only `exciter/command` keeps its last samples for late joiners.
//!
//! | topic | type | QoS | publisher -> subscribers |
//! |---|---|---|---|
//! | `exciter/request` | ExciterCommand (spec only) | reliable, keep-last 10 | user, rclpy -> exciter |
//! | `exciter/command` | ExciterCommand (setpoints) | reliable, keep-last 50, transient-local | exciter -> daq (sim), the rig's exciter driver |
//! | `daq/frames` | DaqFrame | reliable, keep-last 200 | daq -> conditioner, recorder |
//! | `rig/status` | RigStatus | reliable, keep-last 10 | daq -> exciter, estimator |
//! | `conditioned` | ConditionedFrame | reliable, keep-last 200 | conditioner -> estimator |
//! | `estimates` | CoefficientEstimate | reliable, keep-last 100 | estimator -> users |
//! | `/clock` | rosgraph_msgs/Clock | reliable, keep-last 1 | daq (when not wall time), player -> `use_sim_time` nodes |
//! | `/parameter_events` | rcl_interfaces/ParameterEvent | reliable, keep-last 1000, transient-local | every node -> recorder, tools |
//!
//! Why only `exciter/command` is transient-local: RustDDS (under ros2-client) sends a
//! transient-local writer's history to every reader it matches, volatile ones too, where
//! rclcpp-to-rclcpp a volatile reader gets only what is published after it joined (ADR 0025).
//! `rig/status` comes every frame and an estimate every hop, so a late joiner loses nothing
//! by waiting for the next; but an exciter driver that reconnects must learn that the
//! exciter was stopped (its last command, the ramp to zero, is the history it gets).
//!
//! Why reliable for the data streams: a lost DaqFrame is a gap in the record, which the
//! conditioner must answer by restarting its filters (losing a margin of samples either
//! side), and at 5-100 kHz in blocks of 10-100 ms the frame rate is only 10-100 Hz, which
//! reliable delivery on a LAN carries without effort. Depth 200 holds 2-20 s of frames, so
//! a subscriber that stalls for a moment does not make the writer drop anything.

use std::fmt;

/// One topic of the graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Topic {
    /// Relative name (under the namespace).
    pub name: &'static str,
    /// `pkg/msg/Type`.
    pub type_name: &'static str,
    pub qos: TopicQos,
}

/// The QoS a topic is offered and requested with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TopicQos {
    pub reliable: bool,
    pub depth: i32,
    pub transient_local: bool,
}

impl fmt::Display for TopicQos {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}, keep-last {}, {}",
            if self.reliable { "reliable" } else { "best-effort" },
            self.depth,
            if self.transient_local { "transient-local" } else { "volatile" }
        )
    }
}

const fn qos(depth: i32, transient_local: bool) -> TopicQos {
    TopicQos { reliable: true, depth, transient_local }
}

pub const EXCITER_REQUEST: Topic = Topic { name: "exciter/request", type_name: "oilfilm_msgs/msg/ExciterCommand", qos: qos(10, false) };
pub const EXCITER_COMMAND: Topic = Topic { name: "exciter/command", type_name: "oilfilm_msgs/msg/ExciterCommand", qos: qos(50, true) };
pub const DAQ_FRAMES: Topic = Topic { name: "daq/frames", type_name: "oilfilm_msgs/msg/DaqFrame", qos: qos(200, false) };
pub const RIG_STATUS: Topic = Topic { name: "rig/status", type_name: "oilfilm_msgs/msg/RigStatus", qos: qos(10, false) };
pub const CONDITIONED: Topic = Topic { name: "conditioned", type_name: "oilfilm_msgs/msg/ConditionedFrame", qos: qos(200, false) };
pub const ESTIMATES: Topic = Topic { name: "estimates", type_name: "oilfilm_msgs/msg/CoefficientEstimate", qos: qos(100, false) };

/// The simulated (or replayed) clock: absolute, outside the graph's namespace; the player
/// publishes it.
pub const CLOCK: Topic = Topic { name: "/clock", type_name: "rosgraph_msgs/msg/Clock", qos: TopicQos { reliable: true, depth: 1, transient_local: false } };

/// The nodes' parameter events (absolute, as in every ROS 2 graph): each node announces
/// its declared parameters when it starts and every change it applied, transient-local so a
/// recorder that joins later still gets the declarations (ADR 0026).
pub const PARAMETER_EVENTS: Topic = Topic { name: "/parameter_events", type_name: "rcl_interfaces/msg/ParameterEvent", qos: qos(1000, true) };

/// What the recorder keeps by default: the graph's topics and the parameter events.
pub const RECORDED: &[Topic] = &[EXCITER_REQUEST, EXCITER_COMMAND, DAQ_FRAMES, RIG_STATUS, CONDITIONED, ESTIMATES, PARAMETER_EVENTS];

/// Every topic of the graph.
pub const ALL: &[Topic] = &[EXCITER_REQUEST, EXCITER_COMMAND, DAQ_FRAMES, RIG_STATUS, CONDITIONED, ESTIMATES];

/// The default namespace.
pub const NAMESPACE: &str = "/oilfilm";

/// `namespace/name` with exactly one slash between; an absolute name (`/clock`) as it is.
pub fn qualified(namespace: &str, topic: &Topic) -> String {
    if topic.name.starts_with('/') {
        return topic.name.to_string();
    }
    format!("{}/{}", namespace.trim_end_matches('/'), topic.name)
}
