//! The exciter node's core: an excitation plan turned into blocks of force setpoints on the
//! rig's clock, inside hard limits nothing can raise.
//!
//! Clock: the exciter is slaved to the DAQ, as an exciter's DAC is slaved to the acquisition
//! clock on a real rig. Each `rig/status` carries the rig time of the newest scan; the core
//! answers with setpoints from where it left off up to that time plus `lookahead_s`. The
//! plan's `t = 0` is the first rig time it sees (or the first setpoint after a new plan is
//! accepted), so a run is reproducible whatever the transport's timing.
//!
//! Limits, in three layers: (1) the rig file's `exciter_max_force_n` and `exciter_band_hz`
//! are hard limits fixed at start; (2) parameters and requests can only lower them, never
//! raise them, and a plan outside the effective limits is rejected with the reason; (3) every
//! setpoint is clamped to the effective force limit and NaN becomes 0 after all that, so no
//! request, parameter or waveform can make the node publish a force beyond its limit.

use std::f64::consts::PI;

use oilfilm_identification::excitation::{ExcitationPlan, LineSet, Limits, Waveform};
use oilfilm_msgs::{ExciterCommand, Header, BEARING_FRAME_ID};
use serde::{Deserialize, Serialize};

use crate::error::NodeError;
use crate::stamp::Stamp;

/// The longest block of setpoints one command carries, s (bounds memory whatever
/// `lookahead_s` and the rate say).
pub const MAX_BLOCK_S: f64 = 2.0;
/// Setpoint rates the node accepts, Hz.
pub const SETPOINT_RATE_RANGE_HZ: [f64; 2] = [10.0, 200_000.0];
/// Shortest ramp to zero on a stop, s.
pub const MIN_STOP_RAMP_S: f64 = 0.05;

/// The exciter node's parameters (ROS 2 parameters of the same names).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExciterParams {
    /// Rig file (TOML); empty: the built-in Zhou et al. (2004) rig.
    pub rig: String,
    /// `two_tone` (f1 on exciter 1, f2 on exciter 2: one record identifies all eight
    /// coefficients), `multisine` (Schroeder, odd/even lines per exciter), `sine` (the
    /// paper's: one frequency on both, which the estimator must refuse) or `off`.
    pub plan: String,
    pub frequency_1_hz: f64,
    pub frequency_2_hz: f64,
    /// Amplitude per exciter for `two_tone` and `sine`, N.
    pub amplitude_n: f64,
    /// Multisine band and period (line spacing 1 / period_s), and rms per exciter, N.
    pub band_low_hz: f64,
    pub band_high_hz: f64,
    pub period_s: f64,
    pub rms_n: f64,
    /// Raised-cosine ramp at start, s.
    pub ramp_s: f64,
    /// Setpoints per second (the DAQ rate, so the simulated rig gets one per scan).
    pub setpoint_rate_hz: f64,
    /// How far ahead of the rig clock the setpoints reach, s.
    pub lookahead_s: f64,
    /// Force limit per exciter, N; can lower the rig file's hard limit, never raise it
    /// (0: the hard limit).
    pub max_force_n: f64,
    /// Band every excitation line must lie in, Hz; can narrow the hard band, never widen it
    /// (both 0: the hard band).
    pub band_limit_low_hz: f64,
    pub band_limit_high_hz: f64,
}

impl Default for ExciterParams {
    fn default() -> Self {
        Self {
            rig: String::new(),
            plan: "two_tone".into(),
            frequency_1_hz: 23.0,
            frequency_2_hz: 37.0,
            amplitude_n: 100.0,
            band_low_hz: 5.0,
            band_high_hz: 80.0,
            period_s: 1.0,
            rms_n: 100.0,
            ramp_s: 0.5,
            setpoint_rate_hz: 5000.0,
            lookahead_s: 0.5,
            max_force_n: 0.0,
            band_limit_low_hz: 0.0,
            band_limit_high_hz: 0.0,
        }
    }
}

