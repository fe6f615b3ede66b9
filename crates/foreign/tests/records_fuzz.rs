//! A bounded, seeded fuzz loop over the foreign records and their channel maps: TDMS, MAT
//! (level 5) and CSV files mutated at the byte level, read through their map as the DAQ
//! node reads them ([`ForeignRecord::open`], then every block), and mutated maps
//! ([`ChannelMap::from_toml_str`], and a record read through what is accepted), never panic,
//! never hang, never allocate from a size or count they have not checked against the file,
//! and every refusal names the file (the record's or the map's) and says what is wrong.
//!
//! Corpus, per format: files the crate's own fixture writers make at the start of the test
//! (every TDMS layout: one or several segments, incremental object lists, interleaved,
//! big-endian; every MAT layout, compressed or not; CSV with and without a units row and a
//! time column), and the seeds in `crates/foreign/tests/data/fuzz/<format>/` (small files
//! by the same writers, each `<name>.<ext>` with its map `<name>.map.toml`, and the inputs
//! that once broke a reader: see their `.map.toml`'s first line). Each case mutates one
//! (bits flipped, cut anywhere, a 4- or 8-byte word set to a huge size or count, bytes
//! inserted, deleted or repeated: a segment or element duplicated; `tests/support/fuzz.rs`).
//! Maps are mutated as bytes and as TOML values (a number replaced by an extreme, a key
//! dropped or repeated).
//!
//! Bounded: `OILFILM_FUZZ_CASES` (default 10 000) cases per format from seed
//! `OILFILM_FUZZ_SEED`; case `k` runs from seed + `k` (printed on failure), so
//! `OILFILM_FUZZ_SEED=<seed> OILFILM_FUZZ_CASES=1` reproduces it. `OILFILM_FUZZ_CASES=1000000`
//! fuzzes longer (a benchmark-length run; nothing here is judged on time).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use oilfilm_foreign::fixtures::{self, MatLayout, TdmsChannel, TdmsLayout};
use oilfilm_foreign::map::ChannelMap;
use oilfilm_foreign::{Block, ForeignError, ForeignRecord};
use oilfilm_physics::daq::{Calibration, ChannelId};
use rand::RngExt;

use crate::fuzz;

const SEED: u64 = 0xf0_4e16_f11e;

/// Scans of the generated seeds: small, so that a case is cheap, yet several blocks.
const SCANS: usize = 60;

/// A seed: a record file and the text of its map (or, for the map loop, a map and the
/// record it maps).
struct Seed {
    name: String,
    bytes: Vec<u8>,
    map: String,
    ext: &'static str,
}

fn names() -> Vec<&'static str> {
    ChannelId::ALL.iter().map(|c| c.name()).collect()
}

const GROUPS: [&str; 10] = ["Probes", "Probes", "Probes", "Probes", "Frame", "Frame", "Forces", "Forces", "Forces", "Temperatures"];

/// A map of every rig channel in volts from `source(k)`, the speed from `speed`.
fn map_text(format: &str, timing: &str, source: impl Fn(usize) -> String, speed: &str, extra: &str) -> String {
    let mut text = format!("format = \"{format}\"\n{extra}\n[timing]\n{timing}\nmultiplexer = \"sequential\"\nchannel_interval_s = 1e-5\n");
    for (k, c) in names().iter().enumerate() {
        text.push_str(&format!("[[channel]]\nrig = \"{c}\"\n{}\nunit = \"V\"\n", source(k)));
    }
    text.push_str(speed);
    text
}

fn columns(scans: usize) -> (Vec<Vec<f64>>, Vec<f64>) {
    let columns = (0..10).map(|c| (0..scans).map(|i| ((i * (c + 1)) as f64 * 0.1).sin() * 3.0).collect()).collect();
    (columns, (0..scans).map(|i| 25.0 + 1e-3 * i as f64).collect())
}

