//! The node binaries' `main`s: parse the ROS arguments and typed parameters, build the core,
//! connect its ports to DDS and turn [`crate::poll`] until SIGINT/SIGTERM.

use std::cell::Cell;
use std::io::{BufRead, BufReader, ErrorKind};
use std::net::{TcpStream, ToSocketAddrs};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use oilfilm_identification::simulate::limits_of;
use oilfilm_physics::config::RigConfig;
use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::conditioner::{ConditionerCore, ConditionerParams};
use crate::daq::{DaqParams, SimDaqCore};
use crate::dds::{init_logging, shutdown_flag, RosNode};
use crate::error::NodeError;
use crate::estimator::{EstimatorCore, EstimatorParams};
use crate::exciter::{ExciterCore, ExciterParams};
use crate::params::{self, NodeArgs};
use crate::poll::{self, ConditionerPorts, DaqPorts, EstimatorPorts, ExciterPorts, Pace, SimDaqState};
use crate::player::{self, PlayerCore, PlayerParams, Rate};
use crate::ports::{Publish, RawCdr, Receive};
use crate::recorder::{self, RecorderCore, RecorderParams};
use crate::replay::{Produced, ReplayCore};
use crate::stamp::Stamp;
use crate::topics;

/// Idle wait of a loop turn that found nothing to do.
const IDLE: Duration = Duration::from_micros(500);

/// The rig file a `rig` parameter names (empty: the built-in Zhou et al. rig).
pub fn load_rig(path: &str) -> Result<RigConfig, NodeError> {
    if path.is_empty() {
        return Ok(RigConfig::zhou2004()?);
    }
    let text = std::fs::read_to_string(path).map_err(|e| NodeError::File { file: path.into(), reason: e.to_string() })?;
    Ok(RigConfig::from_toml_str(&text, path)?)
}

fn setup<P: DeserializeOwned + Serialize + Default>(name: &str) -> Result<(NodeArgs, P, serde_json::Map<String, serde_json::Value>), NodeError> {
    init_logging();
    let args = params::parse_args(name, std::env::args().skip(1))?;
    let (p, map) = params::load::<P>(&args)?;
    tracing::info!(node = %args.fully_qualified_name(), domain = crate::dds::domain_id()?, "starting");
    Ok((args, p, map))
}

pub fn exciter_main() -> Result<(), NodeError> {
    let (args, p, map) = setup::<ExciterParams>("exciter")?;
    let rig = load_rig(&p.rig)?;
    let hard = limits_of(&rig);
    let mut core = ExciterCore::new(hard, &p)?;
    let validate = Box::new(move |m: &serde_json::Map<String, serde_json::Value>| {
        let p: ExciterParams = params::typed(m).map_err(|e| e.to_string())?;
        p.validate(&hard).map_err(|e| e.to_string())
    });
    let mut ros = RosNode::new(&args, &map, validate)?;
    let mut requests = ros.subscription(&topics::EXCITER_REQUEST)?;
    let mut status = ros.subscription(&topics::RIG_STATUS)?;
    let mut commands = ros.publisher(&topics::EXCITER_COMMAND)?;
    let stop = shutdown_flag()?;
    while !stop.load(Ordering::SeqCst) {
        if let Some(m) = ros.parameter_change() {
            match params::typed::<ExciterParams>(&m).and_then(|p| core.set_params(&p)) {
                Ok(()) => tracing::info!("parameters changed: plan {:?}, limit {} N", core.plan().exciters, core.limits().max_force_n),
                Err(e) => tracing::warn!("parameter change not applied: {e}"),
            }
        }
        let turn = poll::exciter(&mut core, &mut ExciterPorts { requests: &mut requests, status: &mut status, commands: &mut commands })?;
        if turn.handled == 0 {
            std::thread::sleep(IDLE);
        }
    }
    // Safe stop: ramp both exciters to zero and hold.
    if let Some(cmd) = core.shutdown() {
        tracing::info!("stopping: ramp to zero over {} setpoints", cmd.force_1_n.len());
        commands.publish(cmd)?;
        std::thread::sleep(Duration::from_millis(200));
    }
    // Entities go before their participant, or DDS cannot remove them cleanly.
    drop((requests, status, commands));
    ros.shutdown();
    Ok(())
}

