//! The simulation's own error, and the updated simulation. The rig file describes the bearing
//! as its operator knows it; what the operator does not know well — the effective clearance
//! (thermal growth, wear, the bore's shape), the effective viscosity (the film runs hotter or
//! cooler than the thermocouple), and which film theory describes this bearing — is fitted
//! here to the identified coefficients, and the updated simulation is judged on held-out data
//! against the nominal one.
//!
//! ## How
//! * **Theories**: the rig file's film, and the others the physics core has (finite-length
//!   Reynolds, plain 360 degree; finite-length, two axial grooves; Ocvirk's short bearing).
//! * **Clearance and viscosity** enter a theory's coefficients only through the Sommerfeld
//!   number `S = mu N L D / W (R/c)^2` and the scale `W / c`: `K = (W/c) K_bar(S)`,
//!   `C = (W / (c w)) C_bar(S)`. Each theory is solved once on a grid of `S` at the record's
//!   measured load vector; a fit is then a one-dimensional search over `S` with the scale
//!   `1/c` in closed form, and `mu` follows from `S` and `c`.
//! * **Fit**: each coefficient matrix's relative mismatch `|K_model - K| / |K|` (Frobenius),
//!   squared and summed for K and C; the theory that fits best is the update.
//! * **Held-out**: for each cross-validation block, the update is fitted to the coefficients
//!   identified without that block and predicts that block's motion; the nominal model
//!   predicts every block as it is. The prediction is the linear rig driven by the measured
//!   applied force (`F_exc + (f3 - m g) e_y = F_film + m X''`, journal fixed so `X = -r`):
//!   `r(w) = -(K + i w C - m w^2)^-1 F_app(w)`, computed by FFT over the record (zero-padded,
//!   so the response is causal, not circular). The NRMSE is the dynamic motion's, over the held-out
//!   samples, both axes.
//! * **Standard errors** of the fitted clearance and viscosity: the jackknife over the blocks.

use nalgebra::{Complex, Matrix2, Vector2};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::film::{FilmModelConfig, Running};
use oilfilm_physics::geometry::BearingKind;
use oilfilm_physics::operating_point::{self, EquilibriumOptions};
use rustfft::FftPlanner;
use serde::{Deserialize, Serialize};

use crate::catalog::{self, Context, Judged};
use crate::evidence::Prepared;
use crate::DiagnosisError;

/// Sommerfeld numbers tabulated per theory, as factors of the nominal one.
const S_GRID: [f64; 11] = [0.12, 0.18, 0.27, 0.4, 0.6, 0.8, 1.0, 1.3, 1.8, 2.7, 4.5];

/// One theory's fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TheoryFit {
    pub theory: String,
    pub clearance_m: f64,
    pub viscosity_pa_s: f64,
    /// `sqrt(e_K^2 + e_C^2)`, each the relative Frobenius mismatch of the matrix.
    pub coefficient_mismatch: f64,
}

