//! The `player` node's core: a bag's messages republished in log-time order, paced against
//! a wall clock that is passed in, with `/clock` carrying the bag's log time.
//!
//! The stamp and `/clock` story:
//! * Each message is published with the bytes it was recorded with, so its `header.stamp`
//!   (the DAQ clock at acquisition) is the recorded one: replayed frames and estimates carry
//!   the times of the run, and our nodes (slaved to the frame stamps) compute exactly what
//!   they computed live.
//! * `/clock` (`rosgraph_msgs/msg/Clock`) carries the bag's **log time** (when the recorder
//!   received the message): before any message is published, `/clock` has reached that
//!   message's log time, and between messages it advances at the playback rate
//!   (`clock_hz` times a second of wall time). ROS nodes with `use_sim_time:=true` thus see
//!   the time of the recording, at the rate of the playback. With `--loop` it jumps back at
//!   each new pass, as `ros2 bag play --loop` does.
//!
//! Pacing ([`PlayerCore::step`], a pure function of the wall time given): message `i` is
//! due at `wall_start + (log_time_i - log_time_0) / rate`; with [`Rate::Fast`] every message
//! is due at once, in batches, and the shell waits for the reliable readers'
//! acknowledgments after each batch, so nothing is dropped however slow the reader.

use std::ops::Range;
use std::sync::Arc;

use oilfilm_bag::{BagMessage, QosProfile};
use oilfilm_msgs::{Clock, Time};
use serde::{Deserialize, Serialize};

use crate::error::NodeError;
use crate::node::{Connect, Node, Output, RawTopic, Start, Turn};
use crate::params::{NodeParams, Rule, Spec};
use crate::ports::{Publish, RawCdr};
use crate::stamp::Stamp;

/// The player's parameters (ROS parameters of the node; `oilfilm play` options).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlayerParams {
    /// The bag directory.
    pub bag: String,
    /// Playback rate: 1 real time, 2 twice as fast, 0.5 half speed.
    pub rate: f64,
    /// As fast as the readers take it (reliable, nothing dropped); overrides `rate`.
    pub fast: bool,
    /// Start again at the end, for ever.
    #[serde(rename = "loop")]
    pub looped: bool,
    /// Publish `/clock` with the bag's log time.
    pub clock: bool,
    /// `/clock` messages per second of wall time between messages.
    pub clock_hz: f64,
    /// Topics to play (full names as in the bag); empty: all.
    pub topics: Vec<String>,
    /// Seconds to wait for a subscriber on every played topic before starting.
    pub wait_s: f64,
}

impl Default for PlayerParams {
    fn default() -> Self {
        Self { bag: String::new(), rate: 1.0, fast: false, looped: false, clock: true, clock_hz: 100.0, topics: Vec::new(), wait_s: 10.0 }
    }
}

impl NodeParams for PlayerParams {
    fn specs() -> Vec<Spec> {
        vec![
            Spec::fixed("bag", "the bag directory to play", Rule::Any).with_constraints("not empty"),
            Spec::fixed("rate", "playback rate: 1 real time, 2 twice as fast, 0.5 half speed", Rule::above(0.0, 1e9)),
            Spec::fixed("fast", "as fast as the readers take it (reliable, nothing dropped); overrides rate", Rule::Any),
            Spec::fixed("loop", "start again at the end, for ever", Rule::Any),
            Spec::fixed("clock", "publish /clock (rosgraph_msgs/msg/Clock) with the bag's log time", Rule::Any),
            Spec::fixed("clock_hz", "/clock messages per second of wall time between messages", Rule::above(0.0, 1e6)),
            Spec::fixed("topics", "topics to play (full names as in the bag); empty: all", Rule::Any),
            Spec::fixed("wait_s", "seconds to wait for a subscriber on every played topic before starting", Rule::number(0.0, 86_400.0)),
        ]
    }

    fn validate(&self) -> Result<(), NodeError> {
        self.options().map(|_| ())
    }
}

