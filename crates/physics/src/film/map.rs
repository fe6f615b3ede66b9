//! A tabulated film: any homogeneous [`Film`] interpolated from a table of its forces, so that
//! the rig simulator can call the finite-length film thousands of times per simulated second.
//!
//! ## Why a table of three variables is enough
//!
//! The isoviscous Reynolds equation for a film between a journal of radius `R`, turning at
//! `omega`, and a fixed bearing, with `h = c (1 - ex cos(theta) - ey sin(theta))`,
//! `ex = x / c`, `ey = y / c`, reads
//!
//! ```text
//! (1/R^2) d/dtheta(h^3 dp/dtheta) + d/dz(h^3 dp/dz) = 12 mu [ (omega/2) dh/dtheta + dh/dt ].
//! ```
//!
//! With `dh/dtheta = c (ex sin - ey cos)` and `dh/dt = -c (ex' cos + ey' sin)` (primes: time
//! derivatives, `sin`, `cos` of `theta`) the bracket is
//!
//! ```text
//! (c/2) [ (omega ex - 2 ey') sin(theta) - (omega ey + 2 ex') cos(theta) ]
//!   = (c/2) (u sin(theta) - v cos(theta)) = (c/2) |w| sin(theta - alpha),
//! w = (u, v) = (omega ex - 2 ey', omega ey + 2 ex'),   alpha = atan2(v, u).
//! ```
//!
//! So the right-hand side depends on speed and squeeze only through `w`, linearly, and the
//! operator on the left depends on the position `(ex, ey)` only. Swift-Stieber cavitation
//! (`p >= 0`, with the Reynolds equation holding where `p > 0`) and the pi-film cut of the short
//! bearing are both of the form "the pressure solves a linear complementarity problem
//! `p >= 0, A p - b >= 0, p . (A p - b) = 0`", with `A` depending on position and `b` linear in
//! `mu w`. Scaling `b` by any `lambda > 0` scales the solution by `lambda`; grooves at ambient
//! pressure keep `p = 0` there, which scales too. Hence the pressure, and the force
//! `F = -R int int p (cos, sin) dtheta dz`, is
//!
//! ```text
//! F(x, y, x', y'; omega, mu) = mu |w| f(ex, ey, alpha)
//! ```
//!
//! for a function `f` of three variables that knows nothing of speed or viscosity. The vector
//! `w` is twice the journal-centre velocity seen from a frame turning at `omega / 2`, rotated
//! by 90 degrees: the classical "equivalent pure squeeze" of Booker's mobility method
//! (J. F. Booker, "Dynamically loaded journal bearings: mobility method of solution", J. Basic
//! Eng. 87, 1965) and the impedance method of Childs, Moes & van Leeuwen ("Journal bearing
//! impedance descriptions for rotordynamic applications", J. Lubr. Technol. 99, 1977), which
//! express the force through exactly this function of the eccentricity and the direction of
//! the squeeze velocity (for a plain bearing, where rotational symmetry removes one more
//! variable). Precomputed bearing-force tables of this kind are a common way to make long
//! nonlinear rotordynamic transients affordable.
//!
//! The argument fails, and the map must not be used, when the film has a nonzero supply
//! pressure, fluid inertia, thermal or piezoviscous effects, or a mass-conserving (JFO)
//! cavitation model with a nonzero cavity pressure: all of these break the degree-one
//! homogeneity. [`FilmMap::build`] checks homogeneity once on the inner film and refuses films
//! that violate it by more than 1e-3 relative.
//!
//! ## Filling the table
//!
//! Any target `(ex, ey, alpha)` is realised on the inner film by choosing velocities: with a
//! reference speed `omega_r` ([`REFERENCE_OMEGA_RAD_S`]) put `w = omega_r (cos alpha, sin alpha)`,
//! i.e. `ey' = omega_r (ex - cos alpha) / 2`, `ex' = omega_r (sin alpha - ey) / 2`, and a
//! reference viscosity `mu_r` ([`REFERENCE_VISCOSITY_PA_S`]). The table stores
//! `f = F / (mu_r omega_r)`, multiplied by the wall weight `(1 - ex^2 - ey^2)^(5/2)`, which
//! takes out the growth of the force towards the bearing wall (`(1 - eps^2)^(-5/2)` is the
//! pure-squeeze growth of the short bearing) so that the interpolated quantity stays tame over a
//! box that reaches high eccentricity. Nodes: `n_position` x `n_position` positions evenly over
//! the box `centre +- half_width` (eccentricity-ratio units) times `n_angle` angles evenly over
//! `[0, 2 pi)`; one inner solve per node.
//!
//! ## Interpolation
//!
//! Tensor-product cubic Hermite (tricubic) in `(ex, ey, alpha)`, periodic in `alpha`. Node
//! slopes and the mixed derivatives a tricubic Hermite patch needs (`f_x, f_y, f_a, f_xy, f_xa,
//! f_ya, f_xya`) come from fourth-order finite differences of the node values applied axis by
//! axis (five-point centred stencil, periodic in alpha; fourth-order one-sided stencils at the
//! box faces). The interpolant is C1, passes through every node, and for a smooth `f` its error
//! is `O(h^4)` (about `h^4 |f''''| / 384` per axis, the slope errors being `O(h^5)`), its first
//! derivatives `O(h^3)`. Each call reads the 8 corners of one cell, 16 numbers each (8 Hermite
//! quantities x 2 force components, contiguous), from one flat `Vec<f64>`: no allocation.
//!
//! `f` is not smooth everywhere, and two kinds of non-smoothness set the resolution:
//!
//! * **Pad-end kinks.** Where the cavitation boundary (or, for the pi-film, the edge of the
//!   pressurised half) meets the end of a pad at a groove, the force has a jump in its second
//!   derivative, chiefly along `alpha`. Near such a kink the interpolation error degrades to
//!   `O(h^2)` in force and `O(h)` in the Jacobian over a couple of cells.
//! * **Grid roughness of a discrete film.** A Swift-Stieber film solved on a grid is a
//!   discrete complementarity problem: its pressure is piecewise linear in the right-hand side,
//!   one piece per set of cavitated nodes. The force is continuous, but the Jacobian jumps each
//!   time the free boundary crosses a node. Each axial row of the grid ruptures at its own
//!   place, so along `alpha` the Jacobian is a fine staircase (steps a fraction of one
//!   circumferential cell apart) of per-mille to percent amplitude. No practical table resolves
//!   it: the map's Jacobian follows its mean, and the pointwise difference from the inner
//!   film's Jacobian cannot fall below the staircase. At any one point (an equilibrium, say)
//!   that difference is a lottery between zero and one or two step heights, which changes with
//!   the angular spacing but does not shrink with it: on the Zhou point the map's coefficients
//!   differed from those of a 72 x 8 film by 0.25 % with 128 angles, 0.7 % with 192 and
//!   0.2-0.4 % with 256 to 384; from a 36 x 8 film by 0.5 % with 128 angles and 1.6 % with 256.
//!   More angles buy nothing here, so the default takes the fewest that resolve the pad-end
//!   kinks. The force, being continuous, is matched far below its budget on every grid.
//!
//! Measured errors of the default map (relative; "typical" states have velocities up to
//! `0.1 omega c` per axis, "violent" ones up to `0.5 omega c`, so that `w` points anywhere;
//! max over seeded random states in a box around the Zhou operating point, 1500 rpm, 5 kN,
//! unless stated; tests `film::map::tests` and `tests/film_map.rs` print them):
//!
//! | inner film | force max (typical / violent) | Jacobian max (typical / violent) | Jacobian rms |
//! |---|---|---|---|
//! | Ocvirk pi-film, closed form (no grooves: smooth) | 6e-6 / 6e-6 | 8e-5 / 1.1e-4 | 1.2e-5 |
//! | grooved pi-film, exact quadrature (sharp pad-end kinks) | 2.2e-5 / 3.6e-5 | 2.4e-3 / 2.8e-3 | 9e-5 |
//! | the same, box reaching eccentricity 0.9 | 2.9e-4 / 5.9e-4 | 2.7e-3 / 5.6e-3 | 2.7e-4 |
//! | finite Reynolds, grid 144 x 8 per pad | 9.6e-5 / 1.7e-4 | 8.2e-3 / 8.3e-3 | 1.9e-3 |
//! | finite Reynolds, default grid 72 x 8 per pad | 2.0e-4 / 3.3e-4 | 1.3e-2 / 1.6e-2 | 3.3e-3 |
//! | finite Reynolds, grid 36 x 8 per pad (typical states only) | 7.8e-4 / - | 2.9e-2 / - | - |
//!
//! The finite films' Jacobian maxima are set by their grid roughness, not by interpolation: the
//! film's own Jacobian differs from its own secant over `+-1e-3 c` by up to 7e-3 (72 x 8) and
//! 5e-3 (144 x 8) at the same states. At the Zhou equilibrium the eccentricity agrees within
//! 2e-6 and the map's eight coefficients agree with the inner film's within 8e-6 (closed-form
//! pi-film), 2.5e-3 (72 x 8, whose own roughness there is 2.1e-3) and 3.3e-3 (144 x 8, 1.7e-3).
//!
//! ## Jacobian
//!
//! Analytic, from the interpolant by the chain rule through `w`. Writing `G(ex, ey, u, v) =
//! |w| f(ex, ey, alpha)` so that `F = mu G`:
//! `dG/du = cos(alpha) f - sin(alpha) f_alpha`, `dG/dv = sin(alpha) f + cos(alpha) f_alpha`,
//! `dF/dx = (mu/c) (|w| f_ex + omega dG/du)`, `dF/dy = (mu/c) (|w| f_ey + omega dG/dv)`,
//! `dF/dx' = (2 mu / c) dG/dv`, `dF/dy' = -(2 mu / c) dG/du`. At `w = 0` exactly, where `G` is
//! not differentiable, the central-difference limit `dG/du = (f(0) - f(pi)) / 2`,
//! `dG/dv = (f(pi/2) - f(3 pi/2)) / 2` is returned.
//!
//! ## Outside the table
//!
//! States whose position lies outside the box, and runs with a viscosity that is not positive,
//! are handed to the inner film unchanged and counted ([`FilmMap::fallbacks`]), so the result is
//! always the inner film's where the table cannot answer. NaN or infinite inputs are errors.

