//! # Windowed least squares for the oil-film coefficients, done honestly
//!
//! Zhou et al. ("An experimental study on oil-film dynamic coefficients", Tribology
//! International 37 (2004) 245–253, §3.1) identify the film by least squares in the time
//! domain: the dynamic film force (their eq. 2) is regressed on the relative displacement and
//! velocity (eq. 3), and the minimiser is found from the normal equations (eq. 5–6). This module
//! fits the same model — and optionally the added-mass terms — but
//!
//! * **never forms the normal equations** (unless [`Solver::NormalEquations`] is asked for, to
//!   show what they cost): each window's regressors and forces are reduced to a small triangular
//!   factor by Householder QR ([`qr`], Golub & Van Loan, *Matrix Computations*, 4th ed., §5.2–5.3)
//!   and solved by back-substitution or by the SVD of that factor ([`svd`]);
//! * **reports the condition number** of the centred, column-scaled regressors and refuses
//!   windows whose excitation cannot separate the coefficients ([`Refusal`]), saying why;
//! * gives **standard errors that hold** when the residuals are coloured, as filtered and
//!   differentiated rig signals always are: the fixed-regressor covariance with the residual's
//!   spectral density at the regressors' frequencies ([`uncertainty`]; Grenander, Ann. Math.
//!   Statist. 25 (1954) 252–272). Newey–West HAC is kept there for comparison: on the rig's
//!   blue residuals it overstated the scatter by up to 1.7×;
//! * finds the **excitation lines** in the motion ([`spectrum`]) and uses them both to explain
//!   refusals and for a frequency-domain cross-check ([`frequency`]);
//! * runs as a **stream** whose overlapping windows reuse the factors of hop-sized blocks
//!   ([`streaming`], TSQR: Demmel, Grigori, Hoemmen & Langou, SIAM J. Sci. Comput. 34 (2012)).
//!
//! For the wider identification context (impulse, sine-sweep and multi-sine methods, and why
//! time-domain least squares with noisy, differentiated regressors needs care) see Tiwari, Lees
//! & Friswell, "Identification of dynamic bearing parameters: a review", Shock and Vibration
//! Digest 36 (2004) 99–124.
//!
//! ## Model and signs
//!
//! Frame and sign convention are those of `oilfilm-physics` (x horizontal, y up, `r` the journal
//! relative to the bearing, forces on the journal, Lund's `dF = -(K r + C r' + M r'')`). Per
//! window the estimator fits
//!
//! ```text
//! f(t) = -(K r(t) + C r'(t) [+ M r''(t)]) + f0,
//! ```
//!
//! i.e. regresses `[fx fy]` on `[x y x' y' (x'' y'') 1]`; `K = -(coefficients of x, y)` and so
//! on, with rows of each matrix the force components and columns the motion components
//! (`K[(0, 1)]` is `kxy`, the x-force per unit y-displacement). The intercept `f0` absorbs the
//! static film force (and the static journal position); it is handled by centring every column
//! on its window mean, which is exactly equivalent ([`window`]).
//!
//! ## Refusals
//!
//! A window is refused, not guessed at, when
//! * a sample is not finite ([`Refusal::NonFinite`], naming the column and absolute index);
//! * it is shorter than `max(16 (p + 1), 64)` samples ([`Refusal::TooShort`]);
//! * the regressors are rank-deficient numerically (singular values below `max(n, p) ε σ_max`)
//!   or structurally (the excitation lines span fewer dimensions than there are coefficients:
//!   one frequency for both exciters, one frequency per direction for the added-mass model)
//!   ([`Refusal::RankDeficient`]);
//! * the condition number of the column-scaled regressors exceeds
//!   [`EstimatorConfig::max_condition`] ([`Refusal::IllConditioned`]).
//!
//! Warnings that do not refuse (aliasing, errors-in-variables bias, poor fit, clipped HAC lag)
//! go into [`WindowEstimate::flags`].

// `!(a > b)` is written on purpose wherever NaN must fail the test; index loops mirror the
// formulas they implement.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

mod explain;
pub mod frequency;
pub mod normal_equations;
pub mod qr;
pub mod solve;
pub mod spectrum;
pub mod streaming;
pub mod svd;
pub mod uncertainty;
pub mod window;

use std::fmt;
use std::ops::Range;

