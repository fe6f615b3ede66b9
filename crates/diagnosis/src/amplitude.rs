//! Does the film's nonlinearity matter? Zhou et al. (2004, section 3.3, eq. 11) measure it by
//! the **relative variation** of each identified coefficient with the excitation amplitude
//! `d`: `RV = (K_D(d) - K_D(0)) / K_D(0)`. From one record the same quantity follows from the
//! nonlinear film model fitted to it: `K_D(0)` is its linear part (the small-perturbation
//! coefficients about the mean position), `K_D(d)` the linear model that best reproduces its
//! force over the record's own orbit (the describing function at amplitude `d`).
//!
//! A film is always somewhat nonlinear; with low probe noise its second- and third-order terms
//! always predict held-out data better. What a rotordynamics engineer needs to know is whether
//! the linear coefficients identified at this amplitude differ from the small-amplitude ones by
//! more than [`RV_THRESHOLD`] on a direct term: then the linear model does not describe this
//! record, and `amplitude_nonlinearity` is named. The film model's own RV at the same amplitude
//! (its force along the measured orbit, fitted the same way) is reported beside it.

use nalgebra::{DMatrix, DVector, Vector2};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::film::{FilmState, Running};
use oilfilm_physics::operating_point::{self, EquilibriumOptions};
use serde::{Deserialize, Serialize};

use crate::catalog::{Cause, Context, Judged, Part};
use crate::evidence::Prepared;
use crate::least_squares;
use crate::DiagnosisError;

/// A direct coefficient varying by more than this over the record's amplitude makes the film's
/// nonlinearity matter (Zhou et al. report 20-30 % at d = 0.05-0.1 for their heavier loads).
pub const RV_THRESHOLD: f64 = 0.10;
/// Orbit samples the film model is evaluated at.
const MODEL_SAMPLES: usize = 400;

/// The coefficient order of the RV arrays.
pub const COEFFICIENTS: [&str; 8] = ["kxx", "kxy", "cxx", "cxy", "kyx", "kyy", "cyx", "cyy"];
/// The direct terms among them.
const DIRECT: [usize; 4] = [0, 2, 5, 7];

/// How much the coefficients move over the record's amplitude.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Amplitude {
    /// Zhou's `d = max |r - mean r| / c`.
    pub d: f64,
    /// RV of each coefficient (order [`COEFFICIENTS`]) from the fitted nonlinear film, and the
    /// largest magnitude among the direct terms.
    pub relative_variation: [f64; 8],
    pub largest_direct: f64,
    /// Its standard error (jackknife over the cross-validation fits).
    pub largest_direct_se: f64,
    /// The film model's RV at the same orbit, where it could be evaluated.
    pub film_model_relative_variation: Option<[f64; 8]>,
    pub film_model_largest_direct: Option<f64>,
    pub threshold: f64,
    /// `largest_direct - 2 se > threshold`: it exceeds the threshold beyond its uncertainty.
    pub matters: bool,
    pub note: Option<String>,
}

fn largest_direct(rv: &[f64; 8]) -> f64 {
    DIRECT.iter().map(|&k| rv[k].abs()).fold(0.0, f64::max)
}

