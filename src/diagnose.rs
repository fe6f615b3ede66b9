//! `oilfilm diagnose INPUT --rig RIG`: what the simulation gets wrong about a record (issue 6).
//! Reads an ASCII record or a bag directory's DAQ frames, runs the diagnosis library (the
//! catalog judged on held-out blocks) and the show (model against measurement), prints the
//! verdict or the JSON contract, and writes the figures and `report.md`.

use std::path::PathBuf;

use anyhow::{Context, Result};
use oilfilm_diagnosis::{diagnose, diagnose_prepared, evidence, show, Diagnosis, DiagnosisOptions, ShowConfig};
use oilfilm_identification::pipeline::{self, SpeedSource};
use oilfilm_identification::record::RawRecord;
use oilfilm_identification::simulate;
use oilfilm_physics::config::RigConfig;

use crate::RigSource;

#[derive(Debug, clap::Args)]
pub struct DiagnoseArgs {
    /// An ASCII record (format: docs/manual/ascii-format.md), a rosbag2 bag directory holding
    /// DAQ frames, or with --map a TDMS, .mat or CSV record.
    input: PathBuf,
    /// Channel map (TOML) of a TDMS, .mat or CSV record (docs/manual/foreign-records.md).
    #[arg(long, value_name = "MAP")]
    map: Option<PathBuf>,
    #[command(flatten)]
    source: RigSource,
    /// Shaft speed, rpm, if the record does not state it.
    #[arg(long)]
    speed_rpm: Option<f64>,
    /// Directory for report.md and the SVG figures (created if missing).
    #[arg(long, value_name = "DIR", default_value = "out/diagnose")]
    out: PathBuf,
    /// Print the diagnosis as one JSON object (the contract in docs/manual/diagnosis.md) instead of text.
    #[arg(long)]
    json: bool,
    /// Skip the show (simulation against measurement) and the report: verdict only.
    #[arg(long)]
    no_report: bool,
    /// For a bag: go on past damaged chunks, unlisted or missing files and counts that
    /// differ, saying what is missing (as `oilfilm identify BAG --allow-partial`).
    #[arg(long)]
    allow_partial: bool,
}

/// A record ready for the libraries: raw columns, the rig's calibration on its schedule,
/// its speed and where that came from.
struct Loaded {
    raw: RawRecord,
    calibration: oilfilm_physics::daq::Calibration,
    speed_rpm: f64,
    speed_source: SpeedSource,
    /// What a partial read of a bag could not deliver.
    shortfalls: Vec<oilfilm_bag::Shortfall>,
    /// For a bag: how much of it was read.
    bag_read: Option<oilfilm::bags::BagRead>,
}

fn load_ascii(args: &DiagnoseArgs) -> Result<(Loaded, RigConfig, String)> {
    let name = args.input.display().to_string();
    let input = crate::ascii_input::load(&args.input, args.source.path())?;
    let record = &input.record;
    let rig = nominal(input.rig);
    let raw = simulate::raw_from_ascii(record)?;
    let offsets: Vec<f64> = (0..record.header.channels.len())
        .map(|p| record.header.channel_offset_s(p).with_context(|| format!("{name}: no offset for channel {p}")))
        .collect::<Result<_>>()?;
    let calibration = pipeline::calibration_for(&rig, &raw, &offsets).with_context(|| format!("{name}: the rig's calibration on the record's schedule"))?;
    let (speed_rpm, speed_source) = match (args.speed_rpm, record.header.speed_rpm) {
        (Some(v), _) => (v, SpeedSource::User),
        (None, Some(v)) => (v, SpeedSource::Record),
        (None, None) => (rig.operating.speed_rpm, SpeedSource::RigFile),
    };
    Ok((Loaded { raw, calibration, speed_rpm, speed_source, shortfalls: Vec::new(), bag_read: None }, rig, input.rig_source))
}

/// The rig as the diagnosis reads it: its nominal description, injected effects cleared.
fn nominal(mut rig: RigConfig) -> RigConfig {
    if !rig.effects.is_none() {
        eprintln!("note: the rig file injects effects; they belong to simulations, the diagnosis reads only the rig's nominal description");
    }
    rig.effects = Default::default();
    rig
}