/// The files the fixture writers make, each with its map, written under `dir`.
fn generated(dir: &Path, scans: usize) -> Vec<Seed> {
    let (columns, speed) = columns(scans);
    let read = |p: &Path| std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    let mut seeds = Vec::new();
    let tdms_map = map_text(
        "tdms",
        "sample_rate_from = \"wf_increment\"",
        |k| format!("from = \"{}/{}\"", GROUPS[k], names()[k]),
        "[speed]\nfrom = \"Tacho/speed\"\nunit = \"Hz\"\n",
        "",
    );
    let position = |k: usize| GROUPS[..k].iter().filter(|g| **g == GROUPS[k]).count();
    let tdms_by_index =
        map_text("tdms", "sample_rate_hz = 5000", |k| format!("from = \"{}\"\nindex = {}", GROUPS[k], position(k)), "[speed]\nrpm = 1500\n", "");
    let mut channels: Vec<TdmsChannel> = names()
        .iter()
        .enumerate()
        .map(|(k, name)| TdmsChannel { group: GROUPS[k], name, values: &columns[k], properties: vec![("wf_increment", 1.0 / 5000.0)] })
        .collect();
    channels.push(TdmsChannel { group: "Tacho", name: "speed", values: &speed, properties: vec![] });
    for (k, (segments, interleaved, big_endian)) in
        [(1, false, false), (4, false, false), (3, true, false), (2, true, true), (3, false, true)].into_iter().enumerate()
    {
        let path = dir.join(format!("gen{k}.tdms"));
        fixtures::tdms(&path, &channels, TdmsLayout { segments, interleaved, big_endian }).unwrap();
        let map = if k % 2 == 0 { tdms_map.clone() } else { tdms_by_index.clone() };
        seeds.push(Seed {
            name: format!("generated TDMS {segments} segments interleaved {interleaved} big-endian {big_endian}"),
            bytes: read(&path),
            map,
            ext: "tdms",
        });
    }
    let mut cols: Vec<(&str, &[f64])> = names().into_iter().zip(columns.iter().map(Vec::as_slice)).collect();
    cols.push(("speed", &speed));
    let scalars = [("fs", 5000.0)];
    for compress in [false, true] {
        for (k, layout) in [MatLayout::Variables, MatLayout::Struct("rec"), MatLayout::Matrix("data")].into_iter().enumerate() {
            let path = dir.join(format!("gen{k}-{compress}.mat"));
            fixtures::mat(&path, &cols, &scalars, layout, compress).unwrap();
            let map = match layout {
                MatLayout::Variables => {
                    map_text("mat", "sample_rate_from = \"fs\"", |k| format!("from = \"{}\"", names()[k]), "[speed]\nfrom = \"speed\"\nunit = \"Hz\"\n", "")
                }
                MatLayout::Struct(_) => map_text(
                    "mat",
                    "sample_rate_from = \"rec.fs\"",
                    |k| format!("from = \"rec.{}\"", names()[k]),
                    "[speed]\nfrom = \"rec.speed\"\nunit = \"Hz\"\n",
                    "",
                ),
                MatLayout::Matrix(_) => map_text(
                    "mat",
                    "sample_rate_hz = 5000",
                    |k| format!("from = \"data\"\nindex = {k}"),
                    "[speed]\nfrom = \"data\"\nindex = 10\nunit = \"Hz\"\n",
                    "",
                ),
            };
            seeds.push(Seed { name: format!("generated MAT {layout:?} compressed {compress}"), bytes: read(&path), map, ext: "mat" });
        }
    }
    let time: Vec<f64> = (0..scans).map(|i| 12.5 + i as f64 / 5000.0).collect();
    let mut cols: Vec<(&str, &[f64])> = vec![("time", &time)];
    cols.extend(names().into_iter().zip(columns.iter().map(Vec::as_slice)));
    cols.push(("speed", &speed));
    let mut units = vec!["s"];
    units.extend(["V"; 10]);
    units.push("Hz");
    for units_row in [false, true] {
        let path = dir.join(format!("gen-{units_row}.csv"));
        fixtures::csv(&path, &cols, units_row.then_some(units.as_slice())).unwrap();
        let map = if units_row {
            map_text(
                "csv",
                "sample_rate_from = \"time\"",
                |k| format!("from = \"{}\"", names()[k]),
                "[speed]\nfrom = \"speed\"\nunit = \"Hz\"\n",
                "[csv]\nunits_row = true",
            )
        } else {
            map_text("csv", "sample_rate_hz = 5000", |k| format!("index = {}", k + 1), "[speed]\nindex = 11\nunit = \"Hz\"\n", "")
        };
        seeds.push(Seed { name: format!("generated CSV units row {units_row}"), bytes: read(&path), map, ext: "csv" });
    }
    seeds
}

