//! The rosbag2 bag writer: a directory `NAME/` holding `NAME_0.mcap`, `NAME_1.mcap`, ... and
//! `metadata.yaml`, written when a file is closed (on split and on close).
//!
//! Each file is a chunked MCAP file with profile `ros2`, framed here (`records`): header,
//! schemas and channels, chunks each followed by its message indexes, data end with the
//! data-section CRC, a summary (schemas, channels, statistics, chunk indexes, summary
//! offsets) and the footer with the summary CRC. A chunk is closed when it reaches
//! `chunk_size` bytes or spans `max_chunk_duration_ns` of log time and handed to
//! `compression_threads` workers (`chunks`), which compress it and put it in the file, in
//! the order chunks were closed, and hand it to the OS as soon as the chunks before it are
//! there: a writer killed at any moment loses the chunk it was filling and the few closed
//! in the last milliseconds that were still being compressed (ADR 0015).
//!
//! With `chunk_per_topic` (the default) each topic's messages are gathered in memory and
//! written as chunks of that topic alone, so a reader that wants some topics (re-analysis:
//! the DAQ frames and rig status) decompresses only their chunks. A topic's chunk is closed
//! when it holds `chunk_size` bytes or once any message is `max_chunk_duration_ns` of log
//! time after its first, so a killed writer loses at most the last
//! `max_chunk_duration_ns` of each topic (one chunk per topic). ADR 0013.

use std::collections::BTreeMap;
use std::fs::{self, File};
use std::io::Write;
use std::path::{Path, PathBuf};

use oilfilm_msgs::RosMessage;

use crate::chunks::{FileSink, Gathered, Pipeline};
use crate::error::{io, BagError, Result};
use crate::lock::RecordingLock;
use crate::metadata::{qos_to_channel_metadata, FileInfo, MetadataFile, QosProfile, TopicMetadata, TopicWithCount};
use crate::records::{self, ChunkIndex};
use crate::{Duration as NsDuration, StartingTime, METADATA_FILE};

/// Compression of the MCAP chunks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compression {
    Zstd,
    Lz4,
    None,
}

#[derive(Debug, Clone)]
pub struct WriterOptions {
    pub compression: Compression,
    /// Close a chunk once it holds this many (uncompressed) bytes.
    pub chunk_size: u64,
    /// Close a chunk once it spans this much log time: bounds what a crash loses.
    pub max_chunk_duration_ns: u64,
    /// Start a new file once the current one reaches this many bytes on disk (checked
    /// before each message; the chunks still gathering, one per topic with
    /// `chunk_per_topic`, are not counted until they are closed).
    pub split_size_bytes: Option<u64>,
    /// Start a new file once a message is this much log time after the file's first.
    pub split_duration_ns: Option<u64>,
    /// `ros_distro` in metadata.yaml.
    pub ros_distro: String,
    /// zstd level (negative: zstd's fast levels) or lz4 acceleration level; ignored without
    /// compression. See [`WriterOptions::DEFAULT_ZSTD_LEVEL`].
    pub compression_level: i32,
    /// Threads compressing closed chunks while the writing thread gathers the next ones
    /// (0: the writing thread compresses each chunk itself). Chunks reach the file in the
    /// order they were closed either way, the same bytes; at most twice this many chunks are
    /// in flight (ADR 0015).
    pub compression_threads: u32,
    /// Chunks of one topic each (see the module docs); `false`: chunks hold the messages of
    /// every topic in the order written.
    pub chunk_per_topic: bool,
}

impl WriterOptions {
    /// zstd level of the recorder: 1 (ADR 0013: the fast levels were not reliably faster on
    /// the rig's DAQ frames, and level -1 makes a chunk of one small message larger than the
    /// message, which `pymcap-cli doctor` warns about).
    pub const DEFAULT_ZSTD_LEVEL: i32 = 1;
    /// Compression threads of the recorder: 2, so on the rig PC's two cores compression
    /// (the bulk of recording's work) runs on both while the writing thread only gathers
    /// and writes (ADR 0015). At the live data rate they are mostly idle.
    pub const DEFAULT_COMPRESSION_THREADS: u32 = 2;
}

