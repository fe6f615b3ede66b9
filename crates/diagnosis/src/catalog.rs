//! The catalog: the named effects a model of the record can add to the linear K-C film, and
//! how each enters the model. There are two kinds:
//!
//! * **corrections** act on the measured data before the film model sees it (a probe that
//!   reads runout, a channel sampled off its slot, a clipped probe): the record is corrected
//!   and every row is judged on the corrected data;
//! * **extensions** add regressors to the film force (added mass, friction, nonlinear terms,
//!   coefficients that follow the temperature).
//!
//! | name | kind | the model | parameters (contract keys) |
//! |---|---|---|---|
//! | `amplitude_nonlinearity` | extension | the film force as a polynomial of second and third order in the motion about the slowly moving equilibrium (`x, y, x', y'`: 30 terms per axis) | `relative_variation_largest_direct`, `amplitude_d` (named only when it matters: see [`crate::amplitude`]) |
//! | `fluid_inertia` | extension | `F = -(K r + C r' + M_a r'')`, isotropic `M_a > 0` | `added_mass_kg` |
//! | `support_friction` | extension | eq. 2's force also holds the supports' Coulomb friction, `+F_c X'/|X'|` (`X' = -r'`, the journal fixed) | `friction_force_n` |
//! | `thermal_drift` | extension | every coefficient changes linearly with the measured bearing temperature; the pattern must be the viscosity's | `viscosity_temperature_slope_per_c`, `temperature_rise_c` |
//! | `synchronous_runout` | correction | the bearing probes read `r + rho`, `rho` a 1X vector turning with the journal, seen against the frame probes (`J = r + X` holds it alone) | `runout_amplitude_m`, `runout_phase_rad`, `runout_phase_deg` |
//! | `channel_delay` | correction | one channel (bearing or frame probe, exciter force) is sampled `delay_s` later than its multiplexer slot: its reading leads the signal by `delay_s` (negative: it lags, as an amplifier's phase) | `channel`, `delay_s` |
//! | `probe_saturation` | correction | a displacement probe clips (a run of one extreme code); its clipped samples are rebuilt from its partner (the other bearing end; for a frame probe, the bearing probes through the fixed journal) | `channel`, `saturation_limit_m` (its own SI reading), `side` |
//!
//! The film's velocity terms matter: its force depends on the squeeze velocity through the
//! cavitated arc, so the polynomial carries every term up to third order, the pure velocity
//! cubics included. Without those, a large-amplitude record's smooth velocity nonlinearity
//! is what a Coulomb friction regressor fits; with them, a real friction still earns (its
//! force saturates with speed where a cubic grows).
//!
//! The verdicts `none`, `unexplained` and `insufficient_data` are not in the catalog (see
//! [`crate::verdict`]).

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::rc::Rc;

use nalgebra::{DMatrix, DVector};
use oilfilm_identification::conditioning::lowpass::Butterworth;
use oilfilm_identification::record::RawUnits;
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::ChannelId;
use oilfilm_physics::film::Running;
use oilfilm_physics::operating_point::{self, EquilibriumOptions};
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

use crate::evidence::{Prepared, Series};
use crate::least_squares::{self, Blocked};
use crate::DiagnosisError;

/// Every name the output's `cause` can take.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Cause {
    AmplitudeNonlinearity,
    FluidInertia,
    ChannelDelay,
    ThermalDrift,
    SynchronousRunout,
    ProbeSaturation,
    SupportFriction,
    /// The linear model is adequate: no named effect earns its extra parameters.
    None,
    /// Excitation-locked structure remains that no catalog effect removes.
    Unexplained,
    /// Too short, too poorly excited or too noisy to decide.
    InsufficientData,
}

impl Cause {
    /// The seven effects of the catalog.
    pub const CATALOG: [Cause; 7] = [
        Cause::AmplitudeNonlinearity,
        Cause::FluidInertia,
        Cause::ChannelDelay,
        Cause::ThermalDrift,
        Cause::SynchronousRunout,
        Cause::ProbeSaturation,
        Cause::SupportFriction,
    ];

    /// The exact name used in output.
    pub fn name(self) -> &'static str {
        match self {
            Cause::AmplitudeNonlinearity => "amplitude_nonlinearity",
            Cause::FluidInertia => "fluid_inertia",
            Cause::ChannelDelay => "channel_delay",
            Cause::ThermalDrift => "thermal_drift",
            Cause::SynchronousRunout => "synchronous_runout",
            Cause::ProbeSaturation => "probe_saturation",
            Cause::SupportFriction => "support_friction",
            Cause::None => "none",
            Cause::Unexplained => "unexplained",
            Cause::InsufficientData => "insufficient_data",
        }
    }

    /// Parses an output name.
    pub fn parse(name: &str) -> Option<Cause> {
        Self::CATALOG.into_iter().chain([Cause::None, Cause::Unexplained, Cause::InsufficientData]).find(|c| c.name() == name)
    }

    /// Whether the effect is in the measurement rather than in the film or the rig: its
    /// corrected data give coefficients a user can keep.
    pub fn is_measurement_effect(self) -> bool {
        matches!(self, Cause::ChannelDelay | Cause::SynchronousRunout | Cause::ProbeSaturation)
    }
}

impl std::fmt::Display for Cause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A structure no catalog effect names: the general extensions the verdict tries on top of the
/// chosen model to see whether excitation-locked structure remains (see [`crate::structure`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Generic {
    /// The film force's dependence on frequency beyond `K + i w C` (+ an isotropic mass): a
    /// full 2x2 mass matrix and a 2x2 term in the third derivative of the motion.
    FrequencyDependence,
    /// The redundant probes disagree in proportion to the motion: tilt and journal rows as
    /// linear functions of `r` and `r'`.
    SensorDisagreement,
    /// Every coefficient changes linearly with time (whatever the temperature does).
    TimeDrift,
}

impl Generic {
    pub const ALL: [Generic; 3] = [Generic::FrequencyDependence, Generic::SensorDisagreement, Generic::TimeDrift];

    pub fn name(self) -> &'static str {
        match self {
            Generic::FrequencyDependence => "frequency_dependence",
            Generic::SensorDisagreement => "sensor_disagreement",
            Generic::TimeDrift => "time_drift",
        }
    }
}

/// One part of a model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Part {
    Named(Cause),
    Generic(Generic),
}

/// A model: the linear K-C film and its parts, in the order they entered.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Spec {
    pub parts: Vec<Part>,
}

impl Spec {
    pub fn has(&self, c: Cause) -> bool {
        self.parts.contains(&Part::Named(c))
    }

    pub fn has_generic(&self, g: Generic) -> bool {
        self.parts.contains(&Part::Generic(g))
    }

    pub fn with(&self, part: Part) -> Spec {
        let mut s = self.clone();
        s.parts.push(part);
        s
    }

    /// The named parts.
    pub fn causes(&self) -> impl Iterator<Item = Cause> + '_ {
        self.parts.iter().filter_map(|p| match p {
            Part::Named(c) => Some(*c),
            Part::Generic(_) => None,
        })
    }

    /// `"linear K-C + a + b"`.
    pub fn describe(&self) -> String {
        let mut s = "linear K-C".to_string();
        for p in &self.parts {
            s.push_str(" + ");
            s.push_str(match p {
                Part::Named(c) => c.name(),
                Part::Generic(g) => g.name(),
            });
        }
        s
    }
}

/// What a column of the force design belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Tag {
    Kc(usize),
    Part(Part, usize),
}

/// A model fitted on all blocks, with the held-out error of each block.
#[derive(Debug, Clone)]
pub struct Judged {
    pub spec: Spec,
    /// Held-out residual sum of squares of each block (force and sensor rows).
    pub block_sse: Vec<f64>,
    /// The K-C part fitted without each block (the cross-validation's fits), and every force
    /// parameter of those fits.
    pub fold_kc: Vec<[f64; 8]>,
    fold_theta: Vec<DVector<f64>>,
    /// Whole-record residual sum of squares (force and sensor rows).
    pub sse: f64,
    /// Rows judged and parameters fitted beyond the linear model's eight.
    pub rows: usize,
    pub extra_parameters: usize,
    /// The K-C part (minus K and C, [`Prepared::kc_design`]'s column order) and its SEs.
    pub kc: [f64; 8],
    pub kc_se: [f64; 8],
    /// Each part's parameters (contract keys), their standard errors, and `Err(why)` when they
    /// are unphysical for the effect.
    pub parameters: BTreeMap<Part, BTreeMap<String, Value>>,
    pub standard_errors: BTreeMap<Part, BTreeMap<String, f64>>,
    pub physical: BTreeMap<Part, Result<(), String>>,
    /// Whole-record residual of the force rows (`f_x` then `f_y`) and of the sensor rows.
    pub force_residual: DVector<f64>,
    pub sensor_residual: DVector<f64>,
    /// The series the model was judged on (after its corrections).
    pub series: Series,
    /// With a thermal drift: the viscosity slope fitted to the film's pattern, its SE, and the
    /// K-C part at the mean temperature it was fitted on.
    pub drift_beta: Option<(f64, f64, [f64; 8])>,
    /// The fitted force parameters by tag, for derived quantities.
    theta: DVector<f64>,
    tags: Vec<Tag>,
}

