//! `oilfilm simulate` and `oilfilm identify`: records in the ASCII format, out of the simulated
//! rig and into the identification pipeline.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use oilfilm_identification::ascii::{self, Units};
use oilfilm_identification::estimator::{ModelOrder, Solver};
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::{self, Identification, PipelineConfig, SpeedSource};
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::effects::{
    ChannelDelay, FilmRelaxation, FluidInertia, HousingMassMismatch, ProbeSaturation, SupportFriction, SynchronousRunout, ThermalDrift,
};

use std::io::Write;

use oilfilm::bags::{merge_shortfalls, print_shortfalls, reader_threads_beside_analysis, reanalyse_bag_with};
pub use oilfilm::progress::Progress;
use oilfilm_bag::{ReadOptions, Shortfall};

use crate::{Outcome, RigSource};

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum Excitation {
    /// Different frequency per exciter (identifies all 8 coefficients in one record).
    TwoTone,
    /// Schroeder multisine over the band, odd lines on exciter 1, even on exciter 2.
    Multisine,
    /// The paper's method: one sine, both exciters at one frequency (refused by `identify`).
    Sine,
}

#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    #[command(flatten)]
    source: RigSource,
    /// Seconds of record (the paper: 10 s = 50 000 scans at 5 kHz).
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Excitation preset (ignored with --plan).
    #[arg(long, value_enum, default_value = "two-tone")]
    excitation: Excitation,
    /// Amplitude per exciter, N (rms for the multisine).
    #[arg(long, default_value_t = 100.0)]
    amplitude_n: f64,
    /// Frequencies, Hz: two-tone f1,f2 (default 23,37); sine f (default 37); multisine band lo,hi (default 5,80).
    #[arg(long, value_delimiter = ',')]
    frequencies_hz: Vec<f64>,
    /// An excitation plan (TOML, the `ExcitationPlan` format) instead of a preset.
    #[arg(long, value_name = "FILE")]
    plan: Option<PathBuf>,
    /// Inject an effect (repeatable): fluid_inertia=KG, thermal_drift=C_PER_S,
    /// synchronous_runout=M, channel_delay=CHANNEL:S, probe_saturation=CHANNEL:M,
    /// support_friction=N, housing_mass_mismatch=KG, and outside the diagnosis catalog
    /// film_relaxation=K_N_M:TAU_S.
    #[arg(long = "inject", value_name = "EFFECT=VALUE")]
    inject: Vec<String>,
    /// Seed of the sensor noise (default: the rig file's).
    #[arg(long)]
    seed: Option<u64>,
    /// Write volts as the card read them (default) or SI values.
    #[arg(long, value_enum, default_value = "volts")]
    units: UnitsArg,
    /// Output file (default: standard output).
    #[arg(long, short, value_name = "FILE")]
    output: Option<PathBuf>,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum UnitsArg {
    Volts,
    Si,
}

fn parse_injection(config: &mut RigConfig, spec: &str) -> Result<()> {
    let (name, value) = spec.split_once('=').with_context(|| format!("--inject `{spec}`: expected EFFECT=VALUE"))?;
    let number = |text: &str| -> Result<f64> { text.trim().parse::<f64>().with_context(|| format!("--inject `{spec}`: `{text}` is not a number")) };
    let channel_value = || -> Result<(String, f64)> {
        let (c, v) = value.split_once(':').with_context(|| format!("--inject `{spec}`: expected {name}=CHANNEL:VALUE"))?;
        Ok((c.trim().to_string(), number(v)?))
    };
    let e = &mut config.effects;
    match name.trim() {
        "fluid_inertia" => e.fluid_inertia = Some(FluidInertia { added_mass_kg: number(value)? }),
        "thermal_drift" => e.thermal_drift = Some(ThermalDrift { heating_rate_c_per_s: number(value)? }),
        "synchronous_runout" => e.synchronous_runout = Some(SynchronousRunout { amplitude_m: number(value)?, phase_deg: 0.0 }),
        "channel_delay" => {
            let (channel, delay_s) = channel_value()?;
            e.channel_delay = Some(ChannelDelay { channel, delay_s });
        }
        "probe_saturation" => {
            let (channel, limit_m) = channel_value()?;
            e.probe_saturation = Some(ProbeSaturation { channel, limit_m });
        }
        "support_friction" => e.support_friction = Some(SupportFriction { friction_force_n: number(value)? }),
        "housing_mass_mismatch" => e.housing_mass_mismatch = Some(HousingMassMismatch { mass_error_kg: number(value)? }),
        "film_relaxation" => {
            let (k, tau) = value.split_once(':').with_context(|| format!("--inject `{spec}`: expected film_relaxation=K_N_M:TAU_S"))?;
            e.film_relaxation = Some(FilmRelaxation { stiffness_n_m: number(k)?, time_constant_s: number(tau)? });
        }
        other => bail!("--inject: unknown effect `{other}` (fluid_inertia, thermal_drift, synchronous_runout, channel_delay, probe_saturation, support_friction, housing_mass_mismatch, film_relaxation)"),
    }
    Ok(())
}

