//! Ocvirk's short-bearing film (Ocvirk 1952, NACA TN 2808) as a nonlinear force in closed
//! form, with its analytic Jacobian, closed-form linear coefficients and a temporal-inertia
//! (added-mass) estimate.
//!
//! ## The film
//!
//! Crate frame (see the crate docs): the journal centre sits at `r = (x, y)` relative to the
//! bearing centre, angles `theta` run from `+x` towards `+y`, and the journal surface moves in
//! `+theta` at `U = omega R`. With `ex = x/c`, `ey = y/c` the film thickness is
//! `h = c H`, `H = 1 - ex cos(theta) - ey sin(theta)`.
//!
//! Dropping the circumferential pressure-flow term of the isoviscous Reynolds equation
//! (L/D small) leaves, with ambient pressure at both ends `z = +-L/2`,
//!
//! ```text
//! d/dz (h^3 dp/dz) = 6 mu omega dh/dtheta + 12 mu dh/dt
//!                  = 6 mu c (wx sin(theta) - wy cos(theta))
//! p(theta, z)      = 3 mu (z^2 - L^2/4) c (wx sin(theta) - wy cos(theta)) / h^3
//! ```
//!
//! where `w = (omega ex - 2 ey', omega ey + 2 ex')` (primes: time derivatives). Speed and
//! squeeze enter only through `w`, and `p` is linear in it: the homogeneity that the force map
//! relies on. With `w = |w| (cos alpha, sin alpha)` the bracket is `|w| sin(theta - alpha)`,
//! so the short-bearing pressure is positive exactly on the half circumference
//! `theta in [beta, beta + pi]`, `beta = alpha + pi`; the film is taken as ruptured (ambient
//! pressure) on the other half. This is the short-bearing **pi-film** whose boundaries follow
//! the effective velocity `w`; it is exact for that model (Adiletta, Guido & Rossi 1996,
//! "Chaotic motions of a rigid rotor in short journal bearings", Nonlinear Dynamics 10,
//! 251-269). Bearing grooves are ignored: every geometry carries this one 180 degree film.
//!
//! ## Closed-form force
//!
//! Integrating over the length (`int (z^2 - L^2/4) dz = -L^3/6`) and the active arc, the force
//! on the journal `F = -R int int p (cos theta, sin theta) dz dtheta` is
//!
//! ```text
//! F = k int_beta^{beta+pi} (wx sin - wy cos) (cos, sin) / H^3 dtheta,   k = mu R L^3 / (2 c^2)
//! ```
//!
//! All such integrals are derivatives, at fixed limits, of the one elementary integral
//! (Weierstrass substitution `t = tan((theta - beta)/2)`)
//!
//! ```text
//! G(ex, ey) = int_beta^{beta+pi} dtheta / H = (2 / s) (pi/2 + atan(B / s)),
//! s = sqrt(1 - ex^2 - ey^2),   A = r.u,   B = r.v,
//! u = (cos beta, sin beta) = -w/|w|,   v = (-sin beta, cos beta)
//! ```
//!
//! since `d^2(1/H)/dex^2 = 2 cos^2/H^3` and so on. In the `(A, B)` frame of the active arc
//! the force reduces to `F = -(k/2) |w| grad V` with `V = dG/dB = (2 + B G)/s^2`, and
//!
//! ```text
//! dV/dA = (3 A V - 2 S)/s^2,   dV/dB = (3 B V + G)/s^2,   S = A / (1 - A^2),
//! ```
//!
//! which are Adiletta's `G`, `V`, `S` functions. `pi/2 + atan(B/s)` is evaluated as
//! `atan2(s, -B)`, which is accurate for every `B`. Nothing is singular inside the clearance:
//! `s > 0` and `1 - A^2 >= s^2`; the concentric journal needs no special case; at `w = 0` the
//! force is exactly zero (and the arc, which is then undefined, is chosen as the static one).
//!
//! ## Jacobian
//!
//! The pressure vanishes at both ends of the active arc, so moving the arc (which follows `w`)
//! changes nothing to first order: derivatives are those of the integrand at fixed limits.
//! Writing `F = (k/2) N w` with `N = Hess(G) J` (`J` the +90 degree rotation), exact
//! differentiation of the closed forms gives `dF/dr = (k/2c) (omega N - |w| Hess(V))` and
//! `dF/dr' = (k/c) N J`, both from the second derivatives of `V` and `G` in closed form.
//! At `w = 0` (e.g. half-frequency whirl) the force is not differentiable; the Jacobian of the
//! static arc is returned there.
//!
//! ## Linear coefficients in closed form
//!
//! At rest with `w = omega eps e_r`, the arc runs from the thickest to the thinnest film and the
//! classical polar forces follow (Ocvirk 1952; Friswell, Penny, Garvey & Lees 2010, "Dynamics
//! of Rotating Machines", section 5.5; Hamrock, "Fundamentals of Fluid Film Lubrication"):
//!
//! ```text
//! F_r = -(mu R L^3/c^2) [eps^2 (omega - 2 phi')/(1-eps^2)^2 + pi eps'(1+2 eps^2)/(2 (1-eps^2)^{5/2})]
//! F_t =  (mu R L^3/c^2) [pi eps (omega - 2 phi')/(4 (1-eps^2)^{3/2}) + 2 eps eps'/(1-eps^2)^2]
//! ```
//!
//! (`r` along the line of centres, `t` 90 degrees ahead in the rotation direction). Balancing
//! a load `W` gives `W c^2/(mu omega R L^3) = eps sqrt(16 eps^2 + pi^2 (1-eps^2)) / (4 (1-eps^2)^2)`,
//! increasing in `eps` and solved by bisection, and the attitude `tan(phi) = pi sqrt(1-eps^2)/(4 eps)`.
//! Perturbing `(eps, phi, eps', phi')` (with the rotation of the polar basis) gives `K` and
//! `C` in the `(r, t)` frame; they are rotated by the attitude angle into Lund's load frame
//! (x along the load, journal turning x -> y) and from there into the crate frame with
//! [`dimensionless::from_load_frame`]. They agree with the Jacobian of the nonlinear film at
//! its equilibrium (a test checks it).
//!
//! ## Added mass
//!
//! Leading-order temporal fluid inertia (Reinhardt & Lund 1975, "The influence of fluid
//! inertia on the dynamic properties of journal bearings", J. Lubr. Technol. 97): the inertia
//! pressure solves `d/dz (h^3 dp/dz) = rho h^2 d2h/dt2` over the active arc, i.e.
//! `p = rho h'' (z^2 - L^2/4) / (2 h)`, and with `h'' = -(x'' cos + y'' sin)` the added mass is
//!
//! ```text
//! M = (rho R L^3 / (12 c)) int_beta^{beta+pi} (cos, sin)(cos, sin)^T / H dtheta
//! ```
//!
//! (`pi rho R L^3/(12 c)` for a centred full film, half of it for the pi-film). The three
//! integrals are in closed form from `G` and `ln((1+A)/(1-A))` when `eps >= 0.1`, and by
//! 20-point Gauss-Legendre quadrature below (where the closed form loses digits to
//! cancellation and the integrand is nearly constant, so the quadrature is exact to rounding).

