//! The channel map: a TOML file that says which channel of a foreign record is which of the
//! rig's ten, in what unit, with what scale, offset and sign, at what sample rate and on
//! what multiplexer schedule, and where the shaft speed and the bearing temperature come
//! from. docs/manual/foreign-records.md documents every key; this module
//! reads the file ([`ChannelMap::from_toml_str`]) and checks it whole before any record is
//! opened, so that a bad map is refused with the key at fault and nothing is read.
//!
//! ```toml
//! format = "tdms"                     # tdms | mat | csv (optional: else the file says)
//! [timing]
//! sample_rate_from = "wf_increment"   # or sample_rate_hz = 5000
//! multiplexer = "sequential"          # simultaneous | sequential | offsets
//! channel_interval_s = 1e-5
//! [[channel]]
//! rig = "probe_a_x"
//! from = "Probes/A horizontal"        # TDMS group/channel, .mat variable or struct.field, CSV column
//! unit = "um"                         # V mV m um mm N kN C
//! sign = -1                           # the probe faces -x
//! [speed]
//! rpm = 1500
//! ```

use std::path::{Path, PathBuf};

use oilfilm_physics::daq::ChannelId;
use serde::Deserialize;

use crate::error::{ForeignError, Result};

/// The file formats read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// National Instruments TDMS (LabVIEW, DAQmx logging, npTDMS).
    Tdms,
    /// MATLAB MAT-file, level 5 (`save -v7`, `-v6`; scipy.io.savemat).
    Mat,
    /// Comma- (or otherwise) separated values with a header row.
    Csv,
}

impl Format {
    pub fn name(self) -> &'static str {
        match self {
            Format::Tdms => "tdms",
            Format::Mat => "mat",
            Format::Csv => "csv",
        }
    }
}

/// The unit a mapped channel's values are in (after the map's scale and offset).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub enum Unit {
    /// Amplifier output volts: the rig file's calibration converts them, as for our own DAQ.
    V,
    #[serde(rename = "mV")]
    MilliVolt,
    #[serde(rename = "m")]
    Metre,
    #[serde(rename = "um", alias = "µm")]
    Micrometre,
    #[serde(rename = "mm")]
    Millimetre,
    N,
    #[serde(rename = "kN")]
    KiloNewton,
    #[serde(rename = "C", alias = "degC")]
    Celsius,
}

impl Unit {
    pub fn name(self) -> &'static str {
        match self {
            Unit::V => "V",
            Unit::MilliVolt => "mV",
            Unit::Metre => "m",
            Unit::Micrometre => "um",
            Unit::Millimetre => "mm",
            Unit::N => "N",
            Unit::KiloNewton => "kN",
            Unit::Celsius => "C",
        }
    }

    /// Volts (the rig's calibration converts them) rather than a physical unit.
    pub fn is_volts(self) -> bool {
        matches!(self, Unit::V | Unit::MilliVolt)
    }

    /// A value in this unit in volts or the channel's SI unit (m, N, degC). Dividing by a
    /// power of ten gives the correctly rounded quotient; multiplying by its reciprocal would
    /// round twice.
    pub fn to_base(self, x: f64) -> f64 {
        match self {
            Unit::V | Unit::Metre | Unit::N | Unit::Celsius => x,
            Unit::MilliVolt | Unit::Millimetre => x / 1e3,
            Unit::Micrometre => x / 1e6,
            Unit::KiloNewton => x * 1e3,
        }
    }

    /// Whether a channel of the rig can be given in this unit.
    fn fits(self, channel: ChannelId) -> bool {
        if self.is_volts() {
            return true;
        }
        match channel {
            c if c.is_displacement_probe() => matches!(self, Unit::Metre | Unit::Micrometre | Unit::Millimetre),
            ChannelId::F1 | ChannelId::F2 | ChannelId::F3 => matches!(self, Unit::N | Unit::KiloNewton),
            _ => self == Unit::Celsius,
        }
    }

    /// The units a channel takes, for messages.
    fn allowed(channel: ChannelId) -> &'static str {
        match channel {
            c if c.is_displacement_probe() => "V, mV, m, um or mm",
            ChannelId::F1 | ChannelId::F2 | ChannelId::F3 => "V, mV, N or kN",
            _ => "V, mV or C",
        }
    }
}

