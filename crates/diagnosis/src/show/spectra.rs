//! Spectral helpers of the show: Welch power spectra, single-line phasors and the named
//! components of a residual spectrum. Plain arithmetic on slices; the FFT is the
//! identification crate's radix-2 one.

use oilfilm_identification::estimator::spectrum;

/// A one-sided Welch power spectrum: Hann-tapered segments with 50 % overlap, each segment's
/// mean removed. `power[k]` is the power (signal units squared) of bin `k`, scaled so that a
/// sinusoid of amplitude `A` centred on a bin shows `A^2 / 2` summed over its main lobe
/// (`±2` bins for Hann), and white noise of variance `s^2` shows `s^2 / bins` per bin.
#[derive(Debug, Clone)]
pub(crate) struct Welch {
    pub resolution_hz: f64,
    pub power: Vec<f64>,
}

/// Half-width of the Hann main lobe, bins.
pub(crate) const LOBE: usize = 2;

/// The largest power of two not above `n`, capped at `max`.
pub(crate) fn segment_len(n: usize, max: usize) -> usize {
    let mut s = 1usize;
    while s * 2 <= n && s * 2 <= max {
        s *= 2;
    }
    s
}

/// Welch spectra of several equally long signals on one segment length (`segment` a power of
/// two not longer than the signals). Empty power vectors when a signal is too short.
pub(crate) fn welch(signals: &[&[f64]], segment: usize, sample_rate_hz: f64) -> Vec<Welch> {
    let n = signals.iter().map(|s| s.len()).min().unwrap_or(0);
    if segment < 8 || !segment.is_power_of_two() || n < segment {
        return signals.iter().map(|_| Welch { resolution_hz: sample_rate_hz / segment.max(1) as f64, power: Vec::new() }).collect();
    }
    let taper: Vec<f64> = (0..segment).map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / segment as f64).cos()).collect();
    let taper_energy: f64 = taper.iter().map(|w| w * w).sum();
    let (tc, ts) = spectrum::twiddles(segment);
    let hop = segment / 2;
    let count = (n - segment) / hop + 1;
    let bins = segment / 2 + 1;
    let mut out = Vec::with_capacity(signals.len());
    let mut re = vec![0.0; segment];
    let mut im = vec![0.0; segment];
    for s in signals {
        let mut power = vec![0.0; bins];
        for k in 0..count {
            let seg = &s[k * hop..k * hop + segment];
            let mean = seg.iter().sum::<f64>() / segment as f64;
            for i in 0..segment {
                re[i] = (seg[i] - mean) * taper[i];
                im[i] = 0.0;
            }
            spectrum::fft_with(&mut re, &mut im, &tc, &ts);
            for (b, p) in power.iter_mut().enumerate() {
                // One-sided: double every bin but DC and Nyquist.
                let two = if b == 0 || b == segment / 2 { 1.0 } else { 2.0 };
                *p += two * (re[b] * re[b] + im[b] * im[b]);
            }
        }
        // Parseval: sum over bins of |X|^2 / (N * sum w^2) is the variance of the tapered
        // signal scaled back; dividing by N * sum(w^2) makes the bins sum to the variance.
        let scale = 1.0 / (count as f64 * segment as f64 * taper_energy);
        for p in &mut power {
            *p *= scale;
        }
        out.push(Welch { resolution_hz: sample_rate_hz / segment as f64, power });
    }
    out
}

impl Welch {
    /// Bin nearest to `f_hz`, if inside the spectrum.
    pub fn bin(&self, f_hz: f64) -> Option<usize> {
        let b = (f_hz / self.resolution_hz).round();
        (b >= 0.0 && (b as usize) < self.power.len()).then_some(b as usize)
    }

    /// Power of the line at `f_hz`: the sum over the main lobe around the nearest bin.
    pub fn line_power(&self, f_hz: f64) -> Option<f64> {
        let b = self.bin(f_hz)?;
        let lo = b.saturating_sub(LOBE);
        let hi = (b + LOBE).min(self.power.len() - 1);
        Some(self.power[lo..=hi].iter().sum())
    }