use std::f64::consts::PI;
use std::sync::OnceLock;

use nalgebra::{Matrix2, Matrix2x4, Vector2};
use serde::{Deserialize, Serialize};

use crate::dimensionless;
use crate::error::PhysicsError;
use crate::film::{check_state, Film, FilmState, ForceJacobian, Running};
use crate::geometry::BearingGeometry;
use crate::operating_point::LinearCoefficients;

/// Ocvirk's short-bearing pi-film, nonlinear and in closed form.
///
/// Bearing grooves in the geometry are ignored: the short-bearing pi-film is a single
/// 180 degree film whose position follows the journal's effective velocity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShortBearing {
    geometry: BearingGeometry,
}

impl ShortBearing {
    /// A short-bearing film for `geometry` (validated under the name `bearing`).
    pub fn new(geometry: BearingGeometry) -> Result<Self, PhysicsError> {
        geometry.validate("bearing")?;
        Ok(Self { geometry })
    }

    /// Force scale `k = mu R L^3 / (2 c^2)`, N s.
    fn force_scale(&self, running: &Running) -> f64 {
        let g = &self.geometry;
        running.viscosity_pa_s * g.radius_m() * g.length_m.powi(3) / (2.0 * g.clearance_m * g.clearance_m)
    }

    /// Validates inputs and sets up the active arc for `state`.
    fn prepare(&self, state: &FilmState, running: &Running) -> Result<Kinematics, PhysicsError> {
        let c = self.geometry.clearance_m;
        let eps = check_state(state, c)?;
        running.validate()?;
        let omega = running.omega_rad_s;
        let r = Vector2::new(state.x_m / c, state.y_m / c);
        let w = Vector2::new(omega * r.x - 2.0 * state.vy_m_s / c, omega * r.y + 2.0 * state.vx_m_s / c);
        let w_norm = w.norm();
        PhysicsError::check_finite("short-bearing effective velocity |w|", w_norm)?;
        let u = arc_start_direction(&w, w_norm, &r, omega);
        Ok(Kinematics { r, eps, w_norm, u })
    }
}