impl PlayerParams {
    pub fn options(&self) -> Result<PlayerOptions, NodeError> {
        if self.bag.is_empty() {
            return Err(NodeError::parameter("bag", "no bag directory given"));
        }
        let rate = if self.fast {
            Rate::Fast
        } else if self.rate.is_finite() && self.rate > 0.0 {
            Rate::Factor(self.rate)
        } else {
            return Err(NodeError::parameter("rate", format!("{} is not a rate > 0 (use fast for as fast as possible)", self.rate)));
        };
        if !(self.clock_hz.is_finite() && self.clock_hz > 0.0) {
            return Err(NodeError::parameter("clock_hz", format!("{} is not a rate > 0", self.clock_hz)));
        }
        if !(self.wait_s.is_finite() && self.wait_s >= 0.0) {
            return Err(NodeError::parameter("wait_s", format!("{} is not a time >= 0", self.wait_s)));
        }
        Ok(PlayerOptions { rate, looped: self.looped, clock_period_ns: (1e9 / self.clock_hz).round().max(1.0) as i64, fast_batch: 64 })
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rate {
    /// Log time runs this many times faster than the wall clock.
    Factor(f64),
    /// Every message at once, in batches of [`PlayerOptions::fast_batch`].
    Fast,
}

#[derive(Debug, Clone, PartialEq)]
pub struct PlayerOptions {
    pub rate: Rate,
    pub looped: bool,
    /// Wall time between `/clock` messages while no message is due.
    pub clock_period_ns: i64,
    /// Messages per step in fast mode (the shell waits for acknowledgments between steps).
    pub fast_batch: usize,
}

/// A topic to play: its name, type and the QoS the recorder's publisher offered.
#[derive(Debug, Clone, PartialEq)]
pub struct PlayTopic {
    pub name: String,
    pub type_name: String,
    pub qos: Option<QosProfile>,
}

/// One message to play.
#[derive(Debug, Clone, PartialEq)]
pub struct PlayItem {
    /// Index into the topics.
    pub topic: usize,
    pub log_time: u64,
    pub data: RawCdr,
}

/// The topics and messages of a bag's messages (in the order read: by log time), keeping
/// the topics named in `wanted` (all when empty). `qos_of` gives a topic's recorded QoS.
pub fn play_list(
    messages: Vec<BagMessage>,
    wanted: &[String],
    qos_of: &dyn Fn(&str) -> Option<QosProfile>,
) -> Result<(Vec<PlayTopic>, Vec<PlayItem>), NodeError> {
    let mut topics: Vec<PlayTopic> = Vec::new();
    let mut names: Vec<Arc<str>> = Vec::new();
    let mut items = Vec::with_capacity(messages.len());
    for m in messages {
        if !wanted.is_empty() && !wanted.iter().any(|w| **w == *m.topic) {
            continue;
        }
        let topic = match names.iter().position(|n| *n == m.topic) {
            Some(i) => i,
            None => {
                topics.push(PlayTopic { name: m.topic.to_string(), type_name: m.type_name.to_string(), qos: qos_of(&m.topic) });
                names.push(Arc::clone(&m.topic));
                names.len() - 1
            }
        };
        items.push(PlayItem { topic, log_time: m.log_time, data: RawCdr(m.data) });
    }
    if let Some(w) = wanted.iter().find(|w| !topics.iter().any(|t| t.name == **w)) {
        let have: Vec<&str> = topics.iter().map(|t| t.name.as_str()).collect();
        return Err(NodeError::parameter("topics", format!("`{w}` has no message in the bag (it has: {})", have.join(", "))));
    }
    // Files follow each other in time, each sorted; keep that order stable across files.
    items.sort_by_key(|i| i.log_time);
    Ok((topics, items))
}

/// What to do now.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    /// Publish this on `/clock` first.
    pub clock: Option<Time>,
    /// Then these messages (indices into [`PlayerCore::items`]), in order.
    pub publish: Range<usize>,
    /// Call again at this wall time (or at once when it is past).
    pub next_wall: Stamp,
    /// Every message was published (never with `looped`).
    pub finished: bool,
}

pub struct PlayerCore {
    topics: Vec<PlayTopic>,
    items: Vec<PlayItem>,
    options: PlayerOptions,
    next: usize,
    /// Wall time and log time of the first message of this pass.
    start: Option<(Stamp, u64)>,
    last_clock: Option<(Stamp, u64)>,
    passes: u64,
}

impl PlayerCore {
    pub fn new(topics: Vec<PlayTopic>, items: Vec<PlayItem>, options: PlayerOptions) -> Result<Self, NodeError> {
        if let Some(i) = items.iter().position(|i| i.topic >= topics.len()) {
            return Err(NodeError::parameter("bag", format!("message {i} names topic {} of {}", items[i].topic, topics.len())));
        }
        if items.windows(2).any(|w| w[1].log_time < w[0].log_time) {
            return Err(NodeError::parameter("bag", "messages are not in log-time order"));
        }
        Ok(Self { topics, items, options, next: 0, start: None, last_clock: None, passes: 0 })
    }

