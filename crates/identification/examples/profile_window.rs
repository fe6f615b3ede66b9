//! Where one window's estimate spends its time, stage by stage, at the window lengths the
//! node benchmark uses (25 000 samples at 5 kHz, 200 000 at 100 kHz).
//!
//! `cargo run --release -p oilfilm-identification --example profile_window` (stage table);
//! `... -- print` (every estimate with all digits, to compare two builds bit for bit);
//! `... -- once` (one 200 000-sample window, for `valgrind --tool=callgrind`).
//!
//! Median of repeats, `std::time::Instant`; on a shared machine compare rows within one run.

use std::hint::black_box;
use std::time::Instant;

use oilfilm_identification::estimator::solve::ScaledFactor;
use oilfilm_identification::estimator::window::BlockSummary;
use oilfilm_identification::estimator::{
    self, estimate_window, estimate_window_with_search, spectrum, uncertainty, EstimatorConfig, ModelOrder, Signals, Solver,
};

/// A two-tone record with deterministic pseudo-noise (xorshift, no RNG dependency).
fn data(n: usize, fs: f64) -> Vec<Vec<f64>> {
    let mut cols: Vec<Vec<f64>> = (0..6).map(|_| Vec::with_capacity(n)).collect();
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut noise = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    for i in 0..n {
        let t = i as f64 / fs;
        let w1 = 2.0 * std::f64::consts::PI * 23.0;
        let w2 = 2.0 * std::f64::consts::PI * 37.0;
        let (x, vx) = (5e-6 * (w1 * t).cos() + 3e-6 * (w2 * t).sin(), -5e-6 * w1 * (w1 * t).sin() + 3e-6 * w2 * (w2 * t).cos());
        let (y, vy) = (4e-6 * (w2 * t).cos() + 2e-6 * (w1 * t).sin(), -4e-6 * w2 * (w2 * t).sin() + 2e-6 * w1 * (w1 * t).cos());
        let fx = 150.0 - (1.2e8 * x + 3e7 * y + 2e5 * vx + 1.5e4 * vy) + 5.0 * noise();
        let fy = 8000.0 - (-2e7 * x + 2e8 * y + 1.2e4 * vx + 3e5 * vy) + 5.0 * noise();
        for (c, v) in cols.iter_mut().zip([x - 2e-5 + 1e-9 * noise(), y - 6e-5 + 1e-9 * noise(), vx, vy, fx, fy]) {
            c.push(v);
        }
    }
    cols
}

fn median_ms(reps: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let t0 = Instant::now();
            f();
            t0.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[reps / 2]
}

