//! The DDS port: ros2-client (pure Rust DDS) under the node binaries.
//!
//! What ros2-client does not do for us, done here: `ROS_DOMAIN_ID` is read from the
//! environment and passed into the context; every topic's QoS is set explicitly from
//! [`oilfilm_graph::topics`] (ros2-client's subscription default is best-effort, keep-last 1);
//! the parameter services are ours ([`crate::parameters`]: descriptors from the node's specs,
//! a set applied by the node or refused with the reason); the log goes to `/rosout`
//! ([`crate::logging`]); a writer whose readers' acknowledgments a node waits for (the
//! exciter's last command, the player's messages) is RustDDS's own, made here; and the node
//! re-announces itself on `ros_discovery_info`, with the readers and writers ros2-client does
//! not know of (those writers, the recorder's raw readers), so a graph that missed its first
//! announcement still lists it and every topic shows its node (ADR 0017).
//!
//! ros2-client's spinner is not run: it would serve its own parameter services and subscribe
//! `/clock` as `builtin_interfaces/msg/Time`, a second type on a topic whose type is
//! `rosgraph_msgs/msg/Clock` (ADR 0025). Nothing here needs its discovery bookkeeping: reader
//! counts come from the participant's discovered readers.

use std::mem::ManuallyDrop;
use std::sync::{Arc, Mutex, PoisonError};

use ros2_client::{
    qos::{Durability, History, Reliability, WhenFull},
    Context, ContextOptions, MessageTypeName, Name, Node, NodeName, NodeOptions, ParameterValue, QosProfile,
};
use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::{Map, Value};

use oilfilm_graph::node::{Connect, Input, Message, Output, RawTopic};
use oilfilm_graph::params::NodeArgs;
use oilfilm_graph::ports::{Publish, RawCdr, Receive};
use oilfilm_graph::stamp::Stamp;
use oilfilm_graph::topics::Topic;
use oilfilm_graph::NodeError;

use crate::parameters::{Change, ParameterServer, SimTime};

pub(crate) fn mw(what: impl Into<String>, e: impl std::fmt::Display) -> NodeError {
    NodeError::Middleware { what: what.into(), reason: e.to_string() }
}

/// `ROS_DOMAIN_ID` (0 when unset), checked as ROS does (0..=232).
pub fn domain_id() -> Result<u16, NodeError> {
    match std::env::var("ROS_DOMAIN_ID") {
        Err(_) => Ok(0),
        Ok(s) if s.trim().is_empty() => Ok(0),
        Ok(s) => match s.trim().parse::<u16>() {
            Ok(d) if d <= 232 => Ok(d),
            _ => Err(NodeError::parameter("ROS_DOMAIN_ID", format!("`{s}` is not a domain id (0..=232)"))),
        },
    }
}

/// A topic's QoS in ros2-client's terms.
pub fn qos_of(topic: &Topic) -> QosProfile {
    qos_from(topic.qos)
}

/// Our QoS table's entry in ros2-client's terms.
pub fn qos_from(q: oilfilm_graph::topics::TopicQos) -> QosProfile {
    QosProfile {
        reliability: if q.reliable {
            Reliability::Reliable { when_full: WhenFull::Wait(std::time::Duration::from_millis(500)) }
        } else {
            Reliability::BestEffort
        },
        durability: if q.transient_local { Durability::TransientLocal } else { Durability::Volatile },
        history: History::KeepLast { depth: q.depth.max(1) as usize },
        ..QosProfile::publisher_default()
    }
}

/// A QoS profile recorded in a bag (the publisher's offer) in ros2-client's terms.
/// `reliable` forces reliable delivery (the player's fast mode, which must not drop).
pub fn qos_from_bag(q: &oilfilm_bag::QosProfile, reliable: bool) -> QosProfile {
    use oilfilm_bag::metadata::{Durability as D, History as H, Reliability as R};
    let reliability = if reliable || !matches!(q.reliability, R::BestEffort) {
        Reliability::Reliable { when_full: WhenFull::Wait(std::time::Duration::from_millis(500)) }
    } else {
        Reliability::BestEffort
    };
    QosProfile {
        reliability,
        durability: if matches!(q.durability, D::TransientLocal) { Durability::TransientLocal } else { Durability::Volatile },
        history: match q.history {
            H::KeepAll => History::KeepAll,
            _ => History::KeepLast { depth: q.depth.max(1) as usize },
        },
        ..QosProfile::publisher_default()
    }
}

/// A JSON parameter as a ROS parameter value.
pub fn to_parameter(v: &Value) -> ParameterValue {
    match v {
        Value::Bool(b) => ParameterValue::Boolean(*b),
        Value::Number(n) if n.is_i64() => ParameterValue::Integer(n.as_i64().unwrap_or_default()),
        Value::Number(n) => ParameterValue::Double(n.as_f64().unwrap_or(f64::NAN)),
        Value::String(s) => ParameterValue::String(s.clone()),
        Value::Array(a) if a.iter().all(Value::is_string) => ParameterValue::StringArray(a.iter().filter_map(|s| s.as_str().map(str::to_string)).collect()),
        Value::Array(a) if a.iter().all(|x| x.is_i64()) => ParameterValue::IntegerArray(a.iter().filter_map(Value::as_i64).collect()),
        Value::Array(a) => ParameterValue::DoubleArray(a.iter().filter_map(Value::as_f64).collect()),
        Value::Null | Value::Object(_) => ParameterValue::NotSet,
    }
}

