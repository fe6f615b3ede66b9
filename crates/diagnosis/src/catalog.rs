//! The catalog: each candidate extends the baseline linear K-C model by one named effect and
//! is fitted on the training blocks only; it returns its residual on every row so held-out
//! blocks can be scored.
//!
//! | name | extension | parameters (contract keys) |
//! |---|---|---|
//! | `fluid_inertia` | `F = -(K r + C r' + M_a r'')`, isotropic `M_a > 0` | `added_mass_kg` |
//! | `support_friction` | eq. 2 force also holds the supports' Coulomb friction, `+F_c X'/|X'|` | `friction_force_n` |
//! | `amplitude_nonlinearity` | quadratic and cubic displacement terms, displacement x velocity terms, per axis | `cubic_stiffness_n_per_m3` (vertical, `F_y = -k3 y^3`) |
//! | `synchronous_runout` | the bearing probes read `r + rho`, `rho` a forward 1X orbit with no force cause | `runout_amplitude_m`, `runout_phase_deg` |
//! | `thermal_drift` | every coefficient follows the measured temperature through the viscosity: `theta_ij (1 + beta s_ij dT)`, `s_ij = dln coef / dln mu` of the film model at the measured point | `viscosity_temperature_slope_per_c` (`beta = dln mu / dT`) |
//! | `channel_delay` | one channel (bearing or frame probe, exciter force) lags by `tau` beyond the multiplex schedule; the record is re-conditioned with it advanced | `channel`, `delay_s` |
//! | `probe_saturation` | a displacement probe clips (flat-topped codes); its clipped samples are rebuilt from its partner (the other bearing end; for a frame probe, the bearing probes through the fixed journal) | `channel`, `saturation_limit_m` |
//!
//! The catalog names are the `Cause` names; the three verdicts are `none`, `unexplained` and
//! `insufficient_data` (see [`crate::verdict`]).

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector, Vector2};
use oilfilm_identification::conditioning::deskew::FractionalDelay;
use oilfilm_identification::conditioning::{RawRecord, RawUnits};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::ChannelId;
use oilfilm_physics::film::Running;
use oilfilm_physics::operating_point::{self, EquilibriumOptions};
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

use crate::evidence::{Prepared, Series};
use crate::least_squares::{self, Fit};
use crate::DiagnosisError;

/// Every name the output's `cause` can take.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Cause {
    AmplitudeNonlinearity,
    FluidInertia,
    ChannelDelay,
    ThermalDrift,
    SynchronousRunout,
    ProbeSaturation,
    SupportFriction,
    /// The linear model is adequate: no candidate earns its extra parameters.
    None,
    /// The linear model is inadequate and no candidate explains the residual.
    Unexplained,
    /// Too short, too poorly excited or too noisy to decide.
    InsufficientData,
}

impl Cause {
    /// The seven effects of the catalog, in the order they are tried.
    pub const CATALOG: [Cause; 7] = [
        Cause::AmplitudeNonlinearity,
        Cause::FluidInertia,
        Cause::ChannelDelay,
        Cause::ThermalDrift,
        Cause::SynchronousRunout,
        Cause::ProbeSaturation,
        Cause::SupportFriction,
    ];

    /// The exact name used in output.
    pub fn name(self) -> &'static str {
        match self {
            Cause::AmplitudeNonlinearity => "amplitude_nonlinearity",
            Cause::FluidInertia => "fluid_inertia",
            Cause::ChannelDelay => "channel_delay",
            Cause::ThermalDrift => "thermal_drift",
            Cause::SynchronousRunout => "synchronous_runout",
            Cause::ProbeSaturation => "probe_saturation",
            Cause::SupportFriction => "support_friction",
            Cause::None => "none",
            Cause::Unexplained => "unexplained",
            Cause::InsufficientData => "insufficient_data",
        }
    }

    /// Parses an output name.
    pub fn parse(name: &str) -> Option<Cause> {
        Self::CATALOG.into_iter().chain([Cause::None, Cause::Unexplained, Cause::InsufficientData]).find(|c| c.name() == name)
    }
}

impl std::fmt::Display for Cause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A model fitted on some rows.
#[derive(Debug, Clone)]
pub struct Fitted {
    /// Target minus prediction on every row (the target may be the corrected record).
    pub residual: DVector<f64>,
    /// The K-C part, in [`Prepared::kc_design`]'s column order (minus K and C).
    pub kc: [f64; 8],
    /// Named parameters (contract keys) and their standard errors.
    pub parameters: BTreeMap<String, Value>,
    pub standard_errors: BTreeMap<String, f64>,
    /// Parameters beyond the baseline's eight.
    pub extra_parameters: usize,
    /// `Err(why)` when the fitted parameters are unphysical for the effect (negative added
    /// mass, negative friction): the candidate cannot be the cause whatever it gains.
    pub physical: Result<(), String>,
}

