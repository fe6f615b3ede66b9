//! A bounded, seeded fuzz loop over mutated bags: the reader ([`Bag::open`],
//! [`Bag::messages`], [`oilfilm_bag::BagMessage::decode_ours`]) and [`recover`] never panic,
//! and every error names the file (or directory) it is about and says what is wrong.
//!
//! Mutations of a sound bag (zstd, lz4 or uncompressed chunks, one file or split): bytes
//! flipped, the file truncated anywhere, top-level records duplicated, dropped or swapped,
//! metadata.yaml missing, cut, flipped or edited (version, storage, file list), the header's
//! profile rewritten, a type no reader here knows, message payloads that are not valid CDR.
//!
//! Corpus: the seed bags in `crates/bag/tests/data/fuzz/` (`seed_*/`: a real graph run's
//! first messages, uncompressed in one file, lz4 split in three, and zstd with every topic
//! and `/parameter_events`; written by `examples/write_fuzz_seeds.rs`), and six bags of DAQ
//! frames and status written at the start by today's writer (each compression, one file or
//! split), so the loop also follows the writer as it changes. Each case copies one (a bag's
//! writer syncs its files to disk, which cost more than the rest of a case: the loop once
//! wrote a bag a case and ran 400 cases in 17 s), mutates the copy and reads it; one case in
//! ten is also recovered and read again, and one in forty is a fresh bag that is not ours or
//! not CDR.
//!
//! Bounded: `CASES` (10 000) cases; each case's seed is `SEED + case`, printed on failure, so
//! `OILFILM_FUZZ_SEED=<seed> OILFILM_FUZZ_CASES=1` reproduces it. `OILFILM_FUZZ_CASES=1000000`
//! fuzzes longer (a benchmark-length run; nothing here is judged on time).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

use oilfilm_bag::{recover, Bag, BagWriter, Compression, QosProfile, TopicSpec, WriterOptions};
use oilfilm_msgs::{DaqFrame, Header, RigStatus, Time};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SEED: u64 = 0x0171_f11e_ba65;
const CASES: u64 = 10_000;

/// The cases' scratch directory: in memory (`/dev/shm`) where there is one, as a case's
/// files are written, read and removed within a millisecond and the bag writer and `recover`
/// sync theirs to disk (on disk the loop took five times as long); else the temp dir.
fn tmp_root(test: &str) -> PathBuf {
    let name = format!("oilfilm-bag-fuzz-{}-{test}", std::process::id());
    for base in [PathBuf::from("/dev/shm"), std::env::temp_dir()] {
        let d = base.join(&name);
        let _ = std::fs::remove_dir_all(&d);
        if base.is_dir() && std::fs::create_dir_all(&d).is_ok() {
            return d;
        }
    }
    panic!("no scratch directory for {name}");
}

fn header(t_ns: u64) -> Header {
    Header { stamp: Time { sec: (t_ns / 1_000_000_000) as i32, nanosec: (t_ns % 1_000_000_000) as u32 }, frame_id: "oilfilm_bearing".into() }
}

fn frame(i: u64, t_ns: u64) -> DaqFrame {
    let scans = 50u32;
    DaqFrame {
        header: header(t_ns),
        sequence: i,
        first_scan: i * scans as u64,
        sample_rate_hz: 5000.0,
        units: DaqFrame::UNITS_SI,
        channel_names: ["probe_a_x", "probe_a_y", "probe_b_x", "probe_b_y", "frame_x", "frame_y", "f1", "f2", "f3", "temperature"].map(String::from).to_vec(),
        channel_units: ["m", "m", "m", "m", "m", "m", "N", "N", "N", "degC"].map(String::from).to_vec(),
        channel_offsets_s: (0..10).map(|p| p as f64 * 1e-5).collect(),
        scan_count: scans,
        values: (0..scans as u64 * 10).map(|k| ((i * 1000 + k) as f64 * 0.37).sin()).collect(),
        rig: "zhou2004".into(),
        ..Default::default()
    }
}

