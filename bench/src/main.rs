//! `oilfilm-bench`: benchmarks that print a table, kept out of the `oilfilm` command.
//! Wall-clock numbers vary with the machine; the ratios measured in one run (speed-up over a
//! reference measured beside it, multiple of real time) are the numbers to compare between
//! runs.
//!
//! `cargo run --release -p oilfilm-bench -- pipeline` (or `physics`, `nodes`, `bag`,
//! `diagnose`, `memory`; each takes `--help`).

mod bench_bag;
mod bench_diagnose;
mod bench_memory;
mod bench_nodes;
mod bench_pipeline;

// What `bench_diagnose` uses of the command's diagnosis code, compiled from its sources (they
// are modules of the `oilfilm` binary, not of its library).
#[allow(dead_code)] // the reader's whole result: only the record and rig are used here
#[path = "../../src/ascii_input.rs"]
mod ascii_input;
#[path = "../../src/diagnose_report.rs"]
mod diagnose_report;
#[allow(dead_code)] // the campaign's figures: only `padded` is used here
#[path = "../../src/figures.rs"]
mod figures;

use std::path::{Path, PathBuf};
use std::process::Command;

use std::time::Instant;

use anyhow::{Context, Result};
use nalgebra::Vector2;
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::film::finite::{FiniteBearing, GridSpec};
use oilfilm_physics::film::{FilmModelConfig, Running};
use oilfilm_physics::operating_point::{self, EquilibriumOptions};
use oilfilm_physics::rig::RigInput;
use oilfilm_physics::simulation::SimulatedRig;
use oilfilm_physics::validation;

/// Benchmarks of oilfilm that print a table.
#[derive(Debug, clap::Parser)]
#[command(name = "oilfilm-bench", version, about, long_about = None)]
struct BenchArgs {
    #[command(subcommand)]
    what: BenchWhat,
}

#[derive(Debug, clap::Subcommand)]
enum BenchWhat {
    /// Conditioning + windowed estimation throughput beside the equivalent Python pipeline
    /// (scipy/numpy, run in .venv), the least-squares stage against numpy.linalg.lstsq, and
    /// the paper's method against ours on the same simulated rig.
    Pipeline {
        /// Seconds of simulated record for the throughput rows.
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
        /// Python interpreter with numpy and scipy (default: .venv/bin/python, made by
        /// tests/python/setup-venv.sh).
        #[arg(long)]
        python: Option<std::path::PathBuf>,
    },
    /// The conditioner and estimator nodes on loopback DDS: latency, throughput, drops and
    /// CPU at 5 kHz x 10 channels and 100 kHz x 16 channels.
    Nodes {
        /// Seconds of frames per configuration.
        #[arg(long, default_value_t = 20.0)]
        seconds: f64,
    },
    /// The diagnosis catalog on a 10 s, 5 kHz record (target: under 5 s on one core), and
    /// the show (model against measurement) beside it.
    Diagnose {
        /// Repeats per record (the median is reported; for the outside records, the best).
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        /// Seconds of the simulated records.
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// Directory of outside records (`case-NN/record.txt.gz` with `rig.toml`); default
        /// `tests/data/measured-records`.
        #[arg(long, value_name = "DIR")]
        records: Option<std::path::PathBuf>,
    },
    /// rosbag2 bags: record throughput (MB/s, msgs/s; zstd, lz4, none) of the simulated rig's
    /// DAQ frames and whole graph, and `oilfilm identify BAG --replay` speed as a multiple of real time.
    Bag {
        /// Seconds of simulated rig (5 kHz x 10 channels).
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
        /// Also sweep zstd levels (fast levels included) and the mcap crate's compression
        /// worker threads on the DAQ frames (ratio against MB/s: how ADR 0013 chose).
        #[arg(long)]
        zstd_sweep: bool,
    },
    /// Peak memory (RSS) and wall time of `oilfilm identify` as a child process: a ~1 GB
    /// ASCII record, streamed (the size switches it), beside a smaller record identified
    /// whole and streamed. Writes the records to a scratch directory and removes them.
    Memory {
        /// Size of the large record, GB.
        #[arg(long, default_value_t = 1.0)]
        gb: f64,
        /// Size of the smaller record, MB (identified whole and streamed).
        #[arg(long, default_value_t = 50.0)]
        small_mb: f64,
        /// Seconds of the simulated segment the records repeat.
        #[arg(long, default_value_t = 20.0)]
        segment_seconds: f64,
        /// Scratch directory for the records (default: one in the temp directory).
        #[arg(long, value_name = "DIR")]
        dir: Option<PathBuf>,
        /// The `oilfilm` binary (default: beside this one).
        #[arg(long, value_name = "FILE")]
        oilfilm: Option<PathBuf>,
    },
    /// Film coefficient set at the Zhou point beside ROSS's on the same bearing and grid
    /// (measured in the same run: `bash bench/ross/setup-venv.sh` once), the Lund & Thomsen
    /// comparison, and rig simulation speed.
    Physics {
        /// Repeats of the coefficient set (the median is reported), ours and ROSS's.
        #[arg(long, default_value_t = 30)]
        repeats: usize,
        /// Simulated seconds for each rig-speed row (the direct finite film runs a tenth).
        #[arg(long, default_value_t = 2.0)]
        seconds: f64,
        /// Python interpreter with ROSS (default: .venv-ross/bin/python, made by
        /// bench/ross/setup-venv.sh).
        #[arg(long)]
        ross_python: Option<PathBuf>,
    },
}

