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

/// The longest name or text of the file quoted in a message, characters.
const SHOWN_CHARS: usize = 64;

/// The most names a message lists.
const LISTED: usize = 12;

/// A name or text read from the file, as a message quotes it: whole when short, else its
/// start and its length (a damaged file's "name" can be a megabyte of anything).
pub(crate) fn shown(text: &str) -> String {
    if text.chars().count() <= SHOWN_CHARS {
        return text.to_string();
    }
    let start: String = text.chars().take(SHOWN_CHARS - 4).collect();
    format!("{start}... ({} bytes)", text.len())
}

/// Names of the file for a message: the first few, and how many there are in all.
pub(crate) fn listed(names: impl IntoIterator<Item = String>) -> String {
    let names: Vec<String> = names.into_iter().collect();
    if names.len() <= LISTED {
        return names.join(", ");
    }
    format!("{}, ... ({} in all)", names[..LISTED].join(", "), names.len())
}

#[cfg(test)]
mod tests {
    use super::{listed, shown};

    #[test]
    fn long_names_and_lists_are_shortened() {
        assert_eq!(shown("probe_a_x"), "probe_a_x");
        let long = "x".repeat(5000);
        let s = shown(&long);
        assert!(s.starts_with("xxxx") && s.ends_with("... (5000 bytes)") && s.len() < 90, "{s}");
        assert_eq!(listed(["a".to_string(), "b".to_string()]), "a, b");
        let l = listed((0..100).map(|i| i.to_string()));
        assert!(l.starts_with("0, 1, 2") && l.ends_with("11, ... (100 in all)"), "{l}");
    }
}