/// The bag's DAQ frames, in order, as one raw record: [`oilfilm::bags::record_of_bag`], what
/// `oilfilm identify BAG` analyses (the same reader, checks and frames, so the same messages).
fn load_bag(args: &DiagnoseArgs, rig: &RigConfig) -> Result<Loaded> {
    let name = args.input.display().to_string();
    let b = oilfilm::bags::record_of_bag(&args.input, oilfilm_bag::ReadOptions { allow_partial: args.allow_partial })?;
    if !b.ignored.is_empty() {
        eprintln!("{name}: channels not used by the diagnosis left out: {}", b.ignored.join(", "));
    }
    let calibration = pipeline::calibration_for(rig, &b.raw, &b.offsets_s).with_context(|| format!("{name}: the rig's calibration on the frames' schedule"))?;
    let (speed_rpm, speed_source) = match (args.speed_rpm, b.speed_rpm) {
        (Some(v), _) => (v, SpeedSource::User),
        (None, Some(v)) => (v, SpeedSource::Record),
        (None, None) => (rig.operating.speed_rpm, SpeedSource::RigFile),
    };
    Ok(Loaded { raw: b.raw, calibration, speed_rpm, speed_source, shortfalls: b.shortfalls, bag_read: Some(b.read) })
}

pub fn run(args: &DiagnoseArgs) -> Result<crate::Outcome> {
    let name = args.input.display().to_string();
    let (loaded, rig, rig_source) = if let Some(map) = &args.map {
        let rig = nominal(args.source.load()?);
        let source = args.source.path().map_or("built-in zhou2004".to_string(), |p| format!("{} (--rig)", p.display()));
        let f = crate::foreign_input::load_raw(&args.input, map, &rig)?;
        let (speed_rpm, speed_source) = crate::foreign_input::speed_source(args.speed_rpm, f.speed_rpm, &rig);
        (Loaded { raw: f.raw, calibration: f.calibration, speed_rpm, speed_source, shortfalls: Vec::new(), bag_read: None }, rig, source)
    } else if args.input.is_dir() {
        let rig = nominal(args.source.load()?);
        let source = args.source.path().map_or("built-in zhou2004".to_string(), |p| format!("{} (--rig)", p.display()));
        (load_bag(args, &rig)?, rig, source)
    } else {
        load_ascii(args)?
    };
    let options = DiagnosisOptions::default();
    // Conditioned once: the diagnosis and the report share the prepared record.
    let (d, prepared) = match evidence::prepare(&loaded.raw, &loaded.calibration, &rig, loaded.speed_rpm, loaded.speed_source, &options.prepare)
        .with_context(|| format!("diagnosing {name}"))?
    {
        Ok(p) => {
            let mut d = diagnose_prepared(&p, &rig, &options).with_context(|| format!("diagnosing {name}"))?;
            if loaded.speed_source == SpeedSource::RigFile {
                d.notes.push("the record states no speed: the rig file's was assumed (1X runout is looked for at that speed)".into());
            }
            (d, Some(p))
        }
        // Too short or too poorly excited: the library's verdict says why.
        Err(_) => (
            diagnose(&loaded.raw, &loaded.calibration, &rig, loaded.speed_rpm, loaded.speed_source, &options).with_context(|| format!("diagnosing {name}"))?,
            None,
        ),
    };
    let mut value = serde_json::to_value(&d)?;
    if args.input.is_dir() {
        if let Some(map) = value.as_object_mut() {
            map.insert("bag_read".into(), serde_json::to_value(loaded.bag_read)?);
            map.insert("complete".into(), serde_json::Value::Bool(loaded.shortfalls.is_empty()));
            map.insert("shortfalls".into(), serde_json::to_value(&loaded.shortfalls)?);
        }
    }
    let mut written = Vec::new();
    if !args.no_report {
        match prepared.as_ref().map(|p| show(p, &rig, d.model_update.as_ref(), &ShowConfig::default())) {
            Some(Ok(s)) => written = crate::diagnose_report::write_report(&args.out, &name, &s, Some(&d))?,
            Some(Err(e)) => eprintln!("note: no report: the model against the measurement failed: {e}"),
            None => eprintln!("note: no report: {}", d.reason),
        }
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&value)?);
    } else {
        oilfilm::bags::print_shortfalls(&name, &loaded.shortfalls);
        print_diagnosis(&name, &rig_source, &d);
        if let Some(report) = written.iter().find(|p| p.extension().is_some_and(|e| e == "md")) {
            println!("report: {} ({} files in {})", report.display(), written.len(), args.out.display());
        }
    }
    Ok(if d.cause == oilfilm_diagnosis::catalog::Cause::InsufficientData {
        crate::Outcome::Refused(format!("{name}: the record cannot be judged: {}", d.reason))
    } else {
        crate::Outcome::Done
    })
}

