//! Multisine design: which harmonics of `1/period_s` a multisine uses, their Schroeder phases,
//! and the signal over one period (by an inverse FFT) to find its true peak.
//!
//! References:
//! * M. R. Schroeder (1970), "Synthesis of low-peak-factor signals and binary sequences with
//!   low autocorrelation", IEEE Trans. Inf. Theory 16(1), 85-89: for `N` equal-amplitude
//!   lines, the phases `phi_k = -pi k (k - 1) / N` (`k = 1..N`) give a low peak factor.
//! * R. Pintelon and J. Schoukens, "System Identification: A Frequency Domain Approach"
//!   (IEEE Press/Wiley), chapter on periodic excitation design: lines on the grid `k / T`,
//!   odd/even line sets, crest factor, and why an integer number of periods in a window is
//!   leakage-free.
//!
//! Here `k` in Schroeder's formula is the *index of the line within the exciter's line set*
//! (1, 2, ..., N), not its harmonic number: for an odd-only or even-only set this keeps the
//! phase quadratic in frequency, which is what makes the peak factor low (with harmonic numbers
//! an odd set of 40 lines has a crest factor near 2.9 instead of 1.7).

use std::f64::consts::PI;

use rustfft::num_complex::Complex;

use super::LineSet;

/// The highest harmonic number a multisine may use (`band_hz[1] * period_s`): at 80 Hz a
/// period of up to 51 s (0.02 Hz resolution), far more than a 10 s record resolves. It bounds
/// the work of evaluating the waveform (three complex products per line per call of
/// `force_at`: about 20 µs for 2048 lines measured on a loaded 2-core machine, inside a 5 kHz
/// setpoint period) and of finding its peak at validation (under a second).
pub const MAX_HARMONIC: u64 = 4096;

/// Largest number of points over one period used to find the peak (an FFT of this size).
const MAX_PEAK_POINTS: usize = 1 << 22;

/// Relative tolerance used when deciding whether a frequency lies on a band edge: `k / T` is
/// computed in floating point and must not fall out of a band it sits exactly on.
pub(crate) const EDGE_TOLERANCE: f64 = 1e-9;

/// Whether `f` lies in `[lo, hi]`, with [`EDGE_TOLERANCE`] on both edges.
pub(crate) fn in_band(f: f64, band: [f64; 2]) -> bool {
    let slack = |x: f64| EDGE_TOLERANCE * x.abs().max(1.0);
    f >= band[0] - slack(band[0]) && f <= band[1] + slack(band[1])
}

/// The lines of a multisine as an arithmetic progression of harmonic numbers: `first`,
/// `first + step`, ... (`count` of them, `count >= 1`, step 1 for all lines, 2 for odd or even).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Lines {
    pub first: u64,
    pub step: u64,
    pub count: u64,
}

impl Lines {
    /// The harmonic numbers, ascending.
    pub fn iter(self) -> impl Iterator<Item = u64> {
        (0..self.count).map(move |j| self.first + j * self.step)
    }
}

/// The harmonics `k >= 1` with `k / period_s` inside `band_hz` that belong to `set`. Refuses
/// (with a reason) malformed parameters, an empty set and sets that reach beyond
/// [`MAX_HARMONIC`]. Allocates nothing.
pub(crate) fn lines(band_hz: [f64; 2], period_s: f64, set: LineSet) -> Result<Lines, String> {
    if !(period_s.is_finite() && period_s > 0.0) {
        return Err(format!("period_s must be finite and positive, got {period_s}"));
    }
    let [lo, hi] = band_hz;
    if !(lo.is_finite() && hi.is_finite() && lo >= 0.0 && lo <= hi) {
        return Err(format!("band_hz must be finite with 0 <= low <= high, got [{lo}, {hi}]"));
    }
    let lo_k = lo * period_s;
    let hi_k = hi * period_s;
    let hi_k = (hi_k + EDGE_TOLERANCE * hi_k.max(1.0)).floor();
    if hi_k > MAX_HARMONIC as f64 {
        return Err(format!(
            "band_hz[1] * period_s = {} harmonics exceeds the limit of {MAX_HARMONIC}; \
             shorten period_s or narrow the band",
            hi * period_s
        ));
    }
    let lo_k = (lo_k - EDGE_TOLERANCE * lo_k.max(1.0)).ceil().max(1.0);
    // Both are now integers in [1, MAX_HARMONIC] or hi_k = 0: the casts are exact.
    let (k_lo, k_hi) = (lo_k as u64, hi_k as u64);
    let (first, step) = match set {
        LineSet::All => (k_lo, 1),
        LineSet::Odd => (k_lo | 1, 2),
        LineSet::Even => (k_lo + (k_lo & 1), 2),
    };
    if first > k_hi {
        let which = match set {
            LineSet::All => "",
            LineSet::Odd => "odd ",
            LineSet::Even => "even ",
        };
        return Err(format!("no {which}harmonic of 1/period_s = {} Hz lies in band [{lo}, {hi}] Hz", 1.0 / period_s));
    }
    Ok(Lines { first, step, count: (k_hi - first) / step + 1 })
}

