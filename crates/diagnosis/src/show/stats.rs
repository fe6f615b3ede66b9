//! Small statistics of the show: the straight-line fit of a trend and the eigen-decay of the
//! linear film model that sets how much start-up transient to discard.

use nalgebra::{Matrix2, Matrix4};

/// Ordinary least-squares line `v = a + b u`: slope, its standard error (classical, `n - 2`
/// degrees of freedom) and the mean of `v`. `None` with fewer than three points or no spread
/// in `u`.
pub(crate) fn line_fit(u: &[f64], v: &[f64]) -> Option<(f64, f64, f64)> {
    let n = u.len().min(v.len());
    if n < 3 {
        return None;
    }
    let nf = n as f64;
    let mu = u[..n].iter().sum::<f64>() / nf;
    let mv = v[..n].iter().sum::<f64>() / nf;
    let suu: f64 = u[..n].iter().map(|a| (a - mu) * (a - mu)).sum();
    let suv: f64 = u[..n].iter().zip(&v[..n]).map(|(a, b)| (a - mu) * (b - mv)).sum();
    let scale = u[..n].iter().map(|a| a.abs()).fold(0.0, f64::max).max(f64::MIN_POSITIVE);
    let threshold = (1e-12 * scale) * (1e-12 * scale) * nf;
    if suu.is_nan() || suu <= threshold {
        return None;
    }
    let slope = suv / suu;
    let rss: f64 = u[..n]
        .iter()
        .zip(&v[..n])
        .map(|(a, b)| {
            let e = b - mv - slope * (a - mu);
            e * e
        })
        .sum();
    let se = (rss / (nf - 2.0) / suu).sqrt();
    (slope.is_finite() && se.is_finite()).then_some((slope, se, mv))
}

/// The slowest decay rate (1/s) of the housing on the linear film, `m r'' + C r' + K r = 0`,
/// or `None` when a mode does not decay (the linear model is unstable there).
pub(crate) fn slowest_decay_rate(k: &Matrix2<f64>, c: &Matrix2<f64>, mass_kg: f64) -> Option<f64> {
    let mut a = Matrix4::zeros();
    a[(0, 2)] = 1.0;
    a[(1, 3)] = 1.0;
    for i in 0..2 {
        for j in 0..2 {
            a[(2 + i, j)] = -k[(i, j)] / mass_kg;
            a[(2 + i, 2 + j)] = -c[(i, j)] / mass_kg;
        }
    }
    let rate = a.complex_eigenvalues().iter().map(|l| -l.re).fold(f64::INFINITY, f64::min);
    (rate.is_finite() && rate > 0.0).then_some(rate)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_fit_recovers_slope_and_refuses_degenerate_input() {
        let u = [0.0, 1.0, 2.0, 3.0, 4.0];
        let v: Vec<f64> = u.iter().map(|x| 2.0 - 0.5 * x + if (*x as i32) % 2 == 0 { 0.01 } else { -0.01 }).collect();
        let (b, se, m) = line_fit(&u, &v).unwrap();
        assert!((b + 0.5).abs() < 0.01 && se > 0.0 && se < 0.01, "slope {b} se {se}");
        assert!((m - 1.0).abs() < 0.01);
        assert!(line_fit(&[1.0, 1.0, 1.0], &[1.0, 2.0, 3.0]).is_none());
        assert!(line_fit(&[1.0, 2.0], &[1.0, 2.0]).is_none());
    }

    #[test]
    fn decay_rate_of_a_damped_oscillator() {
        // m = 1, k = 100, c = 2: rate = c / 2m = 1 for both (uncoupled) axes.
        let r = slowest_decay_rate(&Matrix2::identity().scale(100.0), &Matrix2::identity().scale(2.0), 1.0).unwrap();
        assert!((r - 1.0).abs() < 1e-9, "rate {r}");
        assert!(slowest_decay_rate(&Matrix2::identity(), &Matrix2::identity().scale(-1.0), 1.0).is_none());
    }
}