    pub fn topics(&self) -> &[PlayTopic] {
        &self.topics
    }

    pub fn items(&self) -> &[PlayItem] {
        &self.items
    }

    /// Messages published so far in this pass.
    pub fn position(&self) -> usize {
        self.next
    }

    /// Completed passes (with `looped`).
    pub fn passes(&self) -> u64 {
        self.passes
    }

    /// The wall time message `index` is due in this pass.
    fn due(&self, index: usize, (w0, b0): (Stamp, u64)) -> Stamp {
        match self.options.rate {
            Rate::Fast => w0,
            Rate::Factor(r) => Stamp(w0.0.saturating_add(((self.items[index].log_time - b0) as f64 / r).ceil() as i64)),
        }
    }

    /// The step at wall time `wall` (which must not go backwards).
    pub fn step(&mut self, wall: Stamp) -> Step {
        let Some(first) = self.items.first() else {
            return Step { clock: None, publish: 0..0, next_wall: wall, finished: true };
        };
        if self.next == self.items.len() {
            if !self.options.looped {
                return Step { clock: None, publish: self.next..self.next, next_wall: wall, finished: true };
            }
            self.next = 0;
            self.start = None;
            self.last_clock = None;
            self.passes += 1;
        }
        let start = *self.start.get_or_insert((wall, first.log_time));
        let begin = self.next;
        let limit = match self.options.rate {
            Rate::Fast => (begin + self.options.fast_batch.max(1)).min(self.items.len()),
            Rate::Factor(_) => self.items.len(),
        };
        while self.next < limit && self.due(self.next, start) <= wall {
            self.next += 1;
        }
        let publish = begin..self.next;
        let last_log = self.items[self.items.len() - 1].log_time;
        // The bag's time now: the log time the wall clock has reached, never behind a
        // message about to be published, never past the last message.
        let bag_now = match self.options.rate {
            Rate::Fast => publish.end.checked_sub(1).map(|i| self.items[i].log_time),
            Rate::Factor(r) => Some((start.1 + ((wall.0 - start.0 .0).max(0) as f64 * r) as u64).min(last_log)),
        };
        let bag_now = bag_now.map(|t| match publish.end.checked_sub(1) {
            Some(i) if !publish.is_empty() => t.max(self.items[i].log_time),
            _ => t,
        });
        let tick_due = self.last_clock.is_none_or(|(w, _)| wall.0 - w.0 >= self.options.clock_period_ns);
        let clock = match bag_now {
            Some(t) if !publish.is_empty() || tick_due => {
                let t = self.last_clock.map_or(t, |(_, prev)| t.max(prev));
                self.last_clock = Some((wall, t));
                Some(Stamp(i64::try_from(t).unwrap_or(i64::MAX)).to_time())
            }
            _ => None,
        };
        let finished = self.next == self.items.len() && !self.options.looped;
        let next_wall = if self.next < self.items.len() {
            let message = self.due(self.next, start);
            let tick = self.last_clock.map_or(wall, |(w, _)| Stamp(w.0 + self.options.clock_period_ns));
            if matches!(self.options.rate, Rate::Fast) {
                wall
            } else {
                message.min(tick)
            }
        } else {
            wall
        };
        Step { clock, publish, next_wall, finished }
    }
}

/// Publishes a step: `/clock` first, then the messages on their topics' ports.
pub fn publish_step(core: &PlayerCore, step: &Step, ports: &mut [Output<'_, RawCdr>], clock: Option<&mut dyn Publish<Clock>>) -> Result<(), NodeError> {
    if let (Some(c), Some(port)) = (step.clock.clone(), clock) {
        port.publish(Clock { clock: c })?;
    }
    for item in &core.items[step.publish.clone()] {
        let port = ports.get_mut(item.topic).ok_or_else(|| NodeError::Closed(core.topics[item.topic].name.clone()))?;
        port.publish(item.data.clone())?;
    }
    Ok(())
}

/// How long a reliable reader may take to acknowledge, at the end, what was played.
const LAST_ACK: std::time::Duration = std::time::Duration::from_secs(5);

/// Where the player is.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    /// Waiting (since then) for a subscriber on every topic, at most `wait_s`.
    Waiting(Option<Stamp>),
    /// Subscribers found: the readers learn of the writers about when the writers learn of
    /// them, so a moment more, until then.
    Settling(Stamp),
    /// Playing since then (the origin of the core's wall clock); with a fast batch still to
    /// be acknowledged.
    Playing { origin: Stamp, unacknowledged: bool },
}

/// The player node: a bag on its topics, with `/clock`.
pub struct Player {
    core: PlayerCore,
    bag: String,
    wait_s: f64,
    clock: bool,
    phase: Phase,
}

pub struct PlayerPorts<'a> {
    /// One per topic, in the core's topic order.
    pub topics: Vec<Output<'a, RawCdr>>,
    pub clock: Option<Output<'a, Clock>>,
}

