//! The two studies of Zhou et al. (2004), section 3, on the simulated rig: the eight
//! dimensionless coefficients against the load parameter (their Figs 5-6) and against the
//! excitation amplitude (Figs 7-10), with the paper's fits and the checks of its findings.
//!
//! Pure: no I/O, no clock. Every record is simulated from the rig file with a seed derived
//! from the file's seed and the record's index, so a campaign is reproducible bit for bit.
//!
//! ## Conventions
//! Frame and signs are the crate's ([`pipeline::FRAME`]): x horizontal, y vertical up, the
//! journal turning from +x to +y, `r` the journal centre relative to the bearing centre, the
//! film force on the journal `dF = -(K r + C r')`, rows = force component, columns = motion
//! component. Coefficients are in Zhou's normalisation ([`CONVENTION`]):
//! `K = k psi^3 / (mu omega L)`, `D = d psi^3 / (mu L)`, load parameter
//! `F_Y = f_y psi^2 / (mu U L)`, `U = omega R`, `psi = c / R` (so `F_Y = 1 / (pi S)`).
//! `Kxy` is the x-force per unit y-displacement. The paper's X, Y are horizontal and vertical
//! like ours.
//!
//! ## How one record is made ([`run_record`])
//! 1. The rig file's operating point is replaced by the study's (speed, load on the film, bearing
//!    temperature) and re-validated: the bellows must supply the load plus the housing's
//!    weight within `static_load.max_force_n`.
//! 2. The film model's own equilibrium and linear coefficients at that point (the untabulated
//!    film of the rig file, [`RigConfig::film`]): the "classic linear theory" the paper
//!    compares with.
//! 3. A two-tone excitation, exciter 1 (45 deg) at `ratio[0]` and exciter 2 (135 deg) at
//!    `ratio[1]` times the running frequency, so that every operating point sees the same
//!    dimensionless frequencies. Its amplitude is chosen from the model's linear response of
//!    the floating housing (`(K - w^2 m + i w C) X = F`, `r = -X`) to reach a target
//!    `d = max |r - mean r| / c`, within the exciters' force limit.
//! 4. Probe noise for a given SNR (40 dB by default) on the six displacement probes, as in the
//!    identification tests: per-axis rms `rms_r 10^(-SNR/20) / sqrt 2`, with `rms_r` the
//!    dynamic relative displacement predicted by the same linear response (not measured on a
//!    noise-free pass: at the largest amplitudes the film's nonlinearity moves the true SNR by
//!    a fraction of a dB).
//! 5. Simulate ramp + settling + the analysed seconds, drop the ramp and settling scans, and
//!    identify the rest as one window ([`pipeline::identify`]).

// `!(a < b)` is written on purpose wherever NaN must fail the check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::f64::consts::{PI, SQRT_2};

use nalgebra::{Complex, Matrix2, Vector2};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::dimensionless::{self, DimensionlessCoefficients};
use oilfilm_physics::film::{FilmModelConfig, Running};
use oilfilm_physics::operating_point::{self, EquilibriumOptions, OperatingPoint};
use serde::{Deserialize, Serialize};

use crate::error::IdentificationError;
use crate::estimator::qr;
use crate::estimator::svd::SmallSvd;
use crate::excitation::ExcitationPlan;
use crate::pipeline::{self, PipelineConfig, SpeedSource, WindowReport};
use crate::record::RawRecord;
use crate::simulate::{self, SimulateOptions};

/// Zhou's normalisation and the frame, stated in every output.
pub const CONVENTION: &str = "Zhou et al. (2004) dimensionless groups: K = k psi^3/(mu omega L), D = d psi^3/(mu L), \
load parameter F_Y = f_y psi^2/(mu U L), U = omega R, psi = c/R (F_Y = 1/(pi S)); amplitude d = max |r - mean r| / c. \
Frame: x horizontal, y vertical up, journal turning from +x to +y, r = journal centre relative to bearing centre, \
film force on the journal dF = -(K r + C r') (Lund's sign convention); Kxy = x-force per unit y-displacement.";

/// The eight coefficients' names, in the order of [`Coefficients8::as_array`].
pub const COEFFICIENT_NAMES: [&str; 8] = ["Kxx", "Kxy", "Kyx", "Kyy", "Dxx", "Dxy", "Dyx", "Dyy"];

/// The direct coefficients (indices into [`COEFFICIENT_NAMES`]).
pub const DIRECT: [usize; 4] = [0, 3, 4, 7];

/// Added to the rig file's seed for the amplitude study's records (the load study uses the
/// record index itself).
pub const AMPLITUDE_SEED_OFFSET: u64 = 1000;

/// Eight coefficients, one number each (dimensionless in Zhou's groups unless said otherwise).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Coefficients8 {
    pub kxx: f64,
    pub kxy: f64,
    pub kyx: f64,
    pub kyy: f64,
    pub dxx: f64,
    pub dxy: f64,
    pub dyx: f64,
    pub dyy: f64,
}

impl Coefficients8 {
    pub fn from_matrices(k: &Matrix2<f64>, d: &Matrix2<f64>) -> Self {
        Self { kxx: k[(0, 0)], kxy: k[(0, 1)], kyx: k[(1, 0)], kyy: k[(1, 1)], dxx: d[(0, 0)], dxy: d[(0, 1)], dyx: d[(1, 0)], dyy: d[(1, 1)] }
    }

    pub fn from_dimensionless(c: &DimensionlessCoefficients) -> Self {
        Self::from_matrices(&c.stiffness, &c.damping)
    }

    /// In the order of [`COEFFICIENT_NAMES`].
    pub fn as_array(&self) -> [f64; 8] {
        [self.kxx, self.kxy, self.kyx, self.kyy, self.dxx, self.dxy, self.dyx, self.dyy]
    }

    pub fn from_array(a: [f64; 8]) -> Self {
        Self { kxx: a[0], kxy: a[1], kyx: a[2], kyy: a[3], dxx: a[4], dxy: a[5], dyx: a[6], dyy: a[7] }
    }
}

/// Zhou's groups of dimensional coefficients at a running condition.
fn zhou8(k: &Matrix2<f64>, d: &Matrix2<f64>, rig: &RigConfig, running: &Running) -> Coefficients8 {
    Coefficients8::from_dimensionless(&dimensionless::zhou(k, d, &rig.bearing, running))
}

// ---------------------------------------------------------------------------------------------
// Configuration
// ---------------------------------------------------------------------------------------------

/// One operating point of the load study.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OperatingSpec {
    pub speed_rpm: f64,
    /// Static load carried by the film, N.
    pub load_n: f64,
    /// Bearing temperature, C; `None`: the rig file's.
    #[serde(default)]
    pub temperature_c: Option<f64>,
}

/// How every record is excited, measured and analysed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordSettings {
    /// Excitation frequencies of exciter 1 (45 deg) and exciter 2 (135 deg) as multiples of
    /// the running frequency (must differ: two tones identify all eight coefficients).
    pub frequency_ratios: [f64; 2],
    /// Displacement-probe SNR, dB (noise rms against the dynamic relative displacement).
    pub probe_snr_db: f64,
    /// Raised-cosine ramp of the excitation, s (dropped from the analysis).
    pub ramp_s: f64,
    /// Further seconds dropped after the ramp.
    pub settle_s: f64,
    /// Seconds analysed (one window): 10 s is the paper's 50 000 samples at 5 kHz.
    pub analysed_s: f64,
}

impl Default for RecordSettings {
    fn default() -> Self {
        Self { frequency_ratios: [0.4, 0.64], probe_snr_db: 40.0, ramp_s: 0.5, settle_s: 0.5, analysed_s: 10.0 }
    }
}

/// The load-parameter study (Figs 5-6).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoadStudyConfig {
    pub points: Vec<OperatingSpec>,
    /// Target amplitude `d` of every record (small: the linear regime).
    pub target_d: f64,
    /// Points of the model's curve over the studied `F_Y` range.
    pub model_curve_points: usize,
}

impl Default for LoadStudyConfig {
    /// 17 points, speeds 600-1500 rpm and loads 1.4-18.5 kN at the rig file's temperature:
    /// `F_Y` from 0.10 to 1.97 on the built-in rig (the paper: 43 sets, 300-1500 rpm,
    /// 0-20 kN). High `F_Y` is reached by load more than by low speed, because the film
    /// force, and with it the force signal against the force sensors' noise, scales with
    /// `mu omega`.
    fn default() -> Self {
        let mut points = vec![OperatingSpec { speed_rpm: 1500.0, load_n: 1400.0, temperature_c: None }];
        for (speed, loads) in [
            (1500.0, &[2000.0, 4000.0, 7000.0, 10000.0, 14000.0, 18500.0][..]),
            (1000.0, &[2000.0, 4000.0, 7000.0, 10000.0, 14000.0, 18500.0][..]),
            (600.0, &[2000.0, 4000.0, 7000.0, 10000.0][..]),
        ] {
            for &load_n in loads {
                points.push(OperatingSpec { speed_rpm: speed, load_n, temperature_c: None });
            }
        }
        Self { points, target_d: 0.01, model_curve_points: 41 }
    }
}

