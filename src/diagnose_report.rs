//! The written side of `oilfilm diagnose`: SVG figures and a Markdown report of a
//! [`Show`] and its [`Diagnosis`], for an engineer to read.
//!
//! `report.md` opens with the verdict, the model update and `lines.svg` (the motion at the
//! excitation lines: measured, nominal film model, updated film model), then how the verdict
//! was reached and the details. Figures (plotters' SVG backend, as in `figures.rs`):
//! `lines.svg`, `motion_time.svg`, `motion_spectrum.svg`, `coefficients.svg`,
//! `trends_<variable>.svg` (one per variable) and `residual_spectrum.svg`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use oilfilm_diagnosis::show::{ComponentKind, Show, Trend, TrendVariable, COEFFICIENT_NAMES, TREND_MIN_CHANGE, TREND_MIN_WINDOWS, TREND_SIGNIFICANT_T};
use oilfilm_diagnosis::Diagnosis;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::figures::padded;

const FONT: &str = "sans-serif";
const MEASURED: RGBColor = RGBColor(31, 119, 180);
const PREDICTED: RGBColor = RGBColor(214, 39, 40);
const UPDATED: RGBColor = RGBColor(44, 160, 44);
const GRID: RGBColor = RGBColor(235, 235, 235);

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// Writes the figures and `report.md` into `dir` (created if missing); returns every path
/// written, `report.md` last.
pub fn write_report(dir: &Path, record_name: &str, show: &Show, diagnosis: Option<&Diagnosis>) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create the report directory {}", dir.display()))?;
    let mut out = Vec::new();
    let mut figure = |name: &str, draw: &dyn Fn(&Path) -> Result<()>| -> Result<()> {
        let path = dir.join(name);
        draw(&path).with_context(|| format!("cannot write figure {}", path.display()))?;
        out.push(path);
        Ok(())
    };
    if !show.excitation_lines_hz.is_empty() {
        figure("lines.svg", &|p| lines_figure(show, record_name, p))?;
    }
    figure("motion_time.svg", &|p| motion_time(show, record_name, p))?;
    figure("motion_spectrum.svg", &|p| motion_spectrum(show, record_name, p))?;
    if !show.coefficients.windows.is_empty() {
        figure("coefficients.svg", &|p| coefficients(show, record_name, p))?;
    }
    for var in TrendVariable::ALL {
        if show.trends.iter().any(|t| t.variable == var) {
            figure(&format!("trends_{}.svg", variable_slug(var)), &|p| trends(show, record_name, var, p))?;
        }
    }
    figure("residual_spectrum.svg", &|p| residual_spectrum(show, record_name, p))?;
    let names: Vec<String> = out.iter().filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned())).collect();
    let text = markdown(record_name, show, diagnosis, &names);
    let path = dir.join("report.md");
    std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
    out.push(path);
    Ok(out)
}

fn variable_slug(v: TrendVariable) -> &'static str {
    match v {
        TrendVariable::AmplitudeD => "amplitude_d",
        TrendVariable::LoadParameter => "load_parameter",
        TrendVariable::TemperatureC => "temperature",
        TrendVariable::TimeS => "time",
    }
}

fn header<'a>(root: &Area<'a>, title: &str, sub: &str) -> Result<Area<'a>> {
    root.fill(&WHITE)?;
    let (top, body) = root.split_vertically(62);
    top.draw(&Text::new(title.to_string(), (14, 8), (FONT, 22).into_font().style(FontStyle::Bold)))?;
    top.draw(&Text::new(sub.to_string(), (14, 38), (FONT, 13)))?;
    Ok(body)
}

fn subtitle(show: &Show, record: &str) -> String {
    format!(
        "record `{record}` on rig `{}`, {:.0} rpm, {:.2} C, load {:.0} N; frame x horizontal, y up; r = journal relative to bearing",
        show.rig, show.speed_rpm, show.operating.temperature_c, show.operating.load_n
    )
}

/// Draws a chart's legend box (a macro: the chart type's lifetimes are unwieldy to name).
macro_rules! legend {
    ($chart:expr) => {
        $chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.9))
            .border_style(RGBColor(150, 150, 150))
            .label_font((FONT, 13))
            .draw()
    };
}

