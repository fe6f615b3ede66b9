//! Records from other tools, end to end through the `oilfilm` binary: one simulated record
//! written as our ASCII format, as TDMS (several groups, interleaved, incremental segments),
//! as a MAT-file (a compressed struct of channels) and as CSV (a units row) is imported to
//! four bags whose identification (batch, and through the nodes with `--replay`) gives the
//! same estimates bit for bit; `identify --map` gives them without a bag; `diagnose --map` reads the same record as the ASCII one; and a broken
//! file is refused naming file, channel and place, with nothing written.

#[path = "support/scratch.rs"]
mod support;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use oilfilm_foreign::fixtures::{self, MatLayout, TdmsChannel, TdmsLayout};
use support::Scratch;

fn oilfilm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_oilfilm")).args(args).env("RUST_BACKTRACE", "0").output().expect("the oilfilm binary runs")
}

fn ok(args: &[&str]) -> Output {
    let out = oilfilm(args);
    assert!(out.status.success(), "oilfilm {}: {}", args.join(" "), String::from_utf8_lossy(&out.stderr));
    out
}

const PARAMS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/launch_configs/params/sim_rig.yaml");

/// The channels of the simulated record and where each goes in the foreign files.
const CHANNELS: [(&str, &str, &str); 10] = [
    ("probe_a_x", "Bearing probes", "A x"),
    ("probe_a_y", "Bearing probes", "A y"),
    ("probe_b_x", "Bearing probes", "B x"),
    ("probe_b_y", "Bearing probes", "B y"),
    ("frame_x", "Frame probes", "x"),
    ("frame_y", "Frame probes", "y"),
    ("f1", "Forces", "Exciter 1"),
    ("f2", "Forces", "Exciter 2"),
    ("f3", "Forces", "Bellows"),
    ("temperature", "Thermal", "Bearing"),
];

fn map_text(timing: &str, source: impl Fn(usize) -> String, extra: &str) -> String {
    let mut text = format!("{extra}\n[timing]\n{timing}\nmultiplexer = \"sequential\"\nchannel_interval_s = 1e-5\n\n[speed]\nrpm = 1500\n");
    for (k, (rig, _, _)) in CHANNELS.iter().enumerate() {
        text.push_str(&format!("\n[[channel]]\nrig = \"{rig}\"\n{}\nunit = \"V\"\n", source(k)));
    }
    text
}

struct Files {
    _dir: Scratch,
    dir: PathBuf,
    ascii: PathBuf,
    /// (record, map) of TDMS, MAT, CSV.
    foreign: Vec<(PathBuf, PathBuf)>,
}

