//! Reading some topics of a bag fast: what offline re-analysis needs (the DAQ frames and
//! rig status) without touching the rest.
//!
//! A closed MCAP file ends with a summary: every channel and schema, and a chunk index per
//! chunk naming the channels it holds (its message index offsets) and where it is. From it
//! [`Bag::read_topics`] reads only the chunks that hold a wanted channel (`pread`, no whole-file
//! read), decompresses and CRC-checks them and decodes their wanted messages on worker
//! threads, chunk by chunk, while the caller consumes the decoded values in log-time order
//! on its own thread (the conditioner, in `oilfilm identify BAG`). Messages of other
//! channels in a read chunk are skipped by their channel id, never copied.
//!
//! A file without a readable summary or chunk indexes (cut short, damaged, or written
//! without them) goes through the full checking reader ([`messages_of_file`]) instead, so
//! what it refuses and why is the same as [`Bag::messages`].
//!
//! The order is [`Bag::messages`]' order restricted to the wanted topics: file by file, each
//! file's messages stably sorted by log time in file order, merged across chunks as they
//! arrive (see [`Stream`]).

use std::cmp::Reverse;
use std::collections::{BTreeMap, BTreeSet, BinaryHeap};
use std::fs::File;
use std::io::{Read, Seek};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc;
use std::sync::Arc;

use mcap::records::{ChunkIndex, Record};
use mcap::sans_io::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
use oilfilm_msgs::RosMessage;

use crate::error::{io, BagError, Result};
use crate::integrity::{difference, ReadOptions, Shortfall, ShortfallKind, Shortfalls};
use crate::reader::{read_file, Bag};

/// One message of a chunk, borrowed from the decompressed chunk.
#[derive(Debug, Clone, Copy)]
pub struct MessageRef<'a> {
    pub topic: &'a str,
    /// `pkg/msg/Type`.
    pub type_name: &'a str,
    pub log_time: u64,
    /// CDR with its 4-byte encapsulation header.
    pub data: &'a [u8],
    /// For errors: the file, the chunk's byte offset in it (`None` when the file was read
    /// whole), and the message's index in the chunk (or file).
    pub file: &'a Path,
    pub chunk_offset: Option<u64>,
    pub index: u64,
}

impl MessageRef<'_> {
    /// Decodes the message as `M`, which must be its type.
    pub fn decode<M: RosMessage>(&self) -> Result<M> {
        if self.type_name != M::TYPE_NAME {
            return Err(BagError::Usage {
                path: self.file.to_path_buf(),
                what: format!("message {} on {} is a {}, not a {}", self.index, self.topic, self.type_name, M::TYPE_NAME),
            });
        }
        oilfilm_msgs::decode(self.data).map_err(|source| BagError::Decode {
            path: self.file.to_path_buf(),
            topic: self.topic.to_string(),
            index: self.index,
            chunk_offset: self.chunk_offset,
            log_time: self.log_time,
            source: Box::new(source),
        })
    }
}

/// A file's channels: topic, type, and whether the caller wants it.
type Channels = BTreeMap<u16, (String, String, bool)>;

/// What a worker made of one chunk: its wanted messages decoded, with their log times, and
/// how many of each wanted channel it held; or, in a partial read, why it was skipped.
struct ChunkRead<T> {
    values: Vec<(u64, T)>,
    counts: BTreeMap<u16, u64>,
    skipped: Option<Shortfall>,
}

/// A worker's result: the job's index and its chunk.
type Done<T> = (usize, Result<ChunkRead<T>>);

/// Why a chunk could not be read: damage (skipped in a partial read), or anything else (a
/// message that does not decode, an I/O error), which ends every read.
enum ChunkFail {
    Damaged(BagError),
    Fatal(BagError),
}

/// A chunk to read: which file, and its index.
struct Job {
    file: usize,
    index: ChunkIndex,
}

/// What one file contributes: its chunks to read, or (no usable summary) its wanted
/// messages already decoded by the full reader.
enum Plan<T> {
    Chunks {
        channels: Arc<Channels>,
        jobs: Vec<ChunkIndex>,
        /// The summary's statistics: messages per wanted channel, if it has them.
        expected: Option<BTreeMap<u16, u64>>,
    },
    /// Read whole: the wanted messages decoded, and how many of each topic.
    Decoded { values: Vec<T>, counts: BTreeMap<String, u64> },
}

