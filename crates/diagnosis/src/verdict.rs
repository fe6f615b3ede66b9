//! Judging the catalog by **forward selection with held-out scoring**. Every model is fitted on
//! all blocks but one and scored on the block it did not see (contiguous time blocks, so
//! neighbouring samples never straddle the split), then fitted on the whole record for its
//! parameters, a likelihood-ratio test and the BIC. Starting from the linear K-C film, each
//! step tries every catalog effect not yet in the model **on top of the best model so far** and
//! keeps the one that predicts held-out data best, if it *earns* its parameters: held-out
//! error lower by at least [`DiagnosisOptions::min_gain`], lower in most blocks, significant,
//! BIC lower, parameters physical. So a real effect is judged against the film's own
//! nonlinearity once that is in the model, not against a linear baseline it cannot beat.
//!
//! Then the verdict:
//! * `amplitude_nonlinearity` is *named* only when it matters in engineering terms: the
//!   coefficients' relative variation over the record's amplitude (Zhou's RV) exceeds
//!   [`crate::amplitude::RV_THRESHOLD`] on a direct term. Otherwise its terms stay in the model
//!   (the film is never exactly linear) and the output says by how little it matters;
//! * `unexplained` when structure remains that the chosen model does not remove: three general
//!   extensions are tried on top of it ([`crate::catalog::Generic`]: a frequency dependence of
//!   the film force beyond the catalog's, a disagreement of the redundant probes in proportion
//!   to the motion, coefficients that change with time) and one earns at least
//!   [`DiagnosisOptions::structure_gain`]; the output says what it looks like;
//! * otherwise the first named effect selected (the largest gain), the others as `also`;
//! * `none` when nothing named earns and no structure remains;
//! * `insufficient_data` (with a `reason`) when the record is too short, too poorly excited or
//!   too noisy to judge.
//!
//! ## Output contract (`oilfilm diagnose --json`; stable)
//! `cause`, `reason`, `also`, `steps` (each selection step: the model, its held-out NRMSE, every
//! candidate tried against it), `candidates` (each catalog entry's last judgement, best first:
//! `name`, `score` = held-out gain over the model it was tried against, `against`,
//! `heldout_nrmse`, `parameters`, ...), `baseline_heldout_nrmse` (linear K-C),
//! `extended_heldout_nrmse` (the chosen model), `gain` = 1 - extended / baseline, `parameters`
//! and `standard_errors` of the named cause, `amplitude`, `structure`, `coefficients`,
//! `model_update`, `aliases`, `evidence`, `frame`, `notes`.

use std::collections::BTreeMap;

use nalgebra::Matrix2;
use oilfilm_identification::pipeline::{SpeedSource, FRAME};
use oilfilm_identification::record::RawRecord;
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::Calibration;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::amplitude::{self, Amplitude};
use crate::catalog::{self, Cause, Context, Generic, Judged, Part, Spec};
use crate::evidence::{self, Insufficient, PrepareOptions, Prepared};
use crate::model_update::{self, ModelUpdate};
use crate::statistics::{self, LineStructure};
use crate::DiagnosisError;

/// Displacement power ratio (lines over the floor between them) below which a record is too
/// noisy to judge (20 dB).
pub const MIN_MOTION_SNR: f64 = 100.0;
/// Where the film's nonlinearity is at least half-way to mattering, a support friction is
/// named only when it earns this much (see the verdict).
pub const FRICTION_OVER_NONLINEARITY_GAIN: f64 = 0.05;
/// The chosen model's residual is locked to the excitation lines when its line test gives a
/// p-value below this and a ratio (line residual over the floor between the lines) above
/// [`LINE_LOCKED_RATIO`].
pub const LINE_LOCKED_P: f64 = 1e-2;
pub const LINE_LOCKED_RATIO: f64 = 1.2;
/// At most this many effects are selected into one model.
pub const MAX_STEPS: usize = 4;

/// Thresholds of a diagnosis.
#[derive(Debug, Clone, PartialEq)]
pub struct DiagnosisOptions {
    pub prepare: PrepareOptions,
    /// Largest p-value of the likelihood-ratio test for a part to earn.
    pub significance: f64,
    /// Smallest held-out gain `1 - nrmse / nrmse_before` for a catalog effect to earn.
    pub min_gain: f64,
    /// Fraction of held-out blocks in which an earning part must beat the model before it.
    pub min_fold_fraction: f64,
    /// Smallest held-out gain of a general extension on top of the chosen model for the
    /// structure it fits to count as remaining (the verdict `unexplained`).
    pub structure_gain: f64,
    /// Fit and score the model update (the film's clearance, viscosity and theory).
    pub model_update: bool,
}

impl Default for DiagnosisOptions {
    fn default() -> Self {
        Self { prepare: PrepareOptions::default(), significance: 1e-4, min_gain: 0.005, min_fold_fraction: 0.7, structure_gain: 0.06, model_update: true }
    }
}