impl ExciterParams {
    /// The plan the parameters describe.
    pub fn plan(&self) -> Result<ExcitationPlan, NodeError> {
        let mut plan = match self.plan.as_str() {
            "two_tone" => ExcitationPlan::two_tone(self.frequency_1_hz, self.frequency_2_hz, self.amplitude_n),
            "multisine" => {
                let mut p = ExcitationPlan::multisine([self.band_low_hz, self.band_high_hz], self.period_s, self.rms_n);
                p.ramp_s = self.ramp_s;
                p
            }
            "sine" => ExcitationPlan::paper_sine(self.frequency_1_hz, self.amplitude_n),
            "off" => ExcitationPlan { exciters: [Waveform::Off, Waveform::Off], ramp_s: 0.0, amplitude_steps: Vec::new() },
            other => {
                return Err(NodeError::parameter(
                    "plan",
                    format!("`{other}` is not a plan (two_tone, multisine, sine, off)"),
                ))
            }
        };
        plan.ramp_s = self.ramp_s;
        Ok(plan)
    }

    /// The effective limits: the hard ones, lowered by the parameters.
    pub fn limits(&self, hard: &Limits) -> Result<Limits, NodeError> {
        let mut limits = *hard;
        let f = self.max_force_n;
        if !(f.is_finite() && f >= 0.0) {
            return Err(NodeError::parameter("max_force_n", format!("must be finite and >= 0 (0: the hard limit), got {f}")));
        }
        if f > hard.max_force_n {
            return Err(NodeError::parameter(
                "max_force_n",
                format!("{f} N exceeds the rig's hard limit {} N (exciter_max_force_n in the rig file)", hard.max_force_n),
            ));
        }
        if f > 0.0 {
            limits.max_force_n = f;
        }
        let (lo, hi) = (self.band_limit_low_hz, self.band_limit_high_hz);
        if !(lo == 0.0 && hi == 0.0) {
            if !(lo.is_finite() && hi.is_finite() && lo >= hard.band_hz[0] && hi <= hard.band_hz[1] && lo < hi) {
                return Err(NodeError::parameter(
                    "band_limit_low_hz",
                    format!("[{lo}, {hi}] Hz must be a band inside the rig's hard band [{}, {}] Hz", hard.band_hz[0], hard.band_hz[1]),
                ));
            }
            limits.band_hz = [lo, hi];
        }
        Ok(limits)
    }

    /// Checks every parameter; the error names the first bad one.
    pub fn validate(&self, hard: &Limits) -> Result<(), NodeError> {
        let r = self.setpoint_rate_hz;
        if !(SETPOINT_RATE_RANGE_HZ[0]..=SETPOINT_RATE_RANGE_HZ[1]).contains(&r) {
            return Err(NodeError::parameter(
                "setpoint_rate_hz",
                format!("must be in [{}, {}] Hz, got {r}", SETPOINT_RATE_RANGE_HZ[0], SETPOINT_RATE_RANGE_HZ[1]),
            ));
        }
        let l = self.lookahead_s;
        if !(l.is_finite() && l > 0.0 && l <= MAX_BLOCK_S) {
            return Err(NodeError::parameter("lookahead_s", format!("must be in (0, {MAX_BLOCK_S}] s, got {l}")));
        }
        if !(self.ramp_s.is_finite() && self.ramp_s >= 0.0) {
            return Err(NodeError::parameter("ramp_s", format!("must be finite and >= 0, got {}", self.ramp_s)));
        }
        let limits = self.limits(hard)?;
        self.plan()?
            .validate(&limits)
            .map_err(|e| NodeError::parameter("plan", format!("the {} plan is outside the limits: {e}", self.plan)))?;
        Ok(())
    }
}

/// A safe stop in progress: scale from 1 down to 0 over `ramp_s` from `from`.
#[derive(Debug, Clone, Copy)]
struct Stopping {
    from: Stamp,
    ramp_s: f64,
}