fn files(test: &str) -> Files {
    let dir = Scratch::new("oilfilm-foreign-test", test);
    std::fs::create_dir_all(&*dir).unwrap();
    let d = dir.to_path_buf();
    let ascii = d.join("record.txt");
    ok(&["simulate", "--seconds", "6", "-o", ascii.to_str().unwrap()]);
    let record = oilfilm_identification::ascii::read(&std::fs::read_to_string(&ascii).unwrap(), "record.txt").unwrap();
    let names: Vec<&str> = record.header.channels.iter().map(String::as_str).collect();
    assert_eq!(names, CHANNELS.map(|c| c.0), "the simulated record's scan order");
    let col = |k: usize| record.columns[k].as_slice();

    let tdms = d.join("record.tdms");
    let chans: Vec<TdmsChannel> = CHANNELS
        .iter()
        .enumerate()
        .map(|(k, (_, g, n))| TdmsChannel { group: g, name: n, values: col(k), properties: vec![("wf_increment", 1.0 / 5000.0)] })
        .collect();
    fixtures::tdms(&tdms, &chans, TdmsLayout { segments: 7, interleaved: true, big_endian: false }).unwrap();
    let tdms_map = d.join("tdms.map.toml");
    std::fs::write(
        &tdms_map,
        map_text("sample_rate_from = \"wf_increment\"", |k| format!("from = \"{}/{}\"", CHANNELS[k].1, CHANNELS[k].2), "format = \"tdms\""),
    )
    .unwrap();

    let mat = d.join("record.mat");
    let cols: Vec<(&str, &[f64])> = CHANNELS.iter().enumerate().map(|(k, (rig, _, _))| (*rig, col(k))).collect();
    fixtures::mat(&mat, &cols, &[("fs", 5000.0)], MatLayout::Struct("run"), true).unwrap();
    let mat_map = d.join("mat.map.toml");
    std::fs::write(&mat_map, map_text("sample_rate_from = \"run.fs\"", |k| format!("from = \"run.{}\"", CHANNELS[k].0), "")).unwrap();

    let csv = d.join("record.csv");
    let headers: Vec<String> = CHANNELS.iter().map(|(_, g, n)| format!("{g} {n}")).collect();
    let cols: Vec<(&str, &[f64])> = headers.iter().enumerate().map(|(k, h)| (h.as_str(), col(k))).collect();
    fixtures::csv(&csv, &cols, Some(&["V"; 10])).unwrap();
    let csv_map = d.join("csv.map.toml");
    std::fs::write(&csv_map, map_text("sample_rate_hz = 5000", |k| format!("from = \"{}\"", headers[k]), "[csv]\nunits_row = true")).unwrap();

    Files { _dir: dir, dir: d, ascii, foreign: vec![(tdms, tdms_map), (mat, mat_map), (csv, csv_map)] }
}

