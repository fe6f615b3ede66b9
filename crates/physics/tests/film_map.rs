//! The force map against the real films: the homogeneity it rests on, its force and Jacobian
//! errors over the box, its fallback, the equilibrium and coefficients it gives at the Zhou
//! operating point, and (printed only) its speed.
//!
//! Run with `--nocapture` to see the measured errors.

use std::sync::{Mutex, MutexGuard, OnceLock};
use std::time::Instant;

use nalgebra::{Matrix2x4, Vector2};
use oilfilm_physics::film::finite::{FiniteBearing, GridSpec};
use oilfilm_physics::film::map::{FilmMap, MapSpec};
use oilfilm_physics::film::short::ShortBearing;
use oilfilm_physics::film::{component_mut, Film, FilmState, Running};
use oilfilm_physics::geometry::BearingGeometry;
use oilfilm_physics::operating_point::{solve, EquilibriumOptions, OperatingPoint};
use oilfilm_physics::PhysicsError;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The documented bounds of the default map (see `film::map`).
const FORCE_MAX: f64 = 2e-3;
const FORCE_RMS: f64 = 2e-4;
const JACOBIAN_MAX: f64 = 1e-2;

fn geometry() -> BearingGeometry {
    BearingGeometry::zhou2004()
}

/// Zhou et al. (2004) operating point: 1500 rpm, 0.03 Pa s.
fn running() -> Running {
    Running::from_rpm(1500.0, 0.03)
}

/// 5 kN on the journal along -y.
fn load() -> Vector2<f64> {
    Vector2::new(0.0, -5000.0)
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    /// Ocvirk pi-film, closed form.
    Short,
    /// Finite-length Reynolds film on its default grid (72 x 8 per pad when written).
    Finite,
    /// The same on a finer grid (144 x 8 per pad), whose own Jacobian is smoother.
    FiniteFine,
}

fn new_film(kind: Kind) -> Box<dyn Film + Send> {
    // The Zhou geometry and these grids are valid: construction cannot fail.
    match kind {
        Kind::Short => Box::new(ShortBearing::new(geometry()).unwrap()),
        Kind::Finite => Box::new(FiniteBearing::new(geometry(), GridSpec::default()).unwrap()),
        Kind::FiniteFine => Box::new(FiniteBearing::new(geometry(), GridSpec { n_theta: 144, n_z: 8 }).unwrap()),
    }
}

/// One inner film, its equilibrium at the Zhou point and a default map built around it.
struct Fixture {
    kind: Kind,
    inner: Box<dyn Film + Send>,
    inner_point: OperatingPoint,
    map: FilmMap,
    build_s: f64,
}

/// Offset of the box centre from the inner equilibrium, eccentricity units, so that the
/// equilibrium sits at a generic place in the table rather than on a node.
const CENTRE_OFFSET: (f64, f64) = (0.037, -0.021);

fn build_fixture(kind: Kind) -> Fixture {
    let mut inner = new_film(kind);
    let inner_point =
        solve(inner.as_mut(), &running(), load(), &EquilibriumOptions::default()).unwrap_or_else(|e| panic!("{kind:?} equilibrium at the Zhou point: {e}"));
    let c = geometry().clearance_m;
    let centre = (inner_point.journal.x_m + CENTRE_OFFSET.0 * c, inner_point.journal.y_m + CENTRE_OFFSET.1 * c);
    let start = Instant::now();
    let map = FilmMap::build(new_film(kind), centre.0, centre.1, MapSpec::default()).unwrap_or_else(|e| panic!("{kind:?} map: {e}"));
    let build_s = start.elapsed().as_secs_f64();
    println!(
        "{kind:?}: inner equilibrium eps {:.4}, attitude {:.2} deg; default map {:?}: {} inner solves in {:.2} s",
        inner_point.eccentricity,
        inner_point.attitude_deg,
        map.spec(),
        map.inner_solves(),
        build_s
    );
    Fixture { kind, inner, inner_point, map, build_s }
}

