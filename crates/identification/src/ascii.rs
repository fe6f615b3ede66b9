//! # The oilfilm ASCII record format, version 1
//!
//! Zhou et al. (2004, section 3) converted every acquisition into "standard ASCII files" that
//! MATLAB or Fortran could read. This is that file, specified: one acquisition of the rig's
//! ten channels, plain text, easy to write from any DAQ software, MATLAB or Python, and read
//! back by [`read`] with an error that names the file, line and column of the first problem.
//!
//! ## Example
//!
//! ```text
//! # oilfilm-ascii 1
//! # rig: zhou2004
//! # sample_rate_hz: 5000
//! # channel_interval_s: 1e-5
//! # units: si
//! # start_time_s: 0
//! ## two-tone run, 20 Hz and 30 Hz, 100 N
//! scan probe_a_x probe_a_y probe_b_x probe_b_y frame_x frame_y f1 f2 f3 temperature
//! 0 5.0312e-05 -7.9874e-05 5.0288e-05 -8.0137e-05 1.2e-08 -3.1e-08 0.31 -0.42 5600.8 29.03
//! 1 5.0551e-05 -7.9563e-05 5.0527e-05 -7.9811e-05 2.1e-08 -2.9e-08 2.86 3.35 5601.2 29.03
//! ```
//!
//! ## Lexical rules
//!
//! * UTF-8 text (plain ASCII is enough). Lines end with LF or CR LF; the last line may lack
//!   its line end. A byte-order mark before the first line is ignored.
//! * Fields are separated by one or more spaces or tabs; blanks at the start or end of a line
//!   are ignored. Nothing else separates fields (a comma is part of a field, and an error).
//! * **Blank lines** and **comment lines** (first non-blank characters `##`) are ignored
//!   anywhere after the first line.
//! * **Numbers** are decimal floating point as printed by C `%g`/`%.17g`, MATLAB, Python
//!   `repr` or Rust: `5000`, `-8.1e-05`, `1E-5`, `.5`, `+3`. `nan`, `inf`, values that
//!   overflow to infinity and Fortran's `D` exponent (write `E`) are refused. Write 17
//!   significant digits (or a shortest round-trip form) if the values must come back bit for
//!   bit.
//! * Errors give 1-based line and column numbers; columns count characters; column 0 means
//!   the whole line is at fault.
//!
//! ## 1. Format line
//!
//! The first line is `# oilfilm-ascii <version>`, `<version>` a decimal integer. This reader
//! reads version `1` and refuses any other. Future versions raise the number; a version-1
//! reader never guesses at a newer file.
//!
//! ## 2. Header lines: `# <key>: <value>`
//!
//! Then, in any order, one line per key (each key at most once; unknown keys are refused):
//!
//! | key | required | value |
//! | --- | --- | --- |
//! | `rig` | yes | name or path of the rig configuration the record belongs to: the rest of the line without the blanks at its ends, non-empty, no control characters. With `units: volts` its DAQ calibration converts the values. |
//! | `sample_rate_hz` | yes | scan rate, Hz, > 0 and <= 1e7 (Zhou: 5000) |
//! | `channel_interval_s` | yes | time between the conversions of two successive channels of one scan by the multiplexer, s, >= 0 (0 for simultaneous sampling; Zhou's card at 100 kHz: 1e-5). The channel in position `p` of the column line (0-based) is converted `p * channel_interval_s` after the scan starts; `(channels - 1) * channel_interval_s` must be shorter than the scan period `1 / sample_rate_hz`. |
//! | `channel_offsets_s` | no | for a DAQ that is not uniformly multiplexed: one offset per channel, in column-line order, blank-separated, each >= 0 and < `1 / sample_rate_hz`. Replaces `p * channel_interval_s` (which is then not checked against the scan period). |
//! | `units` | yes | `si` (m, N, degC as in the channel table) or `volts` (amplifier outputs, converted with the calibration of the rig config named by `rig`) |
//! | `start_time_s` | yes | time of scan index 0 on the recording's clock, s, from 0 to 2147483647 (0, or seconds since the Unix epoch up to the last second a ROS 2 stamp's int32 seconds hold) |
//! | `speed_rpm` | no | shaft speed during the record, rpm, > 0 and <= 1e6. The ten channels carry no tachometer; without this key the rig configuration's operating speed is assumed, and tools say so. |
//!
//! ## 3. Column line
//!
//! The first line that is neither blank, a comment nor a header line ends the header. It is
//! `scan` followed by the ten channel names, each exactly once, in the order the DAQ scans
//! them (that order defines each channel's position `p`):
//!
//! | channel | what | SI unit |
//! | --- | --- | --- |
//! | `probe_a_x`, `probe_a_y` | eddy-current probes at bearing end A: journal relative to bearing, horizontal / vertical | m |
//! | `probe_b_x`, `probe_b_y` | the same at bearing end B | m |
//! | `frame_x`, `frame_y` | frame probes: absolute displacement of the housing, horizontal / vertical | m |
//! | `f1`, `f2` | exciter forces at 45° and 135° from the horizontal (force sensors in the connectors) | N |
//! | `f3` | static load of the bellows (pneumatic loading system) | N |
//! | `temperature` | bearing temperature 0.5 mm under the bearing surface | degC |
//!
//! ## 4. Data rows, one per scan
//!
//! `<scan> <value> ... <value>`: the scan index, then one value per channel in column-line
//! order (so 11 fields). The scan index is a decimal integer without sign (0 to 2^64 - 1);
//! each row's index is the previous row's plus one (the first may be any value: a file may
//! hold a slice of a longer acquisition). Values are finite numbers in the header's units.
//! A record has at least one row. Header lines (single `#`) may not appear after the
//! column line.
//!
//! ## Time of a sample
//!
//! `t(scan n, channel at position p) = start_time_s + n / sample_rate_hz + offset_p`, with
//! `offset_p = channel_offsets_s[p]` if given, else `p * channel_interval_s`
//! ([`Record::time_of`]). The multiplex offsets are what the paper's "inner-insert filter"
//! (section 3.1, step 4) removes.
//!
//! ## Reading and writing elsewhere
//!
//! * Python: `pandas.read_csv(path, comment="#", sep=r"\s+")` gives a table with a `scan`
//!   column and one column per channel; header values are the `# key: value` lines.
//!   Write values with `repr(float)` or `"%.17g"`.
//! * MATLAB: `fprintf(fid, "%d%s\n", n, sprintf(" %.17g", values))` per scan; read with
//!   `readtable` with `CommentStyle` `#` and blank delimiters.
//!
//! ## Reading a line at a time
//!
//! [`LineReader`] is the parser: fed one line at a time (from a file, a socket, anything),
//! it gives the header, then each row with its scan index. Header errors are fatal; a
//! malformed row is reported with its line and column and skipped, and a row after missing
//! scans is delivered with the gap reported, so a live stream survives bad rows. [`read`]
//! runs it over a whole file and refuses the file at its first problem of any kind.
//!
//! [`write()`] and [`Writer`] print every value in its shortest form that reads back to the
//! same `f64` (Rust's `{}` or `{:e}`, whichever is shorter), so write → read is bit-exact.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::io::Write;

