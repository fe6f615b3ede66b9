//! Judging the catalog: every candidate is fitted on all blocks but one and scored on the block
//! it did not see (contiguous time blocks, so neighbouring samples never straddle the split),
//! then fitted on the whole record for its parameters, a likelihood-ratio test and the BIC.
//! A candidate *earns* its parameters only if all of these agree: held-out error lower by at
//! least [`DiagnosisOptions::min_gain`], lower in most blocks, significant, BIC lower,
//! parameters physical. The verdict:
//!
//! * the best earning candidate, if it also removes most of the excitation-locked residual
//!   the baseline left ([`crate::statistics::line_structure`]);
//! * `unexplained` if the baseline leaves excitation-locked residual that no candidate
//!   removes (or the best removes only part of it);
//! * `none` if no candidate earns and the baseline's residual is noise at the lines;
//! * `insufficient_data` (with a `reason`) if the record is too short, too poorly excited or
//!   too noisy to judge.
//!
//! ## Output contract (`oilfilm diagnose --json`; stable)
//! `cause`, `reason`, `candidates` (best first: `name`, `score` = held-out gain,
//! `heldout_nrmse`, `parameters`, ...), `baseline_heldout_nrmse`, `extended_heldout_nrmse`,
//! `gain` = 1 - extended / baseline, `parameters` and `standard_errors` of the named cause,
//! `aliases` (pairs of effects and whether this record separates them), `coefficients`
//! (baseline against extended K and C), `evidence`, `frame`, `notes`.

use std::collections::BTreeMap;

use nalgebra::Matrix2;
use oilfilm_identification::conditioning::RawRecord;
use oilfilm_identification::pipeline::{SpeedSource, FRAME};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::Calibration;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::catalog::{self, Baseline, Candidate, Cause, Fitted};
use crate::evidence::{self, Insufficient, PrepareOptions, Prepared};
use crate::statistics::{self, LineStructure};
use crate::DiagnosisError;

/// Displacement power ratio (lines over the floor between them) below which a record is too
/// noisy to judge (20 dB).
pub const MIN_MOTION_SNR: f64 = 100.0;

/// Thresholds of a diagnosis.
#[derive(Debug, Clone, PartialEq)]
pub struct DiagnosisOptions {
    pub prepare: PrepareOptions,
    /// Largest p-value of the likelihood-ratio test for a candidate to earn.
    pub significance: f64,
    /// Smallest held-out gain `1 - nrmse / nrmse_baseline` for a candidate to earn.
    pub min_gain: f64,
    /// Fraction of held-out blocks in which an earning candidate must beat the baseline.
    pub min_fold_fraction: f64,
    /// The baseline's residual counts as excitation-locked when its line test gives a
    /// p-value below this and a relative amplitude above `min_structure`.
    pub structure_p: f64,
    pub min_structure: f64,
    /// The winner must remove at least this fraction of the baseline's line-locked residual
    /// amplitude, or the verdict is `unexplained`.
    pub explained_fraction: f64,
    /// A baseline held-out NRMSE above this with nothing line-locked means noise rules.
    pub max_noise_nrmse: f64,
}

impl Default for DiagnosisOptions {
    fn default() -> Self {
        Self {
            prepare: PrepareOptions::default(),
            significance: 1e-4,
            min_gain: 0.005,
            min_fold_fraction: 0.7,
            structure_p: 1e-6,
            min_structure: 0.01,
            explained_fraction: 0.3,
            max_noise_nrmse: 0.7,
        }
    }
}

