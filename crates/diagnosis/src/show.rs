//! Show what the simulation gets wrong (issue 6, part 1).
//!
//! [`show`] takes a measured record and the rig it came from and puts the film model next to
//! the measurement four ways:
//!
//! 1. **Motion.** The linear rig (housing mass on the film's K and C at the measured
//!    operating point, journal fixed) is driven by the *measured* applied forces and its
//!    relative motion `r = (x, y)` compared with the measured one in time (NRMSE per axis)
//!    and at the excitation lines (amplitude ratio and phase difference), with both spectra
//!    for plotting; the nominal film model and, when given, the updated one
//!    ([`crate::model_update`]).
//! 2. **Coefficients.** Per accepted window of the identification ([`pipeline::identify`]),
//!    the identified K and C with their standard errors next to the film model's linear
//!    coefficients at that window's operating point (speed, temperature, static load).
//! 3. **Trends.** Each identified coefficient against the amplitude `d`, the load parameter
//!    `F_Y`, the temperature and time: a straight-line slope with its standard error.
//! 4. **Residual spectra.** What the baseline K-C fit leaves in the film force, per axis: the
//!    power at the excitation lines, their 2x and 3x harmonics, the sums and differences of
//!    the strongest lines (intermodulation), the shaft's 1X and the broadband floor, in dB
//!    above the floor.
//!
//! ## How the prediction is driven (and what it assumes)
//! * The applied forces are taken from the record's one conditioning ([`crate::evidence`]):
//!   eq. 2 solved for `F_app = F_exc + (f3 - m g) e_y = F_film + m X''`, in the judging band.
//!   With the journal fixed, `X = -r` and `F_app(w) = -(K + i w C - m w^2) r(w)`, solved for
//!   `r` bin by bin (zero-padded FFT: the response is causal, starting from rest).
//! * The film's K and C are the model's at the measured speed, mean bearing temperature and
//!   static load. A drift during the record shows up as disagreement, which is the point.
//! * **Start-up.** The prediction starts from rest at the first valid sample while the real
//!   rig was already moving; `settle_time_constants` of the linear film's slowest decay are
//!   discarded before any comparison (reported as `transient_discarded_s`).
//! * Comparisons are on the dynamic parts (each signal minus its own mean over the compared
//!   span); the static positions are reported separately, since a probe's zero is rarely
//!   known to the micrometre.
//!
//! Everything is a pure function of its arguments: no I/O, no clock.

mod spectra;
mod stats;

use nalgebra::{Matrix2, Vector2};
use oilfilm_identification::conditioning::Conditioned;
use oilfilm_identification::estimator::{self, Coefficients, Signals};
use oilfilm_identification::pipeline::{self, SpeedSource};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::dimensionless;
use oilfilm_physics::film::Running;
use oilfilm_physics::operating_point::{self, EquilibriumOptions};
use serde::{Deserialize, Serialize};

use crate::error::DiagnosisError;
use crate::evidence::Prepared;
use crate::model_update::{self, ModelUpdate};
use spectra::{phasor, segment_len, welch, wrap_deg, Welch};

/// The eight linear coefficients in the order every array of this module uses: stiffness
/// (N/m) then damping (N s/m), rows = force component, columns = motion component.
pub const COEFFICIENT_NAMES: [&str; 8] = ["kxx", "kxy", "kyx", "kyy", "cxx", "cxy", "cyx", "cyy"];

/// Settings of the show.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ShowConfig {
    /// Time constants of the linear film's slowest mode discarded at the start of the
    /// prediction (10: the start-up error falls to 5e-5 of its size).
    pub settle_time_constants: f64,
    /// Length of the time-series excerpt kept for plotting, s (taken at the end of the record).
    pub plot_seconds: f64,
    /// At most this many points per plotted time series (decimated by a whole stride).
    pub plot_points: usize,
    /// Longest Welch segment, samples (a power of two; shorter records use shorter ones).
    pub spectrum_segment: usize,
    /// Upper edge of the spectra, Hz; `None`: 3.5x the highest excitation line or shaft 1X,
    /// at least 20 Hz, never above the conditioning's low-pass cutoff.
    pub spectrum_max_hz: Option<f64>,
    /// At most this many excitation lines are compared and named (the strongest in force).
    pub max_lines: usize,
}

impl Default for ShowConfig {
    fn default() -> Self {
        Self { settle_time_constants: 10.0, plot_seconds: 0.25, plot_points: 1500, spectrum_segment: 16_384, spectrum_max_hz: None, max_lines: 40 }
    }
}

impl ShowConfig {
    /// Checks every field; the error names it.
    pub fn validate(&self) -> Result<(), DiagnosisError> {
        if !(self.settle_time_constants.is_finite() && self.settle_time_constants >= 0.0) {
            return Err(DiagnosisError::invalid("settle_time_constants", format!("must be finite and >= 0, got {}", self.settle_time_constants)));
        }
        if !(self.plot_seconds.is_finite() && self.plot_seconds > 0.0) {
            return Err(DiagnosisError::invalid("plot_seconds", format!("must be finite and > 0, got {}", self.plot_seconds)));
        }
        if self.plot_points < 16 {
            return Err(DiagnosisError::invalid("plot_points", format!("must be at least 16, got {}", self.plot_points)));
        }
        if !self.spectrum_segment.is_power_of_two() || self.spectrum_segment < 256 {
            return Err(DiagnosisError::invalid("spectrum_segment", format!("must be a power of two >= 256, got {}", self.spectrum_segment)));
        }
        if let Some(f) = self.spectrum_max_hz {
            if !(f.is_finite() && f > 0.0) {
                return Err(DiagnosisError::invalid("spectrum_max_hz", format!("must be finite and > 0, got {f}")));
            }
        }
        if self.max_lines == 0 {
            return Err(DiagnosisError::invalid("max_lines", "must be at least 1"));
        }
        Ok(())
    }
}

