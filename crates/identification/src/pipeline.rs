//! The identification pipeline: a raw record and its rig in, windowed coefficients out, each
//! window with the operating point it was measured at and its dimensionless coefficients.
//! The same path serves the CLI, the nodes and offline re-analysis.
//!
//! Steps: conditioning (Zhou et al. 2004, section 3.1 steps 1-7, [`crate::conditioning`]);
//! the paper's step 2 rule that a record whose probe left its linear range is invalid as a
//! whole; windowed least squares ([`crate::estimator`]) over the samples free of filter edge
//! effects; per window the measured operating point (static film load from eq. 2, bearing
//! temperature and the oil law's viscosity, speed), the Sommerfeld number, Zhou's load
//! parameter `F_Y`, the amplitude `d = max |r - mean r| / c`, Lund's and Zhou's
//! dimensionless coefficients; and the frequency-domain cross-check at the excitation lines.

use nalgebra::Matrix2;
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::{Calibration, ChannelId};
use oilfilm_physics::dimensionless::{self, DimensionlessCoefficients};
use oilfilm_physics::film::Running;
use serde::{Deserialize, Serialize};

use crate::conditioning::{self, Conditioned, ConditioningConfig, Mechanics, RangeViolation, RawRecord};
use crate::error::IdentificationError;
use crate::estimator::{self, Coefficients, EstimatorConfig, FrequencyEstimate, Signals, WindowEstimate};

/// The frame and sign convention every output states.
pub const FRAME: &str = "x horizontal, y vertical up, journal turning from +x to +y; r = journal centre relative to bearing centre; \
film force on the journal dF = -(K r + C r' + M r''); rows = force component, columns = motion component; SI units";

/// Settings of the whole pipeline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PipelineConfig {
    pub conditioning: ConditioningConfig,
    pub estimator: EstimatorConfig,
    /// Lower the low-pass cutoff to `ADAPTIVE_CUTOFF_FACTOR` times the highest strong
    /// excitation line found on a first pass (never above the configured cutoff, never below
    /// `MIN_ADAPTIVE_CUTOFF_HZ`). Differentiated sensor noise grows with the cube of the
    /// bandwidth and, in the regressors, biases every coefficient low (errors in variables):
    /// with the rig's 0.1 um probes and a 37 Hz two-tone, a 200 Hz band costs 20-50 %.
    pub adaptive_lowpass: bool,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self { conditioning: ConditioningConfig::default(), estimator: EstimatorConfig::default(), adaptive_lowpass: true }
    }
}

/// The adaptive cutoff is this multiple of the highest strong excitation line.
pub const ADAPTIVE_CUTOFF_FACTOR: f64 = 1.5;
/// Lines weaker than this fraction of the strongest line's displacement amplitude do not set
/// the band (harmonics of the film's nonlinearity, the bellows ripple).
pub const STRONG_LINE_FRACTION: f64 = 0.1;
/// The adaptive cutoff never goes below this, Hz.
pub const MIN_ADAPTIVE_CUTOFF_HZ: f64 = 10.0;

/// Where the speed of a record came from: the ten channels carry no tachometer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SpeedSource {
    /// Stated by the record (ASCII header `speed_rpm`, a bag's rig status).
    Record,
    /// Not stated: the rig file's operating speed was assumed.
    RigFile,
    /// Given by the user.
    User,
}

/// The operating point a window was measured at.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WindowOperatingPoint {
    pub speed_rpm: f64,
    /// Mean bearing temperature over the window, C.
    pub temperature_c: f64,
    /// The oil law's viscosity at that temperature, Pa s.
    pub viscosity_pa_s: f64,
    /// Static film force on the journal (eq. 2, mean over the window), N.
    pub static_force_n: [f64; 2],
    /// Its magnitude: the load the film carries, N.
    pub load_n: f64,
    pub sommerfeld: f64,
    /// Zhou's load parameter `F_Y = f_y psi^2 / (mu U L)`.
    pub load_parameter: f64,
    /// Mean journal position relative to the bearing, m.
    pub mean_position_m: [f64; 2],
    /// Excitation amplitude `d = max |r - mean r| / c` (Zhou et al., section 3.3).
    pub amplitude_d: f64,
}

