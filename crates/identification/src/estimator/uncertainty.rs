//! Standard errors that survive coloured residuals.
//!
//! The rig's signals are low-pass filtered, resampled and differentiated (Zhou et al. 2004
//! §3.1 steps 1, 4 and 6), so the equation error of the regression is strongly autocorrelated.
//! The textbook OLS covariance `σ² (AᵀA)⁻¹` assumes white errors and then reports intervals
//! several times wrong. Two estimators of `Cov(b) = (AᵀA)⁻¹ S (AᵀA)⁻¹ · n/(n-p-1)`,
//! `S = Var(Σ_t a_t e_t)`, live here (`a_t` the centred, column-scaled regressor row, `e_t` the
//! residual; `n/(n-p-1)` the usual degrees-of-freedom correction, the intercept counts):
//!
//! * [`spectral`] (used by the estimator): the **fixed-regressor** form
//!   `S = Σ_l γ_e(l) R_a(l)`, `R_a(l) = Σ_t a_t a_{t+l}ᵀ`, evaluated in the frequency domain as
//!   `S = (1/N) Σ_k Re(A_k^* A_kᵀ) Ŝ_e(f_k)`: the regressors' own spectrum (exact, from their
//!   FFT) weighted by the residual's spectral density, estimated with a Parzen lag window.
//!   This is the classical covariance of least squares with deterministic regressors and a
//!   stationary disturbance (U. Grenander, "On the estimation of regression coefficients in
//!   the case of an autocorrelated disturbance", Ann. Math. Statist. 25 (1954) 252–272;
//!   E. J. Hannan, *Multiple Time Series*, Wiley 1970, ch. VII). For a rig excited at a few
//!   lines it says what matters: the residual's spectral density **at the excitation lines**.
//! * [`newey_west`] (kept for comparison): Newey–West (Bartlett kernel) HAC on the scores
//!   `g_t = a_t e_t`, prewhitened by a VAR(1) and with Andrews' plug-in bandwidth.
//!
//! ## Why the estimator no longer uses Newey–West (measured)
//!
//! The residual of the rig's regression is **blue**: the probe noise reaches it through the
//! differentiated velocity regressor (`C · n'`, spectral density `∝ f²` up to the 200 Hz
//! low-pass) and the frame probes through `m X''` (`∝ f⁴`), while the force sensors add a flat
//! floor. Most of the residual power lies far above the excitation lines (23/37 Hz for the
//! two-tone test), but only its density at the lines moves the estimate. Newey–West estimates
//! the scores' spectrum at zero with a kernel whose width is set by the scores' short
//! correlation time, i.e. it averages the residual spectrum over a band of several hundred Hz
//! around each line, and the VAR(1) prewhitening cannot flatten a spectrum that peaks near the
//! low-pass edge. On 10 s simulated Zhou records (short film, two-tone 23/37 Hz, 30 N, default
//! 200 Hz low-pass, 100 seeds; empirical SD of the estimates over the mean reported SE, range
//! over the eight coefficients):
//!
//! | residual dominated by | Newey–West SD/SE | spectral SD/SE |
//! |---|---|---|
//! | force-sensor noise (1 N), 1.5 nm bearing-probe noise | 0.80–0.97 | 0.90–1.09 |
//! | 1.5 nm bearing-probe noise alone (no force noise) | 0.57–0.74 | 0.82–1.03 |
//! | 1.5 nm on all six probes, 16-bit quantisation, force noise | 0.67–0.97 | 0.84–1.03 |
//!
//! (kyy stays near 0.89 under every estimator and lag tried.) Newey–West was conservative by
//! up to a factor 1.7, so a bias could hide inside its too-wide intervals; the spectral form is
//! within sampling error of the truth. Neither can cover a **bias**, e.g. errors in variables
//! from noise in the regressors (see the estimator's flags): a standard error describes
//! scatter only. Nor can any residual-based error see the part of a regressor's error that
//! lies exactly on the excitation lines (undithered ADC quantisation of a periodic motion puts
//! some there): the fit absorbs it as if it were a coefficient change.
//!
//! ## The spectral estimator in detail
//!
//! * Residual autocovariance `γ̂(l) = (1/n) Σ_t e_t e_{t+l}` (biased, hence a positive definite
//!   sequence) from the FFT of the zero-padded residual.
//! * Parzen lag window (E. Parzen, "Mathematical considerations in the estimation of spectra",
//!   Technometrics 3 (1961) 167–190) truncated at `L = ⌈n^(2/3)⌉` (at most `n/4`): its spectral
//!   window is non-negative, so `Ŝ_e ≥ 0` and `S` is positive semi-definite; its equivalent
//!   bandwidth `≈ 1.86 f_s / L` is 7 Hz for a 10 s window at 5 kHz (fine against the residual
//!   spectrum's structure, which is set by the 200 Hz low-pass and the differentiators), and
//!   its relative variance `≈ 0.54 L / n` (12 % SD of `Ŝ_e` per line, a few % on an SE).
//! * Lines in the residual are kept at their own height: a bin of the residual's periodogram
//!   more than 20 times the smoothed density (chance `e^-20` per bin for noise) is a
//!   deterministic line, the linear model's misfit at that frequency (the film's harmonics, a
//!   ripple it cannot follow), and the lag window would dilute it over its ~7 Hz bandwidth,
//!   about 70 bins. It matters where the excitation leaves directions of the design to weak
//!   lines, which the fit then bends to that misfit: on Zhou's own single 37 Hz sine (300 N,
//!   beside it only the film's 74 Hz harmonic) dxx came out 91 % low with a smoothed-density
//!   SE of 15 %; counted at their height the misfit lines give 43 %, and the estimator refuses
//!   the window as undetermined. On the two-tone coverage records the rule changes no SE by
//!   more than 0.5 %.
//! * FFT length `N ≥ n + L + 1` (a power of two), so every circular correlation used is the
//!   linear one: the formula is exact for the windowed `γ̂`.
//! * Assumption: the residual is independent of the regressors (sensor noise is; regressor
//!   noise makes it slightly untrue, by terms of the order of the regressors' noise fraction;
//!   a regressor error that lies on the lines themselves, e.g. undithered quantisation, is
//!   absorbed by the fit and no residual shows it).
//!
//! Cost: `⌈p/2⌉ + 3` complex FFTs of length `N` (pairs of real signals share one), 65 536
//! points for a 50 000-sample window: measured 13 ms per window against 2 ms for Newey–West
//! (test profile, one core of the shared development machine).
//!
//! ## Decimated standard errors
//!
//! At 100 kHz a 2 s window is 200 000 samples and the FFTs above are 262 144 points: 49 ms
//! of the 68 ms a window's estimate costs after its last sample (release build, shared
//! machine; `examples/profile_window.rs`). But the conditioned signals are band-limited by
//! the conditioning low-pass (55.5–200 Hz), i.e. oversampled several hundred times, and for
//! band-limited regressors and residual every `q`-th sample carries the covariance:
//!
//! * `Σ_m a_{mq} e_{mq}` equals `(1/q) Σ_t a_t e_t` when the product's spectrum (twice the
//!   band) has nothing at multiples of `f_s / q` (Poisson summation); so `S = q² S_q`, with
//!   `S_q` this estimator on the decimated series, while the Gram matrix, the degrees of
//!   freedom and the residual RMS stay those of the full window;
//! * the Parzen window keeps its length in time (`⌈L/q⌉` decimated lags), hence its bandwidth
//!   in Hz and its relative variance `0.54 L / n`; no extra filtering is needed, the
//!   conditioning's low-pass already removed what would alias.
//!
//! [`super::se_decimation`] picks `q` from [`super::EstimatorConfig::signal_band_hz`] (the
//! low-pass cutoff; `None`, the default: `q = 1`, bit for bit the computation above):
//! `f_s / q ≥ 8 × band` (`SE_RATE_PER_BAND`; the alias of a line at `f` comes from
//! `f_s/q - f ≥ 7 × band`, where the default 4th-order zero-phase Butterworth has cut the
//! residual's power by `7^16 ≈ 3·10^13`, far more than the differentiators' blue `f⁴` growth
//! restores) and at least 2 000 decimated samples (`SE_MIN_SAMPLES`; it was 20 000, a margin:
//! the estimator's statistics depend on `L/n`, which decimation keeps; ADR 0011's amendment).
//! The coefficients never change. Measured (with the 20 000 floor):
//!
//! | | full | decimated |
//! |---|---|---|
//! | 200 000 samples at 100 kHz, band 55.5 Hz (`q = 10`, 32 768-point FFTs): spectral SE | 48.6 ms | 5.7 ms |
//! | same, whole estimate after the last sample (line search fed) | 68.0 ms | 11.5 ms |
//! | 30 seeds at 20 kHz, 10 s, 60 Hz low-pass (`q = 9`, `tests/se_decimation.rs`): largest SE change | | 0.09 % |
//! | same: coverage of ±1.96 SE per coefficient | | 0.90–1.00 |
//!
//! With the 2 000 floor: the same test decimates 41-fold (largest SE change 0.36 %, coverage
//! 0.90–1.00); a 25 000-sample window at 5 kHz, band 55.5 Hz, decimates 11-fold (4 096-point
//! FFTs): spectral SE 3.4 -> 0.6 ms (`examples/profile_window.rs`); at 100 kHz, 2 s: `q = 100`.
//!
//! An order-1 or order-2 low-pass, or a band given below the cutoff really used, breaks the
//! assumption: the pipeline raises a configured band to its cutoff, and the estimator node to
//! the cutoff its conditioned frames declare.
//!
//! ## Newey–West in detail
//!
//! `S = Σ_{|l|≤L} (1 - |l|/(L+1)) Σ_t g_t g_{t-l}ᵀ` (Newey & West, "A simple, positive
//! semi-definite, heteroskedasticity and autocorrelation consistent covariance matrix",
//! Econometrica 55 (1987) 703–708).
//!
//! **Prewhitening.** Following Andrews & Monahan, "An improved heteroskedasticity and
//! autocorrelation consistent covariance matrix estimator", Econometrica 60 (1992) 953–966,
//! the scores are first filtered by a fitted VAR(1), `u_t = g_t - Â g_{t-1}` (singular values
//! of `Â` capped at 0.97), the Bartlett estimator is applied to `u`, and the result is
//! recoloured, `S = (I - Â)⁻¹ S_u (I - Â)⁻ᵀ`.
//!
//! **Lag choice.** Andrews, "Heteroskedasticity and autocorrelation consistent covariance matrix
//! estimation", Econometrica 59 (1991) 817–858, eq. 6.2–6.4: fit an AR(1) to each score
//! component, `ρ_j`, innovation variance `σ_j²`, form
//! `α(1) = Σ 4ρ²σ⁴/((1-ρ)⁶(1+ρ)²) / Σ σ⁴/(1-ρ)⁴` and take the Bartlett bandwidth
//! `S_T = 1.1447 (α(1) n)^{1/3}` (computed on the prewhitened scores); the truncation lag is `L = ⌈S_T⌉ - 1` so the weights
//! `1 - l/(L+1)` vanish at `S_T`. `ρ` is clipped to ±0.97 (Andrews' own safeguard against
//! near-unit-root fits) and `L` to `n/4`; hitting the cap is reported.
//!
//! **Computation.** The Bartlett sum equals `(1/(L+1)) Σ_t G_t G_tᵀ` with `G_t` the moving sum
//! of the last `L+1` scores (zero-padded at both ends of the window): every pair `(s, s')` is
//! counted by exactly `L + 1 - |s - s'|` of the windows. That costs `O(n p²)` whatever the lag,
//! and is positive semi-definite by construction.