impl LoadStudyConfig {
    /// Five points, `F_Y` 0.10 to 1.97 on the built-in rig.
    pub fn quick() -> Self {
        let p = |speed_rpm, load_n| OperatingSpec { speed_rpm, load_n, temperature_c: None };
        Self {
            points: vec![p(1500.0, 1400.0), p(1500.0, 5000.0), p(1500.0, 10000.0), p(1000.0, 12000.0), p(1000.0, 18500.0)],
            target_d: 0.01,
            model_curve_points: 21,
        }
    }
}

/// One operating point of the amplitude study, given by its load parameter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AmplitudePointConfig {
    /// Target `F_Y`; the load is computed from it at this speed and temperature.
    pub load_parameter: f64,
    pub speed_rpm: f64,
    /// Bearing temperature, C; `None`: the rig file's.
    #[serde(default)]
    pub temperature_c: Option<f64>,
}

/// The amplitude study (Figs 7-10).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AmplitudeStudyConfig {
    /// The small load parameter (paper: 0.35).
    pub low: AmplitudePointConfig,
    /// The large load parameter (paper: 1.3).
    pub high: AmplitudePointConfig,
    /// Smallest target amplitude.
    pub d_min: f64,
    /// Largest target amplitude (the linear prediction), unless the exciters' force limit
    /// comes first. The rig integrates a film tabulated over +-0.15 c around equilibrium
    /// (outside it every force falls back to the finite-difference film, about a hundred
    /// times slower), so the default stops at 0.12.
    pub d_cap: f64,
    /// Records per point, forces evenly spaced from the `d_min` force to the largest.
    pub steps: usize,
}

impl Default for AmplitudeStudyConfig {
    /// `F_Y` 0.35 at 1500 rpm (4.9 kN on the built-in rig, the rig file's own point) and
    /// `F_Y` 1.3 at 1000 rpm (12.2 kN), both at the rig file's temperature; 8 steps each.
    /// At 1500 rpm `F_Y` 1.3 needs 18.3 kN and a film so stiff that the exciters' 1.5 kN reach
    /// only d ~ 0.09; at 1000 rpm they reach the 0.12 cap, so both sweeps span the same
    /// `d` and compare at the same largest `d`. With the excitation frequencies tied to the
    /// running speed, Zhou's groups see the same dimensionless problem at either speed (the
    /// housing's inertia aside).
    fn default() -> Self {
        Self {
            low: AmplitudePointConfig { load_parameter: 0.35, speed_rpm: 1500.0, temperature_c: None },
            high: AmplitudePointConfig { load_parameter: 1.3, speed_rpm: 1000.0, temperature_c: None },
            d_min: 0.005,
            d_cap: 0.12,
            steps: 8,
        }
    }
}

/// The whole campaign's settings.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CampaignConfig {
    pub record: RecordSettings,
    pub load: LoadStudyConfig,
    pub amplitude: AmplitudeStudyConfig,
}

impl CampaignConfig {
    /// About a tenth of the default's work: 5 load points, 4 amplitude steps per point,
    /// 4 s analysed per record.
    pub fn quick() -> Self {
        Self {
            record: RecordSettings { analysed_s: 4.0, ..RecordSettings::default() },
            load: LoadStudyConfig::quick(),
            amplitude: AmplitudeStudyConfig { steps: 4, ..AmplitudeStudyConfig::default() },
        }
    }

    /// Checks every number; the error names the field.
    pub fn validate(&self) -> Result<(), IdentificationError> {
        let r = &self.record;
        let [a, b] = r.frequency_ratios;
        if !(a.is_finite() && b.is_finite() && a > 0.0 && b > 0.0) || a == b {
            return Err(IdentificationError::invalid("record.frequency_ratios", format!("must be two different positive numbers, got [{a}, {b}]")));
        }
        if !(r.probe_snr_db.is_finite() && r.probe_snr_db > 0.0) {
            return Err(IdentificationError::invalid("record.probe_snr_db", format!("must be positive, got {}", r.probe_snr_db)));
        }
        for (name, v, min) in [("record.ramp_s", r.ramp_s, 0.0), ("record.settle_s", r.settle_s, 0.0)] {
            if !(v.is_finite() && v >= min) {
                return Err(IdentificationError::invalid(name, format!("must be finite and >= {min}, got {v}")));
            }
        }
        if !(r.analysed_s.is_finite() && r.analysed_s >= 0.5 && r.analysed_s <= 600.0) {
            return Err(IdentificationError::invalid("record.analysed_s", format!("must lie in [0.5, 600] s, got {}", r.analysed_s)));
        }
        let l = &self.load;
        if l.points.len() < 3 {
            return Err(IdentificationError::invalid("load.points", format!("a quadratic fit needs at least 3 points, got {}", l.points.len())));
        }
        for (i, p) in l.points.iter().enumerate() {
            check_operating(&format!("load.points[{i}]"), p.speed_rpm, Some(p.load_n), p.temperature_c)?;
        }
        if !(l.target_d.is_finite() && l.target_d > 0.0 && l.target_d < 0.5) {
            return Err(IdentificationError::invalid("load.target_d", format!("must lie in (0, 0.5), got {}", l.target_d)));
        }
        if !(2..=10_000).contains(&l.model_curve_points) {
            return Err(IdentificationError::invalid("load.model_curve_points", format!("must lie in 2..=10000, got {}", l.model_curve_points)));
        }
        let m = &self.amplitude;
        for (name, p) in [("amplitude.low", &m.low), ("amplitude.high", &m.high)] {
            if !(p.load_parameter.is_finite() && p.load_parameter > 0.0) {
                return Err(IdentificationError::invalid(format!("{name}.load_parameter"), format!("must be positive, got {}", p.load_parameter)));
            }
            check_operating(name, p.speed_rpm, None, p.temperature_c)?;
        }
        if !(m.low.load_parameter < m.high.load_parameter) {
            return Err(IdentificationError::invalid(
                "amplitude.high.load_parameter",
                format!("must exceed amplitude.low.load_parameter ({} vs {})", m.high.load_parameter, m.low.load_parameter),
            ));
        }
        if !(m.d_min.is_finite() && m.d_min > 0.0 && m.d_cap.is_finite() && m.d_cap > m.d_min && m.d_cap < 0.5) {
            return Err(IdentificationError::invalid("amplitude.d_cap", format!("need 0 < d_min < d_cap < 0.5, got d_min {} and d_cap {}", m.d_min, m.d_cap)));
        }
        if !(3..=200).contains(&m.steps) {
            return Err(IdentificationError::invalid("amplitude.steps", format!("the fit KD(d) = a d^3 + b d^2 + d0 needs 3..=200 steps, got {}", m.steps)));
        }
        Ok(())
    }
}