impl Default for WriterOptions {
    fn default() -> Self {
        Self {
            compression: Compression::Zstd,
            chunk_size: 1 << 20,
            max_chunk_duration_ns: 1_000_000_000,
            split_size_bytes: None,
            split_duration_ns: None,
            ros_distro: "kilted".into(),
            compression_level: Self::DEFAULT_ZSTD_LEVEL,
            compression_threads: Self::DEFAULT_COMPRESSION_THREADS,
            chunk_per_topic: true,
        }
    }
}

/// A topic of the bag: its name, `pkg/msg/Type`, `ros2msg` schema text and offered QoS.
#[derive(Debug, Clone, PartialEq)]
pub struct TopicSpec {
    pub name: String,
    pub type_name: String,
    pub schema_text: String,
    pub qos: Vec<QosProfile>,
}

impl TopicSpec {
    /// A topic of one of our types (`oilfilm_msgs/msg/DaqFrame`), its schema text from the
    /// .msg files, dependencies named `pkg/msg/Type`.
    pub fn ours(name: &str, type_name: &str, qos: Vec<QosProfile>) -> std::result::Result<Self, String> {
        let schema_text = oilfilm_msgs::schema_text(type_name, oilfilm_msgs::spec::SchemaNaming::Qualified)?;
        Ok(Self { name: name.into(), type_name: type_name.into(), schema_text, qos })
    }
}

/// Index of a topic added to a [`BagWriter`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TopicId(usize);

/// One chunk being gathered: its message records back to back and where each message is.
struct Gathering {
    chunk: Gathered,
    /// The earliest log time among its messages.
    first: Option<u64>,
}

impl Gathering {
    fn new(records: Vec<u8>) -> Self {
        Self { chunk: Gathered { records, index: Vec::new(), start_ns: u64::MAX, end_ns: 0 }, first: None }
    }

    fn add(&mut self, channel_id: u16, sequence: u32, log_time: u64, cdr: &[u8]) {
        let c = &mut self.chunk;
        c.index.push((channel_id, log_time, c.records.len() as u64));
        records::message(&mut c.records, channel_id, sequence, log_time, cdr);
        c.start_ns = c.start_ns.min(log_time);
        c.end_ns = c.end_ns.max(log_time);
        self.first = Some(self.first.map_or(log_time, |t| t.min(log_time)));
    }
}

struct OpenFile {
    path: PathBuf,
    /// Channel id of each topic.
    channels: Vec<u16>,
    /// Schema id of each (type name, schema text) written to this file.
    schema_ids: Vec<(String, String, u16)>,
    /// The schema and channel records as written in the data section, repeated in the
    /// summary.
    schema_records: Vec<u8>,
    channel_records: Vec<u8>,
    sequences: Vec<u32>,
    /// Messages per channel id.
    channel_counts: BTreeMap<u16, u64>,
    first: Option<u64>,
    last: u64,
    count: u64,
    /// The chunk being gathered of each topic (`chunk_per_topic`) or the one chunk of all.
    gathering: Vec<Gathering>,
}

