//! Forward complex FFTs of the line search and the standard errors, through `rustfft`.
//!
//! Planned once per length and thread (`rustfft`'s planner keeps its plans; every window of a
//! run has the same lengths), with one scratch buffer per thread. `rustfft` picks its AVX
//! kernels at run time on x86-64; the same machine always takes the same path, so a replay on
//! it gives the live run's bits. Replaced the crate's own radix-2 transform in these two
//! places (measured 3-6x faster at 32 768-65 536 points, `examples/profile_window.rs`); the
//! results differ from it at round-off level only.

use std::cell::RefCell;

use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

thread_local! {
    static PLANNER: RefCell<(FftPlanner<f64>, Vec<Complex<f64>>)> = RefCell::new((FftPlanner::new(), Vec::new()));
}

/// In-place forward DFT of `buf` (any length; `X_k = Σ_t x_t e^{-2πikt/N}`, unnormalised).
pub fn forward(buf: &mut [Complex<f64>]) {
    if buf.len() < 2 {
        return;
    }
    PLANNER.with(|cell| {
        let (planner, scratch) = &mut *cell.borrow_mut();
        let fft = planner.plan_fft_forward(buf.len());
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

    #[test]
    fn matches_the_dft() {
        for n in [2usize, 16, 12, 1024] {
            let x: Vec<Complex<f64>> = (0..n).map(|k| Complex::new((k as f64 * 0.7).sin() + 0.1 * k as f64, (k as f64 * 1.3).cos())).collect();
            let mut y = x.clone();
            forward(&mut y);
            for (f, yf) in y.iter().enumerate() {
                let mut s = Complex::new(0.0, 0.0);
                for (t, xt) in x.iter().enumerate() {
                    let a = -2.0 * std::f64::consts::PI * ((f * t) % n) as f64 / n as f64;
                    s += xt * Complex::new(a.cos(), a.sin());
                }
                assert!((s - yf).norm() < 1e-9 * n as f64, "n {n} bin {f}: {s} vs {yf}");
            }
        }
    }
}
