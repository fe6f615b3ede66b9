//! `oilfilm-bench` as a user runs it.

use std::process::{Command, Output};

fn bench(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_oilfilm-bench")).args(args).env("RUST_BACKTRACE", "0").output().expect("the oilfilm-bench binary runs")
}

/// `oilfilm-bench pipeline` on the shortest record it takes (one window, which the 10 000-scan
/// blocks do not divide, so blocks straddle its end): every row is printed, and the
/// block-by-block pipeline's first window gives the whole record's kxx to well inside its
/// standard error (ADR 0020: the blocks differ from the whole record by the filters' settling
/// tolerance). The times are not checked: speed belongs to the benchmark, not to a test.
#[test]
fn bench_pipeline_runs_and_its_blocks_agree_with_the_whole_record() {
    let out = bench(&["pipeline", "--seconds", "10", "--python", "/nonexistent/python"]);
    assert!(out.status.success(), "bench failed: {}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    for row in ["| conditioning (steps 1-7) |", "| conditioning + least squares |", "| conditioning + least squares, block by block"] {
        assert!(text.contains(row), "no row `{row}` in:\n{text}");
    }
    assert!(text.contains("Python column skipped: no Python interpreter at /nonexistent/python"), "{text}");
    let line = text.lines().find(|l| l.starts_with("(block by block against the whole record")).unwrap_or_else(|| panic!("no comparison line in:\n{text}"));
    let rel: f64 =
        line.rsplit("relative difference ").next().and_then(|v| v.trim_end_matches(')').parse().ok()).unwrap_or_else(|| panic!("unreadable: {line}"));
    assert!(rel < 1e-6, "{line}");
    let kxx: Vec<f64> = line.split_whitespace().filter_map(|w| w.parse().ok()).collect();
    assert!(kxx.len() >= 2 && kxx[0] > 1e7 && kxx[1] > 1e7, "two film stiffnesses of the Zhou point expected: {line}");
}
