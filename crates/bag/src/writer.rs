//! The rosbag2 bag writer: a directory `NAME/` holding `NAME_0.mcap`, `NAME_1.mcap`, ... and
//! `metadata.yaml`, written when a file is closed (on split and on close).
//!
//! Each file is a chunked MCAP file with profile `ros2`; a chunk is closed when it reaches
//! `chunk_size` bytes or spans `max_chunk_duration_ns` of log time, and flushed to the OS
//! then, so a writer killed at any moment loses at most the chunk it was filling.
//!
//! With `chunk_per_topic` (the default) each topic's messages are gathered in memory and
//! written as chunks of that topic alone, so a reader that wants some topics (re-analysis:
//! the DAQ frames and rig status) decompresses only their chunks. A topic's chunk is closed
//! when it holds `chunk_size` bytes or once any message is `max_chunk_duration_ns` of log
//! time after its first, so a killed writer loses at most the last
//! `max_chunk_duration_ns` of each topic (one chunk per topic). ADR 0013.

use std::cell::Cell;
use std::fs::{self, File};
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::rc::Rc;

use mcap::records::MessageHeader;
use oilfilm_msgs::RosMessage;

use crate::error::{io, mcap_err, BagError, Result};
use crate::metadata::{qos_to_channel_metadata, FileInfo, MetadataFile, QosProfile, TopicMetadata, TopicWithCount};
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
    /// before each message; the open chunk is not counted until it is closed).
    pub split_size_bytes: Option<u64>,
    /// Start a new file once a message is this much log time after the file's first.
    pub split_duration_ns: Option<u64>,
    /// `ros_distro` in metadata.yaml.
    pub ros_distro: String,
    /// zstd level (negative: zstd's fast levels) or lz4 acceleration level; ignored without
    /// compression. See [`WriterOptions::DEFAULT_ZSTD_LEVEL`].
    pub compression_level: i32,
    /// zstd worker threads of the mcap crate (0: compress on the writing thread).
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
    /// zstd worker threads of the recorder: none, compression on the writing thread (ADR
    /// 0013: a chunk of 1 s is smaller than one zstd job, so workers only add hand-offs; one
    /// worker was the slowest setting in every sweep).
    pub const DEFAULT_COMPRESSION_THREADS: u32 = 0;
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

/// Tracks the length of what was written (shared with [`OpenFile`], as `mcap::Writer`
/// lends no access to its sink), so splitting by size needs no `stat`.
struct Counting<W> {
    inner: W,
    pos: u64,
    len: Rc<Cell<u64>>,
}

impl<W: Write> Write for Counting<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.pos += n as u64;
        self.len.set(self.len.get().max(self.pos));
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

impl<W: Seek> Seek for Counting<W> {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        self.pos = self.inner.seek(to)?;
        Ok(self.pos)
    }
}

struct OpenFile {
    path: PathBuf,
    writer: mcap::Writer<Counting<BufWriter<File>>>,
    /// Channel id of each topic.
    channels: Vec<u16>,
    sequences: Vec<u32>,
    first: Option<u64>,
    last: u64,
    count: u64,
    chunk_start: Option<u64>,
    len: Rc<Cell<u64>>,
    /// Each topic's messages not yet written (`chunk_per_topic`).
    pending: Vec<Pending>,
}

/// One topic's messages gathered for its next chunk: their bytes back to back.
#[derive(Default)]
struct Pending {
    data: Vec<u8>,
    /// Sequence, log time and end in `data` of each message.
    messages: Vec<(u32, u64, usize)>,
    /// The earliest log time among them.
    first: Option<u64>,
}