/// The seeds in `tests/data/fuzz/<format>/`: each file with the map beside it.
fn stored(ext: &'static str) -> Vec<Seed> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fuzz").join(ext);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == ext))
        .collect();
    files.sort();
    files
        .into_iter()
        .map(|p| {
            let map_path = p.with_extension("map.toml");
            let map = std::fs::read_to_string(&map_path).unwrap_or_else(|e| panic!("{}: {e}", map_path.display()));
            Seed { name: p.file_name().unwrap().to_string_lossy().into_owned(), bytes: std::fs::read(&p).unwrap(), map, ext }
        })
        .collect()
}

fn calibration() -> Calibration {
    oilfilm_physics::config::RigConfig::zhou2004().unwrap().daq.calibration()
}

/// Reads the record as the DAQ node does: open, then every block; the scans read.
fn read_all(path: &Path, map: &ChannelMap, calibration: &Calibration) -> Result<u64, ForeignError> {
    let mut rec = ForeignRecord::open(path, map, calibration)?;
    let mut block = Block::default();
    let mut scans = 0u64;
    while rec.next_block(25, &mut block)? > 0 {
        assert_eq!(block.first_scan, scans, "blocks follow each other");
        assert_eq!(block.values.len(), block.scans * rec.channels.len(), "a block holds every channel of its scans");
        assert!(block.values.iter().all(|v| v.is_finite()), "a block's values are finite");
        scans += block.scans as u64;
    }
    if let Some(n) = rec.scans {
        assert_eq!(scans, n, "the record gave the scans it said it had");
    }
    Ok(scans)
}

/// The largest single allocation a case over `len` bytes may ask for: the readers' 64 KiB
/// buffers, zlib's window and the CSV reader's buffers, and the file's size a few times.
fn allocation_bound(len: usize) -> usize {
    (4 << 20) + 16 * len
}

/// What every refusal must do: name the file it is about and say what is wrong, briefly.
/// Returns whether it names a place (a byte, segment, line, row or scan) or a channel.
fn check_error(e: &ForeignError, file: &Path, map: &Path, case: &str) -> bool {
    let text = e.to_string();
    let named = match e {
        ForeignError::Map { map: m, key, .. } => {
            assert!(!key.is_empty(), "{case}: a map error without its key: {text}");
            m == map
        }
        ForeignError::Record { file: f, .. } => f == file,
        ForeignError::Io { .. } => text.contains(&file.display().to_string()),
    };
    assert!(named || text.contains(&file.display().to_string()), "{case}: the error names neither the file nor its map: {text}");
    assert!(text.len() < 8192, "{case}: an error of {} bytes: {}", text.len(), &text[..300]);
    let words = text.rsplit(": ").next().unwrap_or("");
    assert!(words.len() >= 8, "{case}: the error does not say what is wrong: {text}");
    matches!(e, ForeignError::Record { position: Some(_), .. } | ForeignError::Record { channel: Some(_), .. } | ForeignError::Map { .. })
}

/// Counts of one loop.
#[derive(Default)]
struct Tally {
    read: u64,
    refused: u64,
    placed: u64,
    largest: usize,
    slowest: Duration,
}

/// Runs `cases` cases of one record format from `seeds`: mutate, write, read through the map.
fn record_loop(ext: &str, seeds: &[Seed], dir: &Path, first: u64, cases: u64) -> Tally {
    let calibration = calibration();
    let path = dir.join(format!("case.{ext}"));
    let map_path = dir.join("case.map.toml");
    let maps: Vec<ChannelMap> =
        seeds.iter().map(|s| ChannelMap::from_toml_str(&s.map, &map_path).unwrap_or_else(|e| panic!("{}: its map: {e}", s.name))).collect();
    let mut t = Tally::default();
    for case in 0..cases {
        let seed = first.wrapping_add(case);
        let mut rng = fuzz::rng(seed);
        let k = rng.random_range(0..seeds.len());
        let mut bytes = seeds[k].bytes.clone();
        let what = fuzz::mutate_some(&mut rng, &mut bytes);
        let label = format!("{ext} case {case} (seed {seed}): {} ({what})", seeds[k].name);
        write_fresh(&path, &bytes);
        let started = Instant::now();
        let (outcome, asked) = fuzz::largest_allocation(seed, || catch_unwind(AssertUnwindSafe(|| read_all(&path, &maps[k], &calibration))));
        t.slowest = t.slowest.max(started.elapsed());
        let result = outcome.unwrap_or_else(|_| panic!("{label}: a panic"));
        assert!(asked <= allocation_bound(bytes.len()), "{label}: an allocation of {asked} bytes for a file of {}", bytes.len());
        t.largest = t.largest.max(asked);
        match result {
            Ok(_) => t.read += 1,
            Err(e) => {
                t.refused += 1;
                t.placed += u64::from(check_error(&e, &path, &map_path, &label));
            }
        }
    }
    t
}