use rustfft::num_complex::Complex;

use crate::fft;

/// Standard errors of one window.
#[derive(Debug, Clone)]
pub struct Hac {
    /// Standard errors of the unscaled coefficients, `se[j * m + k]`.
    pub se: Vec<f64>,
    /// Root-mean-square residual per right-hand side.
    pub residual_rms: Vec<f64>,
    /// Truncation lag per right-hand side, in samples of the full window: of the Parzen lag
    /// window ([`spectral`], [`spectral_decimated`]) or of the Bartlett kernel on the
    /// prewhitened scores ([`newey_west`]).
    pub lag: Vec<usize>,
    /// True if a lag was clipped to `n/4`.
    pub lag_capped: bool,
}

impl Hac {
    fn nan(p: usize, m: usize) -> Self {
        Self { se: vec![f64::NAN; p * m], residual_rms: vec![f64::NAN; m], lag: vec![0; m], lag_capped: false }
    }
}

/// A residual periodogram bin this many times above the smoothed density is a line (misfit
/// of the model), not noise: exceeded by chance with probability `e^-20` per bin.
const MISFIT_RATIO: f64 = 20.0;

/// Truncation lag of the Parzen lag window for a window of `n` samples: `⌈n^(2/3)⌉`, at most
/// `n/4` (and whether that cap applied).
pub fn parzen_lag(n: usize) -> (usize, bool) {
    let l = (n as f64).powf(2.0 / 3.0).ceil() as usize;
    let cap = n / 4;
    if l > cap {
        (cap, true)
    } else {
        (l, false)
    }
}