/// Accepts the values the node started with (ros2-client validates declarations too) and
/// refuses any change.
fn read_only(node: &'static str, initial: serde_json::Map<String, serde_json::Value>) -> crate::dds::Validator {
    Box::new(move |m| {
        if *m == initial {
            Ok(())
        } else {
            Err(format!("the {node} node's parameters are read-only while it runs: restart it with new ones"))
        }
    })
}

/// Frames published before a subscriber is discovered are lost to it (volatile topic): give
/// the graph up to 10 s to come up, then go on regardless (a DAQ does not wait for ever).
fn wait_for_conditioner(ros: &RosNode) {
    if !ros.wait_for_subscribers(&topics::DAQ_FRAMES, Duration::from_secs(10)) {
        tracing::warn!("no subscriber on {} after 10 s: publishing anyway", topics::DAQ_FRAMES.name);
    }
}

pub fn daq_main() -> Result<(), NodeError> {
    let (args, p, map) = setup::<DaqParams>("daq")?;
    p.validate()?;
    let rig = load_rig(&p.rig)?;
    if p.source == "ascii" || p.source == "tcp" {
        // The line sources: an ASCII record replayed, or a TCP stream in the same format.
        let (kind, name) = if p.source == "ascii" { ("ascii replay", p.file.clone()) } else { ("tcp stream", format!("tcp://{}", p.address)) };
        let mut core = ReplayCore::new(&rig, &p, kind, &name)?;
        let file = if p.source == "ascii" {
            Some(std::fs::File::open(&p.file).map_err(|e| NodeError::Io { what: format!("ascii record `{}`", p.file), source: e })?)
        } else {
            None
        };
        let mut ros = RosNode::new(&args, &map, read_only("daq", map.clone()))?;
        let mut frames = ros.publisher(&topics::DAQ_FRAMES)?;
        let mut status = ros.publisher(&topics::RIG_STATUS)?;
        wait_for_conditioner(&ros);
        let stop = shutdown_flag()?;
        let stopped = || stop.load(Ordering::SeqCst);
        let mut emit = |out: Produced| -> Result<(), NodeError> {
            for (frame, rig_status) in out.frames {
                frames.publish(frame)?;
                status.publish(rig_status)?;
            }
            Ok(())
        };
        match file {
            Some(file) => {
                let pace = ReplayPace { rate_factor: p.rate_factor, duration_s: p.duration_s };
                run_ascii_source(BufReader::new(file), &mut core, &pace, &stopped, &mut emit)?;
                tracing::info!(
                    "{}: replay finished: {} frame(s), {} malformed row(s) skipped, {} gap(s)",
                    p.file,
                    core.frames(),
                    core.malformed_rows(),
                    core.gaps()
                );
                // Give reliable readers a moment to take the last frames.
                std::thread::sleep(Duration::from_millis(500));
            }
            None => {
                let backoff = Backoff { initial: Duration::from_millis(100), max: Duration::from_secs(5) };
                run_tcp_source(&p.address, &mut core, &backoff, &stopped, &mut emit)?;
            }
        }
        drop((frames, status));
        ros.shutdown();
        return Ok(());
    }
    let epoch = if p.start_stamp_ns != 0 { Stamp(p.start_stamp_ns) } else { Stamp::now() };
    let mut core = SimDaqCore::new(&rig, &p, epoch)?;
    let mut ros = RosNode::new(&args, &map, read_only("daq", map.clone()))?;
    let mut commands = ros.subscription(&topics::EXCITER_COMMAND)?;
    let mut frames = ros.publisher(&topics::DAQ_FRAMES)?;
    let mut status = ros.publisher(&topics::RIG_STATUS)?;
    wait_for_conditioner(&ros);
    let stop = shutdown_flag()?;
    let pace = Pace { rate_factor: p.rate_factor, wall_start: Stamp::now(), command_timeout_s: p.command_timeout_s, duration_s: p.duration_s };
    let mut state = SimDaqState::default();
    while !stop.load(Ordering::SeqCst) {
        let turn = poll::sim_daq(&mut core, &mut state, &mut DaqPorts { commands: &mut commands, frames: &mut frames, status: &mut status }, &pace, Stamp::now())?;
        if turn.finished {
            tracing::info!("duration reached: {} s of rig time", p.duration_s);
            // Give reliable readers a moment to take the last frames.
            std::thread::sleep(Duration::from_millis(500));
            break;
        }
        if turn.handled == 0 {
            std::thread::sleep(IDLE);
        }
    }
    drop((commands, frames, status));
    ros.shutdown();
    Ok(())
}