/// A sound bag of DAQ frames and rig status in small chunks (so there are many), written
/// with `compression`, split every `split_ns` of log time if given.
fn sound_bag(dir: &Path, compression: Compression, split_ns: Option<u64>) {
    let options = WriterOptions { compression, chunk_size: 6 << 10, split_duration_ns: split_ns, ..WriterOptions::default() };
    let mut w = BagWriter::create(dir, options).unwrap();
    let qos = vec![QosProfile::keep_last(200, true, false)];
    let frames = w.add_topic(TopicSpec::ours("/oilfilm/daq/frames", "oilfilm_msgs/msg/DaqFrame", qos.clone()).unwrap()).unwrap();
    let status = w.add_topic(TopicSpec::ours("/oilfilm/rig/status", "oilfilm_msgs/msg/RigStatus", qos).unwrap()).unwrap();
    let t0 = 1_700_000_000_000_000_000u64;
    for i in 0..24u64 {
        let t = t0 + i * 10_000_000;
        w.write_message(frames, t, &frame(i, t)).unwrap();
        let s = RigStatus {
            header: header(t),
            speed_rad_s: 157.08,
            static_load_n: 5000.0,
            bearing_temperature_degc: 29.0,
            state: RigStatus::STATE_EXCITING,
            message: String::new(),
            frames_dropped: i,
        };
        w.write_message(status, t, &s).unwrap();
    }
    w.close().unwrap();
}

/// A bag holding a type that is not ours, and one whose payloads are not valid CDR of their
/// (our) type.
fn odd_bag(dir: &Path, rng: &mut ChaCha8Rng) -> &'static str {
    let mut w = BagWriter::create(dir, WriterOptions::default()).unwrap();
    let qos = vec![QosProfile::keep_last(10, true, false)];
    if rng.random_bool(0.5) {
        let spec =
            TopicSpec { name: "/point".into(), type_name: "geometry_msgs/msg/Point".into(), schema_text: "float64 x\nfloat64 y\nfloat64 z\n".into(), qos };
        let id = w.add_topic(spec).unwrap();
        let mut cdr = vec![0, 1, 0, 0];
        cdr.extend_from_slice(&[0u8; 24]);
        w.write(id, 1, &cdr).unwrap();
        w.close().unwrap();
        "a type that is not ours"
    } else {
        let id = w.add_topic(TopicSpec::ours("/oilfilm/daq/frames", "oilfilm_msgs/msg/DaqFrame", qos).unwrap()).unwrap();
        let mut cdr = oilfilm_msgs::encode(&frame(0, 1));
        match rng.random_range(0..3) {
            0 => cdr.truncate(rng.random_range(0..cdr.len())),
            1 => {
                for _ in 0..rng.random_range(1..8) {
                    let i = rng.random_range(0..cdr.len());
                    cdr[i] = rng.random();
                }
            }
            _ => cdr = (0..rng.random_range(0..64)).map(|_| rng.random()).collect(),
        }
        w.write(id, 1, &cdr).unwrap();
        w.close().unwrap();
        "payloads that are not valid CDR"
    }
}

/// Top-level records of an MCAP file: (start, end) byte ranges after the 8-byte magic, up
/// to the end magic (or as far as the lengths make sense).
fn records(bytes: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut at = 8;
    while at + 9 <= bytes.len().saturating_sub(8) {
        let mut len = [0u8; 8];
        len.copy_from_slice(&bytes[at + 1..at + 9]);
        let Some(end) = usize::try_from(u64::from_le_bytes(len)).ok().and_then(|l| l.checked_add(at + 9)).filter(|&e| e <= bytes.len()) else { break };
        out.push((at, end));
        at = end;
    }
    out
}

/// The header record rewritten with another profile.
fn with_profile(bytes: &[u8], profile: &str) -> Vec<u8> {
    let recs = records(bytes);
    let (start, end) = recs[0];
    assert_eq!(bytes[start], 0x01, "the first record is the header");
    let body = &bytes[start + 9..end];
    let plen = u32::from_le_bytes(body[..4].try_into().unwrap()) as usize;
    let library = &body[4 + plen..];
    let mut new_body = (profile.len() as u32).to_le_bytes().to_vec();
    new_body.extend_from_slice(profile.as_bytes());
    new_body.extend_from_slice(library);
    let mut out = bytes[..start].to_vec();
    out.push(0x01);
    out.extend_from_slice(&(new_body.len() as u64).to_le_bytes());
    out.extend_from_slice(&new_body);
    out.extend_from_slice(&bytes[end..]);
    out
}