/// Parzen's lag window at `u = l / L` (zero for `|u| ≥ 1`).
fn parzen(u: f64) -> f64 {
    let u = u.abs();
    if u <= 0.5 {
        1.0 - 6.0 * u * u * (1.0 - u)
    } else if u < 1.0 {
        2.0 * (1.0 - u).powi(3)
    } else {
        0.0
    }
}

/// Forward FFT of two real signals at once (`z = a + i b`, zero-padded to `nfft`); returns
/// the spectra of `a` and `b` for bins `0..=N/2` as (re, im) pairs.
#[cfg(test)]
fn fft_pair(a: &[f64], b: Option<&[f64]>, nfft: usize) -> ([Vec<f64>; 2], [Vec<f64>; 2]) {
    let mut z = vec![Complex::new(0.0, 0.0); nfft];
    for (zk, v) in z.iter_mut().zip(a) {
        zk.re = *v;
    }
    if let Some(b) = b {
        for (zk, v) in z.iter_mut().zip(b) {
            zk.im = *v;
        }
    }
    fft::forward(&mut z);
    let nb = nfft / 2 + 1;
    let mut sa = [vec![0.0; nb], vec![0.0; nb]];
    let mut sb = [vec![0.0; nb], vec![0.0; nb]];
    for k in 0..nb {
        let (zk, zn) = (z[k], z[(nfft - k) % nfft]);
        // A_k = (Z_k + conj Z_{N-k}) / 2, B_k = (Z_k - conj Z_{N-k}) / (2i).
        sa[0][k] = 0.5 * (zk.re + zn.re);
        sa[1][k] = 0.5 * (zk.im - zn.im);
        sb[0][k] = 0.5 * (zk.im + zn.im);
        sb[1][k] = -0.5 * (zk.re - zn.re);
    }
    (sa, sb)
}

/// Forward FFT of two real, even sequences given on `0..N` (their transforms are real):
/// returns both transforms, bins `0..N`.
#[cfg(test)]
fn fft_even_pair(a: Vec<f64>, b: Vec<f64>) -> (Vec<f64>, Vec<f64>) {
    let mut z: Vec<Complex<f64>> = a.iter().zip(&b).map(|(r, i)| Complex::new(*r, *i)).collect();
    fft::forward(&mut z);
    (z.iter().map(|c| c.re).collect(), z.iter().map(|c| c.im).collect())
}

/// Standard errors from the fixed-regressor covariance `S = Σ_l γ_e(l) R_a(l)` with a Parzen
/// lag-window estimate of the residual spectrum (see the module documentation). Same inputs
/// and outputs as [`newey_west`]: `cols` are the window's regressors (`p`, 1 to 8) then
/// right-hand sides (`m`); `mean`, `scale` as in the factor; `coef[j * m + k]` the solution;
/// `ginv_s` the inverse Gram of the scaled regressors. Malformed sizes give NaN errors.
pub fn spectral(cols: &[&[f64]], p: usize, mean: &[f64], scale: &[f64], coef: &[f64], ginv_s: &[f64]) -> Hac {
    spectral_decimated(cols, p, mean, scale, coef, ginv_s, 1)
}

/// [`spectral`] with `S` computed from every `q`-th sample of the window (samples `0, q, 2q,
/// ...`), for band-limited signals (see "Decimated standard errors" in the module
/// documentation): `S ≈ q² S_q`, the lag window keeps its length in time (`⌈L/q⌉` decimated
/// lags, `L` the full window's), and the Gram matrix (`ginv_s`), the degrees of freedom and the
/// residual RMS stay those of the full window. `q = 1` is [`spectral`], bit for bit; `q = 0`
/// gives NaN errors. The reported lag is in full-rate samples (`q ⌈L/q⌉`).
pub fn spectral_decimated(cols: &[&[f64]], p: usize, mean: &[f64], scale: &[f64], coef: &[f64], ginv_s: &[f64], q: usize) -> Hac {
    let m = cols.len().saturating_sub(p);
    let n = cols.iter().map(|c| c.len()).min().unwrap_or(0);
    if q == 0 || mean.len() < cols.len() || coef.len() != p * m {
        return Hac::nan(p, m);
    }
    let decimated: Vec<Vec<f64>> = cols.iter().map(|c| c[..n].iter().step_by(q).copied().collect()).collect();
    let views: Vec<&[f64]> = decimated.iter().map(|c| c.as_slice()).collect();
    let mut out = spectral_of_decimated(&views, n, p, mean, scale, coef, ginv_s, q);
    // The residual RMS over every sample of the window.
    let mut sse = vec![0.0; m];
    let mut centred = vec![0.0; p];
    for t in 0..n {
        for j in 0..p {
            centred[j] = cols[j][t] - mean[j];
        }
        for k in 0..m {
            let mut e = cols[p + k][t] - mean[p + k];
            for j in 0..p {
                e -= centred[j] * coef[j * m + k];
            }
            sse[k] += e * e;
        }
    }
    for k in 0..m {
        out.residual_rms[k] = (sse[k] / n as f64).sqrt();
    }
    out
}