/// A ROS parameter value as JSON (for the typed struct).
pub fn from_parameter(p: &ParameterValue) -> Value {
    match p {
        ParameterValue::NotSet => Value::Null,
        ParameterValue::Boolean(b) => Value::Bool(*b),
        ParameterValue::Integer(i) => Value::from(*i),
        ParameterValue::Double(d) => serde_json::Number::from_f64(*d).map_or(Value::Null, Value::Number),
        ParameterValue::String(s) => Value::String(s.clone()),
        ParameterValue::ByteArray(b) => Value::from(b.clone()),
        ParameterValue::BooleanArray(b) => Value::from(b.clone()),
        ParameterValue::IntegerArray(i) => Value::from(i.clone()),
        ParameterValue::DoubleArray(d) => Value::from(d.clone()),
        ParameterValue::StringArray(s) => Value::from(s.clone()),
    }
}

/// One ROS 2 node on DDS. Dropping it (or [`RosNode::shutdown`]) takes the node off DDS in
/// the order that leaves no entity behind: see the `Drop` impl.
pub struct RosNode {
    /// Dropped by hand, after `node` (`Drop for RosNode`).
    context: ManuallyDrop<Context>,
    /// Dropped by hand, first after the announcer (`Drop for RosNode`).
    node: ManuallyDrop<Node>,
    namespace: String,
    /// `/namespace/name`.
    fully_qualified: String,
    /// The parameter services, once declared ([`RosNode::declare_parameters`]).
    parameters: Option<ParameterServer>,
    /// `/clock` while the node follows it, and the last time it said.
    clock: Option<(DdsSubscription<oilfilm_msgs::Clock>, Option<Stamp>)>,
    /// The node's own `/rosout` writer (rclcpp's QoS), shared with the log; dropped with the
    /// node's other entities, before the participant (`Drop for RosNode`).
    rosout: Option<Arc<ros2_client::Publisher<ros2_client::Log>>>,
    /// Readers and writers made outside ros2-client's node (raw ones): announced with it.
    extra: Arc<Mutex<ExtraEntities>>,
    announcer: Option<Announcer>,
}

/// The GIDs of a node's readers and writers made outside ros2-client's node (the raw and
/// acknowledged ones), which ros2-client's own announcements leave out.
#[derive(Default)]
struct ExtraEntities {
    readers: Vec<ros2_client::Gid>,
    writers: Vec<ros2_client::Gid>,
}

/// Re-announces the node on `ros_discovery_info` while it lives.
///
/// ros2-client announces a node (the participant's `ParticipantEntitiesInfo`) only when
/// an entity is created, from a transient-local keep-last-1 writer. The ROS graph cache
/// (rmw_dds_common, behind `ros2 node list` and rclpy's `get_node_names`) reads that
/// keyless topic with keep-last 1 too, so when several nodes start together an
/// announcement can be overwritten in a busy reader's queue by another participant's
/// before it is taken, and then it is never sent again: the node's topics are visible but
/// the node is not. CI failed on that once (`rclpy sees our four nodes`), and 3 of 8 runs
/// of the live rclpy test here with both cores busy.
/// So the current info is sent again from a second writer of this participant, after
/// waits of 0.5, 1, 2, 4 and 8 s and then every 15 s, each scaled by a factor drawn once per
/// process in [0.75, 1.25). Without the factor, nodes launched together repeated their
/// announcements together, so the burst that lost one could lose it again every time (a
/// clean-clone CI run saw the conditioner unlisted for 30 s, through five repeats). The
/// graph cache keys by participant GID, so a repeat only restates what the first
/// announcement said.
///
/// The info sent also lists the entities made outside ros2-client's node ([`ExtraEntities`]:
/// the raw and acknowledged writers, the recorder's raw readers), which ros2-client's own
/// announcements leave out, so `ros2 topic info -v` shows them with their node instead of
/// `_NODE_NAME_UNKNOWN_`. So that ros2-client's announcement is not the last word, ours is
/// sent at once whenever an entity is made, ros2-client's or ours ([`Announcer::now`]), and
/// again [`Announcer::NEWCOMER`] after a new reader matched: a participant that joins late
/// receives both writers' stored announcements, and took ros2-client's last.
struct Announcer {
    wake: std::sync::mpsc::Sender<Wake>,
    thread: std::thread::JoinHandle<()>,
}

enum Wake {
    Now,
    Stop,
}

/// The announcer's factor on its waits, in [0.75, 1.25): from the standard library's
/// per-process random hasher keys, so processes started together get different schedules.
fn schedule_scale() -> f64 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u32(std::process::id());
    // The top 53 bits as a fraction in [0, 1).
    0.75 + 0.5 * ((h.finish() >> 11) as f64 / (1u64 << 53) as f64)
}

/// The `ros_discovery_info` topic (rmw_dds_common's `ParticipantEntitiesInfo`, the QoS
/// ros2-client's own writer has) in `participant`.
pub fn ros_discovery_topic(participant: &ros2_client::dds::rustdds::DomainParticipant) -> Result<ros2_client::dds::rustdds::Topic, NodeError> {
    use ros2_client::builtin_topics::ros_discovery;
    participant
        .create_topic(
            ros_discovery::TOPIC_NAME.to_string(),
            ros_discovery::TYPE_NAME.to_string(),
            &ros_discovery::QOS_PUB,
            ros2_client::dds::rustdds::TopicKind::NoKey,
        )
        .map_err(|e| mw("ros_discovery_info topic", e))
}