fn plan_of(args: &SimulateArgs) -> Result<ExcitationPlan> {
    if let Some(path) = &args.plan {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read plan {}", path.display()))?;
        return toml::from_str(&text).with_context(|| format!("plan {}", path.display()));
    }
    let f = &args.frequencies_hz;
    let a = args.amplitude_n;
    Ok(match args.excitation {
        Excitation::TwoTone => {
            let (f1, f2) = if f.len() >= 2 { (f[0], f[1]) } else { (23.0, 37.0) };
            ExcitationPlan::two_tone(f1, f2, a)
        }
        Excitation::Sine => ExcitationPlan::paper_sine(f.first().copied().unwrap_or(37.0), a),
        Excitation::Multisine => {
            let band = if f.len() >= 2 { [f[0], f[1]] } else { [5.0, 80.0] };
            ExcitationPlan::multisine(band, 1.0, a)
        }
    })
}

pub fn run_simulate(args: &SimulateArgs) -> Result<()> {
    let mut config = args.source.load()?;
    for spec in &args.inject {
        parse_injection(&mut config, spec)?;
    }
    if let Some(seed) = args.seed {
        config.simulation.seed = seed;
    }
    config.validate()?;
    let plan = plan_of(args)?;
    let mut progress = Progress::new("simulating");
    let record = simulate::simulate(&config, &plan, args.seconds, SimulateOptions::default(), &mut |f| progress.update(f))?;
    progress.finish();
    let units = match args.units {
        UnitsArg::Volts => Units::Volts,
        UnitsArg::Si => Units::Si,
    };
    let text = ascii::write(&record.to_ascii(&config, units)?)?;
    match &args.output {
        Some(path) => std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))?,
        None => std::io::stdout().write_all(text.as_bytes())?,
    }
    let k = record.truth.coefficients.stiffness_n_m;
    let c = record.truth.coefficients.damping_n_s_m;
    eprintln!(
        "simulated {} scans of rig `{}` ({}); the film's own coefficients at this point: K = [{:.4e} {:.4e}; {:.4e} {:.4e}] N/m, C = [{:.4e} {:.4e}; {:.4e} {:.4e}] N s/m",
        record.scans.len(),
        config.name,
        if config.effects.is_none() { "no injected effect".to_string() } else { format!("effects: {}", args.inject.join(", ")) },
        k[(0, 0)], k[(0, 1)], k[(1, 0)], k[(1, 1)], c[(0, 0)], c[(0, 1)], c[(1, 0)], c[(1, 1)]
    );
    Ok(())
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum ModelArg {
    /// Stiffness and damping (8 coefficients).
    Kc,
    /// Stiffness, damping and added mass (12).
    Kcm,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum SolverArg {
    Qr,
    Svd,
    /// Zhou et al. eq. 6 (normal equations), for comparison only.
    Paper,
}

#[derive(Debug, clap::Args)]
pub struct IdentifyArgs {
    /// An ASCII record (format: docs/manual/ascii-format.md), or a rosbag2 bag directory (MCAP)
    /// recorded from the node graph: its DAQ frames, as one record, go through the same
    /// identification as an ASCII record (with `--replay`: through the very conditioner and
    /// estimator the nodes run, so the estimates equal the live ones, bit for bit); or, with
    /// `--map`, a TDMS, .mat or CSV record, read as a bag of it would be.
    pub(crate) file: PathBuf,
    /// Channel map (TOML) of a TDMS, .mat or CSV record (docs/manual/foreign-records.md): the
    /// record is read as the DAQ node's foreign source publishes it and identified as
    /// `oilfilm import` then `identify BAG` would (`--params` and `--replay` apply).
    #[arg(long, value_name = "MAP")]
    pub(crate) map: Option<PathBuf>,
    /// For a bag or a `--map` record: a ROS 2 params file for the conditioner and estimator
    /// (`/oilfilm/conditioner`, `/oilfilm/estimator` sections, e.g.
    /// launch_configs/params/sim_rig.yaml), whose chain and window settings are used (the
    /// low-pass as set, not adapted); default: the parameters the bag's conditioner and
    /// estimator ran with (recorded on /parameter_events), else the identification's
    /// defaults (with `--replay`: the nodes').
    #[arg(long, value_name = "FILE")]
    pub(crate) params: Option<PathBuf>,
    /// For a bag (or a `--map` record): re-run the node graph's conditioner and estimator on
    /// its frames instead of the batch identification, giving the estimates the graph
    /// published live.
    #[arg(long)]
    pub(crate) replay: bool,
    #[command(flatten)]
    pub(crate) source: RigSource,
    /// Shaft speed, rpm, if the record does not state it.
    #[arg(long)]
    pub(crate) speed_rpm: Option<f64>,
    /// Samples per window (default 50 000, the paper's; a shorter record is one window).
    #[arg(long)]
    pub(crate) window: Option<usize>,
    /// Samples between window starts (default: the window).
    #[arg(long)]
    pub(crate) hop: Option<usize>,
    /// Model order (default kc; for a bag: the params file's, else kc).
    #[arg(long, value_enum)]
    pub(crate) model: Option<ModelArg>,
    /// Solver (default qr; for a bag: the params file's, else qr).
    #[arg(long, value_enum)]
    pub(crate) solver: Option<SolverArg>,
    /// Skip the de-skew stage (only to see what the multiplex skew does).
    #[arg(long)]
    pub(crate) no_deskew: bool,
    /// Print JSON instead of tables.
    #[arg(long)]
    pub(crate) json: bool,
    /// Diagnose the record and report the coefficients a user can keep (corrected for a
    /// measurement effect, an added mass or friction separated, at the start for a drift)
    /// even when no window is refused (a refused window always does this).
    #[arg(long, conflicts_with = "no_correct")]
    pub(crate) correct: bool,
    /// Never diagnose: the windows as the estimator gives them.
    #[arg(long)]
    pub(crate) no_correct: bool,
    /// For a bag: go on past damaged chunks, files metadata.yaml does not list or lacks and
    /// counts that differ, analysing what is readable and saying what is missing (in the
    /// output and the JSON's `shortfalls`). Without it any of these is an error (exit 4).
    #[arg(long)]
    pub(crate) allow_partial: bool,
    /// Identify an ASCII record (or a `--map` record) window by window as it is read, through
    /// the node graph of launch_configs/replay.launch.yaml in this process (its DAQ,
    /// conditioner and estimator, its parameters; `--params`, `--window`, `--hop`, `--model`,
    /// `--solver`, `--speed-rpm`, `--no-deskew` set theirs): memory stays bounded whatever
    /// the record's length. Each window's estimate prints as it comes (`--json`: one JSON
    /// object a line, then a summary line). What needs the whole record (`--correct`, the
    /// drift re-identification) is not available. A record over 256 MB (gzip: 64 MB) is
    /// streamed without it being asked.
    #[arg(long, conflicts_with = "no_stream")]
    pub(crate) stream: bool,
    /// Identify the record whole even when it is large enough to be streamed (it takes about
    /// three times the record's size in memory).
    #[arg(long)]
    pub(crate) no_stream: bool,
    /// Tests only: the size, bytes, above which a plain ASCII record is streamed without
    /// `--stream` (a gzip one above a quarter of it), instead of
    /// `identify_stream::STREAM_ABOVE_BYTES`; lets a test exercise the switch on a small file.
    #[arg(long, hide = true, value_name = "BYTES")]
    pub(crate) stream_above_bytes: Option<u64>,
}

pub fn run_identify(args: &IdentifyArgs) -> Result<Outcome> {
    if args.stream {
        return crate::identify_stream::run(args, None);
    }
    if let Some(why) = crate::identify_stream::too_large_to_hold(args)? {
        return crate::identify_stream::run(args, Some(&why));
    }
    if let (Some(map), true) = (&args.map, args.replay) {
        return crate::foreign_input::identify(args, map);
    }
    if args.file.is_dir() && args.replay {
        return replay_bag(args);
    }
    anyhow::ensure!(!args.replay, "--replay applies to bags and --map records (the node graph re-run); {} is a file", args.file.display());
    let is_bag = args.file.is_dir();
    let max = oilfilm_identification::estimator::MAX_WINDOW_SAMPLES;
    for (flag, v) in [("--window", args.window), ("--hop", args.hop)] {
        if let Some(v) = v.filter(|v| !(1..=max).contains(v) || (flag == "--window" && *v < 2)) {
            bail!("{flag} {v}: must be {} to {max} samples", if flag == "--window" { 2 } else { 1 });
        }
    }
    anyhow::ensure!(is_bag || !args.allow_partial, "--allow-partial applies to bags; a record file is read whole or refused at its first bad line");
    let (mut shortfalls, mut bag_read) = (Vec::new(), None);
    let name = args.file.display().to_string();
    // The record, its schedule, the speed it states and its rig: from a bag's DAQ frames and
    // rig status (the rig file), or from an ASCII record (the rig its header names, else the
    // rig file).
    let (raw, offsets, stated_rpm, mut config, rig) = if let Some(map) = &args.map {
        anyhow::ensure!(!args.file.is_dir(), "{name} is a directory: --map is for a TDMS, .mat or CSV file");
        let rig = args.source.load()?;
        let l = crate::foreign_input::load_raw(&args.file, map, &rig)?;
        let config = match node_params(args)? {
            (c, e, ParamsFrom::File | ParamsFrom::Bag) => params_config(&c, &e, l.raw.sample_rate_hz)?,
            (_, _, ParamsFrom::Defaults) => PipelineConfig::default(),
        };
        (l.raw, l.offsets_s, l.speed_rpm, config, rig)
    } else if args.file.is_dir() {
        let rig = args.source.load()?;
        let b = oilfilm::bags::record_of_bag(&args.file, ReadOptions { allow_partial: args.allow_partial })?;
        shortfalls = b.shortfalls;
        bag_read = Some(b.read);
        if !b.ignored.is_empty() {
            eprintln!("{name}: channels not used by the conditioning left out: {}", b.ignored.join(", "));
        }
        let config = match node_params(args)? {
            (c, e, ParamsFrom::File | ParamsFrom::Bag) => params_config(&c, &e, b.raw.sample_rate_hz)?,
            (_, _, ParamsFrom::Defaults) => PipelineConfig::default(),
        };
        (b.raw, b.offsets_s, b.speed_rpm, config, rig)
    } else {
        anyhow::ensure!(args.params.is_none(), "--params applies to bags (the node parameters); an ASCII record takes --window, --hop, --model, --solver");
        let input = crate::ascii_input::load(&args.file, args.source.path())?;
        let (record, rig) = (input.record, input.rig);
        let raw = simulate::raw_from_ascii(&record)?;
        let offsets: Vec<f64> = (0..record.header.channels.len())
            .map(|p| record.header.channel_offset_s(p).with_context(|| format!("{name}: no offset for channel {p}")))
            .collect::<Result<_>>()?;
        (raw, offsets, record.header.speed_rpm, PipelineConfig::default(), rig)
    };
    let calibration = pipeline::calibration_for(&rig, &raw, &offsets).with_context(|| format!("{name}: the rig's calibration on the record's schedule"))?;
    let (speed_rpm, source) = match (args.speed_rpm, stated_rpm) {
        (Some(v), _) => (v, SpeedSource::User),
        (None, Some(v)) => (v, SpeedSource::Record),
        (None, None) => (rig.operating.speed_rpm, SpeedSource::RigFile),
    };
    config.estimator.sample_rate_hz = raw.sample_rate_hz;
    if let Some(w) = args.window {
        config.estimator.window = w;
        config.estimator.hop = args.hop.unwrap_or(w);
    } else if let Some(h) = args.hop {
        config.estimator.hop = h;
    }
    if let Some(m) = args.model {
        config.estimator.model = match m {
            ModelArg::Kc => ModelOrder::Kc,
            ModelArg::Kcm => ModelOrder::Kcm,
        };
    }
    if let Some(s) = args.solver {
        config.estimator.solver = match s {
            SolverArg::Qr => Solver::Qr,
            SolverArg::Svd => Solver::Svd,
            SolverArg::Paper => Solver::NormalEquations,
        };
    }
    config.conditioning.deskew &= !args.no_deskew;
    let id = pipeline::identify(&raw, &calibration, &rig, speed_rpm, source, &config).with_context(|| format!("identifying {name}"))?;
    let correction = if args.no_correct {
        None
    } else {
        crate::identify_corrected::correct(&raw, &calibration, &rig, speed_rpm, source, &config, &id, args.correct)
            .with_context(|| format!("correcting {name}"))?
    };
    if args.json {
        let mut value = serde_json::to_value(&id)?;
        if let Some(map) = value.as_object_mut() {
            if let Some(c) = &correction {
                map.insert("correction".into(), serde_json::to_value(c)?);
            }
            if is_bag {
                map.insert("bag_read".into(), serde_json::to_value(bag_read)?);
                map.insert("complete".into(), serde_json::Value::Bool(shortfalls.is_empty()));
                map.insert("shortfalls".into(), serde_json::to_value(&shortfalls)?);
            }
        }
        println!("{}", serde_json::to_string_pretty(&value)?);
    } else {
        print_shortfalls(&name, &shortfalls);
        let drift = correction.as_ref().and_then(|c| c.relative_drift_per_s).map(|r| {
            let names = ["kxx", "kxy", "cxx", "cxy", "kyx", "kyy", "cyx", "cyy"];
            let direct: Vec<String> = [0usize, 5, 2, 7].iter().map(|&k| format!("{} {:+.2} %/s", names[k], 100.0 * r[k])).collect();
            format!("the coefficients drift during the record ({}), not the excitation", direct.join(", "))
        });
        print_identification(&name, &id, drift.as_deref());
        if let Some(c) = &correction {
            crate::identify_corrected::print(c);
        }
    }
    // Done when a window was solved or the correction gave coefficients to keep.
    let kept = correction.as_ref().is_some_and(|c| c.stiffness_n_m.iter().chain(c.damping_n_s_m.iter()).all(|v| v.is_finite()));
    Ok(match &id.refusal {
        _ if id.accepted().count() > 0 || kept => Outcome::Done,
        Some(r) => Outcome::Refused(format!("{name}: refused: {r}")),
        None => Outcome::Refused(format!("{name}: every one of {} window(s) refused", id.windows.len())),
    })
}

/// The pipeline settings node parameters give (a params file's or those a bag recorded): the
/// conditioner's chain settings (its low-pass as set, not adapted to the excitation) and the
/// estimator's window settings.
fn params_config(
    conditioner: &oilfilm_graph::conditioner::ConditionerParams,
    estimator: &oilfilm_graph::estimator::EstimatorParams,
    sample_rate_hz: f64,
) -> Result<PipelineConfig> {
    Ok(PipelineConfig { conditioning: conditioner.conditioning()?, estimator: estimator.config(sample_rate_hz)?, adaptive_lowpass: false })
}

/// Where the conditioner's and estimator's parameters came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ParamsFrom {
    /// `--params FILE`.
    File,
    /// The bag's `/parameter_events`: what its nodes ran with (ADR 0026).
    Bag,
    /// Neither: the nodes' defaults.
    Defaults,
}