/// A catalog entry ready to be fitted on any training rows.
pub trait Candidate {
    fn cause(&self) -> Cause;
    fn fit(&self, p: &Prepared, train: &[bool]) -> Result<Fitted, DiagnosisError>;
}

fn kc_of(theta: &DVector<f64>) -> [f64; 8] {
    std::array::from_fn(|k| theta[k])
}

fn residual_of(design: &DMatrix<f64>, target: &DVector<f64>, theta: &DVector<f64>) -> DVector<f64> {
    target - least_squares::predict(design, theta)
}

/// Puts `values` into column `col` of one axis' rows (`axis` 0: f_x, 1: f_y), detrended.
fn set_axis_column(p: &Prepared, m: &mut DMatrix<f64>, col: usize, axis: usize, values: &[f64]) {
    let n = p.len();
    let mut v = values.to_vec();
    p.detrend(&mut v);
    m.view_mut((axis * n, col), (n, 1)).copy_from_slice(&v);
}

/// Per-block mean removed (the dynamic part about the block's equilibrium).
fn about_block_mean(p: &Prepared, v: &[f64]) -> Vec<f64> {
    let mut out = v.to_vec();
    for b in &p.blocks {
        let seg = &mut out[b.clone()];
        let m = seg.iter().sum::<f64>() / seg.len() as f64;
        seg.iter_mut().for_each(|x| *x -= m);
    }
    out
}

/// The K-C model plus one regressor shared by both force axes (`columns[0]` on the `f_x`
/// rows, `columns[1]` on the `f_y` rows), whose coefficient is the parameter `key`; it must
/// come out positive, else `negative(value)` says why it is unphysical.
fn fit_shared_column(
    p: &Prepared,
    train: &[bool],
    what: &str,
    columns: [&[f64]; 2],
    key: &str,
    negative: impl Fn(f64) -> String,
) -> Result<Fitted, DiagnosisError> {
    let s = &p.series;
    let mut design = p.kc_design(s, 1);
    p.set_column(&mut design, 8, columns[0], columns[1]);
    let target = p.target(s, 0.0);
    let fit = least_squares::solve(&design, &target, train, what)?;
    let value = fit.theta[8];
    Ok(Fitted {
        residual: residual_of(&design, &target, &fit.theta),
        kc: kc_of(&fit.theta),
        parameters: BTreeMap::from([(key.to_string(), json!(value))]),
        standard_errors: BTreeMap::from([(key.to_string(), fit.standard_errors[8])]),
        extra_parameters: 1,
        physical: if value > 0.0 { Ok(()) } else { Err(negative(value)) },
    })
}

/// The baseline: the linear K-C model of Zhou et al. (2004), eq. 3.
pub struct Baseline;

impl Baseline {
    pub fn fit_series(p: &Prepared, s: &Series, train: &[bool]) -> Result<(Fit, DVector<f64>), DiagnosisError> {
        let design = p.kc_design(s, 0);
        let target = p.target(s, 0.0);
        let fit = least_squares::solve(&design, &target, train, "baseline K-C")?;
        let residual = residual_of(&design, &target, &fit.theta);
        Ok((fit, residual))
    }

    pub fn fit(p: &Prepared, train: &[bool]) -> Result<Fitted, DiagnosisError> {
        let (fit, residual) = Self::fit_series(p, &p.series, train)?;
        Ok(Fitted {
            residual,
            kc: kc_of(&fit.theta),
            parameters: BTreeMap::new(),
            standard_errors: BTreeMap::new(),
            extra_parameters: 0,
            physical: Ok(()),
        })
    }
}

/// `fluid_inertia`: an isotropic added mass.
pub struct FluidInertia;

impl Candidate for FluidInertia {
    fn cause(&self) -> Cause {
        Cause::FluidInertia
    }

    fn fit(&self, p: &Prepared, train: &[bool]) -> Result<Fitted, DiagnosisError> {
        let s = &p.series;
        let nx: Vec<f64> = s.ax_m_s2.iter().map(|a| -a).collect();
        let ny: Vec<f64> = s.ay_m_s2.iter().map(|a| -a).collect();
        fit_shared_column(p, train, "fluid_inertia (K-C + isotropic added mass)", [&nx, &ny], "added_mass_kg", |m| {
            format!("negative added mass ({m:.3} kg): fluid inertia only adds mass")
        })
    }
}