impl Bag {
    /// The messages of the topics `wanted(topic, type)` accepts, each turned into a `T` by
    /// `decode` on one of `threads` worker threads (at least 1), handed to `consume` as an
    /// iterator in [`Bag::messages`]' order while the workers decode what comes next.
    /// An error (I/O, a damaged chunk, `decode`'s) ends the iteration early and is returned
    /// instead of `consume`'s result. A strict read ([`Bag::read_topics_with`]): when
    /// `consume` took every message, what was read is checked against the bag's counts too.
    pub fn read_topics<T, R>(
        &self,
        wanted: &dyn Fn(&str, &str) -> bool,
        decode: &(dyn Fn(&MessageRef) -> Result<T> + Sync),
        threads: usize,
        consume: impl FnOnce(&mut dyn Iterator<Item = T>) -> R,
    ) -> Result<R>
    where
        T: Send,
    {
        self.read_topics_with(ReadOptions::STRICT, wanted, decode, threads, consume).map(|(r, _)| r)
    }

    /// [`Bag::read_topics`] with `options`: checks the directory against metadata.yaml
    /// (unlisted, missing files; a live writer), each file's summary CRC and each chunk's,
    /// and, when `consume` took every message, the counts read per topic against
    /// metadata.yaml's and per file against its statistics. A strict read fails on the first
    /// difference; a partial one skips damaged chunks and files it cannot read, and returns
    /// every difference beside `consume`'s result.
    pub fn read_topics_with<T, R>(
        &self,
        options: ReadOptions,
        wanted: &dyn Fn(&str, &str) -> bool,
        decode: &(dyn Fn(&MessageRef) -> Result<T> + Sync),
        threads: usize,
        consume: impl FnOnce(&mut dyn Iterator<Item = T>) -> R,
    ) -> Result<(R, Vec<Shortfall>)>
    where
        T: Send,
    {
        let mut found = Shortfalls::new(options);
        self.check_directory(&mut found)?;
        let paths: Vec<PathBuf> = self.files().into_iter().filter(|p| !options.allow_partial || p.is_file()).collect();
        let mut plans = Vec::with_capacity(paths.len());
        for path in &paths {
            plans.push(plan_file(path, wanted, decode, &mut found)?);
        }
        let jobs: Vec<Job> = plans
            .iter_mut()
            .enumerate()
            .flat_map(|(file, p)| match p {
                Plan::Chunks { jobs, .. } => std::mem::take(jobs).into_iter().map(|index| Job { file, index }).collect(),
                Plan::Decoded { .. } => Vec::new(),
            })
            .collect();
        let channels: Vec<Option<Arc<Channels>>> = plans
            .iter()
            .map(|p| match p {
                Plan::Chunks { channels, .. } => Some(Arc::clone(channels)),
                Plan::Decoded { .. } => None,
            })
            .collect();
        let files: Vec<Option<File>> = plans
            .iter()
            .zip(&paths)
            .map(|(p, path)| match p {
                Plan::Chunks { .. } => File::open(path).map(Some).map_err(io(path)),
                Plan::Decoded { .. } => Ok(None),
            })
            .collect::<Result<_>>()?;
        let threads = threads.clamp(1, jobs.len().max(1));
        let stop = AtomicBool::new(false);
        let allow_partial = options.allow_partial;
        // Jobs handed out in order to whichever worker is free (chunks differ in size: a
        // topic's chunks can alternate with another's much smaller ones).
        let taken = AtomicUsize::new(0);
        // Bounded: the workers run at most a few chunks ahead of the consumer (a long bag is
        // not decoded into memory faster than it is used). The consumer receives whatever
        // comes while it waits for the chunk it needs, so a worker blocked here is always
        // released.
        let (tx, rx) = mpsc::sync_channel::<Done<T>>(2 * threads + 2);
        std::thread::scope(|s| {
            for _ in 0..threads {
                let tx = tx.clone();
                let (jobs, files, channels, paths, stop, taken) = (&jobs, &files, &channels, &paths, &stop, &taken);
                s.spawn(move || {
                    let mut buffers = crate::scan::ChunkBuffers::default();
                    loop {
                        let i = taken.fetch_add(1, Ordering::Relaxed);
                        let Some(job) = jobs.get(i) else { return };
                        if stop.load(Ordering::Relaxed) {
                            return;
                        }
                        let (Some(file), Some(ch)) = (&files[job.file], &channels[job.file]) else { continue };
                        let path = &paths[job.file];
                        let out = match read_chunk_of(file, path, &job.index, ch, decode, &mut buffers) {
                            Ok(read) => Ok(read),
                            Err(ChunkFail::Damaged(e)) if allow_partial => {
                                let what = format!(
                                    "the chunk at byte {} (log times {}..={} ns) is skipped: {}",
                                    job.index.chunk_start_offset,
                                    job.index.message_start_time,
                                    job.index.message_end_time,
                                    strip_path(&e, path)
                                );
                                Ok(ChunkRead {
                                    values: Vec::new(),
                                    counts: BTreeMap::new(),
                                    skipped: Some(Shortfall::new(path, ShortfallKind::DamagedChunk, what)),
                                })
                            }
                            Err(ChunkFail::Damaged(e) | ChunkFail::Fatal(e)) => Err(e),
                        };
                        if out.is_err() {
                            stop.store(true, Ordering::Relaxed);
                        }
                        if tx.send((i, out)).is_err() {
                            return;
                        }
                    }
                });
            }
            drop(tx);
            let channels = &channels;
            let mut stream = Stream {
                rx,
                pending: BTreeMap::new(),
                next: 0,
                dir: self.dir(),
                jobs: &jobs,
                plans: &mut plans,
                file: 0,
                heap: BinaryHeap::new(),
                rest_start: Vec::new(),
                file_start: 0,
                file_end: 0,
                current: Vec::new().into_iter(),
                error: None,
                stop: &stop,
                topic_counts: BTreeMap::new(),
                file_counts: vec![BTreeMap::new(); paths.len()],
                skipped: Vec::new(),
                exhausted: false,
            };
            let r = consume(&mut stream);
            stream.stop.store(true, Ordering::Relaxed);
            if let Some(e) = stream.error.take() {
                return Err(e);
            }
            for s in std::mem::take(&mut stream.skipped) {
                found.note(s)?;
            }
            if stream.exhausted {
                // Counts are known only when every message was taken.
                for (f, plan) in stream.plans.iter().enumerate() {
                    let (Plan::Chunks { expected: Some(expected), .. }, Some(ch)) = (plan, &channels[f]) else { continue };
                    for (id, &n) in expected {
                        let got = stream.file_counts[f].get(id).copied().unwrap_or(0);
                        if got != n {
                            let topic = ch.get(id).map_or("?", |c| c.0.as_str());
                            found.note(Shortfall::new(
                                &paths[f],
                                ShortfallKind::Count,
                                format!("topic {topic}: the file's statistics count {n} messages, {got} were read ({})", difference(n, got)),
                            ))?;
                        }
                    }
                }
                self.check_counts(wanted, &stream.topic_counts, &mut found)?;
            }
            Ok((r, found.found))
        })
    }
}

