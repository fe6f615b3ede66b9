//! The numeric finite-length film against the closed-form short-bearing film: as L/D -> 0 the
//! circumferential pressure flow vanishes, the Swift-Stieber film region becomes the half
//! where the film converges, and the Reynolds solution of a plain bearing tends to Ocvirk's
//! pi-film. The two models are independent code; their agreement (and its improvement as
//! L/D shrinks) validates both.

use nalgebra::Vector2;
use oilfilm_physics::film::finite::{FiniteBearing, GridSpec};
use oilfilm_physics::film::short::ShortBearing;
use oilfilm_physics::film::{Film, FilmState, Running};
use oilfilm_physics::geometry::{BearingGeometry, BearingKind};
use oilfilm_physics::operating_point::{self, EquilibriumOptions};

fn plain(slenderness: f64) -> BearingGeometry {
    BearingGeometry { diameter_m: 0.1, length_m: 0.1 * slenderness, clearance_m: 1e-4, kind: BearingKind::Plain }
}

/// Largest relative difference over eps, attitude and the 8 coefficients (each coefficient
/// relative to the norm of its matrix, so near-zero entries do not dominate).
fn coefficient_difference(slenderness: f64, eps_target: f64) -> (f64, f64, f64) {
    let g = plain(slenderness);
    let running = Running::from_rpm(3000.0, 0.02);
    let short_point_eps = |w: f64| oilfilm_physics::film::short::linear_point(&g, &running, w).unwrap().eccentricity;
    // Find the load that puts the short film at eps_target (bisection on the monotone load curve).
    let (mut lo, mut hi) = (1.0_f64, 1e7_f64);
    for _ in 0..200 {
        let mid = (lo * hi).sqrt();
        if short_point_eps(mid) < eps_target {
            lo = mid
        } else {
            hi = mid
        }
    }
    let w = (lo * hi).sqrt();
    let mut short = ShortBearing::new(g).unwrap();
    let mut finite = FiniteBearing::new(g, GridSpec { n_theta: 144, n_z: 12 }).unwrap();
    let opts = EquilibriumOptions::default();
    let a = operating_point::solve(&mut short, &running, Vector2::new(0.0, -w), &opts).unwrap();
    let b = operating_point::solve(&mut finite, &running, Vector2::new(0.0, -w), &opts).unwrap();
    let ka = a.coefficients.stiffness_n_m;
    let kb = b.coefficients.stiffness_n_m;
    let ca = a.coefficients.damping_n_s_m;
    let cb = b.coefficients.damping_n_s_m;
    let coef = ((kb - ka).abs().max() / ka.norm()).max((cb - ca).abs().max() / ca.norm());
    println!(
        "L/D {slenderness:<5} eps short {:.4} finite {:.4} | attitude short {:.2} finite {:.2} deg | worst coefficient difference {:.2} % of the matrix norm",
        a.eccentricity,
        b.eccentricity,
        a.attitude_deg,
        b.attitude_deg,
        100.0 * coef
    );
    ((a.eccentricity - b.eccentricity).abs(), (a.attitude_deg - b.attitude_deg).abs(), coef)
}

#[test]
fn finite_plain_bearing_tends_to_the_short_bearing_as_l_over_d_shrinks() {
    for eps in [0.3, 0.6] {
        let coarse = coefficient_difference(0.25, eps);
        let fine = coefficient_difference(0.1, eps);
        assert!(fine.0 < 0.005 && fine.1 < 0.5 && fine.2 < 0.01, "at L/D 0.1, eps {eps}: {fine:?}");
        assert!(fine.2 < coarse.2, "the models must converge as L/D shrinks: {coarse:?} -> {fine:?}");
    }
}

#[test]
fn finite_force_with_squeeze_matches_the_short_film_at_small_l_over_d() {
    // Random states with velocities (deterministic pseudo-random sequence).
    let g = plain(0.1);
    let running = Running::from_rpm(3000.0, 0.02);
    let mut short = ShortBearing::new(g).unwrap();
    let mut finite = FiniteBearing::new(g, GridSpec { n_theta: 144, n_z: 12 }).unwrap();
    let c = g.clearance_m;
    let mut seed = 12345u64;
    let mut next = || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    let mut worst: f64 = 0.0;
    for _ in 0..40 {
        let (e, phi) = (0.1 + 0.6 * (next() + 1.0) / 2.0, std::f64::consts::PI * next());
        let v = 0.2 * c * running.omega_rad_s;
        let s = FilmState { x_m: e * c * phi.cos(), y_m: e * c * phi.sin(), vx_m_s: v * next(), vy_m_s: v * next() };
        let fa = short.force(&s, &running).unwrap();
        let fb = finite.force(&s, &running).unwrap();
        worst = worst.max((fa - fb).norm() / fa.norm());
    }
    println!("L/D 0.1, 40 random states with squeeze: worst |F_finite - F_short| / |F_short| = {:.2} %", 100.0 * worst);
    assert!(worst < 0.04, "worst relative force difference {worst}");
}
