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
//! * is fed as samples arrive ([`feed`]: the estimator node's window analysis); factors of
//!   blocks merge exactly ([`window`], TSQR: Demmel, Grigori, Hoemmen & Langou, SIAM J. Sci.
//!   Comput. 34 (2012)).
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
pub mod feed;
pub mod frequency;
pub mod normal_equations;
pub mod qr;
pub mod solve;
pub mod spectrum;
pub mod svd;
pub mod uncertainty;
pub mod window;

use std::fmt;
use std::ops::Range;

use nalgebra::Matrix2;
use serde::{Deserialize, Serialize};

use crate::IdentificationError;

pub use feed::WindowFeed;
pub use frequency::{frequency_domain, Axis, FrequencyEstimate, LinePhasors};

use feed::FedWindow;
use solve::ScaledFactor;
use spectrum::{LineAnalysis, LineSearch};
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
    /// Highest frequency, Hz, at which the conditioned signals carry power: the conditioning
    /// low-pass's cutoff (`conditioning.lowpass_cutoff_hz`). When given, the standard errors
    /// (only they; the coefficients are untouched) are computed from every `q`-th sample of
    /// the window, `q` = [`se_decimation`]: at 100 kHz a 2 s window's costs 9 times less. `None`
    /// (the default): every sample. See `uncertainty`, "Decimated standard errors".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub signal_band_hz: Option<f64>,
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
            signal_band_hz: None,
        }
    }
}

/// The standard errors' decimated rate is at least this many times the signal band (its
/// Nyquist frequency 4 times the band): see `uncertainty`, "Decimated standard errors".
pub const SE_RATE_PER_BAND: f64 = 8.0;
/// The standard errors' decimated window keeps at least this many samples. (Was 20 000, "a
/// margin"; the statistics depend on the lag window's length against the window's, `L/n`,
/// which decimation keeps, and 5 kHz windows of 25 000 samples now decimate too: ADR 0011.)
pub const SE_MIN_SAMPLES: usize = 2_000;

/// Decimation factor of the standard errors for a window of `n` samples at `sample_rate_hz`
/// whose signals are band-limited to `signal_band_hz`: the largest `q` with
/// `sample_rate_hz / q >= SE_RATE_PER_BAND * signal_band_hz` and `n / q >= SE_MIN_SAMPLES`;
/// 1 (no decimation) without a band or when either bound allows no more.
pub fn se_decimation(n: usize, sample_rate_hz: f64, signal_band_hz: Option<f64>) -> usize {
    let Some(band) = signal_band_hz.filter(|b| b.is_finite() && *b > 0.0) else { return 1 };
    let by_band = sample_rate_hz / (SE_RATE_PER_BAND * band);
    if !(by_band >= 2.0) {
        return 1;
    }
    let by_band = by_band.floor().min(usize::MAX as f64) as usize;
    by_band.min(n / SE_MIN_SAMPLES).max(1)
}

/// The longest window (and hop) accepted, samples: 200 times the paper's 50 000 (33 min at
/// its 5 kHz). A window's buffers grow with it, so a mistyped size is refused before anything
/// is allocated rather than aborting the process.
pub const MAX_WINDOW_SAMPLES: usize = 10_000_000;

