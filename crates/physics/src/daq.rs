//! # The data-acquisition chain: sensors, amplifiers, a multiplexed 16-bit ADC, calibration
//!
//! This module reproduces the measurement side of the rig of Zhou et al. (2004), section 2.3,
//! as a pure deterministic function of (configuration, injected effects, seed, true signals):
//! no I/O, no clock. Time is whatever the caller passes in.
//!
//! ## What the paper describes (section 2.3)
//!
//! Ten signals, each sensor with its own amplifier whose output is regulated into +-10 V, feed
//! one ADlink PCI-9114 card (16 bit, up to 100 kS/s aggregate). The card converts **one
//! channel at a time**, "in turns", so the ten channels of a scan are *not* simultaneous;
//! 50 000 points per channel are taken at 5000 samples per second. Section 3.1 then
//! (step 2) discards a record if any eddy-current probe left its calibrated linear range,
//! (step 3) converts volts to physical units, and (step 4) removes the inter-channel phase
//! differences of the multiplexing with an interpolating filter. [`Calibration`] is what
//! steps 2-4 need: gain, offset, linear range in volts and each channel's sample offset.
//!
//! ## Channels (SI units, crate frame: x horizontal, y up)
//!
//! | name | unit | meaning |
//! |---|---|---|
//! | `probe_a_x`, `probe_a_y` | m | journal centre **relative to the bearing**, bearing end A |
//! | `probe_b_x`, `probe_b_y` | m | the same at bearing end B |
//! | `frame_x`, `frame_y` | m | **absolute** displacement of the bearing housing: probes on the stiff framework looking at the housing (the framework is the inertial reference) |
//! | `f1`, `f2` | N | exciter force sensors, positive = pushing the housing along the exciter axis |
//! | `f3` | N | bellows static-load sensor, positive = the bellows pulling the housing up (+y) |
//! | `temperature` | degC | Pt thermistor 0.5 mm under the bearing surface |
//!
//! ## The chain, per sample
//!
//! Channel `k` of the scan order is sampled at `scan_start_s + k * channel_interval_s`
//! (the nominal schedule, [`DaqConfig::sample_offset_s`]). Then:
//!
//! 1. **True value** from the caller's `signals(t)`. A channel with an injected
//!    [`ChannelDelay`](crate::effects::ChannelDelay) is sampled `delay_s` later than its slot:
//!    its reading leads the other channels' by `delay_s` (a negative `delay_s` lags). The
//!    chain cannot read the future, so for a lead every other channel is asked for
//!    `t - delay_s` instead (the whole record's time base moves by `delay_s`, which no record
//!    can observe); for a lag the delayed channel is asked for `t + delay_s`.
//! 2. **Synchronous runout** (bearing probes only, if injected): the four bearing probes add a
//!    forward 1X orbit `amplitude * (cos, sin)(phi + phase)` to their (x, y) readings, `phi` the
//!    shaft angle at that sample's time. Frame probes, forces and temperature are untouched.
//! 3. **Sensor noise**: white Gaussian, `noise_rms` in the channel's SI unit. One standard
//!    normal is drawn for *every* channel of *every* scan (also when `noise_rms = 0`), from a
//!    ChaCha8 stream selected by `(seed, scan_index)`. A scan is therefore a pure function of
//!    its inputs: the same seed and signals give bit-identical scans, whatever order scans are
//!    taken in, and changing one channel's noise level does not reshuffle the others'.
//! 4. **Sensor linearity**: the sensor output is clipped (hard clip, no soft knee) to its
//!    `linear_range`. An injected [`ProbeSaturation`](crate::effects::ProbeSaturation) narrows
//!    this for one displacement probe to `zero +- limit_m`, where `zero = -offset_v /
//!    sensitivity` is the calibrated zero (the value that reads 0 V).
//! 5. **Amplifier**: `volts = offset_v + sensitivity_v_per_unit * value`, clipped to
//!    `+-full_scale_v`.
//! 6. **ADC**: mid-tread quantiser, `LSB = 2 full_scale_v / 2^adc_bits`,
//!    `code = round(volts / LSB)` clamped to `[-2^(bits-1), 2^(bits-1) - 1]`; so `-full_scale`
//!    reads exactly `-full_scale` and `+full_scale` reads `full_scale - LSB`.
//!    The reported volts are `code * LSB`.
//!
//! ### Non-finite inputs
//!
//! A real ADC never outputs NaN, so neither does this one. If the value reaching the sensor is
//! not finite (NaN or infinite true value, or NaN shaft angle with runout on) the sample is
//! put on a rail **deliberately**: `+inf` gives the top code, NaN and `-inf` the bottom code
//! (`-full_scale`). Both rails lie outside every default linear range, so the paper's step-2
//! range check rejects the record; [`Daq::non_finite_samples`] counts such samples so the
//! caller can tell a broken simulation from a saturated sensor. Nothing here panics.
//!
//! ## Default sensor set ([`DaqConfig::zhou2004`])
//!
//! Every default linear range maps inside the +-10 V ADC span (at most +-8.1 V), so a sensor
//! that leaves its linear range shows as a plateau that the range check of section 3.1 sees,
//! distinct from (and before) the ADC rails. See [`DaqConfig::zhou2004`] for the numbers.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::effects::Effects;
use crate::error::PhysicsError;

