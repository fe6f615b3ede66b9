//! A bounded, seeded fuzz loop over the DAQ node's line stream (the TCP source and the ASCII
//! replay: [`read_lines`] feeding [`ReplayCore`]): mutated and garbage streams never panic,
//! memory stays bounded (a line longer than [`MAX_LINE_BYTES`] is cut there and refused,
//! never buffered whole), and every report names the stream, the line and the column.
//!
//! Corpus: short records written with the ASCII writer (SI and volts, several blocks) and
//! the streams in `crates/graph/tests/data/fuzz/lines/` (CR LF line ends, comments and blank
//! lines among the rows, a skipped scan, a garbage line, a header that is cut). Each case
//! mutates one (bytes: `tests/support/fuzz.rs`; lines: one repeated, dropped or swapped,
//! a field doubled; one case in forty a run of 70 000 bytes without a line end) and reads it
//! through a buffer of random size (so lines arrive in pieces, as from a socket).
//!
//! Bounded: `OILFILM_FUZZ_CASES` (default 10 000) cases from seed `OILFILM_FUZZ_SEED`; case
//! `k` runs from seed + `k` (printed on failure), so `OILFILM_FUZZ_SEED=<seed>
//! OILFILM_FUZZ_CASES=1` reproduces it. `OILFILM_FUZZ_CASES=1000000` fuzzes longer (a
//! benchmark-length run; nothing here is judged on time).

use std::io::{BufReader, Read};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::time::Instant;

use oilfilm_graph::daq::DaqParams;
use oilfilm_graph::error::NodeError;
use oilfilm_graph::lines::{read_lines, LinesEnd, MAX_LINE_BYTES};
use oilfilm_graph::replay::{Produced, ReplayCore};
use oilfilm_identification::ascii::{Header, Writer};
use oilfilm_physics::config::RigConfig;
use rand::RngExt;

use crate::fuzz;

const SEED: u64 = 0x11e5_f11e;
const SOURCE: &str = "tcp://daq:5000#1";

fn params() -> DaqParams {
    DaqParams { source: "tcp".into(), address: "daq:5000".into(), block_scans: 16, ..DaqParams::default() }
}

/// A record of `scans` rows written with the ASCII writer.
fn written(scans: u64, si: bool) -> Vec<u8> {
    let header = Header::new_si("zhou2004", 5000.0, 1e-5);
    let mut header = header;
    if !si {
        header.units = oilfilm_identification::ascii::Units::Volts;
    }
    let mut w = Writer::new(Vec::new(), &header).expect("header");
    for n in 0..scans {
        let s = (n as f64 * 0.3).sin();
        let row = if si {
            [5e-5 + 1e-6 * s, -8e-5, 5e-5, -8e-5, 0.0, 0.0, 100.0 * s, 0.0, 5600.0, 29.0]
        } else {
            [0.5 * s, -0.4, 0.3, 0.2, 0.1, 0.0, 1.0 * s, 0.0, 2.8, 1.45]
        };
        w.push(1000 + n, &row).expect("row");
    }
    w.finish().expect("finish")
}

fn corpus() -> Vec<(String, Vec<u8>)> {
    let mut seeds = vec![("written SI".to_string(), written(40, true)), ("written volts".to_string(), written(20, false))];
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fuzz/lines");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())).map(|e| e.unwrap().path()).collect();
    files.sort();
    seeds.extend(files.into_iter().map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap())));
    seeds
}

/// A line-level mutation: a line repeated, dropped or swapped with another, a field
/// doubled, or a long run without a line end.
fn mutate_lines(rng: &mut rand_chacha::ChaCha8Rng, bytes: &mut Vec<u8>) -> String {
    let mut lines: Vec<Vec<u8>> = bytes.split_inclusive(|&b| b == b'\n').map(<[u8]>::to_vec).collect();
    if lines.is_empty() {
        return "nothing (empty)".into();
    }
    let k = rng.random_range(0..lines.len());
    let what = match rng.random_range(0..4) {
        0 => {
            let l = lines[k].clone();
            lines.insert(k, l);
            format!("line {} repeated", k + 1)
        }
        1 => {
            lines.remove(k);
            format!("line {} dropped", k + 1)
        }
        2 => {
            let j = rng.random_range(0..lines.len());
            lines.swap(k, j);
            format!("lines {} and {} swapped", k + 1, j + 1)
        }
        _ => {
            let at = lines[k].iter().position(|&b| b == b' ').unwrap_or(0);
            let field: Vec<u8> = lines[k][..at].to_vec();
            lines[k].splice(at..at, [b" ".as_slice(), &field].concat());
            format!("the first field of line {} doubled", k + 1)
        }
    };
    *bytes = lines.concat();
    what
}

