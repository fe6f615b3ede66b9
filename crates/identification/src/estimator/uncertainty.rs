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
//! **Prewhitening.** The scores of a sinusoidally excited rig with low-pass coloured noise are
//! strongly autocorrelated, and a plain Bartlett estimator is then biased low by about
//! `Σ|l|γ(l)/(L+1)` (intervals too narrow). Following Andrews & Monahan, "An improved
//! heteroskedasticity and autocorrelation consistent covariance matrix estimator", Econometrica
//! 60 (1992) 953–966, the scores are first filtered by a fitted VAR(1), `u_t = g_t - Â g_{t-1}`
//! (singular values of `Â` capped at 0.97), the Bartlett estimator is applied to `u`, and the
//! result is recoloured, `S = (I - Â)⁻¹ S_u (I - Â)⁻ᵀ`. Recolouring is exact for the long-run
//! variance whatever the true dynamics, so the estimator stays consistent; the VAR only has to
//! remove most of the correlation for the kernel's bias to become small.
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

/// Standard errors of one window.
#[derive(Debug, Clone)]
pub struct Hac {
    /// Standard errors of the unscaled coefficients, `se[j * m + k]`.
    pub se: Vec<f64>,
    /// Root-mean-square residual per right-hand side.
    pub residual_rms: Vec<f64>,
    /// Bartlett truncation lag per right-hand side (on the prewhitened scores).
    pub lag: Vec<usize>,
    /// True if a lag was clipped to `n/4`.
    pub lag_capped: bool,
}

/// Andrews' AR(1) safeguard on fitted autocorrelations, and Andrews–Monahan's cap on the
/// singular values of the prewhitening VAR.
const RHO_MAX: f64 = 0.97;

/// HAC standard errors. `cols` are the window's regressors (`p`) then right-hand sides (`m`);
/// `mean`, `scale` as in the factor; `coef[j * m + k]` the solution; `ginv_s` the inverse Gram
/// of the scaled regressors.
pub fn newey_west(cols: &[&[f64]], p: usize, mean: &[f64], scale: &[f64], coef: &[f64], ginv_s: &[f64]) -> Hac {
    let q = cols.len();
    let m = q.saturating_sub(p);
    let n = cols.iter().map(|c| c.len()).min().unwrap_or(0);
    let mut out = Hac { se: vec![f64::NAN; p * m], residual_rms: vec![f64::NAN; m], lag: vec![0; m], lag_capped: false };
    if n <= p + 2 || coef.len() != p * m || ginv_s.len() != p * p || scale.len() < p || mean.len() < q {
        return out;
    }
    // Residuals and scores g_t = a_t e_t (row-major n × p per right-hand side).
    let mut g = vec![0.0; m * n * p];
    let mut sse = vec![0.0; m];
    let mut a = vec![0.0; p];
    for t in 0..n {
        for j in 0..p {
            a[j] = cols[j][t] - mean[j];
        }
        for k in 0..m {
            let mut e = cols[p + k][t] - mean[p + k];
            for j in 0..p {
                e -= a[j] * coef[j * m + k];
            }
            sse[k] += e * e;
            let base = (k * n + t) * p;
            for j in 0..p {
                g[base + j] = a[j] / scale[j] * e;
            }
        }
    }
    let dof = n as f64 / (n - p - 1) as f64;
    for k in 0..m {
        out.residual_rms[k] = (sse[k] / n as f64).sqrt();
        let gk = &g[k * n * p..(k + 1) * n * p];
        let var = var1(gk, n, p);
        let u = prewhiten(gk, n, p, &var);
        let nu = n - 1;
        let (lag, capped) = andrews_lag(&u, nu, p);
        out.lag[k] = lag;
        out.lag_capped |= capped;
        let s_u = bartlett(&u, nu, p, lag);
        let s = recolour(&s_u, &var, p);
        // Cov_z = G⁻¹ S G⁻¹ (scaled); b_j = z_j / scale_j.
        for j in 0..p {
            let mut v = 0.0;
            for l in 0..p {
                let mut row = 0.0;
                for r in 0..p {
                    row += s[l * p + r] * ginv_s[r * p + j];
                }
                v += ginv_s[j * p + l] * row;
            }
            out.se[j * m + k] = (v.max(0.0) * dof).sqrt() / scale[j];
        }
    }
    out
}