    /// The largest single bin within the main lobe around `f_hz`.
    pub fn peak_bin_power(&self, f_hz: f64) -> Option<f64> {
        let b = self.bin(f_hz)?;
        let lo = b.saturating_sub(LOBE);
        let hi = (b + LOBE).min(self.power.len() - 1);
        Some(self.power[lo..=hi].iter().copied().fold(0.0, f64::max))
    }

    /// Median bin power over `[lo_hz, hi_hz]`, skipping the main lobes of `exclude_hz`.
    pub fn floor(&self, lo_hz: f64, hi_hz: f64, exclude_hz: &[f64]) -> Option<f64> {
        let excluded: Vec<usize> = exclude_hz.iter().filter_map(|&f| self.bin(f)).collect();
        let mut v: Vec<f64> = (0..self.power.len())
            .filter(|&b| {
                let f = b as f64 * self.resolution_hz;
                f >= lo_hz && f <= hi_hz && !excluded.iter().any(|&e| b.abs_diff(e) <= LOBE + 1)
            })
            .map(|b| self.power[b])
            .collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        Some(v[v.len() / 2])
    }
}

/// Hann-weighted phasor of `signal` at `f_hz` over its samples (`t = i / fs` from the first
/// sample): amplitude and phase of `A cos(w t + phi)`. Leakage between lines further apart
/// than two record-length bins is below the Hann sidelobes (-31 dB and falling).
pub(crate) fn phasor(signal: &[f64], f_hz: f64, sample_rate_hz: f64) -> (f64, f64) {
    let n = signal.len();
    if n < 2 {
        return (f64::NAN, f64::NAN);
    }
    let mean = signal.iter().sum::<f64>() / n as f64;
    let w = 2.0 * std::f64::consts::PI * f_hz / sample_rate_hz;
    let (step_c, step_s) = (w.cos(), w.sin());
    let (mut c, mut s) = (1.0f64, 0.0f64);
    let (mut re, mut im, mut wsum) = (0.0, 0.0, 0.0);
    for (i, &v) in signal.iter().enumerate() {
        let taper = 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / (n - 1) as f64).cos();
        re += taper * (v - mean) * c;
        im -= taper * (v - mean) * s;
        wsum += taper;
        // Rotate by w; renormalise now and then against rounding drift.
        let (nc, ns) = (c * step_c - s * step_s, s * step_c + c * step_s);
        c = nc;
        s = ns;
        if i % 1024 == 1023 {
            let r = c.hypot(s);
            c /= r;
            s /= r;
        }
    }
    let (re, im) = (2.0 * re / wsum, 2.0 * im / wsum);
    (re.hypot(im), im.atan2(re).to_degrees())
}

/// Wraps an angle in degrees to (-180, 180].
pub(crate) fn wrap_deg(a: f64) -> f64 {
    let mut r = a % 360.0;
    if r <= -180.0 {
        r += 360.0;
    } else if r > 180.0 {
        r -= 360.0;
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn welch_line_power_is_half_the_squared_amplitude_and_phasor_recovers_a_sine() {
        let fs = 1000.0;
        let f = 50.0 * fs / 4096.0 * 4.0; // on a bin of a 1024 segment
        let x: Vec<f64> = (0..20_000).map(|i| 3.0 * (2.0 * std::f64::consts::PI * f * i as f64 / fs + 0.5).cos()).collect();
        let w = &welch(&[&x], 1024, fs)[0];
        let p = w.line_power(f).unwrap();
        assert!((p - 4.5).abs() < 0.05, "line power {p}");
        let (a, ph) = phasor(&x, f, fs);
        assert!((a - 3.0).abs() < 1e-3, "amplitude {a}");
        assert!((ph - 0.5f64.to_degrees()).abs() < 0.05, "phase {ph}");
    }

    #[test]
    fn wrap_keeps_angles_in_the_half_open_interval() {
        assert_eq!(wrap_deg(190.0), -170.0);
        assert_eq!(wrap_deg(-180.0), 180.0);
        assert_eq!(wrap_deg(45.0), 45.0);
    }
}
