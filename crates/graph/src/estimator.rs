//! The estimator node's core: conditioned frames in, one coefficient estimate (or refusal)
//! per window out, through the identification crate's windowed least squares and window
//! report (the same code `oilfilm identify` runs).
//!
//! Windows sit at fixed sample indices of the conditioned stream, `[k hop, k hop + window)`,
//! so an estimate depends only on the samples, never on frame boundaries or arrival times.
//! A window holding an invalid sample (a probe out of range, a rejected block) is refused
//! with the count and the first such sample; a gap in the stream restarts the windows.
//! Speed: the `speed_rpm` parameter if set, else the latest `rig/status`, else the rig
//! file's, and the estimate's flags say which.

use std::collections::VecDeque;

use nalgebra::Matrix2;
use oilfilm_identification::estimator::{self, EstimatorConfig, ModelOrder, Signals, Solver, WindowFeed, MAX_WINDOW_SAMPLES};
use oilfilm_identification::pipeline::{window_report_fed, ReportFeed, WindowReport};
use oilfilm_msgs::{CoefficientEstimate, ConditionedFrame, Header, RigStatus, BEARING_FRAME_ID};
use oilfilm_physics::config::RigConfig;
use serde::{Deserialize, Serialize};

use crate::error::NodeError;
use crate::node::{skipped, Connect, Input, Node, Output, Start, Turn};
use crate::params::{NodeParams, Rule, Spec};
use crate::stamp::Stamp;
use crate::topics;

/// Windows fed at once: the one at `next_start` and, with overlapping windows, the next (more
/// would hold more memory for no less work).
const MAX_FEEDS: usize = 2;

/// The estimator node's parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EstimatorParams {
    /// Rig file (TOML); empty: the built-in rig. Geometry and oil law for the dimensionless
    /// coefficients and the operating point.
    pub rig: String,
    /// Samples per window (the paper: 50 000 = 10 s at 5 kHz).
    pub window: i64,
    /// Samples between window starts.
    pub hop: i64,
    /// `kc` (8 coefficients) or `kcm` (12, with added mass).
    pub model: String,
    /// `qr`, `svd` or `normal_equations` (the paper's, for comparison only).
    pub solver: String,
    pub max_condition: f64,
    pub max_relative_se: f64,
    /// Shaft speed, rpm; 0: from rig/status (else the rig file's).
    pub speed_rpm: f64,
    /// Band of the conditioned signals, Hz: set it to the conditioner's `lowpass_cutoff_hz`
    /// and the standard errors are computed from a decimated copy of each window (cheaper
    /// at high rates; the coefficients are unchanged). 0: every sample (the default). A
    /// conditioned frame declaring a higher cutoff (its `lowpass_hz=` flag) wins.
    pub signal_band_hz: f64,
}

impl Default for EstimatorParams {
    fn default() -> Self {
        let c = EstimatorConfig::default();
        Self {
            rig: String::new(),
            window: c.window as i64,
            hop: c.hop as i64,
            model: "kc".into(),
            solver: "qr".into(),
            max_condition: c.max_condition,
            max_relative_se: c.max_relative_se,
            speed_rpm: 0.0,
            signal_band_hz: 0.0,
        }
    }
}

impl NodeParams for EstimatorParams {
    fn specs() -> Vec<Spec> {
        let kc = ModelOrder::Kc.min_samples();
        let kcm = ModelOrder::Kcm.min_samples();
        vec![
            Spec::fixed("rig", "rig file (TOML): geometry and oil law for the dimensionless coefficients and the operating point; empty: the built-in Zhou et al. (2004) rig", Rule::Any),
            Spec::live("window", "samples per window (the paper: 50 000 = 10 s at 5 kHz)", Rule::Integer { min: kc as i64, max: MAX_WINDOW_SAMPLES as i64 })
                .with_constraints(if kcm == 112 { "at least the model's minimum: 80 samples for kc, 112 for kcm (16 per unknown of a row, with its intercept)" } else { "at least the model's minimum number of samples" }),
            Spec::live("hop", "samples between window starts (hop = window: windows end to end; less: they overlap)", Rule::Integer { min: 1, max: MAX_WINDOW_SAMPLES as i64 }),
            Spec::live("model", "kc: 8 coefficients (stiffness, damping); kcm: 12 (plus added mass)", Rule::OneOf(&["kc", "kcm"])),
            Spec::live("solver", "least squares by qr (default), svd, or normal_equations (the paper's, for comparison only)", Rule::OneOf(&["qr", "svd", "normal_equations"])),
            Spec::live("max_condition", "largest condition number of a window's regressors before it is refused", Rule::number(1.0, 1e300)),
            Spec::live("max_relative_se", "largest standard error of a direct coefficient, as a fraction of it, before the window is refused (.inf: never)", Rule::above(0.0, f64::INFINITY)),
            Spec::live("speed_rpm", "shaft speed for the operating point, rpm; 0: from rig/status (else the rig file's)", Rule::number(0.0, 1e6)),
            Spec::live("signal_band_hz", "band of the conditioned signals, Hz (set it to the conditioner's lowpass_cutoff_hz: standard errors from a decimated copy, the same coefficients); 0: every sample", Rule::number(0.0, 1e6))
                .with_constraints("0, or below the Nyquist frequency of the rig file's DAQ rate"),
        ]
    }

