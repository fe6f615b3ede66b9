//! The `recorder` node's core: messages of our topics, as the serialised CDR they arrived
//! in, written to a rosbag2 MCAP bag through [`oilfilm_bag::BagWriter`].
//!
//! * The bytes are the sample's serialized payload as it arrived: nothing is decoded or
//!   re-encoded. (DDS pads a payload sent in one DATA submessage to a multiple of 4 bytes, so
//!   a message ending off that boundary arrives with up to 3 zero bytes more; CDR readers
//!   ignore them, and rosbag2's bags hold them too.)
//! * Log time = the receive time on the recorder's clock (passed in: the system clock of
//!   the rig's machine in the node). A message's own `header.stamp` (the DAQ clock) stays in
//!   its bytes, untouched.
//! * Each topic is subscribed with the QoS its publisher offers ([`crate::topics`]), and that
//!   QoS is what the bag records as `offered_qos_profiles`, so `ros2 bag play` (and ours)
//!   republish with it.
//! * A crash loses at most the chunk being filled of each topic (each topic has chunks of
//!   its own): the writer closes a topic's chunk at `chunk_size` bytes or once it is 1 s of
//!   log time old and hands it to the OS then; so at most the last ~1 s of each topic.
//!
//! The core owns no port and no clock: [`poll`] takes what waits on the inputs and stamps
//! it with the clock it is given; the node ([`Recorder`]) gives it the turn's time.

use std::path::PathBuf;

use oilfilm_bag::{BagWriter, Compression, QosProfile, TopicId, TopicSpec, WriterOptions};
use serde::{Deserialize, Serialize};

use crate::error::NodeError;
use crate::node::{Connect, Input, Node, RawTopic, Start, Turn};
use crate::params::{NodeParams, Rule, Spec};
use crate::ports::RawCdr;
use crate::stamp::Stamp;
use crate::topics::{self, TopicQos};

/// The recorder's parameters (ROS parameters of the node; `oilfilm record` options).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecorderParams {
    /// The bag directory (must not exist, or be empty). Empty: `rosbag2_YYYY_MM_DD-HH_MM_SS`
    /// (UTC) in the working directory, as `ros2 bag record` names it.
    pub output: String,
    /// Topics to record, relative to the namespace (`daq/frames`) or absolute
    /// (`/oilfilm/daq/frames`). Empty: all six of ours and `/parameter_events`.
    pub topics: Vec<String>,
    /// Chunk compression: `zstd`, `lz4` or `none`.
    pub compression: String,
    /// Start a new file of the bag after this many MB (10^6 bytes); 0: never.
    pub split_size_mb: f64,
    /// Start a new file of the bag after this many seconds of log time; 0: never.
    pub split_duration_s: f64,
    /// Seconds between status lines on stderr; 0: none.
    pub status_period_s: f64,
}

impl Default for RecorderParams {
    fn default() -> Self {
        Self { output: String::new(), topics: Vec::new(), compression: "zstd".into(), split_size_mb: 0.0, split_duration_s: 0.0, status_period_s: 1.0 }
    }
}

impl NodeParams for RecorderParams {
    fn specs() -> Vec<Spec> {
        vec![
            Spec::fixed("output", "the bag directory (must not exist, or be empty); empty: rosbag2_YYYY_MM_DD-HH_MM_SS in the working directory", Rule::Any),
            Spec::fixed(
                "topics",
                "topics to record, relative to the namespace (daq/frames) or absolute; empty: all six of ours and /parameter_events",
                Rule::Any,
            )
            .with_constraints("each one of our topics, or /parameter_events"),
            Spec::fixed("compression", "chunk compression", Rule::OneOf(&["zstd", "lz4", "none"])),
            Spec::fixed("split_size_mb", "start a new file of the bag after this many MB (10^6 bytes); 0: never", Rule::number(0.0, 1e12)),
            Spec::fixed("split_duration_s", "start a new file of the bag after this many seconds of log time; 0: never", Rule::number(0.0, 1e12)),
            Spec::fixed("status_period_s", "seconds between status lines on stderr; 0: none", Rule::number(0.0, 1e9)),
        ]
    }

