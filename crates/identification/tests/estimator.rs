//! Tests of the windowed least-squares estimator on synthetic records made here: a chosen
//! film (K, C, M), a multi-tone relative motion with analytic derivatives, and the film force
//! `f = -(K r + C r' + M r'') + f0`, optionally with coloured noise.

use std::f64::consts::PI;

use nalgebra::{DMatrix, Matrix2};
use oilfilm_identification::estimator::{
    estimate_window, estimate_windows, frequency_domain, Coefficients, EstimatorConfig, ModelOrder, Refusal, Signals, Solver, WindowEstimate,
};
use oilfilm_identification::IdentificationError;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

const FS: f64 = 5000.0;

#[derive(Clone, Copy)]
struct Film {
    k: Matrix2<f64>,
    c: Matrix2<f64>,
    m: Matrix2<f64>,
    f0: [f64; 2],
}

fn film(with_mass: bool) -> Film {
    Film {
        k: Matrix2::new(1.2e8, 3.0e7, -2.0e7, 2.0e8),
        c: Matrix2::new(2.0e5, 1.5e4, 1.2e4, 3.0e5),
        m: if with_mass { Matrix2::new(12.0, 1.5, -0.8, 9.0) } else { Matrix2::zeros() },
        f0: [150.0, 8000.0],
    }
}

/// (amplitude m, frequency Hz, phase rad)
type Tone = (f64, f64, f64);

const TONES_X: [Tone; 2] = [(5.0e-6, 17.0, 0.3), (3.0e-6, 43.0, 1.1)];
const TONES_Y: [Tone; 2] = [(4.0e-6, 23.0, -0.7), (2.5e-6, 37.0, 2.0)];

#[derive(Clone)]
struct Record {
    x: Vec<f64>,
    y: Vec<f64>,
    vx: Vec<f64>,
    vy: Vec<f64>,
    ax: Vec<f64>,
    ay: Vec<f64>,
    fx: Vec<f64>,
    fy: Vec<f64>,
}

impl Record {
    fn signals(&self) -> Signals<'_> {
        Signals {
            x_m: &self.x,
            y_m: &self.y,
            vx_m_s: &self.vx,
            vy_m_s: &self.vy,
            ax_m_s2: Some(&self.ax),
            ay_m_s2: Some(&self.ay),
            fx_n: &self.fx,
            fy_n: &self.fy,
        }
    }
}

/// Position, velocity, acceleration of a sum of tones at time t.
fn tones(ts: &[Tone], t: f64) -> (f64, f64, f64) {
    let (mut p, mut v, mut a) = (0.0, 0.0, 0.0);
    for &(amp, hz, ph) in ts {
        let w = 2.0 * PI * hz;
        let arg = w * t + ph;
        p += amp * arg.cos();
        v -= amp * w * arg.sin();
        a -= amp * w * w * arg.cos();
    }
    (p, v, a)
}

/// Noise-free record; the journal sits at a static offset (the intercept must absorb it).
fn record(f: &Film, tx: &[Tone], ty: &[Tone], n: usize) -> Record {
    let (x0, y0) = (-2.0e-5, -6.0e-5);
    let mut r = Record {
        x: Vec::with_capacity(n),
        y: Vec::with_capacity(n),
        vx: Vec::with_capacity(n),
        vy: Vec::with_capacity(n),
        ax: Vec::with_capacity(n),
        ay: Vec::with_capacity(n),
        fx: Vec::with_capacity(n),
        fy: Vec::with_capacity(n),
    };
    for i in 0..n {
        let t = i as f64 / FS;
        let (x, vx, ax) = tones(tx, t);
        let (y, vy, ay) = tones(ty, t);
        let d = [x, y];
        let v = [vx, vy];
        let a = [ax, ay];
        for (row, out) in [&mut r.fx, &mut r.fy].into_iter().enumerate() {
            let mut s = f.f0[row];
            for col in 0..2 {
                s -= f.k[(row, col)] * d[col] + f.c[(row, col)] * v[col] + f.m[(row, col)] * a[col];
            }
            out.push(s);
        }
        r.x.push(x0 + x);
        r.y.push(y0 + y);
        r.vx.push(vx);
        r.vy.push(vy);
        r.ax.push(ax);
        r.ay.push(ay);
    }
    r
}

fn rms_dynamic(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len() as f64).sqrt()
}

/// Add first-order IIR coloured noise (pole `pole`, unit-variance output scaled to
/// `rms(signal) * 10^(-snr_db/20)`).
fn add_coloured(v: &mut [f64], snr_db: f64, pole: f64, rng: &mut ChaCha8Rng) {
    let sd = rms_dynamic(v) * 10f64.powf(-snr_db / 20.0);
    let gain = (1.0 - pole * pole).sqrt();
    let mut state: f64 = rng.sample::<f64, _>(StandardNormal);
    for x in v.iter_mut() {
        let w: f64 = rng.sample(StandardNormal);
        state = pole * state + gain * w;
        *x += sd * state;
    }
}

fn max_abs(m: &Matrix2<f64>) -> f64 {
    m.iter().fold(0.0f64, |a, b| a.max(b.abs()))
}

fn rel_err(est: &Matrix2<f64>, truth: &Matrix2<f64>) -> f64 {
    max_abs(&(est - truth)) / max_abs(truth)
}

