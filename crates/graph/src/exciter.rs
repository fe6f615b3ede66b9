//! The exciter node's core: an excitation plan turned into blocks of force setpoints on the
//! rig's clock, inside hard limits nothing can raise.
//!
//! Clock: the exciter is slaved to the DAQ, as an exciter's DAC is slaved to the acquisition
//! clock on a real rig. Each `rig/status` carries the rig time of the newest scan; the core
//! answers with setpoints from where it left off up to that time plus `lookahead_s`. The
//! plan's `t = 0` is the first rig time it sees (or the first setpoint after a new plan is
//! accepted), so a run is reproducible whatever the transport's timing.
//!
//! Limits, in three layers: (1) the rig file's `exciter_max_force_n`, `exciter_band_hz` and
//! `exciter_max_slew_n_per_s` are hard limits fixed at start ([`HardLimits`]); (2) parameters
//! and requests can only lower the force and band limits, never raise them, and a plan outside
//! the effective limits (its peak, its lines, or its steepest rise against the slew limit) is
//! rejected with the reason; (3) every setpoint is clamped to the effective force limit, NaN
//! becomes 0, and it moves from the previous setpoint by at most the slew limit, so no
//! request, parameter or waveform can make the node publish a force beyond its limit or a
//! step.
//!
//! ## Transitions: the force never steps
//! Every change of what the exciters do is a ramp. A plan's `t = 0` starts with its own
//! raised-cosine ramp (`ramp_s`). A new plan of another shape (other waveforms or
//! frequencies) first ramps the running one down to zero over the new plan's `ramp_s`, then
//! starts the new one with its ramp; a change of amplitude only (the same waveforms)
//! cross-fades the two amplitudes over `ramp_s` on the running plan's clock, so the phase runs
//! on. A stop, the node's shutdown and the loss of the last subscriber of `exciter/command`
//! ramp to zero over the running plan's `ramp_s` and hold zero; after a lost subscriber the
//! plan starts again, with its ramp, once a subscriber is back. Every ramp down or cross-fade
//! lasts at least [`MIN_RAMP_S`] and at most [`MAX_TRANSITION_S`]; a new transition during one
//! shortens it, from where the force is, never lengthens it. Under all of that, each setpoint
//! differs from the one before by at most `exciter_max_slew_n_per_s / setpoint_rate_hz`,
//! whatever the ramps are (a `ramp_s` of 0 moves at the slew limit). The ramps live on the
//! setpoint grid (indices, no clock), so a run is as reproducible as before.

use std::f64::consts::PI;

use oilfilm_identification::excitation::{ExcitationPlan, Limits, LineSet, Waveform};
use oilfilm_identification::simulate::limits_of;
use oilfilm_msgs::{ExciterCommand, Header, RigStatus, BEARING_FRAME_ID};
use oilfilm_physics::config::RigConfig;
use serde::{Deserialize, Serialize};

use crate::error::NodeError;
use crate::node::{skipped, Connect, Input, Node, Output, Start, Turn};
use crate::params::{NodeParams, Rule, Spec};
use crate::stamp::Stamp;
use crate::topics;

/// The longest block of setpoints one command carries, s (bounds memory whatever
/// `lookahead_s` and the rate say).
pub const MAX_BLOCK_S: f64 = 2.0;
/// Setpoint rates the node accepts, Hz.
pub const SETPOINT_RATE_RANGE_HZ: [f64; 2] = [10.0, 200_000.0];
/// Shortest ramp of any transition (a plan's own `ramp_s` can be 0), s.
pub const MIN_RAMP_S: f64 = 0.05;
/// Longest ramp of a transition (down to zero, or a cross-fade), s, whatever a plan's
/// `ramp_s`: a stop must not take minutes, and the shutdown's last command must hold the
/// whole ramp. (A plan's own start ramp is its `ramp_s`, however long.)
pub const MAX_TRANSITION_S: f64 = 1.5;

/// The rig's hard limits on its exciters (the rig file's `[housing]` values): nothing a
/// parameter or request says can raise them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HardLimits {
    /// `exciter_max_force_n` and `exciter_band_hz`.
    pub force: Limits,
    /// `exciter_max_slew_n_per_s`: the fastest an exciter's force may change, N/s.
    pub max_slew_n_per_s: f64,
}