/// The figure to take in at a glance: the motion's amplitude at each excitation line,
/// measured against the nominal film model and (when given) the updated one, per axis; a line
/// where the axis is not excited is drawn hollow.
fn lines_figure(show: &Show, record: &str, path: &Path) -> Result<()> {
    let root = SVGBackend::new(path, (1300, 800)).into_drawing_area();
    let body = header(&root, "Motion at the excitation lines: measured, film model, updated film model", &subtitle(show, record))?;
    let panels = body.split_evenly((2, 1));
    for (k, panel) in panels.iter().enumerate() {
        let Some(axis) = show.motion.axes.get(k) else { continue };
        let mut ls = axis.lines.clone();
        ls.sort_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz));
        let um = |v: f64| v * 1e6;
        let all = ls.iter().flat_map(|l| [um(l.measured_amplitude_m), um(l.predicted_amplitude_m)].into_iter().chain(l.updated_amplitude_m.map(um)));
        let (_, y1) = padded(all.chain([0.0]));
        let (x0, x1) = padded(ls.iter().map(|l| l.frequency_hz));
        let updated = axis.updated_nrmse.map_or(String::new(), |u| format!(", updated {:.1} %", 100.0 * u));
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{} motion (NRMSE of the dynamic part: film model {:.1} %{updated})", axis.axis, 100.0 * axis.nrmse), (FONT, 17))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, 0.0..y1)?;
        chart
            .configure_mesh()
            .x_desc("excitation line (Hz)")
            .y_desc(format!("{} amplitude (um)", axis.axis))
            .label_style((FONT, 13))
            .light_line_style(GRID)
            .draw()?;
        let pts = |f: &dyn Fn(&oilfilm_diagnosis::show::LineComparison) -> Option<f64>| -> Vec<(f64, f64, bool)> {
            ls.iter().filter_map(|l| f(l).map(|v| (l.frequency_hz, um(v), l.excited))).collect()
        };
        let measured = pts(&|l| Some(l.measured_amplitude_m));
        chart
            .draw_series(measured.iter().map(|&(f, v, e)| Circle::new((f, v), 6, if e { MEASURED.filled() } else { MEASURED.stroke_width(1) })))?
            .label("measured (hollow: axis not excited at this line)")
            .legend(|(x, y)| Circle::new((x + 12, y), 6, MEASURED.filled()));
        chart
            .draw_series(pts(&|l| Some(l.predicted_amplitude_m)).iter().map(|&(f, v, _)| TriangleMarker::new((f, v), 7, PREDICTED.filled())))?
            .label("film model (rig file)")
            .legend(|(x, y)| TriangleMarker::new((x + 12, y), 7, PREDICTED.filled()));
        let upd = pts(&|l| l.updated_amplitude_m);
        if !upd.is_empty() {
            chart
                .draw_series(upd.iter().map(|&(f, v, _)| Cross::new((f, v), 7, UPDATED.stroke_width(3))))?
                .label("updated film model")
                .legend(|(x, y)| Cross::new((x + 12, y), 7, UPDATED.stroke_width(3)));
        }
        legend!(chart)?;
    }
    root.present()?;
    Ok(())
}

/// Measured and predicted relative motion over the plotted excerpt, um.
fn motion_time(show: &Show, record: &str, path: &Path) -> Result<()> {
    let root = SVGBackend::new(path, (1300, 800)).into_drawing_area();
    let ts = &show.motion.time_series;
    let title = format!(
        "Relative motion, measured vs film model driven by the measured forces (last {:.2} s)",
        ts.t_s.last().zip(ts.t_s.first()).map_or(0.0, |(b, a)| b - a)
    );
    let body = header(&root, &title, &subtitle(show, record))?;
    let panels = body.split_evenly((2, 1));
    for (k, panel) in panels.iter().enumerate() {
        let (meas, pred) = if k == 0 { (&ts.measured_x_m, &ts.predicted_x_m) } else { (&ts.measured_y_m, &ts.predicted_y_m) };
        let Some(axis) = show.motion.axes.get(k) else { continue };
        let um = |v: &[f64]| -> Vec<f64> { v.iter().map(|a| a * 1e6).collect() };
        let (m, p) = (um(meas), um(pred));
        let (y0, y1) = padded(m.iter().chain(&p).copied());
        let (x0, x1) = padded(ts.t_s.iter().copied());
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{} (NRMSE of the dynamic part {:.2} %)", axis.axis, 100.0 * axis.nrmse), (FONT, 17))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart.configure_mesh().x_desc("time (s)").y_desc(format!("{} (um)", axis.axis)).label_style((FONT, 13)).light_line_style(GRID).draw()?;
        chart
            .draw_series(LineSeries::new(ts.t_s.iter().copied().zip(m), MEASURED.stroke_width(2)))?
            .label("measured")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], MEASURED.stroke_width(2)));
        chart
            .draw_series(LineSeries::new(ts.t_s.iter().copied().zip(p), PREDICTED.stroke_width(1)))?
            .label("predicted (film model)")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], PREDICTED.stroke_width(2)));
        legend!(chart)?;
    }
    root.present()?;
    Ok(())
}

fn db(v: f64, reference: f64) -> f64 {
    20.0 * (v.max(1e-30) / reference).log10()
}

/// Measured and predicted motion spectra, dB re 1 um.
fn motion_spectrum(show: &Show, record: &str, path: &Path) -> Result<()> {
    let root = SVGBackend::new(path, (1300, 800)).into_drawing_area();
    let s = &show.motion.spectrum;
    let title = format!("Motion spectra, measured vs predicted (Welch, {:.3} Hz bins)", s.resolution_hz);
    let body = header(&root, &title, &subtitle(show, record))?;
    let panels = body.split_evenly((2, 1));
    for (k, panel) in panels.iter().enumerate() {
        let (meas, pred) = if k == 0 { (&s.measured_x_m, &s.predicted_x_m) } else { (&s.measured_y_m, &s.predicted_y_m) };
        let m: Vec<f64> = meas.iter().map(|a| db(*a, 1e-6)).collect();
        let p: Vec<f64> = pred.iter().map(|a| db(*a, 1e-6)).collect();
        let top = m.iter().chain(&p).copied().filter(|v| v.is_finite()).fold(-300.0, f64::max);
        let x1 = s.frequency_hz.last().copied().unwrap_or(1.0).max(1.0);
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{} amplitude per bin", ["x", "y"][k]), (FONT, 17))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..x1, (top - 100.0)..(top + 5.0))?;
        chart.configure_mesh().x_desc("frequency (Hz)").y_desc("dB re 1 um").label_style((FONT, 13)).light_line_style(GRID).draw()?;
        let clip = move |v: f64| v.max(top - 100.0);
        chart
            .draw_series(LineSeries::new(s.frequency_hz.iter().copied().zip(m.iter().map(|v| clip(*v))), MEASURED.stroke_width(2)))?
            .label("measured")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], MEASURED.stroke_width(2)));
        chart
            .draw_series(LineSeries::new(s.frequency_hz.iter().copied().zip(p.iter().map(|v| clip(*v))), PREDICTED.stroke_width(1)))?
            .label("predicted (film model)")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], PREDICTED.stroke_width(2)));
        legend!(chart)?;
    }
    root.present()?;
    Ok(())
}

