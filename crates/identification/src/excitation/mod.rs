//! Excitation design: what the two exciters of the rig are asked to do, and the hard limits no
//! setpoint ever exceeds.
//!
//! The rig (Zhou et al. 2004, section 2.1) has two electric exciters pushing the floating
//! bearing housing, exciter 1 (force `f1`) along 45° and exciter 2 (`f2`) along 135° from the
//! horizontal `+x` axis, each up to 1.5 kN, sinusoidal 0–80 Hz ([`Limits::zhou2004`]).
//!
//! ## Waveforms
//! * [`Waveform::Sine`]: the paper's method, one sine per exciter.
//! * [`Waveform::Multisine`]: equal-amplitude lines on the grid `k / period_s` inside a band,
//!   with Schroeder's phases `phi_k = -pi k (k-1) / N` for a low crest factor (Schroeder 1970,
//!   "Synthesis of low-peak-factor signals and binary sequences with low autocorrelation",
//!   IEEE Trans. Inf. Theory 16; Pintelon & Schoukens, "System Identification: A Frequency
//!   Domain Approach", on periodic excitation design). Written as a sum of cosines,
//!   `a * sum cos(2 pi k t / period_s + phi_k)` with `a = rms_n * sqrt(2 / N)`. An analysis
//!   window holding a whole number of periods sees every line exactly on a DFT bin
//!   (leakage-free), provided the sample rate times `period_s` is an integer too (for
//!   example `period_s = 1` s at 5 kHz).
//! * [`Waveform::Chirp`]: `amplitude_n * sin(phase)` with the instantaneous frequency sweeping
//!   linearly from `start_hz` to `end_hz` in `sweep_s`, then starting again at `start_hz`; the
//!   phase runs on continuously across the restart, so the force never jumps. A finite sweep
//!   spreads a little energy just outside `[start_hz, end_hz]`; keep a margin to the band edge.
//!
//! ## Plan, ramp and amplitude steps
//! The [`ExcitationPlan`] holds one waveform per exciter, evaluated on the same clock
//! (`t = 0` is the start of the plan), multiplied by a common scale `s(t)`:
//! * without amplitude steps, `s` rises from 0 to 1 over `ramp_s` seconds (raised cosine,
//!   `0.5 - 0.5 cos(pi t / ramp_s)`) and then stays 1 for as long as the plan runs
//!   (`duration_s() == None`);
//! * with amplitude steps (the amplitude study of section 3.3), step `i` holds
//!   `s = scale_i` for `dwell_s_i` seconds; its first `ramp_s` seconds move from the previous
//!   level (0 before the first step) to `scale_i` by the same raised cosine, and the last
//!   step's final `ramp_s` seconds bring `s` back to 0. After the last step, and before
//!   `t = 0`, the setpoints are zero.
//!
//! Since `s(t)` never exceeds the largest step scale (1 without steps), the peak force of an
//! exciter is its waveform's true peak times that scale; [`ExcitationPlan::validate`] checks
//! exactly that (for a multisine, the peak of the actual sum of cosines over one period with
//! an error bound, not `rms * sqrt(2)`). The envelope widens each line by about `1 / ramp_s`;
//! the band check is on the waveform's own lines.
//!
//! ## What one record can identify
//! The least squares of section 3.1 regresses each film-force component on `x, y, x', y'`
//! (four regressors). A record excited at a **single frequency** (both exciters at the same
//! frequency, as in the paper and [`ExcitationPlan::paper_sine`]) puts every regressor in the
//! two-dimensional space spanned by `cos(w t)` and `sin(w t)`: the 4-column regressor matrix
//! has rank 2 (up to noise and harmonics), the eight coefficients are not identifiable from
//! one record, and a solver returns whatever the noise decides. Use
//! [`ExcitationPlan::two_tone`] (a different frequency per exciter: rank 4) or
//! [`ExcitationPlan::multisine`] (many lines), or two single-frequency records with
//! independent force directions. At one frequency the stiffness and added mass are also
//! indistinguishable (`K - w^2 M`).
//!
//! ## Safety
//! [`ExcitationPlan::force_at`] is the function the exciter node calls. Even for a plan that
//! was never validated it never returns NaN and never a value beyond `±max_force_n`: it is the
//! last line of defence, [`ExcitationPlan::validate`] is the first.

