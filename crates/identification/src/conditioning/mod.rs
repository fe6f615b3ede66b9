//! # Conditioning: from raw multiplexed DAQ samples to what the estimator consumes
//!
//! Zhou et al. (2004), section 3.1, process each record in nine steps; this module does
//! steps 1-7 and hands the kinematics `r, r', r''` and the film force `F` of eq. 2 to the
//! least-squares estimator (steps 8-9, [`crate::estimator`]). One submodule per stage holds
//! its design and kernels: [`range_check`] (step 2), [`deskew`] (4), [`lowpass`] (1),
//! [`kinematics`] (5), [`differentiate`] (6), [`film_force`] (7).
//!
//! The range check reads the raw samples, before any filter, and every channel of eq. 1 and
//! eq. 2 passes through the same low-pass, so that its droop cancels in the fit. The stages
//! treat a record's ends apart from its interior: only [`Conditioned::valid`] is to be used.
//!
//! [`Chain`] designs the stages once and runs them fused; a record ([`condition`]), a window
//! of one ([`Chain::condition_window_into`]), a stream of scans ([`stream::ZeroPhaseStream`]) and the
//! causal chain for live use ([`causal::CausalChain`]) are drivers over it (ADR 0022).
//!
//! Design, order of the stages, error budget and refusals: docs/manual/conditioning.md.

pub mod causal;
mod chain;
pub mod deskew;
pub mod differentiate;
pub mod film_force;
pub mod kinematics;
pub mod lowpass;
pub mod range_check;
pub mod stream;

use std::ops::Range;

pub use chain::Chain;

use oilfilm_physics::daq::{Calibration, ChannelId, CHANNEL_COUNT};
use serde::{Deserialize, Serialize};

use crate::record::RawRecord;
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
            return Err(IdentificationError::invalid("mechanics.housing_mass_kg", format!("must be finite and > 0, got {}", self.housing_mass_kg)));
        }
        if let Some((i, a)) = self.exciter_angles_deg.iter().enumerate().find(|(_, a)| !a.is_finite()) {
            return Err(IdentificationError::invalid(format!("mechanics.exciter_angles_deg[{i}]"), format!("must be finite, got {a}")));
        }
        if !self.gravity_m_s2.is_finite() {
            return Err(IdentificationError::invalid("mechanics.gravity_m_s2", format!("must be finite, got {}", self.gravity_m_s2)));
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
        Self { lowpass_cutoff_hz: 200.0, lowpass_order: 4, differentiator_half_length: 5, deskew: true, deskew_taps: 4 }
    }
}

impl ConditioningConfig {
    /// Checks every field against the record's sample rate; errors name the field
    /// (`conditioning.lowpass_cutoff_hz`, ...).
    pub fn validate(&self, sample_rate_hz: f64) -> Result<(), IdentificationError> {
        lowpass::Butterworth::design(self.lowpass_order, self.lowpass_cutoff_hz, sample_rate_hz)?;
        differentiate::SavitzkyGolayDerivative::new(self.differentiator_half_length, sample_rate_hz)?;
        self.check_taps()
    }

    fn check_taps(&self) -> Result<(), IdentificationError> {
        if !(2..=deskew::MAX_TAPS).contains(&self.deskew_taps) {
            return Err(IdentificationError::invalid("conditioning.deskew_taps", format!("must be in 2..={}, got {}", deskew::MAX_TAPS, self.deskew_taps)));
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
/// `Conditioned::default()` is empty; [`Chain::condition_into`] reuses its buffers.
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
    /// What [`Chain::condition_into`] keeps for the next call besides the buffers.
    work: Work,
}

/// [`Chain::condition_into`]'s memory between calls that is not part of the result. Any two
/// compare equal, and it prints as nothing, so a `Conditioned` compares and prints as its
/// data.
#[derive(Clone, Default)]
pub(super) struct Work {
    /// The housing's x and y velocity (not outputs).
    pub(super) velocity: [Vec<f64>; 2],
    /// The low-pass's scratch: its reflections and its forward pass's output (eight values
    /// per scan, `lowpass::Butterworth::filtfilt8_fed`). Kept between
    /// [`Chain::condition_into`] calls, not returned by [`condition`].
    pub(super) scratch: Vec<f64>,
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
        let channels: Vec<&str> = self.range_violations.iter().map(|v| v.channel.name()).collect();
        Err(IdentificationError::BadInput {
            what: format!("record ({} channel(s) out of linear range: {})", channels.len(), channels.join(", ")),
            reason: self.range_violations.iter().map(ToString::to_string).collect::<Vec<_>>().join("; "),
        })
    }
}

/// The refusal of a record of `n` scans that has no valid scan once the filters' `edge` is
/// trimmed at each end (`n <= 2 edge`).
pub(super) fn too_short(n: usize, edge: usize) -> IdentificationError {
    IdentificationError::BadInput {
        what: "record length".into(),
        reason: format!("{n} scans; the filters' edge effects need {edge} at each end, so at least {} scans", 2 * edge + 1),
    }
}

/// The column holding each channel, by channel index, of a record or stream (`what`) whose
/// columns are `channels`: an error names a channel that is missing.
pub(super) fn columns_of(channels: &[ChannelId], what: &str) -> Result<[usize; CHANNEL_COUNT], IdentificationError> {
    let mut col_of = [usize::MAX; CHANNEL_COUNT];
    for (k, c) in channels.iter().enumerate() {
        col_of[c.index()] = k;
    }
    match ChannelId::ALL.iter().find(|c| col_of[c.index()] == usize::MAX) {
        Some(missing) => Err(IdentificationError::BadInput {
            what: format!("channel `{missing}`"),
            reason: format!("missing from the {what}; conditioning needs all ten channels"),
        }),
        None => Ok(col_of),
    }
}

/// The `BadInput` for a non-finite sample.
pub(crate) fn non_finite_error(channel: ChannelId, index: usize, value: f64, unit: &str) -> IdentificationError {
    IdentificationError::BadInput { what: format!("channel `{channel}`, sample {index}"), reason: format!("{value} is not a finite reading ({unit})") }
}

/// Runs steps 1-7 on a raw record: calibrate, range-check, deskew, low-pass, kinematics,
/// differentiate twice, eq. 2. The record must hold all ten channels. (A [`Chain`] prepared
/// once does the same for many records.)
pub fn condition(raw: &RawRecord, calibration: &Calibration, mechanics: &Mechanics, config: &ConditioningConfig) -> Result<Conditioned, IdentificationError> {
    Chain::new(calibration, mechanics, config, raw.sample_rate_hz)?.condition(raw)
}
