//! The floating-housing rig of Zhou et al. (2004), section 2.1, as a deterministic
//! fixed-step simulation.
//!
//! ## Model
//! The bearing housing (mass `m`) floats on the film around a journal that is fixed in space
//! by default, or moves on a prescribed 1X orbit (unbalance or runout of the shaft itself).
//! With `X` the housing's absolute position, `J(t)` the journal's and `r = J - X` the journal
//! relative to the bearing (what the film sees and the bearing probes measure):
//!
//! ```text
//! (m + M_a) X'' = F_exc(t) + F_bellows(t) e_y - m g e_y - F_film(r, r') - F_relax + M_a J'' + F_friction(X')
//! tau z' = r - z                   (only with `film_relaxation`)
//! ```
//!
//! * `F_exc = f1 (cos 45, sin 45) + f2 (cos 135, sin 135)` (exciter angles configurable);
//! * `F_bellows = W + m_nominal g` with a small pneumatic ripple, so the film carries `W`
//!   (the bellows are set to float the housing the rig's operators believe it weighs);
//! * `F_film` is the film force on the journal; the housing feels its reaction;
//! * `M_a` is the injected fluid-inertia added mass (0 unless `fluid_inertia` is set);
//! * `F_relax = -k_r (r - z)` is the injected film relaxation (a Maxwell element in parallel
//!   with the film, [`crate::effects::FilmRelaxation`]; absent unless `film_relaxation` is
//!   set), with its internal coordinate `z` starting relaxed at the equilibrium (`z = r`);
//! * `F_friction` is the injected Coulomb friction, regularised as
//!   `-F_c X' / sqrt(|X'|^2 + v_s^2)` with `v_s` = 1 um/s.
//!
//! Rearranged, this is eq. (2) of the paper: the film force on the journal equals
//! exciter + bellows - weight - housing mass x acceleration.
//!
//! ## Integration
//! The film's damping makes the system stiff at the DAQ rate (at the Zhou point,
//! `C/m ~ 3e4 1/s` against a 5 kHz step). The integrator is the two-stage, L-stable,
//! second-order Rosenbrock method ROS2 of Verwer, Spee, Blom & Hundsdorfer (1999, SIAM J.
//! Sci. Comput. 20), which needs one film Jacobian and two film forces per step and keeps
//! order two with an approximate Jacobian (it is a W-method), so the explicit time
//! dependence of the forcing needs no special treatment. With `film_relaxation` the
//! element's coordinate `z` joins the integrated state (six unknowns instead of four, its
//! exact Jacobian in the stage matrix), so the element keeps the method's order and
//! L-stability even when `tau` is far below the step. Without it the integrator runs the very
//! same four-unknown arithmetic, so records without the effect are unchanged bit for bit.
//! Between steps the state is
//! interpolated by cubic Hermite polynomials on position and velocity, which is what the
//! multiplexed DAQ samples.
//!
//! Exciter inputs are forces applied with a first-order hold between stamps (the exciter
//! amplifiers are far faster than 5 kHz; the force sensors measure what acts).

use std::collections::VecDeque;

use nalgebra::{Const, DimMin, Matrix2, SMatrix, SVector, Vector2};
use serde::{Deserialize, Serialize};

use crate::config::RigConfig;
use crate::daq::{ChannelId, PhysicalSignals};
use crate::effects::{Effects, FilmRelaxation};
use crate::error::PhysicsError;
use crate::film::{Film, FilmState, Running};
use crate::oil::Oil;
use crate::operating_point::{self, EquilibriumOptions, OperatingPoint};

/// Friction regularisation velocity, m/s.
const FRICTION_SMOOTHING_M_S: f64 = 1e-6;

/// Exciter force setpoints acting at a stamp, N, positive pushing the housing along the
/// exciter's axis.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct RigInput {
    pub exciter_n: [f64; 2],
}