/// The assessment for a model holding the nonlinear film terms.
pub fn assess(ctx: &Context, judged: &Judged, rig: &RigConfig) -> Result<Amplitude, DiagnosisError> {
    let p = ctx.p;
    let s = &judged.series;
    let d = amplitude_d(p, rig);
    let mut note = None;
    let part = Part::Named(Cause::AmplitudeNonlinearity);
    let (relative_variation, folds) = if judged.spec.has(Cause::AmplitudeNonlinearity) {
        // The model's own force over the orbit (linear part plus nonlinear terms), and the
        // linear fit to it; for the whole-record fit and for each cross-validation fit (their
        // spread is the RV's standard error, by the jackknife).
        let design = ctx.design_of(judged)?;
        let linear = p.kc_design(s, 0);
        let cols = judged.part_columns(part);
        let rv = |kc: &[f64; 8], nl: &[f64]| -> Result<[f64; 8], DiagnosisError> {
            let mut force = &linear * DVector::from_column_slice(kc);
            for (c, th) in cols.iter().zip(nl) {
                force += design.column(*c) * *th;
            }
            let fit = least_squares::solve(&linear, &force, &vec![true; force.len()], "describing-function K-C")?;
            Ok(std::array::from_fn(|k| (fit.theta[k] - kc[k]) / kc[k].abs()))
        };
        let whole = rv(&judged.kc, &judged.part_theta(part))?;
        let folds = judged.fold_kc.iter().zip(judged.fold_part_theta(part)).map(|(kc, nl)| rv(kc, &nl)).collect::<Result<Vec<_>, _>>()?;
        (whole, folds)
    } else {
        ([0.0; 8], Vec::new())
    };
    let largest = largest_direct(&relative_variation);
    // Jackknife standard error of the largest direct RV.
    let se = if folds.len() > 2 {
        let b = folds.len() as f64;
        let v: Vec<f64> = folds.iter().map(largest_direct).collect();
        let m = v.iter().sum::<f64>() / b;
        ((b - 1.0) / b * v.iter().map(|x| (x - m).powi(2)).sum::<f64>()).sqrt()
    } else {
        0.0
    };
    let film = match film_model_rv(p, rig) {
        Ok(rv) => Some(rv),
        Err(e) => {
            note = Some(format!("the film model's RV could not be evaluated along the measured orbit: {e}"));
            None
        }
    };
    Ok(Amplitude {
        d,
        relative_variation,
        largest_direct: largest,
        largest_direct_se: se,
        film_model_relative_variation: film,
        film_model_largest_direct: film.as_ref().map(largest_direct),
        threshold: RV_THRESHOLD,
        matters: largest - 2.0 * se > RV_THRESHOLD,
        note,
    })
}

/// Zhou's `d` over the judged samples.
pub fn amplitude_d(p: &Prepared, rig: &RigConfig) -> f64 {
    let s = &p.series;
    let n = s.len() as f64;
    let (mx, my) = (s.x_m.iter().sum::<f64>() / n, s.y_m.iter().sum::<f64>() / n);
    let lk = s.x_m.iter().zip(&s.y_m).map(|(x, y)| (x - mx).hypot(y - my)).fold(0.0, f64::max);
    lk / rig.bearing.clearance_m
}

/// The film model's RV along the measured orbit about its own equilibrium at the record's
/// load, speed and mean temperature.
fn film_model_rv(p: &Prepared, rig: &RigConfig) -> Result<[f64; 8], DiagnosisError> {
    let viscosity = rig.oil.viscosity_pa_s(p.mean_temperature_c)?;
    let running = Running::from_rpm(p.speed_rpm, viscosity);
    let mut film = rig.film()?;
    let load = Vector2::new(-p.static_force_n[0], -p.static_force_n[1]);
    let op = operating_point::solve(film.as_mut(), &running, load, &EquilibriumOptions::default())?;
    let s = &p.series;
    let n = s.len();
    let (mx, my) = (s.x_m.iter().sum::<f64>() / n as f64, s.y_m.iter().sum::<f64>() / n as f64);
    let step = (n / MODEL_SAMPLES).max(1);
    let idx: Vec<usize> = (0..n).step_by(step).collect();
    let m = idx.len();
    let mut design = DMatrix::zeros(2 * m, 8);
    let mut target = DVector::zeros(2 * m);
    let f0 = film.force(&op.journal, &running)?;
    for (row, &i) in idx.iter().enumerate() {
        let dx = [s.x_m[i] - mx, s.y_m[i] - my, s.vx_m_s[i], s.vy_m_s[i]];
        let state = FilmState { x_m: op.journal.x_m + dx[0], y_m: op.journal.y_m + dx[1], vx_m_s: dx[2], vy_m_s: dx[3] };
        let f = film.force(&state, &running)? - f0;
        for axis in 0..2 {
            for (j, v) in dx.iter().enumerate() {
                design[(axis * m + row, 4 * axis + j)] = *v;
            }
            target[axis * m + row] = f[axis];
        }
    }
    let fit = least_squares::solve(&design, &target, &vec![true; 2 * m], "film model describing function")?;
    let (k, c) = (op.coefficients.stiffness_n_m, op.coefficients.damping_n_s_m);
    // The regression's columns are +r, +r': its parameters are minus K and C.
    let lin = [-k[(0, 0)], -k[(0, 1)], -c[(0, 0)], -c[(0, 1)], -k[(1, 0)], -k[(1, 1)], -c[(1, 0)], -c[(1, 1)]];
    Ok(std::array::from_fn(|j| (fit.theta[j] - lin[j]) / lin[j].abs()))
}