impl HardLimits {
    pub fn of(rig: &RigConfig) -> Self {
        Self { force: limits_of(rig), max_slew_n_per_s: rig.housing.exciter_max_slew_n_per_s }
    }
}

/// The steepest rise of `plan`'s forces at full amplitude, N/s: `2 pi f A` for a sine (a
/// chirp: at its highest frequency); for a multisine the sum of its lines' `2 pi f a` when
/// that is below `limit`, else the largest derivative over one period sampled densely, plus
/// the most it can rise between samples. Scaled by the largest amplitude step. The ramps come
/// on top, and the slew limiter holds every setpoint to the limit regardless: this is what a
/// plan must fit to run undistorted.
pub fn steepest_rise_n_per_s(plan: &ExcitationPlan, limit: f64) -> f64 {
    let scale = plan.amplitude_steps.iter().fold(if plan.amplitude_steps.is_empty() { 1.0 } else { 0.0 }, |m: f64, s| m.max(s.scale.abs()));
    plan.exciters.iter().map(|w| waveform_rise(w, limit / scale.max(f64::MIN_POSITIVE))).fold(0.0, f64::max) * scale
}

fn waveform_rise(w: &Waveform, limit: f64) -> f64 {
    match *w {
        Waveform::Off => 0.0,
        Waveform::Sine { frequency_hz, amplitude_n, .. } => 2.0 * PI * frequency_hz.abs() * amplitude_n.abs(),
        Waveform::Chirp { start_hz, end_hz, amplitude_n, .. } => 2.0 * PI * start_hz.abs().max(end_hz.abs()) * amplitude_n.abs(),
        Waveform::Multisine { period_s, .. } => {
            let tones = w.tones();
            let omega = |f: f64| 2.0 * PI * f;
            let bound: f64 = tones.iter().map(|t| omega(t.frequency_hz) * t.amplitude_n.abs()).sum();
            if bound <= limit || !(period_s.is_finite() && period_s > 0.0) {
                return bound;
            }
            // Dense enough for the top line, bounded so a request is answered quickly.
            let top = tones.iter().map(|t| t.frequency_hz * period_s).fold(0.0, f64::max);
            let points = ((32.0 * top).ceil() as usize).clamp(4096, 1 << 18);
            let dt = period_s / points as f64;
            let mut steepest: f64 = 0.0;
            for i in 0..points {
                let t = i as f64 * dt;
                let d: f64 =
                    tones.iter().map(|tone| -omega(tone.frequency_hz) * tone.amplitude_n * (omega(tone.frequency_hz) * t + tone.phase_rad).sin()).sum();
                steepest = steepest.max(d.abs());
            }
            let curvature: f64 = tones.iter().map(|t| omega(t.frequency_hz).powi(2) * t.amplitude_n.abs()).sum();
            (steepest + 0.5 * curvature * dt).min(bound)
        }
    }
}

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
    /// Raised-cosine ramp of every transition (start, plan or amplitude change, stop), s.
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