    fn validate(&self) -> Result<(), NodeError> {
        self.writer_options().map(|_| ())
    }
}

impl RecorderParams {
    /// The bag writer's options (default chunking: 1 MiB or 1 s of log time).
    pub fn writer_options(&self) -> Result<WriterOptions, NodeError> {
        let compression = match self.compression.to_ascii_lowercase().as_str() {
            "zstd" => Compression::Zstd,
            "lz4" => Compression::Lz4,
            "none" | "" => Compression::None,
            other => return Err(NodeError::parameter("compression", format!("`{other}` is not zstd, lz4 or none"))),
        };
        let positive = |name: &str, v: f64| -> Result<Option<f64>, NodeError> {
            if !v.is_finite() || v < 0.0 {
                return Err(NodeError::parameter(name, format!("{v} is not a number >= 0 (0: off)")));
            }
            Ok((v > 0.0).then_some(v))
        };
        let split_size_bytes = positive("split_size_mb", self.split_size_mb)?.map(|mb| (mb * 1e6).round() as u64);
        let split_duration_ns = positive("split_duration_s", self.split_duration_s)?.map(|s| (s * 1e9).round() as u64);
        positive("status_period_s", self.status_period_s)?;
        Ok(WriterOptions { compression, split_size_bytes, split_duration_ns, ..WriterOptions::default() })
    }

    /// The bag directory: `output`, or the rosbag2-style name for `now`.
    pub fn output_dir(&self, now: Stamp) -> PathBuf {
        if self.output.is_empty() {
            PathBuf::from(default_bag_name(now))
        } else {
            PathBuf::from(&self.output)
        }
    }
}

/// `rosbag2_YYYY_MM_DD-HH_MM_SS` of `now` (UTC), the name `ros2 bag record` gives a bag.
pub fn default_bag_name(now: Stamp) -> String {
    let secs = now.0.div_euclid(1_000_000_000);
    let (days, day_s) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date of a day count since 1970-01-01 (proleptic Gregorian).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("rosbag2_{year:04}_{month:02}_{day:02}-{:02}_{:02}_{:02}", day_s / 3600, day_s % 3600 / 60, day_s % 60)
}

/// One topic the recorder subscribes to.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordTopic {
    /// Fully qualified name (`/oilfilm/daq/frames`).
    pub name: String,
    /// `pkg/msg/Type`.
    pub type_name: String,
    /// The QoS its publisher offers (and the recorder requests).
    pub qos: TopicQos,
}

/// The topics `wanted` names (when empty: all six of ours and `/parameter_events`) under
/// `namespace`; an unknown name is an error listing the known ones.
pub fn select_topics(namespace: &str, wanted: &[String]) -> Result<Vec<RecordTopic>, NodeError> {
    let of = |t: &topics::Topic| RecordTopic { name: topics::qualified(namespace, t), type_name: t.type_name.into(), qos: t.qos };
    if wanted.is_empty() {
        return Ok(topics::RECORDED.iter().map(of).collect());
    }
    let mut out: Vec<RecordTopic> = Vec::new();
    for w in wanted {
        let found =
            topics::RECORDED
                .iter()
                .find(|t| {
                    if w.starts_with('/') {
                        topics::qualified(namespace, t) == *w
                    } else {
                        t.name == w.as_str() || t.name.strip_prefix('/') == Some(w.as_str())
                    }
                })
                .map(of);
        match found {
            Some(t) if !out.contains(&t) => out.push(t),
            Some(_) => {}
            None => {
                let known: Vec<String> = topics::RECORDED.iter().map(|t| topics::qualified(namespace, t)).collect();
                return Err(NodeError::parameter("topics", format!("`{w}` is not one of our topics ({})", known.join(", "))));
            }
        }
    }
    Ok(out)
}

/// A topic's QoS as rosbag2 records it.
pub fn bag_qos(q: &TopicQos) -> QosProfile {
    QosProfile::keep_last(q.depth.max(1) as u32, q.reliable, q.transient_local)
}