impl Announcer {
    fn start(context: &Context, node: ros2_client::NodeName, extra: Arc<Mutex<ExtraEntities>>) -> Result<Self, NodeError> {
        use ros2_client::builtin_topics::ros_discovery;
        use ros2_client::dds::rustdds::serialization::CDRSerializerAdapter;
        use ros2_client::entities_info::{NodeEntitiesInfo, ParticipantEntitiesInfo};
        let participant = context.domain_participant();
        let topic = ros_discovery_topic(&participant)?;
        let writer = participant
            .create_publisher(&ros_discovery::QOS_PUB)
            .map_err(|e| mw("ros_discovery_info publisher", e))?
            .create_datawriter_no_key::<ParticipantEntitiesInfo, CDRSerializerAdapter<_>>(&topic, None)
            .map_err(|e| mw("ros_discovery_info writer", e))?;
        let (wake, woken) = std::sync::mpsc::channel::<Wake>();
        let context = context.clone();
        let fqn = node.fully_qualified_name();
        let info = move || {
            let base = context.participant_entities_info();
            let extra = extra.lock().unwrap_or_else(PoisonError::into_inner);
            let nodes = base
                .nodes()
                .iter()
                .map(|n| {
                    let mut n = n.clone();
                    if n.fully_qualified_name() == fqn {
                        extra.readers.iter().for_each(|g| n.add_reader(*g));
                        extra.writers.iter().for_each(|g| n.add_writer(*g));
                    }
                    n
                })
                .collect::<Vec<NodeEntitiesInfo>>();
            ParticipantEntitiesInfo::new(base.gid(), nodes)
        };
        let thread = std::thread::Builder::new()
            .name("ros-discovery-announcer".into())
            .spawn(move || {
                use ros2_client::dds::rustdds::{DataWriterStatus, StatusEvented};
                use std::time::{Duration, Instant};
                let say = || {
                    if let Err(e) = writer.write(info(), Some(ros2_client::dds::rustdds::Timestamp::now())) {
                        tracing::warn!("re-announcing the node on ros_discovery_info failed: {e:?}");
                    }
                };
                let scale = schedule_scale();
                let mut wait = Duration::from_millis(500);
                let mut repeat_at = Instant::now() + wait.mul_f64(scale);
                let mut newcomer_at = None::<Instant>;
                loop {
                    let due = newcomer_at.map_or(repeat_at, |n| n.min(repeat_at));
                    match woken.recv_timeout(due.saturating_duration_since(Instant::now()).min(Self::POLL)) {
                        Ok(Wake::Now) => say(),
                        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
                        // Stopped, or the sender dropped.
                        Ok(Wake::Stop) | Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
                    }
                    while let Some(status) = writer.try_recv_status() {
                        if let DataWriterStatus::PublicationMatched { total, .. } = status {
                            if total.count_change() > 0 {
                                newcomer_at = Some(Instant::now() + Self::NEWCOMER);
                            }
                        }
                    }
                    let now = Instant::now();
                    if newcomer_at.is_some_and(|n| now >= n) {
                        newcomer_at = None;
                        say();
                    }
                    if now >= repeat_at {
                        say();
                        wait = if wait >= Duration::from_secs(8) { Duration::from_secs(15) } else { wait * 2 };
                        repeat_at = now + wait.mul_f64(scale);
                    }
                }
            })
            .map_err(|e| NodeError::Io { what: "ros_discovery_info announcer thread".into(), source: e })?;
        Ok(Self { wake, thread })
    }

    /// How often the announcer looks for new readers of `ros_discovery_info`.
    const POLL: std::time::Duration = std::time::Duration::from_millis(50);
    /// How long after a new reader of `ros_discovery_info` matched the node is announced to
    /// it again: after ros2-client's stored announcement, which leaves out the entities made
    /// here, has reached it.
    const NEWCOMER: std::time::Duration = std::time::Duration::from_millis(200);

    /// Announces now (an entity was made).
    fn now(&self) {
        let _ = self.wake.send(Wake::Now);
    }

    /// Stops before the context goes, so its farewell (an empty node list) is the last word.
    fn stop(self) {
        let _ = self.wake.send(Wake::Stop);
        let _ = self.thread.join();
    }
}

impl RosNode {
    /// A node named by `args` in domain `ROS_DOMAIN_ID`, its log going to `/rosout` from now
    /// on. It has parameter services once [`RosNode::declare_parameters`] is called.
    pub fn new(args: &NodeArgs) -> Result<Self, NodeError> {
        with_stop_signals_blocked(|| Self::start(args))
    }