/// The true state of the rig at one instant: what the simulator knows and a real rig never
/// tells. Tests judge the identification against it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RigSample {
    pub t_s: f64,
    /// Housing absolute position and velocity (what the frame probes see).
    pub housing_m: Vector2<f64>,
    pub housing_m_s: Vector2<f64>,
    /// Journal relative to bearing, `r = J - X` (what the bearing probes see).
    pub relative_m: Vector2<f64>,
    pub relative_m_s: Vector2<f64>,
    /// Film force on the journal, including any injected added-mass and film-relaxation force.
    pub film_force_n: Vector2<f64>,
    pub exciter_n: [f64; 2],
    pub bellows_n: f64,
    pub temperature_c: f64,
    pub viscosity_pa_s: f64,
}

/// One node of the trajectory, kept for dense output.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Node {
    t_s: f64,
    x: Vector2<f64>,
    v: Vector2<f64>,
    /// The film-relaxation element's internal coordinate (unused, zero, without the effect).
    z: Vector2<f64>,
    input: RigInput,
}

/// The right-hand side of the equations of motion at one state of `N` unknowns: (X, X') with
/// `N = 4`, (X, X', z) with `N = 6` (film relaxation).
struct Derivative<const N: usize> {
    /// d/dt of the state.
    rate: SVector<f64, N>,
    /// Its Jacobian with respect to the state, when asked for.
    jacobian: Option<SMatrix<f64, N, N>>,
    /// The film force as the journal feels it, including any added-mass reaction.
    film_on_journal: Vector2<f64>,
}

/// Rig parameters resolved from the configuration.
#[derive(Debug, Clone)]
struct Params {
    mass_nominal_kg: f64,
    mass_true_kg: f64,
    added_mass_kg: f64,
    exciter_dirs: [Vector2<f64>; 2],
    gravity_m_s2: f64,
    omega_rad_s: f64,
    bearing_load_n: f64,
    ripple_fraction: f64,
    ripple_hz: f64,
    temperature_c: f64,
    heating_rate_c_per_s: f64,
    friction_n: f64,
    orbit_m: f64,
    orbit_phase_rad: f64,
    relaxation: Option<FilmRelaxation>,
    oil: Oil,
}

/// The simulated rig.
pub struct Rig {
    film: Box<dyn Film + Send>,
    params: Params,
    operating_point: OperatingPoint,
    start_s: f64,
    substeps: usize,
    /// Trajectory nodes, oldest first; the last is the current state.
    history: VecDeque<Node>,
    history_capacity: usize,
}

impl std::fmt::Debug for Rig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Rig")
            .field("params", &self.params)
            .field("operating_point", &self.operating_point)
            .field("start_s", &self.start_s)
            .field("substeps", &self.substeps)
            .finish_non_exhaustive()
    }
}

