//! Householder QR for tall, skinny least squares, one block of rows at a time.
//!
//! The window's regressors (and, appended as extra columns, its two force signals) are reduced
//! to a small upper-triangular factor `R` by Householder reflections (Golub & Van Loan,
//! *Matrix Computations*, 4th ed., §5.1.2–5.1.4 for reflectors, §5.2.1 for Householder QR,
//! §5.3.3 for least squares by QR). Rows are fed in blocks: a block `C` is annihilated into the
//! current factor, so after the call `R` is the triangular factor of `[R_old; C]`. Because
//! `R_old` is already triangular, the reflector for column `j` only touches row `j` of `R` and
//! the rows of `C`; this is the "sequential" (flat-tree) variant of TSQR, and stacking two
//! finished factors ([`Triangle::absorb_triangle`]) is its reduction step (Demmel, Grigori,
//! Hoemmen & Langou, "Communication-optimal parallel and sequential QR and LU
//! factorizations", SIAM J. Sci. Comput. 34 (2012) A206–A239).
//!
//! Appending the right-hand sides `B` as columns gives the augmented factor
//! `[[R, Qᵀb], [0, T]]`: the least-squares solution is `R⁻¹ Qᵀb` and the residual sums of
//! squares are the column norms of `T`, with no second pass over the data and never the normal
//! matrix `AᵀA`.
//!
//! One decomposition per file: the singular value decomposition of the small factor lives in
//! [`super::svd`], the paper's normal equations in [`super::normal_equations`].

/// An upper-triangular `cols × cols` factor, stored row-major (zeros below the diagonal).
#[derive(Debug, Clone, PartialEq)]
pub struct Triangle {
    cols: usize,
    r: Vec<f64>,
}

impl Triangle {
    /// The factor of an empty matrix with `cols` columns (all zeros).
    pub fn zeros(cols: usize) -> Self {
        Self { cols, r: vec![0.0; cols * cols] }
    }

    /// Number of columns.
    pub fn cols(&self) -> usize {
        self.cols
    }

    /// Entry `(i, j)`; zero below the diagonal.
    pub fn get(&self, i: usize, j: usize) -> f64 {
        self.r[i * self.cols + j]
    }

    /// All entries, row-major.
    pub fn as_slice(&self) -> &[f64] {
        &self.r
    }

    /// True when every entry is finite.
    pub fn is_finite(&self) -> bool {
        self.r.iter().all(|v| v.is_finite())
    }

    /// Euclidean norm of column `j` of the factored matrix (reflections preserve it).
    pub fn column_norm(&self, j: usize) -> f64 {
        let mut s = 0.0;
        for i in 0..=j.min(self.cols.saturating_sub(1)) {
            let v = self.get(i, j);
            s += v * v;
        }
        s.sqrt()
    }

    /// Flip the sign of every row whose diagonal is negative, making the factor unique
    /// (the Cholesky factor of the Gram matrix) without changing any solution.
    pub fn make_diagonal_nonnegative(&mut self) {
        let q = self.cols;
        for i in 0..q {
            if self.r[i * q + i] < 0.0 {
                for v in &mut self.r[i * q + i..(i + 1) * q] {
                    *v = -*v;
                }
            }
        }
    }

    /// Annihilate `rows` rows into the factor. `block` holds them column-major
    /// (`block[j * rows + i]` is row `i`, column `j`) and is overwritten with the reflectors.
    /// Afterwards `self` is the triangular factor of `[self; block]`.
    ///
    /// Does nothing when `block` is not exactly `rows × cols` (a mismatch must not corrupt the
    /// factor).
    pub fn absorb(&mut self, block: &mut [f64], rows: usize) {
        let q = self.cols;
        if rows == 0 || block.len() != rows * q {
            return;
        }
        crate::simd::dispatch(crate::simd::Isa::current(), Absorb { r: &mut self.r, q, block, rows });
    }

    /// Stack another factor below this one and re-triangularise: afterwards `self` is the
    /// factor of `[A_self; A_other]`. This is the TSQR reduction step. Does nothing if the
    /// column counts differ.
    pub fn absorb_triangle(&mut self, other: &Triangle) {
        let q = self.cols;
        if other.cols != q {
            return;
        }
        let mut block = vec![0.0; q * q];
        for i in 0..q {
            for j in i..q {
                block[j * q + i] = other.r[i * q + j];
            }
        }
        self.absorb(&mut block, q);
    }

    /// Annihilate one row into the factor.
    pub fn absorb_row(&mut self, row: &[f64]) {
        let mut block = row.to_vec();
        self.absorb(&mut block, 1);
    }

    /// Leading `p × p` block (rows and columns `0..p`), row-major.
    pub fn leading(&self, p: usize) -> Vec<f64> {
        let p = p.min(self.cols);
        let mut out = vec![0.0; p * p];
        for i in 0..p {
            for j in i..p {
                out[i * p + j] = self.get(i, j);
            }
        }
        out
    }
}