/// Mutates the bag in `dir` (one change chosen by `rng`); returns what it did.
fn mutate(dir: &Path, rng: &mut ChaCha8Rng) -> String {
    let meta = dir.join("metadata.yaml");
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|x| x == "mcap")).collect();
    files.sort();
    let file = files[rng.random_range(0..files.len())].clone();
    let mut bytes = std::fs::read(&file).unwrap();
    let name = file.file_name().unwrap().to_string_lossy().into_owned();
    let what = match rng.random_range(0..12) {
        0 | 1 => {
            let n = rng.random_range(1..9);
            for _ in 0..n {
                let i = rng.random_range(0..bytes.len());
                bytes[i] ^= rng.random_range(1..=255u8);
            }
            format!("{n} bytes of {name} flipped")
        }
        2 | 3 => {
            let at = rng.random_range(0..bytes.len());
            bytes.truncate(at);
            format!("{name} cut at byte {at}")
        }
        4 => {
            let recs = records(&bytes);
            let (s, e) = recs[rng.random_range(0..recs.len())];
            let to = recs[rng.random_range(0..recs.len())].0;
            let copy = bytes[s..e].to_vec();
            bytes.splice(to..to, copy);
            format!("{name}: record at {s} duplicated at {to}")
        }
        5 => {
            let recs = records(&bytes);
            let (s, e) = recs[rng.random_range(0..recs.len())];
            bytes.drain(s..e);
            format!("{name}: record at {s} dropped")
        }
        6 => {
            let recs = records(&bytes);
            let a = rng.random_range(0..recs.len());
            let b = rng.random_range(0..recs.len());
            let (a, b) = (recs[a.min(b)], recs[a.max(b)]);
            if a != b {
                let mut out = bytes[..a.0].to_vec();
                out.extend_from_slice(&bytes[b.0..b.1]);
                out.extend_from_slice(&bytes[a.1..b.0]);
                out.extend_from_slice(&bytes[a.0..a.1]);
                out.extend_from_slice(&bytes[b.1..]);
                bytes = out;
            }
            format!("{name}: records at {} and {} swapped", a.0, b.0)
        }
        7 => {
            let p = ["ros1", "", "ros2 ", "x"][rng.random_range(0..4)];
            bytes = with_profile(&bytes, p);
            format!("{name}: profile `{p}`")
        }
        8 => {
            std::fs::remove_file(&meta).unwrap();
            "metadata.yaml missing".to_string()
        }
        9 => {
            let mut m = std::fs::read(&meta).unwrap();
            let at = rng.random_range(0..m.len());
            if rng.random_bool(0.5) {
                m.truncate(at);
            } else {
                m[at] ^= rng.random_range(1..=255u8);
            }
            write_fresh(&meta, &m);
            format!("metadata.yaml cut or flipped at byte {at}")
        }
        10 => {
            let m = std::fs::read_to_string(&meta).unwrap();
            let edits: [(&str, &str); 6] = [
                ("version: 9", "version: 12"),
                ("storage_identifier: mcap", "storage_identifier: sqlite3"),
                (&name, "missing_9.mcap"),
                (&name, "../../etc/passwd"),
                ("compression_mode: ''", "compression_mode: FILE"),
                ("rosbag2_bagfile_information", "bagfile"),
            ];
            let (from, to) = edits[rng.random_range(0..edits.len())];
            write_fresh(&meta, m.replacen(from, to, 1).as_bytes());
            format!("metadata.yaml: `{from}` -> `{to}`")
        }
        _ => {
            // Several mutations at once.
            let a = mutate_bytes_only(&mut bytes, rng);
            let b = mutate_bytes_only(&mut bytes, rng);
            format!("{name}: {a}, then {b}")
        }
    };
    write_fresh(&file, &bytes);
    what
}

/// Writes `bytes` as a new file: rewriting one in place made ext4 flush it to disk (its
/// replace-by-truncate heuristic), milliseconds a case.
fn write_fresh(path: &Path, bytes: &[u8]) {
    let _ = std::fs::remove_file(path);
    std::fs::write(path, bytes).unwrap();
}

/// The committed seed bags (`tests/data/fuzz/seed_*/`), sorted by name.
fn seeds() -> Vec<(String, PathBuf)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fuzz");
    let mut out: Vec<(String, PathBuf)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_dir() && p.file_name().is_some_and(|n| n.to_string_lossy().starts_with("seed_")))
        .map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), p))
        .collect();
    out.sort();
    out
}

