//! The nodes' one error type.

use thiserror::Error;

/// What can go wrong in a node. Every variant names what it is about (a parameter, a topic,
/// a frame, a file position), so a log line is enough to find the cause.
#[derive(Debug, Error)]
pub enum NodeError {
    /// A parameter (from a params file, a `-p` override or the parameter service) is invalid.
    #[error("parameter `{name}`: {reason}")]
    Parameter { name: String, reason: String },
    /// A params or launch file could not be read or parsed.
    #[error("{file}: {reason}")]
    File { file: String, reason: String },
    /// A message that cannot be used; the node skips it and goes on.
    #[error("{topic}: message {sequence}: {reason}")]
    BadMessage { topic: String, sequence: u64, reason: String },
    /// A malformed record on a DAQ source (ASCII replay or TCP stream), skipped.
    #[error("{source_name}:{line}:{column}: {reason}")]
    BadRecord { source_name: String, line: usize, column: usize, reason: String },
    /// The middleware failed (DDS participant, topic, publisher, subscription).
    #[error("ROS 2 {what}: {reason}")]
    Middleware { what: String, reason: String },
    /// A port closed (the other end of an in-memory channel went away).
    #[error("port `{0}` closed")]
    Closed(String),
    #[error(transparent)]
    Identification(#[from] oilfilm_identification::IdentificationError),
    #[error(transparent)]
    Physics(#[from] oilfilm_physics::PhysicsError),
    /// Writing or reading a bag failed (the error names the file).
    #[error(transparent)]
    Bag(#[from] oilfilm_bag::BagError),
    /// A record from another tool (TDMS, .mat, CSV) or its channel map is unusable (the
    /// error names the file, the channel and the place, or the map's key).
    #[error(transparent)]
    Foreign(#[from] oilfilm_foreign::ForeignError),
    #[error("{what}: {source}")]
    Io { what: String, source: std::io::Error },
}

impl NodeError {
    pub fn parameter(name: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::Parameter { name: name.into(), reason: reason.into() }
    }
}
