//! # Conditioning: from raw multiplexed DAQ samples to what the estimator consumes
//!
//! Zhou et al. (2004), section 3.1, process each record in nine steps; this module does
//! steps 1-7 and hands the kinematics `r, r', r''` and the film force `F` of eq. 2 to the
//! least-squares estimator (steps 8-9, [`crate::estimator`]).
//!
//! | paper step | stage | here |
//! |---|---|---|
//! | 3 volts -> physical value | [`calibrate`] | first, per channel |
//! | 2 linear-range check | [`range_check`] | on the raw samples, before any filter |
//! | 4 "inner-insert filter" (multiplex phase) | [`deskew`] | Lagrange fractional delay per channel |
//! | 1 low-pass | [`lowpass`] | zero-phase Butterworth, forward-backward, same on every channel |
//! | 5 relative / absolute displacement | [`kinematics`] | `r` = mean of ends A, B; tilt = A - B; `X` = frame probes |
//! | 6 velocity, acceleration | [`differentiate`] | Savitzky-Golay FIR, applied twice |
//! | 7 eq. 2, static / dynamic | [`film_force`] | `F = F_exc + (f3 - m g) e_y - m X''`; static = mean over `valid` |
//!
//! ## Order of the stages
//! Deskew, low-pass, kinematics and differentiation are all linear and time-invariant, so
//! their order does not change the result away from the record's ends; what matters is
//! that (a) the range check sees the **raw** samples (a filter would smear a clipped
//! plateau below the threshold), and (b) every channel that enters eq. 1 and eq. 2 passes
//! through the **same** low-pass, so its passband droop is common to both sides of the
//! linear relation and cancels in the fit. Channels then differ only by the deskew residual
//! and the differentiator's gain error, which are the budgeted numbers below.
//!
//! ## Error budget at the top of the excitation band (80 Hz, 5 kHz, defaults)
//!
//! | stage | error at 80 Hz | literature |
//! |---|---|---|
//! | deskew, 4-tap Lagrange, offsets 0..90 us | amplitude <= 2.4e-6, phase <= 3.6e-8 rad | Laakso et al., "Splitting the unit delay", IEEE SP Magazine 1996 |
//! | low-pass, Butterworth N = 4, 200 Hz, forward-backward | gain 0.999367 (-6.3e-4), phase exactly 0; 1 kHz at -122 dB | Gustafsson, IEEE Trans. SP 44(4) 1996 (edge states) |
//! | differentiator, Savitzky-Golay degree 4, M = 5 | gain -1.6e-4 (velocity), -3.2e-4 (acceleration), phase exact | Savitzky & Golay, Anal. Chem. 1964; Gorry, Anal. Chem. 1990 (edges) |
//!
//! The tests in `tests/conditioning.rs` measure each of these on synthetic sines.
//!
//! ## The valid range
//! Every stage treats the record's ends differently from its interior (shifted Lagrange
//! stencils, reflected extension, one-sided Savitzky-Golay windows). [`Conditioned::valid`]
//! excludes, at each end, the deskew stencil's reach (2 samples for 4 taps) + the low-pass
//! settling time (slowest pole down to 1e-7: 169 samples for the defaults) + `2 M` (two
//! differentiator passes, 10 samples): 181 samples, 36 ms, for the defaults. The estimator
//! must use only `valid`; the static force is the mean over `valid`.
//!
//! ## Inputs that are refused
//! Non-finite samples (`BadInput` naming channel and sample index), columns of unequal
//! length, a channel missing or given twice, a non-positive sample rate, a cutoff at or
//! above Nyquist, a record shorter than the edge trims. A probe out of its linear range is
//! *not* an error of [`condition`]: the record is conditioned and carries the violation
//! ([`Conditioned::range_violations`]), and [`Conditioned::require_in_range`] is what a
//! consumer calls to refuse it, as the paper's step 2 demands.
//!
//! ## Cost
//! On a shared machine the chain is bound as much by memory traffic as by arithmetic, so
//! the stages are fused where they meet: calibration, range count, de-skew and the linear
//! combinations of steps 5 and 7 run scan tile by scan tile in L1 (`front_end`), reading
//! each raw column once; the low-pass makes one pass per direction over the eight dynamic
//! columns; the second derivative follows the first block by block, and eq. 2's inertial
//! part follows the housing acceleration; each stage checks the finiteness of what it
//! writes, so nothing is read again for that. The hot loops are compiled for AVX2 when the
//! CPU has it (runtime detection, no FMA, so the result is the same bit for bit on every
//! CPU). The per-stage functions remain, and the fused path falls back to them whenever there
//! is something to report (a non-finite or out-of-range reading) so that the report names
//! the sample. [`condition`] allocates the 17 output columns and nothing else of size;
//! [`condition_into`] reuses those of a previous result and allocates nothing of size.
//! Measured on one core of the shared 2-core development machine for a 300 000-scan,
//! 10-channel record, best of 15: `condition_into` about 16-17 ms under a load average of
//! 4-5 (175-185 M samples/s; 18.4-19.8 ms before the transposed low-pass lanes and the
//! AVX-512 derivative, in the same runs); the front end is now the largest part, then the
//! zero-phase low-pass.

pub mod blocks;
pub mod calibrate;
pub mod causal;
pub mod deskew;
pub mod differentiate;
pub mod film_force;
pub mod kinematics;
pub mod lowpass;
pub mod range_check;
pub mod stream;

use std::ops::Range;

use oilfilm_physics::daq::{Calibration, ChannelId, DaqScan, CHANNEL_COUNT};
use serde::{Deserialize, Serialize};

use crate::IdentificationError;

/// The rig's mechanics needed by eq. 2 (the caller builds it from the rig file).
#[derive(Clone, Debug, PartialEq)]
pub struct Mechanics {
    /// Mass of the floating housing and everything moving with it (kg), `> 0`.
    pub housing_mass_kg: f64,
    /// Exciter axes measured from `+x` towards `+y` (deg); paper: `[45, 135]`.
    pub exciter_angles_deg: [f64; 2],
    /// Gravitational acceleration (m/s^2), acting along `-y`.
    pub gravity_m_s2: f64,
}

impl Mechanics {
    /// Checks that every field is finite and the mass positive; errors name the field
    /// (`mechanics.housing_mass_kg`).
    pub fn validate(&self) -> Result<(), IdentificationError> {
        if !(self.housing_mass_kg.is_finite() && self.housing_mass_kg > 0.0) {
            return Err(IdentificationError::invalid(
                "mechanics.housing_mass_kg",
                format!("must be finite and > 0, got {}", self.housing_mass_kg),
            ));
        }
        for (i, a) in self.exciter_angles_deg.iter().enumerate() {
            if !a.is_finite() {
                return Err(IdentificationError::invalid(
                    format!("mechanics.exciter_angles_deg[{i}]"),
                    format!("must be finite, got {a}"),
                ));
            }
        }
        if !self.gravity_m_s2.is_finite() {
            return Err(IdentificationError::invalid(
                "mechanics.gravity_m_s2",
                format!("must be finite, got {}", self.gravity_m_s2),
            ));
        }
        Ok(())
    }
}

/// Parameters of the conditioning chain. Missing fields in a file take the defaults.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConditioningConfig {
    /// Butterworth cutoff (Hz, -3 dB of one pass); default 200 Hz for an excitation band up
    /// to 80 Hz at 5 kHz. Must lie below Nyquist.
    pub lowpass_cutoff_hz: f64,
    /// Butterworth order (1..=12); default 4.
    pub lowpass_order: usize,
    /// Savitzky-Golay differentiator half-length `M` (2..=64); default 5.
    pub differentiator_half_length: usize,
    /// Remove the multiplex skew (the paper's step 4). `false` only to demonstrate what the
    /// skew does.
    pub deskew: bool,
    /// Lagrange interpolator length (2..=16); default 4 (cubic).
    pub deskew_taps: usize,
}

impl Default for ConditioningConfig {
    fn default() -> Self {
        Self {
            lowpass_cutoff_hz: 200.0,
            lowpass_order: 4,
            differentiator_half_length: 5,
            deskew: true,
            deskew_taps: 4,
        }
    }
}

impl ConditioningConfig {
    /// Checks every field against the record's sample rate; errors name the field
    /// (`conditioning.lowpass_cutoff_hz`, ...).
    pub fn validate(&self, sample_rate_hz: f64) -> Result<(), IdentificationError> {
        self.designs(sample_rate_hz, None).map(|_| ())
    }