impl OpenFile {
    /// Records of the schema (unless this file has it) and channel of topic `t`, appended to
    /// `out` and kept for the summary; the channel's id is pushed to `channels`.
    fn declare(&mut self, t: &TopicSpec, type_hash: &str, out: &mut Vec<u8>) -> Result<()> {
        let too_long = |what: &str| BagError::Usage { path: self.path.clone(), what: format!("topic {}: {what} is longer than MCAP allows (4 GiB)", t.name) };
        if !records::fits_u32(t.schema_text.len()) {
            return Err(too_long("the schema text"));
        }
        let schema_id = match self.schema_ids.iter().find(|(n, s, _)| *n == t.type_name && *s == t.schema_text) {
            Some(&(_, _, id)) => id,
            None => {
                let id = u16::try_from(self.schema_ids.len() + 1).map_err(|_| too_long("the file's schema count"))?;
                let start = self.schema_records.len();
                records::schema(&mut self.schema_records, id, &t.type_name, "ros2msg", t.schema_text.as_bytes());
                out.extend_from_slice(&self.schema_records[start..]);
                self.schema_ids.push((t.type_name.clone(), t.schema_text.clone(), id));
                id
            }
        };
        let channel_id = u16::try_from(self.channels.len() + 1).map_err(|_| too_long("the file's channel count"))?;
        let mut metadata = BTreeMap::new();
        metadata.insert("offered_qos_profiles".to_string(), qos_to_channel_metadata(&t.qos));
        if !type_hash.is_empty() {
            // rosbag2's MCAP storage plugin keeps the type description hash under this key.
            metadata.insert(TYPE_HASH_KEY.to_string(), type_hash.to_string());
        }
        let start = self.channel_records.len();
        records::channel(&mut self.channel_records, channel_id, schema_id, &t.name, "cdr", &metadata);
        out.extend_from_slice(&self.channel_records[start..]);
        self.channels.push(channel_id);
        self.sequences.push(0);
        Ok(())
    }

    /// The summary section and footer for a data section of `data_len` bytes (the data end
    /// record included) holding `chunks` and the rosbag2 metadata record at `metadata`
    /// (offset, length).
    fn summary(&self, data_len: u64, chunks: &[ChunkIndex], metadata: (u64, u64)) -> Vec<u8> {
        let mut b = Vec::with_capacity(self.schema_records.len() + self.channel_records.len() + 128 * (chunks.len() + 4));
        let mut groups = Vec::new();
        let mut group = |b: &mut Vec<u8>, opcode: u8, start: usize| {
            if b.len() > start {
                groups.push((opcode, data_len + start as u64, (b.len() - start) as u64));
            }
        };
        b.extend_from_slice(&self.schema_records);
        group(&mut b, records::op::SCHEMA, 0);
        let start = b.len();
        b.extend_from_slice(&self.channel_records);
        group(&mut b, records::op::CHANNEL, start);
        let start = b.len();
        let stats = records::Statistics {
            message_count: self.count,
            schema_count: self.schema_ids.len() as u16,
            channel_count: self.channels.len() as u32,
            chunk_count: chunks.len() as u32,
            metadata_count: 1,
            start_ns: self.first.unwrap_or(0),
            end_ns: if self.first.is_some() { self.last } else { 0 },
            channel_message_counts: self.channel_counts.clone(),
        };
        records::statistics(&mut b, &stats);
        group(&mut b, records::op::STATISTICS, start);
        let start = b.len();
        for c in chunks {
            records::chunk_index(&mut b, c);
        }
        group(&mut b, records::op::CHUNK_INDEX, start);
        let start = b.len();
        records::metadata_index(&mut b, metadata.0, metadata.1, ROSBAG2_METADATA);
        group(&mut b, records::op::METADATA_INDEX, start);
        let summary_offset_start = data_len + b.len() as u64;
        for (opcode, start, len) in groups {
            records::summary_offset(&mut b, opcode, start, len);
        }
        records::footer_start(&mut b, data_len, summary_offset_start);
        let crc = crc32fast::hash(&b);
        records::footer_end(&mut b, crc);
        b
    }
}

/// Writes one bag. Call [`BagWriter::close`] at the end; dropping it closes it too (errors
/// then are lost: close explicitly to see them).
pub struct BagWriter {
    dir: PathBuf,
    name: String,
    options: WriterOptions,
    topics: Vec<TopicSpec>,
    /// RIHS01 hash of each topic's type ([`type_hash_of`]), empty when not computable.
    hashes: Vec<String>,
    counts: Vec<u64>,
    files: Vec<FileInfo>,
    current: Option<OpenFile>,
    /// Compresses closed chunks and writes them in order (`compression_threads` workers).
    pipeline: Pipeline,
    /// Held while the bag is open, so recovery can tell a live writer from a killed one.
    lock: Option<RecordingLock>,
}

