//! Step 6 of Zhou et al. (2004), section 3.1: velocity from displacement with a differential
//! FIR filter, then acceleration from velocity with the same filter.
//!
//! The filter is the Savitzky-Golay first derivative of degree [`DEGREE`]; its weights are
//! antisymmetrised after the solve, so that its response is exactly the +90 degrees of an
//! ideal differentiator, to the last bit. Near either end the window is one-sided (after
//! Gorry), and the conditioning trims `2M` from [`super::Conditioned::valid`], one `M` per
//! pass.
//!
//! Gain error table, window choice and literature:
//! docs/manual/conditioning.md#step-6-velocity-and-acceleration.

use std::ops::Range;

use crate::estimator::qr::{inverse_gram_from_upper, Triangle};
use crate::simd::{all_finite, Simd};
use crate::IdentificationError;

/// Degree of the least-squares polynomial.
pub const DEGREE: usize = 4;

/// Longest half-length accepted.
pub const MAX_HALF_LENGTH: usize = 64;

/// Least-squares derivative weights (per sample) for a window of `w.len()` consecutive
/// samples, the slope taken at window position `eval` (0-based, may be fractional).
fn ls_derivative_weights(eval: f64, w: &mut [f64]) -> Result<(), IdentificationError> {
    let len = w.len();
    let p = DEGREE + 1;
    let centre = 0.5 * (len as f64 - 1.0);
    let half = centre.max(1.0);
    // The polynomial's basis in the scaled abscissa u = (i - centre) / half, in [-1, 1]; the
    // weights are `V (VᵀV)⁻¹ d` for the slope functional `d`, (VᵀV)⁻¹ = R⁻¹R⁻ᵀ from the
    // estimator's Householder factor (the crate's one least-squares core).
    let basis: Vec<Vec<f64>> = (0..p).map(|j| (0..len).map(|i| ((i as f64 - centre) / half).powi(j as i32)).collect()).collect();
    let mut block: Vec<f64> = basis.concat();
    let mut t = Triangle::zeros(p);
    t.absorb(&mut block, len);
    t.make_diagonal_nonnegative();
    let u0 = (eval - centre) / half;
    let d: Vec<f64> = (0..p).map(|j| if j == 0 { 0.0 } else { j as f64 * u0.powi(j as i32 - 1) }).collect();
    let Some(g) = inverse_gram_from_upper(&t.leading(p), p).filter(|g| g.iter().all(|v| v.is_finite())) else {
        return Err(IdentificationError::invalid(
            "conditioning.differentiator_half_length",
            format!("a {len}-sample window cannot fit a degree-{DEGREE} polynomial"),
        ));
    };
    let v: Vec<f64> = (0..p).map(|r| (0..p).map(|c| g[r * p + c] * d[c]).sum()).collect();
    for (i, wi) in w.iter_mut().enumerate() {
        let u = (i as f64 - centre) / half;
        let mut pw = 1.0;
        let mut s = 0.0;
        for &vj in &v {
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

impl SavitzkyGolayDerivative {
    /// Designs the filter; `2 <= half_length <= MAX_HALF_LENGTH` (a degree-4 fit needs at
    /// least 5 samples).
    pub fn new(half_length: usize, sample_rate_hz: f64) -> Result<Self, IdentificationError> {
        if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
            return Err(IdentificationError::invalid("sample_rate_hz", format!("must be finite and > 0, got {sample_rate_hz}")));
        }
        let min = DEGREE.div_ceil(2);
        if !(min..=MAX_HALF_LENGTH).contains(&half_length) {
            return Err(IdentificationError::invalid(
                "conditioning.differentiator_half_length",
                format!("must be in {min}..={MAX_HALF_LENGTH} (a degree-{DEGREE} fit needs {} samples), got {half_length}", DEGREE + 1),
            ));
        }
        let m = half_length;
        let width = 2 * m + 1;
        let mut w = vec![0.0; width];
        ls_derivative_weights(m as f64, &mut w)?;
        let interior = (1..=m).map(|k| 0.5 * (w[m + k] - w[m - k]) * sample_rate_hz).collect();
        // `M` rows of weights per second, the slope taken at window positions `first ..`.
        let edge = |first: usize| -> Result<Vec<f64>, IdentificationError> {
            let mut rows = vec![0.0; m * width];
            for (r, row) in rows.chunks_exact_mut(width).enumerate() {
                ls_derivative_weights((first + r) as f64, row)?;
                row.iter_mut().for_each(|v| *v *= sample_rate_hz);
            }
            Ok(rows)
        };
        let (left, right) = (edge(0)?, edge(m + 1)?);
        Ok(Self { half_length: m, sample_rate_hz, interior, left, right })
    }

    pub fn half_length(&self) -> usize {
        self.half_length
    }

    /// `c_1 .. c_M` in 1/s: `out[n] = sum_k c_k (x[n+k] - x[n-k])`.
    pub fn coefficients(&self) -> &[f64] {
        &self.interior
    }

    /// Relative gain error of the interior filter at `freq_hz` (> 0),
    /// `|H(w)| / w - 1`; the phase is exactly that of `j w` by antisymmetry.
    pub fn gain_error(&self, freq_hz: f64) -> f64 {
        let w = 2.0 * std::f64::consts::PI * freq_hz / self.sample_rate_hz;
        let h: f64 = self.interior.iter().enumerate().map(|(i, &c)| 2.0 * c * ((i + 1) as f64 * w).sin()).sum();
        h / (2.0 * std::f64::consts::PI * freq_hz) - 1.0
    }

    /// The edge outputs' weights (per second), `M` rows of `2M + 1`: row `r` of the first
    /// gives output `r` from the first `2M + 1` inputs, row `r` of the second output
    /// `len - M + r` from the last `2M + 1`.
    pub fn edge_weights(&self) -> [&[f64]; 2] {
        [&self.left, &self.right]
    }

    /// The interior outputs `dst` centred on `x[M..]`: `x` reaches `M` past `dst` on each side.
    /// Every output is summed in the order of [`crate::simd::derivative_point`], `M` known at
    /// compile time for the usual half-lengths.
    #[inline(always)]
    pub(crate) fn interior_slices<S: Simd>(&self, simd: S, x: &[f64], dst: &mut [f64]) {
        let (m, c) = (self.half_length, &self.interior);
        let x = &x[..dst.len() + 2 * m];
        match m {
            4 => simd.derivative::<4>(&c[..].try_into().unwrap_or([0.0; 4]), x, dst),
            5 => simd.derivative::<5>(&c[..].try_into().unwrap_or([0.0; 5]), x, dst),
            6 => simd.derivative::<6>(&c[..].try_into().unwrap_or([0.0; 6]), x, dst),
            _ => {
                for (o, w) in dst.iter_mut().zip(x.windows(2 * m + 1)) {
                    *o = (2..=m).fold(c[0] * (w[m + 1] - w[m - 1]), |acc, k| acc + c[k - 1] * (w[m + k] - w[m - k]));
                }
            }
        }
    }

    /// Outputs `range` of the derivative of `input` (at least `2M + 1` samples) into `out`:
    /// an edge row within `M` of either end, the interior sum in between.
    #[inline(always)]
    fn outputs<S: Simd>(&self, simd: S, input: &[f64], out: &mut [f64], range: Range<usize>) {
        let (len, m) = (input.len(), self.half_length);
        let width = 2 * m + 1;
        let part = |a: usize, b: usize| range.start.clamp(a, b)..range.end.clamp(a, b);
        let (left, middle, right) = (part(0, m), part(m, len - m), part(len - m, len));
        // Rows `first ..` of `weights` on `inputs`, into `dst`.
        let rows = |weights: &[f64], first: usize, inputs: &[f64], dst: &mut [f64]| {
            for (o, w) in dst.iter_mut().zip(weights.chunks_exact(width).skip(first)) {
                *o = w.iter().zip(inputs).map(|(a, b)| a * b).sum();
            }
        };
        rows(&self.left, left.start, &input[..width], &mut out[left]);
        if !middle.is_empty() {
            self.interior_slices(simd, &input[middle.start - m..middle.end + m], &mut out[middle]);
        }
        rows(&self.right, right.start + m - len, &input[len - width..], &mut out[right]);
    }

    /// Both derivatives fed from the end of the record towards its start, as a backward pass
    /// makes `input` final: `input[from..]` is final, `from` decreasing from call to call and
    /// 0 in the last. Computes every output of `first` and `second` whose inputs are final and
    /// that is not computed yet. Returns whether the outputs of `second` computed in this call
    /// are finite, and their range: just below the previous call's (possibly empty), so that
    /// the ranges cover the column once when `from` has reached 0. Each output is an edge
    /// row's sum or the centred sum of [`crate::simd::derivative_point`], so the bits do not
    /// depend on the cutting. The three columns must have the same length, at least `2M + 1`;
    /// else nothing is computed and `None` returned.
    #[inline(always)]
    pub(crate) fn twice_descending<S: Simd>(
        &self,
        simd: S,
        state: &mut TwiceDescending,
        from: usize,
        input: &[f64],
        first: &mut [f64],
        second: &mut [f64],
    ) -> Option<(bool, Range<usize>)> {
        let len = input.len();
        let m = self.half_length;
        let width = 2 * m + 1;
        if first.len() != len || second.len() != len || len < width {
            return None;
        }
        if state.shape != Some((len, m)) {
            *state = TwiceDescending { shape: Some((len, m)), first: len, second: len };
        }
        // Outputs `computable(from)..` read only `x[from..]`: an interior output `i` reads
        // `x[i - M ..= i + M]`, an edge row the `2M + 1` inputs at its end of the column.
        let computable = |from: usize| match from {
            0 => 0,
            _ if from <= len - width => from + m,
            _ => len,
        };
        let first_lo = computable(from).min(state.first);
        self.outputs(simd, input, first, first_lo..state.first);
        state.first = first_lo;
        let made = computable(first_lo).min(state.second)..state.second;
        self.outputs(simd, first, second, made.clone());
        state.second = made.start;
        Some((all_finite(&second[made.clone()]), made))
    }
}

/// How far [`SavitzkyGolayDerivative::twice_descending`] has got on one column.
#[derive(Clone, Debug, Default)]
pub(crate) struct TwiceDescending {
    /// The column length and `M` the rest refers to (`None`: not started).
    shape: Option<(usize, usize)>,
    /// `first[first..]` and `second[second..]` are computed.
    first: usize,
    second: usize,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simd::Scalar;

    /// The derivative written plainly: an edge row within `M` of either end, the centred sum
    /// `sum_k c_k (x[i + k] - x[i - k])` in between.
    fn plain(sg: &SavitzkyGolayDerivative, x: &[f64]) -> Vec<f64> {
        let (n, m, c) = (x.len(), sg.half_length, &sg.interior);
        let w = 2 * m + 1;
        let row = |weights: &[f64], inputs: &[f64]| weights.iter().zip(inputs).map(|(a, b)| a * b).sum::<f64>();
        (0..n)
            .map(|i| match i {
                _ if i < m => row(&sg.left[i * w..(i + 1) * w], &x[..w]),
                _ if i >= n - m => row(&sg.right[(i + m - n) * w..(i + m - n + 1) * w], &x[n - w..]),
                _ => (2..=m).fold(c[0] * (x[i + 1] - x[i - 1]), |acc, k| acc + c[k - 1] * (x[i + k] - x[i - k])),
            })
            .collect()
    }

    /// The descending form, fed `from` in irregular steps (one sample, a few, a block and
    /// more, as the low-pass's chunks and a record's end may fall), gives the plain
    /// derivative and the plain derivative of that, bit for bit, and hands each sample of
    /// `second` on exactly once.
    #[test]
    fn twice_descending_equals_two_plain_passes_bit_for_bit() {
        let mut state = 0x9e3779b97f4a7c15u64;
        let mut uniform = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for m in [2, 4, 5, 6, 7] {
            let sg = SavitzkyGolayDerivative::new(m, 5000.0).unwrap();
            for len in [2 * m + 1, 2 * m + 2, 4 * m + 3, 50, 1000, 1237] {
                let x: Vec<f64> = (0..len).map(|_| uniform() - 0.5).collect();
                let f1 = plain(&sg, &x);
                let s1 = plain(&sg, &f1);
                let (mut f2, mut s2) = (vec![f64::NAN; len], vec![f64::NAN; len]);
                let mut seen = vec![0u32; len];
                let mut st = TwiceDescending::default();
                let mut from = len;
                while from > 0 {
                    let step = [1, 3, 512, 17, 2 * m + 1][(uniform() * 5.0) as usize % 5];
                    from = from.saturating_sub(step);
                    let (ok, made) = sg.twice_descending(Scalar::token(), &mut st, from, &x, &mut f2, &mut s2).expect("same lengths");
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
        assert_eq!(sg.twice_descending(Scalar::token(), &mut st, 0, &[0.0; 20], &mut [0.0; 19], &mut [0.0; 20]), None);
    }
}