/// One window's result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WindowReport {
    pub t_start_s: f64,
    pub t_end_s: f64,
    pub operating: WindowOperatingPoint,
    pub estimate: WindowEstimate,
    /// Lund's groups (`k c / W`, `b c omega / W`), crate frame, when the window was solved.
    pub lund: Option<DimensionlessCoefficients>,
    /// Zhou's groups (`k psi^3 / (mu omega L)`, `d psi^3 / (mu L)`), crate frame.
    pub zhou: Option<DimensionlessCoefficients>,
}

/// The identification of one record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Identification {
    pub rig: String,
    pub frame: String,
    pub speed_source: SpeedSource,
    /// Scans in the record and the range free of filter edge effects.
    pub samples: usize,
    pub valid: [usize; 2],
    /// Probes out of their linear range; non-empty means the record was refused (step 2).
    pub range_violations: Vec<RangeViolation>,
    /// Why the record as a whole gave no windows, if it did not.
    pub refusal: Option<String>,
    pub windows: Vec<WindowReport>,
    /// Frequency-domain estimate over the valid record at the lines the first window found.
    pub frequency_domain: Option<FrequencyEstimate>,
    /// Why there is no frequency-domain estimate, if there is none.
    pub frequency_domain_note: Option<String>,
    /// The low-pass cutoff the conditioning used, Hz (adapted to the excitation, see
    /// [`PipelineConfig::adaptive_lowpass`]).
    pub lowpass_cutoff_hz: f64,
}

impl Identification {
    /// Windows that were solved.
    pub fn accepted(&self) -> impl Iterator<Item = (&WindowReport, &Coefficients)> {
        self.windows.iter().filter_map(|w| w.estimate.result.as_ref().ok().map(|c| (w, c)))
    }

    /// Mean stiffness and damping over the solved windows, if any.
    pub fn mean_coefficients(&self) -> Option<(Matrix2<f64>, Matrix2<f64>)> {
        let mut n = 0.0;
        let (mut k, mut c) = (Matrix2::zeros(), Matrix2::zeros());
        for (_, co) in self.accepted() {
            k += co.stiffness_n_m;
            c += co.damping_n_s_m;
            n += 1.0;
        }
        (n > 0.0).then(|| (k / n, c / n))
    }
}

/// The mechanics eq. 2 needs, from a rig file.
pub fn mechanics_of(rig: &RigConfig) -> Mechanics {
    Mechanics {
        housing_mass_kg: rig.housing.mass_kg,
        exciter_angles_deg: rig.housing.exciter_angles_deg,
        gravity_m_s2: rig.housing.gravity_m_s2,
    }
}

/// The rig's calibration on the record's own schedule: the record's rate, channel order and
/// per-channel conversion offsets (`offsets_s[k]` for `raw.channels[k]`).
pub fn calibration_for(rig: &RigConfig, raw: &RawRecord, offsets_s: &[f64]) -> Result<Calibration, IdentificationError> {
    if offsets_s.len() != raw.channels.len() {
        return Err(IdentificationError::invalid(
            "offsets_s",
            format!("{} offsets for {} channels", offsets_s.len(), raw.channels.len()),
        ));
    }
    let schedule: Vec<(ChannelId, f64)> = raw.channels.iter().copied().zip(offsets_s.iter().copied()).collect();
    Ok(rig.daq.calibration().with_schedule(raw.sample_rate_hz, &schedule)?)
}

/// The rig DAQ's own schedule for a record in its scan order.
pub fn rig_offsets(rig: &RigConfig, raw: &RawRecord) -> Result<Vec<f64>, IdentificationError> {
    let cal = rig.daq.calibration();
    raw.channels.iter().map(|&c| cal.sample_offset_s(c).map_err(IdentificationError::from)).collect()
}

