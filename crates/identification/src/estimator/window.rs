//! One window's worth of data reduced to a triangular factor, and how factors of adjacent
//! blocks combine.
//!
//! A [`BlockSummary`] holds, for a contiguous block of rows, the row count, the column means
//! and the Householder factor of the **centred** columns (regressors followed by the two force
//! signals). Centring is the intercept of the model `f = -(K r + C r' + M r'') + f0`: by the
//! Frisch–Waugh–Lovell theorem the slopes of a regression with an intercept are those of the
//! regression of centred forces on centred regressors, and the static film force and the
//! static journal position drop out before any arithmetic sees them (they are large next to
//! the dynamic parts, so leaving them in would cost digits and make the condition number
//! describe the static offset instead of the excitation).
//!
//! Two summaries merge exactly: the centred Gram matrix of the union is
//! `G_a + G_b + (n_a n_b / n) δ δᵀ` with `δ = m_a - m_b` (Chan, Golub & LeVeque's pairwise
//! update for variances), which in factor form means stacking `R_a`, `R_b` and the single row
//! `sqrt(n_a n_b / n) δᵀ` and re-triangularising (the TSQR reduction step of Demmel et al.
//! 2012). The normal matrix is never formed. This is what lets overlapping windows reuse work:
//! each hop-sized block is factored once and windows are combinations of block factors.

use super::qr::Triangle;
use crate::simd::{self, Isa, Kernel, Simd};

/// Rows per Householder sweep: a block of `CHUNK_ROWS × cols` doubles (24 KiB for the six
/// columns of the Kc model, 32 KiB for eight) stays in the level-1 cache while all its
/// reflectors are applied. 128–512 measured within noise of each other; 512 was best.
pub const CHUNK_ROWS: usize = 512;

/// Mean of a column, summed relative to its first value (so the sum carries the variation,
/// not the offset) with eight independent partial sums (a single running sum is a chain of
/// dependent additions the compiler may not reorder, and was the slowest part of a window):
/// [`crate::simd::mean`], the same bits on every instruction set.
pub fn mean(c: &[f64]) -> f64 {
    crate::simd::mean(c)
}

/// Row count, column means and the triangular factor of the centred columns of one block.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockSummary {
    /// Number of rows.
    pub n: usize,
    /// Column means.
    pub mean: Vec<f64>,
    /// Triangular factor of the centred columns.
    pub r: Triangle,
}

impl BlockSummary {
    /// The summary of no rows.
    pub fn empty(cols: usize) -> Self {
        Self { n: 0, mean: vec![0.0; cols], r: Triangle::zeros(cols) }
    }

    /// Summarise the columns `cols` (all of one length; the shortest length is used).
    ///
    /// One pass over the data: each cache-sized chunk is centred on its own means while it is
    /// copied, annihilated into the running factor, and the running factor is corrected for
    /// the difference of means by one extra row, `sqrt(n_a n_c / (n_a + n_c)) (m_a - m_c)`
    /// (the same identity as [`BlockSummary::merge`]). [`SummaryBuilder`] is this pass fed in
    /// pieces, with the same bits.
    pub fn from_columns(cols: &[&[f64]]) -> Self {
        let mut b = SummaryBuilder::new(cols.len());
        b.push(cols);
        b.finish()
    }

    /// The summary of the union of the rows of `self` and `other`.
    pub fn merge(&self, other: &BlockSummary) -> BlockSummary {
        if other.n == 0 {
            return self.clone();
        }
        if self.n == 0 {
            return other.clone();
        }
        let q = self.mean.len();
        let (na, nb) = (self.n as f64, other.n as f64);
        let n = na + nb;
        let mut out = self.clone();
        out.n = self.n + other.n;
        let w = (na * nb / n).sqrt();
        let mut row = vec![0.0; q];
        for j in 0..q {
            let delta = self.mean[j] - other.mean[j];
            out.mean[j] = self.mean[j] - delta * nb / n;
            row[j] = w * delta;
        }
        out.r.absorb_triangle(&other.r);
        out.r.absorb_row(&row);
        out
    }
}