fn matrix(m: &nalgebra::Matrix2<f64>) -> String {
    format!("[[{:.4e}, {:.4e}], [{:.4e}, {:.4e}]]", m[(0, 0)], m[(0, 1)], m[(1, 0)], m[(1, 1)])
}

fn print_diagnosis(name: &str, rig_source: &str, d: &Diagnosis) {
    println!("record: {name}");
    println!("rig: {rig_source}");
    println!("frame: {}", d.frame);
    let also = if d.also.is_empty() { String::new() } else { format!(" (also: {})", d.also.iter().map(|c| c.name()).collect::<Vec<_>>().join(", ")) };
    println!("cause: {}{also}", d.cause);
    println!("why: {}", d.reason);
    if let (Some(b), Some(e), Some(g)) = (d.baseline_heldout_nrmse, d.extended_heldout_nrmse, d.gain) {
        println!("held-out NRMSE: linear K-C {b:.4}, chosen model {e:.4} (gain {:.1} %)", 100.0 * g);
    }
    for (k, v) in &d.parameters {
        let se = d.standard_errors.get(k).map_or(String::new(), |s| format!(" (SE {s:.3e})"));
        println!("  {k} = {v}{se}");
    }
    if !d.steps.is_empty() {
        println!("forward selection (each candidate judged on held-out blocks against the model of its step):");
        for (i, st) in d.steps.iter().enumerate() {
            let tried: Vec<String> =
                st.tried.iter().map(|c| format!("{} {:+.2}%{}", c.name, 100.0 * c.score.unwrap_or(f64::NAN), if c.earns { "*" } else { "" })).collect();
            println!(
                "  step {}: {} (NRMSE {:.4}) -> {}; tried {}",
                i + 1,
                st.model,
                st.heldout_nrmse,
                st.chosen.map_or("nothing earns".to_string(), |c| format!("adds {c}")),
                tried.join(", ")
            );
        }
    }
    if let Some(a) = &d.amplitude {
        println!(
            "amplitude: d = {:.3}; coefficients vary by {:.1} +- {:.1} % (largest direct term; named above {:.0} % beyond two SE){}",
            a.d,
            100.0 * a.largest_direct,
            100.0 * a.largest_direct_se,
            100.0 * a.threshold,
            a.film_model_largest_direct.map_or(String::new(), |m| format!("; the film model predicts {:.1} %", 100.0 * m))
        );
    }
    for st in &d.structure {
        println!(
            "structure {}: {:+.2} % on held-out blocks{}",
            st.name.name(),
            100.0 * st.score.unwrap_or(f64::NAN),
            if st.remains { " -- REMAINS" } else { "" }
        );
        if st.remains {
            println!("  {}", st.description);
        }
    }
    if let Some(c) = &d.coefficients {
        println!("coefficients of the chosen model (small amplitude, corrected data; dF = -(K r + C r')):");
        println!("  K = {} N/m (SE {})", matrix(&c.stiffness_n_m), matrix(&c.stiffness_se));
        println!("  C = {} N s/m (SE {})", matrix(&c.damping_n_s_m), matrix(&c.damping_se));
        if let (Some(k), Some(cc)) = (&c.stiffness_at_start_n_m, &c.damping_at_start_n_s_m) {
            println!("  at the record's start (drift trend): K = {}, C = {}", matrix(k), matrix(cc));
        }
        println!("  linear K-C fit as measured: K = {}, C = {}", matrix(&c.linear_stiffness_n_m), matrix(&c.linear_damping_n_s_m));
    }
    if let Some(u) = &d.model_update {
        println!(
            "model update: {} with clearance {:.2} um (SE {:.2}; nominal {:.2}) and viscosity {:.5} Pa s (SE {:.5}; nominal {:.5}{}); motion predicted on held-out blocks: NRMSE {:.3} nominal, {:.3} updated ({:.1}x better)",
            u.theory,
            u.clearance_m * 1e6,
            u.clearance_se_m * 1e6,
            u.nominal_clearance_m * 1e6,
            u.viscosity_pa_s,
            u.viscosity_se_pa_s,
            u.nominal_viscosity_pa_s,
            u.temperature_offset_c.map_or(String::new(), |t| format!(", as if the film ran {t:+.1} C from the thermocouple")),
            u.nominal_heldout_nrmse,
            u.updated_heldout_nrmse,
            u.improvement_factor
        );
    }
    for a in &d.aliases {
        println!("alias {} / {}: {} -- {}", a.pair[0], a.pair[1], if a.separable { "separated" } else { "NOT separable here" }, a.evidence);
    }
    for n in &d.notes {
        println!("note: {n}");
    }
}