/// Identifies one record. `calibration` carries the record's schedule ([`calibration_for`]).
pub fn identify(
    raw: &RawRecord,
    calibration: &Calibration,
    rig: &RigConfig,
    speed_rpm: f64,
    speed_source: SpeedSource,
    config: &PipelineConfig,
) -> Result<Identification, IdentificationError> {
    if !(speed_rpm.is_finite() && speed_rpm > 0.0) {
        return Err(IdentificationError::invalid("speed_rpm", format!("must be finite and > 0, got {speed_rpm}")));
    }
    let conditioned = conditioning::condition(raw, calibration, &mechanics_of(rig), &config.conditioning)?;
    let first = identify_conditioned(&conditioned, rig, speed_rpm, speed_source, config)?;
    if !config.adaptive_lowpass {
        return Ok(first);
    }
    // The lines the estimator found in the motion; failing those (a multisine spreads its
    // power over many lines, none of which stands out of differentiated broadband noise at
    // the configured band), the lines of the measured exciter forces.
    let by_forces = || -> Result<Option<f64>, IdentificationError> {
        let lines = excitation_lines(raw)?;
        Ok(lines.last().map(|&top| (ADAPTIVE_CUTOFF_FACTOR * top).max(MIN_ADAPTIVE_CUTOFF_HZ)).filter(|&c| c < 0.9 * config.conditioning.lowpass_cutoff_hz))
    };
    let cutoff = match adapted_cutoff(&first, config.conditioning.lowpass_cutoff_hz) {
        Some(c) => Some(c),
        None if first.frequency_domain.is_none() => by_forces()?,
        None => None,
    };
    let Some(cutoff) = cutoff else {
        return Ok(first);
    };
    let mut adapted = config.clone();
    adapted.conditioning.lowpass_cutoff_hz = cutoff;
    let conditioned = conditioning::condition(raw, calibration, &mechanics_of(rig), &adapted.conditioning)?;
    identify_conditioned(&conditioned, rig, speed_rpm, speed_source, &adapted)
}

/// The cutoff the excitation found on a first pass calls for, when it is clearly below the
/// configured one: `ADAPTIVE_CUTOFF_FACTOR` x the highest line whose displacement amplitude
/// is at least `STRONG_LINE_FRACTION` of the strongest line's.
fn adapted_cutoff(first: &Identification, configured_hz: f64) -> Option<f64> {
    let lines = &first.frequency_domain.as_ref()?.lines;
    let amplitude = |l: &estimator::LinePhasors| (l.x_m.norm_sqr() + l.y_m.norm_sqr()).sqrt();
    let strongest = lines.iter().map(amplitude).fold(0.0, f64::max);
    if strongest.is_nan() || strongest <= 0.0 {
        return None;
    }
    let top = lines.iter().filter(|l| amplitude(l) >= STRONG_LINE_FRACTION * strongest).map(|l| l.frequency_hz).fold(0.0, f64::max);
    let cutoff = (ADAPTIVE_CUTOFF_FACTOR * top).max(MIN_ADAPTIVE_CUTOFF_HZ);
    (cutoff < 0.9 * configured_hz).then_some(cutoff)
}

/// A line of an exciter force counts when its power is within this factor of the strongest
/// line's and this factor above the median bin.
const LINE_FRACTION_OF_STRONGEST: f64 = 0.05;
const LINE_OVER_MEDIAN: f64 = 100.0;
/// Exciter-force samples kept for the line search (every k-th scan).
const LINE_SEARCH_RATE_HZ: f64 = 500.0;

