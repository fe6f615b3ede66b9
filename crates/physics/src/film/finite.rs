//! Finite-length journal-bearing film: the isoviscous Reynolds equation on a finite-difference
//! grid with the Swift-Stieber (Reynolds) cavitation condition, plain or two-axial-groove.
//!
//! # Equation
//! Laminar, incompressible, isoviscous thin film (Reynolds 1886), with `s = R theta` and the
//! journal surface speed `U = omega R`:
//!
//! ```text
//! d/ds(h^3 dp/ds) + d/dz(h^3 dp/dz) = 6 mu U dh/ds + 12 mu dh/dt,
//! h = c - x cos(theta) - y sin(theta),   dh/dt = -(x' cos(theta) + y' sin(theta)).
//! ```
//!
//! With `H = h / c`, `zeta = z / R` and `p = mu (R/c)^2 Pi` (so `Pi` is in 1/s and no speed
//! enters the scaling, which keeps `omega = 0` squeeze films well posed):
//!
//! ```text
//! d/dtheta(H^3 dPi/dtheta) + d/dzeta(H^3 dPi/dzeta) = 6 omega dH/dtheta + 12 dH/dt
//!   = 6 [(omega ex - 2 ey') sin(theta) - (omega ey + 2 ex') cos(theta)],   ex = x/c, ...
//! ```
//!
//! # Grid and discretisation
//! Each pad (for [`BearingKind::Plain`] the whole periodic circle) carries `n_theta` intervals
//! circumferentially and `n_z` intervals across the **half** length: the midplane `z = 0` is a
//! symmetry plane (`dp/dz = 0`), the edge `z = L/2` is at ambient (`p = 0`), and so are the pad
//! ends (groove edges) of a grooved bearing; a plain bearing is periodic in `theta`.
//! The operator is discretised by finite volumes (the conservative 5-point stencil): the
//! circumferential conductance of a face uses `H^3` at the face's mid-angle, the axial one `H^3`
//! at the node; the midplane row is a half cell. Multiplying each row by its cell area makes the
//! matrix `A` (of `-div(H^3 grad)`) **symmetric** and, with the Dirichlet edges, a positive
//! definite **M-matrix**. The right-hand side is `b = -area * rhs`. Forces use the same cell
//! areas as quadrature weights (the trapezoid rule on this grid, since boundary nodes carry
//! `p = 0`), which also makes the discrete damping matrix exactly symmetric.
//!
//! Unknowns are ordered axial-index fastest, so `A` is banded with half-bandwidth `n_z` and is
//! factorised by the banded Cholesky of `banded_cholesky.rs`. The one exception is the
//! periodic wrap of a plain bearing (the face between the last and the first column): those
//! `n_z` couplings are taken out of the band and put back exactly by the Sherman-Morrison-
//! Woodbury identity (Woodbury 1950): `A = B + U G U^T`, `u_j = e_last,j - e_first,j`, with `B`
//! the band matrix "cut" at theta = 0 (still SPD thanks to the Dirichlet edge), so
//! `A^-1 r = B^-1 r - Z (G^-1 + U^T Z)^-1 U^T B^-1 r`, `Z = B^-1 U`. This is correct whatever the
//! cavitation pattern (a wrap face with a cavitated end simply becomes a Dirichlet face).
//!
//! # Cavitation: the linear complementarity problem
//! Swift (1932) and Stieber (1933) rupture the film where the pressure would fall below
//! ambient, with zero pressure gradient on the free boundary. Discretely this is the linear
//! complementarity problem (Cryer 1971)
//!
//! ```text
//! Pi >= 0,   lambda = A Pi - b >= 0,   Pi_k lambda_k = 0.
//! ```
//!
//! Christopherson (1941) solved it by projected SOR; here it is solved by the primal-dual
//! active-set method (Hintermüller, Ito & Kunisch 2002, "The primal-dual active set strategy
//! as a semismooth Newton method", SIAM J. Optim. 13(3) 865-888): guess the full-film (free)
//! set `F`, solve `A_FF Pi_F = b_F` with `Pi = 0` elsewhere, then move a free node with
//! `Pi < 0` to the cavitated set and a cavitated node with `lambda < 0` to the free set, until
//! nothing moves. For an M-matrix the iterates are monotone after the first step and the method
//! terminates in finitely many steps, each one banded Cholesky of the free nodes (cavitated
//! nodes carry `Pi = 0` and drop out of the system). A tiny hysteresis (a node only
//! switches if its `Pi` or `lambda` is below `-1e-10` of the largest magnitude) stops
//! round-off from flipping degenerate nodes. The first call starts from `F = {b > 0}` (the
//! converging-wedge half-Sommerfeld guess); later calls start from the previous call's set, so
//! a Newton step or a time step costs one to three steps (a small state change: one).
//!
//! # Dynamic coefficients
//! Lund's perturbation method (Lund & Thomsen 1978, "A calculation method and data for the
//! dynamic coefficients of oil-lubricated journal bearings", ASME; Lund 1987, J. Tribol. 109):
//! on the converged film region, with the free boundary held fixed (to first order the moving
//! boundary adds nothing: `p = grad p = 0` there),
//!
//! ```text
//! A_FF dPi/dq = (db/dq - (dA/dq) Pi)_F,   q in (x, y, x', y'),
//! ```
//!
//! reusing the factorisation of the last active-set step. `dA/dq Pi` is the same stencil with
//! `H^3` replaced by `3 H^2 dH/dq`. This is the exact derivative of the discrete map wherever the
//! active set is locally constant (checked against central differences in the tests). The
//! Jacobian returned is `-[K | C]`.
//!
//! At a degenerate point where nothing drives the film (`b = 0`: no rotation and no squeeze, or
//! a centred, still journal; `Pi = 0`), the discrete LCP map is only positively homogeneous, not differentiable; each
//! column is then the symmetric difference quotient `(Pi(db/dq) - Pi(-db/dq)) / 2` of two
//! LCP solves, i.e. exactly what a central difference of the force would return.
//!
//! # Added mass (fluid inertia)
//! Reinhardt & Lund (1975, "The influence of fluid inertia on the dynamic properties of
//! journal bearings", J. Lubr. Technol. 97(2) 159-167) expand the film in the reduced Reynolds
//! number; the leading temporal-inertia correction is a pressure that solves the same operator
//! on the same film region,
//!
//! ```text
//! div(h^3 grad p_I) = rho h^2 d2h/dt2,   d2h/dt2 = -(x'' cos(theta) + y'' sin(theta)),
//! ```
//!
//! and `M_ij = -dF_i/dq''_j`. For a centred, full, short plain film this gives
//! `M = pi rho R L^3 / (12 c)`. The bulk-flow (averaged-momentum) model gives 6/5 of this
//! estimate, so treat it as an order-of-magnitude figure for the film's added mass.
//! The region is the converged film region of the viscous solution. When nothing drives a
//! viscous pressure (`b = 0`: `omega = 0` and no squeeze velocity, or a centred, still journal)
//! there is no film region to inherit, and the full film is used: the film is then full of oil
//! at ambient pressure, and a pure inertia pressure may go below ambient (a choice: acceleration
//! from rest before any cavity forms). With [`Cavitation::FullFilm`] the full film is always
//! used.
//!
//! # Cost
//! Only the free nodes enter the factorised system (numbered in grid order, so the band stays
//! at `n_z`). Within one state, successive active-set steps change the free set only from some
//! node on, and row `i` of a Cholesky factor depends only on the leading `i + 1` rows, so a
//! step refactorises only the trailing rows (the rupture boundary of a grooved pad moves at the
//! end of the numbering). The primal-dual iteration moves the boundary by about one column per
//! step, so a cold start costs about as many steps as the boundary travels columns.
//!
//! # Accuracy, grid convergence and the default grid
//! The force converges smoothly, second order (mostly in `n_z`). The coefficients, being the
//! exact derivative of the discrete system on a free set that moves in whole-node steps, carry
//! a first-order, non-monotone "staircase" noise of a few tenths of a percent of the largest
//! coefficient on practical grids (a secant of the force over a step spanning several node
//! switches averages it out and agrees with fine-grid values). See [`GridSpec::default`] and
//! the study in `tests/lund_validation.rs`. Against Lund & Thomsen (1978), L/D 0.5 and 1.0,
//! the converged model matches eccentricity to 0.001 and attitude to 0.1 degree, K and B to
//! 1-3 %, except the tiny Kyx = -0.13 at L/D 0.5, eps 0.655, where it converges to -0.143.