/// Journal kinematics in the units of the closed forms.
struct Kinematics {
    /// Position over clearance.
    r: Vector2<f64>,
    /// Eccentricity ratio |r|.
    eps: f64,
    /// |w|, 1/s.
    w_norm: f64,
    /// Unit vector to the start of the active arc.
    u: Vector2<f64>,
}

/// Unit vector `u = (cos beta, sin beta)` at the start of the active arc `[beta, beta + pi]`.
///
/// `u = -w/|w|`. When `w = 0` the force vanishes and the arc is undefined; the arc the static
/// journal would have (`w` along `omega r`) is used, or the arc starting at `theta = pi` for a
/// concentric journal (any arc gives the same integrals there).
fn arc_start_direction(w: &Vector2<f64>, w_norm: f64, r: &Vector2<f64>, omega: f64) -> Vector2<f64> {
    if w_norm > 0.0 {
        return -w / w_norm;
    }
    let r_norm = r.norm();
    if r_norm > 0.0 {
        let sign = if omega < 0.0 { -1.0 } else { 1.0 };
        -sign * r / r_norm
    } else {
        Vector2::new(-1.0, 0.0)
    }
}

/// Rotation whose columns are `u` and `v` (u turned +90 degrees): maps arc-frame (A, B)
/// components to crate-frame (x, y) components.
fn arc_rotation(u: &Vector2<f64>) -> Matrix2<f64> {
    Matrix2::new(u.x, -u.y, u.y, u.x)
}

/// `+90` degree rotation `J`.
fn quarter_turn() -> Matrix2<f64> {
    Matrix2::new(0.0, -1.0, 1.0, 0.0)
}

/// The closed-form half-film integrals at arc-frame position `(A, B)`, `A^2 + B^2 < 1`.
#[derive(Debug, Clone, Copy)]
struct HalfFilm {
    /// `G = int dtheta/H` over the arc.
    g: f64,
    /// `V = dG/dB`.
    v: f64,
    /// `dG/dA`.
    g_a: f64,
    /// `dV/dA`, `dV/dB`.
    v_a: f64,
    v_b: f64,
    /// `S = A/(1 - A^2)` and `dS/dA`.
    s_a: f64,
    a: f64,
    b: f64,
    /// `s^2 = 1 - A^2 - B^2`.
    s2: f64,
}

impl HalfFilm {
    /// `s2 = 1 - eps^2` is passed in (computed as `(1 - eps)(1 + eps)` by the caller for
    /// accuracy near the wall).
    fn new(a: f64, b: f64, s2: f64) -> Self {
        let s = s2.sqrt();
        // pi/2 + atan(B/s), accurate for all B.
        let t = s.atan2(-b);
        let g = 2.0 * t / s;
        let v = (2.0 + b * g) / s2;
        // 1 - A^2 >= s^2 > 0.
        let one_minus_a2 = (1.0 - a) * (1.0 + a);
        let s_fn = a / one_minus_a2;
        let s_a = (1.0 + a * a) / (one_minus_a2 * one_minus_a2);
        let g_a = (2.0 * a * b / one_minus_a2 + a * g) / s2;
        let v_a = (3.0 * a * v - 2.0 * s_fn) / s2;
        let v_b = (3.0 * b * v + g) / s2;
        Self { g, v, g_a, v_a, v_b, s_a, a, b, s2 }
    }

    /// Hessian of `G` in the arc frame.
    fn hessian_g(&self) -> Matrix2<f64> {
        let g_aa = (self.g + 2.0 * self.b * self.s_a + 3.0 * self.a * self.g_a) / self.s2;
        Matrix2::new(g_aa, self.v_a, self.v_a, self.v_b)
    }