use nalgebra::Matrix2;
use serde::{Deserialize, Serialize};

use crate::IdentificationError;

pub use frequency::{frequency_domain, Axis, FrequencyEstimate, LinePhasors};
pub use streaming::{Sample, StreamingEstimator, WindowFactors};

use solve::ScaledFactor;
use spectrum::LineAnalysis;
use window::BlockSummary;

/// Which coefficients are fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelOrder {
    /// Eight coefficients: stiffness and damping (regressors x, y, x', y').
    Kc,
    /// Twelve: stiffness, damping and added mass (regressors x, y, x', y', x'', y'').
    Kcm,
}

impl ModelOrder {
    /// Number of regressors (excluding the intercept).
    pub fn regressors(self) -> usize {
        match self {
            ModelOrder::Kc => 4,
            ModelOrder::Kcm => 6,
        }
    }

    /// Short names of the regressors, in column order.
    pub fn regressor_names(self) -> &'static [&'static str] {
        match self {
            ModelOrder::Kc => &["x", "y", "x'", "y'"],
            ModelOrder::Kcm => &["x", "y", "x'", "y'", "x''", "y''"],
        }
    }

    /// Fewest samples a window must have: `max(16 (p + 1), 64)`, so that residual
    /// autocorrelation, the HAC lag and the line search mean something.
    pub fn min_samples(self) -> usize {
        (16 * (self.regressors() + 1)).max(64)
    }
}

/// How the least-squares problem is solved.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Solver {
    /// Householder QR and back-substitution (default).
    Qr,
    /// SVD of the column-scaled triangular factor (pseudo-inverse).
    Svd,
    /// Zhou et al. (2004) eq. 6: normal equations and Gaussian elimination. For side-by-side
    /// comparison only: it squares the condition number and refuses only exactly singular
    /// systems.
    NormalEquations,
}

/// Estimator settings. Deserialises from TOML/JSON with every field named; unknown fields are
/// an error. `window` and `hop` must be given; the others default as in [`Default`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EstimatorConfig {
    /// Samples per window (50 000 in Zhou et al. 2004: 10 s at 5 kHz).
    pub window: usize,
    /// Samples between window starts (= `window` for back-to-back windows).
    pub hop: usize,
    /// Which coefficients to fit.
    #[serde(default = "default_model")]
    pub model: ModelOrder,
    /// Least-squares solver.
    #[serde(default = "default_solver")]
    pub solver: Solver,
    /// Refuse windows whose centred, column-scaled regressors have a larger condition number.
    #[serde(default = "default_max_condition")]
    pub max_condition: f64,
    /// Sampling rate of the conditioned record, Hz.
    #[serde(default = "default_sample_rate")]
    pub sample_rate_hz: f64,
    /// Refuse a solved window when a direct coefficient (kxx, kyy, dxx, dyy) has a standard
    /// error above this fraction of its value: the excitation did not determine it (e.g. one
    /// strong frequency plus a weak ripple line, which makes the design formally full rank).
    #[serde(default = "default_max_relative_se")]
    pub max_relative_se: f64,
}

fn default_model() -> ModelOrder {
    ModelOrder::Kc
}
fn default_solver() -> Solver {
    Solver::Qr
}
fn default_max_condition() -> f64 {
    1.0e6
}
fn default_sample_rate() -> f64 {
    5000.0
}
fn default_max_relative_se() -> f64 {
    0.25
}

impl Default for EstimatorConfig {
    /// Zhou et al. (2004): 50 000 samples at 5 kHz, back to back; stiffness and damping; QR;
    /// refuse above a scaled condition number of 10⁶ (QR then keeps ≥ 10 of 16 digits; the
    /// normal equations would keep ≤ 4).
    fn default() -> Self {
        Self {
            window: 50_000,
            hop: 50_000,
            model: default_model(),
            solver: default_solver(),
            max_condition: default_max_condition(),
            sample_rate_hz: default_sample_rate(),
            max_relative_se: default_max_relative_se(),
        }
    }
}