impl Judged {
    /// Held-out NRMSE given the force target's sum of squares.
    pub fn nrmse(&self, sst: f64) -> f64 {
        (self.block_sse.iter().sum::<f64>() / sst).sqrt()
    }

    /// The fitted values of one part's force columns, in column order.
    pub fn part_theta(&self, part: Part) -> Vec<f64> {
        self.tags.iter().zip(self.theta.iter()).filter(|(t, _)| matches!(t, Tag::Part(p, _) if *p == part)).map(|(_, v)| *v).collect()
    }

    /// The fitted values of one part's force columns in each cross-validation fit.
    pub fn fold_part_theta(&self, part: Part) -> Vec<Vec<f64>> {
        let cols = self.part_columns(part);
        self.fold_theta.iter().map(|t| cols.iter().map(|&c| t[c]).collect()).collect()
    }

    /// The design column indices of one part, in order.
    pub fn part_columns(&self, part: Part) -> Vec<usize> {
        self.tags.iter().enumerate().filter(|(_, t)| matches!(t, Tag::Part(p, _) if *p == part)).map(|(i, _)| i).collect()
    }

    /// Stiffness and damping of the film (`dF = -(K r + C r')`).
    pub fn stiffness_damping(&self) -> (nalgebra::Matrix2<f64>, nalgebra::Matrix2<f64>) {
        coefficients_of(&self.kc)
    }
}

/// `(K, C)` from the K-C part of a design's parameters.
pub fn coefficients_of(kc: &[f64; 8]) -> (nalgebra::Matrix2<f64>, nalgebra::Matrix2<f64>) {
    // Columns 4 i + j are minus K[i][j] (j < 2) and minus C[i][j - 2].
    (nalgebra::Matrix2::new(-kc[0], -kc[1], -kc[4], -kc[5]), nalgebra::Matrix2::new(-kc[2], -kc[3], -kc[6], -kc[7]))
}

/// Channels a delay is looked for on (the ones the film force and motion are made of).
pub const DELAY_CHANNELS: [ChannelId; 8] =
    [ChannelId::ProbeAX, ChannelId::ProbeAY, ChannelId::ProbeBX, ChannelId::ProbeBY, ChannelId::FrameX, ChannelId::FrameY, ChannelId::F1, ChannelId::F2];
/// Largest delay searched, s (either sign).
pub const MAX_DELAY_S: f64 = 1.0e-3;
/// Samples on one extreme plateau that make a probe count as clipped (and at least this
/// fraction of the record).
pub const MIN_CLIPPED_SAMPLES: usize = 10;
pub const MIN_CLIPPED_FRACTION: f64 = 2.0e-4;
/// Widths (ADC codes) of the band below a probe's extreme reading tried as its plateau: an
/// exact code first; then wider, because a card's own noise after the clipping amplifier (one
/// or two codes on a real 16-bit card) spreads the plateau over a few codes.
const PLATEAU_WIDTHS_LSB: [f64; 4] = [0.5, 2.0, 4.0, 8.0];
/// How much denser (per code) the readings must be in the plateau band than in the band twice
/// as wide just below it. A clipped probe stays on its plateau while the signal passes through
/// the band below in moments; an unclipped peak is about as dense at its top codes as just
/// below them, however quiet the probe (measured probes' peaks stay under 3).
const PLATEAU_DENSITY_RATIO: f64 = 4.0;
/// A smooth (parabolic) peak spends time in proportion to the square root of the depth below
/// its top, so the band `[0, w]` holds `1 / (sqrt 3 - 1)` times the readings of `(w, 3 w]`.
const PEAK_BAND_RATIO: f64 = 1.366;
/// Standard deviations (Poisson) by which a plateau band must hold more readings than a
/// smooth peak would put there: a few dozen samples make a ratio by chance.
const PLATEAU_MIN_Z: f64 = 5.0;
/// A record whose temperature moves less than this (standard deviation about its smooth
/// trend's mean, C) cannot show a thermal drift.
pub const MIN_TEMPERATURE_SPREAD_C: f64 = 0.05;
/// The friction regressor's smallest smoothing velocity, as a fraction of the RMS speed.
const FRICTION_SMOOTHING: f64 = 0.02;
/// The frequency-dependence extension acts below this multiple of the highest excitation line.
pub const EXCITED_BAND_FACTOR: f64 = 1.05;
/// Nonlinear film terms per axis.
pub const NONLINEAR_TERMS: usize = 30;

/// A channel's signal at full rate and its first three time derivatives (judging band), and
/// the series fields it enters with their weights and derivative orders.
struct ChannelSignal {
    channel: ChannelId,
    derivatives: [Vec<f64>; 4],
    /// `(field index in Series::fields, weight, derivative order)`.
    enters: Vec<(usize, f64, usize)>,
}

/// Field indices in [`Series::fields`].
mod field {
    pub const X: usize = 0;
    pub const Y: usize = 1;
    pub const VX: usize = 2;
    pub const VY: usize = 3;
    pub const AX: usize = 4;
    pub const AY: usize = 5;
    pub const HX: usize = 6;
    pub const HY: usize = 7;
    pub const HAX: usize = 8;
    pub const HAY: usize = 9;
    pub const FX: usize = 10;
    pub const FY: usize = 11;
    pub const TX: usize = 12;
    pub const TY: usize = 13;
}

/// Field `i` of [`Series::fields_mut`].
fn field_mut(s: &mut Series, i: usize) -> &mut Vec<f64> {
    s.fields_mut().into_iter().nth(i).unwrap_or_else(|| unreachable!("field indices are below 14"))
}

/// Five-point central derivative of a full-rate signal (zero within two samples of an end).
fn derivative(v: &[f64], rate_hz: f64) -> Vec<f64> {
    let n = v.len();
    let mut out = vec![0.0; n];
    for i in 2..n.saturating_sub(2) {
        out[i] = (-v[i + 2] + 8.0 * v[i + 1] - 8.0 * v[i - 1] + v[i - 2]) * rate_hz / 12.0;
    }
    out
}

/// `v` at fractional index `u` by four-point Lagrange interpolation.
fn interpolate(v: &[f64], u: f64) -> f64 {
    let i = u.floor() as isize;
    let p = u - i as f64;
    let at = |k: isize| v[(i + k).clamp(0, v.len() as isize - 1) as usize];
    let (a, b, c, d) = (at(-1), at(0), at(1), at(2));
    // Weights of nodes -1, 0, 1, 2 at p.
    let w0 = -p * (p - 1.0) * (p - 2.0) / 6.0;
    let w1 = (p + 1.0) * (p - 1.0) * (p - 2.0) / 2.0;
    let w2 = -(p + 1.0) * p * (p - 2.0) / 2.0;
    let w3 = (p + 1.0) * p * (p - 1.0) / 6.0;
    w0 * a + w1 * b + w2 * c + w3 * d
}

/// The record as a model sees it after its corrections: the decimated series, and the
/// regressors formed at full rate from its motion.
pub struct View {
    pub series: Series,
    /// Nonlinear film terms at the picks (judging band), [`NONLINEAR_TERMS`] of them.
    nonlinear: Vec<Vec<f64>>,
    /// The friction regressor at the picks, x and y.
    friction: [Vec<f64>; 2],
    /// The second and third derivatives of the motion at the picks, limited to the excited
    /// band (the frequency-dependence extension).
    jerk: [Vec<f64>; 2],
    excited_acceleration: [Vec<f64>; 2],
}

/// Which corrections a view carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
struct Corrections {
    saturation: bool,
    runout: bool,
}

/// The fitted runout: 1X of the journal rows (`J = r + X`: the bearing probes' mean runout)
/// and of the tilt rows (half the ends' difference), phasors `P` with `v = Re(P e^{i W t})`.
#[derive(Debug, Clone, Copy)]
pub struct Runout {
    pub omega_rad_s: f64,
    /// x, y phasors of the mean runout and of the end difference (A - B).
    pub mean: [nalgebra::Complex<f64>; 2],
    pub difference: [nalgebra::Complex<f64>; 2],
    /// Time origin of the phasors: the record's first scan, s.
    pub t0_s: f64,
}

impl Runout {
    /// `(value, first, second derivative)` of a phasor's signal at `t`.
    fn at(&self, p: nalgebra::Complex<f64>, t: f64) -> [f64; 3] {
        let w = self.omega_rad_s;
        let e = nalgebra::Complex::new(0.0, w * (t - self.t0_s)).exp();
        let v = p * e;
        let d = v * nalgebra::Complex::new(0.0, w);
        [v.re, d.re, -(w * w) * v.re]
    }

    /// Amplitude (mean of the axes, m) and phase of the forward 1X vector `A (cos, sin)(W t + phi)`
    /// (rad in [0, 2 pi)).
    pub fn amplitude_phase(&self) -> (f64, f64) {
        let [px, py] = self.mean;
        let a = 0.5 * (px.norm() + py.norm());
        // x = A cos(W t + phi): P_x = A e^{i phi}; y = A sin(W t + phi): P_y = -i A e^{i phi}.
        let from_y = py * nalgebra::Complex::new(0.0, 1.0);
        let phi = (px / px.norm().max(f64::MIN_POSITIVE) + from_y / from_y.norm().max(f64::MIN_POSITIVE)).arg();
        (a, phi.rem_euclid(std::f64::consts::TAU))
    }
}