fn config(window: usize, hop: usize, model: ModelOrder, solver: Solver) -> EstimatorConfig {
    EstimatorConfig { window, hop, model, solver, max_condition: 1.0e6, sample_rate_hz: FS, max_relative_se: 0.25, signal_band_hz: None }
}

fn solved(w: &WindowEstimate) -> &Coefficients {
    match &w.result {
        Ok(c) => c,
        Err(r) => panic!("window {}..{} refused: {r}", w.start, w.end),
    }
}

#[test]
fn noise_free_recovery_kc_kcm_qr_svd() {
    for model in [ModelOrder::Kc, ModelOrder::Kcm] {
        let f = film(model == ModelOrder::Kcm);
        let rec = record(&f, &TONES_X, &TONES_Y, 20_000);
        for solver in [Solver::Qr, Solver::Svd] {
            let cfg = config(10_000, 10_000, model, solver);
            let ws = estimate_windows(&rec.signals(), &cfg).expect("well-formed input");
            assert_eq!(ws.len(), 2);
            for w in &ws {
                let c = solved(w);
                let ek = rel_err(&c.stiffness_n_m, &f.k);
                let ec = rel_err(&c.damping_n_s_m, &f.c);
                let em = c.added_mass_kg.map(|m| rel_err(&m, &f.m)).unwrap_or(0.0);
                println!(
                    "{model:?} {solver:?} window {}..{}: cond {:.3}, rank {}, rel err K {ek:.2e} C {ec:.2e} M {em:.2e}, lines {:?}, flags {:?}",
                    w.start, w.end, w.condition_number, w.rank, w.frequencies_hz, w.flags
                );
                assert!(ek < 1e-9 && ec < 1e-9 && em < 1e-9, "{model:?} {solver:?}: K {ek:e} C {ec:e} M {em:e}");
                assert_eq!(c.added_mass_kg.is_some(), model == ModelOrder::Kcm);
                assert_eq!(w.rank, model.regressors());
                assert!(w.condition_number < 100.0, "well-designed multi-tone should be well conditioned");
                assert!(w.residual_rms_n[0] < 1e-6 && w.residual_rms_n[1] < 1e-6);
                // The line search finds the four tones.
                assert_eq!(w.frequencies_hz.len(), 4, "{:?}", w.frequencies_hz);
                for (found, want) in w.frequencies_hz.iter().zip([17.0, 23.0, 37.0, 43.0]) {
                    assert!((found - want).abs() < 0.05, "{found} vs {want}");
                }
            }
        }
    }
}

#[test]
fn one_frequency_for_both_exciters_is_refused_with_the_reason() {
    let f = film(false);
    let tx = [(5.0e-6, 20.0, 0.0)];
    let ty = [(3.0e-6, 20.0, 1.0)];
    for noisy in [false, true] {
        let mut rec = record(&f, &tx, &ty, 10_000);
        if noisy {
            let mut rng = ChaCha8Rng::seed_from_u64(7);
            for v in [&mut rec.x, &mut rec.y, &mut rec.vx, &mut rec.vy, &mut rec.fx, &mut rec.fy] {
                add_coloured(v, 40.0, 0.8, &mut rng);
            }
        }
        let w = estimate_window(&rec.signals(), 0..10_000, &config(10_000, 10_000, ModelOrder::Kc, Solver::Qr)).unwrap();
        let refusal = w.result.clone().expect_err("one frequency cannot identify eight coefficients");
        println!("noisy={noisy}: cond {:.3e}, rank {}: {refusal}", w.condition_number, w.rank);
        match &refusal {
            Refusal::RankDeficient { rank, needed, explanation } => {
                assert_eq!((*rank, *needed), (2, 4));
                assert!(explanation.contains("span{cos, sin}"), "{explanation}");
                assert!(explanation.contains("20.0 Hz"), "{explanation}");
                assert!(explanation.contains("excite two frequencies"), "{explanation}");
            }
            other => panic!("expected RankDeficient, got {other:?}"),
        }
        assert!(refusal.to_string().contains("rank 2 of 4"));
    }
}

#[test]
fn added_mass_with_one_line_per_direction_is_refused_as_alias() {
    let f = film(true);
    let tx = [(5.0e-6, 20.0, 0.0)];
    let ty = [(3.0e-6, 31.0, 1.0)];
    let rec = record(&f, &tx, &ty, 10_000);
    let w = estimate_window(&rec.signals(), 0..10_000, &config(10_000, 10_000, ModelOrder::Kcm, Solver::Qr)).unwrap();
    println!("Kcm, one line per direction: rank {}, flags {:?}, result {:?}", w.rank, w.flags, w.result.as_ref().err());
    match &w.result {
        Err(Refusal::RankDeficient { rank, needed, explanation }) => {
            assert_eq!((*rank, *needed), (4, 6));
            assert!(explanation.contains("K - w^2 M"), "{explanation}");
        }
        other => panic!("expected RankDeficient, got {other:?}"),
    }
    assert!(w.flags.iter().any(|s| s.contains("K - w^2 M")), "{:?}", w.flags);
    // The same record is fine for the Kc model (the film has mass, so Kc sees K - w^2 M).
    let w = estimate_window(&rec.signals(), 0..10_000, &config(10_000, 10_000, ModelOrder::Kc, Solver::Qr)).unwrap();
    assert!(w.result.is_ok(), "{:?}", w.result);
    // Two lines in x but one in y: still aliased in y.
    let tx2 = [(5.0e-6, 20.0, 0.0), (2.0e-6, 45.0, 0.4)];
    let rec = record(&f, &tx2, &ty, 10_000);
    let w = estimate_window(&rec.signals(), 0..10_000, &config(10_000, 10_000, ModelOrder::Kcm, Solver::Qr)).unwrap();
    println!("Kcm, x two lines, y one: {}", w.result.as_ref().err().map(|r| r.to_string()).unwrap_or_default());
    assert!(matches!(&w.result, Err(Refusal::RankDeficient { rank: 5, needed: 6, .. })), "{:?}", w.result);
}