impl Rig {
    /// Builds the rig at static equilibrium at time `start_s`, with the exciters at rest.
    /// `lookback_s` is how far into the past [`Rig::signals_at`] must still answer (the DAQ's
    /// injected channel delay).
    pub fn new(config: &RigConfig, start_s: f64, lookback_s: f64) -> Result<Self, PhysicsError> {
        config.validate()?;
        PhysicsError::check_finite("start time", start_s)?;
        let effects: &Effects = &config.effects;
        let op = &config.operating;
        let viscosity = config.oil.viscosity_pa_s(op.bearing_temperature_c)?;
        let running = Running::from_rpm(op.speed_rpm, viscosity);
        let mass_nominal_kg = config.housing.mass_kg;
        let mass_true_kg = mass_nominal_kg + effects.housing_mass_mismatch.map_or(0.0, |e| e.mass_error_kg);
        if mass_true_kg <= 0.0 {
            return Err(PhysicsError::invalid(
                "effects.housing_mass_mismatch.mass_error_kg",
                format!("makes the true housing mass {mass_true_kg} kg, which is not positive"),
            ));
        }
        let dir = |deg: f64| Vector2::new(deg.to_radians().cos(), deg.to_radians().sin());
        let params = Params {
            mass_nominal_kg,
            mass_true_kg,
            added_mass_kg: effects.fluid_inertia.map_or(0.0, |e| e.added_mass_kg),
            exciter_dirs: [dir(config.housing.exciter_angles_deg[0]), dir(config.housing.exciter_angles_deg[1])],
            gravity_m_s2: config.housing.gravity_m_s2,
            omega_rad_s: running.omega_rad_s,
            bearing_load_n: op.bearing_load_n,
            ripple_fraction: config.static_load.ripple_fraction,
            ripple_hz: config.static_load.ripple_hz,
            temperature_c: op.bearing_temperature_c,
            heating_rate_c_per_s: effects.thermal_drift.map_or(0.0, |e| e.heating_rate_c_per_s),
            friction_n: effects.support_friction.map_or(0.0, |e| e.friction_force_n),
            orbit_m: config.journal.orbit_amplitude_m,
            orbit_phase_rad: config.journal.orbit_phase_deg.to_radians(),
            relaxation: effects.film_relaxation,
            oil: config.oil.clone(),
        };

        // The film carries W: the bellows lift the housing's nominal weight plus W, and the
        // true weight differs only when a mass mismatch is injected.
        let load_on_journal = Vector2::new(0.0, -Self::static_film_load(&params));
        let options = EquilibriumOptions { density_kg_m3: Some(config.oil.density_kg_m3(op.bearing_temperature_c)), ..Default::default() };
        let mut film = config.film_for_rig(&running, load_on_journal)?;
        let operating_point = operating_point::solve(film.as_mut(), &running, load_on_journal, &options).map_err(|e| {
            PhysicsError::invalid(
                "operating.bearing_load_n",
                format!("no static equilibrium for {:.0} N at {} rpm and {} C: {e}", load_on_journal.norm(), op.speed_rpm, op.bearing_temperature_c),
            )
        })?;

        let journal0 = Self::journal_at(&params, start_s);
        let r0 = Vector2::new(operating_point.journal.x_m, operating_point.journal.y_m);
        // The relaxation element starts relaxed (z = r): it carries no static load.
        let node = Node { t_s: start_s, x: journal0.0 - r0, v: journal0.1, z: r0, input: RigInput::default() };
        let substeps = config.simulation.substeps;
        let period = 1.0 / config.daq.sample_rate_hz;
        let history_capacity = ((lookback_s.max(0.0) / (period / substeps as f64)).ceil() as usize + 4 * substeps + 4).max(8);
        let mut history = VecDeque::with_capacity(history_capacity);
        history.push_back(node);
        Ok(Self { film, params, operating_point, start_s, substeps, history, history_capacity })
    }

    /// The static load the film carries when the housing is at rest: bellows minus true weight.
    fn static_film_load(p: &Params) -> f64 {
        p.bearing_load_n + (p.mass_nominal_kg - p.mass_true_kg) * p.gravity_m_s2
    }

    /// The film's operating point at the start (equilibrium and linear coefficients of the
    /// very film the simulation integrates).
    pub fn operating_point(&self) -> &OperatingPoint {
        &self.operating_point
    }

    /// The film the simulation integrates.
    pub fn film_mut(&mut self) -> &mut (dyn Film + Send) {
        self.film.as_mut()
    }

    /// Time of the current state.
    pub fn time_s(&self) -> f64 {
        self.current().t_s
    }

    fn current(&self) -> &Node {
        // The history is created with one node and only ever grows before it is trimmed
        // back to its capacity (>= 8), so it is never empty.
        self.history.back().expect("rig history is never empty")
    }

    /// Journal position and velocity and acceleration at `t`.
    fn journal_at(p: &Params, t: f64) -> (Vector2<f64>, Vector2<f64>, Vector2<f64>) {
        if p.orbit_m == 0.0 {
            return (Vector2::zeros(), Vector2::zeros(), Vector2::zeros());
        }
        let phi = p.omega_rad_s * t + p.orbit_phase_rad;
        let (s, c) = phi.sin_cos();
        let w = p.omega_rad_s;
        (Vector2::new(c, s) * p.orbit_m, Vector2::new(-s, c) * (p.orbit_m * w), Vector2::new(c, s) * (-p.orbit_m * w * w))
    }

    fn bellows_at(p: &Params, t: f64) -> f64 {
        let mean = p.bearing_load_n + p.mass_nominal_kg * p.gravity_m_s2;
        mean * (1.0 + p.ripple_fraction * (2.0 * std::f64::consts::PI * p.ripple_hz * t).sin())
    }

