//! Static equilibrium of the journal under a steady load, and the linear coefficients of the
//! film about it, for any [`Film`].
//!
//! The equilibrium solves `F_film(r, 0) + W_on_journal = 0` by Newton's method on the film's
//! Jacobian, damped so that the eccentricity ratio never leaves [0, 0.98]. The coefficients are
//! the Jacobian at that point (Lund 1987, "Review of the concept of dynamic coefficients for
//! fluid film journal bearings", J. Tribology 109): perturbation about equilibrium.

use nalgebra::{Matrix2, Vector2};
use serde::{Deserialize, Serialize};

use crate::dimensionless;
use crate::error::PhysicsError;
use crate::film::{Film, FilmState, Running};

/// The eight (or twelve) linear coefficients, dimensional, in Lund's convention
/// `dF_on_journal = -(K dr + C dr' + M dr'')`, frame x horizontal / y up.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LinearCoefficients {
    /// Stiffness, N/m, row = force component, column = displacement component.
    pub stiffness_n_m: Matrix2<f64>,
    /// Damping, N s/m.
    pub damping_n_s_m: Matrix2<f64>,
    /// Added mass (fluid inertia), kg, where estimated.
    pub added_mass_kg: Option<Matrix2<f64>>,
}

/// Static equilibrium of the journal and the film's coefficients about it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OperatingPoint {
    pub running: Running,
    /// Magnitude of the steady load carried by the film, N.
    pub load_n: f64,
    /// Steady load on the journal (the force the film balances), N, frame x/y.
    pub load_on_journal_n: Vector2<f64>,
    /// Journal centre relative to bearing centre at equilibrium.
    pub journal: FilmState,
    /// Eccentricity ratio epsilon = e / c.
    pub eccentricity: f64,
    /// Attitude angle between the load line and the line of centres, degrees, positive in the
    /// direction of rotation.
    pub attitude_deg: f64,
    /// Sommerfeld number S = mu N L D / W (R/c)^2, N in rev/s.
    pub sommerfeld: f64,
    pub coefficients: LinearCoefficients,
}

/// Options of the equilibrium search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EquilibriumOptions {
    /// Converged when |F + W| <= tolerance * |W|.
    pub relative_tolerance: f64,
    pub max_iterations: usize,
    /// Estimate added mass with this oil density (kg/m^3), if the film can.
    pub density_kg_m3: Option<f64>,
}

impl Default for EquilibriumOptions {
    fn default() -> Self {
        Self { relative_tolerance: 1e-10, max_iterations: 60, density_kg_m3: None }
    }
}

/// Finds the static equilibrium under `load_on_journal_n` and the coefficients about it.
pub fn solve(film: &mut dyn Film, running: &Running, load_on_journal_n: Vector2<f64>, options: &EquilibriumOptions) -> Result<OperatingPoint, PhysicsError> {
    let geometry = *film.geometry();
    let c = geometry.clearance_m;
    let load_n = load_on_journal_n.norm();
    PhysicsError::check_finite("static load", load_n)?;
    if load_n <= 0.0 {
        return Err(PhysicsError::invalid("load", "the static load on the film must be positive"));
    }
    for (name, v) in [("running.omega_rad_s", running.omega_rad_s), ("running.viscosity_pa_s", running.viscosity_pa_s)] {
        if !v.is_finite() || v <= 0.0 {
            return Err(PhysicsError::invalid(name, format!("must be positive and finite, got {v}")));
        }
    }

    // Initial guess: eccentricity 0.5, line of centres 45 degrees ahead of the load line in
    // the direction of rotation (counter-clockwise).
    let load_dir = load_on_journal_n / load_n;
    let ahead = Matrix2::new(1.0, -1.0, 1.0, 1.0) / std::f64::consts::SQRT_2;
    let mut r = ahead * load_dir * (0.5 * c);
    let max_eps = 0.98;

    let mut residual_norm = f64::INFINITY;
    for _ in 0..options.max_iterations {
        let state = FilmState::at_rest(r.x, r.y);
        let fj = film.force_jacobian(&state, running)?;
        let residual = fj.force_n + load_on_journal_n;
        residual_norm = residual.norm();
        if residual_norm <= options.relative_tolerance * load_n {
            return finish(film, running, load_on_journal_n, load_n, state, fj.stiffness(), fj.damping(), options);
        }
        let position_jacobian = fj.jacobian.fixed_view::<2, 2>(0, 0).into_owned();
        let Some(inverse) = position_jacobian.try_inverse() else {
            return Err(PhysicsError::Singular { what: "equilibrium Newton step (film stiffness)".into(), row: 0 });
        };
        let mut step = -(inverse * residual);
        // Damping: at most 0.2 c per step, and stay inside max_eps.
        let step_norm = step.norm();
        if step_norm > 0.2 * c {
            step *= 0.2 * c / step_norm;
        }
        let mut candidate = r + step;
        let mut shrink = 0;
        while candidate.norm() > max_eps * c && shrink < 40 {
            step *= 0.5;
            candidate = r + step;
            shrink += 1;
        }
        r = candidate;
    }
    Err(PhysicsError::NoConvergence {
        solver: "static equilibrium (Newton)".into(),
        iterations: options.max_iterations,
        residual: residual_norm / load_n,
        hint: "the load may exceed what the film can carry below eccentricity 0.98".into(),
    })
}

#[allow(clippy::too_many_arguments)]
fn finish(
    film: &mut dyn Film,
    running: &Running,
    load_on_journal_n: Vector2<f64>,
    load_n: f64,
    journal: FilmState,
    stiffness_n_m: Matrix2<f64>,
    damping_n_s_m: Matrix2<f64>,
    options: &EquilibriumOptions,
) -> Result<OperatingPoint, PhysicsError> {
    let geometry = *film.geometry();
    let added_mass_kg = match options.density_kg_m3 {
        Some(rho) => film.added_mass(&journal, running, rho)?,
        None => None,
    };
    let r = Vector2::new(journal.x_m, journal.y_m);
    let load_dir = load_on_journal_n / load_n;
    // Signed angle from the load direction to the line of centres, positive counter-clockwise.
    let attitude = (load_dir.x * r.y - load_dir.y * r.x).atan2(load_dir.dot(&r));
    Ok(OperatingPoint {
        running: *running,
        load_n,
        load_on_journal_n,
        journal,
        eccentricity: r.norm() / geometry.clearance_m,
        attitude_deg: attitude.to_degrees(),
        sommerfeld: dimensionless::sommerfeld(&geometry, running, load_n),
        coefficients: LinearCoefficients { stiffness_n_m, damping_n_s_m, added_mass_kg },
    })
}