/// One candidate's judgement against a model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CandidateReport {
    pub name: Cause,
    /// The model it was added to.
    pub against: String,
    /// Held-out gain over that model, `1 - heldout_nrmse / nrmse_before` (negative: it predicts
    /// held-out data worse). `null` when it could not be fitted.
    pub score: Option<f64>,
    pub heldout_nrmse: Option<f64>,
    pub parameters: BTreeMap<String, Value>,
    pub standard_errors: BTreeMap<String, f64>,
    pub extra_parameters: usize,
    /// Likelihood-ratio test against the model before, on the whole record.
    pub p_value: Option<f64>,
    /// BIC(with it) - BIC(without); negative favours it.
    pub delta_bic: Option<f64>,
    /// Held-out blocks where it beat the model before, of `folds`.
    pub folds_improved: usize,
    pub folds: usize,
    pub earns: bool,
    /// Why it was not tried, or why it does not earn.
    pub note: Option<String>,
}

/// One step of the forward selection.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Step {
    pub model: String,
    pub heldout_nrmse: f64,
    pub tried: Vec<CandidateReport>,
    /// The effect added at this step, if any earned.
    pub chosen: Option<Cause>,
}

/// A general extension tried on top of the chosen model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StructureTest {
    pub name: Generic,
    pub score: Option<f64>,
    pub heldout_nrmse: Option<f64>,
    pub folds_improved: usize,
    pub p_value: Option<f64>,
    pub delta_bic: Option<f64>,
    /// Structure remains: it earns with a gain of at least `structure_gain`, or (the frequency
    /// dependence) it earns at the catalog's `min_gain` while the chosen model's residual is
    /// locked to the excitation lines (see the verdict).
    pub remains: bool,
    /// It earns at the catalog's own `min_gain`.
    pub earns_at_min_gain: bool,
    pub parameters: BTreeMap<String, Value>,
    /// What the structure looks like, for a user who has to find its cause.
    pub description: String,
}

/// A pair of effects that look alike, and whether this record tells them apart.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Alias {
    pub pair: [String; 2],
    pub separable: bool,
    pub evidence: String,
}

/// The coefficients a user can keep (crate frame, `dF = -(K r + C r')`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CoefficientReport {
    /// The plain linear K-C fit of the record as measured.
    pub linear_stiffness_n_m: Matrix2<f64>,
    pub linear_damping_n_s_m: Matrix2<f64>,
    /// The chosen model's: small-amplitude, on the corrected data, with standard errors.
    pub stiffness_n_m: Matrix2<f64>,
    pub damping_n_s_m: Matrix2<f64>,
    pub stiffness_se: Matrix2<f64>,
    pub damping_se: Matrix2<f64>,
    /// With a thermal drift in the model: the coefficients at the record's first scan (the
    /// fitted trend there), else `null`.
    pub stiffness_at_start_n_m: Option<Matrix2<f64>>,
    pub damping_at_start_n_s_m: Option<Matrix2<f64>>,
    /// What the chosen model changed: `(chosen - linear) / |linear|`, element by element.
    pub stiffness_relative_change: Matrix2<f64>,
    pub damping_relative_change: Matrix2<f64>,
    /// How fast each coefficient drifts during the record, relative change per second (order
    /// kxx, kxy, cxx, cxy, kyx, kyy, cyx, cyy): from the thermal drift when it is in the
    /// model, else from the time-drift extension when it earns; `null` when neither.
    pub relative_drift_per_s: Option<[f64; 8]>,
}

/// How the record was judged.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvidenceSummary {
    pub samples: usize,
    pub decimation: usize,
    pub decimated_rate_hz: f64,
    pub folds: usize,
    pub excitation_lines_hz: Vec<f64>,
    pub lowpass_cutoff_hz: f64,
    pub speed_rpm: f64,
    pub mean_temperature_c: f64,
    pub force_rms_n: f64,
    pub sensor_weight_n_m: f64,
    /// The probes' velocity noise over the wide band relative to the excited velocity (it
    /// chose the judging band).
    pub velocity_noise_ratio: Option<f64>,
}

/// The diagnosis of one record (the `--json` contract).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Diagnosis {
    pub cause: Cause,
    pub reason: String,
    /// Other named effects the chosen model holds.
    pub also: Vec<Cause>,
    pub steps: Vec<Step>,
    pub candidates: Vec<CandidateReport>,
    pub baseline_heldout_nrmse: Option<f64>,
    pub extended_heldout_nrmse: Option<f64>,
    pub gain: Option<f64>,
    pub parameters: BTreeMap<String, Value>,
    pub standard_errors: BTreeMap<String, f64>,
    pub amplitude: Option<Amplitude>,
    pub structure: Vec<StructureTest>,
    pub coefficients: Option<CoefficientReport>,
    pub model_update: Option<ModelUpdate>,
    pub aliases: Vec<Alias>,
    pub baseline_structure: Option<LineStructure>,
    /// The same line test on what the chosen model leaves (relative to the film force at the
    /// lines): excitation-locked residual the chosen model does not remove.
    pub residual_structure: Option<LineStructure>,
    pub evidence: Option<EvidenceSummary>,
    pub frame: String,
    pub notes: Vec<String>,
}