/// A probe's clipped samples and how they are rebuilt.
#[derive(Debug, Clone)]
pub struct Saturation {
    pub channel: ChannelId,
    /// The clip level as the probe's own SI reading, m, and which side of the motion it cut.
    pub limit_m: f64,
    pub upper: bool,
    pub count: usize,
    pub resolution_m: f64,
    /// Full-rate change of the channel's SI reading that rebuilds it (zero where not clipped).
    delta_si: Vec<f64>,
}

/// Everything set up once per record for fitting models.
pub struct Context<'a> {
    pub p: &'a Prepared,
    rig: &'a RigConfig,
    /// Exciter directions (unit vectors) and housing mass for eq. 2.
    exciter_dirs: [[f64; 2]; 2],
    /// `Err(why)` when the effect cannot be looked for on this record.
    pub drift: Result<Drift, String>,
    pub saturation: Result<Saturation, String>,
    pub runout: Runout,
    channels: Vec<ChannelSignal>,
    views: RefCell<BTreeMap<Corrections, Rc<View>>>,
    /// The delay fitted for a model, by the model's other parts.
    delays: RefCell<Vec<(Spec, Option<FittedDelay>)>>,
}

/// Where a delayed channel enters the model: (field, weight, which of its derivatives).
type Entry = (usize, f64, usize);

/// A channel delay fitted for a model: the channel's index, the delay (s) and its standard error.
type FittedDelay = (usize, f64, f64);

/// The temperature record the thermal drift is judged against.
#[derive(Debug, Clone)]
pub struct Drift {
    /// Smooth temperature minus its mean, at the picks, C.
    pub delta_t_c: Vec<f64>,
    /// The same at the record's first scan (the smooth trend extended there), C.
    pub delta_t_start_c: f64,
    /// Linear rise of the measured temperature over the whole record, C.
    pub rise_c: f64,
    /// The film model's `dln |coef| / dln mu` at the record's point, K-C column order.
    pub sensitivity: [f64; 8],
    /// The oil law's `dln mu / dT` at the record's mean temperature, 1/C.
    pub oil_slope_per_c: f64,
}

impl<'a> Context<'a> {
    pub fn new(p: &'a Prepared, rig: &'a RigConfig) -> Result<Self, DiagnosisError> {
        let dir = |deg: f64| [deg.to_radians().cos(), deg.to_radians().sin()];
        let exciter_dirs = [dir(p.mechanics.exciter_angles_deg[0]), dir(p.mechanics.exciter_angles_deg[1])];
        let runout = fit_runout(p);
        let mut ctx = Self {
            p,
            rig,
            exciter_dirs,
            drift: Err(String::new()),
            saturation: Err(String::new()),
            runout,
            channels: Vec::new(),
            views: RefCell::new(BTreeMap::new()),
            delays: RefCell::new(Vec::new()),
        };
        ctx.drift = ctx.set_up_drift()?;
        ctx.saturation = ctx.set_up_saturation()?;
        ctx.channels = ctx.channel_signals()?;
        Ok(ctx)
    }

    /// Whether a catalog entry can be tried on this record (`Err(why)` if not).
    pub fn applicable(&self, c: Cause) -> Result<(), String> {
        match c {
            Cause::ThermalDrift => self.drift.as_ref().map(|_| ()).map_err(Clone::clone),
            Cause::ProbeSaturation => self.saturation.as_ref().map(|_| ()).map_err(Clone::clone),
            Cause::ChannelDelay if self.channels.is_empty() => Err("none of the channels a delay is looked for on is in the record".into()),
            Cause::AmplitudeNonlinearity => match self.p.velocity_noise_ratio {
                Some(r) if r > crate::evidence::MAX_VELOCITY_NOISE => Err(format!(
                    "the probes' noise is {:.1} % of the excited velocity (above {:.0} %): products of noisy motion fit the noise, and the film's nonlinearity cannot be told from it; excite harder",
                    100.0 * r,
                    100.0 * crate::evidence::MAX_VELOCITY_NOISE
                )),
                _ => Ok(()),
            },
            _ => Ok(()),
        }
    }

    fn set_up_drift(&self) -> Result<Result<Drift, String>, DiagnosisError> {
        let p = self.p;
        let s = &p.series;
        // A cubic in time through the temperature: the thermocouple's noise must not pose as
        // a coefficient change.
        let t0 = s.t_s[0];
        let span = (s.t_s[s.len() - 1] - t0).max(f64::MIN_POSITIVE);
        let u: Vec<f64> = s.t_s.iter().map(|t| 2.0 * (t - t0) / span - 1.0).collect();
        let design = DMatrix::from_fn(u.len(), 4, |i, j| u[i].powi(j as i32));
        let target = DVector::from_column_slice(&s.temperature_c);
        let fit = least_squares::solve(&design, &target, &vec![true; u.len()], "temperature trend")?;
        let smooth: Vec<f64> = (0..u.len()).map(|i| (design.row(i) * &fit.theta)[0]).collect();
        let mean = smooth.iter().sum::<f64>() / smooth.len() as f64;
        let sd = (smooth.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / smooth.len() as f64).sqrt();
        if sd < MIN_TEMPERATURE_SPREAD_C {
            return Ok(Err(format!(
                "the bearing temperature is steady ({sd:.3} C standard deviation of its trend, below {MIN_TEMPERATURE_SPREAD_C} C): a thermal drift can neither act nor be seen"
            )));
        }
        // Linear rise over the whole record, from every raw temperature sample.
        let raw = &p.raw;
        let rise_c = match raw.column(ChannelId::Temperature) {
            Some(col) => {
                let si: Vec<f64> = match raw.units {
                    RawUnits::Si => col.to_vec(),
                    RawUnits::Volts => col.iter().map(|&v| p.calibration.to_si(ChannelId::Temperature, v)).collect::<Result<_, _>>()?,
                };
                let n = si.len() as f64;
                let tm = (n - 1.0) / 2.0;
                let mean = si.iter().sum::<f64>() / n;
                let (mut stt, mut sty) = (0.0, 0.0);
                for (i, v) in si.iter().enumerate() {
                    stt += (i as f64 - tm).powi(2);
                    sty += (i as f64 - tm) * (v - mean);
                }
                sty / stt * n
            }
            None => return Ok(Err("the record has no temperature channel".into())),
        };
        let viscosity = self.rig.oil.viscosity_pa_s(p.mean_temperature_c)?;
        let oil_slope_per_c = self.rig.oil.viscosity_temperature_slope_per_c(p.mean_temperature_c)?;
        let load = nalgebra::Vector2::new(-p.static_force_n[0], -p.static_force_n[1]);
        let coefficients = |mu: f64| -> Result<[f64; 8], DiagnosisError> {
            let mut film = self.rig.film()?;
            let running = Running::from_rpm(p.speed_rpm, mu);
            let op = operating_point::solve(film.as_mut(), &running, load, &EquilibriumOptions::default())?;
            let (k, c) = (op.coefficients.stiffness_n_m, op.coefficients.damping_n_s_m);
            Ok([k[(0, 0)], k[(0, 1)], c[(0, 0)], c[(0, 1)], k[(1, 0)], k[(1, 1)], c[(1, 0)], c[(1, 1)]])
        };
        let eps = 0.02;
        let sensitivity = match (coefficients(viscosity * (1.0 - eps)), coefficients(viscosity), coefficients(viscosity * (1.0 + eps))) {
            (Ok(lo), Ok(mid), Ok(hi)) => std::array::from_fn(|k| {
                let s = (hi[k] - lo[k]) / (2.0 * eps * mid[k]);
                if s.is_finite() {
                    s.clamp(-5.0, 5.0)
                } else {
                    0.0
                }
            }),
            _ => return Ok(Err("the film model has no equilibrium at the record's operating point: the viscosity's pattern cannot be formed".into())),
        };
        let delta_t_c = smooth.iter().map(|v| v - mean).collect();
        let u0 = 2.0 * (p.raw.start_time_s - t0) / span - 1.0;
        let delta_t_start_c = (0..4).map(|j| fit.theta[j] * u0.powi(j as i32)).sum::<f64>() - mean;
        Ok(Ok(Drift { delta_t_c, delta_t_start_c, rise_c, sensitivity, oil_slope_per_c }))
    }

