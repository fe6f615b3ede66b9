//! Step 6 of Zhou et al. (2004), section 3.1: "calculate the velocity from displacement using
//! a differential FIR filter. After that, derive the acceleration from velocity reusing the
//! differential FIR filter." We do exactly that with one symmetric FIR differentiator.
//!
//! ## The filter: Savitzky-Golay first derivative
//! A. Savitzky & M. J. E. Golay, "Smoothing and differentiation of data by simplified least
//! squares procedures", Analytical Chemistry 36(8), 1964: fit a polynomial of degree
//! [`DEGREE`] (= 4) by least squares to the `2M + 1` samples around `n` and take its slope
//! at `n`. The weights do not depend on the data, so this is an FIR filter; for the centred
//! window the weights are **antisymmetric**, `c_{-k} = -c_k`, so the response is
//! `H(w) = 2j sum_k c_k sin(k w)`: purely imaginary, i.e. exactly the +90 degrees of an
//! ideal differentiator with **no delay at any frequency** (the weights are antisymmetrised
//! after the solve so that this holds to the last bit). Degree 4 makes it exact for
//! polynomials up to degree 4 and its relative gain error grows as `w^4`, not `w^2` as for
//! the quadratic fit, so a short window stays accurate over the whole 0-80 Hz band.
//!
//! Relative gain error `H(w) / (j w) - 1` at 80 Hz, 5 kHz ([`SavitzkyGolayDerivative::gain_error`]):
//!
//! | half-length `M` | velocity (one pass) | acceleration (two passes) | gain at 1 kHz / ideal |
//! |---|---|---|---|
//! | 2 | -3.4e-6 | -6.8e-6 | 0.93 |
//! | 4 | -6.7e-5 | -1.3e-4 | 0.31 |
//! | **5 (default)** | **-1.6e-4** | **-3.2e-4** | 0.005 |
//! | 8 | -9.8e-4 | -2.0e-3 | 0.025 |
//!
//! The default meets the target (< 1e-3) for both velocity and acceleration. Noise above the
//! band is already removed by the low-pass, so a short window is chosen for accuracy; the
//! default has, in addition, a near-zero of its response at 1 kHz.
//!
//! ## Edges
//! Within `M` samples of either end the window is the first (last) `2M + 1` samples and the
//! fitted polynomial's slope is taken at the sample's own position (P. A. Gorry, "General
//! least-squares smoothing and differentiation by the convolution (Savitzky-Golay) method",
//! Analytical Chemistry 62(6), 1990). Those samples are less accurate and are outside
//! [`super::Conditioned::valid`] (the conditioning trims `2M`, one `M` per pass).
//!
//! ## Cost
//! `M` multiply-adds and `2M` adds per sample, vectorised over L1-resident blocks of the
//! column (AVX2 when the CPU has it, AVX-512 intrinsics when it has those; same result bit for
//! bit; the sum over `k` is an exclusive range, which the compiler unrolls, where `2..=M` kept
//! a loop with a branch per term: the two changes took four columns' two derivatives from
//! 2.1-2.5 ms to 1.5-1.7 ms for 300 000 samples);
//! [`SavitzkyGolayDerivative::apply_twice_into`] runs the second derivative a block behind
//! the first, while the first is still in cache.

use oilfilm_physics::daq::ChannelId;

use super::{all_finite, first_non_finite};
use crate::IdentificationError;

/// Degree of the least-squares polynomial.
pub const DEGREE: usize = 4;

/// Output samples per block of the interior loop (4 kB of output, L1-resident).
const BLOCK: usize = 512;

/// Longest half-length accepted.
pub const MAX_HALF_LENGTH: usize = 64;

