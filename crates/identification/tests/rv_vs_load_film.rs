//! Film-level check of the paper's claim that the relative variation RV(d) (Zhou et al. 2004,
//! eq. 11) grows faster with the excitation amplitude d at the large load parameter (F_Y 1.3,
//! Fig. 10) than at the small one (F_Y 0.35, Fig. 9).
//!
//! No rig, no noise, no identification pipeline: the rig file's own finite-difference Reynolds
//! film (72 x 8 per pad, untabulated) is driven along prescribed two-tone orbits of maximum
//! radius `d c` around the journal's mean position, the film force is sampled over one common
//! period of the two tones, and the eight linear coefficients are fitted to it by least
//! squares, as the paper's eq. 6 does. The mean position is the one where the orbit-averaged
//! film force still carries the static load (the bellows hold the static load, not the
//! position). Coefficients at six d from 0.005 to 0.12 are fitted with the campaign's eq. 10
//! (`KD(d) = a d^3 + b d^2 + d0`) and RV taken from the fit, as the campaign does.
//!
//! Two orbit shapes:
//! * the one the campaign's two-tone force excitation produces (exciters at 45 and 135 deg,
//!   0.4 and 0.64 times the running frequency, the housing's linear response);
//! * equal straight lines along 45 and 135 deg at the same two frequencies (the shape a
//!   displacement-controlled test would impose), to show that the finding does not hinge
//!   on the orbit shape.
//!
//! What it establishes (docs/findings/rv-vs-load.md has the tables): on this film RV is
//! smaller at F_Y 1.3 than at 0.35 at the same d, for both shapes, and it stays far below the
//! paper's magnitudes. The force-driven orbit at high load runs almost across the line of
//! centres, where the film's nonlinearity is weakest.

use std::f64::consts::PI;

use nalgebra::{Complex, DMatrix, DVector, Matrix2, Vector2};
use oilfilm_identification::campaign::{fit_cubic_no_linear, load_for, relative_variation, AmplitudeStudyConfig, RecordSettings, COEFFICIENT_NAMES};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::film::{FilmState, Running};
use oilfilm_physics::operating_point::{self, EquilibriumOptions};

/// Samples over one common period of the two tones (0.4 and 0.64 x running: 12.5 revolutions).
const SAMPLES: usize = 96;
/// Amplitudes the coefficients are fitted at.
const D_GRID: [f64; 6] = [0.005, 0.028, 0.051, 0.074, 0.097, 0.12];

#[derive(Clone, Copy, PartialEq)]
enum Shape {
    /// The housing's linear response to the campaign's two-tone force excitation.
    ForceDriven,
    /// Equal lines along 45 and 135 deg.
    Lines,
}

struct Point {
    label: String,
    eccentricity: f64,
    /// RV per coefficient (campaign order) at each of `at`.
    rv: Vec<[f64; 8]>,
    /// rms excursion along the line of centres over the total rms excursion.
    radial_fraction: f64,
    /// Mean-position shift at the largest d, in units of c.
    shift: f64,
}