mod multisine;

use std::f64::consts::PI;

use serde::{Deserialize, Serialize};

use crate::error::IdentificationError;
use multisine::{in_band, Design};

pub use multisine::MAX_HARMONIC;

/// Ramp (seconds) the constructors put on their plans: long enough to keep the housing from
/// being kicked, short compared with a 10 s record.
pub const DEFAULT_RAMP_S: f64 = 1.0;

/// Direction of each exciter's force, degrees from `+x` towards `+y` (paper, eq. 2 and Fig. 4).
pub const EXCITER_ANGLES_DEG: [f64; 2] = [45.0, 135.0];

/// Which harmonics of `1 / period_s` inside the band a multisine uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LineSet {
    /// Every harmonic in the band.
    #[default]
    All,
    /// Odd harmonics only (1, 3, 5, ...).
    Odd,
    /// Even harmonics only (2, 4, 6, ...).
    Even,
}

/// What one exciter does. Forces in N, frequencies in Hz, times in s.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Waveform {
    /// No force.
    Off,
    /// `amplitude_n * sin(2 pi frequency_hz t + phase_deg)`: the paper's method.
    Sine {
        frequency_hz: f64,
        amplitude_n: f64,
        #[serde(default)]
        phase_deg: f64,
    },
    /// Schroeder-phased multisine: lines `k / period_s` inside `band_hz` (DC excluded) from
    /// `line_set`, equal amplitudes scaled to `rms_n`.
    Multisine {
        band_hz: [f64; 2],
        period_s: f64,
        rms_n: f64,
        #[serde(default)]
        line_set: LineSet,
    },
    /// Linear sweep `start_hz` → `end_hz` in `sweep_s`, repeating with continuous phase.
    Chirp { start_hz: f64, end_hz: f64, sweep_s: f64, amplitude_n: f64 },
}

/// One sinusoidal component `amplitude_n * cos(2 pi frequency_hz t + phase_rad)` of a
/// waveform, on the plan's clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tone {
    pub frequency_hz: f64,
    pub amplitude_n: f64,
    pub phase_rad: f64,
}

/// The rig's hard limits, per exciter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Limits {
    /// Largest force magnitude one exciter may be asked for, N.
    pub max_force_n: f64,
    /// Frequency band every excitation line must lie in, Hz, `[low, high]`.
    pub band_hz: [f64; 2],
}

impl Limits {
    /// The limits of Zhou et al. (2004), section 2.4: 1.5 kN, 0–80 Hz.
    pub fn zhou2004() -> Self {
        Self { max_force_n: 1500.0, band_hz: [0.0, 80.0] }
    }
}

/// One level of the amplitude study: both exciters' waveforms scaled by `scale` for `dwell_s`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AmplitudeStep {
    pub scale: f64,
    pub dwell_s: f64,
}

/// The excitation of one run: a waveform per exciter (`exciters[0]` drives `f1` at 45°,
/// `exciters[1]` drives `f2` at 135°), the start ramp and optional amplitude steps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExcitationPlan {
    pub exciters: [Waveform; 2],
    /// Raised-cosine ramp at the start (and between and after amplitude steps), s.
    #[serde(default)]
    pub ramp_s: f64,
    #[serde(default)]
    pub amplitude_steps: Vec<AmplitudeStep>,
}

fn finite_non_negative(x: f64) -> bool {
    x.is_finite() && x >= 0.0
}

fn finite_positive(x: f64) -> bool {
    x.is_finite() && x > 0.0
}

/// Raised cosine from 0 (u <= 0) to 1 (u >= 1).
fn raised_cosine(u: f64) -> f64 {
    0.5 - 0.5 * (PI * u.clamp(0.0, 1.0)).cos()
}