/// The conditioner's and estimator's parameters: from `--params`; without it, for a bag that
/// recorded them, the ones its nodes ran with (said on stderr, with a warning when they
/// changed during the recording); else the nodes' defaults.
pub(crate) fn node_params(
    args: &IdentifyArgs,
) -> Result<(oilfilm_graph::conditioner::ConditionerParams, oilfilm_graph::estimator::EstimatorParams, ParamsFrom)> {
    use oilfilm_graph::conditioner::ConditionerParams;
    use oilfilm_graph::estimator::EstimatorParams;
    use oilfilm_graph::params::{self, NodeArgs};
    let node_args = |node: &str| NodeArgs {
        name: node.into(),
        namespace: oilfilm_graph::topics::NAMESPACE.into(),
        params_files: args.params.iter().cloned().collect(),
        ..Default::default()
    };
    let (mut conditioner, _) = params::load::<ConditionerParams>(&node_args("conditioner"))?;
    let (mut estimator, _) = params::load::<EstimatorParams>(&node_args("estimator"))?;
    if args.params.is_some() {
        return Ok((conditioner, estimator, ParamsFrom::File));
    }
    if !args.file.is_dir() {
        return Ok((conditioner, estimator, ParamsFrom::Defaults));
    }
    let name = args.file.display();
    let recorded =
        oilfilm_graph::runner::bag::recorded_parameters_with(&oilfilm_bag::Bag::open(&args.file)?, ReadOptions { allow_partial: args.allow_partial })?;
    let c = recorded.of::<ConditionerParams>("conditioner")?;
    let e = recorded.of::<EstimatorParams>("estimator")?;
    for (node, what) in [c.as_ref().map(|c| &c.0), e.as_ref().map(|e| &e.0)].into_iter().zip(["conditioner", "estimator"]) {
        if let Some(node) = node {
            eprintln!("{name}: the {what}'s parameters are the ones {node} ran with (the bag's /parameter_events)");
        }
    }
    if !recorded.changed_later.is_empty() {
        eprintln!(
            "warning: {name}: parameters changed during the recording ({}): re-analysing with those in force at the first DAQ frame, so later windows may differ from the recorded estimates",
            recorded.changed_later.join(", ")
        );
    }
    let from = if c.is_some() && e.is_some() { ParamsFrom::Bag } else { ParamsFrom::Defaults };
    if let Some((_, c)) = c {
        conditioner = c;
    }
    if let Some((_, e)) = e {
        estimator = e;
    }
    Ok((conditioner, estimator, from))
}