/// Number of channels of the rig (section 2.3: "these 10 amplified signals").
pub const CHANNEL_COUNT: usize = 10;

/// One of the rig's ten measured signals. The snake_case names are used everywhere in the
/// product (configuration files, records, diagnosis).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ChannelId {
    /// Journal relative to bearing, x, bearing end A (m).
    ProbeAX = 0,
    /// Journal relative to bearing, y (up), bearing end A (m).
    ProbeAY = 1,
    /// Journal relative to bearing, x, bearing end B (m).
    ProbeBX = 2,
    /// Journal relative to bearing, y (up), bearing end B (m).
    ProbeBY = 3,
    /// Housing absolute displacement, x, seen from the stiff framework (m).
    FrameX = 4,
    /// Housing absolute displacement, y (up), seen from the stiff framework (m).
    FrameY = 5,
    /// Exciter 1 force sensor, positive pushing the housing along the exciter axis (N).
    F1 = 6,
    /// Exciter 2 force sensor, positive pushing the housing along the exciter axis (N).
    F2 = 7,
    /// Bellows static-load sensor, positive pulling the housing up (N).
    F3 = 8,
    /// Pt thermistor 0.5 mm under the bearing surface (degC).
    Temperature = 9,
}

impl ChannelId {
    /// All channels, in the paper's default scan order; `ALL[c.index()] == c`.
    pub const ALL: [ChannelId; CHANNEL_COUNT] = [
        ChannelId::ProbeAX,
        ChannelId::ProbeAY,
        ChannelId::ProbeBX,
        ChannelId::ProbeBY,
        ChannelId::FrameX,
        ChannelId::FrameY,
        ChannelId::F1,
        ChannelId::F2,
        ChannelId::F3,
        ChannelId::Temperature,
    ];

    /// The snake_case name (identical to the serde name).
    pub const fn name(self) -> &'static str {
        match self {
            ChannelId::ProbeAX => "probe_a_x",
            ChannelId::ProbeAY => "probe_a_y",
            ChannelId::ProbeBX => "probe_b_x",
            ChannelId::ProbeBY => "probe_b_y",
            ChannelId::FrameX => "frame_x",
            ChannelId::FrameY => "frame_y",
            ChannelId::F1 => "f1",
            ChannelId::F2 => "f2",
            ChannelId::F3 => "f3",
            ChannelId::Temperature => "temperature",
        }
    }

    /// SI unit of the channel's physical value: `"m"`, `"N"` or `"degC"`.
    pub const fn unit(self) -> &'static str {
        match self {
            ChannelId::ProbeAX | ChannelId::ProbeAY | ChannelId::ProbeBX | ChannelId::ProbeBY | ChannelId::FrameX | ChannelId::FrameY => "m",
            ChannelId::F1 | ChannelId::F2 | ChannelId::F3 => "N",
            ChannelId::Temperature => "degC",
        }
    }

    /// Parses a snake_case channel name; anything else is [`PhysicsError::UnknownChannel`].
    pub fn parse(name: &str) -> Result<Self, PhysicsError> {
        Self::ALL.iter().copied().find(|c| c.name() == name).ok_or_else(|| PhysicsError::UnknownChannel(name.to_string()))
    }

    /// One of the four probes measuring the journal relative to the bearing.
    pub fn is_bearing_probe(self) -> bool {
        matches!(self, ChannelId::ProbeAX | ChannelId::ProbeAY | ChannelId::ProbeBX | ChannelId::ProbeBY)
    }

    /// One of the two framework probes measuring the housing's absolute displacement.
    pub fn is_frame_probe(self) -> bool {
        matches!(self, ChannelId::FrameX | ChannelId::FrameY)
    }

    /// Any of the six eddy-current displacement probes (bearing or frame).
    pub fn is_displacement_probe(self) -> bool {
        self.is_bearing_probe() || self.is_frame_probe()
    }

    /// Position in [`ChannelId::ALL`] (and in [`PhysicalSignals::values`]).
    pub fn index(self) -> usize {
        self as usize
    }

    /// Comma-separated list of all names, for error messages.
    pub fn all_names() -> String {
        Self::ALL.iter().map(|c| c.name()).collect::<Vec<_>>().join(", ")
    }
}

impl std::fmt::Display for ChannelId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for ChannelId {
    type Err = PhysicsError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::parse(s)
    }
}

/// The true physical values at one instant, indexed by [`ChannelId::index`], SI (m, N, degC),
/// plus the shaft angle (rad, from +x towards +y) that synchronous runout needs.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct PhysicalSignals {
    pub values: [f64; CHANNEL_COUNT],
    pub shaft_angle_rad: f64,
}

