//! `oilfilm identify` past its refusals: when a window is refused (or `--correct` asks), the
//! record is diagnosed and the coefficients a user can keep are printed beside the windows:
//! those of the diagnosis's chosen model, on the data corrected for a measurement effect
//! (runout, a channel's timing, a clipped probe), with an added mass or friction separated, at
//! the record's start for a drift. A record whose coefficients drift is re-identified in
//! windows short enough for the drift, and the refusal says it drifts, by how much per second.

use anyhow::Result;
use nalgebra::Matrix2;
use oilfilm_diagnosis::catalog::Cause;
use oilfilm_diagnosis::{diagnose, Diagnosis, DiagnosisOptions};
use oilfilm_identification::pipeline::{self, Identification, PipelineConfig, SpeedSource};
use oilfilm_identification::record::RawRecord;
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::Calibration;
use serde::Serialize;

/// A direct coefficient drifting by more than this over one window makes the window too long.
const MAX_DRIFT_PER_WINDOW: f64 = 0.03;
/// Windows are never shortened below this, s.
const MIN_WINDOW_S: f64 = 0.5;

/// What `identify` adds when it corrects (the JSON's `correction` key).
#[derive(Debug, Clone, Serialize)]
pub struct Correction {
    /// Why the record was diagnosed.
    pub why: String,
    pub cause: Cause,
    pub also: Vec<Cause>,
    /// What the coefficients below account for.
    pub note: String,
    pub stiffness_n_m: Matrix2<f64>,
    pub damping_n_s_m: Matrix2<f64>,
    pub stiffness_se: Matrix2<f64>,
    pub damping_se: Matrix2<f64>,
    /// With a drift: the fitted trend at the record's start.
    pub stiffness_at_start_n_m: Option<Matrix2<f64>>,
    pub damping_at_start_n_s_m: Option<Matrix2<f64>>,
    /// Relative change per second of kxx, kxy, cxx, cxy, kyx, kyy, cyx, cyy, when they drift.
    pub relative_drift_per_s: Option<[f64; 8]>,
    /// The record identified again in windows short enough for the drift.
    pub shorter_windows: Option<Identification>,
}

/// The drift's explanation of a refusal, if the coefficients drift.
fn drift_text(rates: &[f64; 8]) -> String {
    let names = ["kxx", "kxy", "cxx", "cxy", "kyx", "kyy", "cyx", "cyy"];
    let direct: Vec<String> = [0usize, 5, 2, 7].iter().map(|&k| format!("{} {:+.2} %/s", names[k], 100.0 * rates[k])).collect();
    format!("the coefficients drift during the record ({}), not the excitation", direct.join(", "))
}

fn largest_direct_rate(rates: &[f64; 8]) -> f64 {
    [0usize, 5, 2, 7].iter().map(|&k| rates[k].abs()).fold(0.0, f64::max)
}