impl Diagnosis {
    fn insufficient(reason: String) -> Self {
        Self {
            cause: Cause::InsufficientData,
            reason,
            also: Vec::new(),
            steps: Vec::new(),
            candidates: Vec::new(),
            baseline_heldout_nrmse: None,
            extended_heldout_nrmse: None,
            gain: None,
            parameters: BTreeMap::new(),
            standard_errors: BTreeMap::new(),
            amplitude: None,
            structure: Vec::new(),
            coefficients: None,
            model_update: None,
            aliases: Vec::new(),
            baseline_structure: None,
            residual_structure: None,
            evidence: None,
            frame: FRAME.to_string(),
            notes: Vec::new(),
        }
    }
}

/// How a part judged against a model fares.
struct Comparison {
    gain: f64,
    nrmse: f64,
    p_value: f64,
    delta_bic: f64,
    improved: usize,
    why_not: Vec<String>,
}

fn compare(before: &Judged, after: &Judged, part: Part, sst: f64, options: &DiagnosisOptions, min_gain: f64) -> Comparison {
    let (n0, n1) = (before.nrmse(sst), after.nrmse(sst));
    let gain = 1.0 - n1 / n0;
    let extra = after.extra_parameters.saturating_sub(before.extra_parameters).max(1);
    let p_value = statistics::likelihood_ratio_p(before.sse, after.sse, after.rows, extra);
    let delta_bic = statistics::delta_bic(before.sse, after.sse, after.rows, extra);
    let improved = after.block_sse.iter().zip(&before.block_sse).filter(|(a, b)| a < b).count();
    let folds = after.block_sse.len();
    let mut why_not = Vec::new();
    if gain < min_gain {
        why_not.push(format!("held-out gain {:.2} % below {:.2} %", 100.0 * gain, 100.0 * min_gain));
    }
    if (improved as f64) < options.min_fold_fraction * folds as f64 {
        why_not.push(format!("better in only {improved} of {folds} held-out blocks"));
    }
    if p_value >= options.significance {
        why_not.push(format!("not significant (p = {p_value:.2e})"));
    }
    if delta_bic >= 0.0 {
        why_not.push(format!("BIC does not favour it (+{delta_bic:.1})"));
    }
    if let Some(Err(why)) = after.physical.get(&part) {
        why_not.push(why.clone());
    }
    Comparison { gain, nrmse: n1, p_value, delta_bic, improved, why_not }
}

fn structure_of(p: &Prepared) -> Option<LineStructure> {
    let s = &p.series;
    let d = |v: &[f64]| p.detrended(v);
    let (x, y, vx, vy, fx, fy) = (d(&s.x_m), d(&s.y_m), d(&s.vx_m_s), d(&s.vy_m_s), d(&s.fx_n), d(&s.fy_n));
    let shaft_hz = p.speed_rpm / 60.0;
    statistics::line_structure([&x, &y, &vx, &vy], [&fx, &fy], &s.t_s, &p.lines_hz, 0.5 * p.rate_hz, &[shaft_hz, 2.0 * shaft_hz])
}

/// The line test on the chosen model's force residual, against the film force at the lines.
fn residual_structure_of(p: &Prepared, chosen: &Judged) -> Option<LineStructure> {
    let s = &chosen.series;
    let n = p.len();
    let d = |v: &[f64]| p.detrended(v);
    let (x, y, vx, vy, fx, fy) = (d(&s.x_m), d(&s.y_m), d(&s.vx_m_s), d(&s.vy_m_s), d(&s.fx_n), d(&s.fy_n));
    let rx: Vec<f64> = chosen.force_residual.rows(0, n).iter().copied().collect();
    let ry: Vec<f64> = chosen.force_residual.rows(n, n).iter().copied().collect();
    let shaft_hz = p.speed_rpm / 60.0;
    statistics::line_structure_normed([&x, &y, &vx, &vy], [&rx, &ry], [&fx, &fy], &s.t_s, &p.lines_hz, 0.5 * p.rate_hz, &[shaft_hz, 2.0 * shaft_hz])
}

/// Diagnoses a record: see the module documentation.
pub fn diagnose(
    raw: &RawRecord,
    calibration: &Calibration,
    rig: &RigConfig,
    speed_rpm: f64,
    speed_source: SpeedSource,
    options: &DiagnosisOptions,
) -> Result<Diagnosis, DiagnosisError> {
    let p = match evidence::prepare(raw, calibration, rig, speed_rpm, speed_source, &options.prepare)? {
        Ok(p) => p,
        Err(Insufficient(reason)) => return Ok(Diagnosis::insufficient(reason)),
    };
    let mut d = diagnose_prepared(&p, rig, options)?;
    if speed_source == SpeedSource::RigFile {
        d.notes.push("the record states no speed: the rig file's was assumed (1X runout is looked for at that speed)".into());
    }
    Ok(d)
}