impl PhysicalSignals {
    /// All values zero, shaft angle zero.
    pub fn zero() -> Self {
        Self { values: [0.0; CHANNEL_COUNT], shaft_angle_rad: 0.0 }
    }

    /// The value of one channel.
    pub fn get(&self, channel: ChannelId) -> f64 {
        self.values[channel.index()]
    }

    /// Sets the value of one channel.
    pub fn set(&mut self, channel: ChannelId, value: f64) {
        self.values[channel.index()] = value;
    }
}

/// One sensor and its amplifier.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelConfig {
    pub channel: ChannelId,
    /// Amplifier output per SI unit of the measured quantity (V/m, V/N, V/degC); non-zero,
    /// may be negative (inverted sensor).
    pub sensitivity_v_per_unit: f64,
    /// Amplifier output at a true value of zero (V).
    pub offset_v: f64,
    /// Sensor noise, rms, in the channel's SI unit, added before the amplifier.
    pub noise_rms: f64,
    /// `[min, max]` in SI where the sensor is linear; outside it the output clips.
    pub linear_range: [f64; 2],
}

impl ChannelConfig {
    /// The calibrated zero: the physical value that reads 0 V (`-offset_v / sensitivity`).
    pub fn calibrated_zero(&self) -> f64 {
        -self.offset_v / self.sensitivity_v_per_unit
    }

    /// The linear range in amplifier volts, `[low, high]` (sorted, so also right for a
    /// negative sensitivity).
    pub fn linear_range_v(&self) -> [f64; 2] {
        let a = self.offset_v + self.sensitivity_v_per_unit * self.linear_range[0];
        let b = self.offset_v + self.sensitivity_v_per_unit * self.linear_range[1];
        [a.min(b), a.max(b)]
    }
}

/// The whole acquisition: card, schedule and the ten sensor chains.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DaqConfig {
    /// Scans per second, i.e. samples per second per channel (paper: 5000).
    pub sample_rate_hz: f64,
    /// Time between two consecutive conversions of the multiplexer within a scan (s).
    pub channel_interval_s: f64,
    /// ADC resolution (paper: 16).
    pub adc_bits: u32,
    /// The ADC converts `-full_scale_v ..= +full_scale_v` (paper: 10 V).
    pub full_scale_v: f64,
    /// The ten sensor chains, **in scan order**.
    pub channels: Vec<ChannelConfig>,
}

impl Default for DaqConfig {
    fn default() -> Self {
        Self::zhou2004()
    }
}

/// Joins a dotted field path to a prefix (no leading dot for an empty prefix).
fn field_path(prefix: &str, rest: &str) -> String {
    if prefix.is_empty() {
        rest.to_string()
    } else {
        format!("{prefix}.{rest}")
    }
}

impl DaqConfig {
    /// Sets the sensor noise of all six displacement probes (bearing and frame) to `rms_m`:
    /// how tests and studies put a record at a chosen signal-to-noise ratio.
    pub fn set_displacement_probe_noise(&mut self, rms_m: f64) {
        for c in self.channels.iter_mut().filter(|c| c.channel.is_displacement_probe()) {
            c.noise_rms = rms_m;
        }
    }

