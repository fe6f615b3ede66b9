//! The one error type of the crate: every message names the file, and where it can, the
//! channel and the position in the file (byte, segment, row) or the map's key.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum ForeignError {
    /// The channel map is not valid: `key` is the dotted TOML path (`channel[3].unit`).
    #[error("{}: {key}: {message}", map.display())]
    Map { map: PathBuf, key: String, message: String },

    /// The record file is not what the map says, or not a valid file of its format.
    /// `channel` is the file's channel (and the rig channel it maps to), `position` where in
    /// the file (byte offset, segment, row and column).
    #[error("{}: {}{}{message}", file.display(), position.as_deref().map(|p| format!("{p}: ")).unwrap_or_default(), channel.as_deref().map(|c| format!("{c}: ")).unwrap_or_default())]
    Record { file: PathBuf, channel: Option<String>, position: Option<String>, message: String },

    #[error("{}: {source}", what)]
    Io { what: String, source: std::io::Error },
}

pub type Result<T, E = ForeignError> = std::result::Result<T, E>;

impl ForeignError {
    pub(crate) fn record(file: &std::path::Path, channel: Option<String>, position: Option<String>, message: impl Into<String>) -> Self {
        ForeignError::Record { file: file.to_path_buf(), channel, position, message: message.into() }
    }

    pub(crate) fn io(what: impl Into<String>, source: std::io::Error) -> Self {
        ForeignError::Io { what: what.into(), source }
    }
}
