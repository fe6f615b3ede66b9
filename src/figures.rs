//! The campaign's figures as SVG (plotters' SVG backend: no fonts or system libraries; the
//! viewer renders the text). One file per figure of Zhou et al. (2004), section 3:
//! Figs 5-6 (coefficients against F_Y), 7-8 (against d), 9-10 (relative variation).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use oilfilm_identification::campaign::{self, AmplitudeSweep, Campaign, COEFFICIENT_NAMES};
use plotters::coord::Shift;
use plotters::prelude::*;

const FONT: &str = "sans-serif";
/// Four curves per RV panel: blue, red, green, orange.
const PALETTE: [RGBColor; 4] = [RGBColor(31, 119, 180), RGBColor(214, 39, 40), RGBColor(44, 160, 44), RGBColor(255, 127, 14)];
/// Identified points by speed (no red: red is the fit's).
const SPEED_COLORS: [RGBColor; 5] = [RGBColor(31, 119, 180), RGBColor(44, 160, 44), RGBColor(255, 127, 14), RGBColor(148, 103, 189), RGBColor(140, 86, 75)];
const FIT_COLOR: RGBColor = RGBColor(200, 30, 30);

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// A dashed legend icon at `(x, y)`: three short strokes (a macro: the composed element's
/// type is unwieldy to name).
macro_rules! dashed_icon {
    ($x:expr, $y:expr, $style:expr) => {
        EmptyElement::at(($x, $y))
            + PathElement::new(vec![(0, 0), (6, 0)], $style)
            + PathElement::new(vec![(9, 0), (15, 0)], $style)
            + PathElement::new(vec![(18, 0), (24, 0)], $style)
    };
}

/// Writes every figure into `dir`; returns the paths written.
pub fn write_all(c: &Campaign, dir: &Path) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for (file, first, what) in [("fig5_stiffness_vs_fy.svg", 0, "stiffness"), ("fig6_damping_vs_fy.svg", 4, "damping")] {
        let path = dir.join(file);
        coefficients_vs_fy(c, &path, first, what).with_context(|| format!("cannot write figure {}", path.display()))?;
        out.push(path);
    }
    let d_max = c.amplitude_study.low.max_d.max(c.amplitude_study.high.max_d);
    for (file, first, what) in [("fig7_stiffness_vs_d.svg", 0, "stiffness"), ("fig8_damping_vs_d.svg", 4, "damping")] {
        let path = dir.join(file);
        coefficients_vs_d(c, &path, first, what, d_max).with_context(|| format!("cannot write figure {}", path.display()))?;
        out.push(path);
    }
    // One RV scale for Figs 9 and 10, so that the two load parameters compare by eye.
    let rv_range = rv_range(c, d_max);
    for (file, sweep, fig) in [("fig9_rv_fy035.svg", &c.amplitude_study.low, 9), ("fig10_rv_fy13.svg", &c.amplitude_study.high, 10)] {
        let path = dir.join(file);
        relative_variation(c, sweep, fig, &path, d_max, rv_range).with_context(|| format!("cannot write figure {}", path.display()))?;
        out.push(path);
    }
    Ok(out)
}

/// `[lo, hi]` of the finite values with 8 % padding and a minimum span (a thousandth of the
/// largest magnitude, so a flat series of micrometres still gets an axis). Shared by every
/// figure of the CLI.
pub(crate) fn padded(values: impl IntoIterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.into_iter().filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    let span = (hi - lo).max(1e-3 * hi.abs().max(lo.abs()).max(1e-12));
    (lo - 0.08 * span, hi + 0.08 * span)
}

/// The model curve's legend: a finite-difference film ("... 72 x 8 grid ...") is slightly rough
/// along F_Y (its free boundary crosses grid nodes), which the legend says rather than
/// smoothing it away.
fn model_label(film: &str) -> String {
    let words: Vec<&str> = film.split_whitespace().collect();
    match words.windows(3).find(|w| w[1] == "x" && w[0].parse::<usize>().is_ok()) {
        Some(w) => format!("film model, linear theory ({}x{} grid: the wiggles are the grid's)", w[0], w[2]),
        None => "film model, linear theory".to_string(),
    }
}

