//! The graph's topics, their types and their QoS, in one place.
//!
//! Every topic lives under the graph's namespace (default `/oilfilm`); the node binaries
//! take `-r __ns:=/other` like any ROS 2 node. QoS is stated per topic because
//! ros2-client's defaults are not rclcpp's: all reliable, keep-last with an explicit depth,
//! volatile; `rig/status` and `exciter/command` keep the last sample for late joiners.
//!
//! | topic | type | QoS | publisher -> subscribers |
//! |---|---|---|---|
//! | `exciter/request` | ExciterCommand (spec only) | reliable, keep-last 10 | user, rclpy -> exciter |
//! | `exciter/command` | ExciterCommand (setpoints) | reliable, keep-last 50, transient-local | exciter -> daq (sim), the rig's exciter driver |
//! | `daq/frames` | DaqFrame | reliable, keep-last 200 | daq -> conditioner, recorder |
//! | `rig/status` | RigStatus | reliable, keep-last 10, transient-local | daq -> exciter, estimator |
//! | `conditioned` | ConditionedFrame | reliable, keep-last 200 | conditioner -> estimator |
//! | `estimates` | CoefficientEstimate | reliable, keep-last 100, transient-local | estimator -> users |
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

pub const EXCITER_REQUEST: Topic =
    Topic { name: "exciter/request", type_name: "oilfilm_msgs/msg/ExciterCommand", qos: qos(10, false) };
pub const EXCITER_COMMAND: Topic =
    Topic { name: "exciter/command", type_name: "oilfilm_msgs/msg/ExciterCommand", qos: qos(50, true) };
pub const DAQ_FRAMES: Topic = Topic { name: "daq/frames", type_name: "oilfilm_msgs/msg/DaqFrame", qos: qos(200, false) };
pub const RIG_STATUS: Topic = Topic { name: "rig/status", type_name: "oilfilm_msgs/msg/RigStatus", qos: qos(10, true) };
pub const CONDITIONED: Topic =
    Topic { name: "conditioned", type_name: "oilfilm_msgs/msg/ConditionedFrame", qos: qos(200, false) };
pub const ESTIMATES: Topic =
    Topic { name: "estimates", type_name: "oilfilm_msgs/msg/CoefficientEstimate", qos: qos(100, true) };

/// The simulated (or replayed) clock: absolute, outside the graph's namespace; the player
/// publishes it.
pub const CLOCK: Topic = Topic { name: "/clock", type_name: "rosgraph_msgs/msg/Clock", qos: TopicQos { reliable: true, depth: 1, transient_local: false } };

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