/// "exciter 1 (exciters[0], f1 at 45°)".
fn exciter_label(j: usize) -> String {
    let angle = EXCITER_ANGLES_DEG.get(j).copied().unwrap_or(f64::NAN);
    format!("exciter {} (exciters[{j}], f{} at {angle}°)", j + 1, j + 1)
}

/// A force for a message: one decimal, or scientific notation when huge.
fn readable(x: f64) -> String {
    if x.abs() < 1e7 {
        format!("{x:.1}")
    } else {
        format!("{x:.3e}")
    }
}

/// Points per sweep/period used for numerical crest factors of sines and chirps.
fn sampling_points(cycles_per_window: f64) -> usize {
    const MIN: f64 = 4096.0;
    const MAX: f64 = (1u64 << 22) as f64;
    let wanted = 64.0 * cycles_per_window;
    if wanted.is_finite() {
        wanted.clamp(MIN, MAX) as usize
    } else {
        MIN as usize
    }
}

impl Waveform {
    /// The force at time `t_s` on the plan's clock, before scaling and without any limit.
    /// Waveforms that cannot be evaluated (malformed multisine) give 0; non-finite parameters
    /// may give NaN, which [`ExcitationPlan::force_at`] turns into 0.
    fn value(&self, t_s: f64) -> f64 {
        match *self {
            Waveform::Off => 0.0,
            Waveform::Sine { frequency_hz, amplitude_n, phase_deg } => amplitude_n * (2.0 * PI * (frequency_hz * t_s).fract() + phase_deg.to_radians()).sin(),
            Waveform::Multisine { band_hz, period_s, rms_n, line_set } => match multisine::lines(band_hz, period_s, line_set) {
                Ok(lines) => multisine::value(lines, rms_n, period_s, t_s),
                Err(_) => 0.0,
            },
            Waveform::Chirp { start_hz, end_hz, sweep_s, amplitude_n } => amplitude_n * (2.0 * PI * chirp_cycles(start_hz, end_hz, sweep_s, t_s)).sin(),
        }
    }

    /// The waveform's sinusoidal components: one for a sine, one per line for a multisine,
    /// none for `Off`, a chirp (broadband) or a malformed multisine.
    pub fn tones(&self) -> Vec<Tone> {
        match *self {
            Waveform::Off | Waveform::Chirp { .. } => Vec::new(),
            Waveform::Sine { frequency_hz, amplitude_n, phase_deg } => vec![Tone {
                frequency_hz,
                amplitude_n,
                // sin(x + p) = cos(x + p - pi/2)
                phase_rad: phase_deg.to_radians() - PI / 2.0,
            }],
            Waveform::Multisine { band_hz, period_s, rms_n, line_set } => match Design::new(band_hz, period_s, rms_n, line_set) {
                Ok(d) => d
                    .harmonics
                    .iter()
                    .zip(&d.phases_rad)
                    .map(|(&k, &phase_rad)| Tone { frequency_hz: k as f64 / period_s, amplitude_n: d.amplitude_n, phase_rad })
                    .collect(),
                Err(_) => Vec::new(),
            },
        }
    }

    /// The excitation frequencies (Hz): empty for `Off` and for a chirp (broadband).
    pub fn lines_hz(&self) -> Vec<f64> {
        self.tones().iter().map(|t| t.frequency_hz).collect()
    }

    /// An upper bound of `|force|`: the amplitude of a sine or chirp; for a multisine the
    /// maximum of the signal sampled densely over one period (inverse FFT) plus the most the
    /// continuous signal can rise between samples. The bound is within 0.1 % of the true peak
    /// unless the sampling hits its cap of 2^22 points per period (multisines of many
    /// thousands of lines), where it stays a bound but is looser. NaN when the waveform is
    /// malformed.
    pub fn peak_force_n(&self) -> f64 {
        match *self {
            Waveform::Off => 0.0,
            Waveform::Sine { amplitude_n, .. } | Waveform::Chirp { amplitude_n, .. } => amplitude_n.abs(),
            Waveform::Multisine { band_hz, period_s, rms_n, line_set } => match Design::new(band_hz, period_s, rms_n, line_set) {
                Ok(d) => d.peak().2,
                Err(_) => f64::NAN,
            },
        }
    }