/// `support_friction`: Coulomb friction of the housing's supports, seen in eq. 2's force.
pub struct SupportFriction;

/// The friction regressor's smallest smoothing velocity, as a fraction of the RMS speed.
const FRICTION_SMOOTHING: f64 = 0.02;

impl Candidate for SupportFriction {
    fn cause(&self) -> Cause {
        Cause::SupportFriction
    }

    fn fit(&self, p: &Prepared, train: &[bool]) -> Result<Fitted, DiagnosisError> {
        let s = &p.series;
        // The housing's velocity is X' = J' - r' = -r' with the journal fixed in space. It is
        // taken from the bearing probes' r', the very signal the baseline regresses on: a
        // velocity from the frame probes would carry independent sensor noise and act as an
        // instrumental variable, "explaining" the baseline's errors-in-variables bias with a
        // friction that is not there. The frame probes do give the noise level: with the
        // journal fixed, r' + X' is the two measurements' noise alone.
        let vx: Vec<f64> = s.vx_m_s.iter().map(|v| -v).collect();
        let vy: Vec<f64> = s.vy_m_s.iter().map(|v| -v).collect();
        let disagreement = |a: &[f64], b: &[f64]| -> f64 {
            let d: Vec<f64> = a.iter().zip(b).map(|(a, b)| b - a).collect();
            let d = about_block_mean(p, &d);
            (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64 / 2.0).sqrt()
        };
        let sigma = 0.5 * (disagreement(&vx, &s.housing_vx_m_s) + disagreement(&vy, &s.housing_vy_m_s));
        let rms = (vx.iter().zip(&vy).map(|(a, b)| a * a + b * b).sum::<f64>() / vx.len() as f64).sqrt();
        // E[sign(v) | measured v] for Gaussian noise of that level (regression calibration):
        // a plain sign of the noisy velocity would bias the friction force low.
        let width = (std::f64::consts::SQRT_2 * sigma).max(FRICTION_SMOOTHING * rms).max(f64::MIN_POSITIVE);
        let (fvx, fvy) = (&p.full_motion[2], &p.full_motion[3]);
        let (mut ux, mut uy) = (Vec::with_capacity(fvx.len()), Vec::with_capacity(fvx.len()));
        for (a, b) in fvx.iter().zip(fvy) {
            let (a, b) = (-a, -b);
            let speed = (a * a + b * b).sqrt();
            let g = if speed > 0.0 { crate::statistics::erf(speed / width) / speed } else { 0.0 };
            ux.push(a * g);
            uy.push(b * g);
        }
        // Through the conditioning's low-pass, like the eq. 2 force the friction hides in.
        let (ux, uy) = (p.filtered_picks(&ux)?, p.filtered_picks(&uy)?);
        fit_shared_column(p, train, "support_friction (K-C + Coulomb friction)", [&ux, &uy], "friction_force_n", |f| {
            format!("negative friction force ({f:.3} N): friction opposes motion")
        })
    }
}

/// `amplitude_nonlinearity`: polynomial film force about the equilibrium.
pub struct AmplitudeNonlinearity;

/// Nonlinear terms per axis.
const NONLINEAR_TERMS: usize = 9;

impl Candidate for AmplitudeNonlinearity {
    fn cause(&self) -> Cause {
        Cause::AmplitudeNonlinearity
    }

    fn fit(&self, p: &Prepared, train: &[bool]) -> Result<Fitted, DiagnosisError> {
        let s = &p.series;
        // Terms formed at full rate about the record's mean position, then low-passed like
        // the force: a cube of an 80 Hz line has a 240 Hz part the force no longer has.
        let [fx, fy, fvx, fvy] = &p.full_motion;
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let (mx, my) = (mean(fx), mean(fy));
        let x: Vec<f64> = fx.iter().map(|v| v - mx).collect();
        let y: Vec<f64> = fy.iter().map(|v| v - my).collect();
        let term = |k: usize, i: usize| -> f64 {
            match k {
                0 => x[i] * x[i],
                1 => x[i] * y[i],
                2 => y[i] * y[i],
                3 => x[i] * x[i] * x[i],
                4 => y[i] * y[i] * y[i],
                5 => x[i] * fvx[i],
                6 => y[i] * fvy[i],
                7 => x[i] * fvy[i],
                _ => y[i] * fvx[i],
            }
        };
        let mut design = p.kc_design(s, 2 * NONLINEAR_TERMS);
        for k in 0..NONLINEAR_TERMS {
            let full: Vec<f64> = (0..x.len()).map(|i| term(k, i)).collect();
            let v = p.filtered_picks(&full)?;
            for axis in 0..2 {
                set_axis_column(p, &mut design, 8 + axis * NONLINEAR_TERMS + k, axis, &v);
            }
        }
        let target = p.target(s, 0.0);
        let fit = least_squares::solve(&design, &target, train, "amplitude_nonlinearity (K-C + polynomial film)")?;
        // F_y = -k3 y^3: the y^3 column of the f_y rows.
        let col_y3 = 8 + NONLINEAR_TERMS + 4;
        let col_x3 = 8 + 3;
        let k3 = -fit.theta[col_y3];
        Ok(Fitted {
            residual: residual_of(&design, &target, &fit.theta),
            kc: kc_of(&fit.theta),
            parameters: BTreeMap::from([
                ("cubic_stiffness_n_per_m3".to_string(), json!(k3)),
                ("cubic_stiffness_xx_n_per_m3".to_string(), json!(-fit.theta[col_x3])),
            ]),
            standard_errors: BTreeMap::from([
                ("cubic_stiffness_n_per_m3".to_string(), fit.standard_errors[col_y3]),
                ("cubic_stiffness_xx_n_per_m3".to_string(), fit.standard_errors[col_x3]),
            ]),
            extra_parameters: 2 * NONLINEAR_TERMS,
            physical: Ok(()),
        })
    }
}