    /// The rig of Zhou et al. (2004), section 2.3, with documented sensor choices.
    ///
    /// Card: 5000 scans/s; channel interval 10 us (the PCI-9114 at its 100 kS/s aggregate
    /// rate), so one scan of 10 channels spans 90 us of the 200 us scan period; 16 bit over
    /// +-10 V, LSB = 305 uV.
    ///
    /// | channel | sensitivity | offset | linear range | volts of linear range | noise rms | resolution (1 LSB) |
    /// |---|---|---|---|---|---|---|
    /// | 4 bearing + 2 frame probes | 40 V/mm (4e4 V/m) | 0 V | +-0.2 mm | +-8 V | 0.1 um | 7.6 nm |
    /// | `f1`, `f2` | 4 mV/N | 0 V | +-2 kN | +-8 V | 1 N | 0.076 N |
    /// | `f3` | 0.6 mV/N | -7.5 V | -1 kN .. 25 kN | -8.1 .. +7.5 V | 5 N | 0.51 N |
    /// | `temperature` | 0.15 V/degC | -7.5 V | 0 .. 100 degC | -7.5 .. +7.5 V | 0.05 degC | 0.002 degC |
    ///
    /// Why these numbers:
    /// * **Probes.** The journal moves inside the clearance circle, radius 0.114 mm, about the
    ///   bearing centre (the calibrated zero: the probes are zeroed with the journal centred);
    ///   the static eccentricity puts it low but never beyond 0.114 mm. 40 V/mm makes +-0.25 mm
    ///   fill +-10 V. The linear range is set to +-0.2 mm, *not* wider than the ADC span: a
    ///   linear range beyond the rails (e.g. +-0.3 mm) would make the paper's linear-range
    ///   check unable to see anything the ADC had not already clipped. +-0.2 mm still leaves
    ///   75 % headroom over the clearance. The frame probes see the housing, which moves by
    ///   the same order (the shaft is stiff), so they use the same setting. 0.1 um rms is a
    ///   typical broadband noise floor of an eddy-current probe driver (about 13 LSB).
    /// * **`f1`, `f2`.** The exciters give up to 1.5 kN (section 2.1); +-2 kN linear range gives
    ///   a third of headroom for the sensor, and 4 mV/N puts it at +-8 V. 1 N rms is 0.05 % of
    ///   the range, a usual figure for a strain-gauge force sensor with its amplifier.
    /// * **`f3`.** The static load runs 0-20 kN in the experiments (section 2.4, rig up to
    ///   40 kN); the sensor is linear to 25 kN and, being bidirectional, down to -1 kN so that
    ///   a zero static load with noise does not clip. 0.6 mV/N with -7.5 V offset puts
    ///   0..25 kN at -7.5..+7.5 V. Noise 5 N rms is 0.02 % of the 25 kN range.
    /// * **Temperature.** 0-100 degC onto -7.5..+7.5 V; the Pt element is linear far beyond,
    ///   the amplifier's range is what is quoted. 0.05 degC rms is a typical Pt-channel noise.
    pub fn zhou2004() -> Self {
        const PROBE_SENSITIVITY_V_PER_M: f64 = 40.0e3;
        const PROBE_LINEAR_M: f64 = 0.2e-3;
        const PROBE_NOISE_M: f64 = 0.1e-6;
        let probe = |channel| ChannelConfig {
            channel,
            sensitivity_v_per_unit: PROBE_SENSITIVITY_V_PER_M,
            offset_v: 0.0,
            noise_rms: PROBE_NOISE_M,
            linear_range: [-PROBE_LINEAR_M, PROBE_LINEAR_M],
        };
        let exciter_force = |channel| ChannelConfig { channel, sensitivity_v_per_unit: 4.0e-3, offset_v: 0.0, noise_rms: 1.0, linear_range: [-2000.0, 2000.0] };
        Self {
            sample_rate_hz: 5000.0,
            channel_interval_s: 10.0e-6,
            adc_bits: 16,
            full_scale_v: 10.0,
            channels: vec![
                probe(ChannelId::ProbeAX),
                probe(ChannelId::ProbeAY),
                probe(ChannelId::ProbeBX),
                probe(ChannelId::ProbeBY),
                probe(ChannelId::FrameX),
                probe(ChannelId::FrameY),
                exciter_force(ChannelId::F1),
                exciter_force(ChannelId::F2),
                ChannelConfig { channel: ChannelId::F3, sensitivity_v_per_unit: 0.6e-3, offset_v: -7.5, noise_rms: 5.0, linear_range: [-1000.0, 25000.0] },
                ChannelConfig { channel: ChannelId::Temperature, sensitivity_v_per_unit: 0.15, offset_v: -7.5, noise_rms: 0.05, linear_range: [0.0, 100.0] },
            ],
        }
    }