/// The excitation lines of a record, Hz, from its measured exciter forces `f1`, `f2`: DFT
/// bins (resolution 1 / record length) up to 0.8 of the search rate's Nyquist frequency that
/// stand out of both the median bin and the strongest line's neighbourhood.
pub fn excitation_lines(raw: &RawRecord) -> Result<Vec<f64>, IdentificationError> {
    let stride = ((raw.sample_rate_hz / LINE_SEARCH_RATE_HZ).floor() as usize).max(1);
    let rate = raw.sample_rate_hz / stride as f64;
    let mut power: Vec<f64> = Vec::new();
    for ch in [ChannelId::F1, ChannelId::F2] {
        let Some(col) = raw.column(ch) else { continue };
        let v: Vec<f64> = col.iter().step_by(stride).copied().collect();
        let m = v.len();
        if m < 16 {
            return Ok(Vec::new());
        }
        let mean = v.iter().sum::<f64>() / m as f64;
        let bins = ((0.4 * m as f64).floor() as usize).max(1);
        power.resize(bins, 0.0);
        for (k, p) in power.iter_mut().enumerate().skip(1) {
            let w = 2.0 * std::f64::consts::PI * k as f64 / m as f64;
            // Goertzel: one recurrence per bin.
            let coeff = 2.0 * w.cos();
            let (mut s1, mut s2) = (0.0, 0.0);
            for &x in &v {
                let s0 = (x - mean) + coeff * s1 - s2;
                s2 = s1;
                s1 = s0;
            }
            *p += s1 * s1 + s2 * s2 - coeff * s1 * s2;
        }
    }
    if power.len() < 3 {
        return Ok(Vec::new());
    }
    let mut sorted = power[1..].to_vec();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let strongest = sorted[sorted.len() - 1];
    let m = power.len() as f64 / 0.4;
    let duration = m / rate;
    let lines: Vec<f64> = (1..power.len())
        .filter(|&k| {
            let p = power[k];
            p >= LINE_FRACTION_OF_STRONGEST * strongest
                && p >= LINE_OVER_MEDIAN * median
                && p >= power[k - 1]
                && power.get(k + 1).is_none_or(|&q| p >= q)
        })
        .map(|k| k as f64 / duration)
        .collect();
    Ok(lines)
}

/// Identifies an already conditioned record.
pub fn identify_conditioned(
    conditioned: &Conditioned,
    rig: &RigConfig,
    speed_rpm: f64,
    speed_source: SpeedSource,
    config: &PipelineConfig,
) -> Result<Identification, IdentificationError> {
    let valid = conditioned.valid.clone();
    let mut out = Identification {
        rig: rig.name.clone(),
        frame: FRAME.to_string(),
        speed_source,
        samples: conditioned.len(),
        valid: [valid.start, valid.end],
        range_violations: conditioned.range_violations.clone(),
        refusal: None,
        windows: Vec::new(),
        frequency_domain: None,
        frequency_domain_note: None,
        lowpass_cutoff_hz: config.conditioning.lowpass_cutoff_hz,
    };
    if !conditioned.range_violations.is_empty() {
        let reasons: Vec<String> = conditioned.range_violations.iter().map(ToString::to_string).collect();
        out.refusal = Some(format!(
            "record refused (Zhou et al. step 2: a probe out of its linear range invalidates the file): {}",
            reasons.join("; ")
        ));
        return Ok(out);
    }
    let mut est = config.estimator.clone();
    est.sample_rate_hz = 1.0 / median_step(&conditioned.t_s).unwrap_or(1.0 / est.sample_rate_hz);
    // Decimated standard errors (asked for by giving a band): the signals carry power up to
    // the low-pass cutoff used here, so the band is never taken below it.
    if let Some(band) = est.signal_band_hz {
        est.signal_band_hz = Some(band.max(config.conditioning.lowpass_cutoff_hz)).filter(|&b| b < est.sample_rate_hz / 2.0);
    }
    let n_valid = valid.len();
    if n_valid < est.model.min_samples() {
        out.refusal = Some(format!(
            "record too short: {n_valid} samples survive the filters' edge trimming, the {:?} model needs at least {}",
            est.model,
            est.model.min_samples()
        ));
        return Ok(out);
    }
    if est.window > n_valid {
        // A record shorter than the configured window is one window (the paper's practice:
        // one 50 000-sample record, one coefficient set).
        est.window = n_valid;
        est.hop = est.hop.min(n_valid).max(1);
    }
    let cut = |v: &[f64]| -> Vec<f64> { v[valid.clone()].to_vec() };
    let (x, y, vx, vy, ax, ay, fx, fy) = (
        cut(&conditioned.x_m),
        cut(&conditioned.y_m),
        cut(&conditioned.vx_m_s),
        cut(&conditioned.vy_m_s),
        cut(&conditioned.ax_m_s2),
        cut(&conditioned.ay_m_s2),
        cut(&conditioned.fx_n),
        cut(&conditioned.fy_n),
    );
    let signals = Signals { x_m: &x, y_m: &y, vx_m_s: &vx, vy_m_s: &vy, ax_m_s2: Some(&ax), ay_m_s2: Some(&ay), fx_n: &fx, fy_n: &fy };
    let estimates = estimator::estimate_windows(&signals, &est)?;
    for e in estimates {
        let range = e.start..e.end;
        let temperature = &conditioned.temperature_c[valid.start + range.start..valid.start + range.end];
        let temperature_c = temperature.iter().sum::<f64>() / range.len() as f64;
        let t_start_s = conditioned.t_s[valid.start + e.start];
        let t_end_s = conditioned.t_s[valid.start + e.end - 1];
        out.windows.push(window_report(&signals, e, temperature_c, rig, speed_rpm, [t_start_s, t_end_s])?);
    }
    // Frequency-domain cross-check at the lines the excitation put in the first window.
    match out.windows.first().map(|w| w.estimate.frequencies_hz.clone()) {
        Some(lines) if !lines.is_empty() => match estimator::frequency_domain(&signals, &lines, est.sample_rate_hz, est.model) {
            Ok(f) => out.frequency_domain = Some(f),
            Err(e) => out.frequency_domain_note = Some(format!("no frequency-domain estimate: {e}")),
        },
        _ => out.frequency_domain_note = Some("no excitation lines found: no frequency-domain estimate".into()),
    }
    Ok(out)
}