/// The spectral standard errors from the window's every `q`-th sample alone: `decimated` holds
/// samples `0, q, 2q, ...` of each column (regressors, then right-hand sides) of a window of
/// `n` samples, `⌈n/q⌉` each; the rest as [`spectral_decimated`], whose errors these are, bit
/// for bit. The residual RMS is left NaN: it needs every sample, and the caller has it from
/// the window's factor (the column norms of `T`, see `qr`) without another pass.
///
/// Every transform runs in one complex buffer, the sums over bins keep their terms in
/// registers: the same operations in the same order as the first, plainer version of this
/// function (kept in the tests as the definition, compared bit for bit), at a fraction of its
/// cost (it was ~15 % of an offline re-analysis's estimator, ADR 0012).
#[allow(clippy::too_many_arguments)] // the solved window in its parts
pub fn spectral_of_decimated(decimated: &[&[f64]], n: usize, p: usize, mean: &[f64], scale: &[f64], coef: &[f64], ginv_s: &[f64], q: usize) -> Hac {
    let nq_cols = decimated.len();
    let m = nq_cols.saturating_sub(p);
    let mut out = Hac::nan(p, m);
    if p == 0 || p > 8 || n <= p + 2 || coef.len() != p * m || ginv_s.len() != p * p || scale.len() < p || mean.len() < nq_cols || q == 0 {
        return out;
    }
    let dof = n as f64 / (n - p - 1) as f64;
    let (full_lag, capped) = parzen_lag(n);
    out.lag_capped = capped;
    // Samples and lag on the decimated grid (the full ones when q = 1).
    let nd = n.div_ceil(q);
    let lag = if q == 1 { full_lag } else { full_lag.div_ceil(q) };
    if nd <= p + 2 || decimated.iter().any(|c| c.len() < nd) {
        return out;
    }
    let nfft = (nd + lag + 1).next_power_of_two();
    let nb = nfft / 2 + 1;
    let zero = Complex::new(0.0, 0.0);
    let mut z = vec![zero; nfft];

    // Spectra of the centred, scaled regressors, two per FFT: `re[a * nb + k]`, `im[..]`.
    let mut re = vec![0.0; p * nb];
    let mut im = vec![0.0; p * nb];
    for j in (0..p).step_by(2) {
        z.fill(zero);
        for (zk, v) in z.iter_mut().zip(&decimated[j][..nd]) {
            zk.re = (v - mean[j]) / scale[j];
        }
        if j + 1 < p {
            for (zk, v) in z.iter_mut().zip(&decimated[j + 1][..nd]) {
                zk.im = (v - mean[j + 1]) / scale[j + 1];
            }
        }
        fft::forward(&mut z);
        let (ra, rest) = re[j * nb..].split_at_mut(nb);
        let (ia, irest) = im[j * nb..].split_at_mut(nb);
        let rb = rest.get_mut(..nb);
        let ib = irest.get_mut(..nb);
        let (mut sb_re, mut sb_im) = (vec![0.0; nb], vec![0.0; nb]);
        split_pair(&z, ra, ia, &mut sb_re, &mut sb_im);
        if let (Some(rb), Some(ib)) = (rb, ib) {
            rb.copy_from_slice(&sb_re);
            ib.copy_from_slice(&sb_im);
        }
    }

    // Residuals of every right-hand side on the decimated grid: `f - m_f - Σ_j (x_j - m_j) b_j`,
    // subtracted in regressor order (sample by sample, vectorised over samples).
    let mut resid: Vec<Vec<f64>> = Vec::with_capacity(m);
    for k in 0..m {
        let mf = mean[p + k];
        let mut e: Vec<f64> = decimated[p + k][..nd].iter().map(|v| v - mf).collect();
        for j in 0..p {
            let (mj, b) = (mean[j], coef[j * m + k]);
            for (e, x) in e.iter_mut().zip(&decimated[j][..nd]) {
                *e -= (x - mj) * b;
            }
        }
        resid.push(e);
    }

    // Residual spectral densities per right-hand side, bins 0..=N/2.
    let mut density = vec![Vec::new(); m];
    let (mut pw_a, mut pw_b) = (vec![0.0; nb], vec![0.0; nb]);
    let (mut s_re, mut s_im) = ([vec![0.0; nb], vec![0.0; nb]], [vec![0.0; nb], vec![0.0; nb]]);
    for k0 in (0..m).step_by(2) {
        let pair = [Some(k0), (k0 + 1 < m).then_some(k0 + 1)];
        // Periodograms |E_k|^2.
        z.fill(zero);
        for (zk, v) in z.iter_mut().zip(&resid[k0]) {
            zk.re = *v;
        }
        if let Some(k1) = pair[1] {
            for (zk, v) in z.iter_mut().zip(&resid[k1]) {
                zk.im = *v;
            }
        }
        fft::forward(&mut z);
        {
            let ([ar, br], [ai, bi]) = (&mut s_re, &mut s_im);
            split_pair(&z, ar, ai, br, bi);
        }
        for i in 0..nb {
            pw_a[i] = s_re[0][i] * s_re[0][i] + s_im[0][i] * s_im[0][i];
            pw_b[i] = s_re[1][i] * s_re[1][i] + s_im[1][i] * s_im[1][i];
        }
        // Autocovariances Σ_t e_t e_{t+l} = FFT(|E|^2)(l) / N (exact for l <= N - n): the
        // periodograms as real, even sequences on 0..N, both in one transform.
        z[0] = Complex::new(pw_a[0], pw_b[0]);
        for i in 1..nb {
            let c = Complex::new(pw_a[i], pw_b[i]);
            z[i] = c;
            z[nfft - i] = c;
        }
        fft::forward(&mut z);
        // Lag-windowed, biased autocovariances, placed symmetrically on 0..N.
        let top = lag.min(nfft / 2 - 1);
        let norm = nfft as f64 * nd as f64;
        let mut g = vec![zero; nfft];
        for l in 0..=top {
            let u = parzen(l as f64 / (lag.max(1)) as f64);
            let w = Complex::new(u * z[l].re / norm, u * z[l].im / norm);
            g[l] = w;
            if l > 0 {
                g[nfft - l] = w;
            }
        }
        // Spectral densities on the grid (real: the sequences are even).
        fft::forward(&mut g);
        for (h, slot) in pair.iter().enumerate() {
            let Some(k) = *slot else { continue };
            let raw = if h == 0 { &pw_a } else { &pw_b };
            // Lines in the residual (misfit) stay at their own height.
            density[k] = (0..nb)
                .map(|i| {
                    let dens = if h == 0 { g[i].re } else { g[i].im };
                    let p = raw[i] / nd as f64;
                    if p > MISFIT_RATIO * dens {
                        p
                    } else {
                        dens
                    }
                })
                .collect();
        }
    }

    // S = (1/N) Σ_k Re(conj(A_k) A_kᵀ) Ŝ_e(f_k) per right-hand side, each entry's terms in bin
    // order.
    for (k, dens) in density.iter().enumerate() {
        let mut s = match p {
            4 => bin_sums::<4>(&re, &im, nb, dens, nfft),
            6 => bin_sums::<6>(&re, &im, nb, dens, nfft),
            _ => bin_sums_any(p, &re, &im, nb, dens, nfft),
        };
        out.lag[k] = lag * q;
        // Σ over every q-th sample of a band-limited product is 1/q of the full sum, so the
        // full window's S is q² times the decimated one's.
        standard_errors_from_sums(&mut s, p, nfft, q, ginv_s, dof, scale, |j, se| out.se[j * m + k] = se);
    }
    out
}

