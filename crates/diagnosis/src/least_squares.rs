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
    let qtb = qr.q().transpose() * &b;
    let scaled = r
        .solve_upper_triangular(&qtb)
        .ok_or_else(|| DiagnosisError::bad_input(what, "triangular solve failed"))?;
    let resid = &b - &a * &scaled;
    let sse = resid.norm_squared();
    let dof = (rows.len() - cols) as f64;
    let s2 = sse / dof;
    // (R^T R)^-1 = R^-1 R^-T; its diagonal is the squared row norms of R^-1.
    let r_inv = r
        .clone()
        .try_inverse()
        .ok_or_else(|| DiagnosisError::bad_input(what, "R is singular"))?;
    let theta = DVector::from_iterator(cols, (0..cols).map(|j| scaled[j] / scale[j]));
    let standard_errors = DVector::from_iterator(cols, (0..cols).map(|j| (s2 * r_inv.row(j).norm_squared()).sqrt() / scale[j]));
    Ok(Fit { theta, standard_errors, sse, rows: rows.len(), condition: dmax / dmin })
}

/// `design theta` on every row.
pub fn predict(design: &DMatrix<f64>, theta: &DVector<f64>) -> DVector<f64> {
    design * theta
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
}