    /// The window must hold the model's minimum of samples (the estimator would refuse every
    /// window), besides each value's own rule.
    fn validate(&self) -> Result<(), NodeError> {
        let model = if self.model == "kcm" { ModelOrder::Kcm } else { ModelOrder::Kc };
        let need = model.min_samples() as i64;
        if self.window < need {
            return Err(NodeError::parameter(
                "window",
                format!("{} samples is shorter than the {} model needs (at least {need}: 16 per unknown of a row, with its intercept): every window would be refused", self.window, self.model),
            ));
        }
        Ok(())
    }
}

impl EstimatorParams {
    /// The estimator's settings at `sample_rate_hz`; the error names the parameter.
    pub fn config(&self, sample_rate_hz: f64) -> Result<EstimatorConfig, NodeError> {
        let count = |name: &str, v: i64| usize::try_from(v).map_err(|_| NodeError::parameter(name, format!("must be >= 0, got {v}")));
        let model = match self.model.as_str() {
            "kc" => ModelOrder::Kc,
            "kcm" => ModelOrder::Kcm,
            other => return Err(NodeError::parameter("model", format!("`{other}` is not a model (kc, kcm)"))),
        };
        let solver = match self.solver.as_str() {
            "qr" => Solver::Qr,
            "svd" => Solver::Svd,
            "normal_equations" => Solver::NormalEquations,
            other => return Err(NodeError::parameter("solver", format!("`{other}` is not a solver (qr, svd, normal_equations)"))),
        };
        let c = EstimatorConfig {
            window: count("window", self.window)?,
            hop: count("hop", self.hop)?,
            model,
            solver,
            max_condition: self.max_condition,
            sample_rate_hz,
            max_relative_se: self.max_relative_se,
            signal_band_hz: if self.signal_band_hz == 0.0 { None } else { Some(self.signal_band_hz) },
        };
        c.validate().map_err(|e| match e {
            oilfilm_identification::IdentificationError::InvalidParameter { field, reason } => NodeError::parameter(field, reason),
            other => NodeError::Identification(other),
        })?;
        if !(self.speed_rpm.is_finite() && self.speed_rpm >= 0.0) {
            return Err(NodeError::parameter("speed_rpm", format!("must be finite and >= 0, got {}", self.speed_rpm)));
        }
        Ok(c)
    }
}

/// Conditioned samples awaiting their windows.
///
/// Samples before the current window are dropped by moving `head`, the count of dead elements
/// at the front of every column; the columns are compacted only once the dead part is at
/// least as long as the live one (with half-overlapping windows every second window instead
/// of every window, and then half as much to move), so the buffer stays below twice its live
/// length.
#[derive(Default)]
struct Buffer {
    /// Sample index of element `head`, the first live one.
    first: u64,
    head: usize,
    x: Vec<f64>,
    y: Vec<f64>,
    vx: Vec<f64>,
    vy: Vec<f64>,
    ax: Vec<f64>,
    ay: Vec<f64>,
    fx: Vec<f64>,
    fy: Vec<f64>,
    temperature: Vec<f64>,
    valid: Vec<bool>,
}

impl Buffer {
    /// Live samples.
    fn len(&self) -> usize {
        self.x.len() - self.head
    }

    fn end(&self) -> u64 {
        self.first + self.len() as u64
    }