/// [`BlockSummary::from_columns`] fed as the rows arrive: chunks of [`CHUNK_ROWS`] rows at
/// fixed offsets from the first row are reduced as soon as they are complete, so
/// [`SummaryBuilder::finish`] has at most one partial chunk left. The result is
/// `from_columns` of all the rows pushed, bit for bit, however they were cut.
#[derive(Debug, Clone)]
pub struct SummaryBuilder {
    out: BlockSummary,
    /// Rows of the current incomplete chunk, one vector per column.
    pending: Vec<Vec<f64>>,
    buf: Vec<f64>,
    chunk_mean: Vec<f64>,
    row: Vec<f64>,
}

impl SummaryBuilder {
    /// A builder for `cols` columns.
    pub fn new(cols: usize) -> Self {
        Self {
            out: BlockSummary::empty(cols),
            pending: (0..cols).map(|_| Vec::new()).collect(),
            buf: Vec::new(),
            chunk_mean: vec![0.0; cols],
            row: vec![0.0; cols],
        }
    }

    /// Rows pushed so far.
    pub fn rows(&self) -> usize {
        self.out.n + self.pending.first().map_or(0, |p| p.len())
    }

    /// Push rows given as columns (the shortest length is used; nothing if the number of
    /// columns is not the builder's).
    pub fn push(&mut self, cols: &[&[f64]]) {
        if cols.len() != self.pending.len() || cols.is_empty() {
            return;
        }
        let n = cols.iter().map(|c| c.len()).min().unwrap_or(0);
        let mut i = 0;
        while i < n {
            let have = self.pending[0].len();
            if have == 0 && n - i >= CHUNK_ROWS {
                // A whole chunk straight from the caller's slices.
                let view: Vec<&[f64]> = cols.iter().map(|c| &c[i..i + CHUNK_ROWS]).collect();
                self.absorb(&view);
                i += CHUNK_ROWS;
                continue;
            }
            let take = (CHUNK_ROWS - have).min(n - i);
            for (dst, src) in self.pending.iter_mut().zip(cols) {
                dst.extend_from_slice(&src[i..i + take]);
            }
            i += take;
            if self.pending[0].len() == CHUNK_ROWS {
                self.flush();
            }
        }
    }

    /// The summary of every row pushed.
    pub fn finish(mut self) -> BlockSummary {
        if self.pending.first().is_some_and(|p| !p.is_empty()) {
            self.flush();
        }
        self.out
    }

    fn flush(&mut self) {
        let pending = std::mem::take(&mut self.pending);
        let view: Vec<&[f64]> = pending.iter().map(|c| c.as_slice()).collect();
        self.absorb(&view);
        self.pending = pending;
        for c in &mut self.pending {
            c.clear();
        }
    }

    /// One chunk (columns of one length, at most `CHUNK_ROWS`).
    fn absorb(&mut self, cols: &[&[f64]]) {
        let q = cols.len();
        let rows = cols.iter().map(|c| c.len()).min().unwrap_or(0);
        if rows == 0 {
            return;
        }
        self.buf.resize(rows * q, 0.0);
        let block = &mut self.buf[..rows * q];
        centre_into(block, cols, rows, &mut self.chunk_mean);
        let out = &mut self.out;
        out.r.absorb(block, rows);
        let (na, nc) = (out.n as f64, rows as f64);
        if out.n > 0 {
            let w = (na * nc / (na + nc)).sqrt();
            for j in 0..q {
                self.row[j] = w * (out.mean[j] - self.chunk_mean[j]);
            }
            out.r.absorb(&mut self.row, 1);
        }
        for j in 0..q {
            out.mean[j] += (self.chunk_mean[j] - out.mean[j]) * nc / (na + nc);
        }
        out.n += rows;
    }
}