    fn set_up_saturation(&self) -> Result<Result<Saturation, String>, DiagnosisError> {
        let p = self.p;
        let raw = &p.raw;
        let n = raw.len();
        let mut best: Option<(ChannelId, Vec<bool>, f64, bool, usize, f64)> = None;
        for (k, &ch) in raw.channels.iter().enumerate() {
            if !ch.is_displacement_probe() {
                continue;
            }
            let cal = p.calibration.channel(ch)?;
            let lsb_units = match raw.units {
                RawUnits::Volts => p.calibration.lsb_v(),
                RawUnits::Si => p.calibration.lsb_v() / cal.sensitivity_v_per_unit.abs(),
            };
            let col = &raw.columns[k];
            for high in [true, false] {
                let Some((flags, level)) = plateau(col, high, lsb_units) else { continue };
                let count = flags.iter().filter(|f| **f).count();
                let runs = flags.windows(2).filter(|w| w[1] && !w[0]).count() + usize::from(flags.first() == Some(&true));
                if count < MIN_CLIPPED_SAMPLES || (count as f64) < MIN_CLIPPED_FRACTION * n as f64 || runs < 2 {
                    continue;
                }
                let si = match raw.units {
                    RawUnits::Volts => p.calibration.to_si(ch, level)?,
                    RawUnits::Si => level,
                };
                // The side in the probe's own SI reading: a negative sensitivity turns the
                // highest code into the lowest reading.
                let upper = match raw.units {
                    RawUnits::Si => high,
                    RawUnits::Volts => high == (cal.sensitivity_v_per_unit > 0.0),
                };
                if best.as_ref().is_none_or(|b| count > b.4) {
                    best = Some((ch, flags, si, upper, count, p.calibration.lsb_v() / cal.sensitivity_v_per_unit.abs()));
                }
            }
        }
        let Some((channel, clipped, limit_m, upper, count, resolution_m)) = best else {
            return Ok(Err("no displacement probe shows flat-topped readings (runs of readings piled up within a few codes of an extreme)".into()));
        };
        let si_of = |ch: ChannelId| -> Result<Vec<f64>, DiagnosisError> {
            let col = raw.column(ch).ok_or_else(|| DiagnosisError::bad_input(format!("channel `{ch}`"), "not in the record"))?;
            match raw.units {
                RawUnits::Si => Ok(col.to_vec()),
                RawUnits::Volts => col.iter().map(|&v| p.calibration.to_si(ch, v).map_err(DiagnosisError::from)).collect(),
            }
        };
        use ChannelId::*;
        let own = si_of(channel)?;
        let partner: Vec<f64> = match channel {
            ProbeAX => si_of(ProbeBX)?,
            ProbeBX => si_of(ProbeAX)?,
            ProbeAY => si_of(ProbeBY)?,
            ProbeBY => si_of(ProbeAY)?,
            // Journal fixed in space: the housing is at minus the mean bearing reading.
            FrameX => si_of(ProbeAX)?.iter().zip(si_of(ProbeBX)?).map(|(a, b)| -0.5 * (a + b)).collect(),
            FrameY => si_of(ProbeAY)?.iter().zip(si_of(ProbeBY)?).map(|(a, b)| -0.5 * (a + b)).collect(),
            other => return Err(DiagnosisError::bad_input(format!("channel `{other}`"), "not a displacement probe")),
        };
        let (mut sum, mut m) = (0.0, 0usize);
        for i in 0..own.len() {
            if !clipped[i] {
                sum += own[i] - partner[i];
                m += 1;
            }
        }
        if m == 0 {
            return Ok(Err(format!("every sample of `{channel}` is at its extreme code")));
        }
        let offset = sum / m as f64;
        let delta_si: Vec<f64> = (0..own.len()).map(|i| if clipped[i] { partner[i] + offset - own[i] } else { 0.0 }).collect();
        Ok(Ok(Saturation { channel, limit_m, upper, count, resolution_m, delta_si }))
    }

    /// Each delay channel's judging-band signal and derivatives, rebuilt from the one
    /// conditioning: the bearing ends from the mean and the tilt, the exciter forces from eq. 2.
    fn channel_signals(&self) -> Result<Vec<ChannelSignal>, DiagnosisError> {
        let p = self.p;
        let c = &p.narrow;
        let fs = p.raw.sample_rate_hz;
        let m = p.mechanics.housing_mass_kg;
        let g = p.mechanics.gravity_m_s2;
        let d = |v: &[f64]| derivative(v, fs);
        let mut out = Vec::new();
        let end = |mean: &[f64], tilt: &[f64], sign: f64| -> Vec<f64> { mean.iter().zip(tilt).map(|(a, t)| a + sign * 0.5 * t).collect() };
        for ch in DELAY_CHANNELS {
            if !p.raw.channels.contains(&ch) {
                continue;
            }
            use field::*;
            let (derivatives, enters): ([Vec<f64>; 4], Vec<Entry>) = match ch {
                ChannelId::ProbeAX | ChannelId::ProbeBX | ChannelId::ProbeAY | ChannelId::ProbeBY => {
                    let (mean, vel, acc, tilt, fx, fv, fa, ft) = if matches!(ch, ChannelId::ProbeAX | ChannelId::ProbeBX) {
                        (&c.x_m, &c.vx_m_s, &c.ax_m_s2, &c.tilt_x_m, X, VX, AX, TX)
                    } else {
                        (&c.y_m, &c.vy_m_s, &c.ay_m_s2, &c.tilt_y_m, Y, VY, AY, TY)
                    };
                    let sign = if matches!(ch, ChannelId::ProbeAX | ChannelId::ProbeAY) { 1.0 } else { -1.0 };
                    let s0 = end(mean, tilt, sign);
                    let dt1 = d(tilt);
                    let dt2 = d(&dt1);
                    let s1 = end(vel, &dt1, sign);
                    let s2 = end(acc, &dt2, sign);
                    let s3 = d(&s2);
                    ([s0, s1, s2, s3], vec![(fx, 0.5, 0), (fv, 0.5, 1), (fa, 0.5, 2), (ft, sign, 0)])
                }
                ChannelId::FrameX | ChannelId::FrameY => {
                    let (h, ha, fh, fha, ff) = if ch == ChannelId::FrameX {
                        (&c.housing_x_m, &c.housing_ax_m_s2, HX, HAX, FX)
                    } else {
                        (&c.housing_y_m, &c.housing_ay_m_s2, HY, HAY, FY)
                    };
                    let s1 = d(h);
                    let s3 = d(ha);
                    ([h.clone(), s1, ha.clone(), s3], vec![(fh, 1.0, 0), (fha, 1.0, 2), (ff, -m, 2)])
                }
                _ => {
                    // F_exc = F + m X'' - (f3 - m g) e_y; [f1, f2] = D^-1 F_exc.
                    let [e1, e2] = self.exciter_dirs;
                    let det = e1[0] * e2[1] - e2[0] * e1[1];
                    let k = usize::from(ch == ChannelId::F2);
                    let s0: Vec<f64> = (0..c.fx_n.len())
                        .map(|i| {
                            let ex = c.fx_n[i] + m * c.housing_ax_m_s2[i];
                            let ey = c.fy_n[i] + m * c.housing_ay_m_s2[i] - (c.static_load_n[i] - m * g);
                            if k == 0 {
                                (e2[1] * ex - e2[0] * ey) / det
                            } else {
                                (-e1[1] * ex + e1[0] * ey) / det
                            }
                        })
                        .collect();
                    let e = if k == 0 { e1 } else { e2 };
                    let s1 = d(&s0);
                    let s2 = d(&s1);
                    let s3 = d(&s2);
                    ([s0, s1, s2, s3], vec![(FX, e[0], 0), (FY, e[1], 0)])
                }
            };
            out.push(ChannelSignal { channel: ch, derivatives, enters });
        }
        Ok(out)
    }

    /// The series with channel `k` corrected for a delay `tau` (its reading at stamp `t` is
    /// the signal at `t + tau`, so the signal at `t` is the reading at `t - tau`), and the
    /// derivative of every field with respect to `tau` there.
    fn delayed(&self, base: &Series, k: usize, tau: f64) -> (Series, Series) {
        let p = self.p;
        let cs = &self.channels[k];
        let fs = p.raw.sample_rate_hz;
        let mut out = base.clone();
        let mut slope = Series { t_s: base.t_s.clone(), ..Series::default() };
        for f in slope.fields_mut() {
            *f = vec![0.0; base.len()];
        }
        for &(fi, w, order) in &cs.enters {
            let sig = &cs.derivatives[order];
            let next = &cs.derivatives[order + 1];
            let dst = field_mut(&mut out, fi);
            for (j, &i) in p.picks.iter().enumerate() {
                let u = i as f64 - tau * fs;
                dst[j] += w * (interpolate(sig, u) - sig[i]);
            }
            let dslope = field_mut(&mut slope, fi);
            for (j, &i) in p.picks.iter().enumerate() {
                dslope[j] += -w * interpolate(next, i as f64 - tau * fs);
            }
        }
        (out, slope)
    }

    /// The record under a set of corrections (cached).
    fn view(&self, corrections: Corrections) -> Result<Rc<View>, DiagnosisError> {
        if let Some(v) = self.views.borrow().get(&corrections) {
            return Ok(v.clone());
        }
        let v = Rc::new(self.make_view(corrections)?);
        self.views.borrow_mut().insert(corrections, v.clone());
        Ok(v)
    }