fn print_identification(name: &str, id: &Identification, drift: Option<&str>) {
    println!("record: {name} ({} scans, {} usable after filter edges), rig `{}`", id.samples, id.valid[1] - id.valid[0], id.rig);
    println!("frame: {}", id.frame);
    println!("conditioning low-pass: {:.1} Hz (adapted to the excitation lines)", id.lowpass_cutoff_hz);
    if id.speed_source == SpeedSource::RigFile {
        println!("speed: not stated by the record; the rig file's operating speed was assumed");
    }
    if let Some(r) = &id.refusal {
        println!("REFUSED: {r}");
        return;
    }
    for (i, w) in id.windows.iter().enumerate() {
        let o = &w.operating;
        println!();
        println!(
            "window {i}: {:.3}-{:.3} s | {:.0} rpm, {:.2} C, mu {:.5} Pa s, load {:.0} N, S {:.4}, F_Y {:.4}, d {:.4}",
            w.t_start_s, w.t_end_s, o.speed_rpm, o.temperature_c, o.viscosity_pa_s, o.load_n, o.sommerfeld, o.load_parameter, o.amplitude_d
        );
        let e = &w.estimate;
        println!(
            "  condition {:.2}, rank {}, residual rms [{:.3}, {:.3}] N, lines {:?} Hz",
            e.condition_number,
            e.rank,
            e.residual_rms_n[0],
            e.residual_rms_n[1],
            e.frequencies_hz.iter().map(|f| (f * 100.0).round() / 100.0).collect::<Vec<_>>()
        );
        match &e.result {
            Err(r) => match drift {
                Some(d) => println!("  REFUSED: {d} (the estimator: {r})"),
                None => println!("  REFUSED: {r}"),
            },
            Ok(c) => {
                let names = ["xx", "xy", "yx", "yy"];
                println!("  {:<6} {:>14} {:>12} {:>9} | {:>14} {:>12} {:>9}", "", "K (N/m)", "SE", "Zhou K", "C (N s/m)", "SE", "Zhou D");
                for (k, (i, j)) in [(0, 0), (0, 1), (1, 0), (1, 1)].into_iter().enumerate() {
                    let zk = w.zhou.as_ref().map_or(f64::NAN, |z| z.stiffness[(i, j)]);
                    let zd = w.zhou.as_ref().map_or(f64::NAN, |z| z.damping[(i, j)]);
                    println!(
                        "  {:<6} {:>14.5e} {:>12.3e} {:>9.4} | {:>14.5e} {:>12.3e} {:>9.4}",
                        names[k],
                        c.stiffness_n_m[(i, j)],
                        c.stiffness_se[(i, j)],
                        zk,
                        c.damping_n_s_m[(i, j)],
                        c.damping_se[(i, j)],
                        zd
                    );
                }
                if let (Some(m), Some(s)) = (&c.added_mass_kg, &c.added_mass_se) {
                    println!(
                        "  added mass M [{:.2} {:.2}; {:.2} {:.2}] kg (SE [{:.2} {:.2}; {:.2} {:.2}])",
                        m[(0, 0)],
                        m[(0, 1)],
                        m[(1, 0)],
                        m[(1, 1)],
                        s[(0, 0)],
                        s[(0, 1)],
                        s[(1, 0)],
                        s[(1, 1)]
                    );
                }
            }
        }
        for f in &e.flags {
            println!("  note: {f}");
        }
    }
    if let Some(f) = &id.frequency_domain {
        if let Ok(c) = &f.result {
            let (k, d) = (c.stiffness_n_m, c.damping_n_s_m);
            println!();
            println!(
                "frequency-domain cross-check at {} lines: K [{:.4e} {:.4e}; {:.4e} {:.4e}], C [{:.4e} {:.4e}; {:.4e} {:.4e}]",
                f.lines.len(),
                k[(0, 0)],
                k[(0, 1)],
                k[(1, 0)],
                k[(1, 1)],
                d[(0, 0)],
                d[(0, 1)],
                d[(1, 0)],
                d[(1, 1)]
            );
        } else if let Err(r) = &f.result {
            println!("frequency-domain cross-check refused: {r}");
        }
    }
    if let Some(n) = &id.frequency_domain_note {
        println!("{n}");
    }
}