/// "Kxx = kxx ψ³/(μωL)".
fn definition(name: &str) -> String {
    let sub = name.get(1..).unwrap_or("");
    if name.starts_with('K') {
        format!("{name} = k{sub} ψ³/(μωL)")
    } else {
        format!("{name} = d{sub} ψ³/(μL)")
    }
}

fn subtitle(c: &Campaign) -> String {
    format!(
        "simulated rig `{}`, {} dB displacement probes; frame x horizontal, y up, journal turning +x→+y; Lund's sign dF = -(K r + C r'); Zhou's groups K = kψ³/(μωL), D = dψ³/(μL), F_Y = f_y ψ²/(μUL)",
        c.rig, c.config.record.probe_snr_db
    )
}

fn header<'a>(root: &Area<'a>, title: &str, sub: &str) -> Result<Area<'a>> {
    root.fill(&WHITE)?;
    let (top, body) = root.split_vertically(62);
    top.draw(&Text::new(title.to_string(), (14, 8), (FONT, 22).into_font().style(FontStyle::Bold)))?;
    top.draw(&Text::new(sub.to_string(), (14, 38), (FONT, 13)))?;
    Ok(body)
}

/// Figs 5-6: four coefficients against F_Y, identified points by speed, the quadratic fit and
/// the film model's curve.
fn coefficients_vs_fy(c: &Campaign, path: &Path, first: usize, what: &str) -> Result<()> {
    let study = &c.load_study;
    let root = SVGBackend::new(path, (1300, 1000)).into_drawing_area();
    let fig = if first == 0 { 5 } else { 6 };
    let title = format!(
        "Fig. {fig}: linear {what} coefficients against the load parameter (after Zhou et al. 2004, Fig. {fig}): {} records at d ≈ {}",
        study.points.len(),
        c.config.load.target_d,
    );
    let body = header(&root, &title, &subtitle(c))?;
    let panels = body.split_evenly((2, 2));
    let mut speeds: Vec<f64> = study.points.iter().map(|p| p.spec.speed_rpm).collect();
    speeds.sort_by(f64::total_cmp);
    speeds.dedup();
    let fy_max =
        study.points.iter().map(|p| p.load_parameter).chain(study.model_curve.iter().map(|m| m.load_parameter)).filter(|v| v.is_finite()).fold(0.0, f64::max);
    for (panel, k) in panels.iter().zip(first..first + 4) {
        let name = COEFFICIENT_NAMES[k];
        let trend = &study.trends[k];
        let pts: Vec<(f64, f64, f64)> =
            study.points.iter().filter_map(|p| p.identified.map(|i| (p.load_parameter, i.as_array()[k], p.spec.speed_rpm))).collect();
        let model: Vec<(f64, f64)> = study.model_curve.iter().map(|m| (m.load_parameter, m.zhou.as_array()[k])).collect();
        let x_hi = fy_max * 1.05;
        let fit: Vec<(f64, f64)> = (0..=100)
            .map(|i| {
                let x = trend.fy_range[0] + (trend.fy_range[1] - trend.fy_range[0]) * i as f64 / 100.0;
                (x, trend.fit.eval(x))
            })
            .collect();
        let (y0, y1) = padded(pts.iter().map(|p| p.1).chain(model.iter().map(|p| p.1)).chain(fit.iter().map(|p| p.1)));
        let mut chart = ChartBuilder::on(panel)
            .caption(definition(name), (FONT, 18))
            .margin(12)
            .x_label_area_size(48)
            .y_label_area_size(64)
            .build_cartesian_2d(0.0..x_hi, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc("load parameter F_Y")
            .y_desc(format!("{name} (dimensionless)"))
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 15))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()?;
        chart
            .draw_series(LineSeries::new(model, BLACK.stroke_width(2)))?
            .label(model_label(&c.film_model))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], BLACK.stroke_width(2)));
        chart
            .draw_series(DashedLineSeries::new(fit, 8, 5, FIT_COLOR.stroke_width(2)))?
            .label(format!("quadratic fit to identified, R² = {:.4}", trend.fit.r_squared))
            .legend(|(x, y)| dashed_icon!(x, y, FIT_COLOR.stroke_width(2)));
        for (j, speed) in speeds.iter().enumerate() {
            let color = SPEED_COLORS[j % SPEED_COLORS.len()];
            let mine: Vec<(f64, f64)> = pts.iter().filter(|p| p.2 == *speed).map(|p| (p.0, p.1)).collect();
            chart
                .draw_series(mine.into_iter().map(move |p| Circle::new(p, 5, color.filled())))?
                .label(format!("identified, {speed:.0} rpm"))
                .legend(move |(x, y)| Circle::new((x + 12, y), 5, color.filled()));
        }
        let position = if trend.slope_sign > 0 { SeriesLabelPosition::UpperLeft } else { SeriesLabelPosition::LowerLeft };
        chart
            .configure_series_labels()
            .position(position)
            .background_style(WHITE.mix(0.9))
            .border_style(RGBColor(150, 150, 150))
            .label_font((FONT, 13))
            .draw()?;
    }
    root.present()?;
    Ok(())
}