    fn start(args: &NodeArgs) -> Result<Self, NodeError> {
        let context = Context::with_options(ContextOptions::new().domain_id(domain_id()?)).map_err(|e| mw("context", e))?;
        let options = NodeOptions::new().enable_rosout(false).start_parameter_services(false);
        let node_name = NodeName::new(&args.namespace, &args.name).map_err(|e| mw("node name", format!("{e:?}")))?;
        let mut node = context.clone().new_node(node_name.clone(), options).map_err(|e| mw("node", e))?;
        // rcl's rosout QoS: reliable, transient-local, keep-last 1000, 10 s lifespan.
        let rosout_qos = QosProfile {
            lifespan: Some(std::time::Duration::from_secs(10)),
            ..qos_from(oilfilm_graph::topics::TopicQos { reliable: true, depth: 1000, transient_local: true })
        };
        let rosout =
            Arc::new(node.create_publisher::<ros2_client::Log>(&context.get_rosout_topic(), Some(rosout_qos)).map_err(|e| mw("/rosout publisher", e))?);
        let fully_qualified = node_name.fully_qualified_name();
        crate::logging::attach(Arc::clone(&rosout), crate::logging::logger_name(&fully_qualified));
        let extra = Arc::new(Mutex::new(ExtraEntities::default()));
        let announcer = Announcer::start(&context, node_name, Arc::clone(&extra))?;
        Ok(Self {
            context: ManuallyDrop::new(context),
            node: ManuallyDrop::new(node),
            namespace: args.namespace.clone(),
            fully_qualified,
            parameters: None,
            clock: None,
            rosout: Some(rosout),
            extra,
            announcer: Some(announcer),
        })
    }

    /// Starts the parameter services for `specs` with their `values`, and `use_sim_time`.
    pub fn declare_parameters(
        &mut self,
        specs: Vec<oilfilm_graph::params::Spec>,
        values: Map<String, Value>,
        use_sim_time: bool,
        sim_time: SimTime,
    ) -> Result<(), NodeError> {
        let now = Stamp::now();
        let server = ParameterServer::new(&mut self.node, &self.context, &self.fully_qualified, specs, values, use_sim_time, sim_time, now)?;
        self.parameters = Some(server);
        self.follow_clock(use_sim_time)?;
        Ok(())
    }

    /// Answers the parameter requests waiting (a set goes through `apply`, which applies it
    /// to the node or refuses it); returns how many were answered.
    pub fn serve_parameters(&mut self, apply: &mut dyn FnMut(&Change) -> Result<(), String>) -> Result<usize, NodeError> {
        let now = self.now()?;
        let Some(server) = &mut self.parameters else { return Ok(0) };
        let mut sim_time = None;
        let answered = server.serve(now, &mut |change: &Change| {
            apply(change)?;
            sim_time = Some(change.use_sim_time);
            Ok(())
        });
        if let Some(on) = sim_time {
            self.follow_clock(on)?;
        }
        Ok(answered)
    }

    /// Follows `/clock` (subscribes) or the wall clock.
    fn follow_clock(&mut self, on: bool) -> Result<(), NodeError> {
        match (on, self.clock.is_some()) {
            (true, false) => {
                let qos = qos_of(&oilfilm_graph::topics::CLOCK);
                let s = self.subscription_named::<oilfilm_msgs::Clock>(oilfilm_graph::topics::CLOCK.name, oilfilm_graph::topics::CLOCK.type_name, qos)?;
                self.clock = Some((s, None));
                tracing::info!("following /clock (use_sim_time)");
            }
            (false, true) => {
                self.clock = None;
                crate::logging::set_sim_time(None);
                tracing::info!("following the wall clock (use_sim_time false)");
            }
            _ => {}
        }
        Ok(())
    }

    /// The node's ROS time: the wall clock, or the last `/clock` when it follows it (zero
    /// until the first arrives, as in rclcpp).
    pub fn now(&mut self) -> Result<Stamp, NodeError> {
        let Some((clock, last)) = &mut self.clock else { return Ok(Stamp::now()) };
        while let Some(c) = clock.receive()? {
            *last = Some(Stamp::from_time(&c.clock));
        }
        let t = last.unwrap_or(Stamp(0));
        crate::logging::set_sim_time(Some(t));
        Ok(t)
    }

    /// The node's fully qualified name (`/oilfilm/exciter`).
    pub fn fully_qualified_name(&self) -> &str {
        &self.fully_qualified
    }

    /// The namespace the node's topics live under.
    pub fn namespace(&self) -> &str {
        &self.namespace
    }

    fn topic(&mut self, topic: &Topic) -> Result<ros2_client::dds::rustdds::Topic, NodeError> {
        let full = oilfilm_graph::topics::qualified(&self.namespace, topic);
        self.topic_named(&full, topic.type_name, &qos_of(topic))
    }

    /// A topic by its fully qualified name (`/oilfilm/daq/frames`, `/clock`) and
    /// `pkg/msg/Type`.
    fn topic_named(&mut self, full: &str, type_name: &str, qos: &QosProfile) -> Result<ros2_client::dds::rustdds::Topic, NodeError> {
        let (ns, base) = full.rsplit_once('/').unwrap_or(("/", full));
        let name = Name::new(if ns.is_empty() { "/" } else { ns }, base).map_err(|e| mw(format!("topic name {full}"), format!("{e:?}")))?;
        let (pkg, ty) = type_name.split_once("/msg/").ok_or_else(|| mw(format!("topic {full}"), format!("type `{type_name}` is not pkg/msg/Type")))?;
        self.node.create_topic(&name, MessageTypeName::new(pkg, ty), qos).map_err(|e| mw(format!("topic {full}"), e))
    }

    /// A typed publisher on a topic given by full name, type and QoS (`/clock`).
    pub fn publisher_named<M: Serialize>(&mut self, full: &str, type_name: &str, qos: QosProfile) -> Result<DdsPublisher<M>, NodeError> {
        let t = self.topic_named(full, type_name, &qos)?;
        let p = self.node.create_publisher::<M>(&t, Some(qos)).map_err(|e| mw(format!("publisher {full}"), e))?;
        Ok(DdsPublisher { publisher: Paced::new(p), topic: leak_name(full), readers: Readers::new(&self.context, full) })
    }

