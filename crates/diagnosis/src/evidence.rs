//! The record made ready for judging models. It is conditioned **once**, by the
//! identification's chain at the configured (wide) band; everything else is derived from
//! that one conditioning:
//!
//! * the **judging band**: every conditioned column post-filtered by the same zero-phase
//!   Butterworth to [`WIDE_BAND_FACTOR`] times the highest excitation line (the pipeline's own
//!   band rule) when the probes' noise allows, else to [`NARROW_BAND_FACTOR`] times it
//!   (differentiated probe noise grows with the cube of the band and, in the regressors,
//!   biases every fitted coefficient low; see [`velocity_noise_ratio`]). Filtering the
//!   conditioned columns is the same as conditioning with the two filters in cascade: every
//!   stage of the chain is linear and time-invariant, so they commute;
//! * the windowed **identification** of the record in that band (the report's per-window
//!   coefficients and trends);
//! * the **decimated series** the models are judged on: the judging band's columns at a rate
//!   of [`DECIMATED_RATE_OVER_CUTOFF`] times its cutoff (so the residual's samples are close to
//!   independent), cut into contiguous time blocks for cross-validation and detrended block
//!   by block.
//!
//! ## What every model predicts
//! * the eq. 2 film force `f_x`, `f_y` (the **force rows**; models are fitted to them);
//! * the redundant sensors' agreement (the **sensor rows**), expressed as the force the film's
//!   stiffness would need for it (`k_bar` times a displacement, `k_bar` the mean direct
//!   stiffness of a whole-record fit): the two bearing ends (`tilt = end A - end B`) and the
//!   journal (`J = r + X`, bearing probes plus frame probes: zero for a journal fixed in
//!   space). No film model predicts anything but zero here; a delayed, clipped or
//!   mis-calibrated probe, or runout, shows itself in these rows, where the linear fit cannot
//!   absorb it into its coefficients.
//!
//! Held-out errors are normalised by the RMS of the dynamic film force.
//!
//! ## Blocks and detrending
//! Each block's slow trend (mean and slope) is removed from every column and target: static
//! load, equilibrium drift with temperature and the bellows are not what is judged, and the
//! same preprocessing is applied to every model alike.

use std::ops::Range;

use nalgebra::{DMatrix, DVector};
use oilfilm_identification::conditioning::lowpass::Butterworth;
use oilfilm_identification::conditioning::{self, Conditioned, ConditioningConfig, Mechanics};
use oilfilm_identification::pipeline::{self, Identification, PipelineConfig, SpeedSource};
use oilfilm_identification::record::RawRecord;
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::Calibration;

use crate::DiagnosisError;

/// The decimated rate is at least this multiple of the judging band's cutoff.
pub const DECIMATED_RATE_OVER_CUTOFF: f64 = 2.5;
/// Full-rate samples kept inside the judging band's valid range at each end, so a channel
/// shifted by up to [`crate::catalog::MAX_DELAY_S`] (plus its interpolator) stays defined on the
/// very same samples.
pub const EDGE_MARGIN: usize = 64;

/// The signals a model is judged on, at the decimated samples, not detrended.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Series {
    pub t_s: Vec<f64>,
    pub x_m: Vec<f64>,
    pub y_m: Vec<f64>,
    pub vx_m_s: Vec<f64>,
    pub vy_m_s: Vec<f64>,
    pub ax_m_s2: Vec<f64>,
    pub ay_m_s2: Vec<f64>,
    /// Housing absolute displacement (frame probes).
    pub housing_x_m: Vec<f64>,
    pub housing_y_m: Vec<f64>,
    /// Housing absolute acceleration (what eq. 2 multiplies by the housing mass).
    pub housing_ax_m_s2: Vec<f64>,
    pub housing_ay_m_s2: Vec<f64>,
    pub fx_n: Vec<f64>,
    pub fy_n: Vec<f64>,
    pub tilt_x_m: Vec<f64>,
    pub tilt_y_m: Vec<f64>,
    pub temperature_c: Vec<f64>,
}