/// One candidate's judgement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CandidateReport {
    pub name: Cause,
    /// Held-out gain over the baseline, `1 - heldout_nrmse / baseline_heldout_nrmse`
    /// (negative: it predicts held-out data worse). `null` when the candidate could not be
    /// fitted.
    pub score: Option<f64>,
    pub heldout_nrmse: Option<f64>,
    pub parameters: BTreeMap<String, Value>,
    pub standard_errors: BTreeMap<String, f64>,
    pub extra_parameters: usize,
    /// Likelihood-ratio test against the baseline on the whole record.
    pub p_value: Option<f64>,
    /// BIC(candidate) - BIC(baseline); negative favours the candidate.
    pub delta_bic: Option<f64>,
    /// Held-out blocks where it beat the baseline, of `folds`.
    pub folds_improved: usize,
    pub folds: usize,
    pub earns: bool,
    /// Fraction of the baseline's excess (line-locked) residual power its held-out gain
    /// accounts for: `(nrmse_0^2 - nrmse^2) / structure^2`; `null` without a line test.
    pub explained_fraction: Option<f64>,
    /// Why it was not tried, or why it does not earn.
    pub note: Option<String>,
}

/// A pair of effects that look alike, and whether this record tells them apart.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Alias {
    pub pair: [String; 2],
    pub separable: bool,
    pub evidence: String,
}

/// Baseline and extended coefficients (crate frame, `dF = -(K r + C r')`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CoefficientChange {
    pub baseline_stiffness_n_m: Matrix2<f64>,
    pub baseline_damping_n_s_m: Matrix2<f64>,
    pub extended_stiffness_n_m: Matrix2<f64>,
    pub extended_damping_n_s_m: Matrix2<f64>,
    /// `(extended - baseline) / |baseline|` element by element.
    pub stiffness_relative_change: Matrix2<f64>,
    pub damping_relative_change: Matrix2<f64>,
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
    pub tilt_weight_n_m: f64,
}

/// The diagnosis of one record (the `--json` contract).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Diagnosis {
    pub cause: Cause,
    pub reason: String,
    pub candidates: Vec<CandidateReport>,
    pub baseline_heldout_nrmse: Option<f64>,
    pub extended_heldout_nrmse: Option<f64>,
    pub gain: Option<f64>,
    pub parameters: BTreeMap<String, Value>,
    pub standard_errors: BTreeMap<String, f64>,
    pub aliases: Vec<Alias>,
    pub coefficients: Option<CoefficientChange>,
    pub baseline_structure: Option<LineStructure>,
    pub evidence: Option<EvidenceSummary>,
    pub frame: String,
    pub notes: Vec<String>,
}

impl Diagnosis {
    fn insufficient(reason: String) -> Self {
        Self {
            cause: Cause::InsufficientData,
            reason,
            candidates: Vec::new(),
            baseline_heldout_nrmse: None,
            extended_heldout_nrmse: None,
            gain: None,
            parameters: BTreeMap::new(),
            standard_errors: BTreeMap::new(),
            aliases: Vec::new(),
            coefficients: None,
            baseline_structure: None,
            evidence: None,
            frame: FRAME.to_string(),
            notes: Vec::new(),
        }
    }
}

/// A candidate ready to fit, or why it is not tried on this record.
type Ready = Result<Box<dyn Candidate>, String>;

/// A candidate's set-up: ready, not applicable to this record (why), or failed (why).
fn set_up<C: Candidate + 'static>(r: Result<Result<C, String>, DiagnosisError>) -> Ready {
    match r {
        Ok(Ok(c)) => Ok(Box::new(c)),
        Ok(Err(why)) => Err(why),
        Err(e) => Err(format!("could not be set up: {e}")),
    }
}

/// Held-out residual sums of squares per block and the whole-record fit of one model.
struct Judged {
    block_sse: Vec<f64>,
    full: Fitted,
}

fn sse_over(residual: &nalgebra::DVector<f64>, rows: impl Iterator<Item = usize>) -> f64 {
    rows.map(|i| residual[i] * residual[i]).sum()
}