use nalgebra::{Matrix2, Matrix2x4, Vector2};
use serde::{Deserialize, Serialize};

use crate::error::PhysicsError;
use crate::film::{Film, FilmState, ForceJacobian, Running};
use crate::geometry::BearingGeometry;

/// Shaft speed at which the table is filled, rad/s. By homogeneity any positive value gives the
/// same table; a typical one is used so that solver tolerances of the inner film see typical
/// pressures.
pub const REFERENCE_OMEGA_RAD_S: f64 = 100.0;

/// Viscosity at which the table is filled, Pa s (see [`REFERENCE_OMEGA_RAD_S`]).
pub const REFERENCE_VISCOSITY_PA_S: f64 = 0.03;

/// The box must stay inside this eccentricity ratio at its farthest corner.
pub const MAX_BOX_ECCENTRICITY: f64 = 0.95;

/// Relative homogeneity violation of the inner film above which [`FilmMap::build`] refuses it.
pub const HOMOGENEITY_TOLERANCE: f64 = 1e-3;

/// Exponent of the wall weight `(1 - eps^2)^WALL_POWER` applied to the tabulated values.
const WALL_POWER: f64 = 2.5;

/// Values per node: 8 Hermite quantities x 2 force components.
const PER_NODE: usize = 16;

/// Extent and resolution of a [`FilmMap`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapSpec {
    /// Half-width of the square box of journal positions around the centre given to
    /// [`FilmMap::build`], in eccentricity-ratio units (a position `x` maps to `x / c`).
    pub half_width: f64,
    /// Nodes per position axis, at least 5.
    pub n_position: usize,
    /// Nodes over the angle `alpha` of `w` in `[0, 2 pi)`, periodic, at least 8.
    pub n_angle: usize,
}

impl Default for MapSpec {
    /// Half-width 0.15 (17 um on the Zhou bearing: more than the excitation orbits of an
    /// identification test), 5 x 5 positions (spacing 0.075: position is the smooth direction,
    /// 7 nodes gained nothing measurable), 128 angles (2.8 degrees: enough for the pad-end
    /// kinks; more do not help against a discrete film's roughness, see the module docs):
    /// 3200 inner solves, about 0.5 s with the default finite film (1 s on a 144 x 8 grid).
    fn default() -> Self {
        Self { half_width: 0.15, n_position: 5, n_angle: 128 }
    }
}

impl MapSpec {
    /// Checks the fields; the error names the field under `film_map.spec`.
    pub fn validate(&self) -> Result<(), PhysicsError> {
        if !self.half_width.is_finite() || self.half_width <= 0.0 {
            return Err(PhysicsError::invalid("film_map.spec.half_width", format!("must be a positive finite eccentricity ratio, got {}", self.half_width)));
        }
        if self.n_position < 5 {
            return Err(PhysicsError::invalid(
                "film_map.spec.n_position",
                format!("needs at least 5 nodes for the fourth-order slopes, got {}", self.n_position),
            ));
        }
        if self.n_angle < 8 {
            return Err(PhysicsError::invalid("film_map.spec.n_angle", format!("needs at least 8 nodes over the full turn, got {}", self.n_angle)));
        }
        // Keep the table to a size that is plainly meant (and whose index arithmetic is safe).
        let nodes = self.n_position.checked_mul(self.n_position).and_then(|n| n.checked_mul(self.n_angle));
        if nodes.is_none_or(|n| n > 50_000_000) {
            return Err(PhysicsError::invalid(
                "film_map.spec",
                format!("{} x {} x {} nodes is too large a table", self.n_position, self.n_position, self.n_angle),
            ));
        }
        Ok(())
    }
}