    /// A writer on the node's participant, announced as the node's. Not ros2-client's
    /// `Publisher`, which hides its writer and with it the wait for acknowledgments
    /// ([`Publish::flush`]); but then only our announcer names its node ([`Announcer`]),
    /// so only where that wait is needed.
    fn writer<M, SA: dds_no_key::SerializerAdapter<M>>(
        &mut self,
        full: &str,
        type_name: &str,
        qos: QosProfile,
    ) -> Result<dds_no_key::DataWriter<M, SA>, NodeError> {
        let t = self.topic_named(full, type_name, &qos)?;
        let publisher = self
            .context
            .domain_participant()
            .create_publisher(&ros2_client::dds::rustdds::QosPolicies::builder().build())
            .map_err(|e| mw(format!("publisher {full}"), e))?;
        let writer = publisher.create_datawriter_no_key::<M, SA>(&t, Some((&qos).into())).map_err(|e| mw(format!("publisher {full}"), e))?;
        self.extra.lock().unwrap_or_else(PoisonError::into_inner).writers.push(ros2_client::Gid::from(ros2_client::dds::rustdds::RTPSEntity::guid(&writer)));
        self.announce_now();
        Ok(writer)
    }

    /// A typed subscription on a topic given by full name, type and QoS (`/clock`).
    pub fn subscription_named<M: DeserializeOwned + 'static>(&mut self, full: &str, type_name: &str, qos: QosProfile) -> Result<DdsSubscription<M>, NodeError> {
        let t = self.topic_named(full, type_name, &qos)?;
        let s = self.node.create_subscription::<M>(&t, Some(qos)).map_err(|e| mw(format!("subscription {full}"), e))?;
        // ros2-client has just announced the node without the writers made here.
        self.announce_now();
        Ok(DdsSubscription { subscription: Paced::new(s), topic: leak_name(full) })
    }

    /// A subscription that hands over each sample's serialised CDR as it arrived (the
    /// recorder's input): nothing is decoded, so any type is recorded byte for byte.
    /// ros2-client has no such subscription, so this is a rustdds reader on the node's
    /// participant with an adapter that keeps the bytes.
    pub fn raw_subscription(&mut self, full: &str, type_name: &str, qos: QosProfile) -> Result<RawSubscription, NodeError> {
        let t = self.topic_named(full, type_name, &qos)?;
        let subscriber = self
            .context
            .domain_participant()
            .create_subscriber(&ros2_client::dds::rustdds::QosPolicies::builder().build())
            .map_err(|e| mw(format!("subscriber {full}"), e))?;
        let reader =
            subscriber.create_simple_datareader_no_key::<RawCdr, RawAdapter>(&t, Some((&qos).into())).map_err(|e| mw(format!("raw subscription {full}"), e))?;
        self.extra.lock().unwrap_or_else(PoisonError::into_inner).readers.push(ros2_client::Gid::from(ros2_client::dds::rustdds::RTPSEntity::guid(&reader)));
        self.announce_now();
        Ok(RawSubscription { reader: Paced::new(reader), topic: full.to_string() })
    }

    /// A writer that sends serialised CDR as it is given (the player's output).
    pub fn raw_publisher(&mut self, full: &str, type_name: &str, qos: QosProfile) -> Result<RawPublisher, NodeError> {
        let writer = self.writer::<RawCdr, RawAdapter>(full, type_name, qos)?;
        Ok(RawPublisher { writer: Paced::new(writer), topic: full.to_string(), matched: 0, acks: Acks::default() })
    }

    /// Sends the node's entities on `ros_discovery_info` now.
    fn announce_now(&self) {
        if let Some(a) = &self.announcer {
            a.now();
        }
    }

    /// Matched subscriptions on a topic (fully qualified name), as DDS discovery sees them.
    pub fn subscription_count_named(&self, full: &str) -> usize {
        self.node.subscription_count(full)
    }

    pub fn publisher<M: Serialize>(&mut self, topic: &Topic) -> Result<DdsPublisher<M>, NodeError> {
        let t = self.topic(topic)?;
        let p = self.node.create_publisher::<M>(&t, Some(qos_of(topic))).map_err(|e| mw(format!("publisher {}", topic.name), e))?;
        let full = oilfilm_graph::topics::qualified(&self.namespace, topic);
        Ok(DdsPublisher { publisher: Paced::new(p), topic: topic.name, readers: Readers::new(&self.context, &full) })
    }

    /// A typed publisher whose [`Publish::flush`] waits for its readers' acknowledgments.
    pub fn acknowledged_publisher<M: Serialize>(&mut self, topic: &Topic) -> Result<AcknowledgedPublisher<M>, NodeError> {
        let full = oilfilm_graph::topics::qualified(&self.namespace, topic);
        let writer = self.writer::<M, CDRSerializerAdapter<M>>(&full, topic.type_name, qos_of(topic))?;
        Ok(AcknowledgedPublisher { writer: Paced::new(writer), topic: topic.name, readers: Readers::new(&self.context, &full), acks: Acks::default() })
    }

    pub fn subscription<M: DeserializeOwned + 'static>(&mut self, topic: &Topic) -> Result<DdsSubscription<M>, NodeError> {
        let t = self.topic(topic)?;
        let s = self.node.create_subscription::<M>(&t, Some(qos_of(topic))).map_err(|e| mw(format!("subscription {}", topic.name), e))?;
        // ros2-client has just announced the node without the writers made here.
        self.announce_now();
        Ok(DdsSubscription { subscription: Paced::new(s), topic: topic.name })
    }

    /// Waits (at most `timeout`) until `topic` has a matched subscription, so that what is
    /// published next is not lost to a reader still being discovered; false on timeout.
    pub fn wait_for_subscribers(&self, topic: &Topic, timeout: std::time::Duration) -> bool {
        let full = oilfilm_graph::topics::qualified(&self.namespace, topic);
        let deadline = std::time::Instant::now() + timeout;
        while self.node.subscription_count(&full) == 0 {
            if std::time::Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        true
    }

    /// Takes the node off DDS now (what dropping it does; the name says where a node ends).
    pub fn shutdown(self) {
        drop(self);
    }
}