/// Solves the small dense system `g v = rhs` in place (Gaussian elimination, partial
/// pivoting). `g` is `n x n`, row-major. Returns `false` if it is singular.
fn solve_small(g: &mut [f64], rhs: &mut [f64]) -> bool {
    let n = rhs.len();
    for col in 0..n {
        let mut piv = col;
        for r in col + 1..n {
            if g[r * n + col].abs() > g[piv * n + col].abs() {
                piv = r;
            }
        }
        if g[piv * n + col] == 0.0 || !g[piv * n + col].is_finite() {
            return false;
        }
        if piv != col {
            for c in 0..n {
                g.swap(piv * n + c, col * n + c);
            }
            rhs.swap(piv, col);
        }
        let d = g[col * n + col];
        for r in col + 1..n {
            let f = g[r * n + col] / d;
            if f != 0.0 {
                for c in col..n {
                    g[r * n + c] -= f * g[col * n + c];
                }
                rhs[r] -= f * rhs[col];
            }
        }
    }
    for col in (0..n).rev() {
        let mut s = rhs[col];
        for c in col + 1..n {
            s -= g[col * n + c] * rhs[c];
        }
        rhs[col] = s / g[col * n + col];
    }
    true
}

/// Least-squares derivative weights (per sample) for a window of `w.len()` consecutive
/// samples, the slope taken at window position `eval` (0-based, may be fractional).
fn ls_derivative_weights(eval: f64, w: &mut [f64]) -> Result<(), IdentificationError> {
    let len = w.len();
    let p = DEGREE + 1;
    let centre = 0.5 * (len as f64 - 1.0);
    let half = centre.max(1.0);
    // Normal equations in the scaled abscissa u = (i - centre) / half, in [-1, 1].
    let mut g = [0.0; (DEGREE + 1) * (DEGREE + 1)];
    for i in 0..len {
        let u = (i as f64 - centre) / half;
        let mut pw = [1.0; DEGREE + 1];
        for j in 1..p {
            pw[j] = pw[j - 1] * u;
        }
        for r in 0..p {
            for c in 0..p {
                g[r * p + c] += pw[r] * pw[c];
            }
        }
    }
    let u0 = (eval - centre) / half;
    let mut v = [0.0; DEGREE + 1];
    for (j, vj) in v.iter_mut().enumerate().skip(1) {
        *vj = j as f64 * u0.powi(j as i32 - 1);
    }
    if !solve_small(&mut g, &mut v) {
        return Err(IdentificationError::invalid(
            "conditioning.differentiator_half_length",
            format!("a {len}-sample window cannot fit a degree-{DEGREE} polynomial"),
        ));
    }
    for (i, wi) in w.iter_mut().enumerate() {
        let u = (i as f64 - centre) / half;
        let mut pw = 1.0;
        let mut s = 0.0;
        for vj in v {
            s += vj * pw;
            pw *= u;
        }
        *wi = s / half;
    }
    Ok(())
}

/// A Savitzky-Golay first-derivative FIR (degree [`DEGREE`], half-length `M`), output in
/// units of the input per second.
#[derive(Clone, Debug, PartialEq)]
pub struct SavitzkyGolayDerivative {
    half_length: usize,
    sample_rate_hz: f64,
    /// `c_1 .. c_M` (per second): `out[n] = sum_k c_k (x[n+k] - x[n-k])`.
    interior: Vec<f64>,
    /// `M` rows of `2M + 1` weights (per second) for output `n < M`, on `x[0 .. 2M]`.
    left: Vec<f64>,
    /// `M` rows for output `len - M + r`, on `x[len - 2M - 1 ..]`.
    right: Vec<f64>,
}

