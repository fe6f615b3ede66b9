//! Frequency-domain cross-check at the excitation lines.
//!
//! With sinusoidal excitation the film is usually identified line by line: the complex
//! amplitudes (phasors) of motion and force at each excitation frequency give the dynamic
//! stiffness `H(w) = K - w² M + i w C` (Tiwari, Lees & Friswell 2004, §3.2; with Lund's sign,
//! `F = -H R`). Doing it here, on the same record as the time-domain fit, is an independent
//! check: the phasors come from a separate least-squares fit and the coefficients from a fit
//! across lines, so a disagreement points at something the linear time-domain model misses
//! (nonlinearity, a wrong channel delay, harmonics).
//!
//! **Phasors.** For known frequencies `w_k` every channel is fitted by least squares (Householder
//! QR, [`super::qr`]) to `c + Σ_k a_k cos(w_k t) + b_k sin(w_k t)` with `t = i / f_s` from the
//! first sample; the phasor is `a_k - i b_k`, so the channel is `Re(X e^{i w t})`. A joint fit,
//! unlike an FFT bin, has no leakage between lines and needs no whole number of periods.
//!
//! **Coefficients.** Each line gives, per force component `i`, two real equations
//! `-Re F_i = Σ_j K_ij Re R_j - w C_ij Im R_j - w² M_ij Re R_j` and
//! `-Im F_i = Σ_j K_ij Im R_j + w C_ij Re R_j - w² M_ij Im R_j`, solved across lines by QR with
//! column scaling. K and C need two independent motions (lines exciting both directions); M
//! needs in addition two lines per direction, or `K - w² M` cannot be split.
//! Standard errors are the classical least-squares ones across lines (NaN when the fit is
//! exactly determined); the time-domain HAC errors are the ones to trust.

use nalgebra::{Complex, Matrix2};

use super::explain::fmt_hz;
use super::solve::ScaledFactor;
use super::window::BlockSummary;
use super::{Coefficients, ModelOrder, Refusal, Signals, Solver};
use crate::IdentificationError;

/// Most lines accepted (the phasor fit has `2 × lines` columns).
pub const MAX_LINES: usize = 64;

/// Which direction a line moves the journal in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Axis {
    /// Only x (|Y| below 1 % of |X|).
    X,
    /// Only y.
    Y,
    /// Both.
    Both,
}

/// Phasors at one line and the dynamic stiffness they show.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LinePhasors {
    pub frequency_hz: f64,
    /// Displacement phasors, m (the channel is `Re(X e^{i w t})`).
    pub x_m: Complex<f64>,
    pub y_m: Complex<f64>,
    /// Film-force phasors, N.
    pub fx_n: Complex<f64>,
    pub fy_n: Complex<f64>,
    /// Direction of the motion at this line.
    pub excited: Axis,
    /// Dynamic stiffness along the motion, `-(F · conj R) / |R|²`, N/m: for motion along x
    /// this is `H_xx = K_xx - w² M_xx + i w C_xx`.
    pub direct_dynamic_stiffness_n_m: Complex<f64>,
    /// For a single-direction line, the column of `H` of that direction, `-F / R_d`, N/m
    /// (`[H_xd, H_yd]`); `None` when both directions move.
    pub column_n_m: Option<[Complex<f64>; 2]>,
}

/// Result of the frequency-domain cross-check.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrequencyEstimate {
    pub lines: Vec<LinePhasors>,
    /// Coefficients fitted to `H(w) = K - w² M + i w C` across lines, or why not.
    pub result: Result<Coefficients, Refusal>,
    /// Condition number of the column-scaled cross-line fit.
    pub condition_number: f64,
    /// RMS misfit of the force phasors (fx, fy) across lines, N.
    pub residual_rms_n: [f64; 2],
}

