//! `oilfilm`: the command-line shell over the physics and identification cores.
//!
//! Thin by design: it parses arguments, reads files, calls the core and prints. All physics
//! lives in `oilfilm-physics`.

mod ascii_input;
mod campaign;
mod diagnose;
mod diagnose_report;
mod figures;
mod foreign_input;
mod identify_corrected;
mod identify_stream;
mod import;
mod launch;
mod record;
mod records;
mod report;

use std::path::PathBuf;

use anyhow::Result;
use clap::{Parser, Subcommand};
use oilfilm_physics::config::RigConfig;

/// Journal-bearing oil-film coefficients on a (simulated or real) test rig.
///
/// Frame everywhere: x horizontal, y vertical up, journal turning from +x to +y; coefficients
/// in Lund's convention dF_on_journal = -(K dr + C dr'), SI units unless a column says otherwise.
#[derive(Debug, Parser)]
#[command(name = "oilfilm", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum BagCommand {
    /// Make a bag whose recorder was killed (no footer, no metadata.yaml) valid again, keeping
    /// every message of every complete chunk; damaged originals are kept as *.mcap.damaged.
    Recover {
        /// The bag directory.
        dir: std::path::PathBuf,
    },
}

fn bag_recover(dir: &std::path::Path) -> Result<()> {
    let r = oilfilm_bag::recover(dir)?;
    for f in &r.files {
        let what = match (&f.original, f.dropped) {
            (_, true) => "dropped (no MCAP header and no readable chunk)".to_string(),
            (Some(orig), false) => format!("rewritten from {} intact chunk(s); original kept as {}", f.chunks, orig.display()),
            (None, false) => "sound, kept as it was".to_string(),
        };
        println!("{}: {} message(s): {what}", f.path.display(), f.messages);
        for d in &f.damage {
            let times = d.log_times.map(|(a, b)| format!(" (log times {a}..={b} ns)")).unwrap_or_default();
            let after = match (d.crc_only, d.resumed_at) {
                (true, _) => "no message lost to it".to_string(),
                (false, Some(r)) => format!("skipped, read on from byte {r}"),
                (false, None) => "nothing after it could be read".to_string(),
            };
            println!("    damage at byte {}{times}: {}; {after}", d.offset, d.what);
        }
        if let Some(stop) = f.stop.as_ref().filter(|s| s.truncated) {
            println!("    the original ended early at byte {}: {}", stop.offset, stop.what);
        }
    }
    println!("{}: {} message(s) in {} file(s); metadata.yaml written", dir.display(), r.messages(), r.files.len());
    Ok(())
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the rig: operating point, film coefficients, and a simulated two-tone record
    /// through the multiplexed DAQ chain.
    Rig(RigArgs),
    /// Start a launch file's nodes (ROS 2 launch YAML), supervise them, print the estimates
    /// as they arrive, and stop them all after --seconds or on Ctrl-C.
    Launch(launch::LaunchArgs),
    /// Record our topics from DDS to a rosbag2 MCAP bag until Ctrl-C (the recorder node's code).
    Record(record::RecordArgs),
    /// Publish a bag's topics on DDS at real time, a rate or as fast as possible, with /clock.
    Play(record::PlayArgs),
    /// rosbag2 bag tools.
    #[command(subcommand)]
    Bag(BagCommand),
    /// The film's static equilibrium and linear coefficients at an operating point.
    Coefficients(CoefficientArgs),
    /// Simulate a record of the rig (any excitation, any injected effect) in the ASCII format.
    Simulate(records::SimulateArgs),
    /// Identify the coefficients of an ASCII record, window by window (or of a bag, or of a
    /// TDMS, .mat or CSV record with --map).
    Identify(records::IdentifyArgs),
    /// Write a record (TDMS, .mat or CSV through --map, or our ASCII format) as a rosbag2
    /// bag of DAQ frames and rig status, as the DAQ node would publish and the recorder record it.
    Import(import::ImportArgs),
    /// What the simulation gets wrong about a record (ASCII or bag): the cause named from a
    /// catalog and judged on held-out data, the extended model's parameters and its gain,
    /// with a report (figures + report.md). `--json` prints the stable contract.
    Diagnose(diagnose::DiagnoseArgs),
    /// Zhou et al. (2004)'s two studies on the simulated rig: coefficients against the load
    /// parameter (Figs 5-6) and against the excitation amplitude (Figs 7-10), with fits,
    /// the film model's coefficients, JSON of every number and SVG figures.
    Campaign(CampaignArgs),
}

#[derive(Debug, clap::Args)]
struct CampaignArgs {
    #[command(flatten)]
    source: RigSource,
    /// Directory for campaign.json and the figures (created if missing).
    #[arg(long, value_name = "DIR", default_value = "out/campaign")]
    out: PathBuf,
    /// About a tenth of the work: 5 load points, 4 amplitude steps per load parameter, 4 s records.
    #[arg(long)]
    quick: bool,
    /// Print the campaign's JSON on stdout instead of the summary tables (files are written either way).
    #[arg(long)]
    json: bool,
}

#[derive(Debug, clap::Args)]
pub struct RigSource {
    /// Rig configuration file (TOML). Default: the built-in Zhou et al. (2004) rig.
    #[arg(long, value_name = "FILE")]
    rig: Option<PathBuf>,
}

impl RigSource {
    /// The `--rig` file, if one was given.
    pub fn path(&self) -> Option<&std::path::Path> {
        self.rig.as_deref()
    }

