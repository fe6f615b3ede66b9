//! The crate's one Fourier transform: `rustfft`, planned once per length and thread (its
//! planner keeps the plans, and every window of a run has the same lengths), with one scratch
//! buffer per thread.
//!
//! Which kernels run follows [`crate::simd::Isa::current`], not `rustfft`'s own look at the
//! CPU: its AVX kernels (which use fused multiply-adds, and are about twice as fast as the
//! others in double precision) where the set is AVX2 or wider and the CPU has FMA, its scalar
//! kernels otherwise. So an estimate is the same bits on every CPU of one class (x86-64 with
//! AVX2 and FMA; all others), and `OILFILM_SIMD=scalar` on an AVX2 CPU reproduces, bit for
//! bit, what a CPU without it computes. Between the two classes only the transforms' rounding
//! differs; what it moves is bounded in `tests/same_bits_on_every_isa.rs` (ADR 0023).

use std::cell::RefCell;

use std::sync::Arc;

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftDirection, FftPlannerScalar};

/// The plans of both kinds, made as first asked for, and the scratch they share.
#[derive(Default)]
struct Planners {
    #[cfg(target_arch = "x86_64")]
    avx: Option<rustfft::FftPlannerAvx<f64>>,
    scalar: Option<FftPlannerScalar<f64>>,
    scratch: Vec<Complex<f64>>,
}

impl Planners {
    fn plan(&mut self, n: usize, direction: FftDirection) -> Arc<dyn Fft<f64>> {
        #[cfg(target_arch = "x86_64")]
        if crate::simd::Isa::current() != crate::simd::Isa::Scalar && std::arch::is_x86_feature_detected!("fma") {
            if self.avx.is_none() {
                self.avx = rustfft::FftPlannerAvx::new().ok();
            }
            if let Some(p) = self.avx.as_mut() {
                return p.plan_fft(n, direction);
            }
        }
        self.scalar.get_or_insert_with(FftPlannerScalar::new).plan_fft(n, direction)
    }
}

thread_local! {
    static PLANNERS: RefCell<Planners> = RefCell::new(Planners::default());
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
    PLANNERS.with(|cell| {
        let planners = &mut *cell.borrow_mut();
        let fft = planners.plan(buf.len(), direction);
        let scratch = &mut planners.scratch;
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

    /// With the baseline set the plans are `rustfft`'s scalar ones, whatever this CPU has
    /// (`rustfft`'s own choice would be its AVX kernels on an AVX CPU, whose bits differ).
    #[test]
    fn the_baseline_plans_are_the_scalar_ones() {
        for n in [4096usize, 32_768, 1000] {
            let x: Vec<Complex<f64>> = (0..n).map(|k| Complex::new((k as f64 * 0.37).sin(), (k as f64 * 0.11).cos() * 1e-3)).collect();
            let mut ours = x.clone();
            crate::simd::with_isa(crate::simd::Isa::Scalar, || forward(&mut ours));
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
