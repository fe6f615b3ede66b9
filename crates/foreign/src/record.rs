//! A foreign record read through its map: the rig's channels, scan by scan, in blocks.
//!
//! [`ForeignRecord::open`] opens the file, finds every channel the map names, reads the
//! sample rate and the schedule, and checks that the channels agree in length, all before
//! the first value is read, so that a bad map or file is refused before anything is written.
//! [`ForeignRecord::next_block`] then gives the next scans, each channel converted to volts
//! (when every channel is in volts: the rig's calibration converts them later, as for our
//! own DAQ) or else to SI (m, N, degC; volts through the rig's calibration).

use std::path::{Path, PathBuf};

use oilfilm_physics::daq::{Calibration, ChannelId};

use crate::csv_file::CsvRows;
use crate::error::{ForeignError, Result};
use crate::map::{ChannelMap, Format, MappedChannel, Multiplexer, Rate, Scaling, Speed, SpeedUnit, Temperature, Unit};
use crate::{mat, tdms};

/// Seconds from 1904-01-01 (LabVIEW's epoch) to 1970-01-01.
const LABVIEW_EPOCH_TO_UNIX_S: i64 = 2_082_844_800;

/// Where the speed of a record comes from, once opened.
#[derive(Debug, Clone, PartialEq)]
pub enum RecordSpeed {
    /// Not stated: the rig file's is assumed.
    RigFile,
    /// One number for the record, and where it came from (for the status message).
    Rpm { rpm: f64, from: String },
    /// A channel: each block carries its values ([`Block::speed_rpm`]).
    Channel { label: String },
}

/// Scans of a record, scan-major.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct Block {
    /// Index of the first scan (scans count from 0 at the file's first).
    pub first_scan: u64,
    pub scans: usize,
    /// `values[n * channels + c]`: channel `c` of scan `n`, in volts or SI.
    pub values: Vec<f64>,
    /// The speed of each scan, rpm, when a channel gives it; else empty.
    pub speed_rpm: Vec<f64>,
}

enum Stream {
    Tdms(tdms::ChannelStream),
    Mat(mat::ChannelStream),
}

impl Stream {
    fn read(&mut self, out: &mut Vec<f64>, max: usize) -> Result<usize> {
        match self {
            Stream::Tdms(s) => s.read(out, max),
            Stream::Mat(s) => s.read(out, max),
        }
    }
}

enum Columns {
    /// One stream per mapped channel in map order, then the speed's.
    Streams(Vec<Stream>),
    /// CSV: the mapped columns in map order, then the speed's.
    Csv { rows: Box<CsvRows>, columns: Vec<(usize, String)> },
}

/// A foreign record opened through its map.
pub struct ForeignRecord {
    pub path: PathBuf,
    pub format: Format,
    pub sample_rate_hz: f64,
    /// Time of scan 0, s (the map's, the file's, or 0).
    pub start_time_s: f64,
    /// The rig's channels in scan order (the map's order; a constant temperature last).
    pub channels: Vec<ChannelId>,
    /// Each channel's conversion time after the scan start, s.
    pub offsets_s: Vec<f64>,
    /// The blocks carry volts (every channel in V or mV) rather than SI.
    pub volts: bool,
    pub speed: RecordSpeed,
    /// Scans in the file, when the format says before reading (TDMS, .mat).
    pub scans: Option<u64>,
    mapped: Vec<MappedChannel>,
    constant_temperature: Option<f64>,
    speed_scaling: Option<(SpeedUnit, Scaling)>,
    calibration: Calibration,
    columns: Columns,
    next_scan: u64,
    buf: Vec<Vec<f64>>,
}