/// The conditioning chain of a bag's first recorded conditioned frame (`causal` if it
/// carries the flag `chain=causal`, else `zero_phase`), or `None` if the bag holds none.
fn recorded_chain(dir: &std::path::Path, options: ReadOptions) -> Result<(Option<&'static str>, Vec<Shortfall>)> {
    use oilfilm_msgs::RosMessage;
    let bag = oilfilm_bag::Bag::open(dir)?;
    let is_conditioned = |_: &str, type_name: &str| type_name == oilfilm_msgs::ConditionedFrame::TYPE_NAME;
    let (first, shortfalls) = bag.read_topics_with(options, &is_conditioned, &|m| m.decode::<oilfilm_msgs::ConditionedFrame>(), 1, |frames| frames.next())?;
    Ok((first.map(|f| if f.flags.iter().any(|x| x == "chain=causal") { "causal" } else { "zero_phase" }), shortfalls))
}

/// `oilfilm identify BAG --replay`: the bag's DAQ frames and rig status through a fresh
/// conditioner and estimator (the nodes, `oilfilm_graph::runner::bag::reanalyse`): the
/// estimates the graph published live, bit for bit.
fn replay_bag(args: &IdentifyArgs) -> Result<Outcome> {
    let rig = args.source.load()?;
    let name = args.file.display().to_string();
    let (mut conditioner, mut estimator, from) = node_params(args)?;
    // The chain the graph conditioned with, from its recorded conditioned frames (flag
    // `chain=causal`, ADR 0014): without a params file or recorded parameters it is the one
    // to re-run; parameters that name another get estimates that cannot equal the recorded
    // ones, so say so.
    let options = ReadOptions { allow_partial: args.allow_partial };
    let (recorded, shortfalls) = recorded_chain(&args.file, options)?;
    if let Some(recorded) = recorded {
        if from == ParamsFrom::Defaults {
            if conditioner.chain != recorded {
                eprintln!("{name}: the recorded conditioned frames were made by the `{recorded}` chain: re-analysing with it");
            }
            conditioner.chain = recorded.into();
        } else if conditioner.chain != recorded {
            eprintln!(
                "warning: {name}: the recorded conditioned frames were made by the `{recorded}` chain, the parameters give `{}`: these estimates will not equal the recorded ones (set `chain: {recorded}` for the conditioner)",
                conditioner.chain
            );
        }
    }
    apply_estimator_options(args, &mut estimator)?;
    replay_and_print(args, &rig, &conditioner, &estimator, shortfalls, options)
}