impl Pending {
    fn first_time(&self) -> Option<u64> {
        self.first
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
        fs::create_dir_all(&dir).map_err(io(&dir))?;
        let name = dir
            .file_name()
            .and_then(|n| n.to_str())
            .filter(|n| !n.is_empty())
            .ok_or_else(|| BagError::Usage { path: dir.clone(), what: "the bag directory needs a UTF-8 name".into() })?
            .to_string();
        let mut w = Self { dir, name, options, topics: Vec::new(), hashes: Vec::new(), counts: Vec::new(), files: Vec::new(), current: None };
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
            let ch = add_channel(&mut f.writer, &spec, &hash).map_err(mcap_err(&f.path))?;
            f.channels.push(ch);
            f.sequences.push(0);
            f.pending.push(Pending::default());
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
        if per_topic {
            let p = &mut f.pending[topic.0];
            p.data.extend_from_slice(cdr);
            p.messages.push((sequence, log_time, p.data.len()));
            p.first = Some(p.first.map_or(log_time, |t| t.min(log_time)));
            let full = p.data.len() as u64 >= chunk_size;
            if full {
                f.write_pending(topic.0)?;
            }
            // Any topic whose chunk now spans the longest a chunk may: written, so a crash
            // loses at most that much of each topic.
            for t in 0..f.pending.len() {
                if f.pending[t].first_time().is_some_and(|s| log_time.saturating_sub(s) >= max_chunk) {
                    f.write_pending(t)?;
                }
            }
        } else {
            if f.chunk_start.is_some_and(|s| log_time.saturating_sub(s) >= max_chunk) {
                f.writer.flush().map_err(mcap_err(&f.path))?;
                f.chunk_start = None;
            }
            let header = MessageHeader { channel_id: f.channels[topic.0], sequence, log_time, publish_time: log_time };
            f.writer.write_to_known_channel(&header, cdr).map_err(mcap_err(&f.path))?;
            f.chunk_start.get_or_insert(log_time);
        }
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
                return Err(BagError::Usage {
                    path: self.dir.clone(),
                    what: format!("a {} written to {}, a {} topic", M::TYPE_NAME, t.name, t.type_name),
                })
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
        let by_size = self.options.split_size_bytes.is_some_and(|max| f.writer_len() >= max);
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
        let len = Rc::new(Cell::new(0));
        let sink = Counting { inner: BufWriter::with_capacity(1 << 16, file), pos: 0, len: Rc::clone(&len) };
        let options = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("oilfilm-bag ", env!("CARGO_PKG_VERSION")))
            .compression(match self.options.compression {
                Compression::Zstd => Some(mcap::Compression::Zstd),
                Compression::Lz4 => Some(mcap::Compression::Lz4),
                Compression::None => None,
            })
            .chunk_size(Some(self.options.chunk_size))
            .compression_threads(self.options.compression_threads)
            .compression_level(level_for_mcap(self.options.compression, self.options.compression_level));
        let mut writer = options.create(sink).map_err(mcap_err(&path))?;
        let mut channels = Vec::with_capacity(self.topics.len());
        for (t, hash) in self.topics.iter().zip(&self.hashes) {
            channels.push(add_channel(&mut writer, t, hash).map_err(mcap_err(&path))?);
        }
        let sequences = vec![0; channels.len()];
        let pending = channels.iter().map(|_| Pending::default()).collect();
        self.current = Some(OpenFile { path, writer, channels, sequences, first: None, last: 0, count: 0, chunk_start: None, len, pending });
        Ok(())
    }

    fn finish_current(&mut self) -> Result<()> {
        let Some(mut f) = self.current.take() else { return Ok(()) };
        // The topics' last chunks, the earliest first.
        let mut order: Vec<(u64, usize)> = f.pending.iter().enumerate().filter_map(|(t, p)| p.first_time().map(|s| (s, t))).collect();
        order.sort_unstable();
        for (_, t) in order {
            f.write_pending(t)?;
        }
        f.writer.finish().map_err(mcap_err(&f.path))?;
        let mut sink = f.writer.into_inner();
        sink.flush().map_err(io(&f.path))?;
        sink.inner.get_ref().sync_data().map_err(io(&f.path))?;
        let first = f.first.unwrap_or(0);
        self.files.push(FileInfo {
            path: f.path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
            starting_time: StartingTime { nanoseconds_since_epoch: first },
            duration: NsDuration { nanoseconds: f.last.saturating_sub(first) },
            message_count: f.count,
        });
        Ok(())
    }

    fn write_metadata(&self) -> Result<()> {
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
        let meta = MetadataFile::for_mcap(topics, self.files.clone(), &self.options.ros_distro);
        write_atomically(&self.dir.join(METADATA_FILE), meta.to_yaml().as_bytes())
    }
}

impl OpenFile {
    /// Writes a topic's gathered messages as a chunk of their own and hands it to the OS.
    fn write_pending(&mut self, topic: usize) -> Result<()> {
        let p = &mut self.pending[topic];
        if p.messages.is_empty() {
            return Ok(());
        }
        let channel_id = self.channels[topic];
        let mut start = 0;
        for &(sequence, log_time, end) in &p.messages {
            let header = MessageHeader { channel_id, sequence, log_time, publish_time: log_time };
            self.writer.write_to_known_channel(&header, &p.data[start..end]).map_err(mcap_err(&self.path))?;
            start = end;
        }
        p.data.clear();
        p.messages.clear();
        p.first = None;
        self.writer.flush().map_err(mcap_err(&self.path))
    }

    /// Bytes written to the file so far (through the buffer).
    fn writer_len(&self) -> u64 {
        self.len.get()
    }
}

impl Drop for BagWriter {
    fn drop(&mut self) {
        if self.current.is_some() {
            // Best effort: a writer dropped without close still leaves a readable bag.
            let _ = self.finish_current().and_then(|()| self.write_metadata());
        }
    }
}

/// The level as the mcap crate takes it: a `u32` that it casts back to `i32` for zstd
/// (`zstd_encoder`: `compression_level as i32`), so a negative zstd level (a fast level)
/// goes through as its two's complement; lz4's level is a `u32` (0 = fast mode).
fn level_for_mcap(compression: Compression, level: i32) -> u32 {
    match compression {
        Compression::Zstd => level as u32,
        Compression::Lz4 | Compression::None => level.max(0) as u32,
    }
}

fn add_channel<W: Write + Seek>(w: &mut mcap::Writer<W>, t: &TopicSpec, type_hash: &str) -> mcap::McapResult<u16> {
    let schema = w.add_schema(&t.type_name, "ros2msg", t.schema_text.as_bytes())?;
    let mut metadata = std::collections::BTreeMap::new();
    metadata.insert("offered_qos_profiles".to_string(), qos_to_channel_metadata(&t.qos));
    if !type_hash.is_empty() {
        // rosbag2's MCAP storage plugin keeps the type description hash under this key.
        metadata.insert(TYPE_HASH_KEY.to_string(), type_hash.to_string());
    }
    w.add_channel(schema, &t.name, "cdr", &metadata)
}

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
