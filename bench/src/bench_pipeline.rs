//! `oilfilm-bench pipeline`: the identification pipeline's speed beside the Python pipeline a
//! user would write instead, and the paper's method beside ours, on one simulated rig.
//!
//! All rows run in one process invocation on the same record, so their ratios are the numbers
//! to read; absolute times move with the machine.

use std::hint::black_box;
use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use nalgebra::Matrix2;
use oilfilm_identification::conditioning::{self, Conditioned};
use oilfilm_identification::estimator::solve::ScaledFactor;
use oilfilm_identification::estimator::window::{BlockSummary, SummaryBuilder};
use oilfilm_identification::estimator::{self, EstimatorConfig, Signals, Solver};
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::{self, PipelineConfig, SpeedSource};
use oilfilm_identification::simulate::{self, SimulateOptions, SimulatedRecord};
use oilfilm_physics::config::RigConfig;

use oilfilm::progress::Progress;

const WINDOW: usize = 50_000;
/// Scans per block of the block-by-block pipeline (ADR 0020); 10 000-25 000 measured best
/// (3-7 MB conditioned per block). A divisor of [`WINDOW`], so that blocks are not split.
const BLOCK: usize = 10_000;
/// Runs per timed stage, the best kept, for oilfilm and (passed in meta.json) for Python
/// alike. On a shared 2-core VM a run of ~20 ms is often hit by a neighbour's burst; the
/// best of 15 (timeit's practice: the minimum is the least disturbed run) made the ratio
/// repeatable where the best of 5 spread 4.7-7.3x over three runs in a row.
const REPEATS: usize = 15;