    /// [`ConditioningConfig::validate`], returning the low-pass and the differentiator it
    /// designed on the way. `reuse` is a differentiator designed before: taken as it is if it
    /// has this half-length and sample rate (designing one solves `2M + 1` small
    /// least-squares problems, a cost that showed in the conditioner node's short blocks).
    fn designs(
        &self,
        sample_rate_hz: f64,
        reuse: Option<differentiate::SavitzkyGolayDerivative>,
    ) -> Result<(lowpass::Butterworth, differentiate::SavitzkyGolayDerivative), IdentificationError> {
        if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
            return Err(IdentificationError::invalid(
                "sample_rate_hz",
                format!("must be finite and > 0, got {sample_rate_hz}"),
            ));
        }
        let lp = lowpass::Butterworth::design(self.lowpass_order, self.lowpass_cutoff_hz, sample_rate_hz)?;
        let sg = match reuse {
            Some(sg)
                if sg.half_length() == self.differentiator_half_length
                    && sg.sample_rate_hz().to_bits() == sample_rate_hz.to_bits() =>
            {
                sg
            }
            _ => differentiate::SavitzkyGolayDerivative::new(self.differentiator_half_length, sample_rate_hz)?,
        };
        if !(2..=deskew::MAX_TAPS).contains(&self.deskew_taps) {
            return Err(IdentificationError::invalid(
                "conditioning.deskew_taps",
                format!(
                    "must be in 2..={}, got {}",
                    deskew::MAX_TAPS,
                    self.deskew_taps
                ),
            ));
        }
        Ok((lp, sg))
    }
}

/// The unit of a raw record's columns.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RawUnits {
    /// Amplifier volts as read by the ADC; calibrated here.
    Volts,
    /// Already in the channel's SI unit (m, N, degC).
    Si,
}

impl RawUnits {
    /// `"volts"` or `"si"`.
    pub fn name(self) -> &'static str {
        match self {
            RawUnits::Volts => "volts",
            RawUnits::Si => "si",
        }
    }
}

/// A raw record: one column per channel in scan order, sample `i` of every column belonging
/// to the scan that started at `start_time_s + i / sample_rate_hz`.
#[derive(Clone, Debug, PartialEq)]
pub struct RawRecord {
    /// Scans per second.
    pub sample_rate_hz: f64,
    /// Start time of the first scan (s).
    pub start_time_s: f64,
    /// Channel of each column, in scan order.
    pub channels: Vec<ChannelId>,
    pub units: RawUnits,
    pub columns: Vec<Vec<f64>>,
}

impl RawRecord {
    /// Transposes a sequence of consecutive scans (volts) into columns. The scans must share
    /// one channel order and be spaced `1 / sample_rate_hz` apart (within 0.1 % of a period):
    /// a gap, a repeated or out-of-order scan is a `BadInput` naming the scan.
    pub fn from_scans(scans: &[DaqScan], sample_rate_hz: f64) -> Result<Self, IdentificationError> {
        if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
            return Err(IdentificationError::invalid(
                "sample_rate_hz",
                format!("must be finite and > 0, got {sample_rate_hz}"),
            ));
        }
        let Some(first) = scans.first() else {
            return Err(IdentificationError::BadInput {
                what: "scans".into(),
                reason: "no scans".into(),
            });
        };
        let channels = first.channels.clone();
        let start = first.scan_start_s;
        if !start.is_finite() {
            return Err(IdentificationError::BadInput {
                what: "scans[0].scan_start_s".into(),
                reason: format!("not finite ({start})"),
            });
        }
        let period = 1.0 / sample_rate_hz;
        let mut columns: Vec<Vec<f64>> = (0..channels.len())
            .map(|_| Vec::with_capacity(scans.len()))
            .collect();
        for (i, s) in scans.iter().enumerate() {
            if s.channels != channels || s.volts.len() != channels.len() {
                return Err(IdentificationError::BadInput {
                    what: format!("scans[{i}] (scan_index {})", s.scan_index),
                    reason: format!(
                        "channels {:?} with {} readings; scans[0] has {:?}",
                        s.channels.iter().map(|c| c.name()).collect::<Vec<_>>(),
                        s.volts.len(),
                        channels.iter().map(|c| c.name()).collect::<Vec<_>>()
                    ),
                });
            }
            let expected = start + i as f64 * period;
            let deviation = (s.scan_start_s - expected).abs();
            if deviation.is_nan() || deviation > 1.0e-3 * period {
                return Err(IdentificationError::BadInput {
                    what: format!("scans[{i}].scan_start_s (scan_index {})", s.scan_index),
                    reason: format!(
                        "{} s, expected {expected} s at {sample_rate_hz} scans/s: missing, repeated or out-of-order scan",
                        s.scan_start_s
                    ),
                });
            }
            for (col, &v) in columns.iter_mut().zip(&s.volts) {
                col.push(v);
            }
        }
        Ok(Self {
            sample_rate_hz,
            start_time_s: start,
            channels,
            units: RawUnits::Volts,
            columns,
        })
    }

    /// Samples per column (of the first column; [`RawRecord::validate_shape`] checks the rest).
    pub fn len(&self) -> usize {
        self.columns.first().map_or(0, Vec::len)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The column of `channel`, if present.
    pub fn column(&self, channel: ChannelId) -> Option<&[f64]> {
        self.channels
            .iter()
            .position(|&c| c == channel)
            .and_then(|k| self.columns.get(k))
            .map(Vec::as_slice)
    }

    /// Checks the shape: finite positive sample rate, finite start time, one column per
    /// channel, no channel twice, all columns the same non-zero length.
    pub fn validate_shape(&self) -> Result<(), IdentificationError> {
        if !(self.sample_rate_hz.is_finite() && self.sample_rate_hz > 0.0) {
            return Err(IdentificationError::invalid(
                "sample_rate_hz",
                format!("must be finite and > 0, got {}", self.sample_rate_hz),
            ));
        }
        if !self.start_time_s.is_finite() {
            return Err(IdentificationError::BadInput {
                what: "start_time_s".into(),
                reason: format!("not finite ({})", self.start_time_s),
            });
        }
        if self.channels.len() != self.columns.len() {
            return Err(IdentificationError::BadInput {
                what: "columns".into(),
                reason: format!(
                    "{} columns for {} channels",
                    self.columns.len(),
                    self.channels.len()
                ),
            });
        }
        let mut seen = [false; CHANNEL_COUNT];
        for &c in &self.channels {
            if std::mem::replace(&mut seen[c.index()], true) {
                return Err(IdentificationError::BadInput {
                    what: format!("channel `{c}`"),
                    reason: "appears twice in the record".into(),
                });
            }
        }
        let n = self.len();
        if n == 0 {
            return Err(IdentificationError::BadInput {
                what: "columns".into(),
                reason: "the record has no samples".into(),
            });
        }
        for (c, col) in self.channels.iter().zip(&self.columns) {
            if col.len() != n {
                return Err(IdentificationError::BadInput {
                    what: format!("column `{c}`"),
                    reason: format!(
                        "{} samples, but `{}` has {n}: ragged columns",
                        col.len(),
                        self.channels[0]
                    ),
                });
            }
        }
        Ok(())
    }
}

/// Why a record was rejected by the linear-range check (paper step 2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RangeViolation {
    pub channel: ChannelId,
    /// First offending sample.
    pub index: usize,
    /// Its value in the channel's SI unit.
    pub value_si: f64,
    /// The calibrated linear range in SI, `[low, high]` (readings within half an LSB of an
    /// edge count as outside, see `Calibration::within_linear_range`).
    pub range_si: [f64; 2],
    /// How many samples of the channel are out of range.
    pub count: usize,
}

impl std::fmt::Display for RangeViolation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let u = self.channel.unit();
        write!(
            f,
            "`{}` left its linear range [{}, {}] {u} at sample {} (value {} {u}); {} sample(s) out of range",
            self.channel, self.range_si[0], self.range_si[1], self.index, self.value_si, self.count
        )
    }
}

/// A conditioned record on ONE time base (the scan start times), all SI.
/// `Conditioned::default()` is empty; [`condition_into`] reuses its buffers.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Conditioned {
    /// Scan start times (s).
    pub t_s: Vec<f64>,
    /// Relative displacement `r` (journal minus bearing centre): mean of bearing ends A, B.
    pub x_m: Vec<f64>,
    pub y_m: Vec<f64>,
    /// End A minus end B (misalignment / tilt indicator).
    pub tilt_x_m: Vec<f64>,
    pub tilt_y_m: Vec<f64>,
    /// `r'`, `r''`.
    pub vx_m_s: Vec<f64>,
    pub vy_m_s: Vec<f64>,
    pub ax_m_s2: Vec<f64>,
    pub ay_m_s2: Vec<f64>,
    /// Housing absolute displacement `X` and acceleration `X''`.
    pub housing_x_m: Vec<f64>,
    pub housing_y_m: Vec<f64>,
    pub housing_ax_m_s2: Vec<f64>,
    pub housing_ay_m_s2: Vec<f64>,
    /// Film force on the journal, eq. 2 (total: static + dynamic).
    pub fx_n: Vec<f64>,
    pub fy_n: Vec<f64>,
    /// Mean of `fx`, `fy` over `valid`.
    pub static_force_n: [f64; 2],
    pub temperature_c: Vec<f64>,
    /// The bellows' load sensor `f3` (N).
    pub static_load_n: Vec<f64>,
    /// Samples free of the stages' edge effects; use only these.
    pub valid: Range<usize>,
    /// Empty when every channel stayed in its linear range.
    pub range_violations: Vec<RangeViolation>,
    /// What [`condition_into`] keeps for the next call besides the buffers.
    work: Work,
}