/// The unit of a speed source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub enum SpeedUnit {
    #[serde(rename = "rpm")]
    Rpm,
    /// Revolutions per second.
    #[serde(rename = "Hz")]
    Hz,
    #[serde(rename = "rad/s")]
    RadPerSecond,
}

impl SpeedUnit {
    pub fn to_rpm(self, x: f64) -> f64 {
        match self {
            SpeedUnit::Rpm => x,
            SpeedUnit::Hz => x * 60.0,
            SpeedUnit::RadPerSecond => x * 30.0 / std::f64::consts::PI,
        }
    }
}

/// Where in the file a channel is: a name (`from`), a position (`index`, counted from 0), or
/// both (a TDMS group or a .mat matrix, and the channel or column in it).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Source {
    pub from: Option<String>,
    pub index: Option<usize>,
}

impl std::fmt::Display for Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (&self.from, self.index) {
            (Some(name), None) => write!(f, "`{name}`"),
            (Some(name), Some(i)) => write!(f, "`{name}` index {i}"),
            (None, Some(i)) => write!(f, "index {i}"),
            (None, None) => write!(f, "(nothing)"),
        }
    }
}

/// A value in the file's numbers made a value in `unit`: `unit(sign * (scale * x + offset))`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scaling {
    pub scale: f64,
    pub offset: f64,
    pub sign: f64,
}

impl Scaling {
    /// `scale = 1, offset = 0, sign = +1`: the file's values unchanged (not even -0.0 made 0.0,
    /// so a record copied between formats keeps its bits).
    pub fn is_identity(&self) -> bool {
        self.scale == 1.0 && self.offset == 0.0 && self.sign == 1.0
    }

    pub fn apply(&self, x: f64) -> f64 {
        if self.is_identity() {
            x
        } else {
            self.sign * (self.scale * x + self.offset)
        }
    }
}

/// One mapped channel of the rig.
#[derive(Debug, Clone, PartialEq)]
pub struct MappedChannel {
    pub rig: ChannelId,
    pub source: Source,
    pub unit: Unit,
    pub scaling: Scaling,
    /// `multiplexer = "offsets"`: its conversion time after the scan start, s.
    pub offset_s: Option<f64>,
    /// Its key in the map (`channel[3]`), for messages.
    pub key: String,
}

impl MappedChannel {
    /// A file value in volts or the channel's SI unit.
    pub fn convert(&self, x: f64) -> f64 {
        if self.scaling.is_identity() && matches!(self.unit, Unit::V | Unit::Metre | Unit::N | Unit::Celsius) {
            return x;
        }
        self.unit.to_base(self.scaling.apply(x))
    }

    /// How it reads in messages: `` `Probes/A x` (probe_a_x) ``.
    pub fn label(&self) -> String {
        format!("{} ({})", self.source, self.rig)
    }
}

/// The scan rate: a number, or where the file keeps it.
#[derive(Debug, Clone, PartialEq)]
pub enum Rate {
    Hz(f64),
    /// TDMS: a property of the mapped channels holding the sample interval in s
    /// (`wf_increment`); .mat: a scalar variable or struct field in Hz; CSV: a time column in s.
    From(String),
}

/// When each channel of a scan is converted.
#[derive(Debug, Clone, PartialEq)]
pub enum Multiplexer {
    /// Every channel at the scan start (simultaneous sample-and-hold).
    Simultaneous,
    /// One after the other in the map's channel order, `channel_interval_s` apart.
    Sequential { channel_interval_s: f64 },
    /// Each channel at its own `offset_s`.
    Offsets,
}

/// Where the shaft speed comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum Speed {
    /// Not stated: the rig file's operating speed is assumed (and tools say so).
    RigFile,
    Rpm(f64),
    /// A file property (TDMS: of the file, or `Group/name` of a group; .mat: a scalar variable).
    Property {
        name: String,
        unit: SpeedUnit,
        scaling: Scaling,
    },
    /// A channel of the file, sampled with the others: each frame's status carries its mean.
    Channel {
        source: Source,
        unit: SpeedUnit,
        scaling: Scaling,
    },
}

/// Where the bearing temperature comes from when no channel gives it.
#[derive(Debug, Clone, PartialEq)]
pub enum Temperature {
    /// A `[[channel]]` with `rig = "temperature"`.
    Channel,
    /// A constant, degC (a rig without a temperature channel, the oil inlet's reading).
    Celsius(f64),
}