/// The update of the film model and what it gains.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelUpdate {
    pub nominal_theory: String,
    pub nominal_clearance_m: f64,
    /// The oil law's viscosity at the record's mean bearing temperature.
    pub nominal_viscosity_pa_s: f64,
    pub theory: String,
    pub clearance_m: f64,
    pub clearance_se_m: f64,
    pub viscosity_pa_s: f64,
    pub viscosity_se_pa_s: f64,
    /// The temperature at which the oil law gives the fitted viscosity, minus the measured
    /// mean (`null` outside the law's range).
    pub temperature_offset_c: Option<f64>,
    /// Every theory tried on the whole record, best first.
    pub theories: Vec<TheoryFit>,
    /// Coefficients (crate frame): the nominal model's, the updated model's, the identified.
    pub nominal_stiffness_n_m: Matrix2<f64>,
    pub nominal_damping_n_s_m: Matrix2<f64>,
    pub updated_stiffness_n_m: Matrix2<f64>,
    pub updated_damping_n_s_m: Matrix2<f64>,
    pub identified_stiffness_n_m: Matrix2<f64>,
    pub identified_damping_n_s_m: Matrix2<f64>,
    /// The journal's static position relative to the bearing, m: measured (mean of the
    /// bearing probes), and the nominal and updated film models' equilibria under the measured
    /// static load (`null` where a model has none). The probes' zero is rarely known to the
    /// micrometre, so this is a check beside the fit, not part of it.
    pub measured_position_m: [f64; 2],
    pub nominal_position_m: Option<[f64; 2]>,
    pub updated_position_m: Option<[f64; 2]>,
    /// Held-out NRMSE of the predicted motion (both axes).
    pub nominal_heldout_nrmse: f64,
    pub updated_heldout_nrmse: f64,
    /// `nominal / updated`: how many times better the updated simulation predicts.
    pub improvement_factor: f64,
    /// The motion at the excitation lines (x then y, amplitude in m): measured, nominal and
    /// updated predictions, over the whole record.
    pub lines: Vec<LinePrediction>,
    pub how: String,
}

/// The motion at one excitation line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LinePrediction {
    pub frequency_hz: f64,
    pub measured_m: [f64; 2],
    pub nominal_m: [f64; 2],
    pub updated_m: [f64; 2],
    /// Whether each axis moves at this line at all (its amplitude is at least a tenth of the
    /// axis's largest line): ratios on an axis that is not excited mean nothing.
    pub excited: [bool; 2],
}

/// A theory tabulated over the Sommerfeld number.
struct Table {
    name: String,
    /// The theory's rig (film model and bearing kind), for its equilibrium.
    rig: RigConfig,
    /// ln S, and the dimensionless `K c / W` and `C c w / W` (row-major 2x2 each) there.
    ln_s: Vec<f64>,
    k: Vec<[f64; 4]>,
    c: Vec<[f64; 4]>,
}

struct Operating {
    load: Vector2<f64>,
    load_n: f64,
    omega: f64,
    /// `S / mu` at the nominal clearance: `N L D / W (R/c)^2`.
    s_per_mu: f64,
    clearance_m: f64,
}

fn theories(rig: &RigConfig) -> Vec<(String, RigConfig)> {
    let describe = |r: &RigConfig| -> String {
        match (&r.film, &r.bearing.kind) {
            (FilmModelConfig::Short, _) => "short bearing (Ocvirk pi-film)".to_string(),
            (FilmModelConfig::Finite { .. }, BearingKind::Plain) => "finite-length Reynolds, plain 360 deg".to_string(),
            (FilmModelConfig::Finite { .. }, BearingKind::TwoAxialGroove { groove_arc_deg, groove_centre_deg }) => {
                format!("finite-length Reynolds, two axial grooves ({groove_arc_deg} deg at {groove_centre_deg} deg)")
            }
        }
    };
    let mut out = vec![(describe(rig), rig.clone())];
    let grid = match rig.film {
        FilmModelConfig::Finite { n_theta, n_z, .. } => FilmModelConfig::Finite { n_theta, n_z, tabulate: false },
        FilmModelConfig::Short => FilmModelConfig::Finite { n_theta: 72, n_z: 8, tabulate: false },
    };
    let mut variants = Vec::new();
    let mut plain = rig.clone();
    plain.film = grid;
    plain.bearing.kind = BearingKind::Plain;
    variants.push(plain);
    let mut grooved = rig.clone();
    grooved.film = grid;
    grooved.bearing.kind = BearingKind::TwoAxialGroove { groove_arc_deg: 20.0, groove_centre_deg: 0.0 };
    variants.push(grooved);
    let mut short = rig.clone();
    short.film = FilmModelConfig::Short;
    variants.push(short);
    for v in variants {
        let name = describe(&v);
        if out.iter().all(|(n, _)| *n != name) {
            out.push((name, v));
        }
    }
    out
}