impl NodeParams for ExciterParams {
    fn specs() -> Vec<Spec> {
        let hz = Rule::above(0.0, 100_000.0);
        let newtons = Rule::number(0.0, 1e7);
        vec![
            Spec::fixed("rig", "rig file (TOML) whose hard exciter limits bound everything else; empty: the built-in Zhou et al. (2004) rig", Rule::Any),
            Spec::live("plan", "excitation: two_tone (f1 on exciter 1, f2 on exciter 2: one record identifies all eight coefficients), multisine (Schroeder, odd/even lines per exciter), sine (the paper's one frequency on both: the estimator refuses it) or off", Rule::OneOf(&["two_tone", "multisine", "sine", "off"])),
            Spec::live("frequency_1_hz", "exciter 1's frequency (two_tone; sine: both exciters), Hz", hz.clone()).with_constraints("inside the exciter band (band_limit_*_hz, else the rig file's exciter_band_hz)"),
            Spec::live("frequency_2_hz", "exciter 2's frequency (two_tone), Hz", hz).with_constraints("inside the exciter band (band_limit_*_hz, else the rig file's exciter_band_hz)"),
            Spec::live("amplitude_n", "force amplitude per exciter (two_tone, sine), N", newtons.clone()).with_constraints("at most max_force_n (else the rig file's exciter_max_force_n); its slope 2 pi f A within the rig file's exciter_max_slew_n_per_s"),
            Spec::live("band_low_hz", "multisine: lowest line, Hz", Rule::above(0.0, 100_000.0)).with_constraints("below band_high_hz, inside the exciter band"),
            Spec::live("band_high_hz", "multisine: highest line, Hz", Rule::above(0.0, 100_000.0)).with_constraints("inside the exciter band"),
            Spec::live("period_s", "multisine: period, s (line spacing 1 / period_s)", Rule::above(0.0, 3600.0)),
            Spec::live("rms_n", "multisine: rms force per exciter, N", newtons.clone()).with_constraints("its peak at most max_force_n, its steepest rise within the slew limit"),
            Spec::live("ramp_s", "raised-cosine ramp of every transition (start, plan or amplitude change, stop), s; transitions take at least 0.05 s and ramps down at most 1.5 s", Rule::number(0.0, 3600.0)),
            Spec::fixed("setpoint_rate_hz", "force setpoints per second (the DAQ's scan rate, so the simulated rig gets one per scan)", Rule::number(SETPOINT_RATE_RANGE_HZ[0], SETPOINT_RATE_RANGE_HZ[1])),
            Spec::live("lookahead_s", "how far ahead of the rig clock the setpoints reach, s", Rule::above(0.0, MAX_BLOCK_S)),
            Spec::live("max_force_n", "force limit per exciter, N; lowers the rig file's exciter_max_force_n, never raises it; 0: the rig file's", newtons).with_constraints("at most the rig file's exciter_max_force_n"),
            Spec::live("band_limit_low_hz", "lower edge of the band every line must lie in, Hz; narrows the rig file's exciter_band_hz, never widens it; both edges 0: the rig file's", Rule::number(0.0, 100_000.0)).with_constraints("with band_limit_high_hz a band inside the rig file's exciter_band_hz"),
            Spec::live("band_limit_high_hz", "upper edge of that band, Hz (0 with band_limit_low_hz 0: the rig file's)", Rule::number(0.0, 100_000.0)).with_constraints("above band_limit_low_hz, inside the rig file's exciter_band_hz"),
        ]
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
            other => return Err(NodeError::parameter("plan", format!("`{other}` is not a plan (two_tone, multisine, sine, off)"))),
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
    pub fn validate(&self, hard: &HardLimits) -> Result<(), NodeError> {
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
        let limits = self.limits(&hard.force)?;
        check_plan(&self.plan()?, &limits, hard.max_slew_n_per_s)
            .map_err(|e| NodeError::parameter("plan", format!("the {} plan is outside the limits: {e}", self.plan)))
    }
}

/// A plan inside the force and band limits whose steepest rise fits the slew limit; the error
/// says which limit and by how much.
pub fn check_plan(plan: &ExcitationPlan, limits: &Limits, max_slew_n_per_s: f64) -> Result<(), String> {
    plan.validate(limits).map_err(|e| e.to_string())?;
    let rise = steepest_rise_n_per_s(plan, max_slew_n_per_s);
    // NaN (a malformed waveform) is refused too.
    if rise.is_nan() || rise > max_slew_n_per_s {
        return Err(format!(
            "its force rises at up to {rise:.0} N/s, beyond the exciters' slew limit {max_slew_n_per_s:.0} N/s (rig file: housing.exciter_max_slew_n_per_s): lower the amplitude or the frequency"
        ));
    }
    Ok(())
}

/// A raised-cosine ramp on the setpoint grid: 0 up to setpoint `from`, 1 from `from + len` on.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Fade {
    from: i64,
    len: i64,
}

impl Fade {
    fn rise(&self, k: i64) -> f64 {
        if k <= self.from {
            0.0
        } else if k >= self.end() {
            1.0
        } else {
            0.5 - 0.5 * (PI * (k - self.from) as f64 / self.len as f64).cos()
        }
    }

    fn end(&self) -> i64 {
        self.from + self.len
    }
}