impl Series {
    /// The samples `picks` (full-rate indices) of a conditioned record.
    pub fn from_conditioned(c: &Conditioned, picks: &[usize]) -> Self {
        let take = |v: &[f64]| picks.iter().map(|&i| v[i]).collect::<Vec<_>>();
        Self {
            t_s: take(&c.t_s),
            x_m: take(&c.x_m),
            y_m: take(&c.y_m),
            vx_m_s: take(&c.vx_m_s),
            vy_m_s: take(&c.vy_m_s),
            ax_m_s2: take(&c.ax_m_s2),
            ay_m_s2: take(&c.ay_m_s2),
            housing_x_m: take(&c.housing_x_m),
            housing_y_m: take(&c.housing_y_m),
            housing_ax_m_s2: take(&c.housing_ax_m_s2),
            housing_ay_m_s2: take(&c.housing_ay_m_s2),
            fx_n: take(&c.fx_n),
            fy_n: take(&c.fy_n),
            tilt_x_m: take(&c.tilt_x_m),
            tilt_y_m: take(&c.tilt_y_m),
            temperature_c: take(&c.temperature_c),
        }
    }

    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// The fields that move with the record's channels, in a fixed order (time and
    /// temperature excluded).
    pub fn fields_mut(&mut self) -> [&mut Vec<f64>; 14] {
        [
            &mut self.x_m,
            &mut self.y_m,
            &mut self.vx_m_s,
            &mut self.vy_m_s,
            &mut self.ax_m_s2,
            &mut self.ay_m_s2,
            &mut self.housing_x_m,
            &mut self.housing_y_m,
            &mut self.housing_ax_m_s2,
            &mut self.housing_ay_m_s2,
            &mut self.fx_n,
            &mut self.fy_n,
            &mut self.tilt_x_m,
            &mut self.tilt_y_m,
        ]
    }

    pub fn fields(&self) -> [&Vec<f64>; 14] {
        [
            &self.x_m,
            &self.y_m,
            &self.vx_m_s,
            &self.vy_m_s,
            &self.ax_m_s2,
            &self.ay_m_s2,
            &self.housing_x_m,
            &self.housing_y_m,
            &self.housing_ax_m_s2,
            &self.housing_ay_m_s2,
            &self.fx_n,
            &self.fy_n,
            &self.tilt_x_m,
            &self.tilt_y_m,
        ]
    }

    /// `self + s * d` field by field (time and temperature from `self`).
    pub fn plus(&self, d: &Series, s: f64) -> Series {
        let mut out = self.clone();
        for (o, df) in out.fields_mut().into_iter().zip(d.fields()) {
            for (v, &dv) in o.iter_mut().zip(df.iter()) {
                *v += s * dv;
            }
        }
        out
    }

    /// The journal's absolute displacement `J = r + X` (bearing plus frame probes), x then y.
    pub fn journal_m(&self) -> [Vec<f64>; 2] {
        [self.x_m.iter().zip(&self.housing_x_m).map(|(a, b)| a + b).collect(), self.y_m.iter().zip(&self.housing_y_m).map(|(a, b)| a + b).collect()]
    }
}

/// A record ready for diagnosis.
#[derive(Debug, Clone)]
pub struct Prepared {
    pub raw: RawRecord,
    pub calibration: Calibration,
    pub mechanics: Mechanics,
    /// The record's one conditioning, at the configured band (the report's spectra and its
    /// simulation use it: harmonics of the excitation are still in it).
    pub wide: Conditioned,
    pub wide_config: ConditioningConfig,
    /// The same columns post-filtered to the judging band (its `valid` range excludes the
    /// post-filter's settling at both ends).
    pub narrow: Conditioned,
    /// The post-filter, `None` when the configured band is already narrow enough.
    pub band: Option<Butterworth>,
    /// The judging band's cutoff, Hz, and the velocity noise over the wide band that chose it
    /// (RMS relative to the excited velocity; `None` when it could not be estimated).
    pub cutoff_hz: f64,
    pub velocity_noise_ratio: Option<f64>,
    /// The pipeline's windowed identification of the judging band.
    pub identification: Identification,
    /// Full-rate indices of the decimated samples.
    pub picks: Vec<usize>,
    pub decimation: usize,
    /// Rate of the decimated samples, Hz.
    pub rate_hz: f64,
    /// Cross-validation blocks, ranges of decimated samples.
    pub blocks: Vec<Range<usize>>,
    /// The record's decimated signals.
    pub series: Series,
    pub speed_rpm: f64,
    /// Excitation lines found in the measured exciter forces, Hz.
    pub lines_hz: Vec<f64>,
    /// Weight turning a sensor disagreement into force, N/m (mean direct stiffness of the
    /// whole-record linear fit).
    pub sensor_weight_n_m: f64,
    /// RMS of the detrended dynamic film force over all blocks, N (the NRMSE's norm).
    pub force_rms_n: f64,
    /// Mean bearing temperature over the record, C.
    pub mean_temperature_c: f64,
    /// Static film force on the journal (eq. 2 mean), N.
    pub static_force_n: [f64; 2],
    /// What the preparation noticed (refused windows, range violations).
    pub notes: Vec<String>,
}