fn study(rig: &RigConfig, load_parameter: f64, speed_rpm: f64, shape: Shape, at: &[f64]) -> Point {
    let c = rig.bearing.clearance_m;
    let temperature_c = rig.operating.bearing_temperature_c;
    let mu = rig.oil.viscosity_pa_s(temperature_c).expect("viscosity");
    let load = load_for(rig, load_parameter, speed_rpm, temperature_c).expect("load");
    let running = Running::from_rpm(speed_rpm, mu);
    let mut film = rig.film().expect("film");
    let op = operating_point::solve(film.as_mut(), &running, Vector2::new(0.0, -load), &EquilibriumOptions::default()).expect("equilibrium");
    let k = op.coefficients.stiffness_n_m;
    let damping = op.coefficients.damping_n_s_m;
    let equilibrium = Vector2::new(op.journal.x_m, op.journal.y_m);
    let film_load = Vector2::new(0.0, load);

    let ratios = RecordSettings::default().frequency_ratios;
    let running_hz = speed_rpm / 60.0;
    let freqs = [ratios[0] * running_hz, ratios[1] * running_hz];
    // Phasors of r for each tone.
    let phasors: [Vector2<Complex<f64>>; 2] = std::array::from_fn(|j| {
        let angle = rig.housing.exciter_angles_deg[j].to_radians();
        match shape {
            Shape::ForceDriven => {
                let w = 2.0 * PI * freqs[j];
                let m = rig.housing.mass_kg;
                let dynamic: Matrix2<Complex<f64>> =
                    Matrix2::from_fn(|r, col| Complex::new(k[(r, col)] - if r == col { w * w * m } else { 0.0 }, w * damping[(r, col)]));
                let x = dynamic.try_inverse().expect("invertible") * Vector2::new(Complex::new(0.0, -angle.cos()), Complex::new(0.0, -angle.sin()));
                -x
            }
            Shape::Lines => Vector2::new(Complex::new(angle.cos(), 0.0), Complex::new(angle.sin(), 0.0)),
        }
    });
    // The two tones share the period 1 / gcd(f1, f2).
    let period = 1.0 / (0.08 * running_hz);
    assert!(
        ((ratios[0] / 0.08).round() - ratios[0] / 0.08).abs() < 1e-9 && ((ratios[1] / 0.08).round() - ratios[1] / 0.08).abs() < 1e-9,
        "the test assumes the campaign's ratios 0.4 and 0.64"
    );
    let sample = |t: f64| -> [f64; 4] {
        let mut out = [0.0; 4];
        for (j, p) in phasors.iter().enumerate() {
            let w = 2.0 * PI * freqs[j];
            let e = Complex::from_polar(1.0, w * t);
            let iw = Complex::new(0.0, w);
            out[0] += (p[0] * e).re;
            out[1] += (p[1] * e).re;
            out[2] += (p[0] * e * iw).re;
            out[3] += (p[1] * e * iw).re;
        }
        out
    };
    let fine: Vec<[f64; 4]> = (0..8192).map(|i| sample(period * i as f64 / 8192.0)).collect();
    let peak = fine.iter().map(|r| r[0].hypot(r[1])).fold(0.0, f64::max);
    let centres = op.journal.y_m.atan2(op.journal.x_m);
    let (cr, sr) = (centres.cos(), centres.sin());
    let radial_ms = fine.iter().map(|r| (r[0] * cr + r[1] * sr).powi(2)).sum::<f64>();
    let total_ms = fine.iter().map(|r| r[0] * r[0] + r[1] * r[1]).sum::<f64>();
    let orbit: Vec<[f64; 4]> = (0..SAMPLES).map(|i| sample(period * i as f64 / SAMPLES as f64)).collect();
    let k_inverse = k.try_inverse().expect("invertible stiffness");

    let mut shift = 0.0;
    let mut fitted = Vec::new();
    for &d in &D_GRID {
        let s = d * c / peak;
        let mut mean = equilibrium;
        let mut forces = vec![Vector2::zeros(); SAMPLES];
        // Move the mean position until the orbit-averaged film force carries the static load.
        for iteration in 0..5 {
            let mut average = Vector2::zeros();
            for (f, r) in forces.iter_mut().zip(&orbit) {
                let state = FilmState { x_m: mean[0] + s * r[0], y_m: mean[1] + s * r[1], vx_m_s: s * r[2], vy_m_s: s * r[3] };
                *f = film.force(&state, &running).expect("film force");
                average += *f;
            }
            average /= SAMPLES as f64;
            if iteration == 4 {
                assert!((average - film_load).norm() < 1e-4 * load, "static balance not reached: {average} vs {film_load}");
                break;
            }
            mean += k_inverse * (average - film_load);
        }
        shift = (mean - equilibrium).norm() / c;
        // Eq. 6: least squares of the dynamic force on displacement and velocity.
        let mut a = DMatrix::<f64>::zeros(SAMPLES, 4);
        let mut fx = DVector::<f64>::zeros(SAMPLES);
        let mut fy = DVector::<f64>::zeros(SAMPLES);
        for (i, (r, f)) in orbit.iter().zip(&forces).enumerate() {
            for (col, v) in r.iter().enumerate() {
                a[(i, col)] = s * v;
            }
            fx[i] = f[0];
            fy[i] = f[1];
        }
        for col in 0..4 {
            let m = a.column(col).mean();
            a.column_mut(col).add_scalar_mut(-m);
        }
        let (mx, my) = (fx.mean(), fy.mean());
        fx.add_scalar_mut(-mx);
        fy.add_scalar_mut(-my);
        let svd = a.svd(true, true);
        let bx = svd.solve(&fx, 0.0).expect("least squares");
        let by = svd.solve(&fy, 0.0).expect("least squares");
        // dF = -(K r + C r'), rows = force component.
        fitted.push([-bx[0], -bx[1], -by[0], -by[1], -bx[2], -bx[3], -by[2], -by[3]]);
    }
    let fits: Vec<_> = (0..8)
        .map(|k| {
            let y: Vec<f64> = fitted.iter().map(|v| v[k]).collect();
            fit_cubic_no_linear(&D_GRID, &y).expect("eq. 10 fit")
        })
        .collect();
    let rv = at.iter().map(|&d| std::array::from_fn(|k| relative_variation(&fits[k], d).expect("RV"))).collect();
    Point { label: format!("F_Y {load_parameter}"), eccentricity: op.eccentricity, rv, radial_fraction: (radial_ms / total_ms).sqrt(), shift }
}