use nalgebra::{Matrix2, Matrix2x4, Vector2};
use serde::{Deserialize, Serialize};

use super::banded_cholesky::BandedCholesky;
use crate::error::PhysicsError;
use crate::film::{check_state, Film, FilmState, ForceJacobian, Running};
use crate::geometry::{BearingGeometry, BearingKind};

/// Grid of the finite-length film.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    /// Intervals per pad circumferentially (for a plain bearing: over 360 degrees).
    pub n_theta: usize,
    /// Intervals across the half length, midplane (symmetry, `dp/dz = 0`) to edge (`p = 0`).
    pub n_z: usize,
}

impl GridSpec {
    /// Smallest accepted `n_theta`.
    pub const MIN_N_THETA: usize = 8;
    /// Largest accepted `n_theta`.
    pub const MAX_N_THETA: usize = 4096;
    /// Smallest accepted `n_z`.
    pub const MIN_N_Z: usize = 2;
    /// Largest accepted `n_z`.
    pub const MAX_N_Z: usize = 256;
    /// Largest accepted band storage per pad, `n_theta * n_z * (n_z + 1)` numbers (160 MB).
    pub const MAX_BAND_STORAGE: usize = 20_000_000;

    /// Checks the bounds; `prefix` is the dotted path of this grid in its config file, and the
    /// error names the field (`film.n_theta`).
    pub fn validate(&self, prefix: &str) -> Result<(), PhysicsError> {
        if !(Self::MIN_N_THETA..=Self::MAX_N_THETA).contains(&self.n_theta) {
            return Err(PhysicsError::invalid(
                format!("{prefix}.n_theta"),
                format!("must lie in [{}, {}] intervals per pad, got {}", Self::MIN_N_THETA, Self::MAX_N_THETA, self.n_theta),
            ));
        }
        if !(Self::MIN_N_Z..=Self::MAX_N_Z).contains(&self.n_z) {
            return Err(PhysicsError::invalid(
                format!("{prefix}.n_z"),
                format!("must lie in [{}, {}] intervals across the half length, got {}", Self::MIN_N_Z, Self::MAX_N_Z, self.n_z),
            ));
        }
        let storage = self.n_theta * self.n_z * (self.n_z + 1);
        if storage > Self::MAX_BAND_STORAGE {
            return Err(PhysicsError::invalid(
                format!("{prefix}.n_z"),
                format!(
                    "grid {} x {} needs {storage} band entries per pad, more than the {} allowed; reduce n_z or n_theta",
                    self.n_theta,
                    self.n_z,
                    Self::MAX_BAND_STORAGE
                ),
            ));
        }
        Ok(())
    }
}

impl Default for GridSpec {
    /// The default grid: 72 intervals per pad, 8 across the half length.
    ///
    /// Chosen by the grid-convergence study in `tests/lund_validation.rs`
    /// (`grid_convergence_study`, run with `--ignored --nocapture`, which documents the
    /// numbers): the coarsest grid whose coefficients lie within 0.5 % (of the largest |K| or
    /// |B|) of a 288 x 64 solution on all ten Lund & Thomsen rows, with eccentricity and
    /// attitude within 0.0015 and 0.12 degrees, and that passes the Lund & Thomsen validation.
    /// One coefficient set at the Zhou operating point takes about 1.1 ms on it (36 x 8: 0.5
    /// ms, but 0.8 % noise and a Lund Kyx miss; 72 x 12: 1.8 ms, equilibrium twice as close).
    /// The study is on grooved pads of 160 degrees; a plain bearing spreads the same `n_theta`
    /// over 360 degrees (5 degrees per interval instead of 2.2), so give it about twice as many.
    fn default() -> Self {
        Self { n_theta: 72, n_z: 8 }
    }
}

/// How the film ruptures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Cavitation {
    /// Swift-Stieber (Reynolds) free boundary: `p >= 0`, solved as a linear complementarity
    /// problem. The physical choice and the default.
    #[default]
    SwiftStieber,
    /// No rupture: the full-Sommerfeld film, pressures may go negative. Linear in the
    /// kinematics; useful for squeeze-film checks against closed forms.
    FullFilm,
}

/// Pressure of the last solve on one pad, on the full grid including boundary nodes.
///
/// `pressure_pa[i * z_m.len() + j]` is the pressure at `theta_rad[i]`, `z_m[j]`. `z_m` runs
/// from the midplane (`0`) to the edge (`L/2`); the other half is the mirror image. For a
/// grooved bearing `theta_rad` runs from the pad's start to its end (both at ambient); for a
/// plain bearing it holds the `n_theta` distinct nodes `0, dtheta, ..., 2 pi - dtheta`.
#[derive(Debug, Clone, PartialEq)]
pub struct PadPressure {
    pub theta_rad: Vec<f64>,
    pub z_m: Vec<f64>,
    pub pressure_pa: Vec<f64>,
}

impl PadPressure {
    /// Pressure at grid node `(i, j)`, `None` outside the grid.
    pub fn at(&self, i: usize, j: usize) -> Option<f64> {
        if i >= self.theta_rad.len() || j >= self.z_m.len() {
            return None;
        }
        self.pressure_pa.get(i * self.z_m.len() + j).copied()
    }

    /// Largest pressure on the pad, Pa.
    pub fn max_pa(&self) -> f64 {
        self.pressure_pa.iter().copied().fold(0.0, f64::max)
    }
}

/// Active-set steps allowed beyond two per grid column before giving up. The method
/// terminates in finitely many steps (at most one per node); in practice the rupture boundary
/// moves about one column per step, so a cold start takes as many steps as the boundary has
/// columns to travel (about 10 on the default grid) and a warm one one to three.
const EXTRA_ACTIVE_SET_STEPS: usize = 100;

/// Relative size below which a pressure or multiplier does not switch a node (round-off guard).
const SWITCH_TOLERANCE: f64 = 1e-10;

/// The factorisation of one pad's reduced matrix: a band Cholesky plus, for a plain bearing,
/// the Woodbury correction for the periodic wrap faces.
#[derive(Debug, Clone, Default)]
struct Factorisation {
    band: BandedCholesky,
    /// Wrap faces with both ends in the film: (index at the last column, index at the first
    /// column, conductance).
    wrap: Vec<(usize, usize, f64)>,
    /// `Z = B^-1 U`, column-major, `wrap.len()` columns of length `band.order()`.
    z_cols: Vec<f64>,
    /// Cholesky factor of the capacitance matrix `G^-1 + U^T Z` (dense, stored as a band).
    capacitance: BandedCholesky,
    work: Vec<f64>,
}

impl Factorisation {
    /// Completes the factorisation once `band` is assembled (rows from `first_row` on; the
    /// ones before are factorised already) and `wrap` filled.
    fn factor_from(&mut self, first_row: usize, what: &str) -> Result<(), PhysicsError> {
        self.band.factor_from(first_row).map_err(|row| PhysicsError::Singular { what: format!("{what}: banded Reynolds matrix"), row })?;
        let m = self.wrap.len();
        if m == 0 {
            return Ok(());
        }
        let n = self.band.order();
        self.z_cols.clear();
        self.z_cols.resize(m * n, 0.0);
        for (col, &(p, q, _)) in self.wrap.iter().enumerate() {
            let z = &mut self.z_cols[col * n..(col + 1) * n];
            z[p] = 1.0;
            z[q] = -1.0;
            self.band.solve_in_place(z);
        }
        self.capacitance.reset(m, m - 1);
        for (r, &(pr, qr, g)) in self.wrap.iter().enumerate() {
            self.capacitance.add(r, r, 1.0 / g);
            for s in 0..=r {
                let z = &self.z_cols[s * n..(s + 1) * n];
                self.capacitance.add(r, s, z[pr] - z[qr]);
            }
        }
        self.capacitance.factor().map_err(|row| PhysicsError::Singular { what: format!("{what}: periodic (Woodbury) capacitance matrix"), row })
    }

    /// Solves `A x = rhs` in place.
    fn solve(&mut self, x: &mut [f64]) {
        self.band.solve_in_place(x);
        if self.wrap.is_empty() {
            return;
        }
        let n = self.band.order();
        self.work.clear();
        self.work.extend(self.wrap.iter().map(|&(p, q, _)| x[p] - x[q]));
        self.capacitance.solve_in_place(&mut self.work);
        for (col, &t) in self.work.iter().enumerate() {
            let z = &self.z_cols[col * n..(col + 1) * n];
            for (xi, zi) in x.iter_mut().zip(z) {
                *xi -= t * zi;
            }
        }
    }
}