fn check_operating(name: &str, speed_rpm: f64, load_n: Option<f64>, temperature_c: Option<f64>) -> Result<(), IdentificationError> {
    if !(speed_rpm.is_finite() && speed_rpm > 0.0) {
        return Err(IdentificationError::invalid(format!("{name}.speed_rpm"), format!("must be positive, got {speed_rpm}")));
    }
    if let Some(w) = load_n {
        if !(w.is_finite() && w > 0.0) {
            return Err(IdentificationError::invalid(format!("{name}.load_n"), format!("must be positive, got {w}")));
        }
    }
    if let Some(t) = temperature_c {
        if !t.is_finite() {
            return Err(IdentificationError::invalid(format!("{name}.temperature_c"), format!("must be finite, got {t}")));
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Fits
// ---------------------------------------------------------------------------------------------

/// `y = c0 + c1 x + c2 x^2`, least squares.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct QuadraticFit {
    pub c0: f64,
    pub c1: f64,
    pub c2: f64,
    pub r_squared: f64,
    pub rms_residual: f64,
    pub points: usize,
    /// Covariance of `(c0, c1, c2)` from the residual scatter; `None` for an exact fit of
    /// three points.
    pub covariance: Option<[[f64; 3]; 3]>,
}

impl QuadraticFit {
    pub fn eval(&self, x: f64) -> f64 {
        self.c0 + x * (self.c1 + x * self.c2)
    }

    /// `dy/dx`.
    pub fn slope(&self, x: f64) -> f64 {
        self.c1 + 2.0 * self.c2 * x
    }
}

/// Zhou's eq. 10, `KD(d) = a d^3 + b d^2 + d0` (no linear term: eq. 9), least squares.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CubicNoLinearFit {
    pub a: f64,
    pub b: f64,
    pub d0: f64,
    pub r_squared: f64,
    pub rms_residual: f64,
    pub points: usize,
    /// Covariance of `(d0, b, a)` from the residual scatter; `None` for an exact fit of three
    /// points.
    pub covariance: Option<[[f64; 3]; 3]>,
}

impl CubicNoLinearFit {
    pub fn eval(&self, d: f64) -> f64 {
        self.d0 + d * d * (self.b + d * self.a)
    }
}

/// Least squares of `y` on the columns `basis(x)`, solved by SVD of the column-scaled design
/// matrix. Refuses fewer points than parameters, non-finite input and a rank-deficient design
/// (too few distinct abscissae).
/// Returns the coefficients, R^2, the rms residual and the coefficients' covariance from the
/// residual scatter (`None` with no degree of freedom left).
#[allow(clippy::type_complexity)]
fn least_squares(
    what: &str,
    x: &[f64],
    y: &[f64],
    p: usize,
    basis: impl Fn(f64) -> Vec<f64>,
) -> Result<(Vec<f64>, f64, f64, Option<Vec<Vec<f64>>>), IdentificationError> {
    let n = x.len();
    if y.len() != n {
        return Err(IdentificationError::BadInput { what: what.into(), reason: format!("{n} abscissae for {} ordinates", y.len()) });
    }
    if n < p {
        return Err(IdentificationError::BadInput { what: what.into(), reason: format!("under-determined: {n} point(s) for {p} parameters") });
    }
    if let Some(i) = x.iter().zip(y).position(|(a, b)| !(a.is_finite() && b.is_finite())) {
        return Err(IdentificationError::BadInput { what: what.into(), reason: format!("point {i} is not finite ({}, {})", x[i], y[i]) });
    }
    // The basis columns, each scaled to a largest magnitude of 1.
    let mut a: Vec<Vec<f64>> = vec![vec![0.0; n]; p];
    for (i, &xi) in x.iter().enumerate() {
        for (j, v) in basis(xi).into_iter().enumerate().take(p) {
            a[j][i] = v;
        }
    }
    let mut scale = vec![1.0; p];
    for (j, (col, s)) in a.iter_mut().zip(scale.iter_mut()).enumerate() {
        let m = col.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if m == 0.0 {
            return Err(IdentificationError::BadInput { what: what.into(), reason: format!("under-determined: basis column {j} is zero at every point") });
        }
        *s = m;
        col.iter_mut().for_each(|v| *v /= m);
    }
    let cols: Vec<&[f64]> = a.iter().map(Vec::as_slice).collect();
    let fit = qr::least_squares(&cols, y)
        .ok_or_else(|| IdentificationError::BadInput { what: what.into(), reason: "least squares failed: the design is rank deficient".into() })?;
    let sigma = SmallSvd::new(&fit.r, p).map(|s| s.sigma).unwrap_or_default();
    let (smax, smin) = (sigma.first().copied().unwrap_or(0.0), sigma.last().copied().unwrap_or(0.0));
    if !(smin > 1e-10 * smax) {
        return Err(IdentificationError::BadInput {
            what: what.into(),
            reason: format!("under-determined: the abscissae do not separate the {p} parameters (scaled singular values {smax:.3e} .. {smin:.3e})"),
        });
    }
    // (AᵀA)⁻¹ of the scaled design, R⁻¹R⁻ᵀ.
    let inverse_normal = qr::inverse_gram_from_upper(&fit.r, p);
    let sol = fit.coef;
    let coef: Vec<f64> = sol.iter().zip(&scale).map(|(c, s)| c / s).collect();
    let mean = y.iter().sum::<f64>() / n as f64;
    let (mut ss_res, mut ss_tot) = (0.0, 0.0);
    for (&xi, &yi) in x.iter().zip(y) {
        let fit: f64 = basis(xi).iter().zip(&coef).map(|(v, c)| v * c).sum();
        ss_res += (yi - fit).powi(2);
        ss_tot += (yi - mean).powi(2);
    }
    let r2 = if ss_tot > 0.0 {
        1.0 - ss_res / ss_tot
    } else if ss_res <= f64::EPSILON * mean.abs().max(1.0) {
        1.0
    } else {
        0.0
    };
    let covariance = match inverse_normal {
        Some(m) if n > p => {
            let sigma2 = ss_res / (n - p) as f64;
            Some((0..p).map(|i| (0..p).map(|j| sigma2 * m[i * p + j] / (scale[i] * scale[j])).collect()).collect())
        }
        _ => None,
    };
    Ok((coef, r2, (ss_res / n as f64).sqrt(), covariance))
}

/// Least-squares quadratic `y = c0 + c1 x + c2 x^2` (the paper's Figs 5-6 fitting curves).
/// Needs at least three points at three distinct `x`.
pub fn fit_quadratic(x: &[f64], y: &[f64]) -> Result<QuadraticFit, IdentificationError> {
    let (c, r2, rms, cov) = least_squares("quadratic fit", x, y, 3, |v| vec![1.0, v, v * v])?;
    Ok(QuadraticFit { c0: c[0], c1: c[1], c2: c[2], r_squared: r2, rms_residual: rms, points: x.len(), covariance: cov.map(to3) })
}

/// Least-squares `KD(d) = a d^3 + b d^2 + d0` (the paper's eq. 10). Needs at least three
/// points whose `d` separate the three parameters.
pub fn fit_cubic_no_linear(d: &[f64], y: &[f64]) -> Result<CubicNoLinearFit, IdentificationError> {
    let (c, r2, rms, cov) = least_squares("cubic fit without linear term", d, y, 3, |v| vec![1.0, v * v, v * v * v])?;
    Ok(CubicNoLinearFit { d0: c[0], b: c[1], a: c[2], r_squared: r2, rms_residual: rms, points: d.len(), covariance: cov.map(to3) })
}

fn to3(v: Vec<Vec<f64>>) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| v.get(i).and_then(|r| r.get(j)).copied().unwrap_or(f64::NAN)))
}

/// Standard error of [`relative_variation`] at `d` from the fit's covariance (first-order
/// propagation); `None` when the fit had no degree of freedom left.
pub fn relative_variation_se(fit: &CubicNoLinearFit, d: f64) -> Option<f64> {
    let cov = fit.covariance?;
    if !(fit.d0.is_finite() && fit.d0 != 0.0 && d.is_finite()) {
        return None;
    }
    let num = fit.eval(d) - fit.d0;
    // Parameter order (d0, b, a).
    let g = [-num / (fit.d0 * fit.d0), d * d / fit.d0, d * d * d / fit.d0];
    let mut v = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            v += g[i] * cov[i][j] * g[j];
        }
    }
    (v >= 0.0).then(|| v.sqrt())
}

/// Zhou's eq. 11, `RV(d) = (KD(d) - KD(0)) / KD(0)`. Refuses `KD(0) = 0` and a non-finite `d`.
pub fn relative_variation(fit: &CubicNoLinearFit, d: f64) -> Result<f64, IdentificationError> {
    if !d.is_finite() {
        return Err(IdentificationError::invalid("d", format!("must be finite, got {d}")));
    }
    if !(fit.d0.is_finite() && fit.d0 != 0.0) {
        return Err(IdentificationError::invalid("fit.d0", format!("RV is undefined for KD(0) = {}", fit.d0)));
    }
    Ok((fit.eval(d) - fit.d0) / fit.d0)
}

// ---------------------------------------------------------------------------------------------
// One record
// ---------------------------------------------------------------------------------------------

/// Where a campaign is.
#[derive(Debug, Clone, PartialEq)]
pub struct Progress {
    /// "load" or "amplitude".
    pub study: &'static str,
    /// Record index within the whole campaign (0-based) and the campaign's total.
    pub record: usize,
    pub records: usize,
    /// What the record is ("1500 rpm, 5000 N").
    pub label: String,
    /// Fraction of this record's simulation done.
    pub fraction: f64,
}

/// A fully specified record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecordSpec {
    pub speed_rpm: f64,
    pub load_n: f64,
    pub temperature_c: f64,
    /// Exciter amplitude (both exciters), N.
    pub amplitude_n: f64,
    pub seed: u64,
}