impl BagWriter {
    /// Creates the bag directory `dir` (which must not exist, or be empty, as with
    /// `ros2 bag record -o`) and opens its first file.
    pub fn create(dir: impl AsRef<Path>, options: WriterOptions) -> Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        if dir.exists() {
            let mut entries = fs::read_dir(&dir).map_err(io(&dir))?;
            if entries.next().is_some() {
                return Err(BagError::Usage { path: dir, what: "the bag directory exists and is not empty; not overwriting it".into() });
            }
        }
        let name = dir
            .file_name()
            .and_then(|n| n.to_str())
            .filter(|n| !n.is_empty())
            .ok_or_else(|| BagError::Usage { path: dir.clone(), what: "the bag directory needs a UTF-8 name".into() })?
            .to_string();
        let pipeline = Pipeline::new(options.compression, options.compression_level, options.compression_threads as usize, &dir)?;
        fs::create_dir_all(&dir).map_err(io(&dir))?;
        let lock = Some(RecordingLock::acquire(&dir)?);
        let mut w = Self { dir, name, options, topics: Vec::new(), hashes: Vec::new(), counts: Vec::new(), files: Vec::new(), current: None, pipeline, lock };
        w.open_next()?;
        Ok(w)
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Adds a topic; a topic name may be added once.
    pub fn add_topic(&mut self, spec: TopicSpec) -> Result<TopicId> {
        if self.topics.iter().any(|t| t.name == spec.name) {
            return Err(BagError::Usage { path: self.dir.clone(), what: format!("topic {} is added twice", spec.name) });
        }
        let id = TopicId(self.topics.len());
        let hash = type_hash_of(&spec);
        if let Some(f) = self.current.as_mut() {
            let mut declared = Vec::new();
            f.declare(&spec, &hash, &mut declared)?;
            if self.options.chunk_per_topic {
                f.gathering.push(Gathering::new(Vec::new()));
            }
            self.pipeline.submit_raw(declared)?;
        }
        self.topics.push(spec);
        self.hashes.push(hash);
        self.counts.push(0);
        Ok(id)
    }

    pub fn topic(&self, id: TopicId) -> Option<&TopicSpec> {
        self.topics.get(id.0)
    }

    /// Writes one message's CDR bytes (with the 4-byte encapsulation header) at `log_time`
    /// (ns since the epoch); publish time is the log time.
    pub fn write(&mut self, topic: TopicId, log_time: u64, cdr: &[u8]) -> Result<()> {
        if topic.0 >= self.topics.len() {
            return Err(BagError::Usage { path: self.dir.clone(), what: format!("no topic with id {}", topic.0) });
        }
        if self.should_split(log_time) {
            self.split()?;
        }
        let (max_chunk, chunk_size, per_topic) = (self.options.max_chunk_duration_ns, self.options.chunk_size, self.options.chunk_per_topic);
        let Some(f) = self.current.as_mut() else {
            return Err(BagError::Usage { path: self.dir.clone(), what: "the bag is closed".into() });
        };
        let sequence = f.sequences[topic.0];
        f.sequences[topic.0] = sequence.wrapping_add(1);
        let channel_id = f.channels[topic.0];
        let g = if per_topic { topic.0 } else { 0 };
        if !per_topic && f.gathering[0].first.is_some_and(|s| log_time.saturating_sub(s) >= max_chunk) {
            // One chunk of every topic: closed before a message that would make it span more
            // than the longest a chunk may.
            close_chunk(f, &mut self.pipeline, 0)?;
        }
        f.gathering[g].add(channel_id, sequence, log_time, cdr);
        if f.gathering[g].chunk.records.len() as u64 >= chunk_size {
            close_chunk(f, &mut self.pipeline, g)?;
        }
        if per_topic {
            // Any topic whose chunk now spans the longest a chunk may: closed, so a crash
            // loses at most that much of each topic.
            for t in 0..f.gathering.len() {
                if f.gathering[t].first.is_some_and(|s| log_time.saturating_sub(s) >= max_chunk) {
                    close_chunk(f, &mut self.pipeline, t)?;
                }
            }
        }
        *f.channel_counts.entry(channel_id).or_default() += 1;
        f.first = Some(f.first.map_or(log_time, |t| t.min(log_time)));
        f.last = f.last.max(log_time);
        f.count += 1;
        self.counts[topic.0] += 1;
        Ok(())
    }

