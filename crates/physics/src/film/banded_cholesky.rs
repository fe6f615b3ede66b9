//! Banded Cholesky factorisation `A = L L^T` of a symmetric positive definite matrix, with
//! triangular solves.
//!
//! The finite-length film orders its unknowns axial-index fastest, so a node couples only to
//! neighbours at most `n_z` places away: the Reynolds matrix is banded with half-bandwidth
//! `bw = n_z`. Cholesky preserves the band (no fill outside it), so factorisation costs
//! `O(n bw^2)` and a solve `O(n bw)` (Golub & Van Loan, *Matrix Computations*, 4th ed., sec.
//! 4.3.5, "band Cholesky").
//!
//! Storage: the lower band only, row-major. Row `i` holds the `bw + 1` entries of columns
//! `i - bw ..= i` (slots left of column 0 stay zero and are never read), so entry `(i, j)` with
//! `i - bw <= j <= i` lives at `data[i * (bw + 1) + (j + bw - i)]`. The factor `L` overwrites
//! the matrix in place, which lets the owner reuse one allocation for every factorisation.

/// A banded symmetric matrix that is factorised in place into its Cholesky factor.
/// `Default` is the empty 0 x 0 matrix; call [`BandedCholesky::reset`] before use.
#[derive(Debug, Clone, Default)]
pub(crate) struct BandedCholesky {
    n: usize,
    bw: usize,
    data: Vec<f64>,
    /// `1 / L_ii`, filled by the factorisation.
    inv_diag: Vec<f64>,
    factored: bool,
}

impl BandedCholesky {
    /// Makes this the zero `n x n` matrix of half-bandwidth `bw`, reusing the allocation.
    pub(crate) fn reset(&mut self, n: usize, bw: usize) {
        self.n = n;
        self.bw = bw;
        self.factored = false;
        self.data.clear();
        self.data.resize(n * (bw + 1), 0.0);
    }

    /// Order of the matrix.
    pub(crate) fn order(&self) -> usize {
        self.n
    }

    #[inline]
    fn slot(&self, i: usize, j: usize) -> usize {
        i * (self.bw + 1) + (j + self.bw - i)
    }

    /// Adds `v` to the symmetric pair `(i, j)`, `(j, i)`. Both indices must lie inside the
    /// matrix and within the band (`|i - j| <= bw`): the caller's assembly guarantees it.
    #[inline]
    pub(crate) fn add(&mut self, i: usize, j: usize, v: f64) {
        let (i, j) = if j > i { (j, i) } else { (i, j) };
        debug_assert!(i < self.n && i - j <= self.bw, "entry ({i}, {j}) outside the band");
        let s = self.slot(i, j);
        self.data[s] += v;
    }

    /// Entry `(i, j)` of the matrix (before factorisation) or of `L` (after), zero outside the
    /// band or the matrix.
    #[cfg(test)]
    pub(crate) fn get(&self, i: usize, j: usize) -> f64 {
        let (i, j) = if j > i { (j, i) } else { (i, j) };
        if i >= self.n || i - j > self.bw {
            return 0.0;
        }
        self.data[self.slot(i, j)]
    }

    /// Factorises in place, `A = L L^T` (row-oriented Cholesky-Crout).
    ///
    /// Errors with the failing row when a pivot is not positive and finite: the matrix is not
    /// positive definite (or is contaminated by NaN).
    pub(crate) fn factor(&mut self) -> Result<(), usize> {
        let bw = self.bw;
        let w = bw + 1;
        self.inv_diag.clear();
        self.inv_diag.resize(self.n, 0.0);
        self.factored = false;
        for i in 0..self.n {
            // Row i stores L_ik at slot k + bw - i; every k in [j0, j) is in both rows i, j.
            let j0 = i.saturating_sub(bw);
            let (prev, cur) = self.data.split_at_mut(i * w);
            let row_i = &mut cur[..w];
            for j in j0..i {
                let row_j = &prev[j * w..(j + 1) * w];
                let dot: f64 = row_i[j0 + bw - i..j + bw - i].iter().zip(&row_j[j0 + bw - j..bw]).map(|(a, b)| a * b).sum();
                row_i[j + bw - i] = (row_i[j + bw - i] - dot) * self.inv_diag[j];
            }
            let dot: f64 = row_i[j0 + bw - i..bw].iter().map(|a| a * a).sum();
            let s = row_i[bw] - dot;
            if !(s > 0.0 && s.is_finite()) {
                return Err(i);
            }
            let d = s.sqrt();
            row_i[bw] = d;
            self.inv_diag[i] = 1.0 / d;
        }
        self.factored = true;
        Ok(())
    }