/// Finishes one right-hand side's `S` (the upper triangle of bin sums, `p x p` row-major):
/// divides by `nfft`, scales a decimated one (`q > 1`) by `q²`, mirrors it, and passes each
/// coefficient's standard error `sqrt(max(Cov_z[j][j], 0) dof) / scale_j`, with
/// `Cov_z = G⁻¹ S G⁻¹` (scaled), to `put(j, se)`.
#[allow(clippy::too_many_arguments)]
fn standard_errors_from_sums(s: &mut [f64], p: usize, nfft: usize, q: usize, ginv_s: &[f64], dof: f64, scale: &[f64], mut put: impl FnMut(usize, f64)) {
    let rescale = (q * q) as f64;
    for a in 0..p {
        for b in a..p {
            s[a * p + b] /= nfft as f64;
            if q > 1 {
                s[a * p + b] *= rescale;
            }
            s[b * p + a] = s[a * p + b];
        }
    }
    for j in 0..p {
        let mut v = 0.0;
        for l in 0..p {
            let mut row = 0.0;
            for r in 0..p {
                row += s[l * p + r] * ginv_s[r * p + j];
            }
            v += ginv_s[j * p + l] * row;
        }
        put(j, (v.max(0.0) * dof).sqrt() / scale[j]);
    }
}

/// The spectra, bins `0..=N/2`, of the real and imaginary parts of the signal whose transform
/// is `z`: `A_k = (Z_k + conj Z_{N-k}) / 2`, `B_k = (Z_k - conj Z_{N-k}) / (2i)` (`Z_N` is
/// `Z_0`), as (re, im).
fn split_pair(z: &[Complex<f64>], a_re: &mut [f64], a_im: &mut [f64], b_re: &mut [f64], b_im: &mut [f64]) {
    let nfft = z.len();
    let nb = nfft / 2 + 1;
    if nfft < 2 || a_re.len() < nb || a_im.len() < nb || b_re.len() < nb || b_im.len() < nb {
        return;
    }
    let mut put = |k: usize, zk: Complex<f64>, zn: Complex<f64>| {
        a_re[k] = 0.5 * (zk.re + zn.re);
        a_im[k] = 0.5 * (zk.im - zn.im);
        b_re[k] = 0.5 * (zk.im + zn.im);
        b_im[k] = -0.5 * (zk.re - zn.re);
    };
    put(0, z[0], z[0]);
    for (k, (zk, zn)) in z[1..nb].iter().zip(z[nfft - nb + 1..].iter().rev()).enumerate() {
        put(k + 1, *zk, *zn);
    }
}

/// Bins 0 and N/2 appear once in the full sum over k, the others twice (k and N - k).
fn bin_weight(k: usize, nfft: usize) -> f64 {
    if k == 0 || k == nfft / 2 {
        1.0
    } else {
        2.0
    }
}

/// `s[a p + b] = Σ_i (re_a re_b + im_a im_b)_i d_i` for `b >= a`, `d_i` the density times the
/// bin weight, bins with `d_i = 0` skipped; `P` regressors, the sums in registers.
fn bin_sums<const P: usize>(re: &[f64], im: &[f64], nb: usize, dens: &[f64], nfft: usize) -> Vec<f64> {
    let mut acc = [[0.0f64; P]; P];
    if re.len() < P * nb || im.len() < P * nb || dens.len() < nb {
        return vec![f64::NAN; P * P];
    }
    for i in 0..nb {
        let d = dens[i].max(0.0) * bin_weight(i, nfft);
        if d == 0.0 {
            continue;
        }
        let mut r = [0.0f64; P];
        let mut m = [0.0f64; P];
        for a in 0..P {
            r[a] = re[a * nb + i];
            m[a] = im[a * nb + i];
        }
        for a in 0..P {
            for b in a..P {
                acc[a][b] += (r[a] * r[b] + m[a] * m[b]) * d;
            }
        }
    }
    let mut s = vec![0.0; P * P];
    for a in 0..P {
        for b in a..P {
            s[a * P + b] = acc[a][b];
        }
    }
    s
}

/// [`bin_sums`] for any number of regressors.
fn bin_sums_any(p: usize, re: &[f64], im: &[f64], nb: usize, dens: &[f64], nfft: usize) -> Vec<f64> {
    let mut s = vec![0.0; p * p];
    if re.len() < p * nb || im.len() < p * nb || dens.len() < nb {
        return vec![f64::NAN; p * p];
    }
    for i in 0..nb {
        let d = dens[i].max(0.0) * bin_weight(i, nfft);
        if d == 0.0 {
            continue;
        }
        for a in 0..p {
            let (ar, ai) = (re[a * nb + i], im[a * nb + i]);
            for b in a..p {
                s[a * p + b] += (ar * re[b * nb + i] + ai * im[b * nb + i]) * d;
            }
        }
    }
    s
}

