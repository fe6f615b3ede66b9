//! Standard errors that survive coloured residuals: Newey–West (Bartlett kernel) HAC
//! covariance with Andrews' data-dependent bandwidth.
//!
//! The rig's signals are low-pass filtered, resampled and differentiated (Zhou et al. 2004
//! §3.1 steps 1, 4 and 6), so the equation error of the regression is strongly autocorrelated.
//! The textbook OLS covariance `σ² (AᵀA)⁻¹` assumes white errors and then reports intervals
//! several times too narrow. We use instead the sandwich
//!
//! ```text
//! Cov(b) = (AᵀA)⁻¹ S (AᵀA)⁻¹ · n/(n-p-1),   S = Σ_{|l|≤L} (1 - |l|/(L+1)) Σ_t g_t g_{t-l}ᵀ,
//! ```
//!
//! with scores `g_t = a_t e_t` (centred, column-scaled regressor row times residual). This is
//! Newey & West, "A simple, positive semi-definite, heteroskedasticity and autocorrelation
//! consistent covariance matrix", Econometrica 55 (1987) 703–708. The factor `n/(n-p-1)` is the
//! usual degrees-of-freedom correction (the intercept counts).
//!
//! **Lag choice.** Andrews, "Heteroskedasticity and autocorrelation consistent covariance matrix
//! estimation", Econometrica 59 (1991) 817–858, eq. 6.2–6.4: fit an AR(1) to each score
//! component, `ρ_j`, innovation variance `σ_j²`, form
//! `α(1) = Σ 4ρ²σ⁴/((1-ρ)⁶(1+ρ)²) / Σ σ⁴/(1-ρ)⁴` and take the Bartlett bandwidth
//! `S_T = 1.1447 (α(1) n)^{1/3}`; the truncation lag is `L = ⌈S_T⌉ - 1` so the weights
//! `1 - l/(L+1)` vanish at `S_T`. `ρ` is clipped to ±0.97 (Andrews' own safeguard against
//! near-unit-root fits) and `L` to `n/4`; hitting the cap is reported.
//!
//! **Computation.** The Bartlett sum equals `(1/(L+1)) Σ_t G_t G_tᵀ` with `G_t` the moving sum
//! of the last `L+1` scores (zero-padded at both ends of the window): every pair `(s, s')` is
//! counted by exactly `L + 1 - |s - s'|` of the windows. That costs `O(n p²)` whatever the lag,
//! and is positive semi-definite by construction.

/// Standard errors of one window.
#[derive(Debug, Clone)]
pub struct Hac {
    /// Standard errors of the unscaled coefficients, `se[j * m + k]`.
    pub se: Vec<f64>,
    /// Root-mean-square residual per right-hand side.
    pub residual_rms: Vec<f64>,
    /// Bartlett truncation lag per right-hand side.
    pub lag: Vec<usize>,
    /// True if a lag was clipped to `n/4`.
    pub lag_capped: bool,
}

/// Andrews' AR(1) safeguard on the fitted autocorrelation of a score.
const RHO_MAX: f64 = 0.97;