/// `synchronous_runout`: 1X in the bearing probes' readings with no force cause. The probes
/// read `r + rho`, so the film force is `-(K (r_m - rho) + C (r_m' - rho'))`: beside the
/// K-C terms on the measured motion, a 1X force `(K + i W C) rho` per axis (four linear
/// parameters, cos and sin per axis). The runout is then `rho = (K + i W C)^-1` times it.
pub struct SynchronousRunout;

impl Candidate for SynchronousRunout {
    fn cause(&self) -> Cause {
        Cause::SynchronousRunout
    }

    fn fit(&self, p: &Prepared, train: &[bool]) -> Result<Fitted, DiagnosisError> {
        let s = &p.series;
        let w = p.speed_rpm * std::f64::consts::PI / 30.0;
        let (c, sn): (Vec<f64>, Vec<f64>) = s.t_s.iter().map(|&t| ((w * t).cos(), (w * t).sin())).unzip();
        let mut design = p.kc_design(s, 4);
        for axis in 0..2 {
            set_axis_column(p, &mut design, 8 + 2 * axis, axis, &c);
            set_axis_column(p, &mut design, 9 + 2 * axis, axis, &sn);
        }
        let target = p.target(s, 0.0);
        let fit = least_squares::solve(&design, &target, train, "synchronous_runout (K-C + 1X force of the runout)")?;
        let th = &fit.theta;
        // 1X force phasors (F = Re(P e^{i W t}): cos -> Re, sin -> -Im) per axis.
        use nalgebra::{Complex, Matrix2 as M2, Vector2 as V2};
        let f1x = V2::new(Complex::new(th[8], -th[9]), Complex::new(th[10], -th[11]));
        // Regression on (r - rho) has coefficients theta = -(K, C): F_runout = +(K + iWC) rho
        // with K = -theta_r, C = -theta_v... i.e. the runout force is -(theta_r + i W theta_v) rho.
        let h = M2::new(
            Complex::new(th[0], w * th[2]),
            Complex::new(th[1], w * th[3]),
            Complex::new(th[4], w * th[6]),
            Complex::new(th[5], w * th[7]),
        );
        let rho = h.try_inverse().map(|hi| -(hi * f1x));
        let (amplitude, phase) = match rho {
            // Forward circle: x = a cos(Wt + phi), y = a sin(Wt + phi): rho_x = a e^{i phi}, rho_y = -i a e^{i phi}.
            Some(r) => {
                let a = 0.5 * (r[0].norm() + r[1].norm());
                (a, r[0].arg().to_degrees())
            }
            None => (f64::NAN, f64::NAN),
        };
        // SE of the amplitude from the 1X force's SE through |H|.
        let f_se = 0.5 * (fit.standard_errors[8] + fit.standard_errors[9] + fit.standard_errors[10] + fit.standard_errors[11]) / 2.0;
        let h_norm = (0.5 * (h[(0, 0)].norm() + h[(1, 1)].norm())).max(f64::MIN_POSITIVE);
        Ok(Fitted {
            residual: residual_of(&design, &target, &fit.theta),
            kc: kc_of(&fit.theta),
            parameters: BTreeMap::from([
                ("runout_amplitude_m".to_string(), json!(amplitude)),
                ("runout_phase_deg".to_string(), json!(phase)),
            ]),
            standard_errors: BTreeMap::from([("runout_amplitude_m".to_string(), f_se / h_norm)]),
            extra_parameters: 4,
            physical: Ok(()),
        })
    }
}