/// The format of `path`: the map's, else its first bytes, else its extension.
pub fn detect_format(path: &Path, map: &ChannelMap) -> Result<Format> {
    if let Some(f) = map.format {
        return Ok(f);
    }
    let mut head = [0u8; 6];
    let n = std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read(&mut f, &mut head))
        .map_err(|e| ForeignError::io(format!("cannot read {}", path.display()), e))?;
    if head[..n.min(4)] == *b"TDSm" {
        return Ok(Format::Tdms);
    }
    if head[..n] == *b"MATLAB" {
        return Ok(Format::Mat);
    }
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("csv" | "tsv" | "txt") => Ok(Format::Csv),
        Some("tdms") => Ok(Format::Tdms),
        Some("mat") => Ok(Format::Mat),
        _ => Err(ForeignError::record(path, None, None, "neither a TDMS file, a MAT-file nor a .csv: give the map's `format`")),
    }
}

impl ForeignRecord {
    /// Opens `path` through `map`; `calibration` is the rig's (it converts volts when the
    /// record holds physical units on some channels).
    pub fn open(path: &Path, map: &ChannelMap, calibration: &Calibration) -> Result<Self> {
        let format = detect_format(path, map)?;
        let at_file = |channel: Option<String>, m: String| ForeignError::record(path, channel, None, m);
        let mapped = map.channels.clone();
        let mut speed_scaling = None;
        let (columns, rate, file_start, scans, speed) = match format {
            Format::Tdms => {
                let f = tdms::TdmsFile::open(path)?;
                let mut objects = Vec::new();
                for c in &mapped {
                    let from = c.source.from.as_deref().unwrap_or("");
                    let o = f.find(from, c.source.index).ok_or_else(|| {
                        at_file(Some(c.label()), format!("mapped by the map's {}, but the file has no such channel (it has {})", c.key, f.channel_names()))
                    })?;
                    objects.push(o);
                }
                let mut streams: Vec<Stream> = mapped.iter().zip(&objects).map(|(c, o)| f.stream(o, &c.label()).map(Stream::Tdms)).collect::<Result<_>>()?;
                let speed = match &map.speed {
                    Speed::Channel { source, unit, scaling } => {
                        let label = format!("{source} (speed)");
                        let o = f.find(source.from.as_deref().unwrap_or(""), source.index).ok_or_else(|| {
                            at_file(Some(label.clone()), format!("the map's [speed] names it, but the file has no such channel (it has {})", f.channel_names()))
                        })?;
                        objects.push(o);
                        streams.push(Stream::Tdms(f.stream(o, &label)?));
                        speed_scaling = Some((*unit, *scaling));
                        RecordSpeed::Channel { label }
                    }
                    Speed::Property { name, unit, scaling } => {
                        let (group, prop) = name.rsplit_once('/').map_or((None, name.as_str()), |(g, p)| (Some(g), p));
                        let owner = match group {
                            Some(g) => f.group(g),
                            None => Some(f.root()),
                        };
                        let v = owner.and_then(|o| o.property(prop)).and_then(tdms::Property::as_f64).ok_or_else(|| {
                            map.error(
                                "speed.property",
                                format!("{}: no numeric property `{name}` on the file{}", path.display(), if group.is_some() { "'s group" } else { "" }),
                            )
                        })?;
                        RecordSpeed::Rpm { rpm: unit.to_rpm(scaling.apply(v)), from: format!("property `{name}` of {}", path.display()) }
                    }
                    other => speed_of(other),
                };
                let rate = match &map.rate {
                    Rate::Hz(hz) => *hz,
                    Rate::From(prop) => {
                        let mut rate = None;
                        for (c, o) in mapped.iter().zip(&objects) {
                            let value = o
                                .property(prop)
                                .and_then(tdms::Property::as_f64)
                                .or_else(|| o.group.as_deref().and_then(|g| f.group(g)).and_then(|g| g.property(prop)).and_then(tdms::Property::as_f64))
                                .or_else(|| f.root().property(prop).and_then(tdms::Property::as_f64));
                            let v = value.ok_or_else(|| {
                                at_file(
                                    Some(c.label()),
                                    format!("the map's timing.sample_rate_from names property `{prop}`, which neither the channel, its group nor the file has"),
                                )
                            })?;
                            let hz = if prop == "wf_increment" { 1.0 / v } else { v };
                            if !(hz.is_finite() && hz > 0.0) {
                                return Err(at_file(Some(c.label()), format!("property `{prop}` = {v} gives no sample rate")));
                            }
                            match rate {
                                None => rate = Some(hz),
                                Some(r) if r == hz => {}
                                Some(r) => {
                                    return Err(at_file(
                                        Some(c.label()),
                                        format!("property `{prop}` gives {hz} Hz, the first mapped channel {r} Hz: the channels were not sampled together"),
                                    ))
                                }
                            }
                        }
                        rate.unwrap_or(0.0)
                    }
                };
                let start = objects.first().and_then(|o| o.property("wf_start_time")).and_then(|p| match p {
                    tdms::Property::Time { seconds, fraction } => Some((seconds - LABVIEW_EPOCH_TO_UNIX_S) as f64 + *fraction as f64 / 2f64.powi(64)),
                    _ => None,
                });
                let lens: Vec<u64> = objects.iter().map(|o| o.len()).collect();
                let labels: Vec<String> =
                    mapped.iter().map(MappedChannel::label).chain(matches!(speed, RecordSpeed::Channel { .. }).then(|| "speed".to_string())).collect();
                let n = same_length(path, &lens, &labels)?;
                (Columns::Streams(streams), rate, start, Some(n), speed)
            }
            Format::Mat => {
                let f = mat::MatFile::open(path)?;
                let mut streams = Vec::new();
                let mut lens = Vec::new();
                let mut labels = Vec::new();
                for c in &mapped {
                    let s = f.stream(c.source.from.as_deref().unwrap_or(""), c.source.index, &c.label())?;
                    lens.push(s.remaining());
                    labels.push(c.label());
                    streams.push(Stream::Mat(s));
                }
                let speed = match &map.speed {
                    Speed::Channel { source, unit, scaling } => {
                        let label = format!("{source} (speed)");
                        let s = f.stream(source.from.as_deref().unwrap_or(""), source.index, &label)?;
                        lens.push(s.remaining());
                        labels.push(label.clone());
                        streams.push(Stream::Mat(s));
                        speed_scaling = Some((*unit, *scaling));
                        RecordSpeed::Channel { label }
                    }
                    Speed::Property { name, unit, scaling } => {
                        RecordSpeed::Rpm { rpm: unit.to_rpm(scaling.apply(f.scalar(name)?)), from: format!("variable `{name}` of {}", path.display()) }
                    }
                    other => speed_of(other),
                };
                let rate = match &map.rate {
                    Rate::Hz(hz) => *hz,
                    Rate::From(name) => f.scalar(name)?,
                };
                let n = same_length(path, &lens, &labels)?;
                (Columns::Streams(streams), rate, None, Some(n), speed)
            }
            Format::Csv => {
                let mut rows = CsvRows::open(path, &map.csv)?;
                let mut columns = Vec::new();
                for c in &mapped {
                    let col = rows.column(c.source.from.as_deref(), c.source.index, &c.label())?;
                    if let (Some(units), true) = (rows.units(), c.scaling.is_identity()) {
                        let said = units[col].trim_matches(['[', ']', '(', ')', ' ']).to_string();
                        let unit = match said.as_str() {
                            "°C" | "degC" | "C" => Some(Unit::Celsius),
                            "µm" | "μm" | "um" => Some(Unit::Micrometre),
                            "V" => Some(Unit::V),
                            "mV" => Some(Unit::MilliVolt),
                            "m" => Some(Unit::Metre),
                            "mm" => Some(Unit::Millimetre),
                            "N" => Some(Unit::N),
                            "kN" => Some(Unit::KiloNewton),
                            _ => None,
                        };
                        if unit != Some(c.unit) {
                            return Err(ForeignError::record(
                                path,
                                Some(c.label()),
                                Some(format!("line 2, column {col}")),
                                format!(
                                    "the units row says `{}`, the map's {}.unit `{}`: fix the map (or give its scale)",
                                    crate::error::shown(&said),
                                    c.key,
                                    c.unit.name()
                                ),
                            ));
                        }
                    }
                    columns.push((col, c.label()));
                }
                let speed = match &map.speed {
                    Speed::Channel { source, unit, scaling } => {
                        let label = format!("{source} (speed)");
                        columns.push((rows.column(source.from.as_deref(), source.index, &label)?, label.clone()));
                        speed_scaling = Some((*unit, *scaling));
                        RecordSpeed::Channel { label }
                    }
                    Speed::Property { .. } => return Err(map.error("speed.property", "a CSV file has no properties: give rpm, or a column (from/index)")),
                    other => speed_of(other),
                };
                let (rate, start) = match &map.rate {
                    Rate::Hz(hz) => (*hz, None),
                    Rate::From(name) => {
                        let label = format!("`{name}` (time)");
                        let col = rows.column(Some(name), None, &label)?;
                        rows.look_ahead(1001)?;
                        let t0 = rows.ahead_value(0, col, &label).ok_or_else(|| at_file(Some(label.clone()), "the file has no data rows".into()))??;
                        let mut k = 1000;
                        let tk = loop {
                            if let Some(v) = rows.ahead_value(k, col, &label) {
                                break v?;
                            }
                            if k == 1 {
                                return Err(at_file(Some(label), "one data row gives no sample interval".into()));
                            }
                            k /= 2;
                        };
                        let hz = k as f64 / (tk - t0);
                        if !(hz.is_finite() && hz > 0.0) {
                            return Err(at_file(Some(label), format!("the time column does not increase ({t0} s, then {tk} s {k} rows later)")));
                        }
                        // Times printed with few digits make the quotient a little off a round
                        // rate: ten significant digits keep every real rate.
                        let hz: f64 = format!("{hz:.9e}").parse().unwrap_or(hz);
                        (hz, Some(t0))
                    }
                };
                (Columns::Csv { rows: Box::new(rows), columns }, rate, start, None, speed)
            }
        };
        if !(rate.is_finite() && rate > 0.0) {
            return Err(map.error("timing", format!("{}: the sample rate is {rate} Hz", path.display())));
        }
        let period = 1.0 / rate;
        let mut channels: Vec<ChannelId> = mapped.iter().map(|c| c.rig).collect();
        let mut offsets_s: Vec<f64> = match &map.multiplexer {
            Multiplexer::Simultaneous => vec![0.0; mapped.len()],
            Multiplexer::Sequential { channel_interval_s } => (0..mapped.len()).map(|p| p as f64 * channel_interval_s).collect(),
            Multiplexer::Offsets => mapped.iter().map(|c| c.offset_s.unwrap_or(0.0)).collect(),
        };
        for (c, o) in mapped.iter().zip(&offsets_s) {
            if *o >= period {
                let key = if matches!(map.multiplexer, Multiplexer::Offsets) { format!("{}.offset_s", c.key) } else { "timing.channel_interval_s".to_string() };
                return Err(
                    map.error(&key, format!("`{}` is converted {o} s after the scan starts, not within the scan period {period} s at {rate} Hz", c.rig))
                );
            }
        }
        let constant_temperature = match map.temperature {
            Temperature::Celsius(t) => {
                channels.push(ChannelId::Temperature);
                offsets_s.push(0.0);
                Some(t)
            }
            Temperature::Channel => None,
        };
        let volts = map.all_volts();
        Ok(ForeignRecord {
            path: path.to_path_buf(),
            format,
            sample_rate_hz: rate,
            start_time_s: map.start_time_s.or(file_start).unwrap_or(0.0),
            channels,
            offsets_s,
            volts,
            speed,
            scans,
            buf: vec![Vec::new(); mapped.len() + usize::from(speed_scaling.is_some())],
            mapped,
            constant_temperature,
            speed_scaling,
            calibration: calibration.clone(),
            columns,
            next_scan: 0,
        })
    }