fn tabulate(name: String, rig: &RigConfig, op: &Operating, s_nominal: f64) -> Result<Table, DiagnosisError> {
    let mut film = rig.film()?;
    let c = op.clearance_m;
    let mut t = Table { name, rig: rig.clone(), ln_s: Vec::new(), k: Vec::new(), c: Vec::new() };
    for f in S_GRID {
        let s = f * s_nominal;
        let running = Running { omega_rad_s: op.omega, viscosity_pa_s: s / op.s_per_mu };
        let Ok(point) = operating_point::solve(film.as_mut(), &running, op.load, &EquilibriumOptions::default()) else {
            continue;
        };
        let (k, d) = (point.coefficients.stiffness_n_m, point.coefficients.damping_n_s_m);
        let kk = c / op.load_n;
        let cc = c * op.omega / op.load_n;
        t.ln_s.push(s.ln());
        t.k.push([k[(0, 0)] * kk, k[(0, 1)] * kk, k[(1, 0)] * kk, k[(1, 1)] * kk]);
        t.c.push([d[(0, 0)] * cc, d[(0, 1)] * cc, d[(1, 0)] * cc, d[(1, 1)] * cc]);
    }
    if t.ln_s.len() < 4 {
        return Err(DiagnosisError::bad_input("model update", format!("{}: the film has no equilibrium over most of the Sommerfeld range tried", t.name)));
    }
    Ok(t)
}

/// Catmull-Rom interpolation of a tabulated quantity at `x` (clamped to the table).
fn interpolate(xs: &[f64], ys: &[[f64; 4]], x: f64) -> [f64; 4] {
    let n = xs.len();
    let x = x.clamp(xs[0], xs[n - 1]);
    let i = (0..n - 1).find(|&i| x <= xs[i + 1]).unwrap_or(n - 2);
    let h = xs[i + 1] - xs[i];
    let u = (x - xs[i]) / h;
    std::array::from_fn(|j| {
        let y0 = ys[i][j];
        let y1 = ys[i + 1][j];
        let m0 = if i > 0 { (ys[i + 1][j] - ys[i - 1][j]) / (xs[i + 1] - xs[i - 1]) * h } else { y1 - y0 };
        let m1 = if i + 2 < n { (ys[i + 2][j] - ys[i][j]) / (xs[i + 2] - xs[i]) * h } else { y1 - y0 };
        let (u2, u3) = (u * u, u * u * u);
        (2.0 * u3 - 3.0 * u2 + 1.0) * y0 + (u3 - 2.0 * u2 + u) * m0 + (-2.0 * u3 + 3.0 * u2) * y1 + (u3 - u2) * m1
    })
}