/// Alternations between the K-C part and a bilinear extension.
const ALTERNATIONS: usize = 5;

/// `thermal_drift`: the coefficients follow the measured temperature through the viscosity.
pub struct ThermalDrift {
    /// `dln |coef| / dln mu` of the film model at the measured point, per K-C column.
    sensitivity: [f64; 8],
    /// Measured temperature minus its record mean, per decimated sample.
    delta_t_c: Vec<f64>,
}

/// Sensitivities beyond this magnitude (near-zero cross terms) are clamped.
const MAX_SENSITIVITY: f64 = 5.0;
/// A record whose temperature moves less than this (standard deviation, C) cannot show drift.
pub const MIN_TEMPERATURE_SPREAD_C: f64 = 0.05;

impl ThermalDrift {
    /// `Err(why)` when the record's temperature is too steady to show drift.
    pub fn new(p: &Prepared, rig: &RigConfig) -> Result<Result<Self, String>, DiagnosisError> {
        let t = &p.series.temperature_c;
        let mean = p.mean_temperature_c;
        let sd = (t.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / t.len() as f64).sqrt();
        if sd < MIN_TEMPERATURE_SPREAD_C {
            return Ok(Err(format!(
                "the bearing temperature is steady ({sd:.3} C standard deviation, below {MIN_TEMPERATURE_SPREAD_C} C): a thermal drift can neither act nor be seen"
            )));
        }
        let viscosity = rig.oil.viscosity_pa_s(mean)?;
        let load = Vector2::new(-p.static_force_n[0], -p.static_force_n[1]);
        let coefficients = |mu: f64| -> Result<[f64; 8], DiagnosisError> {
            let mut film = rig.film()?;
            let running = Running::from_rpm(p.speed_rpm, mu);
            let op = operating_point::solve(film.as_mut(), &running, load, &EquilibriumOptions::default())?;
            let (k, c) = (op.coefficients.stiffness_n_m, op.coefficients.damping_n_s_m);
            Ok([k[(0, 0)], k[(0, 1)], c[(0, 0)], c[(0, 1)], k[(1, 0)], k[(1, 1)], c[(1, 0)], c[(1, 1)]])
        };
        let eps = 0.02;
        let (lo, mid, hi) = (coefficients(viscosity * (1.0 - eps))?, coefficients(viscosity)?, coefficients(viscosity * (1.0 + eps))?);
        let sensitivity = std::array::from_fn(|k| {
            let s = (hi[k] - lo[k]) / (2.0 * eps * mid[k]);
            if s.is_finite() {
                s.clamp(-MAX_SENSITIVITY, MAX_SENSITIVITY)
            } else {
                0.0
            }
        });
        let delta_t_c = t.iter().map(|v| v - mean).collect();
        Ok(Ok(Self { sensitivity, delta_t_c }))
    }

    /// The design at slope `beta` (columns scaled by `1 + beta s dT`) and the slope column
    /// for a K-C part `theta`.
    fn designs(&self, p: &Prepared, beta: f64, theta: Option<&DVector<f64>>) -> DMatrix<f64> {
        let s = &p.series;
        let n = p.len();
        let mut design = DMatrix::zeros(4 * n, 9);
        // The coefficients act on the motion about the (drifting) equilibrium: detrended per
        // block before the temperature scales it, or the equilibrium's own drift times dT
        // would pose as a coefficient change.
        let src: [Vec<f64>; 4] = [&s.x_m, &s.y_m, &s.vx_m_s, &s.vy_m_s].map(|v| {
            let mut v = v.clone();
            p.detrend(&mut v);
            v
        });
        let mut slope = [vec![0.0; n], vec![0.0; n]];
        for (axis, slope_axis) in slope.iter_mut().enumerate() {
            for (j, col) in src.iter().enumerate() {
                let k = 4 * axis + j;
                let sk = self.sensitivity[k];
                let scaled: Vec<f64> = col.iter().zip(&self.delta_t_c).map(|(v, dt)| v * (1.0 + beta * sk * dt)).collect();
                set_axis_column(p, &mut design, k, axis, &scaled);
                if let Some(th) = theta {
                    for ((acc, v), dt) in slope_axis.iter_mut().zip(col).zip(&self.delta_t_c) {
                        *acc += th[k] * sk * dt * v;
                    }
                }
            }
        }
        p.set_column(&mut design, 8, &slope[0], &slope[1]);
        design
    }
}

impl Candidate for ThermalDrift {
    fn cause(&self) -> Cause {
        Cause::ThermalDrift
    }