    fn temperature_at(&self, t: f64) -> f64 {
        self.params.temperature_c + self.params.heating_rate_c_per_s * (t - self.start_s)
    }

    fn running_at(&self, t: f64) -> Result<Running, PhysicsError> {
        let viscosity = if self.params.heating_rate_c_per_s == 0.0 {
            self.operating_point.running.viscosity_pa_s
        } else {
            self.params.oil.viscosity_pa_s(self.temperature_at(t))?
        };
        Ok(Running { omega_rad_s: self.params.omega_rad_s, viscosity_pa_s: viscosity })
    }

    /// The integrated state of `node`: `(X, X')`, and `z` when `N = 6`.
    fn state_of<const N: usize>(node: &Node) -> SVector<f64, N> {
        let mut y = SVector::<f64, N>::zeros();
        y[0] = node.x.x;
        y[1] = node.x.y;
        y[2] = node.v.x;
        y[3] = node.v.y;
        if N == 6 {
            y[4] = node.z.x;
            y[5] = node.z.y;
        }
        y
    }

    /// Time derivative of the state (see [`Derivative`]) and, if asked, its Jacobian.
    fn rhs<const N: usize>(&mut self, t: f64, y: &SVector<f64, N>, input: &RigInput, jacobian: bool) -> Result<Derivative<N>, PhysicsError> {
        let p = &self.params;
        let x = Vector2::new(y[0], y[1]);
        let v = Vector2::new(y[2], y[3]);
        // The relaxation element and its coordinate, when the state carries it.
        let relaxation = if N == 6 { p.relaxation.map(|e| (e, Vector2::new(y[4], y[5]))) } else { None };
        let (j, jd, jdd) = Self::journal_at(p, t);
        let r = j - x;
        let rd = jd - v;
        let state = FilmState { x_m: r.x, y_m: r.y, vx_m_s: rd.x, vy_m_s: rd.y };
        let running = self.running_at(t)?;
        let (film_force, film_jac) = if jacobian {
            let fj = self.film.force_jacobian(&state, &running)?;
            (fj.force_n, Some(fj.jacobian))
        } else {
            (self.film.force(&state, &running)?, None)
        };
        let p = &self.params;
        let exciter = p.exciter_dirs[0] * input.exciter_n[0] + p.exciter_dirs[1] * input.exciter_n[1];
        let vertical = Self::bellows_at(p, t) - p.mass_true_kg * p.gravity_m_s2;
        let speed_s = (v.norm_squared() + FRICTION_SMOOTHING_M_S * FRICTION_SMOOTHING_M_S).sqrt();
        let friction = -v * (p.friction_n / speed_s);
        let m_dyn = p.mass_true_kg + p.added_mass_kg;
        // Film plus relaxation element on the journal: F_relax = -k_r (r - z).
        let film_total = match relaxation {
            Some((e, z)) => film_force - (r - z) * e.stiffness_n_m,
            None => film_force,
        };
        let accel = (exciter + Vector2::new(0.0, vertical) - film_total + jdd * p.added_mass_kg + friction) / m_dyn;
        let mut f = SVector::<f64, N>::zeros();
        f[0] = v.x;
        f[1] = v.y;
        f[2] = accel.x;
        f[3] = accel.y;
        if let Some((e, z)) = relaxation {
            let zd = (r - z) / e.time_constant_s;
            f[4] = zd.x;
            f[5] = zd.y;
        }
        let jac = film_jac.map(|fj| {
            // d accel / d X = (dF/dr)/m (r = J - X); d accel / d X' = (dF/dr')/m + friction.
            let mut d_pos: Matrix2<f64> = fj.fixed_view::<2, 2>(0, 0).into_owned() / m_dyn;
            let mut d_vel: Matrix2<f64> = fj.fixed_view::<2, 2>(0, 2).into_owned() / m_dyn;
            if p.friction_n > 0.0 {
                let s3 = speed_s * speed_s * speed_s;
                d_vel -= (Matrix2::identity() / speed_s - v * v.transpose() / s3) * (p.friction_n / m_dyn);
            }
            let mut a = SMatrix::<f64, N, N>::zeros();
            a[(0, 2)] = 1.0;
            a[(1, 3)] = 1.0;
            if let Some((e, _)) = relaxation {
                // F_relax depends on r = J - X and z: d accel / d X gains -k_r/m, d accel / d z
                // is -k_r/m, and z' = (r - z)/tau gives -1/tau on both X and z.
                let k_m = Matrix2::identity() * (e.stiffness_n_m / m_dyn);
                let inv_tau = Matrix2::identity() * (1.0 / e.time_constant_s);
                d_pos -= k_m;
                a.fixed_view_mut::<2, 2>(2, 4).copy_from(&-k_m);
                a.fixed_view_mut::<2, 2>(4, 0).copy_from(&-inv_tau);
                a.fixed_view_mut::<2, 2>(4, 4).copy_from(&-inv_tau);
            }
            a.fixed_view_mut::<2, 2>(2, 0).copy_from(&d_pos);
            a.fixed_view_mut::<2, 2>(2, 2).copy_from(&d_vel);
            a
        });
        // The film force as the journal feels it, including the added-mass reaction.
        let film_on_journal = film_total + (accel - jdd) * p.added_mass_kg;
        Ok(Derivative { rate: f, jacobian: jac, film_on_journal })
    }