impl Drop for RosNode {
    /// Takes the parameter services down and the log off `/rosout`, stops the announcer (so
    /// ros2-client's farewell, an empty node list, stays the last word), drops the node's
    /// entities and the node, then the context, which lets the participant say goodbye to
    /// DDS. On every path out of a node, errors included: entities go before their
    /// participant, or DDS cannot remove them cleanly ("Cannot remove Reader/Writer ...
    /// Disconnected", `nodes/tests/clean_exit.rs`), and one at a time ([`REMOVAL_PACE`]).
    fn drop(&mut self) {
        crate::logging::detach();
        if self.rosout.take().is_some() {
            std::thread::sleep(REMOVAL_PACE);
        }
        self.parameters = None;
        self.clock = None;
        if let Some(a) = self.announcer.take() {
            // Its writer goes with its thread.
            a.stop();
            std::thread::sleep(REMOVAL_PACE);
        }
        // SAFETY: `node` is dropped here once, and nothing uses it after: this is `drop`.
        unsafe { ManuallyDrop::drop(&mut self.node) };
        // ros2-client's node had its own `/parameter_events` writer.
        std::thread::sleep(REMOVAL_PACE);
        // SAFETY: as for `node`: dropped here once, never used after.
        unsafe { ManuallyDrop::drop(&mut self.context) };
    }
}

/// How long a node waits after dropping one of its DDS entities before the next. RustDDS
/// queues each removal for its event loop in a channel of four and gives up after 20 ms
/// (ERROR "Cannot remove Writer ... Full", the entity left announced), and a node's entities
/// dropped together on a loaded machine overflowed it (`nodes/tests/clean_exit.rs`).
const REMOVAL_PACE: std::time::Duration = std::time::Duration::from_millis(10);

/// A DDS entity that, when dropped, waits [`REMOVAL_PACE`] after its removal is queued.
pub(crate) struct Paced<T> {
    entity: T,
    _pace: RemovalPace,
}

/// Declared after the entity, so dropped after it (fields drop in declaration order).
struct RemovalPace;

impl Drop for RemovalPace {
    fn drop(&mut self) {
        std::thread::sleep(REMOVAL_PACE);
    }
}

impl<T> Paced<T> {
    pub(crate) fn new(entity: T) -> Self {
        Self { entity, _pace: RemovalPace }
    }
}

impl<T> std::ops::Deref for Paced<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.entity
    }
}

impl<T> std::ops::DerefMut for Paced<T> {
    fn deref_mut(&mut self) -> &mut T {
        &mut self.entity
    }
}

pub struct DdsPublisher<M: Serialize> {
    publisher: Paced<ros2_client::Publisher<M>>,
    topic: &'static str,
    readers: Readers,
}

/// A typed writer that can wait for its readers' acknowledgments
/// ([`RosNode::acknowledged_publisher`]).
pub struct AcknowledgedPublisher<M: Serialize> {
    writer: Paced<dds_no_key::DataWriter<M, CDRSerializerAdapter<M>>>,
    topic: &'static str,
    readers: Readers,
    acks: Acks,
}

/// The readers DDS discovery knows on one topic, looked up at most every
/// [`Readers::REFRESH`] (a node asks every turn; discovery changes on a scale of seconds).
struct Readers {
    participant: ros2_client::dds::rustdds::DomainParticipant,
    /// The topic's DDS name (`rt/oilfilm/daq/frames`).
    dds_name: String,
    last: Option<(std::time::Instant, usize)>,
}

impl Readers {
    const REFRESH: std::time::Duration = std::time::Duration::from_millis(100);

    fn new(context: &Context, full: &str) -> Self {
        Self { participant: context.domain_participant(), dds_name: format!("rt/{}", full.trim_start_matches('/')), last: None }
    }

    fn count(&mut self) -> usize {
        match self.last {
            Some((at, n)) if at.elapsed() < Self::REFRESH => n,
            _ => {
                let n = self.participant.discovered_readers().iter().filter(|r| *r.subscription_topic_data.topic_name() == self.dds_name).count();
                self.last = Some((std::time::Instant::now(), n));
                n
            }
        }
    }
}

/// The few topic names given at run time (`/clock`) live as long as the process.
fn leak_name(full: &str) -> &'static str {
    Box::leak(full.to_string().into_boxed_str())
}

/// Keeps a sample's bytes: the adapter of [`RosNode::raw_subscription`] and
/// [`RosNode::raw_publisher`]. Only little-endian plain CDR (what ROS 2 writers send and
/// bags hold) is accepted; the encapsulation header is put back in front of the data.
pub struct RawAdapter;