/// Settings of a diagnosis's preparation.
#[derive(Debug, Clone, PartialEq)]
pub struct PrepareOptions {
    pub pipeline: PipelineConfig,
    /// Cross-validation blocks (contiguous in time).
    pub folds: usize,
    /// A record shorter than this (after the filters' edges) is too short to judge, s.
    pub min_seconds: f64,
}

impl Default for PrepareOptions {
    fn default() -> Self {
        let mut pipeline = PipelineConfig::default();
        // 1 s windows at 5 kHz: the per-window trends of the report need several windows in a
        // 10 s record.
        pipeline.estimator.window = 5_000;
        pipeline.estimator.hop = 5_000;
        Self { pipeline, folds: 10, min_seconds: 2.0 }
    }
}

impl PrepareOptions {
    /// The identification's windows as long as the pipeline's own (one window for a record of
    /// that length or shorter): no per-window trends.
    pub fn prepare_whole_windows(&mut self) {
        let d = PipelineConfig::default();
        self.pipeline.estimator.window = d.estimator.window;
        self.pipeline.estimator.hop = d.estimator.hop;
    }
}

/// Why a record cannot be judged at all, as the `insufficient_data` verdict's reason.
#[derive(Debug, Clone, PartialEq)]
pub struct Insufficient(pub String);

/// The judging band reaches this multiple of the highest excitation line when the probes'
/// noise allows (the identification pipeline's own band), else [`NARROW_BAND_FACTOR`].
pub const WIDE_BAND_FACTOR: f64 = pipeline::ADAPTIVE_CUTOFF_FACTOR;
pub const NARROW_BAND_FACTOR: f64 = 1.05;
/// The wide band is used when the velocity's noise over it stays below this fraction of the
/// excited velocity (RMS): differentiated probe noise grows with the cube of the band and, in
/// the regressors, biases every fitted coefficient low and floods the residual; a wider band
/// keeps what friction and the film's nonlinearity put above the top line.
pub const MAX_VELOCITY_NOISE: f64 = 0.03;

/// The velocity's noise over `[0, band_hz]` relative to its excited part, from the spectrum of
/// the conditioned velocity between the top line and the configured cutoff (where nothing is
/// excited): differentiated white probe noise has a power density rising as `f^2`, whose
/// level the median bin there gives (the median, so that harmonics of the motion do not count).
pub fn velocity_noise_ratio(c: &Conditioned, top_hz: f64, band_hz: f64, configured_hz: f64, sample_rate_hz: f64) -> Option<f64> {
    let v = c.valid.clone();
    let n = v.len();
    if n < 256 {
        return None;
    }
    let (lo, hi) = (1.15 * top_hz, (1.45 * top_hz).min(0.9 * configured_hz));
    if hi <= lo {
        return None;
    }
    let mut planner = rustfft::FftPlanner::new();
    let fft = planner.plan_fft_forward(n);
    let df = sample_rate_hz / n as f64;
    let (mut noise_density, mut excited) = (Vec::new(), 0.0);
    for col in [&c.vx_m_s, &c.vy_m_s] {
        let mean = col[v.clone()].iter().sum::<f64>() / n as f64;
        let mut buf: Vec<rustfft::num_complex::Complex<f64>> = col[v.clone()].iter().map(|x| rustfft::num_complex::Complex::new(x - mean, 0.0)).collect();
        fft.process(&mut buf);
        // One-sided power per bin (sums to the signal's variance).
        let power = |k: usize| 2.0 * buf[k].norm_sqr() / (n as f64 * n as f64);
        for k in 1..n / 2 {
            let f = k as f64 * df;
            if f >= lo && f <= hi {
                noise_density.push(power(k) / (f * f));
            } else if f <= NARROW_BAND_FACTOR * top_hz {
                excited += power(k);
            }
        }
    }
    if noise_density.is_empty() || excited <= 0.0 {
        return None;
    }
    noise_density.sort_by(f64::total_cmp);
    let a = noise_density[noise_density.len() / 2] / df;
    // Both axes' noise over [0, band]: a band^3 / 3; the excited part less its own noise.
    let noise = a * band_hz.powi(3) / 3.0;
    let signal = (excited - a * (NARROW_BAND_FACTOR * top_hz).powi(3) / 3.0).max(f64::MIN_POSITIVE);
    Some((noise / signal).sqrt())
}

