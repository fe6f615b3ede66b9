//! The DAQ node's line sources: an ASCII record replayed from a file, or a live TCP stream
//! from an external acquisition process, both in the ASCII record format v1
//! ([`oilfilm_identification::ascii`]). The core here takes lines (the shell reads them
//! from the file or the socket: [`crate::lines::read_lines`]) and gives [`DaqFrame`]s of
//! `block_scans` consecutive scans, each followed by a [`RigStatus`]. No I/O, no clock.
//!
//! ## The TCP wire format
//!
//! The acquisition process listens on `host:port` (the node's `address` parameter); the
//! node connects to it. The stream is exactly an ASCII record, format v1, sent line by
//! line (UTF-8, LF or CR LF line ends): the format line `# oilfilm-ascii 1`, the header
//! lines, the column line, then one data row per scan for as long as the acquisition runs.
//! Nothing goes from the node to the process. Every connection starts with a complete
//! header; scan indices continue across connections when the acquisition does (a jump in
//! them is a gap, which the frames show). When the connection drops, the node flushes the
//! scans it has as a shorter frame, reconnects with a growing back-off and expects a new
//! header; a line cut by the drop is discarded.
//!
//! ## Frames
//!
//! * `first_scan` is the scan index of the frame's first row; a frame holds consecutive
//!   scans only: a gap in the scan indices ends a frame early, so the frames' `first_scan`
//!   shows the gap (the conditioner restarts its stream there and says so).
//! * Stamp of scan `n`: `start_time_s` of the header + `n / sample_rate_hz` (integer
//!   nanoseconds, [`Stamp`]), or the `start_stamp_ns` parameter for scan 0 when set.
//! * Units (`VOLTS` or `SI`), channel names, units and offsets, rig name: from the header.
//! * The status after each frame is stamped at the start of the next scan; its speed is the
//!   `speed_rpm` parameter, else the header's `speed_rpm`, else the rig file's; its static
//!   load is the mean of channel `f3` over the frame and its temperature the mean of channel
//!   `temperature` (converted with the rig's calibration when the record is in volts).
//!
//! ## Bad input
//!
//! Header errors are fatal for the stream ([`NodeError::BadRecord`] from
//! [`ReplayCore::push_line`]): it cannot be interpreted. A malformed data row is reported
//! ([`Produced::bad_row`], `source:line:column: reason`), counted and skipped; nothing
//! already read is lost and the stream goes on.

use oilfilm_identification::ascii::{Fed, Header as AsciiHeader, LineReader, Row, Units};
use oilfilm_identification::IdentificationError;
use oilfilm_msgs::{DaqFrame, Header, RigStatus, BEARING_FRAME_ID};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::{Calibration, ChannelId};

use crate::daq::DaqParams;
use crate::error::NodeError;
use crate::lines::MAX_LINE_BYTES;
use crate::stamp::Stamp;

/// What one line (or the end of a stream) gave.
#[derive(Debug, Default)]
pub struct Produced {
    /// Completed frames, each with the rig status after it, in order.
    pub frames: Vec<(DaqFrame, RigStatus)>,
    /// The line's problem when it was a malformed row (skipped) or a row after missing
    /// scans (kept): a [`NodeError::BadRecord`] naming the source, line and column.
    pub bad_row: Option<NodeError>,
}

/// The stream a header describes.
struct Stream {
    header: AsciiHeader,
    epoch: Stamp,
    units: u8,
    channel_units: Vec<String>,
    offsets_s: Vec<f64>,
    /// Positions of channels f3 and temperature in a row.
    f3: Option<usize>,
    temperature: Option<usize>,
    speed_rpm: f64,
    speed_note: &'static str,
}

/// Scans of the frame being filled.
struct Block {
    first_scan: u64,
    scans: usize,
    values: Vec<f64>,
}

/// The ASCII-replay / TCP source of the DAQ node.
pub struct ReplayCore {
    reader: LineReader,
    kind: &'static str,
    block_scans: usize,
    speed_param_rpm: f64,
    rig_speed_rpm: f64,
    rig_name: String,
    calibration: Calibration,
    start_override: Option<Stamp>,
    stream: Option<Stream>,
    block: Option<Block>,
    sequence: u64,
    malformed: u64,
    gaps: u64,
}

/// The identification crate's parse error as the node's.
fn bad_record(e: IdentificationError) -> NodeError {
    match e {
        IdentificationError::Parse { file, line, column, message } => NodeError::BadRecord { source_name: file, line, column, reason: message },
        other => NodeError::Identification(other),
    }
}

