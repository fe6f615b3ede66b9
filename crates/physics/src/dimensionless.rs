//! Dimensionless groups of the journal-bearing literature, and frame conversion.
//!
//! Two conventions are in use and both are provided:
//!
//! * **Lund** (Lund & Thomsen 1978, Friswell et al. 2010, most design tables):
//!   `K = k c / W`, `B = b c omega / W`, Sommerfeld `S = mu N L D / W (R/c)^2`, N in rev/s.
//! * **Zhou et al. (2004)**, whose nomenclature is garbled in print. Read correctly:
//!   `K = k psi^3 / (mu omega L)`, `D = d psi^3 / (mu L)`, `psi = c / R`, and the load
//!   parameter `F_Y = f_y psi^2 / (mu U L)` with `U = omega R`. The two load groups are
//!   tied by `F_Y = 1 / (pi S)`, and Zhou's coefficients are Lund's times `F_Y`.
//!
//! Coefficient matrices are in the crate frame (x horizontal, y up, load along -y) unless a
//! function says otherwise; [`to_load_frame`] converts to the tables' frame (x along the load).

use nalgebra::Matrix2;
use serde::{Deserialize, Serialize};

use crate::film::Running;
use crate::geometry::BearingGeometry;

/// Sommerfeld number `S = mu N L D / W (R/c)^2` with `N = omega / 2 pi` in rev/s.
pub fn sommerfeld(geometry: &BearingGeometry, running: &Running, load_n: f64) -> f64 {
    let n_rev_s = running.omega_rad_s / (2.0 * std::f64::consts::PI);
    let r_over_c = geometry.radius_m() / geometry.clearance_m;
    running.viscosity_pa_s * n_rev_s * geometry.length_m * geometry.diameter_m / load_n * r_over_c * r_over_c
}

/// Zhou's load parameter `F_Y = f_y psi^2 / (mu U L)`, `U = omega R`, `psi = c/R`.
pub fn zhou_load_parameter(geometry: &BearingGeometry, running: &Running, load_n: f64) -> f64 {
    let psi = geometry.relative_clearance();
    let u = running.omega_rad_s * geometry.radius_m();
    load_n * psi * psi / (running.viscosity_pa_s * u * geometry.length_m)
}

/// Rotation from the crate frame (x horizontal, y up, load along -y) to the load frame of
/// Lund's tables (x along the load, i.e. down; y horizontal; journal turns x -> y).
/// `r_load = T r`, so a coefficient matrix maps as `T A T^T`.
fn load_frame_rotation() -> Matrix2<f64> {
    Matrix2::new(0.0, -1.0, 1.0, 0.0)
}

/// Converts a coefficient matrix from the crate frame to the load frame:
/// `Axx' = Ayy, Axy' = -Ayx, Ayx' = -Axy, Ayy' = Axx`.
pub fn to_load_frame(a: &Matrix2<f64>) -> Matrix2<f64> {
    let t = load_frame_rotation();
    t * a * t.transpose()
}

/// Inverse of [`to_load_frame`].
pub fn from_load_frame(a: &Matrix2<f64>) -> Matrix2<f64> {
    let t = load_frame_rotation();
    t.transpose() * a * t
}

/// Dimensionless coefficients in one convention.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DimensionlessCoefficients {
    pub stiffness: Matrix2<f64>,
    pub damping: Matrix2<f64>,
}

/// Lund's groups `K = k c / W`, `B = b c omega / W` (frame unchanged).
pub fn lund(
    stiffness_n_m: &Matrix2<f64>,
    damping_n_s_m: &Matrix2<f64>,
    geometry: &BearingGeometry,
    running: &Running,
    load_n: f64,
) -> DimensionlessCoefficients {
    let c = geometry.clearance_m;
    DimensionlessCoefficients { stiffness: stiffness_n_m * (c / load_n), damping: damping_n_s_m * (c * running.omega_rad_s / load_n) }
}

/// Zhou's groups `K = k psi^3 / (mu omega L)`, `D = d psi^3 / (mu L)` (frame unchanged).
pub fn zhou(stiffness_n_m: &Matrix2<f64>, damping_n_s_m: &Matrix2<f64>, geometry: &BearingGeometry, running: &Running) -> DimensionlessCoefficients {
    let psi3 = geometry.relative_clearance().powi(3);
    let mu = running.viscosity_pa_s;
    let l = geometry.length_m;
    DimensionlessCoefficients { stiffness: stiffness_n_m * (psi3 / (mu * running.omega_rad_s * l)), damping: damping_n_s_m * (psi3 / (mu * l)) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn load_frame_matches_the_tables_mapping() {
        // The tables' header: Kxx' = Kyy, Kxy' = -Kyx, Kyx' = -Kxy, Kyy' = Kxx.
        let a = Matrix2::new(1.0, 2.0, 3.0, 4.0);
        let l = to_load_frame(&a);
        assert_eq!(l, Matrix2::new(4.0, -3.0, -2.0, 1.0));
        assert_eq!(from_load_frame(&l), a);
    }

    #[test]
    fn zhou_groups_relate_to_lund_groups() {
        // K_zhou = K_lund * W psi^3 / (c mu omega L) = K_lund * F_Y (since F_Y = W psi^2/(mu omega R L)).
        let g = BearingGeometry::zhou2004();
        let run = Running::from_rpm(1500.0, 0.03);
        let w = 5000.0;
        let k = Matrix2::new(1.0e8, 2.0e8, -3.0e7, 1.5e8);
        let d = Matrix2::new(1.0e6, 2.0e5, 2.0e5, 3.0e6);
        let fy = zhou_load_parameter(&g, &run, w);
        let lu = lund(&k, &d, &g, &run, w);
        let zh = zhou(&k, &d, &g, &run);
        assert!(((zh.stiffness - lu.stiffness * fy).norm() / zh.stiffness.norm()) < 1e-12);
        assert!(((zh.damping - lu.damping * fy).norm() / zh.damping.norm()) < 1e-12);
        // F_Y S = (omega/2 pi) L D / (omega R L) = 1/pi.
        let s = sommerfeld(&g, &run, w);
        assert!((fy * s - 1.0 / std::f64::consts::PI).abs() < 1e-12, "F_Y S = {}", fy * s);
    }
}