    /// Checks the configuration; `prefix` is the dotted path of this table (e.g. `"daq"`), and
    /// every error names the offending field (`daq.channels[3].sensitivity_v_per_unit`).
    pub fn validate(&self, prefix: &str) -> Result<(), PhysicsError> {
        let f = |rest: &str| field_path(prefix, rest);
        if !(self.sample_rate_hz.is_finite() && self.sample_rate_hz > 0.0) {
            return Err(PhysicsError::invalid(f("sample_rate_hz"), format!("must be finite and > 0, got {:?}", self.sample_rate_hz)));
        }
        if !(self.channel_interval_s.is_finite() && self.channel_interval_s >= 0.0) {
            return Err(PhysicsError::invalid(f("channel_interval_s"), format!("must be finite and >= 0, got {:?}", self.channel_interval_s)));
        }
        if !(8..=24).contains(&self.adc_bits) {
            return Err(PhysicsError::invalid(f("adc_bits"), format!("must be in 8..=24, got {:?}", self.adc_bits)));
        }
        if !(self.full_scale_v.is_finite() && self.full_scale_v > 0.0) {
            return Err(PhysicsError::invalid(f("full_scale_v"), format!("must be finite and > 0, got {:?}", self.full_scale_v)));
        }
        let mut seen: [Option<usize>; CHANNEL_COUNT] = [None; CHANNEL_COUNT];
        for (i, ch) in self.channels.iter().enumerate() {
            let cf = |rest: &str| f(&format!("channels[{i}].{rest}"));
            if let Some(first) = seen[ch.channel.index()] {
                return Err(PhysicsError::invalid(cf("channel"), format!("`{}` is already scanned as channels[{first}]", ch.channel)));
            }
            seen[ch.channel.index()] = Some(i);
            let s = ch.sensitivity_v_per_unit;
            if !(s.is_finite() && s != 0.0) {
                return Err(PhysicsError::invalid(cf("sensitivity_v_per_unit"), format!("must be finite and non-zero, got {s:?}")));
            }
            if !ch.offset_v.is_finite() {
                return Err(PhysicsError::invalid(cf("offset_v"), format!("must be finite, got {:?}", ch.offset_v)));
            }
            if !(ch.noise_rms.is_finite() && ch.noise_rms >= 0.0) {
                return Err(PhysicsError::invalid(cf("noise_rms"), format!("must be finite and >= 0, got {:?}", ch.noise_rms)));
            }
            let [lo, hi] = ch.linear_range;
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err(PhysicsError::invalid(cf("linear_range"), format!("must be finite [min, max] with min < max, got [{lo:?}, {hi:?}]")));
            }
            let [vlo, vhi] = ch.linear_range_v();
            if !(vlo < self.full_scale_v && vhi > -self.full_scale_v) {
                return Err(PhysicsError::invalid(
                    cf("linear_range"),
                    format!("maps to [{vlo}, {vhi}] V, entirely outside the ADC span +-{} V (check offset_v and sensitivity)", self.full_scale_v),
                ));
            }
        }
        let missing: Vec<&str> = ChannelId::ALL.iter().filter(|c| seen[c.index()].is_none()).map(|c| c.name()).collect();
        if !missing.is_empty() {
            return Err(PhysicsError::invalid(
                f("channels"),
                format!("missing channel(s) {}; all ten must be scanned ({})", missing.join(", "), ChannelId::all_names()),
            ));
        }
        let scan_span = self.channel_interval_s * (self.channels.len() as f64 - 1.0);
        let period = 1.0 / self.sample_rate_hz;
        if scan_span >= period {
            return Err(PhysicsError::invalid(
                f("channel_interval_s"),
                format!(
                    "{} channels x {} s = {scan_span} s per scan does not fit in the scan period 1/{} Hz = {period} s",
                    self.channels.len(),
                    self.channel_interval_s,
                    self.sample_rate_hz
                ),
            ));
        }
        Ok(())
    }

    /// The scan period `1 / sample_rate_hz` (s).
    pub fn scan_period_s(&self) -> f64 {
        1.0 / self.sample_rate_hz
    }

    /// Nominal time of `channel`'s conversion after the scan start: its position in the scan
    /// order times `channel_interval_s`. Injected delays are not included (they are what the
    /// calibration does not know).
    pub fn sample_offset_s(&self, channel: ChannelId) -> Result<f64, PhysicsError> {
        self.channels
            .iter()
            .position(|c| c.channel == channel)
            .map(|k| k as f64 * self.channel_interval_s)
            .ok_or_else(|| PhysicsError::UnknownChannel(channel.name().to_string()))
    }

    /// The volts-to-SI conversion and schedule the conditioning stage uses.
    pub fn calibration(&self) -> Calibration {
        Calibration {
            sample_rate_hz: self.sample_rate_hz,
            channel_interval_s: self.channel_interval_s,
            adc_bits: self.adc_bits,
            full_scale_v: self.full_scale_v,
            lsb_v: lsb_v(self.full_scale_v, self.adc_bits),
            channels: self
                .channels
                .iter()
                .enumerate()
                .map(|(k, c)| ChannelCalibration {
                    channel: c.channel,
                    sensitivity_v_per_unit: c.sensitivity_v_per_unit,
                    offset_v: c.offset_v,
                    linear_range_v: c.linear_range_v(),
                    sample_offset_s: k as f64 * self.channel_interval_s,
                })
                .collect(),
        }
    }

    /// The channels in the order the multiplexer converts them.
    pub fn scan_order(&self) -> Vec<ChannelId> {
        self.channels.iter().map(|c| c.channel).collect()
    }
}

/// `2 full_scale / 2^bits`; `bits` is clamped to 1..=62 so that no input can overflow.
fn lsb_v(full_scale_v: f64, adc_bits: u32) -> f64 {
    2.0 * full_scale_v / (1u64 << adc_bits.clamp(1, 62)) as f64
}

/// Calibration of one channel, as the conditioning stage sees it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ChannelCalibration {
    pub channel: ChannelId,
    pub sensitivity_v_per_unit: f64,
    pub offset_v: f64,
    /// The sensor's linear range in volts, `[low, high]`.
    pub linear_range_v: [f64; 2],
    /// Nominal conversion time after the scan start (s).
    pub sample_offset_s: f64,
}

/// Volts -> SI for the conditioning stage: per channel gain/offset and linear range expressed
/// in volts, plus the schedule (section 3.1, steps 2-4). Holds only what the calibration of
/// the real rig would know: injected effects are not in here.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    sample_rate_hz: f64,
    channel_interval_s: f64,
    adc_bits: u32,
    full_scale_v: f64,
    lsb_v: f64,
    /// In scan order.
    channels: Vec<ChannelCalibration>,
}

impl Calibration {
    /// The calibration record of one channel.
    pub fn channel(&self, channel: ChannelId) -> Result<&ChannelCalibration, PhysicsError> {
        self.channels.iter().find(|c| c.channel == channel).ok_or_else(|| PhysicsError::UnknownChannel(channel.name().to_string()))
    }