/// One window's report: its estimate with the operating point it was measured at (static
/// film force and mean position over the window, viscosity from `temperature_c` through the
/// rig's oil law, Sommerfeld number, `F_Y`, amplitude `d`) and, when solved, Lund's and
/// Zhou's groups. `signals` is the record the estimate's `start..end` indexes; `times_s` the
/// window's first and last sample times. The live estimator node and [`identify`] share it.
pub fn window_report(
    signals: &Signals,
    estimate: WindowEstimate,
    temperature_c: f64,
    rig: &RigConfig,
    speed_rpm: f64,
    times_s: [f64; 2],
) -> Result<WindowReport, IdentificationError> {
    let range = estimate.start..estimate.end;
    if range.is_empty() || range.end > signals.len() {
        return Err(IdentificationError::invalid(
            "estimate",
            format!("window {}..{} is empty or outside the record of {} samples", range.start, range.end, signals.len()),
        ));
    }
    let cut = |c: &[f64]| -> f64 { c[range.clone()].iter().fold(0.0, |a, v| a + v) };
    let sums = [cut(signals.x_m), cut(signals.y_m), cut(signals.fx_n), cut(signals.fy_n)];
    let [mx, my] = [sums[0], sums[1]].map(|s| s / range.len() as f64);
    let (x, y) = (&signals.x_m[range.clone()], &signals.y_m[range.clone()]);
    let amplitude = x.iter().zip(y).map(|(a, b)| (a - mx).hypot(b - my)).fold(0.0, f64::max);
    report_from(sums, amplitude, range.len(), estimate, temperature_c, rig, speed_rpm, times_s)
}

/// [`window_report`] from a [`ReportFeed`] given every sample of the estimate's window: the
/// same bits as [`window_report`] on those samples (the amplitude is the largest distance
/// from the mean position over the hull's vertices instead of every sample: the same sample
/// wins, unless one inside the hull by a relative 1e-12 came within an ulp of it).
pub fn window_report_fed(
    feed: ReportFeed,
    estimate: WindowEstimate,
    temperature_c: f64,
    rig: &RigConfig,
    speed_rpm: f64,
    times_s: [f64; 2],
) -> Result<WindowReport, IdentificationError> {
    let len = estimate.end.saturating_sub(estimate.start);
    if len == 0 || feed.n != len {
        return Err(IdentificationError::invalid(
            "estimate",
            format!("window {}..{} is empty or not the {} samples the report was fed", estimate.start, estimate.end, feed.n),
        ));
    }
    let [mx, my] = [feed.sums[0], feed.sums[1]].map(|s| s / len as f64);
    // The farthest sample from the mean position is a vertex of the orbit's convex hull.
    let amplitude = feed.hull.iter().map(|[a, b]| (a - mx).hypot(b - my)).fold(0.0, f64::max);
    report_from(feed.sums, amplitude, len, estimate, temperature_c, rig, speed_rpm, times_s)
}

