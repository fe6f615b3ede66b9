//! Least squares by Householder QR on column-scaled designs, with the classical standard
//! errors `s^2 (R^T R)^-1` (never the normal equations). Every model of the catalog is solved
//! here, so they are compared on one footing.

use nalgebra::{DMatrix, DVector};

use crate::DiagnosisError;

/// A solved least-squares problem.
#[derive(Debug, Clone)]
pub struct Fit {
    /// Parameters, in the design's column order and units.
    pub theta: DVector<f64>,
    /// Their standard errors (`NaN` where the design is rank-deficient).
    pub standard_errors: DVector<f64>,
    /// Residual sum of squares over the rows fitted.
    pub sse: f64,
    /// Rows fitted.
    pub rows: usize,
    /// Ratio of the largest to the smallest diagonal of R after column scaling: a cheap
    /// condition estimate.
    pub condition: f64,
}

/// Relative diagonal of R below which a column counts as dependent on the others.
const RANK_TOLERANCE: f64 = 1e-9;

/// Solves `design theta ~ target` over the rows where `use_row` is true.
/// Errors when there are fewer rows than columns or the design is rank-deficient (the caller
/// says which model and why; a rank-deficient model is not identifiable from the record).
pub fn solve(design: &DMatrix<f64>, target: &DVector<f64>, use_row: &[bool], what: &str) -> Result<Fit, DiagnosisError> {
    let cols = design.ncols();
    let rows: Vec<usize> = (0..design.nrows()).filter(|&i| use_row[i]).collect();
    if rows.len() <= cols {
        return Err(DiagnosisError::bad_input(what, format!("{} rows for {cols} parameters", rows.len())));
    }
    // Column scales: the RMS of each column over the rows used.
    let mut scale = vec![0.0; cols];
    for (j, s) in scale.iter_mut().enumerate() {
        let ss: f64 = rows.iter().map(|&i| design[(i, j)] * design[(i, j)]).sum();
        *s = (ss / rows.len() as f64).sqrt();
        if !(s.is_finite() && *s > 0.0) {
            return Err(DiagnosisError::bad_input(what, format!("design column {j} is zero or not finite on the rows used")));
        }
    }
    let a = DMatrix::from_fn(rows.len(), cols, |r, j| design[(rows[r], j)] / scale[j]);
    let b = DVector::from_iterator(rows.len(), rows.iter().map(|&i| target[i]));
    let qr = a.clone().qr();
    let r = qr.r();
    let diag: Vec<f64> = (0..cols).map(|j| r[(j, j)].abs()).collect();
    let dmax = diag.iter().copied().fold(0.0, f64::max);
    let dmin = diag.iter().copied().fold(f64::INFINITY, f64::min);
    // Written so a NaN diagonal is refused too.
    if dmin.partial_cmp(&(RANK_TOLERANCE * dmax)) != Some(std::cmp::Ordering::Greater) {
        return Err(DiagnosisError::bad_input(
            what,
            format!("the design is rank-deficient (R diagonal {dmin:.3e} against {dmax:.3e}): the record cannot tell its parameters apart"),
        ));
    }
    let mut qtb = b.clone();
    qr.q_tr_mul(&mut qtb);
    let qtb = qtb.rows(0, cols).into_owned();
    let scaled = r.solve_upper_triangular(&qtb).ok_or_else(|| DiagnosisError::bad_input(what, "triangular solve failed"))?;
    let resid = &b - &a * &scaled;
    let sse = resid.norm_squared();
    let dof = (rows.len() - cols) as f64;
    let s2 = sse / dof;
    // (R^T R)^-1 = R^-1 R^-T; its diagonal is the squared row norms of R^-1.
    let r_inv = r.clone().try_inverse().ok_or_else(|| DiagnosisError::bad_input(what, "R is singular"))?;
    let theta = DVector::from_iterator(cols, (0..cols).map(|j| scaled[j] / scale[j]));
    let standard_errors = DVector::from_iterator(cols, (0..cols).map(|j| (s2 * r_inv.row(j).norm_squared()).sqrt() / scale[j]));
    Ok(Fit { theta, standard_errors, sse, rows: rows.len(), condition: dmax / dmin })
}

/// `design theta` on every row.
pub fn predict(design: &DMatrix<f64>, theta: &DVector<f64>) -> DVector<f64> {
    design * theta
}

/// A least-squares problem cut into row blocks, each reduced once to its triangular factor, so
/// that leaving any one block out (cross-validation) costs a QR of the stacked small factors
/// instead of one over all the rows. Columns are scaled once by their RMS over all rows.
#[derive(Debug, Clone)]
pub struct Blocked {
    cols: usize,
    scale: Vec<f64>,
    blocks: Vec<Block>,
}