    /// Advances the rig to `stamp_s` with exciter forces `input` acting at `stamp_s` (linear
    /// between the previous stamp's input and this one) and returns the true state there.
    pub fn step(&mut self, input: &RigInput, stamp_s: f64) -> Result<RigSample, PhysicsError> {
        PhysicsError::check_finite("rig step stamp", stamp_s)?;
        for (k, f) in input.exciter_n.iter().enumerate() {
            PhysicsError::check_finite(&format!("exciter {} force", k + 1), *f)?;
        }
        let start = *self.current();
        if stamp_s <= start.t_s {
            return Err(PhysicsError::invalid("stamp", format!("rig time must advance: stamp {stamp_s} s is not after {} s", start.t_s)));
        }
        let node = if self.params.relaxation.is_some() { self.advance::<6>(start, input, stamp_s)? } else { self.advance::<4>(start, input, stamp_s)? };
        self.sample_at_node(&node)
    }

    /// The substeps of [`Rig::step`] from `start` to `stamp_s` on a state of `N` unknowns;
    /// returns the last node (also pushed to the history).
    fn advance<const N: usize>(&mut self, start: Node, input: &RigInput, stamp_s: f64) -> Result<Node, PhysicsError>
    where
        Const<N>: DimMin<Const<N>, Output = Const<N>>,
    {
        let h = (stamp_s - start.t_s) / self.substeps as f64;
        let gamma = 1.0 + std::f64::consts::FRAC_1_SQRT_2;
        let mut node = start;
        for k in 0..self.substeps {
            let t0 = start.t_s + h * k as f64;
            let t1 = if k + 1 == self.substeps { stamp_s } else { t0 + h };
            let in0 = lerp_input(&start.input, input, (t0 - start.t_s) / (stamp_s - start.t_s));
            let in1 = lerp_input(&start.input, input, (t1 - start.t_s) / (stamp_s - start.t_s));
            let y0 = Self::state_of::<N>(&node);
            let d0 = self.rhs(t0, &y0, &in0, true)?;
            let f0 = d0.rate;
            // `rhs` asked with jacobian = true always returns Some.
            let jac = d0.jacobian.unwrap_or_else(SMatrix::<f64, N, N>::zeros);
            let w = SMatrix::<f64, N, N>::identity() - jac * (gamma * h);
            let lu = w.lu();
            let k1 = lu.solve(&f0).ok_or_else(|| PhysicsError::Singular { what: "rig Rosenbrock stage matrix".into(), row: 0 })?;
            let f1 = self.rhs(t1, &(y0 + k1 * h), &in1, false)?.rate;
            let k2 = lu.solve(&(f1 - k1 * 2.0)).ok_or_else(|| PhysicsError::Singular { what: "rig Rosenbrock stage matrix".into(), row: 0 })?;
            let y1 = y0 + (k1 * 1.5 + k2 * 0.5) * h;
            for i in 0..N {
                PhysicsError::check_finite("rig state", y1[i])?;
            }
            let z = if N == 6 { Vector2::new(y1[4], y1[5]) } else { node.z };
            node = Node { t_s: t1, x: Vector2::new(y1[0], y1[1]), v: Vector2::new(y1[2], y1[3]), z, input: in1 };
            self.history.push_back(node);
            while self.history.len() > self.history_capacity {
                self.history.pop_front();
            }
        }
        Ok(node)
    }