/// The sound bags the cases start from: the committed seeds, and bags written once here (a
/// bag's writer syncs its files to disk, milliseconds a bag): each compression, in one file
/// or split.
fn templates(root: &Path) -> Vec<(String, PathBuf)> {
    let mut out = seeds();
    for compression in [Compression::Zstd, Compression::Lz4, Compression::None] {
        for split in [None, Some(80_000_000)] {
            let name = format!("{compression:?}{}", if split.is_some() { " split" } else { "" });
            let dir = root.join(format!("template_{compression:?}_{}", split.is_some()));
            sound_bag(&dir, compression, split);
            out.push((name, dir));
        }
    }
    out
}

/// A copy of a template bag in `dir`, its files renamed to `dir`'s name as a writer names them.
fn copy_bag(from: &Path, dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    let (old, new) = (from.file_name().unwrap().to_string_lossy().into_owned(), dir.file_name().unwrap().to_string_lossy().into_owned());
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().replace(&old, &new);
        if name == "metadata.yaml" {
            std::fs::write(dir.join(name), std::fs::read_to_string(&p).unwrap().replace(&old, &new)).unwrap();
        } else {
            std::fs::copy(&p, dir.join(name)).unwrap();
        }
    }
}

fn mutate_bytes_only(bytes: &mut Vec<u8>, rng: &mut ChaCha8Rng) -> String {
    if bytes.is_empty() {
        return "nothing (empty)".into();
    }
    if rng.random_bool(0.5) {
        let i = rng.random_range(0..bytes.len());
        bytes[i] ^= rng.random_range(1..=255u8);
        format!("byte {i} flipped")
    } else {
        let at = rng.random_range(0..bytes.len());
        bytes.truncate(at);
        format!("cut at {at}")
    }
}

/// The error names a path inside (or equal to) the bag directory and says more than that.
fn check_error(e: &oilfilm_bag::BagError, dir: &Path, case: &str) {
    let text = e.to_string();
    let dir_text = dir.display().to_string();
    let Some(at) = text.find(&dir_text) else {
        panic!("{case}: the error does not name the bag or its file: {text}");
    };
    let rest = &text[at + dir_text.len()..];
    let reason = rest.split_once(": ").map(|(_, r)| r).unwrap_or("");
    assert!(reason.trim().len() >= 8, "{case}: the error does not say what is wrong: {text}");
}

/// Reads the bag as `oilfilm identify` does: open, every message, decode each.
fn read_all(dir: &Path) -> oilfilm_bag::Result<usize> {
    let bag = Bag::open(dir)?;
    // The summary-driven reader first (it trusts the summary where it can, so it may accept
    // a file the full reader refuses, but it must not panic and its errors name the file).
    if let Err(e) = bag.read_topics(&|_, _| true, &|m| m.decode::<oilfilm_msgs::DaqFrame>().map(|_| ()).or_else(|_| Ok(())), 2, |it| it.count()) {
        check_error(&e, dir, "read_topics");
    }
    let msgs = bag.messages()?;
    for m in &msgs {
        m.decode_ours()?;
    }
    Ok(msgs.len())
}

/// Runs one case from the sound bags `templates`; returns whether reading the mutated bag
/// failed (with a good error). A bag that is not ours or not CDR is written afresh one case
/// in forty, and a case is recovered one case in ten: each syncs a bag to disk, which costs
/// more than all the rest of a case.
fn run_case(root: &Path, templates: &[(String, PathBuf)], seed: u64) -> bool {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let dir = root.join(format!("case_{seed}"));
    let what = if rng.random_range(0..40) == 0 {
        odd_bag(&dir, &mut rng).to_string()
    } else {
        let (name, template) = &templates[rng.random_range(0..templates.len())];
        copy_bag(template, &dir);
        format!("{name}: {}", mutate(&dir, &mut rng))
    };
    let recovered = rng.random_range(0..10) == 0;
    let case = format!("seed {seed} ({what})");
    let refused = match catch_unwind(AssertUnwindSafe(|| read_all(&dir))) {
        Err(_) => panic!("{case}: reading panicked"),
        Ok(Err(e)) => {
            check_error(&e, &dir, &case);
            true
        }
        Ok(Ok(_)) => false,
    };
    match catch_unwind(AssertUnwindSafe(|| if recovered { recover(&dir).map(Some) } else { Ok(None) })) {
        Err(_) => panic!("{case}: recover panicked"),
        Ok(Err(e)) => check_error(&e, &dir, &case),
        Ok(Ok(None)) => {}
        Ok(Ok(Some(_))) => match catch_unwind(AssertUnwindSafe(|| read_all(&dir))) {
            Err(_) => panic!("{case}: reading the recovered bag panicked"),
            Ok(Err(e)) => check_error(&e, &dir, &format!("{case}, recovered")),
            Ok(Ok(_)) => {}
        },
    }
    let _ = std::fs::remove_dir_all(&dir);
    refused
}