/// A film tabulated from an inner film over a box of journal positions and all directions of
/// the squeeze-rotation vector `w` (see the module docs).
pub struct FilmMap {
    inner: Box<dyn Film + Send>,
    geometry: BearingGeometry,
    spec: MapSpec,
    centre_ex: f64,
    centre_ey: f64,
    ex_min: f64,
    ey_min: f64,
    d_pos: f64,
    d_alpha: f64,
    /// Node `(i, j, k)` (ex, ey, alpha) starts at `((i * n_position + j) * n_angle + k) * 16`;
    /// within a node, quantity `q` (bit 0: d/dex, bit 1: d/dey, bit 2: d/dalpha, derivatives
    /// in grid-index units) of component `comp` is at `2 q + comp`.
    table: Vec<f64>,
    fallbacks: u64,
    inner_solves: usize,
}

impl std::fmt::Debug for FilmMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FilmMap")
            .field("spec", &self.spec)
            .field("centre_ex", &self.centre_ex)
            .field("centre_ey", &self.centre_ey)
            .field("fallbacks", &self.fallbacks)
            .field("inner_solves", &self.inner_solves)
            .finish_non_exhaustive()
    }
}

impl FilmMap {
    /// Tabulates `inner` on a box of `(ex, ey)` centred at `centre` (journal position relative
    /// to the bearing, m) times all `alpha`.
    ///
    /// Errors: [`PhysicsError::InvalidConfig`] for a bad spec, a box that reaches beyond
    /// [`MAX_BOX_ECCENTRICITY`], or an inner film that is not homogeneous; whatever the inner
    /// film returns for a node it cannot solve.
    pub fn build(mut inner: Box<dyn Film + Send>, centre_x_m: f64, centre_y_m: f64, spec: MapSpec) -> Result<Self, PhysicsError> {
        spec.validate()?;
        PhysicsError::check_finite("film map centre_x_m", centre_x_m)?;
        PhysicsError::check_finite("film map centre_y_m", centre_y_m)?;
        let geometry = *inner.geometry();
        let c = geometry.clearance_m;
        if !c.is_finite() || c <= 0.0 {
            return Err(PhysicsError::invalid("film_map.inner", format!("clearance must be positive, got {c} m")));
        }
        let np = spec.n_position;
        let na = spec.n_angle;
        let hw = spec.half_width;
        let centre_ex = centre_x_m / c;
        let centre_ey = centre_y_m / c;
        let far = (centre_ex.abs() + hw).hypot(centre_ey.abs() + hw);
        if far.is_nan() || far > MAX_BOX_ECCENTRICITY {
            return Err(PhysicsError::invalid(
                "film_map.spec.half_width",
                format!(
                    "the box around (ex, ey) = ({centre_ex:.4}, {centre_ey:.4}) with half-width {hw} reaches eccentricity \
                     {far:.4} at a corner; it must stay within {MAX_BOX_ECCENTRICITY} (reduce the half-width)"
                ),
            ));
        }
        check_homogeneous(inner.as_mut(), centre_ex, centre_ey)?;

        let ex_min = centre_ex - hw;
        let ey_min = centre_ey - hw;
        let d_pos = 2.0 * hw / (np - 1) as f64;
        let d_alpha = std::f64::consts::TAU / na as f64;
        let n_nodes = np * np * na;
        let omega = REFERENCE_OMEGA_RAD_S;
        let running = Running { omega_rad_s: omega, viscosity_pa_s: REFERENCE_VISCOSITY_PA_S };
        let scale = 1.0 / (REFERENCE_OMEGA_RAD_S * REFERENCE_VISCOSITY_PA_S);
        let mut values = [vec![0.0; n_nodes], vec![0.0; n_nodes]];
        for i in 0..np {
            let ex = ex_min + i as f64 * d_pos;
            for j in 0..np {
                let ey = ey_min + j as f64 * d_pos;
                let weight = scale * wall_weight(ex, ey);
                for k in 0..na {
                    let (sa, ca) = (k as f64 * d_alpha).sin_cos();
                    let state = realise(c, ex, ey, omega, omega * ca, omega * sa);
                    let f = inner.force(&state, &running)?;
                    if !(f.x.is_finite() && f.y.is_finite()) {
                        return Err(PhysicsError::NonFinite { quantity: "inner film force while tabulating".into(), value: f.norm() });
                    }
                    let n = (i * np + j) * na + k;
                    values[0][n] = f.x * weight;
                    values[1][n] = f.y * weight;
                }
            }
        }

        // Hermite data: apply the slope operator along the axes named by the bits of q.
        let mut table = vec![0.0; n_nodes * PER_NODE];
        let mut a = vec![0.0; n_nodes];
        let mut b = vec![0.0; n_nodes];
        let mut line = Vec::with_capacity(np.max(na));
        let mut out = Vec::with_capacity(np.max(na));
        for (comp, v) in values.iter().enumerate() {
            for q in 0..8usize {
                a.copy_from_slice(v);
                for axis in 0..3 {
                    if q & (1 << axis) != 0 {
                        slopes_along(&a, &mut b, np, na, axis, &mut line, &mut out);
                        std::mem::swap(&mut a, &mut b);
                    }
                }
                for (n, &x) in a.iter().enumerate() {
                    table[n * PER_NODE + 2 * q + comp] = x;
                }
            }
        }
        Ok(Self { inner, geometry, spec, centre_ex, centre_ey, ex_min, ey_min, d_pos, d_alpha, table, fallbacks: 0, inner_solves: n_nodes + 2 })
    }

    /// How many calls fell outside the table (position outside the box, or a viscosity that is
    /// not positive) and were solved by the inner film directly.
    pub fn fallbacks(&self) -> u64 {
        self.fallbacks
    }

    /// The spec the table was built with.
    pub fn spec(&self) -> MapSpec {
        self.spec
    }

    /// Inner-film solves spent building the table (nodes plus the homogeneity check).
    pub fn inner_solves(&self) -> usize {
        self.inner_solves
    }

    /// Centre of the box, m.
    pub fn centre_m(&self) -> (f64, f64) {
        let c = self.geometry.clearance_m;
        (self.centre_ex * c, self.centre_ey * c)
    }

    /// Whether a journal position (m) lies in the box, where the table answers.
    pub fn covers(&self, x_m: f64, y_m: f64) -> bool {
        let c = self.geometry.clearance_m;
        self.grid_position(x_m / c, y_m / c).is_some()
    }

    /// The tabulated film, for direct use (its calls are not counted).
    pub fn inner_mut(&mut self) -> &mut (dyn Film + Send) {
        self.inner.as_mut()
    }

    /// Position in grid-index units, `None` outside the box (or NaN).
    #[inline]
    fn grid_position(&self, ex: f64, ey: f64) -> Option<(f64, f64)> {
        let last = (self.spec.n_position - 1) as f64;
        let sx = (ex - self.ex_min) / self.d_pos;
        let sy = (ey - self.ey_min) / self.d_pos;
        ((0.0..=last).contains(&sx) && (0.0..=last).contains(&sy)).then_some((sx, sy))
    }

