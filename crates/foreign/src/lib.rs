//! Records from other tools, read through a channel map: LabVIEW TDMS, MATLAB .mat (level
//! 5) and CSV files become the rig's ten channels, scan by scan, in bounded memory.
//!
//! * [`map`]: the channel map (TOML): which channel of the file is which of the rig's, in
//!   what unit, scale, offset and sign, the sample rate and multiplexer schedule, the speed
//!   and temperature sources. Checked whole before a file is opened.
//! * [`tdms`], [`mat`], [`csv_file`]: the readers. Each indexes its file first (so a
//!   truncated or mis-mapped file is refused before anything is read) and then streams each
//!   channel a block at a time.
//! * [`record`]: a file opened through its map, giving blocks of scans in volts or SI.
//!
//! No ROS here: the DAQ node's foreign source (`oilfilm-graph`) makes frames and rig status
//! of the blocks. Frame: x horizontal, y vertical up (a probe facing the other way is given
//! `sign = -1` in the map).

pub mod csv_file;
pub mod error;
pub mod fixtures;
pub mod map;
pub mod mat;
pub mod record;
pub mod tdms;

pub use error::{ForeignError, Result};
pub use map::ChannelMap;
pub use record::{Block, ForeignRecord, RecordSpeed};