/// The summary of one file and the chunks to read, or the full reader's result (a partial
/// read: whatever the file's undamaged records hold, its damage noted).
fn plan_file<T>(
    path: &Path,
    wanted: &dyn Fn(&str, &str) -> bool,
    decode: &(dyn Fn(&MessageRef) -> Result<T> + Sync),
    found: &mut Shortfalls,
) -> Result<Plan<T>> {
    if let Some(plan) = indexed_plan(path, wanted, found)? {
        return Ok(plan);
    }
    let bytes = std::fs::read(path).map_err(io(path))?;
    let (messages, damage) = read_file(path, &bytes, found.allow_partial)?;
    for d in damage {
        found.note(d)?;
    }
    let mut values = Vec::new();
    let mut counts = BTreeMap::new();
    for m in messages {
        if !wanted(&m.topic, &m.type_name) {
            continue;
        }
        let r = MessageRef { topic: &m.topic, type_name: &m.type_name, log_time: m.log_time, data: &m.data, file: path, chunk_offset: None, index: m.index };
        values.push(decode(&r)?);
        *counts.entry(m.topic.to_string()).or_default() += 1;
    }
    Ok(Plan::Decoded { values, counts })
}

/// The text of an error without the path it starts with (a shortfall names the path).
fn strip_path(e: &BagError, path: &Path) -> String {
    match e {
        BagError::Format { what, .. } => what.clone(),
        other => {
            let text = other.to_string();
            let prefix = format!("{}: ", path.display());
            text.strip_prefix(&prefix).map(str::to_string).unwrap_or(text)
        }
    }
}