/// Identified (with +-2 SE bars) and model coefficients per window against window time.
fn coefficients(show: &Show, record: &str, path: &Path) -> Result<()> {
    let root = SVGBackend::new(path, (1700, 900)).into_drawing_area();
    let body = header(&root, "Identified coefficients per window (±2 SE) against the film model at each window's operating point", &subtitle(show, record))?;
    let panels = body.split_evenly((2, 4));
    let w = &show.coefficients.windows;
    for (k, panel) in panels.iter().enumerate() {
        let unit = if k < 4 { "N/m" } else { "N s/m" };
        let pts: Vec<(f64, f64, f64, f64)> = w.iter().map(|w| (0.5 * (w.t_start_s + w.t_end_s), w.identified[k], w.standard_error[k], w.model[k])).collect();
        let (y0, y1) = padded(pts.iter().flat_map(|p| [p.1 - 2.0 * p.2, p.1 + 2.0 * p.2, p.3]));
        let (x0, x1) = padded(pts.iter().map(|p| p.0));
        let mut chart = ChartBuilder::on(panel)
            .caption(COEFFICIENT_NAMES[k], (FONT, 17))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(80)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc("window mid-time (s)")
            .y_desc(unit)
            .label_style((FONT, 12))
            .light_line_style(GRID)
            .y_label_formatter(&|v| format!("{v:.3e}"))
            .draw()?;
        chart
            .draw_series(LineSeries::new(pts.iter().map(|p| (p.0, p.3)), BLACK.stroke_width(2)))?
            .label("film model")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], BLACK.stroke_width(2)));
        chart.draw_series(pts.iter().map(|p| PathElement::new(vec![(p.0, p.1 - 2.0 * p.2), (p.0, p.1 + 2.0 * p.2)], MEASURED.stroke_width(1))))?;
        chart
            .draw_series(pts.iter().map(|p| Circle::new((p.0, p.1), 4, MEASURED.filled())))?
            .label("identified")
            .legend(|(x, y)| Circle::new((x + 12, y), 4, MEASURED.filled()));
        legend!(chart)?;
    }
    root.present()?;
    Ok(())
}

/// Each coefficient against one variable with its straight-line fit.
fn trends(show: &Show, record: &str, var: TrendVariable, path: &Path) -> Result<()> {
    let root = SVGBackend::new(path, (1700, 900)).into_drawing_area();
    let title = format!("Identified coefficients against {} with straight-line fits (slope ± SE)", var.label());
    let body = header(&root, &title, &subtitle(show, record))?;
    let panels = body.split_evenly((2, 4));
    for (k, panel) in panels.iter().enumerate() {
        let Some(t) = show.trends.iter().find(|t| t.variable == var && t.coefficient == COEFFICIENT_NAMES[k]) else { continue };
        let (x0, x1) = padded(t.points.iter().map(|p| p[0]));
        let (y0, y1) = padded(t.points.iter().map(|p| p[1]));
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{}: {:+.2} % over the range (t = {:.1})", t.coefficient, 100.0 * t.relative_change_over_range, t.t_statistic), (FONT, 15))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(80)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart.configure_mesh().x_desc(var.label()).label_style((FONT, 12)).light_line_style(GRID).y_label_formatter(&|v| format!("{v:.3e}")).draw()?;
        let mu = t.points.iter().map(|p| p[0]).sum::<f64>() / t.points.len() as f64;
        let line = [x0, x1].map(|x| (x, t.mean + t.slope * (x - mu)));
        let color = if t.is_notable() { PREDICTED } else { RGBColor(150, 150, 150) };
        chart.draw_series(LineSeries::new(line, color.stroke_width(2)))?;
        chart.draw_series(t.points.iter().map(|p| Circle::new((p[0], p[1]), 4, MEASURED.filled())))?;
    }
    root.present()?;
    Ok(())
}