/// Diagnoses a prepared record (its one conditioning shared with the report).
pub fn diagnose_prepared(p: &Prepared, rig: &RigConfig, options: &DiagnosisOptions) -> Result<Diagnosis, DiagnosisError> {
    let baseline_structure = structure_of(p);
    if let Some(s) = baseline_structure.filter(|s| s.motion_snr < MIN_MOTION_SNR) {
        return Ok(Diagnosis::insufficient(format!(
            "too noisy: the motion at the excitation lines stands only {:.1} dB above the noise between them (at least {:.0} dB needed to judge any model); excite harder or record longer",
            10.0 * s.motion_snr.log10(),
            10.0 * MIN_MOTION_SNR.log10()
        )));
    }
    let ctx = Context::new(p, rig)?;
    let sst = p.force_sst();
    let folds = p.blocks.len();
    let baseline = ctx.judge(&Spec::default())?;
    let nrmse0 = baseline.nrmse(sst);
    let mut notes = p.notes.clone();
    if p.lines_hz.len() < 3 {
        notes.push(format!(
            "only {} excitation line(s): frequency-dependent effects (added mass, delays) cannot be told from stiffness and damping; excite a band (multisine) to see them",
            p.lines_hz.len()
        ));
    }

    // Forward selection.
    let mut last: BTreeMap<Cause, CandidateReport> = BTreeMap::new();
    let mut remaining = Vec::new();
    for c in Cause::CATALOG {
        match ctx.applicable(c) {
            Ok(()) => remaining.push(c),
            Err(why) => {
                last.insert(c, not_tried(c, &Spec::default(), folds, format!("not tried: {why}")));
            }
        }
    }
    let mut current = baseline.clone();
    let mut steps = Vec::new();
    for _ in 0..MAX_STEPS {
        let mut tried = Vec::new();
        let mut best: Option<(Cause, Judged, f64)> = None;
        for &c in &remaining {
            let spec = current.spec.with(Part::Named(c));
            match ctx.judge(&spec) {
                Ok(j) => {
                    let cmp = compare(&current, &j, Part::Named(c), sst, options, options.min_gain);
                    let part = Part::Named(c);
                    let report = CandidateReport {
                        name: c,
                        against: current.spec.describe(),
                        score: Some(cmp.gain),
                        heldout_nrmse: Some(cmp.nrmse),
                        parameters: j.parameters.get(&part).cloned().unwrap_or_default(),
                        standard_errors: j.standard_errors.get(&part).cloned().unwrap_or_default(),
                        extra_parameters: j.extra_parameters - current.extra_parameters.min(j.extra_parameters),
                        p_value: Some(cmp.p_value),
                        delta_bic: Some(cmp.delta_bic),
                        folds_improved: cmp.improved,
                        folds,
                        earns: cmp.why_not.is_empty(),
                        note: (!cmp.why_not.is_empty()).then(|| cmp.why_not.join("; ")),
                    };
                    if report.earns && best.as_ref().is_none_or(|b| cmp.gain > b.2) {
                        best = Some((c, j, cmp.gain));
                    }
                    tried.push(report);
                }
                Err(e) => tried.push(not_tried(c, &current.spec, folds, format!("could not be fitted: {e}"))),
            }
        }
        tried.sort_by(|a, b| b.score.unwrap_or(f64::NEG_INFINITY).total_cmp(&a.score.unwrap_or(f64::NEG_INFINITY)));
        for r in &tried {
            last.insert(r.name, r.clone());
        }
        let chosen = best.as_ref().map(|b| b.0);
        steps.push(Step { model: current.spec.describe(), heldout_nrmse: current.nrmse(sst), tried, chosen });
        let Some((c, j, _)) = best else { break };
        remaining.retain(|r| *r != c);
        current = j;
    }
    let chosen = current;
    let nrmse1 = chosen.nrmse(sst);

    // Does the film's nonlinearity matter?
    let amplitude = Some(amplitude::assess(&ctx, &chosen, rig)?);
    let nonlinearity_matters = amplitude.as_ref().is_some_and(|a| a.matters);

    // Structure the chosen model leaves.
    let mut structure: Vec<StructureTest> = Vec::new();
    for g in Generic::ALL {
        let spec = chosen.spec.with(Part::Generic(g));
        let test = match ctx.judge(&spec) {
            Ok(j) => {
                let cmp = compare(&chosen, &j, Part::Generic(g), sst, options, options.structure_gain);
                let parameters = j.parameters.get(&Part::Generic(g)).cloned().unwrap_or_default();
                let remains = cmp.why_not.is_empty();
                let earns_at_min_gain = compare(&chosen, &j, Part::Generic(g), sst, options, options.min_gain).why_not.is_empty();
                StructureTest {
                    name: g,
                    score: Some(cmp.gain),
                    heldout_nrmse: Some(cmp.nrmse),
                    folds_improved: cmp.improved,
                    p_value: Some(cmp.p_value),
                    delta_bic: Some(cmp.delta_bic),
                    remains,
                    earns_at_min_gain,
                    description: describe_structure(g, &parameters, cmp.gain, p),
                    parameters,
                }
            }
            Err(e) => StructureTest {
                name: g,
                score: None,
                heldout_nrmse: None,
                folds_improved: 0,
                p_value: None,
                delta_bic: None,
                remains: false,
                earns_at_min_gain: false,
                parameters: BTreeMap::new(),
                description: format!("could not be fitted: {e}"),
            },
        };
        structure.push(test);
    }

    let mut named: Vec<Cause> = chosen.spec.causes().filter(|c| *c != Cause::AmplitudeNonlinearity || nonlinearity_matters).collect();
    // At amplitudes where the film's nonlinearity is at least half-way to mattering, what the
    // polynomial leaves of it (the cavitated arc switching with the squeeze velocity) looks
    // like a Coulomb friction: a friction that earns only a little is then not named.
    let mut friction_alias = None;
    if let Some(a) = amplitude.as_ref().filter(|a| a.largest_direct - 2.0 * a.largest_direct_se > 0.5 * a.threshold) {
        let gain = last.get(&Cause::SupportFriction).filter(|_| chosen.spec.has(Cause::SupportFriction)).and_then(|r| r.score);
        if let Some(g) = gain.filter(|g| *g < FRICTION_OVER_NONLINEARITY_GAIN) {
            named.retain(|c| *c != Cause::SupportFriction);
            friction_alias = Some(Alias {
                pair: ["support_friction".into(), "amplitude_nonlinearity".into()],
                separable: false,
                evidence: format!(
                    "a friction-like force earns {:.1} % at an amplitude where the film's coefficients vary by {:.1} %: the film's own velocity nonlinearity that a polynomial does not hold looks the same; a friction is named only when it earns at least {:.0} % here (measure at a smaller amplitude to separate them)",
                    100.0 * g,
                    100.0 * a.largest_direct,
                    100.0 * FRICTION_OVER_NONLINEARITY_GAIN
                ),
            });
        }
    }
    // In a noisy record a structure shows less as a relative gain than as residual locked to
    // the excitation lines: the frequency dependence then counts when it earns (at the
    // catalog's own bar) and what the chosen model leaves at the lines stands clearly above
    // the floor between them.
    let residual_lines = residual_structure_of(p, &chosen);
    if let Some(rl) = residual_lines.filter(|r| r.p_value < LINE_LOCKED_P && r.ratio >= LINE_LOCKED_RATIO) {
        if !nonlinearity_matters {
            for s in &mut structure {
                if s.name == Generic::FrequencyDependence && !s.remains && s.earns_at_min_gain {
                    s.remains = true;
                    s.description.push_str(&format!(
                        " (in a residual locked to the excitation lines: {:.1} times the floor between them, p = {:.1e})",
                        rl.ratio, rl.p_value
                    ));
                }
            }
        }
    }
    // Where the film's nonlinearity matters, a polynomial of finite order leaves part of it at
    // the excitation lines (odd-order distortion lands there), which a frequency dependence
    // partly fits: it counts as remaining structure only at twice the threshold.
    for s in &mut structure {
        if nonlinearity_matters && s.name == Generic::FrequencyDependence && s.remains && s.score.unwrap_or(0.0) < 2.0 * options.structure_gain {
            s.remains = false;
            s.description.push_str(&format!(
                " (not counted: with the film's nonlinearity this large, the polynomial's truncation leaves line-locked residual of this size; at least {:.0} % would be needed)",
                200.0 * options.structure_gain
            ));
        }
    }
    // With fewer than three excitation lines, K and C already fit the lines exactly (two
    // complex equations per force axis, four real unknowns): a frequency dependence has
    // nothing at the lines to be judged on, and whatever it earns comes from the content
    // between them (harmonics, ripple, noise). It is reported, never counted.
    if p.lines_hz.len() < 3 {
        for s in &mut structure {
            if s.name == Generic::FrequencyDependence && s.remains {
                s.remains = false;
                s.description.push_str(&format!(
                    " (not counted: with {} excitation line(s) K and C fit the lines exactly, so what a frequency dependence earns comes from content between them; excite a band to judge it)",
                    p.lines_hz.len()
                ));
            }
        }
    }
    let remaining_structure: Vec<&StructureTest> = structure.iter().filter(|s| s.remains).collect();

    let mut coefficients = coefficient_report(&ctx, &baseline, &chosen);
    let seconds = p.series.t_s.last().copied().unwrap_or(0.0) - p.series.t_s.first().copied().unwrap_or(0.0);
    if coefficients.relative_drift_per_s.is_none() && seconds > 0.0 {
        if let Some(t) = structure.iter().find(|t| t.name == Generic::TimeDrift && t.earns_at_min_gain) {
            let rel: Option<Vec<f64>> = t.parameters.get("relative_change_over_record").and_then(|v| serde_json::from_value(v.clone()).ok());
            coefficients.relative_drift_per_s = rel.filter(|r| r.len() == 8).map(|r| std::array::from_fn(|k| r[k] / seconds));
        }
    }
    let model_update = if options.model_update {
        match model_update::update(&ctx, &chosen, rig) {
            Ok(u) => Some(u),
            Err(e) => {
                notes.push(format!("no model update: {e}"));
                None
            }
        }
    } else {
        None
    };

    let mut out = Diagnosis {
        cause: Cause::None,
        reason: String::new(),
        also: Vec::new(),
        steps,
        candidates: {
            let mut v: Vec<CandidateReport> = last.into_values().collect();
            v.sort_by(|a, b| b.score.unwrap_or(f64::NEG_INFINITY).total_cmp(&a.score.unwrap_or(f64::NEG_INFINITY)));
            v
        },
        baseline_heldout_nrmse: Some(nrmse0),
        extended_heldout_nrmse: Some(nrmse1),
        gain: Some(1.0 - nrmse1 / nrmse0),
        parameters: BTreeMap::new(),
        standard_errors: BTreeMap::new(),
        amplitude,
        structure: structure.clone(),
        coefficients: Some(coefficients),
        model_update,
        aliases: Vec::new(),
        baseline_structure,
        residual_structure: residual_lines,
        evidence: Some(EvidenceSummary {
            samples: p.raw.len(),
            decimation: p.decimation,
            decimated_rate_hz: p.rate_hz,
            folds,
            excitation_lines_hz: p.lines_hz.clone(),
            lowpass_cutoff_hz: p.cutoff_hz,
            speed_rpm: p.speed_rpm,
            mean_temperature_c: p.mean_temperature_c,
            force_rms_n: p.force_rms_n,
            sensor_weight_n_m: p.sensor_weight_n_m,
            velocity_noise_ratio: p.velocity_noise_ratio,
        }),
        frame: FRAME.to_string(),
        notes,
    };
    let amplitude_text = out.amplitude.as_ref().map(|a| {
        format!(
            "the coefficients vary by {:.1} +- {:.1} % (largest direct term) over the record's amplitude d = {:.3}{} (named above {:.0} % beyond two standard errors)",
            100.0 * a.largest_direct,
            100.0 * a.largest_direct_se,
            a.d,
            a.film_model_largest_direct.map_or(String::new(), |m| format!("; the film model predicts {:.1} % there", 100.0 * m)),
            100.0 * a.threshold
        )
    });
    if !remaining_structure.is_empty() {
        out.cause = Cause::Unexplained;
        let what: Vec<String> = remaining_structure.iter().map(|s| s.description.clone()).collect();
        out.reason = format!(
            "structure remains that {} does not remove: {}{}",
            if named.is_empty() { "no catalog effect".to_string() } else { format!("the best catalog model ({})", chosen.spec.describe()) },
            what.join("; "),
            if named.is_empty() { String::new() } else { format!(". Closest catalog effect: {}", named[0]) }
        );
        out.also = named;
    } else if let Some(&first) = named.first() {
        out.cause = first;
        out.also = named[1..].to_vec();
        let part = Part::Named(first);
        out.parameters = chosen.parameters.get(&part).cloned().unwrap_or_default();
        out.standard_errors = chosen.standard_errors.get(&part).cloned().unwrap_or_default();
        if first == Cause::AmplitudeNonlinearity {
            if let Some(a) = &out.amplitude {
                out.parameters.insert("relative_variation_largest_direct".into(), serde_json::json!(a.largest_direct));
                out.parameters.insert("amplitude_d".into(), serde_json::json!(a.d));
            }
        }
        let entered = out.candidates.iter().find(|c| c.name == first);
        out.reason = format!(
            "{} predicts held-out blocks {:.1} % better than {} (NRMSE {:.4} against {:.4}), in {} of {} blocks; the chosen model ({}) predicts {:.1} % better than the linear one{}",
            first,
            100.0 * entered.and_then(|c| c.score).unwrap_or(f64::NAN),
            entered.map_or("the model before it", |c| c.against.as_str()),
            entered.and_then(|c| c.heldout_nrmse).unwrap_or(f64::NAN),
            entered.and_then(|c| c.heldout_nrmse.zip(c.score).map(|(h, s)| h / (1.0 - s))).unwrap_or(f64::NAN),
            entered.map_or(0, |c| c.folds_improved),
            folds,
            chosen.spec.describe(),
            100.0 * (1.0 - nrmse1 / nrmse0),
            if first == Cause::AmplitudeNonlinearity { amplitude_text.as_ref().map_or(String::new(), |t| format!("; {t}")) } else { String::new() }
        );
        out.aliases = aliases(&ctx, first, &chosen, sst, options);
    } else {
        out.cause = Cause::None;
        out.reason = format!(
            "the linear K-C film is adequate: no catalog effect earns its parameters and no structure remains (held-out NRMSE {nrmse1:.4}){}",
            if chosen.spec.has(Cause::AmplitudeNonlinearity) {
                format!("; the film's own nonlinearity is in the model but does not matter here: {}", amplitude_text.unwrap_or_default())
            } else {
                String::new()
            }
        );
    }
    out.aliases.extend(friction_alias);
    Ok(out)
}