/// One independent film: a pad of a grooved bearing or the periodic film of a plain one.
#[derive(Debug, Clone)]
struct PadSystem {
    periodic: bool,
    /// Columns of unknowns (theta nodes that are not at ambient).
    n_col: usize,
    /// Unknowns per column (`j = 0` midplane .. `n_z - 1`; `j = n_z` is the edge).
    n_z: usize,
    start_rad: f64,
    dtheta: f64,
    dzeta: f64,
    /// Axial weight of a row: 1/2 for the midplane half cell, else 1.
    wz: Vec<f64>,
    cos_node: Vec<f64>,
    sin_node: Vec<f64>,
    cos_face: Vec<f64>,
    sin_face: Vec<f64>,
    // State-dependent.
    h_node: Vec<f64>,
    h_face: Vec<f64>,
    h3_node: Vec<f64>,
    h3_face: Vec<f64>,
    b: Vec<f64>,
    pi: Vec<f64>,
    free: Vec<bool>,
    /// Position of each node in the reduced (free-node) system, `usize::MAX` if cavitated.
    pos: Vec<usize>,
    /// Free set of the current factorisation, and whether it belongs to the current state.
    factored_free: Vec<bool>,
    factor_valid: bool,
    /// Diagonal of the full operator per node: the sum of the node's face conductances.
    diag: Vec<f64>,
    warm: bool,
    last_steps: usize,
    // Workspace.
    factorisation: Factorisation,
    work: Vec<f64>,
    work2: Vec<f64>,
    gather: Vec<f64>,
    coef_node: Vec<f64>,
    coef_face: Vec<f64>,
}

impl PadSystem {
    fn new(start_rad: f64, end_rad: f64, periodic: bool, grid: GridSpec, half_length_over_radius: f64) -> Self {
        let n_col = if periodic { grid.n_theta } else { grid.n_theta - 1 };
        let n_face = if periodic { n_col } else { n_col + 1 };
        let dtheta = (end_rad - start_rad) / grid.n_theta as f64;
        let offset = if periodic { 0.0 } else { 1.0 };
        let node_theta: Vec<f64> = (0..n_col).map(|c| start_rad + (c as f64 + offset) * dtheta).collect();
        let face_theta: Vec<f64> = (0..n_face).map(|l| start_rad + (l as f64 + 0.5) * dtheta).collect();
        let n = n_col * grid.n_z;
        Self {
            periodic,
            n_col,
            n_z: grid.n_z,
            start_rad,
            dtheta,
            dzeta: half_length_over_radius / grid.n_z as f64,
            wz: (0..grid.n_z).map(|j| if j == 0 { 0.5 } else { 1.0 }).collect(),
            cos_node: node_theta.iter().map(|t| t.cos()).collect(),
            sin_node: node_theta.iter().map(|t| t.sin()).collect(),
            cos_face: face_theta.iter().map(|t| t.cos()).collect(),
            sin_face: face_theta.iter().map(|t| t.sin()).collect(),
            h_node: vec![1.0; n_col],
            h_face: vec![1.0; n_face],
            h3_node: vec![1.0; n_col],
            h3_face: vec![1.0; n_face],
            b: vec![0.0; n],
            pi: vec![0.0; n],
            free: vec![false; n],
            pos: vec![usize::MAX; n],
            factored_free: vec![false; n],
            factor_valid: false,
            diag: vec![0.0; n],
            warm: false,
            last_steps: 0,
            factorisation: Factorisation::default(),
            work: vec![0.0; n],
            work2: vec![0.0; n],
            gather: Vec::with_capacity(n),
            coef_node: vec![0.0; n_col],
            coef_face: vec![0.0; n_face],
        }
    }

    fn n(&self) -> usize {
        self.n_col * self.n_z
    }

    fn n_face(&self) -> usize {
        self.h_face.len()
    }

    /// Columns either side of circumferential face `l` (`None`: an ambient pad end) and
    /// whether it is the periodic wrap face.
    #[inline]
    fn face_ends(&self, l: usize) -> (Option<usize>, Option<usize>, bool) {
        if self.periodic {
            (Some(l), Some((l + 1) % self.n_col), l + 1 == self.n_col)
        } else {
            (l.checked_sub(1), (l < self.n_col).then_some(l), false)
        }
    }

    /// Cell area in (theta, zeta) of row `j`.
    #[inline]
    fn area(&self, j: usize) -> f64 {
        self.dtheta * self.dzeta * self.wz[j]
    }

    /// Film thickness for journal position `(ex, ey) = (x, y) / c`, and the right-hand side
    /// `b = -area * 6 [w1 sin - w2 cos]` with `w = (omega ex - 2 ey', omega ey + 2 ex')` (1/s).
    fn set_state(&mut self, ex: f64, ey: f64, w1: f64, w2: f64) {
        for c in 0..self.n_col {
            let h = 1.0 - ex * self.cos_node[c] - ey * self.sin_node[c];
            self.h_node[c] = h;
            self.h3_node[c] = h * h * h;
        }
        for l in 0..self.n_face() {
            let h = 1.0 - ex * self.cos_face[l] - ey * self.sin_face[l];
            self.h_face[l] = h;
            self.h3_face[l] = h * h * h;
        }
        let rt = self.dzeta / self.dtheta;
        let rz = self.dtheta / self.dzeta;
        for c in 0..self.n_col {
            let (left, right) = if self.periodic { ((c + self.n_col - 1) % self.n_col, c) } else { (c, c + 1) };
            let theta = (self.h3_face[left] + self.h3_face[right]) * rt;
            let axial = self.h3_node[c] * rz;
            for j in 0..self.n_z {
                self.diag[c * self.n_z + j] = theta * self.wz[j] + axial * if j == 0 { 1.0 } else { 2.0 };
            }
        }
        self.factor_valid = false;
        for c in 0..self.n_col {
            let f = 6.0 * (w1 * self.sin_node[c] - w2 * self.cos_node[c]);
            for j in 0..self.n_z {
                self.b[c * self.n_z + j] = -self.area(j) * f;
            }
        }
    }

    /// Assembles the matrix of the free (full-film) nodes only, numbered in grid order
    /// (cavitated nodes carry `Pi = 0` and drop out), and factorises it. Numbering in grid
    /// order keeps every coupling within `n_z` places, so the half-bandwidth is `n_z`.
    ///
    /// Within one state only the free set changes between active-set steps, and row `i` of a
    /// Cholesky factor depends only on the leading `i + 1` rows of the matrix: so only the rows
    /// from the first node whose status changed are reassembled and refactorised. On a
    /// grooved pad the rupture boundary moves downstream, at the end of the numbering, and a
    /// step costs a few columns instead of a whole factorisation. (Periodic films always
    /// refactorise fully: the wrap faces couple the first and last columns.)
    fn assemble_and_factor(&mut self, what: &str) -> Result<(), PhysicsError> {
        let nz = self.n_z;
        let n = self.n();
        let reuse = self.factor_valid && !self.periodic && self.factorisation.band.bandwidth() == nz;
        let first_change = if reuse { self.free.iter().zip(&self.factored_free).position(|(a, b)| a != b) } else { Some(0) };
        let Some(first_change) = first_change else {
            return Ok(()); // same state, same free set: the factorisation stands
        };
        let mut n_free = 0;
        let mut first_row = 0;
        for (k, (pos, &free)) in self.pos.iter_mut().zip(&self.free).enumerate() {
            if k == first_change {
                first_row = n_free;
            }
            *pos = if free {
                n_free += 1;
                n_free - 1
            } else {
                usize::MAX
            };
        }
        let f = &mut self.factorisation;
        if first_row == 0 {
            f.band.reset(n_free, nz);
        } else {
            f.band.truncate_rows(first_row, n_free);
        }
        f.wrap.clear();
        let rt = self.dzeta / self.dtheta;
        let rz = self.dtheta / self.dzeta;
        let n_col = self.n_col;
        for k in first_change..n {
            let p = self.pos[k];
            if p == usize::MAX {
                continue;
            }
            let (c, j) = (k / nz, k % nz);
            let row = f.band.row_mut(p);
            let mut diag = self.diag[k];
            let left_face = if self.periodic { (c + n_col - 1) % n_col } else { c };
            if c >= 1 {
                let q = self.pos[k - nz];
                if q != usize::MAX {
                    row[nz - (p - q)] = -self.h3_face[left_face] * self.wz[j] * rt;
                }
            } else if self.periodic && self.free[(n_col - 1) * nz + j] {
                // Wrap face to the last column, both ends in the film: Woodbury term.
                diag -= self.h3_face[left_face] * self.wz[j] * rt;
            }
            if self.periodic && c + 1 == n_col && self.free[j] {
                let g = self.h3_face[c] * self.wz[j] * rt;
                diag -= g;
                f.wrap.push((p, self.pos[j], g));
            }
            if j >= 1 && self.free[k - 1] {
                row[nz - 1] = -self.h3_node[c] * rz;
            }
            row[nz] = diag;
        }
        self.factored_free.copy_from_slice(&self.free);
        self.factor_valid = false;
        f.factor_from(first_row, what)?;
        self.factor_valid = true;
        Ok(())
    }