/// Andrews' AR(1) safeguard on fitted autocorrelations, and Andrews–Monahan's cap on the
/// singular values of the prewhitening VAR.
const RHO_MAX: f64 = 0.97;

/// HAC standard errors. `cols` are the window's regressors (`p`, 1 to 8) then right-hand sides
/// (`m`); `mean`, `scale` as in the factor; `coef[j * m + k]` the solution; `ginv_s` the inverse
/// Gram of the scaled regressors. Outside those sizes every standard error is NaN.
pub fn newey_west(cols: &[&[f64]], p: usize, mean: &[f64], scale: &[f64], coef: &[f64], ginv_s: &[f64]) -> Hac {
    match p {
        1 => nw::<1>(cols, mean, scale, coef, ginv_s),
        2 => nw::<2>(cols, mean, scale, coef, ginv_s),
        3 => nw::<3>(cols, mean, scale, coef, ginv_s),
        4 => nw::<4>(cols, mean, scale, coef, ginv_s),
        5 => nw::<5>(cols, mean, scale, coef, ginv_s),
        6 => nw::<6>(cols, mean, scale, coef, ginv_s),
        7 => nw::<7>(cols, mean, scale, coef, ginv_s),
        8 => nw::<8>(cols, mean, scale, coef, ginv_s),
        _ => Hac::nan(p, cols.len().saturating_sub(p)),
    }
}

/// [`newey_west`] for `P` regressors: fixed-size rows so the per-sample loops unroll.
fn nw<const P: usize>(cols: &[&[f64]], mean: &[f64], scale: &[f64], coef: &[f64], ginv_s: &[f64]) -> Hac {
    let q = cols.len();
    let m = q.saturating_sub(P);
    let n = cols.iter().map(|c| c.len()).min().unwrap_or(0);
    let mut out = Hac { se: vec![f64::NAN; P * m], residual_rms: vec![f64::NAN; m], lag: vec![0; m], lag_capped: false };
    if n <= P + 2 || coef.len() != P * m || ginv_s.len() != P * P || scale.len() < P || mean.len() < q {
        return out;
    }
    let dof = n as f64 / (n - P - 1) as f64;
    let mut g: Vec<[f64; P]> = vec![[0.0; P]; n];
    for k in 0..m {
        // Residuals and scores g_t = a_t e_t of right-hand side k.
        let b: [f64; P] = std::array::from_fn(|j| coef[j * m + k]);
        let inv_scale: [f64; P] = std::array::from_fn(|j| 1.0 / scale[j]);
        let f = &cols[P + k][..n];
        let fm = mean[P + k];
        let mut sse = 0.0;
        for (t, gt) in g.iter_mut().enumerate() {
            let a: [f64; P] = std::array::from_fn(|j| cols[j][t] - mean[j]);
            let mut e = f[t] - fm;
            for j in 0..P {
                e -= a[j] * b[j];
            }
            sse += e * e;
            for j in 0..P {
                gt[j] = a[j] * inv_scale[j] * e;
            }
        }
        out.residual_rms[k] = (sse / n as f64).sqrt();
        let var = var1::<P>(&g);
        let u = prewhiten::<P>(&g, &var);
        let (lag, capped) = andrews_lag::<P>(&u);
        out.lag[k] = lag;
        out.lag_capped |= capped;
        let s_u = bartlett::<P>(&u, lag);
        let s = recolour::<P>(&s_u, &var);
        // Cov_z = G⁻¹ S G⁻¹ (scaled); b_j = z_j / scale_j.
        for j in 0..P {
            let mut v = 0.0;
            for l in 0..P {
                let mut row = 0.0;
                for r in 0..P {
                    row += s[l][r] * ginv_s[r * P + j];
                }
                v += ginv_s[j * P + l] * row;
            }
            out.se[j * m + k] = (v.max(0.0) * dof).sqrt() / scale[j];
        }
    }
    out
}

/// Least-squares VAR(1) coefficient `Â` of the scores, singular values capped at
/// [`RHO_MAX`]; zero if the lagged scores are degenerate.
fn var1<const P: usize>(g: &[[f64; P]]) -> [[f64; P]; P] {
    let mut xx = [[0.0; P]; P];
    let mut yx = [[0.0; P]; P];
    for w in g.windows(2) {
        let (prev, cur) = (&w[0], &w[1]);
        for i in 0..P {
            for j in 0..P {
                xx[i][j] += prev[i] * prev[j];
                yx[i][j] += cur[i] * prev[j];
            }
        }
    }
    let zero = [[0.0; P]; P];
    let sxx = nalgebra::DMatrix::from_fn(P, P, |i, j| xx[i][j]);
    let syx = nalgebra::DMatrix::from_fn(P, P, |i, j| yx[i][j]);
    let Some(chol) = sxx.cholesky() else { return zero };
    // Â = Syx Sxx⁻¹  ⇔  Sxx Âᵀ = Syxᵀ.
    let at = chol.solve(&syx.transpose());
    let mut a = vec![0.0; P * P];
    for i in 0..P {
        for j in 0..P {
            a[i * P + j] = at[(j, i)];
        }
    }
    let Some(svd) = super::svd::SmallSvd::new(&a, P) else { return zero };
    let top = svd.sigma.first().copied().unwrap_or(0.0);
    let mut out = [[0.0; P]; P];
    for i in 0..P {
        for j in 0..P {
            out[i][j] = if top <= RHO_MAX { a[i * P + j] } else { (0..P).map(|kk| svd.u[i * P + kk] * svd.sigma[kk].min(RHO_MAX) * svd.v[j * P + kk]).sum() };
        }
    }
    out
}

/// `u_t = g_t - Â g_{t-1}`, `t = 1..n`.
fn prewhiten<const P: usize>(g: &[[f64; P]], a: &[[f64; P]; P]) -> Vec<[f64; P]> {
    g.windows(2)
        .map(|w| {
            let (prev, cur) = (&w[0], &w[1]);
            std::array::from_fn(|i| {
                let mut v = cur[i];
                for j in 0..P {
                    v -= a[i][j] * prev[j];
                }
                v
            })
        })
        .collect()
}