#[test]
fn mutated_bags_never_panic_and_errors_name_the_file() {
    let env = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<u64>().ok());
    let first = env("OILFILM_FUZZ_SEED").unwrap_or(SEED);
    let cases = env("OILFILM_FUZZ_CASES").unwrap_or(CASES);
    let root = tmp_root("loop");
    let templates = templates(&root);
    let start = std::time::Instant::now();
    // Quiet the default hook while panics are caught; the case is named in the failure.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let result = catch_unwind(AssertUnwindSafe(|| (first..first + cases).filter(|&seed| run_case(&root, &templates, seed)).count() as u64));
    std::panic::set_hook(hook);
    let _ = std::fs::remove_dir_all(&root);
    match result {
        Err(p) => {
            let msg = p.downcast_ref::<String>().cloned().or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string())).unwrap_or_default();
            panic!("{msg}");
        }
        Ok(refused) => {
            eprintln!(
                "bag fuzz: {cases} cases from seed {first} in {:.2} s: {refused} refused with a named error, {} read",
                start.elapsed().as_secs_f64(),
                cases - refused
            );
            // Most mutations must bite (a flip in an index or padding may not).
            assert!(cases < 20 || refused * 2 > cases, "only {refused} of {cases} mutated bags were refused");
        }
    }
}

/// The compression of each chunk of an MCAP file ("" for none).
fn chunk_compressions(bytes: &[u8]) -> Vec<String> {
    records(bytes)
        .into_iter()
        .filter(|&(s, _)| bytes[s] == 0x06)
        .map(|(s, e)| {
            // A chunk's body: start and end time, uncompressed size (u64 each), CRC (u32),
            // then the compression as a u32-prefixed string.
            let body = &bytes[s + 9..e];
            let len = u32::from_le_bytes(body[28..32].try_into().unwrap()) as usize;
            String::from_utf8(body[32..32 + len].to_vec()).unwrap()
        })
        .collect()
}

/// The committed seeds are sound bags (each reads whole, as many messages as its
/// metadata.yaml counts, every one decoded), well under 100 KB each, and between them hold
/// what the loop's description says: a split bag, chunks uncompressed, lz4 and zstd, and
/// every type the graph records.
#[test]
fn the_seed_bags_are_sound_small_and_hold_what_the_corpus_claims() {
    use oilfilm_bag::OilfilmMessage;
    let seeds = seeds();
    assert_eq!(seeds.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>(), ["seed_plain", "seed_split", "seed_zstd_every_type"]);
    let (mut compressions, mut kinds, mut most_files) = (std::collections::BTreeSet::new(), std::collections::BTreeSet::new(), 0);
    for (name, dir) in &seeds {
        let bag = Bag::open(dir).unwrap_or_else(|e| panic!("{name}: {e}"));
        let msgs = bag.messages().unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(!msgs.is_empty(), "{name}: no messages");
        assert_eq!(msgs.len() as u64, bag.info().message_count, "{name}: every message metadata.yaml counts");
        for m in &msgs {
            kinds.insert(match m.decode_ours().unwrap_or_else(|e| panic!("{name}: {e}")) {
                OilfilmMessage::ExciterCommand(_) => "ExciterCommand",
                OilfilmMessage::DaqFrame(_) => "DaqFrame",
                OilfilmMessage::ConditionedFrame(_) => "ConditionedFrame",
                OilfilmMessage::CoefficientEstimate(_) => "CoefficientEstimate",
                OilfilmMessage::RigStatus(_) => "RigStatus",
                OilfilmMessage::ParameterEvent(_) => "ParameterEvent",
            });
        }
        let files = bag.files();
        most_files = most_files.max(files.len());
        for f in &files {
            let bytes = std::fs::read(f).unwrap();
            assert!(bytes.len() < 100_000, "{}: {} bytes", f.display(), bytes.len());
            compressions.extend(chunk_compressions(&bytes));
        }
    }
    assert!(most_files >= 3, "a split seed: at most {most_files} files in one bag");
    assert_eq!(compressions.into_iter().collect::<Vec<_>>(), ["", "lz4", "zstd"], "chunks of each compression");
    assert_eq!(kinds.len(), 6, "every type the graph records: {kinds:?}");
}