/// The judging band's cutoff for a record whose highest excitation line is `top_hz`, and
/// its post-filter (`None`: the configured band is already at most that).
pub fn judging_band(
    top_hz: Option<f64>,
    factor: f64,
    configured_hz: f64,
    order: usize,
    sample_rate_hz: f64,
) -> Result<(f64, Option<Butterworth>), DiagnosisError> {
    let Some(top) = top_hz else {
        return Ok((configured_hz, None));
    };
    let cutoff = (factor * top).max(pipeline::MIN_ADAPTIVE_CUTOFF_HZ);
    if cutoff >= 0.9 * configured_hz {
        return Ok((configured_hz, None));
    }
    Ok((cutoff, Some(Butterworth::design(order, cutoff, sample_rate_hz)?)))
}

/// `c`'s columns through `band` over `c.valid`, the valid range shrunk by its settling.
pub fn post_filter(c: &Conditioned, band: Option<&Butterworth>) -> Result<Conditioned, DiagnosisError> {
    let Some(band) = band else {
        return Ok(c.clone());
    };
    let v = c.valid.clone();
    let settle = band.settling_samples();
    if v.len() <= 2 * settle + 2 {
        return Err(DiagnosisError::bad_input("record", format!("{} valid samples cannot hold the judging band's settling ({settle} at each end)", v.len())));
    }
    let mut out = c.clone();
    let mut columns: Vec<Vec<f64>> = [
        &c.x_m,
        &c.y_m,
        &c.vx_m_s,
        &c.vy_m_s,
        &c.ax_m_s2,
        &c.ay_m_s2,
        &c.housing_x_m,
        &c.housing_y_m,
        &c.housing_ax_m_s2,
        &c.housing_ay_m_s2,
        &c.fx_n,
        &c.fy_n,
        &c.tilt_x_m,
        &c.tilt_y_m,
        &c.static_load_n,
    ]
    .iter()
    .map(|col| col[v.clone()].to_vec())
    .collect();
    let mut scratch = Vec::new();
    band.filtfilt_many_in_place(&mut columns, &mut scratch)?;
    for (dst, src) in [
        &mut out.x_m,
        &mut out.y_m,
        &mut out.vx_m_s,
        &mut out.vy_m_s,
        &mut out.ax_m_s2,
        &mut out.ay_m_s2,
        &mut out.housing_x_m,
        &mut out.housing_y_m,
        &mut out.housing_ax_m_s2,
        &mut out.housing_ay_m_s2,
        &mut out.fx_n,
        &mut out.fy_n,
        &mut out.tilt_x_m,
        &mut out.tilt_y_m,
        &mut out.static_load_n,
    ]
    .into_iter()
    .zip(columns)
    {
        dst[v.clone()].copy_from_slice(&src);
    }
    out.valid = v.start + settle..v.end - settle;
    Ok(out)
}