    /// Hessian of `V` in the arc frame.
    fn hessian_v(&self) -> Matrix2<f64> {
        let (a, b, v, s2) = (self.a, self.b, self.v, self.s2);
        let v_aa = (3.0 * v + 5.0 * a * self.v_a - 2.0 * self.s_a) / s2;
        let v_ab = (3.0 * a * self.v_b + 2.0 * b * self.v_a) / s2;
        let v_bb = (4.0 * v + 5.0 * b * self.v_b) / s2;
        Matrix2::new(v_aa, v_ab, v_ab, v_bb)
    }
}

fn half_film(kin: &Kinematics) -> (HalfFilm, Matrix2<f64>) {
    let rot = arc_rotation(&kin.u);
    let ab = rot.transpose() * kin.r;
    let s2 = (1.0 - kin.eps) * (1.0 + kin.eps);
    (HalfFilm::new(ab.x, ab.y, s2), rot)
}

impl Film for ShortBearing {
    fn geometry(&self) -> &BearingGeometry {
        &self.geometry
    }

    fn force(&mut self, state: &FilmState, running: &Running) -> Result<Vector2<f64>, PhysicsError> {
        let kin = self.prepare(state, running)?;
        if kin.w_norm == 0.0 {
            return Ok(Vector2::zeros());
        }
        let (hf, rot) = half_film(&kin);
        let k = self.force_scale(running);
        let f_arc = Vector2::new(hf.v_a, hf.v_b) * (-0.5 * k * kin.w_norm);
        let force = rot * f_arc;
        check_all_finite("short-bearing film force", force.iter())?;
        Ok(force)
    }

    fn force_jacobian(&mut self, state: &FilmState, running: &Running) -> Result<ForceJacobian, PhysicsError> {
        let kin = self.prepare(state, running)?;
        let c = self.geometry.clearance_m;
        let k = self.force_scale(running);
        let (hf, rot) = half_film(&kin);
        let force_arc = Vector2::new(hf.v_a, hf.v_b) * (-0.5 * k * kin.w_norm);
        let force_n = rot * force_arc;
        // Tensors rotate as R A R^T (J commutes with rotations).
        let n = rot * (hf.hessian_g() * quarter_turn()) * rot.transpose();
        let hess_v = rot * hf.hessian_v() * rot.transpose();
        let d_position = (n * running.omega_rad_s - hess_v * kin.w_norm) * (0.5 * k / c);
        let d_velocity = n * quarter_turn() * (k / c);
        let mut jacobian = Matrix2x4::zeros();
        jacobian.fixed_view_mut::<2, 2>(0, 0).copy_from(&d_position);
        jacobian.fixed_view_mut::<2, 2>(0, 2).copy_from(&d_velocity);
        check_all_finite("short-bearing film force and Jacobian", force_n.iter().chain(jacobian.iter()))?;
        Ok(ForceJacobian { force_n, jacobian })
    }

    fn added_mass(&mut self, state: &FilmState, running: &Running, density_kg_m3: f64) -> Result<Option<Matrix2<f64>>, PhysicsError> {
        if !density_kg_m3.is_finite() || density_kg_m3 <= 0.0 {
            return Err(PhysicsError::invalid("oil density", format!("must be positive and finite for the added mass, got {density_kg_m3} kg/m^3")));
        }
        let kin = self.prepare(state, running)?;
        let rot = arc_rotation(&kin.u);
        let ab = rot.transpose() * kin.r;
        let moments = inverse_film_moments(ab.x, ab.y, kin.eps);
        let g = &self.geometry;
        let scale = density_kg_m3 * g.radius_m() * g.length_m.powi(3) / (12.0 * g.clearance_m);
        let mass = rot * moments * rot.transpose() * scale;
        check_all_finite("short-bearing added mass", mass.iter())?;
        Ok(Some(mass))
    }
}

/// Errors with [`PhysicsError::NonFinite`] if any value overflowed (possible only within
/// rounding of the bearing wall or for absurd inputs).
fn check_all_finite<'a>(what: &str, values: impl Iterator<Item = &'a f64>) -> Result<(), PhysicsError> {
    for &v in values {
        PhysicsError::check_finite(what, v)?;
    }
    Ok(())
}