/// Why raw bytes could not be taken or sent.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct RawError(String);

use ros2_client::dds::rustdds::{bytes::Bytes, no_key as dds_no_key, serialization::CDRSerializerAdapter, RepresentationIdentifier};

impl dds_no_key::DeserializerAdapter<RawCdr> for RawAdapter {
    type Error = RawError;
    type Decoded = RawCdr;
    fn supported_encodings() -> &'static [RepresentationIdentifier] {
        &[RepresentationIdentifier::CDR_LE]
    }
    fn transform_decoded(decoded: RawCdr) -> RawCdr {
        decoded
    }
}

#[derive(Clone)]
pub struct RawDecoder;

impl<'de> dds_no_key::Decode<'de, RawCdr> for RawDecoder {
    type Error = RawError;
    fn decode_bytes(self, input: &'de [u8], encoding: RepresentationIdentifier) -> Result<RawCdr, RawError> {
        if encoding != RepresentationIdentifier::CDR_LE {
            return Err(RawError(format!("representation {encoding:?} is not little-endian CDR")));
        }
        let mut v = Vec::with_capacity(input.len() + 4);
        v.extend_from_slice(&oilfilm_msgs::cdr::ENCAPSULATION_CDR_LE);
        v.extend_from_slice(input);
        Ok(RawCdr(v))
    }
}

impl dds_no_key::DefaultDecoder<RawCdr> for RawAdapter {
    type Decoder = RawDecoder;
    const DECODER: RawDecoder = RawDecoder;
}

impl dds_no_key::SerializerAdapter<RawCdr> for RawAdapter {
    type Error = RawError;
    fn output_encoding() -> RepresentationIdentifier {
        RepresentationIdentifier::CDR_LE
    }
    fn to_bytes(value: &RawCdr) -> Result<Bytes, RawError> {
        match value.0.split_first_chunk::<4>() {
            Some((header, body)) if header[..2] == oilfilm_msgs::cdr::ENCAPSULATION_CDR_LE[..2] => Ok(Bytes::copy_from_slice(body)),
            _ => Err(RawError(format!("a message of {} bytes does not start with the little-endian CDR header 00 01 00 00", value.0.len()))),
        }
    }
}

pub struct RawSubscription {
    reader: Paced<dds_no_key::SimpleDataReader<RawCdr, RawAdapter>>,
    topic: String,
}

impl Receive<RawCdr> for RawSubscription {
    fn receive(&mut self) -> Result<Option<RawCdr>, NodeError> {
        self.reader.drain_read_notifications();
        match self.reader.try_take_one() {
            Ok(m) => Ok(m.map(|m| m.into_value())),
            Err(e) => {
                tracing::warn!(topic = %self.topic, "sample not taken: {e}");
                Ok(None)
            }
        }
    }
}

pub struct RawPublisher {
    writer: Paced<dds_no_key::DataWriter<RawCdr, RawAdapter>>,
    topic: String,
    matched: i32,
    acks: Acks,
}

/// The wait for acknowledgments behind [`Publish::flush`], for either kind of writer.
#[derive(Default)]
struct Acks {
    /// Whether the first wait has had its grace.
    graced: bool,
}

impl Acks {
    /// How long a reliable reader may take to send its first acknowledgment: rustdds counts
    /// a reliable reader in its acknowledgment wait only once that reader has sent its first
    /// ACKNACK (answering a heartbeat); until then the wait returns at once.
    const FIRST_ACK: std::time::Duration = std::time::Duration::from_millis(500);

    /// Waits (at most `timeout`, after the first call's [`Acks::FIRST_ACK`]) until every
    /// matched reliable reader acknowledged what `writer` wrote; false on timeout.
    fn flush<M, SA: dds_no_key::SerializerAdapter<M>>(
        &mut self,
        writer: &dds_no_key::DataWriter<M, SA>,
        topic: &str,
        timeout: std::time::Duration,
    ) -> Result<bool, NodeError> {
        if !std::mem::replace(&mut self.graced, true) {
            std::thread::sleep(Self::FIRST_ACK);
        }
        writer.wait_for_acknowledgments(timeout).map_err(|e| mw(format!("acknowledgments on {topic}"), format!("{e:?}")))
    }
}

impl RawPublisher {
    /// The writer's GID, as the graph (`ros_discovery_info`) lists it.
    pub fn gid(&self) -> ros2_client::Gid {
        ros2_client::Gid::from(ros2_client::dds::rustdds::RTPSEntity::guid(&*self.writer))
    }

    /// Readers this writer is matched with now. A reader DDS discovery has seen is not
    /// matched at once, and what is written before it is lost to a volatile reader: the
    /// player waits for this, not for discovery.
    pub fn matched(&mut self) -> usize {
        use ros2_client::dds::rustdds::{DataWriterStatus, StatusEvented};
        while let Some(status) = self.writer.try_recv_status() {
            if let DataWriterStatus::PublicationMatched { current, .. } = status {
                self.matched = current.count();
            }
        }
        self.matched.max(0) as usize
    }
}

impl Publish<RawCdr> for RawPublisher {
    fn publish(&mut self, message: RawCdr) -> Result<(), NodeError> {
        self.writer.write(message, Some(ros2_client::dds::rustdds::Timestamp::now())).map_err(|e| mw(format!("publish on {}", self.topic), format!("{e:?}")))
    }

    fn readers(&mut self) -> Option<usize> {
        Some(self.matched())
    }