    /// Encodes and writes one of our messages; its type must be the topic's.
    pub fn write_message<M: RosMessage>(&mut self, topic: TopicId, log_time: u64, msg: &M) -> Result<()> {
        match self.topics.get(topic.0) {
            Some(t) if t.type_name == M::TYPE_NAME => {}
            Some(t) => {
                return Err(BagError::Usage { path: self.dir.clone(), what: format!("a {} written to {}, a {} topic", M::TYPE_NAME, t.name, t.type_name) })
            }
            None => return Err(BagError::Usage { path: self.dir.clone(), what: format!("no topic with id {}", topic.0) }),
        }
        self.write(topic, log_time, &oilfilm_msgs::encode(msg))
    }

    fn should_split(&self, log_time: u64) -> bool {
        let Some(f) = &self.current else { return false };
        if f.count == 0 {
            return false;
        }
        let by_size = self.options.split_size_bytes.is_some_and(|max| self.pipeline.file_len_bound() >= max);
        let by_time = self.options.split_duration_ns.is_some_and(|max| f.first.is_some_and(|s| log_time.saturating_sub(s) >= max));
        by_size || by_time
    }

    /// Closes the current file, rewrites metadata.yaml and opens the next file.
    pub fn split(&mut self) -> Result<()> {
        self.finish_current()?;
        self.write_metadata()?;
        self.open_next()
    }

    /// Finishes the open file and writes metadata.yaml. Returns the bag directory.
    pub fn close(mut self) -> Result<PathBuf> {
        self.finish_current()?;
        self.write_metadata()?;
        drop(self.lock.take());
        Ok(std::mem::take(&mut self.dir))
    }

    /// The files closed so far.
    pub fn files(&self) -> &[FileInfo] {
        &self.files
    }

    fn open_next(&mut self) -> Result<()> {
        let file_name = format!("{}_{}.mcap", self.name, self.files.len());
        let path = self.dir.join(&file_name);
        let file = File::create_new(&path).map_err(io(&path))?;
        let per_topic = self.options.chunk_per_topic;
        let mut f = OpenFile {
            path: path.clone(),
            channels: Vec::with_capacity(self.topics.len()),
            schema_ids: Vec::new(),
            schema_records: Vec::new(),
            channel_records: Vec::new(),
            sequences: Vec::with_capacity(self.topics.len()),
            channel_counts: BTreeMap::new(),
            first: None,
            last: 0,
            count: 0,
            gathering: Vec::new(),
        };
        let mut start = records::MAGIC.to_vec();
        records::header(&mut start, "ros2", concat!("oilfilm-bag ", env!("CARGO_PKG_VERSION")));
        for (t, hash) in self.topics.iter().zip(&self.hashes) {
            f.declare(t, hash, &mut start)?;
        }
        let gatherings = if per_topic { self.topics.len() } else { 1 };
        f.gathering = (0..gatherings).map(|_| Gathering::new(self.pipeline.take_buffer())).collect();
        self.pipeline.start_file(FileSink::new(path, file));
        self.current = Some(f);
        self.pipeline.submit_raw(start)
    }

    fn finish_current(&mut self) -> Result<()> {
        let Some(mut f) = self.current.take() else { return Ok(()) };
        // The last chunks, the earliest first.
        let mut order: Vec<(u64, usize)> = f.gathering.iter().enumerate().filter_map(|(t, g)| g.first.map(|s| (s, t))).collect();
        order.sort_unstable();
        for (_, g) in order {
            close_chunk(&mut f, &mut self.pipeline, g)?;
        }
        let mut sink = self.pipeline.finish_file()?;
        let first = f.first.unwrap_or(0);
        self.files.push(FileInfo {
            path: f.path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
            starting_time: StartingTime { nanoseconds_since_epoch: first },
            duration: NsDuration { nanoseconds: f.last.saturating_sub(first) },
            message_count: f.count,
        });
        // rosbag2's own record of the bag so far (its MCAP plugin writes one on each file's
        // close): what `ros2 bag` and `pymcap-cli doctor` look for.
        let mut entries = BTreeMap::new();
        entries.insert("serialized_metadata".to_string(), self.metadata().rosbag2_bagfile_information.to_yaml());
        entries.insert("ROS_DISTRO".to_string(), self.options.ros_distro.clone());
        let mut meta = Vec::new();
        records::metadata(&mut meta, ROSBAG2_METADATA, &entries);
        let meta_at = (sink.position(), meta.len() as u64);
        sink.put(&meta).map_err(io(&f.path))?;
        let mut end = Vec::with_capacity(16);
        records::data_end(&mut end, sink.take_crc());
        sink.put(&end).map_err(io(&f.path))?;
        let summary = f.summary(sink.position(), &sink.chunk_indexes, meta_at);
        sink.put(&summary).map_err(io(&f.path))?;
        sink.sync().map_err(io(&f.path))
    }