fn main() -> Result<()> {
    let args = <BenchArgs as clap::Parser>::parse();
    match args.what {
        BenchWhat::Physics { repeats, seconds, ref ross_python } => physics(repeats.max(1), seconds, ross_python.as_deref()),
        BenchWhat::Pipeline { seconds, ref python } => bench_pipeline::run(seconds, python.clone()),
        BenchWhat::Nodes { seconds } => bench_nodes::run(seconds),
        BenchWhat::Diagnose { repeats, seconds, ref records } => bench_diagnose::run(repeats, seconds, records.as_deref()),
        BenchWhat::Bag { seconds, zstd_sweep } => bench_bag::run(seconds, zstd_sweep),
        BenchWhat::Memory { gb, small_mb, segment_seconds, ref dir, ref oilfilm } => {
            bench_memory::run(gb, small_mb, segment_seconds, dir.as_deref(), oilfilm.as_deref())
        }
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// ROSS's time for one coefficient set on `rig`'s bearing and grid, measured now by
/// `bench/ross/ross_film.py` under `python`, with its coefficients.
struct Ross {
    version: String,
    python: String,
    median_s: f64,
    warmup_s: f64,
    eccentricity: f64,
    stiffness: [[f64; 2]; 2],
    damping: [[f64; 2]; 2],
}

fn ross(python: &Path, rig: &RigConfig, grid: GridSpec, running: &Running, load_n: f64, repeats: usize) -> Result<Ross> {
    let oilfilm_physics::geometry::BearingKind::TwoAxialGroove { groove_arc_deg, .. } = rig.bearing.kind else {
        anyhow::bail!("ROSS's PlainJournal is compared on the two-axial-groove bearing; the rig's is {:?}", rig.bearing.kind);
    };
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("ross/ross_film.py");
    let input = serde_json::json!({
        "diameter_m": rig.bearing.diameter_m, "length_m": rig.bearing.length_m, "clearance_m": rig.bearing.clearance_m,
        "groove_arc_deg": groove_arc_deg, "n_theta": grid.n_theta, "n_z": grid.n_z,
        "speed_rpm": running.omega_rad_s * 30.0 / std::f64::consts::PI, "load_n": load_n, "viscosity_pa_s": running.viscosity_pa_s,
        "density_kg_m3": rig.oil.density_kg_m3, "repeats": repeats,
    });
    let out = Command::new(python).arg(&script).arg(input.to_string()).output().with_context(|| format!("running {}", python.display()))?;
    anyhow::ensure!(out.status.success(), "{} {}: {}", python.display(), script.display(), String::from_utf8_lossy(&out.stderr).lines().last().unwrap_or(""));
    let line = String::from_utf8_lossy(&out.stdout).lines().last().unwrap_or("").to_string();
    let v: serde_json::Value = serde_json::from_str(&line).with_context(|| format!("ROSS's output: {line}"))?;
    let m = |key: &str| -> Result<[[f64; 2]; 2]> {
        let at = |i: usize, j: usize| v[key][i][j].as_f64().with_context(|| format!("ROSS's {key}[{i}][{j}]"));
        Ok([[at(0, 0)?, at(0, 1)?], [at(1, 0)?, at(1, 1)?]])
    };
    let num = |key: &str| v[key].as_f64().with_context(|| format!("ROSS's {key}"));
    Ok(Ross {
        version: v["ross"].as_str().unwrap_or("?").into(),
        python: v["python"].as_str().unwrap_or("?").into(),
        median_s: num("median_s")?,
        warmup_s: num("warmup_s")?,
        eccentricity: num("eccentricity")?,
        stiffness: m("stiffness_n_m")?,
        damping: m("damping_n_s_m")?,
    })
}

fn physics(repeats: usize, seconds: f64, ross_python: Option<&Path>) -> Result<()> {
    anyhow::ensure!(seconds.is_finite() && seconds > 0.0, "--seconds must be positive");
    let base = RigConfig::zhou2004()?;
    let FilmModelConfig::Finite { n_theta, n_z, .. } = base.film else {
        anyhow::bail!("the built-in rig is expected to use the finite-length film");
    };
    let grid = GridSpec { n_theta, n_z };
    let running = Running::from_rpm(1500.0, 0.03);
    let load = Vector2::new(0.0, -5000.0);

    // 1. One coefficient set from a cold start (new solver, no warm start), Zhou point.
    let mut times = Vec::with_capacity(repeats);
    let mut last = None;
    for _ in 0..repeats {
        let started = Instant::now();
        let mut film = FiniteBearing::new(base.bearing, grid)?;
        let op = operating_point::solve(&mut film, &running, load, &EquilibriumOptions::default())?;
        times.push(started.elapsed().as_secs_f64());
        last = Some(op);
    }
    let set_s = median(times);
    let op = last.ok_or_else(|| anyhow::anyhow!("no repeat ran"))?;

    // 2. The same grid against every row of Lund & Thomsen.
    let mut lund_rows = Vec::new();
    for table in validation::lund_thomsen_1978() {
        let mut film = FiniteBearing::new(validation::table_geometry(table.slenderness), grid)?;
        for row in validation::compare(&mut film, &table)? {
            lund_rows.push((table.slenderness, row));
        }
    }
    let max_coef = lund_rows.iter().flat_map(|(_, r)| r.coefficient_errors()).map(f64::abs).fold(0.0, f64::max);
    let max_eps = lund_rows.iter().map(|(_, r)| (r.eccentricity - r.reference.eccentricity).abs()).fold(0.0, f64::max);
    let max_att = lund_rows.iter().map(|(_, r)| (r.attitude_deg - r.reference.attitude_deg).abs()).fold(0.0, f64::max);
    // Entries outside max(5 %, 0.005 for |ref| < 0.2): named, not hidden.
    let outside: Vec<String> = lund_rows
        .iter()
        .flat_map(|(ld, r)| {
            let (v, t) = (r.values(), r.reference_values());
            (0..8)
                .filter(move |&i| (v[i] - t[i]).abs() > validation::RowComparison::tolerance(t[i], 0.05))
                .map(move |i| format!("{} at L/D {ld}, S {}: {:.4} vs {}", validation::RowComparison::COEFFICIENT_NAMES[i], r.reference.sommerfeld, v[i], t[i]))
        })
        .collect();

    // 3. Rig simulation speed at 5 kHz (rig + DAQ chain), two-tone excitation.
    let mut rig_rows = Vec::new();
    let variants: [(&str, FilmModelConfig, f64); 3] = [
        ("short-bearing film", FilmModelConfig::Short, seconds),
        ("finite film, tabulated", FilmModelConfig::Finite { n_theta, n_z, tabulate: true }, seconds),
        ("finite film, direct solve", FilmModelConfig::Finite { n_theta, n_z, tabulate: false }, (seconds / 10.0).max(0.05)),
    ];
    for (label, film, secs) in variants {
        let mut config = base.clone();
        config.film = film;
        let built = Instant::now();
        let mut sim = SimulatedRig::new(&config, 0.0)?;
        let build_s = built.elapsed().as_secs_f64();
        let period = sim.period_s();
        let n = (secs / period).round() as usize;
        let started = Instant::now();
        for i in 1..=n {
            let t = i as f64 * period;
            let w = 2.0 * std::f64::consts::PI;
            let input = RigInput { exciter_n: [100.0 * (w * 23.0 * t).sin(), 100.0 * (w * 37.0 * t).sin()] };
            sim.step(&input, t)?;
        }
        let wall = started.elapsed().as_secs_f64();
        rig_rows.push((label, secs, wall, build_s));
    }

    println!("oilfilm-bench physics (one core; wall-clock, median of {repeats} for the coefficient set)");
    println!();
    println!("| measurement | value |");
    println!("|---|---|");
    println!("| grid (per pad: n_theta x n_z half-length) | {n_theta} x {n_z} |");
    println!("| coefficient set, Zhou point (1500 rpm, 5 kN, 0.03 Pa s), cold start | {:.3} ms |", set_s * 1e3);
    println!("| ... eccentricity, attitude | {:.4}, {:.2} deg |", op.eccentricity, op.attitude_deg);
    let python = ross_python.map(Path::to_path_buf).unwrap_or_else(|| PathBuf::from(".venv-ross/bin/python"));
    match ross(&python, &base, grid, &running, load.norm(), repeats.min(10)) {
        Ok(r) => {
            println!(
                "| ROSS {} (Python {}) PlainJournal, same bearing and grid, isothermal, median of {} | {:.1} ms (first solve, compiling its kernels, {:.1} s) |",
                r.version,
                r.python,
                repeats.min(10),
                r.median_s * 1e3,
                r.warmup_s
            );
            println!("| speed-up over ROSS, measured in this run | {:.0}x (target >= 10x) |", r.median_s / set_s);
            let k = op.coefficients.stiffness_n_m;
            let c = op.coefficients.damping_n_s_m;
            let worst = (0..4)
                .map(|i| {
                    let (a, b) = (i / 2, i % 2);
                    ((k[(a, b)] - r.stiffness[a][b]) / r.stiffness[a][b]).abs().max(((c[(a, b)] - r.damping[a][b]) / r.damping[a][b]).abs())
                })
                .fold(0.0, f64::max);
            println!(
                "| ... ROSS's eccentricity; largest relative difference of the 8 coefficients from ours | {:.4}; {:.1} % |",
                r.eccentricity,
                100.0 * worst
            );
        }
        Err(e) => println!("| speed-up over ROSS | not measured ({e}; `bash bench/ross/setup-venv.sh` makes .venv-ross) |"),
    }
    println!(
        "| Lund & Thomsen 1978, 80 coefficients: outside 5 % (or 0.005 below 0.2) | {} of 80{} |",
        outside.len(),
        if outside.is_empty() { String::new() } else { format!(": {}", outside.join("; ")) }
    );
    println!("| ... largest relative error of any coefficient | {:.2} % |", 100.0 * max_coef);
    println!("| ... max eccentricity error / attitude error | {max_eps:.4} / {max_att:.2} deg |");
    for (label, secs, wall, build) in &rig_rows {
        println!("| rig + DAQ at 5 kHz, {label} | {:.1}x real time ({secs} s simulated in {:.3} s; set-up {:.3} s) |", secs / wall, wall, build);
    }
    println!();
    println!("Lund rows (load frame): L/D, S, eps err, attitude err, worst coefficient error");
    for (ld, r) in &lund_rows {
        let errs = r.coefficient_errors();
        let (k, e) = errs.iter().enumerate().map(|(k, e)| (k, e.abs())).fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
        println!(
            "  {ld:.1} {:>6.3} {:>+8.4} {:>+7.2} deg  {} {:+.2} %",
            r.reference.sommerfeld,
            r.eccentricity - r.reference.eccentricity,
            r.attitude_deg - r.reference.attitude_deg,
            validation::RowComparison::COEFFICIENT_NAMES[k],
            100.0 * e * errs[k].signum()
        );
    }
    Ok(())
}