    /// Solves `A_FF x_F = rhs_F` for a full-grid vector in place (entries off the free set are
    /// ignored on input and zero on output), with the current factorisation.
    fn solve_free(factorisation: &mut Factorisation, pos: &[usize], gather: &mut Vec<f64>, x: &mut [f64]) {
        gather.clear();
        gather.extend(x.iter().zip(pos).filter(|(_, &p)| p != usize::MAX).map(|(v, _)| *v));
        factorisation.solve(gather);
        for (v, &p) in x.iter_mut().zip(pos) {
            *v = if p == usize::MAX { 0.0 } else { gather[p] };
        }
    }

    /// `y = A(coef) x` with the full (unreduced) operator whose `H^3` is replaced by the given
    /// per-face and per-node coefficients.
    fn apply(&self, coef_face: &[f64], coef_node: &[f64], x: &[f64], y: &mut [f64]) {
        let nz = self.n_z;
        y.fill(0.0);
        let rt = self.dzeta / self.dtheta;
        let rz = self.dtheta / self.dzeta;
        for (l, &cf) in coef_face.iter().enumerate() {
            let (left, right, _) = self.face_ends(l);
            for j in 0..nz {
                let g = cf * self.wz[j] * rt;
                let xa = left.map_or(0.0, |c| x[c * nz + j]);
                let xb = right.map_or(0.0, |c| x[c * nz + j]);
                if let Some(c) = left {
                    y[c * nz + j] += g * (xa - xb);
                }
                if let Some(c) = right {
                    y[c * nz + j] += g * (xb - xa);
                }
            }
        }
        for (c, &cn) in coef_node.iter().enumerate() {
            let g = cn * rz;
            for j in 0..nz {
                let k = c * nz + j;
                let xb = if j + 1 < nz { x[k + 1] } else { 0.0 };
                let d = g * (x[k] - xb);
                y[k] += d;
                if j + 1 < nz {
                    y[k + 1] -= d;
                }
            }
        }
    }

    /// Solves the film for the current `b`: the LCP by primal-dual active-set steps (or the
    /// full film), leaving `pi` and the factorisation of the final free set.
    fn solve(&mut self, cavitation: Cavitation, what: &str) -> Result<(), PhysicsError> {
        if cavitation == Cavitation::FullFilm {
            self.free.fill(true);
            self.assemble_and_factor(what)?;
            self.pi.copy_from_slice(&self.b);
            Self::solve_free(&mut self.factorisation, &self.pos, &mut self.gather, &mut self.pi);
            self.last_steps = 1;
            return Ok(());
        }
        if !self.warm {
            for (free, &b) in self.free.iter_mut().zip(&self.b) {
                *free = b > 0.0;
            }
        }
        let b_scale = self.b.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let mut moved = 0;
        let max_steps = 2 * self.n_col + EXTRA_ACTIVE_SET_STEPS;
        for step in 1..=max_steps {
            if let Err(e) = self.assemble_and_factor(what) {
                self.warm = false;
                return Err(e);
            }
            self.pi.copy_from_slice(&self.b);
            Self::solve_free(&mut self.factorisation, &self.pos, &mut self.gather, &mut self.pi);
            // lambda = A Pi - b on the cavitated nodes (here `lambda` holds A Pi).
            let mut lambda = std::mem::take(&mut self.work);
            self.apply(&self.h3_face, &self.h3_node, &self.pi, &mut lambda);
            let pi_scale = self.pi.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
            let (tol_pi, tol_lambda) = (SWITCH_TOLERANCE * pi_scale, SWITCH_TOLERANCE * b_scale);
            moved = 0;
            for (((free, &pi), &l), &b) in self.free.iter_mut().zip(&self.pi).zip(&lambda).zip(&self.b) {
                // A film node with Pi < 0 cavitates; a cavity node with lambda < 0 rejoins.
                let now = if *free { pi >= -tol_pi } else { l - b < -tol_lambda };
                if now != *free {
                    *free = now;
                    moved += 1;
                }
            }
            self.work = lambda;
            if moved == 0 {
                self.warm = true;
                self.last_steps = step;
                return Ok(());
            }
        }
        self.warm = false;
        Err(PhysicsError::NoConvergence {
            solver: format!("primal-dual active-set solver (Swift-Stieber cavitation) of {what}"),
            iterations: max_steps,
            residual: moved as f64 / self.free.len().max(1) as f64,
            hint: "the residual is the fraction of nodes still switching between film and cavity; \
                   try a finer or coarser grid"
                .into(),
        })
    }

    /// `sum_k area_k v_k (cos theta_k, sin theta_k)` over the pad's half length.
    fn moment(&self, v: &[f64]) -> Vector2<f64> {
        let mut s = Vector2::zeros();
        for c in 0..self.n_col {
            let mut col = 0.0;
            for j in 0..self.n_z {
                col += self.area(j) * v[c * self.n_z + j];
            }
            s.x += col * self.cos_node[c];
            s.y += col * self.sin_node[c];
        }
        s
    }

    fn b_is_zero(&self) -> bool {
        self.b.iter().all(|&v| v == 0.0)
    }

    /// Derivative of the right-hand side `b` with respect to `q` = x, y, x', y' (SI), per
    /// node, into `out`.
    fn db_dq(&self, q: usize, omega: f64, clearance_m: f64, out: &mut [f64]) {
        for c in 0..self.n_col {
            let (co, si) = (self.cos_node[c], self.sin_node[c]);
            // b = -area * 6 [(omega x/c - 2 y'/c) sin - (omega y/c + 2 x'/c) cos]
            let df = match q {
                0 => 6.0 * omega * si / clearance_m,
                1 => -6.0 * omega * co / clearance_m,
                2 => -12.0 * co / clearance_m,
                _ => -12.0 * si / clearance_m,
            };
            for j in 0..self.n_z {
                out[c * self.n_z + j] = -self.area(j) * df;
            }
        }
    }

    /// `d Pi / d q` for q = x, y, x', y' (SI units of q), on the frozen free set, each as a
    /// moment `sum area dPi/dq (cos, sin)`. `pi` and the factorisation must be those of the
    /// current state.
    fn jacobian_moments(&mut self, omega: f64, clearance_m: f64, cavitation: Cavitation, what: &str) -> Result<[Vector2<f64>; 4], PhysicsError> {
        let mut out = [Vector2::zeros(); 4];
        if cavitation == Cavitation::SwiftStieber && self.b_is_zero() {
            return self.degenerate_jacobian_moments(omega, clearance_m, what);
        }
        let mut rhs = std::mem::take(&mut self.work);
        let mut da_pi = std::mem::take(&mut self.work2);
        for (q, slot) in out.iter_mut().enumerate() {
            self.db_dq(q, omega, clearance_m, &mut rhs);
            if q < 2 {
                // dA/dq Pi with d(H^3)/dq = 3 H^2 dH/dq, dH/dx = -cos/c, dH/dy = -sin/c.
                let (faces, nodes) = if q == 0 { (&self.cos_face, &self.cos_node) } else { (&self.sin_face, &self.sin_node) };
                for (l, cf) in self.coef_face.iter_mut().enumerate() {
                    *cf = -3.0 * self.h_face[l] * self.h_face[l] * faces[l] / clearance_m;
                }
                for (c, cn) in self.coef_node.iter_mut().enumerate() {
                    *cn = -3.0 * self.h_node[c] * self.h_node[c] * nodes[c] / clearance_m;
                }
                self.apply(&self.coef_face, &self.coef_node, &self.pi, &mut da_pi);
                for (r, d) in rhs.iter_mut().zip(&da_pi) {
                    *r -= d;
                }
            }
            Self::solve_free(&mut self.factorisation, &self.pos, &mut self.gather, &mut rhs);
            *slot = self.moment(&rhs);
        }
        self.work = rhs;
        self.work2 = da_pi;
        Ok(out)
    }

