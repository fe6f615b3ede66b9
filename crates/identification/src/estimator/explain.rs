//! Why a window cannot be solved, in words a rotordynamics engineer acts on.
//!
//! Rank is decided twice. Numerically, by the singular values of the column-scaled factor
//! ([`super::solve`]). Structurally, by the excitation: a direction whose motion is (≥ 90 % of
//! its variance) a sum of `L` sinusoids has all its regressors (`x, x'`, and `x''` for the
//! added-mass model) in the `2L`-dimensional span of those lines' cosines and sines, and both
//! directions together in the span of the union of their lines. Noise fills in the missing
//! dimensions numerically, but information about the film it does not carry (sensor noise in a
//! regressor only biases the fit), so a structurally deficient window is refused even when its
//! noisy matrix is technically of full rank. The same holds for a line that is found but lies
//! below the noise of its direction's regressors (the bellows' slow ripple beside one strong
//! sine: its velocity is tiny): only lines at least [`super::spectrum::LINE_SNR_MIN`] above
//! that noise count.

use super::spectrum::LineAnalysis;
use super::svd::SmallSvd;
use super::ModelOrder;

/// Variance fraction above which a direction's motion counts as "made of its lines".
pub const LINE_DOMINATED: f64 = 0.9;

/// Format a list of frequencies: "20.0 Hz", "20.0 and 31.0 Hz", "20.0, 31.0 and 47.3 Hz".
pub fn fmt_hz(f: &[f64]) -> String {
    let parts: Vec<String> = f.iter().map(|v| format!("{v:.1}")).collect();
    match parts.len() {
        0 => "no line".to_string(),
        1 => format!("{} Hz", parts[0]),
        k => format!("{} and {} Hz", parts[..k - 1].join(", "), parts[k - 1]),
    }
}

fn dominated(lines: &LineAnalysis, d: usize) -> bool {
    lines.line_fraction[d] >= LINE_DOMINATED
}

/// The rank the excitation allows, if it is below what the model needs.
///
/// Only lines that stand above the regressors' broadband noise count
/// ([`LineAnalysis::determining`], [`super::spectrum::LINE_SNR_MIN`]): a line buried in the
/// velocity noise (the bellows' slow ripple beside one strong sine) spans its two dimensions
/// with noise, not with information, and least squares attenuates the fit there without any
/// standard error showing it.
pub fn structural_rank(model: ModelOrder, lines: &LineAnalysis) -> Option<usize> {
    let per = model.regressors() / 2;
    let rd = |d: usize| if dominated(lines, d) { per.min(2 * lines.determining(d).len()) } else { per };
    let mut bound = rd(0) + rd(1);
    if dominated(lines, 0) && dominated(lines, 1) {
        bound = bound.min(2 * lines.determining_merged().len());
    }
    (bound < model.regressors()).then_some(bound)
}

/// The lines found but not counted by [`structural_rank`], said with their SNR; empty if none.
fn weak_lines(lines: &LineAnalysis) -> String {
    let mut weak: Vec<(f64, f64)> = Vec::new();
    for d in 0..2 {
        for (f, snr) in lines.weak(d) {
            match weak.iter_mut().find(|(g, _)| (g - f).abs() < super::spectrum::MAIN_LOBE_BINS as f64 * lines.resolution_hz) {
                Some(w) => w.1 = w.1.max(snr),
                None => weak.push((f, snr)),
            }
        }
    }
    if weak.is_empty() {
        return String::new();
    }
    weak.sort_by(|a, b| a.0.total_cmp(&b.0));
    let freqs: Vec<f64> = weak.iter().map(|w| w.0).collect();
    let worst = weak.iter().map(|w| w.1).fold(f64::NEG_INFINITY, f64::max);
    let (noun, verb) = if weak.len() == 1 { ("line", "stands") } else { ("lines", "stand") };
    format!(
        ". The weak {noun} at {} {verb} at most {:+.1} dB against the broadband noise of the displacement or velocity regressors (at least {:+.1} dB needed): in the directions only {} would span, least squares fits noise, attenuating the coefficients with no standard error showing it, so {} not counted",
        fmt_hz(&freqs),
        10.0 * worst.log10(),
        10.0 * super::spectrum::LINE_SNR_MIN.log10(),
        if weak.len() == 1 { "it" } else { "they" },
        if weak.len() == 1 { "it is" } else { "they are" },
    )
}

