//! The DDS port: ros2-client (pure Rust DDS) under the node binaries.
//!
//! What ros2-client does not do for us, done here: `ROS_DOMAIN_ID` is read from the
//! environment and passed into the context; every topic's QoS is set explicitly from
//! [`oilfilm_graph::topics`] (ros2-client's subscription default is best-effort, keep-last 1); the
//! typed parameters are declared through the standard parameter services, and a change
//! from `ros2 param set` (or rclpy) is checked against the typed struct before it is
//! accepted, then handed to the node's loop; and the node re-announces itself on
//! `ros_discovery_info` so a graph that missed its first announcement still lists it
//! (ADR 0017).

use std::mem::ManuallyDrop;
use std::sync::{Arc, Mutex, PoisonError};

use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, Node, NodeName, NodeOptions, ParameterValue, QosProfile,
    qos::{Durability, History, Reliability, WhenFull},
};
use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::{Map, Value};

use oilfilm_graph::node::{Connect, Input, Message, Output, RawTopic};
use oilfilm_graph::params::NodeArgs;
use oilfilm_graph::ports::{Publish, RawCdr, Receive};
use oilfilm_graph::topics::Topic;
use oilfilm_graph::NodeError;

fn mw(what: impl Into<String>, e: impl std::fmt::Display) -> NodeError {
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
        reliability: if q.reliable { Reliability::Reliable { when_full: WhenFull::Wait(std::time::Duration::from_millis(500)) } } else { Reliability::BestEffort },
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
        Value::Array(a) if a.iter().all(Value::is_string) => {
            ParameterValue::StringArray(a.iter().filter_map(|s| s.as_str().map(str::to_string)).collect())
        }
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

/// Checks a whole parameter set (the typed struct's validation): `Err(reason)` refuses it.
pub type Validator = Box<dyn Fn(&Map<String, Value>) -> Result<(), String> + Send + Sync>;

/// One ROS 2 node on DDS. Dropping it (or [`RosNode::shutdown`]) takes the node off DDS in
/// the order that leaves no entity behind: see the `Drop` impl.
pub struct RosNode {
    /// Dropped by hand, after `node` and the spinner (`Drop for RosNode`).
    context: ManuallyDrop<Context>,
    /// Dropped by hand, first after the announcer (`Drop for RosNode`).
    node: ManuallyDrop<Node>,
    namespace: String,
    params: Arc<Mutex<Map<String, Value>>>,
    changed: Arc<Mutex<bool>>,
    spinner: Option<std::thread::JoinHandle<()>>,
    announcer: Option<Announcer>,
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
struct Announcer {
    stop: std::sync::mpsc::Sender<()>,
    thread: std::thread::JoinHandle<()>,
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
pub fn ros_discovery_topic(
    participant: &ros2_client::dds::rustdds::DomainParticipant,
) -> Result<ros2_client::dds::rustdds::Topic, NodeError> {
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
    fn start(context: &Context) -> Result<Self, NodeError> {
        use ros2_client::builtin_topics::ros_discovery;
        use ros2_client::dds::rustdds::serialization::CDRSerializerAdapter;
        use ros2_client::entities_info::ParticipantEntitiesInfo;
        let participant = context.domain_participant();
        let topic = ros_discovery_topic(&participant)?;
        let writer = participant
            .create_publisher(&ros_discovery::QOS_PUB)
            .map_err(|e| mw("ros_discovery_info publisher", e))?
            .create_datawriter_no_key::<ParticipantEntitiesInfo, CDRSerializerAdapter<_>>(&topic, None)
            .map_err(|e| mw("ros_discovery_info writer", e))?;
        let (stop, stopped) = std::sync::mpsc::channel::<()>();
        let context = context.clone();
        let thread = std::thread::Builder::new()
            .name("ros-discovery-announcer".into())
            .spawn(move || {
                let scale = schedule_scale();
                let mut wait = std::time::Duration::from_millis(500);
                // Ends on a stop message or when the sender is dropped.
                while let Err(std::sync::mpsc::RecvTimeoutError::Timeout) = stopped.recv_timeout(wait.mul_f64(scale)) {
                    if let Err(e) = writer.write(context.participant_entities_info(), None) {
                        tracing::warn!("re-announcing the node on ros_discovery_info failed: {e:?}");
                    }
                    wait = if wait >= std::time::Duration::from_secs(8) {
                        std::time::Duration::from_secs(15)
                    } else {
                        wait * 2
                    };
                }
            })
            .map_err(|e| NodeError::Io { what: "ros_discovery_info announcer thread".into(), source: e })?;
        Ok(Self { stop, thread })
    }

    /// Stops before the context goes, so its farewell (an empty node list) is the last word.
    fn stop(self) {
        let _ = self.stop.send(());
        let _ = self.thread.join();
    }
}

impl RosNode {
    /// A node named by `args` in domain `ROS_DOMAIN_ID`, with `params` declared. A set
    /// request is checked by `validate` on the whole set with the new value (so a value the
    /// node would reject is refused through the service, with the reason).
    pub fn new(args: &NodeArgs, params: &Map<String, Value>, validate: Validator) -> Result<Self, NodeError> {
        let context = Context::with_options(ContextOptions::new().domain_id(domain_id()?)).map_err(|e| mw("context", e))?;
        let shared = Arc::new(Mutex::new(params.clone()));
        let changed = Arc::new(Mutex::new(false));
        let mut options = NodeOptions::new().enable_rosout(true).start_parameter_services(true);
        for (k, v) in params {
            options = options.declare_parameter(k, to_parameter(v));
        }
        let (check_params, validate) = (Arc::clone(&shared), Arc::new(validate));
        options = options.parameter_validator(Box::new(move |name, value| {
            let mut next = check_params.lock().unwrap_or_else(PoisonError::into_inner).clone();
            if !next.contains_key(name) {
                return Err(format!("`{name}` is not a parameter of this node"));
            }
            next.insert(name.to_string(), from_parameter(value));
            validate(&next)
        }));
        let (set_params, set_changed) = (Arc::clone(&shared), Arc::clone(&changed));
        options = options.parameter_set_action(Box::new(move |name, value| {
            set_params.lock().unwrap_or_else(PoisonError::into_inner).insert(name.to_string(), from_parameter(value));
            *set_changed.lock().unwrap_or_else(PoisonError::into_inner) = true;
            Ok(())
        }));
        let node_name = NodeName::new(&args.namespace, &args.name).map_err(|e| mw("node name", format!("{e:?}")))?;
        let mut node = context.clone().new_node(node_name, options).map_err(|e| mw("node", e))?;
        let spinner = node.spinner().map_err(|e| mw("spinner", e))?;
        let handle = std::thread::Builder::new()
            .name("ros2-spinner".into())
            .spawn(move || {
                if let Err(e) = smol::block_on(spinner.spin()) {
                    tracing::error!("ROS 2 spinner stopped: {e}");
                }
            })
            .map_err(|e| NodeError::Io { what: "spinner thread".into(), source: e })?;
        let announcer = Announcer::start(&context)?;
        Ok(Self {
            context: ManuallyDrop::new(context),
            node: ManuallyDrop::new(node),
            namespace: args.namespace.clone(),
            params: shared,
            changed,
            spinner: Some(handle),
            announcer: Some(announcer),
        })
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
        let (pkg, ty) = type_name
            .split_once("/msg/")
            .ok_or_else(|| mw(format!("topic {full}"), format!("type `{type_name}` is not pkg/msg/Type")))?;
        self.node.create_topic(&name, MessageTypeName::new(pkg, ty), qos).map_err(|e| mw(format!("topic {full}"), e))
    }

    /// A typed publisher on a topic given by full name, type and QoS (`/clock`).
    pub fn publisher_named<M: Serialize>(&mut self, full: &str, type_name: &str, qos: QosProfile) -> Result<DdsPublisher<M>, NodeError> {
        let t = self.topic_named(full, type_name, &qos)?;
        let p = self.node.create_publisher::<M>(&t, Some(qos)).map_err(|e| mw(format!("publisher {full}"), e))?;
        Ok(DdsPublisher { publisher: p, topic: leak_name(full), readers: Readers::new(&self.context, full) })
    }

    /// A typed subscription on a topic given by full name, type and QoS (`/clock`).
    pub fn subscription_named<M: DeserializeOwned + 'static>(&mut self, full: &str, type_name: &str, qos: QosProfile) -> Result<DdsSubscription<M>, NodeError> {
        let t = self.topic_named(full, type_name, &qos)?;
        let s = self.node.create_subscription::<M>(&t, Some(qos)).map_err(|e| mw(format!("subscription {full}"), e))?;
        Ok(DdsSubscription { subscription: s, topic: leak_name(full) })
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
        let reader = subscriber
            .create_simple_datareader_no_key::<RawCdr, RawAdapter>(&t, Some((&qos).into()))
            .map_err(|e| mw(format!("raw subscription {full}"), e))?;
        Ok(RawSubscription { reader, topic: full.to_string() })
    }

    /// A writer that sends serialised CDR as it is given (the player's output).
    pub fn raw_publisher(&mut self, full: &str, type_name: &str, qos: QosProfile) -> Result<RawPublisher, NodeError> {
        let t = self.topic_named(full, type_name, &qos)?;
        let publisher = self
            .context
            .domain_participant()
            .create_publisher(&ros2_client::dds::rustdds::QosPolicies::builder().build())
            .map_err(|e| mw(format!("publisher {full}"), e))?;
        let writer = publisher
            .create_datawriter_no_key::<RawCdr, RawAdapter>(&t, Some((&qos).into()))
            .map_err(|e| mw(format!("raw publisher {full}"), e))?;
        Ok(RawPublisher { writer, topic: full.to_string(), matched: 0, first_ack: false })
    }

    /// Matched subscriptions on a topic (fully qualified name), as DDS discovery sees them.
    pub fn subscription_count_named(&self, full: &str) -> usize {
        self.node.subscription_count(full)
    }

    pub fn publisher<M: Serialize>(&mut self, topic: &Topic) -> Result<DdsPublisher<M>, NodeError> {
        let t = self.topic(topic)?;
        let p = self.node.create_publisher::<M>(&t, Some(qos_of(topic))).map_err(|e| mw(format!("publisher {}", topic.name), e))?;
        let full = oilfilm_graph::topics::qualified(&self.namespace, topic);
        Ok(DdsPublisher { publisher: p, topic: topic.name, readers: Readers::new(&self.context, &full) })
    }

    pub fn subscription<M: DeserializeOwned + 'static>(&mut self, topic: &Topic) -> Result<DdsSubscription<M>, NodeError> {
        let t = self.topic(topic)?;
        let s = self.node.create_subscription::<M>(&t, Some(qos_of(topic))).map_err(|e| mw(format!("subscription {}", topic.name), e))?;
        Ok(DdsSubscription { subscription: s, topic: topic.name })
    }

    /// The whole parameter set, if a parameter changed since the last call.
    pub fn parameter_change(&self) -> Option<Map<String, Value>> {
        let mut changed = self.changed.lock().unwrap_or_else(PoisonError::into_inner);
        if !std::mem::replace(&mut *changed, false) {
            return None;
        }
        Some(self.params.lock().unwrap_or_else(PoisonError::into_inner).clone())
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
    /// Stops the announcer (so ros2-client's farewell, an empty node list, stays the last
    /// word), drops the node (which signals its spinner), waits for the spinner while this
    /// still holds the DDS participant, then drops the context, which lets the participant
    /// say goodbye to DDS. On every path out of a node, errors included.
    ///
    /// The order matters because ros2-client's spinner declares its context before the
    /// parameter servers: ending as the context's last holder, it dropped the participant
    /// first, and removing each of the twelve service endpoints then failed ("Cannot remove
    /// Reader/Writer ... Disconnected", a RustDDS ERROR line apiece on every node's exit;
    /// `nodes/tests/clean_exit.rs`).
    fn drop(&mut self) {
        if let Some(a) = self.announcer.take() {
            a.stop();
        }
        // SAFETY: `node` is dropped here once, and nothing uses it after: this is `drop`.
        unsafe { ManuallyDrop::drop(&mut self.node) };
        if let Some(h) = self.spinner.take() {
            let _ = h.join();
        }
        // SAFETY: as for `node`: dropped here once, never used after.
        unsafe { ManuallyDrop::drop(&mut self.context) };
    }
}

pub struct DdsPublisher<M: Serialize> {
    publisher: ros2_client::Publisher<M>,
    topic: &'static str,
    readers: Readers,
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

use ros2_client::dds::rustdds::{bytes::Bytes, no_key as dds_no_key, RepresentationIdentifier};

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
            _ => Err(RawError(format!(
                "a message of {} bytes does not start with the little-endian CDR header 00 01 00 00",
                value.0.len()
            ))),
        }
    }
}