/// Residual spectra of the baseline fit, dB re 1 N, the named lines marked.
fn residual_spectrum(show: &Show, record: &str, path: &Path) -> Result<()> {
    let root = SVGBackend::new(path, (1300, 800)).into_drawing_area();
    let r = &show.residual;
    let what = if r.baseline.is_some() { "F - (K r + C r'), K-C fit over the record" } else { "dynamic film force (no baseline fit)" };
    // The legend of the circles goes in the subtitle: the title must fit the width.
    let legend = format!("{}; circles: black excitation, red harmonics/intermodulation, green shaft 1X", subtitle(show, record));
    let body = header(&root, &format!("Residual spectra: {what}"), &legend)?;
    let panels = body.split_evenly((2, 1));
    for (k, panel) in panels.iter().enumerate() {
        let amp = if k == 0 { &r.amplitude_x_n } else { &r.amplitude_y_n };
        let v: Vec<f64> = amp.iter().map(|a| db(*a, 1.0)).collect();
        let top = v.iter().copied().filter(|v| v.is_finite()).fold(-300.0, f64::max);
        let x1 = r.frequency_hz.last().copied().unwrap_or(1.0).max(1.0);
        let lo = top - 60.0;
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{} residual (residual rms {:.3} N of {:.3} N dynamic force)", ["x", "y"][k], r.residual_rms_n[k], r.force_rms_n[k]), (FONT, 17))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..x1, lo..(top + 5.0))?;
        chart.configure_mesh().x_desc("frequency (Hz)").y_desc("dB re 1 N").label_style((FONT, 13)).light_line_style(GRID).draw()?;
        chart.draw_series(LineSeries::new(r.frequency_hz.iter().copied().zip(v.iter().map(|a| a.max(lo))), MEASURED.stroke_width(1)))?;
        for c in &r.components {
            let Some(f) = c.frequency_hz else { continue };
            let color = match c.kind {
                ComponentKind::Excitation => BLACK,
                ComponentKind::Harmonic { .. } | ComponentKind::Intermodulation => PREDICTED,
                _ => RGBColor(44, 160, 44),
            };
            chart.draw_series(std::iter::once(Circle::new((f, db(c.amplitude_n[k], 1.0).max(lo)), 5, color.stroke_width(2))))?;
        }
    }
    root.present()?;
    Ok(())
}

fn pct(v: f64) -> String {
    format!("{:+.2} %", 100.0 * v)
}

fn trend_cell(t: &Trend) -> String {
    let mark = if t.is_notable() { "**" } else { "" };
    let per_unit = match t.variable {
        TrendVariable::TemperatureC | TrendVariable::TimeS => format!(", {:+.2} %/{}", 100.0 * t.relative_slope_per_unit, t.variable.unit()),
        _ => String::new(),
    };
    format!("{mark}{:+.2} %{per_unit} (t = {:.1}){mark}", 100.0 * t.relative_change_over_range, t.t_statistic)
}

