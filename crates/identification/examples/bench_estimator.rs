//! Micro-benchmark of the estimator's least-squares stage (and, for context, the whole window
//! analysis). No criterion: `std::time::Instant`, median of repeats, a table on stdout.
//!
//! `cargo run --release -p oilfilm-identification --example bench_estimator`
//!
//! Reference from the product owner: numpy.linalg.lstsq on a 50 000 × 4 window with two
//! right-hand sides, 1.5 ms per window, about 33 M samples/s. Target: ≥ 3× that throughput.

use std::hint::black_box;
use std::time::Instant;

use nalgebra::DMatrix;
use oilfilm_identification::estimator::solve::ScaledFactor;
use oilfilm_identification::estimator::window::BlockSummary;
use oilfilm_identification::estimator::{estimate_window, normal_equations, EstimatorConfig, ModelOrder, Signals, Solver};

const FS: f64 = 5000.0;
const WINDOW: usize = 50_000;
const HOP: usize = WINDOW / 10;
const NUMPY_MS: f64 = 1.5;

struct Data {
    cols: Vec<Vec<f64>>, // x y vx vy fx fy
}

/// A multi-tone record with a little deterministic pseudo-noise (no RNG dependency needed).
fn data(n: usize) -> Data {
    let mut cols: Vec<Vec<f64>> = (0..6).map(|_| Vec::with_capacity(n)).collect();
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut noise = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let tones = |t: f64, a: [(f64, f64); 2]| {
        let mut p = 0.0;
        let mut v = 0.0;
        for (amp, hz) in a {
            let w = 2.0 * std::f64::consts::PI * hz;
            p += amp * (w * t).cos();
            v -= amp * w * (w * t).sin();
        }
        (p, v)
    };
    for i in 0..n {
        let t = i as f64 / FS;
        let (x, vx) = tones(t, [(5e-6, 17.0), (3e-6, 43.0)]);
        let (y, vy) = tones(t, [(4e-6, 23.0), (2.5e-6, 37.0)]);
        let fx = 150.0 - (1.2e8 * x + 3e7 * y + 2e5 * vx + 1.5e4 * vy) + 5.0 * noise();
        let fy = 8000.0 - (-2e7 * x + 2e8 * y + 1.2e4 * vx + 3e5 * vy) + 5.0 * noise();
        for (c, v) in cols.iter_mut().zip([x - 2e-5 + 1e-8 * noise(), y - 6e-5 + 1e-8 * noise(), vx, vy, fx, fy]) {
            c.push(v);
        }
    }
    Data { cols }
}

/// Median wall time of `reps` runs, seconds.
fn median_time(reps: usize, mut f: impl FnMut()) -> f64 {
    f(); // warm-up
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let t0 = Instant::now();
            f();
            t0.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(|a, b| a.total_cmp(b));
    t[reps / 2]
}

/// One table row. `per_window_s` is the time to produce one window's solution; `samples` the
/// samples that time is charged to (the window, or the new samples of one hop). "vs numpy"
/// compares time per window solution with numpy.linalg.lstsq's 1.5 ms (numpy, too, would have
/// to solve every emitted window).
fn row(name: &str, per_window_s: f64, samples: usize, note: &str) {
    let msps = samples as f64 / per_window_s / 1e6;
    let vs = (NUMPY_MS * 1e-3) / per_window_s;
    println!("| {name:<46} | {:>10.3} | {:>10.1} | {:>7.2}x | {note}", per_window_s * 1e3, msps, vs);
}

fn main() {
    let n = WINDOW + 20 * HOP;
    let d = data(n);
    let w: Vec<&[f64]> = d.cols.iter().map(|c| &c[..WINDOW]).collect();
    let reps = 101;

    println!(
        "least-squares stage, window {WINDOW} x 4 regressors (+ intercept) x 2 right-hand sides; numpy.linalg.lstsq = {NUMPY_MS} ms/window = {:.1} M samples/s",
        WINDOW as f64 / NUMPY_MS / 1e3
    );
    println!("| {:<46} | {:>10} | {:>10} | {:>8} | notes", "method", "ms/window", "M samp/s", "vs numpy");
    println!("|{:-<48}|{:-<12}|{:-<12}|{:-<10}|------", "", "", "", "");

    // 1. One-shot Householder QR of one window (factor, condition via R-SVD, solve).
    let t_qr = median_time(reps, || {
        let s = BlockSummary::from_columns(&w);
        let f = ScaledFactor::new(&s, 4).expect("finite");
        black_box(f.solve(Solver::Qr));
    });
    row("one-shot QR window (Householder, blocked)", t_qr, WINDOW, "factor + cond + solve");

    // 3. SVD: the solver option (SVD of the scaled triangular factor) and, for reference,
    //    nalgebra's SVD of the whole centred window.
    let t_rsvd = median_time(reps, || {
        let s = BlockSummary::from_columns(&w);
        let f = ScaledFactor::new(&s, 4).expect("finite");
        black_box(f.solve(Solver::Svd));
    });
    row("SVD solver (QR, then SVD of 4x4 factor)", t_rsvd, WINDOW, "Solver::Svd, Chan's R-SVD");
    let means: Vec<f64> = w.iter().map(|c| c.iter().sum::<f64>() / c.len() as f64).collect();
    let t_nsvd = median_time(5, || {
        let a = DMatrix::from_fn(WINDOW, 4, |i, j| w[j][i] - means[j]);
        let b = DMatrix::from_fn(WINDOW, 2, |i, j| w[4 + j][i] - means[4 + j]);
        let svd = a.svd(true, true);
        black_box(svd.solve(&b, 1e-12).ok());
    });
    row("nalgebra SVD of the full 50000x4 (reference)", t_nsvd, WINDOW, "not used by the estimator");
    let t_nqr = median_time(5, || {
        let a = DMatrix::from_fn(WINDOW, 4, |i, j| w[j][i] - means[j]);
        let b = DMatrix::from_fn(WINDOW, 2, |i, j| w[4 + j][i] - means[4 + j]);
        let qr = a.qr();
        let qtb = qr.q().transpose() * b;
        black_box(qr.r().solve_upper_triangular(&qtb.rows(0, 4).into_owned()));
    });
    row("nalgebra QR of the full 50000x4 (reference)", t_nqr, WINDOW, "explicit Q, not used");

    // 4. The paper's normal equations (fast, and loses twice the digits).
    let t_ne = median_time(reps, || {
        black_box(normal_equations::solve(&w, 4));
    });
    row("normal equations (Zhou et al. eq. 6)", t_ne, WINDOW, "cond squared; comparison only");

    // 5. Whole window analysis for context: line search (FFT), HAC errors, flags.
    let s =
        Signals { x_m: &d.cols[0], y_m: &d.cols[1], vx_m_s: &d.cols[2], vy_m_s: &d.cols[3], ax_m_s2: None, ay_m_s2: None, fx_n: &d.cols[4], fy_n: &d.cols[5] };
    let cfg = EstimatorConfig {
        window: WINDOW,
        hop: HOP,
        model: ModelOrder::Kc,
        solver: Solver::Qr,
        max_relative_se: 0.25,
        max_condition: 1e6,
        sample_rate_hz: FS,
        signal_band_hz: None,
    };
    let t_full = median_time(7, || {
        black_box(estimate_window(&s, 0..WINDOW, &cfg).ok());
    });
    row("full estimate_window (lines + QR + HAC)", t_full, WINDOW, "what a user calls");
    println!();
    println!("one-shot QR {:.3} ms vs numpy {NUMPY_MS} ms: {:.1}x", t_qr * 1e3, NUMPY_MS * 1e-3 / t_qr);
}