    /// The live part of a column.
    fn live<'a, T>(&self, c: &'a [T]) -> &'a [T] {
        &c[self.head..]
    }

    fn drop_before(&mut self, sample: u64) {
        let k = (sample.saturating_sub(self.first) as usize).min(self.len());
        self.head += k;
        self.first += k as u64;
        if self.head > 0 && self.head >= self.len() {
            let dead = self.head;
            for c in [&mut self.x, &mut self.y, &mut self.vx, &mut self.vy, &mut self.ax, &mut self.ay, &mut self.fx, &mut self.fy, &mut self.temperature] {
                c.drain(..dead);
            }
            self.valid.drain(..dead);
            self.head = 0;
        }
    }
}

/// The estimator's state.
pub struct EstimatorCore {
    rig: RigConfig,
    params: EstimatorParams,
    buffer: Buffer,
    /// Rate and the stream's origin (sample index, rig time) for window times.
    rate_hz: f64,
    origin: Option<(u64, Stamp)>,
    next_start: u64,
    status_speed_rpm: Option<f64>,
    sequence: u64,
    restart_note: Option<String>,
    /// The analyses of the window at `next_start` and of the next one if it has begun (first
    /// sample, the estimator's feed and the report's; at most [`MAX_FEEDS`], in window order),
    /// fed as conditioned frames arrive so that little is left when a window completes and
    /// each frame's samples are taken by both overlapping windows while they are in cache.
    feeds: VecDeque<(u64, WindowFeed, ReportFeed)>,
    /// Highest low-pass cutoff the conditioned frames declared (`lowpass_hz=` flag) since the
    /// windows last restarted.
    frame_cutoff_hz: Option<f64>,
}

impl EstimatorCore {
    pub fn new(rig: RigConfig, params: EstimatorParams) -> Result<Self, NodeError> {
        NodeParams::validate(&params)?;
        params.config(rig.daq.sample_rate_hz)?;
        Ok(Self {
            rig,
            params,
            buffer: Buffer::default(),
            rate_hz: 0.0,
            origin: None,
            next_start: 0,
            status_speed_rpm: None,
            sequence: 0,
            restart_note: None,
            feeds: VecDeque::new(),
            frame_cutoff_hz: None,
        })
    }

    pub fn params(&self) -> &EstimatorParams {
        &self.params
    }

    /// New parameters (the parameter service); the windows restart at the next hop.
    pub fn set_params(&mut self, params: EstimatorParams) -> Result<(), NodeError> {
        if params.rig != self.params.rig {
            return Err(NodeError::parameter("rig", "is read-only while the node runs: restart it with the new rig file"));
        }
        NodeParams::validate(&params)?;
        params.config(if self.rate_hz > 0.0 { self.rate_hz } else { self.rig.daq.sample_rate_hz })?;
        let hop = params.hop as u64;
        self.params = params;
        self.next_start = self.buffer.end().div_ceil(hop) * hop;
        self.feeds.clear();
        Ok(())
    }

    /// The rig's status: its speed is the operating point's unless `speed_rpm` is set.
    pub fn rig_status(&mut self, status: &RigStatus) {
        if status.speed_rad_s.is_finite() && status.speed_rad_s > 0.0 {
            self.status_speed_rpm = Some(status.speed_rad_s * 30.0 / std::f64::consts::PI);
        }
    }