/// Each map is built once and shared by the tests (lock held for a test's duration).
fn fixture(kind: Kind) -> MutexGuard<'static, Fixture> {
    static SHORT: OnceLock<Mutex<Fixture>> = OnceLock::new();
    static FINITE: OnceLock<Mutex<Fixture>> = OnceLock::new();
    static FINITE_FINE: OnceLock<Mutex<Fixture>> = OnceLock::new();
    let cell = match kind {
        Kind::Short => &SHORT,
        Kind::Finite => &FINITE,
        Kind::FiniteFine => &FINITE_FINE,
    };
    // A test that panicked while holding the lock leaves the fixture itself intact.
    cell.get_or_init(|| Mutex::new(build_fixture(kind))).lock().unwrap_or_else(|p| p.into_inner())
}

/// The state that realises position (ex, ey) and w = rho (cos alpha, sin alpha) at `omega`.
fn realise(ex: f64, ey: f64, omega: f64, rho: f64, alpha: f64) -> FilmState {
    let c = geometry().clearance_m;
    let (u, v) = (rho * alpha.cos(), rho * alpha.sin());
    FilmState { x_m: c * ex, y_m: c * ey, vx_m_s: c * 0.5 * (v - omega * ey), vy_m_s: c * 0.5 * (omega * ex - u) }
}

// ---------------------------------------------------------------------------------------------
// Homogeneity

fn homogeneity(kind: Kind) -> f64 {
    let mut film = new_film(kind);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut worst = 0.0f64;
    for _ in 0..60 {
        let eps = rng.random_range(0.0..0.7);
        let phi = rng.random_range(0.0..std::f64::consts::TAU);
        let (ex, ey) = (eps * phi.cos(), eps * phi.sin());
        let alpha = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
        // Reference realisation, then other speeds, viscosities and |w| for the same
        // (ex, ey, alpha): force / (mu |w|) must not change.
        let base = (157.0, 0.03, 40.0);
        let f_base = {
            let (omega, mu, rho) = base;
            film.force(&realise(ex, ey, omega, rho, alpha), &Running { omega_rad_s: omega, viscosity_pa_s: mu }).unwrap() / (mu * rho)
        };
        for (omega, mu, rho) in [(157.0, 0.03, 400.0), (20.0, 0.03, 40.0), (900.0, 0.03, 40.0), (157.0, 0.004, 40.0), (600.0, 0.1, 3.0)] {
            let f = film.force(&realise(ex, ey, omega, rho, alpha), &Running { omega_rad_s: omega, viscosity_pa_s: mu }).unwrap() / (mu * rho);
            worst = worst.max((f - f_base).norm() / f_base.norm());
        }
    }
    worst
}

#[test]
fn short_film_is_homogeneous_in_w() {
    let v = homogeneity(Kind::Short);
    println!("Short: worst relative violation of F = mu |w| f(ex, ey, alpha): {v:.2e}");
    assert!(v < 1e-12);
}

#[test]
fn finite_film_is_homogeneous_in_w() {
    let v = homogeneity(Kind::Finite);
    println!("Finite: worst relative violation of F = mu |w| f(ex, ey, alpha): {v:.2e}");
    // A tenth of the force budget: the map's error cannot come from here.
    assert!(v < FORCE_MAX / 10.0);
}

// ---------------------------------------------------------------------------------------------
// Errors over the box

#[derive(Default)]
struct Errors {
    force_max: f64,
    force_rms: f64,
    jacobian_max: f64,
    jacobian_rms: f64,
    /// How far the inner film's own Jacobian is from its secant over +-1e-3 c (and +-1e-3 c
    /// omega): the grid-scale roughness of a discrete film, which no smooth table can follow.
    roughness_max: f64,
    roughness_rms: f64,
}

/// Relative error of the stiffness and damping blocks (Frobenius), the larger of the two.
fn jacobian_error(a: &Matrix2x4<f64>, b: &Matrix2x4<f64>) -> f64 {
    let block = |m: &Matrix2x4<f64>, j: usize| m.fixed_view::<2, 2>(0, j).into_owned();
    let k = (block(a, 0) - block(b, 0)).norm() / block(b, 0).norm();
    let d = (block(a, 2) - block(b, 2)).norm() / block(b, 2).norm();
    k.max(d)
}