/// Column `j`'s mean into `means[j]` and its rows `0..rows` minus that mean into
/// `block[j rows..(j + 1) rows]` (column-major), for every column.
fn centre_into(block: &mut [f64], cols: &[&[f64]], rows: usize, means: &mut [f64]) {
    struct K<'a>(&'a mut [f64], &'a [&'a [f64]], usize, &'a mut [f64]);
    impl Kernel for K<'_> {
        type Output = ();
        /// The means by [`Simd::mean`], the same bits as [`mean`] on every instruction set.
        #[inline(always)]
        fn run<S: Simd>(self, simd: S) {
            let K(block, cols, rows, means) = self;
            for ((c, dst), m_out) in cols.iter().zip(block.chunks_exact_mut(rows)).zip(means.iter_mut()) {
                let src = &c[..rows];
                let m = simd.mean(src);
                *m_out = m;
                for (d, v) in dst.iter_mut().zip(src) {
                    *d = v - m;
                }
            }
        }
    }
    simd::dispatch(Isa::current(), K(block, cols, rows, means));
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`Simd::mean`] on every instruction set this CPU has is the portable mean, bit for
    /// bit, at every tail length and scale.
    #[test]
    fn mean_is_the_same_on_every_instruction_set() {
        struct K<'a>(&'a [f64]);
        impl Kernel for K<'_> {
            type Output = f64;
            fn run<S: Simd>(self, simd: S) -> f64 {
                simd.mean(self.0)
            }
        }
        for n in [0usize, 1, 2, 7, 8, 9, 15, 16, 17, 511, 512] {
            for scale in [1e-6, 1.0, 3e4] {
                let c: Vec<f64> = (0..n).map(|t| scale * (2.0 + (t as f64 * 0.77).sin() + 1e-3 * t as f64)).collect();
                for isa in Isa::available() {
                    assert_eq!(simd::dispatch(isa, K(&c)).to_bits(), mean(&c).to_bits(), "n {n} scale {scale} {isa:?}");
                }
            }
        }
    }

    #[test]
    fn merge_equals_one_shot() {
        let n = 1000;
        let a: Vec<f64> = (0..n).map(|t| 3.0 + (t as f64 * 0.1).sin()).collect();
        let b: Vec<f64> = (0..n).map(|t| -7.0 + (t as f64 * 0.37).cos() + 0.001 * t as f64).collect();
        let c: Vec<f64> = (0..n).map(|t| (t as f64 * 0.05).sin() * 2.0 + a[t]).collect();
        let whole = BlockSummary::from_columns(&[&a, &b, &c]);
        let split = [0, 130, 500, 999, 1000];
        let mut acc = BlockSummary::empty(3);
        for w in split.windows(2) {
            let part = BlockSummary::from_columns(&[&a[w[0]..w[1]], &b[w[0]..w[1]], &c[w[0]..w[1]]]);
            acc = acc.merge(&part);
        }
        let mut r1 = whole.r.clone();
        let mut r2 = acc.r.clone();
        r1.make_diagonal_nonnegative();
        r2.make_diagonal_nonnegative();
        for (x, y) in r1.as_slice().iter().zip(r2.as_slice()) {
            assert!((x - y).abs() < 1e-10 * (1.0 + x.abs()), "{x} vs {y}");
        }
        for (x, y) in whole.mean.iter().zip(&acc.mean) {
            assert!((x - y).abs() < 1e-12);
        }
    }

    #[test]
    fn builder_fed_in_pieces_is_from_columns_bit_for_bit() {
        let n = 3 * CHUNK_ROWS + 77;
        let a: Vec<f64> = (0..n).map(|t| 3.0 + (t as f64 * 0.1).sin()).collect();
        let b: Vec<f64> = (0..n).map(|t| -7.0 + (t as f64 * 0.37).cos()).collect();
        let whole = BlockSummary::from_columns(&[&a, &b]);
        for step in [1, 100, CHUNK_ROWS, 700] {
            let mut builder = SummaryBuilder::new(2);
            let mut i = 0;
            while i < n {
                let j = (i + step).min(n);
                builder.push(&[&a[i..j], &b[i..j]]);
                i = j;
            }
            assert_eq!(builder.rows(), n);
            assert_eq!(builder.finish(), whole, "fed {step} rows at a time");
        }
    }
}