#[derive(Debug, Clone)]
struct Block {
    /// Scaled design rows and target of the block, kept to score it when it is held out.
    design: DMatrix<f64>,
    target: DVector<f64>,
    /// `R` and `Q^T y` of the block (at most `cols` rows), and `|y|^2 - |Q^T y|^2`.
    r: DMatrix<f64>,
    qty: DVector<f64>,
    rest: f64,
}

/// One solve of a [`Blocked`] problem.
#[derive(Debug, Clone)]
pub struct BlockFit {
    /// Parameters in the design's units, and their standard errors (`s^2 (R^T R)^-1`).
    pub theta: DVector<f64>,
    pub standard_errors: DVector<f64>,
    /// Residual sum of squares over the rows fitted, and their number.
    pub sse: f64,
    pub rows: usize,
}

impl Blocked {
    /// `blocks[b]` lists the rows of block `b`; rows in no block are ignored.
    pub fn new(design: &DMatrix<f64>, target: &DVector<f64>, blocks: &[Vec<usize>], what: &str) -> Result<Self, DiagnosisError> {
        let cols = design.ncols();
        let all: usize = blocks.iter().map(Vec::len).sum();
        if all <= cols {
            return Err(DiagnosisError::bad_input(what, format!("{all} rows for {cols} parameters")));
        }
        let mut scale = vec![0.0; cols];
        for (j, s) in scale.iter_mut().enumerate() {
            let ss: f64 = blocks.iter().flatten().map(|&i| design[(i, j)] * design[(i, j)]).sum();
            *s = (ss / all as f64).sqrt();
            if !(s.is_finite() && *s > 0.0) {
                return Err(DiagnosisError::bad_input(what, format!("design column {j} is zero or not finite")));
            }
        }
        let blocks = blocks
            .iter()
            .map(|rows| {
                let d = DMatrix::from_fn(rows.len(), cols, |r, j| design[(rows[r], j)] / scale[j]);
                let t = DVector::from_iterator(rows.len(), rows.iter().map(|&i| target[i]));
                let (r, qty, rest) = reduce(&d, &t);
                Block { design: d, target: t, r, qty, rest }
            })
            .collect();
        Ok(Self { cols, scale, blocks })
    }

    pub fn blocks(&self) -> usize {
        self.blocks.len()
    }

    /// Least squares over every block but `held_out` (all blocks with `None`).
    pub fn fit(&self, held_out: Option<usize>, what: &str) -> Result<BlockFit, DiagnosisError> {
        let used: Vec<&Block> = self.blocks.iter().enumerate().filter(|(b, _)| Some(*b) != held_out).map(|(_, k)| k).collect();
        let stacked_rows: usize = used.iter().map(|b| b.r.nrows()).sum();
        let rows: usize = used.iter().map(|b| b.design.nrows()).sum();
        if rows <= self.cols {
            return Err(DiagnosisError::bad_input(what, format!("{rows} rows for {} parameters", self.cols)));
        }
        let mut a = DMatrix::zeros(stacked_rows, self.cols);
        let mut y = DVector::zeros(stacked_rows);
        let mut rest = 0.0;
        let mut at = 0;
        for b in &used {
            let m = b.r.nrows();
            a.view_mut((at, 0), (m, self.cols)).copy_from(&b.r);
            y.rows_mut(at, m).copy_from(&b.qty);
            rest += b.rest;
            at += m;
        }
        let (r, qty, rest_stacked) = reduce(&a, &y);
        if r.nrows() < self.cols {
            return Err(DiagnosisError::bad_input(what, "fewer independent rows than parameters"));
        }
        let diag: Vec<f64> = (0..self.cols).map(|j| r[(j, j)].abs()).collect();
        let dmax = diag.iter().copied().fold(0.0, f64::max);
        let dmin = diag.iter().copied().fold(f64::INFINITY, f64::min);
        // Written so a NaN diagonal is refused too.
        if dmin.partial_cmp(&(RANK_TOLERANCE * dmax)) != Some(std::cmp::Ordering::Greater) {
            return Err(DiagnosisError::bad_input(
                what,
                format!("the design is rank-deficient (R diagonal {dmin:.3e} against {dmax:.3e}): the record cannot tell its parameters apart"),
            ));
        }
        let scaled = r.solve_upper_triangular(&qty).ok_or_else(|| DiagnosisError::bad_input(what, "triangular solve failed"))?;
        let sse = (rest + rest_stacked).max(0.0);
        let s2 = sse / (rows - self.cols) as f64;
        let r_inv = r.clone().try_inverse().ok_or_else(|| DiagnosisError::bad_input(what, "R is singular"))?;
        let theta = DVector::from_iterator(self.cols, (0..self.cols).map(|j| scaled[j] / self.scale[j]));
        let standard_errors = DVector::from_iterator(self.cols, (0..self.cols).map(|j| (s2 * r_inv.row(j).norm_squared()).sqrt() / self.scale[j]));
        Ok(BlockFit { theta, standard_errors, sse, rows })
    }