    /// Jacobian moments where `b = 0` (nothing drives the film): the symmetric difference
    /// quotient of the positively homogeneous LCP map, `(Pi(d) - Pi(-d)) / 2`, `d = db/dq`.
    /// Leaves the pad in its true state (`Pi = 0`, `b = 0`) afterwards.
    fn degenerate_jacobian_moments(&mut self, omega: f64, clearance_m: f64, what: &str) -> Result<[Vector2<f64>; 4], PhysicsError> {
        let mut out = [Vector2::zeros(); 4];
        let saved_free = self.free.clone();
        let mut d = vec![0.0; self.n()];
        let mut result = Ok(());
        for (q, slot) in out.iter_mut().enumerate() {
            self.db_dq(q, omega, clearance_m, &mut d);
            let mut m = Vector2::zeros();
            for sign in [1.0, -1.0] {
                for (b, &dv) in self.b.iter_mut().zip(&d) {
                    *b = sign * dv;
                }
                self.warm = false;
                if let Err(e) = self.solve(Cavitation::SwiftStieber, what) {
                    result = Err(e);
                    break;
                }
                m += sign * 0.5 * self.moment(&self.pi);
            }
            if result.is_err() {
                break;
            }
            *slot = m;
        }
        // Restore the true (degenerate) state.
        self.b.fill(0.0);
        self.pi.fill(0.0);
        self.free = saved_free;
        self.warm = false;
        let restore = self.assemble_and_factor(what);
        result?;
        restore?;
        Ok(out)
    }

    /// Inertia-pressure moments for unit x'' and y'' (kg-free: multiply by rho), on the frozen
    /// free set, or on the full film when `full_film`.
    fn inertia_moments(&mut self, radius_m: f64, clearance_m: f64, full_film: bool, what: &str) -> Result<[Vector2<f64>; 2], PhysicsError> {
        if full_film {
            self.free.fill(true);
            self.assemble_and_factor(what)?;
        }
        let mut rhs = std::mem::take(&mut self.work);
        let mut out = [Vector2::zeros(); 2];
        for (q, slot) in out.iter_mut().enumerate() {
            // div(H^3 grad p_I) = rho R^2 H^2 h''/c, h'' = -(x'' cos + y'' sin): A p_I = area R^2 H^2 (cos|sin)/c.
            for c in 0..self.n_col {
                let g = if q == 0 { self.cos_node[c] } else { self.sin_node[c] };
                let s = radius_m * radius_m * self.h_node[c] * self.h_node[c] * g / clearance_m;
                for j in 0..self.n_z {
                    let k = c * self.n_z + j;
                    rhs[k] = self.area(j) * s;
                }
            }
            Self::solve_free(&mut self.factorisation, &self.pos, &mut self.gather, &mut rhs);
            *slot = self.moment(&rhs);
        }
        self.work = rhs;
        Ok(out)
    }
}

/// Finite-length journal-bearing film (see the module documentation for the method).
#[derive(Debug, Clone)]
pub struct FiniteBearing {
    geometry: BearingGeometry,
    grid: GridSpec,
    cavitation: Cavitation,
    pads: Vec<PadSystem>,
    /// `mu (R/c)^2` of the last solve: `p = scale * Pi`.
    pressure_scale_pa_s: f64,
}

impl FiniteBearing {
    /// A film on `geometry` with `grid`, Swift-Stieber cavitation.
    ///
    /// Errors: [`PhysicsError::InvalidConfig`] naming `bearing.*` or `film.*`.
    pub fn new(geometry: BearingGeometry, grid: GridSpec) -> Result<Self, PhysicsError> {
        geometry.validate("bearing")?;
        grid.validate("film")?;
        let periodic = matches!(geometry.kind, BearingKind::Plain);
        let half_length_over_radius = 0.5 * geometry.length_m / geometry.radius_m();
        let pads = geometry.pads().iter().map(|pad| PadSystem::new(pad.start_rad, pad.end_rad, periodic, grid, half_length_over_radius)).collect();
        Ok(Self { geometry, grid, cavitation: Cavitation::SwiftStieber, pads, pressure_scale_pa_s: 0.0 })
    }

    /// The same film with another cavitation model (forgets the warm start).
    pub fn with_cavitation(mut self, cavitation: Cavitation) -> Self {
        self.cavitation = cavitation;
        for pad in &mut self.pads {
            pad.warm = false;
        }
        self
    }

    pub fn cavitation(&self) -> Cavitation {
        self.cavitation
    }

    pub fn grid(&self) -> GridSpec {
        self.grid
    }

    /// Active-set steps the last solve took on each pad (1 = the warm-started set was right).
    pub fn last_active_set_steps(&self) -> Vec<usize> {
        self.pads.iter().map(|p| p.last_steps).collect()
    }

    /// Pressure field of the last solve, one entry per pad (see [`PadPressure`]). All zero
    /// before the first solve.
    pub fn pressure_field(&self) -> Vec<PadPressure> {
        let r = self.geometry.radius_m();
        self.pads
            .iter()
            .map(|pad| {
                let nz = pad.n_z;
                let z_m: Vec<f64> = (0..=nz).map(|j| j as f64 * pad.dzeta * r).collect();
                let n_theta_nodes = if pad.periodic { pad.n_col } else { pad.n_col + 2 };
                let theta_rad: Vec<f64> = (0..n_theta_nodes).map(|i| pad.start_rad + i as f64 * pad.dtheta).collect();
                let mut pressure_pa = vec![0.0; n_theta_nodes * (nz + 1)];
                let shift = usize::from(!pad.periodic);
                for c in 0..pad.n_col {
                    for j in 0..nz {
                        pressure_pa[(c + shift) * (nz + 1) + j] = self.pressure_scale_pa_s * pad.pi[c * nz + j];
                    }
                }
                PadPressure { theta_rad, z_m, pressure_pa }
            })
            .collect()
    }

    /// Validates the inputs, sets every pad's film and right-hand side, solves. Returns the
    /// force constant `2 R^2 mu (R/c)^2` (force = -constant * sum of the pads' moments).
    fn solve_state(&mut self, state: &FilmState, running: &Running) -> Result<f64, PhysicsError> {
        let c = self.geometry.clearance_m;
        check_state(state, c)?;
        running.validate()?;
        let (ex, ey) = (state.x_m / c, state.y_m / c);
        let omega = running.omega_rad_s;
        let w1 = omega * ex - 2.0 * state.vy_m_s / c;
        let w2 = omega * ey + 2.0 * state.vx_m_s / c;
        let r = self.geometry.radius_m();
        let scale = running.viscosity_pa_s * (r / c) * (r / c);
        self.pressure_scale_pa_s = scale;
        let cavitation = self.cavitation;
        for (i, pad) in self.pads.iter_mut().enumerate() {
            pad.set_state(ex, ey, w1, w2);
            pad.solve(cavitation, &format!("the finite-length film (pad {i})"))?;
        }
        Ok(2.0 * r * r * scale)
    }
}

impl Film for FiniteBearing {
    fn geometry(&self) -> &BearingGeometry {
        &self.geometry
    }

    fn force(&mut self, state: &FilmState, running: &Running) -> Result<Vector2<f64>, PhysicsError> {
        let k = self.solve_state(state, running)?;
        Ok(-k * self.pads.iter().map(|p| p.moment(&p.pi)).sum::<Vector2<f64>>())
    }

    /// Force and the analytic Jacobian `-[K | C]` by Lund's perturbation of the discrete
    /// system on the converged film region (see the module documentation).
    fn force_jacobian(&mut self, state: &FilmState, running: &Running) -> Result<ForceJacobian, PhysicsError> {
        let k = self.solve_state(state, running)?;
        let c = self.geometry.clearance_m;
        let cavitation = self.cavitation;
        let force = -k * self.pads.iter().map(|p| p.moment(&p.pi)).sum::<Vector2<f64>>();
        let mut jacobian = Matrix2x4::zeros();
        for (i, pad) in self.pads.iter_mut().enumerate() {
            let moments = pad.jacobian_moments(running.omega_rad_s, c, cavitation, &format!("the finite-length film (pad {i})"))?;
            for (q, m) in moments.iter().enumerate() {
                let col = jacobian.column(q) - k * m;
                jacobian.set_column(q, &col);
            }
        }
        Ok(ForceJacobian { force_n: force, jacobian })
    }