/// `Some(problem)` when the footer's summary CRC does not match the summary; `None` when it
/// does, is not given (0), or there is no summary to check (the caller then reads the file
/// whole). Streams the summary through the CRC: nothing is allocated from its size.
fn summary_crc_problem(file: &File, len: u64) -> Option<String> {
    const FOOTER_AND_MAGIC: u64 = 1 + 8 + 20 + 8;
    let footer_at = len.checked_sub(FOOTER_AND_MAGIC)?;
    let mut footer = [0u8; 29];
    file.read_exact_at(&mut footer, footer_at).ok()?;
    let summary_start = u64::from_le_bytes(footer[9..17].try_into().ok()?);
    let saved = u32::from_le_bytes(footer[25..29].try_into().ok()?);
    if saved == 0 || summary_start > footer_at {
        return None;
    }
    let start = if summary_start == 0 { footer_at } else { summary_start };
    let end = footer_at + 1 + 8 + 16;
    let mut hasher = crc32fast::Hasher::new();
    let mut buf = vec![0u8; 64 << 10];
    let mut at = start;
    while at < end {
        let n = (end - at).min(buf.len() as u64) as usize;
        file.read_exact_at(&mut buf[..n], at).ok()?;
        hasher.update(&buf[..n]);
        at += n as u64;
    }
    let calculated = hasher.finalize();
    (calculated != saved).then(|| crate::scan::summary_crc_text(calculated, saved))
}