/// A ramp down from `level` (1: full) to 0.
#[derive(Debug, Clone, Copy, PartialEq)]
struct FadeOut {
    fade: Fade,
    level: f64,
}

impl FadeOut {
    fn gain(&self, k: i64) -> f64 {
        if self.level == 1.0 {
            1.0 - self.fade.rise(k)
        } else {
            self.level * (1.0 - self.fade.rise(k))
        }
    }
}

/// One plan on the setpoint grid: its `t = 0` is setpoint `start`, its forces are clamped to
/// `limits` and scaled by its fades (a cross-fade in, a ramp out).
#[derive(Debug, Clone)]
struct Segment {
    plan: ExcitationPlan,
    limits: Limits,
    start: i64,
    fade_in: Option<Fade>,
    fade_out: Option<FadeOut>,
}

impl Segment {
    fn force(&self, k: i64, rate_hz: f64) -> [f64; 2] {
        // `k * (1 / rate)`, as the offline simulator computes its times, so that the graph
        // reproduces `oilfilm simulate` bit for bit.
        let t_s = (k - self.start) as f64 * (1.0 / rate_hz);
        let f = self.plan.force_at(t_s, &self.limits);
        let gain = self.fade_in.map_or(1.0, |f| f.rise(k)) * self.fade_out.map_or(1.0, |f| f.gain(k));
        if gain == 1.0 {
            f
        } else {
            f.map(|v| v * gain)
        }
    }

    /// Zero from setpoint `k` on.
    fn over_by(&self, k: i64) -> bool {
        self.fade_out.is_some_and(|f| f.fade.end() <= k)
    }
}

/// A plan waiting to start, not before setpoint `not_before` (the end of the ramps down).
#[derive(Debug, Clone)]
struct Pending {
    plan: ExcitationPlan,
    limits: Limits,
    not_before: i64,
}

/// Why the force is ramping down or held at zero.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Halt {
    /// A stop request or the node's shutdown: zero until a new plan is requested.
    Stopped,
    /// The last subscriber of the commands went away: zero until one is back.
    NoSubscriber,
}

/// Two plans are the same but for their amplitudes (a change between them cross-fades on
/// one clock instead of going through zero).
fn same_shape(a: &ExcitationPlan, b: &ExcitationPlan) -> bool {
    let unit = |p: &ExcitationPlan| {
        let mut p = p.clone();
        p.ramp_s = 0.0;
        for w in &mut p.exciters {
            match w {
                Waveform::Off => {}
                Waveform::Sine { amplitude_n, .. } | Waveform::Chirp { amplitude_n, .. } => *amplitude_n = 1.0,
                Waveform::Multisine { rms_n, .. } => *rms_n = 1.0,
            }
        }
        p
    };
    a.amplitude_steps.is_empty() && b.amplitude_steps.is_empty() && unit(a) == unit(b)
}

/// The exciter's state.
#[derive(Debug, Clone)]
pub struct ExciterCore {
    hard: HardLimits,
    limits: Limits,
    /// The plan asked for last (running, waiting to start, or to resume).
    plan: ExcitationPlan,
    rate_hz: f64,
    lookahead_s: f64,
    /// Rig time of setpoint index 0 (set by the first rig time).
    origin: Option<Stamp>,
    /// Index of the next setpoint to publish, counted from `origin`.
    next_index: i64,
    sequence: u64,
    /// The plans contributing to the setpoints (at most a few during a transition).
    segments: Vec<Segment>,
    pending: Option<Pending>,
    halt: Option<Halt>,
    /// The last setpoint computed: the slew limiter's state (the exciters start at rest).
    last: [f64; 2],
}

