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
        _ => {
            let m = cols.len().saturating_sub(p);
            Hac { se: vec![f64::NAN; p * m], residual_rms: vec![f64::NAN; m], lag: vec![0; m], lag_capped: false }
        }
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
            out[i][j] = if top <= RHO_MAX {
                a[i * P + j]
            } else {
                (0..P).map(|kk| svd.u[i * P + kk] * svd.sigma[kk].min(RHO_MAX) * svd.v[j * P + kk]).sum()
            };
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
    if lag > cap { (cap, true) } else { (lag, false) }
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