/// The film model's linearisation at an operating point and the housing's linear response.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelPoint {
    pub speed_rpm: f64,
    pub load_n: f64,
    pub temperature_c: f64,
    pub viscosity_pa_s: f64,
    pub load_parameter: f64,
    pub sommerfeld: f64,
    pub eccentricity: f64,
    pub attitude_deg: f64,
    pub stiffness_n_m: Matrix2<f64>,
    pub damping_n_s_m: Matrix2<f64>,
    /// Zhou's dimensionless coefficients.
    pub zhou: Coefficients8,
}

/// The linear prediction of a two-tone record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExcitationDesign {
    pub frequencies_hz: [f64; 2],
    pub amplitude_n: f64,
    /// `d` and the rms of the dynamic relative displacement (m) the linear model predicts.
    pub predicted_d: f64,
    pub predicted_rms_m: f64,
    /// Per-axis probe noise set for the SNR, m.
    pub probe_noise_rms_m: f64,
    /// Why the amplitude is what it is ("target d", "exciter force limit", ...).
    pub limited_by: String,
}

/// One simulated and identified record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecordResult {
    pub label: String,
    pub spec: RecordSpec,
    pub excitation: ExcitationDesign,
    /// The film model's own linearisation (untabulated film) at the nominal operating point.
    pub model: ModelPoint,
    /// The linear coefficients of the tabulated film the rig integrates, Zhou's groups.
    pub rig_truth: Coefficients8,
    /// Measured by the pipeline: `F_Y` from the eq. 2 static force, measured temperature.
    pub load_parameter: f64,
    /// Measured `d = max |r - mean r| / c`.
    pub amplitude_d: f64,
    /// Identified, Zhou's groups; `None` when the window was refused.
    pub identified: Option<Coefficients8>,
    /// Their standard errors (HAC), Zhou's groups.
    pub standard_error: Option<Coefficients8>,
    /// `(identified - model) / |model|` per coefficient.
    pub relative_difference_to_model: Option<Coefficients8>,
    /// Why nothing was identified, if so.
    pub refusal: Option<String>,
    /// The pipeline's whole window report (dimensional coefficients, condition, flags).
    pub window: Option<WindowReport>,
}

fn rig_at(rig: &RigConfig, speed_rpm: f64, load_n: f64, temperature_c: f64) -> Result<RigConfig, IdentificationError> {
    let mut r = rig.clone();
    r.operating.speed_rpm = speed_rpm;
    r.operating.bearing_load_n = load_n;
    r.operating.bearing_temperature_c = temperature_c;
    r.validate()?;
    Ok(r)
}

/// The film model's equilibrium and linear coefficients at an operating point.
pub fn model_point(rig: &RigConfig, speed_rpm: f64, load_n: f64, temperature_c: f64) -> Result<ModelPoint, IdentificationError> {
    let mu = rig.oil.viscosity_pa_s(temperature_c)?;
    let running = Running::from_rpm(speed_rpm, mu);
    let op = solve_film(rig, &running, load_n)?;
    Ok(model_from(rig, &op, speed_rpm, temperature_c))
}

fn solve_film(rig: &RigConfig, running: &Running, load_n: f64) -> Result<OperatingPoint, IdentificationError> {
    let mut film = rig.film()?;
    Ok(operating_point::solve(film.as_mut(), running, Vector2::new(0.0, -load_n), &EquilibriumOptions::default())?)
}

fn model_from(rig: &RigConfig, op: &OperatingPoint, speed_rpm: f64, temperature_c: f64) -> ModelPoint {
    let k = op.coefficients.stiffness_n_m;
    let d = op.coefficients.damping_n_s_m;
    ModelPoint {
        speed_rpm,
        load_n: op.load_n,
        temperature_c,
        viscosity_pa_s: op.running.viscosity_pa_s,
        load_parameter: dimensionless::zhou_load_parameter(&rig.bearing, &op.running, op.load_n),
        sommerfeld: op.sommerfeld,
        eccentricity: op.eccentricity,
        attitude_deg: op.attitude_deg,
        stiffness_n_m: k,
        damping_n_s_m: d,
        zhou: zhou8(&k, &d, rig, &op.running),
    }
}

/// The relative-displacement phasors of the two tones for 1 N per exciter:
/// `(K - w^2 m + i w C) X = F`, `r = -X`, a sine `sin(w t)` being the phasor `-i`.
fn unit_response(rig: &RigConfig, model: &ModelPoint, freqs: [f64; 2]) -> Result<[[Complex<f64>; 2]; 2], IdentificationError> {
    let m = rig.housing.mass_kg;
    let mut out = [[Complex::new(0.0, 0.0); 2]; 2];
    for (j, f) in freqs.iter().enumerate() {
        let w = 2.0 * PI * f;
        let a = rig.housing.exciter_angles_deg[j].to_radians();
        let dyn_stiff: Matrix2<Complex<f64>> = Matrix2::from_fn(|r, c| {
            let mass = if r == c { w * w * m } else { 0.0 };
            Complex::new(model.stiffness_n_m[(r, c)] - mass, w * model.damping_n_s_m[(r, c)])
        });
        let inv = dyn_stiff
            .try_inverse()
            .ok_or_else(|| IdentificationError::invalid("excitation", format!("the housing's linear dynamic stiffness is singular at {f} Hz")))?;
        let force = Vector2::new(Complex::new(0.0, -a.cos()), Complex::new(0.0, -a.sin()));
        let x = inv * force;
        out[j] = [-x[0], -x[1]];
    }
    Ok(out)
}

/// `(max |r(t)|, rms |r|)` over `seconds` of the two-tone response to 1 N per exciter.
fn unit_amplitude(resp: &[[Complex<f64>; 2]; 2], freqs: [f64; 2], seconds: f64) -> (f64, f64) {
    let fmax = freqs[0].max(freqs[1]);
    let n = ((seconds * fmax * 64.0).ceil() as usize).clamp(1024, 2_000_000);
    let mut peak: f64 = 0.0;
    for i in 0..n {
        let t = seconds * i as f64 / n as f64;
        let mut r = [0.0; 2];
        for (j, f) in freqs.iter().enumerate() {
            let e = Complex::from_polar(1.0, 2.0 * PI * f * t);
            r[0] += (resp[j][0] * e).re;
            r[1] += (resp[j][1] * e).re;
        }
        peak = peak.max(r[0].hypot(r[1]));
    }
    let ms: f64 = resp.iter().map(|v| (v[0].norm_sqr() + v[1].norm_sqr()) / 2.0).sum();
    (peak, ms.sqrt())
}

/// Designs the excitation of a record: the amplitude for `target_d` (or the given force),
/// limited by the exciters.
fn design_excitation(rig: &RigConfig, model: &ModelPoint, settings: &RecordSettings, amplitude: Amplitude) -> Result<ExcitationDesign, IdentificationError> {
    let n_hz = model.speed_rpm / 60.0;
    let freqs = [settings.frequency_ratios[0] * n_hz, settings.frequency_ratios[1] * n_hz];
    let resp = unit_response(rig, model, freqs)?;
    let (d_unit_m, rms_unit) = unit_amplitude(&resp, freqs, settings.analysed_s);
    let c = rig.bearing.clearance_m;
    let d_unit = d_unit_m / c;
    if !(d_unit.is_finite() && d_unit > 0.0) {
        return Err(IdentificationError::invalid("excitation", format!("the linear model predicts no motion ({d_unit} per N)")));
    }
    let max_f = rig.housing.exciter_max_force_n;
    let (amplitude_n, limited_by) = match amplitude {
        Amplitude::TargetD(d) => {
            let f = d / d_unit;
            if f > max_f {
                (max_f, format!("exciter force limit {max_f} N (target d {d} needs {f:.0} N)"))
            } else {
                (f, format!("target d {d}"))
            }
        }
        Amplitude::Force(f, why) => (f.min(max_f), why),
    };
    let rms = amplitude_n * rms_unit;
    Ok(ExcitationDesign {
        frequencies_hz: freqs,
        amplitude_n,
        predicted_d: amplitude_n * d_unit,
        predicted_rms_m: rms,
        probe_noise_rms_m: rms * 10f64.powf(-settings.probe_snr_db / 20.0) / SQRT_2,
        limited_by,
    })
}

#[derive(Debug, Clone)]
enum Amplitude {
    TargetD(f64),
    Force(f64, String),
}