fn judge(p: &Prepared, fit: &dyn Fn(&[bool]) -> Result<Fitted, DiagnosisError>) -> Result<Judged, DiagnosisError> {
    let mut block_sse = Vec::with_capacity(p.blocks.len());
    for b in 0..p.blocks.len() {
        let f = fit(&p.train_mask(Some(b)))?;
        block_sse.push(sse_over(&f.residual, p.block_rows(b)));
    }
    let full = fit(&p.train_mask(None))?;
    Ok(Judged { block_sse, full })
}

fn structure_of(p: &Prepared) -> Option<LineStructure> {
    let s = &p.series;
    let d = |v: &[f64]| {
        let mut v = v.to_vec();
        p.detrend(&mut v);
        v
    };
    let (x, y, vx, vy, fx, fy) = (d(&s.x_m), d(&s.y_m), d(&s.vx_m_s), d(&s.vy_m_s), d(&s.fx_n), d(&s.fy_n));
    let shaft_hz = p.speed_rpm / 60.0;
    statistics::line_structure([&x, &y, &vx, &vy], [&fx, &fy], &s.t_s, &p.lines_hz, 0.5 * p.rate_hz, &[shaft_hz, 2.0 * shaft_hz])
}

fn coefficients_of(kc: &[f64; 8]) -> (Matrix2<f64>, Matrix2<f64>) {
    // Columns 4 i + j are minus K[i][j] (j < 2) and minus C[i][j - 2].
    let k = Matrix2::new(-kc[0], -kc[1], -kc[4], -kc[5]);
    let c = Matrix2::new(-kc[2], -kc[3], -kc[6], -kc[7]);
    (k, c)
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
    let folds = p.blocks.len();
    let n = p.len();
    let rows = p.rows();
    let sst = 2.0 * n as f64 * p.force_rms_n * p.force_rms_n;
    let nrmse = |block_sse: &[f64]| (block_sse.iter().sum::<f64>() / sst).sqrt();
    let baseline_structure = structure_of(&p);
    if let Some(s) = baseline_structure.filter(|s| s.motion_snr < MIN_MOTION_SNR) {
        return Ok(Diagnosis::insufficient(format!(
            "too noisy: the motion at the excitation lines stands only {:.1} dB above the noise between them (at least {:.0} dB needed to judge any model); excite harder or record longer",
            10.0 * s.motion_snr.log10(),
            10.0 * MIN_MOTION_SNR.log10()
        )));
    }
    let baseline = judge(&p, &|train| Baseline::fit(&p, train))?;
    let nrmse0 = nrmse(&baseline.block_sse);
    let sse0 = baseline.full.residual.norm_squared();
    let mut notes = p.notes.clone();
    if speed_source == SpeedSource::RigFile {
        notes.push("the record states no speed: the rig file's was assumed (1X runout is looked for at that speed)".into());
    }
    if p.lines_hz.len() < 3 {
        notes.push(format!(
            "only {} excitation line(s): frequency-dependent effects (added mass, delays) cannot be told from stiffness and damping; excite a band (multisine) to see them",
            p.lines_hz.len()
        ));
    }

    // The catalog, each entry tried if it applies to this record.
    let mut reports = Vec::new();
    let mut fitted: BTreeMap<Cause, Judged> = BTreeMap::new();
    // A candidate that cannot be set up on this record (a re-conditioning or a film solve that
    // fails, nothing to look at) is listed with why, and the others are still judged.
    let entries: Vec<(Cause, Ready)> = vec![
        (Cause::AmplitudeNonlinearity, Ok(Box::new(catalog::AmplitudeNonlinearity))),
        (Cause::FluidInertia, Ok(Box::new(catalog::FluidInertia))),
        (Cause::ChannelDelay, set_up(catalog::ChannelDelay::new(&p).map(Ok))),
        (Cause::SynchronousRunout, Ok(Box::new(catalog::SynchronousRunout))),
        (Cause::SupportFriction, Ok(Box::new(catalog::SupportFriction))),
        (Cause::ThermalDrift, set_up(catalog::ThermalDrift::new(&p, rig))),
        (Cause::ProbeSaturation, set_up(catalog::ProbeSaturation::new(&p))),
    ];
    for (cause, entry) in entries {
        let mut report = CandidateReport {
            name: cause,
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
            explained_fraction: None,
            note: None,
        };
        let candidate = match &entry {
            Ok(c) => c.as_ref(),
            Err(why) => {
                report.note = Some(format!("not tried: {why}"));
                reports.push(report);
                continue;
            }
        };
        let judged = match judge(&p, &|train| candidate.fit(&p, train)) {
            Ok(j) => j,
            Err(e) => {
                report.note = Some(format!("could not be fitted: {e}"));
                reports.push(report);
                continue;
            }
        };
        let h = nrmse(&judged.block_sse);
        let sse = judged.full.residual.norm_squared();
        let extra = judged.full.extra_parameters;
        let gain = 1.0 - h / nrmse0;
        let p_value = statistics::likelihood_ratio_p(sse0, sse, rows, extra);
        let dbic = statistics::delta_bic(sse0, sse, rows, extra);
        let improved = judged.block_sse.iter().zip(&baseline.block_sse).filter(|(c, b)| c < b).count();
        let mut why_not = Vec::new();
        if gain < options.min_gain {
            why_not.push(format!("held-out gain {:.2} % below {:.2} %", 100.0 * gain, 100.0 * options.min_gain));
        }
        if (improved as f64) < options.min_fold_fraction * folds as f64 {
            why_not.push(format!("better in only {improved} of {folds} held-out blocks"));
        }
        if p_value >= options.significance {
            why_not.push(format!("not significant (p = {p_value:.2e})"));
        }
        if dbic >= 0.0 {
            why_not.push(format!("BIC does not favour it (+{dbic:.1})"));
        }
        if let Err(why) = &judged.full.physical {
            why_not.push(why.clone());
        }
        report.score = Some(gain);
        report.heldout_nrmse = Some(h);
        report.parameters = judged.full.parameters.clone();
        report.standard_errors = judged.full.standard_errors.clone();
        report.extra_parameters = extra;
        report.p_value = Some(p_value);
        report.delta_bic = Some(dbic);
        report.folds_improved = improved;
        report.earns = why_not.is_empty();
        report.explained_fraction = baseline_structure
            .filter(|s| s.relative_amplitude > 0.0)
            .map(|s| (nrmse0 * nrmse0 - h * h) / (s.relative_amplitude * s.relative_amplitude));
        report.note = (!why_not.is_empty()).then(|| why_not.join("; "));
        reports.push(report);
        fitted.insert(cause, judged);
    }
    reports.sort_by(|a, b| b.score.unwrap_or(f64::NEG_INFINITY).total_cmp(&a.score.unwrap_or(f64::NEG_INFINITY)));

    let structured = baseline_structure.is_some_and(|s| s.p_value < options.structure_p && s.relative_amplitude > options.min_structure);
    let winner = reports.iter().find(|r| r.earns).cloned();
    let (baseline_k, baseline_c) = coefficients_of(&baseline.full.kc);
    let mut out = Diagnosis {
        cause: Cause::None,
        reason: String::new(),
        candidates: reports.clone(),
        baseline_heldout_nrmse: Some(nrmse0),
        extended_heldout_nrmse: Some(nrmse0),
        gain: Some(0.0),
        parameters: BTreeMap::new(),
        standard_errors: BTreeMap::new(),
        aliases: Vec::new(),
        coefficients: None,
        baseline_structure,
        evidence: Some(EvidenceSummary {
            samples: p.raw.len(),
            decimation: p.decimation,
            decimated_rate_hz: p.rate_hz,
            folds,
            excitation_lines_hz: p.lines_hz.clone(),
            lowpass_cutoff_hz: p.conditioning.lowpass_cutoff_hz,
            speed_rpm: p.speed_rpm,
            mean_temperature_c: p.mean_temperature_c,
            force_rms_n: p.force_rms_n,
            tilt_weight_n_m: p.tilt_weight_n_m,
        }),
        frame: FRAME.to_string(),
        notes,
    };
    let structure_text = |s: &Option<LineStructure>| {
        s.map_or("no line test possible".to_string(), |s| {
            format!("line-locked residual {:.2} % of the force at {} lines (power ratio {:.1}, p = {:.1e})", 100.0 * s.relative_amplitude, s.lines, s.ratio, s.p_value)
        })
    };
    match winner {
        Some(w) => {
            let explained = w.explained_fraction.unwrap_or(1.0);
            if structured && explained < options.explained_fraction {
                out.cause = Cause::Unexplained;
                out.reason = format!(
                    "the linear model leaves excitation-locked residual ({}); the best candidate, {}, earns its parameters but accounts for only {:.0} % of that excess power (at least {:.0} % needed): an effect outside the catalog",
                    structure_text(&baseline_structure),
                    w.name,
                    100.0 * explained,
                    100.0 * options.explained_fraction
                );
            } else {
                out.cause = w.name;
                out.extended_heldout_nrmse = w.heldout_nrmse;
                out.gain = w.score;
                out.parameters = w.parameters.clone();
                out.standard_errors = w.standard_errors.clone();
                out.reason = format!(
                    "{} predicts held-out blocks {:.1} % better than the linear model (NRMSE {:.4} against {:.4}), in {} of {} blocks, p = {:.1e}, BIC {:+.1}",
                    w.name,
                    100.0 * w.score.unwrap_or(0.0),
                    w.heldout_nrmse.unwrap_or(f64::NAN),
                    nrmse0,
                    w.folds_improved,
                    folds,
                    w.p_value.unwrap_or(f64::NAN),
                    w.delta_bic.unwrap_or(f64::NAN)
                );
                if let Some(j) = fitted.get(&w.name) {
                    let (k, c) = coefficients_of(&j.full.kc);
                    let rel = |a: &Matrix2<f64>, b: &Matrix2<f64>| Matrix2::from_fn(|i, j| (a[(i, j)] - b[(i, j)]) / b[(i, j)].abs());
                    out.coefficients = Some(CoefficientChange {
                        baseline_stiffness_n_m: baseline_k,
                        baseline_damping_n_s_m: baseline_c,
                        extended_stiffness_n_m: k,
                        extended_damping_n_s_m: c,
                        stiffness_relative_change: rel(&k, &baseline_k),
                        damping_relative_change: rel(&c, &baseline_c),
                    });
                }
                out.aliases = aliases(&p, &w, &reports, &fitted, &baseline_k, options);
            }
        }
        None if structured => {
            out.cause = Cause::Unexplained;
            let best = reports.first().map_or("none".to_string(), |r| format!("{} ({})", r.name, r.note.clone().unwrap_or_default()));
            out.reason = format!("the linear model leaves excitation-locked residual ({}) and no candidate earns its parameters; the closest: {best}", structure_text(&baseline_structure));
        }
        None if nrmse0 > options.max_noise_nrmse => {
            out.cause = Cause::InsufficientData;
            out.reason = format!(
                "too noisy: the linear model predicts held-out blocks with NRMSE {nrmse0:.3} and its residual is not excitation-locked ({}); no model can be judged on this record",
                structure_text(&baseline_structure)
            );
        }
        None => {
            out.cause = Cause::None;
            out.reason = format!(
                "the linear K-C model is adequate: held-out NRMSE {nrmse0:.4}, {}; no candidate earns its extra parameters",
                structure_text(&baseline_structure)
            );
        }
    }
    Ok(out)
}