/// [`lines`] as a list.
#[cfg(test)]
pub(crate) fn harmonics(band_hz: [f64; 2], period_s: f64, set: LineSet) -> Result<Vec<u64>, String> {
    lines(band_hz, period_s, set).map(|l| l.iter().collect())
}

/// Amplitude of each of `count` lines for a given rms: distinct non-zero harmonics are
/// orthogonal over a period, so `rms^2 = N a^2 / 2`.
fn line_amplitude(rms_n: f64, count: u64) -> f64 {
    rms_n * (2.0 / count as f64).sqrt()
}

/// `(cos, sin)` of `2 pi cycles`, reduced to one cycle first.
fn cis(cycles: f64) -> (f64, f64) {
    let (s, c) = (2.0 * PI * cycles.fract()).sin_cos();
    (c, s)
}

fn mul(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    (a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0)
}

/// The multisine at time `t_s`, without allocating: `a sum_j cos(2 pi k_j u + phi_j)` with
/// `u = (t mod T) / T`, evaluated as `Re(z_j p_j)` where `z_j = exp(i 2 pi k_j u)` and the
/// Schroeder phase factor `p_j = exp(i phi_j)` are both advanced by one complex product per
/// line (`phi_(j+1) - phi_j = -2 pi (j+1) / N`). Three products per line instead of a cosine:
/// the exciter node calls this at its setpoint rate. The recurrences drift by about
/// `N * 1e-16` rad, nothing at `N <= MAX_HARMONIC`.
pub(crate) fn value(lines: Lines, rms_n: f64, period_s: f64, t_s: f64) -> f64 {
    let u = t_s.rem_euclid(period_s) / period_s;
    let n = lines.count;
    let mut z = cis(lines.first as f64 * u);
    let rotate = cis(lines.step as f64 * u);
    let mut p = (1.0, 0.0);
    let d1 = cis(-1.0 / n as f64);
    let mut d = d1;
    let mut sum = 0.0;
    for _ in 0..n {
        sum += z.0 * p.0 - z.1 * p.1;
        z = mul(z, rotate);
        p = mul(p, d);
        d = mul(d, d1);
    }
    line_amplitude(rms_n, n) * sum
}

/// Schroeder's phase of the `index`-th line (1-based) of `n` lines: `-pi index (index-1) / n`,
/// reduced modulo 2 pi in integer arithmetic so that it stays exact for large indices.
pub(crate) fn schroeder_phase(index: u64, n: u64) -> f64 {
    if n == 0 {
        return 0.0;
    }
    // index <= MAX_HARMONIC, so index * (index - 1) < 2^24: no overflow in u64.
    let m = (index * index.saturating_sub(1)) % (2 * n);
    -PI * m as f64 / n as f64
}

/// A designed multisine: harmonic numbers, their phases, the common amplitude.
#[derive(Debug, Clone)]
pub(crate) struct Design {
    pub harmonics: Vec<u64>,
    pub phases_rad: Vec<f64>,
    /// Amplitude of every line, N: `rms * sqrt(2 / N)`.
    pub amplitude_n: f64,
}

impl Design {
    pub fn new(band_hz: [f64; 2], period_s: f64, rms_n: f64, set: LineSet) -> Result<Self, String> {
        let lines = lines(band_hz, period_s, set)?;
        let n = lines.count;
        Ok(Self { harmonics: lines.iter().collect(), phases_rad: (1..=n).map(|i| schroeder_phase(i, n)).collect(), amplitude_n: line_amplitude(rms_n, n) })
    }

    /// The signal at time `t_s` for period `period_s`, one cosine per line: the reference
    /// the fast [`value`] is tested against.
    #[cfg(test)]
    fn value(&self, period_s: f64, t_s: f64) -> f64 {
        let u = t_s.rem_euclid(period_s) / period_s;
        self.harmonics.iter().zip(&self.phases_rad).map(|(&k, &phi)| (2.0 * PI * (k as f64 * u).fract() + phi).cos()).sum::<f64>() * self.amplitude_n
    }

    /// The signal at `m` equally spaced points of one period (`u = j / m`), by an inverse FFT.
    /// `m` must be a power of two above twice the highest harmonic (the callers ensure it).
    fn samples(&self, m: usize) -> Vec<f64> {
        let mut z = vec![Complex::new(0.0, 0.0); m];
        for (&k, &phi) in self.harmonics.iter().zip(&self.phases_rad) {
            let k = k as usize; // k <= MAX_HARMONIC < m / 2
            let (s, c) = phi.sin_cos();
            let half = 0.5 * self.amplitude_n;
            z[k] += Complex::new(half * c, half * s);
            z[m - k] += Complex::new(half * c, -half * s);
        }
        crate::fft::inverse(&mut z);
        z.iter().map(|c| c.re).collect()
    }

