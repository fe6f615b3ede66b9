//! The record made ready for judging models: conditioned once by the identification pipeline
//! (the same chain and adaptive low-pass `oilfilm identify` uses), decimated to a rate where
//! the band-limited residual is close to white (so sample counts mean degrees of freedom), cut
//! into contiguous time blocks for cross-validation, and detrended block by block.
//!
//! ## What every model predicts
//! The measured signals a rigid-housing linear film model speaks about, stacked as rows:
//! the eq. 2 film force `f_x`, `f_y`, and the disagreement between the two bearing ends
//! (`tilt = end A - end B`, which the model predicts to be zero) expressed as the force the
//! film's stiffness would need for it, `k_bar * tilt` with `k_bar` the mean direct stiffness of
//! the baseline fit. Held-out errors are normalised by the RMS of the dynamic film force.
//! Counting the tilt lets a delayed or clipped bearing probe show itself: the linear fit
//! absorbs a probe's delay into its damping (`C + K tau / 2`) and hides it from the force.
//!
//! ## Blocks and detrending
//! Each block's slow trend (mean and slope) is removed from every column and target: static
//! load, equilibrium drift with temperature and the bellows are not what is judged, and the
//! same preprocessing is applied to every model alike.

use std::ops::Range;

use nalgebra::{DMatrix, DVector};
use oilfilm_identification::conditioning::{self, Conditioned, ConditioningConfig, Mechanics, RawRecord};
use oilfilm_identification::pipeline::{self, Identification, PipelineConfig, SpeedSource};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::Calibration;

use crate::DiagnosisError;

/// The decimated rate is at least this multiple of the conditioning's low-pass cutoff.
pub const DECIMATED_RATE_OVER_CUTOFF: f64 = 2.5;
/// The diagnosis low-pass cutoff is this multiple of the highest excitation line.
pub const DIAGNOSIS_CUTOFF_FACTOR: f64 = 1.05;
/// Margin (full-rate samples) kept inside the conditioner's valid range, so records
/// re-conditioned with a shifted channel are valid on the very same samples.
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
    /// Housing absolute velocity (central difference of the frame-probe displacement).
    pub housing_vx_m_s: Vec<f64>,
    pub housing_vy_m_s: Vec<f64>,
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
    /// The decimated samples `picks` (full-rate indices) of a conditioned record.
    pub fn from_conditioned(c: &Conditioned, picks: &[usize]) -> Self {
        let take = |v: &[f64]| picks.iter().map(|&i| v[i]).collect::<Vec<_>>();
        let rate = if c.t_s.len() > 1 { (c.t_s.len() - 1) as f64 / (c.t_s[c.t_s.len() - 1] - c.t_s[0]) } else { 1.0 };
        let diff = |v: &[f64]| {
            picks
                .iter()
                .map(|&i| {
                    let (a, b) = (i.saturating_sub(1), (i + 1).min(v.len() - 1));
                    (v[b] - v[a]) * rate / (b - a).max(1) as f64
                })
                .collect::<Vec<_>>()
        };
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
            housing_vx_m_s: diff(&c.housing_x_m),
            housing_vy_m_s: diff(&c.housing_y_m),
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

    /// The fields that move with the record's channels, as mutable slices in a fixed order
    /// (time and temperature excluded).
    fn fields_mut(&mut self) -> [&mut Vec<f64>; 16] {
        [
            &mut self.x_m,
            &mut self.y_m,
            &mut self.vx_m_s,
            &mut self.vy_m_s,
            &mut self.ax_m_s2,
            &mut self.ay_m_s2,
            &mut self.housing_x_m,
            &mut self.housing_y_m,
            &mut self.housing_vx_m_s,
            &mut self.housing_vy_m_s,
            &mut self.housing_ax_m_s2,
            &mut self.housing_ay_m_s2,
            &mut self.fx_n,
            &mut self.fy_n,
            &mut self.tilt_x_m,
            &mut self.tilt_y_m,
        ]
    }

    fn fields(&self) -> [&Vec<f64>; 16] {
        [
            &self.x_m,
            &self.y_m,
            &self.vx_m_s,
            &self.vy_m_s,
            &self.ax_m_s2,
            &self.ay_m_s2,
            &self.housing_x_m,
            &self.housing_y_m,
            &self.housing_vx_m_s,
            &self.housing_vy_m_s,
            &self.housing_ax_m_s2,
            &self.housing_ay_m_s2,
            &self.fx_n,
            &self.fy_n,
            &self.tilt_x_m,
            &self.tilt_y_m,
        ]
    }

    /// `a + s1 * b + s2 * c` field by field (time and temperature from `a`): the quadratic
    /// model of a series in a channel's extra delay.
    pub fn combine(a: &Series, b: &Series, s1: f64, c: &Series, s2: f64) -> Series {
        let mut out = a.clone();
        for ((o, bf), cf) in out.fields_mut().into_iter().zip(b.fields()).zip(c.fields()) {
            for ((v, &bv), &cv) in o.iter_mut().zip(bf.iter()).zip(cf.iter()) {
                *v += s1 * bv + s2 * cv;
            }
        }
        out
    }

    /// Every field times `k` (time and temperature kept).
    pub fn scaled(mut self, k: f64) -> Series {
        for f in self.fields_mut() {
            f.iter_mut().for_each(|v| *v *= k);
        }
        self
    }

    /// `(a - b) * s` field by field (time and temperature from `a`).
    pub fn difference(a: &Series, b: &Series, s: f64) -> Series {
        let mut out = a.clone();
        for (o, bf) in out.fields_mut().into_iter().zip(b.fields()) {
            for (v, &bv) in o.iter_mut().zip(bf.iter()) {
                *v = (*v - bv) * s;
            }
        }
        out
    }
}