/// Counts of what was recorded.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecorderStats {
    pub messages: u64,
    /// CDR bytes recorded (before compression).
    pub bytes: u64,
    /// Messages per topic, in the topics' order.
    pub per_topic: Vec<u64>,
    /// Messages missing per topic, in the topics' order: the gaps in the publisher's running
    /// `sequence` ([`numbered`]), zero for topics without one.
    pub missing_per_topic: Vec<u64>,
}

impl RecorderStats {
    pub fn missing(&self) -> u64 {
        self.missing_per_topic.iter().sum()
    }
}

/// The topics whose publisher numbers its messages one by one in `sequence`: the graph's
/// own publications. A gap there is a message that never reached the bag: dropped by its
/// publisher (the DAQ's full queue under a flood), lost on the way, or pushed out of the
/// reader's history (keep-last [`HISTORY_DEPTH`]) while the writer was behind. `exciter/request` is left out: whoever sends a request numbers it as they like.
pub fn numbered(namespace_qualified: &str, type_name: &str) -> bool {
    [topics::EXCITER_COMMAND, topics::DAQ_FRAMES, topics::CONDITIONED, topics::ESTIMATES]
        .iter()
        .any(|t| t.type_name == type_name && namespace_qualified.ends_with(&format!("/{}", t.name)))
}

/// The running `sequence` of a message of a [`numbered`] topic; `None` when it does not
/// decode (it is recorded all the same, as it came).
fn sequence_of(type_name: &str, bytes: &[u8]) -> Option<u64> {
    use oilfilm_msgs::{decode, CoefficientEstimate, ConditionedFrame, DaqFrame, ExciterCommand, RosMessage};
    match type_name {
        DaqFrame::TYPE_NAME => decode::<DaqFrame>(bytes).ok().map(|m| m.sequence),
        ConditionedFrame::TYPE_NAME => decode::<ConditionedFrame>(bytes).ok().map(|m| m.sequence),
        CoefficientEstimate::TYPE_NAME => decode::<CoefficientEstimate>(bytes).ok().map(|m| m.sequence),
        ExciterCommand::TYPE_NAME => decode::<ExciterCommand>(bytes).ok().map(|m| m.sequence),
        _ => None,
    }
}

/// The history each topic's reader keeps while the writer is behind: the recorder's queue
/// limit. Past it the oldest waiting messages are pushed out (counted as missing on the
/// numbered topics).
pub const HISTORY_DEPTH: u32 = 10_000;

pub struct RecorderCore {
    writer: BagWriter,
    topics: Vec<RecordTopic>,
    ids: Vec<TopicId>,
    stats: RecorderStats,
    /// Per topic: whether it is [`numbered`], and the last sequence seen.
    numbered: Vec<bool>,
    last_sequence: Vec<Option<u64>>,
}

impl RecorderCore {
    /// Adds each topic (its schema from our .msg files, its offered QoS) to `writer`.
    pub fn new(mut writer: BagWriter, topics: Vec<RecordTopic>) -> Result<Self, NodeError> {
        let mut ids = Vec::with_capacity(topics.len());
        for t in &topics {
            let spec = TopicSpec::ours(&t.name, &t.type_name, vec![bag_qos(&t.qos)])
                .map_err(|reason| NodeError::parameter("topics", format!("{}: {reason}", t.name)))?;
            ids.push(writer.add_topic(spec)?);
        }
        let stats = RecorderStats { per_topic: vec![0; topics.len()], missing_per_topic: vec![0; topics.len()], ..Default::default() };
        let numbered = topics.iter().map(|t| numbered(&t.name, &t.type_name)).collect();
        let last_sequence = vec![None; topics.len()];
        Ok(Self { writer, topics, ids, stats, numbered, last_sequence })
    }

    pub fn topics(&self) -> &[RecordTopic] {
        &self.topics
    }

    pub fn stats(&self) -> &RecorderStats {
        &self.stats
    }