/// What a stream gave.
#[derive(Default)]
struct Outcome {
    lines: usize,
    frames: usize,
    reports: Vec<NodeError>,
    fatal: Option<NodeError>,
    longest_line: usize,
    cut_lines: usize,
}

/// Reads `bytes` as the TCP source reads a connection, through a buffer of `capacity`.
fn stream(rig: &RigConfig, bytes: impl Read, capacity: usize) -> Outcome {
    let mut core = ReplayCore::new(rig, &params(), "tcp stream", SOURCE).expect("params");
    let mut out = Outcome::default();
    let take = |o: Produced, out: &mut Outcome| {
        for (frame, status) in &o.frames {
            assert_eq!(frame.values.len(), frame.scan_count as usize * frame.channel_names.len(), "a frame holds its scans");
            assert!(frame.scan_count >= 1 && frame.scan_count <= 16, "a frame of {} scans", frame.scan_count);
            assert!(!status.message.is_empty());
        }
        out.frames += o.frames.len();
        out.reports.extend(o.bad_row);
    };
    let mut last = 0;
    let end = read_lines(BufReader::with_capacity(capacity, bytes), &|| false, &mut |number, line, cut| {
        last = number;
        out.lines = number;
        out.longest_line = out.longest_line.max(line.len());
        out.cut_lines += usize::from(cut);
        let o = if cut { core.push_cut_line(number)? } else { core.push_line(number, line)? };
        take(o, &mut out);
        Ok(())
    });
    match end {
        Err(e) => out.fatal = Some(e),
        Ok(LinesEnd::Eof { unterminated }) => {
            // As the TCP source does: a line cut by the drop is dropped; the scans so far are
            // published.
            if let Some((n, _)) = unterminated {
                out.lines = n;
            }
            match core.end_of_stream(last.max(1)) {
                Ok(o) => take(o, &mut out),
                Err(e) => out.fatal = Some(e),
            }
        }
        Ok(other) => panic!("a stream in memory ended {other:?}"),
    }
    out
}

/// A report or a fatal error must name the stream, a line of it and a column.
fn check(e: &NodeError, lines: usize, case: &str) {
    let NodeError::BadRecord { source_name, line, column, reason } = e else { panic!("{case}: not a BadRecord: {e}") };
    assert_eq!(source_name, SOURCE, "{case}: {e}");
    assert!(*line >= 1 && *line <= lines.max(1), "{case}: line {line} of {lines}: {e}");
    assert!(*column <= MAX_LINE_BYTES + 1, "{case}: column {column}: {e}");
    assert!(reason.len() >= 8 && reason.len() < 600, "{case}: {e}");
    assert!(e.to_string().starts_with(&format!("{SOURCE}:{line}:{column}: ")), "{case}: {e}");
}

