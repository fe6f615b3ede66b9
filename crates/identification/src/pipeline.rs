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

use crate::conditioning::{self, Conditioned, ConditioningConfig, Mechanics, RangeViolation};
use crate::error::IdentificationError;
use crate::estimator::{self, Coefficients, EstimatorConfig, FrequencyEstimate, Signals, WindowEstimate};
use crate::record::RawRecord;

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
    Mechanics { housing_mass_kg: rig.housing.mass_kg, exciter_angles_deg: rig.housing.exciter_angles_deg, gravity_m_s2: rig.housing.gravity_m_s2 }
}

/// The rig's calibration on the record's own schedule: the record's rate, channel order and
/// per-channel conversion offsets (`offsets_s[k]` for `raw.channels[k]`).
pub fn calibration_for(rig: &RigConfig, raw: &RawRecord, offsets_s: &[f64]) -> Result<Calibration, IdentificationError> {
    if offsets_s.len() != raw.channels.len() {
        return Err(IdentificationError::invalid("offsets_s", format!("{} offsets for {} channels", offsets_s.len(), raw.channels.len())));
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
            p >= LINE_FRACTION_OF_STRONGEST * strongest && p >= LINE_OVER_MEDIAN * median && p >= power[k - 1] && power.get(k + 1).is_none_or(|&q| p >= q)
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
        out.refusal = Some(format!("record refused (Zhou et al. step 2: a probe out of its linear range invalidates the file): {}", reasons.join("; ")));
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
    let amplitude = orbit_amplitude(&signals.x_m[range.clone()], &signals.y_m[range.clone()], [mx, my]);
    report_from(sums, amplitude, range.len(), estimate, temperature_c, rig, speed_rpm, times_s)
}

/// The largest distance of the orbit's samples from `centre`: `max_t hypot(x_t - cx, y_t - cy)`
/// (NaN samples ignored, as `f64::max` does), the same bits as that one `hypot` pass over every
/// sample. Squared distances (no `hypot`, a loop the compiler vectorises) find the samples
/// that can win: `hypot` is within an ulp of the true distance and the squared distance within
/// a few ulps of its square, so a sample whose `hypot` reaches the maximum has a squared
/// distance within a relative 1e-12 of the largest one; `hypot` is then taken of those only.
/// Where squares could under- or overflow (largest square not a normal number above 1e-280 and
/// finite) every sample goes through `hypot`.
pub fn orbit_amplitude(x: &[f64], y: &[f64], centre: [f64; 2]) -> f64 {
    struct K<'a>(&'a [f64], &'a [f64], [f64; 2]);
    impl crate::simd::Kernel for K<'_> {
        type Output = f64;
        #[inline(always)]
        fn run<S: crate::simd::Simd>(self, _: S) -> f64 {
            orbit_amplitude_kernel(self.0, self.1, self.2)
        }
    }
    crate::simd::dispatch(crate::simd::Isa::current(), K(x, y, centre))
}

#[inline(always)]
fn orbit_amplitude_kernel(x: &[f64], y: &[f64], centre: [f64; 2]) -> f64 {
    let [cx, cy] = centre;
    let n = x.len().min(y.len());
    let (x, y) = (&x[..n], &y[..n]);
    let d2 = |a: f64, b: f64| (a - cx) * (a - cx) + (b - cy) * (b - cy);
    // Eight partial maxima (a single running maximum is a chain the compiler cannot widen).
    let mut acc = [f64::NEG_INFINITY; 8];
    let (mut xc, mut yc) = (x.chunks_exact(8), y.chunks_exact(8));
    for (a, b) in (&mut xc).zip(&mut yc) {
        for l in 0..8 {
            let v = d2(a[l], b[l]);
            // NaN never wins (`f64::max`'s rule) and the comparison vectorises.
            acc[l] = if v > acc[l] { v } else { acc[l] };
        }
    }
    let mut top = acc.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    for (a, b) in xc.remainder().iter().zip(yc.remainder()) {
        top = top.max(d2(*a, *b));
    }
    let hypot = |(a, b): (&f64, &f64)| (a - cx).hypot(b - cy);
    if !(top.is_finite() && top > 1e-280) {
        return x.iter().zip(y).map(hypot).fold(0.0, f64::max);
    }
    let threshold = top * (1.0 - 1e-12);
    // NaN squares go through `hypot` too: `hypot(NaN, ±inf)` is `inf`.
    x.iter()
        .zip(y)
        .filter(|(a, b)| {
            let v = d2(**a, **b);
            v >= threshold || v.is_nan()
        })
        .map(hypot)
        .fold(0.0, f64::max)
}