    fn make_view(&self, corrections: Corrections) -> Result<View, DiagnosisError> {
        let p = self.p;
        let c = &p.narrow;
        let fs = p.raw.sample_rate_hz;
        let len = c.x_m.len();
        // Full-rate motion r, r', r'' and the fields' corrections.
        let mut full: [Vec<f64>; 6] = [c.x_m.clone(), c.y_m.clone(), c.vx_m_s.clone(), c.vy_m_s.clone(), c.ax_m_s2.clone(), c.ay_m_s2.clone()];
        let mut series = p.series.clone();
        if corrections.saturation {
            if let Ok(sat) = &self.saturation {
                self.apply_saturation(sat, &mut full, &mut series)?;
            }
        }
        if corrections.runout {
            let r = &self.runout;
            for (axis, base) in [(0usize, 0usize), (1, 1)] {
                let (pm, pd) = (r.mean[axis], r.difference[axis]);
                for (i, &t) in c.t_s.iter().enumerate().take(len) {
                    let [v, dv, av] = r.at(pm, t);
                    full[base][i] -= v;
                    full[2 + base][i] -= dv;
                    full[4 + base][i] -= av;
                }
                for (j, &t) in p.series.t_s.iter().enumerate() {
                    let [v, dv, av] = r.at(pm, t);
                    let [dd, _, _] = r.at(pd, t);
                    let s = &mut series;
                    if axis == 0 {
                        s.x_m[j] -= v;
                        s.vx_m_s[j] -= dv;
                        s.ax_m_s2[j] -= av;
                        s.tilt_x_m[j] -= dd;
                    } else {
                        s.y_m[j] -= v;
                        s.vy_m_s[j] -= dv;
                        s.ay_m_s2[j] -= av;
                        s.tilt_y_m[j] -= dd;
                    }
                }
            }
        }
        // Nonlinear film terms in the motion about the slowly moving equilibrium (the position
        // low-passed well below the lowest excitation line): a drifting equilibrium must not
        // make the quadratic terms pose as coefficients that change during the record.
        let v = c.valid.clone();
        let slow_hz = (0.25 * p.lines_hz.first().copied().unwrap_or(1.0)).max(0.05);
        let slow = Butterworth::design(2, slow_hz, fs)?;
        let about = |a: &[f64]| -> Result<Vec<f64>, DiagnosisError> {
            let mut out = vec![0.0; a.len()];
            let trend = slow.filtfilt(&a[v.clone()])?;
            for (o, (x, t)) in out[v.clone()].iter_mut().zip(a[v.clone()].iter().zip(&trend)) {
                *o = x - t;
            }
            Ok(out)
        };
        let z: [Vec<f64>; 4] = [about(&full[0])?, about(&full[1])?, full[2].clone(), full[3].clone()];
        let mut terms = Vec::with_capacity(NONLINEAR_TERMS);
        for a in 0..4 {
            for b in a..4 {
                terms.push((0..len).map(|i| z[a][i] * z[b][i]).collect::<Vec<f64>>());
            }
        }
        for a in 0..4 {
            for b in a..4 {
                for cc in b..4 {
                    if usize::from(a >= 2) + usize::from(b >= 2) + usize::from(cc >= 2) > 3 {
                        continue;
                    }
                    terms.push((0..len).map(|i| z[a][i] * z[b][i] * z[cc][i]).collect::<Vec<f64>>());
                }
            }
        }
        debug_assert_eq!(terms.len(), NONLINEAR_TERMS);
        // Friction: E[sign(v) | measured v] for Gaussian noise of the level the frame and
        // bearing probes disagree by (regression calibration; a plain sign of a noisy velocity
        // would bias the friction low). The velocity is the bearing probes' own r', the signal
        // the film model regresses on (a velocity from the frame probes would act as an
        // instrumental variable and turn the linear fit's errors-in-variables bias into a
        // friction that is not there); the frame probes only give the noise level.
        let (hvx, hvy) = (derivative(&c.housing_x_m, fs), derivative(&c.housing_y_m, fs));
        let disagreement = |rv: &[f64], hv: &[f64]| -> f64 {
            let d: Vec<f64> = v.clone().map(|i| hv[i] + rv[i]).collect();
            let m = d.iter().sum::<f64>() / d.len() as f64;
            (d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / d.len() as f64 / 2.0).sqrt()
        };
        let sigma = 0.5 * (disagreement(&full[2], &hvx) + disagreement(&full[3], &hvy));
        let rms = (v.clone().map(|i| full[2][i].powi(2) + full[3][i].powi(2)).sum::<f64>() / v.len() as f64).sqrt();
        let width = (std::f64::consts::SQRT_2 * sigma).max(FRICTION_SMOOTHING * rms).max(f64::MIN_POSITIVE);
        let (mut ux, mut uy) = (vec![0.0; len], vec![0.0; len]);
        for i in 0..len {
            let (a, b) = (-full[2][i], -full[3][i]);
            let speed = a.hypot(b);
            let g = if speed > 0.0 { crate::statistics::erf(speed / width) / speed } else { 0.0 };
            ux[i] = a * g;
            uy[i] = b * g;
        }
        terms.push(ux);
        terms.push(uy);
        let mut filtered = p.band_picks_many(terms)?;
        let fy = filtered.pop().unwrap_or_default();
        let fx = filtered.pop().unwrap_or_default();
        // The frequency-dependence extension's columns (the motion's second and third
        // derivatives) only where the record is excited: above the top line the derivatives of
        // the probes' noise dominate them, and regressors of noise alone would "explain" the
        // linear fit's errors-in-variables bias there as a frequency dependence that is not in
        // the film.
        let excited = Butterworth::design(p.wide_config.lowpass_order, EXCITED_BAND_FACTOR * p.lines_hz.last().copied().unwrap_or(p.cutoff_hz), fs)?;
        let mut derivatives = Vec::with_capacity(4);
        for k in [4usize, 5] {
            let a = excited.filtfilt(&full[k][v.clone()])?;
            let j = derivative(&a, fs);
            derivatives.push(a);
            derivatives.push(j);
        }
        let pick = |w: &[f64]| -> Vec<f64> { p.picks.iter().map(|&i| w[i - v.start]).collect() };
        let excited_acceleration = [pick(&derivatives[0]), pick(&derivatives[2])];
        let jerk = [pick(&derivatives[1]), pick(&derivatives[3])];
        Ok(View { series, nonlinear: filtered, friction: [fx, fy], jerk, excited_acceleration })
    }

    /// Adds the rebuild of a clipped probe to the full-rate motion and the series: the change
    /// of its SI reading through the conditioning's low-pass and the judging band (the chain is
    /// linear, so the change alone can be filtered), differentiated like the motion.
    fn apply_saturation(&self, sat: &Saturation, full: &mut [Vec<f64>; 6], series: &mut Series) -> Result<(), DiagnosisError> {
        let p = self.p;
        let fs = p.raw.sample_rate_hz;
        let wide = Butterworth::design(p.wide_config.lowpass_order, p.wide_config.lowpass_cutoff_hz, fs)?;
        let mut delta = wide.filtfilt(&sat.delta_si)?;
        if let Some(band) = &p.band {
            delta = band.filtfilt(&delta)?;
        }
        let d1 = derivative(&delta, fs);
        let d2 = derivative(&d1, fs);
        use ChannelId::*;
        let m = p.mechanics.housing_mass_kg;
        let (axis, end_sign, frame) = match sat.channel {
            ProbeAX => (0, 1.0, false),
            ProbeBX => (0, -1.0, false),
            ProbeAY => (1, 1.0, false),
            ProbeBY => (1, -1.0, false),
            FrameX => (0, 0.0, true),
            FrameY => (1, 0.0, true),
            other => return Err(DiagnosisError::bad_input(format!("channel `{other}`"), "not a displacement probe")),
        };
        if !frame {
            for i in 0..delta.len().min(full[0].len()) {
                full[axis][i] += 0.5 * delta[i];
                full[2 + axis][i] += 0.5 * d1[i];
                full[4 + axis][i] += 0.5 * d2[i];
            }
        }
        for (j, &i) in p.picks.iter().enumerate() {
            if frame {
                let (h, ha, f) = if axis == 0 {
                    (&mut series.housing_x_m, &mut series.housing_ax_m_s2, 0)
                } else {
                    (&mut series.housing_y_m, &mut series.housing_ay_m_s2, 1)
                };
                h[j] += delta[i];
                ha[j] += d2[i];
                if f == 0 {
                    series.fx_n[j] -= m * d2[i];
                } else {
                    series.fy_n[j] -= m * d2[i];
                }
            } else {
                let (x, v, a, t) = if axis == 0 {
                    (&mut series.x_m, &mut series.vx_m_s, &mut series.ax_m_s2, &mut series.tilt_x_m)
                } else {
                    (&mut series.y_m, &mut series.vy_m_s, &mut series.ay_m_s2, &mut series.tilt_y_m)
                };
                x[j] += 0.5 * delta[i];
                v[j] += 0.5 * d1[i];
                a[j] += 0.5 * d2[i];
                t[j] += end_sign * delta[i];
            }
        }
        Ok(())
    }

