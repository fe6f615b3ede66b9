//! Recovery of a bag whose writer was killed: its last file has no summary, footer or end
//! magic (and may end mid-chunk) and there is no metadata.yaml (or only one from before the
//! last split).
//!
//! Every `*.mcap` file of the directory is read with [`crate::scan::scan`], which skips a
//! damaged chunk and resynchronises on the next good record. A complete, undamaged file is
//! kept as it is. A damaged or cut one is rewritten (same schemas, channels, ids, sequence
//! numbers and times, and rosbag2's metadata record) from every message of its intact
//! chunks, and the original is kept beside it as `NAME_k.mcap.damaged`: nothing recorded is
//! deleted. Then metadata.yaml is written from what the files hold.
//!
//! A bag whose writer is alive (its recording lock held, [`crate::lock`]) is refused: moving
//! its files would pull them from under it.

use std::collections::BTreeMap;
use std::fs::{self, File};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use mcap::records::MessageHeader;

use crate::error::{io, mcap_err, BagError, Result};
use crate::lock::{recording_state, remove_stale, Recording};
use crate::metadata::{parse_qos_text, FileInfo, MetadataFile, TopicMetadata, TopicWithCount};
use crate::scan::{scan, Damage, ScanStop, ScannedFile};
use crate::writer::write_atomically;
use crate::{Duration, StartingTime, METADATA_FILE};

/// What recovery did to one file.
#[derive(Debug, Clone, PartialEq)]
pub struct FileRecovery {
    pub path: PathBuf,
    /// Messages the file holds now.
    pub messages: u64,
    /// Complete chunks kept.
    pub chunks: usize,
    /// Where the damaged original was moved, if the file was rewritten or dropped.
    pub original: Option<PathBuf>,
    /// Why the original could not be read to its end, if it could not: its first problem.
    pub stop: Option<ScanStop>,
    /// Every damaged place of the original, skipped (`stop` is the first of these or the
    /// place the file was cut).
    pub damage: Vec<Damage>,
    /// The file held not even an MCAP header and is left out of the bag.
    pub dropped: bool,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Recovery {
    pub files: Vec<FileRecovery>,
    pub metadata: MetadataFile,
}

impl Recovery {
    pub fn messages(&self) -> u64 {
        self.files.iter().map(|f| f.messages).sum()
    }
}

/// Makes `dir` a valid bag again (see the module docs). Running it on a sound bag rewrites
/// only metadata.yaml, with the same content.
pub fn recover(dir: impl AsRef<Path>) -> Result<Recovery> {
    let dir = dir.as_ref();
    if let Recording::Alive { holder } = recording_state(dir)? {
        return Err(BagError::Usage {
            path: dir.to_path_buf(),
            what: format!("the bag is still being recorded ({holder}); stop the recorder first (it closes the bag itself), then recover only if it was killed"),
        });
    }
    let mut paths: Vec<PathBuf> = fs::read_dir(dir)
        .map_err(io(dir))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "mcap") && p.is_file())
        .collect();
    if paths.is_empty() {
        return Err(BagError::Usage { path: dir.to_path_buf(), what: "no .mcap file to recover".into() });
    }
    paths.sort_by_key(|p| split_order(p));

    let mut files = Vec::new();
    let mut infos = Vec::new();
    // Topic name -> (metadata, count), in order of first appearance.
    let mut topics: Vec<(TopicMetadata, u64)> = Vec::new();
    let mut distro = String::from("kilted");
    if let Ok(old) = fs::read_to_string(dir.join(METADATA_FILE)) {
        if let Ok(m) = MetadataFile::parse(&old) {
            distro = m.rosbag2_bagfile_information.ros_distro;
        }
    }
    // First what every file holds (the metadata of the whole bag goes into each rewritten
    // file), then the rewriting, one file in memory at a time.
    for path in paths {
        let bytes = fs::read(&path).map_err(io(&path))?;
        let scanned = scan(&bytes);
        drop(bytes);
        let report = FileRecovery {
            path: path.clone(),
            messages: scanned.messages.len() as u64,
            chunks: scanned.chunks,
            original: None,
            stop: scanned.stop.clone(),
            damage: scanned.damage.clone(),
            dropped: scanned.profile.is_none() && scanned.messages.is_empty(),
        };
        if !report.dropped {
            add_topics(&path, &scanned, &mut topics)?;
            infos.push(file_info(&path, &scanned));
        }
        files.push(report);
    }
    let topics = topics.into_iter().map(|(topic_metadata, message_count)| TopicWithCount { topic_metadata, message_count }).collect();
    let metadata = MetadataFile::for_mcap(topics, infos, &distro);
    for report in &mut files {
        let path = report.path.clone();
        if report.dropped {
            report.original = Some(set_aside(&path)?);
            report.messages = 0;
            continue;
        }
        let sound = report.stop.is_none();
        if !sound {
            let bytes = fs::read(&path).map_err(io(&path))?;
            let scanned = scan(&bytes);
            drop(bytes);
            let tmp = path.with_extension("mcap.recovering");
            rewrite(&tmp, &scanned, &metadata)?;
            report.original = Some(set_aside(&path)?);
            fs::rename(&tmp, &path).map_err(io(&path))?;
        }
    }
    write_atomically(&dir.join(METADATA_FILE), metadata.to_yaml().as_bytes())?;
    remove_stale(dir)?;
    Ok(Recovery { files, metadata })
}