/// The secant Jacobian of `film` over +-1e-3 c (positions) and +-1e-3 c omega (velocities).
fn secant_jacobian(film: &mut dyn Film, st: &FilmState, r: &Running) -> Matrix2x4<f64> {
    let c = geometry().clearance_m;
    let mut j = Matrix2x4::zeros();
    for col in 0..4 {
        let h = 1e-3 * c * if col >= 2 { r.omega_rad_s } else { 1.0 };
        let (mut p, mut m) = (*st, *st);
        *component_mut(&mut p, col) += h;
        *component_mut(&mut m, col) -= h;
        // Steps of 1e-3 c stay inside the clearance for states in the box.
        j.set_column(col, &((film.force(&p, r).unwrap() - film.force(&m, r).unwrap()) / (2.0 * h)));
    }
    j
}

/// Random seeded states in the box, velocities up to `squeeze * omega * c` per axis.
fn box_errors(f: &mut Fixture, samples: usize, squeeze: f64, roughness: bool) -> Errors {
    let c = geometry().clearance_m;
    let hw = f.map.spec().half_width;
    let (cx, cy) = f.map.centre_m();
    let r = running();
    let v = squeeze * r.omega_rad_s * c;
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let fallbacks = f.map.fallbacks();
    let mut e = Errors::default();
    for _ in 0..samples {
        let st = FilmState {
            x_m: cx + rng.random_range(-hw..hw) * c,
            y_m: cy + rng.random_range(-hw..hw) * c,
            vx_m_s: rng.random_range(-v..v),
            vy_m_s: rng.random_range(-v..v),
        };
        let a = f.map.force_jacobian(&st, &r).unwrap();
        let b = f.inner.force_jacobian(&st, &r).unwrap();
        assert_eq!(a.force_n, f.map.force(&st, &r).unwrap(), "force and force_jacobian disagree");
        let ef = (a.force_n - b.force_n).norm() / b.force_n.norm();
        let ej = jacobian_error(&a.jacobian, &b.jacobian);
        e.force_max = e.force_max.max(ef);
        e.force_rms += ef * ef;
        e.jacobian_max = e.jacobian_max.max(ej);
        e.jacobian_rms += ej * ej;
        if roughness {
            let secant = secant_jacobian(f.inner.as_mut(), &st, &r);
            let er = jacobian_error(&b.jacobian, &secant);
            e.roughness_max = e.roughness_max.max(er);
            e.roughness_rms += er * er;
        }
    }
    assert_eq!(f.map.fallbacks(), fallbacks, "states in the box must not fall back");
    let n = samples as f64;
    e.force_rms = (e.force_rms / n).sqrt();
    e.jacobian_rms = (e.jacobian_rms / n).sqrt();
    e.roughness_rms = (e.roughness_rms / n).sqrt();
    e
}

/// Checks the documented bounds: force within 0.2 % (rms 0.02 %) for typical and violent
/// states; Jacobian within `jacobian_max` for typical states (3x that for violent ones), rms
/// within 1 %.
fn check_box(kind: Kind, samples: usize, jacobian_max: f64) {
    let mut f = fixture(kind);
    let roughness = kind != Kind::Short;
    for (squeeze, label) in [(0.1, "typical (|r'| <= 0.1 omega c)"), (0.5, "violent (|r'| <= 0.5 omega c)")] {
        let e = box_errors(&mut f, samples, squeeze, roughness);
        println!(
            "{kind:?}, {label}, {samples} states: force error max {:.2e} rms {:.2e}; Jacobian error max {:.2e} rms {:.2e}",
            e.force_max, e.force_rms, e.jacobian_max, e.jacobian_rms
        );
        if roughness {
            println!("    the inner film's own Jacobian vs its +-1e-3 c secant: max {:.2e} rms {:.2e}", e.roughness_max, e.roughness_rms);
        }
        assert!(e.force_max < FORCE_MAX && e.force_rms < FORCE_RMS, "{kind:?} {label}: force error over the documented bound");
        let bound = if squeeze <= 0.1 { jacobian_max } else { 3.0 * jacobian_max };
        assert!(e.jacobian_max < bound && e.jacobian_rms < JACOBIAN_MAX, "{kind:?} {label}: Jacobian error over the bound");
    }
}

#[test]
fn short_map_force_and_jacobian_match_the_film_over_the_box() {
    check_box(Kind::Short, 3000, JACOBIAN_MAX);
}