/// Everything the show found, ready to serialise or plot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Show {
    pub rig: String,
    /// The frame and sign convention ([`pipeline::FRAME`]).
    pub frame: String,
    pub speed_rpm: f64,
    pub speed_source: SpeedSource,
    pub sample_rate_hz: f64,
    pub samples: usize,
    pub duration_s: f64,
    pub operating: MeasuredOperatingPoint,
    /// Lines of the applied force (strongest first, at most `max_lines`), Hz.
    pub excitation_lines_hz: Vec<f64>,
    pub motion: MotionComparison,
    pub coefficients: CoefficientComparison,
    pub trends: Vec<Trend>,
    pub residual: ResidualSpectra,
    /// What the reader should know: assumptions taken, things that could not be computed.
    pub notes: Vec<String>,
}

/// The operating point measured over the whole record, and the film model's equilibrium there.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeasuredOperatingPoint {
    pub speed_rpm: f64,
    /// Mean bearing temperature over the valid samples, C, and its range.
    pub temperature_c: f64,
    pub temperature_range_c: [f64; 2],
    /// The oil law's viscosity at the mean temperature, Pa s.
    pub viscosity_pa_s: f64,
    /// Mean bellows force f3, N, and the static load `W = f3 - m g` it puts on the film.
    pub bellows_mean_n: f64,
    pub bellows_load_n: f64,
    /// Mean film force on the journal from eq. 2, N, and its magnitude.
    pub static_force_n: [f64; 2],
    pub load_n: f64,
    pub sommerfeld: f64,
    /// Zhou's load parameter `F_Y`.
    pub load_parameter: f64,
    /// Mean measured journal position relative to the bearing, m, and the model's equilibrium.
    pub measured_position_m: [f64; 2],
    pub model_position_m: [f64; 2],
    pub model_eccentricity: f64,
    pub model_attitude_deg: f64,
}

/// Predicted against measured relative motion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MotionComparison {
    /// The prediction starts here (first valid sample), s.
    pub simulated_from_s: f64,
    /// The linear film's slowest decay rate, 1/s (`None`: the linear model does not decay).
    pub slowest_decay_rate_per_s: Option<f64>,
    pub transient_discarded_s: f64,
    /// The span compared, s.
    pub compared_s: [f64; 2],
    /// x then y.
    pub axes: Vec<AxisComparison>,
    pub time_series: TimeSeries,
    pub spectrum: MotionSpectrum,
}

/// One axis of the motion comparison.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisComparison {
    pub axis: String,
    /// RMS of (predicted - measured) dynamic motion over the RMS of the measured one.
    pub nrmse: f64,
    pub measured_rms_m: f64,
    pub predicted_rms_m: f64,
    pub error_rms_m: f64,
    /// Static (mean) positions over the compared span, m.
    pub measured_mean_m: f64,
    pub predicted_mean_m: f64,
    /// The updated film model's NRMSE and RMS, when an update was given.
    pub updated_nrmse: Option<f64>,
    pub updated_rms_m: Option<f64>,
    pub lines: Vec<LineComparison>,
}

/// Amplitude and phase of the motion at one excitation line (phases against the first
/// compared sample).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LineComparison {
    pub frequency_hz: f64,
    pub measured_amplitude_m: f64,
    pub predicted_amplitude_m: f64,
    /// predicted / measured.
    pub amplitude_ratio: f64,
    pub measured_phase_deg: f64,
    pub predicted_phase_deg: f64,
    /// predicted - measured, wrapped to (-180, 180].
    pub phase_difference_deg: f64,
    /// The updated model's amplitude and its ratio to the measured one, when given.
    pub updated_amplitude_m: Option<f64>,
    pub updated_amplitude_ratio: Option<f64>,
    /// Whether this axis moves at this line (at least a tenth of its strongest line): an axis
    /// that is not excited there has no ratio worth reading.
    pub excited: bool,
}

/// An excerpt of the motion for plotting: measured and predicted, x and y, absolute (m).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TimeSeries {
    pub t_s: Vec<f64>,
    pub measured_x_m: Vec<f64>,
    pub measured_y_m: Vec<f64>,
    pub predicted_x_m: Vec<f64>,
    pub predicted_y_m: Vec<f64>,
    /// The updated model's prediction (empty without an update).
    pub updated_x_m: Vec<f64>,
    pub updated_y_m: Vec<f64>,
}

/// Welch amplitude spectra (`sqrt(2 P)` per bin, m) of the dynamic motion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MotionSpectrum {
    pub resolution_hz: f64,
    pub frequency_hz: Vec<f64>,
    pub measured_x_m: Vec<f64>,
    pub measured_y_m: Vec<f64>,
    pub predicted_x_m: Vec<f64>,
    pub predicted_y_m: Vec<f64>,
    pub updated_x_m: Vec<f64>,
    pub updated_y_m: Vec<f64>,
}