/// Conditions (once), identifies and decimates a record. `Ok(Err(Insufficient))` when the
/// record is too short or too poorly excited to judge any model; `Err` for unusable input.
pub fn prepare(
    raw: &RawRecord,
    calibration: &Calibration,
    rig: &RigConfig,
    speed_rpm: f64,
    speed_source: SpeedSource,
    options: &PrepareOptions,
) -> Result<Result<Prepared, Insufficient>, DiagnosisError> {
    if options.folds < 3 {
        return Err(DiagnosisError::invalid("folds", format!("must be at least 3, got {}", options.folds)));
    }
    if !(speed_rpm.is_finite() && speed_rpm > 0.0) {
        return Err(DiagnosisError::invalid("speed_rpm", format!("must be finite and > 0, got {speed_rpm}")));
    }
    raw.validate_shape()?;
    let mechanics = pipeline::mechanics_of(rig);
    let wide_config = options.pipeline.conditioning.clone();
    let wide = conditioning::condition(raw, calibration, &mechanics, &wide_config)?;
    let lines_hz = pipeline::excitation_lines(raw)?;
    let top = lines_hz.last().copied();
    let noise = top.and_then(|t| velocity_noise_ratio(&wide, t, WIDE_BAND_FACTOR * t, wide_config.lowpass_cutoff_hz, raw.sample_rate_hz));
    let factor = if noise.is_some_and(|r| r <= MAX_VELOCITY_NOISE) { WIDE_BAND_FACTOR } else { NARROW_BAND_FACTOR };
    let (cutoff_hz, band) = judging_band(top, factor, wide_config.lowpass_cutoff_hz, wide_config.lowpass_order, raw.sample_rate_hz)?;
    let narrow = if wide.range_violations.is_empty() { post_filter(&wide, band.as_ref())? } else { wide.clone() };
    let mut config = options.pipeline.clone();
    config.estimator.sample_rate_hz = raw.sample_rate_hz;
    config.conditioning.lowpass_cutoff_hz = cutoff_hz;
    let identification = pipeline::identify_conditioned(&narrow, rig, speed_rpm, speed_source, &config)?;

    let valid = narrow.valid.clone();
    let usable = valid.len().saturating_sub(2 * EDGE_MARGIN);
    let seconds = usable as f64 / raw.sample_rate_hz;
    if seconds < options.min_seconds {
        return Ok(Err(Insufficient(format!(
            "too short: {seconds:.2} s survive the filters' edges, at least {:.1} s are needed to hold some of it out",
            options.min_seconds
        ))));
    }
    if lines_hz.len() < 2 {
        return Ok(Err(Insufficient(format!(
            "too poorly excited: the exciter forces hold {} line(s) ({:?} Hz); at one frequency x, y, x', y' all lie in span{{cos, sin}} (rank 2 of 4) and stiffness, damping and any added mass alias: excite two frequencies or a band (multisine)",
            lines_hz.len(),
            lines_hz
        ))));
    }
    let mut notes = Vec::new();
    if !narrow.range_violations.is_empty() {
        notes.push(format!(
            "a probe left its linear range ({}): the identification refused the record; the diagnosis judges it as it is",
            narrow.range_violations.iter().map(ToString::to_string).collect::<Vec<_>>().join("; ")
        ));
    } else if identification.accepted().count() == 0 {
        let why = identification
            .refusal
            .clone()
            .or_else(|| identification.windows.iter().find_map(|w| w.estimate.result.as_ref().err().map(|r| r.to_string())))
            .unwrap_or_else(|| "no window could be identified".into());
        notes.push(format!("the windowed identification refused every window ({why}); the diagnosis fits the whole record"));
    }
    let decimation = ((raw.sample_rate_hz / (DECIMATED_RATE_OVER_CUTOFF * cutoff_hz)).floor() as usize).max(1);
    let picks: Vec<usize> = (valid.start + EDGE_MARGIN..valid.end - EDGE_MARGIN).step_by(decimation).collect();
    let n = picks.len();
    let per = n / options.folds;
    if per < 20 {
        return Ok(Err(Insufficient(format!("too short: {n} decimated samples for {} blocks", options.folds))));
    }
    let blocks: Vec<Range<usize>> = (0..options.folds).map(|b| b * per..if b + 1 == options.folds { n } else { (b + 1) * per }).collect();
    let series = Series::from_conditioned(&narrow, &picks);
    let mean_temperature_c = series.temperature_c.iter().sum::<f64>() / n as f64;
    let static_force_n = narrow.static_force_n;
    let mut prepared = Prepared {
        raw: raw.clone(),
        calibration: calibration.clone(),
        mechanics,
        wide,
        wide_config,
        narrow,
        band,
        cutoff_hz,
        velocity_noise_ratio: noise,
        identification,
        picks,
        decimation,
        rate_hz: raw.sample_rate_hz / decimation as f64,
        blocks,
        series,
        speed_rpm,
        lines_hz,
        sensor_weight_n_m: 0.0,
        force_rms_n: 0.0,
        mean_temperature_c,
        static_force_n,
        notes,
    };
    let target = prepared.force_target(&prepared.series);
    prepared.force_rms_n = (target.norm_squared() / (2 * n) as f64).sqrt();
    if !(prepared.force_rms_n.is_finite() && prepared.force_rms_n > 0.0) {
        return Ok(Err(Insufficient("no dynamic film force: the exciters did not move the housing".into())));
    }
    // k_bar from a whole-record K-C fit (the weight only scales the sensor rows alike for all
    // models; it is not a fitted parameter of any of them).
    let design = prepared.kc_design(&prepared.series, 0);
    let fit = match crate::least_squares::solve(&design, &target, &vec![true; design.nrows()], "linear K-C (whole record)") {
        Ok(f) => f,
        Err(e) => return Ok(Err(Insufficient(format!("too poorly excited: the linear model itself cannot be fitted ({e})")))),
    };
    prepared.sensor_weight_n_m = 0.5 * (fit.theta[0].abs() + fit.theta[5].abs());
    Ok(Ok(prepared))
}