impl Player {
    pub fn core(&self) -> &PlayerCore {
        &self.core
    }

    fn fast(&self) -> bool {
        matches!(self.core.options.rate, Rate::Fast)
    }
}

impl Node for Player {
    const NAME: &'static str = "player";
    type Params = PlayerParams;
    const CLOCK_SOURCE: Option<&'static str> = Some("the player publishes /clock itself (the bag's log time)");
    type Ports<'a> = PlayerPorts<'a>;

    fn new(params: &PlayerParams, _start: &Start) -> Result<Self, NodeError> {
        let options = params.options()?;
        let bag = oilfilm_bag::Bag::open(&params.bag)?;
        let info = bag.info().clone();
        let qos_of = |name: &str| {
            info.topics_with_message_count.iter().find(|t| t.topic_metadata.name == name).and_then(|t| t.topic_metadata.offered_qos_profiles.first().copied())
        };
        let (topics, items) = play_list(bag.messages()?, &params.topics, &qos_of)?;
        let core = PlayerCore::new(topics, items, options)?;
        Ok(Self { core, bag: params.bag.clone(), wait_s: params.wait_s, clock: params.clock, phase: Phase::Waiting(None) })
    }

    /// Each topic with the QoS it was recorded with; fast: reliable, and every sample kept
    /// until acknowledged (a batch must fit the writer's history).
    fn connect<C: Connect>(&self, c: &mut C) -> Result<PlayerPorts<'static>, NodeError> {
        let fast = self.fast();
        let mut topics = Vec::new();
        for t in self.core.topics() {
            let mut qos = t.qos.unwrap_or_else(|| QosProfile::keep_last(10, true, false));
            if fast {
                qos = QosProfile { reliability: oilfilm_bag::metadata::Reliability::Reliable, history: oilfilm_bag::metadata::History::KeepAll, ..qos };
            }
            topics.push(c.raw_output(&RawTopic { name: t.name.clone(), type_name: t.type_name.clone(), qos })?);
        }
        let clock = if self.clock { Some(c.output(&crate::topics::CLOCK)?) } else { None };
        Ok(PlayerPorts { topics, clock })
    }

    fn turn(&mut self, now: Stamp, ports: &mut PlayerPorts<'_>) -> Result<Turn, NodeError> {
        let fast = self.fast();
        match self.phase {
            Phase::Waiting(since) => {
                let since = since.unwrap_or(now);
                let waiting: Vec<usize> = (0..ports.topics.len()).filter(|&i| ports.topics[i].readers() == Some(0)).collect();
                if !waiting.is_empty() && now.seconds_since(since) < self.wait_s {
                    self.phase = Phase::Waiting(Some(since));
                    return Ok(Turn { wake: Some(Stamp(now.0 + 20_000_000)), ..Turn::default() });
                }
                for i in waiting {
                    tracing::warn!(node = Self::NAME, "no subscriber on {} after {} s: playing anyway", self.core.topics()[i].name, self.wait_s);
                }
                let until = Stamp(now.0 + 200_000_000);
                self.phase = Phase::Settling(until);
                Ok(Turn { wake: Some(until), ..Turn::default() })
            }
            Phase::Settling(until) if now < until => Ok(Turn { wake: Some(until), ..Turn::default() }),
            Phase::Settling(_) => {
                tracing::info!(node = Self::NAME, "playing {} message(s) on {} topic(s) from {}", self.core.items().len(), self.core.topics().len(), self.bag);
                self.phase = Phase::Playing { origin: now, unacknowledged: false };
                self.turn(now, ports)
            }
            Phase::Playing { origin, unacknowledged } => {
                if unacknowledged {
                    // Reliable readers acknowledge a batch before the next: nothing is dropped.
                    for port in &mut ports.topics {
                        if !port.flush(std::time::Duration::from_secs(1))? {
                            return Ok(Turn::default());
                        }
                    }
                    self.phase = Phase::Playing { origin, unacknowledged: false };
                }
                let step = self.core.step(Stamp(now.0 - origin.0));
                publish_step(&self.core, &step, &mut ports.topics, ports.clock.as_mut().map(|c| c.as_mut() as &mut dyn Publish<Clock>))?;
                let handled = step.publish.len() + usize::from(step.clock.is_some());
                if fast && !step.publish.is_empty() {
                    self.phase = Phase::Playing { origin, unacknowledged: true };
                }
                Ok(Turn { handled, finished: step.finished, wake: Some(Stamp(origin.0 + step.next_wall.0)) })
            }
        }
    }

    /// Reliable readers get the last messages before the writers go.
    fn finish(&mut self, _now: Stamp, ports: &mut PlayerPorts<'_>) -> Result<(), NodeError> {
        tracing::info!(
            node = Self::NAME,
            "played {} message(s), {} full pass(es)",
            self.core.position(),
            self.core.passes() + u64::from(self.core.position() == self.core.items().len())
        );
        for port in &mut ports.topics {
            if !port.flush(LAST_ACK).unwrap_or(false) {
                tracing::warn!(node = Self::NAME, "a reader did not acknowledge the last messages within {} s", LAST_ACK.as_secs());
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ports::memory::Bus;
    use crate::ports::Receive;

    const S: i64 = 1_000_000_000;

    fn core(rate: Rate, looped: bool) -> PlayerCore {
        let topics = vec![
            PlayTopic { name: "/oilfilm/daq/frames".into(), type_name: "oilfilm_msgs/msg/DaqFrame".into(), qos: None },
            PlayTopic { name: "/oilfilm/rig/status".into(), type_name: "oilfilm_msgs/msg/RigStatus".into(), qos: None },
        ];
        // Log times 1000 s + 0, 0.1, 0.2, 0.2, 1.0 s.
        let at = [0, 100_000_000, 200_000_000, 200_000_000, 1_000_000_000];
        let items =
            at.iter().enumerate().map(|(k, &dt)| PlayItem { topic: k % 2, log_time: 1000 * S as u64 + dt, data: RawCdr(vec![0, 1, 0, 0, k as u8]) }).collect();
        PlayerCore::new(topics, items, PlayerOptions { rate, looped, clock_period_ns: 10_000_000, fast_batch: 2 }).unwrap()
    }

    fn ns(t: Time) -> i64 {
        Stamp::from_time(&t).0
    }

    #[test]
    fn real_time_pacing_publishes_each_message_when_due_with_clock_first() {
        let mut c = core(Rate::Factor(1.0), false);
        let w0 = Stamp(5 * S);
        let s = c.step(w0);
        assert_eq!(s.publish, 0..1);
        assert_eq!(ns(s.clock.unwrap()), 1000 * S);
        assert_eq!(s.next_wall, Stamp(w0.0 + 10_000_000), "the next clock tick comes before the next message");
        // 50 ms later: a clock tick at log time + 50 ms, no message.
        let s = c.step(Stamp(w0.0 + 50_000_000));
        assert_eq!((s.publish.clone(), ns(s.clock.unwrap())), (1..1, 1000 * S + 50_000_000));
        // 5 ms later: no tick due, nothing due.
        let s = c.step(Stamp(w0.0 + 55_000_000));
        assert_eq!((s.publish.clone(), s.clock), (1..1, None));
        // 0.2 s: three messages due (0.1, 0.2, 0.2), clock at 0.2 s.
        let s = c.step(Stamp(w0.0 + 200_000_000));
        assert_eq!(s.publish, 1..4);
        assert_eq!(ns(s.clock.unwrap()), 1000 * S + 200_000_000);
        assert!(!s.finished);
        // Just before 1 s: not yet; at 1 s: the last one, finished.
        assert_eq!(c.step(Stamp(w0.0 + S - 1)).publish, 4..4);
        let s = c.step(Stamp(w0.0 + S));
        assert_eq!(s.publish, 4..5);
        assert_eq!(ns(s.clock.unwrap()), 1001 * S);
        assert!(s.finished);
        assert!(c.step(Stamp(w0.0 + 2 * S)).finished);
    }

    #[test]
    fn rate_factor_scales_the_wall_time_and_the_clock() {
        let mut c = core(Rate::Factor(4.0), false);
        let w0 = Stamp(0);
        assert_eq!(c.step(w0).publish, 0..1);
        // 25 ms of wall time = 100 ms of log time: message 1 due; the clock says 0.1 s.
        let s = c.step(Stamp(25_000_000));
        assert_eq!(s.publish, 1..2);
        assert_eq!(ns(s.clock.unwrap()), 1000 * S + 100_000_000);
        // The next message (log 0.2 s) is due at 50 ms of wall time; the tick at 35 ms.
        assert_eq!(s.next_wall, Stamp(35_000_000));
        let s = c.step(Stamp(36_000_000));
        assert_eq!((s.publish.clone(), ns(s.clock.unwrap())), (2..2, 1000 * S + 144_000_000));
        // Half speed: the 1 s message is due at 2 s of wall time.
        let mut h = core(Rate::Factor(0.5), false);
        h.step(Stamp(0));
        assert_eq!(h.step(Stamp(2 * S - 1)).publish.end, 4);
        assert_eq!(h.step(Stamp(2 * S)).publish, 4..5);
    }

    #[test]
    fn fast_mode_publishes_everything_in_batches_in_order_and_loops() {
        let mut c = core(Rate::Fast, false);
        let mut got = Vec::new();
        let mut clocks = Vec::new();
        for _ in 0..10 {
            let s = c.step(Stamp(0));
            got.extend(s.publish.clone());
            if let Some(t) = s.clock {
                clocks.push(ns(t));
            }
            assert!(s.publish.len() <= 2, "batches of fast_batch");
            if s.finished {
                break;
            }
        }
        assert_eq!(got, [0, 1, 2, 3, 4]);
        // The clock after each batch is the log time of its last message.
        assert_eq!(clocks, [1000 * S + 100_000_000, 1000 * S + 200_000_000, 1001 * S]);

        let mut l = core(Rate::Fast, true);
        let mut n = 0;
        for _ in 0..9 {
            let s = l.step(Stamp(0));
            n += s.publish.len();
            assert!(!s.finished);
        }
        assert_eq!(n, 15, "three passes of 5 when looping");
        assert_eq!(l.passes(), 2);
    }

    #[test]
    fn published_bytes_and_clock_reach_the_ports_in_order() {
        let mut c = core(Rate::Factor(1.0), false);
        let (frames, status, clock) = (Bus::<RawCdr>::new(), Bus::<RawCdr>::new(), Bus::<Clock>::new());
        let (mut sf, mut ss, mut sc) = (frames.subscriber(), status.subscriber(), clock.subscriber());
        let mut ports: Vec<Box<dyn Publish<RawCdr>>> = vec![Box::new(frames.publisher()), Box::new(status.publisher())];
        let mut cp = clock.publisher();
        for w in [0, 100_000_000, 250_000_000, S] {
            let s = c.step(Stamp(w));
            publish_step(&c, &s, &mut ports, Some(&mut cp as &mut dyn Publish<Clock>)).unwrap();
        }
        let f: Vec<u8> = sf.drain().iter().map(|m| m.0[4]).collect();
        let st: Vec<u8> = ss.drain().iter().map(|m| m.0[4]).collect();
        assert_eq!((f, st), (vec![0, 2, 4], vec![1, 3]));
        let clocks: Vec<i64> = std::iter::from_fn(|| sc.receive().unwrap()).map(|c| ns(c.clock)).collect();
        assert_eq!(clocks, [1000 * S, 1000 * S + 100_000_000, 1000 * S + 250_000_000, 1001 * S]);
    }

    #[test]
    fn parameters_are_checked() {
        let p = PlayerParams { bag: "b".into(), rate: 0.0, ..Default::default() };
        assert!(p.options().unwrap_err().to_string().contains("rate"));
        let p = PlayerParams { bag: "b".into(), rate: 0.0, fast: true, ..Default::default() };
        assert_eq!(p.options().unwrap().rate, Rate::Fast);
        assert!(PlayerParams::default().options().unwrap_err().to_string().contains("bag"));
        let p: PlayerParams = serde_json::from_value(serde_json::json!({"bag": "x", "loop": true, "clock_hz": 50.0})).unwrap();
        assert!(p.looped);
        assert_eq!(p.options().unwrap().clock_period_ns, 20_000_000);
    }
}