/// The exciter's state.
#[derive(Debug, Clone)]
pub struct ExciterCore {
    hard: Limits,
    limits: Limits,
    plan: ExcitationPlan,
    rate_hz: f64,
    lookahead_s: f64,
    /// Rig time of the plan's `t = 0` and of setpoint index 0 (set by the first rig time).
    origin: Option<Stamp>,
    /// Index of the next setpoint to publish, counted from `origin`.
    next_index: i64,
    sequence: u64,
    stopping: Option<Stopping>,
}

impl ExciterCore {
    /// A core with the rig's hard limits and validated parameters.
    pub fn new(hard: Limits, params: &ExciterParams) -> Result<Self, NodeError> {
        if !(hard.max_force_n.is_finite() && hard.max_force_n > 0.0) {
            return Err(NodeError::parameter("rig: exciter_max_force_n", format!("must be finite and > 0, got {}", hard.max_force_n)));
        }
        params.validate(&hard)?;
        Ok(Self {
            hard,
            limits: params.limits(&hard)?,
            plan: params.plan()?,
            rate_hz: params.setpoint_rate_hz,
            lookahead_s: params.lookahead_s,
            origin: None,
            next_index: 0,
            sequence: 0,
            stopping: None,
        })
    }

    pub fn limits(&self) -> Limits {
        self.limits
    }

    pub fn plan(&self) -> &ExcitationPlan {
        &self.plan
    }

    /// True once a stop was requested (the core then only ramps down and holds zero).
    pub fn is_stopping(&self) -> bool {
        self.stopping.is_some()
    }

    /// New parameters at run time (the parameter service): limits and plan change from the
    /// next setpoint; the rate and the rig cannot change while running.
    pub fn set_params(&mut self, params: &ExciterParams) -> Result<(), NodeError> {
        params.validate(&self.hard)?;
        if params.setpoint_rate_hz != self.rate_hz {
            return Err(NodeError::parameter("setpoint_rate_hz", "cannot change while running (restart the node)"));
        }
        let limits = params.limits(&self.hard)?;
        let plan = params.plan()?;
        self.limits = limits;
        self.lookahead_s = params.lookahead_s;
        self.replace_plan(plan);
        Ok(())
    }

    /// A request on `exciter/request`: a new waveform spec, or a stop. Rejected (with the
    /// reason, and the running plan kept) if the spec is malformed or outside the limits.
    pub fn request(&mut self, request: &ExciterCommand) -> Result<(), NodeError> {
        if request.stop {
            self.stop();
            return Ok(());
        }
        let reject = |reason: String| NodeError::BadMessage {
            topic: crate::topics::EXCITER_REQUEST.name.into(),
            sequence: request.sequence,
            reason,
        };
        let plan = plan_from_request(request).map_err(reject)?;
        plan.validate(&self.limits).map_err(|e| reject(format!("outside the exciter's limits: {e}")))?;
        self.stopping = None;
        self.replace_plan(plan);
        Ok(())
    }

    /// Starts a safe stop: from the next setpoint, ramp to zero and hold.
    pub fn stop(&mut self) {
        if self.stopping.is_none() {
            let from = self.origin.map_or(Stamp(0), |o| o.after_samples(self.next_index, self.rate_hz));
            self.stopping = Some(Stopping { from, ramp_s: self.plan.ramp_s.max(MIN_STOP_RAMP_S) });
        }
    }

    /// The plan restarts at the next setpoint (its ramp protects the rig from a jump).
    fn replace_plan(&mut self, plan: ExcitationPlan) {
        if let Some(origin) = self.origin {
            self.origin = Some(origin.after_samples(self.next_index, self.rate_hz));
            self.next_index = 0;
        }
        self.plan = plan;
    }