    fn fit(&self, p: &Prepared, train: &[bool]) -> Result<Fitted, DiagnosisError> {
        let target = p.target(&p.series, 0.0);
        let mut beta = 0.0;
        let mut last = None;
        for _ in 0..ALTERNATIONS {
            let plain = self.designs(p, beta, None);
            let theta0 = least_squares::solve(&plain.columns(0, 8).into_owned(), &target, train, "thermal_drift (K-C step)")?.theta;
            let design = self.designs(p, beta, Some(&theta0));
            let fit = least_squares::solve(&design, &target, train, "thermal_drift (K-C + viscosity slope)")?;
            beta += fit.theta[8];
            last = Some(fit);
        }
        let Some(fit) = last else {
            return Err(DiagnosisError::invalid("alternations", "must be at least 1"));
        };
        let plain = self.designs(p, beta, None).columns(0, 8).into_owned();
        let theta = least_squares::solve(&plain, &target, train, "thermal_drift (final K-C)")?.theta;
        let spread = self.delta_t_c.iter().copied().fold(f64::NEG_INFINITY, f64::max) - self.delta_t_c.iter().copied().fold(f64::INFINITY, f64::min);
        Ok(Fitted {
            residual: residual_of(&plain, &target, &theta),
            kc: kc_of(&theta),
            parameters: BTreeMap::from([
                ("viscosity_temperature_slope_per_c".to_string(), json!(beta)),
                ("temperature_change_c".to_string(), json!(spread)),
            ]),
            standard_errors: BTreeMap::from([("viscosity_temperature_slope_per_c".to_string(), fit.standard_errors[8])]),
            extra_parameters: 1,
            physical: if beta < 0.0 { Ok(()) } else { Err(format!("viscosity rising with temperature (slope {beta:.4}/C): no oil does that")) },
        })
    }
}

/// Channels a delay is looked for on (the ones the film force and motion are made of).
pub const DELAY_CHANNELS: [ChannelId; 8] =
    [ChannelId::ProbeAX, ChannelId::ProbeAY, ChannelId::ProbeBX, ChannelId::ProbeBY, ChannelId::FrameX, ChannelId::FrameY, ChannelId::F1, ChannelId::F2];
/// Largest delay searched, s (the quadratic model in the delay holds well below this at the
/// excitation band's top).
pub const MAX_DELAY_S: f64 = 1.0e-3;

/// `channel_delay`: one channel lags beyond the multiplex schedule.
pub struct ChannelDelay {
    /// Per channel: first and second derivative of the series with respect to advancing the
    /// channel by `tau` (finite differences of re-conditioned records).
    derivatives: Vec<(ChannelId, Series, Series)>,
}

/// Advances one raw column by `tau` seconds (undoing a lag of `tau`).
fn advanced(raw: &RawRecord, channel: ChannelId, tau_s: f64, taps: usize) -> Result<RawRecord, DiagnosisError> {
    let mut out = raw.clone();
    let k = raw
        .channels
        .iter()
        .position(|&c| c == channel)
        .ok_or_else(|| DiagnosisError::bad_input(format!("channel `{channel}`"), "not in the record"))?;
    out.columns[k] = FractionalDelay::new(-tau_s * raw.sample_rate_hz, taps)?.apply(&raw.columns[k])?;
    Ok(out)
}

impl ChannelDelay {
    pub fn new(p: &Prepared) -> Result<Self, DiagnosisError> {
        let delta = 0.5 / p.raw.sample_rate_hz;
        let taps = p.conditioning.deskew_taps.max(4);
        let mut derivatives = Vec::new();
        for ch in DELAY_CHANNELS {
            if !p.raw.channels.contains(&ch) {
                continue;
            }
            let plus = p.recondition(&advanced(&p.raw, ch, delta, taps)?)?;
            let minus = p.recondition(&advanced(&p.raw, ch, -delta, taps)?)?;
            let d1 = Series::difference(&plus, &minus, 1.0 / (2.0 * delta));
            let d2 = Series::combine(&plus, &minus, 1.0, &p.series, -2.0).scaled(1.0 / (delta * delta));
            derivatives.push((ch, d1, d2));
        }
        Ok(Self { derivatives })
    }