    /// The force design of a model on a series, with its column tags.
    fn force_design(&self, spec: &Spec, view: &View, series: &Series) -> (DMatrix<f64>, Vec<Tag>) {
        let p = self.p;
        let mut tags: Vec<Tag> = (0..8).map(Tag::Kc).collect();
        let drift = if spec.has(Cause::ThermalDrift) { self.drift.as_ref().ok() } else { None };
        let force_generic = spec.has_generic(Generic::FrequencyDependence);
        for part in &spec.parts {
            let count = match part {
                Part::Named(Cause::AmplitudeNonlinearity) => 2 * NONLINEAR_TERMS,
                Part::Named(Cause::FluidInertia) if !force_generic => 1,
                Part::Named(Cause::SupportFriction) => 1,
                Part::Named(Cause::ThermalDrift) if drift.is_some() => 16,
                Part::Generic(Generic::FrequencyDependence) => 8,
                Part::Generic(Generic::TimeDrift) => 8,
                _ => 0,
            };
            tags.extend((0..count).map(|k| Tag::Part(*part, k)));
        }
        let mut m = p.kc_design(series, tags.len() - 8);
        let motion = [&series.x_m, &series.y_m, &series.vx_m_s, &series.vy_m_s];
        let t0 = series.t_s[0];
        let span = (series.t_s[series.len() - 1] - t0).max(f64::MIN_POSITIVE);
        for (col, tag) in tags.iter().enumerate().skip(8) {
            let Tag::Part(part, k) = *tag else { continue };
            match part {
                Part::Named(Cause::AmplitudeNonlinearity) => {
                    let (axis, term) = (k / NONLINEAR_TERMS, k % NONLINEAR_TERMS);
                    p.set_axis_column(&mut m, col, axis, &view.nonlinear[term]);
                }
                Part::Named(Cause::FluidInertia) => {
                    let nx: Vec<f64> = series.ax_m_s2.iter().map(|a| -a).collect();
                    let ny: Vec<f64> = series.ay_m_s2.iter().map(|a| -a).collect();
                    p.set_column(&mut m, col, &nx, &ny);
                }
                Part::Named(Cause::SupportFriction) => p.set_column(&mut m, col, &view.friction[0], &view.friction[1]),
                Part::Named(Cause::ThermalDrift) => {
                    // Column k < 8: K-C column k (axis k / 4, motion k % 4) times dT; k >= 8:
                    // column k - 8 times dT^2. Every coefficient may change with the measured
                    // temperature, and not in a straight line (the viscosity falls
                    // exponentially); the film's own pattern is what the named slope is
                    // fitted to, see `judge`. The motion is taken about the (drifting)
                    // equilibrium: detrended before dT scales it.
                    let Some(d) = drift else { continue };
                    let (j, power) = (k % 8, if k < 8 { 1 } else { 2 });
                    let motion_d = p.detrended(motion[j % 4]);
                    let v: Vec<f64> = motion_d.iter().zip(&d.delta_t_c).map(|(a, t)| a * t.powi(power)).collect();
                    p.set_axis_column(&mut m, col, j / 4, &v);
                }
                Part::Generic(Generic::TimeDrift) => {
                    let motion_d = p.detrended(motion[k % 4]);
                    let v: Vec<f64> = motion_d.iter().zip(&series.t_s).map(|(a, t)| a * ((t - t0) / span - 0.5)).collect();
                    p.set_axis_column(&mut m, col, k / 4, &v);
                }
                Part::Generic(Generic::FrequencyDependence) => {
                    // k 0..3: -(axis k/2) acceleration component k%2; 4..7: jerk.
                    let (axis, comp) = ((k % 4) / 2, k % 2);
                    let src: Vec<f64> =
                        if k < 4 { view.excited_acceleration[comp].iter().map(|a| -a).collect() } else { view.jerk[comp].iter().map(|a| -a * 1e-3).collect() };
                    p.set_axis_column(&mut m, col, axis, &src);
                }
                _ => {}
            }
        }
        (m, tags)
    }

    /// The sensor design (the sensor-disagreement extension: each sensor row a linear function
    /// of `r` and `r'`), or no columns.
    fn sensor_design(&self, spec: &Spec, series: &Series) -> DMatrix<f64> {
        let p = self.p;
        let n = p.len();
        if !spec.has_generic(Generic::SensorDisagreement) {
            return DMatrix::zeros(4 * n, 0);
        }
        let w = p.sensor_weight_n_m;
        let mut m = DMatrix::zeros(4 * n, 16);
        let motion = [&series.x_m, &series.y_m, &series.vx_m_s, &series.vy_m_s];
        for row in 0..4 {
            for (j, src) in motion.iter().enumerate() {
                let v: Vec<f64> = p.detrended(src).into_iter().map(|a| w * a).collect();
                m.view_mut((row * n, 4 * row + j), (n, 1)).copy_from_slice(&v);
            }
        }
        m
    }

    /// The delay of the best channel for a model's other parts: `(channel index, tau, SE)`, or
    /// `None` when no channel's delay can be fitted. Gauss-Newton in `tau` with the other
    /// parts' columns projected out at `tau = 0` (the K-C columns move with a probe's delay,
    /// but the projection only to second order in the step), on force and sensor rows alike.
    fn delay_for(&self, spec: &Spec, view: &View) -> Result<Option<(usize, f64, f64)>, DiagnosisError> {
        let others = Spec { parts: spec.parts.iter().copied().filter(|p| *p != Part::Named(Cause::ChannelDelay)).collect() };
        if let Some((_, d)) = self.delays.borrow().iter().find(|(s, _)| *s == others) {
            return Ok(*d);
        }
        let p = self.p;
        let base = &view.series;
        let (x0, _) = self.force_design(&others, view, base);
        let y0 = p.force_target(base);
        let Ok(fit0) = least_squares::solve(&x0, &y0, &vec![true; y0.len()], "channel_delay (the other parts at zero delay)") else {
            self.delays.borrow_mut().push((others, None));
            return Ok(None);
        };
        let kc0 = fit0.theta.rows(0, 8).into_owned();
        let kc_base = p.kc_design(base, 0);
        let scale: Vec<f64> = (0..x0.ncols()).map(|j| x0.column(j).norm().max(f64::MIN_POSITIVE)).collect();
        let xs = DMatrix::from_fn(x0.nrows(), x0.ncols(), |i, j| x0[(i, j)] / scale[j]);
        let qr = xs.clone().qr();
        let r = qr.r();
        let cols = xs.ncols();
        // The least-squares residual of `v` on the others' columns (Q applied by its
        // reflections, never formed).
        let project_out = |v: &DVector<f64>| -> DVector<f64> {
            let mut w = v.clone();
            qr.q_tr_mul(&mut w);
            match r.solve_upper_triangular(&w.rows(0, cols).into_owned()) {
                Some(coef) => v - &xs * coef,
                None => v.clone(),
            }
        };
        let residuals = |s: &Series| -> (DVector<f64>, DVector<f64>) {
            let moved = (p.kc_design(s, 0) - &kc_base) * &kc0;
            (project_out(&(p.force_target(s) - moved)), p.sensor_rows(s))
        };
        let dof = (p.force_rows() + 4 * p.len()).saturating_sub(x0.ncols() + 1).max(1) as f64;
        let mut best: Option<(usize, f64, f64, f64)> = None;
        for k in 0..self.channels.len() {
            let mut tau = 0.0;
            let mut se = f64::NAN;
            for _ in 0..6 {
                let (s, ds) = self.delayed(base, k, tau);
                let (rf, rs) = residuals(&s);
                let gf = project_out(&(p.force_target(&ds) - p.kc_design(&ds, 0) * &kc0));
                let gs = p.sensor_rows(&ds);
                // A probe's timing is measured against its redundant partners (the sensor
                // rows), where nothing else acts; the force rows would lend it the linear
                // fit's errors-in-variables bias. An exciter force has no partner.
                let probe = self.channels[k].channel.is_displacement_probe();
                let (num, den) = if probe { (gs.dot(&rs), gs.norm_squared()) } else { (gf.dot(&rf) + gs.dot(&rs), gf.norm_squared() + gs.norm_squared()) };
                if !(den.is_finite() && den > 0.0) {
                    break;
                }
                let step = -num / den;
                se = ((rf.norm_squared() + rs.norm_squared()) / dof / den).sqrt();
                tau = (tau + step).clamp(-MAX_DELAY_S, MAX_DELAY_S);
                if step.abs() < 1e-8 {
                    break;
                }
            }
            let (s, _) = self.delayed(base, k, tau);
            let (rf, rs) = residuals(&s);
            let sse = rf.norm_squared() + rs.norm_squared();
            if best.is_none_or(|b| sse < b.3) {
                best = Some((k, tau, se, sse));
            }
        }
        let out = best.map(|(k, tau, se, _)| (k, tau, se));
        self.delays.borrow_mut().push((others, out));
        Ok(out)
    }