/// [`condition_into`]'s memory between calls that is not part of the result: the
/// differentiator last designed (its weights depend only on `M` and the sample rate) and
/// buffers. Any two compare equal, and it prints as nothing, so a `Conditioned` compares and
/// prints as its data.
#[derive(Clone, Default)]
struct Work {
    differentiator: Option<differentiate::SavitzkyGolayDerivative>,
    /// The housing's y velocity (not an output) when the derivatives follow the low-pass.
    velocity: Vec<f64>,
    /// The low-pass's scratch: its reflections and its forward pass's output (eight values
    /// per scan, `lowpass::Butterworth::filtfilt8_fed`). Kept between [`condition_into`]
    /// calls, not returned by [`condition`].
    scratch: Vec<f64>,
}

impl PartialEq for Work {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for Work {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("..")
    }
}

impl Conditioned {
    /// Samples per column.
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// `Err(BadInput)` describing every violation if any channel left its linear range: the
    /// paper's step 2 says such a record is invalid as a whole.
    pub fn require_in_range(&self) -> Result<(), IdentificationError> {
        if self.range_violations.is_empty() {
            return Ok(());
        }
        Err(IdentificationError::BadInput {
            what: format!(
                "record ({} channel(s) out of linear range: {})",
                self.range_violations.len(),
                self.range_violations
                    .iter()
                    .map(|v| v.channel.name())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            reason: self
                .range_violations
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join("; "),
        })
    }

    /// The dynamic film force (`F` minus its static part) at sample `i`.
    pub fn dynamic_force_n(&self, i: usize) -> Option<[f64; 2]> {
        Some([
            self.fx_n.get(i)? - self.static_force_n[0],
            self.fy_n.get(i)? - self.static_force_n[1],
        ])
    }
}

/// Whether every value of `x` is finite, branch-free: `v - v` is 0 for a finite `v` and NaN
/// for an infinite or NaN one, and a NaN stays in a sum. Two adds per vector of values; the
/// compare-and-mask form (`ok & v.is_finite()`) took five instructions, packing each mask to
/// a byte, and was a few percent of the conditioning. Sixteen partial sums (four AVX2
/// vectors), so that the adds' latency is hidden.
#[inline(always)]
#[allow(clippy::eq_op)] // `v - v` is the point: 0 or NaN, never folded for floats.
pub(crate) fn all_finite(x: &[f64]) -> bool {
    let (chunks, rest) = x.as_chunks::<16>();
    let mut acc = [0.0f64; 16];
    for c in chunks {
        for l in 0..16 {
            acc[l] += c[l] - c[l];
        }
    }
    let mut sum = acc.iter().sum::<f64>();
    for v in rest {
        sum += v - v;
    }
    sum == 0.0
}

/// The refusal of a record of `n` scans that has no valid scan once the filters' `edge` is
/// trimmed at each end (`n <= 2 edge`).
pub(super) fn too_short(n: usize, edge: usize) -> IdentificationError {
    IdentificationError::BadInput {
        what: "record length".into(),
        reason: format!("{n} scans; the filters' edge effects need {edge} at each end, so at least {} scans", 2 * edge + 1),
    }
}

/// Index of the first non-finite value, by a branch-free scan ([`all_finite`]) and, only
/// when one exists, a second search for its position.
pub(crate) fn first_non_finite(x: &[f64]) -> Option<usize> {
    if all_finite(x) {
        None
    } else {
        x.iter().position(|v| !v.is_finite())
    }
}

/// The `BadInput` for a non-finite sample.
pub(crate) fn non_finite_error(
    channel: ChannelId,
    index: usize,
    value: f64,
    unit: &str,
) -> IdentificationError {
    IdentificationError::BadInput {
        what: format!("channel `{channel}`, sample {index}"),
        reason: format!("{value} is not a finite reading ({unit})"),
    }
}

/// Scans per tile of [`front_end`] (ten channels of 256 samples: 20 kB, L1-resident).
const TILE: usize = 256;

/// One channel's constants for [`front_end`].
struct FrontChannel<'a> {
    volts: &'a [f64],
    offset: f64,
    gain: f64,
    /// Readings `v` with `v > lo && v < hi` are in the linear range.
    lo: f64,
    hi: f64,
    /// Every reading in the linear range converts to a finite value: the conversion
    /// `(v - offset) gain` is monotone in `v` (rounding is), so its values there lie between
    /// those at `lo` and `hi`, and those are finite. The per-reading check of the converted
    /// value is then skipped (it cannot fail).
    si_bounded: bool,
    delay: &'a deskew::FractionalDelay,
    interior: Range<usize>,
}

/// [`FrontChannel::si_bounded`]: both ends of the linear range `(lo, hi)` convert to finite
/// values, so every reading between them does.
fn conversion_bounded(offset: f64, gain: f64, lo: f64, hi: f64) -> bool {
    ((lo - offset) * gain).is_finite() && ((hi - offset) * gain).is_finite()
}

/// Steps 3, 2, 4, the linear combinations of steps 5 and 7 and step 1 (the low-pass) for a
/// record of volts, scan tile by scan tile: each channel is calibrated into L1 and de-skewed
/// from there, its readings counted against the linear range and for finiteness on the way,
/// the tile's ten channels are combined into `out` = `[x, y, tilt_x, tilt_y, frame_x,
/// frame_y, fx (applied), fy (applied), f3, temperature]`, and the eight columns with
/// dynamics go through the low-pass's forward pass while the tile is still in L1
/// ([`lowpass::Butterworth::filtfilt8_fed`]), then backward. The same operations in the same
/// order as [`calibrate::to_si_into`], [`deskew::FractionalDelay::apply_into`],
/// [`kinematics::mean_and_difference_in_place`], the applied part of eq. 2 and
/// [`lowpass::Butterworth::filtfilt_many_in_place`], so the same result bit for bit, with the
/// raw columns read once and each output written once per filter direction instead of some
/// twenty passes over memory.
///
/// Returns `Ok(None)` (and `out` is to be discarded) when a reading is non-finite, does not
/// convert to a finite value or is out of range, or a calibration or stencil is unusable:
/// the caller then runs the stages one by one, which report the cause exactly. Otherwise
/// `Ok(Some(finite))`: whether every low-pass output is finite.
#[allow(clippy::too_many_arguments)]
fn front_end(
    raw: &RawRecord,
    window: Range<usize>,
    col_of: &[usize; CHANNEL_COUNT],
    calibration: &Calibration,
    delays: &[Option<deskew::FractionalDelay>],
    mechanics: &Mechanics,
    lp: &lowpass::Butterworth,
    out: &mut [Vec<f64>; CHANNEL_COUNT],
    scratch: &mut Vec<f64>,
    derivatives: &mut Derivatives<'_>,
) -> Result<Option<bool>, IdentificationError> {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the only requirement of a `target_feature` function is that the CPU has
            // the feature, which was checked on the line above.
            return unsafe { front_end_avx512(raw, window, col_of, calibration, delays, mechanics, lp, out, scratch, derivatives) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: as above.
            return unsafe { front_end_avx2(raw, window, col_of, calibration, delays, mechanics, lp, out, scratch, derivatives) };
        }
    }
    front_end_body(raw, window, col_of, calibration, delays, mechanics, lp, out, scratch, derivatives)
}

/// [`front_end`] compiled for AVX2: the same operations in the same order (no fused
/// multiply-add), so the same result bit for bit.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
fn front_end_avx2(
    raw: &RawRecord,
    window: Range<usize>,
    col_of: &[usize; CHANNEL_COUNT],
    calibration: &Calibration,
    delays: &[Option<deskew::FractionalDelay>],
    mechanics: &Mechanics,
    lp: &lowpass::Butterworth,
    out: &mut [Vec<f64>; CHANNEL_COUNT],
    scratch: &mut Vec<f64>,
    derivatives: &mut Derivatives<'_>,
) -> Result<Option<bool>, IdentificationError> {
    front_end_body(raw, window, col_of, calibration, delays, mechanics, lp, out, scratch, derivatives)
}