/// Phasors of the record at `lines_hz` and the coefficients they imply. Uses the whole record.
pub fn frequency_domain(signals: &Signals, lines_hz: &[f64], sample_rate_hz: f64, model: ModelOrder) -> Result<FrequencyEstimate, IdentificationError> {
    signals.check(model)?;
    if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
        return Err(IdentificationError::invalid("sample_rate_hz", format!("must be finite and positive, got {sample_rate_hz}")));
    }
    let nyquist = 0.5 * sample_rate_hz;
    if lines_hz.is_empty() || lines_hz.len() > MAX_LINES {
        return Err(IdentificationError::invalid("lines_hz", format!("need 1 to {MAX_LINES} lines, got {}", lines_hz.len())));
    }
    if let Some(f) = lines_hz.iter().find(|f| !(f.is_finite() && **f > 0.0 && **f < nyquist)) {
        return Err(IdentificationError::invalid("lines_hz", format!("{f} Hz is not between 0 and the Nyquist frequency {nyquist} Hz")));
    }
    let n = signals.len();
    let nl = lines_hz.len();
    if n < 4 * (2 * nl + 1) {
        return Err(IdentificationError::BadInput { what: "signals".to_string(), reason: format!("{n} samples are too few to fit {nl} lines") });
    }
    let chans: [(&str, &[f64]); 4] = [("x_m", signals.x_m), ("y_m", signals.y_m), ("fx_n", signals.fx_n), ("fy_n", signals.fy_n)];
    for (name, c) in chans {
        if let Some(i) = c.iter().position(|v| !v.is_finite()) {
            return Err(IdentificationError::BadInput { what: name.to_string(), reason: format!("not finite at sample {i}") });
        }
    }
    // Phasor fit: columns cos/sin per line, then the four channels.
    let mut basis: Vec<Vec<f64>> = Vec::with_capacity(2 * nl);
    for &f in lines_hz {
        let w = 2.0 * std::f64::consts::PI * f / sample_rate_hz;
        basis.push((0..n).map(|i| (w * i as f64).cos()).collect());
        basis.push((0..n).map(|i| (w * i as f64).sin()).collect());
    }
    let mut cols: Vec<&[f64]> = basis.iter().map(|v| v.as_slice()).collect();
    cols.extend(chans.iter().map(|(_, c)| *c));
    let summary = BlockSummary::from_columns(&cols);
    let factor = ScaledFactor::new(&summary, 2 * nl);
    let Some(sol) = factor.as_ref().and_then(|f| f.solve(Solver::Qr)) else {
        return Err(IdentificationError::invalid(
            "lines_hz",
            format!("lines {} cannot be separated in a record of {:.3} s (duplicate or too close)", fmt_hz(lines_hz), n as f64 / sample_rate_hz),
        ));
    };
    let m = 4;
    let mut lines = Vec::with_capacity(nl);
    for (k, &f) in lines_hz.iter().enumerate() {
        let ph = |ch: usize| Complex::new(sol.coef[2 * k * m + ch], -sol.coef[(2 * k + 1) * m + ch]);
        let (x, y, fx, fy) = (ph(0), ph(1), ph(2), ph(3));
        let r2 = x.norm_sqr() + y.norm_sqr();
        let direct = if r2 > 0.0 { -(fx * x.conj() + fy * y.conj()) / r2 } else { Complex::new(f64::NAN, f64::NAN) };
        let excited = if y.norm() < 0.01 * x.norm() {
            Axis::X
        } else if x.norm() < 0.01 * y.norm() {
            Axis::Y
        } else {
            Axis::Both
        };
        let column_n_m = match excited {
            Axis::X => Some([-fx / x, -fy / x]),
            Axis::Y => Some([-fx / y, -fy / y]),
            Axis::Both => None,
        };
        lines.push(LinePhasors { frequency_hz: f, x_m: x, y_m: y, fx_n: fx, fy_n: fy, excited, direct_dynamic_stiffness_n_m: direct, column_n_m });
    }
    Ok(fit_across_lines(lines, model))
}