    /// Cell indices and local coordinates in [0, 1] of `(ex, ey, alpha)`, `None` outside the box.
    #[inline]
    fn locate(&self, ex: f64, ey: f64, alpha: f64) -> Option<([usize; 3], [f64; 3])> {
        let np = self.spec.n_position;
        let na = self.spec.n_angle;
        let (sx, sy) = self.grid_position(ex, ey)?;
        let a = if alpha < 0.0 { alpha + std::f64::consts::TAU } else { alpha };
        let sa = a / self.d_alpha;
        if !sa.is_finite() {
            return None;
        }
        // sx, sy in [0, np - 1] and sa >= 0 finite, so the casts are exact floors.
        let i = (sx as usize).min(np - 2);
        let j = (sy as usize).min(np - 2);
        let k = (sa as usize).min(na - 1);
        Some(([i, j, k], [sx - i as f64, sy - j as f64, (sa - k as f64).min(1.0)]))
    }

    /// The table's interpolant (weighted, table units) in one cell and, when `GRAD`, its
    /// derivatives in cell units along (ex, ey, alpha).
    #[inline]
    fn interpolate<const GRAD: bool>(&self, cell: [usize; 3], t: [f64; 3]) -> ([f64; 2], [[f64; 2]; 3]) {
        let np = self.spec.n_position;
        let na = self.spec.n_angle;
        let (wx, dwx) = hermite(t[0]);
        let (wy, dwy) = hermite(t[1]);
        let (wa, dwa) = hermite(t[2]);
        let mut f = [0.0; 2];
        let mut g = [[0.0; 2]; 3];
        for corner in 0..8usize {
            let a = corner & 1;
            let b = (corner >> 1) & 1;
            let cz = (corner >> 2) & 1;
            let k = if cell[2] + cz == na { 0 } else { cell[2] + cz };
            let node = ((cell[0] + a) * np + cell[1] + b) * na + k;
            let data = &self.table[node * PER_NODE..(node + 1) * PER_NODE];
            for q in 0..8usize {
                let ix = 2 * a + (q & 1);
                let iy = 2 * b + ((q >> 1) & 1);
                let ia = 2 * cz + ((q >> 2) & 1);
                let (v0, v1) = (data[2 * q], data[2 * q + 1]);
                let wxy = wx[ix] * wy[iy];
                let w = wxy * wa[ia];
                f[0] += w * v0;
                f[1] += w * v1;
                if GRAD {
                    let gx = dwx[ix] * wy[iy] * wa[ia];
                    let gy = wx[ix] * dwy[iy] * wa[ia];
                    let ga = wxy * dwa[ia];
                    g[0][0] += gx * v0;
                    g[0][1] += gx * v1;
                    g[1][0] += gy * v0;
                    g[1][1] += gy * v1;
                    g[2][0] += ga * v0;
                    g[2][1] += ga * v1;
                }
            }
        }
        (f, g)
    }

    /// `f(ex, ey, alpha)` (force per unit `mu |w|`, m^2) and, when `GRAD`, its derivatives
    /// with respect to ex, ey and alpha; `None` outside the box.
    #[inline]
    fn evaluate<const GRAD: bool>(&self, ex: f64, ey: f64, alpha: f64) -> Option<([f64; 2], [[f64; 2]; 3])> {
        let (cell, t) = self.locate(ex, ey, alpha)?;
        let (ft, gt) = self.interpolate::<GRAD>(cell, t);
        let q = 1.0 - ex * ex - ey * ey;
        let m = 1.0 / (q * q * q.sqrt()); // q^-WALL_POWER
        let f = [ft[0] * m, ft[1] * m];
        let mut g = [[0.0; 2]; 3];
        if GRAD {
            // d(q^-p)/dex = 2 p ex q^(-p-1).
            let dm = 2.0 * WALL_POWER * m / q;
            for comp in 0..2 {
                g[0][comp] = gt[0][comp] / self.d_pos * m + ft[comp] * dm * ex;
                g[1][comp] = gt[1][comp] / self.d_pos * m + ft[comp] * dm * ey;
                g[2][comp] = gt[2][comp] / self.d_alpha * m;
            }
        }
        // Inside the box q >= 1 - MAX_BOX_ECCENTRICITY^2 > 0 and the table is finite, so this
        // holds; should it ever not, the inner film answers instead of a NaN leaking out.
        (f[0].is_finite() && f[1].is_finite()).then_some((f, g))
    }

    fn delegate_force(&mut self, state: &FilmState, running: &Running) -> Result<Vector2<f64>, PhysicsError> {
        self.fallbacks += 1;
        self.inner.force(state, running)
    }

    fn delegate_jacobian(&mut self, state: &FilmState, running: &Running) -> Result<ForceJacobian, PhysicsError> {
        self.fallbacks += 1;
        self.inner.force_jacobian(state, running)
    }
}

/// Dimensionless kinematics of a call: `(ex, ey, u, v)`, after checking every input is finite.
fn kinematics(state: &FilmState, running: &Running, c: f64) -> Result<(f64, f64, f64, f64), PhysicsError> {
    for (name, v) in [
        ("film state x_m", state.x_m),
        ("film state y_m", state.y_m),
        ("film state vx_m_s", state.vx_m_s),
        ("film state vy_m_s", state.vy_m_s),
        ("running.omega_rad_s", running.omega_rad_s),
        ("running.viscosity_pa_s", running.viscosity_pa_s),
    ] {
        PhysicsError::check_finite(name, v)?;
    }
    let ex = state.x_m / c;
    let ey = state.y_m / c;
    let omega = running.omega_rad_s;
    Ok((ex, ey, omega * ex - 2.0 * state.vy_m_s / c, omega * ey + 2.0 * state.vx_m_s / c))
}

/// `(1 - ex^2 - ey^2)^WALL_POWER`.
fn wall_weight(ex: f64, ey: f64) -> f64 {
    (1.0 - ex * ex - ey * ey).powf(WALL_POWER)
}

/// The film state that realises position `(ex, ey)` and `w = (u, v)` at shaft speed `omega`:
/// `u = omega ex - 2 ey'`, `v = omega ey + 2 ex'`.
fn realise(c: f64, ex: f64, ey: f64, omega: f64, u: f64, v: f64) -> FilmState {
    let ex_dot = 0.5 * (v - omega * ey);
    let ey_dot = 0.5 * (omega * ex - u);
    FilmState { x_m: c * ex, y_m: c * ey, vx_m_s: c * ex_dot, vy_m_s: c * ey_dot }
}