    /// All channel records, in scan order.
    pub fn channels(&self) -> &[ChannelCalibration] {
        &self.channels
    }

    /// Converts a reading to the channel's SI unit: `(volts - offset_v) / sensitivity`.
    /// Non-finite volts (or a result that is not finite) give [`PhysicsError::NonFinite`].
    pub fn to_si(&self, channel: ChannelId, volts: f64) -> Result<f64, PhysicsError> {
        let c = self.channel(channel)?;
        PhysicsError::check_finite(&format!("daq volts on {channel}"), volts)?;
        let si = (volts - c.offset_v) / c.sensitivity_v_per_unit;
        PhysicsError::check_finite(&format!("daq {channel} in {}", channel.unit()), si)
    }

    /// The channel's linear range in volts, `[low, high]`.
    pub fn linear_range_v(&self, channel: ChannelId) -> Result<[f64; 2], PhysicsError> {
        Ok(self.channel(channel)?.linear_range_v)
    }

    /// Whether a reading is inside the linear range (section 3.1, step 2). A sensor that clips
    /// at a range edge reads within half an LSB of it after quantisation, so readings within
    /// half an LSB of an edge (or beyond) count as **out of range**; a genuinely linear value
    /// that close to the edge is lost too, which is the conservative side.
    pub fn within_linear_range(&self, channel: ChannelId, volts: f64) -> Result<bool, PhysicsError> {
        let [lo, hi] = self.linear_range_v(channel)?;
        let margin = 0.5 * self.lsb_v;
        Ok(volts > lo + margin && volts < hi - margin)
    }

    /// Nominal conversion time of `channel` after the scan start (s).
    pub fn sample_offset_s(&self, channel: ChannelId) -> Result<f64, PhysicsError> {
        Ok(self.channel(channel)?.sample_offset_s)
    }

    /// Scans per second.
    pub fn sample_rate_hz(&self) -> f64 {
        self.sample_rate_hz
    }

    /// Multiplexer interval within a scan (s).
    pub fn channel_interval_s(&self) -> f64 {
        self.channel_interval_s
    }

    /// ADC resolution in bits.
    pub fn adc_bits(&self) -> u32 {
        self.adc_bits
    }

    /// ADC full scale (V); codes span `-full_scale ..= full_scale - LSB`.
    pub fn full_scale_v(&self) -> f64 {
        self.full_scale_v
    }

    /// One ADC step, `2 full_scale / 2^bits` (V).
    pub fn lsb_v(&self) -> f64 {
        self.lsb_v
    }

    /// One ADC step expressed in the channel's SI unit, `LSB / |sensitivity|`.
    pub fn resolution_si(&self, channel: ChannelId) -> Result<f64, PhysicsError> {
        Ok(self.lsb_v / self.channel(channel)?.sensitivity_v_per_unit.abs())
    }

    /// Channels in scan order.
    pub fn scan_order(&self) -> Vec<ChannelId> {
        self.channels.iter().map(|c| c.channel).collect()
    }

    /// The same sensors on another acquisition schedule: a record made by a different DAQ (or
    /// the same card at another rate) states its scan rate, its channel order and each
    /// channel's conversion offset within a scan; gains, offsets and linear ranges stay.
    /// `schedule` lists every channel once, in scan order, with its offset (s), each in
    /// `[0, 1 / sample_rate_hz)`.
    pub fn with_schedule(&self, sample_rate_hz: f64, schedule: &[(ChannelId, f64)]) -> Result<Self, PhysicsError> {
        if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
            return Err(PhysicsError::invalid("schedule.sample_rate_hz", format!("must be finite and > 0, got {sample_rate_hz:?}")));
        }
        if schedule.len() != self.channels.len() {
            return Err(PhysicsError::invalid("schedule", format!("names {} channels; the calibration has {}", schedule.len(), self.channels.len())));
        }
        let period = 1.0 / sample_rate_hz;
        let mut channels = Vec::with_capacity(schedule.len());
        for (k, &(channel, offset)) in schedule.iter().enumerate() {
            if schedule[..k].iter().any(|(c, _)| *c == channel) {
                return Err(PhysicsError::invalid(format!("schedule[{k}]"), format!("channel `{channel}` appears twice")));
            }
            if !(offset.is_finite() && (0.0..period).contains(&offset)) {
                return Err(PhysicsError::invalid(
                    format!("schedule[{k}] ({channel})"),
                    format!("offset {offset} s must lie in [0, {period}) s, one scan period"),
                ));
            }
            channels.push(ChannelCalibration { sample_offset_s: offset, ..self.channel(channel)?.clone() });
        }
        let interval = if schedule.len() > 1 { schedule[1].1 - schedule[0].1 } else { 0.0 };
        Ok(Self { sample_rate_hz, channel_interval_s: interval, channels, ..self.clone() })
    }
}

/// One multiplexed scan.
#[derive(Clone, Debug, PartialEq)]
pub struct DaqScan {
    pub scan_index: u64,
    pub scan_start_s: f64,
    /// ADC codes, scan order.
    pub counts: Vec<i32>,
    /// `code * LSB`, scan order.
    pub volts: Vec<f64>,
    /// Scan order.
    pub channels: Vec<ChannelId>,
}