/// The journal counts as fixed when its motion at the excitation lines is below this fraction
/// of the journal-bearing motion there.
pub const JOURNAL_FIXED_RATIO: f64 = 0.05;

/// The aliasing pairs relevant to the winner, with what this record says about each.
fn aliases(
    p: &Prepared,
    winner: &CandidateReport,
    reports: &[CandidateReport],
    fitted: &BTreeMap<Cause, Judged>,
    baseline_k: &Matrix2<f64>,
    options: &DiagnosisOptions,
) -> Vec<Alias> {
    let mut out = Vec::new();
    let s = &p.series;
    if winner.name == Cause::FluidInertia {
        // Does the journal move? Its position J = r + X (bearing probes plus frame probes),
        // compared with the relative motion r at the excitation lines, where the probes' noise
        // is one DFT bin against a whole line (accelerations would compare noise).
        let journal = |r: &[f64], h: &[f64]| {
            let mut v: Vec<f64> = r.iter().zip(h).map(|(a, b)| a + b).collect();
            p.detrend(&mut v);
            v
        };
        let detrended = |r: &[f64]| {
            let mut v = r.to_vec();
            p.detrend(&mut v);
            v
        };
        let (jx, jy) = (journal(&s.x_m, &s.housing_x_m), journal(&s.y_m, &s.housing_y_m));
        let (rx, ry) = (detrended(&s.x_m), detrended(&s.y_m));
        let lp = |v: &[f64]| statistics::line_power(v, &s.t_s, &p.lines_hz);
        let ratio = ((lp(&jx) + lp(&jy)) / (lp(&rx) + lp(&ry)).max(f64::MIN_POSITIVE)).sqrt();
        let fixed = ratio < JOURNAL_FIXED_RATIO;
        out.push(Alias {
            pair: ["fluid_inertia".into(), "housing_mass_error".into()],
            separable: !fixed,
            evidence: if fixed {
                format!(
                    "the journal is fixed (its motion at the excitation lines is {:.2} % of the journal-bearing motion): the housing's acceleration is minus the journal-bearing acceleration, so an error of the configured housing mass in eq. 2 is indistinguishable from this added mass ({:.2} kg); weigh the housing or run with the film unloaded to separate them",
                    100.0 * ratio,
                    winner.parameters.get("added_mass_kg").and_then(Value::as_f64).unwrap_or(f64::NAN)
                )
            } else {
                format!("the journal moves ({:.1} % of the journal-bearing motion at the lines): housing and journal-bearing accelerations differ, so an added mass in the film and an error in the configured housing mass act on different signals", 100.0 * ratio)
            },
        });
    }
    if matches!(winner.name, Cause::FluidInertia | Cause::ChannelDelay) {
        // Skew vs inertia: a delay tau raises damping by about K tau on its channel's axis;
        // inertia changes no damping. Compare the two models' held-out blocks pairwise.
        let other = if winner.name == Cause::FluidInertia { Cause::ChannelDelay } else { Cause::FluidInertia };
        if let (Some(w), Some(o), Some(or)) = (fitted.get(&winner.name), fitted.get(&other), reports.iter().find(|r| r.name == other)) {
            let wins = w.block_sse.iter().zip(&o.block_sse).filter(|(a, b)| a < b).count();
            let separable = (wins as f64) >= options.min_fold_fraction * w.block_sse.len() as f64;
            let k_bar = 0.5 * (baseline_k[(0, 0)].abs() + baseline_k[(1, 1)].abs());
            let delay_damping = or.parameters.get("delay_s").or(winner.parameters.get("delay_s")).and_then(Value::as_f64).map(|t| t * k_bar);
            out.push(Alias {
                pair: [winner.name.name().into(), other.name().into()],
                separable,
                evidence: format!(
                    "{} beats {} in {wins} of {} held-out blocks{}; a channel delay tau also raises the damping by about K tau ({}), an added mass leaves damping alone and acts on both axes alike",
                    winner.name,
                    other,
                    w.block_sse.len(),
                    if separable { "" } else { ": this record does not separate them" },
                    delay_damping.map_or("n/a".to_string(), |d| format!("{d:.3e} N s/m for the fitted delay"))
                ),
            });
        }
    }
    out
}