/// The interior of [`SavitzkyGolayDerivative::interior_block`] for one x86 vector width: a
/// dispatcher on the half-length `M` and a kernel with `M` known at compile time, `W` outputs
/// per vector, four vectors per step sharing their loads. Per output: a subtract, a multiply
/// and an add per tap, summed in the order of [`interior_point`] (no fused multiply-add), so
/// the same bits as the plain sum.
#[cfg(target_arch = "x86_64")]
macro_rules! interior_kernels {
    (
        $(#[$doc:meta])*
        $dispatch:ident, $kernel:ident, $feature:literal, $w:literal,
        $vec:ident, $set1:ident, $load:ident, $store:ident, $add:ident, $sub:ident, $mul:ident
    ) => {
        $(#[$doc])*
        #[target_feature(enable = $feature)]
        fn $dispatch(&self, input: &[f64], out: &mut [f64], range: std::ops::Range<usize>) {
            match self.half_length {
                4 => self.$kernel::<4>(input, out, range),
                5 => self.$kernel::<5>(input, out, range),
                6 => self.$kernel::<6>(input, out, range),
                _ => self.interior_block_body::<4>(input, out, range),
            }
        }

        #[target_feature(enable = $feature)]
        fn $kernel<const M: usize>(&self, input: &[f64], out: &mut [f64], range: std::ops::Range<usize>) {
            use std::arch::x86_64::{$add, $load, $mul, $set1, $store, $sub, $vec};
            let Ok(c) = <[f64; M]>::try_from(&self.interior[..M.min(self.interior.len())]) else {
                return self.interior_block_passes(input, out, range);
            };
            let (start, end) = (range.start, range.end);
            // Outputs start..end read input[start - M .. end + M] (the caller keeps the range
            // inside M..len - M, and slicing checks it).
            let x = &input[start - M..end + M];
            let dst = &mut out[start..end];
            let cv: [$vec; M] = std::array::from_fn(|k| $set1(c[k]));
            // Four vectors of outputs per step, one load per distinct shift shared by the
            // outputs that read it: 4 W outputs read the 3 W + 2 M + 1 vectors x[j + M + s
            // ..][..W], -M <= s <= 3 W + M (23 loads for 16 outputs at W = 4, M = 5, where one
            // vector at a time loaded 2 M per vector, 40). Each output's sum is formed in the
            // same order as below, so the same bits.
            let wide = dst.len() / (4 * $w) * (4 * $w);
            let mut j = 0;
            while j < wide {
                // SAFETY: j + 4 W <= wide <= dst.len(), and the loads read x[j + M + s ..
                // j + M + s + W] for -M <= s <= 3 W + M, inside x[0 .. dst.len() + 2M] = x[..].
                unsafe {
                    // Vector q's outputs are centred on x[j + M + q W ..]; `d(q, k)` is its
                    // k-th difference. The compiler loads each address once (the same
                    // pointer arithmetic, and `dst` cannot alias `x`).
                    let p = x.as_ptr().add(j + M);
                    let d = |q: usize, k: usize| $sub($load(p.add(q * $w + k)), $load(p.add(q * $w).sub(k)));
                    let mut acc: [$vec; 4] = std::array::from_fn(|q| $mul(cv[0], d(q, 1)));
                    for k in 2..M + 1 {
                        for q in 0..4 {
                            acc[q] = $add(acc[q], $mul(cv[k - 1], d(q, k)));
                        }
                    }
                    for q in 0..4 {
                        $store(dst.as_mut_ptr().add(j + q * $w), acc[q]);
                    }
                }
                j += 4 * $w;
            }
            let body = dst.len() / $w * $w;
            while j < body {
                // SAFETY: j + W <= body <= dst.len(), and the loads read x[j + M - k .. j + M +
                // k + W] for 1 <= k <= M, inside x[0 .. dst.len() + 2M] = x[..].
                unsafe {
                    let p = x.as_ptr().add(j + M);
                    let d = |k: usize| $sub($load(p.add(k)), $load(p.sub(k)));
                    let mut acc = $mul(cv[0], d(1));
                    for k in 2..M + 1 {
                        acc = $add(acc, $mul(cv[k - 1], d(k)));
                    }
                    $store(dst.as_mut_ptr().add(j), acc);
                }
                j += $w;
            }
            for (j, o) in dst.iter_mut().enumerate().skip(body) {
                *o = interior_point(&c, x, j + M);
            }
        }
    };
}

impl SavitzkyGolayDerivative {
    /// Designs the filter; `2 <= half_length <= MAX_HALF_LENGTH` (a degree-4 fit needs at
    /// least 5 samples).
    pub fn new(half_length: usize, sample_rate_hz: f64) -> Result<Self, IdentificationError> {
        if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
            return Err(IdentificationError::invalid(
                "sample_rate_hz",
                format!("must be finite and > 0, got {sample_rate_hz}"),
            ));
        }
        let min = DEGREE.div_ceil(2);
        if !(min..=MAX_HALF_LENGTH).contains(&half_length) {
            return Err(IdentificationError::invalid(
                "conditioning.differentiator_half_length",
                format!(
                    "must be in {min}..={MAX_HALF_LENGTH} (a degree-{DEGREE} fit needs {} samples), got {half_length}",
                    DEGREE + 1
                ),
            ));
        }
        let m = half_length;
        let width = 2 * m + 1;
        let mut w = vec![0.0; width];
        ls_derivative_weights(m as f64, &mut w)?;
        let interior = (1..=m)
            .map(|k| 0.5 * (w[m + k] - w[m - k]) * sample_rate_hz)
            .collect();
        let mut left = vec![0.0; m * width];
        let mut right = vec![0.0; m * width];
        for r in 0..m {
            ls_derivative_weights(r as f64, &mut w)?;
            for (dst, &src) in left[r * width..(r + 1) * width].iter_mut().zip(&w) {
                *dst = src * sample_rate_hz;
            }
            ls_derivative_weights((m + 1 + r) as f64, &mut w)?;
            for (dst, &src) in right[r * width..(r + 1) * width].iter_mut().zip(&w) {
                *dst = src * sample_rate_hz;
            }
        }
        Ok(Self {
            half_length: m,
            sample_rate_hz,
            interior,
            left,
            right,
        })
    }

    pub fn half_length(&self) -> usize {
        self.half_length
    }

    /// The sample rate the weights were designed for (Hz).
    pub fn sample_rate_hz(&self) -> f64 {
        self.sample_rate_hz
    }

    /// `c_1 .. c_M` in 1/s: `out[n] = sum_k c_k (x[n+k] - x[n-k])`.
    pub fn coefficients(&self) -> &[f64] {
        &self.interior
    }

    /// Relative gain error of the interior filter at `freq_hz` (> 0),
    /// `|H(w)| / w - 1`; the phase is exactly that of `j w` by antisymmetry.
    pub fn gain_error(&self, freq_hz: f64) -> f64 {
        let w = 2.0 * std::f64::consts::PI * freq_hz / self.sample_rate_hz;
        let h: f64 = self
            .interior
            .iter()
            .enumerate()
            .map(|(i, &c)| 2.0 * c * ((i + 1) as f64 * w).sin())
            .sum();
        h / (2.0 * std::f64::consts::PI * freq_hz) - 1.0
    }

    /// Differentiates `input` into `out` (same length, at least `2M + 1` samples).
    pub fn apply_into(&self, input: &[f64], out: &mut [f64]) -> Result<(), IdentificationError> {
        let len = input.len();
        let m = self.half_length;
        let width = 2 * m + 1;
        if out.len() != len {
            return Err(IdentificationError::BadInput {
                what: "differentiator output".into(),
                reason: format!("buffer has {} samples, input {len}", out.len()),
            });
        }
        if len < width {
            return Err(IdentificationError::BadInput {
                what: "differentiator input".into(),
                reason: format!("{len} samples, a half-length {m} window needs at least {width}"),
            });
        }
        // Interior, in blocks that stay in L1 while the M passes of each block run.
        let mut start = m;
        while start < len - m {
            let end = (start + BLOCK).min(len - m);
            self.interior_block(input, out, start..end);
            start = end;
        }
        self.edges(input, out);
        Ok(())
    }

    /// Interior outputs `range` (inside `M..len - M`): `M` vectorised passes over the block,
    /// compiled for AVX2 when the CPU has it (the same operations in the same order, so the
    /// same result bit for bit).
    fn interior_block(&self, input: &[f64], out: &mut [f64], range: std::ops::Range<usize>) {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the only requirement of a `target_feature` function is that the CPU
                // has the feature, which was checked on the line above.
                unsafe { self.interior_block_avx512(input, out, range) };
                return;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: as above.
                unsafe { self.interior_block_avx2(input, out, range) };
                return;
            }
        }
        self.interior_block_body::<4>(input, out, range);
    }

    #[cfg(target_arch = "x86_64")]
    interior_kernels! {
        /// Four outputs per instruction, written with the AVX2 intrinsics: the compiler's own
        /// vectorisation of [`SavitzkyGolayDerivative::interior_block_const`] built each
        /// shifted vector from half loads and blends. Per output the same operations in the
        /// same order, so the same result bit for bit.
        interior_block_avx2, interior_block_avx2_const, "avx2", 4,
        __m256d, _mm256_set1_pd, _mm256_loadu_pd, _mm256_storeu_pd, _mm256_add_pd, _mm256_sub_pd, _mm256_mul_pd
    }

    #[cfg(target_arch = "x86_64")]
    interior_kernels! {
        /// Eight outputs per instruction, written with the AVX-512 intrinsics (the compiler's
        /// own vectorisation of [`SavitzkyGolayDerivative::interior_block_const`] at eight
        /// lanes used gathers and permutes, no faster than four lanes). Per output the same
        /// operations in the same order, so the same result bit for bit.
        interior_block_avx512, interior_block_avx512_const, "avx512f", 8,
        __m512d, _mm512_set1_pd, _mm512_loadu_pd, _mm512_storeu_pd, _mm512_add_pd, _mm512_sub_pd, _mm512_mul_pd
    }

    /// `W` outputs at a time, left to the compiler to vectorise: the path of builds without
    /// AVX2, and of the kernels above for half-lengths other than 4-6.
    #[inline(always)]
    fn interior_block_body<const W: usize>(&self, input: &[f64], out: &mut [f64], range: std::ops::Range<usize>) {
        match self.half_length {
            4 => self.interior_block_const::<4, W>(input, out, range),
            5 => self.interior_block_const::<5, W>(input, out, range),
            6 => self.interior_block_const::<6, W>(input, out, range),
            _ => self.interior_block_passes(input, out, range),
        }
    }

    /// The interior with `M` known at compile time: each output sums its `M` terms in a
    /// register, in the same order as the passes of
    /// [`SavitzkyGolayDerivative::interior_block_passes`] (so the same result bit for bit),
    /// without storing and reloading the partial sums `M - 1` times.
    #[inline(always)]
    fn interior_block_const<const M: usize, const W: usize>(
        &self,
        input: &[f64],
        out: &mut [f64],
        range: std::ops::Range<usize>,
    ) {
        let Ok(c) = <[f64; M]>::try_from(&self.interior[..M.min(self.interior.len())]) else {
            return self.interior_block_passes(input, out, range);
        };
        let (start, end) = (range.start, range.end);
        // Outputs start..end read input[start - M .. end + M]; x[i + M] is input[start + i].
        let x = &input[start - M..end + M];
        let dst = &mut out[start..end];
        let lanes = dst.len() / W * W;
        let (body, rest) = dst.split_at_mut(lanes);
        // `W` outputs at a time as arrays, so that the compiler keeps them in one vector.
        for (q, o) in body.chunks_exact_mut(W).enumerate() {
            let i = W * q + M;
            let pair = |k: usize| -> ([f64; W], [f64; W]) {
                let (a, b) = (&x[i + k..i + k + W], &x[i - k..i - k + W]);
                (std::array::from_fn(|l| a[l]), std::array::from_fn(|l| b[l]))
            };
            let (a, b) = pair(1);
            let mut acc: [f64; W] = std::array::from_fn(|l| c[0] * (a[l] - b[l]));
            for k in 2..M + 1 {
                let (a, b) = pair(k);
                for l in 0..W {
                    acc[l] += c[k - 1] * (a[l] - b[l]);
                }
            }
            o.copy_from_slice(&acc);
        }
        for (j, o) in rest.iter_mut().enumerate() {
            *o = interior_point(&c, x, lanes + j + M);
        }
    }

    /// The interior as `M` vectorised passes over the block (any `M`).
    #[inline(always)]
    fn interior_block_passes(&self, input: &[f64], out: &mut [f64], range: std::ops::Range<usize>) {
        let start = range.start;
        let dst = &mut out[range];
        let c1 = self.interior[0];
        for (o, (&a, &b)) in dst
            .iter_mut()
            .zip(input[start + 1..].iter().zip(&input[start - 1..]))
        {
            *o = c1 * (a - b);
        }
        for (k, &c) in self.interior.iter().enumerate().skip(1) {
            let k = k + 1;
            for (o, (&a, &b)) in dst
                .iter_mut()
                .zip(input[start + k..].iter().zip(&input[start - k..]))
            {
                *o += c * (a - b);
            }
        }
    }

    /// The `M` outputs at each end (one-sided windows); `len >= 2M + 1`.
    fn edges(&self, input: &[f64], out: &mut [f64]) {
        self.edge_left(input, out);
        self.edge_right(input, out);
    }

    /// The first `M` outputs, on `input[..2M + 1]`; `len >= 2M + 1`.
    fn edge_left(&self, input: &[f64], out: &mut [f64]) {
        let width = 2 * self.half_length + 1;
        for (o, lw) in out[..self.half_length].iter_mut().zip(self.left.chunks_exact(width)) {
            *o = lw.iter().zip(&input[..width]).map(|(a, b)| a * b).sum();
        }
    }

    /// The last `M` outputs, on the last `2M + 1` inputs; `len >= 2M + 1`.
    fn edge_right(&self, input: &[f64], out: &mut [f64]) {
        let len = input.len();
        let m = self.half_length;
        let width = 2 * m + 1;
        let tail = &input[len - width..];
        for r in 0..m {
            let rw = &self.right[r * width..(r + 1) * width];
            out[len - m + r] = rw.iter().zip(tail).map(|(a, b)| a * b).sum();
        }
    }

    /// [`SavitzkyGolayDerivative::apply_twice_each`] fed from the end of the record towards
    /// its start, as a backward pass makes `input` final: `input[from..]` is final, `from`
    /// decreasing from call to call and 0 in the last. Computes every output of `first` and
    /// `second` whose inputs are final and that is not computed yet. Returns whether the
    /// outputs of `second` computed in this call are finite, and their range: one range
    /// (possibly empty), just below the previous call's, so that the ranges cover the column
    /// once when `from` has reached 0. Each output is computed by the same kernel as in
    /// [`SavitzkyGolayDerivative::apply_twice_each`], so the same result bit for bit. The three
    /// columns must have the same length, at least `2M + 1`; else nothing is computed and
    /// `None` returned (the caller then uses the one-pass form, which reports the mismatch).
    ///
    /// The caller works on the returned range itself (eq. 2's inertial part), rather than
    /// passing a closure: a closure that is not inlined is compiled without the target
    /// features of the front end this is inlined into (ADR 0016, amendment 1), and perf showed
    /// the inertial subtraction as such a closure.
    #[inline(always)]
    pub(crate) fn twice_descending(
        &self,
        state: &mut TwiceDescending,
        from: usize,
        input: &[f64],
        first: &mut [f64],
        second: &mut [f64],
    ) -> Option<(bool, std::ops::Range<usize>)> {
        let len = input.len();
        let m = self.half_length;
        let width = 2 * m + 1;
        if first.len() != len || second.len() != len || len < width {
            return None;
        }
        let st = state.at_length(len, m);
        let from = from.min(len);
        // First derivative: output i reads input[i - M ..= i + M].
        if !st.first_right && from <= len - width {
            self.edge_right(input, first);
            st.first_right = true;
        }
        if st.first_right {
            let lo = (from + m).clamp(m, st.first_lo);
            if lo < st.first_lo {
                self.interior_block(input, first, lo..st.first_lo);
                st.first_lo = lo;
            }
            if from == 0 && !st.first_left {
                self.edge_left(input, first);
                st.first_left = true;
            }
        }
        // first[ready..] is computed.
        let ready = match (st.first_right, st.first_left) {
            (false, _) => len,
            (true, true) if st.first_lo <= m => 0,
            (true, _) => st.first_lo,
        };
        // Second derivative, from `first` in the same way: the right edge, the interior below
        // what is done, the left edge, each only once its inputs are, so each piece ends where
        // the one before it (in this call or the last) starts.
        // second[done..] was handed on by earlier calls.
        let done = if st.second_left {
            0
        } else if st.second_right {
            st.second_lo
        } else {
            len
        };
        let mut made = done..done;
        if !st.second_right && ready <= len - width {
            self.edge_right(first, second);
            made.start = len - m;
            st.second_right = true;
        }
        if ready < len {
            let lo = (ready + m).clamp(m, st.second_lo);
            if lo < st.second_lo {
                self.interior_block(first, second, lo..st.second_lo);
                made.start = lo;
                st.second_lo = lo;
            }
        }
        if ready == 0 && !st.second_left {
            self.edge_left(first, second);
            made.start = 0;
            st.second_left = true;
        }
        Some((all_finite(&second[made.clone()]), made))
    }

    /// Differentiates `input` twice, as the paper does: `first` is its derivative and
    /// `second` the derivative of `first` (all three the same length, at least `2M + 1`).
    /// The same result, bit for bit, as two calls of [`SavitzkyGolayDerivative::apply_into`],
    /// but the second pass follows the first block by block while `first` is still in cache,
    /// so the columns cross memory once each.
    pub fn apply_twice_into(
        &self,
        input: &[f64],
        first: &mut [f64],
        second: &mut [f64],
    ) -> Result<(), IdentificationError> {
        self.apply_twice_into_finite(input, first, second).map(|_| ())
    }

    /// [`SavitzkyGolayDerivative::apply_twice_into`], telling whether every sample of
    /// `second` is finite (checked block by block while it is in cache).
    pub(crate) fn apply_twice_into_finite(
        &self,
        input: &[f64],
        first: &mut [f64],
        second: &mut [f64],
    ) -> Result<bool, IdentificationError> {
        self.apply_twice_each(input, first, second, |_, _| {})
    }

    /// [`SavitzkyGolayDerivative::apply_twice_into_finite`], calling `each(range, block)` as
    /// each block of `second` becomes final (`block` is `second[range]`; the ranges cover the
    /// column once, the interior in increasing order, then the two ends), so that a
    /// consumer can use it while it is in cache.
    pub(crate) fn apply_twice_each(
        &self,
        input: &[f64],
        first: &mut [f64],
        second: &mut [f64],
        mut each: impl FnMut(std::ops::Range<usize>, &[f64]),
    ) -> Result<bool, IdentificationError> {
        let len = input.len();
        let m = self.half_length;
        if first.len() != len || second.len() != len || len < 2 * m + 1 {
            // The one-pass path reports the mismatch.
            self.apply_into(input, first)?;
            self.apply_into(first, second)?;
            each(0..len, second);
            return Ok(all_finite(second));
        }
        let mut finite = true;
        self.edges(input, first);
        let mut start = m;
        let mut done = m;
        while start < len - m {
            let end = (start + BLOCK).min(len - m);
            self.interior_block(input, first, start..end);
            start = end;
            // first[..end] and first[len - m..] are final: second[i] needs first[i - M..=i + M].
            let upto = if end == len - m { len - m } else { end - m };
            if upto > done {
                self.interior_block(first, second, done..upto);
                finite &= all_finite(&second[done..upto]);
                each(done..upto, &second[done..upto]);
                done = upto;
            }
        }
        self.edges(first, second);
        each(0..m, &second[..m]);
        each(len - m..len, &second[len - m..]);
        Ok(finite && all_finite(&second[..m]) && all_finite(&second[len - m..]))
    }

    /// Differentiates, allocating the output.
    pub fn apply(&self, input: &[f64]) -> Result<Vec<f64>, IdentificationError> {
        let mut out = vec![0.0; input.len()];
        self.apply_into(input, &mut out)?;
        Ok(out)
    }
}