/// A record ready for diagnosis.
#[derive(Debug, Clone)]
pub struct Prepared {
    pub raw: RawRecord,
    pub calibration: Calibration,
    pub mechanics: Mechanics,
    /// The conditioning used (the pipeline's, with its adapted cutoff).
    pub conditioning: ConditioningConfig,
    /// The pipeline's identification of the record (windows, lines, refusals).
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
    /// Excitation lines found by the pipeline, Hz.
    pub lines_hz: Vec<f64>,
    /// Weight turning end-to-end probe disagreement into force, N/m (mean direct stiffness
    /// of the whole-record baseline fit).
    pub tilt_weight_n_m: f64,
    /// RMS of the detrended dynamic film force over all blocks, N (the NRMSE's norm).
    pub force_rms_n: f64,
    /// Mean bearing temperature over the record, C.
    pub mean_temperature_c: f64,
    /// Static film force on the journal (eq. 2 mean), N.
    pub static_force_n: [f64; 2],
    /// Full-rate conditioned motion `[x, y, x', y']` (every scan), for regressors that are
    /// nonlinear in it: they are formed at full rate and passed through the conditioning's
    /// low-pass like the force they are compared with ([`Prepared::filtered_picks`]).
    pub full_motion: [Vec<f64>; 4],
    /// What the preparation noticed (refused windows, range violations).
    pub notes: Vec<String>,
}

/// Settings of a diagnosis.
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
        // 2 s windows: the per-window trends need several windows in a 10 s record.
        pipeline.estimator.window = 10_000;
        pipeline.estimator.hop = 10_000;
        Self { pipeline, folds: 10, min_seconds: 2.0 }
    }
}

/// Why a record cannot be judged at all, as the `insufficient_data` verdict's reason.
#[derive(Debug, Clone, PartialEq)]
pub struct Insufficient(pub String);