impl EstimatorConfig {
    /// Check every field; the error names the offending one.
    pub fn validate(&self) -> Result<(), IdentificationError> {
        if !(2..=MAX_WINDOW_SAMPLES).contains(&self.window) {
            return Err(IdentificationError::invalid("window", format!("must be 2 to {MAX_WINDOW_SAMPLES} samples, got {}", self.window)));
        }
        if !(1..=MAX_WINDOW_SAMPLES).contains(&self.hop) {
            return Err(IdentificationError::invalid("hop", format!("must be 1 to {MAX_WINDOW_SAMPLES} samples (0 would never advance), got {}", self.hop)));
        }
        if !(self.sample_rate_hz.is_finite() && self.sample_rate_hz > 0.0) {
            return Err(IdentificationError::invalid("sample_rate_hz", format!("must be finite and positive, got {}", self.sample_rate_hz)));
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
        if let Some(band) = self.signal_band_hz {
            if !(band.is_finite() && band > 0.0 && band < self.sample_rate_hz / 2.0) {
                return Err(IdentificationError::invalid(
                    "signal_band_hz",
                    format!(
                        "must be finite, above 0 and below the Nyquist frequency {} Hz (the conditioning low-pass cutoff), got {band}",
                        self.sample_rate_hz / 2.0
                    ),
                ));
            }
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
        let mut cols: Vec<(&str, &[f64])> = vec![("y_m", self.y_m), ("vx_m_s", self.vx_m_s), ("vy_m_s", self.vy_m_s), ("fx_n", self.fx_n), ("fy_n", self.fy_n)];
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
        let mut cols = vec![("x_m", cut(self.x_m)), ("y_m", cut(self.y_m)), ("vx_m_s", cut(self.vx_m_s)), ("vy_m_s", cut(self.vy_m_s))];
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
            Refusal::IllConditioned { condition, limit, explanation } => {
                write!(f, "ill-conditioned window: condition number {condition:.3e} of the scaled regressors exceeds the limit {limit:.1e} ({explanation})")
            }
            Refusal::TooShort { samples, needed } => {
                write!(f, "window too short: {samples} samples, at least {needed} needed for the coefficients, their intercept and meaningful standard errors")
            }
            Refusal::Undetermined { coefficient, relative_se, limit, explanation } => write!(
                f,
                "{coefficient} is not determined by this excitation: its standard error is {:.0} % of its value (limit {:.0} %): {explanation}",
                100.0 * relative_se,
                100.0 * limit
            ),
            Refusal::NonFinite { column, index } => {
                write!(f, "`{column}` is not finite at sample {index}: a dropped or saturated sample; repair or cut it before identification")
            }
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
        return Err(IdentificationError::invalid("window", format!("{} samples is longer than the record ({n} samples)", config.window)));
    }
    let mut out = Vec::new();
    let mut start = 0;
    while start <= n - config.window {
        let cols = signals.design(config.model, start..start + config.window);
        out.push(analyse_window(&cols, start, None, None, config));
        match start.checked_add(config.hop) {
            Some(next) => start = next,
            None => break,
        }
    }
    Ok(out)
}

/// Estimate one window, `range` of the record (its length overrides `config.window`).
pub fn estimate_window(signals: &Signals, range: Range<usize>, config: &EstimatorConfig) -> Result<WindowEstimate, IdentificationError> {
    estimate_window_searched(signals, range, config, None)
}

/// [`estimate_window`] with the window's line search fed while its samples arrived
/// ([`LineSearch`], for a window of `range.len()` samples at `config.sample_rate_hz`; another
/// search is ignored). The result is [`estimate_window`]'s, bit for bit: only the time after
/// the last sample is shorter.
pub fn estimate_window_with_search(
    signals: &Signals,
    range: Range<usize>,
    config: &EstimatorConfig,
    search: LineSearch,
) -> Result<WindowEstimate, IdentificationError> {
    estimate_window_searched(signals, range, config, Some(search))
}

/// [`estimate_window`] with the window's analysis fed while its samples arrived
/// ([`WindowFeed`], for windows of `range.len()` samples with `config`; a feed that does not
/// fit, or has not taken all of the window, is ignored and the window analysed from its
/// samples). The result is [`estimate_window`]'s, bit for bit: only the time after the last
/// sample is shorter.
pub fn estimate_window_fed(signals: &Signals, range: Range<usize>, config: &EstimatorConfig, feed: WindowFeed) -> Result<WindowEstimate, IdentificationError> {
    let n = range.len();
    let fed = if feed.fits(&EstimatorConfig { window: n, ..config.clone() }) { feed.into_window(n) } else { None };
    match fed {
        Some(fed) => {
            config.validate()?;
            signals.check(config.model)?;
            if range.start >= range.end || range.end > signals.len() {
                return Err(IdentificationError::invalid(
                    "range",
                    format!("{}..{} is empty or outside the record of {} samples", range.start, range.end, signals.len()),
                ));
            }
            let cols = signals.design(config.model, range.clone());
            Ok(analyse_window(&cols, range.start, None, Some(fed), config))
        }
        None => estimate_window_searched(signals, range, config, None),
    }
}

/// The checks and the analysis both single-window entry points share.
fn estimate_window_searched(
    signals: &Signals,
    range: Range<usize>,
    config: &EstimatorConfig,
    search: Option<LineSearch>,
) -> Result<WindowEstimate, IdentificationError> {
    config.validate()?;
    signals.check(config.model)?;
    let n = signals.len();
    if range.start >= range.end || range.end > n {
        return Err(IdentificationError::invalid("range", format!("{}..{} is empty or outside the record of {n} samples", range.start, range.end)));
    }
    let cols = signals.design(config.model, range.clone());
    Ok(analyse_window(&cols, range.start, search, None, config))
}

/// The common path of batch and fed estimation. `cols` are the regressors then fx, fy,
/// sliced to the window; `fed` is what a [`WindowFeed`] of all of the window kept (the same
/// bits as computing it here).
pub(crate) fn analyse_window(
    cols: &[(&'static str, &[f64])],
    start: usize,
    search: Option<LineSearch>,
    fed: Option<FedWindow>,
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
    let fed = fed.filter(|f| f.first_bad.len() == cols.len());
    let mut first_bad: Option<(usize, &str)> = None;
    for (k, (name, c)) in cols.iter().enumerate() {
        let bad = match &fed {
            Some(f) => f.first_bad[k],
            None => c[..n].iter().position(|v| !v.is_finite()),
        };
        if let Some(i) = bad {
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
    // 3. Excitation lines (from the search fed while the samples arrived, if it is this
    // window's: the same bits).
    let (x, y, vx, vy) = (data[0], data[1], data[2], data[3]);
    let (search, fed_summary, decimated) = match fed {
        Some(f) => (Some(f.search), Some(f.summary), Some((f.q, f.decimated))),
        None => (search, None, None),
    };
    let lines = match search.filter(|s| s.window() == (n, config.sample_rate_hz)) {
        Some(s) => s.finish(x, y, vx, vy),
        None => spectrum::analyse(x, y, vx, vy, config.sample_rate_hz),
    };
    est.frequencies_hz = lines.merged.clone();
    let names = model.regressor_names();
    let structural = explain::structural_rank(model, &lines);
    excitation_flags(&mut est.flags, model, &lines);

    // 4. Solve. The factor's last columns give each force's residual sum of squares and its
    // centred sum of squares (`qr`: the column norms of `T` and of the force column).
    let mut sums_of_squares: Option<([f64; 2], [f64; 2])> = None;
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
            let owned = fed_summary.unwrap_or_else(|| BlockSummary::from_columns(&data));
            let summary = &owned;
            if summary.r.cols() == p + 2 {
                let r = &summary.r;
                let t = |i: usize, j: usize| r.get(i, j) * r.get(i, j);
                sums_of_squares = Some(([t(p, p), t(p, p + 1) + t(p + 1, p + 1)], [r.column_norm(p).powi(2), r.column_norm(p + 1).powi(2)]));
            }
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
                est.result = Err(Refusal::RankDeficient { rank: est.rank, needed: p, explanation: "a zero pivot appeared in back-substitution".to_string() });
                return est;
            };
            (factor.mean, factor.scale, sol.coef, sol.inverse_gram_scaled)
        }
    };

    // 5. Residuals and standard errors (fixed-regressor spectral form, see `uncertainty`).
    // With the factor's sums of squares, only the decimated samples are needed.
    let q = se_decimation(n, config.sample_rate_hz, config.signal_band_hz);
    let (hac, centred_ss) = match sums_of_squares {
        Some((residual_ss, centred_ss)) => {
            let owned: Vec<Vec<f64>>;
            let decimated: Vec<&[f64]> = match &decimated {
                Some((qf, d)) if *qf == q => d.iter().map(|c| c.as_slice()).collect(),
                _ => {
                    owned = data.iter().map(|c| c.iter().step_by(q).copied().collect()).collect();
                    owned.iter().map(|c| c.as_slice()).collect()
                }
            };
            let mut hac = uncertainty::spectral_of_decimated(&decimated, n, p, &mean, &scale, &coef, &ginv, q);
            for k in 0..2 {
                hac.residual_rms[k] = (residual_ss[k].max(0.0) / n as f64).sqrt();
            }
            (hac, centred_ss)
        }
        None => {
            let hac = uncertainty::spectral_decimated(&data, p, &mean, &scale, &coef, &ginv, q);
            let centred_ss = [p, p + 1].map(|j| {
                let f = data[j];
                let mean = f.iter().sum::<f64>() / f.len() as f64;
                f.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>()
            });
            (hac, centred_ss)
        }
    };
    est.residual_rms_n = [hac.residual_rms[0], hac.residual_rms[1]];
    let coefficients = assemble(model, &coef, &hac.se);
    let accel_noise = (model == ModelOrder::Kcm).then(|| spectrum::noise_fraction(data[4], data[5], &lines, config.sample_rate_hz));
    let fit = Fit { scale: &scale, coef: &coef, ginv_s: &ginv, se: &hac.se };
    flags(&mut est.flags, model, &lines, n, centred_ss, &hac, &fit, accel_noise);
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
    let (name, value, se) = direct.iter().copied().max_by(|a, b| (a.2 / a.1.abs()).total_cmp(&(b.2 / b.1.abs())))?;
    let relative_se = se / value.abs();
    if relative_se.is_nan() || relative_se <= limit {
        return None;
    }
    let explanation = if lines.merged.is_empty() {
        "no excitation line stands out of the noise: excite the bearing (two-tone or multisine)".to_string()
    } else {
        format!(
            "the motion's lines ({}) do not separate stiffness from damping in both directions: either one strong frequency has only weak ripple or harmonics beside it (excite two strong frequencies: two-tone or multisine), or sensor noise over the regression band swamps the excitation (keep the low-pass near the excitation band, excite harder)",
            explain::fmt_hz(&lines.merged)
        )
    };
    Some(Refusal::Undetermined { coefficient: name.to_string(), relative_se, limit, explanation })
}

/// Coefficient matrices from the regression vector (`coef[j * 2 + k]`, regressor `j`, force `k`).
fn assemble(model: ModelOrder, coef: &[f64], se: &[f64]) -> Coefficients {
    let m = 2;
    let block = |v: &[f64], first: usize, sign: f64| Matrix2::from_fn(|k, d| sign * v.get((first + d) * m + k).copied().unwrap_or(f64::NAN));
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
            out.push(format!("stiffness and added mass alias at one frequency (K - w^2 M): {} moves at {} only", dir[d], explain::fmt_hz(l)));
        }
        if !dominated(d) && l.is_empty() {
            out.push(format!("no excitation line in {}: its coefficients rest on broadband motion (biased if that motion is sensor noise)", dir[d]));
        }
    }
}

/// Noise fractions below this (60 dB) are at the floor of the spectral estimate.
const EIV_FLOOR: f64 = 1e-6;

/// The solution in the factor's terms, for the flags that need it.
struct Fit<'a> {
    /// Norms of the centred regressor columns.
    scale: &'a [f64],
    /// Unscaled coefficients, `coef[j * 2 + k]` for regressor `j`, force `k`.
    coef: &'a [f64],
    /// Inverse Gram matrix of the scaled regressors, row-major `p × p`.
    ginv_s: &'a [f64],
    /// Standard errors, indexed as `coef`.
    se: &'a [f64],
}

