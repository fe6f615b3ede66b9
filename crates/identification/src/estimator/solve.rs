//! From a window's triangular factor to scaled regressors, rank, condition and solution.
//!
//! The regressors are scaled to unit column norm (`A_s = A D⁻¹`, equivalently `R_s = R D⁻¹`;
//! column norms survive the orthogonal reduction, so `D` is read off `R`). Column scaling is
//! the equilibration that makes the condition number describe the *excitation* rather than the
//! units (metres against metres per second differ by the excitation frequency); by van der
//! Sluis' theorem it is within a factor `sqrt(p)` of the best diagonal scaling. The numerical
//! rank counts singular values of `R_s` above `max(n, p) ε σ_max` (LAPACK's default `rcond`).
//!
//! [`Solver::Qr`] back-substitutes `R_s z = Qᵀb`; [`Solver::Svd`] applies the pseudo-inverse of
//! `R_s`. Both then unscale, `b = D⁻¹ z`.

use super::qr::{inverse_gram_from_upper, solve_upper};
use super::svd::SmallSvd;
use super::window::BlockSummary;
use super::Solver;

/// The column-scaled least-squares problem of one window.
#[derive(Debug, Clone)]
pub struct ScaledFactor {
    /// Regressors.
    pub p: usize,
    /// Right-hand sides.
    pub m: usize,
    /// Column means of regressors then right-hand sides.
    pub mean: Vec<f64>,
    /// Norms of the centred regressor columns (1 for an all-zero column).
    pub scale: Vec<f64>,
    /// Regressors that do not vary at all (zero centred norm).
    pub zero_columns: Vec<usize>,
    /// Scaled factor `R D⁻¹`, row-major `p × p`.
    pub rs: Vec<f64>,
    /// `Qᵀb`, row-major `p × m`.
    pub qtb: Vec<f64>,
    /// Residual sums of squares (from the trailing triangle of the augmented factor).
    pub rss: Vec<f64>,
    /// SVD of `rs`.
    pub svd: SmallSvd,
    /// Condition number of the scaled, centred regressors.
    pub condition: f64,
    /// Numerical rank.
    pub rank: usize,
}

/// Solution in unscaled units, row-major `p × m`, and `(A_sᵀA_s)⁻¹` (`p × p`).
#[derive(Debug, Clone)]
pub struct Solution {
    /// Coefficients, `coef[j * m + k]` for regressor `j`, right-hand side `k`.
    pub coef: Vec<f64>,
    /// Inverse Gram matrix of the scaled regressors.
    pub inverse_gram_scaled: Vec<f64>,
}

impl ScaledFactor {
    /// Analyse an augmented summary whose first `p` columns are regressors and the remaining
    /// `m` are right-hand sides. `None` when the factor is not finite (overflow) or the SVD fails.
    pub fn new(summary: &BlockSummary, p: usize) -> Option<Self> {
        let q = summary.r.cols();
        if p == 0 || p > q || !summary.r.is_finite() {
            return None;
        }
        let m = q - p;
        let r = &summary.r;
        let norms: Vec<f64> = (0..p).map(|j| r.column_norm(j)).collect();
        let zero_columns: Vec<usize> = (0..p).filter(|&j| norms[j] == 0.0).collect();
        let scale: Vec<f64> = norms.into_iter().map(|d| if d > 0.0 && d.is_finite() { d } else { 1.0 }).collect();
        let mut rs = vec![0.0; p * p];
        for i in 0..p {
            for j in i..p {
                rs[i * p + j] = r.get(i, j) / scale[j];
            }
        }
        let mut qtb = vec![0.0; p * m];
        for i in 0..p {
            for k in 0..m {
                qtb[i * m + k] = r.get(i, p + k);
            }
        }
        let mut rss = vec![0.0; m];
        for k in 0..m {
            let col = p + k;
            for i in 0..=col {
                let v = r.get(i, col);
                if i >= p {
                    rss[k] += v * v;
                }
            }
        }
        let svd = SmallSvd::new(&rs, p)?;
        let n = summary.n;
        let rtol = (n.max(p) as f64) * f64::EPSILON;
        let rank = svd.rank(rtol);
        let condition = svd.condition();
        Some(Self { p, m, mean: summary.mean.clone(), scale, zero_columns, rs, qtb, rss, svd, condition, rank })
    }

    /// Solve with QR back-substitution or the SVD pseudo-inverse. `None` if rank-deficient.
    pub fn solve(&self, solver: Solver) -> Option<Solution> {
        let (p, m) = (self.p, self.m);
        if self.rank < p {
            return None;
        }
        let mut coef = vec![0.0; p * m];
        let inverse_gram_scaled = match solver {
            Solver::Svd => {
                for k in 0..m {
                    let b: Vec<f64> = (0..p).map(|i| self.qtb[i * m + k]).collect();
                    let z = self.svd.solve(&b, p);
                    for j in 0..p {
                        coef[j * m + k] = z[j] / self.scale[j];
                    }
                }
                self.svd.inverse_gram(p)
            }
            Solver::Qr | Solver::NormalEquations => {
                for k in 0..m {
                    let mut z: Vec<f64> = (0..p).map(|i| self.qtb[i * m + k]).collect();
                    if !solve_upper(&self.rs, p, &mut z) {
                        return None;
                    }
                    for j in 0..p {
                        coef[j * m + k] = z[j] / self.scale[j];
                    }
                }
                inverse_gram_from_upper(&self.rs, p)?
            }
        };
        Some(Solution { coef, inverse_gram_scaled })
    }
}