/// `int_0^pi (cos, sin)(cos, sin)^T / (1 - A cos - B sin) dphi`, `eps = |(A, B)| < 1`.
fn inverse_film_moments(a: f64, b: f64, eps: f64) -> Matrix2<f64> {
    if eps >= 0.1 {
        // Closed form from  A I_C + B I_S = G - pi,  A I_S - B I_C = ln((1+A)/(1-A)),
        // A I_CC + B I_CS = I_C,  A I_CS + B I_SS = I_S - 2,  I_CC + I_SS = G.
        let s2 = (1.0 - eps) * (1.0 + eps);
        let s = s2.sqrt();
        let g = 2.0 * s.atan2(-b) / s;
        let e2 = a * a + b * b;
        let log_ratio = a.ln_1p() - (-a).ln_1p();
        let i_c = (a * (g - PI) - b * log_ratio) / e2;
        let i_s = (b * (g - PI) + a * log_ratio) / e2;
        let q = i_s - 2.0 - b * g;
        let i_cc = (a * i_c - b * q) / e2;
        let i_cs = (b * i_c + a * q) / e2;
        Matrix2::new(i_cc, i_cs, i_cs, g - i_cc)
    } else {
        let rule = gauss_legendre_20();
        let mut m = Matrix2::zeros();
        for &(node, weight) in rule.iter() {
            // Map [-1, 1] to [0, pi].
            let phi = 0.5 * PI * (node + 1.0);
            let (sn, cs) = phi.sin_cos();
            let inv_h = 1.0 / (1.0 - a * cs - b * sn);
            let wt = 0.5 * PI * weight * inv_h;
            m[(0, 0)] += wt * cs * cs;
            m[(0, 1)] += wt * cs * sn;
            m[(1, 1)] += wt * sn * sn;
        }
        m[(1, 0)] = m[(0, 1)];
        m
    }
}

/// Nodes and weights of the 20-point Gauss-Legendre rule on [-1, 1], by Newton's method on
/// the Legendre polynomial (computed once).
fn gauss_legendre_20() -> &'static [(f64, f64); 20] {
    static RULE: OnceLock<[(f64, f64); 20]> = OnceLock::new();
    RULE.get_or_init(|| {
        const N: usize = 20;
        let mut rule = [(0.0, 0.0); N];
        for (i, slot) in rule.iter_mut().enumerate() {
            // Tricomi's initial guess, then Newton.
            let mut x = (PI * (i as f64 + 0.75) / (N as f64 + 0.5)).cos();
            for _ in 0..100 {
                let (p, dp) = legendre_and_derivative(N, x);
                let dx = p / dp;
                x -= dx;
                if dx.abs() < 1e-16 {
                    break;
                }
            }
            // The roots are simple and lie well inside (-1, 1), so dp is finite and non-zero.
            let (_, derivative) = legendre_and_derivative(N, x);
            *slot = (x, 2.0 / ((1.0 - x * x) * derivative * derivative));
        }
        rule
    })
}

/// `P_n(x)` and `P_n'(x)` by the three-term recurrence (|x| < 1).
fn legendre_and_derivative(n: usize, x: f64) -> (f64, f64) {
    let mut p0 = 1.0;
    let mut p1 = x;
    for k in 2..=n {
        let kf = k as f64;
        let p2 = ((2.0 * kf - 1.0) * x * p1 - (kf - 1.0) * p0) / kf;
        p0 = p1;
        p1 = p2;
    }
    let dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
    (p1, dp)
}

/// Closed-form static equilibrium and linear coefficients of the short bearing.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ShortBearingPoint {
    /// Eccentricity ratio.
    pub eccentricity: f64,
    /// Angle from the load line to the line of centres, degrees, positive in the direction of
    /// rotation (the journal sits low and ahead of the load line).
    pub attitude_deg: f64,
    /// Sommerfeld number `S = mu N L D / W (R/c)^2`.
    pub sommerfeld: f64,
    /// Coefficients in the crate frame (x horizontal, y up); no added mass.
    pub coefficients: LinearCoefficients,
}

/// Dimensionless load `W c^2 / (mu omega R L^3)` the short bearing carries at `eps`.
fn load_function(eps: f64) -> f64 {
    let s2 = (1.0 - eps) * (1.0 + eps);
    eps * (16.0 * eps * eps + PI * PI * s2).sqrt() / (4.0 * s2 * s2)
}