    /// Solves `A x = rhs` in place with the factor. `rhs.len()` must equal the order; the
    /// caller only solves after a successful [`BandedCholesky::factor`].
    pub(crate) fn solve_in_place(&self, rhs: &mut [f64]) {
        debug_assert!(self.factored, "solve before a successful factorisation");
        debug_assert_eq!(rhs.len(), self.n);
        let bw = self.bw;
        let w = bw + 1;
        let n = self.n.min(rhs.len());
        // Forward: L y = rhs.
        for i in 0..n {
            let j0 = i.saturating_sub(bw);
            let row = &self.data[i * w..(i + 1) * w];
            let (done, cur) = rhs.split_at_mut(i);
            let dot: f64 = row[j0 + bw - i..bw].iter().zip(&done[j0..]).map(|(a, b)| a * b).sum();
            cur[0] = (cur[0] - dot) * self.inv_diag[i];
        }
        // Backward: L^T x = y, column-oriented so that L is read by rows.
        for i in (0..n).rev() {
            let j0 = i.saturating_sub(bw);
            let row = &self.data[i * w..(i + 1) * w];
            let (before, cur) = rhs.split_at_mut(i);
            let xi = cur[0] * self.inv_diag[i];
            cur[0] = xi;
            for (r, l) in before[j0..].iter_mut().zip(&row[j0 + bw - i..bw]) {
                *r -= l * xi;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};

    /// Deterministic pseudo-random numbers in [-1, 1) (64-bit LCG, Knuth's MMIX constants).
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        }
    }

    fn random_banded_spd(n: usize, bw: usize, seed: u64) -> (BandedCholesky, DMatrix<f64>) {
        let mut rng = Lcg(seed);
        let mut dense = DMatrix::<f64>::zeros(n, n);
        for i in 0..n {
            for j in i.saturating_sub(bw)..i {
                let v = rng.next();
                dense[(i, j)] = v;
                dense[(j, i)] = v;
            }
        }
        // Strict diagonal dominance makes it SPD.
        for i in 0..n {
            let off: f64 = (0..n).filter(|&j| j != i).map(|j| dense[(i, j)].abs()).sum();
            dense[(i, i)] = off + 0.1 + rng.next().abs();
        }
        let mut band = BandedCholesky::default();
        band.reset(n, bw);
        for i in 0..n {
            for j in i.saturating_sub(bw)..=i {
                band.add(i, j, dense[(i, j)]);
            }
        }
        (band, dense)
    }

    #[test]
    fn matches_a_dense_solve() {
        for &(n, bw, seed) in &[(1, 0, 1), (5, 0, 2), (7, 1, 3), (40, 6, 4), (120, 12, 5), (9, 8, 6), (6, 10, 7)] {
            let (mut band, dense) = random_banded_spd(n, bw, seed);
            let mut rng = Lcg(seed + 100);
            let rhs = DVector::from_fn(n, |_, _| rng.next());
            let expected = dense.clone().lu().solve(&rhs).expect("diagonally dominant matrix is regular");
            band.factor().expect("SPD by construction");
            let mut x = rhs.as_slice().to_vec();
            band.solve_in_place(&mut x);
            let err = (DVector::from_vec(x) - &expected).norm() / expected.norm().max(1e-300);
            assert!(err < 1e-12, "n {n} bw {bw}: relative error {err:e}");
            // The factor reproduces the matrix.
            let l = DMatrix::from_fn(n, n, |i, j| if j <= i { band.get(i, j) } else { 0.0 });
            let rec = (&l * l.transpose() - &dense).norm() / dense.norm();
            assert!(rec < 1e-13, "n {n} bw {bw}: L L^T mismatch {rec:e}");
        }
    }

    #[test]
    fn reset_reuses_storage_and_clears() {
        let (mut band, _) = random_banded_spd(30, 4, 11);
        band.factor().unwrap();
        band.reset(3, 1);
        assert_eq!(band.order(), 3);
        for i in 0..3 {
            for j in 0..3 {
                assert_eq!(band.get(i, j), 0.0);
            }
        }
        band.add(0, 0, 4.0);
        band.add(1, 1, 4.0);
        band.add(2, 2, 4.0);
        band.add(0, 1, 1.0);
        band.factor().unwrap();
        let mut x = vec![5.0, 5.0, 4.0];
        band.solve_in_place(&mut x);
        for (a, b) in x.iter().zip([1.0, 1.0, 1.0]) {
            assert!((a - b).abs() < 1e-14, "{x:?}");
        }
    }

    #[test]
    fn reports_the_row_where_definiteness_fails() {
        let mut band = BandedCholesky::default();
        band.reset(3, 1);
        band.add(0, 0, 1.0);
        band.add(1, 1, 1.0);
        band.add(1, 0, 2.0); // 2x2 leading minor 1 - 4 < 0
        band.add(2, 2, 1.0);
        assert_eq!(band.factor(), Err(1));
        band.reset(2, 1);
        band.add(0, 0, f64::NAN);
        band.add(1, 1, 1.0);
        assert_eq!(band.factor(), Err(0));
    }
}