/// `--window`, `--hop`, `--model`, `--solver`, `--speed-rpm` over the estimator's parameters;
/// `--no-deskew` is refused (the conditioner's `deskew` parameter says it).
pub(crate) fn apply_estimator_options(args: &IdentifyArgs, estimator: &mut oilfilm_graph::estimator::EstimatorParams) -> Result<()> {
    set_estimator_options(args, estimator);
    if args.no_deskew {
        let name = args.file.display();
        bail!("{name}: --no-deskew is for ASCII records; for a bag or a --map record set `deskew: false` in the conditioner's params");
    }
    Ok(())
}

/// `--window`, `--hop`, `--model`, `--solver`, `--speed-rpm` over the estimator's parameters.
pub(crate) fn set_estimator_options(args: &IdentifyArgs, estimator: &mut oilfilm_graph::estimator::EstimatorParams) {
    if let Some(w) = args.window {
        estimator.window = w as i64;
        estimator.hop = args.hop.unwrap_or(w) as i64;
    } else if let Some(h) = args.hop {
        estimator.hop = h as i64;
    }
    if let Some(m) = args.model {
        estimator.model = match m {
            ModelArg::Kc => "kc",
            ModelArg::Kcm => "kcm",
        }
        .into();
    }
    if let Some(s) = args.solver {
        estimator.solver = match s {
            SolverArg::Qr => "qr",
            SolverArg::Svd => "svd",
            SolverArg::Paper => "normal_equations",
        }
        .into();
    }
    if let Some(rpm) = args.speed_rpm {
        estimator.speed_rpm = rpm;
    }
}