/// Identified against modelled coefficients, per window.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CoefficientComparison {
    pub windows: Vec<WindowComparison>,
    pub refused: Vec<RefusedWindow>,
    /// Why there are no windows at all, if so.
    pub refusal: Option<String>,
    /// Mean over the windows of each relative difference (identified - model) / |model|.
    pub mean_relative_difference: Option<[f64; 8]>,
}

/// One accepted window. Arrays follow [`COEFFICIENT_NAMES`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WindowComparison {
    pub t_start_s: f64,
    pub t_end_s: f64,
    pub speed_rpm: f64,
    pub temperature_c: f64,
    pub load_n: f64,
    pub load_parameter: f64,
    pub amplitude_d: f64,
    pub identified: [f64; 8],
    pub standard_error: [f64; 8],
    pub model: [f64; 8],
    /// (identified - model) / |model|.
    pub relative_difference: [f64; 8],
}

/// A window the estimator refused, with its reason.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RefusedWindow {
    pub t_start_s: f64,
    pub t_end_s: f64,
    pub reason: String,
}

/// What a trend is plotted against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrendVariable {
    /// Excitation amplitude `d = max |r - mean r| / c`.
    AmplitudeD,
    /// Zhou's load parameter `F_Y`.
    LoadParameter,
    TemperatureC,
    /// Window mid-time, s.
    TimeS,
}

impl TrendVariable {
    pub const ALL: [TrendVariable; 4] = [Self::AmplitudeD, Self::LoadParameter, Self::TemperatureC, Self::TimeS];

    /// A label with the unit, for tables and axes.
    pub fn label(self) -> &'static str {
        match self {
            Self::AmplitudeD => "amplitude d",
            Self::LoadParameter => "load parameter F_Y",
            Self::TemperatureC => "temperature (C)",
            Self::TimeS => "time (s)",
        }
    }

    /// The unit of one step of the variable, for "%/unit".
    pub fn unit(self) -> &'static str {
        match self {
            Self::AmplitudeD => "unit d",
            Self::LoadParameter => "unit F_Y",
            Self::TemperatureC => "C",
            Self::TimeS => "s",
        }
    }

    fn of(self, w: &WindowComparison) -> f64 {
        match self {
            Self::AmplitudeD => w.amplitude_d,
            Self::LoadParameter => w.load_parameter,
            Self::TemperatureC => w.temperature_c,
            Self::TimeS => 0.5 * (w.t_start_s + w.t_end_s),
        }
    }
}

/// One coefficient against one variable over the accepted windows: `value = a + slope u`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Trend {
    pub coefficient: String,
    pub variable: TrendVariable,
    /// (variable, coefficient) per window.
    pub points: Vec<[f64; 2]>,
    pub slope: f64,
    pub slope_se: f64,
    /// slope / slope_se.
    pub t_statistic: f64,
    pub mean: f64,
    /// slope / |mean|: the fractional change per unit of the variable (x100 for %/unit).
    pub relative_slope_per_unit: f64,
    /// The fitted change across the observed range of the variable, as a fraction of the
    /// mean: what the trend amounts to in this record (a steep slope over a range of noise
    /// amounts to nothing).
    pub relative_change_over_range: f64,
    /// Smallest and largest value of the variable over the windows.
    pub range: [f64; 2],
}

impl Trend {
    /// Worth a reader's attention: at least [`TREND_MIN_WINDOWS`] windows, |t| above
    /// [`TREND_SIGNIFICANT_T`] and a change over the observed range above
    /// [`TREND_MIN_CHANGE`]. The thresholds are stated, not tuned: 32 trends are tested at
    /// once, so a |t| of 3 on a handful of windows is no evidence.
    pub fn is_notable(&self) -> bool {
        self.points.len() >= TREND_MIN_WINDOWS && self.t_statistic.abs() > TREND_SIGNIFICANT_T && self.relative_change_over_range.abs() > TREND_MIN_CHANGE
    }
}

/// See [`Trend::is_notable`].
pub const TREND_MIN_WINDOWS: usize = 6;
/// See [`Trend::is_notable`].
pub const TREND_SIGNIFICANT_T: f64 = 4.0;
/// See [`Trend::is_notable`]: 2 %.
pub const TREND_MIN_CHANGE: f64 = 0.02;

/// The kind of a named residual component.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ComponentKind {
    Excitation,
    /// `order` x an excitation line.
    Harmonic {
        order: u32,
    },
    /// Sum or difference of two excitation lines (a nonlinearity mixes them).
    Intermodulation,
    /// Once per shaft revolution.
    Shaft1x,
    /// Everything in the band that is not a named line.
    Broadband,
}

/// One named component of the residual spectrum, per axis (x, y).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResidualComponent {
    pub name: String,
    pub kind: ComponentKind,
    /// `None` for the broadband part.
    pub frequency_hz: Option<f64>,
    /// Amplitude of the line (`sqrt(2 P_line)`), or the RMS of the broadband part, N.
    pub amplitude_n: [f64; 2],
    /// Peak bin of the line over the median floor bin, dB (0 for the broadband part).
    pub db_above_floor: [f64; 2],
    /// Share of the residual power in the band.
    pub fraction_of_residual: [f64; 2],
}