/// `None` when the file has no usable summary (the caller then reads it whole and reports
/// what is wrong with it); errors only for what the full reader would refuse too (a foreign
/// profile, channels that are not CDR).
fn indexed_plan<T>(path: &Path, wanted: &dyn Fn(&str, &str) -> bool, found: &mut Shortfalls) -> Result<Option<Plan<T>>> {
    let format = |what: String| BagError::Format { path: path.to_path_buf(), offset: None, what };
    let mut file = File::open(path).map_err(io(path))?;
    let len = file.metadata().map_err(io(path))?.len();
    // Magic, then the header record: its profile says whether this is a rosbag2 file.
    let mut head = [0u8; 17];
    if len < 17 || file.read_exact(&mut head).is_err() || head[..8] != *mcap::MAGIC || head[8] != 0x01 {
        return Ok(None);
    }
    let header_len = u64::from_le_bytes(head[9..17].try_into().unwrap_or_default());
    if header_len > len.saturating_sub(17) {
        return Ok(None);
    }
    let mut body = vec![0u8; header_len as usize];
    if file.read_exact(&mut body).is_err() {
        return Ok(None);
    }
    match mcap::parse_record(0x01, &body) {
        Ok(Record::Header(h)) if h.profile == "ros2" => {}
        Ok(Record::Header(h)) => return Err(format(format!("MCAP profile is `{}`, not `ros2`: not a rosbag2 file", h.profile))),
        _ => return Ok(None),
    }
    if let Some(problem) = summary_crc_problem(&file, len) {
        // Strict: the error. Partial: the file is read record by record instead, its damage
        // (if any beyond the summary) noted there.
        found.note(Shortfall::new(path, ShortfallKind::SummaryCrc, problem))?;
        return Ok(None);
    }
    let Some(summary) = read_summary(&mut file, len) else { return Ok(None) };
    if summary.chunk_indexes.is_empty() && summary.stats.as_ref().is_none_or(|s| s.message_count > 0) {
        return Ok(None);
    }
    let mut channels = BTreeMap::new();
    let mut wanted_ids = BTreeSet::new();
    for (&id, c) in &summary.channels {
        if c.message_encoding != "cdr" {
            return Err(format(format!("topic {} has message encoding `{}`, not cdr", c.topic, c.message_encoding)));
        }
        let schema = c.schema.as_ref().ok_or_else(|| format(format!("topic {} has no schema", c.topic)))?;
        if schema.encoding != "ros2msg" && schema.encoding != "ros2idl" {
            return Err(format(format!("topic {}: schema encoding `{}` is not ros2msg or ros2idl", c.topic, schema.encoding)));
        }
        if wanted(&c.topic, &schema.name) {
            wanted_ids.insert(id);
        }
        channels.insert(id, (c.topic.clone(), schema.name.clone(), wanted_ids.contains(&id)));
    }
    let mut jobs = Vec::new();
    for ci in summary.chunk_indexes {
        let end = ci.chunk_start_offset.checked_add(ci.chunk_length);
        if end.is_none_or(|e| e > len) || ci.chunk_length < 9 {
            return Ok(None);
        }
        // No message index (a writer that leaves them out): the chunk may hold anything.
        let holds_wanted = ci.message_index_offsets.is_empty() || ci.message_index_offsets.keys().any(|id| wanted_ids.contains(id));
        if holds_wanted {
            jobs.push(ci);
        }
    }
    jobs.sort_by_key(|c| c.chunk_start_offset);
    // Per-channel counts, when the statistics give them (a writer may leave them out).
    let expected = summary.stats.as_ref().filter(|s| !s.channel_message_counts.is_empty() || s.message_count == 0).map(|s| {
        let mut e: BTreeMap<u16, u64> = wanted_ids.iter().map(|id| (*id, 0)).collect();
        for (id, n) in &s.channel_message_counts {
            if let Some(v) = e.get_mut(id) {
                *v = *n;
            }
        }
        e
    });
    Ok(Some(Plan::Chunks { channels: Arc::new(channels), jobs, expected }))
}

/// The summary section, read with seeks (the data section is not read); `None` if the file
/// has none or it does not parse.
fn read_summary(file: &mut File, len: u64) -> Option<mcap::Summary> {
    let mut reader = SummaryReader::new_with_options(SummaryReaderOptions::default().with_file_size(len));
    while let Some(event) = reader.next_event() {
        match event.ok()? {
            SummaryReadEvent::ReadRequest(n) => {
                let got = file.read(reader.insert(n)).ok()?;
                reader.notify_read(got);
            }
            SummaryReadEvent::SeekRequest(to) => {
                let pos = file.seek(to).ok()?;
                reader.notify_seeked(pos);
            }
        }
    }
    reader.finish()
}

