//! `oilfilm-bench memory`: the peak memory (resident set) and wall time of `oilfilm identify`
//! on a large ASCII record, streamed (issue 25: a 1 GB record within 200 MB), beside the
//! whole-record path and the streamed path on a smaller record, each `oilfilm identify` a
//! child process whose peak RSS `wait4` reports.
//!
//! The records: a simulated two-tone record of `--segment-seconds` (the default tones, 23 and
//! 37 Hz, repeat every whole second, so copies of a whole-second segment follow each other
//! without a seam in the excitation; only the noise repeats), written with consecutive scan
//! indices as many times as the size asks, in volts as `oilfilm simulate` writes them.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use oilfilm_identification::ascii::{self, Units};
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_physics::config::RigConfig;

/// What `wait4` said of one `oilfilm identify` run.
struct Run {
    peak_rss_mb: f64,
    wall_s: f64,
    exit: i32,
    /// The last lines of its standard output (the summary).
    tail: Vec<String>,
}

/// Writes the segment `copies` times (scan indices consecutive) to `path`; its size in bytes.
fn write_record(path: &Path, segment: &ascii::Record, copies: usize) -> Result<u64> {
    let file = std::fs::File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    let mut w = ascii::Writer::new(BufWriter::with_capacity(1 << 20, file), &segment.header)?;
    let (n, width) = (segment.len(), segment.columns.len());
    let mut row = vec![0.0; width];
    let mut index = 0u64;
    for _ in 0..copies {
        for i in 0..n {
            for (v, c) in row.iter_mut().zip(&segment.columns) {
                *v = c[i];
            }
            w.push(index, &row)?;
            index += 1;
        }
    }
    w.finish()?.flush()?;
    Ok(std::fs::metadata(path)?.len())
}

/// Runs `oilfilm identify` with `args` as a child and waits for it with `wait4`: its peak
/// resident set (ru_maxrss, of that child alone) and wall time.
fn measure(oilfilm: &Path, args: &[&str], out: &Path) -> Result<Run> {
    let stdout = std::fs::File::create(out)?;
    let started = Instant::now();
    let child = Command::new(oilfilm)
        .arg("identify")
        .args(args)
        .stdout(stdout)
        .stderr(Stdio::null())
        .spawn()
        .with_context(|| format!("starting {}", oilfilm.display()))?;
    let pid = i32::try_from(child.id()).context("child pid")?;
    let mut status = 0;
    // SAFETY: rusage is plain data, zeroed is a valid value; wait4 fills it for our child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `pid` is our own child, not yet waited for (std's `Child` is never waited on).
    let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    let wall_s = started.elapsed().as_secs_f64();
    if r != pid {
        bail!("wait4 on {pid}: {}", std::io::Error::last_os_error());
    }
    let exit = if libc::WIFEXITED(status) { libc::WEXITSTATUS(status) } else { -1 };
    let text = std::fs::read_to_string(out).unwrap_or_default();
    let tail = text.lines().rev().take(4).map(str::to_string).collect::<Vec<_>>().into_iter().rev().collect();
    // ru_maxrss is in KiB on Linux.
    Ok(Run { peak_rss_mb: usage.ru_maxrss as f64 / 1024.0, wall_s, exit, tail })
}

pub fn run(gb: f64, small_mb: f64, segment_seconds: f64, dir: Option<&Path>, oilfilm: Option<&Path>) -> Result<()> {
    anyhow::ensure!(gb > 0.0 && small_mb > 0.0 && segment_seconds >= 1.0, "--gb and --small-mb must be > 0, --segment-seconds >= 1");
    let oilfilm: PathBuf = match oilfilm {
        Some(p) => p.to_path_buf(),
        None => std::env::current_exe()?.parent().map(|d| d.join("oilfilm")).context("locating the oilfilm binary")?,
    };
    anyhow::ensure!(oilfilm.exists(), "{} not found (build it: cargo build --release --bin oilfilm, or give --oilfilm)", oilfilm.display());
    let dir = dir.map_or_else(|| std::env::temp_dir().join(format!("oilfilm-bench-memory-{}", std::process::id())), Path::to_path_buf);
    std::fs::create_dir_all(&dir)?;

    let rig = RigConfig::zhou2004()?;
    let started = Instant::now();
    let sim = simulate::simulate(&rig, &ExcitationPlan::two_tone(23.0, 37.0, 100.0), segment_seconds.round(), SimulateOptions::default(), &mut |_| {})?;
    let segment = sim.to_ascii(&rig, Units::Volts)?;
    let probe = dir.join("segment.txt");
    let segment_bytes = write_record(&probe, &segment, 1)?;
    std::fs::remove_file(&probe)?;
    let copies = |mb: f64| ((mb * 1024.0 * 1024.0 / segment_bytes as f64).round() as usize).max(1);
    let (small, large) = (dir.join("small.txt"), dir.join("large.txt"));
    let small_bytes = write_record(&small, &segment, copies(small_mb))?;
    let large_bytes = write_record(&large, &segment, copies(gb * 1024.0))?;
    let mb = |b: u64| b as f64 / (1024.0 * 1024.0);
    println!(
        "records: {:.0} s segment ({:.1} MB) simulated and written {} and {} times: {:.1} MB and {:.1} MB, in {:.1} s",
        segment_seconds.round(),
        mb(segment_bytes),
        copies(small_mb),
        copies(gb * 1024.0),
        mb(small_bytes),
        mb(large_bytes),
        started.elapsed().as_secs_f64()
    );
    println!("oilfilm: {}", oilfilm.display());
    println!();
    let (s, l) = (small.display().to_string(), large.display().to_string());
    let rows: [(&str, u64, Vec<&str>); 3] = [
        ("whole record (default)", small_bytes, vec![s.as_str()]),
        ("--stream", small_bytes, vec![s.as_str(), "--stream"]),
        ("default (streamed: over the size)", large_bytes, vec![l.as_str()]),
    ];
    println!("{:<36} {:>10} {:>14} {:>12} {:>10} {:>8} {:>6}", "oilfilm identify", "record MB", "peak RSS MB", "RSS/record", "wall s", "MB/s", "exit");
    let mut results = Vec::new();
    for (i, (what, bytes, args)) in rows.iter().enumerate() {
        let r = measure(&oilfilm, args, &dir.join(format!("out-{i}.txt")))?;
        println!(
            "{:<36} {:>10.1} {:>14.1} {:>12.3} {:>10.2} {:>8.1} {:>6}",
            what,
            mb(*bytes),
            r.peak_rss_mb,
            r.peak_rss_mb / mb(*bytes),
            r.wall_s,
            mb(*bytes) / r.wall_s,
            r.exit
        );
        results.push(r);
    }
    println!();
    for ((what, _, _), r) in rows.iter().zip(&results) {
        println!("{what}: last lines of its output:");
        for line in &r.tail {
            let short: String = line.chars().take(160).collect();
            println!("    {short}");
        }
    }
    let (whole, large_run) = (&results[0], &results[2]);
    println!();
    println!(
        "streamed {:.0} MB record: peak RSS {:.1} MB ({:.1} x the whole-record path's on a record {:.0} x smaller)",
        mb(large_bytes),
        large_run.peak_rss_mb,
        large_run.peak_rss_mb / whole.peak_rss_mb,
        large_bytes as f64 / small_bytes as f64
    );
    std::fs::remove_dir_all(&dir).with_context(|| format!("removing {}", dir.display()))?;
    Ok(())
}