/// The baseline K-C fit over the whole valid record and the spectrum of what it leaves.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResidualSpectra {
    /// The fit (order of [`COEFFICIENT_NAMES`]) and its standard errors; `None` if refused.
    pub baseline: Option<[f64; 8]>,
    pub baseline_se: Option<[f64; 8]>,
    /// Why there is no fit, if there is none.
    pub refusal: Option<String>,
    /// RMS of the dynamic film force and of the residual, N, per axis.
    pub force_rms_n: [f64; 2],
    pub residual_rms_n: [f64; 2],
    /// Band the components and the floor are taken over, Hz.
    pub band_hz: [f64; 2],
    /// Median floor bin, N^2.
    pub floor_n2_per_bin: [f64; 2],
    pub components: Vec<ResidualComponent>,
    pub resolution_hz: f64,
    pub frequency_hz: Vec<f64>,
    /// `sqrt(2 P)` per bin, N.
    pub amplitude_x_n: Vec<f64>,
    pub amplitude_y_n: Vec<f64>,
}

fn coefficient_array(k: &Matrix2<f64>, c: &Matrix2<f64>) -> [f64; 8] {
    [k[(0, 0)], k[(0, 1)], k[(1, 0)], k[(1, 1)], c[(0, 0)], c[(0, 1)], c[(1, 0)], c[(1, 1)]]
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.iter().sum::<f64>() / v.len() as f64
}