    /// Takes one conditioned frame; returns the estimates of the windows it completes.
    pub fn push(&mut self, frame: &ConditionedFrame) -> Result<Vec<CoefficientEstimate>, NodeError> {
        let n = frame.x_m.len();
        let bad = |reason: String| NodeError::BadMessage { topic: topics::CONDITIONED.name.into(), sequence: frame.sequence, reason };
        if !(frame.sample_rate_hz.is_finite() && frame.sample_rate_hz > 0.0) {
            return Err(bad(format!("sample_rate_hz must be finite and > 0, got {}", frame.sample_rate_hz)));
        }
        for (name, len) in [
            ("y_m", frame.y_m.len()),
            ("x_dot_m_s", frame.x_dot_m_s.len()),
            ("y_dot_m_s", frame.y_dot_m_s.len()),
            ("fx_n", frame.fx_n.len()),
            ("fy_n", frame.fy_n.len()),
            ("valid", frame.valid.len()),
        ] {
            if len != n {
                return Err(bad(format!("{name} has {len} samples, x_m has {n}")));
            }
        }
        let has_acc = frame.x_ddot_m_s2.len() == n && frame.y_ddot_m_s2.len() == n;
        if !(has_acc || frame.x_ddot_m_s2.is_empty() && frame.y_ddot_m_s2.is_empty()) {
            return Err(bad(format!("x_ddot_m_s2 / y_ddot_m_s2 have {} / {} samples: either none or {n}", frame.x_ddot_m_s2.len(), frame.y_ddot_m_s2.len())));
        }
        let mut config = self.params.config(frame.sample_rate_hz)?;
        if self.rate_hz != frame.sample_rate_hz || self.buffer.end() != frame.first_sample || self.origin.is_none() {
            if self.origin.is_some() {
                self.restart_note = Some(format!(
                    "windows restarted at sample {}: the conditioned stream {}",
                    frame.first_sample,
                    if self.rate_hz != frame.sample_rate_hz { "changed rate".to_string() } else { format!("jumped from sample {}", self.buffer.end()) }
                ));
            }
            self.buffer = Buffer { first: frame.first_sample, ..Buffer::default() };
            self.feeds.clear();
            self.frame_cutoff_hz = None;
            self.rate_hz = frame.sample_rate_hz;
            self.origin = Some((frame.first_sample, Stamp::from_time(&frame.header.stamp)));
            let hop = config.hop as u64;
            self.next_start = frame.first_sample.div_ceil(hop) * hop;
        }
        let b = &mut self.buffer;
        b.x.extend(&frame.x_m);
        b.y.extend(&frame.y_m);
        b.vx.extend(&frame.x_dot_m_s);
        b.vy.extend(&frame.y_dot_m_s);
        if has_acc {
            b.ax.extend(&frame.x_ddot_m_s2);
            b.ay.extend(&frame.y_ddot_m_s2);
        } else {
            b.ax.extend(std::iter::repeat_n(f64::NAN, n));
            b.ay.extend(std::iter::repeat_n(f64::NAN, n));
        }
        b.fx.extend(&frame.fx_n);
        b.fy.extend(&frame.fy_n);
        b.temperature.extend(std::iter::repeat_n(frame.bearing_temperature_degc, n));
        b.valid.extend(&frame.valid);

        // The standard errors may be decimated only to the band the conditioner really passed.
        if let Some(c) = declared_cutoff_hz(&frame.flags) {
            self.frame_cutoff_hz = Some(self.frame_cutoff_hz.map_or(c, |f| f.max(c)));
        }
        if let (Some(band), Some(declared)) = (config.signal_band_hz, self.frame_cutoff_hz) {
            if declared > band {
                config.signal_band_hz = Some(declared).filter(|&d| d < frame.sample_rate_hz / 2.0);
            }
        }
        let mut out = Vec::new();
        let (window, hop) = (config.window as u64, config.hop as u64);
        while self.buffer.end() >= self.next_start + window {
            self.buffer.drop_before(self.next_start);
            out.push(self.estimate(&config)?);
            self.next_start += hop;
        }
        self.buffer.drop_before(self.next_start);
        self.feed_window(&config);
        Ok(out)
    }

    /// Feeds the samples buffered for the windows at `next_start` and after (up to
    /// [`MAX_FEEDS`] windows that have begun) to their analyses, started here if there is none
    /// for a window and configuration yet: the line search, QR chunks, decimated samples and
    /// report sums sit at fixed offsets in each window, so an estimate is the same bits however
    /// the frames cut it and whenever its feed started.
    fn feed_window(&mut self, config: &EstimatorConfig) {
        let hop = config.hop as u64;
        let next = self.next_start;
        self.feeds.retain(|(s, f, _)| *s >= next && f.fits(config));
        let b = &self.buffer;
        for i in 0..MAX_FEEDS {
            let start = next + i as u64 * hop;
            if b.end() <= start || b.first > start {
                break;
            }
            if self.feeds.get(i).is_none_or(|(s, _, _)| *s != start) {
                self.feeds.truncate(i);
                self.feeds.push_back((start, WindowFeed::new(config), ReportFeed::default()));
            }
            let from = (start - b.first) as usize;
            let to = b.len().min(from + config.window);
            let (_, wf, rf) = &mut self.feeds[i];
            feed(wf, rf, &window_signals(b, from..to, config.model));
        }
    }