/// [`absorb_kernel`] as a [`crate::simd::Kernel`]: compiled for the CPU's vector
/// instructions, with separate multiplies and adds (no fused multiply-add), so the factor is
/// the same bits on every CPU.
struct Absorb<'a> {
    r: &'a mut [f64],
    q: usize,
    block: &'a mut [f64],
    rows: usize,
}

impl crate::simd::Kernel for Absorb<'_> {
    type Output = ();
    #[inline(always)]
    fn run<S: crate::simd::Simd>(self, _: S) {
        absorb_kernel(self.r, self.q, self.block, self.rows);
    }
}

/// One Householder reflector per column `j` annihilates `block[:, j]` into `r[j][j]`; see
/// [`Triangle::absorb`].
#[inline(always)]
fn absorb_kernel(r: &mut [f64], q: usize, block: &mut [f64], rows: usize) {
    for j in 0..q {
        let (head, tail) = block.split_at_mut((j + 1) * rows);
        let v = &mut head[j * rows..];
        let sigma = dot_k(v, v);
        if sigma == 0.0 {
            continue; // column already zero below the diagonal: identity reflector
        }
        let alpha = r[j * q + j];
        // Plain sqrt: an overflow here shows up as a non-finite factor, which is refused.
        let norm = (alpha * alpha + sigma).sqrt();
        // beta = -sign(alpha) * norm keeps alpha - beta free of cancellation.
        let beta = if alpha > 0.0 { -norm } else { norm };
        let denom = alpha - beta;
        let inv = 1.0 / denom;
        for x in v.iter_mut() {
            *x *= inv;
        }
        let tau = -denom / beta;
        r[j * q + j] = beta;
        // Trailing columns two at a time: one pass over v serves both dot products and both
        // updates (fewer loads per flop than column by column).
        let v: &[f64] = v;
        let mut cols = tail.chunks_exact_mut(rows);
        let mut k = j + 1;
        loop {
            match (cols.next(), cols.next()) {
                (Some(c1), Some(c2)) => {
                    let (d1, d2) = dot2_k(v, c1, c2);
                    let tw1 = tau * (r[j * q + k] + d1);
                    let tw2 = tau * (r[j * q + k + 1] + d2);
                    r[j * q + k] -= tw1;
                    r[j * q + k + 1] -= tw2;
                    axpy2_k(-tw1, -tw2, v, c1, c2);
                    k += 2;
                }
                (Some(c1), None) => {
                    let tw = tau * (r[j * q + k] + dot_k(v, c1));
                    r[j * q + k] -= tw;
                    axpy_k(-tw, v, c1);
                    break;
                }
                _ => break,
            }
        }
    }
}

#[inline(always)]
fn dot2_k(v: &[f64], a: &[f64], b: &[f64]) -> (f64, f64) {
    let n = v.len().min(a.len()).min(b.len());
    let (v, a, b) = (&v[..n], &a[..n], &b[..n]);
    let mut s1 = [0.0f64; 8];
    let mut s2 = [0.0f64; 8];
    let mut cv = v.chunks_exact(8);
    let mut ca = a.chunks_exact(8);
    let mut cb = b.chunks_exact(8);
    for ((xv, xa), xb) in (&mut cv).zip(&mut ca).zip(&mut cb) {
        for l in 0..8 {
            s1[l] += xv[l] * xa[l];
            s2[l] += xv[l] * xb[l];
        }
    }
    let (mut t1, mut t2) = (0.0, 0.0);
    for ((x, y), z) in cv.remainder().iter().zip(ca.remainder()).zip(cb.remainder()) {
        t1 += x * y;
        t2 += x * z;
    }
    let fold = |s: [f64; 8]| ((s[0] + s[4]) + (s[1] + s[5])) + ((s[2] + s[6]) + (s[3] + s[7]));
    (fold(s1) + t1, fold(s2) + t2)
}

#[inline(always)]
fn axpy2_k(alpha: f64, beta: f64, x: &[f64], a: &mut [f64], b: &mut [f64]) {
    for ((xi, ai), bi) in x.iter().zip(a.iter_mut()).zip(b.iter_mut()) {
        *ai += alpha * xi;
        *bi += beta * xi;
    }
}

#[inline(always)]
fn dot_k(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 16];
    let mut ca = a.chunks_exact(16);
    let mut cb = b.chunks_exact(16);
    for (xa, xb) in (&mut ca).zip(&mut cb) {
        for l in 0..16 {
            acc[l] += xa[l] * xb[l];
        }
    }
    let mut tail = 0.0;
    for (x, y) in ca.remainder().iter().zip(cb.remainder()) {
        tail += x * y;
    }
    let mut s = [0.0f64; 4];
    for l in 0..4 {
        s[l] = (acc[l] + acc[l + 4]) + (acc[l + 8] + acc[l + 12]);
    }
    ((s[0] + s[2]) + (s[1] + s[3])) + tail
}

#[inline(always)]
fn axpy_k(alpha: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += alpha * xi;
    }
}