/// Conditions, identifies and decimates a record. `Ok(Err(Insufficient))` when the record
/// is too short or too poorly excited to judge any model; `Err` for unusable input.
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
    let mut config = options.pipeline.clone();
    config.estimator.sample_rate_hz = raw.sample_rate_hz;
    let identification = pipeline::identify(raw, calibration, rig, speed_rpm, speed_source, &config)?;
    let mechanics = pipeline::mechanics_of(rig);
    let mut conditioning = config.conditioning.clone();
    conditioning.lowpass_cutoff_hz = identification.lowpass_cutoff_hz;
    let lines_hz = pipeline::excitation_lines(raw)?;
    if let Some(&top) = lines_hz.last() {
        // Band-limit to the excitation (ADR 0005), from the measured exciter forces, closer
        // than the pipeline does: differentiated probe noise grows with the cube of the band
        // and, as errors in the regressors, sets the floor every model is judged against. The
        // same filter acts on force and motion, so lines it attenuates keep their relation.
        let cutoff = (DIAGNOSIS_CUTOFF_FACTOR * top).max(pipeline::MIN_ADAPTIVE_CUTOFF_HZ);
        if cutoff < conditioning.lowpass_cutoff_hz {
            conditioning.lowpass_cutoff_hz = cutoff;
        }
    }
    let conditioned = conditioning::condition(raw, calibration, &mechanics, &conditioning)?;
    let valid = conditioned.valid.clone();
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
    if identification.accepted().count() == 0 {
        let why = identification
            .refusal
            .clone()
            .or_else(|| identification.windows.iter().find_map(|w| w.estimate.result.as_ref().err().map(|r| r.to_string())))
            .unwrap_or_else(|| "no window could be identified".into());
        notes.push(format!("the windowed identification refused every window ({why}); the diagnosis fits the whole record"));
    }
    let decimation = ((raw.sample_rate_hz / (DECIMATED_RATE_OVER_CUTOFF * conditioning.lowpass_cutoff_hz)).floor() as usize).max(1);
    let picks: Vec<usize> = (valid.start + EDGE_MARGIN..valid.end - EDGE_MARGIN).step_by(decimation).collect();
    let n = picks.len();
    let per = n / options.folds;
    if per < 20 {
        return Ok(Err(Insufficient(format!("too short: {n} decimated samples for {} blocks", options.folds))));
    }
    let blocks: Vec<Range<usize>> = (0..options.folds).map(|b| b * per..if b + 1 == options.folds { n } else { (b + 1) * per }).collect();
    let series = Series::from_conditioned(&conditioned, &picks);
    let mean_temperature_c = series.temperature_c.iter().sum::<f64>() / n as f64;
    let mut prepared = Prepared {
        raw: raw.clone(),
        calibration: calibration.clone(),
        mechanics,
        conditioning,
        identification,
        picks,
        decimation,
        rate_hz: raw.sample_rate_hz / decimation as f64,
        blocks,
        series,
        speed_rpm,
        lines_hz,
        tilt_weight_n_m: 0.0,
        force_rms_n: 0.0,
        mean_temperature_c,
        static_force_n: conditioned.static_force_n,
        full_motion: [conditioned.x_m.clone(), conditioned.y_m.clone(), conditioned.vx_m_s.clone(), conditioned.vy_m_s.clone()],
        notes,
    };
    let mut fx = prepared.series.fx_n.clone();
    let mut fy = prepared.series.fy_n.clone();
    prepared.detrend(&mut fx);
    prepared.detrend(&mut fy);
    prepared.force_rms_n = ((fx.iter().map(|v| v * v).sum::<f64>() + fy.iter().map(|v| v * v).sum::<f64>()) / (2 * n) as f64).sqrt();
    if !(prepared.force_rms_n.is_finite() && prepared.force_rms_n > 0.0) {
        return Ok(Err(Insufficient("no dynamic film force: the exciters did not move the housing".into())));
    }
    // k_bar from a whole-record K-C fit (the weight only scales the tilt rows alike for all
    // models; it is not a fitted parameter of any of them).
    let design = prepared.kc_design(&prepared.series, 0);
    let target = prepared.target(&prepared.series, 0.0);
    let fit = match crate::least_squares::solve(&design, &target, &vec![true; design.nrows()], "baseline K-C (whole record)") {
        Ok(f) => f,
        Err(e) => return Ok(Err(Insufficient(format!("too poorly excited: the linear model itself cannot be fitted ({e})")))),
    };
    prepared.tilt_weight_n_m = 0.5 * (fit.theta[0].abs() + fit.theta[5].abs());
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

    /// A full-rate signal formed from the conditioned record, through the conditioning's
    /// zero-phase low-pass, at the decimated samples: a nonlinear regressor's harmonics above
    /// the band are removed as they were from the force (and cannot alias on decimation).
    pub fn filtered_picks(&self, full: &[f64]) -> Result<Vec<f64>, DiagnosisError> {
        let filtered = conditioning::lowpass::filtfilt(
            oilfilm_physics::daq::ChannelId::ProbeAX,
            full,
            self.conditioning.lowpass_order,
            self.conditioning.lowpass_cutoff_hz,
            self.raw.sample_rate_hz,
        )?;
        Ok(self.picks.iter().map(|&i| filtered[i]).collect())
    }

    /// Rows of the stacked problem: `fx`, `fy`, `k_bar tilt_x`, `k_bar tilt_y`, each `len()`.
    pub fn rows(&self) -> usize {
        4 * self.len()
    }

    /// The stacked, detrended target of a series. `tilt_weight` 0 means "use the record's".
    pub fn target(&self, s: &Series, tilt_weight: f64) -> DVector<f64> {
        let w = if tilt_weight > 0.0 { tilt_weight } else { self.tilt_weight_n_m };
        let n = self.len();
        let mut out = DVector::zeros(4 * n);
        for (k, (col, scale)) in [(&s.fx_n, 1.0), (&s.fy_n, 1.0), (&s.tilt_x_m, w), (&s.tilt_y_m, w)].into_iter().enumerate() {
            let mut v: Vec<f64> = col.iter().map(|x| x * scale).collect();
            self.detrend(&mut v);
            out.rows_mut(k * n, n).copy_from_slice(&v);
        }
        out
    }

    /// The baseline K-C design (8 columns: `x, y, x', y'` for `f_x`, then for `f_y`; zero on
    /// the tilt rows), detrended, with `extra` zero columns after them for a candidate.
    /// Column `4 i + j` is minus stiffness (j < 2) or minus damping (j >= 2) `[i][j mod 2]`.
    pub fn kc_design(&self, s: &Series, extra: usize) -> DMatrix<f64> {
        let n = self.len();
        let mut m = DMatrix::zeros(4 * n, 8 + extra);
        for axis in 0..2 {
            for (j, col) in [&s.x_m, &s.y_m, &s.vx_m_s, &s.vy_m_s].into_iter().enumerate() {
                let mut v = col.clone();
                self.detrend(&mut v);
                m.view_mut((axis * n, 4 * axis + j), (n, 1)).copy_from_slice(&v);
            }
        }
        m
    }

    /// Puts a per-axis regressor (one value per sample for `f_x` rows and one for `f_y`
    /// rows) into column `col`, detrended.
    pub fn set_column(&self, m: &mut DMatrix<f64>, col: usize, fx_rows: &[f64], fy_rows: &[f64]) {
        let n = self.len();
        for (axis, src) in [fx_rows, fy_rows].into_iter().enumerate() {
            let mut v = src.to_vec();
            self.detrend(&mut v);
            m.view_mut((axis * n, col), (n, 1)).copy_from_slice(&v);
        }
    }

    /// Row mask of the training rows for holding out block `b` (`None`: all rows).
    pub fn train_mask(&self, held_out: Option<usize>) -> Vec<bool> {
        let n = self.len();
        let mut mask = vec![true; 4 * n];
        if let Some(b) = held_out {
            for k in 0..4 {
                for i in self.blocks[b].clone() {
                    mask[k * n + i] = false;
                }
            }
        }
        mask
    }

    /// Row indices of block `b` in the stacked problem.
    pub fn block_rows(&self, b: usize) -> impl Iterator<Item = usize> + '_ {
        let n = self.len();
        (0..4).flat_map(move |k| self.blocks[b].clone().map(move |i| k * n + i))
    }

    /// Re-conditions the record with `raw` in place of the measured one (a shifted or
    /// repaired channel) and returns its decimated series on the same samples.
    pub fn recondition(&self, raw: &RawRecord) -> Result<Series, DiagnosisError> {
        let c = conditioning::condition(raw, &self.calibration, &self.mechanics, &self.conditioning)?;
        if c.valid.start > self.picks[0] || c.valid.end <= *self.picks.last().unwrap_or(&0) {
            return Err(DiagnosisError::bad_input(
                "re-conditioned record",
                format!("valid range {:?} no longer covers the diagnosed samples", c.valid),
            ));
        }
        Ok(Series::from_conditioned(&c, &self.picks))
    }
}
