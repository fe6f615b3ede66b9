//! Step 4 of Zhou et al. (2004), section 3.1, the paper's "inner-insert filter": the card
//! converts the channels one by one in turn, and a **fractional-delay FIR** per channel
//! (Lagrange interpolation) rebuilds simultaneous samples. The smoothing is the separate
//! [`super::lowpass`].
//!
//! The `N` taps sit on `n + s .. n + s + N - 1` with `s = ceil(-D - N/2)`, so the
//! interpolation point lies within half a sample of the stencil centre; near either end the
//! stencil is shifted to stay inside the record, and those samples are outside
//! [`super::Conditioned::valid`].
//!
//! Why Lagrange, the error table and the literature:
//! docs/manual/conditioning.md#step-4-de-skew.

use crate::IdentificationError;

/// Largest stencil accepted (beyond this Lagrange weights grow and nothing is gained).
pub const MAX_TAPS: usize = 16;

/// A Lagrange fractional-delay FIR: `out[n] = in(n - delay_samples)`.
#[derive(Clone, Debug, PartialEq)]
pub struct FractionalDelay {
    delay_samples: f64,
    /// Stencil start relative to `n` for the interior.
    start: isize,
    /// Interior weights, for `in[n + start + j]`.
    weights: Vec<f64>,
}

/// Lagrange weights for nodes `first, first + 1, ..` (`w.len()` of them) evaluated at `p`.
fn lagrange_weights(first: isize, p: f64, w: &mut [f64]) {
    let n = w.len() as isize;
    for (j, wj) in w.iter_mut().enumerate() {
        let xj = (first + j as isize) as f64;
        let mut v = 1.0;
        for m in 0..n {
            if m != j as isize {
                let xm = (first + m) as f64;
                v *= (p - xm) / (xj - xm);
            }
        }
        *wj = v;
    }
}

impl FractionalDelay {
    /// A delay of `delay_samples` (finite, `|D| <= 1e6`) with a `taps`-point Lagrange
    /// stencil, `2 <= taps <= MAX_TAPS`.
    pub fn new(delay_samples: f64, taps: usize) -> Result<Self, IdentificationError> {
        if !(2..=MAX_TAPS).contains(&taps) {
            return Err(IdentificationError::invalid("conditioning.deskew_taps", format!("must be in 2..={MAX_TAPS}, got {taps}")));
        }
        if !(delay_samples.is_finite() && delay_samples.abs() <= 1.0e6) {
            return Err(IdentificationError::invalid("deskew delay", format!("must be finite and at most 1e6 samples, got {delay_samples}")));
        }
        // |D| <= 1e6, so the ceiling is an exact small integer.
        let start = (-delay_samples - 0.5 * taps as f64).ceil() as isize;
        let mut weights = vec![0.0; taps];
        lagrange_weights(start, -delay_samples, &mut weights);
        Ok(Self { delay_samples, start, weights })
    }

    /// No delay: one tap of weight 1 (what a chain without de-skew runs, so that its front end
    /// is the same code; `1 x = x` exactly).
    pub(crate) fn identity() -> Self {
        Self { delay_samples: 0.0, start: 0, weights: vec![1.0] }
    }

    /// The filter for a channel converted `offset_s` after the scan start, at `sample_rate_hz`.
    pub fn for_offset(offset_s: f64, sample_rate_hz: f64, taps: usize) -> Result<Self, IdentificationError> {
        Self::new(offset_s * sample_rate_hz, taps)
    }

    /// Number of taps.
    pub fn taps(&self) -> usize {
        self.weights.len()
    }

    /// Interior weights, applied to `in[n + stencil_start() + j]`.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// Start of the interior stencil relative to the output index.
    pub fn stencil_start(&self) -> isize {
        self.start
    }

    /// Samples at each end computed with a shifted stencil (outside the valid range).
    pub fn edge_samples(&self) -> usize {
        let last = self.start + self.weights.len() as isize - 1;
        self.start.unsigned_abs().max(last.unsigned_abs())
    }

    /// Complex error of the interior filter at `freq_hz` for `sample_rate_hz`:
    /// `(|H| - 1, arg(H e^{+jwD}))`, i.e. relative amplitude error and phase error (rad)
    /// against the ideal delay `e^{-jwD}`.
    pub fn error_at(&self, freq_hz: f64, sample_rate_hz: f64) -> (f64, f64) {
        let w = 2.0 * std::f64::consts::PI * freq_hz / sample_rate_hz;
        // H(w) = sum_j h_j e^{jw(start + j)} for the input e^{jwn}; divide by e^{-jwD}.
        let (mut re, mut im) = (0.0, 0.0);
        for (j, &h) in self.weights.iter().enumerate() {
            let phi = w * ((self.start + j as isize) as f64 + self.delay_samples);
            re += h * phi.cos();
            im += h * phi.sin();
        }
        (re.hypot(im) - 1.0, im.atan2(re))
    }

    /// Output indices `lo..hi` whose interior stencil lies inside a record of `len >= taps`
    /// samples; the others are [`FractionalDelay::edge_value`]s.
    pub(crate) fn interior(&self, len: usize) -> std::ops::Range<usize> {
        let lo = (-self.start).max(0) as usize;
        let hi = (len as isize - self.start - self.weights.len() as isize + 1).clamp(0, len as isize) as usize;
        lo..hi
    }

    /// Output `n` of a record of `len >= taps` samples with the stencil shifted inside
    /// `[0, len)`; `input(i)` is input sample `i`.
    pub fn edge_value(&self, n: usize, len: usize, input: impl Fn(usize) -> f64) -> f64 {
        let taps = self.weights.len();
        let mut w = [0.0; MAX_TAPS];
        let w = &mut w[..taps];
        let first = (n as isize + self.start).clamp(0, (len - taps) as isize);
        lagrange_weights(first, n as f64 - self.delay_samples, w);
        let first = first as usize;
        w.iter().enumerate().map(|(j, a)| a * input(first + j)).sum()
    }
}

/// The de-skew stencil over a tile: `dst[i] = w[0] x[i] + w[1] x[i + 1] + ...`, summed in
/// that order. The default four taps are summed in registers and each output stored once;
/// other lengths take a pass over the tile per tap, the same sums.
#[inline(always)]
pub(crate) fn stencil(w: &[f64], x: &[f64], dst: &mut [f64]) {
    if let Ok(w) = <&[f64; 4]>::try_from(w) {
        for (o, xs) in dst.iter_mut().zip(x.windows(4)) {
            *o = w[0] * xs[0] + w[1] * xs[1] + w[2] * xs[2] + w[3] * xs[3];
        }
        return;
    }
    let m = dst.len();
    for (o, &x) in dst.iter_mut().zip(&x[..m]) {
        *o = w[0] * x;
    }
    for (j, &wj) in w.iter().enumerate().skip(1) {
        for (o, &x) in dst.iter_mut().zip(&x[j..j + m]) {
            *o += wj * x;
        }
    }
}