    /// Writes one message of topic `index` received at `receive_time`.
    pub fn record(&mut self, index: usize, receive_time: Stamp, message: &RawCdr) -> Result<(), NodeError> {
        let id = *self.ids.get(index).ok_or_else(|| NodeError::parameter("topics", format!("no topic {index}")))?;
        let log_time = u64::try_from(receive_time.0).map_err(|_| NodeError::BadMessage {
            topic: self.topics[index].name.clone(),
            sequence: self.stats.per_topic[index],
            reason: format!("receive time {} ns is before 1970", receive_time.0),
        })?;
        self.writer.write(id, log_time, &message.0)?;
        self.stats.messages += 1;
        self.stats.bytes += message.0.len() as u64;
        self.stats.per_topic[index] += 1;
        if self.numbered[index] {
            if let Some(seq) = sequence_of(&self.topics[index].type_name, &message.0) {
                // A sequence at or below the last one is a publisher that started again (or a
                // transient-local history sent anew): counting starts over from it.
                if let Some(last) = self.last_sequence[index].filter(|&last| seq > last) {
                    self.stats.missing_per_topic[index] += seq - last - 1;
                }
                self.last_sequence[index] = Some(seq);
            }
        }
        Ok(())
    }

    /// Closes the bag: its last file finished, metadata.yaml written. Returns its directory.
    pub fn close(self) -> Result<PathBuf, NodeError> {
        Ok(self.writer.close()?)
    }
}