use oilfilm_physics::daq::ChannelId;

use crate::error::IdentificationError;

/// The format version this module reads and writes.
pub const FORMAT_VERSION: u32 = 1;

/// The text of the format line, without the version.
pub const FORMAT_TAG: &str = "oilfilm-ascii";

/// The ten channels, in the recommended (and the paper's listing) order: the DAQ's own
/// channel names ([`ChannelId::ALL`]), so the file format and the rig cannot drift apart.
pub const CHANNEL_NAMES: [&str; 10] = {
    let all = ChannelId::ALL;
    let mut names = [""; 10];
    let mut i = 0;
    while i < 10 {
        names[i] = all[i].name();
        i += 1;
    }
    names
};
/// SI unit of each channel of [`CHANNEL_NAMES`] (same order) when `units: si`.
pub const CHANNEL_UNITS_SI: [&str; 10] = {
    let all = ChannelId::ALL;
    let mut units = [""; 10];
    let mut i = 0;
    while i < 10 {
        units[i] = all[i].unit();
        i += 1;
    }
    units
};
/// Header keys, in the order [`write`] prints them.
const KEYS: [&str; 7] = ["rig", "sample_rate_hz", "channel_interval_s", "channel_offsets_s", "units", "start_time_s", "speed_rpm"];

/// Header keys a file may leave out.
const OPTIONAL_KEYS: [&str; 2] = ["channel_offsets_s", "speed_rpm"];

/// What the values of a record are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Units {
    /// Amplifier output voltages; the rig config named in the header calibrates them.
    Volts,
    /// SI units per channel ([`CHANNEL_UNITS_SI`]).
    Si,
}

impl Units {
    /// The header spelling: `volts` or `si`.
    pub fn as_str(self) -> &'static str {
        match self {
            Units::Volts => "volts",
            Units::Si => "si",
        }
    }
}

/// The header of a record (see the module docs for each field's rules).
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    pub version: u32,
    pub rig: String,
    pub sample_rate_hz: f64,
    pub channel_interval_s: f64,
    /// One offset per channel, in `channels` order, replacing `p * channel_interval_s`.
    pub channel_offsets_s: Option<Vec<f64>>,
    pub units: Units,
    pub start_time_s: f64,
    /// Shaft speed during the record, rpm, when the file states it.
    pub speed_rpm: Option<f64>,
    /// Channel names in file (scan) order: a permutation of [`CHANNEL_NAMES`].
    pub channels: Vec<String>,
}

impl Header {
    /// A version-1 SI header with the channels in [`CHANNEL_NAMES`] order.
    pub fn new_si(rig: &str, sample_rate_hz: f64, channel_interval_s: f64) -> Self {
        Self {
            version: FORMAT_VERSION,
            rig: rig.to_string(),
            sample_rate_hz,
            channel_interval_s,
            channel_offsets_s: None,
            units: Units::Si,
            start_time_s: 0.0,
            speed_rpm: None,
            channels: CHANNEL_NAMES.iter().map(|c| c.to_string()).collect(),
        }
    }

    /// Sampling offset of the channel at `position` within a scan, s; `None` out of range.
    pub fn channel_offset_s(&self, position: usize) -> Option<f64> {
        if position >= self.channels.len() {
            return None;
        }
        match &self.channel_offsets_s {
            Some(offsets) => offsets.get(position).copied(),
            None => Some(position as f64 * self.channel_interval_s),
        }
    }

    /// Checks everything a reader would check, so that what [`Writer`] writes reads back.
    pub fn validate(&self) -> Result<(), IdentificationError> {
        let bad = |field: &str, reason: String| Err(IdentificationError::invalid(format!("header.{field}"), reason));
        if self.version != FORMAT_VERSION {
            return bad("version", format!("this writer writes version {FORMAT_VERSION}, not {}", self.version));
        }
        if let Err(reason) = check_rig(&self.rig) {
            return bad("rig", reason);
        }
        if let Err(reason) = check_sample_rate(self.sample_rate_hz) {
            return bad("sample_rate_hz", reason);
        }
        if let Err(reason) = check_interval(self.channel_interval_s) {
            return bad("channel_interval_s", reason);
        }
        if let Err(reason) = check_start_time(self.start_time_s) {
            return bad("start_time_s", reason);
        }
        if let Some(v) = self.speed_rpm {
            if let Err(reason) = check_speed(v) {
                return bad("speed_rpm", reason);
            }
        }
        if let Err((_, reason)) = check_channels(self.channels.iter().map(String::as_str)) {
            return bad("channels", reason);
        }
        if let Err((_, reason)) = check_timing(self) {
            let field = if self.channel_offsets_s.is_some() { "channel_offsets_s" } else { "channel_interval_s" };
            return bad(field, reason);
        }
        Ok(())
    }
}