fn not_tried(c: Cause, against: &Spec, folds: usize, note: String) -> CandidateReport {
    CandidateReport {
        name: c,
        against: against.describe(),
        score: None,
        heldout_nrmse: None,
        parameters: BTreeMap::new(),
        standard_errors: BTreeMap::new(),
        extra_parameters: 0,
        p_value: None,
        delta_bic: None,
        folds_improved: 0,
        folds,
        earns: false,
        note: Some(note),
    }
}

/// What a general extension that earns says about the record.
fn describe_structure(g: Generic, params: &BTreeMap<String, Value>, gain: f64, p: &Prepared) -> String {
    let m2 = |key: &str| -> Option<[[f64; 2]; 2]> { serde_json::from_value(params.get(key)?.clone()).ok() };
    match g {
        Generic::FrequencyDependence => {
            let m = m2("mass_matrix_kg").unwrap_or([[f64::NAN; 2]; 2]);
            let iso = 0.5 * (m[0][0] + m[1][1]);
            format!(
                "the film force departs from K + i w C at the excitation lines ({:.1}-{:.1} Hz) in a way no catalog effect reproduces: its apparent mass matrix is [[{:.1}, {:.1}], [{:.1}, {:.1}]] kg (an isotropic added mass would be [[{iso:.1}, 0], [0, {iso:.1}]]); a frequency-dependent or anisotropic film force or a force measurement error (exciter angles, force-sensor dynamics) predicts {:.1} % better",
                p.lines_hz.first().copied().unwrap_or(f64::NAN),
                p.lines_hz.last().copied().unwrap_or(f64::NAN),
                m[0][0],
                m[0][1],
                m[1][0],
                m[1][1],
                100.0 * gain
            )
        }
        Generic::SensorDisagreement => {
            let j = m2("journal_per_motion").unwrap_or([[f64::NAN; 2]; 2]);
            let t = m2("tilt_per_motion").unwrap_or([[f64::NAN; 2]; 2]);
            format!(
                "the redundant probes disagree in proportion to the motion: bearing + frame probes (J = r + X, zero for a journal fixed in space) read [[{:+.2}, {:+.2}], [{:+.2}, {:+.2}]] % of r, end A - end B [[{:+.2}, {:+.2}], [{:+.2}, {:+.2}]] % of r; a sensitivity, orientation or cross-talk error of a probe set (recalibrate against each other) explains {:.1} % of the held-out error",
                100.0 * j[0][0],
                100.0 * j[0][1],
                100.0 * j[1][0],
                100.0 * j[1][1],
                100.0 * t[0][0],
                100.0 * t[0][1],
                100.0 * t[1][0],
                100.0 * t[1][1],
                100.0 * gain
            )
        }
        Generic::TimeDrift => {
            let rel: Vec<f64> = params.get("relative_change_over_record").and_then(|v| serde_json::from_value(v.clone()).ok()).unwrap_or_default();
            let seconds = p.series.t_s.last().copied().unwrap_or(0.0) - p.series.t_s.first().copied().unwrap_or(0.0);
            let direct: Vec<String> = [(0usize, "kxx"), (5, "kyy"), (2, "cxx"), (7, "cyy")]
                .iter()
                .filter_map(|&(k, name)| rel.get(k).map(|r| format!("{name} {:+.2} %/s", 100.0 * r / seconds.max(f64::MIN_POSITIVE))))
                .collect();
            format!(
                "the coefficients drift during the record ({}) while the bearing temperature {}: a non-stationarity no catalog effect names (a probe's sensitivity or zero drifting, the load or speed changing); identify in shorter windows",
                direct.join(", "),
                format_args!("changes by {:.2} C", p.series.temperature_c.iter().copied().fold(f64::NEG_INFINITY, f64::max) - p.series.temperature_c.iter().copied().fold(f64::INFINITY, f64::min))
            )
        }
    }
}