/// Figs 7-8: four coefficients against d at both load parameters (rows), points and the
/// eq. 10 fit.
fn coefficients_vs_d(c: &Campaign, path: &Path, first: usize, what: &str, d_max: f64) -> Result<()> {
    let root = SVGBackend::new(path, (1700, 950)).into_drawing_area();
    let fig = if first == 0 { 7 } else { 8 };
    let title = format!(
        "Fig. {fig}: linear {what} coefficients against the excitation amplitude d = max|r - mean r|/c (after Zhou et al. 2004, Fig. {fig}); fit KD(d) = a d³ + b d² + d0 (eq. 10)",
    );
    let body = header(&root, &title, &subtitle(c))?;
    let rows = body.split_evenly((2, 4));
    let sweeps = [&c.amplitude_study.low, &c.amplitude_study.high];
    for (r, sweep) in sweeps.iter().enumerate() {
        for (col, k) in (first..first + 4).enumerate() {
            let panel = &rows[r * 4 + col];
            let name = COEFFICIENT_NAMES[k];
            let f = &sweep.fits[k].fit;
            let pts: Vec<(f64, f64)> = sweep.steps.iter().filter_map(|s| s.identified.map(|i| (s.amplitude_d, i.as_array()[k]))).collect();
            let curve: Vec<(f64, f64)> = (0..=100)
                .map(|i| {
                    let d = sweep.max_d * i as f64 / 100.0;
                    (d, f.eval(d))
                })
                .collect();
            let model = sweep.model.zhou.as_array()[k];
            let (y0, y1) = padded(pts.iter().map(|p| p.1).chain(curve.iter().map(|p| p.1)).chain([model]));
            let mut chart = ChartBuilder::on(panel)
                .caption(format!("{name}, {} ({:.0} rpm, {:.1} kN)", sweep.label, sweep.speed_rpm, sweep.load_n / 1e3), (FONT, 16))
                .margin(10)
                .x_label_area_size(44)
                .y_label_area_size(64)
                .build_cartesian_2d(0.0..d_max * 1.05, y0..y1)?;
            chart
                .configure_mesh()
                .x_desc("d")
                .y_desc(format!("{name} (dimensionless)"))
                .label_style((FONT, 13))
                .axis_desc_style((FONT, 14))
                .x_labels(6)
                .light_line_style(RGBColor(235, 235, 235))
                .draw()?;
            chart
                .draw_series(DashedLineSeries::new(vec![(0.0, model), (d_max * 1.05, model)], 4, 4, RGBColor(90, 90, 90).stroke_width(1)))?
                .label(format!("film model, small d: {model:.4}"))
                .legend(|(x, y)| dashed_icon!(x, y, RGBColor(90, 90, 90).stroke_width(1)));
            chart
                .draw_series(DashedLineSeries::new(curve, 8, 5, FIT_COLOR.stroke_width(2)))?
                .label(format!("eq. 10 fit: d0 {:.4}, R² {:.3}", f.d0, f.r_squared))
                .legend(|(x, y)| dashed_icon!(x, y, FIT_COLOR.stroke_width(2)));
            let color = PALETTE[0];
            chart
                .draw_series(pts.into_iter().map(move |p| Circle::new(p, 5, color.filled())))?
                .label("identified")
                .legend(move |(x, y)| Circle::new((x + 12, y), 5, color.filled()));
            // The fits fall with d for most coefficients: keep the legend where the points are not.
            let falls = f.eval(sweep.max_d) < f.d0;
            chart
                .configure_series_labels()
                .position(if falls { SeriesLabelPosition::LowerLeft } else { SeriesLabelPosition::UpperLeft })
                .background_style(WHITE.mix(0.9))
                .border_style(RGBColor(150, 150, 150))
                .label_font((FONT, 12))
                .draw()?;
        }
    }
    root.present()?;
    Ok(())
}