/// The report text.
fn markdown(record: &str, s: &Show, diagnosis: Option<&Diagnosis>, figures: &[String]) -> String {
    let mut m = String::new();
    let o = &s.operating;
    // `write!` into a String cannot fail; its Result is ignored throughout.
    let _ = writeln!(m, "# What the model gets wrong: `{record}`\n");
    let _ = writeln!(m, "Rig `{}`. {}\n", s.rig, s.frame);
    if let Some(d) = diagnosis {
        verdict_section(&mut m, d, figures);
    }
    let _ = writeln!(m, "## What was measured\n");
    let _ = writeln!(m, "| quantity | value |\n|---|---|");
    let _ = writeln!(m, "| record | {} samples at {} Hz ({:.2} s) |", s.samples, s.sample_rate_hz, s.duration_s);
    let _ = writeln!(m, "| speed | {:.1} rpm ({:?}) |", s.speed_rpm, s.speed_source);
    let _ = writeln!(m, "| bearing temperature | {:.2} C (range {:.2} to {:.2} C) |", o.temperature_c, o.temperature_range_c[0], o.temperature_range_c[1]);
    let _ = writeln!(m, "| viscosity at the mean temperature | {:.4} Pa s |", o.viscosity_pa_s);
    let _ = writeln!(m, "| static film force (eq. 2) | ({:.1}, {:.1}) N, load {:.1} N |", o.static_force_n[0], o.static_force_n[1], o.load_n);
    let _ = writeln!(m, "| bellows f3 | {:.1} N mean; f3 - m g = {:.1} N |", o.bellows_mean_n, o.bellows_load_n);
    let _ = writeln!(m, "| Sommerfeld S / load parameter F_Y | {:.4} / {:.4} |", o.sommerfeld, o.load_parameter);
    let _ = writeln!(m, "| journal position, measured | ({:.2}, {:.2}) um |", 1e6 * o.measured_position_m[0], 1e6 * o.measured_position_m[1]);
    let _ = writeln!(
        m,
        "| journal position, film model | ({:.2}, {:.2}) um, eccentricity {:.3}, attitude {:.1} deg |",
        1e6 * o.model_position_m[0],
        1e6 * o.model_position_m[1],
        o.model_eccentricity,
        o.model_attitude_deg
    );
    let lines: Vec<String> = s.excitation_lines_hz.iter().map(|f| format!("{f:.2}")).collect();
    let _ = writeln!(m, "| excitation lines (applied force) | {} Hz |\n", if lines.is_empty() { "none".to_string() } else { lines.join(", ") });

    let mo = &s.motion;
    let _ = writeln!(m, "## How well the model predicts the motion\n");
    let _ = writeln!(
        m,
        "The linear rig (the housing on the film's K and C) was driven from {:.3} s by the measured exciter and bellows forces, at the measured speed, load and mean temperature; the film model of the rig file, and the updated one where there is an update. \
         The first {:.3} s are discarded as start-up ({}); {:.3} s to {:.3} s are compared.\n",
        mo.simulated_from_s,
        mo.transient_discarded_s,
        mo.slowest_decay_rate_per_s.map_or("the linear model does not decay".to_string(), |r| format!("slowest linear mode decays at {r:.1} 1/s")),
        mo.compared_s[0],
        mo.compared_s[1]
    );
    let _ = writeln!(m, "| axis | NRMSE (dynamic), film model | updated film model | measured rms | predicted rms | error rms | static position, model - measured |\n|---|---|---|---|---|---|---|");
    for a in &mo.axes {
        let _ = writeln!(
            m,
            "| {} | {:.2} % | {} | {:.4} um | {:.4} um | {:.4} um | {:+.3} um |",
            a.axis,
            100.0 * a.nrmse,
            a.updated_nrmse.map_or("-".to_string(), |u| format!("{:.2} %", 100.0 * u)),
            1e6 * a.measured_rms_m,
            1e6 * a.predicted_rms_m,
            1e6 * a.error_rms_m,
            1e6 * (a.predicted_mean_m - a.measured_mean_m)
        );
    }
    let _ = writeln!(
        m,
        "\nAt the excitation lines: amplitude measured / film model (/ updated), the ratio film model / measured and the phase film model - measured. \
         An axis that does not move at a line (below a tenth of its strongest line) is marked `not excited`: a ratio there compares noise.\n"
    );
    let _ = writeln!(m, "| line (Hz) | x amplitude (um) | x ratio | x phase | y amplitude (um) | y ratio | y phase |\n|---|---|---|---|---|---|---|");
    let cell = |l: &oilfilm_diagnosis::show::LineComparison| -> [String; 3] {
        let amp = match l.updated_amplitude_m {
            Some(u) => format!("{:.4} / {:.4} / {:.4}", 1e6 * l.measured_amplitude_m, 1e6 * l.predicted_amplitude_m, 1e6 * u),
            None => format!("{:.4} / {:.4}", 1e6 * l.measured_amplitude_m, 1e6 * l.predicted_amplitude_m),
        };
        if l.excited {
            [amp, format!("{:.4}", l.amplitude_ratio), format!("{:+.2} deg", l.phase_difference_deg)]
        } else {
            [amp, "not excited".into(), "-".into()]
        }
    };
    if let [ax, ay] = &mo.axes[..] {
        for (lx, ly) in ax.lines.iter().zip(&ay.lines) {
            let ([a, b, c], [d, e, f]) = (cell(lx), cell(ly));
            let _ = writeln!(m, "| {:.2} | {a} | {b} | {c} | {d} | {e} | {f} |", lx.frequency_hz);
        }
    }

    let c = &s.coefficients;
    let _ = writeln!(m, "\n## Identified against model coefficients\n");
    if let Some(why) = &c.refusal {
        let _ = writeln!(m, "No window was identified: {why}\n");
    } else {
        let n = c.windows.len() as f64;
        let _ = writeln!(
            m,
            "{} window(s) accepted, {} refused. Means over the accepted windows; the model is evaluated at each window's own operating point.\n",
            c.windows.len(),
            c.refused.len()
        );
        let _ = writeln!(m, "| coefficient | identified | mean SE | film model | identified - model |\n|---|---|---|---|---|");
        for (k, name) in COEFFICIENT_NAMES.iter().enumerate() {
            let mean = |f: &dyn Fn(&oilfilm_diagnosis::show::WindowComparison) -> f64| c.windows.iter().map(f).sum::<f64>() / n;
            let rel = c.mean_relative_difference.map_or(f64::NAN, |r| r[k]);
            let unit = if k < 4 { "N/m" } else { "N s/m" };
            let _ = writeln!(
                m,
                "| {name} | {:.4e} {unit} | {:.2e} | {:.4e} | {} |",
                mean(&|w| w.identified[k]),
                mean(&|w| w.standard_error[k]),
                mean(&|w| w.model[k]),
                pct(rel)
            );
        }
        for r in &c.refused {
            let _ = writeln!(m, "\n- refused {:.2}-{:.2} s: {}", r.t_start_s, r.t_end_s, r.reason);
        }
    }

    let _ = writeln!(m, "\n## Trends across windows\n");
    if s.trends.is_empty() {
        let _ = writeln!(m, "Too few windows (or no spread in any variable) for trends.");
    } else {
        let _ = writeln!(
            m,
            "Change of each coefficient across the observed range of the variable (straight-line fit, as a fraction of its mean; per unit for temperature and time), with t = slope / SE. \
             **Bold**: notable, i.e. at least {TREND_MIN_WINDOWS} windows, |t| > {TREND_SIGNIFICANT_T} and a change above {:.0} %.\n",
            100.0 * TREND_MIN_CHANGE
        );
        for v in TrendVariable::ALL {
            if let Some(t) = s.trends.iter().find(|t| t.variable == v) {
                let _ = writeln!(m, "- {} ranges over {:.4} to {:.4}", v.label(), t.range[0], t.range[1]);
            }
        }
        let _ = writeln!(m);
        let vars: Vec<TrendVariable> = TrendVariable::ALL.into_iter().filter(|v| s.trends.iter().any(|t| t.variable == *v)).collect();
        let _ = writeln!(m, "| coefficient | {} |", vars.iter().map(|v| v.label()).collect::<Vec<_>>().join(" | "));
        let _ = writeln!(m, "|---|{}", "---|".repeat(vars.len()));
        for name in COEFFICIENT_NAMES {
            let cells: Vec<String> =
                vars.iter().map(|v| s.trends.iter().find(|t| t.variable == *v && t.coefficient == name).map_or("-".into(), trend_cell)).collect();
            let _ = writeln!(m, "| {name} | {} |", cells.join(" | "));
        }
    }

    let r = &s.residual;
    let _ = writeln!(m, "\n## Residual spectra of the baseline K-C fit\n");
    match (&r.baseline, &r.refusal) {
        (Some(b), _) => {
            let txt: Vec<String> = COEFFICIENT_NAMES.iter().zip(b).map(|(n, v)| format!("{n} = {v:.4e}")).collect();
            let _ = writeln!(m, "Baseline fit over the whole record: {}.", txt.join(", "));
        }
        (None, Some(why)) => {
            let _ = writeln!(m, "No baseline fit over the whole record ({why}); the spectra are of the dynamic film force itself.");
        }
        (None, None) => {}
    }
    let _ = writeln!(
        m,
        "Residual rms x {:.3} N, y {:.3} N (dynamic film force rms x {:.3} N, y {:.3} N); band {:.1}-{:.1} Hz. dB: the line's peak bin over the median bin of the band.\n",
        r.residual_rms_n[0], r.residual_rms_n[1], r.force_rms_n[0], r.force_rms_n[1], r.band_hz[0], r.band_hz[1]
    );
    let _ = writeln!(m, "| component | x amplitude | x dB above floor | x share | y amplitude | y dB above floor | y share |\n|---|---|---|---|---|---|---|");
    for comp in &r.components {
        let _ = writeln!(
            m,
            "| {} | {:.3} N | {:+.1} | {:.1} % | {:.3} N | {:+.1} | {:.1} % |",
            comp.name,
            comp.amplitude_n[0],
            comp.db_above_floor[0],
            100.0 * comp.fraction_of_residual[0],
            comp.amplitude_n[1],
            comp.db_above_floor[1],
            100.0 * comp.fraction_of_residual[1]
        );
    }

    let _ = writeln!(m, "\n## Where model and measurement disagree\n");
    let findings = disagreements(s);
    if findings.is_empty() {
        let _ = writeln!(m, "Nowhere beyond the thresholds (NRMSE 5 %, line amplitude 5 % or phase 5 deg, coefficient 5 %, notable trend, residual line 10 dB above the floor).");
    }
    for f in findings {
        let _ = writeln!(m, "- {f}");
    }

    if !s.notes.is_empty() {
        let _ = writeln!(m, "\n## Notes\n");
        for n in &s.notes {
            let _ = writeln!(m, "- {n}");
        }
    }
    let _ = writeln!(m, "\n## Figures\n");
    for f in figures {
        let _ = writeln!(m, "- [{f}]({f})");
    }
    m
}