pub struct RawSubscription {
    reader: dds_no_key::SimpleDataReader<RawCdr, RawAdapter>,
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
    writer: dds_no_key::DataWriter<RawCdr, RawAdapter>,
    topic: String,
    matched: i32,
    /// Whether the first wait for acknowledgments has had its grace (see `flush`).
    first_ack: bool,
}

/// How long a reliable reader may take to send its first acknowledgment: rustdds counts a
/// reliable reader in its acknowledgment wait only once that reader has sent its first
/// ACKNACK (answering a heartbeat); until then the wait returns at once.
const FIRST_ACK: std::time::Duration = std::time::Duration::from_millis(500);

impl RawPublisher {
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

    /// Waits (at most `max`) until every matched reliable reader acknowledged what was
    /// written; false on timeout.
    pub fn wait_for_acknowledgments(&self, max: std::time::Duration) -> Result<bool, NodeError> {
        self.writer
            .wait_for_acknowledgments(max)
            .map_err(|e| mw(format!("acknowledgments on {}", self.topic), format!("{e:?}")))
    }
}

impl Publish<RawCdr> for RawPublisher {
    fn publish(&mut self, message: RawCdr) -> Result<(), NodeError> {
        self.writer
            .write(message, Some(ros2_client::dds::rustdds::Timestamp::now()))
            .map_err(|e| mw(format!("publish on {}", self.topic), format!("{e:?}")))
    }

    fn readers(&mut self) -> Option<usize> {
        Some(self.matched())
    }

    /// The first call gives the readers [`FIRST_ACK`] to send their first acknowledgment.
    fn flush(&mut self, timeout: std::time::Duration) -> Result<bool, NodeError> {
        if !std::mem::replace(&mut self.first_ack, true) {
            std::thread::sleep(FIRST_ACK);
        }
        self.wait_for_acknowledgments(timeout)
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

pub struct DdsSubscription<M> {
    subscription: ros2_client::Subscription<M>,
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
    ctrlc::set_handler(move || f.store(true, std::sync::atomic::Ordering::SeqCst))
        .map_err(|e| mw("signal handler", e))?;
    Ok(flag)
}

/// Logs to stderr, `RUST_LOG` filtering (default info).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,rustdds=warn,ros2_client=warn"));
    let _ = tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).try_init();
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