/// Checks `F = mu |w| f(ex, ey, alpha)` on the inner film at one generic state: the same
/// `(ex, ey, alpha)` realised with a different speed, viscosity and `|w|` must give the force
/// scaled by `mu |w|`.
fn check_homogeneous(inner: &mut dyn Film, ex: f64, ey: f64) -> Result<(), PhysicsError> {
    let c = inner.geometry().clearance_m;
    let (sa, ca) = 1.1_f64.sin_cos();
    let (omega1, mu1, rho1) = (REFERENCE_OMEGA_RAD_S, REFERENCE_VISCOSITY_PA_S, REFERENCE_OMEGA_RAD_S);
    let (omega2, mu2, rho2) = (2.7 * omega1, 0.2 * mu1, 1.9 * rho1);
    let f1 = inner.force(&realise(c, ex, ey, omega1, rho1 * ca, rho1 * sa), &Running { omega_rad_s: omega1, viscosity_pa_s: mu1 })?;
    let f2 = inner.force(&realise(c, ex, ey, omega2, rho2 * ca, rho2 * sa), &Running { omega_rad_s: omega2, viscosity_pa_s: mu2 })?;
    let expected = f1 * (mu2 * rho2 / (mu1 * rho1));
    let violation = (f2 - expected).norm() / expected.norm();
    if violation.is_nan() || violation > HOMOGENEITY_TOLERANCE {
        return Err(PhysicsError::invalid(
            "film_map.inner",
            format!(
                "the film is not homogeneous of degree one in w = (omega ex - 2 ey', omega ey + 2 ex') \
                 (relative violation {violation:.3e} > {HOMOGENEITY_TOLERANCE:e}); it cannot be tabulated \
                 over (ex, ey, alpha) (supply pressure, inertia or thermal effects?)"
            ),
        ));
    }
    Ok(())
}

/// Cubic Hermite weights on [0, 1] for (f0, f0', f1, f1') and their derivatives in t.
#[inline]
fn hermite(t: f64) -> ([f64; 4], [f64; 4]) {
    let t2 = t * t;
    let t3 = t2 * t;
    (
        [2.0 * t3 - 3.0 * t2 + 1.0, t3 - 2.0 * t2 + t, -2.0 * t3 + 3.0 * t2, t3 - t2],
        [6.0 * t2 - 6.0 * t, 3.0 * t2 - 4.0 * t + 1.0, -6.0 * t2 + 6.0 * t, 3.0 * t2 - 2.0 * t],
    )
}

/// Slopes (in index units) along `axis` (0: ex, 1: ey, both of length `np`; 2: alpha, periodic,
/// of length `na`) of an `np x np x na` array stored ex-slowest, alpha-fastest.
fn slopes_along(src: &[f64], dst: &mut [f64], np: usize, na: usize, axis: usize, line: &mut Vec<f64>, out: &mut Vec<f64>) {
    let (len, stride, periodic) = match axis {
        0 => (np, np * na, false),
        1 => (np, na, false),
        _ => (na, 1, true),
    };
    line.resize(len, 0.0);
    out.resize(len, 0.0);
    for start in 0..src.len() {
        // `start` begins a line iff its index along `axis` is zero.
        if (start / stride) % len != 0 {
            continue;
        }
        for (m, l) in line.iter_mut().enumerate() {
            *l = src[start + m * stride];
        }
        slopes_line(line, out, periodic);
        for (m, &o) in out.iter().enumerate() {
            dst[start + m * stride] = o;
        }
    }
}

/// Fourth-order finite-difference slopes of evenly spaced samples (unit spacing): centred
/// five-point stencil, wrapped when `periodic`, else one-sided five-point stencils at the two
/// first and two last points. Needs `f.len() >= 5`.
fn slopes_line(f: &[f64], d: &mut [f64], periodic: bool) {
    let n = f.len();
    let centred = |a: f64, b: f64, c: f64, e: f64| (a - 8.0 * b + 8.0 * c - e) / 12.0;
    if periodic {
        for m in 0..n {
            let at = |o: isize| f[(m as isize + o).rem_euclid(n as isize) as usize];
            d[m] = centred(at(-2), at(-1), at(1), at(2));
        }
        return;
    }
    d[0] = (-25.0 * f[0] + 48.0 * f[1] - 36.0 * f[2] + 16.0 * f[3] - 3.0 * f[4]) / 12.0;
    d[1] = (-3.0 * f[0] - 10.0 * f[1] + 18.0 * f[2] - 6.0 * f[3] + f[4]) / 12.0;
    for m in 2..n - 2 {
        d[m] = centred(f[m - 2], f[m - 1], f[m + 1], f[m + 2]);
    }
    d[n - 2] = (3.0 * f[n - 1] + 10.0 * f[n - 2] - 18.0 * f[n - 3] + 6.0 * f[n - 4] - f[n - 5]) / 12.0;
    d[n - 1] = (25.0 * f[n - 1] - 48.0 * f[n - 2] + 36.0 * f[n - 3] - 16.0 * f[n - 4] + 3.0 * f[n - 5]) / 12.0;
}

impl Film for FilmMap {
    fn geometry(&self) -> &BearingGeometry {
        &self.geometry
    }

    fn force(&mut self, state: &FilmState, running: &Running) -> Result<Vector2<f64>, PhysicsError> {
        let (ex, ey, u, v) = kinematics(state, running, self.geometry.clearance_m)?;
        let rho = u.hypot(v);
        if running.viscosity_pa_s <= 0.0 || !rho.is_finite() {
            return self.delegate_force(state, running);
        }
        match self.evaluate::<false>(ex, ey, v.atan2(u)) {
            Some((f, _)) => {
                let s = running.viscosity_pa_s * rho;
                Ok(Vector2::new(s * f[0], s * f[1]))
            }
            None => self.delegate_force(state, running),
        }
    }

    fn force_jacobian(&mut self, state: &FilmState, running: &Running) -> Result<ForceJacobian, PhysicsError> {
        let c = self.geometry.clearance_m;
        let (ex, ey, u, v) = kinematics(state, running, c)?;
        let rho = u.hypot(v);
        let mu = running.viscosity_pa_s;
        let omega = running.omega_rad_s;
        if mu <= 0.0 || !rho.is_finite() {
            return self.delegate_jacobian(state, running);
        }
        let alpha = v.atan2(u);
        let Some((f, g)) = self.evaluate::<true>(ex, ey, alpha) else {
            return self.delegate_jacobian(state, running);
        };
        // dG/du, dG/dv per component.
        let mut gu = [0.0; 2];
        let mut gv = [0.0; 2];
        if rho > 0.0 {
            let (sa, ca) = alpha.sin_cos();
            for comp in 0..2 {
                gu[comp] = ca * f[comp] - sa * g[2][comp];
                gv[comp] = sa * f[comp] + ca * g[2][comp];
            }
        } else {
            // w = 0: G is not differentiable; use the central-difference limit.
            use std::f64::consts::{FRAC_PI_2, PI};
            let at = |a: f64| self.evaluate::<false>(ex, ey, a).map(|(f, _)| f);
            let (Some(f0), Some(f1), Some(f2), Some(f3)) = (at(0.0), at(FRAC_PI_2), at(PI), at(-FRAC_PI_2)) else {
                return self.delegate_jacobian(state, running);
            };
            for comp in 0..2 {
                gu[comp] = 0.5 * (f0[comp] - f2[comp]);
                gv[comp] = 0.5 * (f1[comp] - f3[comp]);
            }
        }
        let mut jacobian = Matrix2x4::zeros();
        for comp in 0..2 {
            jacobian[(comp, 0)] = mu / c * (rho * g[0][comp] + omega * gu[comp]);
            jacobian[(comp, 1)] = mu / c * (rho * g[1][comp] + omega * gv[comp]);
            jacobian[(comp, 2)] = 2.0 * mu / c * gv[comp];
            jacobian[(comp, 3)] = -2.0 * mu / c * gu[comp];
        }
        let s = mu * rho;
        Ok(ForceJacobian { force_n: Vector2::new(s * f[0], s * f[1]), jacobian })
    }