impl EstimatorConfig {
    /// Check every field; the error names the offending one.
    pub fn validate(&self) -> Result<(), IdentificationError> {
        if self.window < 2 {
            return Err(IdentificationError::invalid("window", format!("must be at least 2 samples, got {}", self.window)));
        }
        if self.hop == 0 {
            return Err(IdentificationError::invalid("hop", "must be at least 1 sample (0 would never advance)"));
        }
        if !(self.sample_rate_hz.is_finite() && self.sample_rate_hz > 0.0) {
            return Err(IdentificationError::invalid(
                "sample_rate_hz",
                format!("must be finite and positive, got {}", self.sample_rate_hz),
            ));
        }
        if !(self.max_relative_se > 0.0) {
            return Err(IdentificationError::invalid(
                "max_relative_se",
                format!("must be > 0 (a fraction of the coefficient; inf disables the check), got {}", self.max_relative_se),
            ));
        }
        if !(self.max_condition.is_finite() && self.max_condition >= 1.0) {
            return Err(IdentificationError::invalid(
                "max_condition",
                format!("must be finite and at least 1 (a condition number is never below 1), got {}", self.max_condition),
            ));
        }
        Ok(())
    }
}

/// Columns of one conditioned record on one time base (all the same length). Forces are the
/// film force on the journal (Zhou et al. eq. 2); the estimator fits their variation (an
/// intercept absorbs the static part). Accelerations are needed only for [`ModelOrder::Kcm`].
#[derive(Debug, Clone, Copy)]
pub struct Signals<'a> {
    pub x_m: &'a [f64],
    pub y_m: &'a [f64],
    pub vx_m_s: &'a [f64],
    pub vy_m_s: &'a [f64],
    pub ax_m_s2: Option<&'a [f64]>,
    pub ay_m_s2: Option<&'a [f64]>,
    pub fx_n: &'a [f64],
    pub fy_n: &'a [f64],
}

impl<'a> Signals<'a> {
    /// Number of samples (of `x_m`; [`Signals::check`] makes sure all agree).
    pub fn len(&self) -> usize {
        self.x_m.len()
    }

    /// True for an empty record.
    pub fn is_empty(&self) -> bool {
        self.x_m.is_empty()
    }

    /// All columns present must have one length; `Kcm` needs both accelerations.
    pub fn check(&self, model: ModelOrder) -> Result<(), IdentificationError> {
        let n = self.x_m.len();
        let mut cols: Vec<(&str, &[f64])> =
            vec![("y_m", self.y_m), ("vx_m_s", self.vx_m_s), ("vy_m_s", self.vy_m_s), ("fx_n", self.fx_n), ("fy_n", self.fy_n)];
        if let Some(a) = self.ax_m_s2 {
            cols.push(("ax_m_s2", a));
        }
        if let Some(a) = self.ay_m_s2 {
            cols.push(("ay_m_s2", a));
        }
        for (name, c) in cols {
            if c.len() != n {
                return Err(IdentificationError::BadInput {
                    what: name.to_string(),
                    reason: format!("has {} samples but x_m has {n}: all columns must share one time base", c.len()),
                });
            }
        }
        if model == ModelOrder::Kcm {
            for (name, c) in [("ax_m_s2", self.ax_m_s2), ("ay_m_s2", self.ay_m_s2)] {
                if c.is_none() {
                    return Err(IdentificationError::BadInput {
                        what: name.to_string(),
                        reason: "the added-mass model (Kcm) needs both accelerations".to_string(),
                    });
                }
            }
        }
        Ok(())
    }

    /// Regressor columns then the two forces, with their field names, sliced to `range`.
    /// Call [`Signals::check`] first (missing accelerations give empty columns here).
    fn design(&self, model: ModelOrder, range: Range<usize>) -> Vec<(&'static str, &'a [f64])> {
        let cut = |c: &'a [f64]| c.get(range.clone()).unwrap_or(&[]);
        let mut cols = vec![
            ("x_m", cut(self.x_m)),
            ("y_m", cut(self.y_m)),
            ("vx_m_s", cut(self.vx_m_s)),
            ("vy_m_s", cut(self.vy_m_s)),
        ];
        if model == ModelOrder::Kcm {
            cols.push(("ax_m_s2", self.ax_m_s2.map(cut).unwrap_or(&[])));
            cols.push(("ay_m_s2", self.ay_m_s2.map(cut).unwrap_or(&[])));
        }
        cols.push(("fx_n", cut(self.fx_n)));
        cols.push(("fy_n", cut(self.fy_n)));
        cols
    }
}

