//! What a read of a bag checks beyond each record: that the directory holds the files
//! `metadata.yaml` lists and no others, that no writer is still at work on it, and that the
//! messages read per topic are the counts `metadata.yaml` states (and, per file, the counts
//! of its summary's statistics). Each difference is a [`Shortfall`]; a strict read
//! (the default) fails on the first, one with [`ReadOptions::allow_partial`] goes on and
//! returns them all, so the caller can say what is missing.

use std::collections::BTreeMap;
use std::fmt;
use std::fs;
use std::path::PathBuf;

use serde::Serialize;

use crate::error::{io, BagError, Result};
use crate::lock::{recording_state, Recording};
use crate::reader::Bag;

/// How to read a bag.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReadOptions {
    /// Go on past damaged chunks, missing or unlisted files and counts that differ,
    /// returning each as a [`Shortfall`], instead of failing on the first.
    pub allow_partial: bool,
}

impl ReadOptions {
    pub const STRICT: ReadOptions = ReadOptions { allow_partial: false };
    pub const PARTIAL: ReadOptions = ReadOptions { allow_partial: true };
}

/// What kind of difference a [`Shortfall`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ShortfallKind {
    /// A writer holds the bag's recording lock: it is still being written.
    Recording,
    /// An `.mcap` file in the directory that metadata.yaml does not list (not read).
    UnlistedFile,
    /// A file metadata.yaml lists that is not there.
    MissingFile,
    /// A file's summary fails its CRC (the file was read without it, record by record).
    SummaryCrc,
    /// A chunk that fails its CRC or does not decompress or parse: its messages are missing.
    DamagedChunk,
    /// Damage outside a chunk, or a file cut short: what lies past it may be missing.
    DamagedFile,
    /// The messages read of a topic differ from the count metadata.yaml or a file's
    /// statistics state.
    Count,
}

/// One difference between what a bag says it holds and what was read.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Shortfall {
    /// The file it is about (the bag directory or its metadata.yaml for a whole-bag count).
    pub path: PathBuf,
    pub kind: ShortfallKind,
    /// What differs or is missing, in words.
    pub what: String,
}

impl fmt::Display for Shortfall {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.what)
    }
}

impl Shortfall {
    pub(crate) fn new(path: impl Into<PathBuf>, kind: ShortfallKind, what: impl Into<String>) -> Self {
        Self { path: path.into(), kind, what: what.into() }
    }

    /// The error a strict read gives for it.
    pub(crate) fn into_error(self) -> BagError {
        BagError::Incomplete { path: self.path, what: self.what }
    }
}

/// Collects shortfalls: a strict read turns the first into an error.
#[derive(Debug, Default)]
pub(crate) struct Shortfalls {
    pub(crate) allow_partial: bool,
    pub(crate) found: Vec<Shortfall>,
}

impl Shortfalls {
    pub(crate) fn new(options: ReadOptions) -> Self {
        Self { allow_partial: options.allow_partial, found: Vec::new() }
    }

    /// Notes `s`; `Err` when the read is strict.
    pub(crate) fn note(&mut self, s: Shortfall) -> Result<()> {
        if self.allow_partial {
            if !self.found.contains(&s) {
                self.found.push(s);
            }
            Ok(())
        } else {
            Err(s.into_error())
        }
    }
}

impl Bag {
    /// The directory against metadata.yaml: a live writer, `.mcap` files it does not list,
    /// listed files that are not there.
    pub(crate) fn check_directory(&self, found: &mut Shortfalls) -> Result<()> {
        let dir = self.dir();
        if let Recording::Alive { holder } = recording_state(dir)? {
            found.note(Shortfall::new(
                dir,
                ShortfallKind::Recording,
                format!("the bag is still being recorded ({holder}): metadata.yaml describes only the files closed so far"),
            ))?;
        }
        let listed = &self.info().relative_file_paths;
        let mut present: Vec<String> = fs::read_dir(dir)
            .map_err(io(dir))?
            .filter_map(|e| e.ok())
            .filter(|e| e.path().extension().is_some_and(|x| x == "mcap") && e.path().is_file())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        present.sort();
        for name in &present {
            if !listed.contains(name) {
                found.note(Shortfall::new(
                    dir.join(name),
                    ShortfallKind::UnlistedFile,
                    format!("this file is in the bag directory but metadata.yaml does not list it (a recorder killed after a split leaves that: `oilfilm bag recover {}` lists it); its messages are not read", dir.display()),
                ))?;
            }
        }
        for name in listed {
            if !present.contains(name) {
                found.note(Shortfall::new(dir.join(name), ShortfallKind::MissingFile, "metadata.yaml lists this file, which is not in the bag directory"))?;
            }
        }
        Ok(())
    }

    /// The messages read per topic (of the topics `wanted` accepts) against metadata.yaml's
    /// counts.
    pub(crate) fn check_counts(&self, wanted: &dyn Fn(&str, &str) -> bool, read: &BTreeMap<String, u64>, found: &mut Shortfalls) -> Result<()> {
        let meta = self.dir().join(crate::METADATA_FILE);
        for t in &self.info().topics_with_message_count {
            let m = &t.topic_metadata;
            if !wanted(&m.name, &m.type_name) {
                continue;
            }
            let got = read.get(&m.name).copied().unwrap_or(0);
            if got != t.message_count {
                found.note(Shortfall::new(
                    &meta,
                    ShortfallKind::Count,
                    format!("topic {}: metadata.yaml counts {} messages, {got} were read ({})", m.name, t.message_count, difference(t.message_count, got)),
                ))?;
            }
        }
        for (topic, &got) in read {
            if !self.info().topics_with_message_count.iter().any(|t| t.topic_metadata.name == *topic) {
                found.note(Shortfall::new(
                    &meta,
                    ShortfallKind::Count,
                    format!("topic {topic}: {got} messages were read, metadata.yaml does not list the topic"),
                ))?;
            }
        }
        Ok(())
    }
}

/// `n missing` or `n more than listed`.
pub(crate) fn difference(expected: u64, got: u64) -> String {
    if got < expected {
        format!("{} missing", expected - got)
    } else {
        format!("{} more than stated", got - expected)
    }
}