/// CSV options.
#[derive(Debug, Clone, PartialEq)]
pub struct CsvOptions {
    pub delimiter: u8,
    /// The row after the header names each column's unit; it is checked against the map.
    pub units_row: bool,
}

impl Default for CsvOptions {
    fn default() -> Self {
        Self { delimiter: b',', units_row: false }
    }
}

/// A checked channel map.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelMap {
    /// The map file, for messages.
    pub path: PathBuf,
    pub format: Option<Format>,
    pub rate: Rate,
    pub start_time_s: Option<f64>,
    pub multiplexer: Multiplexer,
    /// In the order listed (the scan order of a sequential multiplexer).
    pub channels: Vec<MappedChannel>,
    pub speed: Speed,
    pub temperature: Temperature,
    pub csv: CsvOptions,
}

// ---- the file as written ----

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MapFile {
    format: Option<Format>,
    timing: TimingFile,
    #[serde(default)]
    channel: Vec<ChannelFile>,
    speed: Option<SpeedFile>,
    temperature: Option<TemperatureFile>,
    csv: Option<CsvFile>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TimingFile {
    sample_rate_hz: Option<f64>,
    sample_rate_from: Option<String>,
    start_time_s: Option<f64>,
    multiplexer: Option<String>,
    channel_interval_s: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ChannelFile {
    rig: String,
    from: Option<String>,
    index: Option<usize>,
    unit: Unit,
    scale: Option<f64>,
    offset: Option<f64>,
    sign: Option<i64>,
    offset_s: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SpeedFile {
    rpm: Option<f64>,
    from: Option<String>,
    index: Option<usize>,
    property: Option<String>,
    unit: Option<SpeedUnit>,
    scale: Option<f64>,
    offset: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TemperatureFile {
    celsius: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CsvFile {
    delimiter: Option<String>,
    units_row: Option<bool>,
}

impl ChannelMap {
    /// Reads and checks a map file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| ForeignError::io(format!("cannot read channel map {}", path.display()), e))?;
        Self::from_toml_str(&text, path)
    }

    /// Parses and checks a map; `path` names it in errors.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Self> {
        let bad = |key: &str, message: String| ForeignError::Map { map: path.to_path_buf(), key: key.to_string(), message };
        let file: MapFile = toml::from_str(text).map_err(|e| {
            // toml says where (line, column) and which key; keep its words.
            let message = e.to_string().replace('\n', " ").split_whitespace().collect::<Vec<_>>().join(" ");
            let key = e.span().map(|s| format!("byte {}", s.start)).unwrap_or_else(|| "(file)".into());
            bad(&key, message)
        })?;

        let t = &file.timing;
        let rate = match (t.sample_rate_hz, &t.sample_rate_from) {
            (Some(hz), None) if hz.is_finite() && hz > 0.0 => Rate::Hz(hz),
            (Some(hz), None) => return Err(bad("timing.sample_rate_hz", format!("must be finite and > 0, got {hz}"))),
            (None, Some(from)) if !from.trim().is_empty() => Rate::From(from.trim().to_string()),
            (None, Some(_)) => return Err(bad("timing.sample_rate_from", "is empty".into())),
            (Some(_), Some(_)) => return Err(bad("timing", "give sample_rate_hz or sample_rate_from, not both".into())),
            (None, None) => return Err(bad("timing", "the sample rate is missing: give sample_rate_hz, or sample_rate_from (TDMS: a channel property such as wf_increment; .mat: a scalar variable in Hz; CSV: a time column in s)".into())),
        };
        if let Some(s) = t.start_time_s {
            if !s.is_finite() {
                return Err(bad("timing.start_time_s", format!("must be finite, got {s}")));
            }
        }
        let multiplexer = match (t.multiplexer.as_deref().unwrap_or("simultaneous"), t.channel_interval_s) {
            ("simultaneous", None) => Multiplexer::Simultaneous,
            ("sequential", Some(dt)) if dt.is_finite() && dt > 0.0 => Multiplexer::Sequential { channel_interval_s: dt },
            ("sequential", Some(dt)) => return Err(bad("timing.channel_interval_s", format!("must be finite and > 0, got {dt}"))),
            ("sequential", None) => {
                return Err(bad("timing.channel_interval_s", "multiplexer = \"sequential\" needs the time between two conversions, s".into()))
            }
            ("offsets", None) => Multiplexer::Offsets,
            ("simultaneous" | "offsets", Some(_)) => return Err(bad("timing.channel_interval_s", "applies only to multiplexer = \"sequential\"".into())),
            (other, _) => return Err(bad("timing.multiplexer", format!("`{other}`: expected simultaneous, sequential or offsets"))),
        };

        let format = file.format;
        let mut channels: Vec<MappedChannel> = Vec::with_capacity(file.channel.len());
        for (k, c) in file.channel.iter().enumerate() {
            let key = format!("channel[{k}]");
            let rig = ChannelId::parse(c.rig.trim())
                .map_err(|_| bad(&format!("{key}.rig"), format!("`{}` is not a channel of the rig ({})", c.rig, ChannelId::all_names())))?;
            if let Some(first) = channels.iter().find(|m| m.rig == rig) {
                return Err(bad(&format!("{key}.rig"), format!("`{rig}` is mapped twice: {} maps it already", first.key)));
            }
            let source = source_of(&key, c.from.as_deref(), c.index, format).map_err(|(k, m)| bad(&k, m))?;
            if let Some(first) = channels.iter().find(|m| m.source == source) {
                return Err(bad(&format!("{key}.from"), format!("the file's channel {source} is mapped twice: {} ({}) maps it already", first.key, first.rig)));
            }
            if !c.unit.fits(rig) {
                return Err(bad(&format!("{key}.unit"), format!("`{}` is not a unit of `{rig}` (give {})", c.unit.name(), Unit::allowed(rig))));
            }
            let scaling = scaling_of(&key, c.scale, c.offset, c.sign).map_err(|(k, m)| bad(&k, m))?;
            let offset_s = match (&multiplexer, c.offset_s) {
                (Multiplexer::Offsets, Some(o)) if o.is_finite() && o >= 0.0 => Some(o),
                (Multiplexer::Offsets, Some(o)) => return Err(bad(&format!("{key}.offset_s"), format!("must be finite and >= 0, got {o}"))),
                (Multiplexer::Offsets, None) => {
                    return Err(bad(
                        &format!("{key}.offset_s"),
                        "multiplexer = \"offsets\" needs each channel's conversion time after the scan start, s".into(),
                    ))
                }
                (_, Some(_)) => return Err(bad(&format!("{key}.offset_s"), "applies only to multiplexer = \"offsets\"".into())),
                (_, None) => None,
            };
            channels.push(MappedChannel { rig, source, unit: c.unit, scaling, offset_s, key });
        }

        let temperature = match (&file.temperature, channels.iter().any(|c| c.rig == ChannelId::Temperature)) {
            (Some(_), true) => return Err(bad("temperature", "the temperature is mapped from a channel already; give one or the other".into())),
            (Some(t), false) if t.celsius.is_finite() => Temperature::Celsius(t.celsius),
            (Some(t), false) => return Err(bad("temperature.celsius", format!("must be finite, got {}", t.celsius))),
            (None, true) => Temperature::Channel,
            (None, false) => {
                return Err(bad("channel", "the rig's `temperature` is not mapped: map a channel to it, or give [temperature] celsius = ...".into()))
            }
        };
        let missing: Vec<&str> =
            ChannelId::ALL.iter().filter(|c| **c != ChannelId::Temperature && !channels.iter().any(|m| m.rig == **c)).map(|c| c.name()).collect();
        if !missing.is_empty() {
            return Err(bad(
                "channel",
                format!(
                    "the rig's {} {} not mapped (each of {} needs a [[channel]])",
                    missing.join(", "),
                    if missing.len() == 1 { "is" } else { "are" },
                    ChannelId::all_names()
                ),
            ));
        }

        let speed = match &file.speed {
            None => Speed::RigFile,
            Some(s) => {
                let unit = s.unit.unwrap_or(SpeedUnit::Rpm);
                match (s.rpm, &s.property, s.from.is_some() || s.index.is_some()) {
                    (Some(rpm), None, false) => {
                        if s.unit.is_some() || s.scale.is_some() || s.offset.is_some() {
                            return Err(bad("speed", "rpm is a number in rpm: unit, scale and offset apply to a property or a channel".into()));
                        }
                        if !(rpm.is_finite() && rpm > 0.0) {
                            return Err(bad("speed.rpm", format!("must be finite and > 0, got {rpm}")));
                        }
                        Speed::Rpm(rpm)
                    }
                    (None, Some(name), false) => {
                        Speed::Property { name: name.clone(), unit, scaling: scaling_of("speed", s.scale, s.offset, None).map_err(|(k, m)| bad(&k, m))? }
                    }
                    (None, None, true) => {
                        let source = source_of("speed", s.from.as_deref(), s.index, format).map_err(|(k, m)| bad(&k, m))?;
                        if let Some(c) = channels.iter().find(|m| m.source == source) {
                            return Err(bad("speed.from", format!("the file's channel {source} is mapped to `{}` by {} already", c.rig, c.key)));
                        }
                        Speed::Channel { source, unit, scaling: scaling_of("speed", s.scale, s.offset, None).map_err(|(k, m)| bad(&k, m))? }
                    }
                    _ => {
                        return Err(bad("speed", "give one of rpm (a number), property (a file property or scalar variable) or from/index (a channel)".into()))
                    }
                }
            }
        };

        let mut csv = CsvOptions::default();
        if let Some(c) = &file.csv {
            if format.is_some_and(|f| f != Format::Csv) {
                return Err(bad("csv", format!("applies to CSV files; the map's format is {}", format.map_or("", Format::name))));
            }
            if let Some(d) = &c.delimiter {
                csv.delimiter = match d.as_str() {
                    "," => b',',
                    ";" => b';',
                    "\t" | "\\t" | "tab" => b'\t',
                    "|" => b'|',
                    " " | "space" => b' ',
                    other => return Err(bad("csv.delimiter", format!("`{other}`: expected one of , ; tab | space"))),
                };
            }
            csv.units_row = c.units_row.unwrap_or(false);
        }

        Ok(ChannelMap { path: path.to_path_buf(), format, rate, start_time_s: t.start_time_s, multiplexer, channels, speed, temperature, csv })
    }

    /// Every rig channel gets volts (so the frames carry volts for the rig's calibration),
    /// rather than some or all physical units (then everything is converted to SI).
    pub fn all_volts(&self) -> bool {
        self.temperature == Temperature::Channel && self.channels.iter().all(|c| c.unit.is_volts())
    }

    /// The map's error for `key`.
    pub fn error(&self, key: &str, message: impl Into<String>) -> ForeignError {
        ForeignError::Map { map: self.path.clone(), key: key.into(), message: message.into() }
    }
}

fn source_of(key: &str, from: Option<&str>, index: Option<usize>, format: Option<Format>) -> std::result::Result<Source, (String, String)> {
    let from = from.map(str::trim);
    if from == Some("") {
        return Err((format!("{key}.from"), "is empty".into()));
    }
    match (from, index, format) {
        (None, None, _) => Err((key.to_string(), "says neither from (a name) nor index (a position from 0) for the file's channel".into())),
        (None, Some(_), Some(Format::Tdms)) => Err((
            format!("{key}.index"),
            "a TDMS channel is found by from = \"Group/Channel\", or from = \"Group\" with index = its position in the group".into(),
        )),
        (None, Some(_), Some(Format::Mat)) => {
            Err((format!("{key}.index"), "a .mat column needs from = the matrix variable (index = its column from 0)".into()))
        }
        (Some(_), Some(_), Some(Format::Csv)) => {
            Err((key.to_string(), "a CSV column is from (its name in the header row) or index (its position from 0), not both".into()))
        }
        _ => Ok(Source { from: from.map(str::to_string), index }),
    }
}

fn scaling_of(key: &str, scale: Option<f64>, offset: Option<f64>, sign: Option<i64>) -> std::result::Result<Scaling, (String, String)> {
    let scale = scale.unwrap_or(1.0);
    let offset = offset.unwrap_or(0.0);
    if !(scale.is_finite() && scale != 0.0) {
        return Err((format!("{key}.scale"), format!("must be finite and non-zero, got {scale}")));
    }
    if !offset.is_finite() {
        return Err((format!("{key}.offset"), format!("must be finite, got {offset}")));
    }
    let sign = match sign.unwrap_or(1) {
        1 => 1.0,
        -1 => -1.0,
        other => return Err((format!("{key}.sign"), format!("must be 1 or -1, got {other}"))),
    };
    Ok(Scaling { scale, offset, sign })
}