/// The best clearance and viscosity of one theory for identified `(K, C)`: `(mismatch, c, mu)`.
fn fit_theory(t: &Table, op: &Operating, k_id: &Matrix2<f64>, c_id: &Matrix2<f64>) -> (f64, f64, f64) {
    let kid = [k_id[(0, 0)], k_id[(0, 1)], k_id[(1, 0)], k_id[(1, 1)]];
    let cid = [c_id[(0, 0)], c_id[(0, 1)], c_id[(1, 0)], c_id[(1, 1)]];
    let nk: f64 = kid.iter().map(|v| v * v).sum();
    let nc: f64 = cid.iter().map(|v| v * v).sum();
    // At a given S the model is a / c times the table's shape; a = 1/c in closed form.
    let objective = |ln_s: f64| -> (f64, f64) {
        let kb = interpolate(&t.ln_s, &t.k, ln_s);
        let cb = interpolate(&t.ln_s, &t.c, ln_s);
        let (w, om) = (op.load_n, op.omega);
        let mk: [f64; 4] = std::array::from_fn(|j| w * kb[j]);
        let mc: [f64; 4] = std::array::from_fn(|j| w * cb[j] / om);
        let num: f64 = (0..4).map(|j| mk[j] * kid[j] / nk + mc[j] * cid[j] / nc).sum();
        let den: f64 = (0..4).map(|j| mk[j] * mk[j] / nk + mc[j] * mc[j] / nc).sum();
        let a = (num / den).max(f64::MIN_POSITIVE);
        let ek: f64 = (0..4).map(|j| (a * mk[j] - kid[j]).powi(2)).sum::<f64>() / nk;
        let ec: f64 = (0..4).map(|j| (a * mc[j] - cid[j]).powi(2)).sum::<f64>() / nc;
        ((ek + ec).sqrt(), a)
    };
    // Coarse scan of the table's nodes and midpoints, then golden section around the best.
    let (lo, hi) = (t.ln_s[0], t.ln_s[t.ln_s.len() - 1]);
    let steps = 40;
    let mut best = (f64::INFINITY, lo);
    for i in 0..=steps {
        let x = lo + (hi - lo) * i as f64 / steps as f64;
        let (e, _) = objective(x);
        if e < best.0 {
            best = (e, x);
        }
    }
    let h = (hi - lo) / steps as f64;
    let (mut a, mut b) = ((best.1 - h).max(lo), (best.1 + h).min(hi));
    let g = 0.5 * (5f64.sqrt() - 1.0);
    for _ in 0..40 {
        let (x1, x2) = (b - g * (b - a), a + g * (b - a));
        if objective(x1).0 < objective(x2).0 {
            b = x2;
        } else {
            a = x1;
        }
    }
    let x = 0.5 * (a + b);
    let (e, scale) = objective(x);
    // a = 1/c; S = mu N L D / W (R/c)^2 = mu s_per_mu (c0/c)^2.
    let c = 1.0 / scale;
    let mu = x.exp() / (op.s_per_mu * (op.clearance_m / c).powi(2));
    (e, c, mu)
}

/// The theory's coefficients at clearance `c` and viscosity `mu`.
fn coefficients_at(t: &Table, op: &Operating, c: f64, mu: f64) -> (Matrix2<f64>, Matrix2<f64>) {
    let s = mu * op.s_per_mu * (op.clearance_m / c).powi(2);
    let kb = interpolate(&t.ln_s, &t.k, s.ln());
    let cb = interpolate(&t.ln_s, &t.c, s.ln());
    let (w, om) = (op.load_n, op.omega);
    (Matrix2::new(kb[0], kb[1], kb[2], kb[3]) * (w / c), Matrix2::new(cb[0], cb[1], cb[2], cb[3]) * (w / (c * om)))
}

/// The motion the linear rig predicts from the measured applied force, at full rate over the
/// judging band's valid range (the force's spectrum taken once, any coefficients after).
pub struct Predictor {
    /// Spectra of the applied force (x, y), zero-padded.
    fx: Vec<Complex<f64>>,
    fy: Vec<Complex<f64>>,
    n: usize,
    fs: f64,
    mass: f64,
}

impl Predictor {
    pub fn new(p: &Prepared) -> Self {
        let c = &p.narrow;
        let v = c.valid.clone();
        let m = p.mechanics.housing_mass_kg;
        let len = v.len();
        let n = (2 * len).next_power_of_two();
        let mut planner = FftPlanner::new();
        let fft = planner.plan_fft_forward(n);
        let mean = |a: &[f64]| a.iter().sum::<f64>() / a.len() as f64;
        let ax: Vec<f64> = v.clone().map(|i| c.fx_n[i] + m * c.housing_ax_m_s2[i]).collect();
        let ay: Vec<f64> = v.clone().map(|i| c.fy_n[i] + m * c.housing_ay_m_s2[i]).collect();
        let (mx, my) = (mean(&ax), mean(&ay));
        let mut fx: Vec<Complex<f64>> = (0..n).map(|i| Complex::new(if i < len { ax[i] - mx } else { 0.0 }, 0.0)).collect();
        let mut fy: Vec<Complex<f64>> = (0..n).map(|i| Complex::new(if i < len { ay[i] - my } else { 0.0 }, 0.0)).collect();
        fft.process(&mut fx);
        fft.process(&mut fy);
        Self { fx, fy, n, fs: p.raw.sample_rate_hz, mass: m }
    }