fn estimates(v: &serde_json::Value) -> serde_json::Value {
    v["estimates"].clone()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn one_record_in_four_formats_gives_the_same_estimates_bit_for_bit() {
    let f = files("four-formats");
    // 2 s windows every second: four of them in the 6 s record.
    let window = ["--params", PARAMS, "--window", "10000", "--hop", "5000", "--json"];
    let run = |first: &[&str], more: &[&str]| -> serde_json::Value {
        let args: Vec<&str> = ["identify"].iter().chain(first).chain(more).chain(&window).copied().collect();
        let mut v: serde_json::Value = serde_json::from_slice(&ok(&args).stdout).expect("JSON");
        // How much of a bag was read says nothing of the estimates; a file has no such keys.
        if let Some(o) = v.as_object_mut() {
            for k in ["bag_read", "complete", "shortfalls"] {
                o.remove(k);
            }
        }
        v
    };
    let reference_bag = f.dir.join("ascii-bag");
    let out = ok(&["import", s(&f.ascii), "-o", s(&reference_bag)]);
    println!("{}", String::from_utf8_lossy(&out.stdout));
    // The batch identification (identify BAG's default) and the node graph's re-run.
    let batch = run(&[s(&reference_bag)], &[]);
    let solved = batch["windows"].as_array().expect("windows").iter().filter(|w| w["estimate"]["result"].get("Ok").is_some()).count();
    assert!(solved >= 3, "the reference record is identified: {batch}");
    let replayed = estimates(&run(&[s(&reference_bag)], &["--replay"]));
    assert!(replayed.as_array().unwrap().iter().filter(|e| e["solved"] == true).count() >= 3, "the node graph identifies it: {replayed}");
    for (record, map) in &f.foreign {
        let bag = f.dir.join(format!("{}-bag", record.extension().unwrap().to_str().unwrap()));
        let out = ok(&["import", s(record), "--map", s(map), "-o", s(&bag)]);
        println!("{}", String::from_utf8_lossy(&out.stdout));
        // serde_json keeps every f64's shortest round-trip digits: equal JSON, equal bits.
        assert_eq!(run(&[s(&bag)], &[]), batch, "{}: the imported bag's batch identification", record.display());
        assert_eq!(estimates(&run(&[s(&bag)], &["--replay"])), replayed, "{}: the imported bag through the nodes", record.display());
        assert_eq!(run(&[s(record)], &["--map", s(map)]), batch, "{}: identify --map", record.display());
        assert_eq!(estimates(&run(&[s(record)], &["--map", s(map), "--replay"])), replayed, "{}: identify --map --replay", record.display());
    }
}

#[test]
fn diagnose_reads_a_tdms_record_as_it_reads_the_ascii_one() {
    let f = files("diagnose");
    let (tdms, map) = &f.foreign[0];
    let a = ok(&["diagnose", s(&f.ascii), "--json", "--no-report"]);
    let b = ok(&["diagnose", s(tdms), "--map", s(map), "--json", "--no-report"]);
    let (a, b): (serde_json::Value, serde_json::Value) = (serde_json::from_slice(&a.stdout).unwrap(), serde_json::from_slice(&b.stdout).unwrap());
    assert!(a["cause"].is_string() && a["coefficients"].is_object(), "a diagnosis: {a}");
    assert_eq!(a, b, "the same record, the same diagnosis");
}

#[test]
fn broken_files_and_maps_are_refused_and_nothing_is_written() {
    let f = files("refused");
    let (tdms, map) = &f.foreign[0];
    let bytes = std::fs::read(tdms).unwrap();
    let cut = f.dir.join("cut.tdms");
    std::fs::write(&cut, &bytes[..bytes.len() - 4321]).unwrap();
    let bag = f.dir.join("cut-bag");
    let out = oilfilm(&["import", s(&cut), "--map", s(map), "-o", s(&bag)]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("cut.tdms") && err.contains("segment 6 at byte") && err.contains("truncated"), "{err}");
    assert!(!bag.exists(), "no bag");
    let left: Vec<_> = std::fs::read_dir(&f.dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("importing"))
        .collect();
    assert!(left.is_empty(), "no staging directory left: {left:?}");
    // A CSV whose rows turn ragged half-way: refused after frames were made, still nothing.
    let (csv, csv_map) = &f.foreign[2];
    let mut text = std::fs::read_to_string(csv).unwrap();
    let cut_at = text.len() / 2;
    let line_end = text[cut_at..].find('\n').unwrap() + cut_at;
    text.insert_str(line_end, ",0.5");
    let ragged = f.dir.join("ragged.csv");
    std::fs::write(&ragged, text).unwrap();
    let bag = f.dir.join("ragged-bag");
    let out = oilfilm(&["import", s(&ragged), "--map", s(csv_map), "-o", s(&bag)]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("ragged.csv") && err.contains("11 fields, the header has 10") && err.contains("nothing was written"),
        "{err}"
    );
    assert!(!bag.exists());
    // A map naming a channel the file lacks, and one naming a file channel twice: refused
    // before anything is read, the map's key and the file's channel named, no bag.
    let map_text = std::fs::read_to_string(map).unwrap();
    for (name, text, words) in [
        ("missing", map_text.replace("Forces/Exciter 2", "Forces/Exciter 3"), vec!["record.tdms", "`Forces/Exciter 3` (f2)", "no such channel"]),
        (
            "twice",
            map_text.replace("Forces/Exciter 2", "Forces/Exciter 1"),
            vec!["twice.map.toml", "channel[7].from", "`Forces/Exciter 1` is mapped twice", "channel[6] (f1)"],
        ),
    ] {
        let bad_map = f.dir.join(format!("{name}.map.toml"));
        std::fs::write(&bad_map, text).unwrap();
        let bag = f.dir.join(format!("{name}-bag"));
        let out = oilfilm(&["import", s(tdms), "--map", s(&bad_map), "-o", s(&bag)]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && words.iter().all(|w| err.contains(w)), "{name}: {err}");
        assert!(!bag.exists(), "{name}: no bag");
    }
    // An existing output is never overwritten.
    let out = oilfilm(&["import", s(tdms), "--map", s(map), "-o", s(&f.dir)]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("already exists"));
}