/// The coefficients of the linear fit and of the chosen model.
fn coefficient_report(ctx: &Context, linear: &Judged, chosen: &Judged) -> CoefficientReport {
    let (k0, c0) = linear.stiffness_damping();
    let (k, c) = chosen.stiffness_damping();
    let se = chosen.kc_se;
    let rel = |a: &Matrix2<f64>, b: &Matrix2<f64>| Matrix2::from_fn(|i, j| (a[(i, j)] - b[(i, j)]) / b[(i, j)].abs());
    let (mut k_start, mut c_start) = (None, None);
    let mut drift_per_s = None;
    if chosen.spec.has(Cause::ThermalDrift) {
        if let Some(d) = ctx.drift() {
            // The fitted trend of every coefficient, at the first judged sample.
            let slopes = chosen.part_theta(Part::Named(Cause::ThermalDrift));
            if slopes.len() == 16 {
                let dt0 = d.delta_t_start_c;
                let at: [f64; 8] = std::array::from_fn(|i| chosen.kc[i] + slopes[i] * dt0 + slopes[8 + i] * dt0 * dt0);
                let (ks, cs) = catalog::coefficients_of(&at);
                k_start = Some(ks);
                c_start = Some(cs);
                // Per second, at the mean temperature: the slope per C times the temperature's
                // rate over the record.
                let p = ctx.p;
                let seconds = p.raw.len() as f64 / p.raw.sample_rate_hz;
                drift_per_s = Some(std::array::from_fn(|i| slopes[i] / chosen.kc[i] * d.rise_c / seconds));
            }
        }
    }
    CoefficientReport {
        linear_stiffness_n_m: k0,
        linear_damping_n_s_m: c0,
        stiffness_n_m: k,
        damping_n_s_m: c,
        stiffness_se: Matrix2::new(se[0], se[1], se[4], se[5]),
        damping_se: Matrix2::new(se[2], se[3], se[6], se[7]),
        stiffness_at_start_n_m: k_start,
        damping_at_start_n_s_m: c_start,
        stiffness_relative_change: rel(&k, &k0),
        damping_relative_change: rel(&c, &c0),
        relative_drift_per_s: drift_per_s,
    }
}

