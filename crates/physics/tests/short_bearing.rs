//! The short-bearing (Ocvirk) pi-film: published example, closed form vs nonlinear film,
//! analytic Jacobian, homogeneity, added mass and robustness.

use std::f64::consts::PI;

use nalgebra::{Matrix2, Vector2};
use oilfilm_physics::film::short::{linear_point, ShortBearing};
use oilfilm_physics::film::{component_mut, Film, FilmState, Running};
use oilfilm_physics::geometry::{BearingGeometry, BearingKind};
use oilfilm_physics::operating_point::{solve, EquilibriumOptions};
use oilfilm_physics::PhysicsError;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Friswell, Penny, Garvey & Lees (2010), example 5.5.1.
fn friswell_geometry() -> BearingGeometry {
    BearingGeometry { diameter_m: 0.1, length_m: 0.03, clearance_m: 0.1e-3, kind: BearingKind::Plain }
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

/// Load (N) the short bearing carries at eccentricity `eps`, from Ocvirk's Sommerfeld number
/// S (L/D)^2 = (1-eps^2)^2 / (pi eps sqrt(pi^2 (1-eps^2) + 16 eps^2)), written independently
/// of the library.
fn ocvirk_load(g: &BearingGeometry, run: &Running, eps: f64) -> f64 {
    let s2 = 1.0 - eps * eps;
    let s_ld2 = s2 * s2 / (PI * eps * (PI * PI * s2 + 16.0 * eps * eps).sqrt());
    let sommerfeld = s_ld2 / g.slenderness().powi(2);
    let n = run.omega_rad_s / (2.0 * PI);
    run.viscosity_pa_s * n * g.length_m * g.diameter_m * (g.radius_m() / g.clearance_m).powi(2) / sommerfeld
}

#[test]
fn friswell_example_5_5_1() {
    let g = friswell_geometry();
    let run = Running::from_rpm(1500.0, 0.1);
    let point = linear_point(&g, &run, 525.0).expect("the example is a valid operating point");
    let k = point.coefficients.stiffness_n_m / 1e6;
    let c = point.coefficients.damping_n_s_m / 1e3;
    let k_expected = Matrix2::new(12.81, 16.39, -25.06, 8.815);
    let c_expected = Matrix2::new(232.9, -81.92, -81.92, 294.9);

    println!("Friswell et al. (2010) example 5.5.1, crate frame (x horizontal, y up, load along -y)");
    println!("eccentricity {:.5} (expected 0.2663), attitude {:.3} deg, Sommerfeld {:.5}", point.eccentricity, point.attitude_deg, point.sommerfeld);
    println!("{:<6} {:>12} {:>12} {:>10}", "coef", "computed", "expected", "rel err");
    let names = [("xx", 0, 0), ("xy", 0, 1), ("yx", 1, 0), ("yy", 1, 1)];
    let mut worst = 0.0_f64;
    for (unit, label, got, want) in [("MN/m", "K", &k, &k_expected), ("kN s/m", "C", &c, &c_expected)] {
        for &(n, i, j) in &names {
            let e = rel(got[(i, j)], want[(i, j)]);
            worst = worst.max(e);
            println!("{:<6} {:>12.4} {:>12.4} {:>9.3}%  {unit}", format!("{label}{n}"), got[(i, j)], want[(i, j)], 100.0 * e);
        }
    }
    println!("worst relative error {:.3}%", 100.0 * worst);
    assert!((point.eccentricity - 0.2663).abs() <= 5e-4, "eccentricity {} vs 0.2663", point.eccentricity);
    assert!(worst <= 5e-3, "a coefficient is off by {:.3}% (> 0.5%)", 100.0 * worst);
    // The journal sits low and ahead of the load line: positive attitude, y below the centre.
    assert!(point.attitude_deg > 0.0 && point.attitude_deg < 90.0, "attitude {}", point.attitude_deg);
}

#[test]
fn closed_form_matches_nonlinear_equilibrium() {
    let g = friswell_geometry();
    let run = Running::from_rpm(3000.0, 0.05);
    let mut film = ShortBearing::new(g).expect("valid geometry");
    let options = EquilibriumOptions { relative_tolerance: 1e-12, max_iterations: 100, density_kg_m3: None };
    let mut worst = 0.0_f64;
    for eps in [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9] {
        let load = ocvirk_load(&g, &run, eps);
        let closed = linear_point(&g, &run, load).expect("closed form");
        let numeric = solve(&mut film, &run, Vector2::new(0.0, -load), &options).expect("Newton equilibrium");
        let mut errors: Vec<(String, f64)> = vec![
            ("eps(Ocvirk S)".into(), rel(closed.eccentricity, eps)),
            ("eps".into(), rel(closed.eccentricity, numeric.eccentricity)),
            ("attitude".into(), rel(closed.attitude_deg, numeric.attitude_deg)),
            ("sommerfeld".into(), rel(closed.sommerfeld, numeric.sommerfeld)),
        ];
        let pairs = [
            ("K", closed.coefficients.stiffness_n_m, numeric.coefficients.stiffness_n_m),
            ("C", closed.coefficients.damping_n_s_m, numeric.coefficients.damping_n_s_m),
        ];
        for (name, a, b) in pairs.iter() {
            for (label, i, j) in [("xx", 0, 0), ("xy", 0, 1), ("yx", 1, 0), ("yy", 1, 1)] {
                errors.push((format!("{name}{label}"), rel(a[(i, j)], b[(i, j)])));
            }
        }
        let (worst_name, worst_here) = errors.into_iter().fold((String::new(), 0.0_f64), |acc, e| if e.1 > acc.1 { e } else { acc });
        println!(
            "eps {eps:.1}: closed eps {:.6}, Newton eps {:.6}, attitude {:.4} vs {:.4} deg; worst rel diff {worst_here:.2e} ({worst_name})",
            closed.eccentricity, numeric.eccentricity, closed.attitude_deg, numeric.attitude_deg
        );
        worst = worst.max(worst_here);
        assert!(worst_here <= 1e-4, "at eps {eps}: {worst_name} differs by {worst_here:e} relative");
    }
    println!("worst relative difference over all eccentricities: {worst:.2e}");
}

fn random_state(rng: &mut ChaCha8Rng, c: f64, omega: f64, max_eps: f64) -> FilmState {
    let eps = max_eps * rng.random::<f64>().sqrt();
    let angle = 2.0 * PI * rng.random::<f64>();
    let v_scale = 0.5 * omega * c;
    FilmState {
        x_m: eps * c * angle.cos(),
        y_m: eps * c * angle.sin(),
        vx_m_s: v_scale * rng.random_range(-1.0..1.0),
        vy_m_s: v_scale * rng.random_range(-1.0..1.0),
    }
}

#[test]
fn analytic_jacobian_matches_central_differences() {
    let g = friswell_geometry();
    let c = g.clearance_m;
    let mut film = ShortBearing::new(g).expect("valid geometry");
    let mut rng = ChaCha8Rng::seed_from_u64(20240917);
    let mut worst = 0.0_f64;
    for trial in 0..200 {
        let run = Running { omega_rad_s: rng.random_range(20.0..600.0), viscosity_pa_s: rng.random_range(0.01..0.2) };
        let state = random_state(&mut rng, c, run.omega_rad_s, 0.9);
        let analytic = film.force_jacobian(&state, &run).expect("inside the clearance");
        let force = film.force(&state, &run).expect("inside the clearance");
        let force_err = (analytic.force_n - force).norm() / force.norm().max(1e-300);
        assert!(force_err < 1e-13, "force from force_jacobian differs from force: {force_err:e}");
        let steps = [1e-6 * c, 1e-6 * c, 1e-6 * c * run.omega_rad_s, 1e-6 * c * run.omega_rad_s];
        // Scale of each column: the force over the quantity's natural scale.
        let scale = analytic.force_n.norm() / c;
        for (j, &h) in steps.iter().enumerate() {
            let mut plus = state;
            let mut minus = state;
            *component_mut(&mut plus, j) += h;
            *component_mut(&mut minus, j) -= h;
            let fd = (film.force(&plus, &run).expect("inside") - film.force(&minus, &run).expect("inside")) / (2.0 * h);
            let col = analytic.jacobian.column(j).into_owned();
            let col_scale = if j < 2 { scale } else { scale / run.omega_rad_s };
            let err = (col - fd).norm() / (col.norm().max(fd.norm()).max(1e-3 * col_scale));
            if err > worst {
                worst = err;
            }
            if err > 1e-6 {
                println!("trial {trial} column {j}: analytic {col:?} central difference {fd:?} rel err {err:e} state {state:?} run {run:?}");
            }
            assert!(err <= 1e-6, "trial {trial}, column {j}: relative error {err:e}");
        }
    }
    println!("worst relative Jacobian error over 200 random states: {worst:.2e}");
}

#[test]
fn closed_form_force_matches_quadrature_of_the_pressure() {
    // Independent check: integrate the Ocvirk pressure, clipped at zero, numerically.
    let g = friswell_geometry();
    let c = g.clearance_m;
    let r = g.radius_m();
    let l = g.length_m;
    let mut film = ShortBearing::new(g).expect("valid geometry");
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut worst = 0.0_f64;
    for _ in 0..20 {
        let run = Running { omega_rad_s: rng.random_range(50.0..400.0), viscosity_pa_s: 0.05 };
        let s = random_state(&mut rng, c, run.omega_rad_s, 0.8);
        let mu = run.viscosity_pa_s;
        let n = 40_000;
        let dtheta = 2.0 * PI / n as f64;
        let mut f = Vector2::zeros();
        for i in 0..n {
            let th = (i as f64 + 0.5) * dtheta;
            let (sn, cs) = th.sin_cos();
            let h = c - s.x_m * cs - s.y_m * sn;
            let dh_dtheta = s.x_m * sn - s.y_m * cs;
            let dh_dt = -s.vx_m_s * cs - s.vy_m_s * sn;
            // Integral over z of p = 3 mu (z^2 - L^2/4)(omega dh/dtheta + 2 dh/dt)/h^3, clipped.
            let p_int = -mu * l.powi(3) / (2.0 * h.powi(3)) * (run.omega_rad_s * dh_dtheta + 2.0 * dh_dt);
            if p_int > 0.0 {
                f -= Vector2::new(cs, sn) * (p_int * r * dtheta);
            }
        }
        let closed = film.force(&s, &run).expect("inside");
        let err = (closed - f).norm() / f.norm();
        worst = worst.max(err);
        if err > 1e-6 {
            println!("closed {closed:?} vs quadrature {f:?}: rel err {err:e} at {s:?}");
        }
        assert!(err < 1e-6, "closed form vs quadrature: {err:e}");
    }
    println!("closed-form force vs direct quadrature: worst relative difference {worst:.2e}");
}

#[test]
fn static_forces_match_ocvirk_polar_forces() {
    // Journal at rest on the bottom (x = 0, y = -e): radial force up, tangential force along +x
    // (the direction of surface motion at the bottom), with Ocvirk's magnitudes.
    let g = friswell_geometry();
    let run = Running::from_rpm(1500.0, 0.1);
    let mut film = ShortBearing::new(g).expect("valid geometry");
    let p = run.viscosity_pa_s * g.radius_m() * g.length_m.powi(3) * run.omega_rad_s / g.clearance_m.powi(2);
    for eps in [0.05, 0.3, 0.7, 0.95] {
        let f = film.force(&FilmState::at_rest(0.0, -eps * g.clearance_m), &run).expect("inside");
        let s2: f64 = 1.0 - eps * eps;
        let radial = p * eps * eps / (s2 * s2);
        let tangential = p * PI * eps / (4.0 * s2.powf(1.5));
        println!("eps {eps}: Fx {:.6e} (Ocvirk {tangential:.6e}), Fy {:.6e} (Ocvirk {radial:.6e})", f.x, f.y);
        assert!(rel(f.x, tangential) < 1e-12, "tangential force at eps {eps}: {} vs {tangential}", f.x);
        assert!(rel(f.y, radial) < 1e-12, "radial force at eps {eps}: {} vs {radial}", f.y);
    }
}

#[test]
fn force_depends_on_velocity_only_through_w_and_is_homogeneous() {
    let g = friswell_geometry();
    let c = g.clearance_m;
    let mut film = ShortBearing::new(g).expect("valid geometry");
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let mut worst_same_w = 0.0_f64;
    let mut worst_scaled = 0.0_f64;
    for _ in 0..100 {
        let run = Running { omega_rad_s: rng.random_range(50.0..400.0), viscosity_pa_s: 0.07 };
        let s = random_state(&mut rng, c, run.omega_rad_s, 0.9);
        let f = film.force(&s, &run).expect("inside");
        // w = (omega x/c - 2 y'/c, omega y/c + 2 x'/c) in 1/s.
        let w = Vector2::new(run.omega_rad_s * s.x_m / c - 2.0 * s.vy_m_s / c, run.omega_rad_s * s.y_m / c + 2.0 * s.vx_m_s / c);

        // Same position and w with a different speed: choose the velocities that keep w.
        let omega2 = rng.random_range(0.0..800.0);
        let run2 = Running { omega_rad_s: omega2, ..run };
        let s2 = FilmState { vx_m_s: (w.y - omega2 * s.y_m / c) * c / 2.0, vy_m_s: -(w.x - omega2 * s.x_m / c) * c / 2.0, ..s };
        let f2 = film.force(&s2, &run2).expect("inside");
        let e1 = (f2 - f).norm() / f.norm();
        worst_same_w = worst_same_w.max(e1);
        assert!(e1 < 1e-10, "same w, different omega: {f:?} vs {f2:?} ({e1:e})");

        // Scale w by lambda > 0 (speed and velocities together): force scales by lambda.
        let lambda = rng.random_range(0.01..20.0);
        let run3 = Running { omega_rad_s: lambda * run.omega_rad_s, ..run };
        let s3 = FilmState { vx_m_s: lambda * s.vx_m_s, vy_m_s: lambda * s.vy_m_s, ..s };
        let f3 = film.force(&s3, &run3).expect("inside");
        let e2 = (f3 - f * lambda).norm() / (f * lambda).norm();
        worst_scaled = worst_scaled.max(e2);
        assert!(e2 < 1e-10, "force not homogeneous of degree 1 in w: lambda {lambda}, {f3:?} vs {:?} ({e2:e})", f * lambda);

        // Negative scaling is not a symmetry: the pi-film moves to the other half.
        let s4 = FilmState { vx_m_s: -s.vx_m_s, vy_m_s: -s.vy_m_s, ..s };
        let run4 = Running { omega_rad_s: -run.omega_rad_s, ..run };
        let f4 = film.force(&s4, &run4).expect("inside");
        assert!((f4 + f).norm() > 1e-6 * f.norm(), "force odd in w: the half-film did not move");
    }
    println!("same w, different speed: worst rel diff {worst_same_w:.2e}; scaled w: worst {worst_scaled:.2e}");
}

#[test]
fn degenerate_states_are_handled_without_panics() {
    let g = friswell_geometry();
    let c = g.clearance_m;
    let mut film = ShortBearing::new(g).expect("valid geometry");
    let run = Running::from_rpm(1500.0, 0.1);

    // Concentric with no squeeze: no force, and the Jacobian is the concentric one.
    let centre = FilmState::default();
    let f = film.force(&centre, &run).expect("centre");
    println!("concentric, no squeeze: force {f:?}");
    assert_eq!(f, Vector2::zeros());
    let j = film.force_jacobian(&centre, &run).expect("centre");
    let k0 = run.viscosity_pa_s * g.radius_m() * g.length_m.powi(3) * run.omega_rad_s * PI / (4.0 * c.powi(3));
    let k = j.stiffness();
    println!("concentric stiffness {k:?}, expected [[0, {k0:e}], [-{k0:e}, 0]]");
    assert!((k - Matrix2::new(0.0, k0, -k0, 0.0)).norm() < 1e-10 * k0, "concentric stiffness {k:?}");
    // The concentric stiffness is also what a tiny displacement sees (the force is linear there).
    let tiny = FilmState::at_rest(1e-9 * c, -2e-9 * c);
    let ft = film.force(&tiny, &run).expect("tiny");
    let predicted = -k * Vector2::new(tiny.x_m, tiny.y_m);
    assert!((ft - predicted).norm() < 1e-6 * predicted.norm(), "tiny displacement {ft:?} vs {predicted:?}");

    // Not spinning, not moving, off-centre: zero force, finite Jacobian.
    let still = Running { omega_rad_s: 0.0, viscosity_pa_s: 0.1 };
    let off = FilmState::at_rest(0.3 * c, 0.2 * c);
    assert_eq!(film.force(&off, &still).expect("still"), Vector2::zeros());
    let js = film.force_jacobian(&off, &still).expect("still");
    assert!(js.jacobian.iter().all(|v| v.is_finite()), "Jacobian not finite: {js:?}");

    // Half-frequency whirl: w = 0 exactly, zero force.
    let e = 0.4 * c;
    let whirl = FilmState { x_m: e, y_m: 0.0, vx_m_s: 0.0, vy_m_s: 0.5 * run.omega_rad_s * e };
    let fw = film.force(&whirl, &run).expect("whirl");
    println!("half-frequency whirl: force {fw:?}");
    assert!(fw.norm() < 1e-9, "half-frequency whirl carries no load, got {fw:?}");

    // Tiny w, tiny eccentricity, near the wall: finite.
    for s in [
        FilmState { x_m: 1e-300, y_m: 0.0, vx_m_s: 1e-300, vy_m_s: 0.0 },
        FilmState::at_rest(0.0, -(1.0 - 1e-9) * c),
        FilmState { x_m: 0.7 * c, y_m: 0.7 * c, vx_m_s: -1.0, vy_m_s: 1.0 },
        FilmState { x_m: 0.0, y_m: 0.999 * c, vx_m_s: 0.0, vy_m_s: 1e-3 },
    ] {
        let fj = film.force_jacobian(&s, &run).expect("inside the clearance");
        println!("state {s:?}: force {:?}", fj.force_n);
        assert!(fj.force_n.iter().chain(fj.jacobian.iter()).all(|v| v.is_finite()), "non-finite at {s:?}: {fj:?}");
        let m = film.added_mass(&s, &run, 870.0).expect("added mass").expect("estimate");
        assert!(m.iter().all(|v| v.is_finite()), "added mass not finite at {s:?}: {m:?}");
    }

    // On or beyond the wall, NaN: errors, not panics.
    let wall = film.force(&FilmState::at_rest(0.0, -c), &run);
    println!("at the wall: {wall:?}");
    assert!(matches!(wall, Err(PhysicsError::EccentricityLimit { .. })));
    let nan = film.force(&FilmState { x_m: f64::NAN, ..FilmState::default() }, &run);
    println!("NaN state: {nan:?}");
    assert!(matches!(nan, Err(PhysicsError::NonFinite { .. })));
    let bad_run = film.force(&off, &Running { omega_rad_s: f64::INFINITY, viscosity_pa_s: 0.1 });
    assert!(bad_run.is_err(), "infinite speed accepted");
    let negative_mu = film.force(&off, &Running { omega_rad_s: 100.0, viscosity_pa_s: -0.1 });
    println!("negative viscosity: {negative_mu:?}");
    assert!(negative_mu.is_err(), "negative viscosity accepted");
    assert!(film.added_mass(&off, &run, -1.0).is_err(), "negative density accepted");
}

#[test]
fn grooves_are_ignored_and_bad_geometry_is_rejected() {
    let plain = BearingGeometry::zhou2004();
    let grooved_film = ShortBearing::new(plain).expect("Zhou bearing");
    let plain_geometry = BearingGeometry { kind: BearingKind::Plain, ..plain };
    let mut a = grooved_film;
    let mut b = ShortBearing::new(plain_geometry).expect("plain");
    let run = Running::from_rpm(2000.0, 0.03);
    let s = FilmState { x_m: 2e-5, y_m: -5e-5, vx_m_s: 1e-3, vy_m_s: -2e-3 };
    assert_eq!(a.force(&s, &run).expect("inside"), b.force(&s, &run).expect("inside"));

    let bad = BearingGeometry { clearance_m: -1e-4, ..plain_geometry };
    let err = ShortBearing::new(bad).expect_err("negative clearance");
    println!("{err}");
    assert!(err.to_string().contains("bearing.clearance_m"), "error does not name the field: {err}");
    let err = linear_point(&plain_geometry, &run, -5.0).expect_err("negative load");
    println!("{err}");
    assert!(err.to_string().contains("load"));
    let err = linear_point(&plain_geometry, &Running { omega_rad_s: 0.0, viscosity_pa_s: 0.03 }, 100.0).expect_err("no speed");
    println!("{err}");
    // An absurd load drives the film to the wall: an error, not NaN.
    let err = linear_point(&plain_geometry, &run, 1e30).expect_err("absurd load");
    println!("{err}");
    assert!(matches!(err, PhysicsError::EccentricityLimit { .. }));
    // A tiny load: nearly concentric, attitude near 90 degrees, finite coefficients.
    let light = linear_point(&plain_geometry, &run, 1e-9).expect("tiny load");
    println!("tiny load: eps {:e}, attitude {}", light.eccentricity, light.attitude_deg);
    assert!(light.eccentricity < 1e-9 && (light.attitude_deg - 90.0).abs() < 1e-6);
}

#[test]
fn added_mass_matches_the_centred_value_and_quadrature() {
    let g = friswell_geometry();
    let c = g.clearance_m;
    let rho = 870.0;
    let mut film = ShortBearing::new(g).expect("valid geometry");
    let run = Running::from_rpm(1500.0, 0.1);

    // Centred: half of the full-film pi rho R L^3 / (12 c), isotropic.
    let m0 = film.added_mass(&FilmState::default(), &run, rho).expect("centre").expect("estimate");
    let full = PI * rho * g.radius_m() * g.length_m.powi(3) / (12.0 * c);
    println!("centred added mass {m0:?}; full film {full:.5e} kg, half {:.5e} kg", 0.5 * full);
    assert!((m0 - Matrix2::identity() * (0.5 * full)).norm() < 1e-12 * full, "centred added mass {m0:?}");

    // Eccentric: against midpoint quadrature of rho R L^3/(12 h) n n^T over the active arc,
    // the half circumference where the viscous short-bearing pressure is positive: there
    // omega dh/dtheta + 2 dh/dt = c (wx sin - wy cos) < 0, i.e. theta in [beta, beta + pi]
    // with (cos beta, sin beta) = -w/|w|.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut worst = 0.0_f64;
    for _ in 0..30 {
        let s = random_state(&mut rng, c, run.omega_rad_s, 0.9);
        let m = film.added_mass(&s, &run, rho).expect("inside").expect("estimate");
        let w = Vector2::new(run.omega_rad_s * s.x_m - 2.0 * s.vy_m_s, run.omega_rad_s * s.y_m + 2.0 * s.vx_m_s);
        let beta = (-w.y).atan2(-w.x);
        let n = 20_000;
        let dtheta = PI / n as f64;
        let mut q = Matrix2::zeros();
        for i in 0..n {
            let th = beta + (i as f64 + 0.5) * dtheta;
            let (sn, cs) = th.sin_cos();
            let h = c - s.x_m * cs - s.y_m * sn;
            let squeeze = run.omega_rad_s * (s.x_m * sn - s.y_m * cs) + 2.0 * (-s.vx_m_s * cs - s.vy_m_s * sn);
            assert!(squeeze <= 0.0, "theta {th} is not in the positive-pressure arc");
            let nv = Vector2::new(cs, sn);
            q += nv * nv.transpose() * (rho * g.radius_m() * g.length_m.powi(3) / (12.0 * h) * dtheta);
        }
        let err = (m - q).norm() / q.norm();
        worst = worst.max(err);
        assert!(err < 1e-7, "added mass {m:?} vs quadrature {q:?}: {err:e}");
        assert!((m - m.transpose()).norm() < 1e-12 * m.norm(), "added mass not symmetric");
        assert!(m[(0, 0)] > 0.0 && m.determinant() > 0.0, "added mass not positive definite: {m:?}");
    }
    println!("added mass vs midpoint quadrature: worst relative difference {worst:.2e}");

    // The equilibrium solver picks it up.
    let options = EquilibriumOptions { density_kg_m3: Some(rho), ..EquilibriumOptions::default() };
    let op = solve(&mut film, &run, Vector2::new(0.0, -525.0), &options).expect("equilibrium");
    let m_op = op.coefficients.added_mass_kg.expect("added mass estimated");
    println!("added mass at the Friswell operating point (eps {:.4}): {m_op:?} kg", op.eccentricity);
}
