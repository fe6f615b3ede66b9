//! The oil film: force on the journal as a function of its position and velocity relative
//! to the bearing.
//!
//! Three models implement [`Film`]:
//! * [`short::ShortBearing`]: Ocvirk's short-bearing pi-film in closed form, nonlinear
//!   (Adiletta, Guido & Rossi 1996, exact for that film) with its closed-form linear
//!   coefficients; fast, and a cross-check of the numeric model at small L/D.
//! * [`finite::FiniteBearing`]: the isoviscous Reynolds equation on a finite-difference grid
//!   with Swift-Stieber (Reynolds) cavitation, plain or two-axial-groove.
//! * [`map::FilmMap`]: a tabulated wrapper around any film that makes rig simulation with
//!   the finite-length film run many times faster than real time.
//!
//! ## Homogeneity (used by the force map and worth knowing)
//! For the isoviscous Reynolds equation with a cavitation condition of the form `p >= 0`, the
//! pressure depends on rotation and squeeze only through the vector
//! `w = (omega*ex - 2*ey', omega*ey + 2*ex')` (ex = x/c, ey = y/c, primes: time derivatives),
//! and is positively homogeneous of degree one in `w`. Force is therefore
//! `mu * |w| * f(ex, ey, angle(w))`: a function of three variables for any speed and viscosity.

mod banded_cholesky;
pub mod finite;
pub mod map;
pub mod short;

use nalgebra::{Matrix2, Matrix2x4, Vector2};
use serde::{Deserialize, Serialize};

use crate::error::PhysicsError;
use crate::geometry::BearingGeometry;

/// Journal centre relative to bearing centre: position (m) and velocity (m/s).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct FilmState {
    pub x_m: f64,
    pub y_m: f64,
    pub vx_m_s: f64,
    pub vy_m_s: f64,
}

impl FilmState {
    pub fn at_rest(x_m: f64, y_m: f64) -> Self {
        Self { x_m, y_m, vx_m_s: 0.0, vy_m_s: 0.0 }
    }

    /// Eccentricity ratio |r| / c.
    pub fn eccentricity(&self, clearance_m: f64) -> f64 {
        self.x_m.hypot(self.y_m) / clearance_m
    }
}

/// What drives the film besides kinematics: shaft speed and oil viscosity.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Running {
    /// Journal angular speed, rad/s, positive counter-clockwise seen from +z.
    pub omega_rad_s: f64,
    /// Dynamic viscosity of the oil in the film, Pa s.
    pub viscosity_pa_s: f64,
}

impl Running {
    pub fn from_rpm(rpm: f64, viscosity_pa_s: f64) -> Self {
        Self { omega_rad_s: rpm * std::f64::consts::PI / 30.0, viscosity_pa_s }
    }

    /// Finite speed (either sign) and finite, non-negative viscosity; errors name the field.
    pub fn validate(&self) -> Result<(), PhysicsError> {
        PhysicsError::check_finite("running.omega_rad_s", self.omega_rad_s)?;
        PhysicsError::check_finite("running.viscosity_pa_s", self.viscosity_pa_s)?;
        if self.viscosity_pa_s < 0.0 {
            return Err(PhysicsError::invalid("running.viscosity_pa_s", format!("must not be negative, got {}", self.viscosity_pa_s)));
        }
        Ok(())
    }
}

/// Film force on the journal (N) and its Jacobian with respect to `(x, y, vx, vy)`.
/// The Jacobian is `-[K | C]` in Lund's convention.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceJacobian {
    pub force_n: Vector2<f64>,
    pub jacobian: Matrix2x4<f64>,
}

impl ForceJacobian {
    /// Stiffness K = -dF/dr (N/m).
    pub fn stiffness(&self) -> Matrix2<f64> {
        -self.jacobian.fixed_view::<2, 2>(0, 0).into_owned()
    }
    /// Damping C = -dF/dr' (N s/m).
    pub fn damping(&self) -> Matrix2<f64> {
        -self.jacobian.fixed_view::<2, 2>(0, 2).into_owned()
    }
}