fn rms_about_mean(v: &[f64]) -> f64 {
    let m = mean(v);
    (v.iter().map(|a| (a - m) * (a - m)).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// The show of a prepared record (its one conditioning and identification, shared with the
/// diagnosis), against the rig's film model and, when given, the updated one.
pub fn show(p: &Prepared, rig: &RigConfig, update: Option<&ModelUpdate>, config: &ShowConfig) -> Result<Show, DiagnosisError> {
    config.validate()?;
    let raw = &p.raw;
    let fs = raw.sample_rate_hz;
    let mut notes = Vec::new();
    let wide = &p.wide;
    if !wide.range_violations.is_empty() {
        notes.push(format!(
            "a probe left its linear range ({}): the identification refused the record; the motion comparison still runs but clipped samples disagree by construction",
            wide.range_violations.iter().map(ToString::to_string).collect::<Vec<_>>().join("; ")
        ));
    }
    let valid = p.narrow.valid.clone();
    if valid.len() < 64 {
        return Err(DiagnosisError::bad_input("record", format!("only {} samples survive the filters' edge trimming; at least 64 are needed", valid.len())));
    }
    let m = rig.housing.mass_kg;
    let applied: [Vec<f64>; 2] = [
        wide.fx_n.iter().zip(&wide.housing_ax_m_s2).map(|(f, a)| f + m * a).collect(),
        wide.fy_n.iter().zip(&wide.housing_ay_m_s2).map(|(f, a)| f + m * a).collect(),
    ];
    let lines = strongest_lines(&p.lines_hz, &applied[0][valid.clone()], &applied[1][valid.clone()], fs, config.max_lines);
    if lines.is_empty() {
        notes.push("no excitation line found in the applied forces: no line-by-line comparison".into());
    }
    let operating = measured_operating_point(wide, rig, p.speed_rpm)?;
    let motion = motion_comparison(p, rig, &operating, update, &lines, config, &mut notes)?;
    let coefficients = coefficient_comparison(&p.identification, rig, &mut notes)?;
    let trends = trends(&coefficients.windows, &mut notes);
    let residual = residual_spectra(wide, &p.narrow, p.wide_config.lowpass_cutoff_hz, &lines, p.speed_rpm, config, &mut notes)?;
    Ok(Show {
        rig: rig.name.clone(),
        frame: pipeline::FRAME.to_string(),
        speed_rpm: p.speed_rpm,
        speed_source: p.identification.speed_source,
        sample_rate_hz: fs,
        samples: raw.len(),
        duration_s: raw.len() as f64 / fs,
        operating,
        excitation_lines_hz: lines,
        motion,
        coefficients,
        trends,
        residual,
        notes,
    })
}

/// The excitation lines (the pipeline's one line search, on the measured exciter forces)
/// ranked by the applied forces' power there (both directions), strongest first, at most `max`.
fn strongest_lines(lines: &[f64], fx: &[f64], fy: &[f64], fs: f64, max: usize) -> Vec<f64> {
    if lines.is_empty() {
        return Vec::new();
    }
    let seg = segment_len(fx.len(), 1 << 16);
    let w = welch(&[fx, fy], seg, fs);
    let mut scored: Vec<(f64, f64)> = lines.iter().map(|&f| (f, w[0].line_power(f).unwrap_or(0.0) + w[1].line_power(f).unwrap_or(0.0))).collect();
    scored.sort_by(|a, b| b.1.total_cmp(&a.1));
    scored.truncate(max);
    scored.into_iter().map(|(f, _)| f).collect()
}

fn measured_operating_point(c: &Conditioned, rig: &RigConfig, speed_rpm: f64) -> Result<MeasuredOperatingPoint, DiagnosisError> {
    let v = c.valid.clone();
    let temps = &c.temperature_c[v.clone()];
    let temperature_c = mean(temps);
    let t_lo = temps.iter().copied().fold(f64::INFINITY, f64::min);
    let t_hi = temps.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let viscosity_pa_s = rig
        .oil
        .viscosity_pa_s(temperature_c)
        .map_err(|e| DiagnosisError::bad_input("temperature", format!("mean bearing temperature {temperature_c:.2} C: {e}")))?;
    let bellows_mean_n = mean(&c.static_load_n[v.clone()]);
    let bellows_load_n = bellows_mean_n - rig.housing.mass_kg * rig.housing.gravity_m_s2;
    let static_force_n = c.static_force_n;
    let load_n = static_force_n[0].hypot(static_force_n[1]);
    if load_n.is_nan() || load_n <= 0.0 {
        return Err(DiagnosisError::bad_input("f3", format!("the measured static film load is {load_n} N: no operating point to simulate")));
    }
    let running = Running::from_rpm(speed_rpm, viscosity_pa_s);
    let mut film = rig.film()?;
    let load = -Vector2::new(static_force_n[0], static_force_n[1]);
    let op = operating_point::solve(film.as_mut(), &running, load, &EquilibriumOptions::default())?;
    let geometry = rig.bearing;
    Ok(MeasuredOperatingPoint {
        speed_rpm,
        temperature_c,
        temperature_range_c: [t_lo, t_hi],
        viscosity_pa_s,
        bellows_mean_n,
        bellows_load_n,
        static_force_n,
        load_n,
        sommerfeld: dimensionless::sommerfeld(&geometry, &running, load_n),
        load_parameter: dimensionless::zhou_load_parameter(&geometry, &running, load_n),
        measured_position_m: [mean(&c.x_m[v.clone()]), mean(&c.y_m[v])],
        model_position_m: [op.journal.x_m, op.journal.y_m],
        model_eccentricity: op.eccentricity,
        model_attitude_deg: op.attitude_deg,
    })
}

/// The linear rig driven by the measured forces, against the measured motion.
fn motion_comparison(
    p: &Prepared,
    rig: &RigConfig,
    op: &MeasuredOperatingPoint,
    update: Option<&ModelUpdate>,
    lines: &[f64],
    config: &ShowConfig,
    notes: &mut Vec<String>,
) -> Result<MotionComparison, DiagnosisError> {
    let c = &p.narrow;
    let fs = p.raw.sample_rate_hz;
    let valid = c.valid.clone();
    let n_valid = valid.len();
    let running = Running::from_rpm(op.speed_rpm, op.viscosity_pa_s);
    let mut film = rig.film()?;
    let load = -Vector2::new(op.static_force_n[0], op.static_force_n[1]);
    let nominal = operating_point::solve(film.as_mut(), &running, load, &EquilibriumOptions::default())?;
    let (k, cc) = (nominal.coefficients.stiffness_n_m, nominal.coefficients.damping_n_s_m);
    let rate = stats::slowest_decay_rate(&k, &cc, rig.housing.mass_kg);
    let predictor = model_update::Predictor::new(p);
    let predicted = predictor.predict(&k, &cc, n_valid);
    let updated = update.map(|u| predictor.predict(&u.updated_stiffness_n_m, &u.updated_damping_n_s_m, n_valid));

    // Start-up transient.
    let record_s = n_valid as f64 / fs;
    let mut discard_s = match rate {
        Some(r) => config.settle_time_constants / r,
        None => {
            notes.push("the linear film model has a mode that does not decay at this operating point: half the record is discarded as start-up".into());
            0.5 * record_s
        }
    };
    if discard_s > 0.5 * record_s {
        notes.push(format!("the start-up transient ({discard_s:.3} s) is longer than half the record: only the second half is compared"));
        discard_s = 0.5 * record_s;
    }
    let skip = (discard_s * fs).ceil() as usize;
    let cmp = skip..n_valid;
    let start = valid.start;
    let t0 = c.t_s[start + cmp.start];
    let t1 = c.t_s[start + n_valid - 1];

    let measured = [&c.x_m[valid.clone()], &c.y_m[valid.clone()]];
    let nrmse_of = |meas: &[f64], pred: &[f64]| -> (f64, f64) {
        let (mm, pm) = (mean(meas), mean(pred));
        let err: Vec<f64> = meas.iter().zip(pred).map(|(u, v)| (v - pm) - (u - mm)).collect();
        let e = (err.iter().map(|e| e * e).sum::<f64>() / err.len() as f64).sqrt();
        (e, e / rms_about_mean(meas))
    };
    let mut axes = Vec::new();
    for (a, name) in ["x", "y"].iter().enumerate() {
        let meas = &measured[a][cmp.clone()];
        let pred = &predicted[a][cmp.clone()];
        let upd = updated.as_ref().map(|u| &u[a][cmp.clone()]);
        let (error_rms_m, nrmse) = nrmse_of(meas, pred);
        let measured_rms_m = rms_about_mean(meas);
        let strongest = lines.iter().map(|&f| phasor(meas, f, fs).0).fold(0.0, f64::max);
        let line_cmp = lines
            .iter()
            .map(|&f| {
                let (am, phm) = phasor(meas, f, fs);
                let (ap, php) = phasor(pred, f, fs);
                let updated_amplitude_m = upd.map(|u| phasor(u, f, fs).0);
                LineComparison {
                    frequency_hz: f,
                    measured_amplitude_m: am,
                    predicted_amplitude_m: ap,
                    amplitude_ratio: ap / am,
                    measured_phase_deg: phm,
                    predicted_phase_deg: php,
                    phase_difference_deg: wrap_deg(php - phm),
                    updated_amplitude_m,
                    updated_amplitude_ratio: updated_amplitude_m.map(|u| u / am),
                    excited: am >= 0.1 * strongest,
                }
            })
            .collect();
        axes.push(AxisComparison {
            axis: name.to_string(),
            nrmse,
            measured_rms_m,
            predicted_rms_m: rms_about_mean(pred),
            error_rms_m,
            measured_mean_m: mean(meas),
            predicted_mean_m: op.model_position_m[a],
            updated_nrmse: upd.map(|u| nrmse_of(meas, u).1),
            updated_rms_m: upd.map(rms_about_mean),
            lines: line_cmp,
        });
    }

    // Time-series excerpt: the last `plot_seconds` of the compared span.
    let len = ((config.plot_seconds * fs).round() as usize).clamp(2, cmp.len());
    let from = n_valid - len;
    let stride = len.div_ceil(config.plot_points).max(1);
    let pick = |v: &[f64]| -> Vec<f64> { v[from..].iter().step_by(stride).copied().collect() };
    let time_series = TimeSeries {
        t_s: c.t_s[start + from..start + n_valid].iter().step_by(stride).copied().collect(),
        measured_x_m: pick(measured[0]),
        measured_y_m: pick(measured[1]),
        predicted_x_m: pick(&predicted[0]),
        predicted_y_m: pick(&predicted[1]),
        updated_x_m: updated.as_ref().map_or(Vec::new(), |u| pick(&u[0])),
        updated_y_m: updated.as_ref().map_or(Vec::new(), |u| pick(&u[1])),
    };

    // Spectra of the dynamic motion.
    let max_hz = spectrum_band_top(lines, op.speed_rpm, p.cutoff_hz, config, fs);
    let seg = segment_len(cmp.len(), config.spectrum_segment);
    let mut signals: Vec<&[f64]> = vec![&measured[0][cmp.clone()], &measured[1][cmp.clone()], &predicted[0][cmp.clone()], &predicted[1][cmp.clone()]];
    if let Some(u) = &updated {
        signals.push(&u[0][cmp.clone()]);
        signals.push(&u[1][cmp.clone()]);
    }
    let w = welch(&signals, seg, fs);
    let bins = w[0].power.len().min(((max_hz / w[0].resolution_hz).floor() as usize) + 1);
    let amp = |s: &Welch| -> Vec<f64> { s.power[..bins.min(s.power.len())].iter().map(|p| (2.0 * p).sqrt()).collect() };
    let spectrum = MotionSpectrum {
        resolution_hz: w[0].resolution_hz,
        frequency_hz: (0..bins).map(|b| b as f64 * w[0].resolution_hz).collect(),
        measured_x_m: amp(&w[0]),
        measured_y_m: amp(&w[1]),
        predicted_x_m: amp(&w[2]),
        predicted_y_m: amp(&w[3]),
        updated_x_m: w.get(4).map_or(Vec::new(), amp),
        updated_y_m: w.get(5).map_or(Vec::new(), amp),
    };
    Ok(MotionComparison {
        simulated_from_s: c.t_s[start],
        slowest_decay_rate_per_s: rate,
        transient_discarded_s: skip as f64 / fs,
        compared_s: [t0, t1],
        axes,
        time_series,
        spectrum,
    })
}

/// Top of the spectra: configured, or 3.5x the highest line / shaft 1X (at least 20 Hz),
/// below the wide low-pass cutoff and Nyquist.
fn spectrum_band_top(lines: &[f64], speed_rpm: f64, cutoff: f64, config: &ShowConfig, fs: f64) -> f64 {
    let top = config.spectrum_max_hz.unwrap_or_else(|| {
        let highest = lines.iter().copied().fold(speed_rpm / 60.0, f64::max);
        (3.5 * highest).max(20.0).min(cutoff)
    });
    top.min(0.5 * fs)
}

fn coefficient_comparison(id: &pipeline::Identification, rig: &RigConfig, notes: &mut Vec<String>) -> Result<CoefficientComparison, DiagnosisError> {
    let mut windows = Vec::new();
    let mut refused = Vec::new();
    let mut film = rig.film()?;
    for w in &id.windows {
        match &w.estimate.result {
            Err(r) => refused.push(RefusedWindow { t_start_s: w.t_start_s, t_end_s: w.t_end_s, reason: r.to_string() }),
            Ok(co) => {
                let o = &w.operating;
                let running = Running::from_rpm(o.speed_rpm, o.viscosity_pa_s);
                let load = -Vector2::new(o.static_force_n[0], o.static_force_n[1]);
                let model = match operating_point::solve(film.as_mut(), &running, load, &EquilibriumOptions::default()) {
                    Ok(op) => op.coefficients,
                    Err(e) => {
                        refused.push(RefusedWindow {
                            t_start_s: w.t_start_s,
                            t_end_s: w.t_end_s,
                            reason: format!(
                                "identified, but the film model has no equilibrium at this window's operating point ({:.0} N, {:.2} C): {e}",
                                o.load_n, o.temperature_c
                            ),
                        });
                        continue;
                    }
                };
                windows.push(window_comparison(w, co, &model.stiffness_n_m, &model.damping_n_s_m));
            }
        }
    }
    let refusal = if windows.is_empty() {
        let why = id.refusal.clone().unwrap_or_else(|| format!("every window ({}) was refused", refused.len()));
        notes.push(format!("no identified coefficients to compare: {why}"));
        Some(why)
    } else {
        None
    };
    let mean_relative_difference = (!windows.is_empty()).then(|| {
        let mut m = [0.0; 8];
        for w in &windows {
            for (a, r) in m.iter_mut().zip(&w.relative_difference) {
                *a += r / windows.len() as f64;
            }
        }
        m
    });
    Ok(CoefficientComparison { windows, refused, refusal, mean_relative_difference })
}

fn window_comparison(w: &pipeline::WindowReport, co: &Coefficients, k_model: &Matrix2<f64>, c_model: &Matrix2<f64>) -> WindowComparison {
    let identified = coefficient_array(&co.stiffness_n_m, &co.damping_n_s_m);
    let model = coefficient_array(k_model, c_model);
    let mut relative_difference = [0.0; 8];
    for i in 0..8 {
        relative_difference[i] = (identified[i] - model[i]) / model[i].abs();
    }
    WindowComparison {
        t_start_s: w.t_start_s,
        t_end_s: w.t_end_s,
        speed_rpm: w.operating.speed_rpm,
        temperature_c: w.operating.temperature_c,
        load_n: w.operating.load_n,
        load_parameter: w.operating.load_parameter,
        amplitude_d: w.operating.amplitude_d,
        identified,
        standard_error: coefficient_array(&co.stiffness_se, &co.damping_se),
        model,
        relative_difference,
    }
}

fn trends(windows: &[WindowComparison], notes: &mut Vec<String>) -> Vec<Trend> {
    let mut out = Vec::new();
    if windows.len() < 3 {
        notes.push(format!("{} accepted window(s): trends need at least 3 (shorten `window_s`)", windows.len()));
        return out;
    }
    for var in TrendVariable::ALL {
        let u: Vec<f64> = windows.iter().map(|w| var.of(w)).collect();
        let mut any = false;
        for (k, name) in COEFFICIENT_NAMES.iter().enumerate() {
            let v: Vec<f64> = windows.iter().map(|w| w.identified[k]).collect();
            let Some((slope, se, m)) = stats::line_fit(&u, &v) else { continue };
            any = true;
            let lo = u.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = u.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            out.push(Trend {
                coefficient: name.to_string(),
                variable: var,
                points: u.iter().zip(&v).map(|(a, b)| [*a, *b]).collect(),
                slope,
                slope_se: se,
                t_statistic: slope / se,
                mean: m,
                relative_slope_per_unit: slope / m.abs(),
                relative_change_over_range: slope * (hi - lo) / m.abs(),
                range: [lo, hi],
            });
        }
        if !any {
            notes.push(format!("no trend against {}: it does not vary across the windows", var.label()));
        }
    }
    out
}

fn residual_spectra(
    wide: &Conditioned,
    narrow: &Conditioned,
    wide_cutoff_hz: f64,
    lines: &[f64],
    speed_rpm: f64,
    config: &ShowConfig,
    notes: &mut Vec<String>,
) -> Result<ResidualSpectra, DiagnosisError> {
    let fs = 1.0 / (wide.t_s[1] - wide.t_s[0]);
    // Baseline K-C over the whole valid narrow-band record, by the project's estimator.
    let v = narrow.valid.clone();
    let signals = Signals {
        x_m: &narrow.x_m[v.clone()],
        y_m: &narrow.y_m[v.clone()],
        vx_m_s: &narrow.vx_m_s[v.clone()],
        vy_m_s: &narrow.vy_m_s[v.clone()],
        ax_m_s2: Some(&narrow.ax_m_s2[v.clone()]),
        ay_m_s2: Some(&narrow.ay_m_s2[v.clone()]),
        fx_n: &narrow.fx_n[v.clone()],
        fy_n: &narrow.fy_n[v.clone()],
    };
    let est = estimator::EstimatorConfig { model: estimator::ModelOrder::Kc, sample_rate_hz: fs, window: v.len(), hop: v.len(), ..Default::default() };
    let fit = estimator::estimate_window(&signals, 0..v.len(), &est)?;
    let (baseline, baseline_se, refusal, k, c) = match &fit.result {
        Ok(co) => (
            Some(coefficient_array(&co.stiffness_n_m, &co.damping_n_s_m)),
            Some(coefficient_array(&co.stiffness_se, &co.damping_se)),
            None,
            co.stiffness_n_m,
            co.damping_n_s_m,
        ),
        Err(r) => {
            notes.push(format!("no baseline K-C fit over the whole record ({r}): the residual spectra show the dynamic film force itself"));
            (None, None, Some(r.to_string()), Matrix2::zeros(), Matrix2::zeros())
        }
    };

    // Residual on the wide band: F - mean F - (K (r - mean r) + C r').
    let w = wide.valid.clone();
    let (mx, my) = (mean(&wide.x_m[w.clone()]), mean(&wide.y_m[w.clone()]));
    let (mvx, mvy) = (mean(&wide.vx_m_s[w.clone()]), mean(&wide.vy_m_s[w.clone()]));
    let (mfx, mfy) = (mean(&wide.fx_n[w.clone()]), mean(&wide.fy_n[w.clone()]));
    let mut res = [Vec::with_capacity(w.len()), Vec::with_capacity(w.len())];
    let mut force = [Vec::with_capacity(w.len()), Vec::with_capacity(w.len())];
    for i in w {
        let r = Vector2::new(wide.x_m[i] - mx, wide.y_m[i] - my);
        let rd = Vector2::new(wide.vx_m_s[i] - mvx, wide.vy_m_s[i] - mvy);
        let f = Vector2::new(wide.fx_n[i] - mfx, wide.fy_n[i] - mfy);
        // Lund's sign: the film force varies as -(K r + C r').
        let e = f + k * r + c * rd;
        res[0].push(e.x);
        res[1].push(e.y);
        force[0].push(f.x);
        force[1].push(f.y);
    }
    let seg = segment_len(res[0].len(), config.spectrum_segment);
    let spectra = welch(&[&res[0], &res[1]], seg, fs);
    let df = spectra[0].resolution_hz;
    let top = spectrum_band_top(lines, speed_rpm, wide_cutoff_hz, config, fs);
    let band = [2.0 * df * spectra::LOBE as f64, top];

    // Named components.
    let shaft_hz = speed_rpm / 60.0;
    let lobe_hz = (spectra::LOBE as f64 + 1.0) * df;
    let mut named: Vec<(String, ComponentKind, f64)> = lines.iter().map(|&f| (format!("excitation {f:.2} Hz"), ComponentKind::Excitation, f)).collect();
    for order in [2u32, 3] {
        for &f in lines {
            let h = order as f64 * f;
            if h > band[1] || named.iter().any(|(_, _, g)| (g - h).abs() <= lobe_hz) {
                continue;
            }
            named.push((format!("{order}x {f:.2} Hz ({h:.2} Hz)"), ComponentKind::Harmonic { order }, h));
        }
    }
    // Sums and differences of the strongest lines (at most four of them).
    let strong = &lines[..lines.len().min(4)];
    for (i, &a) in strong.iter().enumerate() {
        for &b in &strong[i + 1..] {
            for (h, sign) in [(a + b, '+'), ((a - b).abs(), '-')] {
                if h < band[0] || h > band[1] || named.iter().any(|(_, _, g)| (g - h).abs() <= lobe_hz) {
                    continue;
                }
                let (hi, lo) = if a >= b { (a, b) } else { (b, a) };
                named.push((format!("{hi:.2} {sign} {lo:.2} Hz ({h:.2} Hz)"), ComponentKind::Intermodulation, h));
            }
        }
    }
    if let Some((name, _, _)) = named.iter().find(|(_, _, g)| (g - shaft_hz).abs() <= lobe_hz) {
        notes.push(format!("the shaft's 1X ({shaft_hz:.2} Hz) coincides with {name}: the two cannot be told apart in the residual spectrum"));
    } else if shaft_hz <= band[1] {
        named.push((format!("shaft 1X ({shaft_hz:.2} Hz)"), ComponentKind::Shaft1x, shaft_hz));
    }
    let exclude: Vec<f64> = named.iter().map(|(_, _, f)| *f).collect();
    let floor = [spectra[0].floor(band[0], band[1], &exclude).unwrap_or(f64::NAN), spectra[1].floor(band[0], band[1], &exclude).unwrap_or(f64::NAN)];
    let in_band =
        |s: &Welch| -> f64 { s.power.iter().enumerate().filter(|(b, _)| (*b as f64 * df) >= band[0] && (*b as f64 * df) <= band[1]).map(|(_, p)| p).sum() };
    let total = [in_band(&spectra[0]), in_band(&spectra[1])];
    let mut components = Vec::new();
    let mut named_power = [0.0; 2];
    for (name, kind, f) in named {
        let mut amplitude_n = [0.0; 2];
        let mut db = [0.0; 2];
        let mut frac = [0.0; 2];
        for a in 0..2 {
            let p = spectra[a].line_power(f).unwrap_or(f64::NAN);
            let peak = spectra[a].peak_bin_power(f).unwrap_or(f64::NAN);
            amplitude_n[a] = (2.0 * p).sqrt();
            db[a] = 10.0 * (peak / floor[a]).log10();
            frac[a] = p / total[a];
            named_power[a] += p;
        }
        components.push(ResidualComponent { name, kind, frequency_hz: Some(f), amplitude_n, db_above_floor: db, fraction_of_residual: frac });
    }
    let broadband = [(total[0] - named_power[0]).max(0.0), (total[1] - named_power[1]).max(0.0)];
    components.push(ResidualComponent {
        name: format!("broadband {:.1}-{:.1} Hz", band[0], band[1]),
        kind: ComponentKind::Broadband,
        frequency_hz: None,
        amplitude_n: [broadband[0].sqrt(), broadband[1].sqrt()],
        db_above_floor: [0.0, 0.0],
        fraction_of_residual: [broadband[0] / total[0], broadband[1] / total[1]],
    });
    let bins = spectra[0].power.len().min((top / df).floor() as usize + 1);
    Ok(ResidualSpectra {
        baseline,
        baseline_se,
        refusal,
        force_rms_n: [rms_about_mean(&force[0]), rms_about_mean(&force[1])],
        residual_rms_n: [rms_about_mean(&res[0]), rms_about_mean(&res[1])],
        band_hz: band,
        floor_n2_per_bin: floor,
        components,
        resolution_hz: df,
        frequency_hz: (0..bins).map(|b| b as f64 * df).collect(),
        amplitude_x_n: spectra[0].power[..bins].iter().map(|p| (2.0 * p).sqrt()).collect(),
        amplitude_y_n: spectra[1].power[..bins].iter().map(|p| (2.0 * p).sqrt()).collect(),
    })
}