/// The common RV axis of Figs 9-10, in percent.
fn rv_range(c: &Campaign, d_max: f64) -> (f64, f64) {
    let mut values = vec![0.0];
    for sweep in [&c.amplitude_study.low, &c.amplitude_study.high] {
        for (k, fit) in sweep.fits.iter().enumerate() {
            for i in 0..=50 {
                let d = sweep.max_d * i as f64 / 50.0;
                values.push(100.0 * campaign::relative_variation(&fit.fit, d).unwrap_or(0.0));
            }
            for s in &sweep.steps {
                if let Some(v) = s.identified {
                    values.push(100.0 * (v.as_array()[k] - fit.fit.d0) / fit.fit.d0);
                }
            }
        }
    }
    let _ = d_max;
    padded(values)
}

/// Figs 9-10: RV of the four stiffness and four damping coefficients against d at one load
/// parameter: the eq. 11 curves from the fits and each identified point relative to its fit's
/// KD(0).
fn relative_variation(c: &Campaign, sweep: &AmplitudeSweep, fig: u32, path: &Path, d_max: f64, (y0, y1): (f64, f64)) -> Result<()> {
    let root = SVGBackend::new(path, (1500, 720)).into_drawing_area();
    let title = format!(
        "Fig. {fig}: relative variation RV = (KD(d) - KD(0))/KD(0) (eq. 11) at {} ({:.0} rpm, {:.1} kN, {:.1} C); same RV scale in Figs 9 and 10",
        sweep.label,
        sweep.speed_rpm,
        sweep.load_n / 1e3,
        sweep.temperature_c
    );
    let body = header(&root, &title, &subtitle(c))?;
    let halves = body.split_evenly((1, 2));
    for (h, (first, what)) in halves.iter().zip([(0usize, "(a) stiffness"), (4, "(b) damping")]) {
        let mut chart = ChartBuilder::on(h)
            .caption(what, (FONT, 18))
            .margin(12)
            .x_label_area_size(48)
            .y_label_area_size(64)
            .build_cartesian_2d(0.0..d_max * 1.05, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc("d = max|r - mean r| / c")
            .y_desc("RV (%)")
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 15))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()?;
        chart.draw_series(LineSeries::new(vec![(0.0, 0.0), (d_max * 1.05, 0.0)], RGBColor(120, 120, 120).stroke_width(1)))?;
        if 0.05 < d_max {
            // The paper's reference amplitude.
            chart.draw_series(DashedLineSeries::new(vec![(0.05, y0), (0.05, y1)], 5, 5, RGBColor(120, 120, 120).stroke_width(1)))?;
            chart.draw_series(std::iter::once(Text::new("d = 0.05", (0.051, y1 - 0.04 * (y1 - y0)), (FONT, 13))))?;
        }
        for (j, k) in (first..first + 4).enumerate() {
            let color = PALETTE[j];
            let fit = &sweep.fits[k].fit;
            let name = COEFFICIENT_NAMES[k];
            let curve: Vec<(f64, f64)> = (0..=100)
                .map(|i| {
                    let d = sweep.max_d * i as f64 / 100.0;
                    (d, 100.0 * campaign::relative_variation(fit, d).unwrap_or(f64::NAN))
                })
                .collect();
            let rv_end = curve.last().map_or(f64::NAN, |p| p.1);
            chart
                .draw_series(LineSeries::new(curve, color.stroke_width(2)))?
                .label(format!("{name}: RV {rv_end:+.1} % at d = {:.3}", sweep.max_d))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], color.stroke_width(2)));
            let pts: Vec<(f64, f64)> =
                sweep.steps.iter().filter_map(|s| s.identified.map(|v| (s.amplitude_d, 100.0 * (v.as_array()[k] - fit.d0) / fit.d0))).collect();
            chart.draw_series(pts.into_iter().map(move |p| Circle::new(p, 4, color.filled())))?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerLeft)
            .background_style(WHITE.mix(0.9))
            .border_style(RGBColor(150, 150, 150))
            .label_font((FONT, 14))
            .draw()?;
    }
    root.present()?;
    Ok(())
}