/// The journal counts as fixed when its motion at the excitation lines is below this fraction
/// of the journal-bearing motion there.
pub const JOURNAL_FIXED_RATIO: f64 = 0.05;

/// The aliasing pairs relevant to the named cause, with what this record says about each.
fn aliases(ctx: &Context, named: Cause, chosen: &Judged, sst: f64, options: &DiagnosisOptions) -> Vec<Alias> {
    let p = ctx.p;
    let mut out = Vec::new();
    let s = &p.series;
    if named == Cause::FluidInertia {
        // Does the journal move? Its position J = r + X compared with the relative motion r at
        // the excitation lines, where the probes' noise is one DFT bin against a whole line.
        let [jx, jy] = s.journal_m();
        let (jx, jy, rx, ry) = (p.detrended(&jx), p.detrended(&jy), p.detrended(&s.x_m), p.detrended(&s.y_m));
        let lp = |v: &[f64]| statistics::line_power(v, &s.t_s, &p.lines_hz);
        let ratio = ((lp(&jx) + lp(&jy)) / (lp(&rx) + lp(&ry)).max(f64::MIN_POSITIVE)).sqrt();
        let fixed = ratio < JOURNAL_FIXED_RATIO;
        let mass = chosen.parameters.get(&Part::Named(Cause::FluidInertia)).and_then(|m| m.get("added_mass_kg")).and_then(Value::as_f64).unwrap_or(f64::NAN);
        out.push(Alias {
            pair: ["fluid_inertia".into(), "housing_mass_error".into()],
            separable: !fixed,
            evidence: if fixed {
                format!(
                    "the journal is fixed (its motion at the excitation lines is {:.2} % of the journal-bearing motion): the housing's acceleration is minus the journal-bearing acceleration, so an error of the configured housing mass in eq. 2 is indistinguishable from this added mass ({mass:.2} kg); weigh the housing or run with the film unloaded to separate them",
                    100.0 * ratio
                )
            } else {
                format!("the journal moves ({:.1} % of the journal-bearing motion at the lines): housing and journal-bearing accelerations differ, so an added mass in the film and an error in the configured housing mass act on different signals", 100.0 * ratio)
            },
        });
    }
    if matches!(named, Cause::FluidInertia | Cause::ChannelDelay) {
        // Skew against inertia: swap the one for the other in the chosen model and compare
        // held-out blocks pairwise.
        let other = if named == Cause::FluidInertia { Cause::ChannelDelay } else { Cause::FluidInertia };
        let mut swapped = Spec { parts: chosen.spec.parts.iter().copied().filter(|p| *p != Part::Named(named)).collect() };
        swapped = swapped.with(Part::Named(other));
        if let Ok(o) = ctx.judge(&swapped) {
            let wins = chosen.block_sse.iter().zip(&o.block_sse).filter(|(a, b)| a < b).count();
            let separable = (wins as f64) >= options.min_fold_fraction * chosen.block_sse.len() as f64;
            out.push(Alias {
                pair: [named.name().into(), other.name().into()],
                separable,
                evidence: format!(
                    "{named} beats {other} in {wins} of {} held-out blocks (NRMSE {:.4} against {:.4}){}; a channel delay shifts one channel's phase in proportion to frequency and shows in the redundant probes when it is a probe's, an added mass acts on both force axes alike",
                    chosen.block_sse.len(),
                    chosen.nrmse(sst),
                    o.nrmse(sst),
                    if separable { "" } else { ": this record does not separate them" }
                ),
            });
        }
    }
    out
}