/// How far [`SavitzkyGolayDerivative::twice_descending`] has got on one column.
#[derive(Clone, Debug, Default)]
pub(crate) struct TwiceDescending {
    /// The column length and `M` the rest refers to (`None`: not started).
    shape: Option<(usize, usize)>,
    /// Interior outputs `first_lo .. len - M` of the first derivative are computed, and the
    /// `M` at its right (left) end when `first_right` (`first_left`); likewise the second.
    first_lo: usize,
    first_right: bool,
    first_left: bool,
    second_lo: usize,
    second_right: bool,
    second_left: bool,
}

impl TwiceDescending {
    /// The state, started afresh if it was for another shape.
    fn at_length(&mut self, len: usize, m: usize) -> &mut Self {
        if self.shape != Some((len, m)) {
            *self = Self {
                shape: Some((len, m)),
                first_lo: len - m,
                second_lo: len - m,
                ..Self::default()
            };
        }
        self
    }
}

/// One-call derivative (per second) of one channel's samples at `sample_rate_hz` with a
/// Savitzky-Golay FIR of half-length `half_length`. NaN input is a `BadInput`.
pub fn fir_derivative(
    channel: ChannelId,
    column: &[f64],
    half_length: usize,
    sample_rate_hz: f64,
) -> Result<Vec<f64>, IdentificationError> {
    if let Some(i) = first_non_finite(column) {
        return Err(super::non_finite_error(channel, i, column[i], "sample"));
    }
    SavitzkyGolayDerivative::new(half_length, sample_rate_hz)?.apply(column)
}