    /// Crest factor `max |x| / rms(x)`, computed numerically over one period (a sine's period,
    /// a multisine's `period_s`, a chirp's `sweep_s`). 0 for `Off` or a zero amplitude; NaN
    /// for a malformed waveform. A sine gives sqrt(2) ≈ 1.414; a Schroeder multisine of ten
    /// or more lines stays below 2, where the same lines in phase give `sqrt(2 N)`.
    pub fn crest_factor(&self) -> f64 {
        let (peak, rms) = match *self {
            Waveform::Off => return 0.0,
            Waveform::Multisine { band_hz, period_s, rms_n, line_set } => match Design::new(band_hz, period_s, rms_n, line_set) {
                Ok(d) => {
                    let (peak, rms, _) = d.peak();
                    (peak, rms)
                }
                Err(_) => return f64::NAN,
            },
            Waveform::Sine { frequency_hz, .. } => {
                if !finite_positive(frequency_hz) {
                    return f64::NAN;
                }
                sampled_peak_rms(|t| self.value(t), 1.0 / frequency_hz, sampling_points(1.0))
            }
            Waveform::Chirp { start_hz, end_hz, sweep_s, .. } => {
                if !(finite_positive(sweep_s) && start_hz.is_finite() && end_hz.is_finite()) {
                    return f64::NAN;
                }
                let cycles = sweep_s * start_hz.abs().max(end_hz.abs());
                sampled_peak_rms(|t| self.value(t), sweep_s, sampling_points(cycles))
            }
        };
        if rms > 0.0 {
            peak / rms
        } else if rms == 0.0 {
            0.0
        } else {
            f64::NAN
        }
    }
}

/// `(max |x|, rms x)` of `x(t)` sampled at `m` points of `[0, window)`.
fn sampled_peak_rms(x: impl Fn(f64) -> f64, window: f64, m: usize) -> (f64, f64) {
    let (mut peak, mut sum2) = (0.0_f64, 0.0);
    for j in 0..m {
        let v = x(window * j as f64 / m as f64);
        peak = peak.max(v.abs());
        sum2 += v * v;
    }
    (peak, (sum2 / m.max(1) as f64).sqrt())
}

/// Fractional cycle count of a repeating linear chirp at time `t_s`, in [0, 1) (NaN for
/// malformed parameters). Within a sweep (`tau` since its start) the phase is
/// `start tau + (end - start) tau^2 / (2 sweep)` cycles; each completed sweep adds
/// `sweep (start + end) / 2` cycles, so the phase is continuous across restarts.
fn chirp_cycles(start_hz: f64, end_hz: f64, sweep_s: f64, t_s: f64) -> f64 {
    if !finite_positive(sweep_s) {
        return f64::NAN;
    }
    let n = (t_s / sweep_s).floor();
    let tau = (t_s - n * sweep_s).clamp(0.0, sweep_s);
    let per_sweep = (sweep_s * 0.5 * (start_hz + end_hz)).fract();
    let within = start_hz * tau + 0.5 * (end_hz - start_hz) * tau * tau / sweep_s;
    ((n * per_sweep).fract() + within.fract()).fract()
}

impl ExcitationPlan {
    /// The paper's excitation: both exciters at `frequency_hz` with `amplitude_n`, exciter 2
    /// lagging 90° in phase, so that the two orthogonal forces make a rotating force.
    ///
    /// **Rank deficiency**: with one frequency, `x, y, x', y'` all lie in the span of
    /// `cos(w t)` and `sin(w t)`, so the four-regressor least squares of the paper (eq. 6) has
    /// rank 2 and cannot separate the eight coefficients from one record (see the module
    /// docs). Kept for reproducing the paper; prefer [`ExcitationPlan::two_tone`].
    pub fn paper_sine(frequency_hz: f64, amplitude_n: f64) -> Self {
        Self {
            exciters: [Waveform::Sine { frequency_hz, amplitude_n, phase_deg: 0.0 }, Waveform::Sine { frequency_hz, amplitude_n, phase_deg: -90.0 }],
            ramp_s: DEFAULT_RAMP_S,
            amplitude_steps: Vec::new(),
        }
    }