/// Plain-language findings past fixed thresholds.
fn disagreements(s: &Show) -> Vec<String> {
    let mut out = Vec::new();
    for a in &s.motion.axes {
        if a.nrmse > 0.05 {
            out.push(format!("the predicted {} motion misses the measured one by {:.1} % (NRMSE)", a.axis, 100.0 * a.nrmse));
        }
        for l in a.lines.iter().filter(|l| l.excited) {
            if (l.amplitude_ratio - 1.0).abs() > 0.05 || l.phase_difference_deg.abs() > 5.0 {
                out.push(format!(
                    "at {:.2} Hz the model's {} amplitude is {:.1} % of the measured, {:+.1} deg out of phase",
                    l.frequency_hz,
                    a.axis,
                    100.0 * l.amplitude_ratio,
                    l.phase_difference_deg
                ));
            }
        }
    }
    if let Some(r) = s.coefficients.mean_relative_difference {
        for (n, v) in COEFFICIENT_NAMES.iter().zip(r) {
            if v.abs() > 0.05 {
                out.push(format!("identified {n} differs from the film model by {}", pct(v)));
            }
        }
    }
    let mut sig: Vec<&Trend> = s.trends.iter().filter(|t| t.is_notable()).collect();
    sig.sort_by(|a, b| b.t_statistic.abs().total_cmp(&a.t_statistic.abs()));
    for t in sig.iter().take(8) {
        out.push(format!(
            "{} trends with {}: {:+.2} % across the record's range (t = {:.1})",
            t.coefficient,
            t.variable.label(),
            100.0 * t.relative_change_over_range,
            t.t_statistic
        ));
    }
    for c in &s.residual.components {
        if c.kind != ComponentKind::Broadband && c.db_above_floor.iter().any(|d| *d > 10.0) {
            out.push(format!("the residual holds {} at {:+.1} dB (x) / {:+.1} dB (y) above its floor", c.name, c.db_above_floor[0], c.db_above_floor[1]));
        }
    }
    out
}

fn fmt_value(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Number(n) => {
            n.as_f64().map_or(n.to_string(), |x| if x != 0.0 && (x.abs() < 1e-3 || x.abs() >= 1e5) { format!("{x:.4e}") } else { format!("{x:.4}") })
        }
        serde_json::Value::String(s) => s.clone(),
        serde_json::Value::Null => "-".into(),
        serde_json::Value::Object(o) => o.iter().map(|(k, v)| format!("{k} = {}", fmt_value(v))).collect::<Vec<_>>().join(", "),
        other => other.to_string(),
    }
}

fn matrix(mtx: &nalgebra::Matrix2<f64>) -> String {
    format!("[[{:.4e}, {:.4e}], [{:.4e}, {:.4e}]]", mtx[(0, 0)], mtx[(0, 1)], mtx[(1, 0)], mtx[(1, 1)])
}