pub fn conditioner_main() -> Result<(), NodeError> {
    let (args, p, map) = setup::<ConditionerParams>("conditioner")?;
    let rig = load_rig(&p.rig)?;
    let mut core = ConditionerCore::new(rig, &p)?;
    let mut ros = RosNode::new(&args, &map, read_only("conditioner", map.clone()))?;
    let mut frames = ros.subscription(&topics::DAQ_FRAMES)?;
    let mut conditioned = ros.publisher(&topics::CONDITIONED)?;
    let stop = shutdown_flag()?;
    while !stop.load(Ordering::SeqCst) {
        let turn = poll::conditioner(&mut core, &mut ConditionerPorts { frames: &mut frames, conditioned: &mut conditioned })?;
        if turn.handled == 0 {
            std::thread::sleep(IDLE);
        }
    }
    drop((frames, conditioned));
    ros.shutdown();
    Ok(())
}

pub fn estimator_main() -> Result<(), NodeError> {
    let (args, p, map) = setup::<EstimatorParams>("estimator")?;
    let rig = load_rig(&p.rig)?;
    let mut core = EstimatorCore::new(rig, p)?;
    let validate = Box::new(|m: &serde_json::Map<String, serde_json::Value>| {
        let p: EstimatorParams = params::typed(m).map_err(|e| e.to_string())?;
        p.config(5000.0).map(|_| ()).map_err(|e| e.to_string())
    });
    let mut ros = RosNode::new(&args, &map, validate)?;
    let mut conditioned = ros.subscription(&topics::CONDITIONED)?;
    let mut status = ros.subscription(&topics::RIG_STATUS)?;
    let mut estimates = ros.publisher(&topics::ESTIMATES)?;
    let stop = shutdown_flag()?;
    while !stop.load(Ordering::SeqCst) {
        if let Some(m) = ros.parameter_change() {
            match params::typed::<EstimatorParams>(&m).and_then(|p| core.set_params(p)) {
                Ok(()) => tracing::info!("parameters changed: window {}, hop {}", core.params().window, core.params().hop),
                Err(e) => tracing::warn!("parameter change not applied: {e}"),
            }
        }
        let turn = poll::estimator(&mut core, &mut EstimatorPorts { conditioned: &mut conditioned, status: &mut status, estimates: &mut estimates })?;
        if turn.handled == 0 {
            std::thread::sleep(IDLE);
        }
    }
    drop((conditioned, status, estimates));
    ros.shutdown();
    Ok(())
}

/// The `recorder` node: `oilfilm-recorder --ros-args -p output:=DIR ...`.
pub fn recorder_main() -> Result<(), NodeError> {
    let (args, p, map) = setup::<RecorderParams>("recorder")?;
    run_recorder(&args, &p, &map).map(|_| ())
}