    /// The window at `next_start` (at the front of the buffer).
    fn estimate(&mut self, config: &EstimatorConfig) -> Result<CoefficientEstimate, NodeError> {
        let w = config.window;
        // The window's analysis as fed so far (a new one if none was fed for this window).
        let (mut wf, mut rf) = match self.feeds.pop_front() {
            Some((s, wf, rf)) if s == self.next_start && wf.fits(config) => (wf, rf),
            _ => (WindowFeed::new(config), ReportFeed::default()),
        };
        let b = &self.buffer;
        let temperature = b.live(&b.temperature).iter().take(w).sum::<f64>() / w as f64;
        let invalid: Vec<usize> = b.live(&b.valid).iter().take(w).enumerate().filter(|(_, v)| !**v).map(|(i, _)| i).collect();
        let start = self.next_start;
        let (origin_sample, origin_stamp) = self.origin.unwrap_or((start, Stamp(0)));
        let t0 = origin_stamp.after_samples((start - origin_sample) as i64, self.rate_hz);
        let t1 = origin_stamp.after_samples((start + w as u64 - origin_sample) as i64, self.rate_hz);
        let (speed_rpm, speed_flag) = match (self.params.speed_rpm, self.status_speed_rpm) {
            (s, _) if s > 0.0 => (s, "speed from the speed_rpm parameter"),
            (_, Some(s)) => (s, "speed from rig/status"),
            _ => (self.rig.operating.speed_rpm, "speed not reported: the rig file's speed assumed"),
        };
        let mut msg = CoefficientEstimate {
            header: Header { stamp: t1.to_time(), frame_id: BEARING_FRAME_ID.into() },
            sequence: self.sequence,
            window_start: t0.to_time(),
            window_end: t1.to_time(),
            window_start_sample: start,
            window_end_sample: start + w as u64,
            model: if config.model == ModelOrder::Kcm { CoefficientEstimate::MODEL_KCM } else { CoefficientEstimate::MODEL_KC },
            ..nan_estimate()
        };
        self.sequence += 1;
        if let Some(note) = self.restart_note.take() {
            msg.flags.push(note);
        }
        msg.flags.push(speed_flag.to_string());
        if let Some(&first) = invalid.first() {
            msg.refusal_reason = format!(
                "{} of {w} samples in the window are invalid (first: sample {}): a probe left its linear range or the conditioner rejected a block (see the conditioned frames' flags)",
                invalid.len(),
                start + first as u64
            );
            msg.speed_rad_s = speed_rpm * std::f64::consts::PI / 30.0;
            return Ok(msg);
        }
        // The rest of the window (its last samples) into the feeds; the same bits as analysing
        // the window in one piece (the feeds only move work before the window's end).
        let signals = window_signals(b, 0..w, config.model);
        feed(&mut wf, &mut rf, &signals);
        let estimate = estimator::estimate_window_fed(&signals, 0..w, config, wf)?;
        let report = window_report_fed(rf, signals.x_m, signals.y_m, estimate, temperature, &self.rig, speed_rpm, [t0.as_seconds(), t1.as_seconds()])?;
        fill(&mut msg, &report);
        Ok(msg)
    }
}

/// The buffered samples `range` as the estimator's columns (accelerations only for Kcm).
fn window_signals(b: &Buffer, range: std::ops::Range<usize>, model: ModelOrder) -> Signals<'_> {
    let r = range;
    let acc = model == ModelOrder::Kcm;
    Signals {
        x_m: &b.live(&b.x)[r.clone()],
        y_m: &b.live(&b.y)[r.clone()],
        vx_m_s: &b.live(&b.vx)[r.clone()],
        vy_m_s: &b.live(&b.vy)[r.clone()],
        ax_m_s2: acc.then(|| &b.live(&b.ax)[r.clone()]),
        ay_m_s2: acc.then(|| &b.live(&b.ay)[r.clone()]),
        fx_n: &b.live(&b.fx)[r.clone()],
        fy_n: &b.live(&b.fy)[r],
    }
}

/// Feeds `signals` (from the window's first sample) to the window's feeds: what they have not
/// taken yet.
fn feed(wf: &mut WindowFeed, rf: &mut ReportFeed, signals: &Signals) {
    wf.advance(signals);
    let done = rf.samples().min(signals.len());
    rf.advance(&signals.x_m[done..], &signals.y_m[done..], &signals.fx_n[done..], &signals.fy_n[done..]);
}

/// The low-pass cutoff a conditioned frame declares in its `lowpass_hz=` flag.
fn declared_cutoff_hz(flags: &[String]) -> Option<f64> {
    flags.iter().find_map(|f| f.strip_prefix("lowpass_hz=")?.trim().parse::<f64>().ok()).filter(|c| c.is_finite() && *c > 0.0)
}