/// One turn: takes everything waiting on `inputs` (one per topic, in the core's topic
/// order), each message stamped with `clock()` as it is taken. Returns the number taken.
pub fn poll(core: &mut RecorderCore, inputs: &mut [Input<'_, RawCdr>], clock: &dyn Fn() -> Stamp) -> Result<usize, NodeError> {
    let mut taken = 0;
    for (index, input) in inputs.iter_mut().enumerate() {
        while let Some(m) = input.receive()? {
            core.record(index, clock(), &m)?;
            taken += 1;
        }
    }
    Ok(taken)
}

/// The status line: totals, throughput since the last line, and per-topic counts.
/// `mb_per_s`: MB (10^6 bytes) of CDR per second over the last period.
pub fn status_line(stats: &RecorderStats, topics: &[RecordTopic], elapsed_s: f64, mb_per_s: f64) -> String {
    let short = |t: &RecordTopic| t.name.rsplit_once("/oilfilm/").map_or(t.name.clone(), |(_, r)| r.to_string());
    let per_topic: Vec<String> = topics.iter().zip(&stats.per_topic).map(|(t, n)| format!("{} {n}", short(t))).collect();
    let missing: Vec<String> = topics.iter().zip(&stats.missing_per_topic).filter(|(_, &n)| n > 0).map(|(t, n)| format!("{} {n}", short(t))).collect();
    let missing = if missing.is_empty() { String::new() } else { format!(" | MISSING (gaps in sequence): {}", missing.join(", ")) };
    format!(
        "recording {:.0} s: {} msgs, {:.2} MB, {:.2} MB/s | {}{missing}",
        elapsed_s,
        stats.messages,
        stats.bytes as f64 * 1e-6,
        mb_per_s,
        per_topic.join(", ")
    )
}

/// The recorder node: our topics to a bag until it is stopped.
pub struct Recorder {
    /// `None` once closed.
    core: Option<RecorderCore>,
    dir: PathBuf,
    status_period_s: f64,
    started: Stamp,
    /// When the last status line was printed, and the bytes then.
    last_status: (Stamp, u64),
    /// The last log time given (each message's is later than the one before).
    last_log: Stamp,
    /// Missing messages already warned of, and when the last warning went out.
    warned_missing: (u64, Option<Stamp>),
    closed: Option<PathBuf>,
}

impl Recorder {
    /// The bag's directory.
    pub fn dir(&self) -> &std::path::Path {
        &self.dir
    }

    /// The closed bag's directory, once [`Node::finish`] has closed it.
    pub fn closed(&self) -> Option<&std::path::Path> {
        self.closed.as_deref()
    }

    fn take(&mut self, now: Stamp, inputs: &mut [Input<'_, RawCdr>]) -> Result<usize, NodeError> {
        let Some(core) = &mut self.core else { return Ok(0) };
        // The turn's time, one nanosecond more for each message after the first: log times
        // keep the order messages were taken in.
        let last = std::cell::Cell::new(self.last_log);
        let clock = || {
            let t = Stamp(now.0.max(last.get().0 + 1));
            last.set(t);
            t
        };
        let taken = poll(core, inputs, &clock)?;
        self.last_log = last.get();
        Ok(taken)
    }
}

impl Node for Recorder {
    const NAME: &'static str = "recorder";
    type Params = RecorderParams;
    type Ports<'a> = Vec<Input<'a, RawCdr>>;

    fn new(params: &RecorderParams, start: &Start) -> Result<Self, NodeError> {
        let options = params.writer_options()?;
        let topics = select_topics(start.namespace, &params.topics)?;
        let dir = params.output_dir(start.now);
        let core = RecorderCore::new(BagWriter::create(&dir, options)?, topics)?;
        tracing::info!(node = Self::NAME, "recording {} topic(s) to {}", core.topics().len(), dir.display());
        Ok(Self {
            core: Some(core),
            dir,
            status_period_s: params.status_period_s,
            started: start.now,
            last_status: (start.now, 0),
            last_log: Stamp(i64::MIN),
            warned_missing: (0, None),
            closed: None,
        })
    }

    /// Each topic with its publisher's reliability and durability (so they match), but a
    /// deep history: a burst (a fast replay) must wait in the reader rather than push older
    /// samples out.
    fn connect<C: Connect>(&self, c: &mut C) -> Result<Vec<Input<'static, RawCdr>>, NodeError> {
        let topics = self.core.as_ref().map_or(&[][..], |core| core.topics());
        topics
            .iter()
            .map(|t| {
                c.raw_input(&RawTopic {
                    name: t.name.clone(),
                    type_name: t.type_name.clone(),
                    qos: QosProfile::keep_last(HISTORY_DEPTH, t.qos.reliable, t.qos.transient_local),
                })
            })
            .collect()
    }

    fn turn(&mut self, now: Stamp, inputs: &mut Vec<Input<'_, RawCdr>>) -> Result<Turn, NodeError> {
        let taken = self.take(now, inputs)?;
        if let Some(core) = &self.core {
            // New gaps are warned of (to /rosout too), at most once a second, with the count.
            let missing = core.stats().missing();
            let due = self.warned_missing.1.is_none_or(|t| now.seconds_since(t) >= 1.0);
            if missing > self.warned_missing.0 && due {
                tracing::warn!(
                    node = Self::NAME,
                    "{} message(s) missing from the bag so far, by gaps in their sequence numbers ({} since the last warning): \
                     dropped by their publisher, lost on the way, or pushed out of the recorder's history of {HISTORY_DEPTH} \
                     per topic while it was behind",
                    missing,
                    missing - self.warned_missing.0
                );
                self.warned_missing = (missing, Some(now));
            }
            let since_s = now.seconds_since(self.last_status.0);
            if self.status_period_s > 0.0 && since_s >= self.status_period_s {
                let rate = (core.stats().bytes - self.last_status.1) as f64 * 1e-6 / since_s;
                eprintln!("{}", status_line(core.stats(), core.topics(), now.seconds_since(self.started), rate));
                self.last_status = (now, core.stats().bytes);
            }
        }
        Ok(Turn { handled: taken, ..Turn::default() })
    }

    /// What arrived before the stop is kept; the bag is closed (metadata.yaml written), even
    /// after an error, so what was written stays readable.
    fn finish(&mut self, now: Stamp, inputs: &mut Vec<Input<'_, RawCdr>>) -> Result<(), NodeError> {
        let taken = self.take(now, inputs);
        let Some(core) = self.core.take() else { return taken.map(|_| ()) };
        let (stats, topics) = (core.stats().clone(), core.topics().to_vec());
        let dir = core.close()?;
        taken?;
        eprintln!("{}", status_line(&stats, &topics, now.seconds_since(self.started), 0.0));
        if stats.missing() > 0 {
            tracing::warn!(
                node = Self::NAME,
                "closed {} ({} messages; {} missing by gaps in their sequence numbers)",
                dir.display(),
                stats.messages,
                stats.missing()
            );
        } else {
            tracing::info!(node = Self::NAME, "closed {} ({} messages)", dir.display(), stats.messages);
        }
        self.closed = Some(dir);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ports::{memory::Bus, Publish, Receive};
    use oilfilm_bag::Bag;
    use oilfilm_msgs::{encode, DaqFrame, Header, RigStatus, Time};

    fn temp_dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("oilfilm-recorder-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    /// Gaps in a numbered topic's sequence are counted as missing messages (the ones a flood
    /// pushed out of the reader's history never arrive), a publisher that starts again is
    /// not a gap, and a topic without a running sequence (rig status, requests) counts none.
    #[test]
    fn gaps_in_the_publishers_sequence_are_counted_as_missing() {
        use oilfilm_msgs::ExciterCommand;
        let dir = temp_dir("missing");
        let topics = select_topics("/oilfilm", &["daq/frames".into(), "rig/status".into(), "exciter/request".into()]).unwrap();
        let mut core = RecorderCore::new(BagWriter::create(&dir, WriterOptions::default()).unwrap(), topics).unwrap();
        let frame = |k: u64| RawCdr(encode(&DaqFrame { sequence: k, values: vec![1.0; 10], ..Default::default() }));
        let mut t = 1_700_000_000_000_000_000_i64;
        let mut at = || {
            t += 1_000;
            Stamp(t)
        };
        // 0 1 2, then 6 (3, 4, 5 missing), 7, then a restart at 0 1, then 4 (2, 3 missing).
        for k in [0, 1, 2, 6, 7, 0, 1, 4] {
            core.record(0, at(), &frame(k)).unwrap();
        }
        for k in 0..3 {
            core.record(1, at(), &RawCdr(encode(&RigStatus { speed_rad_s: f64::from(k), ..Default::default() }))).unwrap();
        }
        // Requests are numbered by whoever sends them: 0, 0, 9 is no gap.
        for k in [0, 0, 9] {
            core.record(2, at(), &RawCdr(encode(&ExciterCommand { sequence: k, ..Default::default() }))).unwrap();
        }
        assert_eq!(core.stats().missing_per_topic, [5, 0, 0]);
        assert_eq!(core.stats().missing(), 5);
        let line = status_line(core.stats(), core.topics(), 1.0, 0.0);
        assert!(line.contains("MISSING (gaps in sequence): daq/frames 5"), "{line}");
        assert!(
            numbered("/oilfilm/estimates", "oilfilm_msgs/msg/CoefficientEstimate") && !numbered("/oilfilm/exciter/request", "oilfilm_msgs/msg/ExciterCommand")
        );
        // Every message is in the bag all the same.
        assert_eq!(Bag::open(core.close().unwrap()).unwrap().messages().unwrap().len(), 14);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn records_what_was_published_byte_for_byte_at_the_receive_time() {
        let dir = temp_dir("bytes");
        let topics = select_topics("/oilfilm", &["daq/frames".into(), "/oilfilm/rig/status".into()]).unwrap();
        assert_eq!(topics.iter().map(|t| t.name.as_str()).collect::<Vec<_>>(), ["/oilfilm/daq/frames", "/oilfilm/rig/status"]);
        let mut core = RecorderCore::new(BagWriter::create(&dir, WriterOptions::default()).unwrap(), topics).unwrap();
        let (frames, status) = (Bus::<RawCdr>::new(), Bus::<RawCdr>::new());
        let mut inputs: Vec<Box<dyn Receive<RawCdr>>> = vec![Box::new(frames.subscriber()), Box::new(status.subscriber())];
        let (mut pf, mut ps) = (frames.publisher(), status.publisher());
        let mut published = Vec::new();
        for k in 0..5u32 {
            let f = DaqFrame {
                header: Header { stamp: Time { sec: 100, nanosec: k * 1000 }, frame_id: "oilfilm_bearing".into() },
                sequence: u64::from(k),
                values: (0..10).map(|i| f64::from(i * k)).collect(),
                ..Default::default()
            };
            let s = RigStatus { speed_rad_s: f64::from(k), message: format!("s{k}"), ..Default::default() };
            // Bytes another writer might send: not what our encoder would produce (a
            // non-zero padding byte) must still be kept as they came.
            let mut fb = encode(&f);
            fb.push(0xAB);
            pf.publish(RawCdr(fb.clone())).unwrap();
            ps.publish(RawCdr(encode(&s))).unwrap();
            published.push(("/oilfilm/daq/frames", fb));
            published.push(("/oilfilm/rig/status", encode(&s)));
        }
        let t = std::cell::Cell::new(1_700_000_000_000_000_000_i64);
        let clock = || {
            t.set(t.get() + 1_000);
            Stamp(t.get())
        };
        assert_eq!(poll(&mut core, &mut inputs, &clock).unwrap(), 10);
        assert_eq!(poll(&mut core, &mut inputs, &clock).unwrap(), 0);
        assert_eq!(core.stats().per_topic, [5, 5]);
        let line = status_line(core.stats(), core.topics(), 2.0, 0.5);
        assert!(line.contains("10 msgs") && line.contains("daq/frames 5") && line.contains("rig/status 5"), "{line}");
        let dir = core.close().unwrap();
        let bag = Bag::open(&dir).unwrap();
        let msgs = bag.messages().unwrap();
        assert_eq!(msgs.len(), 10);
        // Poll takes all of a topic's waiting messages before the next topic's.
        let want: Vec<_> = published.iter().filter(|(t, _)| t.contains("daq")).chain(published.iter().filter(|(t, _)| t.contains("rig"))).collect();
        for (i, (m, (topic, bytes))) in msgs.iter().zip(want).enumerate() {
            assert_eq!(&*m.topic, *topic, "message {i}");
            assert_eq!(&m.data, bytes, "message {i}: bytes differ");
            assert_eq!(m.log_time, 1_700_000_000_000_000_000 + 1_000 * (i as u64 + 1), "message {i}: log time is the receive time");
        }
        let info = bag.info();
        let daq = &info.topics_with_message_count[0].topic_metadata;
        assert_eq!(daq.offered_qos_profiles, vec![bag_qos(&topics::DAQ_FRAMES.qos)]);
        // rig/status is volatile (only exciter/command keeps history: topics.rs).
        assert_eq!(info.topics_with_message_count[1].topic_metadata.offered_qos_profiles[0].durability, oilfilm_bag::metadata::Durability::Volatile);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn parameters_are_checked_and_topics_named() {
        let p = RecorderParams { compression: "lz4".into(), split_size_mb: 2.5, split_duration_s: 10.0, ..Default::default() };
        let o = p.writer_options().unwrap();
        assert_eq!((o.compression, o.split_size_bytes, o.split_duration_ns), (Compression::Lz4, Some(2_500_000), Some(10_000_000_000)));
        assert_eq!(RecorderParams::default().writer_options().unwrap().compression, Compression::Zstd);
        let e = RecorderParams { compression: "gzip".into(), ..Default::default() }.writer_options().unwrap_err().to_string();
        assert!(e.contains("compression") && e.contains("gzip"), "{e}");
        let e = RecorderParams { split_size_mb: -1.0, ..Default::default() }.writer_options().unwrap_err().to_string();
        assert!(e.contains("split_size_mb"), "{e}");
        let all = select_topics("/oilfilm", &[]).unwrap();
        assert_eq!(all.len(), 7, "our six and the parameter events");
        assert_eq!(all[6].name, "/parameter_events");
        assert_eq!(select_topics("/oilfilm", &["parameter_events".into()]).unwrap()[0].type_name, "rcl_interfaces/msg/ParameterEvent");
        let e = select_topics("/oilfilm", &["daq/frame".into()]).unwrap_err().to_string();
        assert!(e.contains("daq/frame") && e.contains("/oilfilm/daq/frames"), "{e}");
        assert_eq!(select_topics("/rig2", &["estimates".into()]).unwrap()[0].name, "/rig2/estimates");
    }

    #[test]
    fn default_bag_name_is_the_utc_date() {
        // 2026-11-21 19:52:13 UTC
        assert_eq!(default_bag_name(Stamp(1_795_290_733_000_000_000)), "rosbag2_2026_11_21-19_52_13");
        assert_eq!(default_bag_name(Stamp(0)), "rosbag2_1970_01_01-00_00_00");
        // 2024-02-29 23:59:59 UTC (a leap day)
        assert_eq!(default_bag_name(Stamp(1_709_251_199_000_000_000)), "rosbag2_2024_02_29-23_59_59");
    }
}