/// [`window_report`] from a [`ReportFeed`] given every sample of the estimate's window and
/// that window's orbit `x`, `y` (the same samples): the same bits as [`window_report`] on those
/// samples (the sums were taken in sample order as they arrived; the amplitude needs the mean
/// position, known only now, and is one pass over the orbit, [`orbit_amplitude`]).
#[allow(clippy::too_many_arguments)] // the window's parts, as `window_report` plus the feed
pub fn window_report_fed(
    feed: ReportFeed,
    x: &[f64],
    y: &[f64],
    estimate: WindowEstimate,
    temperature_c: f64,
    rig: &RigConfig,
    speed_rpm: f64,
    times_s: [f64; 2],
) -> Result<WindowReport, IdentificationError> {
    let len = estimate.end.saturating_sub(estimate.start);
    if len == 0 || feed.n != len || x.len() != len || y.len() != len {
        return Err(IdentificationError::invalid(
            "estimate",
            format!(
                "window {}..{} is empty or not the {} samples the report was fed ({} x, {} y samples given)",
                estimate.start,
                estimate.end,
                feed.n,
                x.len(),
                y.len()
            ),
        ));
    }
    let [mx, my] = [feed.sums[0], feed.sums[1]].map(|s| s / len as f64);
    let amplitude = orbit_amplitude(x, y, [mx, my]);
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
/// arrive: the sums of x, y, fx and fy, in sample order, so the means are the same bits
/// however the samples were cut. (The amplitude needs the mean position first: it is one pass
/// over the window's orbit at the end, [`window_report_fed`].)
#[derive(Debug, Clone, Default)]
pub struct ReportFeed {
    n: usize,
    sums: [f64; 4],
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
        // The four columns in one loop: four independent chains of additions (each sum still
        // in sample order) instead of four chains one after the other.
        let mut s = self.sums;
        for (((a, b), c), d) in x[..n].iter().zip(&y[..n]).zip(&fx[..n]).zip(&fy[..n]) {
            s = [s[0] + a, s[1] + b, s[2] + c, s[3] + d];
        }
        self.sums = s;
        self.n += n;
    }
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

    /// The orbit's amplitude is the one-`hypot`-pass maximum bit for bit (random orbits, odd
    /// lengths, NaN samples, centres near and far, scales where the squares would underflow),
    /// and a feed cut into pieces gives the sums of one pass, bit for bit.
    #[test]
    fn amplitude_is_the_hypot_pass_and_a_feed_in_pieces_is_the_full_pass() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut unit = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for (case, scale) in [1e-5, 1.0, 1e3, 1e-150, 1e200].into_iter().cycle().take(40).enumerate() {
            let n = 1 + case * 137 % 5_003;
            let mut x: Vec<f64> = (0..n).map(|t| scale * ((t as f64 * 0.013).sin() + 0.01 * unit())).collect();
            let mut y: Vec<f64> = (0..n).map(|t| scale * ((t as f64 * 0.0371).cos() + 0.01 * unit())).collect();
            if case % 3 == 0 {
                x[case % n] = f64::NAN;
            }
            if case % 7 == 5 {
                // hypot(NaN, inf) is inf: such a sample wins.
                x[n / 2] = f64::NAN;
                y[n / 2] = f64::INFINITY;
            }
            if case % 4 == 1 && n > 2 {
                // Ties and near-ties: a sample mirrored through the centre.
                y[n - 1] = -y[0];
                x[n - 1] = -x[0];
            }
            for centre in [[0.0, 0.0], [scale * unit(), scale * unit()], [-scale * 3.0, scale * 0.5]] {
                let brute = x.iter().zip(&y).map(|(a, b)| (a - centre[0]).hypot(b - centre[1])).fold(0.0, f64::max);
                assert_eq!(orbit_amplitude(&x, &y, centre).to_bits(), brute.to_bits(), "case {case}, n {n}, centre {centre:?}");
            }
        }
        let n = 20_011;
        let x: Vec<f64> =
            (0..n).map(|t| 3e-6 * (t as f64 * 0.013).sin() + 1e-6 * (t as f64 * 0.0371).cos() - 2e-5 + 1e-9 * ((t * 7919) % 101) as f64).collect();
        let y: Vec<f64> = (0..n).map(|t| 4e-6 * (t as f64 * 0.0371).cos() + 2e-6 * (t as f64 * 0.013).sin() - 6e-5).collect();
        let fx: Vec<f64> = x.iter().map(|v| 150.0 - 1e8 * v).collect();
        let fy: Vec<f64> = y.iter().map(|v| 8000.0 - 2e8 * v).collect();
        let one_pass: Vec<f64> = [&x, &y, &fx, &fy].iter().map(|c| c.iter().fold(0.0, |a, v| a + v)).collect();
        for step in [n, 1_000, 777, 5] {
            let mut feed = ReportFeed::default();
            let mut i = 0;
            while i < n {
                let j = (i + step).min(n);
                feed.advance(&x[i..j], &y[i..j], &fx[i..j], &fy[i..j]);
                i = j;
            }
            assert_eq!(feed.samples(), n);
            assert_eq!(feed.sums.to_vec(), one_pass, "fed {step} at a time");
        }
    }
}