/// Records `p.topics` under `args.namespace` to a bag until SIGINT/SIGTERM, then closes it
/// (metadata.yaml written). The node and `oilfilm record` both run this. Returns the bag.
pub fn run_recorder(args: &NodeArgs, p: &RecorderParams, map: &serde_json::Map<String, serde_json::Value>) -> Result<std::path::PathBuf, NodeError> {
    let options = p.writer_options()?;
    let topics = recorder::select_topics(&args.namespace, &p.topics)?;
    let dir = p.output_dir(Stamp::now());
    let writer = oilfilm_bag::BagWriter::create(&dir, options)?;
    let mut core = RecorderCore::new(writer, topics)?;
    let mut ros = RosNode::new(args, map, read_only("recorder", map.clone()))?;
    let mut inputs: Vec<Box<dyn Receive<RawCdr>>> = Vec::new();
    for t in core.topics().to_vec() {
        // The publisher's reliability and durability (so they match), but a deep history:
        // a burst (a fast replay) must wait in the reader rather than push older samples out.
        let qos = ros2_client::QosProfile { history: ros2_client::qos::History::KeepLast { depth: 10_000 }, ..crate::dds::qos_from(t.qos) };
        inputs.push(Box::new(ros.raw_subscription(&t.name, &t.type_name, qos)?));
    }
    let stop = shutdown_flag()?;
    tracing::info!("recording {} topic(s) to {}", core.topics().len(), dir.display());
    let started = Instant::now();
    let period = Duration::from_secs_f64(p.status_period_s.max(0.0));
    let (mut last_status, mut last_bytes) = (Instant::now(), 0_u64);
    let clock = Stamp::now;
    let result = (|| -> Result<(), NodeError> {
        while !stop.load(Ordering::SeqCst) {
            let taken = recorder::poll(&mut core, &mut inputs, &clock)?;
            if !period.is_zero() && last_status.elapsed() >= period {
                let dt = last_status.elapsed().as_secs_f64();
                let rate = (core.stats().bytes - last_bytes) as f64 * 1e-6 / dt;
                eprintln!("{}", recorder::status_line(core.stats(), core.topics(), started.elapsed().as_secs_f64(), rate));
                (last_status, last_bytes) = (Instant::now(), core.stats().bytes);
            }
            if taken == 0 {
                std::thread::sleep(IDLE);
            }
        }
        // What arrived before the signal is kept.
        recorder::poll(&mut core, &mut inputs, &clock)?;
        Ok(())
    })();
    drop(inputs);
    let stats = core.stats().clone();
    let topics = core.topics().to_vec();
    // Close the bag even when recording failed, so what was written stays readable.
    let closed = core.close();
    ros.shutdown();
    result?;
    let dir = closed?;
    eprintln!("{}", recorder::status_line(&stats, &topics, started.elapsed().as_secs_f64(), 0.0));
    tracing::info!("closed {} ({} messages)", dir.display(), stats.messages);
    Ok(dir)
}

/// How long a reliable reader may take to send its first acknowledgment (see `run_player`).
const FIRST_ACK: Duration = Duration::from_millis(500);

/// The `player` node: `oilfilm-player --ros-args -p bag:=DIR ...`.
pub fn player_main() -> Result<(), NodeError> {
    let (args, p, map) = setup::<PlayerParams>("player")?;
    run_player(&args, &p, &map)
}