    /// Fits the delay of one channel by Gauss-Newton on the quadratic series model.
    fn fit_channel(&self, p: &Prepared, k: usize, train: &[bool]) -> Result<(f64, f64, Fit, DVector<f64>), DiagnosisError> {
        let (_, d1, d2) = &self.derivatives[k];
        let mut tau: f64 = 0.0;
        let mut se = f64::NAN;
        for _ in 0..6 {
            let s = Series::combine(&p.series, d1, tau, d2, 0.5 * tau * tau);
            let ds = Series::combine(d1, d2, tau, d2, 0.0);
            let mut design = p.kc_design(&s, 1);
            let target = p.target(&s, 0.0);
            let theta0 = least_squares::solve(&design.columns(0, 8).into_owned(), &target, train, "channel_delay (K-C step)")?.theta;
            // T(tau) ~ Phi theta + dtau (dPhi theta - dT).
            let d_design = p.kc_design(&ds, 0);
            let d_target = p.target(&ds, 0.0);
            let g = d_design * theta0.rows(0, 8) - d_target;
            design.set_column(8, &g);
            let fit = least_squares::solve(&design, &target, train, "channel_delay (K-C + delay)")?;
            let step = fit.theta[8];
            se = fit.standard_errors[8];
            tau = (tau + step).clamp(-MAX_DELAY_S, MAX_DELAY_S);
            if step.abs() < 1e-9 {
                break;
            }
        }
        let s = Series::combine(&p.series, d1, tau, d2, 0.5 * tau * tau);
        let (fit, residual) = Baseline::fit_series(p, &s, train)?;
        Ok((tau, se, fit, residual))
    }
}

impl Candidate for ChannelDelay {
    fn cause(&self) -> Cause {
        Cause::ChannelDelay
    }

    fn fit(&self, p: &Prepared, train: &[bool]) -> Result<Fitted, DiagnosisError> {
        let mut best: Option<(usize, f64, f64, Fit, DVector<f64>)> = None;
        for k in 0..self.derivatives.len() {
            let (tau, se, fit, residual) = self.fit_channel(p, k, train)?;
            if best.as_ref().is_none_or(|b| fit.sse < b.3.sse) {
                best = Some((k, tau, se, fit, residual));
            }
        }
        let Some((k, tau, se, fit, residual)) = best else {
            return Err(DiagnosisError::bad_input("record", "none of the channels a delay is looked for on is in the record"));
        };
        let channel = self.derivatives[k].0;
        Ok(Fitted {
            residual,
            kc: kc_of(&fit.theta),
            parameters: BTreeMap::from([("channel".to_string(), json!(channel.name())), ("delay_s".to_string(), json!(tau))]),
            standard_errors: BTreeMap::from([("delay_s".to_string(), se)]),
            // The delay and the choice among the channels.
            extra_parameters: 2,
            physical: if tau > 0.0 { Ok(()) } else { Err(format!("`{channel}` would lead by {:.1} us: a channel can only lag", -tau * 1e6)) },
        })
    }
}

/// `probe_saturation`: a displacement probe with flat-topped readings.
pub struct ProbeSaturation {
    channel: ChannelId,
    /// Full-rate samples at the clip level.
    clipped: Vec<bool>,
    /// The clip level in the record's units and in metres from the calibrated zero.
    limit_m: f64,
    resolution_m: f64,
    count: usize,
}

/// Samples at one extreme code that make a probe count as clipped (and at least this
/// fraction of the record).
pub const MIN_CLIPPED_SAMPLES: usize = 10;
pub const MIN_CLIPPED_FRACTION: f64 = 2.0e-4;

impl ProbeSaturation {
    /// Looks for flat tops on every displacement probe; `Err(why)` when none has them.
    pub fn new(p: &Prepared) -> Result<Result<Self, String>, DiagnosisError> {
        let raw = &p.raw;
        let n = raw.len();
        let mut best: Option<Self> = None;
        for (k, &ch) in raw.channels.iter().enumerate() {
            if !ch.is_displacement_probe() {
                continue;
            }
            let cal = p.calibration.channel(ch)?;
            let unit_per_volt = 1.0 / cal.sensitivity_v_per_unit;
            let lsb_units = match raw.units {
                RawUnits::Volts => p.calibration.lsb_v(),
                RawUnits::Si => p.calibration.lsb_v() * unit_per_volt.abs(),
            };
            let col = &raw.columns[k];
            for high in [true, false] {
                let extreme = if high { col.iter().copied().fold(f64::NEG_INFINITY, f64::max) } else { col.iter().copied().fold(f64::INFINITY, f64::min) };
                let flags: Vec<bool> = col.iter().map(|v| (v - extreme).abs() <= 0.5 * lsb_units).collect();
                let count = flags.iter().filter(|f| **f).count();
                let runs = flags.windows(2).filter(|w| w[1] && !w[0]).count() + usize::from(flags.first() == Some(&true));
                if count < MIN_CLIPPED_SAMPLES || (count as f64) < MIN_CLIPPED_FRACTION * n as f64 || runs < 2 {
                    continue;
                }
                let si = match raw.units {
                    RawUnits::Volts => p.calibration.to_si(ch, extreme)?,
                    RawUnits::Si => extreme,
                };
                let zero = -cal.offset_v / cal.sensitivity_v_per_unit;
                let candidate = Self {
                    channel: ch,
                    clipped: flags,
                    limit_m: (si - zero).abs(),
                    resolution_m: p.calibration.lsb_v() * unit_per_volt.abs(),
                    count,
                };
                if best.as_ref().is_none_or(|b| count > b.count) {
                    best = Some(candidate);
                }
            }
        }
        Ok(best.ok_or_else(|| "no displacement probe shows flat-topped readings (a run of identical extreme codes)".to_string()))
    }