/// On the default grid the inner Jacobian itself is rough at the percent level (the film
/// ruptures node by node; printed), which sets the floor of any smooth table: the pointwise
/// bound is relaxed to 3 %; the rms stays under 1 %. The fine grid below meets 1 %.
#[test]
fn finite_map_force_and_jacobian_match_the_film_over_the_box() {
    check_box(Kind::Finite, 400, 3.0 * JACOBIAN_MAX);
}

#[test]
fn finite_fine_map_force_and_jacobian_match_the_film_over_the_box() {
    check_box(Kind::FiniteFine, 400, JACOBIAN_MAX);
}

// ---------------------------------------------------------------------------------------------
// Fallback

fn check_fallback(kind: Kind) {
    let mut f = fixture(kind);
    let Fixture { map, inner, .. } = &mut *f;
    let c = geometry().clearance_m;
    let r = running();
    let hw = map.spec().half_width;
    let (cx, cy) = map.centre_m();
    let before = map.fallbacks();
    let outside = [
        FilmState { x_m: cx + 1.2 * hw * c, y_m: cy, vx_m_s: 0.002, vy_m_s: -0.001 },
        FilmState { x_m: cx, y_m: cy - 1.01 * hw * c, vx_m_s: 0.0, vy_m_s: 0.0 },
        FilmState::at_rest(0.0, 0.0),
    ];
    for st in &outside {
        assert!(!map.covers(st.x_m, st.y_m));
        assert_eq!(map.force(st, &r).unwrap(), inner.force(st, &r).unwrap());
        assert_eq!(map.force_jacobian(st, &r).unwrap(), inner.force_jacobian(st, &r).unwrap());
    }
    assert_eq!(map.fallbacks() - before, 2 * outside.len() as u64);
    // Beyond the wall the inner film's error comes back (and counts).
    let wall = FilmState::at_rest(0.0, -1.05 * c);
    assert!(matches!(map.force(&wall, &r), Err(PhysicsError::EccentricityLimit { .. })));
    assert_eq!(map.fallbacks() - before, 2 * outside.len() as u64 + 1);
    // NaN is an error, not a fallback.
    let nan = FilmState { vx_m_s: f64::NAN, ..FilmState::at_rest(cx, cy) };
    assert!(matches!(map.force(&nan, &r), Err(PhysicsError::NonFinite { .. })));
    // Inside: no fallback.
    map.force_jacobian(&FilmState::at_rest(cx, cy), &r).unwrap();
    assert_eq!(map.fallbacks() - before, 2 * outside.len() as u64 + 1);
}

#[test]
fn short_map_falls_back_outside_the_box() {
    check_fallback(Kind::Short);
}

#[test]
fn finite_map_falls_back_outside_the_box() {
    check_fallback(Kind::Finite);
}

// ---------------------------------------------------------------------------------------------
// Equilibrium and coefficients at the Zhou point

/// Equilibrium by `operating_point::solve` on the map against the inner film's: eccentricity
/// within 1e-3, each of the eight coefficients within `coefficient_bound` (relative).
fn check_equilibrium(kind: Kind, coefficient_bound: f64) {
    let mut f = fixture(kind);
    let inner = f.inner_point;
    let before = f.map.fallbacks();
    let mapped = solve(&mut f.map, &running(), load(), &EquilibriumOptions::default()).unwrap();
    let eps_err = (mapped.eccentricity - inner.eccentricity).abs();
    println!(
        "{kind:?}: equilibrium eps inner {:.5} map {:.5} (diff {eps_err:.1e}); attitude inner {:.3} map {:.3} deg; \
         {} Newton steps fell back (started outside the box)",
        inner.eccentricity,
        mapped.eccentricity,
        inner.attitude_deg,
        mapped.attitude_deg,
        f.map.fallbacks() - before
    );
    if kind != Kind::Short {
        let st = inner.journal;
        let pointwise = f.inner.force_jacobian(&st, &running()).unwrap().jacobian;
        let secant = secant_jacobian(f.inner.as_mut(), &st, &running());
        let worst = (0..8).map(|k| ((secant[k] - pointwise[k]) / pointwise[k]).abs()).fold(0.0, f64::max);
        println!("    inner film's own coefficients vs its +-1e-3 c secant there: worst {worst:.2e}");
    }
    let xy = |k: usize| if k == 0 { 'x' } else { 'y' };
    let mut worst = 0.0f64;
    for (name, a, b) in
        [("K", inner.coefficients.stiffness_n_m, mapped.coefficients.stiffness_n_m), ("C", inner.coefficients.damping_n_s_m, mapped.coefficients.damping_n_s_m)]
    {
        for (i, j) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
            let rel = (b[(i, j)] - a[(i, j)]).abs() / a[(i, j)].abs();
            println!("    {name}{}{}: inner {:+.5e} map {:+.5e} rel diff {rel:.2e}", xy(i), xy(j), a[(i, j)], b[(i, j)]);
            worst = worst.max(rel);
        }
    }
    assert!(eps_err < 1e-3, "{kind:?}: eccentricity differs by {eps_err:.2e}");
    assert!(worst < coefficient_bound, "{kind:?}: a coefficient differs by {worst:.2e} > {coefficient_bound:e}");
}