/// The opening of the report: the verdict, the model update and the figure at the lines, then
/// how the verdict was reached.
fn verdict_section(m: &mut String, d: &Diagnosis, figures: &[String]) {
    let also = if d.also.is_empty() {
        String::new()
    } else {
        format!(" (also in the model: {})", d.also.iter().map(|c| format!("`{c}`")).collect::<Vec<_>>().join(", "))
    };
    let _ = writeln!(m, "## Verdict: `{}`{also}\n", d.cause);
    let _ = writeln!(m, "{}\n", d.reason);
    if !d.parameters.is_empty() {
        let _ = writeln!(m, "| parameter | value | standard error |\n|---|---|---|");
        for (k, v) in &d.parameters {
            let _ = writeln!(m, "| {k} | {} | {} |", fmt_value(v), d.standard_errors.get(k).map_or("-".into(), |s| format!("{s:.3e}")));
        }
        let _ = writeln!(m);
    }
    if let (Some(b), Some(e)) = (d.baseline_heldout_nrmse, d.extended_heldout_nrmse) {
        let _ = writeln!(m, "Held-out NRMSE of the film force: linear K-C {b:.4}, chosen model {e:.4}.\n");
    }
    if let Some(u) = &d.model_update {
        let _ = writeln!(m, "## What the simulation gets wrong: the model update\n");
        let _ = writeln!(
            m,
            "The film model of the rig file predicts the measured motion with a held-out NRMSE of **{:.3}**; updated to the record it predicts **{:.3}**, {:.1} times better ({}).\n",
            u.nominal_heldout_nrmse, u.updated_heldout_nrmse, u.improvement_factor, u.how
        );
        let _ = writeln!(m, "| | rig file (nominal) | updated (standard error) |\n|---|---|---|");
        let _ = writeln!(m, "| film theory | {} | {} |", u.nominal_theory, u.theory);
        let _ = writeln!(m, "| radial clearance | {:.2} um | {:.2} um ({:.2}) |", 1e6 * u.nominal_clearance_m, 1e6 * u.clearance_m, 1e6 * u.clearance_se_m);
        let _ = writeln!(
            m,
            "| viscosity | {:.5} Pa s (oil law at the measured temperature) | {:.5} Pa s ({:.5}){} |",
            u.nominal_viscosity_pa_s,
            u.viscosity_pa_s,
            u.viscosity_se_pa_s,
            u.temperature_offset_c.map_or(String::new(), |t| format!(", as if the film ran {t:+.1} C from the thermocouple"))
        );
        let _ = writeln!(m, "| K (N/m) | {} | {} |", matrix(&u.nominal_stiffness_n_m), matrix(&u.updated_stiffness_n_m));
        let _ = writeln!(m, "| C (N s/m) | {} | {} |", matrix(&u.nominal_damping_n_s_m), matrix(&u.updated_damping_n_s_m));
        let _ = writeln!(m, "| identified K, C | {} | {} |\n", matrix(&u.identified_stiffness_n_m), matrix(&u.identified_damping_n_s_m));
        let _ = writeln!(m, "Theories fitted to the identified coefficients (relative mismatch of K and C):\n");
        for t in &u.theories {
            let _ = writeln!(
                m,
                "- {}: {:.2} % at clearance {:.2} um, viscosity {:.5} Pa s",
                t.theory,
                100.0 * t.coefficient_mismatch,
                1e6 * t.clearance_m,
                t.viscosity_pa_s
            );
        }
        let _ = writeln!(m);
    }
    if figures.iter().any(|f| f == "lines.svg") {
        let _ = writeln!(m, "![The motion at the excitation lines: measured, film model, updated film model](lines.svg)\n");
    }
    if let Some(c) = &d.coefficients {
        let _ = writeln!(m, "## Coefficients to keep\n");
        let _ = writeln!(m, "The chosen model's K and C (small amplitude, on the corrected data), with their standard errors; the plain linear fit of the record as measured beside them.\n");
        let _ = writeln!(m, "| | K (N/m) | C (N s/m) |\n|---|---|---|");
        let _ = writeln!(m, "| chosen model | {} | {} |", matrix(&c.stiffness_n_m), matrix(&c.damping_n_s_m));
        let _ = writeln!(m, "| standard error | {} | {} |", matrix(&c.stiffness_se), matrix(&c.damping_se));
        if let (Some(k), Some(cc)) = (&c.stiffness_at_start_n_m, &c.damping_at_start_n_s_m) {
            let _ = writeln!(m, "| at the record's start (drift trend) | {} | {} |", matrix(k), matrix(cc));
        }
        let _ = writeln!(m, "| linear K-C as measured | {} | {} |\n", matrix(&c.linear_stiffness_n_m), matrix(&c.linear_damping_n_s_m));
    }
    let _ = writeln!(m, "## How the verdict was reached\n");
    let _ = writeln!(m, "Forward selection: each step adds the catalog effect that predicts held-out blocks best on top of the model so far, if it earns its parameters (`*`).\n");
    let _ = writeln!(m, "| step | model | held-out NRMSE | candidates (held-out gain) | added |\n|---|---|---|---|---|");
    for (i, st) in d.steps.iter().enumerate() {
        let tried: Vec<String> =
            st.tried.iter().map(|c| format!("{} {:+.2} %{}", c.name, 100.0 * c.score.unwrap_or(f64::NAN), if c.earns { "*" } else { "" })).collect();
        let _ = writeln!(
            m,
            "| {} | {} | {:.4} | {} | {} |",
            i + 1,
            st.model,
            st.heldout_nrmse,
            tried.join(", "),
            st.chosen.map_or("-".to_string(), |c| c.to_string())
        );
    }
    let _ = writeln!(m);
    for c in d.candidates.iter().filter(|c| c.score.is_none()) {
        let _ = writeln!(m, "- {}: {}", c.name, c.note.clone().unwrap_or_default());
    }
    if let Some(a) = &d.amplitude {
        let _ = writeln!(
            m,
            "\n**Does the film's nonlinearity matter?** Over the record's amplitude d = {:.3} the coefficients vary by {:.1} +- {:.1} % (largest direct term, Zhou's RV); {}. It is named above {:.0} % beyond two standard errors.\n",
            a.d,
            100.0 * a.largest_direct,
            100.0 * a.largest_direct_se,
            a.film_model_largest_direct.map_or("the film model could not be evaluated on this orbit".to_string(), |f| format!("the film model predicts {:.1} % on the same orbit", 100.0 * f)),
            100.0 * a.threshold
        );
    }
    let _ = writeln!(m, "**Does structure remain?** General extensions tried on top of the chosen model:\n");
    for st in &d.structure {
        let _ = writeln!(
            m,
            "- {}: {:+.2} % on held-out blocks{}",
            st.name.name(),
            100.0 * st.score.unwrap_or(f64::NAN),
            if st.remains { format!(" -- **remains**: {}", st.description) } else { String::new() }
        );
    }
    if !d.aliases.is_empty() {
        let _ = writeln!(m, "\n**Look-alikes:**\n");
        for a in &d.aliases {
            let _ = writeln!(m, "- {} / {}: {} -- {}", a.pair[0], a.pair[1], if a.separable { "told apart" } else { "not separable here" }, a.evidence);
        }
    }
    for n in &d.notes {
        let _ = writeln!(m, "\n- note: {n}");
    }
    let _ = writeln!(m);
}