/// Plays a bag on DDS (see [`crate::player`]); the node and `oilfilm play` both run this.
/// Returns at the end of the bag (never with `loop`) or on SIGINT/SIGTERM.
pub fn run_player(args: &NodeArgs, p: &PlayerParams, map: &serde_json::Map<String, serde_json::Value>) -> Result<(), NodeError> {
    let options = p.options()?;
    let bag = oilfilm_bag::Bag::open(&p.bag)?;
    let info = bag.info().clone();
    let qos_of = |name: &str| {
        info.topics_with_message_count.iter().find(|t| t.topic_metadata.name == name).and_then(|t| t.topic_metadata.offered_qos_profiles.first().copied())
    };
    let (topics, items) = player::play_list(bag.messages()?, &p.topics, &qos_of)?;
    let fast = matches!(options.rate, Rate::Fast);
    let mut core = PlayerCore::new(topics, items, options)?;
    let mut ros = RosNode::new(args, map, read_only("player", map.clone()))?;
    let mut writers = Vec::new();
    for t in core.topics() {
        let default = oilfilm_bag::QosProfile::keep_last(10, true, false);
        let mut qos = crate::dds::qos_from_bag(t.qos.as_ref().unwrap_or(&default), fast);
        if fast {
            // A batch must fit the writer's history, or unacknowledged samples are replaced.
            qos.history = ros2_client::qos::History::KeepAll;
        }
        writers.push(ros.raw_publisher(&t.name, &t.type_name, qos)?);
    }
    let clock_qos = crate::dds::qos_from(topics::TopicQos { reliable: true, depth: 1, transient_local: false });
    let mut clock = if p.clock { Some(ros.publisher_named::<oilfilm_msgs::Clock>("/clock", "rosgraph_msgs/msg/Clock", clock_qos)?) } else { None };
    let stop = shutdown_flag()?;
    // Like the DAQ: what is published before a reader is discovered is lost to it.
    let deadline = Instant::now() + Duration::from_secs_f64(p.wait_s);
    for (t, w) in core.topics().iter().zip(writers.iter_mut()) {
        while w.matched() == 0 && Instant::now() < deadline && !stop.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(20));
        }
        if w.matched() == 0 {
            tracing::warn!("no subscriber on {} after {} s: playing anyway", t.name, p.wait_s);
        }
    }
    // The readers learn of the writers about when the writers learn of them: a moment more.
    std::thread::sleep(Duration::from_millis(200));
    tracing::info!("playing {} message(s) on {} topic(s) from {}", core.items().len(), core.topics().len(), p.bag);
    let origin = Instant::now();
    let wall = || Stamp(i64::try_from(origin.elapsed().as_nanos()).unwrap_or(i64::MAX));
    let result = (|| -> Result<(), NodeError> {
        let mut ports: Vec<Box<dyn Publish<RawCdr> + '_>> = writers.iter_mut().map(|w| Box::new(w) as Box<dyn Publish<RawCdr> + '_>).collect();
        while !stop.load(Ordering::SeqCst) {
            let step = core.step(wall());
            player::publish_step(&core, &step, &mut ports, clock.as_mut().map(|c| c as &mut dyn Publish<oilfilm_msgs::Clock>))?;
            if step.finished {
                break;
            }
            if fast && !step.publish.is_empty() {
                drop(ports);
                if step.publish.start == 0 {
                    // rustdds counts a reliable reader in its acknowledgment wait only once
                    // that reader has sent its first ACKNACK (answering a heartbeat): until
                    // then the wait returns at once. Give the first batch time for it.
                    std::thread::sleep(FIRST_ACK);
                }
                for w in &writers {
                    // Reliable readers acknowledge before the next batch: nothing is dropped.
                    while !w.wait_for_acknowledgments(Duration::from_secs(1))? && !stop.load(Ordering::SeqCst) {}
                }
                ports = writers.iter_mut().map(|w| Box::new(w) as Box<dyn Publish<RawCdr> + '_>).collect();
            }
            let left = Duration::from_nanos(u64::try_from(step.next_wall.0 - wall().0).unwrap_or(0));
            if !left.is_zero() {
                std::thread::sleep(left.min(Duration::from_millis(20)));
            }
        }
        Ok(())
    })();
    tracing::info!("played {} message(s), {} full pass(es)", core.position(), core.passes() + u64::from(core.position() == core.items().len()));
    // Give reliable readers the last messages before the writers go.
    // (The same rustdds caveat: a short run may end before the first ACKNACK.)
    std::thread::sleep(FIRST_ACK);
    for w in &writers {
        if !w.wait_for_acknowledgments(Duration::from_secs(5)).unwrap_or(false) {
            tracing::warn!("a reader did not acknowledge the last messages within 5 s");
        }
    }
    drop(writers);
    drop(clock.take());
    ros.shutdown();
    result
}

// ---------------------------------------------------------------------------------------------
// The DAQ node's line sources (ASCII replay, TCP): the I/O and the clock around
// `crate::replay::ReplayCore`.

/// How [`read_lines`] ended.
#[derive(Debug)]
pub enum LinesEnd {
    /// The end of the stream. `unterminated`: a last line that had no line end (its number
    /// and text): the end of a file may lack it; on a socket it is a line cut by the drop.
    Eof { unterminated: Option<(usize, String)> },
    /// `stop()` said so.
    Stopped,
    /// Reading failed (a connection reset); lines before it were delivered.
    Broken(std::io::Error),
}