    /// Predicted `r` (x, y) over the valid range for coefficients `(K, C)`.
    pub fn predict(&self, k: &Matrix2<f64>, c: &Matrix2<f64>, len: usize) -> [Vec<f64>; 2] {
        let n = self.n;
        let mut rx = vec![Complex::new(0.0, 0.0); n];
        let mut ry = vec![Complex::new(0.0, 0.0); n];
        for b in 0..n {
            let f = if b <= n / 2 { b as f64 } else { b as f64 - n as f64 } * self.fs / n as f64;
            let w = 2.0 * std::f64::consts::PI * f;
            let h = nalgebra::Matrix2::from_fn(|i, j| Complex::new(k[(i, j)] - if i == j { self.mass * w * w } else { 0.0 }, w * c[(i, j)]));
            let Some(hi) = h.try_inverse() else { continue };
            let fv = nalgebra::Vector2::new(self.fx[b], self.fy[b]);
            let r = -(hi * fv);
            rx[b] = r[0];
            ry[b] = r[1];
        }
        let mut planner = FftPlanner::new();
        let ifft = planner.plan_fft_inverse(n);
        ifft.process(&mut rx);
        ifft.process(&mut ry);
        let scale = 1.0 / n as f64;
        [rx[..len].iter().map(|z| z.re * scale).collect(), ry[..len].iter().map(|z| z.re * scale).collect()]
    }
}

/// Squared error and squared signal of a prediction over block `b`'s samples (detrended).
fn block_error(p: &Prepared, predicted: &[Vec<f64>; 2], b: usize) -> (f64, f64) {
    let start = p.narrow.valid.start;
    let (mut e, mut s) = (0.0, 0.0);
    for (axis, meas) in [&p.series.x_m, &p.series.y_m].into_iter().enumerate() {
        let range = p.blocks[b].clone();
        let pred: Vec<f64> = range.clone().map(|j| predicted[axis][p.picks[j] - start]).collect();
        let m: Vec<f64> = range.map(|j| meas[j]).collect();
        let (pd, md) = (detrend(&pred), detrend(&m));
        e += pd.iter().zip(&md).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
        s += md.iter().map(|v| v * v).sum::<f64>();
    }
    (e, s)
}

fn detrend(v: &[f64]) -> Vec<f64> {
    let m = v.len() as f64;
    let tm = (m - 1.0) / 2.0;
    let mean = v.iter().sum::<f64>() / m;
    let (mut stt, mut sty) = (0.0, 0.0);
    for (i, &y) in v.iter().enumerate() {
        stt += (i as f64 - tm).powi(2);
        sty += (i as f64 - tm) * (y - mean);
    }
    let slope = if stt > 0.0 { sty / stt } else { 0.0 };
    v.iter().enumerate().map(|(i, y)| y - mean - slope * (i as f64 - tm)).collect()
}

