//! The DAQ node's line sources (ASCII replay, TCP): the reading, pacing and reconnecting
//! around [`crate::replay::ReplayCore`], and [`LineDaq`], the DAQ node on them. The reading
//! blocks (a file, a socket), so it runs on a thread of its own and hands each frame to the
//! node's turns through a channel.

use std::cell::Cell;
use std::io::{BufRead, BufReader, ErrorKind};
use std::net::{TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::daq::{DaqParams, DaqPorts, READER_WAIT_S};
use crate::error::NodeError;
use crate::foreign::ForeignSource;
use crate::node::Turn;
use crate::replay::{Produced, ReplayCore};
use crate::stamp::Stamp;
use crate::topics;

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

/// The longest line kept, bytes: the rest of a longer line is dropped, and the line is
/// handed on marked as cut, to be refused ([`ReplayCore::push_cut_line`]) rather than fill
/// the memory or be read without its end.
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// Reads `stream` line by line and hands each line ended by LF (the LF, and a CR before it,
/// included), numbered from 1, to `on_line`, until the end of the stream, a read error or
/// `stop()`. The third argument says the line was longer than [`MAX_LINE_BYTES`]: only its
/// first [`MAX_LINE_BYTES`] were kept. A read that times out (a socket with a read timeout)
/// only gives `stop()` a chance: the part of a line read so far is kept. Bytes that are not
/// UTF-8 become U+FFFD (and the row is then refused by the reader with its column). `Err`
/// only from `on_line`.
pub fn read_lines(
    mut stream: impl BufRead,
    stop: &dyn Fn() -> bool,
    on_line: &mut dyn FnMut(usize, &str, bool) -> Result<(), NodeError>,
) -> Result<LinesEnd, NodeError> {
    let mut line: Vec<u8> = Vec::new();
    let mut cut = false;
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
                // The line end does not count: a line of exactly MAX_LINE_BYTES is whole.
                let content = chunk.len() - usize::from(complete);
                cut |= content > room;
                line.extend_from_slice(&chunk[..chunk.len().min(room)]);
                (chunk.len(), complete)
            }
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted) => continue,
            Err(e) => return Ok(LinesEnd::Broken(e)),
        };
        stream.consume(used);
        if complete {
            number += 1;
            on_line(number, &String::from_utf8_lossy(&line), cut)?;
            line.clear();
            cut = false;
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

/// Warnings of one kind at most once per interval, with a count of those held back: a
/// stream of garbage gives a warning a second, not one a line.
#[derive(Debug)]
pub struct WarnLimiter {
    every: Duration,
    last: Option<Instant>,
    held: u64,
}

impl WarnLimiter {
    pub fn new(every: Duration) -> Self {
        Self { every, last: None, held: 0 }
    }

    /// `Some(held back since the last one shown)` when a warning at `now` is to be shown;
    /// `None` (and counted) when it is held back.
    pub fn admit(&mut self, now: Instant) -> Option<u64> {
        match self.last {
            Some(last) if now.saturating_duration_since(last) < self.every => {
                self.held += 1;
                None
            }
            _ => {
                self.last = Some(now);
                Some(std::mem::take(&mut self.held))
            }
        }
    }

    /// The warnings held back since the last one shown (and forgets them): for a summary.
    pub fn take_held(&mut self) -> u64 {
        std::mem::take(&mut self.held)
    }
}

/// Logs the bad row of `out` (a warning `source:line:column: reason`, at most one a second
/// with the count of those held back) and hands `out` on.
fn deliver(out: Produced, warnings: &mut WarnLimiter, emit: &mut dyn FnMut(Produced) -> Result<(), NodeError>) -> Result<(), NodeError> {
    if let Some(e) = &out.bad_row {
        match warnings.admit(Instant::now()) {
            Some(0) => tracing::warn!(node = "daq", "{e}"),
            Some(held) => tracing::warn!(node = "daq", "{e} (and {held} more bad row(s) not shown since the last warning)"),
            None => {}
        }
    }
    emit(out)
}

/// Logs how many bad-row warnings `warnings` held back at the end of `name`'s stream.
fn flush_warnings(name: &str, warnings: &mut WarnLimiter) {
    let held = warnings.take_held();
    if held > 0 {
        tracing::warn!(node = "daq", "{name}: {held} more bad row(s) not shown (warnings are limited to one a second)");
    }
}

/// Frames the reading thread may hold for the node's turns. A TCP source floods it only when
/// the acquisition sends faster than the node publishes: the frames beyond it are dropped and
/// counted (the count is in `frames_dropped` of every rig status after, and warned about once
/// a second) rather than held in memory; a file replay waits for room instead.
pub const QUEUE_FRAMES: usize = 64;

/// A frame queue's sending end for a source that must not wait (TCP): a full queue drops the
/// frames of `out` and adds them to `dropped`. Output without frames is not queued.
pub struct DroppingSender {
    tx: mpsc::SyncSender<Produced>,
    dropped: Arc<AtomicU64>,
    warnings: WarnLimiter,
}

impl DroppingSender {
    pub fn new(tx: mpsc::SyncSender<Produced>, dropped: Arc<AtomicU64>) -> Self {
        Self { tx, dropped, warnings: WarnLimiter::new(Duration::from_secs(1)) }
    }

    pub fn send(&mut self, out: Produced) -> Result<(), NodeError> {
        if out.frames.is_empty() {
            return Ok(());
        }
        match self.tx.try_send(out) {
            Ok(()) => Ok(()),
            Err(mpsc::TrySendError::Full(out)) => {
                let total = self.dropped.fetch_add(out.frames.len() as u64, Ordering::SeqCst) + out.frames.len() as u64;
                if self.warnings.admit(Instant::now()).is_some() {
                    tracing::warn!(
                        node = "daq",
                        "the input arrives faster than the node publishes: {total} frame(s) dropped so far (queue of {QUEUE_FRAMES} frames full)"
                    );
                }
                Ok(())
            }
            Err(mpsc::TrySendError::Disconnected(_)) => Err(NodeError::Closed("the DAQ node stopped taking frames".into())),
        }
    }
}

/// A frame queue's receiving end, as the node's turns take from it: every status taken
/// carries in `frames_dropped` the frames the sending end ([`DroppingSender`]) has dropped
/// so far. The count is read when the node takes the frame, not when it was queued: a flood
/// drops frames while the queue is full, so the statuses of the frames still queued then
/// report those drops at once rather than only after the flood, when a new frame comes.
pub struct FrameQueue {
    frames: mpsc::Receiver<Produced>,
    dropped: Arc<AtomicU64>,
}

impl FrameQueue {
    pub fn new(frames: mpsc::Receiver<Produced>, dropped: Arc<AtomicU64>) -> Self {
        Self { frames, dropped }
    }

    /// The next output, waiting up to `wait` for it (zero: not at all).
    pub fn take(&self, wait: Duration) -> Result<Produced, mpsc::TryRecvError> {
        let mut out = if wait.is_zero() {
            self.frames.try_recv()?
        } else {
            self.frames.recv_timeout(wait).map_err(|e| match e {
                mpsc::RecvTimeoutError::Timeout => mpsc::TryRecvError::Empty,
                mpsc::RecvTimeoutError::Disconnected => mpsc::TryRecvError::Disconnected,
            })?
        };
        let dropped = self.dropped.load(Ordering::SeqCst);
        for (_, status) in &mut out.frames {
            status.frames_dropped = dropped;
        }
        Ok(out)
    }
}

/// How long a [`LineDaq`]'s turn waits for its reader when nothing is waiting: short beside
/// a DDS node's idle nap, long beside the time to read a line.
pub const READER_NAP: Duration = Duration::from_millis(1);

/// Opens an ASCII record for the line reader, plain or gzip-compressed (recognised by its
/// magic bytes, not its name, as `oilfilm identify` reads it), as a stream: the file is
/// never held whole.
pub fn open_ascii(path: &str) -> Result<Box<dyn BufRead + Send>, NodeError> {
    let io = |e| NodeError::Io { what: format!("ascii record `{path}`"), source: e };
    let file = std::fs::File::open(path).map_err(io)?;
    let mut stream = BufReader::with_capacity(1 << 16, file);
    let gzip = stream.fill_buf().map_err(io)?.starts_with(&[0x1f, 0x8b]);
    Ok(if gzip { Box::new(BufReader::with_capacity(1 << 16, flate2::bufread::MultiGzDecoder::new(stream))) } else { Box::new(stream) })
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
pub fn run_ascii_source(
    stream: impl BufRead,
    core: &mut ReplayCore,
    pace: &ReplayPace,
    stop: &dyn Fn() -> bool,
    emit: &mut dyn FnMut(Produced) -> Result<(), NodeError>,
) -> Result<(), NodeError> {
    let wall_start = Instant::now();
    let origin: Cell<Option<Stamp>> = Cell::new(None);
    let done = Cell::new(false);
    let stop_or_done = || stop() || done.get();
    let warnings = std::cell::RefCell::new(WarnLimiter::new(Duration::from_secs(1)));
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
        deliver(out, &mut warnings.borrow_mut(), emit)
    };
    let mut last_line = 0;
    let end = read_lines(stream, &stop_or_done, &mut |number, line, cut| {
        last_line = number;
        let out = if cut { core.push_cut_line(number)? } else { core.push_line(number, line)? };
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
            paced(out, emit)?;
            flush_warnings(core.source_name(), &mut warnings.borrow_mut());
            Ok(())
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
pub fn run_tcp_source(
    address: &str,
    core: &mut ReplayCore,
    backoff: &Backoff,
    stop: &dyn Fn() -> bool,
    emit: &mut dyn FnMut(Produced) -> Result<(), NodeError>,
) -> Result<(), NodeError> {
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
        let mut warnings = WarnLimiter::new(Duration::from_secs(1));
        let end = read_lines(BufReader::new(stream), stop, &mut |number, line, cut| {
            last_line = number;
            let out = if cut { core.push_cut_line(number)? } else { core.push_line(number, line)? };
            deliver(out, &mut warnings, emit)
        });
        flush_warnings(&name, &mut warnings);
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

/// The reading thread of a [`LineDaq`].
struct Reader {
    /// What the thread read; the statuses say how many frames a TCP source dropped because
    /// the queue was full.
    frames: FrameQueue,
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<Result<ReplayCore, NodeError>>,
}

/// What a [`LineDaq`] reads.
enum Source {
    /// An ASCII record, plain or gzip-compressed (recognised by its magic bytes).
    Ascii(Box<dyn BufRead + Send>),
    Tcp(String),
    /// A TDMS, .mat or CSV record through its channel map (it has no lines: the reading
    /// thread runs [`run_foreign_source`] instead of the line reader).
    Foreign(Box<ForeignSource>),
}

/// Replays a foreign record's frames (each with its status) to `emit`, paced as an ASCII
/// replay is. Returns at the end of the record, after `duration_s` of rig time or at
/// `stop()`; `Err` when the record turns out unreadable (the error names the file, the
/// channel and the scan) or from `emit`.
pub fn run_foreign_source(
    source: &mut ForeignSource,
    pace: &ReplayPace,
    stop: &dyn Fn() -> bool,
    emit: &mut dyn FnMut(Produced) -> Result<(), NodeError>,
) -> Result<(), NodeError> {
    let wall_start = Instant::now();
    let mut origin: Option<Stamp> = None;
    while !stop() {
        let Some((frame, status)) = source.next_frame()? else { break };
        let first = *origin.get_or_insert_with(|| Stamp::from_time(&frame.header.stamp));
        let rig_s = Stamp::from_time(&status.header.stamp).seconds_since(first);
        if pace.rate_factor > 0.0 {
            let due = Duration::try_from_secs_f64((rig_s / pace.rate_factor).max(0.0)).unwrap_or(Duration::MAX);
            sleep_unless(due.saturating_sub(wall_start.elapsed()), stop);
        }
        emit(Produced { frames: vec![(frame, status)], bad_row: None })?;
        if pace.duration_s > 0.0 && rig_s >= pace.duration_s {
            break;
        }
    }
    tracing::info!(node = "daq", "{}: replay finished: {} frame(s)", source.record().path.display(), source.frames());
    Ok(())
}

/// The DAQ node on a line source (`source: ascii` or `tcp`).
pub struct LineDaq {
    params: DaqParams,
    /// The core and its source until reading starts.
    idle: Option<(ReplayCore, Source)>,
    reader: Option<Reader>,
    reader_wait: Option<Stamp>,
}

impl LineDaq {
    pub fn params(&self) -> &DaqParams {
        &self.params
    }

    pub fn new(params: &DaqParams, rig: &oilfilm_physics::config::RigConfig) -> Result<Self, NodeError> {
        let (kind, name) = match params.source.as_str() {
            "ascii" => ("ascii replay", params.file.clone()),
            "foreign" => ("foreign replay", params.file.clone()),
            _ => ("tcp stream", format!("tcp://{}", params.address)),
        };
        let core = ReplayCore::new(rig, params, kind, &name)?;
        let source = match params.source.as_str() {
            "ascii" => Source::Ascii(open_ascii(&params.file)?),
            // Opened here, so that a bad map or file fails the node before it runs.
            "foreign" => Source::Foreign(Box::new(ForeignSource::open(std::path::Path::new(&params.file), std::path::Path::new(&params.map), rig, params)?)),
            _ => Source::Tcp(params.address.clone()),
        };
        Ok(Self { params: params.clone(), idle: Some((core, source)), reader: None, reader_wait: None })
    }

    /// Starts the reading thread.
    fn start(&mut self, (mut core, source): (ReplayCore, Source)) -> Result<(), NodeError> {
        let (tx, frames) = mpsc::sync_channel(QUEUE_FRAMES);
        let dropped = Arc::new(AtomicU64::new(0));
        let mut dropping = DroppingSender::new(tx.clone(), Arc::clone(&dropped));
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = Arc::clone(&stop);
        let pace = ReplayPace { rate_factor: self.params.rate_factor, duration_s: self.params.duration_s };
        let thread = std::thread::Builder::new()
            .name("daq-lines".into())
            .spawn(move || {
                let stopped = || stopped.load(Ordering::SeqCst);
                match source {
                    // A file waits for room in the queue: nothing of it is dropped.
                    Source::Ascii(file) => {
                        let mut emit = |out: Produced| {
                            if out.frames.is_empty() {
                                Ok(())
                            } else {
                                tx.send(out).map_err(|_| NodeError::Closed("the DAQ node stopped taking frames".into()))
                            }
                        };
                        run_ascii_source(file, &mut core, &pace, &stopped, &mut emit)?
                    }
                    // A foreign file, likewise.
                    Source::Foreign(mut source) => {
                        let mut emit = |out: Produced| {
                            if out.frames.is_empty() {
                                Ok(())
                            } else {
                                tx.send(out).map_err(|_| NodeError::Closed("the DAQ node stopped taking frames".into()))
                            }
                        };
                        run_foreign_source(&mut source, &pace, &stopped, &mut emit)?
                    }
                    Source::Tcp(address) => {
                        drop(tx);
                        let backoff = Backoff { initial: Duration::from_millis(100), max: Duration::from_secs(5) };
                        run_tcp_source(&address, &mut core, &backoff, &stopped, &mut |out| dropping.send(out))?
                    }
                }
                Ok(core)
            })
            .map_err(|e| NodeError::Io { what: "the DAQ's reading thread".into(), source: e })?;
        self.reader = Some(Reader { frames: FrameQueue::new(frames, dropped), stop, thread });
        Ok(())
    }

    /// Publishes what the reader delivered, at most [`QUEUE_FRAMES`] of its outputs a turn
    /// (so that a reader as fast as the node cannot make one turn publish without end while
    /// the nodes downstream wait for theirs: what waits between the nodes stays bounded);
    /// `true` once it has ended. With nothing delivered yet, waits up to [`READER_NAP`] for
    /// the reader rather than return at once: a file replay's reader is then the pace, and
    /// an in-memory runner does not spin on the node while it parses.
    fn deliver(&mut self, ports: &mut DaqPorts<'_>, turn: &mut Turn) -> Result<bool, NodeError> {
        let Some(reader) = &self.reader else { return Ok(false) };
        for taken in 0..QUEUE_FRAMES {
            match reader.frames.take(if taken == 0 { READER_NAP } else { Duration::ZERO }) {
                Ok(out) => {
                    for (frame, status) in out.frames {
                        ports.frames.publish(frame)?;
                        ports.status.publish(status)?;
                        turn.handled += 2;
                    }
                }
                Err(mpsc::TryRecvError::Empty) => return Ok(false),
                Err(mpsc::TryRecvError::Disconnected) => return Ok(true),
            }
        }
        Ok(false)
    }

    /// Joins the ended reader: its error, or the replay's summary.
    fn join(&mut self) -> Result<(), NodeError> {
        let Some(reader) = self.reader.take() else { return Ok(()) };
        let core = reader.thread.join().map_err(|_| NodeError::Closed("the DAQ's reading thread panicked".into()))??;
        if self.params.source == "ascii" {
            tracing::info!(
                node = "daq",
                "{}: replay finished: {} frame(s), {} malformed row(s) skipped, {} gap(s)",
                self.params.file,
                core.frames(),
                core.malformed_rows(),
                core.gaps()
            );
        }
        Ok(())
    }

    pub fn turn(&mut self, now: Stamp, ports: &mut DaqPorts<'_>) -> Result<Turn, NodeError> {
        let mut turn = Turn::default();
        if let Some(idle) = self.idle.take() {
            // Frames published before a subscriber is discovered are lost to it (volatile
            // topic): give the graph time to come up, then go on regardless.
            let since = *self.reader_wait.get_or_insert(now);
            let readers = ports.frames.readers();
            if readers == Some(0) && now.seconds_since(since) < READER_WAIT_S {
                self.idle = Some(idle);
                return Ok(Turn { wake: Some(Stamp(now.0 + 20_000_000)), ..turn });
            }
            if readers == Some(0) {
                tracing::warn!(node = "daq", "no subscriber on {} after {READER_WAIT_S} s: publishing anyway", topics::DAQ_FRAMES.name);
            }
            self.start(idle)?;
        }
        if self.deliver(ports, &mut turn)? {
            self.join()?;
            turn.finished = true;
        } else if turn.handled == 0 {
            // The reading thread is on it: look again shortly (the in-memory runner's clock
            // must not think the graph stalled).
            turn.wake = Some(Stamp(now.0 + 5_000_000));
        }
        Ok(turn)
    }

    /// Stops the reader and publishes what it had.
    pub fn finish(&mut self, ports: &mut DaqPorts<'_>) -> Result<(), NodeError> {
        if let Some(reader) = &self.reader {
            reader.stop.store(true, Ordering::SeqCst);
            let mut turn = Turn::default();
            while !self.deliver(ports, &mut turn)? {
                std::thread::sleep(Duration::from_millis(5));
            }
            self.join()?;
        }
        Ok(())
    }
}
