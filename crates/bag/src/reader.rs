//! Reading a rosbag2 MCAP bag: metadata.yaml, then each file's messages in log-time order.
//!
//! The checks ([`messages_of_file`]) are a pure function of a file's bytes; [`Bag`] is the
//! thin shell that reads the directory.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use oilfilm_msgs::{CoefficientEstimate, ConditionedFrame, DaqFrame, ExciterCommand, ParameterEvent, RigStatus, RosMessage};

use crate::error::{io, BagError, Result};
use crate::integrity::{difference, ReadOptions, Shortfall, ShortfallKind, Shortfalls};
use crate::metadata::{BagInfo, MetadataFile};
use crate::scan::scan;
use crate::METADATA_FILE;

/// One message of a bag.
#[derive(Debug, Clone, PartialEq)]
pub struct BagMessage {
    pub topic: Arc<str>,
    /// `pkg/msg/Type`.
    pub type_name: Arc<str>,
    /// Nanoseconds since the epoch.
    pub log_time: u64,
    pub publish_time: u64,
    /// CDR with its 4-byte encapsulation header.
    pub data: Vec<u8>,
    /// The file it came from and its index there (file order), for errors.
    pub file: Arc<Path>,
    pub index: u64,
}

/// One of our message types, decoded. (Sizes differ as the messages do; a box per
/// message would buy nothing for values read once.)
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum OilfilmMessage {
    ExciterCommand(ExciterCommand),
    DaqFrame(DaqFrame),
    ConditionedFrame(ConditionedFrame),
    CoefficientEstimate(CoefficientEstimate),
    RigStatus(RigStatus),
    /// `/parameter_events`, which our recorder keeps with the graph's topics: the nodes'
    /// parameters.
    ParameterEvent(ParameterEvent),
}

impl BagMessage {
    /// Decodes the message as `M`, which must be its type.
    pub fn decode<M: RosMessage>(&self) -> Result<M> {
        if *self.type_name != *M::TYPE_NAME {
            return Err(BagError::Usage {
                path: self.file.to_path_buf(),
                what: format!("message {} on {} is a {}, not a {}", self.index, self.topic, self.type_name, M::TYPE_NAME),
            });
        }
        oilfilm_msgs::decode(&self.data).map_err(|source| BagError::Decode {
            path: self.file.to_path_buf(),
            topic: self.topic.to_string(),
            index: self.index,
            chunk_offset: None,
            log_time: self.log_time,
            source: Box::new(source),
        })
    }

    /// Decodes one of our types; other types are an error naming the type.
    pub fn decode_ours(&self) -> Result<OilfilmMessage> {
        Ok(match &*self.type_name {
            ExciterCommand::TYPE_NAME => OilfilmMessage::ExciterCommand(self.decode()?),
            DaqFrame::TYPE_NAME => OilfilmMessage::DaqFrame(self.decode()?),
            ConditionedFrame::TYPE_NAME => OilfilmMessage::ConditionedFrame(self.decode()?),
            CoefficientEstimate::TYPE_NAME => OilfilmMessage::CoefficientEstimate(self.decode()?),
            RigStatus::TYPE_NAME => OilfilmMessage::RigStatus(self.decode()?),
            ParameterEvent::TYPE_NAME => OilfilmMessage::ParameterEvent(self.decode()?),
            other => {
                return Err(BagError::Format {
                    path: self.file.to_path_buf(),
                    offset: None,
                    what: format!("message {} on {}: type {other} is not an oilfilm_msgs type", self.index, self.topic),
                })
            }
        })
    }
}

/// A bag opened for reading.
#[derive(Debug, Clone)]
pub struct Bag {
    dir: PathBuf,
    metadata: MetadataFile,
}

impl Bag {
    /// Reads `dir/metadata.yaml`. A bag without one (its writer was killed) must be
    /// recovered first: the error says so.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        let meta_path = dir.join(METADATA_FILE);
        let text = match fs::read_to_string(&meta_path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                let hint = if dir.is_dir() {
                    "no metadata.yaml: not a bag, or its writer was killed before closing it (`oilfilm bag recover DIR` rewrites it)"
                } else {
                    "no such bag directory"
                };
                return Err(BagError::Metadata { path: meta_path, what: hint.into() });
            }
            Err(e) => return Err(io(meta_path)(e)),
        };
        let metadata = MetadataFile::parse(&text).map_err(|what| BagError::Metadata { path: meta_path.clone(), what })?;
        for f in &metadata.rosbag2_bagfile_information.relative_file_paths {
            if Path::new(f).components().any(|c| !matches!(c, std::path::Component::Normal(_))) {
                return Err(BagError::Metadata { path: meta_path, what: format!("file `{f}` is not a plain name inside the bag") });
            }
        }
        Ok(Self { dir, metadata })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn info(&self) -> &BagInfo {
        &self.metadata.rosbag2_bagfile_information
    }

    /// The bag's files, in order.
    pub fn files(&self) -> Vec<PathBuf> {
        self.info().relative_file_paths.iter().map(|f| self.dir.join(f)).collect()
    }

    /// Every message of the bag: file by file (in metadata.yaml's order), each file's in
    /// log-time order (file order among equal times). A strict read: see
    /// [`Bag::messages_with`].
    pub fn messages(&self) -> Result<Vec<BagMessage>> {
        self.messages_with(ReadOptions::STRICT).map(|(m, _)| m)
    }

    /// [`Bag::messages`] with `options`, checked as [`Bag::read_topics_with`] checks (the
    /// directory, every record, the counts per topic against metadata.yaml and per file
    /// against its entry there). A partial read skips damage and unreadable files and
    /// returns every difference.
    pub fn messages_with(&self, options: ReadOptions) -> Result<(Vec<BagMessage>, Vec<Shortfall>)> {
        let mut found = Shortfalls::new(options);
        self.check_directory(&mut found)?;
        let mut out = Vec::new();
        let mut per_topic: BTreeMap<String, u64> = BTreeMap::new();
        for (path, listed) in self.files().into_iter().zip(&self.info().files) {
            let bytes = match fs::read(&path) {
                Ok(b) => b,
                // A missing file was noted by check_directory (a strict read stopped there).
                Err(e) if e.kind() == std::io::ErrorKind::NotFound && options.allow_partial => continue,
                Err(e) => return Err(io(&path)(e)),
            };
            let (messages, damage) = read_file(&path, &bytes, options.allow_partial)?;
            for d in damage {
                found.note(d)?;
            }
            if messages.len() as u64 != listed.message_count {
                found.note(Shortfall::new(
                    &path,
                    ShortfallKind::Count,
                    format!(
                        "metadata.yaml counts {} messages in this file, {} were read ({})",
                        listed.message_count,
                        messages.len(),
                        difference(listed.message_count, messages.len() as u64)
                    ),
                ))?;
            }
            for m in &messages {
                *per_topic.entry(m.topic.to_string()).or_default() += 1;
            }
            out.extend(messages);
        }
        self.check_counts(&|_, _| true, &per_topic, &mut found)?;
        Ok((out, found.found))
    }
}