/// The longest line kept, bytes: the rest of a longer line is dropped (so it is refused as
/// malformed rather than filling the memory).
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// Reads `stream` line by line and hands each line ended by LF (the LF, and a CR before it,
/// included), numbered from 1, to `on_line`, until the end of the stream, a read error or
/// `stop()`. A read that times out (a socket with a read timeout) only gives `stop()` a
/// chance: the part of a line read so far is kept. Bytes that are not UTF-8 become U+FFFD
/// (and the row is then refused by the reader with its column). `Err` only from `on_line`.
pub fn read_lines(mut stream: impl BufRead, stop: &dyn Fn() -> bool, on_line: &mut dyn FnMut(usize, &str) -> Result<(), NodeError>) -> Result<LinesEnd, NodeError> {
    let mut line: Vec<u8> = Vec::new();
    let mut number = 0;
    loop {
        if stop() {
            return Ok(LinesEnd::Stopped);
        }
        let (used, complete) = match stream.fill_buf() {
            Ok([]) => {
                let unterminated = (!line.is_empty()).then(|| (number + 1, String::from_utf8_lossy(&line).into_owned()));
                return Ok(LinesEnd::Eof { unterminated });
            }
            Ok(available) => {
                let (chunk, complete) = match available.iter().position(|&b| b == b'\n') {
                    Some(end) => (&available[..=end], true),
                    None => (available, false),
                };
                let room = MAX_LINE_BYTES.saturating_sub(line.len());
                line.extend_from_slice(&chunk[..chunk.len().min(room)]);
                (chunk.len(), complete)
            }
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted) => continue,
            Err(e) => return Ok(LinesEnd::Broken(e)),
        };
        stream.consume(used);
        if complete {
            number += 1;
            on_line(number, &String::from_utf8_lossy(&line))?;
            line.clear();
        }
    }
}

/// Sleeps `d`, in short slices, unless `stop()` says so.
fn sleep_unless(d: Duration, stop: &dyn Fn() -> bool) {
    let end = Instant::now().checked_add(d);
    while !stop() {
        let left = end.map_or(Duration::MAX, |end| end.saturating_duration_since(Instant::now()));
        if left.is_zero() {
            break;
        }
        std::thread::sleep(left.min(Duration::from_millis(50)));
    }
}

/// Logs the bad row of `out` (a warning `source:line:column: reason`) and hands `out` on.
fn deliver(out: Produced, emit: &mut dyn FnMut(Produced) -> Result<(), NodeError>) -> Result<(), NodeError> {
    if let Some(e) = &out.bad_row {
        tracing::warn!(node = "daq", "{e}");
    }
    emit(out)
}

/// Pacing of an ASCII replay.
#[derive(Debug, Clone, Copy)]
pub struct ReplayPace {
    /// 1 = real time from the record's sample rate, 4 = four times faster, 0 = as fast as
    /// possible.
    pub rate_factor: f64,
    /// Stop after this much rig time (0: at the end of the record).
    pub duration_s: f64,
}

/// Replays an ASCII record (the lines of `stream`) through `core`, handing each frame and
/// status to `emit` when it is due (paced on the wall clock), bad rows logged as warnings.
/// Returns after the last frame of the record, after `duration_s` of rig time or at
/// `stop()`; `Err` for a header error (the record cannot be interpreted) or from `emit`.
pub fn run_ascii_source(stream: impl BufRead, core: &mut ReplayCore, pace: &ReplayPace, stop: &dyn Fn() -> bool, emit: &mut dyn FnMut(Produced) -> Result<(), NodeError>) -> Result<(), NodeError> {
    let wall_start = Instant::now();
    let origin: Cell<Option<Stamp>> = Cell::new(None);
    let done = Cell::new(false);
    let stop_or_done = || stop() || done.get();
    // Waits until the last frame of `out` is due, emits it, and notes the end of the duration.
    let paced = |out: Produced, emit: &mut dyn FnMut(Produced) -> Result<(), NodeError>| -> Result<(), NodeError> {
        if let Some((frame, status)) = out.frames.last() {
            let first = origin.get().unwrap_or_else(|| Stamp::from_time(&frame.header.stamp));
            origin.set(Some(first));
            let rig_s = Stamp::from_time(&status.header.stamp).seconds_since(first);
            if pace.rate_factor > 0.0 {
                let due = Duration::try_from_secs_f64((rig_s / pace.rate_factor).max(0.0)).unwrap_or(Duration::MAX);
                sleep_unless(due.saturating_sub(wall_start.elapsed()), stop);
            }
            if pace.duration_s > 0.0 && rig_s >= pace.duration_s {
                done.set(true);
            }
        }
        deliver(out, emit)
    };
    let mut last_line = 0;
    let end = read_lines(stream, &stop_or_done, &mut |number, line| {
        last_line = number;
        let out = core.push_line(number, line)?;
        paced(out, emit)
    })?;
    match end {
        LinesEnd::Stopped => Ok(()),
        LinesEnd::Broken(e) => Err(NodeError::Io { what: format!("reading {}", core.source_name()), source: e }),
        LinesEnd::Eof { unterminated } => {
            // A file's last line may lack its line end.
            if let Some((number, line)) = unterminated {
                last_line = number;
                let out = core.push_line(number, &line)?;
                paced(out, emit)?;
            }
            let out = core.end_of_stream(last_line.max(1))?;
            paced(out, emit)
        }
    }
}