/// One acquisition: header, scan indices and one column of values per channel.
#[derive(Debug, Clone, PartialEq)]
pub struct Record {
    pub header: Header,
    /// Scan index of each row (consecutive integers).
    pub scan_index: Vec<u64>,
    /// One column per `header.channels` entry, each as long as `scan_index`.
    pub columns: Vec<Vec<f64>>,
}

impl Record {
    /// The values of channel `name`, if the record has it.
    pub fn column(&self, name: &str) -> Option<&[f64]> {
        let position = self.header.channels.iter().position(|c| c == name)?;
        self.columns.get(position).map(Vec::as_slice)
    }

    /// Number of scans (rows).
    pub fn len(&self) -> usize {
        self.scan_index.len()
    }

    /// Whether the record has no scans (a record read from a file never is).
    pub fn is_empty(&self) -> bool {
        self.scan_index.is_empty()
    }

    /// Time (s, on the recording's clock) at which row `scan` (0-based position in the
    /// record) of the channel at `channel` (position in `header.channels`) was sampled:
    /// `start_time_s + scan_index / sample_rate_hz + offset`. Rows past the end continue the
    /// consecutive scan indices; NaN for an empty record or a channel out of range.
    ///
    /// With a large `start_time_s` (seconds since the epoch, ~1.7e9) an `f64` resolves only
    /// about 0.2 µs, a few percent of a 10 µs multiplex offset: to correct for the
    /// multiplexing, use `scan_index / sample_rate_hz` and [`Header::channel_offset_s`] relative
    /// to the start rather than differences of absolute times.
    pub fn time_of(&self, scan: usize, channel: usize) -> f64 {
        let Some(offset) = self.header.channel_offset_s(channel) else {
            return f64::NAN;
        };
        let index = match (self.scan_index.get(scan), self.scan_index.first()) {
            (Some(&n), _) => n as f64,
            (None, Some(&first)) => first as f64 + scan as f64,
            (None, None) => return f64::NAN,
        };
        self.header.start_time_s + index / self.header.sample_rate_hz + offset
    }
}

// ---------------------------------------------------------------------------------------------
// Checks shared by the reader and the writer.

/// The rig value as the reader leaves it: non-empty, no blank (space, tab) at either end, no
/// control character (tab, CR, LF, ...), so that writing it and reading it back changes nothing.
fn check_rig(rig: &str) -> Result<(), String> {
    if rig.is_empty() {
        Err("the rig name must not be empty".into())
    } else if rig.trim_matches([' ', '\t']) != rig {
        Err("the rig name must not start or end with a blank".into())
    } else if let Some(c) = rig.chars().find(|c| c.is_control()) {
        Err(format!("the rig name must not contain control characters (found {c:?})"))
    } else {
        Ok(())
    }
}

/// Highest `sample_rate_hz` accepted, Hz: far above any DAQ's scan rate, low enough that
/// the times and sizes derived from it stay meaningful.
pub const MAX_SAMPLE_RATE_HZ: f64 = 10e6;
/// Latest `start_time_s` accepted, s: the last second a ROS 2 `builtin_interfaces/Time`
/// (int32 seconds) can stamp, so a replayed record's stamps are never pinned at the limit.
pub const MAX_START_TIME_S: f64 = i32::MAX as f64;
/// Highest `speed_rpm` accepted: above any journal-bearing rig's shaft speed.
pub const MAX_SPEED_RPM: f64 = 1e6;

fn check_sample_rate(x: f64) -> Result<(), String> {
    if x.is_finite() && x > 0.0 && x <= MAX_SAMPLE_RATE_HZ {
        Ok(())
    } else {
        Err(format!("sample_rate_hz must be in (0, {MAX_SAMPLE_RATE_HZ:e}] Hz, got {x:?}"))
    }
}

fn check_interval(x: f64) -> Result<(), String> {
    if x.is_finite() && x >= 0.0 {
        Ok(())
    } else {
        Err(format!("channel_interval_s must be finite and non-negative, got {x:?}"))
    }
}

fn check_start_time(x: f64) -> Result<(), String> {
    if (0.0..=MAX_START_TIME_S).contains(&x) {
        Ok(())
    } else {
        Err(format!("start_time_s must be in [0, {MAX_START_TIME_S}] s (0, or seconds since the Unix epoch up to ROS 2's int32 limit in 2038), got {x:?}"))
    }
}

fn check_speed(x: f64) -> Result<(), String> {
    if x > 0.0 && x <= MAX_SPEED_RPM {
        Ok(())
    } else {
        Err(format!("speed_rpm must be in (0, {MAX_SPEED_RPM:e}] rpm, got {x:?}"))
    }
}

