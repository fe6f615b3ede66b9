//! The crate's one Fourier transform: `rustfft`, planned once per length and thread (its
//! planner keeps the plans, and every window of a run has the same lengths), with one scratch
//! buffer per thread.
//!
//! The planner is `rustfft`'s scalar one, on every CPU. `rustfft`'s default planner picks
//! AVX or SSE kernels at run time, and those sum in another order than the scalar ones: the
//! same record would give estimates that differ in the last bits from one CPU to another,
//! and a replayed bag would not reproduce, bit for bit, what a live graph on another machine
//! published. The scalar planner's plans are the same code on every CPU of an architecture.

use std::cell::RefCell;

use rustfft::num_complex::Complex;
use rustfft::{FftDirection, FftPlannerScalar};

thread_local! {
    static PLANNER: RefCell<(FftPlannerScalar<f64>, Vec<Complex<f64>>)> = RefCell::new((FftPlannerScalar::new(), Vec::new()));
}

/// In-place forward DFT of `buf` (any length): `X_k = sum_t x_t e^{-2 pi i k t / N}`,
/// unnormalised.
pub fn forward(buf: &mut [Complex<f64>]) {
    transform(buf, FftDirection::Forward);
}

/// In-place inverse DFT of `buf` (any length): `x_t = sum_k X_k e^{+2 pi i k t / N}`, without
/// the `1 / N`.
pub fn inverse(buf: &mut [Complex<f64>]) {
    transform(buf, FftDirection::Inverse);
}

fn transform(buf: &mut [Complex<f64>], direction: FftDirection) {
    if buf.len() < 2 {
        return;
    }
    PLANNER.with(|cell| {
        let (planner, scratch) = &mut *cell.borrow_mut();
        let fft = planner.plan_fft(buf.len(), direction);
        let need = fft.get_inplace_scratch_len();
        if scratch.len() < need {
            scratch.resize(need, Complex::new(0.0, 0.0));
        }
        fft.process_with_scratch(buf, &mut scratch[..need]);
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plans are the scalar planner's, whatever this CPU has: `rustfft`'s default planner
    /// would take its AVX kernels here (on an AVX CPU), whose bits differ.
    #[test]
    fn the_plans_are_the_scalar_ones() {
        for n in [4096usize, 32_768, 1000] {
            let x: Vec<Complex<f64>> = (0..n).map(|k| Complex::new((k as f64 * 0.37).sin(), (k as f64 * 0.11).cos() * 1e-3)).collect();
            let mut ours = x.clone();
            forward(&mut ours);
            let mut scalar = x.clone();
            FftPlannerScalar::new().plan_fft_forward(n).process(&mut scalar);
            assert!(ours.iter().zip(&scalar).all(|(a, b)| a.re.to_bits() == b.re.to_bits() && a.im.to_bits() == b.im.to_bits()), "n {n}");
        }
    }

    #[test]
    fn matches_the_dft_both_ways() {
        for n in [2usize, 16, 12, 1024] {
            let x: Vec<Complex<f64>> = (0..n).map(|k| Complex::new((k as f64 * 0.7).sin() + 0.1 * k as f64, (k as f64 * 1.3).cos())).collect();
            for (sign, run) in [(-1.0, forward as fn(&mut [Complex<f64>])), (1.0, inverse)] {
                let mut y = x.clone();
                run(&mut y);
                for (f, yf) in y.iter().enumerate() {
                    let mut s = Complex::new(0.0, 0.0);
                    for (t, xt) in x.iter().enumerate() {
                        let a = sign * 2.0 * std::f64::consts::PI * ((f * t) % n) as f64 / n as f64;
                        s += xt * Complex::new(a.cos(), a.sin());
                    }
                    assert!((s - yf).norm() < 1e-9 * n as f64, "n {n} bin {f}: {s} vs {yf}");
                }
            }
        }
    }
}