#[cfg(test)]
mod tests {
    use super::*;
    use oilfilm_diagnosis::show::ShowConfig;
    use oilfilm_diagnosis::{diagnose_prepared, evidence, DiagnosisOptions};
    use oilfilm_identification::excitation::ExcitationPlan;
    use oilfilm_identification::pipeline::{self, SpeedSource};
    use oilfilm_identification::simulate::{self, SimulateOptions};
    use oilfilm_physics::config::RigConfig;
    use oilfilm_physics::film::FilmModelConfig;

    #[test]
    fn write_report_opens_with_the_verdict_and_the_update_and_holds_its_sections_and_numbers() {
        let mut rig = RigConfig::zhou2004().unwrap();
        rig.film = FilmModelConfig::Short;
        rig.daq.set_displacement_probe_noise(2.0e-8);
        let rec = simulate::simulate(&rig, &ExcitationPlan::multisine([5.0, 80.0], 1.0, 150.0), 6.0, SimulateOptions::default(), &mut |_| {}).unwrap();
        let raw = rec.raw().unwrap();
        let cal = pipeline::calibration_for(&rig, &raw, &pipeline::rig_offsets(&rig, &raw).unwrap()).unwrap();
        let options = DiagnosisOptions::default();
        let p = evidence::prepare(&raw, &cal, &rig, rec.speed_rpm, SpeedSource::Record, &options.prepare).unwrap().unwrap();
        let d = diagnose_prepared(&p, &rig, &options).unwrap();
        let show = oilfilm_diagnosis::show(&p, &rig, d.model_update.as_ref(), &ShowConfig::default()).unwrap();
        assert!(show.coefficients.windows.len() >= 3, "windows: {:?}; notes {:?}", show.coefficients.refused, show.notes);
        let dir = std::env::temp_dir().join(format!("oilfilm-diagnose-report-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let paths = write_report(&dir, "sim.txt", &show, Some(&d)).unwrap();
        for name in ["lines.svg", "motion_time.svg", "motion_spectrum.svg", "coefficients.svg", "trends_time.svg", "residual_spectrum.svg", "report.md"] {
            let p = dir.join(name);
            assert!(paths.contains(&p), "{name} not reported as written");
            let meta = std::fs::metadata(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(meta.len() > 500, "{name} is only {} bytes", meta.len());
        }
        let text = std::fs::read_to_string(dir.join("report.md")).unwrap();
        let order = [
            "## Verdict: ",
            "## What the simulation gets wrong: the model update",
            "](lines.svg)",
            "## Coefficients to keep",
            "## How the verdict was reached",
            "## What was measured",
            "## How well the model predicts the motion",
            "## Identified against model coefficients",
            "## Trends across windows",
            "## Residual spectra of the baseline K-C fit",
            "## Where model and measurement disagree",
        ];
        let mut at = 0;
        for section in order {
            let i = text[at..].find(section).unwrap_or_else(|| panic!("missing (or out of order) {section}"));
            at += i + section.len();
        }
        // The numbers of the diagnosis and the show appear as the report prints them.
        assert!(text.contains(&format!("## Verdict: `{}`", d.cause)));
        let u = d.model_update.as_ref().expect("an update");
        assert!(text.contains(&format!("held-out NRMSE of **{:.3}**", u.nominal_heldout_nrmse)));
        let x = &show.motion.axes[0];
        assert!(text.contains(&format!("| x | {:.2} % |", 100.0 * x.nrmse)), "x NRMSE missing");
        assert!(text.contains(&format!("{:.2} C", show.operating.temperature_c)));
        assert!(text.contains(&format!("{} window(s) accepted", show.coefficients.windows.len())));
        // Each exciter moves the housing along its own axis: at a line only one exciter drives,
        // so some line leaves an axis nearly still and is marked rather than given a ratio.
        let svg = std::fs::read_to_string(dir.join("lines.svg")).unwrap();
        assert!(svg.contains("<svg") && svg.contains("updated film model"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