    /// Fits a model on all blocks but one, for each block, and on the whole record.
    pub fn judge(&self, spec: &Spec) -> Result<Judged, DiagnosisError> {
        let p = self.p;
        let corrections = Corrections { saturation: spec.has(Cause::ProbeSaturation), runout: spec.has(Cause::SynchronousRunout) };
        let view = self.view(corrections)?;
        let mut series = view.series.clone();
        let mut delay = None;
        let mut sensor_worse = false;
        if spec.has(Cause::ChannelDelay) {
            let Some((k, tau, se)) = self.delay_for(spec, &view)? else {
                return Err(DiagnosisError::bad_input("channel_delay", "no channel's delay could be fitted"));
            };
            let delayed = self.delayed(&view.series, k, tau).0;
            // A probe's timing error shows in the redundant probes (end A against end B,
            // bearing against frame): a delay that makes them disagree more is not one.
            if self.channels[k].channel.is_displacement_probe() && p.sensor_rows(&delayed).norm_squared() >= p.sensor_rows(&view.series).norm_squared() {
                sensor_worse = true;
            }
            series = delayed;
            delay = Some((k, tau, se));
        }
        let what = spec.describe();
        // The named drift's viscosity slope: every coefficient as theta_k (1 + beta s_k dT),
        // s_k the film's own dln|coef|/dln mu and theta the fit without the drift; one column
        // per axis, sum_k theta_k s_k dT x_k, carries beta.
        let drift_beta = match (spec.has(Cause::ThermalDrift), self.drift.as_ref()) {
            (true, Ok(d)) => {
                let others = Spec { parts: spec.parts.iter().copied().filter(|p| *p != Part::Named(Cause::ThermalDrift)).collect() };
                let (x, _) = self.force_design(&others, &view, &series);
                let y = p.force_target(&series);
                let fit = least_squares::solve(&x, &y, &vec![true; y.len()], "thermal_drift (the film at the mean temperature)")?;
                let motion = [&series.x_m, &series.y_m, &series.vx_m_s, &series.vy_m_s].map(|m| p.detrended(m));
                let mut xb = x.clone().insert_column(x.ncols(), 0.0);
                for axis in 0..2 {
                    let mut v = vec![0.0; series.len()];
                    for (j, m) in motion.iter().enumerate() {
                        let k = 4 * axis + j;
                        for ((acc, a), dt) in v.iter_mut().zip(m).zip(&d.delta_t_c) {
                            *acc += fit.theta[k] * d.sensitivity[k] * dt * a;
                        }
                    }
                    p.set_axis_column(&mut xb, x.ncols(), axis, &v);
                }
                let with = least_squares::solve(&xb, &y, &vec![true; y.len()], "thermal_drift (the viscosity's slope)")?;
                Some((with.theta[x.ncols()], with.standard_errors[x.ncols()], std::array::from_fn::<f64, 8, _>(|k| fit.theta[k])))
            }
            _ => None,
        };
        let (design, tags) = self.force_design(spec, &view, &series);
        let target = p.force_target(&series);
        let force = Blocked::new(&design, &target, &p.force_blocks(), &what)?;
        let sensor_target = p.sensor_rows(&series);
        let sensor_design = self.sensor_design(spec, &series);
        let sensor_blocks: Vec<Vec<usize>> = (0..p.blocks.len()).map(|b| p.sensor_block_rows(b).collect()).collect();
        let sensor = if sensor_design.ncols() > 0 { Some(Blocked::new(&sensor_design, &sensor_target, &sensor_blocks, &what)?) } else { None };
        let mut block_sse = Vec::with_capacity(p.blocks.len());
        let mut fold_kc = Vec::with_capacity(p.blocks.len());
        let mut fold_theta = Vec::with_capacity(p.blocks.len());
        for (b, rows) in sensor_blocks.iter().enumerate() {
            let f = force.fit(Some(b), &what)?;
            fold_kc.push(std::array::from_fn(|k| f.theta[k]));
            fold_theta.push(f.theta.clone());
            let mut sse = force.block_sse(b, &f.theta);
            sse += match &sensor {
                Some(s) => s.block_sse(b, &s.fit(Some(b), &what)?.theta),
                None => rows.iter().map(|&i| sensor_target[i] * sensor_target[i]).sum::<f64>(),
            };
            block_sse.push(sse);
        }
        let full = force.fit(None, &what)?;
        let force_residual = &target - &design * &full.theta;
        let (sensor_residual, sensor_theta) = match &sensor {
            Some(s) => {
                let f = s.fit(None, &what)?;
                (&sensor_target - &sensor_design * &f.theta, Some(f))
            }
            None => (sensor_target.clone(), None),
        };
        let sse = force_residual.norm_squared() + sensor_residual.norm_squared();
        let rows = p.force_rows() + 4 * p.len();
        let mut judged = Judged {
            spec: spec.clone(),
            block_sse,
            fold_kc,
            fold_theta,
            sse,
            rows,
            extra_parameters: 0,
            kc: std::array::from_fn(|k| full.theta[k]),
            kc_se: std::array::from_fn(|k| full.standard_errors[k]),
            parameters: BTreeMap::new(),
            standard_errors: BTreeMap::new(),
            physical: BTreeMap::new(),
            force_residual,
            sensor_residual,
            series,
            drift_beta,
            theta: full.theta.clone(),
            tags: tags.clone(),
        };
        judged.extra_parameters = tags.len() - 8 + sensor_theta.as_ref().map_or(0, |f| f.theta.len());
        self.describe_parts(&mut judged, &full, sensor_theta.as_ref(), delay);
        if sensor_worse {
            if let Some((k, _, _)) = delay {
                judged.physical.insert(
                    Part::Named(Cause::ChannelDelay),
                    Err(format!("a delay of `{}` would make the redundant probes (end A against end B, bearing against frame) disagree more: a probe's timing error shows there first", self.channels[k].channel)),
                );
            }
        }
        Ok(judged)
    }

    /// Each part's named parameters from a whole-record fit.
    fn describe_parts(&self, j: &mut Judged, full: &least_squares::BlockFit, sensor: Option<&least_squares::BlockFit>, delay: Option<(usize, f64, f64)>) {
        let tags = j.tags.clone();
        let kc = j.kc;
        let cols = |part: Part| -> Vec<(f64, f64)> {
            tags.iter().enumerate().filter(|(_, t)| matches!(t, Tag::Part(p, _) if *p == part)).map(|(i, _)| (full.theta[i], full.standard_errors[i])).collect()
        };
        for part in j.spec.parts.clone() {
            let mut params = BTreeMap::new();
            let mut ses = BTreeMap::new();
            let mut physical = Ok(());
            match part {
                Part::Named(Cause::FluidInertia) => {
                    if let Some(&(m, se)) = cols(part).first() {
                        params.insert("added_mass_kg".into(), json!(m));
                        ses.insert("added_mass_kg".into(), se);
                        if m <= 0.0 {
                            physical = Err(format!("negative added mass ({m:.3} kg): fluid inertia only adds mass"));
                        }
                    }
                }
                Part::Named(Cause::SupportFriction) => {
                    if let Some(&(f, se)) = cols(part).first() {
                        params.insert("friction_force_n".into(), json!(f));
                        ses.insert("friction_force_n".into(), se);
                        if f <= 0.0 {
                            physical = Err(format!("negative friction force ({f:.3} N): friction opposes motion"));
                        }
                    }
                }
                Part::Named(Cause::ThermalDrift) => {
                    if let (Ok(d), Some((beta, se, _))) = (&self.drift, j.drift_beta) {
                        params.insert("viscosity_temperature_slope_per_c".into(), json!(beta));
                        params.insert("oil_law_slope_per_c".into(), json!(d.oil_slope_per_c));
                        params.insert("temperature_rise_c".into(), json!(d.rise_c));
                        ses.insert("viscosity_temperature_slope_per_c".into(), se);
                        if beta.is_nan() || beta >= 0.0 {
                            physical =
                                Err(format!("the coefficients change with temperature as if the viscosity rose with it (slope {beta:.4}/C): no oil does that"));
                        }
                    }
                }
                Part::Named(Cause::SynchronousRunout) => {
                    let (a, phi) = self.runout.amplitude_phase();
                    params.insert("runout_amplitude_m".into(), json!(a));
                    params.insert("runout_phase_rad".into(), json!(phi));
                    let deg = phi.to_degrees();
                    params.insert("runout_phase_deg".into(), json!(if deg > 180.0 { deg - 360.0 } else { deg }));
                }
                Part::Named(Cause::ChannelDelay) => {
                    if let Some((k, tau, se)) = delay {
                        params.insert("channel".into(), json!(self.channels[k].channel.name()));
                        params.insert("delay_s".into(), json!(tau));
                        params.insert("delay_convention".into(), json!(DELAY_CONVENTION));
                        ses.insert("delay_s".into(), se);
                        if tau.abs() >= 0.999 * MAX_DELAY_S {
                            physical = Err(format!("the delay ran to the search limit ({:.0} us): not a timing error of one channel", MAX_DELAY_S * 1e6));
                        }
                    }
                }
                Part::Named(Cause::ProbeSaturation) => {
                    if let Ok(s) = &self.saturation {
                        params.insert("channel".into(), json!(s.channel.name()));
                        params.insert("saturation_limit_m".into(), json!(s.limit_m));
                        params.insert("side".into(), json!(if s.upper { "upper" } else { "lower" }));
                        params.insert("clipped_samples".into(), json!(s.count));
                        ses.insert("saturation_limit_m".into(), s.resolution_m);
                    }
                }
                Part::Named(Cause::AmplitudeNonlinearity) => {
                    params.insert("terms_per_axis".into(), json!(NONLINEAR_TERMS));
                }
                Part::Generic(Generic::SensorDisagreement) => {
                    if let Some(f) = sensor {
                        // Rows tilt_x, tilt_y, J_x, J_y; columns x, y, x', y'.
                        let g = |row: usize, j: usize| f.theta[4 * row + j];
                        params.insert("tilt_per_motion".into(), json!([[g(0, 0), g(0, 1)], [g(1, 0), g(1, 1)]]));
                        params.insert("journal_per_motion".into(), json!([[g(2, 0), g(2, 1)], [g(3, 0), g(3, 1)]]));
                        params.insert("journal_per_velocity_s".into(), json!([[g(2, 2), g(2, 3)], [g(3, 2), g(3, 3)]]));
                        params.insert("tilt_per_velocity_s".into(), json!([[g(0, 2), g(0, 3)], [g(1, 2), g(1, 3)]]));
                    }
                }
                Part::Generic(Generic::FrequencyDependence) => {
                    let c = cols(part);
                    if c.len() == 8 {
                        params.insert("mass_matrix_kg".into(), json!([[c[0].0, c[1].0], [c[2].0, c[3].0]]));
                        params.insert("third_derivative_matrix_kg_s".into(), json!([[c[4].0 * 1e-3, c[5].0 * 1e-3], [c[6].0 * 1e-3, c[7].0 * 1e-3]]));
                    }
                }
                Part::Generic(Generic::TimeDrift) => {
                    let c = cols(part);
                    // Relative change of each coefficient over the record.
                    let rel: Vec<f64> = (0..c.len().min(8)).map(|k| if kc[k] != 0.0 { c[k].0 / kc[k] } else { f64::NAN }).collect();
                    params.insert("relative_change_over_record".into(), json!(rel));
                }
                _ => {}
            }
            j.parameters.insert(part, params);
            j.standard_errors.insert(part, ses);
            j.physical.insert(part, physical);
        }
    }

