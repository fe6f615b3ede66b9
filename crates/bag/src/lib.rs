//! rosbag2 bags with MCAP storage, as `ros2 bag`, rosbags and the mcap tools read them.
//!
//! * [`BagWriter`]: a bag directory of chunked (zstd, lz4 or plain) MCAP files with profile
//!   `ros2`, split by size or duration, `metadata.yaml` (version 9) written on each split and
//!   on close.
//! * [`Bag`]: reads a bag's messages (topic, type, log time, CDR bytes) in log-time order and
//!   decodes our types ([`BagMessage::decode`], [`BagMessage::decode_ours`]).
//! * [`Bag::read_topics`]: only the chunks holding the wanted topics (from the summary),
//!   decompressed and decoded on worker threads while the caller consumes them in order.
//! * [`recover`]: a bag whose writer was killed (no footer, no metadata.yaml) rewritten into a
//!   valid bag holding every message of every complete chunk.
//!
//! The parsing core is sans-IO ([`scan::scan`], [`reader::messages_of_file`],
//! [`metadata::MetadataFile`]); the writer, `Bag::open` and `recover` are the shell.
//! What a bag must look like for the readers to accept it is in issue 5's "facts found by
//! trying" and the module docs.

mod chunks;
pub mod error;
pub mod integrity;
pub mod lock;
pub mod metadata;
pub mod reader;
mod records;
pub mod recover;
pub mod scan;
pub mod select;
pub mod writer;

pub use error::{BagError, Result};
pub use integrity::{ReadOptions, Shortfall, ShortfallKind};
pub use lock::{recording_state, Recording, LOCK_FILE};
pub use metadata::{Duration, FileInfo, MetadataFile, QosProfile, StartingTime};
pub use reader::{Bag, BagMessage, OilfilmMessage};
pub use recover::{recover, FileRecovery, Recovery};
pub use select::MessageRef;
pub use writer::{BagWriter, Compression, TopicId, TopicSpec, WriterOptions};

/// The name of a bag's metadata file.
pub const METADATA_FILE: &str = "metadata.yaml";
