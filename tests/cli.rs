//! The `oilfilm` command as a user runs it: a record written by `simulate` is read back by
//! `identify`, whose JSON must carry coefficients close to the film model's; bad input gives
//! an error that names the file, line and column, and a non-zero exit.

use std::path::PathBuf;
use std::process::{Command, Output};

fn oilfilm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_oilfilm")).args(args).env("RUST_BACKTRACE", "0").output().expect("the oilfilm binary runs")
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("oilfilm-cli-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir.join(name)
}

fn matrix(v: &serde_json::Value) -> [[f64; 2]; 2] {
    // nalgebra serialises a Matrix2 column-major as a flat array of 4.
    let a: Vec<f64> = v.as_array().expect("matrix array").iter().map(|x| x.as_f64().expect("number")).collect();
    assert_eq!(a.len(), 4, "2x2 matrix: {v}");
    [[a[0], a[2]], [a[1], a[3]]]
}

#[test]
fn simulate_then_identify_recovers_the_film_coefficients() {
    let record = scratch("two-tone.txt");
    let out = oilfilm(&["simulate", "--seconds", "10", "--amplitude-n", "100", "-o", record.to_str().unwrap()]);
    assert!(out.status.success(), "simulate failed: {}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&record).expect("record written");
    assert!(text.starts_with("# oilfilm-ascii 1\n"), "format line");
    assert!(text.contains("# speed_rpm: 1500"), "the record states its speed");

    let out = oilfilm(&["identify", record.to_str().unwrap(), "--json"]);
    assert!(out.status.success(), "identify failed: {}", String::from_utf8_lossy(&out.stderr));
    let id: serde_json::Value = serde_json::from_slice(&out.stdout).expect("identify --json prints JSON");
    assert_eq!(id["speed_source"], "record");
    assert!(id["frame"].as_str().unwrap().contains("y vertical up"), "the output states the frame");
    let window = &id["windows"][0];
    let coefficients = &window["estimate"]["result"]["Ok"];
    assert!(coefficients.is_object(), "window solved: {}", window["estimate"]["result"]);
    let k = matrix(&coefficients["stiffness_n_m"]);
    let c = matrix(&coefficients["damping_n_s_m"]);

    // The film model's own coefficients at the record's operating point, from `coefficients`.
    let out = oilfilm(&["coefficients", "--json"]);
    assert!(out.status.success());
    let model: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let km: Vec<Vec<f64>> = serde_json::from_value(model["stiffness_n_m"].clone()).expect("rows");
    let cm: Vec<Vec<f64>> = serde_json::from_value(model["damping_n_s_m"].clone()).expect("rows");
    for i in 0..2 {
        for j in 0..2 {
            let (ek, ec) = ((k[i][j] - km[i][j]) / km[i][j].abs(), (c[i][j] - cm[i][j]) / cm[i][j].abs());
            println!("K{i}{j} {:.4e} vs {:.4e} ({:+.2} %), C{i}{j} {:.4e} vs {:.4e} ({:+.2} %)", k[i][j], km[i][j], 100.0 * ek, c[i][j], cm[i][j], 100.0 * ec);
            // The rig's own 0.1 um probes (not 40 dB): a few percent of errors-in-variables
            // bias remains and is flagged; the film model is the untabulated grid solution.
            assert!(ek.abs() < 0.06 && ec.abs() < 0.06, "K{i}{j} or C{i}{j} too far from the film model");
        }
    }
    let _ = std::fs::remove_file(&record);
}

#[test]
fn a_single_sine_record_is_refused_by_the_command_too() {
    let record = scratch("sine.txt");
    let out = oilfilm(&["simulate", "--seconds", "2", "--excitation", "sine", "--amplitude-n", "300", "-o", record.to_str().unwrap()]);
    assert!(out.status.success());
    let out = oilfilm(&["identify", record.to_str().unwrap()]);
    assert!(out.status.success(), "a refusal is an answer, not a crash");
    let text = String::from_utf8_lossy(&out.stdout);
    println!("{text}");
    assert!(text.contains("REFUSED") && text.contains("37.0 Hz"), "refusal with its reason");
    let _ = std::fs::remove_file(&record);
}

#[test]
fn bad_input_names_file_line_and_column_and_exits_non_zero() {
    let bad = scratch("bad.txt");
    std::fs::write(
        &bad,
        "# oilfilm-ascii 1\n# rig: zhou2004\n# sample_rate_hz: 5000\n# channel_interval_s: 1e-5\n# units: si\n# start_time_s: 0\n\
         scan probe_a_x probe_a_y probe_b_x probe_b_y frame_x frame_y f1 f2 f3 temperature\n0 1 2 3 4 5 6 7 8 9 nan\n",
    )
    .unwrap();
    let out = oilfilm(&["identify", bad.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    println!("{err}");
    assert!(!out.status.success());
    assert!(err.contains(&format!("{}:8:21", bad.display())) && err.contains("temperature"), "{err}");

    let out = oilfilm(&["identify", "/nonexistent/record.txt"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/record.txt"));

    let out = oilfilm(&["simulate", "--inject", "magic=3", "-o", scratch("x.txt").to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown effect `magic`"));

    let rig = scratch("bad-rig.toml");
    std::fs::write(&rig, oilfilm_physics::config::ZHOU2004_TOML.replacen("clearance_m = 0.114e-3", "clearance_m = -1.0", 1)).unwrap();
    let out = oilfilm(&["coefficients", "--rig", rig.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("bearing.clearance_m"));
    let _ = std::fs::remove_file(&bad);
    let _ = std::fs::remove_file(&rig);
}