    /// Exciter 1 at `f1_hz`, exciter 2 at `f2_hz` (which must differ), same amplitude: two
    /// frequencies give the regressors rank 4, so one record identifies all eight
    /// coefficients. For leakage-free windows pick both as integer multiples of
    /// `1 / window length`.
    pub fn two_tone(f1_hz: f64, f2_hz: f64, amplitude_n: f64) -> Self {
        Self {
            exciters: [
                Waveform::Sine { frequency_hz: f1_hz, amplitude_n, phase_deg: 0.0 },
                Waveform::Sine { frequency_hz: f2_hz, amplitude_n, phase_deg: 0.0 },
            ],
            ramp_s: DEFAULT_RAMP_S,
            amplitude_steps: Vec::new(),
        }
    }

    /// Schroeder multisines on the grid `k / period_s` inside `band_hz`: exciter 1 on the odd
    /// harmonics, exciter 2 on the even ones (disjoint, so each line's response is caused by
    /// one known force direction), each with `rms_n`.
    pub fn multisine(band_hz: [f64; 2], period_s: f64, rms_n: f64) -> Self {
        let make = |line_set| Waveform::Multisine { band_hz, period_s, rms_n, line_set };
        Self { exciters: [make(LineSet::Odd), make(LineSet::Even)], ramp_s: DEFAULT_RAMP_S, amplitude_steps: Vec::new() }
    }

    /// Checks the plan against the rig's hard limits. Refuses, naming the exciter and the
    /// quantity:
    /// * malformed limits, ramp or amplitude steps (`InvalidParameter`);
    /// * NaN, infinite or negative waveform parameters, an empty multisine or one beyond
    ///   [`MAX_HARMONIC`] (`InvalidParameter` with field `exciters[j].<name>`);
    /// * any line (sine frequency, multisine line, chirp start or end) outside
    ///   `limits.band_hz` (`ExcitationLimit`);
    /// * a peak force (true waveform peak times the largest amplitude-step scale, 1 without
    ///   steps) above `limits.max_force_n` (`ExcitationLimit`).
    pub fn validate(&self, limits: &Limits) -> Result<(), IdentificationError> {
        if !finite_positive(limits.max_force_n) {
            return Err(IdentificationError::invalid("limits.max_force_n", format!("must be finite and positive, got {}", limits.max_force_n)));
        }
        let [lo, hi] = limits.band_hz;
        if !(finite_non_negative(lo) && hi.is_finite() && lo < hi) {
            return Err(IdentificationError::invalid("limits.band_hz", format!("must be finite with 0 <= low < high, got [{lo}, {hi}]")));
        }
        if !finite_non_negative(self.ramp_s) {
            return Err(IdentificationError::invalid("ramp_s", format!("must be finite and non-negative, got {}", self.ramp_s)));
        }
        let last = self.amplitude_steps.len().saturating_sub(1);
        for (i, step) in self.amplitude_steps.iter().enumerate() {
            if !finite_non_negative(step.scale) {
                return Err(IdentificationError::invalid(
                    format!("amplitude_steps[{i}].scale"),
                    format!("must be finite and non-negative, got {}", step.scale),
                ));
            }
            if !finite_positive(step.dwell_s) {
                return Err(IdentificationError::invalid(
                    format!("amplitude_steps[{i}].dwell_s"),
                    format!("must be finite and positive, got {}", step.dwell_s),
                ));
            }
            let ramps = if i == last { 2.0 } else { 1.0 };
            if step.dwell_s < ramps * self.ramp_s {
                return Err(IdentificationError::invalid(
                    format!("amplitude_steps[{i}].dwell_s"),
                    format!(
                        "{} s is shorter than the {} s of ramp{} it must hold \
                         (ramp_s = {} s{})",
                        step.dwell_s,
                        ramps * self.ramp_s,
                        if i == last { "s" } else { "" },
                        self.ramp_s,
                        if i == last { ", ramp in and ramp down after the last step" } else { "" }
                    ),
                ));
            }
        }
        let max_scale = if self.amplitude_steps.is_empty() { 1.0 } else { self.amplitude_steps.iter().fold(0.0_f64, |m, s| m.max(s.scale)) };
        for (j, waveform) in self.exciters.iter().enumerate() {
            validate_waveform(j, waveform, limits, max_scale)?;
        }
        Ok(())
    }