/// Reads, decompresses and checks one chunk and decodes its wanted messages, each with its
/// log time, in the chunk's order stably sorted by log time.
fn read_chunk_of<T>(
    file: &File,
    path: &Path,
    index: &ChunkIndex,
    channels: &Channels,
    decode: &(dyn Fn(&MessageRef) -> Result<T> + Sync),
    buffers: &mut crate::scan::ChunkBuffers,
) -> Result<ChunkRead<T>, ChunkFail> {
    let offset = index.chunk_start_offset;
    let format = |what: String| ChunkFail::Damaged(BagError::Format { path: path.to_path_buf(), offset: Some(offset), what });
    // indexed_plan() checked the chunk lies inside the file.
    let record = &mut buffers.record;
    record.clear();
    record.resize(index.chunk_length as usize, 0);
    file.read_exact_at(record, offset).map_err(|e| ChunkFail::Fatal(io(path)(e)))?;
    if record[0] != 0x06 {
        return Err(format("the chunk index points at a record that is not a chunk".into()));
    }
    let (header, data) = match mcap::parse_record(0x06, &record[9..]) {
        Ok(Record::Chunk { header, data }) => (header, data),
        Ok(_) => return Err(format("the chunk index points at a record that is not a chunk".into())),
        Err(e) => return Err(format(format!("chunk: {e}"))),
    };
    let records = crate::scan::decompress_chunk_reusing(&header, &data, &mut buffers.records, &mut buffers.zstd).map_err(format)?;
    let mut out = Vec::new();
    let mut counts = BTreeMap::new();
    let mut at = 0usize;
    let mut n = 0u64;
    while at < records.len() {
        let rest = &records[at..];
        if rest.len() < 9 {
            return Err(format(format!("a record header in the chunk is cut short at its byte {at}")));
        }
        let opcode = rest[0];
        let len = u64::from_le_bytes([rest[1], rest[2], rest[3], rest[4], rest[5], rest[6], rest[7], rest[8]]);
        let Some(end) = usize::try_from(len).ok().and_then(|l| l.checked_add(9)).filter(|&e| e <= rest.len()) else {
            return Err(format(format!("a record in the chunk at its byte {at} claims {len} bytes, more than the chunk holds")));
        };
        let body = &rest[9..end];
        at += end;
        if opcode != 0x05 {
            continue; // schemas and channels: the summary has them
        }
        // channel u16, sequence u32, log time u64, publish time u64, then the data.
        if body.len() < 22 {
            return Err(format(format!("a message record in the chunk at its byte {} is cut short", at - end)));
        }
        let channel = u16::from_le_bytes([body[0], body[1]]);
        let log_time = u64::from_le_bytes([body[6], body[7], body[8], body[9], body[10], body[11], body[12], body[13]]);
        if log_time < index.message_start_time || log_time > index.message_end_time {
            return Err(format(format!(
                "a message (log time {log_time} ns) lies outside the chunk's time range in its index ({}..={} ns)",
                index.message_start_time, index.message_end_time
            )));
        }
        let Some((topic, type_name, wanted)) = channels.get(&channel) else {
            return Err(format(format!("a message (log time {log_time} ns) is on channel {channel}, which the summary does not declare")));
        };
        n += 1;
        if !wanted {
            continue;
        }
        *counts.entry(channel).or_default() += 1;
        let m = MessageRef { topic, type_name, log_time, data: &body[22..], file: path, chunk_offset: Some(offset), index: n - 1 };
        out.push((log_time, decode(&m).map_err(ChunkFail::Fatal)?));
    }
    out.sort_by_key(|(t, _)| *t); // stable: chunk order among equal times
    Ok(ChunkRead { values: out, counts, skipped: None })
}

/// The decoded values in order: chunks as the workers finish them, merged in job order;
/// files without a summary from their plan. Ends early on the first error, kept in `error`.
///
/// A file's order is its messages stably sorted by log time in file order. Chunks are taken
/// in file order; a taken message is handed out once no chunk still to come can hold an
/// earlier one (its log time is at most the least start time of the file's remaining
/// chunks), the ties in file order. Chunks of one series that do not overlap (one topic's,
/// or a writer's that mixes all topics) are so handed out as each arrives.
struct Stream<'a, T> {
    rx: mpsc::Receiver<Done<T>>,
    pending: BTreeMap<usize, Result<ChunkRead<T>>>,
    next: usize,
    dir: &'a Path,
    jobs: &'a [Job],
    plans: &'a mut [Plan<T>],
    file: usize,
    /// Taken messages not yet handed out: (log time, job, position in the chunk).
    heap: BinaryHeap<Reverse<Keyed<T>>>,
    /// `rest_start[k]`: the least start time of the current file's chunks from its k-th on
    /// (`u64::MAX` past the last).
    rest_start: Vec<u64>,
    /// Jobs of the current file: `file_start..file_end`.
    file_start: usize,
    file_end: usize,
    current: std::vec::IntoIter<T>,
    error: Option<BagError>,
    stop: &'a AtomicBool,
    /// Wanted messages handed over per topic, and per file and channel (chunked files).
    topic_counts: BTreeMap<String, u64>,
    file_counts: Vec<BTreeMap<u16, u64>>,
    /// Chunks skipped as damaged (partial reads).
    skipped: Vec<Shortfall>,
    /// Every message was handed out.
    exhausted: bool,
}