/// Simulates and identifies one record at `spec` with the excitation `design`.
fn run_record(
    rig: &RigConfig,
    settings: &RecordSettings,
    label: String,
    spec: RecordSpec,
    model: ModelPoint,
    design: ExcitationDesign,
    progress: &mut dyn FnMut(f64),
) -> Result<RecordResult, IdentificationError> {
    let mut r = rig_at(rig, spec.speed_rpm, spec.load_n, spec.temperature_c)?;
    r.simulation.seed = spec.seed;
    r.daq.set_displacement_probe_noise(design.probe_noise_rms_m);
    let mut plan = ExcitationPlan::two_tone(design.frequencies_hz[0], design.frequencies_hz[1], design.amplitude_n);
    plan.ramp_s = settings.ramp_s;
    let dropped_s = settings.ramp_s + settings.settle_s;
    let rec = simulate::simulate(&r, &plan, dropped_s + settings.analysed_s, SimulateOptions::default(), progress)?;
    let skip = ((dropped_s * rec.sample_rate_hz).round() as usize).min(rec.scans.len());
    let raw = RawRecord::from_scans(&rec.scans[skip..], rec.sample_rate_hz)?;
    let calibration = pipeline::calibration_for(&r, &raw, &pipeline::rig_offsets(&r, &raw)?)?;
    let mut config = PipelineConfig::default();
    // One window over the whole analysed record (the pipeline shortens it to the samples
    // free of filter edge effects).
    config.estimator.window = raw.columns.first().map_or(1, Vec::len).max(2);
    config.estimator.hop = config.estimator.window;
    let id = pipeline::identify(&raw, &calibration, &r, spec.speed_rpm, SpeedSource::Record, &config)?;
    let truth = zhou8(&rec.truth.coefficients.stiffness_n_m, &rec.truth.coefficients.damping_n_s_m, &r, &rec.truth.running);
    let window = id.windows.first().cloned();
    let mut out = RecordResult {
        label,
        spec,
        excitation: design,
        model,
        rig_truth: truth,
        load_parameter: f64::NAN,
        amplitude_d: f64::NAN,
        identified: None,
        standard_error: None,
        relative_difference_to_model: None,
        refusal: id.refusal.clone(),
        window: None,
    };
    let Some(w) = window else {
        if out.refusal.is_none() {
            out.refusal = Some("the pipeline returned no window".into());
        }
        return Ok(out);
    };
    out.load_parameter = w.operating.load_parameter;
    out.amplitude_d = w.operating.amplitude_d;
    match (&w.estimate.result, &w.zhou) {
        (Ok(c), Some(z)) => {
            let running = Running::from_rpm(w.operating.speed_rpm, w.operating.viscosity_pa_s);
            let ident = Coefficients8::from_dimensionless(z);
            out.standard_error = Some(zhou8(&c.stiffness_se, &c.damping_se, &r, &running));
            let m = out.model.zhou.as_array();
            let i = ident.as_array();
            out.relative_difference_to_model = Some(Coefficients8::from_array(std::array::from_fn(|k| (i[k] - m[k]) / m[k].abs())));
            out.identified = Some(ident);
        }
        (Err(refusal), _) => out.refusal = Some(refusal.to_string()),
        (Ok(_), None) => out.refusal = Some("no static film load measured: no dimensionless coefficients".into()),
    }
    out.window = Some(w);
    Ok(out)
}

fn seed_for(rig: &RigConfig, offset: u64, index: usize) -> u64 {
    rig.simulation.seed.wrapping_add(offset).wrapping_add(index as u64)
}

// ---------------------------------------------------------------------------------------------
// Load study
// ---------------------------------------------------------------------------------------------

/// A fit of one coefficient against `F_Y` and what it says.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FyTrend {
    pub name: String,
    pub fit: QuadraticFit,
    /// The measured `F_Y` range the fit covers.
    pub fy_range: [f64; 2],
    /// The fit at the smallest and largest measured `F_Y`.
    pub fit_at_min_fy: f64,
    pub fit_at_max_fy: f64,
    /// Sign of `fit(max) - fit(min)`: +1 grows in value, -1 falls, 0 flat.
    pub slope_sign: i8,
    /// `|fit(max)| > |fit(min)|`.
    pub grows_in_magnitude: bool,
    /// The fit's slope keeps one sign over the measured range.
    pub monotone_in_range: bool,
    /// The model at the same two `F_Y` (from the model curve).
    pub model_at_min_fy: f64,
    pub model_at_max_fy: f64,
    pub model_slope_sign: i8,
    /// Where the model curve turns inside the range, `(F_Y, value)`, if it does.
    pub model_extremum: Option<(f64, f64)>,
    /// Mean and largest `|identified - model|` over the points (dimensionless), and the same
    /// relative to `|model|` (large where the model is near zero).
    pub mean_abs_difference: f64,
    pub max_abs_difference: f64,
    pub mean_abs_relative_difference: f64,
    pub max_abs_relative_difference: f64,
}

/// The load-parameter study.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LoadStudy {
    pub convention: String,
    pub points: Vec<RecordResult>,
    /// The model's coefficients over the studied `F_Y` range: Zhou's groups depend on `F_Y`
    /// alone for this isoviscous film, so the curve is computed at the rig file's speed and
    /// temperature with the load that gives each `F_Y` (some beyond the bellows' reach: it is
    /// the film model, not the rig).
    pub model_curve: Vec<ModelPoint>,
    /// One per coefficient, in [`COEFFICIENT_NAMES`] order.
    pub trends: Vec<FyTrend>,
}

/// Runs the load-parameter study: one small-amplitude record per operating point.
pub fn run_load_study(rig: &RigConfig, cfg: &CampaignConfig, progress: &mut dyn FnMut(Progress)) -> Result<LoadStudy, IdentificationError> {
    cfg.validate()?;
    let total = total_records(cfg);
    run_load_study_from(rig, cfg, 0, total, progress)
}

fn total_records(cfg: &CampaignConfig) -> usize {
    cfg.load.points.len() + 2 * cfg.amplitude.steps
}

fn run_load_study_from(
    rig: &RigConfig,
    cfg: &CampaignConfig,
    first: usize,
    total: usize,
    progress: &mut dyn FnMut(Progress),
) -> Result<LoadStudy, IdentificationError> {
    let mut points = Vec::with_capacity(cfg.load.points.len());
    for (i, p) in cfg.load.points.iter().enumerate() {
        let temperature_c = p.temperature_c.unwrap_or(rig.operating.bearing_temperature_c);
        let label = format!("{:.0} rpm, {:.0} N, {:.1} C", p.speed_rpm, p.load_n, temperature_c);
        let ctx = |e: IdentificationError| IdentificationError::invalid(format!("load.points[{i}]"), format!("{label}: {e}"));
        rig_at(rig, p.speed_rpm, p.load_n, temperature_c).map_err(ctx)?;
        let model = model_point(rig, p.speed_rpm, p.load_n, temperature_c).map_err(ctx)?;
        let design = design_excitation(rig, &model, &cfg.record, Amplitude::TargetD(cfg.load.target_d)).map_err(ctx)?;
        let spec = RecordSpec { speed_rpm: p.speed_rpm, load_n: p.load_n, temperature_c, amplitude_n: design.amplitude_n, seed: seed_for(rig, 0, i) };
        let mut cb = |fraction: f64| progress(Progress { study: "load", record: first + i, records: total, label: label.clone(), fraction });
        let result = run_record(rig, &cfg.record, label.clone(), spec, model, design, &mut cb).map_err(ctx)?;
        points.push(result);
    }
    let solved: Vec<&RecordResult> = points.iter().filter(|p| p.identified.is_some()).collect();
    if solved.len() < 3 {
        return Err(IdentificationError::BadInput {
            what: "load study".into(),
            reason: format!(
                "only {} of {} records identified; refusals: {}",
                solved.len(),
                points.len(),
                points.iter().filter_map(|p| p.refusal.as_deref()).collect::<Vec<_>>().join("; ")
            ),
        });
    }
    let fy: Vec<f64> = solved.iter().map(|p| p.load_parameter).collect();
    let fy_min = fy.iter().copied().fold(f64::INFINITY, f64::min);
    let fy_max = fy.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let model_curve = model_curve(rig, fy_min, fy_max, cfg.load.model_curve_points)?;
    let model_at = |x: f64, k: usize| interpolate_curve(&model_curve, x, k);
    let mut trends = Vec::with_capacity(8);
    for (k, name) in COEFFICIENT_NAMES.iter().enumerate() {
        let y: Vec<f64> = solved.iter().filter_map(|p| p.identified.map(|c| c.as_array()[k])).collect();
        let fit = fit_quadratic(&fy, &y).map_err(|e| IdentificationError::BadInput { what: format!("{name} vs F_Y"), reason: e.to_string() })?;
        let (lo, hi) = (fit.eval(fy_min), fit.eval(fy_max));
        let (mlo, mhi) = (model_at(fy_min, k), model_at(fy_max, k));
        let diffs: Vec<f64> = solved.iter().filter_map(|p| p.relative_difference_to_model.map(|c| c.as_array()[k].abs())).collect();
        let abs: Vec<f64> = solved.iter().filter_map(|p| p.identified.map(|c| (c.as_array()[k] - p.model.zhou.as_array()[k]).abs())).collect();
        let values: Vec<f64> = model_curve.iter().map(|m| m.zhou.as_array()[k]).collect();
        let model_extremum = interior_extremum(&values).map(|i| (model_curve[i].load_parameter, values[i]));
        trends.push(FyTrend {
            name: (*name).to_string(),
            fit,
            fy_range: [fy_min, fy_max],
            fit_at_min_fy: lo,
            fit_at_max_fy: hi,
            slope_sign: sign(hi - lo),
            grows_in_magnitude: hi.abs() > lo.abs(),
            monotone_in_range: fit.slope(fy_min).signum() == fit.slope(fy_max).signum(),
            model_at_min_fy: mlo,
            model_at_max_fy: mhi,
            model_slope_sign: sign(mhi - mlo),
            model_extremum,
            mean_abs_difference: abs.iter().sum::<f64>() / abs.len().max(1) as f64,
            max_abs_difference: abs.iter().copied().fold(0.0, f64::max),
            mean_abs_relative_difference: diffs.iter().sum::<f64>() / diffs.len().max(1) as f64,
            max_abs_relative_difference: diffs.iter().copied().fold(0.0, f64::max),
        });
    }
    Ok(LoadStudy { convention: CONVENTION.into(), points, model_curve, trends })
}