    /// Reinhardt & Lund (1975) temporal-inertia estimate (see the module documentation):
    /// always `Some`.
    fn added_mass(&mut self, state: &FilmState, running: &Running, density_kg_m3: f64) -> Result<Option<Matrix2<f64>>, PhysicsError> {
        PhysicsError::check_finite("oil density", density_kg_m3)?;
        if density_kg_m3 < 0.0 {
            return Err(PhysicsError::invalid("density_kg_m3", format!("must not be negative, got {density_kg_m3}")));
        }
        self.solve_state(state, running)?;
        let r = self.geometry.radius_m();
        let c = self.geometry.clearance_m;
        let cavitation = self.cavitation;
        let mut m = Matrix2::zeros();
        for (i, pad) in self.pads.iter_mut().enumerate() {
            let full_film = cavitation == Cavitation::FullFilm || pad.b_is_zero();
            let what = format!("the finite-length film (pad {i}, inertia pressure)");
            let moments = pad.inertia_moments(r, c, full_film, &what)?;
            if full_film && cavitation == Cavitation::SwiftStieber {
                // The full film was only for the inertia estimate: the warm start should
                // remember the viscous (empty) film region.
                pad.warm = false;
            }
            for (q, mo) in moments.iter().enumerate() {
                // F = -2 R^2 sum area p_I (cos, sin); M_iq = -dF_i/dq'' = 2 R^2 rho * moment.
                let col = m.column(q) + 2.0 * r * r * density_kg_m3 * mo;
                m.set_column(q, &col);
            }
        }
        Ok(Some(m))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::component_mut;
    use crate::operating_point::{solve, EquilibriumOptions};
    use std::f64::consts::PI;
    use std::time::Instant;

    fn grooved(slenderness: f64) -> BearingGeometry {
        BearingGeometry {
            diameter_m: 0.1,
            length_m: slenderness * 0.1,
            clearance_m: 1e-4,
            kind: BearingKind::TwoAxialGroove { groove_arc_deg: 20.0, groove_centre_deg: 0.0 },
        }
    }

    fn plain(slenderness: f64) -> BearingGeometry {
        BearingGeometry { kind: BearingKind::Plain, ..grooved(slenderness) }
    }

    fn running() -> Running {
        Running { omega_rad_s: 200.0, viscosity_pa_s: 0.02 }
    }

    fn rotate(v: Vector2<f64>, angle: f64) -> Vector2<f64> {
        let (s, c) = angle.sin_cos();
        Vector2::new(c * v.x - s * v.y, s * v.x + c * v.y)
    }

    fn rotate_state(state: &FilmState, angle: f64) -> FilmState {
        let r = rotate(Vector2::new(state.x_m, state.y_m), angle);
        let v = rotate(Vector2::new(state.vx_m_s, state.vy_m_s), angle);
        FilmState { x_m: r.x, y_m: r.y, vx_m_s: v.x, vy_m_s: v.y }
    }

    /// Central differences of the force with steps `rel * c` and `rel * c * max(omega, 1)`.
    fn central_differences(film: &mut FiniteBearing, state: &FilmState, run: &Running, rel: f64) -> Matrix2x4<f64> {
        let c = film.geometry().clearance_m;
        let mut j = Matrix2x4::zeros();
        for q in 0..4 {
            let h = if q < 2 { rel * c } else { rel * c * run.omega_rad_s.abs().max(1.0) };
            let (mut plus, mut minus) = (*state, *state);
            *component_mut(&mut plus, q) += h;
            *component_mut(&mut minus, q) -= h;
            let fp = film.force(&plus, run).unwrap();
            let fm = film.force(&minus, run).unwrap();
            j.set_column(q, &((fp - fm) / (2.0 * h)));
        }
        j
    }

    /// Largest deviation of `a` from `b` relative to the largest entry of the same 2x2 block
    /// (stiffness or damping) of `b`.
    fn block_relative_error(a: &Matrix2x4<f64>, b: &Matrix2x4<f64>) -> f64 {
        let mut worst = 0.0_f64;
        for block in 0..2 {
            let scale = b.fixed_view::<2, 2>(0, 2 * block).amax();
            let err = (a.fixed_view::<2, 2>(0, 2 * block) - b.fixed_view::<2, 2>(0, 2 * block)).amax();
            worst = worst.max(err / scale);
        }
        worst
    }

    #[test]
    fn grid_validation_names_the_field() {
        assert!(GridSpec::default().validate("film").is_ok());
        let bad = [
            (GridSpec { n_theta: 4, n_z: 8 }, "film.n_theta"),
            (GridSpec { n_theta: 100_000, n_z: 8 }, "film.n_theta"),
            (GridSpec { n_theta: 36, n_z: 1 }, "film.n_z"),
            (GridSpec { n_theta: 36, n_z: 1000 }, "film.n_z"),
            (GridSpec { n_theta: 4096, n_z: 256 }, "film.n_z"),
        ];
        for (grid, field) in bad {
            match grid.validate("film") {
                Err(PhysicsError::InvalidConfig { field: f, .. }) => assert_eq!(f, field, "{grid:?}"),
                other => panic!("{grid:?}: expected InvalidConfig on {field}, got {other:?}"),
            }
        }
        match FiniteBearing::new(BearingGeometry { clearance_m: -1.0, ..grooved(0.5) }, GridSpec::default()) {
            Err(PhysicsError::InvalidConfig { field, .. }) => assert_eq!(field, "bearing.clearance_m"),
            other => panic!("expected InvalidConfig, got {other:?}"),
        }
        assert!(FiniteBearing::new(grooved(0.5), GridSpec { n_theta: 2, n_z: 2 }).is_err());
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let mut film = FiniteBearing::new(grooved(0.5), GridSpec::default()).unwrap();
        let run = running();
        let nan = FilmState { x_m: f64::NAN, ..Default::default() };
        assert!(matches!(film.force(&nan, &run), Err(PhysicsError::NonFinite { .. })));
        let wall = FilmState::at_rest(0.0, -1e-4);
        assert!(matches!(film.force(&wall, &run), Err(PhysicsError::EccentricityLimit { .. })));
        assert!(matches!(film.force_jacobian(&wall, &run), Err(PhysicsError::EccentricityLimit { .. })));
        let ok = FilmState::at_rest(0.0, -5e-5);
        let bad_run = Running { omega_rad_s: f64::INFINITY, viscosity_pa_s: 0.02 };
        assert!(matches!(film.force(&ok, &bad_run), Err(PhysicsError::NonFinite { .. })));
        let negative = Running { omega_rad_s: 100.0, viscosity_pa_s: -1.0 };
        assert!(matches!(film.force(&ok, &negative), Err(PhysicsError::InvalidConfig { .. })));
        assert!(film.added_mass(&ok, &run, f64::NAN).is_err());
        assert!(film.added_mass(&ok, &run, -850.0).is_err());
        // Still usable afterwards, and close to the wall too.
        assert!(film.force(&ok, &run).unwrap().y > 0.0);
        let near_wall = FilmState::at_rest(0.0, -0.999e-4);
        let f = film.force_jacobian(&near_wall, &run).unwrap();
        assert!(f.force_n.y > 0.0 && f.jacobian.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn centred_still_journal_carries_no_load() {
        let run = running();
        for geometry in [grooved(0.5), plain(1.0)] {
            for cavitation in [Cavitation::SwiftStieber, Cavitation::FullFilm] {
                let mut film = FiniteBearing::new(geometry, GridSpec::default()).unwrap().with_cavitation(cavitation);
                let f = film.force(&FilmState::default(), &run).unwrap();
                assert_eq!(f, Vector2::zeros(), "{:?} {cavitation:?}", geometry.kind);
                assert!(film.pressure_field().iter().all(|p| p.max_pa() == 0.0));
            }
        }
    }

    #[test]
    fn jacobian_matches_central_differences() {
        let run = running();
        let cases = [
            (grooved(0.5), Cavitation::SwiftStieber, FilmState { x_m: 3.1e-5, y_m: -4.4e-5, vx_m_s: 2e-4, vy_m_s: -1e-4 }),
            (grooved(1.0), Cavitation::SwiftStieber, FilmState::at_rest(2.0e-5, -6.0e-5)),
            (plain(0.8), Cavitation::SwiftStieber, FilmState { x_m: -2.0e-5, y_m: -5.0e-5, vx_m_s: -3e-4, vy_m_s: 5e-4 }),
            (plain(0.8), Cavitation::FullFilm, FilmState { x_m: 4.0e-5, y_m: 1.0e-5, vx_m_s: 1e-4, vy_m_s: 0.0 }),
        ];
        for (geometry, cavitation, state) in cases {
            let mut film = FiniteBearing::new(geometry, GridSpec::default()).unwrap().with_cavitation(cavitation);
            let analytic = film.force_jacobian(&state, &run).unwrap();
            assert_eq!(analytic.force_n, film.force(&state, &run).unwrap());
            let numeric = central_differences(&mut film, &state, &run, 1e-6);
            let err = block_relative_error(&analytic.jacobian, &numeric);
            println!("{:?} {cavitation:?}: Jacobian vs central differences, relative error {err:.2e}", geometry.kind);
            assert!(err < 1e-4, "{:?} {cavitation:?}: relative error {err:e}\nanalytic {}\nnumeric {}", geometry.kind, analytic.jacobian, numeric);
            // Frozen-film-region damping is exactly symmetric.
            let c = analytic.damping();
            assert!((c[(0, 1)] - c[(1, 0)]).abs() <= 1e-9 * c.amax(), "damping not symmetric: {c}");
        }
    }

    #[test]
    fn jacobian_at_the_centre_is_the_symmetric_difference_quotient() {
        // Nothing drives the film at the centre: the LCP map is only positively homogeneous,
        // and the Jacobian is defined as what a central difference returns.
        let run = running();
        for geometry in [plain(0.5), grooved(1.0)] {
            let mut film = FiniteBearing::new(geometry, GridSpec::default()).unwrap();
            let state = FilmState::default();
            let analytic = film.force_jacobian(&state, &run).unwrap();
            assert_eq!(analytic.force_n, Vector2::zeros());
            let numeric = central_differences(&mut film, &state, &run, 1e-6);
            let err = block_relative_error(&analytic.jacobian, &numeric);
            println!("{:?} at the centre: Jacobian vs central differences, relative error {err:.2e}", geometry.kind);
            assert!(err < 1e-4, "{:?}: relative error {err:e}\n{}\n{}", geometry.kind, analytic.jacobian, numeric);
            // Pure cross-coupling at the centre: displaced along +x, the journal is pushed
            // along +y (Kyx < 0); squeeze damping is positive.
            assert!(analytic.stiffness()[(1, 0)] < 0.0 && analytic.damping()[(0, 0)] > 0.0, "{}", analytic.jacobian);
        }
    }

    #[test]
    fn plain_bearing_force_rotates_with_the_journal() {
        let run = running();
        let grid = GridSpec { n_theta: 48, n_z: 8 };
        let dtheta = 2.0 * PI / grid.n_theta as f64;
        for cavitation in [Cavitation::SwiftStieber, Cavitation::FullFilm] {
            let mut film = FiniteBearing::new(plain(0.7), grid).unwrap().with_cavitation(cavitation);
            let state = FilmState { x_m: 5.0e-5, y_m: -2.0e-5, vx_m_s: 1e-4, vy_m_s: 3e-4 };
            let base = film.force_jacobian(&state, &run).unwrap();
            // Whole grid steps map the grid onto itself: equal to round-off.
            for steps in [1, 7, 24, 41] {
                let angle = steps as f64 * dtheta;
                let turned = film.force_jacobian(&rotate_state(&state, angle), &run).unwrap();
                let expected = rotate(base.force_n, angle);
                assert!((turned.force_n - expected).norm() < 1e-9 * expected.norm(), "{cavitation:?} {steps}: {} vs {}", turned.force_n, expected);
                let (s, c) = angle.sin_cos();
                let rot = Matrix2::new(c, -s, s, c);
                let k = rot * base.stiffness() * rot.transpose();
                assert!((turned.stiffness() - k).amax() < 1e-8 * k.amax(), "{cavitation:?} {steps}: K {} vs {}", turned.stiffness(), k);
            }
            // Any other angle: equal to discretisation error.
            let angle = 0.3;
            let turned = film.force(&rotate_state(&state, angle), &run).unwrap();
            let expected = rotate(base.force_n, angle);
            assert!((turned - expected).norm() < 2e-3 * expected.norm(), "{cavitation:?}: {turned} vs {expected}");
        }
    }

    #[test]
    fn squeeze_only_force_opposes_the_velocity() {
        let run = Running { omega_rad_s: 0.0, viscosity_pa_s: 0.02 };
        for geometry in [plain(0.5), grooved(0.5)] {
            for cavitation in [Cavitation::SwiftStieber, Cavitation::FullFilm] {
                let mut film = FiniteBearing::new(geometry, GridSpec::default()).unwrap().with_cavitation(cavitation);
                for (x, y, vx, vy) in [(0.0, 0.0, 1e-3, 0.0), (0.0, 0.0, 0.0, -1e-3), (2e-5, -3e-5, 7e-4, 4e-4), (-5e-5, 1e-5, -2e-4, 1e-3)] {
                    let state = FilmState { x_m: x, y_m: y, vx_m_s: vx, vy_m_s: vy };
                    let f = film.force(&state, &run).unwrap();
                    let v = Vector2::new(vx, vy);
                    // Power into the film is -F.v = integral of h^3 |grad p|^2 / (12 mu) > 0.
                    assert!(f.dot(&v) < 0.0, "{:?} {cavitation:?}: F {f} v {v}", geometry.kind);
                    if x == 0.0 && y == 0.0 && matches!(geometry.kind, BearingKind::Plain) {
                        // Centred plain film: the force is exactly against the velocity.
                        assert!(f.perp(&v).abs() < 1e-9 * f.norm() * v.norm(), "{cavitation:?}: F {f} v {v}");
                    }
                }
            }
        }
    }

    /// Exact centred full-film squeeze for any L/D: p = P(z) cos(theta), P'' - P/R^2 = -k gives
    /// F = -pi R k R^2 (L - 2R tanh(L/2R)); k = 12 mu x'/c^3 (viscous) or rho x''/c (inertia).
    fn centred_full_film_integral(geometry: &BearingGeometry) -> f64 {
        let (r, l) = (geometry.radius_m(), geometry.length_m);
        PI * r * r * r * (l - 2.0 * r * (l / (2.0 * r)).tanh())
    }

    #[test]
    fn centred_full_film_squeeze_damping_matches_the_closed_form() {
        let run = Running { omega_rad_s: 0.0, viscosity_pa_s: 0.02 };
        for slenderness in [0.1, 0.5, 1.0] {
            let geometry = plain(slenderness);
            let mut film = FiniteBearing::new(geometry, GridSpec { n_theta: 72, n_z: 16 }).unwrap().with_cavitation(Cavitation::FullFilm);
            let fj = film.force_jacobian(&FilmState::default(), &run).unwrap();
            let c3 = geometry.clearance_m.powi(3);
            let exact = 12.0 * run.viscosity_pa_s * centred_full_film_integral(&geometry) / c3;
            let damping = fj.damping();
            assert!((damping[(0, 0)] / exact - 1.0).abs() < 2e-3, "L/D {slenderness}: Cxx {} vs {exact}", damping[(0, 0)]);
            assert!((damping[(1, 1)] / exact - 1.0).abs() < 2e-3, "L/D {slenderness}: Cyy {} vs {exact}", damping[(1, 1)]);
            assert!(damping[(0, 1)].abs() < 1e-9 * exact);
            // Velocity along x: force exactly -Cxx vx.
            let f = film.force(&FilmState { vx_m_s: 1e-3, ..Default::default() }, &run).unwrap();
            assert!((f.x + damping[(0, 0)] * 1e-3).abs() < 1e-9 * f.norm());
        }
    }

    #[test]
    fn added_mass_of_a_centred_full_plain_film() {
        let rho = 850.0;
        let still = Running { omega_rad_s: 0.0, viscosity_pa_s: 0.02 };
        for slenderness in [0.05, 0.1, 0.25, 1.0] {
            let geometry = plain(slenderness);
            let short = PI * rho * geometry.radius_m() * geometry.length_m.powi(3) / (12.0 * geometry.clearance_m);
            let exact = rho * centred_full_film_integral(&geometry) / geometry.clearance_m;
            // Both cavitation settings: a centred, still journal has no viscous film region to
            // restrict the inertia pressure to, so the full film is used.
            for cavitation in [Cavitation::SwiftStieber, Cavitation::FullFilm] {
                let mut film = FiniteBearing::new(geometry, GridSpec { n_theta: 72, n_z: 16 }).unwrap().with_cavitation(cavitation);
                let m = film.added_mass(&FilmState::default(), &still, rho).unwrap().expect("the finite film estimates added mass");
                assert!((m[(0, 0)] / exact - 1.0).abs() < 2e-3, "L/D {slenderness}: Mxx {} vs exact {exact}", m[(0, 0)]);
                assert!((m[(1, 1)] / exact - 1.0).abs() < 2e-3, "L/D {slenderness}: Myy {} vs exact {exact}", m[(1, 1)]);
                assert!(m[(0, 1)].abs() < 1e-9 * exact && m[(1, 0)].abs() < 1e-9 * exact);
                if slenderness <= 0.1 {
                    // Short-bearing limit pi rho R L^3 / (12 c), approached as 1 - 2 (L/D)^2 / 5.
                    assert!((m[(0, 0)] / short - 1.0).abs() < 0.01, "L/D {slenderness}: Mxx {} vs short {short}", m[(0, 0)]);
                }
            }
        }
    }

    #[test]
    fn added_mass_on_a_running_film_is_positive_and_below_the_full_film() {
        let rho = 850.0;
        let geometry = grooved(0.5);
        let mut film = FiniteBearing::new(geometry, GridSpec::default()).unwrap();
        let state = FilmState::at_rest(3.0e-5, -4.0e-5);
        let m = film.added_mass(&state, &running(), rho).unwrap().unwrap();
        let full = rho * centred_full_film_integral(&geometry) / geometry.clearance_m;
        assert!(m[(0, 0)] > 0.0 && m[(1, 1)] > 0.0, "{m}");
        assert!(m[(0, 0)] < full && m[(1, 1)] < full, "{m} vs full film {full}");
        // The viscous solve is unaffected by the inertia estimate.
        let f1 = film.force(&state, &running()).unwrap();
        let f0 = FiniteBearing::new(geometry, GridSpec::default()).unwrap().force(&state, &running()).unwrap();
        assert!((f1 - f0).norm() < 1e-9 * f0.norm());
    }

    #[test]
    fn cavitated_pressure_is_nonnegative_and_the_field_is_complete() {
        let geometry = grooved(0.5);
        let grid = GridSpec { n_theta: 40, n_z: 6 };
        let mut film = FiniteBearing::new(geometry, grid).unwrap();
        let state = FilmState::at_rest(2.0e-5, -6.0e-5);
        let f = film.force(&state, &running()).unwrap();
        let field = film.pressure_field();
        assert_eq!(field.len(), 2);
        for pad in &field {
            assert_eq!(pad.theta_rad.len(), grid.n_theta + 1);
            assert_eq!(pad.z_m.len(), grid.n_z + 1);
            assert!((pad.z_m[grid.n_z] - 0.5 * geometry.length_m).abs() < 1e-15);
            let max = pad.max_pa();
            assert!(pad.pressure_pa.iter().all(|&p| p >= -1e-9 * max));
            for i in 0..=grid.n_theta {
                assert_eq!(pad.at(i, grid.n_z), Some(0.0), "edge at ambient");
            }
            for j in 0..=grid.n_z {
                assert_eq!(pad.at(0, j), Some(0.0), "groove edge at ambient");
                assert_eq!(pad.at(grid.n_theta, j), Some(0.0), "groove edge at ambient");
            }
            assert_eq!(pad.at(grid.n_theta + 1, 0), None);
        }
        // The lower pad carries the load and has a cavity; the force is the field's integral.
        let lower = &field[1];
        assert!(lower.max_pa() > 0.0 && lower.pressure_pa.iter().filter(|&&p| p == 0.0).count() > grid.n_theta);
        let (dtheta, dz) = (lower.theta_rad[1] - lower.theta_rad[0], lower.z_m[1]);
        let mut integral = Vector2::zeros();
        for pad in &field {
            for (i, &t) in pad.theta_rad.iter().enumerate() {
                for j in 0..pad.z_m.len() {
                    let w = if j == 0 { 0.5 } else { 1.0 };
                    integral -= 2.0 * w * pad.at(i, j).unwrap() * Vector2::new(t.cos(), t.sin()) * geometry.radius_m() * dtheta * dz;
                }
            }
        }
        assert!((integral - f).norm() < 1e-9 * f.norm(), "{integral} vs {f}");
    }

    #[test]
    fn warm_and_cold_starts_agree() {
        let run = running();
        let geometry = grooved(1.0);
        let mut warm = FiniteBearing::new(geometry, GridSpec::default()).unwrap();
        let states = [
            FilmState::at_rest(1e-5, -2e-5),
            FilmState::at_rest(4e-5, -7e-5),
            FilmState { x_m: -3e-5, y_m: -5e-5, vx_m_s: 1e-3, vy_m_s: 2e-3 },
            FilmState::at_rest(1e-5, -2e-5),
        ];
        for state in states {
            let fw = warm.force_jacobian(&state, &run).unwrap();
            let fc = FiniteBearing::new(geometry, GridSpec::default()).unwrap().force_jacobian(&state, &run).unwrap();
            assert!((fw.force_n - fc.force_n).norm() <= 1e-9 * fc.force_n.norm(), "{state:?}");
            assert!((fw.jacobian - fc.jacobian).amax() <= 1e-8 * fc.jacobian.amax(), "{state:?}");
        }
    }

    #[test]
    fn equilibrium_converges_from_light_to_heavy_load() {
        // Sommerfeld numbers from 10 down to 0.01 (eccentricity about 0.03 to 0.9), both kinds.
        let run = running();
        for geometry in [grooved(0.5), grooved(1.0), plain(0.5), plain(1.0)] {
            let r_over_c = geometry.radius_m() / geometry.clearance_m;
            let mut eps_prev = 0.0;
            for s in [10.0, 1.0, 0.1, 0.03, 0.01] {
                let w = run.viscosity_pa_s * run.omega_rad_s / (2.0 * PI) * geometry.length_m * geometry.diameter_m * r_over_c * r_over_c / s;
                let mut film = FiniteBearing::new(geometry, GridSpec::default()).unwrap();
                let op = solve(&mut film, &run, Vector2::new(0.0, -w), &EquilibriumOptions::default())
                    .unwrap_or_else(|e| panic!("{:?} L/D {} S {s}: {e}", geometry.kind, geometry.slenderness()));
                assert!(op.eccentricity > eps_prev && op.eccentricity < 0.98, "{:?} S {s}: eps {}", geometry.kind, op.eccentricity);
                eps_prev = op.eccentricity;
                let k = op.coefficients.stiffness_n_m;
                let c = op.coefficients.damping_n_s_m;
                assert!(k.iter().chain(c.iter()).all(|v| v.is_finite()));
                assert!(c[(0, 0)] > 0.0 && c[(1, 1)] > 0.0 && c.determinant() > 0.0, "{:?} S {s}: C {c}", geometry.kind);
            }
        }
    }

    /// One full coefficient set at the Zhou et al. (2004) operating point from a cold start:
    /// prints the wall time (no assertion on time: machines differ).
    #[test]
    fn coefficient_set_timing_at_the_zhou_point() {
        let grids = [GridSpec::default(), GridSpec { n_theta: 36, n_z: 8 }, GridSpec { n_theta: 72, n_z: 12 }];
        for grid in grids {
            let running = Running::from_rpm(1500.0, 0.03);
            let mut times = Vec::new();
            let mut last = None;
            for _ in 0..30 {
                let t0 = Instant::now();
                let mut film = FiniteBearing::new(BearingGeometry::zhou2004(), grid).unwrap();
                let op = solve(&mut film, &running, Vector2::new(0.0, -5000.0), &EquilibriumOptions::default()).unwrap();
                times.push(t0.elapsed().as_secs_f64() * 1e3);
                last = Some(op);
            }
            times.sort_by(f64::total_cmp);
            let op = last.unwrap();
            println!(
                "Zhou point, grid {} x {}: one coefficient set from a cold start: min {:.3} ms, median {:.3} ms (eps {:.4}, attitude {:.2} deg)",
                grid.n_theta,
                grid.n_z,
                times[0],
                times[times.len() / 2],
                op.eccentricity,
                op.attitude_deg
            );
        }
    }
}