/// The bag's frames through the node conditioner and estimator, printed; `shortfalls`: what
/// reading the bag so far found missing.
fn replay_and_print(
    args: &IdentifyArgs,
    rig: &RigConfig,
    conditioner: &oilfilm_graph::conditioner::ConditionerParams,
    estimator: &oilfilm_graph::estimator::EstimatorParams,
    mut shortfalls: Vec<Shortfall>,
    options: ReadOptions,
) -> Result<Outcome> {
    let name = args.file.display().to_string();
    let r = reanalyse_bag_with(&args.file, rig, conditioner, estimator, reader_threads_beside_analysis(), options)?;
    merge_shortfalls(&mut shortfalls, r.shortfalls);
    let (out, frames, status) = (r.recording, r.frames, r.status);
    let solved = out.estimates.iter().filter(|e| e.solved).count();
    if args.json {
        let doc = serde_json::json!({
            "bag": name,
            "frame": pipeline::FRAME,
            "frames": frames,
            "conditioner": conditioner,
            "estimator": estimator,
            "estimates": out.estimates,
            "complete": shortfalls.is_empty(),
            "shortfalls": shortfalls,
        });
        println!("{}", serde_json::to_string_pretty(&doc)?);
    } else {
        print_shortfalls(&name, &shortfalls);
        println!("{name}: {frames} DAQ frames, {status} rig status messages through the node conditioner and estimator");
        println!("frame: {}", pipeline::FRAME);
        for e in &out.estimates {
            crate::launch::print_estimate(e);
        }
        println!("{} estimate(s), {solved} solved", out.estimates.len());
    }
    Ok(if solved == 0 { Outcome::Refused(format!("{name}: {} estimate(s), none solved", out.estimates.len())) } else { Outcome::Done })
}