/// One interior output, `sum_k c[k-1] (x[i+k] - x[i-k])` for k = 1..=M, summed in the order
/// the vector kernels use (so their scalar tails give the same bits as their lanes).
#[inline(always)]
fn interior_point<const M: usize>(c: &[f64; M], x: &[f64], i: usize) -> f64 {
    let mut acc = c[0] * (x[i + 1] - x[i - 1]);
    for k in 2..M + 1 {
        acc += c[k - 1] * (x[i + k] - x[i - k]);
    }
    acc
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The descending form, fed `from` in irregular steps (one sample, a few, a block and
    /// more, as the low-pass's chunks and a record's end may fall), gives `apply_twice_each`'s
    /// two derivatives bit for bit, and hands each sample of `second` on exactly once.
    #[test]
    fn twice_descending_equals_apply_twice_each_bit_for_bit() {
        let mut state = 0x9e3779b97f4a7c15u64;
        let mut uniform = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for m in [2, 4, 5, 6, 7] {
            let sg = SavitzkyGolayDerivative::new(m, 5000.0).unwrap();
            for len in [2 * m + 1, 2 * m + 2, 4 * m + 3, 50, 1000, 1237] {
                let x: Vec<f64> = (0..len).map(|_| uniform() - 0.5).collect();
                let (mut f1, mut s1) = (vec![0.0; len], vec![0.0; len]);
                assert!(sg.apply_twice_each(&x, &mut f1, &mut s1, |_, _| {}).unwrap());
                let (mut f2, mut s2) = (vec![f64::NAN; len], vec![f64::NAN; len]);
                let mut seen = vec![0u32; len];
                let mut st = TwiceDescending::default();
                let mut from = len;
                while from > 0 {
                    let step = [1, 3, 512, 17, 2 * m + 1][(uniform() * 5.0) as usize % 5];
                    from = from.saturating_sub(step);
                    let (ok, made) = sg.twice_descending(&mut st, from, &x, &mut f2, &mut s2).expect("same lengths");
                    assert!(ok, "M {m}, len {len}, from {from}");
                    for i in made {
                        seen[i] += 1;
                        assert!(!s2[i].is_nan(), "M {m}, len {len}: sample {i} handed on before it was computed");
                    }
                }
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert!(bits(&f1) == bits(&f2), "first, M {m}, len {len}");
                assert!(bits(&s1) == bits(&s2), "second, M {m}, len {len}");
                assert!(seen.iter().all(|&c| c == 1), "M {m}, len {len}: {seen:?}");
            }
        }
        // Mismatched lengths are refused, not half computed.
        let sg = SavitzkyGolayDerivative::new(5, 5000.0).unwrap();
        let mut st = TwiceDescending::default();
        assert_eq!(sg.twice_descending(&mut st, 0, &[0.0; 20], &mut [0.0; 19], &mut [0.0; 20]), None);
    }
}