impl ReplayCore {
    /// A source reading the lines of `source_name` (a file path, or the address and
    /// connection for TCP: it labels every report). `kind` says what it is in the status
    /// (`ascii replay`, `tcp stream`).
    pub fn new(rig: &RigConfig, params: &DaqParams, kind: &'static str, source_name: &str) -> Result<Self, NodeError> {
        params.validate()?;
        Ok(Self {
            reader: LineReader::new(source_name),
            kind,
            block_scans: params.block_scans as usize,
            speed_param_rpm: params.speed_rpm,
            rig_speed_rpm: rig.operating.speed_rpm,
            rig_name: rig.name.clone(),
            calibration: rig.daq.calibration(),
            start_override: (params.start_stamp_ns != 0).then_some(Stamp(params.start_stamp_ns)),
            stream: None,
            block: None,
            sequence: 0,
            malformed: 0,
            gaps: 0,
        })
    }

    /// Malformed rows skipped so far.
    pub fn malformed_rows(&self) -> u64 {
        self.malformed
    }

    /// Gaps (rows after missing scans) so far.
    pub fn gaps(&self) -> u64 {
        self.gaps
    }

    /// The header of the current stream, once read.
    pub fn header(&self) -> Option<&AsciiHeader> {
        self.reader.header()
    }

    /// The label of the current stream's reports.
    pub fn source_name(&self) -> &str {
        self.reader.file_name()
    }

    /// Line `number` (1-based) of the stream. `Err` only for a header error: the stream
    /// cannot be interpreted (every later line gives the same error).
    pub fn push_line(&mut self, number: usize, line: &str) -> Result<Produced, NodeError> {
        let mut out = Produced::default();
        match self.reader.feed(number, line).map_err(bad_record)? {
            Fed::Nothing => {}
            Fed::Header(header) => self.start(header),
            Fed::Row(row) => self.push_row(row, &mut out),
            Fed::Gap { row, gap } => {
                self.gaps += 1;
                out.bad_row = Some(bad_record(gap));
                self.flush(&mut out);
                self.push_row(row, &mut out);
            }
            Fed::Bad(e) => {
                self.malformed += 1;
                out.bad_row = Some(bad_record(e));
            }
        }
        Ok(out)
    }

    /// Line `number` was longer than [`MAX_LINE_BYTES`] (and only that much of it was kept):
    /// a data row is reported and skipped as malformed, as any bad row is; in the header it is
    /// fatal, as any header error is. Its end was not read, so it is not read at all: a row
    /// cut there could look whole.
    pub fn push_cut_line(&mut self, number: usize) -> Result<Produced, NodeError> {
        let e = NodeError::BadRecord {
            source_name: self.source_name().to_string(),
            line: number,
            column: MAX_LINE_BYTES + 1,
            reason: format!("the line is longer than {MAX_LINE_BYTES} bytes: refused, and nothing of it past that was kept"),
        };
        if self.reader.header().is_none() {
            return Err(e);
        }
        self.malformed += 1;
        Ok(Produced { frames: Vec::new(), bad_row: Some(e) })
    }

    /// The end of the stream (end of file, connection closed) after line `last_line`: the
    /// scans not yet published, as a shorter frame. `Err` when the stream ended before its
    /// header was complete (or the header was refused).
    pub fn end_of_stream(&mut self, last_line: usize) -> Result<Produced, NodeError> {
        let mut out = Produced::default();
        self.flush(&mut out);
        self.reader.finish(last_line).map_err(bad_record)?;
        Ok(out)
    }

    /// A new stream (a new TCP connection) labelled `source_name`: expects a new header.
    /// Gives the scans of the old stream not yet published, if any. Frame sequence numbers
    /// go on.
    pub fn restart(&mut self, source_name: &str) -> Produced {
        let mut out = Produced::default();
        self.flush(&mut out);
        self.reader = LineReader::new(source_name);
        self.stream = None;
        out
    }

    /// Frames produced so far.
    pub fn frames(&self) -> u64 {
        self.sequence
    }

