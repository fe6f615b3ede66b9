//! Show what the simulation gets wrong (issue 6, part 1).
//!
//! [`show`] takes a measured record and the rig it came from and puts the film model next to
//! the measurement four ways:
//!
//! 1. **Motion.** The rig is simulated through the film model, driven by the *measured*
//!    forces, at the *measured* operating point, and its relative motion `r = (x, y)` is
//!    compared with the measured one in time (NRMSE per axis) and at the excitation lines
//!    (amplitude ratio and phase difference), with both spectra for plotting.
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
//! ## How the simulation is driven (and what it assumes)
//! * The applied forces are taken from the conditioned record: eq. 2 solved for
//!   `F_exc + (f3 - m g) e_y = F_film + m X''`, i.e. the exciters' and the bellows' force
//!   sensors after the same deskew and low-pass as the motion. The bellows' mean sets the
//!   static load `W = mean(f3) - m g` of the simulated rig (the rig's own pneumatic ripple is
//!   switched off); everything else — exciter forces, the measured bellows ripple — is resolved
//!   onto the two exciter axes and fed to the rig as exciter inputs, so the rig feels exactly
//!   the measured forces.
//! * Speed is the given one; the temperature is the record's mean bearing temperature, held
//!   constant (the baseline model's assumption: a drift during the record shows up as
//!   disagreement, which is the point). Injected effects are cleared; the journal's configured
//!   1X orbit (a property of the shaft) is kept. The rig simulation has no sensor noise.
//! * **Start-up.** The simulated rig starts at static equilibrium at the first valid sample
//!   with its exciters at rest (the first step ramps them to the measured force), while the
//!   real one was already moving. The difference decays as the linear film's
//!   slowest mode; `settle_time_constants` of its time constants are discarded before any
//!   comparison (reported as `transient_discarded_s`).
//! * Comparisons are on the dynamic parts (each signal minus its own mean over the compared
//!   span); the static positions are reported separately, since a probe's zero is rarely
//!   known to the micrometre.
//!
//! Everything is a pure function of its arguments: no I/O, no clock.

mod spectra;
mod stats;

use nalgebra::{Matrix2, Vector2};
use oilfilm_identification::conditioning::{self, Conditioned, RawRecord};
use oilfilm_identification::estimator::{self, Coefficients, Signals};
use oilfilm_identification::pipeline::{self, PipelineConfig, SpeedSource};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::Calibration;
use oilfilm_physics::dimensionless;
use oilfilm_physics::effects::Effects;
use oilfilm_physics::film::Running;
use oilfilm_physics::operating_point::{self, EquilibriumOptions};
use oilfilm_physics::rig::{Rig, RigInput};
use serde::{Deserialize, Serialize};

use crate::error::DiagnosisError;
use spectra::{phasor, segment_len, welch, wrap_deg, Welch};

/// The eight linear coefficients in the order every array of this module uses: stiffness
/// (N/m) then damping (N s/m), rows = force component, columns = motion component.
pub const COEFFICIENT_NAMES: [&str; 8] = ["kxx", "kxy", "kyx", "kyy", "cxx", "cxy", "cyx", "cyy"];

/// Settings of the show.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ShowConfig {
    /// The identification's settings (default: the pipeline's).
    pub pipeline: PipelineConfig,
    /// Window (and hop) length of the identification in seconds, overriding
    /// `pipeline.estimator.window`/`hop`; trends need several windows. `None` keeps the
    /// pipeline's (one 10 s window for a 10 s record).
    pub window_s: Option<f64>,
    /// Time constants of the linear film's slowest mode discarded at the start of the
    /// simulation (10: the start-up error falls to 5e-5 of its size).
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
        Self {
            pipeline: PipelineConfig::default(),
            window_s: Some(1.0),
            settle_time_constants: 10.0,
            plot_seconds: 0.25,
            plot_points: 1500,
            spectrum_segment: 16_384,
            spectrum_max_hz: None,
            max_lines: 12,
        }
    }
}

