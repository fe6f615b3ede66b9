//! `oilfilm campaign`: the paper's two studies on the simulated rig, by one command. Runs
//! [`oilfilm_identification::campaign::run_campaign`], writes `campaign.json` (every number)
//! and the SVG figures, and prints a summary. All computing is in the library.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use oilfilm_identification::campaign::{self, Campaign, CampaignConfig, Progress, RecordResult, COEFFICIENT_NAMES};
use oilfilm_physics::config::RigConfig;

use crate::figures;

/// Runs the campaign on `rig` and writes into `out`.
pub fn run(rig: &RigConfig, out: &Path, quick: bool, json: bool) -> Result<()> {
    let cfg = if quick { CampaignConfig::quick() } else { CampaignConfig::default() };
    let started = Instant::now();
    let mut last_shown = String::new();
    let mut progress = |p: Progress| {
        // One line on stderr, rewritten in place, at most once per 10 % of a record.
        let line = format!("[{}/{}] {} study: {} ({:.0} %)", p.record + 1, p.records, p.study, p.label, (p.fraction * 10.0).floor() * 10.0);
        if line != last_shown {
            eprint!("\r\x1b[2K{line}");
            let _ = std::io::stderr().flush();
            last_shown = line;
        }
    };
    let result = campaign::run_campaign(rig, &cfg, &mut progress);
    eprintln!();
    let c = result.with_context(|| format!("campaign on rig `{}` failed", rig.name))?;
    let wall_s = started.elapsed().as_secs_f64();

    std::fs::create_dir_all(out).with_context(|| format!("cannot create output directory {}", out.display()))?;
    let figures = figures::write_all(&c, out)?;
    let json_path = out.join("campaign.json");
    let mut value = serde_json::to_value(&c).context("cannot serialise the campaign")?;
    if let Some(obj) = value.as_object_mut() {
        obj.insert("command".into(), serde_json::json!(if quick { "oilfilm campaign --quick" } else { "oilfilm campaign" }));
        obj.insert("wall_time_s".into(), serde_json::json!(wall_s));
        obj.insert("figures".into(), serde_json::json!(figures.iter().map(|p| p.display().to_string()).collect::<Vec<_>>()));
    }
    let text = serde_json::to_string_pretty(&value).context("cannot serialise the campaign")?;
    std::fs::write(&json_path, &text).with_context(|| format!("cannot write {}", json_path.display()))?;

    if json {
        println!("{text}");
    } else {
        print_summary(&c, wall_s);
        println!();
        println!("wrote {}", json_path.display());
        for f in &figures {
            println!("wrote {}", f.display());
        }
    }
    Ok(())
}

fn row8(values: [f64; 8]) -> String {
    values.iter().map(|v| format!("{v:>8.4}")).collect::<Vec<_>>().join("")
}

fn names8() -> String {
    COEFFICIENT_NAMES.iter().map(|n| format!("{n:>8}")).collect::<Vec<_>>().join("")
}