    /// The bag's metadata.yaml content for the files closed so far.
    fn metadata(&self) -> MetadataFile {
        let topics = self
            .topics
            .iter()
            .zip(&self.counts)
            .zip(&self.hashes)
            .map(|((t, &n), hash)| TopicWithCount {
                topic_metadata: TopicMetadata {
                    name: t.name.clone(),
                    type_name: t.type_name.clone(),
                    serialization_format: "cdr".into(),
                    offered_qos_profiles: t.qos.clone(),
                    type_description_hash: hash.clone(),
                },
                message_count: n,
            })
            .collect();
        MetadataFile::for_mcap(topics, self.files.clone(), &self.options.ros_distro)
    }

    fn write_metadata(&self) -> Result<()> {
        write_atomically(&self.dir.join(METADATA_FILE), self.metadata().to_yaml().as_bytes())
    }
}

/// Hands gathering `g`'s chunk to the pipeline (if it holds any message) and starts the next.
fn close_chunk(f: &mut OpenFile, pipeline: &mut Pipeline, g: usize) -> Result<()> {
    if f.gathering[g].first.is_none() {
        return Ok(());
    }
    let next = Gathering::new(pipeline.take_buffer());
    let closed = std::mem::replace(&mut f.gathering[g], next);
    pipeline.submit_chunk(closed.chunk)
}

impl Drop for BagWriter {
    fn drop(&mut self) {
        if self.current.is_some() {
            // Best effort: a writer dropped without close still leaves a readable bag.
            let _ = self.finish_current().and_then(|()| self.write_metadata());
        }
    }
}

/// The name of the metadata record rosbag2's MCAP plugin writes (keys `serialized_metadata`,
/// the bag's metadata.yaml content without its top-level key, and `ROS_DISTRO`).
pub const ROSBAG2_METADATA: &str = "rosbag2";

/// The MCAP channel metadata key of the RIHS01 type hash (as rosbag2_storage_mcap writes it).
pub const TYPE_HASH_KEY: &str = "topic_type_hash";

/// The RIHS01 type description hash of a topic's type, from the definitions in its schema
/// text (dependencies it leaves out, such as builtin_interfaces, from ours); empty when the
/// schema does not define the type completely: rosbags checks a hash that is present, so an
/// unknown one is left out rather than guessed.
pub fn type_hash_of(t: &TopicSpec) -> String {
    let Ok(defs) = oilfilm_msgs::type_hash::definitions_of_schema(&t.type_name, &t.schema_text) else {
        return String::new();
    };
    let lookup = |p: &str, ty: &str| defs.get(&(p.to_string(), ty.to_string())).map(String::as_str).or_else(|| oilfilm_msgs::definition(p, ty));
    oilfilm_msgs::type_hash::type_hash(&t.type_name, &lookup).unwrap_or_default()
}

/// Writes `path` through a temporary file and a rename, so a reader never sees half of it.
pub(crate) fn write_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("yaml.tmp");
    let mut f = File::create(&tmp).map_err(io(&tmp))?;
    f.write_all(bytes).map_err(io(&tmp))?;
    f.sync_data().map_err(io(&tmp))?;
    fs::rename(&tmp, path).map_err(io(path))
}