    fn added_mass(&mut self, state: &FilmState, running: &Running, density_kg_m3: f64) -> Result<Option<Matrix2<f64>>, PhysicsError> {
        self.inner.added_mass(state, running, density_kg_m3)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pad;
    use rand::{RngExt, SeedableRng};

    /// Ocvirk pi-film on the bearing's pads, integrated by Gauss-Legendre quadrature over the
    /// exact pressurised arcs: homogeneous by construction, and with the sharp pad-end kinks of
    /// a grooved bearing (a harder surface to tabulate than a Reynolds film's).
    struct PiFilm {
        geometry: BearingGeometry,
        pads: Vec<Pad>,
        nodes: Vec<(f64, f64)>,
        /// Added to the pressure integral to break homogeneity in one test.
        offset_n: f64,
    }

    impl PiFilm {
        fn new(geometry: BearingGeometry) -> Self {
            Self { geometry, pads: geometry.pads(), nodes: gauss_legendre(12), offset_n: 0.0 }
        }
    }

    /// n-point Gauss-Legendre nodes and weights on [-1, 1] by Newton's method on P_n.
    fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
        (0..n)
            .map(|i| {
                let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
                let mut dp = 1.0;
                for _ in 0..100 {
                    let (mut p0, mut p1) = (1.0, x);
                    for k in 2..=n {
                        let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                        p0 = p1;
                        p1 = p2;
                    }
                    dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                    let dx = p1 / dp;
                    x -= dx;
                    if dx.abs() < 1e-15 {
                        break;
                    }
                }
                (x, 2.0 / ((1.0 - x * x) * dp * dp))
            })
            .collect()
    }

    impl Film for PiFilm {
        fn geometry(&self) -> &BearingGeometry {
            &self.geometry
        }

        fn force(&mut self, state: &FilmState, running: &Running) -> Result<Vector2<f64>, PhysicsError> {
            let c = self.geometry.clearance_m;
            crate::film::check_state(state, c)?;
            let ex = state.x_m / c;
            let ey = state.y_m / c;
            let u = running.omega_rad_s * ex - 2.0 * state.vy_m_s / c;
            let v = running.omega_rad_s * ey + 2.0 * state.vx_m_s / c;
            let rho = u.hypot(v);
            let alpha = v.atan2(u);
            let tau = std::f64::consts::TAU;
            let mut sum = Vector2::zeros();
            for pad in &self.pads {
                // Pressurised where sin(alpha - theta) > 0: theta in (alpha - pi, alpha) mod 2 pi.
                for m in -2..=2 {
                    let lo = (alpha - std::f64::consts::PI + m as f64 * tau).max(pad.start_rad);
                    let hi = (alpha + m as f64 * tau).min(pad.end_rad);
                    if hi <= lo {
                        continue;
                    }
                    let pieces = ((hi - lo) / 0.2).ceil().max(1.0) as usize;
                    let dl = (hi - lo) / pieces as f64;
                    for p in 0..pieces {
                        let a = lo + p as f64 * dl;
                        for &(x, wgt) in &self.nodes {
                            let th = a + 0.5 * dl * (x + 1.0);
                            let (s, co) = th.sin_cos();
                            let h = 1.0 - ex * co - ey * s;
                            sum += Vector2::new(co, s) * ((alpha - th).sin() / (h * h * h) * wgt * 0.5 * dl);
                        }
                    }
                }
            }
            // int p dz = mu (c/2) |w| sin(alpha - theta) L^3 / h^3, F = -R int int p (cos, sin).
            let g = &self.geometry;
            let k = -running.viscosity_pa_s * g.radius_m() * g.length_m.powi(3) * 0.5 * rho / (c * c);
            Ok(sum * k + Vector2::new(0.0, self.offset_n))
        }
    }

    fn zhou() -> BearingGeometry {
        BearingGeometry::zhou2004()
    }

    fn running() -> Running {
        Running::from_rpm(1500.0, 0.03)
    }

    /// Roughly where the Zhou bearing sits under 5 kN at 1500 rpm in this pi-film.
    const CENTRE: (f64, f64) = (0.08, -0.17);

    fn map_at(centre: (f64, f64), spec: MapSpec) -> FilmMap {
        let c = zhou().clearance_m;
        // The pi-film is homogeneous and the box is inside the wall: build cannot fail.
        FilmMap::build(Box::new(PiFilm::new(zhou())), centre.0 * c, centre.1 * c, spec).unwrap()
    }

    /// Random state in the box; `squeeze` scales the velocities against omega c.
    fn random_state(rng: &mut rand_chacha::ChaCha8Rng, centre: (f64, f64), hw: f64, squeeze: f64) -> FilmState {
        let c = zhou().clearance_m;
        let w = running().omega_rad_s;
        FilmState {
            x_m: (centre.0 + rng.random_range(-hw..hw)) * c,
            y_m: (centre.1 + rng.random_range(-hw..hw)) * c,
            vx_m_s: rng.random_range(-squeeze..squeeze) * w * c,
            vy_m_s: rng.random_range(-squeeze..squeeze) * w * c,
        }
    }

    struct Errors {
        force_max: f64,
        force_rms: f64,
        jac_max: f64,
        jac_rms: f64,
    }

    fn errors(centre: (f64, f64), spec: MapSpec, samples: usize, squeeze: f64) -> Errors {
        let mut map = map_at(centre, spec);
        let mut inner = PiFilm::new(zhou());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let (mut fm, mut fs, mut jm, mut js) = (0.0f64, 0.0, 0.0f64, 0.0);
        for n in 0..samples {
            let _ = n;
            let st = random_state(&mut rng, centre, spec.half_width, squeeze);
            let a = map.force_jacobian(&st, &running()).unwrap();
            let b = inner.force_jacobian(&st, &running()).unwrap();
            let e = (a.force_n - b.force_n).norm() / b.force_n.norm();
            let ek = (a.stiffness() - b.stiffness()).norm() / b.stiffness().norm();
            let ec = (a.damping() - b.damping()).norm() / b.damping().norm();
            let ej = ek.max(ec);
            fm = fm.max(e);
            fs += e * e;
            jm = jm.max(ej);
            js += ej * ej;
        }
        assert_eq!(map.fallbacks(), 0);
        let n = samples as f64;
        Errors { force_max: fm, force_rms: (fs / n).sqrt(), jac_max: jm, jac_rms: (js / n).sqrt() }
    }