impl ExciterCore {
    /// A core with the rig's hard limits and validated parameters.
    pub fn new(hard: HardLimits, params: &ExciterParams) -> Result<Self, NodeError> {
        if !(hard.force.max_force_n.is_finite() && hard.force.max_force_n > 0.0) {
            return Err(NodeError::parameter("rig: exciter_max_force_n", format!("must be finite and > 0, got {}", hard.force.max_force_n)));
        }
        if !(hard.max_slew_n_per_s.is_finite() && hard.max_slew_n_per_s > 0.0) {
            return Err(NodeError::parameter("rig: exciter_max_slew_n_per_s", format!("must be finite and > 0, got {}", hard.max_slew_n_per_s)));
        }
        params.validate(&hard)?;
        let limits = params.limits(&hard.force)?;
        let plan = params.plan()?;
        Ok(Self {
            hard,
            limits,
            pending: Some(Pending { plan: plan.clone(), limits, not_before: 0 }),
            plan,
            rate_hz: params.setpoint_rate_hz,
            lookahead_s: params.lookahead_s,
            origin: None,
            next_index: 0,
            sequence: 0,
            segments: Vec::new(),
            halt: None,
            last: [0.0; 2],
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
        self.halt == Some(Halt::Stopped)
    }

    /// True while the force is held at zero for want of a subscriber.
    pub fn is_waiting_for_subscriber(&self) -> bool {
        self.halt == Some(Halt::NoSubscriber)
    }

    /// The largest change between consecutive setpoints, N.
    pub fn max_step_n(&self) -> f64 {
        self.hard.max_slew_n_per_s / self.rate_hz
    }

    /// New parameters at run time (the parameter service): limits and plan change from the
    /// next setpoint, through the transition ramps; the rate and the rig cannot change while
    /// running.
    pub fn set_params(&mut self, params: &ExciterParams) -> Result<(), NodeError> {
        params.validate(&self.hard)?;
        if params.setpoint_rate_hz != self.rate_hz {
            return Err(NodeError::parameter("setpoint_rate_hz", "cannot change while running (restart the node)"));
        }
        let limits = params.limits(&self.hard.force)?;
        let plan = params.plan()?;
        self.lookahead_s = params.lookahead_s;
        if plan == self.plan {
            // The plan fits the new limits (validated), so they apply at once.
            self.limits = limits;
            for s in self.segments.iter_mut().filter(|s| s.plan == plan) {
                s.limits = limits;
            }
            if let Some(p) = &mut self.pending {
                p.limits = limits;
            }
            return Ok(());
        }
        self.limits = limits;
        self.change_plan(plan);
        Ok(())
    }

    /// A request on `exciter/request`: a new waveform spec, or a stop. Rejected (with the
    /// reason, and the running plan kept) if the spec is malformed or outside the limits.
    pub fn request(&mut self, request: &ExciterCommand) -> Result<(), NodeError> {
        if request.stop {
            self.stop();
            return Ok(());
        }
        let reject = |reason: String| NodeError::BadMessage { topic: crate::topics::EXCITER_REQUEST.name.into(), sequence: request.sequence, reason };
        let plan = plan_from_request(request).map_err(reject)?;
        check_plan(&plan, &self.limits, self.hard.max_slew_n_per_s).map_err(|e| reject(format!("outside the exciter's limits: {e}")))?;
        if self.halt == Some(Halt::Stopped) {
            self.halt = None;
        }
        self.change_plan(plan);
        Ok(())
    }

    /// Setpoints of a transition of `ramp_s` (a plan's).
    fn ramp_len(&self, ramp_s: f64) -> i64 {
        (ramp_s.clamp(MIN_RAMP_S, MAX_TRANSITION_S) * self.rate_hz).ceil() as i64
    }

    /// Setpoints of a ramp to zero from the running plan.
    fn stop_len(&self) -> i64 {
        self.ramp_len(self.plan.ramp_s)
    }

    /// Ramps every segment down to zero from the next setpoint over `len` (one already
    /// ramping down and due to end later: from where it is now); returns the setpoint from
    /// which they are all zero.
    fn ramp_down(&mut self, len: i64) -> i64 {
        let from = self.next_index;
        let fade = Fade { from, len };
        let mut end = from;
        for s in &mut self.segments {
            s.fade_out = match s.fade_out {
                Some(f) if f.fade.end() <= fade.end() => Some(f),
                Some(f) => Some(FadeOut { fade, level: f.gain(from) }),
                None => Some(FadeOut { fade, level: 1.0 }),
            };
            end = end.max(s.fade_out.map_or(from, |f| f.fade.end()));
        }
        end
    }

    /// Moves to `plan` from the next setpoint: a cross-fade if only amplitudes change, else
    /// a ramp down of what runs and then the new plan from zero with its own ramp.
    fn change_plan(&mut self, plan: ExcitationPlan) {
        self.plan = plan.clone();
        if self.halt == Some(Halt::NoSubscriber) {
            // Started when a subscriber is back.
            return;
        }
        let len = self.ramp_len(plan.ramp_s);
        let running = self.segments.iter().rposition(|s| s.fade_out.is_none());
        match running {
            Some(i) if self.pending.is_none() && same_shape(&self.segments[i].plan, &plan) => {
                let fade = Fade { from: self.next_index, len };
                let start = self.segments[i].start;
                self.segments[i].fade_out = Some(FadeOut { fade, level: 1.0 });
                self.segments.push(Segment { plan, limits: self.limits, start, fade_in: Some(fade), fade_out: None });
            }
            _ => {
                let not_before = self.ramp_down(len);
                self.pending = Some(Pending { plan, limits: self.limits, not_before });
            }
        }
    }

    /// Starts a safe stop: from the next setpoint, ramp to zero and hold.
    pub fn stop(&mut self) {
        if self.halt != Some(Halt::Stopped) {
            self.halt = Some(Halt::Stopped);
            self.pending = None;
            let len = self.stop_len();
            self.ramp_down(len);
        }
    }

    /// The last subscriber of the commands went away: the ramp to zero from the next setpoint
    /// and zero held, as one command (`stop = true`; a subscriber that comes back gets it
    /// first, from the transient-local history). The plan starts again, from zero with its
    /// ramp, at [`ExciterCore::subscriber_back`]. `None` if nothing was running.
    pub fn subscriber_lost(&mut self) -> Option<ExciterCommand> {
        if self.halt.is_some() {
            return None;
        }
        self.halt = Some(Halt::NoSubscriber);
        self.pending = None;
        let len = self.stop_len();
        self.ramp_down(len);
        self.final_ramp()
    }

    /// A subscriber is back after [`ExciterCore::subscriber_lost`]: the plan starts again at
    /// the next rig time, from zero with its ramp.
    pub fn subscriber_back(&mut self) {
        if self.halt == Some(Halt::NoSubscriber) {
            self.halt = None;
            self.pending = Some(Pending { plan: self.plan.clone(), limits: self.limits, not_before: self.next_index });
        }
    }

    /// The setpoint index of rig time `t` (the last one at or before it).
    fn index_of(&self, origin: Stamp, t: Stamp) -> i64 {
        ((t.0 - origin.0) as f64 * self.rate_hz * 1e-9).floor() as i64
    }

    /// Nothing is moving: no segment left and the last setpoint zero.
    fn at_rest(&self) -> bool {
        self.segments.is_empty() && self.last == [0.0; 2]
    }

    /// The rig clock says `rig_time`: the setpoints due up to `rig_time + lookahead_s`
    /// (at most [`MAX_BLOCK_S`] of them), or `None` when nothing new is due.
    pub fn on_rig_time(&mut self, rig_time: Stamp) -> Option<ExciterCommand> {
        let origin = *self.origin.get_or_insert(rig_time);
        let rig_index = self.index_of(origin, rig_time);
        if self.at_rest() && self.next_index < rig_index {
            // The rig clock ran on while nothing moved (a subscriber came back, the rig
            // restarted): a plan starts from now, not from a past the rig has left.
            self.next_index = rig_index;
        }
        if self.halt.is_none() {
            if let Some(p) = self.pending.take() {
                let start = self.next_index.max(p.not_before);
                self.segments.push(Segment { plan: p.plan, limits: p.limits, start, fade_in: None, fade_out: None });
            }
        }
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
            let f = self.setpoint(k);
            f1.push(f[0]);
            f2.push(f[1]);
        }
        let max_force_n = self.force_limit();
        self.next_index = end + 1;
        self.segments.retain(|s| !s.over_by(end + 1));
        Some(self.command(origin.after_samples(start, self.rate_hz), f1, f2, max_force_n))
    }

    /// The force limit in force: the largest of the segments' (a plan ramping down keeps the
    /// limit it ran under), or the parameters'.
    fn force_limit(&self) -> f64 {
        self.segments.iter().map(|s| s.limits.max_force_n).fold(self.limits.max_force_n, f64::max)
    }

    /// Setpoint `k`: the segments' sum, clamped, then moved from the last setpoint by at most
    /// the slew limit.
    fn setpoint(&mut self, k: i64) -> [f64; 2] {
        let mut target = [0.0; 2];
        for (i, s) in self.segments.iter().enumerate() {
            let f = s.force(k, self.rate_hz);
            if i == 0 {
                target = f;
            } else {
                target = [target[0] + f[0], target[1] + f[1]];
            }
        }
        let max = self.force_limit();
        let step = self.max_step_n();
        let mut out = [0.0; 2];
        for j in 0..2 {
            let t = if target[j].is_finite() { target[j].clamp(-max, max) } else { 0.0 };
            let d = t - self.last[j];
            out[j] = if d.abs() <= step { t } else { self.last[j] + step.copysign(d) };
        }
        self.last = out;
        out
    }

    /// One command from the next setpoint through the ramp down to zero, zero held after.
    fn final_ramp(&mut self) -> Option<ExciterCommand> {
        let origin = self.origin?;
        let zero_from = self.segments.iter().filter_map(|s| s.fade_out.map(|f| f.fade.end())).max().unwrap_or(self.next_index);
        // The slew limiter may trail the ramp by at most the largest force over the step.
        let tail = (self.force_limit() / self.max_step_n()).ceil() as i64 + 1;
        let start = self.next_index;
        let (mut f1, mut f2) = (Vec::new(), Vec::new());
        let max_force_n = self.force_limit();
        let mut k = start;
        while k < zero_from + tail && !(k >= zero_from && self.last == [0.0; 2]) {
            let f = self.setpoint(k);
            f1.push(f[0]);
            f2.push(f[1]);
            k += 1;
        }
        // Hold zero after the ramp.
        f1.push(0.0);
        f2.push(0.0);
        self.next_index = k + 1;
        self.segments.retain(|s| !s.over_by(k));
        Some(self.command(origin.after_samples(start, self.rate_hz), f1, f2, max_force_n))
    }

    /// The final command on shutdown: the ramp to zero from the next setpoint, then zero,
    /// `stop = true`. `None` if the exciter never started (no rig time seen).
    pub fn shutdown(&mut self) -> Option<ExciterCommand> {
        self.origin?;
        self.halt = None;
        self.stop();
        self.final_ramp()
    }

    fn command(&mut self, first: Stamp, force_1_n: Vec<f64>, force_2_n: Vec<f64>, max_force_n: f64) -> ExciterCommand {
        let mut m = spec_of(&self.plan);
        m.header = Header { stamp: first.to_time(), frame_id: BEARING_FRAME_ID.into() };
        m.sequence = self.sequence;
        self.sequence += 1;
        m.setpoint_rate_hz = self.rate_hz;
        m.force_1_n = force_1_n;
        m.force_2_n = force_2_n;
        m.max_force_n = max_force_n;
        m.band_limit_low_hz = self.limits.band_hz[0];
        m.band_limit_high_hz = self.limits.band_hz[1];
        m.stop = self.halt.is_some();
        m
    }
}

/// How long the exciter waits, as it stops, for its subscribers to acknowledge the ramp.
const STOP_ACK: std::time::Duration = std::time::Duration::from_secs(3);

/// The exciter node: requests and the rig clock in, setpoints out.
pub struct Exciter {
    core: ExciterCore,
    /// Subscribers of the commands at the last turn, if the port can tell.
    subscribers: Option<usize>,
}

pub struct ExciterPorts<'a> {
    pub requests: Input<'a, ExciterCommand>,
    pub status: Input<'a, RigStatus>,
    pub commands: Output<'a, ExciterCommand>,
}

