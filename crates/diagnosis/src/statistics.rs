//! The tests behind a verdict: the chi-square tail of a nested-model likelihood-ratio test,
//! the BIC difference, and the line-structure test that says whether a residual still holds
//! excitation-locked content (model error) or only noise.
//!
//! The incomplete gamma function follows Numerical Recipes (Press et al., 3rd ed., section
//! 6.2): series below `a + 1`, Lentz's continued fraction above.

use std::f64::consts::PI;

/// `ln Gamma(x)`, `x > 0` (Lanczos, g = 7, n = 9; about 15 digits).
fn ln_gamma(x: f64) -> f64 {
    const G: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection.
        return (PI / (PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = G[0];
    let t = x + 7.5;
    for (i, g) in G.iter().enumerate().skip(1) {
        a += g / (x + i as f64);
    }
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Regularised upper incomplete gamma `Q(a, x)`.
fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let gln = ln_gamma(a);
    if x < a + 1.0 {
        let (mut sum, mut del, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..500 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        1.0 - sum * (-x + a * x.ln() - gln).exp()
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..500 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        (-x + a * x.ln() - gln).exp() * h
    }
}

/// The error function, `erf(x) = sign(x) P(1/2, x^2)`.
pub fn erf(x: f64) -> f64 {
    let p = 1.0 - gamma_q(0.5, x * x);
    if x < 0.0 {
        -p
    } else {
        p
    }
}

/// Upper tail of the chi-square distribution with `dof` degrees of freedom.
pub fn chi2_sf(x: f64, dof: f64) -> f64 {
    if !(x.is_finite()) {
        return if x > 0.0 { 0.0 } else { 1.0 };
    }
    gamma_q(0.5 * dof, 0.5 * x).clamp(0.0, 1.0)
}

/// Likelihood-ratio test of a model with `extra` more parameters than the baseline, on `rows`
/// Gaussian rows: `n ln(SSE0 / SSE1) ~ chi2(extra)` under the baseline. Returns the p-value.
pub fn likelihood_ratio_p(sse_baseline: f64, sse_model: f64, rows: usize, extra: usize) -> f64 {
    if extra == 0 || sse_model.is_nan() || sse_model <= 0.0 {
        return 1.0;
    }
    let stat = rows as f64 * (sse_baseline / sse_model).ln();
    if stat <= 0.0 {
        return 1.0;
    }
    chi2_sf(stat, extra as f64)
}

/// `BIC(model) - BIC(baseline)`; negative favours the model.
pub fn delta_bic(sse_baseline: f64, sse_model: f64, rows: usize, extra: usize) -> f64 {
    let n = rows as f64;
    n * (sse_model / sse_baseline).ln() + extra as f64 * n.ln()
}

/// Residual power at the excitation lines against the power between them.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LineStructure {
    /// Mean power at the lines over mean power between them (1 for a noise-only residual).
    pub ratio: f64,
    /// Probability of a ratio this large from noise alone (F distribution, large-sample
    /// chi-square approximation of the numerator).
    pub p_value: f64,
    /// Line-locked residual amplitude (excess over the between-line floor) relative to the
    /// film force at the same lines.
    pub relative_amplitude: f64,
    pub lines: usize,
    /// Displacement power at the lines over the power between them: the motion's own
    /// signal-to-noise ratio (below ~10 the line fit itself is biased by the noise).
    pub motion_snr: f64,
}

/// Phasor of `v` at `f` (sampled at `t`): `(2 / sum w) sum w v e^{-i w t}` as (re, im), with
/// `w` a Hann window or none. Over a whole number of the lines' common period the plain sum
/// keeps every line and every probe between them orthogonal; otherwise the Hann window keeps
/// a strong line's leakage out of a probe half a line spacing away (with a plain sum over a
/// record that is not a whole number of periods, the sidelobes of many lines would fill the
/// floor between them, about 20 dB down for 0.5 Hz offsets in a 6 s record).
fn phasor_windowed(v: &[f64], t: &[f64], f: f64, hann: bool) -> (f64, f64) {
    let w = 2.0 * PI * f;
    let n = v.len();
    let (mut re, mut im, mut sum) = (0.0, 0.0, 0.0);
    for (i, (x, &ti)) in v.iter().zip(t).enumerate() {
        let h = if hann && n > 1 { 0.5 - 0.5 * (2.0 * PI * i as f64 / (n - 1) as f64).cos() } else { 1.0 };
        let (s, c) = (w * ti).sin_cos();
        re += h * x * c;
        im -= h * x * s;
        sum += h;
    }
    let k = 2.0 / sum.max(f64::MIN_POSITIVE);
    (re * k, im * k)
}

/// `v` less its least-squares fit by a constant and a sine and cosine at each of `tones_hz`.
fn remove_tones(v: &[f64], t: &[f64], tones_hz: &[f64]) -> Vec<f64> {
    if tones_hz.is_empty() || v.len() < 2 * tones_hz.len() + 2 {
        return v.to_vec();
    }
    let cols = 1 + 2 * tones_hz.len();
    let design = nalgebra::DMatrix::from_fn(v.len(), cols, |i, j| match j {
        0 => 1.0,
        j => {
            let w = 2.0 * PI * tones_hz[(j - 1) / 2] * t[i];
            if j % 2 == 1 {
                w.cos()
            } else {
                w.sin()
            }
        }
    });
    let target = nalgebra::DVector::from_column_slice(v);
    match crate::least_squares::solve(&design, &target, &vec![true; v.len()], "tones") {
        Ok(fit) => (target - design * fit.theta).iter().copied().collect(),
        Err(_) => v.to_vec(),
    }
}

/// [`phasor_windowed`] with the Hann window.
fn phasor(v: &[f64], t: &[f64], f: f64) -> (f64, f64) {
    phasor_windowed(v, t, f, true)
}

/// The samples spanning a whole number of periods of `grid_hz` (all lines and probes are
/// multiples of it), when the lines lie on such a grid: `Some(n)` samples from the start.
fn whole_periods(lines: &[f64], grid_hz: f64, t: &[f64]) -> Option<usize> {
    if grid_hz.is_nan() || grid_hz <= 0.0 || lines.iter().any(|f| ((f / grid_hz) - (f / grid_hz).round()).abs() > 0.01) {
        return None;
    }
    let step = if t.len() > 1 { (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64 } else { return None };
    let periods = ((t[t.len() - 1] - t[0] + step) * grid_hz).floor();
    if periods < 2.0 {
        return None;
    }
    let n = (periods / grid_hz / step).round() as usize;
    (n >= 16 && n <= t.len()).then_some(n)
}

/// Summed power of `v` at the frequencies `lines_hz` (phasor magnitudes squared).
pub fn line_power(v: &[f64], t: &[f64], lines_hz: &[f64]) -> f64 {
    lines_hz
        .iter()
        .map(|&f| {
            let (re, im) = phasor(v, t, f);
            re * re + im * im
        })
        .sum()
}

/// The off-line probe frequencies: half a line spacing either side of every line (0.5 Hz
/// for a single line), or `None` when the record is too short to resolve them.
fn off_lines(lines: &[f64], duration_s: f64, nyquist_hz: f64) -> Option<Vec<f64>> {
    let spacing = lines.windows(2).map(|w| w[1] - w[0]).fold(f64::INFINITY, f64::min);
    let half = if spacing.is_finite() { 0.5 * spacing } else { 0.5 };
    if half * duration_s < 1.5 {
        // Off-line probes would sit in the lines' own leakage.
        return None;
    }
    let mut off: Vec<f64> = lines.iter().flat_map(|f| [f - half, f + half]).filter(|f| *f > 0.0 && *f < nyquist_hz).collect();
    off.sort_by(f64::total_cmp);
    off.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    (!off.is_empty()).then_some(off)
}

/// Is the linear K-C model adequate at the excitation lines? The model is fitted in the
/// frequency domain, to the phasors of force and motion at the lines (per force axis, real
/// coefficients on `x, y, x', y'`): there the probes' noise is one DFT bin against the whole
/// line, so the fit is free of the errors-in-variables bias a time-domain fit suffers from
/// differentiated noise (whose deterministic part would otherwise look like model error).
/// The same coefficients applied to the phasors half-way between the lines give the noise
/// floor; the ratio of residual power at the lines to that floor is 1 for an adequate model.
///
/// `motion` = `[x, y, x', y']`, `force` = `[f_x, f_y]`, all detrended, sampled at `t`.
/// `exclude_hz` are frequencies (shaft 1X, 2X) no off-line probe may sit within two DFT bins of.
pub fn line_structure(motion: [&[f64]; 4], force: [&[f64]; 2], t: &[f64], lines_hz: &[f64], nyquist_hz: f64, exclude_hz: &[f64]) -> Option<LineStructure> {
    line_structure_normed(motion, force, force, t, lines_hz, nyquist_hz, exclude_hz)
}

/// [`line_structure`] of a residual `force` (what a model left of the film force), with the
/// relative amplitude taken against the film force `norm` at the lines.
pub fn line_structure_normed(
    motion: [&[f64]; 4],
    force: [&[f64]; 2],
    norm: [&[f64]; 2],
    t: &[f64],
    lines_hz: &[f64],
    nyquist_hz: f64,
    exclude_hz: &[f64],
) -> Option<LineStructure> {
    let mut lines: Vec<f64> = lines_hz.iter().copied().filter(|f| *f > 0.0 && *f < nyquist_hz).collect();
    lines.sort_by(f64::total_cmp);
    lines.dedup();
    // Four real coefficients per axis from two real equations per line.
    if lines.len() < 3 || t.len() < 16 {
        return None;
    }
    let duration = t[t.len() - 1] - t[0];
    let bin = 1.0 / duration;
    let off: Vec<f64> = off_lines(&lines, duration, nyquist_hz)?.into_iter().filter(|f| exclude_hz.iter().all(|e| (f - e).abs() > 2.0 * bin)).collect();
    if off.is_empty() {
        return None;
    }
    // Lines and the probes half a spacing beside them on one grid: a whole number of its
    // periods, summed plainly (every frequency orthogonal to the others, no leakage, the full
    // record's resolution); else the whole record through a Hann window.
    let spacing = lines.windows(2).map(|w| w[1] - w[0]).fold(f64::INFINITY, f64::min);
    let span = whole_periods(&lines, 0.5 * spacing, t);
    let (n_used, hann) = match span {
        Some(n) => (n, false),
        None => (t.len(), true),
    };
    let (t_all, motion_all) = (t, motion);
    let t = &t[..n_used];
    // The excluded lines (the shaft's 1X, 2X) are off the grid: they would leak into every bin
    // of a plain sum, so they are fitted and taken out of each signal first.
    let clean = |v: &[f64]| -> Vec<f64> { remove_tones(&v[..n_used], t, exclude_hz) };
    let cleaned = |vs: &[&[f64]]| -> Vec<Vec<f64>> { vs.iter().map(|v| clean(v)).collect() };
    let (motion, force, norm) = (cleaned(&motion), cleaned(&force), cleaned(&norm));
    let phasors = |freqs: &[f64]| -> Vec<[(f64, f64); 6]> {
        freqs
            .iter()
            .map(|&f| {
                let m: [(f64, f64); 4] = std::array::from_fn(|j| phasor_windowed(&motion[j], t, f, hann));
                [m[0], m[1], m[2], m[3], phasor_windowed(&force[0], t, f, hann), phasor_windowed(&force[1], t, f, hann)]
            })
            .collect()
    };
    let on = phasors(&lines);
    let offp = phasors(&off);
    let (mut res_on, mut res_off, mut force_on) = (0.0, 0.0, 0.0);
    for axis in 0..2 {
        let rows = 2 * on.len();
        let design = nalgebra::DMatrix::from_fn(rows, 4, |r, j| {
            let (re, im) = on[r / 2][j];
            if r % 2 == 0 {
                re
            } else {
                im
            }
        });
        let target = nalgebra::DVector::from_fn(rows, |r, _| {
            let (re, im) = on[r / 2][4 + axis];
            if r % 2 == 0 {
                re
            } else {
                im
            }
        });
        let fit = crate::least_squares::solve(&design, &target, &vec![true; rows], "line fit").ok()?;
        let residual_power = |ph: &[[(f64, f64); 6]]| -> f64 {
            ph.iter()
                .map(|p| {
                    let (mut re, mut im) = p[4 + axis];
                    for (th, m) in fit.theta.iter().zip(&p[..4]) {
                        re -= th * m.0;
                        im -= th * m.1;
                    }
                    re * re + im * im
                })
                .sum::<f64>()
                / ph.len() as f64
        };
        // The fit used 4 of the 2L line equations: scale its residual back to per-line noise.
        res_on += residual_power(&on) * rows as f64 / (rows - 4) as f64;
        res_off += residual_power(&offp);
        force_on += lines
            .iter()
            .map(|&f| {
                let (re, im) = phasor_windowed(&norm[axis], t, f, hann);
                re * re + im * im
            })
            .sum::<f64>()
            / lines.len() as f64;
    }
    if !(res_off > 0.0 && force_on > 0.0) {
        return None;
    }
    // The motion's own signal-to-noise ratio over the whole record (Hann window): the
    // whole-period span above trades length for orthogonality, which a noise level does not
    // need.
    let whole_t = t_all;
    let displacement_power = |freqs: &[f64]| -> f64 {
        freqs
            .iter()
            .map(|&f| {
                let (a, b) = (phasor_windowed(motion_all[0], whole_t, f, true), phasor_windowed(motion_all[1], whole_t, f, true));
                a.0 * a.0 + a.1 * a.1 + b.0 * b.0 + b.1 * b.1
            })
            .sum::<f64>()
            / freqs.len() as f64
    };
    let motion_snr = displacement_power(&lines) / displacement_power(&off).max(f64::MIN_POSITIVE);
    let ratio = res_on / res_off;
    // Each line's residual power (both axes) ~ floor * chi2(4) / 4 under an adequate model.
    let dof = 4.0 * lines.len() as f64;
    let p_value = chi2_sf(ratio * dof, dof);
    let relative_amplitude = ((res_on - res_off).max(0.0) / force_on).sqrt();
    Some(LineStructure { ratio, p_value, relative_amplitude, lines: lines.len(), motion_snr })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn erf_matches_tabled_values() {
        assert!((erf(0.5) - 0.520_499_877_813_046_5).abs() < 1e-12);
        assert!((erf(-1.0) + 0.842_700_792_949_714_9).abs() < 1e-12);
        assert!((erf(3.0) - 0.999_977_909_503_001_4).abs() < 1e-12);
    }

    #[test]
    fn chi_square_tail_matches_tabled_values() {
        // chi2(1): P(X > 3.841) = 0.05; chi2(10): P(X > 18.307) = 0.05; chi2(2): exp(-x/2).
        assert!((chi2_sf(3.841_458_8, 1.0) - 0.05).abs() < 1e-6);
        assert!((chi2_sf(18.307_038, 10.0) - 0.05).abs() < 1e-6);
        assert!((chi2_sf(7.0, 2.0) - (-3.5f64).exp()).abs() < 1e-12);
        assert!(chi2_sf(1e4, 3.0) < 1e-300 || chi2_sf(1e4, 3.0) == 0.0);
    }

    #[test]
    fn structure_test_passes_a_linear_system_and_flags_a_frequency_dependent_one() {
        // x moves at the odd lines, y at the even ones; f = -(k r + c r') per axis, plus
        // deterministic pseudo-noise on every signal. Then the same with a stiffness that
        // grows with frequency, which no constant K, C reproduces.
        let n = 5000;
        let rate = 500.0;
        let t: Vec<f64> = (0..n).map(|i| i as f64 / rate).collect();
        let lines: Vec<f64> = (1..=16).map(|k| 5.0 * k as f64).collect();
        let (k, c) = (1.0e7, 2.0e4);
        let make = |dependent: bool| {
            let mut state = 12345u64;
            let mut noise = move || {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5
            };
            let mut s: [Vec<f64>; 6] = std::array::from_fn(|_| vec![0.0; n]);
            for i in 0..n {
                for (m, &fl) in lines.iter().enumerate() {
                    let (w, ph) = (2.0 * PI * fl, m as f64);
                    let kk = if dependent { k * (1.0 + 0.002 * fl) } else { k };
                    let axis = m % 2;
                    let (sn, cs) = (w * t[i] + ph).sin_cos();
                    s[axis][i] += 1e-6 * sn;
                    s[2 + axis][i] += 1e-6 * w * cs;
                    s[4 + axis][i] -= kk * 1e-6 * sn + c * 1e-6 * w * cs;
                }
                for (j, v) in s.iter_mut().enumerate() {
                    v[i] += [1e-8, 1e-8, 1e-5, 1e-5, 0.05, 0.05][j] * noise();
                }
            }
            s
        };
        let a = make(false);
        let quiet = line_structure([&a[0], &a[1], &a[2], &a[3]], [&a[4], &a[5]], &t, &lines, 250.0, &[]).expect("computable");
        assert!(quiet.p_value > 1e-3 && quiet.ratio < 2.0, "{quiet:?}");
        let b = make(true);
        let loud = line_structure([&b[0], &b[1], &b[2], &b[3]], [&b[4], &b[5]], &t, &lines, 250.0, &[]).expect("computable");
        assert!(loud.p_value < 1e-6 && loud.ratio > 10.0, "{loud:?}");
        assert!(loud.relative_amplitude > 0.005, "{loud:?}");
    }
}