/// The index of an interior maximum or minimum that stands out of both ends by more than 2 %
/// of the curve's span (a turning point, not the discrete film's roughness).
fn interior_extremum(v: &[f64]) -> Option<usize> {
    let (first, last) = (*v.first()?, *v.last()?);
    let (mut imax, mut imin) = (0, 0);
    for (i, x) in v.iter().enumerate() {
        if *x > v[imax] {
            imax = i;
        }
        if *x < v[imin] {
            imin = i;
        }
    }
    let span = v[imax] - v[imin];
    let tol = 0.02 * span;
    if imax > 0 && imax + 1 < v.len() && v[imax] - first.max(last) > tol {
        return Some(imax);
    }
    if imin > 0 && imin + 1 < v.len() && first.min(last) - v[imin] > tol {
        return Some(imin);
    }
    None
}

fn sign(x: f64) -> i8 {
    if x > 0.0 {
        1
    } else if x < 0.0 {
        -1
    } else {
        0
    }
}

/// The model's Zhou coefficients at `n` load parameters evenly over `[fy_min, fy_max]`, at the
/// rig file's speed and temperature.
pub fn model_curve(rig: &RigConfig, fy_min: f64, fy_max: f64, n: usize) -> Result<Vec<ModelPoint>, IdentificationError> {
    if !(fy_min.is_finite() && fy_max.is_finite() && fy_min > 0.0 && fy_max >= fy_min && n >= 2) {
        return Err(IdentificationError::invalid("model curve", format!("needs 0 < F_Y min <= max and 2+ points, got [{fy_min}, {fy_max}], {n}")));
    }
    let speed = rig.operating.speed_rpm;
    let temperature = rig.operating.bearing_temperature_c;
    let running = rig.running()?;
    let per_fy = dimensionless::zhou_load_parameter(&rig.bearing, &running, 1.0);
    (0..n)
        .map(|i| {
            let fy = fy_min + (fy_max - fy_min) * i as f64 / (n - 1) as f64;
            let op = solve_film(rig, &running, fy / per_fy)?;
            Ok(model_from(rig, &op, speed, temperature))
        })
        .collect()
}

/// Linear interpolation of coefficient `k` of a model curve at `fy` (clamped to its ends).
fn interpolate_curve(curve: &[ModelPoint], fy: f64, k: usize) -> f64 {
    let v = |p: &ModelPoint| p.zhou.as_array()[k];
    let (Some(first), Some(last)) = (curve.first(), curve.last()) else { return f64::NAN };
    if fy <= first.load_parameter {
        return v(first);
    }
    for w in curve.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        if fy <= b.load_parameter {
            let s = (fy - a.load_parameter) / (b.load_parameter - a.load_parameter);
            return v(a) + s * (v(b) - v(a));
        }
    }
    v(last)
}

// ---------------------------------------------------------------------------------------------
// Amplitude study
// ---------------------------------------------------------------------------------------------

/// One coefficient against `d` at one load parameter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AmplitudeFit {
    pub name: String,
    pub fit: CubicNoLinearFit,
    /// `RV` at the largest `d` of this sweep.
    pub rv_at_max_d: f64,
    /// `|RV|` never decreases over `[0, max d]` (checked on 50 points).
    pub abs_rv_monotone: bool,
}

/// The amplitude sweep at one load parameter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AmplitudeSweep {
    /// "F_Y 0.35".
    pub label: String,
    pub target_load_parameter: f64,
    pub speed_rpm: f64,
    pub load_n: f64,
    pub temperature_c: f64,
    pub model: ModelPoint,
    /// The force of the largest step and what limited it.
    pub max_force_n: f64,
    pub max_force_limited_by: String,
    pub steps: Vec<RecordResult>,
    /// Largest measured `d` among identified steps.
    pub max_d: f64,
    /// One per coefficient, in [`COEFFICIENT_NAMES`] order.
    pub fits: Vec<AmplitudeFit>,
}

/// The amplitude study at the two load parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AmplitudeStudy {
    pub convention: String,
    pub low: AmplitudeSweep,
    pub high: AmplitudeSweep,
}

/// Runs the amplitude study: at each of the two load parameters, `steps` records from
/// `d_min` up to what the exciters (or `d_cap`) allow.
pub fn run_amplitude_study(rig: &RigConfig, cfg: &CampaignConfig, progress: &mut dyn FnMut(Progress)) -> Result<AmplitudeStudy, IdentificationError> {
    cfg.validate()?;
    let total = total_records(cfg);
    run_amplitude_study_from(rig, cfg, cfg.load.points.len(), total, progress)
}

fn run_amplitude_study_from(
    rig: &RigConfig,
    cfg: &CampaignConfig,
    first: usize,
    total: usize,
    progress: &mut dyn FnMut(Progress),
) -> Result<AmplitudeStudy, IdentificationError> {
    let a = &cfg.amplitude;
    let low = sweep(rig, cfg, "amplitude.low", &a.low, 0, first, total, progress)?;
    let high = sweep(rig, cfg, "amplitude.high", &a.high, a.steps, first + a.steps, total, progress)?;
    Ok(AmplitudeStudy { convention: CONVENTION.into(), low, high })
}

/// The load on the film that gives `load_parameter` at `speed_rpm` and `temperature_c`.
pub fn load_for(rig: &RigConfig, load_parameter: f64, speed_rpm: f64, temperature_c: f64) -> Result<f64, IdentificationError> {
    let running = Running::from_rpm(speed_rpm, rig.oil.viscosity_pa_s(temperature_c)?);
    Ok(load_parameter / dimensionless::zhou_load_parameter(&rig.bearing, &running, 1.0))
}