/// Andrews (1991) AR(1) plug-in bandwidth for the Bartlett kernel; returns the truncation lag
/// and whether it was clipped to `n/4`.
fn andrews_lag<const P: usize>(u: &[[f64; P]]) -> (usize, bool) {
    let n = u.len();
    let (mut tt, mut t10, mut t00) = ([0.0; P], [0.0; P], [0.0; P]);
    for w in u.windows(2) {
        for j in 0..P {
            let (c, pr) = (w[1][j], w[0][j]);
            tt[j] += c * c;
            t10[j] += c * pr;
            t00[j] += pr * pr;
        }
    }
    let (mut num, mut den) = (0.0, 0.0);
    for j in 0..P {
        if t00[j] <= 0.0 || n < 2 {
            continue;
        }
        let rho = (t10[j] / t00[j]).clamp(-RHO_MAX, RHO_MAX);
        let sig2 = ((tt[j] - 2.0 * rho * t10[j] + rho * rho * t00[j]) / (n - 1) as f64).max(0.0);
        let s4 = sig2 * sig2;
        num += 4.0 * rho * rho * s4 / ((1.0 - rho).powi(6) * (1.0 + rho).powi(2));
        den += s4 / (1.0 - rho).powi(4);
    }
    let alpha = if den > 0.0 { num / den } else { 0.0 };
    let bandwidth = 1.1447 * (alpha * n as f64).cbrt();
    let lag = if bandwidth.is_finite() && bandwidth > 1.0 { bandwidth.ceil() as usize - 1 } else { 0 };
    let cap = n / 4;
    if lag > cap {
        (cap, true)
    } else {
        (lag, false)
    }
}

/// `S = (1/(L+1)) Σ_t G_t G_tᵀ` with `G_t` the moving sum of the last `L + 1` rows of `u`.
fn bartlett<const P: usize>(u: &[[f64; P]], lag: usize) -> [[f64; P]; P] {
    let n = u.len();
    let mut big_g = [0.0; P];
    let mut s = [[0.0; P]; P];
    for t in 0..(n + lag) {
        if let Some(add) = u.get(t) {
            for j in 0..P {
                big_g[j] += add[j];
            }
        }
        if t > lag {
            if let Some(old) = u.get(t - lag - 1) {
                for j in 0..P {
                    big_g[j] -= old[j];
                }
            }
        }
        for i in 0..P {
            for j in i..P {
                s[i][j] += big_g[i] * big_g[j];
            }
        }
    }
    let w = 1.0 / (lag + 1) as f64;
    for i in 0..P {
        for j in i..P {
            s[i][j] *= w;
            s[j][i] = s[i][j];
        }
    }
    s
}