fn mean_abs(v: &[f64; 8]) -> f64 {
    v.iter().map(|x| x.abs()).sum::<f64>() / 8.0
}

fn print(p: &Point, at: &[f64]) {
    println!(
        "{} (eccentricity {:.3}): radial rms fraction of the orbit {:.2}, mean shift at d 0.12 {:.4} c",
        p.label, p.eccentricity, p.radial_fraction, p.shift
    );
    println!("  {:>5} {}", "d", COEFFICIENT_NAMES.iter().map(|n| format!("{n:>8}")).collect::<String>());
    for (d, rv) in at.iter().zip(&p.rv) {
        println!("  {d:>5.2} {} | mean |RV| {:.2} %", rv.iter().map(|x| format!("{:>+7.2}%", 100.0 * x)).collect::<String>(), 100.0 * mean_abs(rv));
    }
}

#[test]
fn film_rv_is_smaller_at_the_high_load_parameter_for_force_driven_and_line_orbits() {
    let rig = RigConfig::zhou2004().expect("built-in rig");
    // The campaign's two operating points.
    let cfg = AmplitudeStudyConfig::default();
    let at = [0.05, 0.12];
    for shape in [Shape::ForceDriven, Shape::Lines] {
        let low = study(&rig, cfg.low.load_parameter, cfg.low.speed_rpm, shape, &at);
        let high = study(&rig, cfg.high.load_parameter, cfg.high.speed_rpm, shape, &at);
        println!("{} orbit", if shape == Shape::ForceDriven { "force-driven (campaign)" } else { "45/135 deg lines" });
        print(&low, &at);
        print(&high, &at);
        assert!(low.eccentricity < 0.35 && high.eccentricity > 0.55, "operating points moved: {} {}", low.eccentricity, high.eccentricity);
        for p in [&low, &high] {
            // RV grows with d, quadratically at first: at 0.12 well over twice its value at 0.05.
            assert!(mean_abs(&p.rv[1]) > 2.5 * mean_abs(&p.rv[0]), "{}: {:?}", p.label, p.rv);
        }
        // The paper's claim fails at both d: the high load parameter varies clearly less.
        for (i, d) in at.iter().enumerate() {
            let (l, h) = (mean_abs(&low.rv[i]), mean_abs(&high.rv[i]));
            assert!(h < 0.75 * l, "d {d}: mean |RV| {h} at F_Y 1.3 vs {l} at F_Y 0.35");
        }
        // Coefficient by coefficient at d = 0.12: smaller at F_Y 1.3 for at least five of eight.
        let smaller = (0..8).filter(|&k| high.rv[1][k].abs() < low.rv[1][k].abs()).count();
        assert!(smaller >= 5, "only {smaller} of 8 smaller at F_Y 1.3");
        match shape {
            Shape::ForceDriven => {
                // Far from the paper's magnitudes (over 20 % for the stiffness terms at F_Y 1.3
                // and d = 0.05): this film's RV stays within 5 % at d = 0.05 and 10 % at 0.12.
                for p in [&low, &high] {
                    assert!(p.rv[0].iter().all(|x| x.abs() < 0.05) && p.rv[1].iter().all(|x| x.abs() < 0.10), "{}: {:?}", p.label, p.rv);
                }
                // Why: the exciters drive the journal mostly across the line of centres, and
                // the more so the stiffer (more loaded) the film.
                assert!(
                    high.radial_fraction < 0.75 * low.radial_fraction && low.radial_fraction < 0.7,
                    "radial fractions {} {}",
                    low.radial_fraction,
                    high.radial_fraction
                );
                // The static load, held by the bellows, moves the mean position by O(d^2).
                assert!(low.shift > 1e-3 && low.shift < 0.01 && high.shift > 1e-3 && high.shift < 0.01, "shifts {} {}", low.shift, high.shift);
            }
            Shape::Lines => {
                // Equal-amplitude lines put more of the orbit along the line of centres: RV is
                // larger than for the force-driven orbit, but still smaller at F_Y 1.3.
                assert!(mean_abs(&low.rv[1]) > 0.08, "{:?}", low.rv);
            }
        }
    }
}