impl DaqScan {
    /// The reading of one channel in volts.
    pub fn volts_of(&self, channel: ChannelId) -> Result<f64, PhysicsError> {
        self.channels
            .iter()
            .position(|&c| c == channel)
            .and_then(|k| self.volts.get(k).copied())
            .ok_or_else(|| PhysicsError::UnknownChannel(channel.name().to_string()))
    }

    /// The ADC code of one channel.
    pub fn count_of(&self, channel: ChannelId) -> Result<i32, PhysicsError> {
        self.channels
            .iter()
            .position(|&c| c == channel)
            .and_then(|k| self.counts.get(k).copied())
            .ok_or_else(|| PhysicsError::UnknownChannel(channel.name().to_string()))
    }
}

/// Injected synchronous runout as one bearing probe sees it.
#[derive(Clone, Copy, Debug)]
struct ProbeRunout {
    amplitude_m: f64,
    phase_rad: f64,
    /// x probe reads the cosine, y probe the sine (forward orbit).
    is_x: bool,
}

/// One resolved slot of the scan.
#[derive(Clone, Debug)]
struct Slot {
    channel: ChannelId,
    nominal_offset_s: f64,
    extra_delay_s: f64,
    runout: Option<ProbeRunout>,
    noise_rms: f64,
    sensor_lo: f64,
    sensor_hi: f64,
    sensitivity: f64,
    offset_v: f64,
}

/// The acquisition chain, ready to scan. See the module documentation for the chain.
#[derive(Clone, Debug)]
pub struct Daq {
    slots: Vec<Slot>,
    full_scale_v: f64,
    lsb_v: f64,
    code_min: i32,
    code_max: i32,
    max_delay_s: f64,
    max_schedule_s: f64,
    /// Seeded generator at stream 0, word 0; each scan clones it and selects its own stream.
    base_rng: ChaCha8Rng,
    non_finite_samples: u64,
    calibration: Calibration,
}

impl Daq {
    /// Validates `config` (fields named under `daq.`) and `effects` (under `effects.`) and
    /// resolves the DAQ effects' channel names: an unknown channel is an error on
    /// `effects.channel_delay.channel` / `effects.probe_saturation.channel`, and saturation
    /// must name a displacement probe. Effects acting in the rig are ignored here.
    pub fn new(config: &DaqConfig, effects: &Effects, seed: u64) -> Result<Self, PhysicsError> {
        config.validate("daq")?;
        effects.validate("effects")?;

        let delay = match &effects.channel_delay {
            Some(d) => {
                let ch = ChannelId::parse(&d.channel).map_err(|_| {
                    PhysicsError::invalid(
                        "effects.channel_delay.channel",
                        format!("unknown DAQ channel `{}`; expected one of {}", d.channel, ChannelId::all_names()),
                    )
                })?;
                Some((ch, d.delay_s))
            }
            None => None,
        };
        let saturation = match &effects.probe_saturation {
            Some(s) => {
                let ch = ChannelId::parse(&s.channel).map_err(|_| {
                    PhysicsError::invalid(
                        "effects.probe_saturation.channel",
                        format!("unknown DAQ channel `{}`; expected one of {}", s.channel, ChannelId::all_names()),
                    )
                })?;
                if !ch.is_displacement_probe() {
                    return Err(PhysicsError::invalid(
                        "effects.probe_saturation.channel",
                        format!("`{ch}` is not a displacement probe; expected one of probe_a_x, probe_a_y, probe_b_x, probe_b_y, frame_x, frame_y"),
                    ));
                }
                Some((ch, s.limit_m))
            }
            None => None,
        };

        let mut slots = Vec::with_capacity(config.channels.len());
        for (k, c) in config.channels.iter().enumerate() {
            let [mut lo, mut hi] = c.linear_range;
            if let Some((ch, limit)) = saturation {
                if ch == c.channel {
                    let zero = c.calibrated_zero();
                    lo = lo.max(zero - limit);
                    hi = hi.min(zero + limit);
                    if lo >= hi {
                        return Err(PhysicsError::invalid(
                            "effects.probe_saturation.limit_m",
                            format!(
                                "the band {zero:?} +- {limit:?} m about the calibrated zero of `{ch}` does not overlap its linear range [{:?}, {:?}] m",
                                c.linear_range[0], c.linear_range[1]
                            ),
                        ));
                    }
                }
            }
            let runout = match &effects.synchronous_runout {
                Some(r) if c.channel.is_bearing_probe() => Some(ProbeRunout {
                    amplitude_m: r.amplitude_m,
                    phase_rad: r.phase_deg.to_radians(),
                    is_x: matches!(c.channel, ChannelId::ProbeAX | ChannelId::ProbeBX),
                }),
                _ => None,
            };
            // How much earlier than its slot each channel reads the signal. A channel sampled
            // `d > 0` later than its slot leads the others by `d`; the chain has no future to
            // read, so the others read `d` earlier instead (the record's time base moves by
            // `d`, which no record can observe). A channel with `d < 0` lags: it reads `-d`
            // earlier itself.
            let extra_delay_s = match delay {
                Some((ch, d)) if ch == c.channel => (-d).max(0.0),
                Some((_, d)) => d.max(0.0),
                None => 0.0,
            };
            slots.push(Slot {
                channel: c.channel,
                nominal_offset_s: k as f64 * config.channel_interval_s,
                extra_delay_s,
                runout,
                noise_rms: c.noise_rms,
                sensor_lo: lo,
                sensor_hi: hi,
                sensitivity: c.sensitivity_v_per_unit,
                offset_v: c.offset_v,
            });
        }

        let half_codes = 1i64 << (config.adc_bits - 1);
        Ok(Self {
            slots,
            full_scale_v: config.full_scale_v,
            lsb_v: lsb_v(config.full_scale_v, config.adc_bits),
            code_min: -half_codes as i32,
            code_max: (half_codes - 1) as i32,
            max_delay_s: delay.map_or(0.0, |(_, d)| d.abs()),
            max_schedule_s: config.channel_interval_s * (config.channels.len() as f64 - 1.0),
            base_rng: ChaCha8Rng::seed_from_u64(seed),
            non_finite_samples: 0,
            calibration: config.calibration(),
        })
    }