#[test]
fn mutated_streams_never_panic_stay_bounded_and_reports_name_line_and_column() {
    let rig = RigConfig::zhou2004().unwrap();
    let corpus = corpus();
    let (first, cases) = fuzz::settings(SEED, 10_000);
    let start = Instant::now();
    let (mut clean, mut reported, mut fatal, mut frames, mut cut, mut largest) = (0u64, 0u64, 0u64, 0usize, 0usize, 0usize);
    for case in 0..cases {
        let seed = first.wrapping_add(case);
        let mut rng = fuzz::rng(seed);
        let (name, base) = &corpus[rng.random_range(0..corpus.len())];
        let mut bytes = base.clone();
        let mut what = Vec::new();
        for _ in 0..rng.random_range(1..4) {
            what.push(if rng.random_bool(0.5) { mutate_lines(&mut rng, &mut bytes) } else { fuzz::mutate_bytes(&mut rng, &mut bytes) });
        }
        if rng.random_range(0..40) == 0 {
            let at = rng.random_range(0..=bytes.len());
            let fill = [b'1', b' ', b'x'][rng.random_range(0..3)];
            bytes.splice(at..at, std::iter::repeat_n(fill, 70_000));
            what.push(format!("70 000 x {:?} inserted at {at}", fill as char));
        }
        let label = format!("case {case} (seed {seed}): {name} ({})", what.join(", then "));
        let capacity = rng.random_range(1..4096);
        let (outcome, asked) = fuzz::largest_allocation(seed, || catch_unwind(AssertUnwindSafe(|| stream(&rig, bytes.as_slice(), capacity))));
        let out = outcome.unwrap_or_else(|_| panic!("{label}: a panic"));
        // The line buffer, its text (U+FFFD triples a bad byte) and a frame's values.
        assert!(asked <= 4 * MAX_LINE_BYTES + 65_536, "{label}: an allocation of {asked} bytes");
        assert!(out.longest_line <= 3 * MAX_LINE_BYTES, "{label}: a line of {} bytes handed on", out.longest_line);
        largest = largest.max(asked);
        for e in out.reports.iter().chain(&out.fatal) {
            check(e, out.lines, &label);
        }
        frames += out.frames;
        cut += out.cut_lines;
        match (&out.fatal, out.reports.is_empty()) {
            (Some(_), _) => fatal += 1,
            (None, false) => reported += 1,
            (None, true) => clean += 1,
        }
    }
    println!(
        "line stream fuzz: {cases} cases from seed {first} ({} seeds) in {:.2} s: {clean} clean, {reported} with bad rows reported, {fatal} refused whole; {frames} frames, {cut} over-long lines cut; largest allocation {largest} bytes",
        corpus.len(),
        start.elapsed().as_secs_f64()
    );
    if fuzz::mix_is_judged(cases) {
        assert!(
            clean > 0 && reported > cases / 10 && fatal > cases / 10,
            "the mutations reach every outcome: {clean} clean, {reported} reported, {fatal} fatal"
        );
        assert!(cut > 0, "no over-long line in {cases} cases");
    }
}

/// An endless run of bytes without a line end (a reader that never stops, not a buffer).
struct Endless {
    left: u64,
    byte: u8,
}

impl Read for Endless {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = (buf.len() as u64).min(self.left) as usize;
        buf[..n].fill(self.byte);
        self.left -= n as u64;
        Ok(n)
    }
}

/// Not fuzz cases: 16 MB without a line end keeps at most one line's worth in memory, and a
/// row whose end was past the limit is refused, not read cut: before, the first 64 KiB of a
/// row padded with spaces read as a whole row, and the fields past them were lost unseen.
#[test]
fn an_over_long_line_is_cut_and_refused_not_buffered_or_read_cut() {
    let rig = RigConfig::zhou2004().unwrap();
    // The header of a record: its lines up to the column line.
    let one = String::from_utf8(written(1, true)).unwrap();
    let header: String = one.lines().take_while(|l| !l.starts_with("1000 ")).map(|l| format!("{l}\n")).collect();
    let endless = header.as_bytes().chain(Endless { left: 16 << 20, byte: b'7' }).chain(&b"\n"[..]);
    let (out, asked) = fuzz::largest_allocation(0, || stream(&rig, endless, 8192));
    assert!(asked < 4 * MAX_LINE_BYTES, "{asked} bytes allocated for a 16 MB line");
    assert_eq!(out.cut_lines, 1);
    let e = out.reports.first().unwrap_or_else(|| panic!("not reported: {:?}", out.fatal));
    assert!(e.to_string().contains(&format!("longer than {MAX_LINE_BYTES} bytes")), "{e}");

    // A good row, 70 000 spaces, and two more fields: the line is cut inside the spaces.
    let good = written(3, true);
    let text = String::from_utf8(good.clone()).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let last = lines.len() - 1;
    lines[last] = format!("{}{} 1 2", lines[last], " ".repeat(70_000));
    let damaged = lines.join("\n") + "\n";
    let out = stream(&rig, damaged.as_bytes(), 4096);
    let whole = stream(&rig, good.as_slice(), 4096);
    assert_eq!(out.reports.len(), 1, "the cut row is reported: {:?}", out.reports);
    check(&out.reports[0], out.lines, "cut row");
    assert!(matches!(&out.reports[0], NodeError::BadRecord { line, .. } if *line == lines.len()));
    assert_eq!(whole.frames, out.frames, "the rows before it make the same frames");
    // In the header, a cut line is fatal, with its position.
    let cut_header = format!("# oilfilm-ascii 1\n# rig: {}\n", "z".repeat(70_000));
    let out = stream(&rig, cut_header.as_bytes(), 4096);
    let e = out.fatal.expect("fatal");
    assert!(e.to_string().starts_with(&format!("{SOURCE}:2:{}: the line is longer", MAX_LINE_BYTES + 1)), "{e}");
}