    /// The partner reading of the clipped channel, in the record's units, per full-rate sample.
    fn partner(&self, p: &Prepared) -> Result<Vec<f64>, DiagnosisError> {
        let raw = &p.raw;
        let si_of = |ch: ChannelId| -> Result<Vec<f64>, DiagnosisError> {
            let col = raw.column(ch).ok_or_else(|| DiagnosisError::bad_input(format!("channel `{ch}`"), "not in the record"))?;
            match raw.units {
                RawUnits::Si => Ok(col.to_vec()),
                RawUnits::Volts => col.iter().map(|&v| p.calibration.to_si(ch, v).map_err(DiagnosisError::from)).collect(),
            }
        };
        use ChannelId::*;
        let si: Vec<f64> = match self.channel {
            ProbeAX => si_of(ProbeBX)?,
            ProbeBX => si_of(ProbeAX)?,
            ProbeAY => si_of(ProbeBY)?,
            ProbeBY => si_of(ProbeAY)?,
            // Journal fixed in space: the housing is at minus the mean bearing reading.
            FrameX => si_of(ProbeAX)?.iter().zip(si_of(ProbeBX)?).map(|(a, b)| -0.5 * (a + b)).collect(),
            FrameY => si_of(ProbeAY)?.iter().zip(si_of(ProbeBY)?).map(|(a, b)| -0.5 * (a + b)).collect(),
            other => return Err(DiagnosisError::bad_input(format!("channel `{other}`"), "not a displacement probe")),
        };
        let cal = p.calibration.channel(self.channel)?;
        Ok(match raw.units {
            RawUnits::Si => si,
            RawUnits::Volts => si.iter().map(|v| cal.offset_v + cal.sensitivity_v_per_unit * v).collect(),
        })
    }
}

impl Candidate for ProbeSaturation {
    fn cause(&self) -> Cause {
        Cause::ProbeSaturation
    }

    fn fit(&self, p: &Prepared, train: &[bool]) -> Result<Fitted, DiagnosisError> {
        let partner = self.partner(p)?;
        let k = p
            .raw
            .channels
            .iter()
            .position(|&c| c == self.channel)
            .ok_or_else(|| DiagnosisError::bad_input(format!("channel `{}`", self.channel), "not in the record"))?;
        let col = &p.raw.columns[k];
        // Full-rate samples of the training blocks: between the first and last pick of each.
        let mut in_train = vec![false; col.len()];
        for b in &p.blocks {
            if train[b.start] {
                let (lo, hi) = (p.picks[b.start], p.picks[b.end - 1] + p.decimation);
                in_train[lo..hi.min(col.len())].iter_mut().for_each(|v| *v = true);
            }
        }
        let (mut sum, mut count) = (0.0, 0usize);
        for i in 0..col.len() {
            if in_train[i] && !self.clipped[i] {
                sum += col[i] - partner[i];
                count += 1;
            }
        }
        if count == 0 {
            return Err(DiagnosisError::bad_input(format!("channel `{}`", self.channel), "every training sample is clipped"));
        }
        let offset = sum / count as f64;
        let mut raw = p.raw.clone();
        for ((v, &clipped), &q) in raw.columns[k].iter_mut().zip(&self.clipped).zip(&partner) {
            if clipped {
                *v = q + offset;
            }
        }
        let s = p.recondition(&raw)?;
        let (fit, residual) = Baseline::fit_series(p, &s, train)?;
        Ok(Fitted {
            residual,
            kc: kc_of(&fit.theta),
            parameters: BTreeMap::from([
                ("channel".to_string(), json!(self.channel.name())),
                ("saturation_limit_m".to_string(), json!(self.limit_m)),
                ("clipped_samples".to_string(), json!(self.count)),
            ]),
            standard_errors: BTreeMap::from([("saturation_limit_m".to_string(), self.resolution_m)]),
            // The clip level; the rebuild's offset.
            extra_parameters: 2,
            physical: Ok(()),
        })
    }
}
