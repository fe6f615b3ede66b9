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

    /// Half-bandwidth.
    pub(crate) fn bandwidth(&self) -> usize {
        self.bw
    }

    /// Keeps rows `0..keep` (matrix entries, or factor rows if factorised) and makes rows
    /// `keep..n` zero, for a matrix of new order `n` and the same bandwidth. With
    /// [`BandedCholesky::factor_from`]`(keep)` this refactorises only the trailing rows: row `i`
    /// of `L` depends only on the leading `(i + 1) x (i + 1)` block of the matrix, so when
    /// only rows `>= keep` change the leading factor rows stay valid.
    pub(crate) fn truncate_rows(&mut self, keep: usize, n: usize) {
        let keep = keep.min(self.n).min(n);
        let w = self.bw + 1;
        self.n = n;
        self.data.truncate(keep * w);
        self.data.resize(n * w, 0.0);
        self.inv_diag.truncate(keep);
        self.factored = false;
    }

    /// Row `i` of the lower band: slot `bw - d` holds column `i - d` (slot `bw`: the diagonal).
    /// `i` must be below the order.
    #[inline]
    pub(crate) fn row_mut(&mut self, i: usize) -> &mut [f64] {
        let w = self.bw + 1;
        &mut self.data[i * w..(i + 1) * w]
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
        self.inv_diag.clear();
        self.factor_from(0)
    }

    /// Factorises rows `first..n`, the rows before being already factorised (see
    /// [`BandedCholesky::truncate_rows`]). Errors as [`BandedCholesky::factor`].
    pub(crate) fn factor_from(&mut self, first: usize) -> Result<(), usize> {
        let bw = self.bw;
        let w = bw + 1;
        let first = first.min(self.inv_diag.len());
        self.inv_diag.truncate(first);
        self.inv_diag.resize(self.n, 0.0);
        self.factored = false;
        for i in first..self.n {
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
    fn refactoring_the_trailing_rows_matches_a_full_factorisation() {
        let (mut band, dense) = random_banded_spd(60, 5, 21);
        band.factor().unwrap();
        // A different matrix of another order that shares the leading 25 x 25 block.
        let (_, other) = random_banded_spd(70, 5, 22);
        let mut changed = DMatrix::<f64>::zeros(70, 70);
        for i in 0..70 {
            for j in 0..70 {
                changed[(i, j)] = if i < 25 && j < 25 { dense[(i, j)] } else { other[(i, j)] };
            }
        }
        // Keep diagonal dominance where the blocks meet.
        for i in 0..70 {
            let off: f64 = (0..70).filter(|&j| j != i).map(|j| changed[(i, j)].abs()).sum();
            if i >= 25 {
                changed[(i, i)] = off + 0.5;
            }
        }
        band.truncate_rows(25, 70);
        for i in 25..70 {
            let row = band.row_mut(i);
            for d in 0..=5.min(i) {
                row[5 - d] = changed[(i, i - d)];
            }
        }
        band.factor_from(25).unwrap();
        let mut full = BandedCholesky::default();
        full.reset(70, 5);
        for i in 0..70_usize {
            for j in i.saturating_sub(5)..=i {
                full.add(i, j, changed[(i, j)]);
            }
        }
        full.factor().unwrap();
        for i in 0..70_usize {
            for j in i.saturating_sub(5)..=i {
                assert!((band.get(i, j) - full.get(i, j)).abs() < 1e-13, "L({i}, {j})");
            }
        }
        let mut x = vec![1.0; 70];
        band.solve_in_place(&mut x);
        let residual = &changed * DVector::from_vec(x) - DVector::from_element(70, 1.0);
        assert!(residual.norm() < 1e-12, "{}", residual.norm());
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