/// A small dense least-squares problem `min |A x - b|` solved by the same Householder
/// factor as the estimator's windows (the crate's one least-squares core: the campaign's
/// curve fits and the differentiator's design use it too).
#[derive(Debug, Clone, PartialEq)]
pub struct DenseSolution {
    /// `x`.
    pub coef: Vec<f64>,
    /// `|A x - b|^2`.
    pub residual_ss: f64,
    /// The triangular factor of `A`, `p × p` row-major, diagonal non-negative: `AᵀA = RᵀR`
    /// ([`inverse_gram_from_upper`] gives the covariance kernel).
    pub r: Vec<f64>,
}

/// [`DenseSolution`] of the columns `a` (each at least as long as `b`) against `b`; `None`
/// when `a` is empty or rank deficient (a zero on the factor's diagonal) or a value is not
/// finite.
pub fn least_squares(a: &[&[f64]], b: &[f64]) -> Option<DenseSolution> {
    let (p, rows) = (a.len(), b.len());
    if p == 0 || a.iter().any(|c| c.len() < rows) {
        return None;
    }
    let mut block: Vec<f64> = a.iter().flat_map(|c| c[..rows].iter().copied()).chain(b.iter().copied()).collect();
    let mut t = Triangle::zeros(p + 1);
    t.absorb(&mut block, rows);
    t.make_diagonal_nonnegative();
    if !t.is_finite() {
        return None;
    }
    let r = t.leading(p);
    let mut coef: Vec<f64> = (0..p).map(|i| t.get(i, p)).collect();
    solve_upper(&r, p, &mut coef).then(|| DenseSolution { coef, residual_ss: t.get(p, p).powi(2), r })
}

/// Solve `R z = b` in place for upper-triangular `R` (`p × p`, row-major).
/// Returns false (leaving `b` partly overwritten) if a diagonal entry is zero.
pub fn solve_upper(r: &[f64], p: usize, b: &mut [f64]) -> bool {
    if r.len() < p * p || b.len() < p {
        return false;
    }
    for i in (0..p).rev() {
        let mut s = b[i];
        for k in (i + 1)..p {
            s -= r[i * p + k] * b[k];
        }
        let d = r[i * p + i];
        if d == 0.0 {
            return false;
        }
        b[i] = s / d;
    }
    true
}

/// `(RᵀR)⁻¹ = R⁻¹ R⁻ᵀ` for upper-triangular `R` (`p × p`, row-major), as a dense row-major
/// matrix; `None` if `R` is singular. This is the unscaled covariance kernel of least squares.
pub fn inverse_gram_from_upper(r: &[f64], p: usize) -> Option<Vec<f64>> {
    // Columns of R⁻¹ by back substitution on unit vectors.
    let mut rinv = vec![0.0; p * p]; // row-major
    for c in 0..p {
        let mut e = vec![0.0; p];
        e[c] = 1.0;
        if !solve_upper(r, p, &mut e) {
            return None;
        }
        for i in 0..p {
            rinv[i * p + c] = e[i];
        }
    }
    let mut g = vec![0.0; p * p];
    for i in 0..p {
        for j in 0..p {
            let mut s = 0.0;
            for k in 0..p {
                s += rinv[i * p + k] * rinv[j * p + k];
            }
            g[i * p + j] = s;
        }
    }
    Some(g)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn absorb_matches_gram_and_is_blocking_invariant() {
        // 3 columns, 7 rows, deterministic values.
        let rows = 7;
        let cols = 3;
        let a: Vec<f64> = (0..rows * cols).map(|k| ((k * 37 % 11) as f64 - 5.0) * 0.3 + k as f64 * 0.01).collect();
        let mut one = Triangle::zeros(cols);
        let mut block = a.clone();
        one.absorb(&mut block, rows);
        one.make_diagonal_nonnegative();
        // Gram from data vs RᵀR.
        for i in 0..cols {
            for j in 0..cols {
                let g: f64 = (0..rows).map(|t| a[i * rows + t] * a[j * rows + t]).sum();
                let rr: f64 = (0..cols).map(|k| one.get(k, i) * one.get(k, j)).sum();
                assert!((g - rr).abs() < 1e-12 * (1.0 + g.abs()), "{g} vs {rr}");
            }
        }
        // Two blocks (rows 0..3 and 3..7) then stacking gives the same factor.
        let take = |r0: usize, r1: usize| {
            let n = r1 - r0;
            let mut b = vec![0.0; n * cols];
            for j in 0..cols {
                for t in 0..n {
                    b[j * n + t] = a[j * rows + r0 + t];
                }
            }
            (b, n)
        };
        let (mut b1, n1) = take(0, 3);
        let (mut b2, n2) = take(3, 7);
        let mut t1 = Triangle::zeros(cols);
        t1.absorb(&mut b1, n1);
        let mut t2 = Triangle::zeros(cols);
        t2.absorb(&mut b2, n2);
        t1.absorb_triangle(&t2);
        t1.make_diagonal_nonnegative();
        for (x, y) in t1.as_slice().iter().zip(one.as_slice()) {
            assert!((x - y).abs() < 1e-12, "{x} vs {y}");
        }
    }
}