impl ShowConfig {
    /// Checks every field; the error names it.
    pub fn validate(&self) -> Result<(), DiagnosisError> {
        if let Some(w) = self.window_s {
            if !(w.is_finite() && w > 0.0) {
                return Err(DiagnosisError::invalid("window_s", format!("must be finite and > 0, got {w}")));
            }
        }
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
    /// The simulation starts here (first valid sample), s.
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
}

/// An excerpt of the motion for plotting: measured and predicted, x and y, absolute (m).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TimeSeries {
    pub t_s: Vec<f64>,
    pub measured_x_m: Vec<f64>,
    pub measured_y_m: Vec<f64>,
    pub predicted_x_m: Vec<f64>,
    pub predicted_y_m: Vec<f64>,
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
    Harmonic { order: u32 },
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

/// The show of one record. `calibration` carries the record's schedule
/// ([`pipeline::calibration_for`]); `speed_rpm` the shaft speed and where it came from.
pub fn show(
    raw: &RawRecord,
    calibration: &Calibration,
    rig: &RigConfig,
    speed_rpm: f64,
    speed_source: SpeedSource,
    config: &ShowConfig,
) -> Result<Show, DiagnosisError> {
    config.validate()?;
    if !(speed_rpm.is_finite() && speed_rpm > 0.0) {
        return Err(DiagnosisError::invalid("speed_rpm", format!("must be finite and > 0, got {speed_rpm}")));
    }
    raw.validate_shape()?;
    let fs = raw.sample_rate_hz;
    let mut notes = Vec::new();

    // Identification, windows as configured.
    let mut pcfg = config.pipeline.clone();
    if let Some(w) = config.window_s {
        let n = ((w * fs).round() as usize).max(1);
        pcfg.estimator.window = n;
        pcfg.estimator.hop = n;
    }
    let identification = pipeline::identify(raw, calibration, rig, speed_rpm, speed_source, &pcfg)?;
    let mechanics = pipeline::mechanics_of(rig);
    // Wide band (the configured cutoff): motion and residual spectra, so that harmonics of the
    // excitation are not filtered away. Narrow band (the identification's adapted cutoff):
    // the baseline fit, free of the errors-in-variables bias of a wide band.
    let wide = conditioning::condition(raw, calibration, &mechanics, &pcfg.conditioning)?;
    let narrow = if identification.lowpass_cutoff_hz < pcfg.conditioning.lowpass_cutoff_hz {
        let mut c = pcfg.conditioning.clone();
        c.lowpass_cutoff_hz = identification.lowpass_cutoff_hz;
        Some(conditioning::condition(raw, calibration, &mechanics, &c)?)
    } else {
        None
    };
    let narrow_ref = narrow.as_ref().unwrap_or(&wide);
    if !wide.range_violations.is_empty() {
        notes.push(format!(
            "a probe left its linear range ({}): the identification refused the record; the motion comparison still runs but clipped samples disagree by construction",
            wide.range_violations.iter().map(ToString::to_string).collect::<Vec<_>>().join("; ")
        ));
    }
    // The simulation runs where both conditionings are free of edge effects.
    let valid = wide.valid.start.max(narrow_ref.valid.start)..wide.valid.end.min(narrow_ref.valid.end);
    if valid.len() < 64 {
        return Err(DiagnosisError::bad_input("record", format!("only {} samples survive the filters' edge trimming; at least 64 are needed", valid.len())));
    }

    // Applied forces: F_exc + (f3 - m g) e_y = F_film + m X'', in the wide band. (Not the
    // narrow one: its cutoff sits at 1.5x the top line, where the Butterworth's droop, which
    // cancels in the identification, would shrink the simulated motion by a few per cent.
    // The price: the force sensors' noise in the wide band drives the simulation too, about
    // 1 % NRMSE on the Zhou rig.)
    let m = rig.housing.mass_kg;
    let applied: [Vec<f64>; 2] = [
        wide.fx_n.iter().zip(&wide.housing_ax_m_s2).map(|(f, a)| f + m * a).collect(),
        wide.fy_n.iter().zip(&wide.housing_ay_m_s2).map(|(f, a)| f + m * a).collect(),
    ];
    let lines = strongest_lines(&pipeline::excitation_lines(raw)?, &applied[0][valid.clone()], &applied[1][valid.clone()], fs, config.max_lines);
    if lines.is_empty() {
        notes.push("no excitation line found in the applied forces: no line-by-line comparison".into());
    }

    let operating = measured_operating_point(&wide, rig, speed_rpm)?;
    let motion = motion_comparison(&wide, valid, &applied, rig, &operating, &lines, config, &mut notes)?;
    let coefficients = coefficient_comparison(&identification, rig, &mut notes)?;
    let trends = trends(&coefficients.windows, &mut notes);
    let residual = residual_spectra(&wide, narrow_ref, &pcfg, &lines, speed_rpm, config, &mut notes)?;

    Ok(Show {
        rig: rig.name.clone(),
        frame: pipeline::FRAME.to_string(),
        speed_rpm,
        speed_source,
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
    let mut scored: Vec<(f64, f64)> = lines
        .iter()
        .map(|&f| (f, w[0].line_power(f).unwrap_or(0.0) + w[1].line_power(f).unwrap_or(0.0)))
        .collect();
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

/// Simulates the rig driven by the measured forces and compares the motion.
#[allow(clippy::too_many_arguments)]
fn motion_comparison(
    c: &Conditioned,
    valid: std::ops::Range<usize>,
    applied: &[Vec<f64>; 2],
    rig: &RigConfig,
    op: &MeasuredOperatingPoint,
    lines: &[f64],
    config: &ShowConfig,
    notes: &mut Vec<String>,
) -> Result<MotionComparison, DiagnosisError> {
    let fs = 1.0 / (c.t_s[1] - c.t_s[0]);
    let mut cfg = rig.clone();
    cfg.effects = Effects::default();
    cfg.static_load.ripple_fraction = 0.0;
    cfg.operating.speed_rpm = op.speed_rpm;
    cfg.operating.bearing_temperature_c = op.temperature_c;
    if op.bellows_load_n.is_nan() || op.bellows_load_n <= 0.0 {
        return Err(DiagnosisError::bad_input(
            "f3",
            format!("the bellows carry {:.1} N, less than the housing's weight: the static load f3 - m g = {:.1} N must be positive", op.bellows_mean_n, op.bellows_load_n),
        ));
    }
    cfg.operating.bearing_load_n = op.bellows_load_n;
    let dir = |deg: f64| Vector2::new(deg.to_radians().cos(), deg.to_radians().sin());
    let d = Matrix2::from_columns(&[dir(rig.housing.exciter_angles_deg[0]), dir(rig.housing.exciter_angles_deg[1])]);
    // The rig file's validation keeps the two exciter axes independent (|sin| >= 0.1).
    let d_inv = d.try_inverse().ok_or_else(|| DiagnosisError::invalid("housing.exciter_angles_deg", "the exciter axes are parallel"))?;

    let start = valid.start;
    let mut sim = Rig::new(&cfg, c.t_s[start], 0.0)?;
    let eq = sim.operating_point().journal;
    let rate = stats::slowest_decay_rate(&sim.operating_point().coefficients.stiffness_n_m, &sim.operating_point().coefficients.damping_n_s_m, rig.housing.mass_kg);
    let n_valid = valid.len();
    let mut predicted = [vec![0.0; n_valid], vec![0.0; n_valid]];
    predicted[0][0] = eq.x_m;
    predicted[1][0] = eq.y_m;
    for (j, i) in (start + 1..valid.end).enumerate() {
        let net = d_inv * Vector2::new(applied[0][i], applied[1][i] - op.bellows_load_n);
        let sample = sim.step(&RigInput { exciter_n: [net.x, net.y] }, c.t_s[i]).map_err(|e| {
            DiagnosisError::bad_input("simulation", format!("the rig driven by the measured forces failed at t = {:.4} s: {e}", c.t_s[i]))
        })?;
        predicted[0][j + 1] = sample.relative_m.x;
        predicted[1][j + 1] = sample.relative_m.y;
    }

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
    let t0 = c.t_s[start + cmp.start];
    let t1 = c.t_s[start + n_valid - 1];

    let measured = [&c.x_m[valid.clone()], &c.y_m[valid.clone()]];
    let mut axes = Vec::new();
    for (a, name) in ["x", "y"].iter().enumerate() {
        let meas = &measured[a][cmp.clone()];
        let pred = &predicted[a][cmp.clone()];
        let (mm, pm) = (mean(meas), mean(pred));
        let err: Vec<f64> = meas.iter().zip(pred).map(|(u, v)| (v - pm) - (u - mm)).collect();
        let error_rms_m = (err.iter().map(|e| e * e).sum::<f64>() / err.len() as f64).sqrt();
        let measured_rms_m = rms_about_mean(meas);
        let line_cmp = lines
            .iter()
            .map(|&f| {
                let (am, phm) = phasor(meas, f, fs);
                let (ap, php) = phasor(pred, f, fs);
                LineComparison {
                    frequency_hz: f,
                    measured_amplitude_m: am,
                    predicted_amplitude_m: ap,
                    amplitude_ratio: ap / am,
                    measured_phase_deg: phm,
                    predicted_phase_deg: php,
                    phase_difference_deg: wrap_deg(php - phm),
                }
            })
            .collect();
        axes.push(AxisComparison {
            axis: name.to_string(),
            nrmse: error_rms_m / measured_rms_m,
            measured_rms_m,
            predicted_rms_m: rms_about_mean(pred),
            error_rms_m,
            measured_mean_m: mm,
            predicted_mean_m: pm,
            lines: line_cmp,
        });
    }

    // Time-series excerpt: the last `plot_seconds` of the compared span. `cmp` holds at least
    // half of the >= 64 valid samples, so the clamp's bounds are ordered.
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
    };

    // Spectra of the dynamic motion.
    let max_hz = spectrum_band_top(lines, op.speed_rpm, config, fs);
    let seg = segment_len(cmp.len(), config.spectrum_segment);
    let w = welch(&[&measured[0][cmp.clone()], &measured[1][cmp.clone()], &predicted[0][cmp.clone()], &predicted[1][cmp.clone()]], seg, fs);
    let bins = w[0].power.len().min(((max_hz / w[0].resolution_hz).floor() as usize) + 1);
    let amp = |s: &Welch| -> Vec<f64> { s.power[..bins.min(s.power.len())].iter().map(|p| (2.0 * p).sqrt()).collect() };
    let spectrum = MotionSpectrum {
        resolution_hz: w[0].resolution_hz,
        frequency_hz: (0..bins).map(|b| b as f64 * w[0].resolution_hz).collect(),
        measured_x_m: amp(&w[0]),
        measured_y_m: amp(&w[1]),
        predicted_x_m: amp(&w[2]),
        predicted_y_m: amp(&w[3]),
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
fn spectrum_band_top(lines: &[f64], speed_rpm: f64, config: &ShowConfig, fs: f64) -> f64 {
    let cutoff = config.pipeline.conditioning.lowpass_cutoff_hz;
    let top = config.spectrum_max_hz.unwrap_or_else(|| {
        let highest = lines.iter().copied().fold(speed_rpm / 60.0, f64::max);
        (3.5 * highest).max(20.0).min(cutoff)
    });
    top.min(0.5 * fs)
}

fn coefficient_comparison(
    id: &pipeline::Identification,
    rig: &RigConfig,
    notes: &mut Vec<String>,
) -> Result<CoefficientComparison, DiagnosisError> {
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
                            reason: format!("identified, but the film model has no equilibrium at this window's operating point ({:.0} N, {:.2} C): {e}", o.load_n, o.temperature_c),
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

#[allow(clippy::too_many_arguments)]
fn residual_spectra(
    wide: &Conditioned,
    narrow: &Conditioned,
    pcfg: &PipelineConfig,
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
    let mut est = pcfg.estimator.clone();
    est.model = estimator::ModelOrder::Kc;
    est.sample_rate_hz = fs;
    est.window = v.len();
    est.hop = v.len();
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
    let top = spectrum_band_top(lines, speed_rpm, config, fs);
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
    let in_band = |s: &Welch| -> f64 {
        s.power.iter().enumerate().filter(|(b, _)| (*b as f64 * df) >= band[0] && (*b as f64 * df) <= band[1]).map(|(_, p)| p).sum()
    };
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