/// A value ordered by its key alone.
struct Keyed<T>((u64, usize, usize), T);

impl<T> PartialEq for Keyed<T> {
    fn eq(&self, other: &Self) -> bool {
        self.0 == other.0
    }
}
impl<T> Eq for Keyed<T> {}
impl<T> PartialOrd for Keyed<T> {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl<T> Ord for Keyed<T> {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.cmp(&other.0)
    }
}

impl<T> Stream<'_, T> {
    /// The next job's values, waiting for them.
    fn take_job(&mut self) -> Result<ChunkRead<T>> {
        loop {
            if let Some(r) = self.pending.remove(&self.next) {
                self.next += 1;
                return r;
            }
            match self.rx.recv() {
                Ok((i, r)) => {
                    self.pending.insert(i, r);
                }
                // Every worker ended without sending this job: another job failed first and
                // stopped them (its error is pending), or one panicked.
                Err(_) => {
                    let first_error = self
                        .pending
                        .values_mut()
                        .find(|r| r.is_err())
                        .map(|r| std::mem::replace(r, Ok(ChunkRead { values: Vec::new(), counts: BTreeMap::new(), skipped: None })));
                    return match first_error {
                        Some(Err(e)) => Err(e),
                        _ => Err(BagError::Usage { path: self.dir.to_path_buf(), what: "a bag reader thread stopped before its chunk".into() }),
                    };
                }
            }
        }
    }

    /// Refills `current`; `Ok(false)` at the end.
    fn refill(&mut self) -> Result<bool> {
        if self.next < self.file_end {
            let job = self.next;
            let read = self.take_job()?;
            let file = self.jobs[job].file;
            if let Some(Plan::Chunks { channels, .. }) = self.plans.get(file) {
                for (&id, &n) in &read.counts {
                    *self.file_counts[file].entry(id).or_default() += n;
                    if let Some((topic, _, _)) = channels.get(&id) {
                        *self.topic_counts.entry(topic.clone()).or_default() += n;
                    }
                }
            }
            self.skipped.extend(read.skipped);
            for (pos, (t, v)) in read.values.into_iter().enumerate() {
                self.heap.push(Reverse(Keyed((t, job, pos), v)));
            }
            let bound = self.rest_start[self.next - self.file_start];
            let mut out = Vec::new();
            while self.heap.peek().is_some_and(|Reverse(Keyed((t, _, _), _))| *t <= bound) {
                let Some(Reverse(Keyed(_, v))) = self.heap.pop() else { break };
                out.push(v);
            }
            self.current = out.into_iter();
            return Ok(true);
        }
        let Some(plan) = self.plans.get_mut(self.file) else {
            self.exhausted = true;
            return Ok(false);
        };
        let f = self.file;
        self.file += 1;
        match plan {
            Plan::Decoded { values, counts } => {
                for (topic, n) in counts.iter() {
                    *self.topic_counts.entry(topic.clone()).or_default() += n;
                }
                self.current = std::mem::take(values).into_iter();
            }
            Plan::Chunks { .. } => {
                let mine: Vec<u64> = self.jobs.iter().filter(|j| j.file == f).map(|j| j.index.message_start_time).collect();
                // rest_start[k]: the least start of this file's chunks k.. (k counted from
                // the file's first job).
                let mut rest = vec![u64::MAX; mine.len() + 1];
                for k in (0..mine.len()).rev() {
                    rest[k] = rest[k + 1].min(mine[k]);
                }
                self.rest_start = rest;
                self.file_start = self.next;
                self.file_end = self.next + mine.len();
                self.current = Vec::new().into_iter();
            }
        }
        Ok(true)
    }
}
impl<T> Iterator for Stream<'_, T> {
    type Item = T;
    fn next(&mut self) -> Option<T> {
        loop {
            if let Some(v) = self.current.next() {
                return Some(v);
            }
            if self.error.is_some() {
                return None;
            }
            match self.refill() {
                Ok(true) => {}
                Ok(false) => return None,
                Err(e) => {
                    self.stop.store(true, Ordering::Relaxed);
                    self.error = Some(e);
                    return None;
                }
            }
        }
    }
}
