//! Rust mirror types of the `oilfilm_msgs` ROS 2 interface package (`msgs/` at the
//! repository root), with their CDR encoding ([`cdr`]) and bag schema text ([`spec`]).
//!
//! The `.msg` files are the single source of truth. Each type here is declared once, in
//! .msg field order, by [`ros_message!`], which derives the struct (serde
//! `Serialize`/`Deserialize` with the .msg field names, so a serde CDR serializer such as
//! the transport's produces the same bytes), its CDR writer and reader and its field table
//! ([`RosMessage::fields`]). The tests check that table against the parsed .msg files and the
//! bytes against what rclpy serialises.
//!
//! Conventions of every message: x horizontal, y vertical up; r = journal centre relative to
//! the bearing centre; force = film force on the journal; Lund's
//! `dF = -(K r + C r' + M r'')`; 2x2 matrices row-major `[xx, xy, yx, yy]`; SI units named
//! in the field.

pub mod cdr;
pub mod spec;
pub mod type_hash;

pub use cdr::{decode, decode_exact, encode, encode_with_padding, CdrError, CdrField, Layout, RosMessage};

/// Declares a message struct and derives its CDR form and field table, in field order.
///
/// Fields in an optional `appended { .. }` block follow the others and were added to the
/// .msg after messages without them were recorded: a message whose data ends where they
/// would begin (at most 3 bytes of padding left) decodes with all of them at their default
/// (empty, zero), so old bags stay readable; otherwise all must be present. Only for
/// top-level messages (none is nested in another) whose appended fields are sequences, so
/// "absent" and "empty" cannot be confused with data, or scalars whose zero is what the .msg
/// says a message without them means (RigStatus's `frames_dropped`: nothing dropped, or not
/// counted then) and that are at least 4 bytes wide: present, they leave more than the 3
/// bytes of padding an old message may end with, so the two cannot be confused either.
#[macro_export]
macro_rules! ros_message {
    (
        $(#[$meta:meta])*
        pub struct $name:ident = $type_name:literal, definition = $definition:expr; {
            $( $(#[$fmeta:meta])* pub $field:ident : $ty:ty ),* $(,)?
        }
        $( appended {
            $( $(#[$ameta:meta])* pub $afield:ident : $aty:ty ),* $(,)?
        } )?
        constants { $( $cname:ident : $cty:ty = $cval:literal as $cros:literal ),* $(,)? }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, PartialEq, Default, ::serde::Serialize, ::serde::Deserialize)]
        #[serde(deny_unknown_fields)]
        pub struct $name {
            $( $(#[$fmeta])* pub $field: $ty, )*
            $( $( #[serde(default)] $(#[$ameta])* pub $afield: $aty, )* )?
        }

        impl $name {
            $( pub const $cname: $cty = $cval; )*
        }

        impl $crate::cdr::CdrField for $name {
            fn ros_type() -> String {
                let full: &str = $type_name;
                // `pkg/msg/Type` is written `pkg/Type` as a field type.
                full.replacen("/msg/", "/", 1)
            }
            const MIN_BYTES: usize = 0 $( + <$ty as $crate::cdr::CdrField>::MIN_BYTES )*;
            fn write(&self, w: &mut $crate::cdr::CdrWriter) {
                $( $crate::cdr::CdrField::write(&self.$field, w); )*
                $( $( $crate::cdr::CdrField::write(&self.$afield, w); )* )?
            }
            fn read(r: &mut $crate::cdr::CdrReader, field: &str) -> Result<Self, $crate::cdr::CdrError> {
                $( let $field = <$ty as $crate::cdr::CdrField>::read(r, stringify!($field))
                    .map_err(|e| if field.is_empty() { e } else { e.within(field) })?; )*
                $(
                    // A message written before the appended fields existed ends (at most 3
                    // bytes of padding left) where they would start: all take their default.
                    // Otherwise all must be there, so a cut between them is an error.
                    let absent = r.remaining() <= 3;
                    $( let $afield = if absent {
                        Default::default()
                    } else {
                        <$aty as $crate::cdr::CdrField>::read(r, stringify!($afield))
                            .map_err(|e| if field.is_empty() { e } else { e.within(field) })?
                    }; )*
                )?
                Ok(Self { $( $field, )* $( $( $afield, )* )? })
            }
        }

        impl $crate::cdr::RosMessage for $name {
            const TYPE_NAME: &'static str = $type_name;
            const DEFINITION: &'static str = $definition;
            fn fields() -> Vec<(&'static str, String)> {
                vec![
                    $( (stringify!($field), <$ty as $crate::cdr::CdrField>::ros_type()), )*
                    $( $( (stringify!($afield), <$aty as $crate::cdr::CdrField>::ros_type()), )* )?
                ]
            }
            const CONSTANTS: &'static [(&'static str, &'static str, &'static str)] =
                &[ $( (stringify!($cname), $cros, stringify!($cval)) ),* ];
        }
    };
}

ros_message! {
    /// `builtin_interfaces/msg/Time`: seconds and nanoseconds (in [0, 1e9)) since the epoch
    /// of the clock.
    pub struct Time = "builtin_interfaces/msg/Time",
        definition = include_str!("../upstream/builtin_interfaces/msg/Time.msg"); {
        pub sec: i32,
        pub nanosec: u32,
    }
    constants {}
}

impl Time {
    /// The time `seconds` (finite) as ROS does it: nanosec in [0, 1e9), sec = floor;
    /// saturates outside the `int32` seconds range, NaN gives zero.
    pub fn from_seconds(seconds: f64) -> Self {
        if seconds.is_nan() {
            return Self::default();
        }
        let whole = seconds.floor();
        if whole < f64::from(i32::MIN) {
            return Self { sec: i32::MIN, nanosec: 0 };
        }
        if whole > f64::from(i32::MAX) {
            return Self { sec: i32::MAX, nanosec: 999_999_999 };
        }
        let ns = ((seconds - whole) * 1e9).round();
        // Rounding can reach a whole second.
        if ns >= 1e9 {
            match (whole as i32).checked_add(1) {
                Some(sec) => Self { sec, nanosec: 0 },
                None => Self { sec: i32::MAX, nanosec: 999_999_999 },
            }
        } else {
            Self { sec: whole as i32, nanosec: ns as u32 }
        }
    }

    pub fn as_seconds(&self) -> f64 {
        f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
    }
}

ros_message! {
    /// `std_msgs/msg/Header`: a stamp and the frame the data is in.
    pub struct Header = "std_msgs/msg/Header",
        definition = include_str!("../upstream/std_msgs/msg/Header.msg"); {
        pub stamp: Time,
        pub frame_id: String,
    }
    constants {}
}

ros_message! {
    /// `rosgraph_msgs/msg/Clock`: the time of a simulated (or replayed) clock, published on
    /// `/clock` for nodes with `use_sim_time`. Our player publishes a bag's log time here.
    pub struct Clock = "rosgraph_msgs/msg/Clock",
        definition = include_str!("../upstream/rosgraph_msgs/msg/Clock.msg"); {
        pub clock: Time,
    }
    constants {}
}

ros_message! {
    /// `rcl_interfaces/msg/ParameterValue`: one parameter's value, the field `type` says
    /// (1 bool, 2 integer, 3 double, 4 string, 5-9 arrays) is set.
    pub struct ParameterValue = "rcl_interfaces/msg/ParameterValue",
        definition = include_str!("../upstream/rcl_interfaces/msg/ParameterValue.msg"); {
        pub r#type: u8,
        pub bool_value: bool,
        pub integer_value: i64,
        pub double_value: f64,
        pub string_value: String,
        pub byte_array_value: Vec<u8>,
        pub bool_array_value: Vec<bool>,
        pub integer_array_value: Vec<i64>,
        pub double_array_value: Vec<f64>,
        pub string_array_value: Vec<String>,
    }
    constants {}
}

ros_message! {
    /// `rcl_interfaces/msg/Parameter`: a parameter's name and value.
    pub struct Parameter = "rcl_interfaces/msg/Parameter",
        definition = include_str!("../upstream/rcl_interfaces/msg/Parameter.msg"); {
        pub name: String,
        pub value: ParameterValue,
    }
    constants {}
}

// A `Parameter[]` starts with its first string's length: aligned to 4.
impl cdr::CdrElement for Parameter {
    const ALIGN: usize = 4;
}

ros_message! {
    /// `rcl_interfaces/msg/ParameterEvent`: a node's parameters declared, changed or deleted,
    /// as nodes publish them on `/parameter_events`. Our recorder keeps this topic in a bag,
    /// so the bag says which parameters the nodes ran with (ADR 0026).
    pub struct ParameterEvent = "rcl_interfaces/msg/ParameterEvent",
        definition = include_str!("../upstream/rcl_interfaces/msg/ParameterEvent.msg"); {
        pub stamp: Time,
        pub node: String,
        pub new_parameters: Vec<Parameter>,
        pub changed_parameters: Vec<Parameter>,
        pub deleted_parameters: Vec<Parameter>,
    }
    constants {}
}

/// The frame id our nodes put in `header.frame_id`: the rig's bearing frame (x horizontal,
/// y up, origin at the bearing centre).
pub const BEARING_FRAME_ID: &str = "oilfilm_bearing";

ros_message! {
    /// `oilfilm_msgs/msg/ExciterCommand`: waveform spec and force setpoints for the two
    /// exciters (index 0: f1 at 45 deg, index 1: f2 at 135 deg). See `msgs/msg/ExciterCommand.msg`.
    pub struct ExciterCommand = "oilfilm_msgs/msg/ExciterCommand",
        definition = include_str!("../../../msgs/msg/ExciterCommand.msg"); {
        pub header: Header,
        pub sequence: u64,
        pub waveform: [u8; 2],
        pub amplitude_n: [f64; 2],
        pub frequency_hz: [f64; 2],
        pub phase_rad: [f64; 2],
        pub rms_n: [f64; 2],
        pub period_s: [f64; 2],
        pub band_low_hz: [f64; 2],
        pub band_high_hz: [f64; 2],
        pub line_set: [u8; 2],
        pub chirp_start_hz: [f64; 2],
        pub chirp_end_hz: [f64; 2],
        pub sweep_s: [f64; 2],
        pub ramp_s: f64,
        pub amplitude_scale: f64,
        pub setpoint_rate_hz: f64,
        pub force_1_n: Vec<f64>,
        pub force_2_n: Vec<f64>,
        pub max_force_n: f64,
        pub band_limit_low_hz: f64,
        pub band_limit_high_hz: f64,
        pub stop: bool,
    }
    constants {
        WAVEFORM_OFF: u8 = 0 as "uint8",
        WAVEFORM_SINE: u8 = 1 as "uint8",
        WAVEFORM_MULTISINE: u8 = 2 as "uint8",
        WAVEFORM_CHIRP: u8 = 3 as "uint8",
        LINES_ALL: u8 = 0 as "uint8",
        LINES_ODD: u8 = 1 as "uint8",
        LINES_EVEN: u8 = 2 as "uint8",
    }
}

ros_message! {
    /// `oilfilm_msgs/msg/DaqFrame`: a block of multiplexed scans as acquired, scan-major
    /// values. See `msgs/msg/DaqFrame.msg`.
    pub struct DaqFrame = "oilfilm_msgs/msg/DaqFrame",
        definition = include_str!("../../../msgs/msg/DaqFrame.msg"); {
        pub header: Header,
        pub sequence: u64,
        pub first_scan: u64,
        pub sample_rate_hz: f64,
        pub units: u8,
        pub channel_names: Vec<String>,
        pub channel_units: Vec<String>,
        pub channel_offsets_s: Vec<f64>,
        pub scan_count: u32,
        pub values: Vec<f64>,
        pub rig: String,
    }
    appended {
        pub volts_per_count: Vec<f64>,
        pub counts: Vec<i16>,
    }
    constants {
        UNITS_SI: u8 = 0 as "uint8",
        UNITS_VOLTS: u8 = 1 as "uint8",
        UNITS_COUNTS: u8 = 2 as "uint8",
    }
}

impl DaqFrame {
    /// Checks that the samples are where `units` says and as many as `scan_count` times the
    /// channels: `values` for UNITS_SI and UNITS_VOLTS (`counts` and `volts_per_count` empty);
    /// `counts` and one finite, positive `volts_per_count` per channel for UNITS_COUNTS
    /// (`values` empty). The error names the field.
    pub fn check_samples(&self) -> Result<(), String> {
        let width = self.channel_names.len();
        let n = (self.scan_count as usize).saturating_mul(width);
        let expect = |field: &str, got: usize| {
            if got == n {
                Ok(())
            } else {
                Err(format!("{got} {field}, but scan_count {} x {width} channels = {n}", self.scan_count))
            }
        };
        let must_be_empty = |field: &str, len: usize, units: &str| {
            if len == 0 {
                Ok(())
            } else {
                Err(format!("{field} holds {len} element(s); it must be empty with {units}"))
            }
        };
        match self.units {
            Self::UNITS_SI | Self::UNITS_VOLTS => {
                let units = if self.units == Self::UNITS_SI { "UNITS_SI" } else { "UNITS_VOLTS" };
                expect("values", self.values.len())?;
                must_be_empty("counts", self.counts.len(), units)?;
                must_be_empty("volts_per_count", self.volts_per_count.len(), units)
            }
            Self::UNITS_COUNTS => {
                expect("counts", self.counts.len())?;
                must_be_empty("values", self.values.len(), "UNITS_COUNTS")?;
                if self.volts_per_count.len() != width {
                    return Err(format!("{} volts_per_count for {width} channel_names", self.volts_per_count.len()));
                }
                match self.volts_per_count.iter().position(|v| !(v.is_finite() && *v > 0.0)) {
                    Some(c) => Err(format!("volts_per_count[{c}] (channel `{}`) = {}: must be finite and > 0", self.channel_names[c], self.volts_per_count[c])),
                    None => Ok(()),
                }
            }
            other => Err(format!("units = {other} is none of UNITS_SI (0), UNITS_VOLTS (1), UNITS_COUNTS (2)")),
        }
    }

    /// The scan-major samples as `values` would hold them, in the channel's SI unit or in
    /// volts: `values` itself, or for UNITS_COUNTS each count times its channel's
    /// `volts_per_count`, written into `buf` (its contents replaced). After
    /// [`DaqFrame::check_samples`]; an error from it otherwise.
    pub fn samples<'a>(&'a self, buf: &'a mut Vec<f64>) -> Result<&'a [f64], String> {
        self.check_samples()?;
        if self.units != Self::UNITS_COUNTS {
            return Ok(&self.values);
        }
        buf.clear();
        buf.reserve(self.counts.len());
        let width = self.volts_per_count.len();
        match self.volts_per_count.first() {
            // One ADC range for every channel (the usual card): one flat loop, vectorised.
            Some(&lsb) if self.volts_per_count.iter().all(|&v| v == lsb) => {
                buf.extend(self.counts.iter().map(|&q| f64::from(q) * lsb));
            }
            Some(_) => {
                for scan in self.counts.chunks_exact(width) {
                    buf.extend(scan.iter().zip(&self.volts_per_count).map(|(&q, &lsb)| f64::from(q) * lsb));
                }
            }
            None => {}
        }
        Ok(buf)
    }

    /// Appends the samples of some channels to columns: `columns[k]` gets channel
    /// `picks[k]`'s samples, scan by scan, the very values [`DaqFrame::samples`] gives (a
    /// count times its channel's `volts_per_count`, the same multiply), without decoding the
    /// whole frame into a buffer first. The scans go tile by tile, so the part of the frame
    /// being read stays in L1 while every column takes its values from it (a column at a
    /// time over the whole frame read each cache line once per column). After
    /// [`DaqFrame::check_samples`]; an error from it, or for a pick that is no channel, with
    /// nothing appended.
    pub fn extend_columns(&self, picks: &[usize], columns: &mut [Vec<f64>]) -> Result<(), String> {
        self.check_samples()?;
        let width = self.channel_names.len();
        if picks.len() != columns.len() {
            return Err(format!("{} channels picked for {} columns", picks.len(), columns.len()));
        }
        if let Some(&bad) = picks.iter().find(|&&c| c >= width) {
            return Err(format!("channel {bad} picked from a frame of {width} channels"));
        }
        /// Scans per tile: 256 scans of 10 float64 channels are 20 kB.
        const TILE: usize = 256;
        let scans = self.scan_count as usize;
        for col in columns.iter_mut() {
            col.reserve(scans);
        }
        let mut start = 0;
        while start < scans {
            let end = (start + TILE).min(scans);
            for (&c, col) in picks.iter().zip(columns.iter_mut()) {
                if self.units == Self::UNITS_COUNTS {
                    let lsb = self.volts_per_count[c];
                    col.extend(self.counts[start * width + c..end * width].iter().step_by(width).map(|&q| f64::from(q) * lsb));
                } else {
                    col.extend(self.values[start * width + c..end * width].iter().step_by(width));
                }
            }
            start = end;
        }
        Ok(())
    }

    /// `UNITS_VOLTS` samples (scan-major, as `values` holds them) as `UNITS_COUNTS`, when every
    /// one is an exact multiple of its channel's `volts_per_count` within `int16`: then the
    /// frame's `counts` decode to the very same `f64`s, so nothing downstream changes but the
    /// bytes. `false` (and nothing changed) otherwise: the frame stays in volts.
    pub fn pack_counts(&mut self, volts_per_count: &[f64]) -> bool {
        let width = self.channel_names.len();
        if self.units != Self::UNITS_VOLTS || volts_per_count.len() != width || width == 0 || !self.values.len().is_multiple_of(width) {
            return false;
        }
        let mut counts = Vec::with_capacity(self.values.len());
        for scan in self.values.chunks_exact(width) {
            for (&v, &lsb) in scan.iter().zip(volts_per_count) {
                let q = (v / lsb).round();
                if !(q >= f64::from(i16::MIN) && q <= f64::from(i16::MAX)) {
                    return false;
                }
                // In range, so the cast is exact; what `samples` will make of the count must be
                // `v` bit for bit (so -0.0, which a count cannot carry, stays in volts).
                let count = q as i16;
                if (f64::from(count) * lsb).to_bits() != v.to_bits() {
                    return false;
                }
                counts.push(count);
            }
        }
        self.units = Self::UNITS_COUNTS;
        self.values = Vec::new();
        self.counts = counts;
        self.volts_per_count = volts_per_count.to_vec();
        true
    }
}

ros_message! {
    /// `oilfilm_msgs/msg/ConditionedFrame`: de-skewed x, y, x', y', x'', y'', fx, fy per
    /// sample with validity. See `msgs/msg/ConditionedFrame.msg`.
    pub struct ConditionedFrame = "oilfilm_msgs/msg/ConditionedFrame",
        definition = include_str!("../../../msgs/msg/ConditionedFrame.msg"); {
        pub header: Header,
        pub sequence: u64,
        pub first_sample: u64,
        pub sample_rate_hz: f64,
        pub x_m: Vec<f64>,
        pub y_m: Vec<f64>,
        pub x_dot_m_s: Vec<f64>,
        pub y_dot_m_s: Vec<f64>,
        pub x_ddot_m_s2: Vec<f64>,
        pub y_ddot_m_s2: Vec<f64>,
        pub fx_n: Vec<f64>,
        pub fy_n: Vec<f64>,
        pub valid: Vec<bool>,
        pub bearing_temperature_degc: f64,
        pub flags: Vec<String>,
    }
    constants {}
}

ros_message! {
    /// `oilfilm_msgs/msg/CoefficientEstimate`: one window's 8 or 12 coefficients with
    /// standard errors, dimensionless forms, diagnostics and operating point, or the refusal
    /// reason. See `msgs/msg/CoefficientEstimate.msg`.
    pub struct CoefficientEstimate = "oilfilm_msgs/msg/CoefficientEstimate",
        definition = include_str!("../../../msgs/msg/CoefficientEstimate.msg"); {
        pub header: Header,
        pub sequence: u64,
        pub window_start: Time,
        pub window_end: Time,
        pub window_start_sample: u64,
        pub window_end_sample: u64,
        pub model: u8,
        pub solved: bool,
        pub refusal_reason: String,
        pub stiffness_n_m: [f64; 4],
        pub damping_n_s_m: [f64; 4],
        pub stiffness_se_n_m: [f64; 4],
        pub damping_se_n_s_m: [f64; 4],
        pub added_mass_kg: Vec<f64>,
        pub added_mass_se_kg: Vec<f64>,
        pub stiffness_lund: [f64; 4],
        pub damping_lund: [f64; 4],
        pub stiffness_zhou: [f64; 4],
        pub damping_zhou: [f64; 4],
        pub condition_number: f64,
        pub rank: u32,
        pub residual_rms_n: [f64; 2],
        pub excitation_frequencies_hz: Vec<f64>,
        pub flags: Vec<String>,
        pub speed_rad_s: f64,
        pub bearing_temperature_degc: f64,
        pub viscosity_pa_s: f64,
        pub static_force_n: [f64; 2],
        pub load_n: f64,
        pub journal_position_m: [f64; 2],
        pub sommerfeld_number: f64,
        pub load_parameter_fy: f64,
        pub amplitude_d: f64,
    }
    constants {
        MODEL_KC: u8 = 0 as "uint8",
        MODEL_KCM: u8 = 1 as "uint8",
    }
}

ros_message! {
    /// `oilfilm_msgs/msg/RigStatus`: speed, static load, bearing temperature, state, and
    /// the DAQ input's dropped frames. See `msgs/msg/RigStatus.msg`.
    pub struct RigStatus = "oilfilm_msgs/msg/RigStatus",
        definition = include_str!("../../../msgs/msg/RigStatus.msg"); {
        pub header: Header,
        pub speed_rad_s: f64,
        pub static_load_n: f64,
        pub bearing_temperature_degc: f64,
        pub state: u8,
        pub message: String,
    }
    appended {
        pub frames_dropped: u64,
    }
    constants {
        STATE_IDLE: u8 = 0 as "uint8",
        STATE_RUNNING: u8 = 1 as "uint8",
        STATE_EXCITING: u8 = 2 as "uint8",
        STATE_FAULT: u8 = 3 as "uint8",
    }
}

/// The .msg text of a type this crate knows (`pkg`, `Type`): ours and their dependencies.
pub fn definition(package: &str, type_name: &str) -> Option<&'static str> {
    Some(match (package, type_name) {
        ("builtin_interfaces", "Time") => Time::DEFINITION,
        ("std_msgs", "Header") => Header::DEFINITION,
        ("rosgraph_msgs", "Clock") => Clock::DEFINITION,
        ("rcl_interfaces", "ParameterEvent") => ParameterEvent::DEFINITION,
        ("rcl_interfaces", "Parameter") => Parameter::DEFINITION,
        ("rcl_interfaces", "ParameterValue") => ParameterValue::DEFINITION,
        ("oilfilm_msgs", "ExciterCommand") => ExciterCommand::DEFINITION,
        ("oilfilm_msgs", "DaqFrame") => DaqFrame::DEFINITION,
        ("oilfilm_msgs", "ConditionedFrame") => ConditionedFrame::DEFINITION,
        ("oilfilm_msgs", "CoefficientEstimate") => CoefficientEstimate::DEFINITION,
        ("oilfilm_msgs", "RigStatus") => RigStatus::DEFINITION,
        _ => return None,
    })
}

/// The `ros2msg` schema text of one of our types (`oilfilm_msgs/msg/DaqFrame`) as rosbag2
/// writes it into a bag (see [`spec::schema_text`]).
pub fn schema_text(type_name: &str, naming: spec::SchemaNaming) -> Result<String, String> {
    spec::schema_text(type_name, naming, &definition)
}

/// The RIHS01 type description hash of one of our types (`oilfilm_msgs/msg/DaqFrame`), as
/// rosidl computes it and rosbag2 stores it (see [`type_hash`](mod@type_hash)).
pub fn type_description_hash(type_name: &str) -> Result<String, String> {
    type_hash::type_hash(type_name, &definition)
}

/// Which of our topics' types a name is, for tools (`pkg/msg/Type`).
pub const MESSAGE_TYPES: &[&str] =
    &[ExciterCommand::TYPE_NAME, DaqFrame::TYPE_NAME, ConditionedFrame::TYPE_NAME, CoefficientEstimate::TYPE_NAME, RigStatus::TYPE_NAME];