    /// Samples one scan starting at `scan_start_s`: channel `k` in scan order is converted at
    /// `scan_start_s + k * channel_interval_s`; with an injected channel delay the delayed
    /// channel's reading leads the others' by `delay_s` (lags for a negative one). `signals(t)` must return the true physical values at `t`
    /// (the caller interpolates its simulation); it is called once per channel, in scan order.
    /// The result depends only on the configuration, effects, seed, `scan_index`,
    /// `scan_start_s` and what `signals` returns.
    pub fn scan(&mut self, scan_index: u64, scan_start_s: f64, signals: &mut dyn FnMut(f64) -> PhysicalSignals) -> DaqScan {
        let mut rng = self.base_rng.clone();
        rng.set_stream(scan_index);
        rng.set_word_pos(0);

        let n = self.slots.len();
        let mut counts = Vec::with_capacity(n);
        let mut volts = Vec::with_capacity(n);
        let mut channels = Vec::with_capacity(n);
        for slot in &self.slots {
            let t = scan_start_s + slot.nominal_offset_s - slot.extra_delay_s;
            let s = signals(t);
            // Always draw, so the stream stays aligned whatever the noise settings.
            let z: f64 = StandardNormal.sample(&mut rng);

            let mut value = s.values[slot.channel.index()];
            if let Some(r) = slot.runout {
                let phi = s.shaft_angle_rad + r.phase_rad;
                value += r.amplitude_m * if r.is_x { phi.cos() } else { phi.sin() };
            }
            value += slot.noise_rms * z;

            let code = if value.is_finite() {
                // Sensor linearity: hard clip (finite value and lo < hi, so no NaN games).
                let sensed = value.max(slot.sensor_lo).min(slot.sensor_hi);
                let amp = (slot.offset_v + slot.sensitivity * sensed).max(-self.full_scale_v).min(self.full_scale_v);
                let raw = (amp / self.lsb_v).round();
                // `raw` is finite and within +-2^(bits-1) (+1 at most), so the cast is exact.
                (raw as i64).clamp(self.code_min as i64, self.code_max as i64) as i32
            } else {
                self.non_finite_samples = self.non_finite_samples.saturating_add(1);
                if value == f64::INFINITY {
                    self.code_max
                } else {
                    self.code_min
                }
            };
            counts.push(code);
            volts.push(code as f64 * self.lsb_v);
            channels.push(slot.channel);
        }
        DaqScan { scan_index, scan_start_s, counts, volts, channels }
    }

    /// How far before `scan_start_s` [`Daq::scan`] may ask `signals` (the injected channel
    /// delay, 0 without one), so the caller keeps enough history.
    pub fn max_lookback_s(&self) -> f64 {
        self.max_delay_s
    }

    /// How far after `scan_start_s` [`Daq::scan`] may ask `signals`: the last channel's
    /// schedule offset, `(n - 1) * channel_interval_s`.
    pub fn max_lookahead_s(&self) -> f64 {
        self.max_schedule_s
    }

    /// Samples whose value reaching the sensor was not finite, since construction (each was
    /// put on an ADC rail, see the module documentation).
    pub fn non_finite_samples(&self) -> u64 {
        self.non_finite_samples
    }

    /// The calibration of this chain (nominal: injected effects are not in it).
    pub fn calibration(&self) -> &Calibration {
        &self.calibration
    }

    /// One ADC step (V).
    pub fn lsb_v(&self) -> f64 {
        self.lsb_v
    }

    /// Channels in scan order.
    pub fn scan_order(&self) -> Vec<ChannelId> {
        self.slots.iter().map(|s| s.channel).collect()
    }
}