/// Diagnoses the record and, for a drift, re-identifies it in shorter windows. `None` when
/// nothing is refused and no correction was asked for.
#[allow(clippy::too_many_arguments)]
pub fn correct(
    raw: &RawRecord,
    calibration: &Calibration,
    rig: &RigConfig,
    speed_rpm: f64,
    source: SpeedSource,
    config: &PipelineConfig,
    id: &Identification,
    asked: bool,
) -> Result<Option<Correction>> {
    let refused = id.windows.iter().filter(|w| w.estimate.result.is_err()).count();
    if !asked && refused == 0 && id.refusal.is_none() {
        return Ok(None);
    }
    let why = if asked { "--correct".to_string() } else { format!("{refused} of {} window(s) refused", id.windows.len()) };
    let mut nominal = rig.clone();
    nominal.effects = Default::default();
    let d: Diagnosis = diagnose(raw, calibration, &nominal, speed_rpm, source, &DiagnosisOptions::default())?;
    let Some(c) = d.coefficients.clone() else {
        return Ok(Some(Correction {
            why,
            cause: d.cause,
            also: d.also.clone(),
            note: format!("no correction: {}", d.reason),
            stiffness_n_m: Matrix2::from_element(f64::NAN),
            damping_n_s_m: Matrix2::from_element(f64::NAN),
            stiffness_se: Matrix2::from_element(f64::NAN),
            damping_se: Matrix2::from_element(f64::NAN),
            stiffness_at_start_n_m: None,
            damping_at_start_n_s_m: None,
            relative_drift_per_s: None,
            shorter_windows: None,
        }));
    };
    let mut note = match d.cause {
        Cause::None => "the linear film is adequate; the coefficients are the small-amplitude ones (the film's own nonlinearity separated)".to_string(),
        Cause::Unexplained => {
            format!("an effect outside the catalog remains ({}); the coefficients are the closest catalog model's and may still be biased", d.reason)
        }
        Cause::InsufficientData => format!("the record cannot be judged: {}", d.reason),
        c if c.is_measurement_effect() => format!("{c} corrected in the data ({}); the coefficients are the corrected record's", fmt_parameters(&d)),
        c => format!("{c} separated from the film ({}); the coefficients are the film's own", fmt_parameters(&d)),
    };
    // Drift: shorter windows.
    let mut shorter = None;
    if let Some(rates) = c.relative_drift_per_s.filter(|r| largest_direct_rate(r) > 0.0) {
        let rate = largest_direct_rate(&rates);
        let window_s = config.estimator.window as f64 / raw.sample_rate_hz;
        note.push_str(&format!("; {}", drift_text(&rates)));
        if rate * window_s > MAX_DRIFT_PER_WINDOW {
            let short_s = (MAX_DRIFT_PER_WINDOW / rate).max(MIN_WINDOW_S).min(window_s);
            let mut cfg = config.clone();
            cfg.estimator.window = (short_s * raw.sample_rate_hz).round() as usize;
            cfg.estimator.hop = cfg.estimator.window;
            note.push_str(&format!(
                "; a {:.1} s window changes by {:.1} % over its length: identified again in {:.2} s windows (below)",
                window_s,
                100.0 * rate * window_s,
                short_s
            ));
            shorter = Some(pipeline::identify(raw, calibration, &nominal, speed_rpm, source, &cfg)?);
        }
    }
    Ok(Some(Correction {
        why,
        cause: d.cause,
        also: d.also.clone(),
        note,
        stiffness_n_m: c.stiffness_n_m,
        damping_n_s_m: c.damping_n_s_m,
        stiffness_se: c.stiffness_se,
        damping_se: c.damping_se,
        stiffness_at_start_n_m: c.stiffness_at_start_n_m,
        damping_at_start_n_s_m: c.damping_at_start_n_s_m,
        relative_drift_per_s: c.relative_drift_per_s,
        shorter_windows: shorter,
    }))
}

fn fmt_parameters(d: &Diagnosis) -> String {
    d.parameters
        .iter()
        .filter(|(k, _)| k.as_str() != "delay_convention")
        .map(|(k, v)| match v.as_f64() {
            Some(x) => format!("{k} = {x:.4e}"),
            None => format!("{k} = {}", v.as_str().map_or(v.to_string(), str::to_string)),
        })
        .collect::<Vec<_>>()
        .join(", ")
}

fn matrix(m: &Matrix2<f64>) -> String {
    format!("[{:.5e} {:.5e}; {:.5e} {:.5e}]", m[(0, 0)], m[(0, 1)], m[(1, 0)], m[(1, 1)])
}

/// The text form, after the windows.
pub fn print(c: &Correction) {
    println!();
    println!(
        "corrected identification ({}): the diagnosis names `{}`{}",
        c.why,
        c.cause,
        if c.also.is_empty() { String::new() } else { format!(" (also {})", c.also.iter().map(|a| a.name()).collect::<Vec<_>>().join(", ")) }
    );
    println!("  {}", c.note);
    if c.stiffness_n_m.iter().all(|v| v.is_finite()) {
        println!("  K = {} N/m (SE {})", matrix(&c.stiffness_n_m), matrix(&c.stiffness_se));
        println!("  C = {} N s/m (SE {})", matrix(&c.damping_n_s_m), matrix(&c.damping_se));
    }
    if let (Some(k), Some(d)) = (&c.stiffness_at_start_n_m, &c.damping_at_start_n_s_m) {
        println!("  at the record's start (the drift's trend): K = {} N/m, C = {} N s/m", matrix(k), matrix(d));
    }
    if let Some(s) = &c.shorter_windows {
        let accepted = s.accepted().count();
        println!("  shorter windows: {accepted} of {} accepted", s.windows.len());
        for w in &s.windows {
            match &w.estimate.result {
                Ok(e) => println!(
                    "    {:.2}-{:.2} s, {:.2} C: kxx {:.4e} kyy {:.4e} cxx {:.4e} cyy {:.4e}",
                    w.t_start_s,
                    w.t_end_s,
                    w.operating.temperature_c,
                    e.stiffness_n_m[(0, 0)],
                    e.stiffness_n_m[(1, 1)],
                    e.damping_n_s_m[(0, 0)],
                    e.damping_n_s_m[(1, 1)]
                ),
                Err(r) => println!("    {:.2}-{:.2} s: refused: {r}", w.t_start_s, w.t_end_s),
            }
        }
    }
}