/// A model of the oil film.
///
/// Methods take `&mut self` so that numeric models can keep their workspace (and a warm
/// start) between calls without allocating; every call is still a pure function of its
/// arguments up to solver tolerance.
pub trait Film {
    /// The bearing this film belongs to.
    fn geometry(&self) -> &BearingGeometry;

    /// Force of the film on the journal, N.
    ///
    /// Errors: [`PhysicsError::EccentricityLimit`] when the state puts the journal on or
    /// beyond the bearing wall, [`PhysicsError::NonFinite`] for NaN input.
    fn force(&mut self, state: &FilmState, running: &Running) -> Result<Vector2<f64>, PhysicsError>;

    /// Force and Jacobian. The default uses central differences of [`Film::force`] with steps
    /// of `1e-6 c` and `1e-6 c omega`; models with an analytic Jacobian override it.
    fn force_jacobian(&mut self, state: &FilmState, running: &Running) -> Result<ForceJacobian, PhysicsError> {
        let c = self.geometry().clearance_m;
        let force_n = self.force(state, running)?;
        let steps = [1e-6 * c, 1e-6 * c, 1e-6 * c * running.omega_rad_s.abs().max(1.0), 1e-6 * c * running.omega_rad_s.abs().max(1.0)];
        let mut jacobian = Matrix2x4::zeros();
        for (j, &h) in steps.iter().enumerate() {
            let mut plus = *state;
            let mut minus = *state;
            *component_mut(&mut plus, j) += h;
            *component_mut(&mut minus, j) -= h;
            let fp = self.force(&plus, running)?;
            let fm = self.force(&minus, running)?;
            jacobian.set_column(j, &((fp - fm) / (2.0 * h)));
        }
        Ok(ForceJacobian { force_n, jacobian })
    }

    /// Added-mass (fluid inertia) matrix estimate at this state, kg, in the convention
    /// `dF = -M dr''`. `None` when the model has no inertia estimate.
    fn added_mass(&mut self, _state: &FilmState, _running: &Running, _density_kg_m3: f64) -> Result<Option<Matrix2<f64>>, PhysicsError> {
        Ok(None)
    }
}

/// Component `j` of `(x, y, vx, vy)`.
pub fn component_mut(state: &mut FilmState, j: usize) -> &mut f64 {
    match j {
        0 => &mut state.x_m,
        1 => &mut state.y_m,
        2 => &mut state.vx_m_s,
        _ => &mut state.vy_m_s,
    }
}

/// Checks a state is finite and inside the clearance circle.
pub fn check_state(state: &FilmState, clearance_m: f64) -> Result<f64, PhysicsError> {
    for (name, v) in [("film state x_m", state.x_m), ("film state y_m", state.y_m), ("film state vx_m_s", state.vx_m_s), ("film state vy_m_s", state.vy_m_s)] {
        PhysicsError::check_finite(name, v)?;
    }
    let eps = state.eccentricity(clearance_m);
    if eps >= 1.0 {
        return Err(PhysicsError::EccentricityLimit { eccentricity: eps, context: format!("at x = {:.4e} m, y = {:.4e} m", state.x_m, state.y_m) });
    }
    Ok(eps)
}

/// The film models a rig configuration can choose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum FilmModelConfig {
    /// Ocvirk short-bearing pi-film (closed form). Ignores grooves: a 180 degree film.
    Short,
    /// Finite-length Reynolds solution on an `n_theta` x `n_z` grid per pad
    /// (`n_z` counts intervals across the half length; the midplane is a symmetry plane).
    Finite {
        n_theta: usize,
        n_z: usize,
        /// Tabulate the film around the operating point for fast rig simulation.
        #[serde(default = "default_true")]
        tabulate: bool,
    },
}

fn default_true() -> bool {
    true
}