/// `(I - Â)⁻¹ S_u (I - Â)⁻ᵀ`; `S_u` unchanged if `I - Â` cannot be inverted (it always can
/// with the singular values of `Â` capped below one).
fn recolour<const P: usize>(s_u: &[[f64; P]; P], a: &[[f64; P]; P]) -> [[f64; P]; P] {
    let ia = nalgebra::DMatrix::from_fn(P, P, |i, j| if i == j { 1.0 } else { 0.0 } - a[i][j]);
    let Some(inv) = ia.try_inverse() else { return *s_u };
    let su = nalgebra::DMatrix::from_fn(P, P, |i, j| s_u[i][j]);
    let s = &inv * su * inv.transpose();
    std::array::from_fn(|i| std::array::from_fn(|j| s[(i, j)]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`spectral_of_decimated`] as it was written first (allocating per transform, one loop per
    /// formula): the definition the faster one must equal bit for bit (tested).
    ///
    /// The spectral standard errors from the window's every `q`-th sample alone: `decimated` holds
    /// samples `0, q, 2q, ...` of each column (regressors, then right-hand sides) of a window of
    /// `n` samples, `⌈n/q⌉` each; the rest as [`spectral_decimated`], whose errors these are, bit
    /// for bit. The residual RMS is left NaN: it needs every sample, and the caller has it from
    /// the window's factor (the column norms of `T`, see `qr`) without another pass.
    #[cfg(test)]
    #[allow(clippy::too_many_arguments)]
    fn spectral_of_decimated_reference(decimated: &[&[f64]], n: usize, p: usize, mean: &[f64], scale: &[f64], coef: &[f64], ginv_s: &[f64], q: usize) -> Hac {
        let nq_cols = decimated.len();
        let m = nq_cols.saturating_sub(p);
        let mut out = Hac::nan(p, m);
        if p == 0 || p > 8 || n <= p + 2 || coef.len() != p * m || ginv_s.len() != p * p || scale.len() < p || mean.len() < nq_cols || q == 0 {
            return out;
        }
        let dof = n as f64 / (n - p - 1) as f64;
        let (full_lag, capped) = parzen_lag(n);
        out.lag_capped = capped;
        // Samples and lag on the decimated grid (the full ones when q = 1).
        let nd = n.div_ceil(q);
        let lag = if q == 1 { full_lag } else { full_lag.div_ceil(q) };
        if nd <= p + 2 || decimated.iter().any(|c| c.len() < nd) {
            return out;
        }
        let nfft = (nd + lag + 1).next_power_of_two();
        let nb = nfft / 2 + 1;
        // Bins 0 and N/2 appear once in the full sum over k, the others twice (k and N - k).
        let bin_weight = |k: usize| if k == 0 || k == nfft / 2 { 1.0 } else { 2.0 };

        // Spectra of the centred, scaled regressors, two per FFT.
        let scaled: Vec<Vec<f64>> = (0..p).map(|j| decimated[j][..nd].iter().map(|v| (v - mean[j]) / scale[j]).collect()).collect();
        let mut spec: Vec<[Vec<f64>; 2]> = Vec::with_capacity(p);
        for j in (0..p).step_by(2) {
            let (a, b) = fft_pair(&scaled[j], scaled.get(j + 1).map(|v| v.as_slice()), nfft);
            spec.push(a);
            if j + 1 < p {
                spec.push(b);
            }
        }

        // Residuals of every right-hand side on the decimated grid, all right-hand sides in one
        // pass over the regressors.
        let mut resid: Vec<Vec<f64>> = (0..m).map(|_| Vec::with_capacity(nd)).collect();
        let mut centred = vec![0.0; p];
        for t in 0..nd {
            for j in 0..p {
                centred[j] = decimated[j][t] - mean[j];
            }
            for k in 0..m {
                let mut e = decimated[p + k][t] - mean[p + k];
                for j in 0..p {
                    e -= centred[j] * coef[j * m + k];
                }
                resid[k].push(e);
            }
        }

        // Residual spectral densities per right-hand side, bins 0..=N/2.
        let mut density = vec![Vec::new(); m];
        for k0 in (0..m).step_by(2) {
            let pair = [Some(k0), (k0 + 1 < m).then_some(k0 + 1)];
            // Periodograms |E_k|², full length N (real and even).
            let (ea, eb) = fft_pair(&resid[k0], pair[1].map(|k| resid[k].as_slice()), nfft);
            let full = |s: &[Vec<f64>; 2]| -> Vec<f64> {
                let mut v = vec![0.0; nfft];
                for i in 0..nb {
                    let pw = s[0][i] * s[0][i] + s[1][i] * s[1][i];
                    v[i] = pw;
                    v[(nfft - i) % nfft] = pw;
                }
                v
            };
            // Autocovariances Σ_t e_t e_{t+l} = FFT(|E|²)(l) / N (exact for l ≤ N - n).
            let (ca, cb) = fft_even_pair(full(&ea), full(&eb));
            // Lag-windowed, biased autocovariances, placed symmetrically on 0..N.
            let windowed = |c: &[f64]| -> Vec<f64> {
                let mut g = vec![0.0; nfft];
                for l in 0..=lag.min(nfft / 2 - 1) {
                    let w = parzen(l as f64 / (lag.max(1)) as f64) * c[l] / (nfft as f64 * nd as f64);
                    g[l] = w;
                    if l > 0 {
                        g[nfft - l] = w;
                    }
                }
                g
            };
            // Spectral densities on the grid (real: the sequences are even).
            let (sa, sb) = fft_even_pair(windowed(&ca), windowed(&cb));
            for ((slot, dens), raw) in pair.iter().zip([&sa, &sb]).zip([&ea, &eb]) {
                let Some(k) = *slot else { continue };
                // Lines in the residual (misfit) stay at their own height.
                density[k] = (0..nb)
                    .map(|i| {
                        let p = (raw[0][i] * raw[0][i] + raw[1][i] * raw[1][i]) / nd as f64;
                        if p > MISFIT_RATIO * dens[i] {
                            p
                        } else {
                            dens[i]
                        }
                    })
                    .collect();
            }
        }

        // S = (1/N) Σ_k Re(conj(A_k) A_kᵀ) Ŝ_e(f_k), every right-hand side in one pass over the
        // regressors' spectra (each sum still in bin order).
        let mut sums = vec![vec![0.0; p * p]; m];
        for i in 0..nb {
            for (s, dens) in sums.iter_mut().zip(&density) {
                let d = dens[i].max(0.0) * bin_weight(i);
                if d == 0.0 {
                    continue;
                }
                for a in 0..p {
                    let (ar, ai) = (spec[a][0][i], spec[a][1][i]);
                    for b in a..p {
                        s[a * p + b] += (ar * spec[b][0][i] + ai * spec[b][1][i]) * d;
                    }
                }
            }
        }
        // Σ over every q-th sample of a band-limited product is 1/q of the full sum, so the full
        // window's S is q² times the decimated one's.
        for (k, mut s) in sums.into_iter().enumerate() {
            out.lag[k] = lag * q;
            standard_errors_from_sums(&mut s, p, nfft, q, ginv_s, dof, scale, |j, se| out.se[j * m + k] = se);
        }
        out
    }

    /// The faster spectral standard errors are the plain ones, bit for bit: regressor counts
    /// even and odd, one and two right-hand sides, decimated or not, a residual with a line.
    #[test]
    fn spectral_of_decimated_is_the_reference_bit_for_bit() {
        let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut noise = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for (p, m, n, q) in [(4, 2, 25_000, 11), (6, 2, 20_000, 9), (4, 1, 3_000, 1), (3, 2, 5_000, 2), (1, 1, 800, 1), (8, 2, 9_000, 4)] {
            let cols: Vec<Vec<f64>> = (0..p + m)
                .map(|c| {
                    (0..n)
                        .map(|t| {
                            (c as f64 + 1.0) * (t as f64 * (0.01 + 0.003 * c as f64)).sin()
                                + 0.1 * noise()
                                + if c >= p { 0.3 * (t as f64 * 0.2).cos() } else { 0.0 }
                        })
                        .collect()
                })
                .collect();
            let dec: Vec<Vec<f64>> = cols.iter().map(|c| c.iter().step_by(q).copied().collect()).collect();
            let views: Vec<&[f64]> = dec.iter().map(|c| c.as_slice()).collect();
            let mean: Vec<f64> = cols.iter().map(|c| c.iter().sum::<f64>() / n as f64).collect();
            let scale: Vec<f64> = (0..p).map(|j| 1.0 + 0.5 * j as f64).collect();
            let coef: Vec<f64> = (0..p * m).map(|i| 0.2 * i as f64 - 0.4).collect();
            let mut ginv = vec![0.0; p * p];
            for a in 0..p {
                for b in 0..p {
                    ginv[a * p + b] = if a == b { 1e-3 * (1.0 + a as f64) } else { 1e-5 * (a + b) as f64 };
                }
            }
            let fast = spectral_of_decimated(&views, n, p, &mean, &scale, &coef, &ginv, q);
            let reference = spectral_of_decimated_reference(&views, n, p, &mean, &scale, &coef, &ginv, q);
            assert!(fast.se.iter().all(|v| v.is_finite() && *v > 0.0), "p {p} m {m}: {:?}", fast.se);
            assert_eq!(format!("{fast:?}"), format!("{reference:?}"), "p {p} m {m} n {n} q {q}");
            let bits = |h: &Hac| h.se.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&fast), bits(&reference), "p {p} m {m} n {n} q {q}");
        }
    }
}