    /// The rig clock says `rig_time`: the setpoints due up to `rig_time + lookahead_s`
    /// (at most [`MAX_BLOCK_S`] of them), or `None` when nothing new is due.
    pub fn on_rig_time(&mut self, rig_time: Stamp) -> Option<ExciterCommand> {
        let origin = *self.origin.get_or_insert(rig_time);
        let horizon_s = rig_time.seconds_since(origin) + self.lookahead_s;
        let last = (horizon_s * self.rate_hz).floor() as i64;
        let max_block = (MAX_BLOCK_S * self.rate_hz) as i64;
        let end = last.min(self.next_index + max_block);
        if end < self.next_index {
            return None;
        }
        let start = self.next_index;
        let n = (end - start + 1) as usize;
        let (mut f1, mut f2) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for k in start..=end {
            let f = self.setpoint(origin, k);
            f1.push(f[0]);
            f2.push(f[1]);
        }
        self.next_index = end + 1;
        Some(self.command(origin.after_samples(start, self.rate_hz), f1, f2))
    }

    /// Setpoint `k` of the current plan, clamped, with the stop ramp applied.
    fn setpoint(&self, origin: Stamp, k: i64) -> [f64; 2] {
        // `k * (1 / rate)`, as the offline simulator computes its times, so that the graph
        // reproduces `oilfilm simulate` bit for bit.
        let t_s = k as f64 * (1.0 / self.rate_hz);
        let mut f = self.plan.force_at(t_s, &self.limits);
        if let Some(stop) = self.stopping {
            let at = origin.after_samples(k, self.rate_hz);
            let u = if stop.ramp_s > 0.0 { at.seconds_since(stop.from) / stop.ramp_s } else { 1.0 };
            let scale = if u <= 0.0 { 1.0 } else if u >= 1.0 { 0.0 } else { 0.5 + 0.5 * (PI * u).cos() };
            f = [f[0] * scale, f[1] * scale];
        }
        // Last line of defence: nothing beyond the limit, nothing non-finite.
        let max = self.limits.max_force_n;
        f.map(|v| if v.is_finite() { v.clamp(-max, max) } else { 0.0 })
    }

    /// The final command on shutdown: the ramp to zero from the next setpoint, then zeros,
    /// `stop = true`. `None` if the exciter never started (no rig time seen).
    pub fn shutdown(&mut self) -> Option<ExciterCommand> {
        let origin = self.origin?;
        self.stop();
        let ramp_s = self.stopping.map_or(MIN_STOP_RAMP_S, |s| s.ramp_s);
        let n = ((ramp_s * self.rate_hz).ceil() as i64 + 1).min((MAX_BLOCK_S * self.rate_hz) as i64);
        let start = self.next_index;
        let (mut f1, mut f2) = (Vec::new(), Vec::new());
        for k in start..start + n {
            let f = self.setpoint(origin, k);
            f1.push(f[0]);
            f2.push(f[1]);
        }
        // Hold zero after the ramp.
        f1.push(0.0);
        f2.push(0.0);
        self.next_index = start + n + 1;
        Some(self.command(origin.after_samples(start, self.rate_hz), f1, f2))
    }

    fn command(&mut self, first: Stamp, force_1_n: Vec<f64>, force_2_n: Vec<f64>) -> ExciterCommand {
        let mut m = spec_of(&self.plan);
        m.header = Header { stamp: first.to_time(), frame_id: BEARING_FRAME_ID.into() };
        m.sequence = self.sequence;
        self.sequence += 1;
        m.setpoint_rate_hz = self.rate_hz;
        m.force_1_n = force_1_n;
        m.force_2_n = force_2_n;
        m.max_force_n = self.limits.max_force_n;
        m.band_limit_low_hz = self.limits.band_hz[0];
        m.band_limit_high_hz = self.limits.band_hz[1];
        m.stop = self.stopping.is_some();
        m
    }
}

