//! Singular value decomposition of the small column-scaled triangular factor ("R-SVD").
//!
//! For a tall matrix `A = Q R` the singular values and right singular vectors of `A` are those
//! of `R`, and `Uᵀb = U_Rᵀ Qᵀb`; decomposing the `p × p` factor instead of the `n × p` data is
//! Chan's R-bidiagonalisation (T. F. Chan, "An improved algorithm for computing the singular
//! value decomposition", ACM TOMS 8 (1982) 72–83; Golub & Van Loan 4th ed. §8.6.3), and what
//! LAPACK's `gelsd` does when `m ≫ n`. The singular values give the condition number and the
//! numerical rank for every solver; [`SmallSvd::solve`] is the [`super::Solver::Svd`] path.
//! The iteration itself is nalgebra's Golub–Kahan SVD, bounded in iterations so that it cannot
//! loop on pathological input.

use nalgebra::DMatrix;

/// Thin SVD `A = U diag(sigma) Vᵀ` of a square matrix, singular values in decreasing order.
#[derive(Debug, Clone)]
pub struct SmallSvd {
    /// Order of the matrix.
    pub p: usize,
    /// Singular values, largest first.
    pub sigma: Vec<f64>,
    /// Left singular vectors, row-major `p × p` (column `k` is `u_k`).
    pub u: Vec<f64>,
    /// Right singular vectors, row-major `p × p` (column `k` is `v_k`).
    pub v: Vec<f64>,
}

impl SmallSvd {
    /// Decompose the row-major `p × p` matrix `a`; `None` if it is not finite or the iteration
    /// does not converge.
    pub fn new(a: &[f64], p: usize) -> Option<Self> {
        if p == 0 || a.len() != p * p || a.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let m = DMatrix::from_row_slice(p, p, a);
        let svd = nalgebra::linalg::SVD::try_new(m, true, true, f64::EPSILON, 10_000)?;
        let u = svd.u?;
        let vt = svd.v_t?;
        let mut order: Vec<usize> = (0..p).collect();
        order.sort_by(|&i, &j| svd.singular_values[j].total_cmp(&svd.singular_values[i]));
        let mut out = Self { p, sigma: vec![0.0; p], u: vec![0.0; p * p], v: vec![0.0; p * p] };
        for (k, &src) in order.iter().enumerate() {
            out.sigma[k] = svd.singular_values[src];
            for i in 0..p {
                out.u[i * p + k] = u[(i, src)];
                out.v[i * p + k] = vt[(src, i)];
            }
        }
        Some(out)
    }

    /// `sigma_max / sigma_min` (infinite when the smallest is zero).
    pub fn condition(&self) -> f64 {
        match (self.sigma.first(), self.sigma.last()) {
            (Some(&hi), Some(&lo)) if lo > 0.0 => hi / lo,
            (Some(_), Some(_)) => f64::INFINITY,
            _ => f64::NAN,
        }
    }

    /// Number of singular values above `rtol * sigma_max`.
    pub fn rank(&self, rtol: f64) -> usize {
        let hi = self.sigma.first().copied().unwrap_or(0.0);
        self.sigma.iter().filter(|&&s| s > rtol * hi && s > 0.0).count()
    }

    /// Minimum-norm solution `V Σ⁺ Uᵀ b` using the leading `rank` singular triplets.
    pub fn solve(&self, b: &[f64], rank: usize) -> Vec<f64> {
        let p = self.p;
        let mut x = vec![0.0; p];
        for k in 0..rank.min(p) {
            let mut c = 0.0;
            for i in 0..p {
                c += self.u[i * p + k] * b[i];
            }
            let c = c / self.sigma[k];
            for i in 0..p {
                x[i] += self.v[i * p + k] * c;
            }
        }
        x
    }

    /// `V Σ⁻² Vᵀ` over the leading `rank` triplets: `(AᵀA)⁻¹` when `rank == p`.
    pub fn inverse_gram(&self, rank: usize) -> Vec<f64> {
        let p = self.p;
        let mut g = vec![0.0; p * p];
        for k in 0..rank.min(p) {
            let w = 1.0 / (self.sigma[k] * self.sigma[k]);
            for i in 0..p {
                for j in 0..p {
                    g[i * p + j] += w * self.v[i * p + k] * self.v[j * p + k];
                }
            }
        }
        g
    }

    /// Right singular vector of the smallest singular value (the near-dependency of columns).
    pub fn weakest_direction(&self) -> Vec<f64> {
        let p = self.p;
        (0..p).map(|i| self.v[i * p + p - 1]).collect()
    }
}