/// An estimate with every number NaN and nothing solved.
fn nan_estimate() -> CoefficientEstimate {
    let n4 = [f64::NAN; 4];
    CoefficientEstimate {
        stiffness_n_m: n4,
        damping_n_s_m: n4,
        stiffness_se_n_m: n4,
        damping_se_n_s_m: n4,
        stiffness_lund: n4,
        damping_lund: n4,
        stiffness_zhou: n4,
        damping_zhou: n4,
        condition_number: f64::NAN,
        residual_rms_n: [f64::NAN; 2],
        speed_rad_s: f64::NAN,
        bearing_temperature_degc: f64::NAN,
        viscosity_pa_s: f64::NAN,
        static_force_n: [f64::NAN; 2],
        load_n: f64::NAN,
        journal_position_m: [f64::NAN; 2],
        sommerfeld_number: f64::NAN,
        load_parameter_fy: f64::NAN,
        amplitude_d: f64::NAN,
        ..Default::default()
    }
}

/// Row-major `[xx, xy, yx, yy]`.
pub fn row_major(m: &Matrix2<f64>) -> [f64; 4] {
    [m[(0, 0)], m[(0, 1)], m[(1, 0)], m[(1, 1)]]
}

/// The message fields of a window report.
fn fill(msg: &mut CoefficientEstimate, r: &WindowReport) {
    let e = &r.estimate;
    let o = &r.operating;
    msg.condition_number = e.condition_number;
    msg.rank = e.rank as u32;
    msg.residual_rms_n = e.residual_rms_n;
    msg.excitation_frequencies_hz = e.frequencies_hz.clone();
    msg.flags.extend(e.flags.iter().cloned());
    msg.speed_rad_s = o.speed_rpm * std::f64::consts::PI / 30.0;
    msg.bearing_temperature_degc = o.temperature_c;
    msg.viscosity_pa_s = o.viscosity_pa_s;
    msg.static_force_n = o.static_force_n;
    msg.load_n = o.load_n;
    msg.journal_position_m = o.mean_position_m;
    msg.sommerfeld_number = o.sommerfeld;
    msg.load_parameter_fy = o.load_parameter;
    msg.amplitude_d = o.amplitude_d;
    match &e.result {
        Ok(c) => {
            msg.solved = true;
            msg.stiffness_n_m = row_major(&c.stiffness_n_m);
            msg.damping_n_s_m = row_major(&c.damping_n_s_m);
            msg.stiffness_se_n_m = row_major(&c.stiffness_se);
            msg.damping_se_n_s_m = row_major(&c.damping_se);
            if let (Some(m), Some(se)) = (&c.added_mass_kg, &c.added_mass_se) {
                msg.added_mass_kg = row_major(m).to_vec();
                msg.added_mass_se_kg = row_major(se).to_vec();
            }
            if let Some(l) = &r.lund {
                msg.stiffness_lund = row_major(&l.stiffness);
                msg.damping_lund = row_major(&l.damping);
            }
            if let Some(z) = &r.zhou {
                msg.stiffness_zhou = row_major(&z.stiffness);
                msg.damping_zhou = row_major(&z.damping);
            }
        }
        Err(refusal) => {
            msg.solved = false;
            msg.refusal_reason = refusal.to_string();
        }
    }
}

/// The estimator node: conditioned frames and the rig's status in, estimates out.
pub struct Estimator {
    core: EstimatorCore,
}

pub struct EstimatorPorts<'a> {
    pub conditioned: Input<'a, ConditionedFrame>,
    pub status: Input<'a, RigStatus>,
    pub estimates: Output<'a, CoefficientEstimate>,
}

impl Node for Estimator {
    const NAME: &'static str = "estimator";
    type Params = EstimatorParams;
    type Ports<'a> = EstimatorPorts<'a>;

    fn new(params: &EstimatorParams, start: &Start) -> Result<Self, NodeError> {
        let rig = (start.rig)(&params.rig)?;
        params.config(rig.daq.sample_rate_hz)?;
        Ok(Self { core: EstimatorCore::new(rig, params.clone())? })
    }