/// [`front_end`] compiled for AVX-512: the low-pass's eight lanes in one register each,
/// with room for the two sections' state (see `lowpass::Butterworth::filtfilt_lanes_avx512`).
/// The same operations in the same order, so the same result bit for bit.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
fn front_end_avx512(
    raw: &RawRecord,
    window: Range<usize>,
    col_of: &[usize; CHANNEL_COUNT],
    calibration: &Calibration,
    delays: &[Option<deskew::FractionalDelay>],
    mechanics: &Mechanics,
    lp: &lowpass::Butterworth,
    out: &mut [Vec<f64>; CHANNEL_COUNT],
    scratch: &mut Vec<f64>,
    derivatives: &mut Derivatives<'_>,
) -> Result<Option<bool>, IdentificationError> {
    front_end_body(raw, window, col_of, calibration, delays, mechanics, lp, out, scratch, derivatives)
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn front_end_body(
    raw: &RawRecord,
    window: Range<usize>,
    col_of: &[usize; CHANNEL_COUNT],
    calibration: &Calibration,
    delays: &[Option<deskew::FractionalDelay>],
    mechanics: &Mechanics,
    lp: &lowpass::Butterworth,
    out: &mut [Vec<f64>; CHANNEL_COUNT],
    scratch: &mut Vec<f64>,
    derivatives: &mut Derivatives<'_>,
) -> Result<Option<bool>, IdentificationError> {
    let len = window.len();
    if raw.units != RawUnits::Volts || len < 2 || out.iter().any(|c| c.len() != len) {
        return Ok(None);
    }
    let mut chans = Vec::with_capacity(CHANNEL_COUNT);
    for (&ch, delay) in ChannelId::ALL.iter().zip(delays) {
        let (Some(delay), Some(volts)) = (delay, raw.columns.get(col_of[ch.index()]).and_then(|c| c.get(window.clone()))) else {
            return Ok(None);
        };
        let c = calibration.channel(ch)?;
        let (offset, sensitivity) = (c.offset_v, c.sensitivity_v_per_unit);
        if volts.len() != len
            || len < delay.taps()
            || !(sensitivity.is_finite() && sensitivity != 0.0 && offset.is_finite())
        {
            return Ok(None);
        }
        let (lo, hi) = range_check::volts_bounds(ch, calibration)?;
        let gain = 1.0 / sensitivity;
        chans.push(FrontChannel {
            volts,
            offset,
            gain,
            lo,
            hi,
            si_bounded: conversion_bounded(offset, gain, lo, hi),
            delay,
            interior: delay.interior(len),
        });
    }
    let [x, y, tilt_x, tilt_y, hx, hy, fx, fy, load, temp] = out;
    let dynamic = [&mut x[..], &mut y[..], &mut tilt_x[..], &mut tilt_y[..], &mut hx[..], &mut hy[..], &mut fx[..], &mut fy[..]];
    let mut producer = FrontTiles {
        chans: &chans,
        applied: film_force::Applied::new(mechanics),
        len,
        tile: [[0.0; TILE]; CHANNEL_COUNT],
        input: [0.0; TILE + deskew::MAX_TAPS],
        load,
        temp,
        bad: 0,
    };
    let finite = lp.filtfilt8_fed(dynamic, scratch, TILE, &mut producer, derivatives)?;
    Ok((producer.bad == 0).then_some(finite))
}

/// [`front_end`]'s work before the low-pass, tile by tile as the low-pass asks for samples.
struct FrontTiles<'a, 'b> {
    chans: &'b [FrontChannel<'a>],
    applied: film_force::Applied,
    len: usize,
    tile: [[f64; TILE]; CHANNEL_COUNT],
    input: [f64; TILE + deskew::MAX_TAPS],
    load: &'b mut [f64],
    temp: &'b mut [f64],
    /// Readings out of range or not finite so far.
    bad: usize,
}

impl lowpass::Produce8 for FrontTiles<'_, '_> {
    type Error = IdentificationError;

    #[inline(always)]
    fn produce(&mut self, from: usize, to: usize, cols: &mut [&mut [f64]; 8]) -> Result<(), IdentificationError> {
        let mut o0 = from;
        while o0 < to {
            let o1 = (o0 + TILE).min(to);
            self.bad += front_tile(self.chans, &self.applied, self.len, from, o0, o1, &mut self.tile, &mut self.input, cols, self.load, self.temp);
            o0 = o1;
        }
        Ok(())
    }
}

/// What the front end's low-pass hands its final output to ([`lowpass::Consume8`]), range
/// by range as the backward pass writes it, while it is in cache: the first and second
/// derivatives of `x`, `y` (r', r'') and of the housing's `X`, `Y` (velocity, `X''`), and
/// eq. 2's inertial part `F -= m X''` on the film force. The same operations on the same
/// values as the stages after the low-pass ([`differentiate::SavitzkyGolayDerivative::
/// apply_twice_each`] and the inertial loop of [`condition_into`]), only in another order of
/// samples, so the same result bit for bit; the columns are not read back from memory.
struct Derivatives<'a> {
    sg: &'a differentiate::SavitzkyGolayDerivative,
    mass_kg: f64,
    /// `[first, second]` derivative of x, y, X, Y.
    out: [[&'a mut [f64]; 2]; 4],
    state: [differentiate::TwiceDescending; 4],
    /// r'' (x, y) and the forces all finite so far.
    finite: [bool; 3],
    /// The last call had `from == 0`: every output is written.
    complete: bool,
    /// A column had the wrong length: the caller computes the derivatives itself.
    refused: bool,
}

impl<'a> Derivatives<'a> {
    fn new(sg: &'a differentiate::SavitzkyGolayDerivative, mass_kg: f64, out: [[&'a mut [f64]; 2]; 4]) -> Self {
        Self { sg, mass_kg, out, state: Default::default(), finite: [true; 3], complete: false, refused: false }
    }
}

impl lowpass::Consume8 for Derivatives<'_> {
    type Error = IdentificationError;

    #[inline(always)]
    fn consume(&mut self, from: usize, cols: &mut [&mut [f64]; 8]) -> Result<(), IdentificationError> {
        let [x, y, _, _, hx, hy, fx, fy] = cols;
        let [[vx, ax], [vy, ay], [hvx, hax], [hvy, hay]] = &mut self.out;
        let [sx, sy, shx, shy] = &mut self.state;
        let sg = self.sg;
        let m = self.mass_kg;
        let mut force_finite = true;
        let results = [
            sg.twice_descending(sx, from, x, vx, ax),
            sg.twice_descending(sy, from, y, vy, ay),
            sg.twice_descending(shx, from, hx, hvx, hax),
            sg.twice_descending(shy, from, hy, hvy, hay),
        ];
        // Eq. 2's inertial part on the housing accelerations made final just now.
        for (result, force, acc) in [(&results[2], &mut **fx, &**hax), (&results[3], &mut **fy, &**hay)] {
            if let Some((_, made)) = result {
                force_finite &= subtract_inertia(&mut force[made.clone()], &acc[made.clone()], m);
            }
        }
        self.refused |= results.iter().any(Option::is_none);
        self.finite[0] &= results[0].as_ref().is_some_and(|r| r.0);
        self.finite[1] &= results[1].as_ref().is_some_and(|r| r.0);
        self.finite[2] &= force_finite;
        self.complete = from == 0;
        Ok(())
    }
}

/// Eq. 2's static part ([`film_force::static_part`], whose checks `valid` has passed) and
/// the scans' times, `t[i] = t0 + i / fs`, in one pass. The static part's two sums are
/// chains of dependent adds in index order, bound by an add's latency per sample; the
/// times' divisions, four at a time, run beside them in the pipes the chains leave idle
/// (apart, they were a pass of their own, 2-3 % of the conditioning). The same operations
/// in the same order as `static_part` and a plain loop over the times, so the same bits
/// (`static_part_and_times_equals_the_two_loops`).
fn static_part_and_times(fx: &[f64], fy: &[f64], valid: Range<usize>, t0: f64, fs: f64, t: &mut [f64]) -> [f64; 2] {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the only requirement of a `target_feature` function is that the CPU has
            // the feature, which was checked on the line above.
            return unsafe { static_part_and_times_avx2(fx, fy, valid, t0, fs, t) };
        }
    }
    static_part_and_times_body(fx, fy, valid, t0, fs, t)
}

/// [`static_part_and_times`] compiled for AVX2 (four divisions per instruction; no fused
/// multiply-add, so the same bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn static_part_and_times_avx2(fx: &[f64], fy: &[f64], valid: Range<usize>, t0: f64, fs: f64, t: &mut [f64]) -> [f64; 2] {
    static_part_and_times_body(fx, fy, valid, t0, fs, t)
}