#[test]
fn the_fuzzer_reaches_every_kind_of_error() {
    // Not a fuzz case: the named mutations each give the error they should, so the loop
    // above is exercising the paths it claims to.
    let root = tmp_root("kinds");
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let fresh = |name: &str| {
        let d = root.join(name);
        sound_bag(&d, Compression::Zstd, None);
        let f = d.join(format!("{name}_0.mcap"));
        (d, f)
    };
    let (d, f) = fresh("profile");
    std::fs::write(&f, with_profile(&std::fs::read(&f).unwrap(), "ros1")).unwrap();
    let e = read_all(&d).unwrap_err().to_string();
    assert!(e.contains("profile_0.mcap") && e.contains("`ros1`, not `ros2`"), "{e}");

    let (d, _) = fresh("nometa");
    std::fs::remove_file(d.join("metadata.yaml")).unwrap();
    let e = read_all(&d).unwrap_err().to_string();
    assert!(e.contains("nometa/metadata.yaml") && e.contains("recover"), "{e}");

    // Cut inside a chunk, and a byte flipped inside a chunk's compressed data.
    let (d, f) = fresh("cut");
    let bytes = std::fs::read(&f).unwrap();
    let recs = records(&bytes);
    let chunks: Vec<_> = recs.iter().filter(|(s, _)| bytes[*s] == 0x06).collect();
    assert!(chunks.len() >= 3, "{} chunks", chunks.len());
    let (s, e) = *chunks[1];
    std::fs::write(&f, &bytes[..(s + e) / 2]).unwrap();
    let e1 = read_all(&d).unwrap_err().to_string();
    assert!(e1.contains("cut_0.mcap") && e1.contains("ends early") && e1.contains("after 1 complete chunks"), "{e1}");
    let (d, f) = fresh("flip");
    let mut bad = bytes.clone();
    bad[e - 20] ^= 0xff;
    std::fs::write(&f, &bad).unwrap();
    let e2 = read_all(&d).unwrap_err().to_string();
    assert!(e2.contains("flip_0.mcap") && (e2.contains("CRC") || e2.contains("zstd")), "{e2}");
    // Reordered: the second chunk before the first is read (MCAP allows any chunk order)
    // and gives the same messages, sorted by log time.
    let (d, f) = fresh("swap");
    let (a, b) = (*chunks[0], *chunks[1]);
    let mut out = bytes[..a.0].to_vec();
    out.extend_from_slice(&bytes[b.0..b.1]);
    out.extend_from_slice(&bytes[a.0..a.1]);
    out.extend_from_slice(&bytes[b.1..]);
    std::fs::write(&f, &out).unwrap();
    let n = read_all(&d);
    assert!(matches!(n, Ok(48)) || n.as_ref().is_err_and(|e| e.to_string().contains("swap_0.mcap")), "{n:?}");

    let d = root.join("foreign");
    while odd_bag(&d, &mut rng) != "a type that is not ours" {
        std::fs::remove_dir_all(&d).unwrap();
    }
    let e = read_all(&d).unwrap_err().to_string();
    assert!(e.contains("foreign_0.mcap") && e.contains("geometry_msgs/msg/Point is not an oilfilm_msgs type"), "{e}");

    let d = root.join("badcdr");
    while odd_bag(&d, &mut rng) != "payloads that are not valid CDR" {
        std::fs::remove_dir_all(&d).unwrap();
    }
    match read_all(&d) {
        Err(e) => {
            let e = e.to_string();
            assert!(e.contains("badcdr_0.mcap") && e.contains("/oilfilm/daq/frames"), "{e}");
        }
        // A few flipped bytes inside a float are still a valid frame.
        Ok(n) => assert_eq!(n, 1),
    }
    let _ = std::fs::remove_dir_all(&root);
}