    /// The common scale `s(t)` of both waveforms: ramp, amplitude steps, zero outside the plan
    /// (see the module docs). Never above the largest step scale (1 without steps) for a
    /// valid plan; 0 for `t < 0`, NaN `t`, or a step with a non-positive or non-finite dwell.
    pub fn scale_at(&self, t_s: f64) -> f64 {
        if t_s.is_nan() || t_s < 0.0 {
            return 0.0;
        }
        let ramp = if finite_positive(self.ramp_s) { self.ramp_s } else { 0.0 };
        let ramp_fraction = |dt: f64| if ramp > 0.0 { raised_cosine(dt / ramp) } else { 1.0 };
        if self.amplitude_steps.is_empty() {
            return ramp_fraction(t_s);
        }
        let last = self.amplitude_steps.len() - 1; // non-empty: checked above
        let mut start = 0.0;
        let mut previous = 0.0;
        for (i, step) in self.amplitude_steps.iter().enumerate() {
            if !finite_positive(step.dwell_s) {
                return 0.0;
            }
            let end = start + step.dwell_s;
            if t_s < end {
                let mut level = previous + (step.scale - previous) * ramp_fraction(t_s - start);
                if i == last {
                    level *= ramp_fraction(end - t_s);
                }
                return level;
            }
            start = end;
            previous = step.scale;
        }
        0.0
    }

    /// The two force setpoints at time `t_s` (N, `[f1, f2]`).
    ///
    /// Always finite and within `±limits.max_force_n`, whatever the plan: NaN becomes 0 and
    /// anything larger is clamped. With non-finite or non-positive `max_force_n` the output is
    /// 0. For a plan that passed [`ExcitationPlan::validate`] with the same limits the clamp
    /// never acts.
    pub fn force_at(&self, t_s: f64, limits: &Limits) -> [f64; 2] {
        let max = if finite_positive(limits.max_force_n) { limits.max_force_n } else { 0.0 };
        let scale = self.scale_at(t_s);
        let mut out = [0.0; 2];
        if scale == 0.0 || max == 0.0 {
            return out;
        }
        for (o, waveform) in out.iter_mut().zip(&self.exciters) {
            let v = scale * waveform.value(t_s);
            *o = if v.is_nan() { 0.0 } else { v.clamp(-max, max) };
        }
        out
    }

    /// Excitation frequencies (Hz) per exciter; a chirp is broadband and has none.
    pub fn lines_hz(&self) -> [Vec<f64>; 2] {
        [self.exciters[0].lines_hz(), self.exciters[1].lines_hz()]
    }

    /// Total duration with amplitude steps (sum of dwells); `None` without steps (the plan runs
    /// until stopped) or if the sum is not finite.
    pub fn duration_s(&self) -> Option<f64> {
        if self.amplitude_steps.is_empty() {
            return None;
        }
        let total: f64 = self.amplitude_steps.iter().map(|s| s.dwell_s).sum();
        total.is_finite().then_some(total)
    }

    /// Honest peak force of each exciter over the whole plan: waveform peak times the largest
    /// amplitude-step scale (1 without steps). NaN for a malformed waveform.
    pub fn peak_force_n(&self) -> [f64; 2] {
        let scale = if self.amplitude_steps.is_empty() { 1.0 } else { self.amplitude_steps.iter().fold(0.0_f64, |m, s| m.max(s.scale.abs())) };
        [self.exciters[0].peak_force_n() * scale, self.exciters[1].peak_force_n() * scale]
    }
}