#[inline(always)]
fn static_part_and_times_body(fx: &[f64], fy: &[f64], valid: Range<usize>, t0: f64, fs: f64, t: &mut [f64]) -> [f64; 2] {
    #[inline(always)]
    fn times(t: &mut [f64], from: usize, t0: f64, fs: f64) {
        for (i, t) in t.iter_mut().enumerate() {
            *t = t0 + (from + i) as f64 / fs;
        }
    }
    // `valid` lies inside the columns (checked by the caller); clamped anyway, so that a
    // wrong range cannot index out of them.
    let b = valid.end.min(t.len()).min(fx.len()).min(fy.len());
    let a = valid.start.min(b);
    let (fx, fy) = (&fx[a..b], &fy[a..b]);
    let (before, rest) = t.split_at_mut(a);
    let (inside, after) = rest.split_at_mut(b - a);
    times(before, 0, t0, fs);
    // From -0.0, as `Iterator::sum` (and `static_part`).
    let (mut sx, mut sy) = (-0.0, -0.0);
    let (tc, tr) = inside.as_chunks_mut::<4>();
    let (xc, xr) = fx.as_chunks::<4>();
    let (yc, yr) = fy.as_chunks::<4>();
    for (q, ((tq, xq), yq)) in tc.iter_mut().zip(xc).zip(yc).enumerate() {
        let i = a + 4 * q;
        *tq = std::array::from_fn(|l| t0 + (i + l) as f64 / fs);
        for l in 0..4 {
            sx += xq[l];
            sy += yq[l];
        }
    }
    times(tr, a + 4 * tc.len(), t0, fs);
    for (&x, &y) in xr.iter().zip(yr) {
        sx += x;
        sy += y;
    }
    times(after, b, t0, fs);
    let k = (b - a) as f64;
    [sx / k, sy / k]
}

/// Eq. 2's inertial part on a block, `f -= m a`; whether every result is finite.
#[inline(always)]
fn subtract_inertia(force: &mut [f64], acc: &[f64], mass_kg: f64) -> bool {
    // Locals, not captured state: written through a reference on every sample they kept
    // this loop scalar (a store and a reload per sample).
    let (m, mut finite) = (mass_kg, true);
    for (f, &a) in force.iter_mut().zip(acc) {
        *f -= m * a;
        finite &= f.is_finite();
    }
    finite
}

/// The de-skew stencil over a tile: `dst[i] = w[0] x[i] + w[1] x[i + 1] + ...`, summed in
/// that order (as [`deskew::FractionalDelay::apply_into`]), with `T` taps known at compile
/// time so each output is summed in registers and stored once (a pass per tap loaded and
/// stored every output `T` times: the front end was bound by those L1 accesses).
#[inline(always)]
fn stencil<const T: usize>(w: &[f64], x: &[f64], dst: &mut [f64]) {
    let Ok(w) = <&[f64; T]>::try_from(w) else {
        return stencil_passes(w, x, dst);
    };
    for (o, xs) in dst.iter_mut().zip(x.windows(T)) {
        let mut acc = w[0] * xs[0];
        for j in 1..T {
            acc += w[j] * xs[j];
        }
        *o = acc;
    }
}

/// [`stencil`] for any number of taps: a pass over the tile per tap, the same sums.
#[inline(always)]
fn stencil_passes(w: &[f64], x: &[f64], dst: &mut [f64]) {
    let m = dst.len();
    for (o, &x) in dst.iter_mut().zip(&x[..m]) {
        *o = w[0] * x;
    }
    for (j, &wj) in w.iter().enumerate().skip(1) {
        for (o, &x) in dst.iter_mut().zip(&x[j..j + m]) {
            *o += wj * x;
        }
    }
}