/// The waveform spec fields of a command describing `plan`.
pub fn spec_of(plan: &ExcitationPlan) -> ExciterCommand {
    let mut m = ExciterCommand { ramp_s: plan.ramp_s, amplitude_scale: 1.0, ..Default::default() };
    for (j, w) in plan.exciters.iter().enumerate() {
        match *w {
            Waveform::Off => m.waveform[j] = ExciterCommand::WAVEFORM_OFF,
            Waveform::Sine { frequency_hz, amplitude_n, phase_deg } => {
                m.waveform[j] = ExciterCommand::WAVEFORM_SINE;
                m.frequency_hz[j] = frequency_hz;
                m.amplitude_n[j] = amplitude_n;
                m.phase_rad[j] = phase_deg.to_radians();
            }
            Waveform::Multisine { band_hz, period_s, rms_n, line_set } => {
                m.waveform[j] = ExciterCommand::WAVEFORM_MULTISINE;
                m.band_low_hz[j] = band_hz[0];
                m.band_high_hz[j] = band_hz[1];
                m.period_s[j] = period_s;
                m.rms_n[j] = rms_n;
                m.line_set[j] = match line_set {
                    LineSet::All => ExciterCommand::LINES_ALL,
                    LineSet::Odd => ExciterCommand::LINES_ODD,
                    LineSet::Even => ExciterCommand::LINES_EVEN,
                };
            }
            Waveform::Chirp { start_hz, end_hz, sweep_s, amplitude_n } => {
                m.waveform[j] = ExciterCommand::WAVEFORM_CHIRP;
                m.chirp_start_hz[j] = start_hz;
                m.chirp_end_hz[j] = end_hz;
                m.sweep_s[j] = sweep_s;
                m.amplitude_n[j] = amplitude_n;
            }
        }
    }
    m
}

/// The plan a request's spec describes (setpoints in a request are ignored: the exciter
/// computes its own from the spec).
pub fn plan_from_request(m: &ExciterCommand) -> Result<ExcitationPlan, String> {
    let mut exciters = [Waveform::Off, Waveform::Off];
    for (j, w) in exciters.iter_mut().enumerate() {
        *w = match m.waveform[j] {
            ExciterCommand::WAVEFORM_OFF => Waveform::Off,
            ExciterCommand::WAVEFORM_SINE => Waveform::Sine {
                frequency_hz: m.frequency_hz[j],
                amplitude_n: m.amplitude_n[j],
                phase_deg: m.phase_rad[j].to_degrees(),
            },
            ExciterCommand::WAVEFORM_MULTISINE => Waveform::Multisine {
                band_hz: [m.band_low_hz[j], m.band_high_hz[j]],
                period_s: m.period_s[j],
                rms_n: m.rms_n[j],
                line_set: match m.line_set[j] {
                    ExciterCommand::LINES_ALL => LineSet::All,
                    ExciterCommand::LINES_ODD => LineSet::Odd,
                    ExciterCommand::LINES_EVEN => LineSet::Even,
                    other => return Err(format!("line_set[{j}] = {other} is not LINES_ALL, LINES_ODD or LINES_EVEN")),
                },
            },
            ExciterCommand::WAVEFORM_CHIRP => Waveform::Chirp {
                start_hz: m.chirp_start_hz[j],
                end_hz: m.chirp_end_hz[j],
                sweep_s: m.sweep_s[j],
                amplitude_n: m.amplitude_n[j],
            },
            other => return Err(format!("waveform[{j}] = {other} is not WAVEFORM_OFF, _SINE, _MULTISINE or _CHIRP")),
        };
    }
    if !(m.ramp_s.is_finite() && m.ramp_s >= 0.0) {
        return Err(format!("ramp_s must be finite and >= 0, got {}", m.ramp_s));
    }
    let scale = m.amplitude_scale;
    if !(scale.is_finite() && (0.0..=1.0).contains(&scale)) {
        return Err(format!("amplitude_scale must be in [0, 1], got {scale}"));
    }
    // amplitude_scale 0 (the .msg default) means 1: an unset field must not silence the plan.
    let scale = if scale == 0.0 { 1.0 } else { scale };
    for w in &mut exciters {
        match w {
            Waveform::Off => {}
            Waveform::Sine { amplitude_n, .. } | Waveform::Chirp { amplitude_n, .. } => *amplitude_n *= scale,
            Waveform::Multisine { rms_n, .. } => *rms_n *= scale,
        }
    }
    let plan = ExcitationPlan { exciters, ramp_s: m.ramp_s, amplitude_steps: Vec::new() };
    Ok(plan)
}