fn fit_across_lines(lines: Vec<LinePhasors>, model: ModelOrder) -> FrequencyEstimate {
    let p = model.regressors();
    let rows = 2 * lines.len();
    let q = p + 2;
    // Column-major rows × q block: regressors then -Re/Im F.
    let mut block = vec![0.0; rows * q];
    for (l, ph) in lines.iter().enumerate() {
        let w = 2.0 * std::f64::consts::PI * ph.frequency_hz;
        let r = [ph.x_m, ph.y_m];
        let f = [ph.fx_n, ph.fy_n];
        let (re, im) = (2 * l, 2 * l + 1);
        for d in 0..2 {
            block[d * rows + re] = r[d].re;
            block[d * rows + im] = r[d].im;
            block[(2 + d) * rows + re] = -w * r[d].im;
            block[(2 + d) * rows + im] = w * r[d].re;
            if p == 6 {
                block[(4 + d) * rows + re] = -w * w * r[d].re;
                block[(4 + d) * rows + im] = -w * w * r[d].im;
            }
        }
        for i in 0..2 {
            block[(p + i) * rows + re] = -f[i].re;
            block[(p + i) * rows + im] = -f[i].im;
        }
    }
    let mut summary = BlockSummary::empty(q);
    summary.n = rows;
    summary.r.absorb(&mut block, rows);
    let mut out =
        FrequencyEstimate { lines, result: Err(Refusal::TooShort { samples: rows, needed: p }), condition_number: f64::NAN, residual_rms_n: [f64::NAN; 2] };
    if rows < p {
        out.result = Err(Refusal::RankDeficient { rank: rows, needed: p, explanation: needs(model, &out.lines) });
        return out;
    }
    let Some(factor) = ScaledFactor::new(&summary, p) else {
        out.result = Err(Refusal::IllConditioned { condition: f64::INFINITY, limit: f64::INFINITY, explanation: "phasors not finite".to_string() });
        return out;
    };
    out.condition_number = factor.condition;
    let Some(sol) = factor.solve(Solver::Qr) else {
        out.result = Err(Refusal::RankDeficient { rank: factor.rank, needed: p, explanation: needs(model, &out.lines) });
        return out;
    };
    let dof = rows.saturating_sub(p);
    let mut se = vec![f64::NAN; p * 2];
    for k in 0..2 {
        out.residual_rms_n[k] = (factor.rss[k] / rows as f64).sqrt();
        if dof > 0 {
            let s2 = factor.rss[k] / dof as f64;
            for j in 0..p {
                se[j * 2 + k] = (s2 * sol.inverse_gram_scaled[j * p + j]).max(0.0).sqrt() / factor.scale[j];
            }
        }
    }
    // The unknowns are +K, +C, +M directly (no sign flip: the force was negated above).
    let block2 = |v: &[f64], first: usize| Matrix2::from_fn(|k, d| v[(first + d) * 2 + k]);
    let kcm = model == ModelOrder::Kcm;
    out.result = Ok(Coefficients {
        stiffness_n_m: block2(&sol.coef, 0),
        damping_n_s_m: block2(&sol.coef, 2),
        added_mass_kg: kcm.then(|| block2(&sol.coef, 4)),
        stiffness_se: block2(&se, 0),
        damping_se: block2(&se, 2),
        added_mass_se: kcm.then(|| block2(&se, 4)),
    });
    out
}

fn needs(model: ModelOrder, lines: &[LinePhasors]) -> String {
    let count = |a: Axis| lines.iter().filter(|l| l.excited == a || l.excited == Axis::Both).count();
    let (nx, ny) = (count(Axis::X), count(Axis::Y));
    match model {
        ModelOrder::Kc => format!("K and C need two independent motions; the lines move x at {nx} and y at {ny} of {} lines", lines.len()),
        ModelOrder::Kcm => format!(
            "stiffness and added mass alias (K - w^2 M) unless each direction moves at two or more lines; x moves at {nx}, y at {ny} of {} lines",
            lines.len()
        ),
    }
}
