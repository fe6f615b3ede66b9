//! The one error type of the crate. Every variant names the file it is about.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },

    /// The MCAP library refused to write or could not parse a record.
    #[error("{}: MCAP error{}: {source}", path.display(), at(*offset))]
    Mcap { path: PathBuf, offset: Option<u64>, source: mcap::McapError },

    /// The file is MCAP but not a bag we can read, or is damaged: `what` says how.
    #[error("{}{}: {what}", path.display(), at(*offset))]
    Format { path: PathBuf, offset: Option<u64>, what: String },

    /// metadata.yaml is missing, unreadable or inconsistent.
    #[error("{}: {what}", path.display())]
    Metadata { path: PathBuf, what: String },

    /// A message's CDR does not decode as its topic's type.
    /// `index` counts the file's messages, or the chunk's when `chunk_offset` names it (a
    /// reader that skips chunks does not know the file's count).
    #[error("{}: message {index}{} on {topic} (log time {log_time} ns): {source}", path.display(), chunk_offset.map(|o| format!(" of the chunk at byte {o}")).unwrap_or_default())]
    Decode { path: PathBuf, topic: String, index: u64, chunk_offset: Option<u64>, log_time: u64, source: Box<oilfilm_msgs::CdrError> },

    /// The bag holds less (or other) than it says: a damaged chunk, a file metadata.yaml
    /// does not list or lacks, a count that differs. A partial read
    /// ([`crate::ReadOptions::allow_partial`]) goes on past it.
    #[error("{}: {what}", path.display())]
    Incomplete { path: PathBuf, what: String },

    /// The caller asked for something the bag or writer cannot do (unknown topic id, a
    /// type this crate has no definition for, a message of another type).
    #[error("{}: {what}", path.display())]
    Usage { path: PathBuf, what: String },
}

fn at(offset: Option<u64>) -> String {
    offset.map(|o| format!(" at byte {o}")).unwrap_or_default()
}

pub type Result<T, E = BagError> = std::result::Result<T, E>;

pub(crate) fn io(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> BagError {
    let path = path.into();
    move |source| BagError::Io { path, source }
}

pub(crate) fn mcap_err(path: impl Into<PathBuf>) -> impl FnOnce(mcap::McapError) -> BagError {
    let path = path.into();
    move |source| BagError::Mcap { path, offset: None, source }
}