fn best_of<T>(reps: usize, mut f: impl FnMut() -> T) -> f64 {
    (0..reps)
        .map(|_| {
            let t0 = Instant::now();
            black_box(f());
            t0.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn max_rel(a: &Matrix2<f64>, b: &Matrix2<f64>) -> f64 {
    (0..4).map(|i| ((a[i] - b[i]) / b[i]).abs()).fold(0.0, f64::max)
}

pub fn run(seconds: f64, python: Option<PathBuf>) -> Result<()> {
    anyhow::ensure!(seconds.is_finite() && seconds >= 10.0, "--seconds must be at least 10 (one 50 000-scan window)");
    let rig = RigConfig::zhou2004()?;
    let mut progress = Progress::new("simulating the benchmark record");
    let rec = simulate::simulate(&rig, &ExcitationPlan::two_tone(23.0, 37.0, 100.0), seconds, SimulateOptions::default(), &mut |f| progress.update(f))?;
    progress.finish();
    let raw = rec.raw()?;
    let cal = pipeline::calibration_for(&rig, &raw, &pipeline::rig_offsets(&rig, &raw)?)?;
    let mech = pipeline::mechanics_of(&rig);
    let ccfg = conditioning::ConditioningConfig::default();
    let scans = raw.len();
    let samples = scans * raw.channels.len();

    // 1. Rust: conditioning (buffers reused) + the lean least-squares stage per window, the
    //    same work the Python pipeline does; and the full estimator (lines, HAC errors, flags).
    // Every call below is made once outside the timing first, so its errors surface as errors.
    let mut out = Conditioned::default();
    // The chain designed in each call, as `conditioning::condition` does.
    let condition_into = |out: &mut Conditioned| conditioning::Chain::new(&cal, &mech, &ccfg, raw.sample_rate_hz).and_then(|c| c.condition_into(&raw, out));
    condition_into(&mut out)?;
    let t_cond = best_of(REPEATS, || black_box(condition_into(&mut out).is_ok()));
    let valid = out.valid.clone();
    let window = WINDOW.min(valid.len());
    let est = EstimatorConfig { window, hop: window, ..Default::default() };
    let cols: Vec<&[f64]> = [&out.x_m, &out.y_m, &out.vx_m_s, &out.vy_m_s, &out.fx_n, &out.fy_n].iter().map(|c| &c[valid.clone()]).collect();
    let n_windows = valid.len() / window;
    let factor = |w: usize| {
        let view: Vec<&[f64]> = cols.iter().map(|c| &c[w * window..(w + 1) * window]).collect();
        ScaledFactor::new(&BlockSummary::from_columns(&view), 4).and_then(|f| f.solve(Solver::Qr))
    };
    anyhow::ensure!(factor(0).is_some(), "the first window does not solve");
    let t_ls = best_of(REPEATS, || (0..n_windows).all(|w| factor(w).is_some()));
    let signals = Signals { x_m: cols[0], y_m: cols[1], vx_m_s: cols[2], vy_m_s: cols[3], ax_m_s2: None, ay_m_s2: None, fx_n: cols[4], fy_n: cols[5] };
    estimator::estimate_windows(&signals, &est)?;
    let t_full_est = best_of(3, || black_box(estimator::estimate_windows(&signals, &est).is_ok()));
    let t_one_window = best_of(51, || black_box(factor(0)));

    // 1b. The same work block by block (ADR 0020): the record conditioned in blocks of
    //     BLOCK scans (each with the filters' edge on each side) into reused buffers, each
    //     block's six columns pushed into its window's factor while they are in cache, and a
    //     window solved when its last block is in. Its first window's kxx is printed beside
    //     the whole record's.
    let mut block_out = Conditioned::default();
    let mut block_kxx = Vec::with_capacity(n_windows);
    let edge = valid.start;
    let chain = conditioning::Chain::new(&cal, &mech, &ccfg, raw.sample_rate_hz)?;
    let mut by_block = |kxx: &mut Vec<f64>| -> Result<()> {
        kxx.clear();
        let mut builder = SummaryBuilder::new(6);
        // Each block conditioned as a window reaching the chain's edge past it on either
        // side (so the whole block is valid), into the same buffers.
        let mut range = edge..(edge + BLOCK).min(scans - edge);
        while !range.is_empty() {
            let c = &mut block_out;
            chain.condition_window_into(&raw, range.start - edge..range.end + edge, c)?;
            // The block's scans window by window (a block straddles a window's end when
            // BLOCK does not divide the window); scans past the last whole window are
            // conditioned, as above, and not solved.
            let mut a = range.start;
            while a < range.end && (a - edge) / window < n_windows {
                let window_end = edge + ((a - edge) / window + 1) * window;
                let b = range.end.min(window_end);
                let rows = c.valid.start + (a - range.start)..c.valid.start + (b - range.start);
                let view: Vec<&[f64]> = [&c.x_m, &c.y_m, &c.vx_m_s, &c.vy_m_s, &c.fx_n, &c.fy_n].iter().map(|col| &col[rows.clone()]).collect();
                builder.push(&view);
                if b == window_end {
                    let summary = std::mem::replace(&mut builder, SummaryBuilder::new(6)).finish();
                    let solution = ScaledFactor::new(&summary, 4).and_then(|f| f.solve(Solver::Qr));
                    kxx.push(solution.context("a window does not solve")?.coef[0]);
                }
                a = b;
            }
            range = range.end..(range.end + BLOCK).min(scans - edge);
        }
        Ok(())
    };
    by_block(&mut block_kxx)?;
    anyhow::ensure!(block_kxx.len() == n_windows, "{} windows solved block by block for {n_windows}", block_kxx.len());
    let t_blocks = best_of(REPEATS, || black_box(by_block(&mut block_kxx).is_ok()));
    let whole_kxx = factor(0).map(|s| s.coef[0]).unwrap_or(f64::NAN);
    let first_block_kxx = block_kxx.first().copied().unwrap_or(f64::NAN);

    // 2. Python: the same record through scipy/numpy.
    let py = python.unwrap_or_else(|| PathBuf::from(".venv/bin/python"));
    let py_result = run_python(&py, &rec, &rig, &raw, &ccfg, (out.valid.start, window), scans);

    // 3. The paper's method against ours, on the same rig (10 s records, the rig's own noise).
    let paper = compare_methods(&rig)?;

    let lean = t_cond + t_ls;
    println!(
        "oilfilm-bench pipeline: {scans} scans x {} channels ({seconds} s at 5 kHz, two-tone), {n_windows} window(s) of {window}; one core",
        raw.channels.len()
    );
    println!();
    println!("| stage | oilfilm | M scans/s | M channel-samples/s |");
    println!("|---|---|---|---|");
    let row = |name: &str, t: f64| println!("| {name} | {:.2} ms | {:.1} | {:.1} |", t * 1e3, scans as f64 / t / 1e6, samples as f64 / t / 1e6);
    row("conditioning (steps 1-7)", t_cond);
    row("least squares, QR per window", t_ls);
    row("conditioning + least squares", lean);
    row("conditioning + full estimator (lines, HAC errors, flags)", t_cond + t_full_est);
    row(&format!("conditioning + least squares, block by block ({BLOCK}-scan blocks, ADR 0020)"), t_blocks);
    println!(
        "(block by block against the whole record: kxx of the first window {:.6e} against {:.6e} N/m, relative difference {:.1e})",
        -first_block_kxx,
        -whole_kxx,
        ((first_block_kxx - whole_kxx) / whole_kxx).abs()
    );
    println!();
    match &py_result {
        Ok(p) => {
            println!("Python (numpy {}, scipy {}), same record, same steps:", p.numpy, p.scipy);
            println!("| stage | Python | oilfilm | oilfilm faster by |");
            println!("|---|---|---|---|");
            println!("| conditioning | {:.1} ms | {:.2} ms | {:.1}x |", p.conditioning_s * 1e3, t_cond * 1e3, p.conditioning_s / t_cond);
            println!("| conditioning + least squares (whole pipeline) | {:.1} ms | {:.2} ms | {:.1}x |", p.pipeline_s * 1e3, lean * 1e3, p.pipeline_s / lean);
            println!("| the same, oilfilm block by block | {:.1} ms | {:.2} ms | {:.1}x |", p.pipeline_s * 1e3, t_blocks * 1e3, p.pipeline_s / t_blocks);
            println!(
                "| least squares, one {window} x 4 window, 2 right-hand sides | {:.3} ms (numpy.linalg.lstsq) | {:.3} ms | {:.1}x |",
                p.lstsq_window_s * 1e3,
                t_one_window * 1e3,
                p.lstsq_window_s / t_one_window
            );
            println!("(sanity: kxx of the first window, Python {:.4e} N/m)", p.kxx);
        }
        Err(e) => println!("Python column skipped: {e:#} (run `bash tests/python/setup-venv.sh` to make .venv)"),
    }
    println!();
    println!("The paper's method against oilfilm's (10 s records, Zhou point, the rig file's own sensor noise):");
    println!("| method | excitation | solver | band | result | max |K error| | max |C error| |");
    println!("|---|---|---|---|---|---|---|");
    for r in &paper {
        println!("| {} | {} | {} | {} | {} | {} | {} |", r.method, r.excitation, r.solver, r.band, r.result, r.k_err, r.c_err);
    }
    Ok(())
}

struct PythonResult {
    pipeline_s: f64,
    conditioning_s: f64,
    lstsq_window_s: f64,
    kxx: f64,
    numpy: String,
    scipy: String,
}

fn run_python(
    python: &PathBuf,
    rec: &SimulatedRecord,
    rig: &RigConfig,
    raw: &oilfilm_identification::record::RawRecord,
    ccfg: &conditioning::ConditioningConfig,
    (trim, window): (usize, usize),
    scans: usize,
) -> Result<PythonResult> {
    if !python.exists() {
        bail!("no Python interpreter at {}", python.display());
    }
    let dir = std::env::temp_dir().join(format!("oilfilm-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let raw_path = dir.join("raw.f64");
    let mut bytes = Vec::with_capacity(8 * scans * raw.channels.len());
    for col in &raw.columns {
        for v in col {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::write(&raw_path, bytes)?;
    let cal = rig.daq.calibration();
    let mut calibration = serde_json::Map::new();
    for &ch in &raw.channels {
        let c = cal.channel(ch)?;
        calibration.insert(
            ch.name().to_string(),
            serde_json::json!({
                "offset_v": c.offset_v,
                "sensitivity_v_per_unit": c.sensitivity_v_per_unit,
                "sample_offset_s": c.sample_offset_s,
                "linear_range_v": c.linear_range_v,
            }),
        );
    }
    let meta = serde_json::json!({
        "sample_rate_hz": rec.sample_rate_hz,
        "lsb_v": cal.lsb_v(),
        "channels": raw.channels.iter().map(|c| c.name()).collect::<Vec<_>>(),
        "calibration": calibration,
        "lowpass_order": ccfg.lowpass_order,
        "lowpass_cutoff_hz": ccfg.lowpass_cutoff_hz,
        "differentiator_half_length": ccfg.differentiator_half_length,
        "housing_mass_kg": rig.housing.mass_kg,
        "exciter_angles_deg": rig.housing.exciter_angles_deg,
        "gravity_m_s2": rig.housing.gravity_m_s2,
        "window": window,
        "hop": window,
        "trim": trim,
        "repeats": REPEATS, // as many as the Rust rows: best of fewer runs would handicap Python on a loaded machine
    });
    let meta_path = dir.join("meta.json");
    std::fs::write(&meta_path, serde_json::to_vec(&meta)?)?;
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/python/bench_pipeline.py");
    let output = Command::new(python).arg(&script).arg(&raw_path).arg(&meta_path).output().with_context(|| format!("running {}", python.display()))?;
    let _ = std::fs::remove_dir_all(&dir);
    if !output.status.success() {
        bail!("{} failed: {}", script.display(), String::from_utf8_lossy(&output.stderr).trim());
    }
    let v: serde_json::Value = serde_json::from_slice(&output.stdout).context("reading the Python benchmark's JSON")?;
    let num = |k: &str| v[k].as_f64().with_context(|| format!("Python result has no `{k}`"));
    Ok(PythonResult {
        pipeline_s: num("pipeline_s")?,
        conditioning_s: num("conditioning_s")?,
        lstsq_window_s: num("lstsq_window_s")?,
        kxx: num("kxx")?,
        numpy: v["numpy"].as_str().unwrap_or("?").to_string(),
        scipy: v["scipy"].as_str().unwrap_or("?").to_string(),
    })
}

struct MethodRow {
    method: &'static str,
    excitation: &'static str,
    solver: &'static str,
    band: String,
    result: String,
    k_err: String,
    c_err: String,
}

fn compare_methods(rig: &RigConfig) -> Result<Vec<MethodRow>> {
    let cases: [(&str, &str, ExcitationPlan, Solver, bool); 5] = [
        ("Zhou et al. 2004", "one sine, 37 Hz, 300 N", ExcitationPlan::paper_sine(37.0, 300.0), Solver::NormalEquations, false),
        ("oilfilm", "one sine, 37 Hz, 300 N", ExcitationPlan::paper_sine(37.0, 300.0), Solver::Qr, true),
        ("paper's solver, our excitation", "two-tone 23/37 Hz, 100 N", ExcitationPlan::two_tone(23.0, 37.0, 100.0), Solver::NormalEquations, false),
        ("oilfilm, fixed band", "two-tone 23/37 Hz, 100 N", ExcitationPlan::two_tone(23.0, 37.0, 100.0), Solver::Qr, false),
        ("oilfilm", "two-tone 23/37 Hz, 100 N", ExcitationPlan::two_tone(23.0, 37.0, 100.0), Solver::Qr, true),
    ];
    let mut rows = Vec::new();
    for (method, excitation, plan, solver, adaptive) in cases {
        let rec = simulate::simulate(rig, &plan, 10.0, SimulateOptions::default(), &mut |_| {})?;
        let raw = rec.raw()?;
        let cal = pipeline::calibration_for(rig, &raw, &pipeline::rig_offsets(rig, &raw)?)?;
        let mut config = PipelineConfig { adaptive_lowpass: adaptive, ..Default::default() };
        config.estimator.solver = solver;
        let id = pipeline::identify(&raw, &cal, rig, rec.speed_rpm, SpeedSource::Record, &config)?;
        let (kt, ct) = (rec.truth.coefficients.stiffness_n_m, rec.truth.coefficients.damping_n_s_m);
        let w = id.windows.first().context("no window")?;
        let (result, k_err, c_err) = match &w.estimate.result {
            Ok(c) => {
                ("answered".to_string(), format!("{:.1} %", 100.0 * max_rel(&c.stiffness_n_m, &kt)), format!("{:.1} %", 100.0 * max_rel(&c.damping_n_s_m, &ct)))
            }
            Err(r) => {
                let text = r.to_string();
                let short: String = text.chars().take(60).collect();
                (format!("refused: {short}..."), "-".into(), "-".into())
            }
        };
        rows.push(MethodRow {
            method,
            excitation,
            solver: match solver {
                Solver::NormalEquations => "normal equations",
                Solver::Qr => "QR + HAC errors",
                Solver::Svd => "SVD",
            },
            band: format!("{:.0} Hz", id.lowpass_cutoff_hz),
            result,
            k_err,
            c_err,
        });
    }
    Ok(rows)
}