/// Reconnection back-off of the TCP source: `initial`, doubling up to `max`.
#[derive(Debug, Clone, Copy)]
pub struct Backoff {
    pub initial: Duration,
    pub max: Duration,
}

/// Connects to `address` (`host:port`), trying each address it resolves to.
fn connect(address: &str) -> std::io::Result<TcpStream> {
    let mut last = std::io::Error::new(ErrorKind::NotFound, "the address resolves to nothing");
    for a in address.to_socket_addrs()? {
        match TcpStream::connect_timeout(&a, Duration::from_secs(2)) {
            Ok(s) => return Ok(s),
            Err(e) => last = e,
        }
    }
    Err(last)
}

/// The TCP source: connects to `address`, reads ASCII format v1 lines through `core` and
/// hands its frames to `emit` (bad rows logged as warnings), until `stop()`. A dropped
/// connection, a refused connection or a header that cannot be interpreted is logged and
/// followed by a reconnection after the back-off (which grows while connections give no
/// header); each connection starts a new stream with its own header and line numbers,
/// labelled `tcp://address#n`. `Err` only from `emit`.
pub fn run_tcp_source(address: &str, core: &mut ReplayCore, backoff: &Backoff, stop: &dyn Fn() -> bool, emit: &mut dyn FnMut(Produced) -> Result<(), NodeError>) -> Result<(), NodeError> {
    let mut wait = backoff.initial;
    let mut connection = 0_u64;
    while !stop() {
        let stream = match connect(address) {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!(node = "daq", "tcp://{address}: cannot connect ({e}); retrying in {:.1} s", wait.as_secs_f64());
                sleep_unless(wait, stop);
                wait = (wait * 2).min(backoff.max);
                continue;
            }
        };
        connection += 1;
        let name = format!("tcp://{address}#{connection}");
        tracing::info!(node = "daq", "{name}: connected; expecting an oilfilm-ascii 1 header");
        emit(core.restart(&name))?;
        // A read timeout lets the loop see `stop()` while the acquisition is silent.
        if let Err(e) = stream.set_read_timeout(Some(Duration::from_millis(100))) {
            tracing::warn!(node = "daq", "{name}: cannot set a read timeout ({e}): stopping may wait for the next line");
        }
        let mut last_line = 0;
        let end = read_lines(BufReader::new(stream), stop, &mut |number, line| {
            last_line = number;
            let out = core.push_line(number, line)?;
            deliver(out, emit)
        });
        let refused = matches!(end, Err(NodeError::BadRecord { .. }));
        match end {
            Ok(LinesEnd::Stopped) => {}
            Ok(LinesEnd::Eof { unterminated }) => {
                if let Some((number, _)) = unterminated {
                    tracing::warn!(node = "daq", "{name}:{number}:0: the connection closed in the middle of this line: dropped");
                }
                tracing::warn!(node = "daq", "{name}: the acquisition process closed the connection");
            }
            Ok(LinesEnd::Broken(e)) => tracing::warn!(node = "daq", "{name}: connection lost: {e}"),
            Err(e @ NodeError::BadRecord { .. }) => tracing::error!(node = "daq", "{e}: the stream cannot be interpreted; dropping the connection"),
            Err(e) => return Err(e),
        }
        if core.header().is_some() {
            wait = backoff.initial;
        }
        match core.end_of_stream(last_line.max(1)) {
            Ok(out) => emit(out)?,
            // A refused header was logged above.
            Err(_) if refused => {}
            Err(e) => tracing::warn!(node = "daq", "{e}"),
        }
        if !stop() {
            tracing::info!(node = "daq", "tcp://{address}: reconnecting in {:.1} s", wait.as_secs_f64());
            sleep_unless(wait, stop);
            wait = (wait * 2).min(backoff.max);
        }
    }
    Ok(())
}