/// The report from the window's sums of x, y, fx, fy (in sample order) and its amplitude.
#[allow(clippy::too_many_arguments)] // the window's parts
fn report_from(
    sums: [f64; 4],
    amplitude: f64,
    len: usize,
    estimate: WindowEstimate,
    temperature_c: f64,
    rig: &RigConfig,
    speed_rpm: f64,
    times_s: [f64; 2],
) -> Result<WindowReport, IdentificationError> {
    let geometry = rig.bearing;
    let [mx, my, mfx, mfy] = sums.map(|s| s / len as f64);
    let static_force_n = [mfx, mfy];
    let load_n = static_force_n[0].hypot(static_force_n[1]);
    let viscosity_pa_s = rig.oil.viscosity_pa_s(temperature_c)?;
    let running = Running::from_rpm(speed_rpm, viscosity_pa_s);
    let (lund, zhou) = match &estimate.result {
        Ok(c) if load_n > 0.0 => (
            Some(dimensionless::lund(&c.stiffness_n_m, &c.damping_n_s_m, &geometry, &running, load_n)),
            Some(dimensionless::zhou(&c.stiffness_n_m, &c.damping_n_s_m, &geometry, &running)),
        ),
        _ => (None, None),
    };
    Ok(WindowReport {
        t_start_s: times_s[0],
        t_end_s: times_s[1],
        operating: WindowOperatingPoint {
            speed_rpm,
            temperature_c,
            viscosity_pa_s,
            static_force_n,
            load_n,
            sommerfeld: if load_n > 0.0 { dimensionless::sommerfeld(&geometry, &running, load_n) } else { f64::INFINITY },
            load_parameter: dimensionless::zhou_load_parameter(&geometry, &running, load_n),
            mean_position_m: [mx, my],
            amplitude_d: amplitude / geometry.clearance_m,
        },
        estimate,
        lund,
        zhou,
    })
}

/// What the window report needs from every sample of a window, gathered as the samples
/// arrive: the sums of x, y, fx and fy (in sample order, so the means are the same bits
/// however the samples were cut) and the convex hull of the (x, y) orbit, which holds the
/// sample farthest from any centre (the mean position is known only at the end). A sample is
/// dropped from the hull only when it lies inside it by more than a relative 1e-12, so
/// round-off in the orientation test never drops a vertex.
#[derive(Debug, Clone, Default)]
pub struct ReportFeed {
    n: usize,
    sums: [f64; 4],
    hull: Vec<[f64; 2]>,
}

impl ReportFeed {
    /// Samples taken so far.
    pub fn samples(&self) -> usize {
        self.n
    }

    /// Take the next samples of the window (the shortest column counts).
    pub fn advance(&mut self, x: &[f64], y: &[f64], fx: &[f64], fy: &[f64]) {
        let n = x.len().min(y.len()).min(fx.len()).min(fy.len());
        if n == 0 {
            return;
        }
        for (s, c) in self.sums.iter_mut().zip([x, y, fx, fy]) {
            *s = c[..n].iter().fold(*s, |a, v| a + v);
        }
        self.n += n;
        // The new samples' own hull first (most of them go), then the union with the old one.
        let mut pts = convex_hull(x[..n].iter().zip(&y[..n]).map(|(a, b)| [*a, *b]).collect());
        pts.append(&mut self.hull);
        self.hull = convex_hull(pts);
    }
}