fn main() {
    if std::env::args().nth(1).as_deref() == Some("print") {
        // Every window's estimate, all digits (`{:?}` of an f64 round-trips its bits): for
        // comparing builds.
        for (fs, n) in [(5_000.0, 25_000usize), (100_000.0, 200_000)] {
            let cols = data(n, fs);
            let signals =
                Signals { x_m: &cols[0], y_m: &cols[1], vx_m_s: &cols[2], vy_m_s: &cols[3], ax_m_s2: None, ay_m_s2: None, fx_n: &cols[4], fy_n: &cols[5] };
            for solver in [Solver::Qr, Solver::Svd, Solver::NormalEquations] {
                let cfg = EstimatorConfig { window: n, hop: n, model: ModelOrder::Kc, solver, sample_rate_hz: fs, ..EstimatorConfig::default() };
                println!("{:?}", estimate_window(&signals, 0..n, &cfg));
            }
        }
        return;
    }
    if std::env::args().nth(1).as_deref() == Some("once") {
        // One 200 000-sample window and nothing else (for valgrind --tool=callgrind).
        let (fs, n) = (100_000.0, 200_000);
        let cols = data(n, fs);
        let signals =
            Signals { x_m: &cols[0], y_m: &cols[1], vx_m_s: &cols[2], vy_m_s: &cols[3], ax_m_s2: None, ay_m_s2: None, fx_n: &cols[4], fy_n: &cols[5] };
        let cfg = EstimatorConfig { window: n, hop: n, model: ModelOrder::Kc, solver: Solver::Qr, sample_rate_hz: fs, ..EstimatorConfig::default() };
        black_box(estimate_window(&signals, 0..n, &cfg).ok());
        return;
    }
    for nfft in [1usize << 16, 1 << 18] {
        let (tc, ts) = spectrum::twiddles(nfft);
        let mut re: Vec<f64> = (0..nfft).map(|k| (k as f64 * 0.1).sin()).collect();
        let mut im = vec![0.0; nfft];
        let t = median_ms(9, || spectrum::fft_with(&mut re, &mut im, &tc, &ts));
        let t_tw = median_ms(5, || {
            black_box(spectrum::twiddles(nfft));
        });
        println!("complex FFT of {nfft} points: {t:.2} ms (twiddle table {t_tw:.2} ms)");
    }
    for (fs, n) in [(5_000.0, 25_000usize), (100_000.0, 200_000)] {
        let cols = data(n, fs);
        let c: Vec<&[f64]> = cols.iter().map(|v| v.as_slice()).collect();
        let reps = 9;
        let t_lines = median_ms(reps, || {
            black_box(spectrum::analyse(c[0], c[1], c[2], c[3], fs));
        });
        let t_qr = median_ms(reps, || {
            let s = BlockSummary::from_columns(&c);
            black_box(ScaledFactor::new(&s, 4).and_then(|f| f.solve(Solver::Qr)));
        });
        let s = BlockSummary::from_columns(&c);
        let f = ScaledFactor::new(&s, 4).expect("finite");
        let sol = f.solve(Solver::Qr).expect("solvable");
        let t_hac = median_ms(reps, || {
            black_box(uncertainty::spectral(&c, 4, &f.mean, &f.scale, &sol.coef, &sol.inverse_gram_scaled));
        });
        let signals = Signals { x_m: c[0], y_m: c[1], vx_m_s: c[2], vy_m_s: c[3], ax_m_s2: None, ay_m_s2: None, fx_n: c[4], fy_n: c[5] };
        let cfg = EstimatorConfig { window: n, hop: n, model: ModelOrder::Kc, solver: Solver::Qr, sample_rate_hz: fs, ..EstimatorConfig::default() };
        let t_all = median_ms(reps, || {
            black_box(estimate_window(&signals, 0..n, &cfg).ok());
        });
        // What is left after the last sample when the line search was fed beforehand (all
        // segments but those that end with the window, as the estimator node does).
        let t_fed = {
            let mut t: Vec<f64> = (0..reps)
                .map(|_| {
                    let mut ls = spectrum::LineSearch::new(n, fs);
                    ls.advance(&c[0][..n - 1], &c[1][..n - 1], &c[2][..n - 1], &c[3][..n - 1]);
                    let t0 = Instant::now();
                    black_box(estimate_window_with_search(&signals, 0..n, &cfg, ls).ok());
                    t0.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            t.sort_by(f64::total_cmp);
            t[reps / 2]
        };
        println!("n = {n} at {fs} Hz: estimate_window_with_search, line search fed up to the last sample: {t_fed:.2} ms");
        // The same with the standard errors decimated for a 55.5 Hz signal band (the node
        // benchmark's conditioner cutoff).
        let band = Some(55.5);
        let q = estimator::se_decimation(n, fs, band);
        let t_hac_q = median_ms(reps, || {
            black_box(uncertainty::spectral_decimated(&c, 4, &f.mean, &f.scale, &sol.coef, &sol.inverse_gram_scaled, q));
        });
        let cfg_q = EstimatorConfig { signal_band_hz: band, ..cfg.clone() };
        let t_fed_q = {
            let mut t: Vec<f64> = (0..reps)
                .map(|_| {
                    let mut ls = spectrum::LineSearch::new(n, fs);
                    ls.advance(&c[0][..n - 1], &c[1][..n - 1], &c[2][..n - 1], &c[3][..n - 1]);
                    let t0 = Instant::now();
                    black_box(estimate_window_with_search(&signals, 0..n, &cfg_q, ls).ok());
                    t0.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            t.sort_by(f64::total_cmp);
            t[reps / 2]
        };
        let t_finish = {
            let mut t: Vec<f64> = (0..reps)
                .map(|_| {
                    let mut ls = spectrum::LineSearch::new(n, fs);
                    ls.advance(&c[0][..n - 1], &c[1][..n - 1], &c[2][..n - 1], &c[3][..n - 1]);
                    let t0 = Instant::now();
                    black_box(ls.finish(c[0], c[1], c[2], c[3]));
                    t0.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            t.sort_by(f64::total_cmp);
            t[reps / 2]
        };
        println!(
            "n = {n} at {fs} Hz, signal band 55.5 Hz: SE decimation q = {q}: spectral SE {t_hac_q:.2} ms | fed estimate {t_fed_q:.2} ms (of which the fed line search's finish {t_finish:.2} ms)"
        );
        println!(
            "n = {n} at {fs} Hz: lines (Welch) {t_lines:.2} ms | QR + solve {t_qr:.2} ms | spectral SE {t_hac:.2} ms | whole estimate_window {t_all:.2} ms (rest {:.2} ms)",
            t_all - t_lines - t_qr - t_hac
        );
    }
}