    fn sample_at_node(&mut self, node: &Node) -> Result<RigSample, PhysicsError> {
        let film_force_n = if self.params.relaxation.is_some() {
            self.rhs(node.t_s, &Self::state_of::<6>(node), &node.input, false)?.film_on_journal
        } else {
            self.rhs(node.t_s, &Self::state_of::<4>(node), &node.input, false)?.film_on_journal
        };
        let (j, jd, _) = Self::journal_at(&self.params, node.t_s);
        let running = self.running_at(node.t_s)?;
        Ok(RigSample {
            t_s: node.t_s,
            housing_m: node.x,
            housing_m_s: node.v,
            relative_m: j - node.x,
            relative_m_s: jd - node.v,
            film_force_n,
            exciter_n: node.input.exciter_n,
            bellows_n: Self::bellows_at(&self.params, node.t_s),
            temperature_c: self.temperature_at(node.t_s),
            viscosity_pa_s: running.viscosity_pa_s,
        })
    }

    /// The true physical values every DAQ channel would see at time `t`, interpolated from
    /// the kept trajectory (cubic Hermite). Before the kept history the rig is taken as it was
    /// at its oldest kept node; after the current time, as it is now.
    pub fn signals_at(&self, t: f64) -> PhysicalSignals {
        let (a, b) = self.bracket(t);
        let (x, input) = if b.t_s > a.t_s {
            let h = b.t_s - a.t_s;
            let s = ((t - a.t_s) / h).clamp(0.0, 1.0);
            let s2 = s * s;
            let s3 = s2 * s;
            let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
            let h10 = s3 - 2.0 * s2 + s;
            let h01 = -2.0 * s3 + 3.0 * s2;
            let h11 = s3 - s2;
            let x = a.x * h00 + a.v * (h10 * h) + b.x * h01 + b.v * (h11 * h);
            (x, lerp_input(&a.input, &b.input, s))
        } else {
            (a.x, a.input)
        };
        let (j, _, _) = Self::journal_at(&self.params, t);
        let r = j - x;
        let mut values = [0.0; 10];
        values[ChannelId::ProbeAX.index()] = r.x;
        values[ChannelId::ProbeAY.index()] = r.y;
        values[ChannelId::ProbeBX.index()] = r.x;
        values[ChannelId::ProbeBY.index()] = r.y;
        values[ChannelId::FrameX.index()] = x.x;
        values[ChannelId::FrameY.index()] = x.y;
        values[ChannelId::F1.index()] = input.exciter_n[0];
        values[ChannelId::F2.index()] = input.exciter_n[1];
        values[ChannelId::F3.index()] = Self::bellows_at(&self.params, t);
        values[ChannelId::Temperature.index()] = self.temperature_at(t);
        PhysicalSignals { values, shaft_angle_rad: (self.params.omega_rad_s * t).rem_euclid(2.0 * std::f64::consts::PI) }
    }

    fn bracket(&self, t: f64) -> (Node, Node) {
        let first = self.history.front().copied();
        let last = *self.current();
        let Some(first) = first else { return (last, last) };
        if t <= first.t_s {
            return (first, first);
        }
        if t >= last.t_s {
            return (last, last);
        }
        // Binary search over the (time-ordered) history.
        let (mut lo, mut hi) = (0usize, self.history.len() - 1);
        while hi - lo > 1 {
            let mid = (lo + hi) / 2;
            if self.history[mid].t_s <= t {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        (self.history[lo], self.history[hi])
    }
}

fn lerp_input(a: &RigInput, b: &RigInput, s: f64) -> RigInput {
    RigInput { exciter_n: [a.exciter_n[0] + (b.exciter_n[0] - a.exciter_n[0]) * s, a.exciter_n[1] + (b.exciter_n[1] - a.exciter_n[1]) * s] }
}