/// The vertices of the convex hull of `pts` (Andrew's monotone chain), keeping every point not
/// clearly inside (collinear and nearly collinear points stay; exact duplicates go; NaN
/// points go, as the amplitude's `f64::max` ignores them; infinite ones stay).
fn convex_hull(mut pts: Vec<[f64; 2]>) -> Vec<[f64; 2]> {
    pts.retain(|p| !(p[0].is_nan() || p[1].is_nan()));
    pts.sort_unstable_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    // Turn o -> a -> b clearly clockwise (a clearly inside the chain).
    let inside = |o: &[f64; 2], a: &[f64; 2], b: &[f64; 2]| {
        let (ux, uy, vx, vy) = (a[0] - o[0], a[1] - o[1], b[0] - o[0], b[1] - o[1]);
        let cross = ux * vy - uy * vx;
        cross < 0.0 && cross * cross > 1e-24 * (ux * ux + uy * uy) * (vx * vx + vy * vy)
    };
    let chain = |iter: &mut dyn Iterator<Item = [f64; 2]>| {
        let mut h: Vec<[f64; 2]> = Vec::new();
        for p in iter {
            while h.len() >= 2 && inside(&h[h.len() - 2], &h[h.len() - 1], &p) {
                h.pop();
            }
            h.push(p);
        }
        h
    };
    let lower = chain(&mut pts.iter().copied());
    let upper = chain(&mut pts.iter().rev().copied());
    let mut out = lower;
    out.extend(upper);
    out.sort_unstable_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    out.dedup();
    out
}

/// Median time step of a sampled time base.
fn median_step(t: &[f64]) -> Option<f64> {
    if t.len() < 2 {
        return None;
    }
    let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    d.sort_by(f64::total_cmp);
    let m = d[d.len() / 2];
    (m.is_finite() && m > 0.0).then_some(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The hull keeps the farthest sample from any centre, and a feed cut into pieces gives the
    /// sums and amplitude of one pass, bit for bit.
    #[test]
    fn report_feed_in_pieces_is_the_full_pass() {
        let n = 20_011;
        let x: Vec<f64> = (0..n).map(|t| 3e-6 * (t as f64 * 0.013).sin() + 1e-6 * (t as f64 * 0.0371).cos() - 2e-5 + 1e-9 * ((t * 7919) % 101) as f64).collect();
        let y: Vec<f64> = (0..n).map(|t| 4e-6 * (t as f64 * 0.0371).cos() + 2e-6 * (t as f64 * 0.013).sin() - 6e-5).collect();
        let fx: Vec<f64> = x.iter().map(|v| 150.0 - 1e8 * v).collect();
        let fy: Vec<f64> = y.iter().map(|v| 8000.0 - 2e8 * v).collect();
        let mut whole = ReportFeed::default();
        whole.advance(&x, &y, &fx, &fy);
        assert!(whole.hull.len() < n / 10, "hull of {} points", whole.hull.len());
        for c in [[0.0, 0.0], [-2e-5, -6e-5], [-2.3e-5, -5.7e-5], [1.0, -1.0]] {
            let brute = x.iter().zip(&y).map(|(a, b)| (a - c[0]).hypot(b - c[1])).fold(0.0, f64::max);
            let hull = whole.hull.iter().map(|[a, b]| (a - c[0]).hypot(b - c[1])).fold(0.0, f64::max);
            assert_eq!(hull, brute, "centre {c:?}");
        }
        for step in [1_000, 777, 5] {
            let mut feed = ReportFeed::default();
            let mut i = 0;
            while i < n {
                let j = (i + step).min(n);
                feed.advance(&x[i..j], &y[i..j], &fx[i..j], &fy[i..j]);
                i = j;
            }
            assert_eq!(feed.samples(), n);
            assert_eq!(feed.sums, whole.sums, "fed {step} at a time");
            let amp = |f: &ReportFeed| f.hull.iter().map(|[a, b]| (a - -2e-5f64).hypot(b - -6e-5)).fold(0.0, f64::max);
            assert_eq!(amp(&feed), amp(&whole), "fed {step} at a time");
        }
    }
}