fn validate_waveform(j: usize, waveform: &Waveform, limits: &Limits, max_scale: f64) -> Result<(), IdentificationError> {
    let label = exciter_label(j);
    let check = |ok: bool, name: &str, value: f64, rule: &str| {
        if ok {
            Ok(())
        } else {
            Err(IdentificationError::invalid(format!("exciters[{j}].{name}"), format!("{label}: {name} must be {rule}, got {value}")))
        }
    };
    let out_of_band = |what: String, f: f64| {
        IdentificationError::ExcitationLimit(format!("{label}: {what} = {f} Hz lies outside the rig band [{}, {}] Hz", limits.band_hz[0], limits.band_hz[1]))
    };
    let too_strong = |peak: f64, how: String| {
        IdentificationError::ExcitationLimit(format!("{label}: peak force {} N ({how}) exceeds max_force_n = {} N", readable(peak), limits.max_force_n))
    };
    let scaled = if max_scale == 1.0 { String::new() } else { format!(" x largest amplitude-step scale {max_scale}") };
    match *waveform {
        Waveform::Off => Ok(()),
        Waveform::Sine { frequency_hz, amplitude_n, phase_deg } => {
            check(finite_positive(frequency_hz), "frequency_hz", frequency_hz, "finite and positive")?;
            check(finite_non_negative(amplitude_n), "amplitude_n", amplitude_n, "finite and non-negative")?;
            check(phase_deg.is_finite(), "phase_deg", phase_deg, "finite")?;
            if !in_band(frequency_hz, limits.band_hz) {
                return Err(out_of_band("sine frequency_hz".into(), frequency_hz));
            }
            let peak = amplitude_n * max_scale;
            if peak > limits.max_force_n {
                return Err(too_strong(peak, format!("amplitude_n {amplitude_n} N{scaled}")));
            }
            Ok(())
        }
        Waveform::Multisine { band_hz, period_s, rms_n, line_set } => {
            check(finite_positive(period_s), "period_s", period_s, "finite and positive")?;
            check(finite_non_negative(rms_n), "rms_n", rms_n, "finite and non-negative")?;
            let design = Design::new(band_hz, period_s, rms_n, line_set)
                .map_err(|reason| IdentificationError::invalid(format!("exciters[{j}].band_hz"), format!("{label}: {reason}")))?;
            for &k in &design.harmonics {
                let f = k as f64 / period_s;
                if !in_band(f, limits.band_hz) {
                    return Err(out_of_band(format!("multisine line {k}/period_s"), f));
                }
            }
            let (_, rms, bound) = design.peak();
            let peak = bound * max_scale;
            if peak > limits.max_force_n {
                let crest = if rms > 0.0 { bound / rms } else { f64::NAN };
                return Err(too_strong(peak, format!("rms_n {rms_n} N x true crest factor {crest:.3} over {} lines{scaled}", design.harmonics.len())));
            }
            Ok(())
        }
        Waveform::Chirp { start_hz, end_hz, sweep_s, amplitude_n } => {
            check(finite_non_negative(start_hz), "start_hz", start_hz, "finite and non-negative")?;
            check(finite_non_negative(end_hz), "end_hz", end_hz, "finite and non-negative")?;
            check(finite_positive(sweep_s), "sweep_s", sweep_s, "finite and positive")?;
            check(finite_non_negative(amplitude_n), "amplitude_n", amplitude_n, "finite and non-negative")?;
            for (name, f) in [("chirp start_hz", start_hz), ("chirp end_hz", end_hz)] {
                if !in_band(f, limits.band_hz) {
                    return Err(out_of_band(name.into(), f));
                }
            }
            let peak = amplitude_n * max_scale;
            if peak > limits.max_force_n {
                return Err(too_strong(peak, format!("amplitude_n {amplitude_n} N{scaled}")));
            }
            Ok(())
        }
    }
}