    /// Residual sum of squares of block `b` under parameters `theta` (design units).
    pub fn block_sse(&self, b: usize, theta: &DVector<f64>) -> f64 {
        let k = &self.blocks[b];
        let scaled = DVector::from_iterator(self.cols, (0..self.cols).map(|j| theta[j] * self.scale[j]));
        (&k.target - &k.design * scaled).norm_squared()
    }
}

/// `R` (at most `cols` rows), `Q^T y` and the part of `|y|^2` outside the column space.
fn reduce(a: &DMatrix<f64>, y: &DVector<f64>) -> (DMatrix<f64>, DVector<f64>, f64) {
    let m = a.nrows().min(a.ncols());
    let qr = a.clone().qr();
    // Q^T y by the Householder reflections themselves: Q is never formed.
    let mut qty_full = y.clone();
    qr.q_tr_mul(&mut qty_full);
    let r = qr.r().rows(0, m).into_owned();
    let qty = qty_full.rows(0, m).into_owned();
    let rest = (y.norm_squared() - qty.norm_squared()).max(0.0);
    (r, qty, rest)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_known_line_and_its_standard_error_scale() {
        // y = 2 + 3 t with a deterministic +-0.1 alternating error.
        let n = 200;
        let design = DMatrix::from_fn(n, 2, |i, j| if j == 0 { 1.0 } else { i as f64 / n as f64 });
        let target = DVector::from_fn(n, |i, _| 2.0 + 3.0 * i as f64 / n as f64 + if i % 2 == 0 { 0.1 } else { -0.1 });
        let fit = solve(&design, &target, &vec![true; n], "line").expect("well posed");
        assert!((fit.theta[0] - 2.0).abs() < 0.02, "{}", fit.theta[0]);
        assert!((fit.theta[1] - 3.0).abs() < 0.04, "{}", fit.theta[1]);
        // sigma = 0.1: SE of the intercept ~ 0.1 * sqrt(4/n).
        assert!(fit.standard_errors[0] > 0.005 && fit.standard_errors[0] < 0.03, "{}", fit.standard_errors[0]);
    }

    #[test]
    fn a_repeated_column_is_refused_not_answered() {
        let n = 50;
        let design = DMatrix::from_fn(n, 2, |i, _| i as f64);
        let target = DVector::from_fn(n, |i, _| i as f64);
        let err = solve(&design, &target, &vec![true; n], "twins").expect_err("rank 1");
        assert!(err.to_string().contains("twins") && err.to_string().contains("rank-deficient"), "{err}");
    }

    #[test]
    fn rows_left_out_are_not_fitted() {
        let n = 100;
        let design = DMatrix::from_fn(n, 1, |_, _| 1.0);
        let target = DVector::from_fn(n, |i, _| if i < 50 { 1.0 } else { 100.0 });
        let mask: Vec<bool> = (0..n).map(|i| i < 50).collect();
        let fit = solve(&design, &target, &mask, "mean").expect("well posed");
        assert!((fit.theta[0] - 1.0).abs() < 1e-12);
        assert_eq!(fit.rows, 50);
    }

    #[test]
    fn blocked_fits_equal_the_plain_solve_on_the_same_rows() {
        let n = 120;
        let design = DMatrix::from_fn(n, 3, |i, j| ((i * (j + 3)) as f64 * 0.37).sin() + j as f64 * 0.1);
        let target = DVector::from_fn(n, |i, _| 1.0 + 2.0 * design[(i, 0)] - 0.5 * design[(i, 2)] + ((i * 7) as f64).cos() * 0.01);
        let blocks: Vec<Vec<usize>> = (0..4).map(|b| (b * 30..(b + 1) * 30).collect()).collect();
        let blocked = Blocked::new(&design, &target, &blocks, "four blocks").expect("well posed");
        for held in [None, Some(0), Some(3)] {
            let mask: Vec<bool> = (0..n).map(|i| held.is_none_or(|b| i / 30 != b)).collect();
            let plain = solve(&design, &target, &mask, "plain").expect("well posed");
            let fit = blocked.fit(held, "blocked").expect("well posed");
            for j in 0..3 {
                assert!((fit.theta[j] - plain.theta[j]).abs() < 1e-10 * (1.0 + plain.theta[j].abs()), "{held:?} {j}");
                assert!((fit.standard_errors[j] - plain.standard_errors[j]).abs() < 1e-8 * plain.standard_errors[j], "{held:?} {j}");
            }
            assert!((fit.sse - plain.sse).abs() < 1e-9 * (1.0 + plain.sse), "{held:?}");
            if let Some(b) = held {
                let direct: f64 = (b * 30..(b + 1) * 30).map(|i| (target[i] - (design.row(i) * &plain.theta)[0]).powi(2)).sum();
                assert!((blocked.block_sse(b, &fit.theta) - direct).abs() < 1e-9 * (1.0 + direct));
            }
        }
    }
}