/// Least-squares VAR(1) coefficient `Â` (row-major `p × p`) of the scores, singular values
/// capped at [`RHO_MAX`]; zero if the lagged scores are degenerate.
fn var1(g: &[f64], n: usize, p: usize) -> Vec<f64> {
    let mut xx = vec![0.0; p * p];
    let mut yx = vec![0.0; p * p];
    for t in 1..n {
        let (prev, cur) = (&g[(t - 1) * p..t * p], &g[t * p..(t + 1) * p]);
        for i in 0..p {
            let (pi, ci) = (prev[i], cur[i]);
            let (rx, ry) = (&mut xx[i * p..(i + 1) * p], &mut yx[i * p..(i + 1) * p]);
            for j in 0..p {
                rx[j] += pi * prev[j];
                ry[j] += ci * prev[j];
            }
        }
    }
    let sxx = nalgebra::DMatrix::from_row_slice(p, p, &xx);
    let syx = nalgebra::DMatrix::from_row_slice(p, p, &yx);
    let zero = vec![0.0; p * p];
    let Some(chol) = sxx.cholesky() else { return zero };
    // Â = Syx Sxx⁻¹  ⇔  Sxx Âᵀ = Syxᵀ.
    let at = chol.solve(&syx.transpose());
    let mut a = vec![0.0; p * p];
    for i in 0..p {
        for j in 0..p {
            a[i * p + j] = at[(j, i)];
        }
    }
    let Some(svd) = super::svd::SmallSvd::new(&a, p) else { return zero };
    if svd.sigma.first().copied().unwrap_or(0.0) <= RHO_MAX {
        return a;
    }
    let mut capped = vec![0.0; p * p];
    for kk in 0..p {
        let sk = svd.sigma[kk].min(RHO_MAX);
        for i in 0..p {
            for j in 0..p {
                capped[i * p + j] += svd.u[i * p + kk] * sk * svd.v[j * p + kk];
            }
        }
    }
    capped
}

/// `u_t = g_t - Â g_{t-1}`, `t = 1..n` (row-major `(n-1) × p`).
fn prewhiten(g: &[f64], n: usize, p: usize, a: &[f64]) -> Vec<f64> {
    let mut u = vec![0.0; (n - 1) * p];
    for t in 1..n {
        let prev = &g[(t - 1) * p..t * p];
        for i in 0..p {
            let mut v = g[t * p + i];
            for j in 0..p {
                v -= a[i * p + j] * prev[j];
            }
            u[(t - 1) * p + i] = v;
        }
    }
    u
}

/// Andrews (1991) AR(1) plug-in bandwidth for the Bartlett kernel; returns the truncation lag
/// and whether it was clipped to `n/4`.
fn andrews_lag(u: &[f64], n: usize, p: usize) -> (usize, bool) {
    let (mut num, mut den) = (0.0, 0.0);
    for j in 0..p {
        let (mut tt, mut t10, mut t00) = (0.0, 0.0, 0.0);
        for t in 1..n {
            let (c, pr) = (u[t * p + j], u[(t - 1) * p + j]);
            tt += c * c;
            t10 += c * pr;
            t00 += pr * pr;
        }
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
    let lag = if bandwidth.is_finite() && bandwidth > 1.0 { bandwidth.ceil() as usize - 1 } else { 0 };
    let cap = n / 4;
    if lag > cap { (cap, true) } else { (lag, false) }
}

/// `S = (1/(L+1)) Σ_t G_t G_tᵀ` with `G_t` the moving sum of the last `L + 1` rows of `u`.
fn bartlett(u: &[f64], n: usize, p: usize, lag: usize) -> Vec<f64> {
    let mut big_g = vec![0.0; p];
    let mut s = vec![0.0; p * p];
    for t in 0..(n + lag) {
        if t < n {
            for j in 0..p {
                big_g[j] += u[t * p + j];
            }
        }
        if t > lag {
            let old = t - lag - 1;
            if old < n {
                for j in 0..p {
                    big_g[j] -= u[old * p + j];
                }
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
    s
}

/// `(I - Â)⁻¹ S_u (I - Â)⁻ᵀ`; `S_u` unchanged if `I - Â` cannot be inverted (it always can
/// with the singular values of `Â` capped below one).
fn recolour(s_u: &[f64], a: &[f64], p: usize) -> Vec<f64> {
    let ia = nalgebra::DMatrix::from_fn(p, p, |i, j| if i == j { 1.0 } else { 0.0 } - a[i * p + j]);
    let Some(inv) = ia.try_inverse() else { return s_u.to_vec() };
    let su = nalgebra::DMatrix::from_row_slice(p, p, s_u);
    let s = &inv * su * inv.transpose();
    let mut out = vec![0.0; p * p];
    for i in 0..p {
        for j in 0..p {
            out[i * p + j] = s[(i, j)];
        }
    }
    out
}