impl Exciter {
    pub fn core(&self) -> &ExciterCore {
        &self.core
    }
}

impl Node for Exciter {
    const NAME: &'static str = "exciter";
    type Params = ExciterParams;
    type Ports<'a> = ExciterPorts<'a>;

    fn new(params: &ExciterParams, start: &Start) -> Result<Self, NodeError> {
        let rig = (start.rig)(&params.rig)?;
        Ok(Self { core: ExciterCore::new(HardLimits::of(&rig), params)?, subscribers: None })
    }

    fn connect<C: Connect>(&self, c: &mut C) -> Result<ExciterPorts<'static>, NodeError> {
        Ok(ExciterPorts {
            requests: c.input(&topics::EXCITER_REQUEST)?,
            status: c.input(&topics::RIG_STATUS)?,
            commands: c.acknowledged_output(&topics::EXCITER_COMMAND)?,
        })
    }

    /// Requests first (a new plan applies from the next setpoint), then the subscribers of
    /// the commands (the last one gone: ramp down; one back: start again), then the newest
    /// rig time.
    fn turn(&mut self, _now: Stamp, ports: &mut ExciterPorts<'_>) -> Result<Turn, NodeError> {
        let mut turn = Turn::default();
        while let Some(req) = ports.requests.receive()? {
            turn.handled += 1;
            match self.core.request(&req) {
                Ok(()) => tracing::info!(node = "exciter", "request {} accepted{}", req.sequence, if req.stop { ": stopping" } else { "" }),
                Err(e) => skipped("exciter", &e),
            }
        }
        if let Some(now) = ports.commands.readers() {
            match (self.subscribers, now) {
                (Some(before), 0) if before > 0 => {
                    if let Some(cmd) = self.core.subscriber_lost() {
                        tracing::warn!(
                            node = "exciter",
                            "no subscriber left on {}: ramping to zero over {} setpoints; the plan starts again when one is back",
                            topics::EXCITER_COMMAND.name,
                            cmd.force_1_n.len()
                        );
                        ports.commands.publish(cmd)?;
                        turn.handled += 1;
                    }
                }
                (_, n) if n > 0 && self.core.is_waiting_for_subscriber() => {
                    tracing::info!(node = "exciter", "a subscriber is back on {}: starting the plan again with its ramp", topics::EXCITER_COMMAND.name);
                    self.core.subscriber_back();
                }
                _ => {}
            }
            self.subscribers = Some(now);
        }
        let mut rig_time = None;
        while let Some(status) = ports.status.receive()? {
            turn.handled += 1;
            rig_time = Some(Stamp::from_time(&status.header.stamp));
        }
        if let Some(t) = rig_time {
            if let Some(cmd) = self.core.on_rig_time(t) {
                ports.commands.publish(cmd)?;
                turn.handled += 1;
            }
        }
        Ok(turn)
    }

    fn reconfigure(&mut self, params: &ExciterParams) -> Result<(), NodeError> {
        self.core.set_params(params)?;
        tracing::info!(node = "exciter", "parameters changed: plan {:?}, limit {} N", self.core.plan().exciters, self.core.limits().max_force_n);
        Ok(())
    }

    /// Safe stop: ramp both exciters to zero and hold.
    fn finish(&mut self, _now: Stamp, ports: &mut ExciterPorts<'_>) -> Result<(), NodeError> {
        if let Some(cmd) = self.core.shutdown() {
            tracing::info!(node = "exciter", "stopping: ramp to zero over {} setpoints", cmd.force_1_n.len());
            ports.commands.publish(cmd)?;
            // A rig driver that misses the ramp holds the last setpoint: wait until every
            // subscriber has it (a sending lost in a burst is repaired only on the next
            // heartbeat) rather than leave DDS after a fixed linger.
            if !ports.commands.flush(STOP_ACK)? {
                tracing::warn!(node = "exciter", "not every subscriber of {} acknowledged the ramp to zero within {STOP_ACK:?}", topics::EXCITER_COMMAND.name);
            }
        }
        Ok(())
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
            ExciterCommand::WAVEFORM_SINE => {
                Waveform::Sine { frequency_hz: m.frequency_hz[j], amplitude_n: m.amplitude_n[j], phase_deg: m.phase_rad[j].to_degrees() }
            }
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
            ExciterCommand::WAVEFORM_CHIRP => {
                Waveform::Chirp { start_hz: m.chirp_start_hz[j], end_hz: m.chirp_end_hz[j], sweep_s: m.sweep_s[j], amplitude_n: m.amplitude_n[j] }
            }
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