/// Naive OLS standard errors (white-noise assumption), formed here only for comparison.
fn naive_se(rec: &Record, coefs: &Coefficients) -> [[f64; 8]; 1] {
    let n = rec.x.len();
    let cols = [&rec.x, &rec.y, &rec.vx, &rec.vy];
    let means: Vec<f64> = cols.iter().map(|c| c.iter().sum::<f64>() / n as f64).collect();
    let a = DMatrix::from_fn(n, 4, |i, j| cols[j][i] - means[j]);
    let g = (a.transpose() * &a).try_inverse().expect("full rank");
    let mut out = [0.0; 8];
    for (k, f) in [&rec.fx, &rec.fy].iter().enumerate() {
        let fm = f.iter().sum::<f64>() / n as f64;
        let b: Vec<f64> = (0..4)
            .map(|j| {
                let m = if j < 2 { coefs.stiffness_n_m[(k, j)] } else { coefs.damping_n_s_m[(k, j - 2)] };
                -m
            })
            .collect();
        let mut sse = 0.0;
        for i in 0..n {
            let mut e = f[i] - fm;
            for j in 0..4 {
                e -= a[(i, j)] * b[j];
            }
            sse += e * e;
        }
        let s2 = sse / (n - 5) as f64;
        for j in 0..4 {
            out[k * 4 + j] = (s2 * g[(j, j)]).sqrt();
        }
    }
    [out]
}