/// Explanation of a structural rank deficiency found by [`structural_rank`].
pub fn structural_explanation(model: ModelOrder, lines: &LineAnalysis, rank: usize, numerical: Option<&SmallSvd>) -> String {
    let p = model.regressors();
    let names = model.regressor_names().join(", ");
    let merged = lines.determining_merged();
    let mut text = if dominated(lines, 0) && dominated(lines, 1) && merged.len() == 1 {
        let f = fmt_hz(&merged);
        match model {
            ModelOrder::Kc => format!(
                "both exciters at one frequency: {names} all lie in span{{cos, sin}} of {f} (rank {rank} of {p}): excite two frequencies"
            ),
            ModelOrder::Kcm => format!(
                "both exciters at one frequency: {names} all lie in span{{cos, sin}} of {f} (rank {rank} of {p}); stiffness and added mass alias there (K - w^2 M): excite at least two frequencies in each direction"
            ),
        }
    } else {
        let mut parts = Vec::new();
        let dir = ["x", "y"];
        for d in 0..2 {
            if !dominated(lines, d) {
                continue;
            }
            let l = &lines.determining(d);
            if model == ModelOrder::Kcm && l.len() == 1 {
                parts.push(format!(
                    "{v} moves only at {f}, where {v}'' = -w^2 {v}, so {v}, {v}', {v}'' lie in span{{cos, sin}} of {f}",
                    v = dir[d],
                    f = fmt_hz(l)
                ));
            }
        }
        let alias = model == ModelOrder::Kcm && !parts.is_empty();
        if !alias && dominated(lines, 0) && dominated(lines, 1) && 2 * merged.len() < p {
            parts.push(format!("{names} all lie in span{{cos, sin}} of {}", fmt_hz(&merged)));
        }
        let advice = match model {
            ModelOrder::Kc => "excite two frequencies",
            ModelOrder::Kcm => "excite at least two frequencies in each direction, three in all, or fit Kc and read K - w^2 M as the dynamic stiffness",
        };
        let head = if alias { "stiffness and added mass alias at one frequency (K - w^2 M): " } else { "" };
        format!("{head}{} (rank {rank} of {p}): {advice}", parts.join("; "))
    };
    text.push_str(&weak_lines(lines));
    if let Some(svd) = numerical {
        let p_num = svd.rank((svd.p as f64) * 1e3 * f64::EPSILON);
        if p_num > rank {
            if let (Some(&hi), Some(&lo)) = (svd.sigma.first(), svd.sigma.get(rank)) {
                text.push_str(&format!(
                    ". The data are numerically of rank {p_num}, but the extra directions (singular values down to {:.1e} of the largest) come from broadband noise, not from the excitation",
                    lo / hi
                ));
            }
        }
    }
    text
}

/// Describe the weakest direction of the scaled regressors: which columns nearly cancel.
pub fn dependency(svd: &SmallSvd, names: &[&str]) -> String {
    let v = svd.weakest_direction();
    let big = v.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    if !(big > 0.0) {
        return "the regressors are degenerate".to_string();
    }
    let involved: Vec<usize> = (0..v.len()).filter(|&j| v[j].abs() >= 0.2 * big).collect();
    if involved.len() == 1 {
        let j = involved[0];
        return format!("{} does not vary over the window (constant, or its channel is dead)", names.get(j).copied().unwrap_or("?"));
    }
    let sign = if v[involved[0]] < 0.0 { -1.0 } else { 1.0 };
    let mut combo = String::new();
    for (i, &j) in involved.iter().enumerate() {
        let c = sign * v[j];
        let name = names.get(j).copied().unwrap_or("?");
        if i == 0 {
            combo.push_str(&format!("{c:.3} {name}"));
        } else if c < 0.0 {
            combo.push_str(&format!(" - {:.3} {name}", -c));
        } else {
            combo.push_str(&format!(" + {c:.3} {name}"));
        }
    }
    let pair = |a: &str, b: &str| involved.len() == 2 && names.get(involved[0]) == Some(&a) && names.get(involved[1]) == Some(&b);
    let hint = if pair("x", "y") || pair("x'", "y'") {
        ": the orbit is (nearly) a straight line, both directions move in phase; drive the exciters out of phase or at different frequencies"
    } else if pair("x", "x''") || pair("y", "y''") {
        ": stiffness and added mass alias (K - w^2 M); add a frequency in that direction"
    } else {
        ""
    };
    format!("{combo} ≈ 0 on unit-norm columns{hint}")
}

/// Why a window is ill-conditioned: the near-dependency and, if lines are close, their spacing.
pub fn ill_conditioned_explanation(svd: &SmallSvd, names: &[&str], lines: &LineAnalysis, window_s: f64) -> String {
    let mut text = format!("the regressors are nearly dependent, {}", dependency(svd, names));
    if window_s > 0.0 {
        let res = 1.0 / window_s;
        let m = &lines.merged;
        for w in m.windows(2) {
            if w[1] - w[0] < 2.0 * res {
                text.push_str(&format!(
                    "; lines {} are closer than two bins of this window (1/T = {res:.2} Hz): lengthen the window or separate the frequencies",
                    fmt_hz(w)
                ));
                break;
            }
        }
    }
    text
}

/// Regressors that do not vary over the window.
pub fn constant_columns(cols: &[usize], names: &[&str]) -> String {
    let list: Vec<&str> = cols.iter().map(|&j| names.get(j).copied().unwrap_or("?")).collect();
    let verb = if list.len() == 1 { "does" } else { "do" };
    format!("{} {verb} not vary over the window: that direction is not excited or its probe is dead", list.join(", "))
}