/// The temperature at which `rig`'s oil has viscosity `mu` (bisection; the law falls with T).
fn temperature_for(rig: &RigConfig, mu: f64) -> Option<f64> {
    let (mut lo, mut hi) = (-20.0_f64, 200.0_f64);
    let f = |t: f64| rig.oil.viscosity_pa_s(t).ok().map(|v| v - mu);
    let (flo, fhi) = (f(lo)?, f(hi)?);
    if flo.signum() == fhi.signum() {
        return None;
    }
    for _ in 0..80 {
        let mid = 0.5 * (lo + hi);
        let fm = f(mid)?;
        if fm.signum() == flo.signum() {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(0.5 * (lo + hi))
}

/// Fits the update to the chosen model's coefficients and scores it on held-out blocks.
pub fn update(ctx: &Context, chosen: &Judged, rig: &RigConfig) -> Result<ModelUpdate, DiagnosisError> {
    let p = ctx.p;
    let mu0 = rig.oil.viscosity_pa_s(p.mean_temperature_c)?;
    let load = Vector2::new(-p.static_force_n[0], -p.static_force_n[1]);
    let load_n = load.norm();
    let g = &rig.bearing;
    let omega = p.speed_rpm * std::f64::consts::PI / 30.0;
    let radius = 0.5 * g.diameter_m;
    let s_per_mu = (p.speed_rpm / 60.0) * g.length_m * g.diameter_m / load_n * (radius / g.clearance_m).powi(2);
    let op = Operating { load, load_n, omega, s_per_mu, clearance_m: g.clearance_m };
    let s0 = mu0 * s_per_mu;
    let mut tables = Vec::new();
    for (name, r) in theories(rig) {
        match tabulate(name, &r, &op, s0) {
            Ok(t) => tables.push(t),
            Err(e) if tables.is_empty() => return Err(e),
            Err(_) => {}
        }
    }
    // The nominal model: the rig's own theory at its clearance and the oil law's viscosity.
    let mut nominal_film = rig.film()?;
    let nominal_op = operating_point::solve(nominal_film.as_mut(), &Running::from_rpm(p.speed_rpm, mu0), load, &EquilibriumOptions::default())?;
    let (k_nom, c_nom) = (nominal_op.coefficients.stiffness_n_m, nominal_op.coefficients.damping_n_s_m);

    let best_of = |kc: &[f64; 8]| -> (usize, f64, f64, f64) {
        let (k, c) = catalog::coefficients_of(kc);
        let mut best = (0usize, f64::INFINITY, g.clearance_m, mu0);
        for (i, t) in tables.iter().enumerate() {
            let (e, cl, mu) = fit_theory(t, &op, &k, &c);
            if e < best.1 {
                best = (i, e, cl, mu);
            }
        }
        best
    };

    let predictor = Predictor::new(p);
    let len = p.narrow.valid.len();
    let nominal_pred = predictor.predict(&k_nom, &c_nom, len);
    let (mut e_nom, mut e_upd, mut s_tot) = (0.0, 0.0, 0.0);
    let mut fold_fits = Vec::new();
    for (b, kc) in chosen.fold_kc.iter().enumerate() {
        let (ti, _, cl, mu) = best_of(kc);
        fold_fits.push((cl, mu));
        let (k, c) = coefficients_at(&tables[ti], &op, cl, mu);
        let pred = predictor.predict(&k, &c, len);
        let (eu, s) = block_error(p, &pred, b);
        let (en, _) = block_error(p, &nominal_pred, b);
        e_upd += eu;
        e_nom += en;
        s_tot += s;
    }
    let (ti, _, cl, mu) = best_of(&chosen.kc);
    let (k_upd, c_upd) = coefficients_at(&tables[ti], &op, cl, mu);
    let updated_position = {
        let mut r = tables[ti].rig.clone();
        r.bearing.clearance_m = cl;
        r.film()
            .ok()
            .and_then(|mut f| {
                operating_point::solve(f.as_mut(), &Running { omega_rad_s: omega, viscosity_pa_s: mu }, load, &EquilibriumOptions::default()).ok()
            })
            .map(|o| [o.journal.x_m, o.journal.y_m])
    };
    let measured_position_m = {
        let v = p.narrow.valid.clone();
        let n = v.len() as f64;
        [p.narrow.x_m[v.clone()].iter().sum::<f64>() / n, p.narrow.y_m[v].iter().sum::<f64>() / n]
    };
    let (k_id, c_id) = chosen.stiffness_damping();
    let mut theory_fits: Vec<TheoryFit> = tables
        .iter()
        .map(|t| {
            let (e, c, m) = fit_theory(t, &op, &k_id, &c_id);
            TheoryFit { theory: t.name.clone(), clearance_m: c, viscosity_pa_s: m, coefficient_mismatch: e }
        })
        .collect();
    theory_fits.sort_by(|a, b| a.coefficient_mismatch.total_cmp(&b.coefficient_mismatch));
    let jack = |f: &dyn Fn(&(f64, f64)) -> f64| -> f64 {
        let n = fold_fits.len() as f64;
        let m = fold_fits.iter().map(f).sum::<f64>() / n;
        ((n - 1.0) / n * fold_fits.iter().map(|x| (f(x) - m).powi(2)).sum::<f64>()).sqrt()
    };
    // Motion at the lines, whole record.
    let updated_pred = predictor.predict(&k_upd, &c_upd, len);
    let lines = line_predictions(p, &nominal_pred, &updated_pred);
    let nominal_nrmse = (e_nom / s_tot).sqrt();
    let updated_nrmse = (e_upd / s_tot).sqrt();
    Ok(ModelUpdate {
        nominal_theory: tables[0].name.clone(),
        nominal_clearance_m: g.clearance_m,
        nominal_viscosity_pa_s: mu0,
        theory: tables[ti].name.clone(),
        clearance_m: cl,
        clearance_se_m: jack(&|x| x.0),
        viscosity_pa_s: mu,
        viscosity_se_pa_s: jack(&|x| x.1),
        temperature_offset_c: temperature_for(rig, mu).map(|t| t - p.mean_temperature_c),
        theories: theory_fits,
        nominal_stiffness_n_m: k_nom,
        nominal_damping_n_s_m: c_nom,
        updated_stiffness_n_m: k_upd,
        updated_damping_n_s_m: c_upd,
        identified_stiffness_n_m: k_id,
        identified_damping_n_s_m: c_id,
        measured_position_m,
        nominal_position_m: Some([nominal_op.journal.x_m, nominal_op.journal.y_m]),
        updated_position_m: updated_position,
        nominal_heldout_nrmse: nominal_nrmse,
        updated_heldout_nrmse: updated_nrmse,
        improvement_factor: nominal_nrmse / updated_nrmse,
        lines,
        how: "linear rig (housing mass, film K and C) driven by the measured applied force, journal fixed; the update fitted to the coefficients identified without each held-out block".into(),
    })
}

/// Measured and predicted motion amplitudes at the excitation lines.
fn line_predictions(p: &Prepared, nominal: &[Vec<f64>; 2], updated: &[Vec<f64>; 2]) -> Vec<LinePrediction> {
    let c = &p.narrow;
    let v = c.valid.clone();
    let t: Vec<f64> = c.t_s[v.clone()].to_vec();
    let meas = [c.x_m[v.clone()].to_vec(), c.y_m[v].to_vec()];
    let amp = |sig: &[f64], f: f64| -> f64 {
        let w = 2.0 * std::f64::consts::PI * f;
        let mean = sig.iter().sum::<f64>() / sig.len() as f64;
        let (mut re, mut im) = (0.0, 0.0);
        for (x, ti) in sig.iter().zip(&t) {
            let (s, co) = (w * ti).sin_cos();
            re += (x - mean) * co;
            im -= (x - mean) * s;
        }
        2.0 * (re * re + im * im).sqrt() / sig.len() as f64
    };
    let mut out: Vec<LinePrediction> = p
        .lines_hz
        .iter()
        .map(|&f| LinePrediction {
            frequency_hz: f,
            measured_m: [amp(&meas[0], f), amp(&meas[1], f)],
            nominal_m: [amp(&nominal[0], f), amp(&nominal[1], f)],
            updated_m: [amp(&updated[0], f), amp(&updated[1], f)],
            excited: [true, true],
        })
        .collect();
    for axis in 0..2 {
        let top = out.iter().map(|l| l.measured_m[axis]).fold(0.0, f64::max);
        for l in &mut out {
            l.excited[axis] = l.measured_m[axis] >= 0.1 * top;
        }
    }
    out
}