/// Closed-form static equilibrium and linear coefficients under a load `load_n` on the journal
/// along `-y` (crate frame), for the short-bearing pi-film (Ocvirk; Friswell et al. 2010,
/// section 5.5). See the module docs for the derivation.
pub fn linear_point(geometry: &BearingGeometry, running: &Running, load_n: f64) -> Result<ShortBearingPoint, PhysicsError> {
    geometry.validate("bearing")?;
    for (name, v) in [("load", load_n), ("running.omega_rad_s", running.omega_rad_s), ("running.viscosity_pa_s", running.viscosity_pa_s)] {
        if !v.is_finite() || v <= 0.0 {
            return Err(PhysicsError::invalid(name, format!("must be positive and finite, got {v}")));
        }
    }
    let c = geometry.clearance_m;
    let omega = running.omega_rad_s;
    // P = mu R L^3 / c^2 (N s): the polar forces are P omega times functions of eps.
    let p = running.viscosity_pa_s * geometry.radius_m() * geometry.length_m.powi(3) / (c * c);
    let target = load_n / (p * omega);
    PhysicsError::check_finite("short-bearing dimensionless load", target)?;

    // load_function rises monotonically from 0 at eps = 0 to infinity at eps = 1: bisect.
    let (mut lo, mut hi) = (0.0_f64, 1.0_f64);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if load_function(mid) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let eps = 0.5 * (lo + hi);
    let s2 = (1.0 - eps) * (1.0 + eps);
    if s2 <= 1e-12 {
        return Err(PhysicsError::EccentricityLimit {
            eccentricity: eps,
            context: format!("under a {load_n} N load on the short bearing (the film cannot carry it)"),
        });
    }
    let s = s2.sqrt();
    let s3 = s2 * s;
    let s4 = s2 * s2;
    let s5 = s4 * s;
    let s6 = s4 * s2;
    let e2 = eps * eps;
    let attitude = (PI * s).atan2(4.0 * eps);

    // (r, t) frame: r along the line of centres, t 90 degrees ahead in the rotation direction.
    let kp = p * omega / c;
    let k_rt = Matrix2::new(kp * 2.0 * eps * (1.0 + e2) / s6, kp * PI / (4.0 * s3), -kp * PI * (1.0 + 2.0 * e2) / (4.0 * s5), kp * eps / s4);
    let cp = p / c;
    let c_cross = -cp * 2.0 * eps / s4;
    let c_rt = Matrix2::new(cp * PI * (1.0 + 2.0 * e2) / (2.0 * s5), c_cross, c_cross, cp * PI / (2.0 * s3));

    // Load frame (x along the load, journal turning x -> y): the line of centres is at the
    // attitude angle from x, so its basis (e_r, e_t) has columns (cos, sin), (-sin, cos).
    let (sa, ca) = attitude.sin_cos();
    let basis = Matrix2::new(ca, -sa, sa, ca);
    let k_load = basis * k_rt * basis.transpose();
    let c_load = basis * c_rt * basis.transpose();
    let stiffness_n_m = dimensionless::from_load_frame(&k_load);
    let damping_n_s_m = dimensionless::from_load_frame(&c_load);
    for (name, m) in [("short-bearing stiffness", &stiffness_n_m), ("short-bearing damping", &damping_n_s_m)] {
        for v in m.iter() {
            PhysicsError::check_finite(name, *v)?;
        }
    }
    Ok(ShortBearingPoint {
        eccentricity: eps,
        attitude_deg: attitude.to_degrees(),
        sommerfeld: dimensionless::sommerfeld(geometry, running, load_n),
        coefficients: LinearCoefficients { stiffness_n_m, damping_n_s_m, added_mass_kg: None },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gauss_legendre_integrates_polynomials_exactly() {
        let rule = gauss_legendre_20();
        let total: f64 = rule.iter().map(|&(_, w)| w).sum();
        assert!((total - 2.0).abs() < 1e-14, "weights sum {total}");
        // x^38 integrates to 2/39 on [-1, 1]; degree 39 is the limit of a 20-point rule.
        let moment: f64 = rule.iter().map(|&(x, w)| w * x.powi(38)).sum();
        assert!((moment - 2.0 / 39.0).abs() < 1e-14, "x^38 moment {moment}");
    }

    #[test]
    fn added_mass_moments_agree_across_the_switch() {
        // Both branches at the switch eccentricity, in several arc positions.
        for k in 0..8 {
            let ang = k as f64 * 0.8;
            let (a, b) = (0.1 * ang.cos(), 0.1 * ang.sin());
            let closed = inverse_film_moments(a, b, 0.1);
            let quad = inverse_film_moments(a, b, 0.0999999999);
            let diff = (closed - quad).norm();
            assert!(diff < 1e-12, "closed vs quadrature at angle {ang}: {diff:e}");
        }
    }
}