/// Predicted errors-in-variables bias ≥ half a standard error (or ≥ 1 % of the coefficient)
/// flags a window.
const EIV_FLAG_SE: f64 = 0.5;
const EIV_FLAG_RELATIVE: f64 = 0.01;

/// Errors in variables, predicted per coefficient.
///
/// Noise in a regressor (probe noise, ADC quantisation noise) does not average out of least
/// squares: it adds its variance to the Gram matrix, `AᵀA = SᵀS + NᵀN`, while the forces do not
/// correlate with it, so `b → b - (AᵀA)⁻¹ NᵀN b`. What counts is the noise over the **whole
/// regression band** (everything the low-pass passes), not only at the excitation lines, and
/// differentiation makes it worst in the velocities: white probe noise of variance `σ²` gives
/// `x'` a noise variance `≈ σ² (2π)² f_c³ / (3 f_s / 2)` for a low-pass at `f_c`, against a
/// signal `∝ f_line²`. The bias then spreads to every coefficient through `(AᵀA)⁻¹`; at the Zhou
/// point the film force at 20–40 Hz is damping-dominated (`d ω ≈ 3–6 k` for the direct terms), so a small
/// attenuation of the velocity regressors reappears several times larger, relatively, in the
/// smaller stiffness terms.
///
/// Measured (short film, two-tone 23/37 Hz, 30 N, 10 s, 200 Hz low-pass, 1.5 nm white noise
/// on each bearing probe, 24-bit ADC, 200 seeds): the velocity regressors carry a noise
/// fraction of 1.5e-4 (38 dB) and the mean errors moved by kxy −0.09 %, kyx +0.16 %,
/// kyy −0.19 %, dxx −0.06 %, dxy +0.09 %, dyy −0.09 % (dxx: 1.7 standard errors), which is
/// `-(AᵀA)⁻¹ NᵀN b` computed from the actual noise, within the sampling error of the means. With 8 nm (one LSB) and the
/// 16-bit ADC the same term is kyx +4.6 %, kyy −5.5 %, kxy −2.8 %: the 5–9 SE errors single
/// records show at that noise. The 16-bit ADC adds its own quantisation noise (`LSB/√12` =
/// 2.2 nm, identical on both probes of a pair when the probe noise is below an LSB): with
/// 1.5 nm probe noise it raised the velocity noise fraction from 1.5e-4 to 5e-4. An 80 Hz
/// low-pass instead of 200 Hz (the lines are at 23/37 Hz) cut the velocity noise fraction
/// 15.7-fold (60 N, 2.1 nm); the standard errors, set by the noise density at the lines, did
/// not change. In `tests/coverage.rs` (55 N, 40 dB, 16-bit, 80 seeds) the prediction below
/// matches the measured bias of every coefficient it names within 5–15 %.
///
/// Estimate used here: per line-dominated direction, the noise fraction of each regressor is
/// the fraction of its variance outside the excitation lines ([`spectrum`]: `1 - line_fraction`
/// for `x`, `y`, the velocity and acceleration analogues for the others), so `NᵀN` is diagonal
/// with `η_j ‖a_j‖²`, plus, for the added-mass model, `Cov(n, n'') = -Var(n')` between a
/// displacement and its second derivative (exact for a stationary noise and an antisymmetric
/// differentiator). Motion outside the lines that is real (transients, the film's own
/// harmonics) counts as noise, so the prediction errs on the large side.
fn errors_in_variables(out: &mut Vec<String>, model: ModelOrder, lines: &LineAnalysis, fit: &Fit, accel_noise: Option<[f64; 2]>) {
    let p = model.regressors();
    let m = 2;
    if fit.scale.len() < p || fit.coef.len() != p * m || fit.ginv_s.len() != p * p {
        return;
    }
    let clean = |v: f64| if v.is_finite() && v > EIV_FLOOR { v.min(1.0) } else { 0.0 };
    let mut eta = vec![0.0; p];
    for d in 0..2 {
        if lines.line_fraction[d] >= explain::LINE_DOMINATED {
            eta[d] = clean(1.0 - lines.line_fraction[d]);
            eta[2 + d] = clean(lines.velocity_noise_fraction[d]);
            if p == 6 {
                eta[4 + d] = clean(accel_noise.map_or(f64::NAN, |a| a[d]));
            }
        }
    }
    if eta.iter().all(|&e| e == 0.0) {
        return;
    }
    let s = fit.scale;
    // n Σ_nn in scaled coordinates, one matrix per contributing regressor (so the cause of
    // the worst bias can be named): diagonal η_j, and for Kcm the displacement/acceleration
    // cross term -η_{v} s_v² / (s_x s_a), charged to the acceleration.
    let mut parts: Vec<(usize, Vec<f64>)> = Vec::new();
    for j in 0..p {
        if eta[j] == 0.0 {
            continue;
        }
        let mut ns = vec![0.0; p * p];
        ns[j * p + j] = eta[j];
        if p == 6 && j >= 4 {
            let (x, v) = (j - 4, j - 2);
            let cross = -eta[v] * s[v] * s[v] / (s[x] * s[j]);
            ns[x * p + j] = cross;
            ns[j * p + x] = cross;
        }
        parts.push((j, ns));
    }
    // Δb_i = -(1/s_i) Σ_l Ginv_s[i][l] (Ns z)_l, z_j = b_j s_j; the coefficient is -b.
    let shift = |ns: &[f64]| -> Vec<f64> {
        let mut d = vec![0.0; p * m];
        for k in 0..m {
            let z: Vec<f64> = (0..p).map(|j| fit.coef[j * m + k] * s[j]).collect();
            let w: Vec<f64> = (0..p).map(|a| (0..p).map(|b| ns[a * p + b] * z[b]).sum()).collect();
            for i in 0..p {
                let dz: f64 = -(0..p).map(|l| fit.ginv_s[i * p + l] * w[l]).sum::<f64>();
                d[i * m + k] = -dz / s[i];
            }
        }
        d
    };
    let per: Vec<(usize, Vec<f64>)> = parts.iter().map(|(j, ns)| (*j, shift(ns))).collect();
    let total: Vec<f64> = (0..p * m).map(|i| per.iter().map(|(_, d)| d[i]).sum()).collect();
    let names = ["x", "y"];
    let kind = ["k", "k", "d", "d", "m", "m"];
    // (ratio to SE, text) of the coefficients worth naming.
    let mut named: Vec<(f64, usize, String)> = Vec::new();
    for j in 0..p {
        for k in 0..m {
            let i = j * m + k;
            let value = -fit.coef[i];
            let se = fit_se(fit, i);
            let bias = total[i];
            let name = format!("{}{}{}", kind[j], names[k], names[j % 2]);
            let in_se = bias / se;
            let relative = bias / value.abs();
            let big = (se > 0.0 && in_se.abs() >= EIV_FLAG_SE) || (j < 4 && relative.abs() >= EIV_FLAG_RELATIVE);
            if !big || !bias.is_finite() {
                continue;
            }
            let size = if j < 4 { format!("{:+.3} %", 100.0 * relative) } else { format!("{bias:+.2} kg") };
            let sigmas = if se > 0.0 && se.is_finite() { format!(" ({in_se:+.1} SE)") } else { String::new() };
            named.push((if se > 0.0 { in_se.abs() } else { f64::INFINITY }, i, format!("{name} {size}{sigmas}")));
        }
    }
    if named.is_empty() {
        return;
    }
    named.sort_by(|a, b| b.0.total_cmp(&a.0));
    // The regressor whose noise contributes most to the worst coefficient names the headline.
    let worst = named[0].1;
    let cause = per.iter().max_by(|a, b| a.1[worst].abs().total_cmp(&b.1[worst].abs())).map_or(0, |(j, _)| *j);
    let headline = match cause {
        0 | 1 => "stiffness may be biased by displacement noise (errors in variables)",
        2 | 3 => "damping from differentiated noisy displacement may be biased (errors in variables)",
        _ => "added mass from twice-differentiated noisy displacement may be biased (errors in variables)",
    };
    let regressors = model.regressor_names();
    let snr: Vec<String> = (0..p).filter(|&j| eta[j] > 0.0).map(|j| format!("{} {:.1} dB", regressors[j], -10.0 * eta[j].log10())).collect();
    out.push(format!(
        "{headline}: noise in the regressors over the whole regression band, not only at the lines, biases every coefficient it touches, and the standard errors do not include it. Predicted bias: {}. Regressor SNR (variance outside the lines, probe and ADC quantisation noise alike): {}. Less bias: a low-pass cutoff nearer the excitation band (velocity-noise power grows as the cutoff cubed), higher excitation frequencies, quieter probes",
        named.iter().map(|(_, _, t)| t.as_str()).collect::<Vec<_>>().join(", "),
        snr.join(", ")
    ));
}