/// The identified coefficients of one window with their standard errors (HAC, see
/// [`uncertainty`]). Rows are force components, columns motion components.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Coefficients {
    pub stiffness_n_m: Matrix2<f64>,
    pub damping_n_s_m: Matrix2<f64>,
    pub added_mass_kg: Option<Matrix2<f64>>,
    pub stiffness_se: Matrix2<f64>,
    pub damping_se: Matrix2<f64>,
    pub added_mass_se: Option<Matrix2<f64>>,
}

/// Why a window was not solved.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Refusal {
    /// The excitation (or the data) spans fewer dimensions than there are coefficients.
    RankDeficient { rank: usize, needed: usize, explanation: String },
    /// The column-scaled regressors are too close to dependent to trust.
    IllConditioned { condition: f64, limit: f64, explanation: String },
    /// Too few samples in the window.
    TooShort { samples: usize, needed: usize },
    /// A sample is NaN or infinite; `index` is its index in the record (or stream).
    NonFinite { column: String, index: usize },
    /// Solvable, but the excitation leaves a direct coefficient undetermined: its standard
    /// error exceeds `limit` times its value.
    Undetermined { coefficient: String, relative_se: f64, limit: f64, explanation: String },
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Refusal::RankDeficient { rank, needed, explanation } => {
                if explanation.contains(&format!("rank {rank} of {needed}")) {
                    write!(f, "cannot separate the coefficients: {explanation}")
                } else {
                    write!(f, "cannot separate the coefficients (rank {rank} of {needed}): {explanation}")
                }
            }
            Refusal::IllConditioned { condition, limit, explanation } => write!(
                f,
                "ill-conditioned window: condition number {condition:.3e} of the scaled regressors exceeds the limit {limit:.1e} ({explanation})"
            ),
            Refusal::TooShort { samples, needed } => write!(
                f,
                "window too short: {samples} samples, at least {needed} needed for the coefficients, their intercept and meaningful standard errors"
            ),
            Refusal::Undetermined { coefficient, relative_se, limit, explanation } => write!(
                f,
                "{coefficient} is not determined by this excitation: its standard error is {:.0} % of its value (limit {:.0} %): {explanation}",
                100.0 * relative_se,
                100.0 * limit
            ),
            Refusal::NonFinite { column, index } => write!(
                f,
                "`{column}` is not finite at sample {index}: a dropped or saturated sample; repair or cut it before identification"
            ),
        }
    }
}

/// One window's result. `result` is `Err` when the window was refused; the diagnostics are
/// filled in as far as they could be computed (`NaN` otherwise).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WindowEstimate {
    /// First sample (inclusive), index in the record or stream.
    pub start: usize,
    /// Last sample (exclusive).
    pub end: usize,
    pub result: Result<Coefficients, Refusal>,
    /// Condition number of the centred, column-scaled regressors (for
    /// [`Solver::NormalEquations`]: of the scaled normal matrix, the square).
    pub condition_number: f64,
    /// Rank of the regressors: numerical, or the excitation's if that is lower.
    pub rank: usize,
    /// RMS residual of fx and fy, N.
    pub residual_rms_n: [f64; 2],
    /// Excitation lines found in the displacement (x and y merged), Hz.
    pub frequencies_hz: Vec<f64>,
    /// Warnings that do not refuse.
    pub flags: Vec<String>,
}

/// Estimate every window `[k hop, k hop + window)` of the record.
///
/// `Err` only for malformed input (length mismatch, missing accelerations for `Kcm`, invalid
/// configuration, window longer than the record); windows that cannot be solved come back as
/// `Ok` with `result: Err(Refusal)`.
pub fn estimate_windows(signals: &Signals, config: &EstimatorConfig) -> Result<Vec<WindowEstimate>, IdentificationError> {
    config.validate()?;
    signals.check(config.model)?;
    let n = signals.len();
    if config.window > n {
        return Err(IdentificationError::invalid(
            "window",
            format!("{} samples is longer than the record ({n} samples)", config.window),
        ));
    }
    let mut out = Vec::new();
    let mut start = 0;
    while start <= n - config.window {
        let cols = signals.design(config.model, start..start + config.window);
        out.push(analyse_window(&cols, start, None, config));
        match start.checked_add(config.hop) {
            Some(next) => start = next,
            None => break,
        }
    }
    Ok(out)
}