/// Writes `bytes` to `path` as a new file: rewriting a file in place made ext4 flush it to
/// disk on every case (its replace-by-truncate heuristic), 2 ms a case.
fn write_fresh(path: &Path, bytes: &[u8]) {
    let _ = std::fs::remove_file(path);
    std::fs::write(path, bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("oilfilm-foreign-fuzz-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn seeds_of(ext: &'static str, dir: &Path) -> Vec<Seed> {
    let mut seeds: Vec<Seed> = generated(dir, SCANS).into_iter().filter(|s| s.ext == ext).collect();
    seeds.extend(stored(ext));
    seeds
}

fn run_format(ext: &'static str, seed: u64) {
    let dir = scratch(ext);
    let seeds = seeds_of(ext, &dir);
    let (first, cases) = fuzz::settings(seed, 10_000);
    let start = Instant::now();
    let t = record_loop(ext, &seeds, &dir, first, cases);
    println!(
        "{ext} fuzz: {cases} cases from seed {first} ({} seeds) in {:.2} s (slowest {:.1} ms): {} read, {} refused ({} naming a place or channel); largest allocation {} bytes",
        seeds.len(),
        start.elapsed().as_secs_f64(),
        t.slowest.as_secs_f64() * 1e3,
        t.read,
        t.refused,
        t.placed,
        t.largest
    );
    if fuzz::mix_is_judged(cases) {
        assert!(t.read > 0 && t.refused > cases / 4, "the mutations reach both outcomes: {} read, {} refused", t.read, t.refused);
        assert!(t.placed * 10 > t.refused * 9, "most refusals say where: {} of {}", t.placed, t.refused);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn mutated_tdms_files_are_read_or_refused_naming_the_file_and_place() {
    run_format("tdms", SEED);
}

#[test]
fn mutated_mat_files_are_read_or_refused_naming_the_file_and_place() {
    run_format("mat", SEED ^ 0x3a7);
}

#[test]
fn mutated_csv_files_are_read_or_refused_naming_the_file_and_line() {
    run_format("csv", SEED ^ 0xc5f);
}

/// Values a map's number or string is replaced by.
const EXTREMES: [&str; 14] = [
    "1e308",
    "-1",
    "0",
    "nan",
    "inf",
    "-0.0",
    "5e-324",
    "18446744073709551615",
    "9223372036854775807",
    "-9223372036854775808",
    "\"\"",
    "\"x\"",
    "true",
    "[1, 2]",
];

/// A TOML-aware mutation of a map: a value made extreme, a line dropped or repeated.
fn mutate_map(rng: &mut rand_chacha::ChaCha8Rng, text: &str) -> String {
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    if lines.is_empty() {
        return text.to_string();
    }
    let k = rng.random_range(0..lines.len());
    match rng.random_range(0..3) {
        0 => {
            let valued: Vec<usize> = lines.iter().enumerate().filter(|(_, l)| l.contains(" = ")).map(|(i, _)| i).collect();
            if let Some(&i) = valued.get(rng.random_range(0..valued.len().max(1))) {
                let key = lines[i].split_once(" = ").map_or("", |(k, _)| k).to_string();
                lines[i] = format!("{key} = {}", EXTREMES[rng.random_range(0..EXTREMES.len())]);
            }
        }
        1 => {
            lines.remove(k);
        }
        _ => {
            let l = lines[k].clone();
            lines.insert(k, l);
        }
    }
    lines.join("\n") + "\n"
}

#[test]
fn mutated_maps_are_refused_naming_the_map_and_key_or_read_the_record() {
    let dir = scratch("map");
    let mut seeds = generated(&dir, 8);
    for ext in ["tdms", "mat", "csv"] {
        seeds.extend(stored(ext));
    }
    let calibration = calibration();
    let (first, cases) = fuzz::settings(SEED ^ 0x3a9, 10_000);
    let map_path = dir.join("case.map.toml");
    let start = Instant::now();
    let (mut accepted, mut refused, mut records_read, mut records_refused) = (0u64, 0u64, 0u64, 0u64);
    let mut keys = std::collections::BTreeSet::new();
    for case in 0..cases {
        let seed = first.wrapping_add(case);
        let mut rng = fuzz::rng(seed);
        let s = &seeds[rng.random_range(0..seeds.len())];
        let (text, what) = if rng.random_bool(0.7) {
            let mut text = s.map.clone();
            for _ in 0..rng.random_range(1..3) {
                text = mutate_map(&mut rng, &text);
            }
            (text, "values and lines".to_string())
        } else {
            let mut bytes = s.map.clone().into_bytes();
            let what = fuzz::mutate_some(&mut rng, &mut bytes);
            (String::from_utf8_lossy(&bytes).into_owned(), what)
        };
        let label = format!("map case {case} (seed {seed}): the map of {} ({what})", s.name);
        let record = dir.join(format!("case-{}.{}", case % 2, s.ext));
        let (outcome, asked) = fuzz::largest_allocation(seed, || {
            catch_unwind(AssertUnwindSafe(|| {
                ChannelMap::from_toml_str(&text, &map_path).map(|m| {
                    write_fresh(&record, &s.bytes);
                    read_all(&record, &m, &calibration)
                })
            }))
        });
        let result = outcome.unwrap_or_else(|_| panic!("{label}: a panic on\n{text}"));
        assert!(asked <= allocation_bound(s.bytes.len() + text.len()), "{label}: an allocation of {asked} bytes");
        match result {
            Ok(read) => {
                accepted += 1;
                match read {
                    Ok(_) => records_read += 1,
                    Err(e) => {
                        records_refused += 1;
                        check_error(&e, &record, &map_path, &label);
                    }
                }
            }
            Err(e) => {
                refused += 1;
                check_error(&e, &record, &map_path, &label);
                match &e {
                    ForeignError::Map { key, .. } => {
                        keys.insert(key.split(['[', '.', ' ']).next().unwrap_or("").to_string());
                    }
                    other => panic!("{label}: a map refused with a record error: {other}"),
                }
            }
        }
    }
    println!(
        "map fuzz: {cases} cases from seed {first} in {:.2} s: {refused} maps refused (keys {keys:?}), {accepted} accepted ({records_read} records read, {records_refused} refused)",
        start.elapsed().as_secs_f64()
    );
    if fuzz::mix_is_judged(cases) {
        assert!(refused > cases / 4 && records_read > 0 && records_refused > 0, "{refused} refused, {records_read} read, {records_refused} records refused");
        // The refusals reach the parser and the checks of each section.
        for key in ["byte", "timing", "channel", "speed"] {
            assert!(keys.contains(key), "no map refused at `{key}`: {keys:?}");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A level-5 MAT-file of one uncompressed variable: `class`, `dims`, no name, then `rest`
/// (the elements after the name) inside the variable's element.
fn mat_variable(class: u8, dims: &[u32], rest: &[u8]) -> Vec<u8> {
    let mut header = b"MATLAB 5.0 MAT-file, hostile".to_vec();
    header.resize(116, b' ');
    header.extend([0u8; 8]);
    header.extend([0x00, 0x01, b'I', b'M']);
    let mut body = matrix_body(class, dims);
    body.extend(rest);
    header.extend(14u32.to_le_bytes());
    header.extend((body.len() as u32).to_le_bytes());
    header.extend(body);
    header
}

/// Flags, dimensions and an empty name: the start of a matrix element's data.
fn matrix_body(class: u8, dims: &[u32]) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend(6u32.to_le_bytes());
    b.extend(8u32.to_le_bytes());
    b.extend([class, 0, 0, 0, 0, 0, 0, 0]);
    b.extend(5u32.to_le_bytes());
    b.extend((4 * dims.len() as u32).to_le_bytes());
    for d in dims {
        b.extend(d.to_le_bytes());
    }
    b.resize(b.len().next_multiple_of(8), 0);
    b.extend(1u32.to_le_bytes());
    b.extend(0u32.to_le_bytes());
    b
}

/// A TDMS file of one segment whose two string channels claim `bytes` of raw data each, with
/// 16 bytes of raw data.
fn tdms_string_sizes(bytes: u64) -> Vec<u8> {
    let mut meta = 2u32.to_le_bytes().to_vec();
    for name in ["/'g'/'a'", "/'g'/'b'"] {
        meta.extend((name.len() as u32).to_le_bytes());
        meta.extend(name.as_bytes());
        meta.extend(28u32.to_le_bytes());
        meta.extend(0x20u32.to_le_bytes());
        meta.extend(1u32.to_le_bytes());
        meta.extend(1u64.to_le_bytes());
        meta.extend(bytes.to_le_bytes());
        meta.extend(0u32.to_le_bytes());
    }
    let mut file = b"TDSm".to_vec();
    file.extend(14u32.to_le_bytes());
    file.extend(4713u32.to_le_bytes());
    file.extend((meta.len() as u64 + 16).to_le_bytes());
    file.extend((meta.len() as u64).to_le_bytes());
    file.extend(meta);
    file.extend([0u8; 16]);
    file
}

/// Cell arrays each holding the next, `levels` deep.
fn mat_nested_cells(levels: usize) -> Vec<u8> {
    let mut inner: Vec<u8> = Vec::new();
    for _ in 0..levels {
        let mut body = matrix_body(1, &[1, 1]);
        body.extend(14u32.to_le_bytes());
        body.extend((inner.len() as u32).to_le_bytes());
        body.extend(&inner);
        inner = body;
    }
    mat_variable(1, &[1, 1], &inner[matrix_body(1, &[1, 1]).len()..])
}

/// Not fuzz cases: the inputs that broke the readers before they checked what a file's own
/// words claim (each is in the corpus too, but the cells nested 20 000 deep, 1 MB). Before:
/// dimensions whose product overflows panicked (overflow checks) or wrapped; a struct of
/// 2^64 elements of no fields looped for ever; cells nested 20 000 deep overflowed the stack
/// (an abort, not even a panic); 2^33 cells were looped over; two TDMS string channels whose byte counts sum past 2^64
/// panicked.
#[test]
fn hostile_sizes_counts_and_nesting_are_refused_with_the_place() {
    let dir = scratch("hostile");
    let calibration = calibration();
    let mat_map = ChannelMap::from_toml_str(&stored("mat").into_iter().find(|s| s.name == "variables.mat").unwrap().map, Path::new("m.toml")).unwrap();
    let tdms_map = ChannelMap::from_toml_str(&stored("tdms").into_iter().find(|s| s.name == "one-segment.tdms").unwrap().map, Path::new("m.toml")).unwrap();
    let cases: [(&str, Vec<u8>, &ChannelMap, &str); 5] = [
        ("dims.mat", mat_variable(6, &[0x10000; 4], &[]), &mat_map, "dimensions 65536x65536x65536x65536 overflow"),
        (
            "struct.mat",
            mat_variable(2, &[u32::MAX, u32::MAX], &[4, 0, 4, 0, 32, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0]),
            &mat_map,
            "the file has `` (4294967295x4294967295 a struct)",
        ),
        ("cells.mat", mat_variable(1, &[u32::MAX, 2], &[]), &mat_map, "cells cannot fit in its 0 bytes"),
        ("nested.mat", mat_nested_cells(20_000), &mat_map, "nested deeper than 32 levels"),
        ("strings.tdms", tdms_string_sizes(u64::MAX / 2 + 1), &tdms_map, "raw data sizes overflow"),
    ];
    for (name, bytes, map, words) in cases {
        let path = dir.join(name);
        write_fresh(&path, &bytes);
        let e = read_all(&path, map, &calibration).expect_err(name).to_string();
        assert!(e.contains(name) && e.contains(words), "{name}: {e}");
        let stored =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fuzz").join(name[name.len() - 4..].trim_start_matches('.')).join(format!("hostile-{name}"));
        if bytes.len() < 4096 {
            assert_eq!(std::fs::read(&stored).unwrap_or_else(|e| panic!("{}: {e}", stored.display())), bytes, "{name}: the corpus holds it");
        }
    }
    // A damaged name read whole into a message made it 9.5 kB: quoted shortened now.
    let s = stored("mat").into_iter().find(|s| s.name == "regression-long-name.mat").unwrap();
    let path = dir.join(&s.name);
    write_fresh(&path, &s.bytes);
    let map = ChannelMap::from_toml_str(&s.map, Path::new("m.toml")).unwrap();
    let e = read_all(&path, &map, &calibration).expect_err("a damaged name").to_string();
    assert!(e.contains("byte 128") && e.contains("... (") && e.len() < 400, "{} bytes: {e}", e.len());
    let _ = std::fs::remove_dir_all(&dir);
}