/// Each of the ten channels exactly once, nothing else. On error: the 0-based position of the
/// offending name (`None` when a channel is missing) and the message.
fn check_channels<'a>(names: impl Iterator<Item = &'a str>) -> Result<(), (Option<usize>, String)> {
    let mut first_seen: [Option<usize>; 10] = [None; 10];
    for (position, name) in names.enumerate() {
        let Some(c) = CHANNEL_NAMES.iter().position(|n| *n == name) else {
            return Err((Some(position), format!("unknown column `{}` (the channels are {})", excerpt(name), CHANNEL_NAMES.join(" "))));
        };
        if let Some(first) = first_seen[c] {
            return Err((
                Some(position),
                format!(
                    "channel `{name}` appears twice (first as channel {} of the column line): \
                     every channel must appear exactly once",
                    first + 1
                ),
            ));
        }
        first_seen[c] = Some(position);
    }
    let missing: Vec<&str> = CHANNEL_NAMES.iter().zip(first_seen).filter(|(_, seen)| seen.is_none()).map(|(name, _)| *name).collect();
    if missing.is_empty() {
        Ok(())
    } else {
        Err((
            None,
            format!(
                "missing channel{} {}: every one of the 10 channels ({}) must appear exactly once",
                if missing.len() > 1 { "s" } else { "" },
                missing.join(", "),
                CHANNEL_NAMES.join(" ")
            ),
        ))
    }
}