#[test]
fn coverage_of_hac_intervals_under_coloured_noise() {
    let f = film(false);
    let n: usize = std::env::var("COVERAGE_N").ok().and_then(|v| v.parse().ok()).unwrap_or(5_000);
    let clean = record(&f, &TONES_X, &TONES_Y, n);
    let repeats: usize = std::env::var("COVERAGE_REPEATS").ok().and_then(|v| v.parse().ok()).unwrap_or(400);
    let seed0: u64 = std::env::var("COVERAGE_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(1000);
    let names = ["kxx", "kxy", "kyx", "kyy", "dxx", "dxy", "dyx", "dyy"];
    let truth = [f.k[(0, 0)], f.k[(0, 1)], f.k[(1, 0)], f.k[(1, 1)], f.c[(0, 0)], f.c[(0, 1)], f.c[(1, 0)], f.c[(1, 1)]];
    let mut est = vec![[0.0; 8]; repeats];
    let mut se = vec![[0.0; 8]; repeats];
    let mut naive_cover = [0usize; 8];
    let cfg = config(n, n, ModelOrder::Kc, Solver::Qr);
    for r in 0..repeats {
        let mut rng = ChaCha8Rng::seed_from_u64(seed0 + r as u64);
        let mut rec = clean.clone();
        // ~40 dB SNR on force, displacement and velocity; first-order IIR colour (pole 0.8).
        for v in [&mut rec.x, &mut rec.y, &mut rec.vx, &mut rec.vy, &mut rec.fx, &mut rec.fy] {
            add_coloured(v, 40.0, 0.8, &mut rng);
        }
        let w = estimate_window(&rec.signals(), 0..n, &cfg).unwrap();
        if r == 0 {
            println!("repeat 0: cond {:.3}, lines {:?}, flags {:?}", w.condition_number, w.frequencies_hz, w.flags);
        }
        let c = solved(&w).clone();
        est[r] = [
            c.stiffness_n_m[(0, 0)],
            c.stiffness_n_m[(0, 1)],
            c.stiffness_n_m[(1, 0)],
            c.stiffness_n_m[(1, 1)],
            c.damping_n_s_m[(0, 0)],
            c.damping_n_s_m[(0, 1)],
            c.damping_n_s_m[(1, 0)],
            c.damping_n_s_m[(1, 1)],
        ];
        se[r] = [
            c.stiffness_se[(0, 0)],
            c.stiffness_se[(0, 1)],
            c.stiffness_se[(1, 0)],
            c.stiffness_se[(1, 1)],
            c.damping_se[(0, 0)],
            c.damping_se[(0, 1)],
            c.damping_se[(1, 0)],
            c.damping_se[(1, 1)],
        ];
        // Naive white-noise errors, same estimate (order: fx row kxx kxy dxx dxy, fy row ...).
        let [nv] = naive_se(&rec, &c);
        let naive = [nv[0], nv[1], nv[4], nv[5], nv[2], nv[3], nv[6], nv[7]];
        for j in 0..8 {
            if (est[r][j] - truth[j]).abs() <= 1.96 * naive[j] {
                naive_cover[j] += 1;
            }
        }
    }
    println!("coverage of ±1.96 SE over {repeats} seeded repeats (n = {n}, 40 dB, IIR pole 0.8 on x y x' y' fx fy)");
    println!(
        "{:>4} {:>12} {:>12} {:>10} {:>10} {:>10} {:>9} {:>9} {:>9}",
        "coef", "truth", "mean est", "mean SE", "emp. SD", "bias/SE", "SE/SD", "HAC cov", "OLS cov"
    );
    for j in 0..8 {
        let mean = est.iter().map(|e| e[j]).sum::<f64>() / repeats as f64;
        let sd = (est.iter().map(|e| (e[j] - mean).powi(2)).sum::<f64>() / (repeats - 1) as f64).sqrt();
        let mse = se.iter().map(|s| s[j]).sum::<f64>() / repeats as f64;
        let cover = (0..repeats).filter(|&r| (est[r][j] - truth[j]).abs() <= 1.96 * se[r][j]).count() as f64 / repeats as f64;
        let naive = naive_cover[j] as f64 / repeats as f64;
        let bias = (mean - truth[j]) / mse;
        println!(
            "{:>4} {:>12.5e} {:>12.5e} {:>10.3e} {:>10.3e} {:>10.3} {:>9.3} {:>9.3} {:>9.3}",
            names[j],
            truth[j],
            mean,
            mse,
            sd,
            bias,
            mse / sd,
            cover,
            naive
        );
        assert!((0.90..=0.99).contains(&cover), "{}: coverage {cover}", names[j]);
        assert!(bias.abs() < 0.5, "{}: mean bias {bias} SE", names[j]);
    }
}

/// A nearly straight-line orbit: y follows x to within `eps` (both exciters almost in phase).
fn straight_orbit(eps: f64, n: usize) -> (Film, Record) {
    let f = film(false);
    let mut rec = record(&f, &TONES_X, &TONES_X, n);
    // y = x + eps * 5 µm sin(2π 17 t + 0.3), so x, y, x', y' are dependent up to eps.
    let w = 2.0 * PI * 17.0;
    for i in 0..n {
        let t = i as f64 / FS;
        let dy = eps * 5.0e-6 * (w * t + 0.3).sin();
        let dvy = eps * 5.0e-6 * w * (w * t + 0.3).cos();
        let day = -eps * 5.0e-6 * w * w * (w * t + 0.3).sin();
        rec.y[i] += dy - 4.0e-5; // and a different static offset than x
        rec.vy[i] += dvy;
        rec.ay[i] += day;
        rec.fx[i] -= f.k[(0, 1)] * dy + f.c[(0, 1)] * dvy;
        rec.fy[i] -= f.k[(1, 1)] * dy + f.c[(1, 1)] * dvy;
    }
    (f, rec)
}

#[test]
fn normal_equations_lose_digits_that_qr_keeps() {
    let n = 10_000;
    println!("{:>8} {:>12} {:>12} {:>12} {:>12}", "eps", "cond(A_s)", "cond(N_s)", "QR rel err", "NE rel err");
    let mut worst_ratio = f64::INFINITY;
    for eps in [1e-2, 1e-3, 1e-4, 1e-5] {
        let (f, rec) = straight_orbit(eps, n);
        let mut cfg = config(n, n, ModelOrder::Kc, Solver::Qr);
        cfg.max_condition = 1e12;
        let qr = estimate_window(&rec.signals(), 0..n, &cfg).unwrap();
        cfg.solver = Solver::NormalEquations;
        let ne = estimate_window(&rec.signals(), 0..n, &cfg).unwrap();
        let err = |w: &WindowEstimate| {
            let c = solved(w);
            rel_err(&c.stiffness_n_m, &f.k).max(rel_err(&c.damping_n_s_m, &f.c))
        };
        let (eq, en) = (err(&qr), err(&ne));
        println!("{eps:>8.0e} {:>12.3e} {:>12.3e} {eq:>12.3e} {en:>12.3e}", qr.condition_number, ne.condition_number);
        // The paper's normal matrix has the squared condition number.
        let sq = qr.condition_number * qr.condition_number;
        assert!((ne.condition_number / sq - 1.0).abs() < 0.05 || ne.condition_number > 1e14, "{} vs {sq}", ne.condition_number);
        assert!(ne.flags.iter().any(|s| s.contains("normal equations")), "{:?}", ne.flags);
        if eps <= 1e-4 {
            worst_ratio = worst_ratio.min(en / eq.max(f64::MIN_POSITIVE));
        }
    }
    assert!(worst_ratio > 100.0, "QR should beat the normal equations by >100x on a near-straight orbit, got {worst_ratio}");
    // With the default limit the QR path refuses the worst case and says why.
    let (_, rec) = straight_orbit(1e-7, n);
    let w = estimate_window(&rec.signals(), 0..n, &config(n, n, ModelOrder::Kc, Solver::Qr)).unwrap();
    println!("eps 1e-7 with default limit: {}", w.result.as_ref().err().map(|r| r.to_string()).unwrap_or_default());
    match &w.result {
        Err(Refusal::IllConditioned { condition, explanation, .. }) => {
            assert!(*condition > 1e6);
            assert!(explanation.contains("straight line"), "{explanation}");
        }
        other => panic!("expected IllConditioned, got {other:?}"),
    }
}

#[test]
fn frequency_domain_agrees_with_time_domain_on_noise_free_multitone() {
    let lines = [17.0, 23.0, 37.0, 43.0];
    for model in [ModelOrder::Kc, ModelOrder::Kcm] {
        let f = film(model == ModelOrder::Kcm);
        let n = 10_000;
        let rec = record(&f, &TONES_X, &TONES_Y, n);
        let td = estimate_window(&rec.signals(), 0..n, &config(n, n, model, Solver::Qr)).unwrap();
        let fd = frequency_domain(&rec.signals(), &lines, FS, model).unwrap();
        let (t, q) = (solved(&td), fd.result.as_ref().expect("four lines, two per direction"));
        let dk = rel_err(&q.stiffness_n_m, &t.stiffness_n_m);
        let dc = rel_err(&q.damping_n_s_m, &t.damping_n_s_m);
        let dm = match (q.added_mass_kg, t.added_mass_kg) {
            (Some(a), Some(b)) => rel_err(&a, &b),
            _ => 0.0,
        };
        println!("{model:?}: frequency vs time domain: K {dk:.2e}, C {dc:.2e}, M {dm:.2e}; cond {:.2}", fd.condition_number);
        for l in &fd.lines {
            println!(
                "  {:5.1} Hz {:?}: |X| {:.3e} |Y| {:.3e} H_direct {:.4e}{:+.4e}i",
                l.frequency_hz,
                l.excited,
                l.x_m.norm(),
                l.y_m.norm(),
                l.direct_dynamic_stiffness_n_m.re,
                l.direct_dynamic_stiffness_n_m.im
            );
        }
        assert!(dk < 1e-6 && dc < 1e-6 && dm < 1e-6);
        // Line by line: an x-only line shows column x of H = K - w^2 M + i w C.
        let l17 = &fd.lines[0];
        let w = 2.0 * PI * 17.0;
        let col = l17.column_n_m.expect("17 Hz moves x only");
        let want = f.k[(0, 0)] - w * w * f.m[(0, 0)];
        assert!((col[0].re - want).abs() < 1e-6 * want.abs(), "{} vs {want}", col[0].re);
        assert!((col[0].im - w * f.c[(0, 0)]).abs() < 1e-6 * w * f.c[(0, 0)]);
        assert!((col[1].re - (f.k[(1, 0)] - w * w * f.m[(1, 0)])).abs() < 1e-6 * f.k[(1, 0)].abs());
    }
    // One line cannot give the added mass in the frequency domain either.
    let f = film(true);
    let rec = record(&f, &TONES_X, &TONES_Y, 10_000);
    let fd = frequency_domain(&rec.signals(), &[17.0, 23.0], FS, ModelOrder::Kcm).unwrap();
    println!("Kcm from two lines: {}", fd.result.as_ref().err().map(|r| r.to_string()).unwrap_or_default());
    assert!(matches!(fd.result, Err(Refusal::RankDeficient { .. })));
    assert!(frequency_domain(&rec.signals(), &[-3.0], FS, ModelOrder::Kc).is_err());
    assert!(frequency_domain(&rec.signals(), &[17.0, 17.0], FS, ModelOrder::Kc).is_err());
}

#[test]
fn bad_input_gives_clear_errors_and_never_panics() {
    let f = film(false);
    let rec = record(&f, &TONES_X, &TONES_Y, 12_000);
    let cfg = config(4_000, 4_000, ModelOrder::Kc, Solver::Qr);

    // Length mismatch names the column.
    let short = &rec.fy[..11_999];
    let mut s = rec.signals();
    s.fy_n = short;
    match estimate_windows(&s, &cfg) {
        Err(IdentificationError::BadInput { what, reason }) => {
            println!("length mismatch: {what}: {reason}");
            assert_eq!(what, "fy_n");
        }
        other => panic!("expected BadInput, got {other:?}"),
    }

    // NaN: only the window containing it is refused, naming column and index.
    let mut bad = rec.clone();
    bad.vy[5_123] = f64::NAN;
    bad.fx[5_500] = f64::INFINITY;
    let ws = estimate_windows(&bad.signals(), &cfg).unwrap();
    assert_eq!(ws.len(), 3);
    assert!(ws[0].result.is_ok() && ws[2].result.is_ok());
    let r = ws[1].result.clone().unwrap_err();
    println!("NaN: {r}");
    assert_eq!(r, Refusal::NonFinite { column: "vy_m_s".to_string(), index: 5_123 });
    assert!(r.to_string().contains("vy_m_s") && r.to_string().contains("5123"));

    // Window longer than the record; hop 0; bad numbers in the config.
    let e = estimate_windows(&rec.signals(), &config(20_000, 20_000, ModelOrder::Kc, Solver::Qr)).unwrap_err();
    println!("window > record: {e}");
    assert!(matches!(&e, IdentificationError::InvalidParameter { field, .. } if field == "window"));
    let e = estimate_windows(&rec.signals(), &config(4_000, 0, ModelOrder::Kc, Solver::Qr)).unwrap_err();
    println!("hop = 0: {e}");
    assert!(matches!(&e, IdentificationError::InvalidParameter { field, .. } if field == "hop"));
    let mut c = cfg.clone();
    c.max_condition = f64::NAN;
    assert!(matches!(c.validate(), Err(IdentificationError::InvalidParameter { field, .. }) if field == "max_condition"));
    let mut c = cfg.clone();
    c.sample_rate_hz = 0.0;
    assert!(matches!(c.validate(), Err(IdentificationError::InvalidParameter { field, .. }) if field == "sample_rate_hz"));
    let mut c = cfg.clone();
    c.window = 0;
    assert!(matches!(c.validate(), Err(IdentificationError::InvalidParameter { field, .. }) if field == "window"));

    // Absurd sizes: the largest hop gives one window; a hop (or window) beyond the largest a
    // config takes is refused by name before anything is allocated.
    let ws = estimate_windows(&rec.signals(), &config(4_000, oilfilm_identification::estimator::MAX_WINDOW_SAMPLES, ModelOrder::Kc, Solver::Qr)).unwrap();
    assert_eq!(ws.len(), 1);
    let e = estimate_windows(&rec.signals(), &config(4_000, usize::MAX, ModelOrder::Kc, Solver::Qr)).unwrap_err();
    assert!(matches!(&e, IdentificationError::InvalidParameter { field, .. } if field == "hop"), "{e}");

    // Kcm without accelerations.
    let mut s = rec.signals();
    s.ax_m_s2 = None;
    let e = estimate_windows(&s, &config(4_000, 4_000, ModelOrder::Kcm, Solver::Qr)).unwrap_err();
    println!("Kcm without accelerations: {e}");
    assert!(matches!(&e, IdentificationError::BadInput { what, .. } if what == "ax_m_s2"));

    // Too short a range, an empty range, an empty record.
    let w = estimate_window(&rec.signals(), 100..150, &cfg).unwrap();
    println!("short window: {}", w.result.as_ref().unwrap_err());
    assert_eq!(w.result, Err(Refusal::TooShort { samples: 50, needed: 80 }));
    assert!(estimate_window(&rec.signals(), 10..10, &cfg).is_err());
    assert!(estimate_window(&rec.signals(), 0..12_001, &cfg).is_err());
    let empty: [f64; 0] = [];
    let es = Signals { x_m: &empty, y_m: &empty, vx_m_s: &empty, vy_m_s: &empty, ax_m_s2: None, ay_m_s2: None, fx_n: &empty, fy_n: &empty };
    assert!(estimate_windows(&es, &cfg).is_err());

    // A dead y probe (constant y, zero y') is refused and named.
    let mut dead = rec.clone();
    dead.y.iter_mut().for_each(|v| *v = -6.0e-5);
    dead.vy.iter_mut().for_each(|v| *v = 0.0);
    let w = estimate_window(&dead.signals(), 0..4_000, &cfg).unwrap();
    println!("dead y probe: {}", w.result.as_ref().unwrap_err());
    assert!(matches!(&w.result, Err(Refusal::RankDeficient { explanation, .. }) if explanation.contains("y, y' do not vary")));

    // Absurd magnitudes do not panic.
    let mut huge = rec.clone();
    huge.fx.iter_mut().for_each(|v| *v *= 1e300);
    let ws = estimate_windows(&huge.signals(), &cfg).unwrap();
    println!("absurd forces: {:?}", ws[0].result.as_ref().err().map(|r| r.to_string()));

    // Config files: every field named, unknown fields rejected, hop required.
    let ok: EstimatorConfig = serde_json::from_str(r#"{"window": 1000, "hop": 100}"#).unwrap();
    assert_eq!((ok.model, ok.solver, ok.sample_rate_hz), (ModelOrder::Kc, Solver::Qr, 5000.0));
    let ok: EstimatorConfig = toml::from_str("window = 1000\nhop = 500\nmodel = \"kcm\"\nsolver = \"normal_equations\"\n").unwrap();
    assert_eq!((ok.model, ok.solver), (ModelOrder::Kcm, Solver::NormalEquations));
    assert!(serde_json::from_str::<EstimatorConfig>(r#"{"window": 1000, "hop": 100, "windw": 3}"#).is_err());
    assert!(serde_json::from_str::<EstimatorConfig>(r#"{"window": 1000}"#).is_err());
    let d = EstimatorConfig::default();
    assert_eq!((d.window, d.hop), (50_000, 50_000));
}

#[test]
fn noisy_velocity_is_flagged_as_biasing_damping() {
    let f = film(false);
    let n = 10_000;
    let mut rec = record(&f, &TONES_X, &TONES_Y, n);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    add_coloured(&mut rec.vx, 15.0, 0.0, &mut rng);
    add_coloured(&mut rec.vy, 15.0, 0.0, &mut rng);
    let w = estimate_window(&rec.signals(), 0..n, &config(n, n, ModelOrder::Kc, Solver::Qr)).unwrap();
    let c = solved(&w);
    println!("15 dB velocity noise: dxx {:.4e} (truth {:.4e}), flags {:#?}", c.damping_n_s_m[(0, 0)], f.c[(0, 0)], w.flags);
    assert!(w.flags.iter().any(|s| s.contains("damping from differentiated noisy displacement may be biased")));
    // The bias it warns about is real: the direct damping is attenuated by about the noise fraction.
    assert!(c.damping_n_s_m[(0, 0)] < f.c[(0, 0)] * 0.99);
    // A clean record raises no such flag.
    let clean = record(&f, &TONES_X, &TONES_Y, n);
    let w = estimate_window(&clean.signals(), 0..n, &config(n, n, ModelOrder::Kc, Solver::Qr)).unwrap();
    assert!(w.flags.is_empty(), "{:?}", w.flags);
}

#[test]
fn paper_method_answers_where_qr_refuses() {
    // One frequency for both exciters, 40 dB noise: the excitation carries rank 2 of 4; the
    // noise makes the matrix technically invertible, and the normal equations happily invert it.
    let f = film(false);
    let mut rec = record(&f, &[(5.0e-6, 20.0, 0.0)], &[(3.0e-6, 20.0, 1.0)], 10_000);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for v in [&mut rec.x, &mut rec.y, &mut rec.vx, &mut rec.vy, &mut rec.fx, &mut rec.fy] {
        add_coloured(v, 40.0, 0.8, &mut rng);
    }
    let mut cfg = config(10_000, 10_000, ModelOrder::Kc, Solver::Qr);
    let qr = estimate_window(&rec.signals(), 0..10_000, &cfg).unwrap();
    cfg.solver = Solver::NormalEquations;
    let ne = estimate_window(&rec.signals(), 0..10_000, &cfg).unwrap();
    println!("QR: {}", qr.result.as_ref().err().map(|r| r.to_string()).unwrap_or_default());
    let c = solved(&ne);
    println!(
        "normal equations: K = {:.3e} (truth {:.3e}), SE {:.3e}; cond {:.3e}; flags {:?}",
        c.stiffness_n_m, f.k, c.stiffness_se, ne.condition_number, ne.flags
    );
    assert!(matches!(qr.result, Err(Refusal::RankDeficient { rank: 2, needed: 4, .. })));
    assert!(ne.flags.iter().any(|s| s.contains("normal equations")));
    // What it returns is noise-driven: far from the film, at least in one coefficient.
    assert!(rel_err(&c.stiffness_n_m, &f.k) > 0.01 || rel_err(&c.damping_n_s_m, &f.c) > 0.01);
}

/// The eight coefficients of a solved window, in the order kxx kxy kyx kyy dxx dxy dyx dyy.
fn flat8(c: &Coefficients) -> ([f64; 8], [f64; 8]) {
    let f = |m: &Matrix2<f64>, s: &Matrix2<f64>| [m[(0, 0)], m[(0, 1)], m[(1, 0)], m[(1, 1)], s[(0, 0)], s[(0, 1)], s[(1, 0)], s[(1, 1)]];
    (f(&c.stiffness_n_m, &c.damping_n_s_m), f(&c.stiffness_se, &c.damping_se))
}

const NAMES8: [&str; 8] = ["kxx", "kxy", "kyx", "kyy", "dxx", "dxy", "dyx", "dyy"];

/// Adds white noise of `rms` to `v`.
fn add_white(v: &mut [f64], rms: f64, rng: &mut ChaCha8Rng) {
    for x in v.iter_mut() {
        *x += rms * rng.sample::<f64, _>(StandardNormal);
    }
}

#[test]
fn errors_in_variables_flag_predicts_the_bias_it_warns_about() {
    // Noise in the velocity regressors (25 dB) and displacements (40 dB), as differentiated
    // probe noise would put there; force noise at 40 dB. The bias is systematic, so the mean
    // error over repeats must match what the flag predicts for every coefficient it names.
    let f = film(false);
    let n = 10_000;
    let clean = record(&f, &TONES_X, &TONES_Y, n);
    let truth = flat8(&Coefficients {
        stiffness_n_m: f.k,
        damping_n_s_m: f.c,
        added_mass_kg: None,
        stiffness_se: Matrix2::zeros(),
        damping_se: Matrix2::zeros(),
        added_mass_se: None,
    })
    .0;
    let cfg = config(n, n, ModelOrder::Kc, Solver::Qr);
    let repeats = 60;
    let mut err_sum = [0.0; 8];
    let mut se_sum = [0.0; 8];
    let mut predicted: Vec<Vec<f64>> = vec![Vec::new(); 8];
    for r in 0..repeats {
        let mut rng = ChaCha8Rng::seed_from_u64(500 + r);
        let mut rec = clean.clone();
        for v in [&mut rec.vx, &mut rec.vy] {
            let rms = rms_dynamic(v) * 10f64.powf(-25.0 / 20.0);
            add_white(v, rms, &mut rng);
        }
        for v in [&mut rec.x, &mut rec.y, &mut rec.fx, &mut rec.fy] {
            let rms = rms_dynamic(v) * 10f64.powf(-40.0 / 20.0);
            add_white(v, rms, &mut rng);
        }
        let w = estimate_window(&rec.signals(), 0..n, &cfg).unwrap();
        let (est, se) = flat8(solved(&w));
        for j in 0..8 {
            err_sum[j] += est[j] - truth[j];
            se_sum[j] += se[j];
        }
        let flag = w.flags.iter().find(|s| s.contains("errors in variables")).unwrap_or_else(|| panic!("repeat {r}: no flag in {:?}", w.flags));
        if r == 0 {
            println!("{flag}");
        }
        assert!(flag.starts_with("damping from differentiated noisy displacement may be biased"), "{flag}");
        let list = flag.split("Predicted bias: ").nth(1).and_then(|s| s.split(". ").next()).unwrap_or("");
        for item in list.split(", ") {
            let mut words = item.split_whitespace();
            let (Some(name), Some(value)) = (words.next(), words.next().and_then(|v| v.parse::<f64>().ok())) else { continue };
            if let Some(j) = NAMES8.iter().position(|n| *n == name) {
                predicted[j].push(value / 100.0 * truth[j].abs());
            }
        }
    }
    let mut compared = 0;
    for j in 0..8 {
        let (mean, se) = (err_sum[j] / repeats as f64, se_sum[j] / repeats as f64);
        if predicted[j].len() < repeats as usize / 2 {
            println!("{}: mean error {:+.3} SE, not named", NAMES8[j], mean / se);
            continue;
        }
        let p = predicted[j].iter().sum::<f64>() / predicted[j].len() as f64;
        println!("{}: predicted {:+.4} %, measured {:+.4} % ({:+.2} SE)", NAMES8[j], 100.0 * p / truth[j].abs(), 100.0 * mean / truth[j].abs(), mean / se);
        // The measured mean carries the scatter of 60 repeats (about 0.13 SE).
        assert!((p - mean).abs() < 0.25 * p.abs() + 0.4 * se, "{}: predicted {p:.4e}, measured {mean:.4e} (SE {se:.3e})", NAMES8[j]);
        compared += 1;
    }
    assert!(compared >= 2, "the flag named fewer than two coefficients consistently");
}

#[test]
fn spectral_standard_errors_match_the_scatter_of_blue_residuals_where_newey_west_overstates_it() {
    use oilfilm_identification::estimator::solve::ScaledFactor;
    use oilfilm_identification::estimator::uncertainty;
    use oilfilm_identification::estimator::window::BlockSummary;
    // Force noise that is the first difference of white noise: its density rises as
    // sin²(πf/f_s), like the differentiated probe noise the rig's residual carries, and is
    // small at the 17-43 Hz lines. Only the density at the lines moves the estimate.
    let f = film(false);
    let n = 5_000;
    let clean = record(&f, &TONES_X, &TONES_Y, n);
    let repeats = 200;
    let mut est = Vec::new();
    let mut se_spectral = Vec::new();
    let mut se_nw = Vec::new();
    for r in 0..repeats {
        let mut rng = ChaCha8Rng::seed_from_u64(9000 + r);
        let mut rec = clean.clone();
        for v in [&mut rec.fx, &mut rec.fy] {
            let rms = rms_dynamic(v) * 10f64.powf(-30.0 / 20.0);
            let w: Vec<f64> = (0..=n).map(|_| rng.sample::<f64, _>(StandardNormal)).collect();
            for (i, x) in v.iter_mut().enumerate() {
                *x += rms * (w[i + 1] - w[i]);
            }
        }
        let s = rec.signals();
        let cols: Vec<&[f64]> = vec![s.x_m, s.y_m, s.vx_m_s, s.vy_m_s, s.fx_n, s.fy_n];
        let summary = BlockSummary::from_columns(&cols);
        let factor = ScaledFactor::new(&summary, 4).expect("finite");
        let sol = factor.solve(Solver::Qr).expect("full rank");
        let spectral = uncertainty::spectral(&cols, 4, &factor.mean, &factor.scale, &sol.coef, &sol.inverse_gram_scaled);
        let nw = uncertainty::newey_west(&cols, 4, &factor.mean, &factor.scale, &sol.coef, &sol.inverse_gram_scaled);
        // The estimator's own path gives the spectral errors too.
        let w = estimate_window(&s, 0..n, &config(n, n, ModelOrder::Kc, Solver::Qr)).unwrap();
        let (e8, se8) = flat8(solved(&w));
        // coef[j * 2 + k]: regressor j, force k; the coefficient is its negative.
        let order = [(0, 0), (1, 0), (0, 1), (1, 1), (2, 0), (3, 0), (2, 1), (3, 1)];
        let pick = |v: &[f64]| -> [f64; 8] { std::array::from_fn(|i| v[order[i].0 * 2 + order[i].1]) };
        let sp = pick(&spectral.se);
        for j in 0..8 {
            assert!((sp[j] / se8[j] - 1.0).abs() < 1e-9, "the estimator reports the spectral errors");
            assert!((-pick(&sol.coef)[j] / e8[j] - 1.0).abs() < 1e-9);
        }
        est.push(e8);
        se_spectral.push(sp);
        se_nw.push(pick(&nw.se));
    }
    let mut worst_nw: f64 = f64::INFINITY;
    for j in 0..8 {
        let m = est.iter().map(|e| e[j]).sum::<f64>() / repeats as f64;
        let sd = (est.iter().map(|e| (e[j] - m).powi(2)).sum::<f64>() / (repeats - 1) as f64).sqrt();
        let sp = se_spectral.iter().map(|s| s[j]).sum::<f64>() / repeats as f64;
        let nw = se_nw.iter().map(|s| s[j]).sum::<f64>() / repeats as f64;
        println!("{}: SD/SE spectral {:.2}, Newey-West {:.2}", NAMES8[j], sd / sp, sd / nw);
        // 200 repeats: the SD itself is known to about 5 %.
        assert!((0.85..1.15).contains(&(sd / sp)), "{}: spectral SD/SE {:.2}", NAMES8[j], sd / sp);
        worst_nw = worst_nw.min(sd / nw);
    }
    assert!(
        worst_nw < 0.8,
        "Newey-West no longer overstates the scatter of blue residuals (worst SD/SE {worst_nw:.2}): revisit the uncertainty module's documentation"
    );
}