    fn flush(&mut self, timeout: std::time::Duration) -> Result<bool, NodeError> {
        self.acks.flush(&self.writer, &self.topic, timeout)
    }
}

impl<M: Serialize> Publish<M> for DdsPublisher<M> {
    fn publish(&mut self, message: M) -> Result<(), NodeError> {
        self.publisher.publish(message).map_err(|e| mw(format!("publish on {}", self.topic), e))
    }

    fn readers(&mut self) -> Option<usize> {
        Some(self.readers.count())
    }
}

impl<M: Serialize> Publish<M> for AcknowledgedPublisher<M> {
    fn publish(&mut self, message: M) -> Result<(), NodeError> {
        self.writer.write(message, Some(ros2_client::dds::rustdds::Timestamp::now())).map_err(|e| mw(format!("publish on {}", self.topic), e))
    }

    fn readers(&mut self) -> Option<usize> {
        Some(self.readers.count())
    }

    fn flush(&mut self, timeout: std::time::Duration) -> Result<bool, NodeError> {
        self.acks.flush(&self.writer, self.topic, timeout)
    }
}

pub struct DdsSubscription<M> {
    subscription: Paced<ros2_client::Subscription<M>>,
    topic: &'static str,
}

impl<M: DeserializeOwned + 'static> Receive<M> for DdsSubscription<M> {
    fn receive(&mut self) -> Result<Option<M>, NodeError> {
        match self.subscription.take() {
            Ok(m) => Ok(m.map(|(m, _)| m)),
            // A sample that does not decode is skipped with its reason, like any bad input.
            Err(e) => {
                tracing::warn!(topic = self.topic, "undecodable sample skipped: {e}");
                Ok(None)
            }
        }
    }
}

/// The DDS port kind: a node's ports as ros2-client publishers and subscriptions of `ros`.
impl Connect for RosNode {
    fn input<M: Message>(&mut self, topic: &Topic) -> Result<Input<'static, M>, NodeError> {
        Ok(Box::new(self.subscription::<M>(topic)?))
    }
    fn output<M: Message>(&mut self, topic: &Topic) -> Result<Output<'static, M>, NodeError> {
        Ok(Box::new(self.publisher::<M>(topic)?))
    }
    fn acknowledged_output<M: Message>(&mut self, topic: &Topic) -> Result<Output<'static, M>, NodeError> {
        Ok(Box::new(self.acknowledged_publisher::<M>(topic)?))
    }
    fn raw_input(&mut self, topic: &RawTopic) -> Result<Input<'static, RawCdr>, NodeError> {
        Ok(Box::new(self.raw_subscription(&topic.name, &topic.type_name, qos_from_bag(&topic.qos, false))?))
    }
    fn raw_output(&mut self, topic: &RawTopic) -> Result<Output<'static, RawCdr>, NodeError> {
        Ok(Box::new(self.raw_publisher(&topic.name, &topic.type_name, qos_from_bag(&topic.qos, false))?))
    }
}

/// SIGINT/SIGTERM set this; the node loops poll it.
pub fn shutdown_flag() -> Result<Arc<std::sync::atomic::AtomicBool>, NodeError> {
    let flag = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let f = Arc::clone(&flag);
    ctrlc::set_handler(move || f.store(true, std::sync::atomic::Ordering::SeqCst)).map_err(|e| mw("signal handler", e))?;
    Ok(flag)
}

/// Runs `f` with SIGINT and SIGTERM blocked in the calling thread, so that every thread it
/// starts inherits the mask: RustDDS's event loops, which stop for good when a signal
/// interrupts their `poll` ("dp_event_loop poll failed: Interrupted system call"), after which
/// nothing the node writes leaves the process, the exciter's ramp to zero included. The
/// process's stop signals then go to a thread that does not block them (the node's own), which
/// the handler of [`shutdown_flag`] serves.
fn with_stop_signals_blocked<R>(f: impl FnOnce() -> R) -> R {
    // SAFETY: `sigset_t` is plain data that `sigemptyset` initialises; `pthread_sigmask` only
    // changes the calling thread's mask, and the old mask is put back on the way out.
    unsafe {
        let mut stop: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut stop);
        libc::sigaddset(&mut stop, libc::SIGINT);
        libc::sigaddset(&mut stop, libc::SIGTERM);
        let mut before: libc::sigset_t = std::mem::zeroed();
        libc::pthread_sigmask(libc::SIG_BLOCK, &stop, &mut before);
        let out = f();
        libc::pthread_sigmask(libc::SIG_SETMASK, &before, std::ptr::null_mut());
        out
    }
}

/// Logs to stderr, and to `/rosout` once the process has a node ([`crate::logging`]).
pub fn init_logging() {
    crate::logging::init();
}

#[cfg(test)]
mod tests {
    /// Every draw lies in [0.75, 1.25), and draws differ (each `RandomState` has keys of its
    /// own), so nodes started together do not share one announcement schedule.
    #[test]
    fn announcement_schedules_are_scaled_differently_within_a_quarter() {
        let draws: Vec<f64> = (0..200).map(|_| super::schedule_scale()).collect();
        assert!(draws.iter().all(|s| (0.75..1.25).contains(s)), "{draws:?}");
        let (lo, hi) = draws.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &s| (lo.min(s), hi.max(s)));
        assert!(hi - lo > 0.25, "200 draws span only {lo}..{hi}");
    }
}