/// The messages of one MCAP file of a bag, in log-time order, after checking it is a
/// complete `ros2`-profile file with CDR channels and ROS 2 schemas.
pub fn messages_of_file(path: &Path, bytes: &[u8]) -> Result<Vec<BagMessage>> {
    read_file(path, bytes, false).map(|(m, _)| m)
}

/// [`messages_of_file`], or with `allow_partial` the messages of every intact chunk with a
/// shortfall for each damaged place (and for a file cut short). A foreign profile or
/// channels that are not CDR are errors either way.
pub(crate) fn read_file(path: &Path, bytes: &[u8], allow_partial: bool) -> Result<(Vec<BagMessage>, Vec<Shortfall>)> {
    let scanned = scan(bytes);
    let format = |offset: Option<u64>, what: String| BagError::Format { path: path.to_path_buf(), offset, what };
    match scanned.profile.as_deref() {
        Some("ros2") => {}
        Some(other) => return Err(format(None, format!("MCAP profile is `{other}`, not `ros2`: not a rosbag2 file"))),
        None => {}
    }
    let mut shortfalls = Vec::new();
    if allow_partial && scanned.profile.is_some() {
        for d in &scanned.damage {
            if d.crc_only {
                let kind = if d.what.starts_with("summary CRC") { ShortfallKind::SummaryCrc } else { ShortfallKind::DamagedFile };
                shortfalls.push(Shortfall::new(path, kind, d.what.clone()));
                continue;
            }
            let kind = if d.log_times.is_some() { ShortfallKind::DamagedChunk } else { ShortfallKind::DamagedFile };
            let times = d.log_times.map(|(a, b)| format!(" (log times {a}..={b} ns)")).unwrap_or_default();
            let resumed = match d.resumed_at {
                Some(r) => format!("reading went on at byte {r}"),
                None => "nothing after it could be read".into(),
            };
            shortfalls.push(Shortfall::new(path, kind, format!("bad record at byte {}{times}: {}; {resumed}", d.offset, d.what)));
        }
        if let Some(at) = scanned.truncated_at {
            shortfalls.push(Shortfall::new(
                path,
                ShortfallKind::DamagedFile,
                format!("the file ends early at byte {at} (its writer was killed?): what it held after its last complete chunk is missing; `oilfilm bag recover` rewrites it"),
            ));
        }
    } else if let Some(stop) = &scanned.stop {
        let what = if stop.truncated {
            format!(
                "the file ends early ({}) after {} complete chunks: its writer was probably killed; `oilfilm bag recover DIR` keeps every complete chunk",
                stop.what, scanned.chunks
            )
        } else {
            stop.what.clone()
        };
        return Err(format(Some(stop.offset), what));
    }
    if scanned.profile.is_none() {
        return Err(format(Some(0), "no MCAP header".into()));
    }
    let file: Arc<Path> = Arc::from(path);
    let mut channels = std::collections::BTreeMap::new();
    for (&id, c) in &scanned.channels {
        if c.message_encoding != "cdr" {
            return Err(format(None, format!("topic {} has message encoding `{}`, not cdr", c.topic, c.message_encoding)));
        }
        let schema = scanned.schemas.get(&c.schema_id).ok_or_else(|| format(None, format!("topic {} has no schema", c.topic)))?;
        if schema.encoding != "ros2msg" && schema.encoding != "ros2idl" {
            return Err(format(None, format!("topic {}: schema encoding `{}` is not ros2msg or ros2idl", c.topic, schema.encoding)));
        }
        channels.insert(id, (Arc::<str>::from(c.topic.as_str()), Arc::<str>::from(schema.name.as_str())));
    }
    let mut out: Vec<BagMessage> = Vec::with_capacity(scanned.messages.len());
    for (index, m) in scanned.messages.into_iter().enumerate() {
        // scan() refuses a message on an undeclared channel, so the lookup succeeds; an
        // error, not a panic, should that ever change.
        let (topic, type_name) = channels.get(&m.channel_id).ok_or_else(|| format(None, format!("message {index} is on unknown channel {}", m.channel_id)))?;
        out.push(BagMessage {
            topic: Arc::clone(topic),
            type_name: Arc::clone(type_name),
            log_time: m.log_time,
            publish_time: m.publish_time,
            data: m.data,
            file: Arc::clone(&file),
            index: index as u64,
        });
    }
    out.sort_by_key(|m| m.log_time); // stable: file order among equal times
    Ok((out, shortfalls))
}