/// Asks the CPU to bring `x[range]` (clamped to `x`) into its caches ahead of use: a hint
/// that changes no value.
#[inline(always)]
fn prefetch(x: &[f64], range: Range<usize>) {
    let end = range.end.min(x.len());
    let r = &x[range.start.min(end)..end];
    #[cfg(target_arch = "x86_64")]
    for line in r.chunks(8) {
        // SAFETY: SSE is part of every x86_64 CPU; a prefetch of an address inside `x` never
        // faults and reads nothing into Rust.
        unsafe { std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(line.as_ptr().cast()) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = r;
}

/// One tile `o0..o1` (at most [`TILE`] scans) of [`front_end`] before the low-pass: how many
/// readings it found out of range or not finite, zero exactly when every reading of the tile
/// is usable (a reading just past the tile, which its stencil reads, may be counted too: it
/// is in the record, and its own tile counts it again; the callers only ask for zero).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn front_tile(
    chans: &[FrontChannel<'_>],
    applied: &film_force::Applied,
    len: usize,
    base: usize,
    o0: usize,
    o1: usize,
    tile: &mut [[f64; TILE]; CHANNEL_COUNT],
    input: &mut [f64; TILE + deskew::MAX_TAPS],
    dynamic: &mut [&mut [f64]; 8],
    load: &mut [f64],
    temp: &mut [f64],
) -> usize {
    let mut bad = 0;
    for (k, (c, t)) in chans.iter().zip(tile.iter_mut()).enumerate() {
        prefetch(c.volts, o1..o1 + (o1 - o0));
        // The frame probes, the bellows' load and the temperature are not combined with
        // other channels: de-skewed straight into their columns, not via the tile and a copy.
        let t: &mut [f64] = match k {
            4 => &mut dynamic[4][o0 - base..o1 - base],
            5 => &mut dynamic[5][o0 - base..o1 - base],
            8 => &mut load[o0..o1],
            9 => &mut temp[o0..o1],
            _ => &mut t[..o1 - o0],
        };
        let (offset, gain, lo, hi) = (c.offset, c.gain, c.lo, c.hi);
        let si = |v: f64| (v - offset) * gain;
        // Outputs a..b use the interior stencil, on readings i0..i1 (inside the record:
        // a >= interior.start and b <= interior.end).
        let a = o0.max(c.interior.start).min(o1);
        let b = o1.min(c.interior.end).max(a);
        let (w, taps) = (c.delay.weights(), c.delay.taps());
        let i0 = (a as isize + c.delay.stencil_start()).max(0) as usize;
        let i1 = i0 + (b - a) + taps - 1;
        // Where the stencil's readings cover the tile's (every tile but those at the record's
        // ends), the range check runs in the loop that converts them: one pass over the
        // readings instead of two. Else (or where a converted value could overflow) the
        // tile's readings are checked on their own. `&` and `|`, not `&&`: no branch per
        // reading, so the count vectorises. Plain loops: the iterator's `sum` became a call
        // of its own (`fold`) compiled without the caller's AVX2 once the low-pass was fed
        // from here.
        let check_while_converting = c.si_bounded && a == o0 && b == o1 && i0 <= o0 && i1 >= o1;
        if !check_while_converting {
            if c.si_bounded {
                for &v in &c.volts[o0..o1] {
                    bad += !((v > lo) & (v < hi)) as usize;
                }
            } else {
                for &v in &c.volts[o0..o1] {
                    bad += (!((v > lo) & (v < hi)) | !si(v).is_finite()) as usize;
                }
            }
        }
        if a < b {
            let x = &mut input[..i1 - i0];
            if check_while_converting {
                for (x, &v) in x.iter_mut().zip(&c.volts[i0..i1]) {
                    *x = si(v);
                    bad += !((v > lo) & (v < hi)) as usize;
                }
            } else {
                for (x, &v) in x.iter_mut().zip(&c.volts[i0..i1]) {
                    *x = si(v);
                }
            }
            let dst = &mut t[a - o0..b - o0];
            match taps {
                2 => stencil::<2>(w, x, dst),
                3 => stencil::<3>(w, x, dst),
                4 => stencil::<4>(w, x, dst),
                5 => stencil::<5>(w, x, dst),
                6 => stencil::<6>(w, x, dst),
                8 => stencil::<8>(w, x, dst),
                _ => stencil_passes(w, x, dst),
            }
        }
        for n in (o0..a).chain(b..o1) {
            t[n - o0] = c.delay.edge_value(n, len, |i| si(c.volts[i]));
        }
    }
    let [a_x, a_y, b_x, b_y, _, _, f1, f2, _, _] = &*tile;
    let [x, y, tilt_x, tilt_y, _, _, fx, fy] = dynamic;
    let f3 = &load[o0..o1];
    for (i, n) in (o0 - base..o1 - base).enumerate() {
        [x[n], tilt_x[n]] = kinematics::mean_and_difference(a_x[i], b_x[i]);
        [y[n], tilt_y[n]] = kinematics::mean_and_difference(a_y[i], b_y[i]);
        [fx[n], fy[n]] = applied.at(f1[i], f2[i], f3[i]);
    }
    // The temperature is final here (it is not filtered): check it while it is in L1.
    for v in &temp[o0..o1] {
        bad += !v.is_finite() as usize;
    }
    bad
}

/// Runs steps 1-7 on a raw record: calibrate, range-check, deskew, low-pass, kinematics,
/// differentiate twice, eq. 2. The record must hold all ten channels.
pub fn condition(
    raw: &RawRecord,
    calibration: &Calibration,
    mechanics: &Mechanics,
    config: &ConditioningConfig,
) -> Result<Conditioned, IdentificationError> {
    let mut out = Conditioned::default();
    condition_into(raw, calibration, mechanics, config, &mut out)?;
    // The result is kept by the caller; the low-pass's scratch (as large as eight of its
    // columns) is not part of it.
    out.work.scratch = Vec::new();
    Ok(out)
}

/// Number of column buffers of a [`Conditioned`].
const COLUMNS: usize = 17;

impl Conditioned {
    /// Moves the column buffers out (leaving empty columns), for reuse.
    fn take_columns(&mut self) -> [Vec<f64>; COLUMNS] {
        use std::mem::take;
        [
            take(&mut self.t_s),
            take(&mut self.x_m),
            take(&mut self.y_m),
            take(&mut self.tilt_x_m),
            take(&mut self.tilt_y_m),
            take(&mut self.vx_m_s),
            take(&mut self.vy_m_s),
            take(&mut self.ax_m_s2),
            take(&mut self.ay_m_s2),
            take(&mut self.housing_x_m),
            take(&mut self.housing_y_m),
            take(&mut self.housing_ax_m_s2),
            take(&mut self.housing_ay_m_s2),
            take(&mut self.fx_n),
            take(&mut self.fy_n),
            take(&mut self.temperature_c),
            take(&mut self.static_load_n),
        ]
    }
}

/// [`condition`] into `out`, reusing its column buffers: conditioning record after record
/// into the same `Conditioned` allocates nothing once the buffers are large enough (the
/// 17 output columns are the only working memory besides a few kilobytes). On error `out`
/// is left empty.
pub fn condition_into(
    raw: &RawRecord,
    calibration: &Calibration,
    mechanics: &Mechanics,
    config: &ConditioningConfig,
    out: &mut Conditioned,
) -> Result<(), IdentificationError> {
    condition_window_into(raw, 0..raw.len(), calibration, mechanics, config, out)
}

/// [`condition_into`] on the scans `window` of `raw`: the result (indices, `valid`, range
/// violations, bits) is the one [`condition_into`] gives for a record holding only those
/// scans and starting `window.start` scans later, without copying them into one. A
/// streaming conditioner keeps the scans it has in one record and conditions a window of it
/// per block. A window that does not fit in the record is a `BadInput`.
pub fn condition_window_into(
    raw: &RawRecord,
    window: Range<usize>,
    calibration: &Calibration,
    mechanics: &Mechanics,
    config: &ConditioningConfig,
    out: &mut Conditioned,
) -> Result<(), IdentificationError> {
    let mut pool = out.take_columns();
    let mut work = std::mem::take(&mut out.work);
    let mut violations = std::mem::take(&mut out.range_violations);
    violations.clear();
    *out = Conditioned::default();
    let mut used = 0;
    let n = window.len();
    // A buffer of `n` samples from the pool; its contents are overwritten by every stage.
    let mut next = || -> Vec<f64> {
        let v = pool.get_mut(used).map(std::mem::take).unwrap_or_default();
        used += 1;
        if v.capacity() < n {
            // Fresh zeroed memory straight from the allocator (no separate fill pass).
            vec![0.0; n]
        } else {
            let mut v = v;
            v.truncate(n);
            v.resize(n, 0.0);
            v
        }
    };

    raw.validate_shape()?;
    if window.end > raw.len() || window.start > window.end {
        return Err(IdentificationError::BadInput {
            what: "window".into(),
            reason: format!("scans {window:?} of a record of {} scans", raw.len()),
        });
    }
    let (lp, sg) = config.designs(raw.sample_rate_hz, work.differentiator.take())?;
    mechanics.validate()?;
    let fs = raw.sample_rate_hz;

    let mut col_of = [usize::MAX; CHANNEL_COUNT];
    for (k, &c) in raw.channels.iter().enumerate() {
        col_of[c.index()] = k;
    }
    if let Some(missing) = ChannelId::ALL
        .iter()
        .find(|c| col_of[c.index()] == usize::MAX)
    {
        return Err(IdentificationError::BadInput {
            what: format!("channel `{missing}`"),
            reason: "missing from the record; conditioning needs all ten channels".into(),
        });
    }

    let mut delays = Vec::with_capacity(CHANNEL_COUNT);
    let mut deskew_trim = 0;
    for &ch in &ChannelId::ALL {
        let offset = calibration.sample_offset_s(ch)?;
        if config.deskew {
            let d = deskew::FractionalDelay::for_offset(offset, fs, config.deskew_taps)?;
            deskew_trim = deskew_trim.max(d.edge_samples());
            delays.push(Some(d));
        } else {
            delays.push(None);
        }
    }
    let trim = deskew_trim + lp.settling_samples() + 2 * sg.half_length();
    if n <= 2 * trim {
        return Err(too_short(n, trim));
    }
    let valid = trim..n - trim;

    // Per channel: SI, range check on the raw column, deskew; then the low-pass on the eight
    // columns with dynamics together (eight lanes, see `lowpass::Butterworth::filtfilt_many_in_place`),
    // its forward pass fed tile by tile by the front end. `tmp` ends up as the velocity `vx`.
    let mut tmp = next();
    let mut front: [Vec<f64>; CHANNEL_COUNT] = std::array::from_fn(|_| next());
    let mut housing_ax_m_s2 = next();
    let mut housing_ay_m_s2 = next();
    let mut ax_m_s2 = next();
    let mut vy_m_s = next();
    let mut ay_m_s2 = next();
    // The times are written last: until then the buffer holds the housing's x velocity.
    let mut t_s = next();
    let mut housing_vy = std::mem::take(&mut work.velocity);
    if housing_vy.len() != n {
        housing_vy.clear();
        housing_vy.resize(n, 0.0);
    }
    let mass = mechanics.housing_mass_kg;
    // The low-pass is linear and time-invariant, so it commutes with the linear combinations
    // the later steps form: take the mean and difference of the bearing ends and the applied
    // part of eq. 2 first, then filter the eight columns that carry dynamics (one lock-step
    // pass of eight lanes, not ten raw channels). The bellows' load and the temperature keep
    // their de-skewed samples: only their means are used.
    let mut scratch = std::mem::take(&mut work.scratch);
    let mut derivatives = Derivatives::new(
        &sg,
        mass,
        [
            [&mut tmp, &mut ax_m_s2],
            [&mut vy_m_s, &mut ay_m_s2],
            [&mut t_s, &mut housing_ax_m_s2],
            [&mut housing_vy, &mut housing_ay_m_s2],
        ],
    );
    let fused = front_end(raw, window.clone(), &col_of, calibration, &delays, mechanics, &lp, &mut front, &mut scratch, &mut derivatives)?;
    // The derivatives and eq. 2's inertial part followed the low-pass (`Some` finiteness of
    // r'' in x and y and of the forces) or are still to be computed.
    let derived = (fused.is_some() && derivatives.complete && !derivatives.refused).then_some(derivatives.finite);
    if fused.is_none() {
        // Something to report (or a record of SI values): the stages one by one.
        let mut si = front;
        for (&ch, delay) in ChannelId::ALL.iter().zip(&delays) {
            let column = &raw.columns[col_of[ch.index()]][window.clone()];
            let buf = &mut si[ch.index()];
            match raw.units {
                RawUnits::Volts => calibrate::to_si_into(ch, column, calibration, buf)?,
                RawUnits::Si => {
                    if let Some(i) = first_non_finite(column) {
                        return Err(non_finite_error(ch, i, column[i], "si"));
                    }
                    buf.copy_from_slice(column);
                }
            }
            if let Some(v) = range_check::check(ch, column, raw.units, calibration)? {
                violations.push(v);
            }
            if let Some(d) = delay {
                d.apply_into(buf, &mut tmp)?;
                std::mem::swap(buf, &mut tmp);
            }
        }
        let [mut a_x, mut a_y, mut b_x, mut b_y, frame_x, frame_y, mut f1, mut f2, f3, temperature] = si;
        kinematics::mean_and_difference_in_place(&mut a_x, &mut b_x)?;
        kinematics::mean_and_difference_in_place(&mut a_y, &mut b_y)?;
        film_force::applied_in_place(&mut f1, &mut f2, &f3, mechanics)?;
        front = [a_x, a_y, b_x, b_y, frame_x, frame_y, f1, f2, f3, temperature];
    }
    let [x_m, y_m, tilt_x_m, tilt_y_m, frame_x, frame_y, fx_n, fy_n, f3, temperature] = front;
    let mut dynamic = [x_m, y_m, tilt_x_m, tilt_y_m, frame_x, frame_y, fx_n, fy_n];
    let filtered_finite = match fused {
        Some(finite) => finite,
        None => lp.filtfilt_many_in_place_finite(&mut dynamic, &mut scratch)?,
    };
    let [x_m, y_m, tilt_x_m, tilt_y_m, frame_x, frame_y, mut fx_n, mut fy_n] = dynamic;

    // Housing acceleration: differentiate twice, as the paper does (velocity in `t_s`), and
    // eq. 2's inertial part, the film force on the journal `F -= m X''`, block by block as
    // the acceleration is formed (the same operation as `film_force::subtract_inertia_in_place`,
    // without reading the columns back); then r' and r''. Done already if they could follow
    // the low-pass (`derived`).
    let mut vx_m_s = tmp;
    let [ax_finite, ay_finite, force_finite] = match derived {
        Some(finite) => finite,
        None => {
            let mut force_finite = true;
            for (frame, acc, force) in [(&frame_x, &mut housing_ax_m_s2, &mut fx_n), (&frame_y, &mut housing_ay_m_s2, &mut fy_n)] {
                sg.apply_twice_each(frame, &mut t_s, acc, |range, a| {
                    force_finite &= subtract_inertia(&mut force[range], a, mass);
                })?;
            }
            let ax_finite = sg.apply_twice_into_finite(&x_m, &mut vx_m_s, &mut ax_m_s2)?;
            let ay_finite = sg.apply_twice_into_finite(&y_m, &mut vy_m_s, &mut ay_m_s2)?;
            [ax_finite, ay_finite, force_finite]
        }
    };
    film_force::check_static_window(&fx_n, &fy_n, &valid)?;

    // Finite inputs can still overflow in the filters (|x| near f64::MAX): never hand a
    // non-finite number on. The stages checked their final outputs as they wrote them (the
    // front end the temperature, the low-pass r and the tilt, eq. 2 the force, the
    // differentiator r''); only if one of them saw a non-finite value, or the front end did
    // not run, are the columns searched here, to name the first one.
    let known_finite = fused.is_some() && filtered_finite && force_finite && ax_finite && ay_finite;
    for (name, col) in [
        ("x_m", &x_m),
        ("y_m", &y_m),
        ("tilt_x_m", &tilt_x_m),
        ("tilt_y_m", &tilt_y_m),
        ("ax_m_s2", &ax_m_s2),
        ("ay_m_s2", &ay_m_s2),
        ("fx_n", &fx_n),
        ("fy_n", &fy_n),
        ("temperature_c", &temperature),
    ]
    .into_iter()
    .filter(|_| !known_finite)
    {
        if let Some(i) = first_non_finite(col) {
            return Err(IdentificationError::BadInput {
                what: format!("conditioned `{name}`, sample {i}"),
                reason: "not finite after conditioning: an input magnitude overflowed".into(),
            });
        }
    }

    let t0 = raw.start_time_s + window.start as f64 / fs;
    let static_force_n = static_part_and_times(&fx_n, &fy_n, valid.clone(), t0, fs, &mut t_s);
    debug_assert_eq!(used, COLUMNS);
    work.differentiator = Some(sg);
    work.velocity = housing_vy;
    work.scratch = scratch;
    *out = Conditioned {
        t_s,
        x_m,
        y_m,
        tilt_x_m,
        tilt_y_m,
        vx_m_s,
        vy_m_s,
        ax_m_s2,
        ay_m_s2,
        housing_x_m: frame_x,
        housing_y_m: frame_y,
        housing_ax_m_s2,
        housing_ay_m_s2,
        fx_n,
        fy_n,
        static_force_n,
        temperature_c: temperature,
        static_load_n: f3,
        valid,
        range_violations: violations,
        work,
    };
    Ok(())
}

/// Samples at each end of a conditioned record that the stages' edge effects spoil (the
/// de-skew interpolator's half-length, the low-pass settling to 1e-7 and twice the
/// differentiator's half-length): [`condition`] marks `edge..n - edge` valid. A streaming
/// conditioner that conditions a block with this many extra samples on each side gets the
/// whole block valid.
pub fn edge_samples(
    calibration: &Calibration,
    config: &ConditioningConfig,
    sample_rate_hz: f64,
) -> Result<usize, IdentificationError> {
    config.validate(sample_rate_hz)?;
    let lp = lowpass::Butterworth::design(config.lowpass_order, config.lowpass_cutoff_hz, sample_rate_hz)?;
    let sg = differentiate::SavitzkyGolayDerivative::new(config.differentiator_half_length, sample_rate_hz)?;
    let mut deskew_trim = 0;
    if config.deskew {
        for &ch in &ChannelId::ALL {
            let offset = calibration.sample_offset_s(ch)?;
            let d = deskew::FractionalDelay::for_offset(offset, sample_rate_hz, config.deskew_taps)?;
            deskew_trim = deskew_trim.max(d.edge_samples());
        }
    }
    Ok(deskew_trim + lp.settling_samples() + 2 * sg.half_length())
}

#[cfg(test)]
mod tests {
    use super::*;
    use oilfilm_physics::daq::DaqConfig;

    /// A volts record of smooth motion plus noise, every reading inside its probe's linear
    /// range (so the fused front end runs), from a small deterministic generator.
    pub(super) fn volts_record(n: usize, calibration: &Calibration, seed: u64) -> RawRecord {
        let mut state = seed;
        let mut uniform = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let fs = 5000.0;
        let columns = ChannelId::ALL
            .iter()
            .enumerate()
            .map(|(k, &ch)| {
                let (lo, hi) = range_check::volts_bounds(ch, calibration).unwrap();
                let (lo, hi) = (lo.max(-10.0), hi.min(10.0));
                let (mid, span) = (0.5 * (lo + hi), 0.5 * (hi - lo));
                (0..n)
                    .map(|i| {
                        let t = i as f64 / fs;
                        let phase = 2.0 * std::f64::consts::PI * (23.0 + k as f64) * t;
                        mid + span * (0.3 * phase.sin() + 0.05 * (uniform() - 0.5))
                    })
                    .collect()
            })
            .collect();
        RawRecord { sample_rate_hz: fs, start_time_s: 0.0, channels: ChannelId::ALL.to_vec(), units: RawUnits::Volts, columns }
    }

    /// The fused static part and times against `film_force::static_part` and the plain loop,
    /// bit for bit, on lengths and windows that cut its chunks of four anywhere.
    #[test]
    fn static_part_and_times_equals_the_two_loops() {
        let mut state = 7u64;
        let mut uniform = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let (t0, fs) = (12.345_678_9, 5000.0);
        let mut checked = 0;
        for n in [1, 2, 5, 8, 9, 31, 1000] {
            let fx: Vec<f64> = (0..n).map(|_| 1e3 * uniform()).collect();
            let fy: Vec<f64> = (0..n).map(|_| 8e3 + 1e2 * uniform()).collect();
            for (a, b) in [(0, n), (0, 1), (n - 1, n), (n / 3, n - n / 4), (1.min(n - 1), n)] {
                if a >= b {
                    continue;
                }
                let mut t = vec![f64::NAN; n];
                let fused = static_part_and_times(&fx, &fy, a..b, t0, fs, &mut t);
                let reference = film_force::static_part(&fx, &fy, a..b).unwrap();
                assert_eq!(fused.map(f64::to_bits), reference.map(f64::to_bits), "n {n}, {a}..{b}");
                for (i, &ti) in t.iter().enumerate() {
                    assert_eq!(ti.to_bits(), (t0 + i as f64 / fs).to_bits(), "n {n}, {a}..{b}, time {i}");
                }
                checked += 1;
            }
        }
        assert!(checked >= 30, "{checked} cases");
    }

    /// `all_finite` against the definition, on lengths that cut its chunks of sixteen, with the
    /// extremes that `v - v` must still take to 0 (the largest finite, subnormals, -0) and each
    /// kind of non-finite value at each position.
    #[test]
    fn all_finite_agrees_with_the_definition() {
        for n in [0, 1, 7, 8, 9, 15, 16, 17, 33, 40] {
            let clean: Vec<f64> = (0..n).map(|i| [f64::MAX, -f64::MAX, 5e-324, -0.0, 1.5, -2.5e-300, f64::MIN_POSITIVE][i % 7]).collect();
            assert!(all_finite(&clean), "{n} finite values");
            for at in 0..n {
                for bad in [f64::INFINITY, f64::NEG_INFINITY, f64::NAN, -f64::NAN] {
                    let mut x = clean.clone();
                    x[at] = bad;
                    assert!(!all_finite(&x), "{bad} at {at} of {n}");
                    assert_eq!(first_non_finite(&x), Some(at));
                }
            }
        }
    }

    /// A window of a record conditions exactly as a record of its scans: the fused path
    /// (windows of clean readings), the stage-by-stage path with a range violation (indexed
    /// from the window's start), the whole record, and one conditioning buffer reused across
    /// them. A window past the record's end is refused, naming it.
    #[test]
    fn a_window_conditions_as_a_record_of_its_scans() {
        let calibration = DaqConfig::zhou2004().calibration();
        let mechanics = Mechanics { housing_mass_kg: 60.0, exciter_angles_deg: [45.0, 135.0], gravity_m_s2: 9.81 };
        let config = ConditioningConfig::default();
        let mut raw = volts_record(6000, &calibration, 11);
        raw.start_time_s = 2.5;
        // Far outside the probe's range (and finite): step 2 rejects it, by the stages one by one.
        raw.columns[2][3500] = 1.0e3;
        let mut work = Conditioned::default();
        for window in [0..6000, 1000..4234, 2500..5000, 3766..6000, 1000..4234] {
            let alone = RawRecord {
                start_time_s: raw.start_time_s + window.start as f64 / raw.sample_rate_hz,
                columns: raw.columns.iter().map(|c| c[window.clone()].to_vec()).collect(),
                ..raw.clone()
            };
            let expected = condition(&alone, &calibration, &mechanics, &config).unwrap();
            condition_window_into(&raw, window.clone(), &calibration, &mechanics, &config, &mut work).unwrap();
            assert!(work == expected, "window {window:?}");
            let flagged = window.contains(&3500);
            assert_eq!(!work.range_violations.is_empty(), flagged, "window {window:?}");
            if flagged {
                assert_eq!(work.range_violations[0].index, 3500 - window.start);
            }
        }
        let e = condition_window_into(&raw, 5000..7000, &calibration, &mechanics, &config, &mut work).unwrap_err().to_string();
        assert!(e.contains("window") && e.contains("6000"), "{e}");
    }

    /// `condition_into` keeps the differentiator it designed for the next call: a call with
    /// another half-length or sample rate must not use it. Conditioning into one `Conditioned`
    /// with M = 5, then 7, then 5 at another rate, gives what fresh calls give.
    #[test]
    fn reused_differentiator_only_when_half_length_and_rate_match() {
        let calibration = DaqConfig::zhou2004().calibration();
        let mechanics = Mechanics { housing_mass_kg: 60.0, exciter_angles_deg: [45.0, 135.0], gravity_m_s2: 9.81 };
        let raw = volts_record(3000, &calibration, 7);
        let mut other_rate = raw.clone();
        other_rate.sample_rate_hz = 4000.0;
        let m5 = ConditioningConfig::default();
        let m7 = ConditioningConfig { differentiator_half_length: 7, ..ConditioningConfig::default() };
        let mut work = Conditioned::default();
        for (raw, config) in [(&raw, &m5), (&raw, &m7), (&other_rate, &m5), (&raw, &m5)] {
            condition_into(raw, &calibration, &mechanics, config, &mut work).unwrap();
            let fresh = condition(raw, &calibration, &mechanics, config).unwrap();
            assert!(work == fresh, "M {} at {} Hz", config.differentiator_half_length, raw.sample_rate_hz);
            assert_eq!(work.work.differentiator.as_ref().map(|d| (d.half_length(), d.sample_rate_hz())), Some((config.differentiator_half_length, raw.sample_rate_hz)));
        }
        // The velocity differs between M = 5 and 7, so the comparison above can fail.
        let a = condition(&raw, &calibration, &mechanics, &m5).unwrap();
        let b = condition(&raw, &calibration, &mechanics, &m7).unwrap();
        assert!(a.vx_m_s != b.vx_m_s);
    }

    /// The fused front end (calibration, range check, de-skew, the linear combinations and
    /// the low-pass's forward pass tile by tile) against the stages run one after the other
    /// on the same volts: the same bits, at record lengths that cut the tiles and the
    /// reflections differently (the shortest has fewer samples than the low-pass's reflection
    /// beyond the edges it trims).
    #[test]
    fn fused_front_end_equals_the_stages_bit_for_bit() {
        let calibration = DaqConfig::zhou2004().calibration();
        let mechanics = Mechanics { housing_mass_kg: 60.0, exciter_angles_deg: [45.0, 135.0], gravity_m_s2: 9.81 };
        for (config, n) in [
            (ConditioningConfig::default(), 1201),
            (ConditioningConfig::default(), 4099),
            (ConditioningConfig { lowpass_cutoff_hz: 55.5, ..ConditioningConfig::default() }, 3 * TILE * 7 + 5),
            (ConditioningConfig { lowpass_order: 5, ..ConditioningConfig::default() }, 2600),
        ] {
            let raw = volts_record(n, &calibration, n as u64);
            let c = condition(&raw, &calibration, &mechanics, &config).unwrap();
            assert!(c.range_violations.is_empty());

            let mut si: Vec<Vec<f64>> = Vec::new();
            for (&ch, column) in ChannelId::ALL.iter().zip(&raw.columns) {
                let mut v = vec![0.0; n];
                calibrate::to_si_into(ch, column, &calibration, &mut v).unwrap();
                let d = deskew::FractionalDelay::for_offset(calibration.sample_offset_s(ch).unwrap(), raw.sample_rate_hz, config.deskew_taps).unwrap();
                let mut out = vec![0.0; n];
                d.apply_into(&v, &mut out).unwrap();
                si.push(out);
            }
            let [mut a_x, mut a_y, mut b_x, mut b_y, frame_x, frame_y, mut f1, mut f2, f3, temperature]: [Vec<f64>; 10] = si.try_into().unwrap();
            kinematics::mean_and_difference_in_place(&mut a_x, &mut b_x).unwrap();
            kinematics::mean_and_difference_in_place(&mut a_y, &mut b_y).unwrap();
            film_force::applied_in_place(&mut f1, &mut f2, &f3, &mechanics).unwrap();
            let lp = lowpass::Butterworth::design(config.lowpass_order, config.lowpass_cutoff_hz, raw.sample_rate_hz).unwrap();
            let mut dynamic = vec![a_x, a_y, b_x, b_y, frame_x, frame_y, f1, f2];
            lp.filtfilt_many_in_place(&mut dynamic, &mut Vec::new()).unwrap();
            // The two derivatives (which follow the fused low-pass's backward pass) and eq. 2's
            // inertial term, stage by stage.
            let sg = differentiate::SavitzkyGolayDerivative::new(config.differentiator_half_length, raw.sample_rate_hz).unwrap();
            let twice = |x: &[f64]| {
                let (mut v, mut a) = (vec![0.0; n], vec![0.0; n]);
                sg.apply_twice_into(x, &mut v, &mut a).unwrap();
                (v, a)
            };
            let (vx, ax) = twice(&dynamic[0]);
            let (vy, ay) = twice(&dynamic[1]);
            let (_, hax) = twice(&dynamic[4]);
            let (_, hay) = twice(&dynamic[5]);
            let m = mechanics.housing_mass_kg;
            for (f, a) in dynamic[6].iter_mut().zip(&hax) {
                *f -= m * a;
            }
            for (f, a) in dynamic[7].iter_mut().zip(&hay) {
                *f -= m * a;
            }
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
            for (name, fused, staged) in [
                ("vx_m_s", &c.vx_m_s, &vx),
                ("ax_m_s2", &c.ax_m_s2, &ax),
                ("vy_m_s", &c.vy_m_s, &vy),
                ("ay_m_s2", &c.ay_m_s2, &ay),
                ("housing_ax_m_s2", &c.housing_ax_m_s2, &hax),
                ("housing_ay_m_s2", &c.housing_ay_m_s2, &hay),
                ("x_m", &c.x_m, &dynamic[0]),
                ("y_m", &c.y_m, &dynamic[1]),
                ("tilt_x_m", &c.tilt_x_m, &dynamic[2]),
                ("tilt_y_m", &c.tilt_y_m, &dynamic[3]),
                ("housing_x_m", &c.housing_x_m, &dynamic[4]),
                ("housing_y_m", &c.housing_y_m, &dynamic[5]),
                ("fx_n", &c.fx_n, &dynamic[6]),
                ("fy_n", &c.fy_n, &dynamic[7]),
                ("static_load_n", &c.static_load_n, &f3),
                ("temperature_c", &c.temperature_c, &temperature),
            ] {
                assert!(bits(fused) == bits(staged), "{name} differs (n = {n}, {config:?})");
            }
        }
    }
}