fn print_summary(c: &Campaign, wall_s: f64) {
    let cfg = &c.config;
    println!("oilfilm campaign: Zhou et al. (2004) sections 3.2-3.3 on the simulated rig `{}` ({wall_s:.1} s)", c.rig);
    println!("frame: {}", c.frame);
    println!("units: {}", c.convention);
    println!(
        "records: two-tone, exciter 1 (45 deg) at {} x and exciter 2 (135 deg) at {} x the running frequency, {} dB displacement probes, {} s analysed after {} s ramp + {} s settling, one window each",
        cfg.record.frequency_ratios[0], cfg.record.frequency_ratios[1], cfg.record.probe_snr_db, cfg.record.analysed_s, cfg.record.ramp_s, cfg.record.settle_s
    );

    let ls = &c.load_study;
    println!();
    println!("== Load-parameter study (Figs 5-6): {} operating points, target d = {} ==", ls.points.len(), cfg.load.target_d);
    println!("{:>6} {:>7} {:>6} {:>6} {:>7} {:>6}  {:<5}{}", "rpm", "load N", "T C", "F_Y", "d", "F N", "", names8());
    for p in &ls.points {
        print_record_rows(p, true);
    }
    println!();
    println!(
        "(|id-mod| = mean |identified - model| over the points, rel. = the same relative to |model|: large where the model is near 0, as Kxy at high F_Y)"
    );
    println!(
        "quadratic fits KD(F_Y) = c0 + c1 F_Y + c2 F_Y^2 over F_Y {:.2}-{:.2}, and the film model over the same range:",
        ls.trends.first().map_or(f64::NAN, |t| t.fy_range[0]),
        ls.trends.first().map_or(f64::NAN, |t| t.fy_range[1])
    );
    println!(
        "{:<5} {:>9} {:>9} {:>9} {:>7} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8} {:>8}",
        "", "c0", "c1", "c2", "R^2", "fit(min)", "fit(max)", "model min", "model max", "|id-mod|", "rel.", "trend"
    );
    for t in &ls.trends {
        println!(
            "{:<5} {:>9.4} {:>9.4} {:>9.4} {:>7.4} {:>9.4} {:>9.4} {:>9.4} {:>9.4} {:>9.4} {:>7.1}% {:>8}",
            t.name,
            t.fit.c0,
            t.fit.c1,
            t.fit.c2,
            t.fit.r_squared,
            t.fit_at_min_fy,
            t.fit_at_max_fy,
            t.model_at_min_fy,
            t.model_at_max_fy,
            t.mean_abs_difference,
            100.0 * t.mean_abs_relative_difference,
            match (t.slope_sign, t.grows_in_magnitude) {
                (1, _) => "grows",
                (_, true) => "|grows|",
                _ => "falls",
            }
        );
    }

    for s in [&c.amplitude_study.low, &c.amplitude_study.high] {
        println!();
        println!(
            "== Amplitude study (Figs 7-10) at {}: {:.0} rpm, {:.0} N, {:.2} C (mu {:.4} Pa s, model F_Y {:.3}, eccentricity {:.3}) ==",
            s.label, s.speed_rpm, s.load_n, s.temperature_c, s.model.viscosity_pa_s, s.model.load_parameter, s.model.eccentricity
        );
        println!("largest force {:.0} N per exciter: limited by {}", s.max_force_n, s.max_force_limited_by);
        println!("{:>6} {:>7} {:>6} {:>6} {:>7} {:>6}  {:<5}{}", "rpm", "load N", "T C", "F_Y", "d", "F N", "", names8());
        for p in &s.steps {
            print_record_rows(p, false);
        }
        println!("{:>42}  {:<5}{}", "film model at small d", "model", row8(s.model.zhou.as_array()));
        println!("eq. 10 fits KD(d) = a d^3 + b d^2 + d0 and eq. 11 RV:");
        println!("{:<5} {:>9} {:>9} {:>9} {:>7} {:>16}", "", "d0", "b", "a", "R^2", format!("RV(d={:.3})", s.max_d));
        for f in &s.fits {
            println!("{:<5} {:>9.4} {:>9.3} {:>9.3} {:>7.4} {:>+15.2}%", f.name, f.fit.d0, f.fit.b, f.fit.a, f.fit.r_squared, 100.0 * f.rv_at_max_d);
        }
    }

    let f = &c.findings;
    println!();
    println!("== RV at a common d (largest reached at both F_Y) and at the paper's d = 0.05 ==");
    for at in [&f.rv_at_common_d, &f.rv_at_d_005] {
        println!(
            "d = {:.3}{}: {:<5} {:>20} {:>20}",
            at.d,
            if at.extrapolated_high_fy || at.extrapolated_low_fy { " (extrapolated)" } else { "" },
            "",
            c.amplitude_study.low.label,
            c.amplitude_study.high.label
        );
        let se = |v: Option<f64>| v.map_or(String::new(), |e| format!(" +-{:.2}", 100.0 * e));
        for r in &at.coefficients {
            println!(
                "    {:<5} {:>20} {:>20}",
                r.name,
                format!("{:+.2}{} %", 100.0 * r.rv_low_fy, se(r.rv_low_fy_se)),
                format!("{:+.2}{} %", 100.0 * r.rv_high_fy, se(r.rv_high_fy_se))
            );
        }
        println!(
            "    {:<5} {:>20} {:>20}   -> {:?}",
            "mean|RV|",
            format!("{:.2}{} %", 100.0 * at.mean_abs_rv_low_fy, se(at.mean_abs_rv_low_fy_se)),
            format!("{:.2}{} %", 100.0 * at.mean_abs_rv_high_fy, se(at.mean_abs_rv_high_fy_se)),
            at.verdict
        );
    }

    println!();
    println!("== Findings (the paper's claims checked on the simulation) ==");
    println!("direct coefficients (Kxx, Kyy, Dxx, Dyy) grow with F_Y: {}", f.direct_coefficients_grow_with_fy);
    println!(
        "magnitude grows with F_Y: {}; does not: {}",
        f.growing_in_magnitude.join(", "),
        if f.not_growing_in_magnitude.is_empty() { "none".into() } else { f.not_growing_in_magnitude.join(", ") }
    );
    println!("RV grows with d (mean |RV| monotone at both F_Y): {}", f.rv_grows_with_d);
    println!("RV larger at high F_Y at the common d = {:.3} (beyond two standard errors): {}", f.common_d, f.rv_faster_at_high_fy);
    println!("most sensitive coefficient at d = {:.3}: {} (RV {:+.1} % at {})", f.common_d, f.most_sensitive, 100.0 * f.most_sensitive_rv, f.most_sensitive_at);
    for n in &f.notes {
        println!("  - {n}");
    }
}

fn print_record_rows(p: &RecordResult, with_model: bool) {
    let lead = format!(
        "{:>6.0} {:>7.0} {:>6.2} {:>6.3} {:>7.4} {:>6.0}",
        p.spec.speed_rpm, p.spec.load_n, p.spec.temperature_c, p.load_parameter, p.amplitude_d, p.spec.amplitude_n
    );
    match p.identified {
        Some(i) => {
            println!("{lead}  {:<5}{}", "id", row8(i.as_array()));
            if with_model {
                println!("{:>42}  {:<5}{}", "", "model", row8(p.model.zhou.as_array()));
            }
        }
        None => println!("{lead}  refused: {}", p.refusal.as_deref().unwrap_or("no window")),
    }
}