/// HAC standard errors. `cols` are the window's regressors (`p`) then right-hand sides (`m`);
/// `mean`, `scale` as in the factor; `coef[j * m + k]` the solution; `ginv_s` the inverse Gram
/// of the scaled regressors.
pub fn newey_west(cols: &[&[f64]], p: usize, mean: &[f64], scale: &[f64], coef: &[f64], ginv_s: &[f64]) -> Hac {
    let q = cols.len();
    let m = q.saturating_sub(p);
    let n = cols.iter().map(|c| c.len()).min().unwrap_or(0);
    let mut out = Hac { se: vec![f64::NAN; p * m], residual_rms: vec![f64::NAN; m], lag: vec![0; m], lag_capped: false };
    if n <= p + 1 || coef.len() != p * m || ginv_s.len() != p * p {
        return out;
    }
    // Pass A: residuals, scores, and the lag-one sums for the AR(1) fits.
    let mut g = vec![0.0; m * n * p];
    let mut sse = vec![0.0; m];
    let mut s_tt = vec![0.0; m * p]; // Σ_{t≥1} g_t²
    let mut s_10 = vec![0.0; m * p]; // Σ_{t≥1} g_t g_{t-1}
    let mut s_00 = vec![0.0; m * p]; // Σ_{t≥1} g_{t-1}²
    let mut a = vec![0.0; p];
    let mut a_s = vec![0.0; p];
    for t in 0..n {
        for j in 0..p {
            a[j] = cols[j][t] - mean[j];
            a_s[j] = a[j] / scale[j];
        }
        for k in 0..m {
            let mut e = cols[p + k][t] - mean[p + k];
            for j in 0..p {
                e -= a[j] * coef[j * m + k];
            }
            sse[k] += e * e;
            let base = (k * n + t) * p;
            for j in 0..p {
                let gt = a_s[j] * e;
                g[base + j] = gt;
                if t > 0 {
                    let gp = g[base - p + j];
                    s_tt[k * p + j] += gt * gt;
                    s_10[k * p + j] += gt * gp;
                    s_00[k * p + j] += gp * gp;
                }
            }
        }
    }
    let dof = n as f64 / (n - p - 1) as f64;
    let cap = n / 4;
    for k in 0..m {
        out.residual_rms[k] = (sse[k] / n as f64).sqrt();
        // Andrews (1991) AR(1) plug-in for the Bartlett kernel.
        let (mut num, mut den) = (0.0, 0.0);
        for j in 0..p {
            let (tt, t10, t00) = (s_tt[k * p + j], s_10[k * p + j], s_00[k * p + j]);
            if t00 <= 0.0 {
                continue;
            }
            let rho = (t10 / t00).clamp(-RHO_MAX, RHO_MAX);
            let sig2 = ((tt - 2.0 * rho * t10 + rho * rho * t00) / (n - 1) as f64).max(0.0);
            let s4 = sig2 * sig2;
            num += 4.0 * rho * rho * s4 / ((1.0 - rho).powi(6) * (1.0 + rho).powi(2));
            den += s4 / (1.0 - rho).powi(4);
        }
        let alpha = if den > 0.0 { num / den } else { 0.0 };
        let bandwidth = 1.1447 * (alpha * n as f64).cbrt();
        let mut lag = if bandwidth.is_finite() && bandwidth > 1.0 { bandwidth.ceil() as usize - 1 } else { 0 };
        if lag > cap {
            lag = cap;
            out.lag_capped = true;
        }
        out.lag[k] = lag;
        // Pass B: S = (1/(L+1)) Σ_t G_t G_tᵀ with G_t the moving sum of L+1 scores.
        let gk = &g[k * n * p..(k + 1) * n * p];
        let mut big_g = vec![0.0; p];
        let mut s = vec![0.0; p * p];
        for t in 0..(n + lag) {
            if t < n {
                for j in 0..p {
                    big_g[j] += gk[t * p + j];
                }
            }
            if t > lag {
                let old = t - lag - 1;
                for j in 0..p {
                    big_g[j] -= gk[old * p + j];
                }
            }
            for i in 0..p {
                let gi = big_g[i];
                for j in i..p {
                    s[i * p + j] += gi * big_g[j];
                }
            }
        }
        let w = 1.0 / (lag + 1) as f64;
        for i in 0..p {
            for j in i..p {
                s[i * p + j] *= w;
                s[j * p + i] = s[i * p + j];
            }
        }
        // Cov_z = G⁻¹ S G⁻¹ (scaled); b_j = z_j / scale_j.
        let mut tmp = vec![0.0; p * p];
        for i in 0..p {
            for j in 0..p {
                let mut acc = 0.0;
                for l in 0..p {
                    acc += ginv_s[i * p + l] * s[l * p + j];
                }
                tmp[i * p + j] = acc;
            }
        }
        for j in 0..p {
            let mut var = 0.0;
            for l in 0..p {
                var += tmp[j * p + l] * ginv_s[l * p + j];
            }
            out.se[j * m + k] = (var.max(0.0) * dof).sqrt() / scale[j];
        }
    }
    out
}