#[allow(clippy::too_many_arguments)]
fn sweep(
    rig: &RigConfig,
    cfg: &CampaignConfig,
    field: &str,
    point: &AmplitudePointConfig,
    seed_index: usize,
    first: usize,
    total: usize,
    progress: &mut dyn FnMut(Progress),
) -> Result<AmplitudeSweep, IdentificationError> {
    let a = &cfg.amplitude;
    let temperature_c = point.temperature_c.unwrap_or(rig.operating.bearing_temperature_c);
    let load_n = load_for(rig, point.load_parameter, point.speed_rpm, temperature_c)?;
    let ctx = |e: IdentificationError| {
        IdentificationError::invalid(field, format!("F_Y {} at {} rpm, {load_n:.0} N, {temperature_c} C: {e}", point.load_parameter, point.speed_rpm))
    };
    rig_at(rig, point.speed_rpm, load_n, temperature_c).map_err(ctx)?;
    let model = model_point(rig, point.speed_rpm, load_n, temperature_c).map_err(ctx)?;
    // Force per unit d from the linear model, then the force range.
    let unit = design_excitation(rig, &model, &cfg.record, Amplitude::Force(1.0, String::new())).map_err(ctx)?;
    let per_d = 1.0 / unit.predicted_d;
    let max_f = rig.housing.exciter_max_force_n;
    let f_min = a.d_min * per_d;
    let (f_max, why) = if a.d_cap * per_d <= max_f {
        (a.d_cap * per_d, format!("d cap {} (the rig's tabulated film covers +-0.15 c); the exciters' {max_f} N would give d ~ {:.3}", a.d_cap, max_f / per_d))
    } else {
        (max_f, format!("exciter force limit {max_f} N (linear prediction d {:.3})", max_f / per_d))
    };
    if !(f_min < f_max) {
        return Err(ctx(IdentificationError::invalid(
            "amplitude.d_min",
            format!("d_min {} needs {f_min:.0} N, not below the largest force {f_max:.0} N", a.d_min),
        )));
    }
    let label = format!("F_Y {}", point.load_parameter);
    let mut steps = Vec::with_capacity(a.steps);
    for s in 0..a.steps {
        let force = f_min + (f_max - f_min) * s as f64 / (a.steps - 1) as f64;
        let why_step = if s + 1 == a.steps { why.clone() } else { format!("step {} of {}", s + 1, a.steps) };
        let design = design_excitation(rig, &model, &cfg.record, Amplitude::Force(force, why_step)).map_err(ctx)?;
        let spec = RecordSpec {
            speed_rpm: point.speed_rpm,
            load_n,
            temperature_c,
            amplitude_n: design.amplitude_n,
            seed: seed_for(rig, AMPLITUDE_SEED_OFFSET, seed_index + s),
        };
        let step_label = format!("{label}: {:.0} rpm, {load_n:.0} N, {force:.0} N excitation", point.speed_rpm);
        let mut cb = |fraction: f64| progress(Progress { study: "amplitude", record: first + s, records: total, label: step_label.clone(), fraction });
        steps.push(run_record(rig, &cfg.record, step_label.clone(), spec, model.clone(), design, &mut cb).map_err(ctx)?);
    }
    let solved: Vec<&RecordResult> = steps.iter().filter(|s| s.identified.is_some()).collect();
    let d: Vec<f64> = solved.iter().map(|s| s.amplitude_d).collect();
    let max_d = d.iter().copied().fold(0.0, f64::max);
    let mut fits = Vec::with_capacity(8);
    for (k, name) in COEFFICIENT_NAMES.iter().enumerate() {
        let y: Vec<f64> = solved.iter().filter_map(|s| s.identified.map(|c| c.as_array()[k])).collect();
        let fit = fit_cubic_no_linear(&d, &y).map_err(|e| ctx(IdentificationError::BadInput { what: format!("{name} vs d"), reason: e.to_string() }))?;
        let rv_at_max_d = relative_variation(&fit, max_d).map_err(ctx)?;
        let grid: Vec<f64> = (0..=50).map(|i| relative_variation(&fit, max_d * i as f64 / 50.0).map(f64::abs).unwrap_or(f64::NAN)).collect();
        let abs_rv_monotone = grid.windows(2).all(|w| w[1] >= w[0] - 1e-12);
        fits.push(AmplitudeFit { name: (*name).to_string(), fit, rv_at_max_d, abs_rv_monotone });
    }
    Ok(AmplitudeSweep {
        label,
        target_load_parameter: point.load_parameter,
        speed_rpm: point.speed_rpm,
        load_n,
        temperature_c,
        model,
        max_force_n: f_max,
        max_force_limited_by: why,
        steps,
        max_d,
        fits,
    })
}

// ---------------------------------------------------------------------------------------------
// Findings
// ---------------------------------------------------------------------------------------------

/// `RV` of one coefficient at one `d` at both load parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RvComparison {
    pub name: String,
    pub rv_low_fy: f64,
    pub rv_high_fy: f64,
    /// Standard errors from the fits' residual scatter (`None`: no degree of freedom left).
    pub rv_low_fy_se: Option<f64>,
    pub rv_high_fy_se: Option<f64>,
    /// `|RV|` larger at the high load parameter.
    pub high_fy_larger: bool,
}

/// How the high load parameter's `|RV|` compares with the low one's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Larger by more than two standard errors of the difference.
    Larger,
    /// Within two standard errors (or no standard error to judge by: then by sign only,
    /// never called larger).
    Indistinguishable,
    /// Smaller by more than two standard errors.
    Smaller,
}

/// `RV` of every coefficient at one `d`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RvAt {
    pub d: f64,
    /// `d` lies beyond the largest measured `d` of a sweep: the fit is extrapolated there.
    pub extrapolated_low_fy: bool,
    pub extrapolated_high_fy: bool,
    pub coefficients: Vec<RvComparison>,
    /// Mean `|RV|` over the eight coefficients and its standard error.
    pub mean_abs_rv_low_fy: f64,
    pub mean_abs_rv_high_fy: f64,
    pub mean_abs_rv_low_fy_se: Option<f64>,
    pub mean_abs_rv_high_fy_se: Option<f64>,
    /// The high load parameter's mean `|RV|` against the low one's.
    pub verdict: Verdict,
    /// How many of the eight have the larger `|RV|` at the high load parameter.
    pub larger_at_high_fy: usize,
}

/// The paper's qualitative claims checked on the simulation, with the numbers behind them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Findings {
    pub convention: String,
    /// Per coefficient: does it grow with `F_Y` (fit and model)?
    pub coefficients_grow_with_fy: Vec<FyTrend>,
    /// Kxx, Kyy, Dxx, Dyy all grow in value with `F_Y` (identified fits).
    pub direct_coefficients_grow_with_fy: bool,
    /// Names of the coefficients whose magnitude grows with `F_Y`, and of those whose does not.
    pub growing_in_magnitude: Vec<String>,
    pub not_growing_in_magnitude: Vec<String>,
    /// Mean `|RV|` over the eight coefficients grows with `d` from 0 to the largest `d`, at
    /// both load parameters (fits checked on 50 points each).
    pub rv_grows_with_d: bool,
    /// Per load parameter: `(label, largest d, mean |RV| at half of it, mean |RV| at it)`.
    pub mean_abs_rv_growth: Vec<(String, f64, f64, f64)>,
    /// The largest `d` reached at both load parameters.
    pub common_d: f64,
    pub rv_at_common_d: RvAt,
    /// The paper's d = 0.05 (extrapolated where a sweep did not reach it).
    pub rv_at_d_005: RvAt,
    /// The paper's claim: mean `|RV|` at `common_d` larger at the high load parameter by more
    /// than two standard errors ([`Verdict::Larger`]).
    pub rv_faster_at_high_fy: bool,
    /// The coefficient with the largest `|RV|` at `common_d` (either load parameter).
    pub most_sensitive: String,
    pub most_sensitive_rv: f64,
    pub most_sensitive_at: String,
    /// Per load parameter: `(label, coefficient, RV)` of its own most sensitive coefficient.
    pub most_sensitive_per_fy: Vec<(String, String, f64)>,
    /// Plain sentences with the numbers.
    pub notes: Vec<String>,
}

fn rv_at(study: &AmplitudeStudy, d: f64) -> Result<RvAt, IdentificationError> {
    let mut coefficients = Vec::with_capacity(8);
    let (mut sl, mut sh, mut vl, mut vh, mut larger) = (0.0, 0.0, Some(0.0), Some(0.0), 0);
    for (fl, fh) in study.low.fits.iter().zip(&study.high.fits) {
        let (l, h) = (relative_variation(&fl.fit, d)?, relative_variation(&fh.fit, d)?);
        let (el, eh) = (relative_variation_se(&fl.fit, d), relative_variation_se(&fh.fit, d));
        sl += l.abs();
        sh += h.abs();
        vl = vl.zip(el).map(|(v, e)| v + e * e);
        vh = vh.zip(eh).map(|(v, e)| v + e * e);
        let high_fy_larger = h.abs() > l.abs();
        larger += usize::from(high_fy_larger);
        coefficients.push(RvComparison { name: fl.name.clone(), rv_low_fy: l, rv_high_fy: h, rv_low_fy_se: el, rv_high_fy_se: eh, high_fy_larger });
    }
    let n = coefficients.len().max(1) as f64;
    let (ml, mh) = (sl / n, sh / n);
    let (el, eh) = (vl.map(|v| v.sqrt() / n), vh.map(|v| v.sqrt() / n));
    let verdict = match el.zip(eh).map(|(a, b)| a.hypot(b)) {
        Some(se) if mh - ml > 2.0 * se => Verdict::Larger,
        Some(se) if ml - mh > 2.0 * se => Verdict::Smaller,
        _ => Verdict::Indistinguishable,
    };
    Ok(RvAt {
        d,
        extrapolated_low_fy: d > study.low.max_d,
        extrapolated_high_fy: d > study.high.max_d,
        coefficients,
        mean_abs_rv_low_fy: ml,
        mean_abs_rv_high_fy: mh,
        mean_abs_rv_low_fy_se: el,
        mean_abs_rv_high_fy_se: eh,
        verdict,
        larger_at_high_fy: larger,
    })
}