    /// Unit of each channel's values in the blocks (`V`, or `m`, `N`, `degC`).
    pub fn channel_units(&self) -> Vec<&'static str> {
        self.channels.iter().map(|c| if self.volts { "V" } else { c.unit() }).collect()
    }

    /// The next scans, at most `max_scans`, into `block`; its `scans` is 0 at the end.
    pub fn next_block(&mut self, max_scans: usize, block: &mut Block) -> Result<usize> {
        let width = self.channels.len();
        block.first_scan = self.next_scan;
        block.values.clear();
        block.speed_rpm.clear();
        for b in &mut self.buf {
            b.clear();
        }
        let n = match &mut self.columns {
            Columns::Streams(streams) => {
                let mut n = None;
                for (s, b) in streams.iter_mut().zip(self.buf.iter_mut()) {
                    let got = s.read(b, max_scans)?;
                    // Lengths were checked equal on opening, so every stream gives as many.
                    n = Some(n.map_or(got, |m: usize| m.min(got)));
                }
                n.unwrap_or(0)
            }
            Columns::Csv { rows, columns } => {
                let mut row = Vec::with_capacity(columns.len());
                let mut n = 0;
                while n < max_scans {
                    row.clear();
                    if !rows.next_row(columns, &mut row)? {
                        break;
                    }
                    for (b, v) in self.buf.iter_mut().zip(&row) {
                        b.push(*v);
                    }
                    n += 1;
                }
                n
            }
        };
        block.values.reserve(n * width);
        for k in 0..n {
            let scan = self.next_scan + k as u64;
            for (c, m) in self.mapped.iter().enumerate() {
                let x = self.buf[c][k];
                let mut v = m.convert(x);
                if !self.volts && m.unit.is_volts() {
                    v = self.calibration.to_si(m.rig, v).map_err(|e| {
                        ForeignError::record(&self.path, Some(m.label()), Some(format!("scan {scan}")), format!("{x} V through the rig's calibration: {e}"))
                    })?;
                }
                if !v.is_finite() {
                    return Err(ForeignError::record(
                        &self.path,
                        Some(m.label()),
                        Some(format!("scan {scan}")),
                        format!("the value {x} is not a finite number"),
                    ));
                }
                block.values.push(v);
            }
            if let Some(t) = self.constant_temperature {
                block.values.push(t);
            }
            if let Some((unit, scaling)) = self.speed_scaling {
                block.speed_rpm.push(unit.to_rpm(scaling.apply(self.buf[self.mapped.len()][k])));
            }
        }
        block.scans = n;
        self.next_scan += n as u64;
        Ok(n)
    }
}

fn speed_of(speed: &Speed) -> RecordSpeed {
    match speed {
        Speed::Rpm(rpm) => RecordSpeed::Rpm { rpm: *rpm, from: "the channel map".into() },
        _ => RecordSpeed::RigFile,
    }
}

/// The one length of the mapped channels, or an error naming them.
fn same_length(path: &Path, lens: &[u64], labels: &[String]) -> Result<u64> {
    let first = lens.first().copied().unwrap_or(0);
    if lens.iter().all(|&l| l == first) {
        if first == 0 {
            return Err(ForeignError::record(path, labels.first().cloned(), None, "holds no values"));
        }
        return Ok(first);
    }
    let list: Vec<String> = labels.iter().zip(lens).map(|(l, n)| format!("{l}: {n}")).collect();
    Err(ForeignError::record(path, None, None, format!("the mapped channels differ in length ({}): they are not one record", list.join(", "))))
}