/// Estimate one window, `range` of the record (its length overrides `config.window`).
pub fn estimate_window(signals: &Signals, range: Range<usize>, config: &EstimatorConfig) -> Result<WindowEstimate, IdentificationError> {
    config.validate()?;
    signals.check(config.model)?;
    let n = signals.len();
    if range.start >= range.end || range.end > n {
        return Err(IdentificationError::invalid(
            "range",
            format!("{}..{} is empty or outside the record of {n} samples", range.start, range.end),
        ));
    }
    let cols = signals.design(config.model, range.clone());
    Ok(analyse_window(&cols, range.start, None, config))
}

/// The common path of batch and streaming estimation. `cols` are the regressors then fx, fy,
/// sliced to the window; `summary` is the window's factor if the caller already has it (the
/// streaming estimator combines block factors), otherwise it is computed here.
pub(crate) fn analyse_window(
    cols: &[(&'static str, &[f64])],
    start: usize,
    summary: Option<&BlockSummary>,
    config: &EstimatorConfig,
) -> WindowEstimate {
    let model = config.model;
    let p = model.regressors();
    let n = cols.iter().map(|(_, c)| c.len()).min().unwrap_or(0);
    let mut est = WindowEstimate {
        start,
        end: start + n,
        result: Err(Refusal::TooShort { samples: n, needed: model.min_samples() }),
        condition_number: f64::NAN,
        rank: 0,
        residual_rms_n: [f64::NAN; 2],
        frequencies_hz: Vec::new(),
        flags: Vec::new(),
    };
    // 1. Every sample finite (earliest offending sample; ties go to the first column).
    let mut first_bad: Option<(usize, &str)> = None;
    for (name, c) in cols {
        if let Some(i) = c[..n].iter().position(|v| !v.is_finite()) {
            if first_bad.is_none_or(|(j, _)| i < j) {
                first_bad = Some((i, name));
            }
        }
    }
    if let Some((i, name)) = first_bad {
        est.result = Err(Refusal::NonFinite { column: name.to_string(), index: start + i });
        return est;
    }
    // 2. Long enough.
    if n < model.min_samples() {
        return est;
    }
    let data: Vec<&[f64]> = cols.iter().map(|(_, c)| &c[..n]).collect();
    // 3. Excitation lines.
    let lines = spectrum::analyse(data[0], data[1], data[2], data[3], config.sample_rate_hz);
    est.frequencies_hz = lines.merged.clone();
    let names = model.regressor_names();
    let structural = explain::structural_rank(model, &lines);
    excitation_flags(&mut est.flags, model, &lines);

    // 4. Solve.
    let (mean, scale, coef, ginv) = match config.solver {
        Solver::NormalEquations => {
            let ne = normal_equations::solve(&data, p);
            est.condition_number = ne.condition_normal;
            match ne.singular_at {
                None => {
                    est.rank = p;
                    est.flags.push(format!(
                        "paper's normal equations (Zhou et al. 2004 eq. 6): condition number {:.2e}, the square of the scaled regressors' {:.2e}; about {:.0} of 16 digits lost",
                        ne.condition_normal,
                        ne.condition_normal.sqrt(),
                        ne.condition_normal.log10().clamp(0.0, 16.0)
                    ));
                    (ne.mean, ne.scale, ne.coef, ne.inverse_gram_scaled)
                }
                Some(singular) => {
                    est.rank = singular;
                    let explanation = match structural {
                        Some(r) => explain::structural_explanation(model, &lines, r, None),
                        None => format!("the normal matrix is singular to working precision at pivot {}", singular + 1),
                    };
                    est.result = Err(Refusal::RankDeficient { rank: singular, needed: p, explanation });
                    return est;
                }
            }
        }
        Solver::Qr | Solver::Svd => {
            let owned;
            let summary = match summary {
                Some(s) => s,
                None => {
                    owned = BlockSummary::from_columns(&data);
                    &owned
                }
            };
            let Some(factor) = ScaledFactor::new(summary, p) else {
                est.condition_number = f64::INFINITY;
                est.result = Err(Refusal::IllConditioned {
                    condition: f64::INFINITY,
                    limit: config.max_condition,
                    explanation: "the factorisation overflowed or did not converge: values far outside SI magnitudes?".to_string(),
                });
                return est;
            };
            est.condition_number = factor.condition;
            est.rank = factor.rank;
            if let Some(r) = structural {
                if r < est.rank {
                    est.rank = r;
                }
            }
            if est.rank < p {
                let explanation = if !factor.zero_columns.is_empty() {
                    explain::constant_columns(&factor.zero_columns, names)
                } else {
                    match structural {
                        Some(r) => explain::structural_explanation(model, &lines, r.min(factor.rank), Some(&factor.svd)),
                        None => explain::dependency(&factor.svd, names),
                    }
                };
                est.result = Err(Refusal::RankDeficient { rank: est.rank, needed: p, explanation });
                return est;
            }
            if !(factor.condition <= config.max_condition) {
                let window_s = n as f64 / config.sample_rate_hz;
                est.result = Err(Refusal::IllConditioned {
                    condition: factor.condition,
                    limit: config.max_condition,
                    explanation: explain::ill_conditioned_explanation(&factor.svd, names, &lines, window_s),
                });
                return est;
            }
            let Some(sol) = factor.solve(config.solver) else {
                est.result = Err(Refusal::RankDeficient {
                    rank: est.rank,
                    needed: p,
                    explanation: "a zero pivot appeared in back-substitution".to_string(),
                });
                return est;
            };
            (factor.mean, factor.scale, sol.coef, sol.inverse_gram_scaled)
        }
    };

    // 5. Residuals and standard errors (fixed-regressor spectral form, see `uncertainty`).
    let hac = uncertainty::spectral(&data, p, &mean, &scale, &coef, &ginv);
    est.residual_rms_n = [hac.residual_rms[0], hac.residual_rms[1]];
    let coefficients = assemble(model, &coef, &hac.se);
    flags(&mut est.flags, model, &lines, &coefficients, &data, &hac);
    if let Some(refusal) = undetermined(&coefficients, &lines, config.max_relative_se) {
        if config.solver == Solver::NormalEquations {
            // The paper's method answers whatever the data (it is kept for comparison); say
            // what the honest solvers would have refused.
            est.flags.push(format!("the QR/SVD solvers would refuse this window: {refusal}"));
        } else {
            est.result = Err(refusal);
            return est;
        }
    }
    est.result = Ok(coefficients);
    est
}

/// The worst-determined direct coefficient, if its relative standard error is above `limit`.
fn undetermined(c: &Coefficients, lines: &spectrum::LineAnalysis, limit: f64) -> Option<Refusal> {
    let direct = [
        ("kxx", c.stiffness_n_m[(0, 0)], c.stiffness_se[(0, 0)]),
        ("kyy", c.stiffness_n_m[(1, 1)], c.stiffness_se[(1, 1)]),
        ("dxx", c.damping_n_s_m[(0, 0)], c.damping_se[(0, 0)]),
        ("dyy", c.damping_n_s_m[(1, 1)], c.damping_se[(1, 1)]),
    ];
    let (name, value, se) = direct
        .iter()
        .copied()
        .max_by(|a, b| (a.2 / a.1.abs()).total_cmp(&(b.2 / b.1.abs())))?;
    let relative_se = se / value.abs();
    if relative_se.is_nan() || relative_se <= limit {
        return None;
    }
    let explanation = if lines.merged.is_empty() {
        "no excitation line stands out of the noise: excite the bearing (two-tone or multisine)".to_string()
    } else {
        format!(
            "the motion's lines ({}) do not separate stiffness from damping in both directions, typically one strong frequency with only weak ripple or harmonics beside it: excite two strong frequencies (two-tone or multisine)",
            explain::fmt_hz(&lines.merged)
        )
    };
    Some(Refusal::Undetermined { coefficient: name.to_string(), relative_se, limit, explanation })
}

/// Coefficient matrices from the regression vector (`coef[j * 2 + k]`, regressor `j`, force `k`).
fn assemble(model: ModelOrder, coef: &[f64], se: &[f64]) -> Coefficients {
    let m = 2;
    let block = |v: &[f64], first: usize, sign: f64| {
        Matrix2::from_fn(|k, d| sign * v.get((first + d) * m + k).copied().unwrap_or(f64::NAN))
    };
    let kcm = model == ModelOrder::Kcm;
    Coefficients {
        stiffness_n_m: block(coef, 0, -1.0),
        damping_n_s_m: block(coef, 2, -1.0),
        added_mass_kg: kcm.then(|| block(coef, 4, -1.0)),
        stiffness_se: block(se, 0, 1.0),
        damping_se: block(se, 2, 1.0),
        added_mass_se: kcm.then(|| block(se, 4, 1.0)),
    }
}

/// Warnings about the excitation itself (known before solving).
fn excitation_flags(out: &mut Vec<String>, model: ModelOrder, lines: &LineAnalysis) {
    let dir = ["x", "y"];
    let dominated = |d: usize| lines.line_fraction[d] >= explain::LINE_DOMINATED;
    for d in 0..2 {
        let l = &lines.lines[d];
        if model == ModelOrder::Kcm && dominated(d) && l.len() < 2 {
            out.push(format!(
                "stiffness and added mass alias at one frequency (K - w^2 M): {} moves at {} only",
                dir[d],
                explain::fmt_hz(l)
            ));
        }
        if !dominated(d) && l.is_empty() {
            out.push(format!(
                "no excitation line in {}: its coefficients rest on broadband motion (biased if that motion is sensor noise)",
                dir[d]
            ));
        }
    }
}

/// A fraction as a percentage with enough digits to be read.
fn pct(f: f64) -> String {
    let p = 100.0 * f;
    if p.abs() >= 0.1 { format!("{p:.2} %") } else { format!("{p:.1e} %") }
}

/// Noise fractions below this (60 dB) are at the floor of the spectral estimate.
const EIV_FLOOR: f64 = 1e-6;

/// Warnings about the solved window that do not refuse it.
fn flags(out: &mut Vec<String>, model: ModelOrder, lines: &LineAnalysis, c: &Coefficients, data: &[&[f64]], hac: &uncertainty::Hac) {
    let dir = ["x", "y"];
    let dominated = |d: usize| lines.line_fraction[d] >= explain::LINE_DOMINATED;
    for d in 0..2 {
        if !dominated(d) {
            continue;
        }
        // Errors in variables: noise power fraction eta in a regressor attenuates its
        // coefficient by about eta (relative). Flag when that is 1 % or more, or when it exceeds
        // half the standard error; fractions below 1e-6 (60 dB) are at the floor of the
        // spectral estimate and say nothing.
        let eta_x = (1.0 - lines.line_fraction[d]).max(0.0);
        let eta_v = lines.velocity_noise_fraction[d].max(0.0);
        let (kd, kse) = (c.stiffness_n_m[(d, d)], c.stiffness_se[(d, d)]);
        let (dd, dse) = (c.damping_n_s_m[(d, d)], c.damping_se[(d, d)]);
        if eta_x.is_finite() && eta_x > EIV_FLOOR && (eta_x > 0.01 || eta_x * kd.abs() > 0.5 * kse) {
            out.push(format!(
                "stiffness may be biased by displacement noise (errors in variables): {v} has {:.1} dB SNR at its lines, attenuation ≈ {} of k{v}{v} against a standard error of {}",
                -10.0 * eta_x.log10(),
                pct(eta_x),
                pct(kse / kd.abs()),
                v = dir[d]
            ));
        }
        if eta_v.is_finite() && eta_v > EIV_FLOOR && (eta_v > 0.01 || eta_v * dd.abs() > 0.5 * dse) {
            out.push(format!(
                "damping from differentiated noisy displacement may be biased: {v}' has {:.1} dB SNR at the lines, errors-in-variables attenuation ≈ {} of d{v}{v} against a standard error of {}",
                -10.0 * eta_v.log10(),
                pct(eta_v),
                pct(dse / dd.abs()),
                v = dir[d]
            ));
        }
    }
    if hac.lag_capped {
        out.push("the window is so short that the residual spectrum's lag window was clipped to a quarter of it: standard errors may be optimistic".to_string());
    }
    let p = model.regressors();
    for (k, name) in ["fx", "fy"].iter().enumerate() {
        let f = data[p + k];
        let mean = f.iter().sum::<f64>() / f.len() as f64;
        let var = f.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / f.len() as f64;
        let r2 = 1.0 - hac.residual_rms[k] * hac.residual_rms[k] / var;
        if var > 0.0 && r2 < 0.9 {
            out.push(format!(
                "the linear model explains only {:.1} % of the {name} variation: nonlinear film or unmodelled dynamics (Zhou et al. 2004 saw this at high excitation force)",
                100.0 * r2.max(0.0)
            ));
        }
    }
}