    #[test]
    fn slopes_are_exact_for_quartics() {
        let p = |x: f64| 0.3 - 1.2 * x + 0.7 * x * x - 0.05 * x.powi(3) + 0.01 * x.powi(4);
        let dp = |x: f64| -1.2 + 1.4 * x - 0.15 * x * x + 0.04 * x.powi(3);
        let f: Vec<f64> = (0..7).map(|i| p(i as f64)).collect();
        let mut d = vec![0.0; 7];
        slopes_line(&f, &mut d, false);
        for (i, di) in d.iter().enumerate() {
            assert!((di - dp(i as f64)).abs() < 1e-12, "slope {i}: {di} vs {}", dp(i as f64));
        }
        // Periodic: a trigonometric sample, fourth order in the spacing.
        let n = 64;
        let h = std::f64::consts::TAU / n as f64;
        let f: Vec<f64> = (0..n).map(|i| (i as f64 * h).sin()).collect();
        let mut d = vec![0.0; n];
        slopes_line(&f, &mut d, true);
        let err = d.iter().enumerate().map(|(i, di)| (di / h - (i as f64 * h).cos()).abs()).fold(0.0, f64::max);
        println!("periodic slope error at 64 points: {err:.2e}");
        assert!(err < h.powi(4) / 20.0);
    }

    #[test]
    fn the_map_passes_through_its_nodes() {
        let spec = MapSpec { half_width: 0.1, n_position: 5, n_angle: 24 };
        let mut map = map_at(CENTRE, spec);
        let mut inner = PiFilm::new(zhou());
        let c = zhou().clearance_m;
        let r = running();
        for &(i, j, k) in &[(0usize, 0usize, 0usize), (2, 3, 7), (4, 4, 23), (1, 4, 12)] {
            let ex = CENTRE.0 - 0.1 + 0.05 * i as f64;
            let ey = CENTRE.1 - 0.1 + 0.05 * j as f64;
            let alpha = k as f64 * std::f64::consts::TAU / 24.0;
            // Any |w|, any speed: here twice the operating speed's w.
            let rho = 2.0 * r.omega_rad_s;
            let st = realise(c, ex, ey, r.omega_rad_s, rho * alpha.cos(), rho * alpha.sin());
            let a = map.force(&st, &r).unwrap();
            let b = inner.force(&st, &r).unwrap();
            assert!((a - b).norm() <= 1e-12 * b.norm(), "node ({i},{j},{k}): {a} vs {b}");
        }
        assert_eq!(map.fallbacks(), 0);
    }

    #[test]
    fn default_map_is_accurate_on_a_grooved_pi_film() {
        let spec = MapSpec::default();
        // Typical states (velocities up to 0.1 omega c: orbits of a tenth of the clearance at
        // running speed) and violent ones (up to 0.5 omega c: w points anywhere), at the Zhou
        // operating point and in a box that reaches eccentricity 0.9.
        for centre in [CENTRE, (0.25, -0.6)] {
            for squeeze in [0.1, 0.5] {
                let e = errors(centre, spec, 2000, squeeze);
                println!(
                    "grooved pi-film, default spec, centre {centre:?}, velocities up to {squeeze} omega c: \
                     force max {:.2e} rms {:.2e}; Jacobian max {:.2e} rms {:.2e}",
                    e.force_max, e.force_rms, e.jac_max, e.jac_rms
                );
                assert!(e.force_max < 2e-3 && e.force_rms < 2e-4, "force error over budget");
                assert!(e.jac_max < 1e-2 && e.jac_rms < 1e-3, "Jacobian error over budget");
            }
        }
    }

    #[test]
    fn coarse_maps_are_measurably_worse() {
        // The error estimate must be able to fail: a coarse angle grid breaks the budget.
        let e = errors(CENTRE, MapSpec { half_width: 0.15, n_position: 5, n_angle: 16 }, 1000, 0.1);
        println!("coarse 5 x 5 x 16: force max {:.2e}, Jacobian max {:.2e}", e.force_max, e.jac_max);
        assert!(e.force_max > 2e-3 || e.jac_max > 1e-2);
    }

    #[test]
    fn jacobian_is_the_derivative_of_the_interpolant() {
        let mut map = map_at(CENTRE, MapSpec::default());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let r = running();
        let c = zhou().clearance_m;
        let mut worst = 0.0f64;
        for _ in 0..200 {
            let st = random_state(&mut rng, CENTRE, 0.14, 0.3);
            let analytic = map.force_jacobian(&st, &r).unwrap();
            let steps = [1e-7 * c, 1e-7 * c, 1e-7 * c * r.omega_rad_s, 1e-7 * c * r.omega_rad_s];
            for (j, h) in steps.into_iter().enumerate() {
                let (mut p, mut m) = (st, st);
                *crate::film::component_mut(&mut p, j) += h;
                *crate::film::component_mut(&mut m, j) -= h;
                let fd = (map.force(&p, &r).unwrap() - map.force(&m, &r).unwrap()) / (2.0 * h);
                let scale = analytic.jacobian.norm();
                let col = analytic.jacobian.column(j).into_owned();
                worst = worst.max((fd - col).norm() / scale);
            }
            assert_eq!(analytic.force_n, map.force(&st, &r).unwrap());
        }
        println!("analytic vs finite-difference Jacobian of the map: {worst:.2e}");
        assert!(worst < 1e-6);
    }