#[test]
fn short_map_equilibrium_and_coefficients_match_at_zhou_point() {
    check_equilibrium(Kind::Short, 5e-3);
}

/// Measured 2.5e-3 on the 72 x 8 default grid. The margin is thin for a reason outside the
/// map: a discrete film's own Jacobian is a fine staircase (its rupture boundary jumps node by
/// node), 2e-3 high at this point (printed), which no smooth table follows; the map's
/// difference from it lies anywhere between zero and about twice that (see `film::map`). If a
/// change of the finite film's grid breaks this test, read the printed roughness first.
#[test]
fn finite_map_equilibrium_and_coefficients_match_at_zhou_point() {
    check_equilibrium(Kind::Finite, 5e-3);
}

#[test]
fn finite_fine_map_equilibrium_and_coefficients_match_at_zhou_point() {
    check_equilibrium(Kind::FiniteFine, 5e-3);
}

// ---------------------------------------------------------------------------------------------
// Speed (printed, not asserted: the machine is shared)

/// Mean ns per call of `force` (`jacobian == false`) or `force_jacobian` over `states`.
fn time_per_call(film: &mut dyn Film, states: &[FilmState], repeats: usize, jacobian: bool) -> f64 {
    let r = running();
    let mut sink = 0.0;
    let start = Instant::now();
    for _ in 0..repeats {
        for st in states {
            // States are in the box and valid: the calls cannot fail.
            sink += if jacobian { film.force_jacobian(st, &r).unwrap().jacobian[(0, 0)] } else { film.force(st, &r).unwrap().x };
        }
    }
    let ns = start.elapsed().as_secs_f64() * 1e9 / (repeats * states.len()) as f64;
    assert!(sink.is_finite());
    ns
}

#[test]
fn speed_of_map_and_inner_films() {
    for kind in [Kind::Short, Kind::Finite] {
        let mut f = fixture(kind);
        let c = geometry().clearance_m;
        let (cx, cy) = f.map.centre_m();
        let hw = f.map.spec().half_width;
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let v = 0.1 * running().omega_rad_s * c;
        let states: Vec<FilmState> = (0..64)
            .map(|_| FilmState {
                x_m: cx + rng.random_range(-hw..hw) * c,
                y_m: cy + rng.random_range(-hw..hw) * c,
                vx_m_s: rng.random_range(-v..v),
                vy_m_s: rng.random_range(-v..v),
            })
            .collect();
        let inner_repeats = if f.kind == Kind::Short { 200 } else { 2 };
        let inner_ns = time_per_call(f.inner.as_mut(), &states, inner_repeats, true);
        let map_ns = time_per_call(&mut f.map, &states, 2000, true);
        let map_force_ns = time_per_call(&mut f.map, &states, 2000, false);
        println!(
            "{kind:?}: force_jacobian {inner_ns:.0} ns inner, {map_ns:.0} ns map (inner / map = {:.2}); map force {map_force_ns:.0} ns; \
             a Rosenbrock step (2 forces + 1 Jacobian) spends {:.2} us in the map film; map built in {:.2} s",
            inner_ns / map_ns,
            (2.0 * map_force_ns + map_ns) * 1e-3,
            f.build_s
        );
    }
}