    /// The drift set-up (for the coefficients at the record's start).
    pub fn drift(&self) -> Option<&Drift> {
        self.drift.as_ref().ok()
    }

    pub fn rig(&self) -> &RigConfig {
        self.rig
    }

    /// The 26 nonlinear terms and the motion they were formed from, for the amplitude
    /// assessment (uncorrected view unless corrections are named).
    pub fn nonlinear_terms(&self, spec: &Spec) -> Result<Rc<View>, DiagnosisError> {
        self.view(Corrections { saturation: spec.has(Cause::ProbeSaturation), runout: spec.has(Cause::SynchronousRunout) })
    }

    /// Design of a model on its own view (for derived quantities).
    pub fn design_of(&self, j: &Judged) -> Result<DMatrix<f64>, DiagnosisError> {
        let view = self.nonlinear_terms(&j.spec)?;
        Ok(self.force_design(&j.spec, &view, &j.series).0)
    }
}

impl View {
    pub fn nonlinear(&self) -> &[Vec<f64>] {
        &self.nonlinear
    }
}

/// The sign convention of `delay_s`, stated in the output.
pub const DELAY_CONVENTION: &str =
    "delay_s > 0: the channel is sampled delay_s later than its multiplexer slot, so its reading leads the signal by delay_s; delay_s < 0: it lags (amplifier phase, filter)";

/// The runout: 1X of the journal rows (mean runout) and of the tilt rows (end difference),
/// fitted on every decimated sample (detrended per block like the rows they correct).
fn fit_runout(p: &Prepared) -> Runout {
    let s = &p.series;
    let w = p.speed_rpm * std::f64::consts::PI / 30.0;
    let t0 = p.raw.start_time_s;
    let (c, sn): (Vec<f64>, Vec<f64>) = s.t_s.iter().map(|&t| ((w * (t - t0)).cos(), (w * (t - t0)).sin())).unzip();
    let (c, sn) = (p.detrended(&c), p.detrended(&sn));
    let design = DMatrix::from_fn(s.len(), 2, |i, j| if j == 0 { c[i] } else { sn[i] });
    let [jx, jy] = s.journal_m();
    let phasor = |v: &[f64]| -> nalgebra::Complex<f64> {
        let target = DVector::from_vec(p.detrended(v));
        match least_squares::solve(&design, &target, &vec![true; s.len()], "runout") {
            // v = a cos + b sin = Re((a - i b) e^{i w t}).
            Ok(f) => nalgebra::Complex::new(f.theta[0], -f.theta[1]),
            Err(_) => nalgebra::Complex::new(0.0, 0.0),
        }
    };
    Runout { omega_rad_s: w, mean: [phasor(&jx), phasor(&jy)], difference: [phasor(&s.tilt_x_m), phasor(&s.tilt_y_m)], t0_s: t0 }
}

/// A clipped plateau at one extreme of a column: the samples on it and its level (the median
/// reading on it), or `None`. The narrowest band below the extreme (and everything beyond it)
/// that holds enough readings and is [`PLATEAU_DENSITY_RATIO`] times denser per code than the
/// band twice as wide below it.
fn plateau(col: &[f64], high: bool, lsb: f64) -> Option<(Vec<bool>, f64)> {
    if col.is_empty() || lsb.is_nan() || lsb <= 0.0 {
        return None;
    }
    // Work in codes measured down from the extreme, so both sides are one case. The extreme
    // is the `min_count`-th reading from the end, not the last: with the card's noise on a
    // plateau, the very last reading is a tail sample codes away from the plateau's bulk.
    let sign = if high { 1.0 } else { -1.0 };
    let min_count = MIN_CLIPPED_SAMPLES.max((MIN_CLIPPED_FRACTION * col.len() as f64).ceil() as usize);
    if col.len() < min_count {
        return None;
    }
    let mut flipped: Vec<f64> = col.iter().map(|v| sign * v).collect();
    let (_, anchor, _) = flipped.select_nth_unstable_by(col.len() - min_count, f64::total_cmp);
    let extreme = *anchor;
    let depth: Vec<f64> = col.iter().map(|v| (extreme - sign * v) / lsb).collect();
    // The anchor alone puts `min_count` readings in every band: a plateau needs several times
    // that, or a handful of samples would make a ratio.
    let min_on = 3 * min_count;
    for w in PLATEAU_WIDTHS_LSB {
        let on = depth.iter().filter(|d| **d <= w).count();
        let below = depth.iter().filter(|d| **d > w && **d <= 3.0 * w).count();
        // Densities per code: `on` over w, `below` over 2 w.
        let dense = (on as f64) * 2.0 >= PLATEAU_DENSITY_RATIO * below as f64;
        let smooth = PEAK_BAND_RATIO * below as f64;
        let significant = (on as f64 - smooth) / (smooth + 1.0).sqrt() >= PLATEAU_MIN_Z;
        if on >= min_on && dense && significant {
            let flags: Vec<bool> = depth.iter().map(|d| *d <= w).collect();
            let mut levels: Vec<f64> = col.iter().zip(&flags).filter(|(_, f)| **f).map(|(v, _)| *v).collect();
            levels.sort_by(f64::total_cmp);
            // `levels` holds `on >= min_count >= 1` readings, so the index is in range.
            let level = levels[levels.len() / 2];
            return Some((flags, level));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::plateau;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};

    /// A 16-bit +-10 V card's code, V.
    const LSB: f64 = 20.0 / 65536.0;

    /// Two tones, 4000 codes peak, quantised: `clip_codes` from the top clipped away, then
    /// the card's own Gaussian noise (`card_noise_codes` rms) added after the clipping.
    fn record(clip_codes: f64, card_noise_codes: f64) -> Vec<f64> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        (0..50_000)
            .map(|i| {
                let t = i as f64 / 5000.0;
                let v = 2500.0 * (2.0 * std::f64::consts::PI * 23.0 * t).sin() + 1500.0 * (2.0 * std::f64::consts::PI * 37.0 * t + 0.4).sin();
                let z: f64 = StandardNormal.sample(&mut rng);
                (v.min(4000.0 - clip_codes) + card_noise_codes * z).round() * LSB
            })
            .collect()
    }

    fn clipped(flags: &[bool]) -> usize {
        flags.iter().filter(|f| **f).count()
    }

    #[test]
    fn an_exact_plateau_is_found_at_its_code() {
        let (flags, level) = plateau(&record(300.0, 0.0), true, LSB).expect("clipped");
        assert!((level / LSB - 3700.0).abs() < 0.5, "level {} codes", level / LSB);
        assert!(clipped(&flags) > 1000);
        assert!(plateau(&record(300.0, 0.0), false, LSB).is_none(), "the unclipped side is not a plateau");
    }

    #[test]
    fn a_plateau_the_card_spreads_over_a_few_codes_is_found() {
        // Clipped a little (a few hundred samples, as a probe just over its range shows) and
        // spread by 1.5 codes rms: the last reading is a noise tail, not the plateau.
        let r = record(40.0, 1.5);
        let exact = clipped(&record(40.0, 0.0).iter().map(|v| (v / LSB).round() == 3960.0).collect::<Vec<_>>());
        let (flags, level) = plateau(&r, true, LSB).expect("clipped");
        assert!((level / LSB - 3960.0).abs() <= 1.0, "level {} codes", level / LSB);
        let found = clipped(&flags) as f64;
        assert!((found / exact as f64 - 1.0).abs() < 0.2, "{found} flagged of {exact} clipped");
    }

    #[test]
    fn an_unclipped_peak_is_not_a_plateau() {
        // Quantised and noise-free, many samples share the top codes, but no more densely than
        // just below them; with the card's noise, neither.
        for noise in [0.0, 0.5, 1.5, 3.0] {
            let r = record(0.0, noise);
            assert!(plateau(&r, true, LSB).is_none(), "noise {noise}");
            assert!(plateau(&r, false, LSB).is_none(), "noise {noise}");
        }
    }
}