    pub fn load(&self) -> Result<RigConfig> {
        match &self.rig {
            None => Ok(RigConfig::zhou2004()?),
            Some(path) => Ok(oilfilm_graph::node::read_rig_file(path)?),
        }
    }
}

#[derive(Debug, clap::Args)]
struct RigArgs {
    #[command(flatten)]
    source: RigSource,
    /// Seconds of record to simulate (the paper's records: 10 s).
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Exciter amplitude, N (exciter 1 at 23 Hz, exciter 2 at 37 Hz).
    #[arg(long, default_value_t = 100.0)]
    amplitude_n: f64,
    /// Print JSON instead of tables.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, clap::Args)]
struct CoefficientArgs {
    #[command(flatten)]
    source: RigSource,
    /// Shaft speed, rpm (default: the rig file's operating point).
    #[arg(long)]
    speed_rpm: Option<f64>,
    /// Static load carried by the film, N.
    #[arg(long)]
    load_n: Option<f64>,
    /// Bearing temperature, degrees C (sets the viscosity through the oil law).
    #[arg(long, conflicts_with = "viscosity_pa_s")]
    temperature_c: Option<f64>,
    /// Oil viscosity, Pa s (overrides the oil law).
    #[arg(long)]
    viscosity_pa_s: Option<f64>,
    /// Print JSON instead of tables.
    #[arg(long)]
    json: bool,
}

/// What a command that can decline did: what it was asked, or an answer it refused.
pub enum Outcome {
    Done,
    /// The analysis ran and refused to answer (a refused record, no estimate): why.
    Refused(String),
}

/// Exit status: 0 only when the command did what was asked (README, "Exit status").
pub mod exit {
    /// An error: input that cannot be read or is out of range, I/O, a failed node.
    pub const ERROR: u8 = 1;
    /// Command-line usage (clap's own).
    pub const USAGE: u8 = 2;
    /// The analysis ran and refused: a refused record, every window refused, no estimate.
    pub const REFUSED: u8 = 3;
    /// A bag is incomplete or differs from its metadata.yaml (`--allow-partial` goes on).
    pub const INCOMPLETE: u8 = 4;
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let done = |r: Result<()>| r.map(|()| Outcome::Done);
    let result = match cli.command {
        Command::Rig(args) => done(run_rig(&args)),
        Command::Launch(args) => done(launch::run(&args)),
        Command::Record(args) => done(record::run_record(&args)),
        Command::Play(args) => done(record::run_play(&args)),
        Command::Bag(BagCommand::Recover { dir }) => done(bag_recover(&dir)),
        Command::Coefficients(args) => done(run_coefficients(&args)),
        Command::Simulate(args) => done(records::run_simulate(&args)),
        Command::Identify(args) => records::run_identify(&args),
        Command::Import(args) => done(import::run(&args)),
        Command::Diagnose(args) => diagnose::run(&args),
        Command::Campaign(args) => done(args.source.load().and_then(|rig| campaign::run(&rig, &args.out, args.quick, args.json))),
    };
    match result {
        Ok(Outcome::Done) => std::process::ExitCode::SUCCESS,
        Ok(Outcome::Refused(why)) => {
            eprintln!("refused: {why}");
            std::process::ExitCode::from(exit::REFUSED)
        }
        Err(e) => {
            let incomplete = e.chain().any(|c| matches!(c.downcast_ref::<oilfilm_bag::BagError>(), Some(oilfilm_bag::BagError::Incomplete { .. })));
            if incomplete {
                eprintln!("Error: {e:?}\n(the bag is not what its metadata.yaml says: `oilfilm bag recover DIR` rewrites it from what is intact, or --allow-partial analyses what is readable and says what is missing)");
                std::process::ExitCode::from(exit::INCOMPLETE)
            } else {
                eprintln!("Error: {e:?}");
                std::process::ExitCode::from(exit::ERROR)
            }
        }
    }
}

fn run_coefficients(args: &CoefficientArgs) -> Result<()> {
    let mut config = args.source.load()?;
    if let Some(v) = args.speed_rpm {
        config.operating.speed_rpm = v;
    }
    if let Some(v) = args.load_n {
        config.operating.bearing_load_n = v;
    }
    if let Some(v) = args.temperature_c {
        config.operating.bearing_temperature_c = v;
    }
    config.validate()?;
    let mut running = config.running()?;
    if let Some(mu) = args.viscosity_pa_s {
        anyhow::ensure!(mu.is_finite() && mu > 0.0, "--viscosity-pa-s must be positive, got {mu}");
        running.viscosity_pa_s = mu;
    }
    let point = report::operating_point(&config, &running)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&point)?);
    } else {
        report::print_operating_point(&point);
    }
    Ok(())
}

fn run_rig(args: &RigArgs) -> Result<()> {
    anyhow::ensure!(args.seconds.is_finite() && args.seconds > 0.0, "--seconds must be positive, got {}", args.seconds);
    let config = args.source.load()?;
    let running = config.running()?;
    let point = report::operating_point(&config, &running)?;
    let (record, simulated) = report::simulate_two_tone(&config, args.seconds, args.amplitude_n)?;
    let identified = report::identify_record(&config, &simulated)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&serde_json::json!({ "operating_point": point, "record": record, "identification": identified }))?);
    } else {
        report::print_operating_point(&point);
        report::print_record(&record);
        report::print_identified(&identified);
    }
    Ok(())
}
