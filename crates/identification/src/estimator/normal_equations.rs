//! The paper's method, kept only to show what it costs: form the normal equations and solve
//! them by Gaussian elimination (Zhou et al., "An experimental study on oil-film dynamic
//! coefficients", Tribology International 37 (2004) 245–253, eq. 4–6).
//!
//! Zhou et al. set the derivatives of the squared error to zero (eq. 5) and solve the
//! resulting 4 × 4 system of sums of products (eq. 6) per force component. That squares the
//! condition number: `cond(AᵀA) = cond(A)²` for the column-scaled matrix, so where QR loses
//! `log10 κ` digits the normal equations lose `2 log10 κ` (Golub & Van Loan 4th ed. §5.3.7–5.3.8).
//! Here the normal matrix is formed from the centred data exactly as the paper does (the static
//! parts removed, step 7 of §3.1), eliminated with partial pivoting and no scaling, and refused
//! only when a pivot vanishes to working precision. The reported condition number is that of
//! the column-scaled normal matrix, i.e. the square of the one the QR path reports.

use nalgebra::DMatrix;

/// Result of the normal-equation solve of one window.
#[derive(Debug, Clone)]
pub struct NormalSolution {
    /// Column means (regressors then right-hand sides).
    pub mean: Vec<f64>,
    /// Norms of the centred regressor columns (1 for a constant column).
    pub scale: Vec<f64>,
    /// Raw norms of the centred regressor columns.
    pub raw_norm: Vec<f64>,
    /// Coefficients `coef[j * m + k]`; empty when singular.
    pub coef: Vec<f64>,
    /// `D (AᵀA)⁻¹ D`, the inverse Gram matrix of the scaled regressors; empty when singular.
    pub inverse_gram_scaled: Vec<f64>,
    /// Condition number of the column-scaled normal matrix.
    pub condition_normal: f64,
    /// Index of the first vanishing pivot, if any.
    pub singular_at: Option<usize>,
    /// Residual sums of squares are not available without a data pass; totals are:
    pub tss: Vec<f64>,
}

/// Form `AᵀA` and `Aᵀb` from the centred columns (`p` regressors then right-hand sides) and
/// solve by Gaussian elimination with partial pivoting.
pub fn solve(cols: &[&[f64]], p: usize) -> NormalSolution {
    let q = cols.len();
    let m = q.saturating_sub(p);
    let n = cols.iter().map(|c| c.len()).min().unwrap_or(0);
    if p == 0 || p > q || n == 0 {
        return NormalSolution {
            mean: vec![f64::NAN; q],
            scale: vec![1.0; p],
            raw_norm: vec![0.0; p],
            coef: Vec::new(),
            inverse_gram_scaled: Vec::new(),
            condition_normal: f64::NAN,
            singular_at: Some(0),
            tss: vec![0.0; m],
        };
    }
    let mut mean = vec![0.0; q];
    for (j, c) in cols.iter().enumerate() {
        if n > 0 {
            mean[j] = super::window::mean(&c[..n]);
        }
    }
    // Sums of products over the window (eq. 6): the full q × q cross-product matrix.
    let mut s = vec![0.0; q * q];
    let mut row = vec![0.0; q];
    for t in 0..n {
        for j in 0..q {
            row[j] = cols[j][t] - mean[j];
        }
        for i in 0..q {
            let ri = row[i];
            for j in i..q {
                s[i * q + j] += ri * row[j];
            }
        }
    }
    let nmat = |i: usize, j: usize| if i <= j { s[i * q + j] } else { s[j * q + i] };
    let raw_norm: Vec<f64> = (0..p).map(|j| nmat(j, j).max(0.0).sqrt()).collect();
    let scale: Vec<f64> = raw_norm.iter().map(|&d| if d > 0.0 && d.is_finite() { d } else { 1.0 }).collect();
    let tss: Vec<f64> = (0..m).map(|k| nmat(p + k, p + k)).collect();

    // Condition of the scaled normal matrix (for the report only).
    let scaled = DMatrix::from_fn(p, p, |i, j| nmat(i, j) / (scale[i] * scale[j]));
    let condition_normal = if scaled.iter().all(|v| v.is_finite()) {
        match nalgebra::linalg::SymmetricEigen::try_new(scaled, f64::EPSILON, 10_000) {
            Some(e) => {
                let hi = e.eigenvalues.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
                let lo = e.eigenvalues.iter().cloned().fold(f64::INFINITY, f64::min);
                if lo > 0.0 {
                    hi / lo
                } else {
                    f64::INFINITY
                }
            }
            None => f64::NAN,
        }
    } else {
        f64::NAN
    };

    // Gaussian elimination with partial pivoting on [N | Aᵀb | I] (the identity gives N⁻¹ for
    // the covariance).
    let w = p + m + p;
    let mut aug = vec![0.0; p * w];
    let mut big: f64 = 0.0;
    for i in 0..p {
        for j in 0..p {
            aug[i * w + j] = nmat(i, j);
            big = big.max(nmat(i, j).abs());
        }
        for k in 0..m {
            aug[i * w + p + k] = nmat(i, p + k);
        }
        aug[i * w + p + m + i] = 1.0;
    }
    let mut singular_at = None;
    for c in 0..p {
        let mut piv = c;
        for i in (c + 1)..p {
            if aug[i * w + c].abs() > aug[piv * w + c].abs() {
                piv = i;
            }
        }
        let pv = aug[piv * w + c];
        if !(pv.abs() > f64::EPSILON * big) {
            singular_at = Some(c);
            break;
        }
        if piv != c {
            for j in 0..w {
                aug.swap(c * w + j, piv * w + j);
            }
        }
        for i in 0..p {
            if i == c {
                continue;
            }
            let f = aug[i * w + c] / pv;
            if f != 0.0 {
                for j in c..w {
                    aug[i * w + j] -= f * aug[c * w + j];
                }
            }
        }
    }
    let (coef, inverse_gram_scaled) = if singular_at.is_some() {
        (Vec::new(), Vec::new())
    } else {
        let mut coef = vec![0.0; p * m];
        let mut ginv = vec![0.0; p * p];
        for i in 0..p {
            let d = aug[i * w + i];
            for k in 0..m {
                coef[i * m + k] = aug[i * w + p + k] / d;
            }
            for j in 0..p {
                ginv[i * p + j] = aug[i * w + p + m + j] / d * scale[i] * scale[j];
            }
        }
        (coef, ginv)
    };
    NormalSolution { mean, scale, raw_norm, coef, inverse_gram_scaled, condition_normal, singular_at, tss }
}