    fn start(&mut self, header: AsciiHeader) {
        let position = |c: ChannelId| header.channels.iter().position(|n| n == c.name());
        let (speed_rpm, speed_note) = match header.speed_rpm {
            _ if self.speed_param_rpm > 0.0 => (self.speed_param_rpm, "speed from the speed_rpm parameter"),
            Some(s) => (s, "speed from the record's header"),
            None => (self.rig_speed_rpm, "speed not in the record: the rig file's speed assumed"),
        };
        let (units, channel_units) = match header.units {
            Units::Volts => (DaqFrame::UNITS_VOLTS, vec!["V".to_string(); header.channels.len()]),
            Units::Si => (DaqFrame::UNITS_SI, header.channels.iter().map(|n| ChannelId::parse(n).map_or("", ChannelId::unit).to_string()).collect()),
        };
        let epoch = self.start_override.unwrap_or(Stamp((header.start_time_s * 1e9).round() as i64));
        self.stream = Some(Stream {
            epoch,
            units,
            channel_units,
            // Every position below the channel count has an offset.
            offsets_s: (0..header.channels.len()).map(|p| header.channel_offset_s(p).unwrap_or(0.0)).collect(),
            f3: position(ChannelId::F3),
            temperature: position(ChannelId::Temperature),
            speed_rpm,
            speed_note,
            header,
        });
    }

    fn push_row(&mut self, row: Row, out: &mut Produced) {
        let block =
            self.block.get_or_insert_with(|| Block { first_scan: row.scan_index, scans: 0, values: Vec::with_capacity(self.block_scans * row.values.len()) });
        block.values.extend_from_slice(&row.values);
        block.scans += 1;
        if block.scans >= self.block_scans {
            self.flush(out);
        }
    }

    /// Publishes the scans of the frame being filled, if any.
    fn flush(&mut self, out: &mut Produced) {
        let (Some(block), Some(s)) = (self.block.take(), self.stream.as_ref()) else { return };
        let rate = s.header.sample_rate_hz;
        // A header has its ten channels (the reader checks), so `width` > 0 and every channel
        // position is below it: the chunks and `scan[p]` below are in range.
        let width = s.header.channels.len();
        let scan_stamp = |scan: u64| s.epoch.after_samples(i64::try_from(scan).unwrap_or(i64::MAX), rate);
        let mean_si = |position: Option<usize>, channel: ChannelId| {
            let Some(p) = position else { return f64::NAN };
            let sum: f64 = block
                .values
                .chunks_exact(width)
                .map(|scan| {
                    let v = scan[p];
                    match s.header.units {
                        Units::Si => v,
                        Units::Volts => self.calibration.to_si(channel, v).unwrap_or(f64::NAN),
                    }
                })
                .sum();
            sum / block.scans as f64
        };
        let static_load_n = mean_si(s.f3, ChannelId::F3).abs();
        let temperature_c = mean_si(s.temperature, ChannelId::Temperature);
        let frame = DaqFrame {
            header: Header { stamp: scan_stamp(block.first_scan).to_time(), frame_id: BEARING_FRAME_ID.into() },
            sequence: self.sequence,
            first_scan: block.first_scan,
            sample_rate_hz: rate,
            units: s.units,
            channel_names: s.header.channels.clone(),
            channel_units: s.channel_units.clone(),
            channel_offsets_s: s.offsets_s.clone(),
            scan_count: block.scans as u32,
            rig: s.header.rig.clone(),
            values: block.values,
            // An ASCII record holds volts or SI, whatever card wrote it: they go as they are.
            volts_per_count: Vec::new(),
            counts: Vec::new(),
        };
        self.sequence += 1;
        let mut message = format!("{} of {}; {}", self.kind, self.reader.file_name(), s.speed_note);
        if s.header.units == Units::Volts && s.header.rig != self.rig_name {
            message.push_str(&format!("; the record is from rig `{}`, its volts are converted with rig `{}`'s calibration", s.header.rig, self.rig_name));
        }
        if self.malformed > 0 {
            message.push_str(&format!("; {} malformed row(s) skipped", self.malformed));
        }
        if self.gaps > 0 {
            message.push_str(&format!("; {} gap(s) in the scan indices", self.gaps));
        }
        let status = RigStatus {
            header: Header { stamp: scan_stamp(block.first_scan.saturating_add(block.scans as u64)).to_time(), frame_id: BEARING_FRAME_ID.into() },
            speed_rad_s: s.speed_rpm * std::f64::consts::PI / 30.0,
            static_load_n,
            bearing_temperature_degc: temperature_c,
            state: RigStatus::STATE_RUNNING,
            message,
            // A file waits for room in the node's queue; a TCP stream's drops are counted
            // where its frames are queued, and set when the node takes the frame
            // (`lines::FrameQueue`).
            frames_dropped: 0,
        };
        out.frames.push((frame, status));
    }
}