fn mean_abs_rv(sweep: &AmplitudeSweep, d: f64) -> f64 {
    let n = sweep.fits.len().max(1) as f64;
    sweep.fits.iter().map(|f| relative_variation(&f.fit, d).map(f64::abs).unwrap_or(f64::NAN)).sum::<f64>() / n
}

/// The checks of the paper's findings on the two studies.
pub fn findings(load: &LoadStudy, amplitude: &AmplitudeStudy) -> Result<Findings, IdentificationError> {
    let trends = load.trends.clone();
    let direct = DIRECT.iter().all(|&k| trends.get(k).is_some_and(|t| t.slope_sign > 0));
    let growing: Vec<String> = trends.iter().filter(|t| t.grows_in_magnitude).map(|t| t.name.clone()).collect();
    let not_growing: Vec<String> = trends.iter().filter(|t| !t.grows_in_magnitude).map(|t| t.name.clone()).collect();

    let mut growth = Vec::new();
    let mut grows = true;
    for s in [&amplitude.low, &amplitude.high] {
        let grid: Vec<f64> = (0..=50).map(|i| mean_abs_rv(s, s.max_d * i as f64 / 50.0)).collect();
        let monotone = grid.windows(2).all(|w| w[1] >= w[0] - 1e-12);
        let (half, full) = (mean_abs_rv(s, 0.5 * s.max_d), mean_abs_rv(s, s.max_d));
        grows &= monotone && full > half && half > 0.0;
        growth.push((s.label.clone(), s.max_d, half, full));
    }
    let common_d = amplitude.low.max_d.min(amplitude.high.max_d);
    if !(common_d > 0.0) {
        return Err(IdentificationError::BadInput { what: "amplitude study".into(), reason: "no identified step at one of the load parameters".into() });
    }
    let at_common = rv_at(amplitude, common_d)?;
    let at_005 = rv_at(amplitude, 0.05)?;
    let faster = at_common.verdict == Verdict::Larger;
    let mut best = (String::new(), 0.0_f64, String::new());
    let mut per_fy = Vec::new();
    for (sweep, pick) in [(&amplitude.low, 0), (&amplitude.high, 1)] {
        let mut own = (String::new(), 0.0_f64);
        for c in &at_common.coefficients {
            let rv = if pick == 0 { c.rv_low_fy } else { c.rv_high_fy };
            if rv.abs() > own.1.abs() || own.0.is_empty() {
                own = (c.name.clone(), rv);
            }
            if rv.abs() > best.1.abs() || best.0.is_empty() {
                best = (c.name.clone(), rv, sweep.label.clone());
            }
        }
        per_fy.push((sweep.label.clone(), own.0, own.1));
    }

    let pct = |x: f64| format!("{:+.1} %", 100.0 * x);
    let pct_se = |x: f64, se: Option<f64>| match se {
        Some(e) => format!("{:.2} +- {:.2} %", 100.0 * x, 100.0 * e),
        None => format!("{:.2} %", 100.0 * x),
    };
    let fy: Vec<f64> = load.points.iter().filter(|p| p.identified.is_some()).map(|p| p.load_parameter).collect();
    let fy_min = fy.iter().copied().fold(f64::INFINITY, f64::min);
    let fy_max = fy.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut notes = Vec::new();
    for t in &trends {
        let extremum = match t.model_extremum {
            Some((x, v)) => format!(" (the model peaks at {v:.3} near F_Y {x:.2})"),
            None => String::new(),
        };
        notes.push(format!(
            "{}: fit {:.3} at F_Y {fy_min:.2} -> {:.3} at F_Y {fy_max:.2}: {} in value, magnitude {}; model {:.3} -> {:.3}{extremum}; \
identified - model: mean |diff| {:.3} ({:.1} %), max {:.3} ({:.1} %)",
            t.name,
            t.fit_at_min_fy,
            t.fit_at_max_fy,
            match t.slope_sign {
                1 => "grows",
                -1 => "falls",
                _ => "flat",
            },
            if t.grows_in_magnitude { "grows" } else { "does not grow" },
            t.model_at_min_fy,
            t.model_at_max_fy,
            t.mean_abs_difference,
            100.0 * t.mean_abs_relative_difference,
            t.max_abs_difference,
            100.0 * t.max_abs_relative_difference
        ));
    }
    notes.push(format!(
        "Direct coefficients Kxx, Kyy, Dxx, Dyy {} with F_Y; in magnitude {} grow and {} do not.",
        if direct { "all grow" } else { "do NOT all grow" },
        if growing.is_empty() { "none".into() } else { growing.join(", ") },
        if not_growing.is_empty() { "none".into() } else { not_growing.join(", ") }
    ));
    for (label, dmax, half, full) in &growth {
        notes.push(format!("{label}: mean |RV| over the eight is {:.1} % at d = {:.3} and {:.1} % at d = {dmax:.3}.", 100.0 * half, 0.5 * dmax, 100.0 * full));
    }
    let verdict = |v: Verdict| match v {
        Verdict::Larger => "larger at the high F_Y (as the paper found)",
        Verdict::Indistinguishable => "indistinguishable (within two standard errors) between the two F_Y",
        Verdict::Smaller => "smaller at the high F_Y (the paper found it larger)",
    };
    for (what, at) in [(format!("the common d = {common_d:.3}"), &at_common), ("d = 0.05".to_string(), &at_005)] {
        notes.push(format!(
            "At {what}{}: mean |RV| {} at {} against {} at {}: {}; |RV| larger at the high F_Y for {} of 8 coefficients.",
            if at.extrapolated_low_fy || at.extrapolated_high_fy { " (extrapolated beyond a sweep's largest d)" } else { "" },
            pct_se(at.mean_abs_rv_high_fy, at.mean_abs_rv_high_fy_se),
            amplitude.high.label,
            pct_se(at.mean_abs_rv_low_fy, at.mean_abs_rv_low_fy_se),
            amplitude.low.label,
            verdict(at.verdict),
            at.larger_at_high_fy
        ));
    }
    notes.push(format!(
        "Most sensitive at d = {common_d:.3}: {} (RV {} at {}); per load parameter: {}. The paper found KXY and DYX most sensitive on its rig.",
        best.0,
        pct(best.1),
        best.2,
        per_fy.iter().map(|(l, n, rv)| format!("{l}: {n} {}", pct(*rv))).collect::<Vec<_>>().join(", ")
    ));
    Ok(Findings {
        convention: CONVENTION.into(),
        coefficients_grow_with_fy: trends,
        direct_coefficients_grow_with_fy: direct,
        growing_in_magnitude: growing,
        not_growing_in_magnitude: not_growing,
        rv_grows_with_d: grows,
        mean_abs_rv_growth: growth,
        common_d,
        rv_at_common_d: at_common,
        rv_at_d_005: at_005,
        rv_faster_at_high_fy: faster,
        most_sensitive: best.0,
        most_sensitive_rv: best.1,
        most_sensitive_at: best.2,
        most_sensitive_per_fy: per_fy,
        notes,
    })
}

/// Both studies and their findings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Campaign {
    pub rig: String,
    /// The film model behind both the simulation and the "model" coefficients.
    pub film_model: String,
    pub frame: String,
    pub convention: String,
    pub config: CampaignConfig,
    pub load_study: LoadStudy,
    pub amplitude_study: AmplitudeStudy,
    pub findings: Findings,
}

/// Runs the load study, then the amplitude study, and checks the findings.
pub fn run_campaign(rig: &RigConfig, cfg: &CampaignConfig, progress: &mut dyn FnMut(Progress)) -> Result<Campaign, IdentificationError> {
    cfg.validate()?;
    rig.validate()?;
    let total = total_records(cfg);
    let load_study = run_load_study_from(rig, cfg, 0, total, progress)?;
    let amplitude_study = run_amplitude_study_from(rig, cfg, cfg.load.points.len(), total, progress)?;
    let findings = findings(&load_study, &amplitude_study)?;
    let film_model = match rig.film {
        FilmModelConfig::Short => "Ocvirk short-bearing pi-film (closed form)".to_string(),
        FilmModelConfig::Finite { n_theta, n_z, tabulate } => {
            format!("finite-difference Reynolds film, {n_theta} x {n_z} grid per pad{}", if tabulate { " (the rig integrates its force map)" } else { "" })
        }
    };
    Ok(Campaign {
        rig: rig.name.clone(),
        film_model,
        frame: pipeline::FRAME.into(),
        convention: CONVENTION.into(),
        config: cfg.clone(),
        load_study,
        amplitude_study,
        findings,
    })
}