impl Prepared {
    /// Decimated samples.
    pub fn len(&self) -> usize {
        self.picks.len()
    }

    pub fn is_empty(&self) -> bool {
        self.picks.is_empty()
    }

    /// Removes each block's mean and slope from `v` (one value per decimated sample).
    pub fn detrend(&self, v: &mut [f64]) {
        for b in &self.blocks {
            let seg = &mut v[b.clone()];
            let m = seg.len() as f64;
            let tm = (m - 1.0) / 2.0;
            let mean = seg.iter().sum::<f64>() / m;
            let (mut stt, mut sty) = (0.0, 0.0);
            for (i, &y) in seg.iter().enumerate() {
                let t = i as f64 - tm;
                stt += t * t;
                sty += t * (y - mean);
            }
            let slope = if stt > 0.0 { sty / stt } else { 0.0 };
            for (i, y) in seg.iter_mut().enumerate() {
                *y -= mean + slope * (i as f64 - tm);
            }
        }
    }

    /// `v` detrended block by block.
    pub fn detrended(&self, v: &[f64]) -> Vec<f64> {
        let mut v = v.to_vec();
        self.detrend(&mut v);
        v
    }

    /// A full-rate signal through the judging band's post-filter, at the decimated samples:
    /// a nonlinear regressor formed from the judged motion loses its harmonics above the band
    /// as the force did (and cannot alias on decimation).
    pub fn band_picks(&self, full: &[f64]) -> Result<Vec<f64>, DiagnosisError> {
        match &self.band {
            Some(band) => {
                let v = self.narrow.valid.clone();
                let filtered = band.filtfilt(&full[v.clone()])?;
                Ok(self.picks.iter().map(|&i| filtered[i - v.start]).collect())
            }
            None => Ok(self.picks.iter().map(|&i| full[i]).collect()),
        }
    }

    /// Several full-rate signals through the post-filter at once (see [`Prepared::band_picks`]).
    pub fn band_picks_many(&self, full: Vec<Vec<f64>>) -> Result<Vec<Vec<f64>>, DiagnosisError> {
        let v = self.narrow.valid.clone();
        match &self.band {
            Some(band) => {
                let mut cols: Vec<Vec<f64>> = full.into_iter().map(|c| c[v.clone()].to_vec()).collect();
                let mut scratch = Vec::new();
                band.filtfilt_many_in_place(&mut cols, &mut scratch)?;
                Ok(cols.iter().map(|c| self.picks.iter().map(|&i| c[i - v.start]).collect()).collect())
            }
            None => Ok(full.iter().map(|c| self.picks.iter().map(|&i| c[i]).collect()).collect()),
        }
    }