    /// Upper bound of `|second derivative|` with respect to the period fraction `u`:
    /// `a * sum (2 pi k)^2`.
    fn curvature_bound(&self) -> f64 {
        self.amplitude_n.abs() * self.harmonics.iter().map(|&k| (2.0 * PI * k as f64).powi(2)).sum::<f64>()
    }

    /// Number of points per period at which the sampled maximum is within 0.1 % of the true
    /// peak (bounded by the curvature), capped at `MAX_PEAK_POINTS`.
    fn peak_points(&self) -> usize {
        let n = self.harmonics.len() as f64;
        let k_max = self.harmonics.last().copied().unwrap_or(1) as usize;
        // The peak is at least the rms, a sqrt(N/2); ask the sampling error
        // D2 / (8 m^2) to stay below 1e-3 of that.
        let rms = self.amplitude_n.abs() * (n / 2.0).sqrt();
        let wanted = if rms > 0.0 { (self.curvature_bound() / (8.0 * 1e-3 * rms)).sqrt() } else { 0.0 };
        let floor = (4 * k_max).max(1024);
        let wanted = if wanted.is_finite() { wanted.min(MAX_PEAK_POINTS as f64) as usize } else { 0 };
        wanted.max(floor).next_power_of_two().min(MAX_PEAK_POINTS)
    }

    /// `(sampled peak, rms, honest upper bound of the peak)` over one period.
    ///
    /// Between two samples `1/m` of a period apart, the continuous signal near its maximum
    /// (where its derivative is zero) can exceed the nearest sample by at most
    /// `max|x''| (1/(2m))^2 / 2`; adding that to the sampled maximum gives a bound the true
    /// peak cannot exceed, whatever the phases.
    pub fn peak(&self) -> (f64, f64, f64) {
        let m = self.peak_points();
        let x = self.samples(m);
        let peak = x.iter().fold(0.0_f64, |acc, v| acc.max(v.abs()));
        let rms = (x.iter().map(|v| v * v).sum::<f64>() / m as f64).sqrt();
        let bound = peak + self.curvature_bound() / (8.0 * (m as f64).powi(2));
        (peak, rms, bound)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fft_matches_direct_evaluation() {
        let d = Design::new([1.0, 30.0], 1.0, 10.0, LineSet::Odd).expect("valid design");
        let m = 256;
        let l = lines([1.0, 30.0], 1.0, LineSet::Odd).expect("valid lines");
        assert!((value(l, 10.0, 1.0, 0.25) - d.value(1.0, 0.25)).abs() < 1e-12);
        let x = d.samples(m);
        for (j, v) in x.iter().enumerate() {
            let direct = d.value(1.0, j as f64 / m as f64);
            assert!((v - direct).abs() < 1e-9, "sample {j}: fft {v} direct {direct}");
        }
    }

    #[test]
    fn fast_evaluation_matches_one_cosine_per_line() {
        for (band, period, set) in [
            ([1.0, 30.0], 1.0, LineSet::Odd),
            ([0.0, 80.0], 1.0, LineSet::Even),
            ([0.3, 79.7], 10.0, LineSet::All),
            ([0.0, 80.0], MAX_HARMONIC as f64 / 80.0, LineSet::All),
        ] {
            let d = Design::new(band, period, 100.0, set).expect("valid design");
            let l = lines(band, period, set).expect("valid lines");
            let peak = d.amplitude_n * l.count as f64;
            for j in 0..500 {
                let t = 0.001_234_5 * j as f64 * j as f64;
                let (fast, slow) = (value(l, 100.0, period, t), d.value(period, t));
                assert!((fast - slow).abs() < 1e-10 * peak, "{set:?} t {t}: {fast} vs {slow}");
            }
        }
    }

    #[test]
    fn edges_are_inclusive_and_dc_is_never_a_line() {
        assert_eq!(harmonics([0.0, 3.0], 1.0, LineSet::All).unwrap(), vec![1, 2, 3]);
        assert_eq!(harmonics([0.3, 0.8], 10.0, LineSet::All).unwrap(), vec![3, 4, 5, 6, 7, 8]);
        assert_eq!(harmonics([1.0, 6.0], 1.0, LineSet::Even).unwrap(), vec![2, 4, 6]);
        assert!(harmonics([0.0, 0.5], 1.0, LineSet::All).is_err());
        assert!(harmonics([0.0, 80.0], 1e9, LineSet::All).is_err());
        assert_eq!(harmonics([2.0, 7.0], 1.0, LineSet::Odd).unwrap(), vec![3, 5, 7]);
        assert_eq!(harmonics([3.0, 7.0], 1.0, LineSet::Even).unwrap(), vec![4, 6]);
        assert!(harmonics([3.0, 3.5], 1.0, LineSet::Even).is_err());
        assert_eq!(harmonics([0.0, 0.0], 1.0, LineSet::Odd).map_err(|e| e.contains("odd")), Err(true));
    }
}