/// Offsets fit within one scan period. On error: the 0-based index of the offending offset
/// (`None` for the uniform interval) and the message.
fn check_timing(header: &Header) -> Result<(), (Option<usize>, String)> {
    let period = 1.0 / header.sample_rate_hz;
    match &header.channel_offsets_s {
        Some(offsets) => {
            if offsets.len() != header.channels.len() {
                return Err((None, format!("channel_offsets_s has {} values but the column line names {} channels", offsets.len(), header.channels.len())));
            }
            for (i, &o) in offsets.iter().enumerate() {
                if !(o.is_finite() && o >= 0.0 && o < period) {
                    return Err((
                        Some(i),
                        format!(
                            "offset {o:?} s of channel `{}` must be >= 0 and shorter than the scan \
                             period 1/sample_rate_hz = {period:?} s",
                            header.channels.get(i).map(String::as_str).unwrap_or("?")
                        ),
                    ));
                }
            }
            Ok(())
        }
        None => {
            let last = header.channels.len().saturating_sub(1) as f64 * header.channel_interval_s;
            if last < period {
                Ok(())
            } else {
                Err((
                    None,
                    format!(
                        "the last channel would be converted {last:?} s after the scan starts \
                         ({} channels x channel_interval_s {:?} s), not within the scan period \
                         1/sample_rate_hz = {period:?} s",
                        header.channels.len(),
                        header.channel_interval_s
                    ),
                ))
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Reader.

/// Splits a line into blank-separated fields with their 1-based character columns.
fn fields(line: &str) -> Vec<(usize, &str)> {
    let mut out = Vec::new();
    let mut start: Option<(usize, usize)> = None; // (byte, column)
    let mut column = 0;
    for (byte, ch) in line.char_indices() {
        column += 1;
        let blank = ch == ' ' || ch == '\t';
        match (blank, start) {
            (true, Some((b, c))) => {
                out.push((c, &line[b..byte]));
                start = None;
            }
            (false, None) => start = Some((byte, column)),
            _ => {}
        }
    }
    if let Some((b, c)) = start {
        out.push((c, &line[b..]));
    }
    out
}

/// 1-based character column of byte offset `byte` of `line`.
fn column_of(line: &str, byte: usize) -> usize {
    line.get(..byte).map_or(0, |s| s.chars().count()) + 1
}

/// At most `n` characters of `s`, for messages.
fn excerpt(s: &str) -> String {
    const N: usize = 40;
    if s.chars().count() > N {
        format!("{}...", s.chars().take(N).collect::<String>())
    } else {
        s.to_string()
    }
}

/// A hint for files separated by commas instead of blanks.
fn comma_hint(line: &str) -> &'static str {
    if line.contains(',') {
        " (fields are separated by blanks, not commas)"
    } else {
        ""
    }
}

/// A finite number, or why not.
fn parse_number(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(x) if x.is_finite() => Ok(x),
        Ok(_) => Err(format!("`{}` is not a finite number (NaN and infinities are refused)", excerpt(text))),
        Err(_) => Err(format!("`{}` is not a number{}", excerpt(text), comma_hint(text))),
    }
}

/// A scan index: decimal digits only, fitting in u64.
fn parse_scan_index(text: &str) -> Result<u64, String> {
    if !text.is_empty() && text.bytes().all(|b| b.is_ascii_digit()) {
        text.parse::<u64>().map_err(|_| format!("scan index `{}` is too large (at most 2^64 - 1)", excerpt(text)))
    } else {
        Err(format!("scan index `{}` is not a non-negative integer", excerpt(text)))
    }
}

/// A header value found so far: its value text, line and value column.
#[derive(Debug, Clone)]
struct Entry {
    value: String,
    line: usize,
    column: usize,
}

/// A data row as a [`LineReader`] read it.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// 1-based line number the row was on.
    pub line: usize,
    /// Its scan index.
    pub scan_index: u64,
    /// One value per channel, in the header's (column-line) order.
    pub values: Vec<f64>,
}

/// What one line told a [`LineReader`].
#[derive(Debug, Clone, PartialEq)]
pub enum Fed {
    /// Nothing for the caller: the format line, a header line, a blank or a comment line.
    Nothing,
    /// The column line completed the header; the rows follow.
    Header(Header),
    /// A data row whose scan index follows the previous row's (or the first row).
    Row(Row),
    /// A well-formed data row after missing scans. The row is good and counts (the next row
    /// must follow it); `gap` is the [`IdentificationError::Parse`] naming its line, the
    /// column of its scan index and the scans that are missing.
    Gap { row: Row, gap: IdentificationError },
    /// A malformed data row (wrong field count, a bad scan index or value, a scan index that
    /// does not increase, a header line after the column line), as an
    /// [`IdentificationError::Parse`] with its line and column. The reader goes on as if the
    /// line were absent.
    Bad(IdentificationError),
}

/// Where a [`LineReader`] is in the record.
#[derive(Debug, Clone)]
enum Stage {
    /// Waiting for the format line.
    Format,
    /// Header lines, up to the column line.
    Header { version: u32, entries: HashMap<&'static str, Entry> },
    /// Data rows.
    Rows { header: Header, column_line: usize, last_scan: Option<u64> },
    /// The header was refused: the stream cannot be interpreted.
    Failed(IdentificationError),
}

/// Reads a record a line at a time, without I/O: the caller feeds each line with its
/// 1-based number ([`LineReader::feed`]) and gets the header, then the rows, as they come.
/// This is the one parser of the format: [`read`] feeds it a whole file, the DAQ node the
/// lines of a file or of a TCP stream.
///
/// * Errors in the format line, a header line or the column line are fatal (`Err`): the
///   stream cannot be interpreted, and every later `feed` returns the same error.
/// * A malformed data row is recoverable ([`Fed::Bad`]): it is skipped and the next row is
///   read as if it were absent. A row after missing scans is delivered with the gap
///   ([`Fed::Gap`]).
#[derive(Debug, Clone)]
pub struct LineReader {
    file: String,
    stage: Stage,
}

impl LineReader {
    /// A reader at the start of a record; `file_name` labels errors (a path, an address).
    pub fn new(file_name: &str) -> Self {
        Self { file: file_name.to_string(), stage: Stage::Format }
    }

    /// The label errors carry.
    pub fn file_name(&self) -> &str {
        &self.file
    }

    /// The header, once the column line has been read.
    pub fn header(&self) -> Option<&Header> {
        match &self.stage {
            Stage::Rows { header, .. } => Some(header),
            _ => None,
        }
    }

    /// Scan index of the last row delivered.
    pub fn last_scan(&self) -> Option<u64> {
        match &self.stage {
            Stage::Rows { last_scan, .. } => *last_scan,
            _ => None,
        }
    }

    /// The header and the line number of its column line when the header is complete;
    /// else the error of a stream that ended at line `last_line` before its column line (or
    /// the header's own error).
    pub fn finish(&self, last_line: usize) -> Result<(&Header, usize), IdentificationError> {
        match &self.stage {
            Stage::Rows { header, column_line, .. } => Ok((header, *column_line)),
            Stage::Failed(e) => Err(e.clone()),
            Stage::Format | Stage::Header { .. } => {
                Err(parse_error(&self.file, last_line, 0, format!("the file ends before the column line `scan {}`", CHANNEL_NAMES.join(" "))))
            }
        }
    }

    /// Reads line `number` (1-based). A line end (LF or CR LF) at its end is ignored, and a
    /// byte-order mark at the start of the first line.
    pub fn feed(&mut self, number: usize, line: &str) -> Result<Fed, IdentificationError> {
        let line = line.strip_suffix('\n').unwrap_or(line);
        let line = line.strip_suffix('\r').unwrap_or(line);
        let file = self.file.as_str();
        let fail = |line: usize, column: usize, message: String| parse_error(file, line, column, message);
        let result = match &mut self.stage {
            Stage::Failed(e) => return Err(e.clone()),
            Stage::Format => {
                let line = line.strip_prefix('\u{feff}').unwrap_or(line);
                parse_format_line(line)
                    .map(|version| {
                        self.stage = Stage::Header { version, entries: HashMap::new() };
                        Fed::Nothing
                    })
                    .map_err(|(column, message)| fail(number, column, message))
            }
            Stage::Header { version, entries } => match header_line(number, line, entries, &fail) {
                Ok(None) => Ok(Fed::Nothing),
                Ok(Some(())) => {
                    let version = *version;
                    column_line(version, entries, number, line, &fail).map(|header| {
                        self.stage = Stage::Rows { header: header.clone(), column_line: number, last_scan: None };
                        Fed::Header(header)
                    })
                }
                Err(e) => Err(e),
            },
            Stage::Rows { header, last_scan, .. } => return Ok(data_row(number, line, header, last_scan, &fail)),
        };
        if let Err(e) = &result {
            self.stage = Stage::Failed(e.clone());
        }
        result
    }
}

fn parse_error(file: &str, line: usize, column: usize, message: String) -> IdentificationError {
    IdentificationError::Parse { file: file.to_string(), line, column, message }
}

/// One line of the header section: `Ok(None)` for a blank, comment or header line (stored in
/// `entries`), `Ok(Some(()))` for the column line that ends the header.
fn header_line(
    number: usize,
    line: &str,
    entries: &mut HashMap<&'static str, Entry>,
    fail: &dyn Fn(usize, usize, String) -> IdentificationError,
) -> Result<Option<()>, IdentificationError> {
    let trimmed = line.trim_start_matches([' ', '\t']);
    if trimmed.is_empty() || trimmed.starts_with("##") {
        return Ok(None);
    }
    let Some(body) = trimmed.strip_prefix('#') else {
        return Ok(Some(()));
    };
    let body_start = line.len() - body.len();
    let Some(colon) = body.find(':') else {
        return Err(fail(number, 0, format!("header lines read `# key: value`, found `{}` (comments start with `##`)", excerpt(line))));
    };
    let key_raw = &body[..colon];
    let key = key_raw.trim_matches([' ', '\t']);
    let key_column = column_of(line, body_start + (key_raw.len() - key_raw.trim_start_matches([' ', '\t']).len()));
    let value_raw = &body[colon + 1..];
    let value = value_raw.trim_matches([' ', '\t']);
    let value_column = column_of(line, body_start + colon + 1 + (value_raw.len() - value_raw.trim_start_matches([' ', '\t']).len()));
    let Some(&key) = KEYS.iter().find(|k| **k == key) else {
        return Err(fail(number, key_column, format!("unknown header key `{}` (the keys are {})", excerpt(key), KEYS.join(", "))));
    };
    if let Some(earlier) = entries.get(key) {
        return Err(fail(number, key_column, format!("header key `{key}` given twice (first on line {})", earlier.line)));
    }
    if value.is_empty() {
        return Err(fail(number, value_column, format!("header key `{key}` has no value")));
    }
    entries.insert(key, Entry { value: value.to_string(), line: number, column: value_column });
    Ok(None)
}

/// The column line ends the header: every required key must be there.
fn column_line(
    version: u32,
    entries: &HashMap<&'static str, Entry>,
    number: usize,
    line: &str,
    fail: &dyn Fn(usize, usize, String) -> IdentificationError,
) -> Result<Header, IdentificationError> {
    for key in KEYS {
        if !OPTIONAL_KEYS.contains(&key) && !entries.contains_key(key) {
            return Err(fail(
                number,
                0,
                format!(
                    "header key `{key}` is missing: every key but {} is required before the \
                     column line",
                    OPTIONAL_KEYS.join(" and ")
                ),
            ));
        }
    }
    parse_header(version, entries, number, line, fail)
}

/// One line after the column line.
fn data_row(number: usize, line: &str, header: &Header, last_scan: &mut Option<u64>, fail: &dyn Fn(usize, usize, String) -> IdentificationError) -> Fed {
    let n = header.channels.len();
    let trimmed = line.trim_start_matches([' ', '\t']);
    if trimmed.is_empty() || trimmed.starts_with("##") {
        return Fed::Nothing;
    }
    if trimmed.starts_with('#') {
        return Fed::Bad(fail(
            number,
            column_of(line, line.len() - trimmed.len()),
            "header line after the column line: header keys come before `scan ...` \
             (comments start with `##`)"
                .into(),
        ));
    }
    let row = fields(line);
    if row.len() != n + 1 {
        let column = row.get(n + 1).map_or(0, |(c, _)| *c);
        return Fed::Bad(fail(number, column, format!("expected {} fields (scan index and {n} channels), found {}{}", n + 1, row.len(), comma_hint(line))));
    }
    let mut row = row.into_iter();
    // The length was checked just above: n + 1 >= 1 fields.
    let Some((index_column, index_text)) = row.next() else { return Fed::Nothing };
    let index = match parse_scan_index(index_text) {
        Ok(i) => i,
        Err(m) => return Fed::Bad(fail(number, index_column, m)),
    };
    if let Some(previous) = *last_scan {
        if index <= previous {
            return Fed::Bad(fail(number, index_column, format!("scan index {index} does not increase: the previous row is scan {previous}")));
        }
    }
    let mut values = Vec::with_capacity(n);
    for ((column, text), name) in row.zip(&header.channels) {
        match parse_number(text) {
            Ok(x) => values.push(x),
            Err(m) => return Fed::Bad(fail(number, column, format!("channel `{name}`: value {m}"))),
        }
    }
    let gap = match *last_scan {
        // `index > previous` was checked above, so `previous + 1` cannot overflow.
        Some(previous) if index != previous + 1 => Some(if index - previous == 2 {
            format!("scan index {index} skips scan {} (previous row is scan {previous})", previous + 1)
        } else {
            format!("scan index {index} skips scans {} to {} (previous row is scan {previous})", previous + 1, index - 1)
        }),
        _ => None,
    };
    *last_scan = Some(index);
    let row = Row { line: number, scan_index: index, values };
    match gap {
        Some(message) => Fed::Gap { row, gap: fail(number, index_column, message) },
        None => Fed::Row(row),
    }
}

/// The columns and scan indices of a whole-record read, filled from what [`LineReader`]
/// says of each line; the first problem of any kind refuses the file.
#[derive(Default)]
struct Rows {
    scan_index: Vec<u64>,
    columns: Vec<Vec<f64>>,
}

impl Rows {
    fn take(&mut self, fed: Fed) -> Result<(), IdentificationError> {
        match fed {
            Fed::Nothing => {}
            Fed::Header(header) => self.columns = vec![Vec::new(); header.channels.len()],
            Fed::Row(row) => {
                for (column, x) in self.columns.iter_mut().zip(row.values) {
                    column.push(x);
                }
                self.scan_index.push(row.scan_index);
            }
            Fed::Gap { gap: e, .. } | Fed::Bad(e) => return Err(e),
        }
        Ok(())
    }

    /// The record, refused when no scan row followed the column line (at `column_line`).
    fn into_record(self, header: Header, file_name: &str, column_line: usize) -> Result<Record, IdentificationError> {
        if self.scan_index.is_empty() {
            return Err(parse_error(file_name, column_line, 0, "no data: no scan rows follow the column line".into()));
        }
        Ok(Record { header, scan_index: self.scan_index, columns: self.columns })
    }
}

/// Reads a record from `stream`, line by line: the text is never held whole (only the
/// record's columns are), so a record the size of the memory can be read. The same rules and
/// errors as [`read`]; a byte that is not UTF-8 is an error at its line and column.
pub fn read_stream(mut stream: impl std::io::BufRead, file_name: &str) -> Result<Record, IdentificationError> {
    let mut reader = LineReader::new(file_name);
    let mut rows = Rows::default();
    let mut bytes: Vec<u8> = Vec::new();
    let (mut number, mut lines) = (0usize, 0usize);
    loop {
        bytes.clear();
        let n = stream.read_until(b'\n', &mut bytes).map_err(|e| parse_error(file_name, number + 1, 0, format!("cannot read: {e}")))?;
        number += 1;
        let ended = bytes.last() == Some(&b'\n');
        if ended {
            bytes.pop();
        }
        let line = std::str::from_utf8(&bytes).map_err(|e| {
            let at = e.valid_up_to();
            let column = String::from_utf8_lossy(&bytes[..at]).chars().count() + 1;
            parse_error(file_name, number, column, format!("byte 0x{:02x} is not UTF-8 text", bytes[at]))
        })?;
        // `str::lines` counts a last line only when it has text; `read` reports the same.
        if n > 0 && (ended || !line.is_empty()) {
            lines += 1;
        }
        rows.take(reader.feed(number, line)?)?;
        if !ended {
            break;
        }
    }
    let (header, column_line) = reader.finish(lines.max(1))?;
    rows.into_record(header.clone(), file_name, column_line)
}

/// Reads a record from the text of a file; `file_name` only labels errors. Never panics;
/// every refusal is an [`IdentificationError::Parse`] naming the line and column (see the
/// module docs for the rules). The whole-file form of [`LineReader`]: the first problem of
/// any kind, in a data row too, refuses the file.
pub fn read(text: &str, file_name: &str) -> Result<Record, IdentificationError> {
    let mut reader = LineReader::new(file_name);
    let mut rows = Rows::default();
    for (i, line) in text.split('\n').enumerate() {
        rows.take(reader.feed(i + 1, line)?)?;
    }
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let (header, column_line) = reader.finish(text.lines().count().max(1))?;
    rows.into_record(header.clone(), file_name, column_line)
}

/// The version from the format line, or (column, message).
fn parse_format_line(line: &str) -> Result<u32, (usize, String)> {
    let expected = format!("# {FORMAT_TAG} {FORMAT_VERSION}");
    let missing = || (0, format!("missing format line: the first line must be `{expected}`, found `{}`", excerpt(line)));
    let body = line.trim_start_matches([' ', '\t']).strip_prefix('#').ok_or_else(missing)?;
    let offset = line.len() - body.len();
    let parts = fields(body);
    match parts.as_slice() {
        [(_, tag), rest @ ..] if *tag == FORMAT_TAG => match rest {
            [] => Err((0, format!("the format line lacks its version: expected `{expected}`"))),
            [(c, v)] => {
                let column = column_of(line, offset) + c - 1;
                let version = parse_scan_index(v)
                    .ok()
                    .and_then(|v| u32::try_from(v).ok())
                    .ok_or_else(|| (column, format!("format version `{}` is not an integer", excerpt(v))))?;
                if version == FORMAT_VERSION {
                    Ok(version)
                } else {
                    Err((
                        column,
                        format!(
                            "unsupported format version {version}: this reader reads version \
                             {FORMAT_VERSION}"
                        ),
                    ))
                }
            }
            [_, (c, extra), ..] => Err((column_of(line, offset) + c - 1, format!("unexpected `{}` after the format version", excerpt(extra)))),
        },
        _ => Err(missing()),
    }
}

/// Header values and the column line, checked.
fn parse_header(
    version: u32,
    entries: &HashMap<&'static str, Entry>,
    column_line_number: usize,
    column_line: &str,
    fail: &dyn Fn(usize, usize, String) -> IdentificationError,
) -> Result<Header, IdentificationError> {
    // Present: checked by the caller for every key but the optional ones.
    let get = |key: &str| entries.get(key).ok_or_else(|| fail(column_line_number, 0, format!("header key `{key}` is missing")));
    let number = |key: &str, check: fn(f64) -> Result<(), String>| -> Result<f64, IdentificationError> {
        let e = get(key)?;
        let x = parse_number(&e.value).map_err(|m| fail(e.line, e.column, format!("{key}: {m}")))?;
        check(x).map_err(|m| fail(e.line, e.column, m))?;
        Ok(x)
    };
    let rig = {
        let e = get("rig")?;
        check_rig(&e.value).map_err(|m| fail(e.line, e.column, m))?;
        e.value.clone()
    };
    let sample_rate_hz = number("sample_rate_hz", check_sample_rate)?;
    let channel_interval_s = number("channel_interval_s", check_interval)?;
    let start_time_s = number("start_time_s", check_start_time)?;
    let speed_rpm = match entries.get("speed_rpm") {
        None => None,
        Some(_) => Some(number("speed_rpm", check_speed)?),
    };
    let units = {
        let e = get("units")?;
        match e.value.as_str() {
            "si" => Units::Si,
            "volts" => Units::Volts,
            other => return Err(fail(e.line, e.column, format!("units must be `si` or `volts`, found `{}`", excerpt(other)))),
        }
    };
    // Offsets: positions of each value on its line, for errors.
    let offsets = match entries.get("channel_offsets_s") {
        None => None,
        Some(e) => {
            let mut values = Vec::new();
            for (c, text) in fields(&e.value) {
                let column = e.column + c - 1;
                let x = parse_number(text).map_err(|m| fail(e.line, column, format!("channel_offsets_s: {m}")))?;
                values.push((column, x));
            }
            Some((e, values))
        }
    };

    // 3. Column line.
    let parts = fields(column_line);
    let Some(&(first_column, first)) = parts.first() else {
        return Err(fail(column_line_number, 0, "empty column line".into()));
    };
    if first != "scan" {
        return Err(fail(
            column_line_number,
            first_column,
            format!("expected the column line `scan {}`, found `{}`{}", CHANNEL_NAMES.join(" "), excerpt(first), comma_hint(column_line)),
        ));
    }
    let names = &parts[1..];
    check_channels(names.iter().map(|(_, n)| *n)).map_err(|(position, message)| {
        let column = position.and_then(|p| names.get(p)).map_or(0, |(c, _)| *c);
        fail(column_line_number, column, message)
    })?;

    let header = Header {
        version,
        rig,
        sample_rate_hz,
        channel_interval_s,
        channel_offsets_s: offsets.as_ref().map(|(_, v)| v.iter().map(|(_, x)| *x).collect()),
        units,
        start_time_s,
        speed_rpm,
        channels: names.iter().map(|(_, n)| n.to_string()).collect(),
    };
    check_timing(&header).map_err(|(index, message)| match &offsets {
        Some((e, values)) => {
            let column = index.and_then(|i| values.get(i)).map_or(e.column, |(c, _)| *c);
            fail(e.line, column, message)
        }
        None => match entries.get("channel_interval_s") {
            Some(e) => fail(e.line, e.column, message),
            None => fail(column_line_number, 0, message),
        },
    })?;
    Ok(header)
}

// ---------------------------------------------------------------------------------------------
// Writer.

/// `x` in the shorter of Rust's `{}` and `{:e}` forms; both are the shortest digits that
/// read back to the same `f64`.
fn number_text(x: f64) -> String {
    let plain = format!("{x}");
    let exp = format!("{x:e}");
    if exp.len() < plain.len() {
        exp
    } else {
        plain
    }
}

fn io_error(e: std::io::Error) -> IdentificationError {
    IdentificationError::BadInput { what: "ascii output".into(), reason: e.to_string() }
}

/// Writes a record scan by scan (for a node that records while it acquires). The header and
/// column line are written by [`Writer::new`]; each [`Writer::push`] writes one row. Refuses
/// anything a reader would refuse, so a finished file always reads back.
pub struct Writer<W: Write> {
    out: W,
    channels: Vec<String>,
    last_scan: Option<u64>,
    line: String,
}

impl<W: Write> Writer<W> {
    /// Checks the header ([`Header::validate`]) and writes it with the column line.
    pub fn new(mut out: W, header: &Header) -> Result<Self, IdentificationError> {
        header.validate()?;
        let mut text = format!("# {FORMAT_TAG} {}\n", header.version);
        for key in KEYS {
            let value = match key {
                "rig" => header.rig.clone(),
                "sample_rate_hz" => number_text(header.sample_rate_hz),
                "channel_interval_s" => number_text(header.channel_interval_s),
                "channel_offsets_s" => match &header.channel_offsets_s {
                    Some(o) => o.iter().map(|x| number_text(*x)).collect::<Vec<_>>().join(" "),
                    None => continue,
                },
                "units" => header.units.as_str().to_string(),
                "speed_rpm" => match header.speed_rpm {
                    Some(v) => number_text(v),
                    None => continue,
                },
                _ => number_text(header.start_time_s),
            };
            let _ = writeln!(text, "# {key}: {value}"); // writing to a String cannot fail
        }
        let _ = writeln!(text, "scan {}", header.channels.join(" "));
        out.write_all(text.as_bytes()).map_err(io_error)?;
        Ok(Self { out, channels: header.channels.clone(), last_scan: None, line: String::new() })
    }

    /// Writes one scan: its index (the first any, then consecutive) and one finite value per
    /// channel, in the header's channel order.
    pub fn push(&mut self, scan_index: u64, values: &[f64]) -> Result<(), IdentificationError> {
        let what = || format!("scan {scan_index}");
        if let Some(last) = self.last_scan {
            if last.checked_add(1) != Some(scan_index) {
                return Err(IdentificationError::BadInput { what: what(), reason: format!("scan indices must be consecutive: the previous scan is {last}") });
            }
        }
        if values.len() != self.channels.len() {
            return Err(IdentificationError::BadInput { what: what(), reason: format!("{} values for {} channels", values.len(), self.channels.len()) });
        }
        if let Some((x, name)) = values.iter().zip(&self.channels).find(|(x, _)| !x.is_finite()) {
            return Err(IdentificationError::BadInput { what: format!("scan {scan_index}, channel {name}"), reason: format!("value {x} is not finite") });
        }
        self.line.clear();
        let _ = write!(self.line, "{scan_index}"); // writing to a String cannot fail
        for x in values {
            self.line.push(' ');
            self.line.push_str(&number_text(*x));
        }
        self.line.push('\n');
        self.out.write_all(self.line.as_bytes()).map_err(io_error)?;
        self.last_scan = Some(scan_index);
        Ok(())
    }

    /// Flushes and returns the output. Refuses a record without rows (a reader would).
    pub fn finish(mut self) -> Result<W, IdentificationError> {
        if self.last_scan.is_none() {
            return Err(IdentificationError::BadInput { what: "ascii record".into(), reason: "no scans were written; a record needs at least one".into() });
        }
        self.out.flush().map_err(io_error)?;
        Ok(self.out)
    }
}

/// The text of a whole record. Refuses (`InvalidParameter`/`BadInput`) a record the reader
/// would refuse: invalid header, columns of unequal length, non-finite values, non-consecutive
/// scan indices, no scans.
pub fn write(record: &Record) -> Result<String, IdentificationError> {
    let n = record.header.channels.len();
    if record.columns.len() != n {
        return Err(IdentificationError::BadInput { what: "record.columns".into(), reason: format!("{} columns for {n} channels", record.columns.len()) });
    }
    if let Some((name, c)) = record.header.channels.iter().zip(&record.columns).find(|(_, c)| c.len() != record.len()) {
        return Err(IdentificationError::BadInput {
            what: format!("record.columns ({name})"),
            reason: format!("{} values for {} scans", c.len(), record.len()),
        });
    }
    let mut writer = Writer::new(Vec::new(), &record.header)?;
    let mut row = vec![0.0; n];
    for (i, &index) in record.scan_index.iter().enumerate() {
        for (r, c) in row.iter_mut().zip(&record.columns) {
            *r = c.get(i).copied().unwrap_or(f64::NAN); // lengths checked above
        }
        writer.push(index, &row)?;
    }
    let bytes = writer.finish()?;
    String::from_utf8(bytes).map_err(|e| IdentificationError::BadInput { what: "ascii output".into(), reason: e.to_string() })
}