/// Standard error of regression coefficient `i` (`j * 2 + k`), from the solved window.
fn fit_se(fit: &Fit, i: usize) -> f64 {
    fit.se.get(i).copied().unwrap_or(f64::NAN)
}

/// Warnings about the solved window that do not refuse it.
#[allow(clippy::too_many_arguments)] // the solved window in its parts
fn flags(
    out: &mut Vec<String>,
    model: ModelOrder,
    lines: &LineAnalysis,
    n: usize,
    centred_ss: [f64; 2],
    hac: &uncertainty::Hac,
    fit: &Fit,
    accel_noise: Option<[f64; 2]>,
) {
    errors_in_variables(out, model, lines, fit, accel_noise);
    if hac.lag_capped {
        out.push(
            "the window is so short that the residual spectrum's lag window was clipped to a quarter of it: standard errors may be optimistic".to_string(),
        );
    }
    for (k, name) in ["fx", "fy"].iter().enumerate() {
        let var = centred_ss[k] / n as f64;
        let r2 = 1.0 - hac.residual_rms[k] * hac.residual_rms[k] / var;
        if var > 0.0 && r2 < 0.9 {
            out.push(format!(
                "the linear model explains only {:.1} % of the {name} variation: nonlinear film or unmodelled dynamics (Zhou et al. 2004 saw this at high excitation force)",
                100.0 * r2.max(0.0)
            ));
        }
    }
}