    #[test]
    fn outside_the_box_the_inner_film_answers() {
        let mut map = map_at(CENTRE, MapSpec::default());
        let mut inner = PiFilm::new(zhou());
        let c = zhou().clearance_m;
        let r = running();
        let outside = FilmState { x_m: (CENTRE.0 + 0.2) * c, y_m: CENTRE.1 * c, vx_m_s: 1e-3, vy_m_s: -2e-3 };
        assert!(!map.covers(outside.x_m, outside.y_m));
        assert_eq!(map.force(&outside, &r).unwrap(), inner.force(&outside, &r).unwrap());
        assert_eq!(map.fallbacks(), 1);
        assert_eq!(map.force_jacobian(&outside, &r).unwrap(), inner.force_jacobian(&outside, &r).unwrap());
        assert_eq!(map.fallbacks(), 2);
        // Beyond the wall: the inner film's error.
        let wall = FilmState::at_rest(1.2 * c, 0.0);
        assert!(matches!(map.force(&wall, &r), Err(PhysicsError::EccentricityLimit { .. })));
        assert_eq!(map.fallbacks(), 3);
        // Inside: no fallback.
        let inside = FilmState::at_rest(CENTRE.0 * c, CENTRE.1 * c);
        assert!(map.covers(inside.x_m, inside.y_m));
        map.force(&inside, &r).unwrap();
        assert_eq!(map.fallbacks(), 3);
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let mut map = map_at(CENTRE, MapSpec { half_width: 0.1, n_position: 5, n_angle: 16 });
        let c = zhou().clearance_m;
        let r = running();
        let ok = FilmState::at_rest(CENTRE.0 * c, CENTRE.1 * c);
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            for j in 0..4 {
                let mut st = ok;
                *crate::film::component_mut(&mut st, j) = bad;
                assert!(matches!(map.force(&st, &r), Err(PhysicsError::NonFinite { .. })));
                assert!(matches!(map.force_jacobian(&st, &r), Err(PhysicsError::NonFinite { .. })));
            }
            let rr = Running { omega_rad_s: bad, ..r };
            assert!(matches!(map.force(&ok, &rr), Err(PhysicsError::NonFinite { .. })));
            let rr = Running { viscosity_pa_s: bad, ..r };
            assert!(matches!(map.force_jacobian(&ok, &rr), Err(PhysicsError::NonFinite { .. })));
        }
        assert_eq!(map.fallbacks(), 0);
        // Huge but finite velocities: an answer, finite or an error, never a panic.
        let st = FilmState { vx_m_s: 1e300, vy_m_s: -1e300, ..ok };
        if let Ok(f) = map.force(&st, &r) {
            assert!(f.x.is_finite() || f.x.is_nan() || f.x.is_infinite());
        }
        // Negative speed and zero viscosity are not the table's business but must not panic.
        let _ = map.force(&ok, &Running { omega_rad_s: -300.0, viscosity_pa_s: 0.03 });
        let _ = map.force(&ok, &Running { omega_rad_s: 157.0, viscosity_pa_s: 0.0 });
    }

    #[test]
    fn bad_specs_are_refused() {
        let c = zhou().clearance_m;
        let build = |spec: MapSpec, centre: (f64, f64)| FilmMap::build(Box::new(PiFilm::new(zhou())), centre.0 * c, centre.1 * c, spec);
        let good = MapSpec { half_width: 0.1, n_position: 5, n_angle: 8 };
        assert!(build(good, CENTRE).is_ok());
        for (spec, field) in [
            (MapSpec { half_width: 0.0, ..good }, "film_map.spec.half_width"),
            (MapSpec { half_width: f64::NAN, ..good }, "film_map.spec.half_width"),
            (MapSpec { n_position: 4, ..good }, "film_map.spec.n_position"),
            (MapSpec { n_angle: 7, ..good }, "film_map.spec.n_angle"),
            (MapSpec { half_width: 0.8, ..good }, "film_map.spec.half_width"),
            (MapSpec { n_position: usize::MAX, ..good }, "film_map.spec"),
        ] {
            match build(spec, CENTRE) {
                Err(PhysicsError::InvalidConfig { field: f, reason }) => {
                    assert_eq!(f, field, "{reason}");
                }
                other => panic!("{spec:?} gave {other:?}"),
            }
        }
        assert!(matches!(build(good, (f64::NAN, 0.0)), Err(PhysicsError::NonFinite { .. })));
    }

    #[test]
    fn a_film_that_is_not_homogeneous_is_refused() {
        let c = zhou().clearance_m;
        let mut film = PiFilm::new(zhou());
        film.offset_n = 50.0; // like a supply-pressure force that does not scale with mu |w|
        match FilmMap::build(Box::new(film), CENTRE.0 * c, CENTRE.1 * c, MapSpec::default()) {
            Err(PhysicsError::InvalidConfig { field, reason }) => {
                assert_eq!(field, "film_map.inner");
                println!("{reason}");
            }
            other => panic!("expected a refusal, got {other:?}"),
        }
    }

    #[test]
    fn w_zero_gives_zero_force_and_a_finite_jacobian() {
        let mut map = map_at(CENTRE, MapSpec::default());
        let c = zhou().clearance_m;
        let r = running();
        let (ex, ey) = (CENTRE.0 + 0.02, CENTRE.1 - 0.03);
        let st = realise(c, ex, ey, r.omega_rad_s, 0.0, 0.0);
        let fj = map.force_jacobian(&st, &r).unwrap();
        assert_eq!(fj.force_n, Vector2::zeros());
        assert!(fj.jacobian.iter().all(|v| v.is_finite()));
        // Central differences across w = 0 agree with the returned limit.
        let h = 1e-6 * c * r.omega_rad_s;
        for j in 2..4 {
            let (mut p, mut m) = (st, st);
            *crate::film::component_mut(&mut p, j) += h;
            *crate::film::component_mut(&mut m, j) -= h;
            let fd = (map.force(&p, &r).unwrap() - map.force(&m, &r).unwrap()) / (2.0 * h);
            let col = fj.jacobian.column(j).into_owned();
            assert!((fd - col).norm() < 1e-6 * fj.jacobian.norm(), "column {j}: {fd} vs {col}");
        }
    }

    #[test]
    fn angle_wraps_continuously() {
        let mut map = map_at(CENTRE, MapSpec::default());
        let c = zhou().clearance_m;
        let r = running();
        let (ex, ey) = (CENTRE.0 + 0.013, CENTRE.1 + 0.021);
        let at = |map: &mut FilmMap, a: f64| {
            let st = realise(c, ex, ey, r.omega_rad_s, 150.0 * a.cos(), 150.0 * a.sin());
            map.force_jacobian(&st, &r).unwrap()
        };
        let below = at(&mut map, -1e-12);
        let zero = at(&mut map, 0.0);
        let above = at(&mut map, 1e-12);
        for other in [&below, &above] {
            assert!((other.force_n - zero.force_n).norm() < 1e-9 * zero.force_n.norm());
            assert!((other.jacobian - zero.jacobian).norm() < 1e-9 * zero.jacobian.norm());
        }
        let pi_below = at(&mut map, std::f64::consts::PI - 1e-12);
        let pi_above = at(&mut map, -std::f64::consts::PI + 1e-12);
        assert!((pi_below.force_n - pi_above.force_n).norm() < 1e-9 * pi_below.force_n.norm());
    }

    #[test]
    #[ignore = "exploration: error against spec, prints a table"]
    fn explore_specs() {
        for &centre in &[CENTRE, (0.3, -0.45), (0.25, -0.6)] {
            for &(hw, np, na) in &[(0.15, 5usize, 192usize), (0.15, 7, 192), (0.1, 5, 192)] {
                let spec = MapSpec { half_width: hw, n_position: np, n_angle: na };
                for squeeze in [0.05, 0.15, 0.5] {
                    let e = errors(centre, spec, 2000, squeeze);
                    println!(
                        "centre {centre:?} hw {hw} np {np} na {na} squeeze {squeeze}: force max {:.2e} rms {:.2e}; Jacobian max {:.2e} rms {:.2e}",
                        e.force_max, e.force_rms, e.jac_max, e.jac_rms
                    );
                }
            }
        }
    }
}