    fn connect<C: Connect>(&self, c: &mut C) -> Result<EstimatorPorts<'static>, NodeError> {
        Ok(EstimatorPorts { conditioned: c.input(&topics::CONDITIONED)?, status: c.input(&topics::RIG_STATUS)?, estimates: c.output(&topics::ESTIMATES)? })
    }

    /// The status first (the speed), then the conditioned frames.
    fn turn(&mut self, _now: Stamp, ports: &mut EstimatorPorts<'_>) -> Result<Turn, NodeError> {
        let mut turn = Turn::default();
        while let Some(status) = ports.status.receive()? {
            turn.handled += 1;
            self.core.rig_status(&status);
        }
        while let Some(frame) = ports.conditioned.receive()? {
            turn.handled += 1;
            match self.core.push(&frame) {
                Ok(out) => {
                    for e in out {
                        if e.solved {
                            tracing::info!(node = Self::NAME, "window {}..{}: solved", e.window_start_sample, e.window_end_sample);
                        } else {
                            tracing::info!(node = Self::NAME, "window {}..{}: refused: {}", e.window_start_sample, e.window_end_sample, e.refusal_reason);
                        }
                        ports.estimates.publish(e)?;
                        turn.handled += 1;
                    }
                }
                Err(e) => skipped(Self::NAME, &e),
            }
        }
        Ok(turn)
    }

    fn reconfigure(&mut self, params: &EstimatorParams) -> Result<(), NodeError> {
        self.core.set_params(params.clone())?;
        tracing::info!(node = Self::NAME, "parameters changed: window {}, hop {}", self.core.params().window, self.core.params().hop);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Conditioned frames of `size` samples (the last may be shorter) of a two-tone record
    /// with a linear film and deterministic pseudo-noise.
    fn frames(total: usize, size: usize, fs: f64) -> Vec<ConditionedFrame> {
        noisy_frames(total, size, fs, None)
    }

    /// [`frames`] with the noise white, or band-limited by four one-pole low-passes at
    /// `band_hz` (each noise stream its own filter state; the white input scaled by
    /// `2 / sqrt(alpha)` so the filtered noise stays of the order of the white).
    fn noisy_frames(total: usize, size: usize, fs: f64, band_hz: Option<f64>) -> Vec<ConditionedFrame> {
        let mut state: u64 = 0x2545_F491_4F6C_DD1D;
        let mut white = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let alpha = band_hz.map(|b| 1.0 - (-2.0 * std::f64::consts::PI * b / fs).exp());
        // One filter state per call site, in call order within a sample (4 streams).
        let mut stages = [[0.0f64; 4]; 4];
        let mut call = 0usize;
        let mut noise = move || {
            let w = white();
            let Some(a) = alpha else { return w };
            let st = &mut stages[call % 4];
            call += 1;
            let mut v = w * (1.0 / a).sqrt() * 2.0;
            for s in st.iter_mut() {
                *s += a * (v - *s);
                v = *s;
            }
            v
        };
        let (w1, w2) = (2.0 * std::f64::consts::PI * 23.0, 2.0 * std::f64::consts::PI * 37.0);
        let mut out = Vec::new();
        let mut first = 0;
        while first < total {
            let n = size.min(total - first);
            let mut f = ConditionedFrame {
                sequence: out.len() as u64,
                first_sample: first as u64,
                sample_rate_hz: fs,
                bearing_temperature_degc: 40.0,
                ..Default::default()
            };
            for i in first..first + n {
                let t = i as f64 / fs;
                let (x, vx) = (5e-6 * (w1 * t).cos() + 3e-6 * (w2 * t).sin(), -5e-6 * w1 * (w1 * t).sin() + 3e-6 * w2 * (w2 * t).cos());
                let (y, vy) = (4e-6 * (w2 * t).cos() + 2e-6 * (w1 * t).sin(), -4e-6 * w2 * (w2 * t).sin() + 2e-6 * w1 * (w1 * t).cos());
                f.x_m.push(x - 2e-5 + 1e-9 * noise());
                f.y_m.push(y - 6e-5 + 1e-9 * noise());
                f.x_dot_m_s.push(vx);
                f.y_dot_m_s.push(vy);
                f.fx_n.push(150.0 - (1.2e8 * x + 3e7 * y + 2e5 * vx + 1.5e4 * vy) + 5.0 * noise());
                f.fy_n.push(8000.0 - (-2e7 * x + 2e8 * y + 1.2e4 * vx + 3e5 * vy) + 5.0 * noise());
                f.valid.push(true);
            }
            out.push(f);
            first += n;
        }
        out
    }

    fn run(frames: &[ConditionedFrame], params: &EstimatorParams) -> Vec<String> {
        let mut core = EstimatorCore::new(RigConfig::zhou2004().expect("built-in rig"), params.clone()).expect("valid parameters");
        frames.iter().flat_map(|f| core.push(f).expect("good frame")).map(|e| format!("{e:?}")).collect()
    }

    fn estimates(frames: &[ConditionedFrame], params: &EstimatorParams) -> Vec<CoefficientEstimate> {
        let mut core = EstimatorCore::new(RigConfig::zhou2004().expect("built-in rig"), params.clone()).expect("valid parameters");
        frames.iter().flat_map(|f| core.push(f).expect("good frame")).collect()
    }

    /// With `signal_band_hz` the standard errors come from a decimated window (here 50-fold:
    /// 100 000 samples at 50 kHz, down to the 2 000-sample floor) and agree with the full ones;
    /// the coefficients do not move.
    /// Frames declaring a wider low-pass than the parameter say the band is theirs.
    #[test]
    fn signal_band_decimates_only_the_standard_errors_and_frames_can_widen_it() {
        let fs = 50_000.0;
        let window = 100_000;
        let mut fr = noisy_frames(2 * window as usize, 10_000, fs, Some(40.0));
        for f in &mut fr {
            f.flags.push("lowpass_hz=55.5".into());
        }
        let full = EstimatorParams { window, hop: window, speed_rpm: 1500.0, ..EstimatorParams::default() };
        let banded = EstimatorParams { signal_band_hz: 55.5, ..full.clone() };
        let (a, b) = (estimates(&fr, &full), estimates(&fr, &banded));
        // The decimated samples and the factor are fed at fixed offsets: frames cut otherwise
        // give the same bits.
        let mut cut = noisy_frames(2 * window as usize, 7_777, fs, Some(40.0));
        for f in &mut cut {
            f.flags.push("lowpass_hz=55.5".into());
        }
        assert_eq!(format!("{:?}", estimates(&cut, &banded)), format!("{b:?}"));
        assert_eq!(a.len(), 2);
        assert_eq!(a.len(), b.len());
        for (a, b) in a.iter().zip(&b) {
            assert!(a.solved && b.solved);
            assert_eq!((a.stiffness_n_m, a.damping_n_s_m), (b.stiffness_n_m, b.damping_n_s_m));
            assert_ne!(a.stiffness_se_n_m, b.stiffness_se_n_m, "the standard errors were not decimated");
            for (x, y) in a.stiffness_se_n_m.iter().chain(&a.damping_se_n_s_m).zip(b.stiffness_se_n_m.iter().chain(&b.damping_se_n_s_m)) {
                assert!((y / x - 1.0).abs() < 0.02, "decimated SE {y} against {x}");
            }
        }
        // White noise breaks the band assumption: decimation folds it onto the lines, so the
        // decimated errors come out larger (up to about sqrt(50) here), never smaller.
        let mut white = frames(2 * window as usize, 10_000, fs);
        for f in &mut white {
            f.flags.push("lowpass_hz=55.5".into());
        }
        for (a, b) in estimates(&white, &full).iter().zip(&estimates(&white, &banded)) {
            for (x, y) in a.stiffness_se_n_m.iter().chain(&a.damping_se_n_s_m).zip(b.stiffness_se_n_m.iter().chain(&b.damping_se_n_s_m)) {
                assert!(y / x > 1.5, "white noise: decimated SE {y} against {x}");
            }
        }
        // A conditioner at 8 kHz leaves nothing to decimate at 50 kHz: the full errors.
        for f in &mut fr {
            f.flags = vec!["lowpass_hz=8000".into()];
        }
        let wide = estimates(&fr, &banded);
        assert_eq!(format!("{wide:?}"), format!("{:?}", estimates(&fr, &full)));
        // A band the record cannot have is refused by name.
        let bad = EstimatorParams { signal_band_hz: -3.0, ..full };
        assert!(EstimatorCore::new(RigConfig::zhou2004().expect("built-in rig"), bad).err().is_some_and(|e| e.to_string().contains("signal_band_hz")));
    }

    /// Windows completed by many small frames (line search fed while they arrive) and by one
    /// frame each (the search done at the end) give the same estimates, to the bit.
    #[test]
    fn fed_line_search_gives_the_batch_estimate() {
        let fs = 5000.0;
        for (window, hop) in [(25_000, 25_000), (20_000, 12_000)] {
            let params = EstimatorParams { window, hop, speed_rpm: 1500.0, ..EstimatorParams::default() };
            let total = 3 * window as usize;
            let batch = run(&frames(total, window as usize, fs), &params);
            assert!(batch.len() >= 2 && batch.iter().all(|e| e.contains("solved: true")), "{batch:?}");
            for size in [1_000, 777] {
                assert_eq!(run(&frames(total, size, fs), &params), batch, "frames of {size}, window {window}, hop {hop}");
            }
        }
    }
}