    /// Rows of the force problem: `f_x` then `f_y`, each `len()`.
    pub fn force_rows(&self) -> usize {
        2 * self.len()
    }

    /// The force rows' detrended target.
    pub fn force_target(&self, s: &Series) -> DVector<f64> {
        let n = self.len();
        let mut out = DVector::zeros(2 * n);
        out.rows_mut(0, n).copy_from_slice(&self.detrended(&s.fx_n));
        out.rows_mut(n, n).copy_from_slice(&self.detrended(&s.fy_n));
        out
    }

    /// The sensor rows, detrended and weighted: `k_bar tilt_x`, `k_bar tilt_y`, `k_bar J_x`,
    /// `k_bar J_y` (each `len()`), what no film model predicts but zero.
    pub fn sensor_rows(&self, s: &Series) -> DVector<f64> {
        let n = self.len();
        let w = self.sensor_weight_n_m;
        let [jx, jy] = s.journal_m();
        let mut out = DVector::zeros(4 * n);
        for (k, col) in [&s.tilt_x_m, &s.tilt_y_m, &jx, &jy].into_iter().enumerate() {
            let v: Vec<f64> = self.detrended(col).into_iter().map(|x| w * x).collect();
            out.rows_mut(k * n, n).copy_from_slice(&v);
        }
        out
    }

    /// The linear K-C design on the force rows (8 columns: `x, y, x', y'` for `f_x`, then for
    /// `f_y`), detrended, with `extra` zero columns after them for extensions. Column
    /// `4 i + j` is minus stiffness (j < 2) or minus damping (j >= 2) `[i][j mod 2]`.
    pub fn kc_design(&self, s: &Series, extra: usize) -> DMatrix<f64> {
        let n = self.len();
        let mut m = DMatrix::zeros(2 * n, 8 + extra);
        for axis in 0..2 {
            for (j, col) in [&s.x_m, &s.y_m, &s.vx_m_s, &s.vy_m_s].into_iter().enumerate() {
                m.view_mut((axis * n, 4 * axis + j), (n, 1)).copy_from_slice(&self.detrended(col));
            }
        }
        m
    }

    /// Puts a per-axis regressor (one value per sample for the `f_x` rows and one for the `f_y`
    /// rows) into column `col`, detrended.
    pub fn set_column(&self, m: &mut DMatrix<f64>, col: usize, fx_rows: &[f64], fy_rows: &[f64]) {
        let n = self.len();
        for (axis, src) in [fx_rows, fy_rows].into_iter().enumerate() {
            m.view_mut((axis * n, col), (n, 1)).copy_from_slice(&self.detrended(src));
        }
    }

    /// Puts a regressor into column `col` on one axis' rows only (`axis` 0: `f_x`, 1: `f_y`).
    pub fn set_axis_column(&self, m: &mut DMatrix<f64>, col: usize, axis: usize, values: &[f64]) {
        let n = self.len();
        m.view_mut((axis * n, col), (n, 1)).copy_from_slice(&self.detrended(values));
    }

    /// The force rows of each block (for [`crate::least_squares::Blocked`]).
    pub fn force_blocks(&self) -> Vec<Vec<usize>> {
        let n = self.len();
        self.blocks.iter().map(|b| b.clone().chain(b.clone().map(|i| n + i)).collect()).collect()
    }

    /// The sensor rows of block `b`.
    pub fn sensor_block_rows(&self, b: usize) -> impl Iterator<Item = usize> + '_ {
        let n = self.len();
        (0..4).flat_map(move |k| self.blocks[b].clone().map(move |i| k * n + i))
    }

    /// Sum of squares of the force target (the NRMSE's norm times its row count).
    pub fn force_sst(&self) -> f64 {
        2.0 * self.len() as f64 * self.force_rms_n * self.force_rms_n
    }
}