/// `NAME_12.mcap` sorts by 12, then by name.
fn split_order(p: &Path) -> (u64, String) {
    let stem = p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let n = stem.rsplit('_').next().and_then(|n| n.parse().ok()).unwrap_or(u64::MAX);
    (n, stem)
}

/// Moves a damaged file to `FILE.damaged`, refusing to overwrite an earlier one.
fn set_aside(path: &Path) -> Result<PathBuf> {
    let mut to = path.as_os_str().to_owned();
    to.push(".damaged");
    let to = PathBuf::from(to);
    if to.exists() {
        return Err(BagError::Usage { path: to, what: "a damaged original from an earlier recovery is in the way; move it first".into() });
    }
    fs::rename(path, &to).map_err(io(path))?;
    Ok(to)
}

fn rewrite(tmp: &Path, s: &ScannedFile, bag: &MetadataFile) -> Result<()> {
    let file = File::create(tmp).map_err(io(tmp))?;
    // A file whose header was lost but whose chunks were read is a rosbag2 file still.
    let options = mcap::WriteOptions::new().profile(s.profile.clone().unwrap_or_else(|| "ros2".into())).library(concat!(
        "oilfilm-bag ",
        env!("CARGO_PKG_VERSION"),
        " (recovered)"
    ));
    let mut w = options.create(BufWriter::new(file)).map_err(mcap_err(tmp))?;
    for (&id, schema) in &s.schemas {
        w.add_schema_with_id(id, &schema.name, &schema.encoding, &schema.data).map_err(mcap_err(tmp))?;
    }
    for (&id, c) in &s.channels {
        w.add_channel_with_id(id, c.schema_id, &c.topic, &c.message_encoding, &c.metadata).map_err(mcap_err(tmp))?;
    }
    for m in &s.messages {
        let header = MessageHeader { channel_id: m.channel_id, sequence: m.sequence, log_time: m.log_time, publish_time: m.publish_time };
        w.write_to_known_channel(&header, &m.data).map_err(mcap_err(tmp))?;
    }
    let mut entries = BTreeMap::new();
    entries.insert("serialized_metadata".to_string(), bag.rosbag2_bagfile_information.to_yaml());
    entries.insert("ROS_DISTRO".to_string(), bag.rosbag2_bagfile_information.ros_distro.clone());
    w.write_metadata(&mcap::records::Metadata { name: crate::writer::ROSBAG2_METADATA.into(), metadata: entries }).map_err(mcap_err(tmp))?;
    w.finish().map_err(mcap_err(tmp))?;
    let mut sink = w.into_inner();
    sink.flush().map_err(io(tmp))?;
    sink.get_ref().sync_data().map_err(io(tmp))
}

fn add_topics(path: &Path, s: &ScannedFile, topics: &mut Vec<(TopicMetadata, u64)>) -> Result<()> {
    let mut counts: BTreeMap<u16, u64> = BTreeMap::new();
    for m in &s.messages {
        *counts.entry(m.channel_id).or_default() += 1;
    }
    for (id, c) in &s.channels {
        let type_name = s.schemas.get(&c.schema_id).map(|x| x.name.clone()).unwrap_or_default();
        let qos = parse_qos_text(c.metadata.get("offered_qos_profiles").map(String::as_str).unwrap_or("")).map_err(|what| BagError::Format {
            path: path.to_path_buf(),
            offset: None,
            what: format!("channel {}: {what}", c.topic),
        })?;
        let n = counts.get(id).copied().unwrap_or(0);
        match topics.iter_mut().find(|(t, _)| t.name == c.topic) {
            Some((_, count)) => *count += n,
            None => topics.push((
                TopicMetadata {
                    name: c.topic.clone(),
                    type_name,
                    serialization_format: c.message_encoding.clone(),
                    offered_qos_profiles: qos,
                    type_description_hash: c.metadata.get(crate::writer::TYPE_HASH_KEY).cloned().unwrap_or_default(),
                },
                n,
            )),
        }
    }
    Ok(())
}

fn file_info(path: &Path, s: &ScannedFile) -> FileInfo {
    let first = s.messages.iter().map(|m| m.log_time).min().unwrap_or(0);
    let last = s.messages.iter().map(|m| m.log_time).max().unwrap_or(0);
    FileInfo {
        path: path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
        starting_time: StartingTime { nanoseconds_since_epoch: first },
        duration: Duration { nanoseconds: last - first },
        message_count: s.messages.len() as u64,
    }
}
