//! The ASCII record format: example files, every refusal with its line and column, bit-exact
//! round trips, and a seeded mutation search that the reader never panics on.
//!
//! The mutation search is bounded: `OILFILM_FUZZ_CASES` (default 10 000) cases from seed
//! `OILFILM_FUZZ_SEED`; case `k` runs from seed + `k` alone (its base record and every edit
//! come from that seed's generator, printed on failure with the command that runs it
//! alone). `OILFILM_FUZZ_CASES=200000` searches longer (nothing here is judged on time).

use std::path::PathBuf;

use oilfilm_identification::ascii::{self, Fed, Header, LineReader, Record, Row, Units, Writer, CHANNEL_NAMES, CHANNEL_UNITS_SI};
use oilfilm_identification::IdentificationError;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn data(path: &str) -> (String, String) {
    let full = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(path);
    let text = std::fs::read_to_string(&full).unwrap_or_else(|e| panic!("{}: {e}", full.display()));
    (text, path.to_string())
}

/// (line, column, message) of a parse error.
fn parse_error(result: Result<Record, IdentificationError>) -> (usize, usize, String) {
    match result {
        Err(IdentificationError::Parse { line, column, message, .. }) => (line, column, message),
        Err(other) => panic!("expected a parse error, got {other:?}"),
        Ok(r) => panic!("expected a parse error, read {} scans", r.len()),
    }
}

fn mean(x: &[f64]) -> f64 {
    x.iter().sum::<f64>() / x.len() as f64
}

#[test]
fn the_si_example_reads_with_plausible_values() {
    let (text, name) = data("example-si.txt");
    let r = ascii::read(&text, &name).expect("the example is valid");
    assert_eq!(r.len(), 50);
    assert_eq!(r.header.version, 1);
    assert_eq!(r.header.rig, "zhou2004");
    assert_eq!(r.header.units, Units::Si);
    assert_eq!(r.header.sample_rate_hz, 5000.0);
    assert_eq!(r.header.channel_interval_s, 1e-5);
    assert_eq!(r.header.channel_offsets_s, None);
    assert_eq!(r.header.speed_rpm, Some(1500.0));
    assert_eq!(r.header.channels, CHANNEL_NAMES);
    assert_eq!(r.scan_index, (0..50).collect::<Vec<u64>>());
    // Zhou's operating point: journal about (+0.05, -0.08) mm from the bearing centre.
    for (x, y) in [("probe_a_x", "probe_a_y"), ("probe_b_x", "probe_b_y")] {
        let mx = mean(r.column(x).expect("x"));
        let my = mean(r.column(y).expect("y"));
        assert!((mx - 5e-5).abs() < 3e-6 && (my + 8e-5).abs() < 3e-6, "{x} {mx}, {y} {my}");
    }
    for frame in ["frame_x", "frame_y"] {
        assert!(r.column(frame).expect("frame").iter().all(|v| v.abs() < 1e-6));
    }
    for f in ["f1", "f2"] {
        let c = r.column(f).expect("force");
        assert!(c.iter().all(|v| v.abs() < 102.0) && c.iter().any(|v| v.abs() > 80.0), "{f}");
    }
    assert!((mean(r.column("f3").expect("f3")) - 5600.0).abs() < 10.0);
    assert!((mean(r.column("temperature").expect("temperature")) - 29.0).abs() < 0.1);
    assert_eq!(r.column("probe_c_x"), None);
    assert_eq!(CHANNEL_UNITS_SI[9], "degC");
    // Multiplexed: channel p is sampled p * 10 us into the scan.
    assert_eq!(r.time_of(0, 0), 0.0);
    assert!((r.time_of(49, 9) - (49.0 / 5000.0 + 9e-5)).abs() < 1e-15);
    assert!((r.time_of(50, 0) - 0.01).abs() < 1e-15, "rows past the end continue");
    assert!(r.time_of(0, 10).is_nan());
}

#[test]
fn a_volts_file_with_shuffled_channels_offsets_tabs_and_comments_reads() {
    let (text, name) = data("example-volts-offsets.txt");
    let r = ascii::read(&text, &name).expect("valid");
    assert_eq!(r.header.units, Units::Volts);
    assert_eq!(r.header.rig, "configs/zhou2004.toml");
    assert_eq!(r.header.sample_rate_hz, 5000.0);
    assert_eq!(r.header.start_time_s, 1712345678.25);
    assert_eq!(r.header.channels[..3], ["f1", "f2", "probe_a_x"]);
    assert_eq!(r.scan_index, vec![1000, 1001, 1002, 1003]);
    assert_eq!(r.column("f1").expect("f1"), [0.0153, 0.1829, 0.3420, 0.4630]);
    assert_eq!(r.column("temperature").expect("t")[3], 2.904);
    let offsets = r.header.channel_offsets_s.clone().expect("offsets");
    assert_eq!(offsets.len(), 10);
    // The explicit offset wins over position * interval.
    assert_eq!(r.header.channel_offset_s(9), Some(1.5e-4));
    let t = r.time_of(2, 9);
    assert!((t - (1712345678.25 + 1002.0 / 5000.0 + 1.5e-4)).abs() < 1e-6, "{t}");
    // Same text with CR LF line ends and a byte-order mark reads the same.
    let crlf = format!("\u{feff}{}", text.replace('\n', "\r\n"));
    assert_eq!(ascii::read(&crlf, &name).expect("crlf"), r);
}

/// Every invalid fixture: (file, line, column, words the message must contain).
const INVALID: [(&str, usize, usize, &[&str]); 13] = [
    ("bad-version.txt", 1, 17, &["unsupported format version 2", "reads version 1"]),
    ("no-format-line.txt", 1, 0, &["missing format line", "# oilfilm-ascii 1"]),
    ("missing-key.txt", 6, 0, &["header key `sample_rate_hz` is missing"]),
    ("unknown-key.txt", 3, 3, &["unknown header key `sample_rate`", "sample_rate_hz"]),
    ("bad-header-number.txt", 3, 19, &["sample_rate_hz", "`5 kHz` is not a number"]),
    ("unknown-column.txt", 7, 26, &["unknown column `probe_c_x`"]),
    ("duplicate-channel.txt", 7, 65, &["channel `f1` appears twice", "first as channel 7"]),
    ("missing-channel.txt", 7, 0, &["missing channel temperature", "exactly once"]),
    ("ragged-row.txt", 9, 0, &["expected 11 fields", "found 10"]),
    ("nan-value.txt", 9, 57, &["channel `f2`", "`NaN` is not a finite number"]),
    ("skipped-scan.txt", 10, 1, &["scan index 3 skips scan 2", "previous row is scan 1"]),
    ("empty-data.txt", 7, 0, &["no data"]),
    ("comma-separated.txt", 7, 1, &["expected the column line", "not commas"]),
];

#[test]
fn invalid_fixtures_are_refused_at_the_right_line_and_column() {
    for (file, line, column, words) in INVALID {
        let (text, name) = data(&format!("invalid/{file}"));
        let err = ascii::read(&text, &name).expect_err(file);
        let shown = err.to_string();
        assert!(shown.starts_with(&format!("invalid/{file}:{line}:{column}: ")), "{shown}");
        let (l, c, message) = parse_error(Err(err));
        assert_eq!((l, c), (line, column), "{file}: {message}");
        for w in words {
            assert!(message.contains(w), "{file}: `{message}` lacks `{w}`");
        }
    }
}

const GOOD: &str = "# oilfilm-ascii 1
# rig: zhou2004
# sample_rate_hz: 5000
# channel_interval_s: 1e-5
# units: si
# start_time_s: 0
scan probe_a_x probe_a_y probe_b_x probe_b_y frame_x frame_y f1 f2 f3 temperature
0 5e-05 -8e-05 5e-05 -8e-05 1e-08 -2e-08 0.5 0.9 5600 29
1 5.1e-05 -7.9e-05 5e-05 -8e-05 1e-08 -2e-08 3.6 5.2 5601 29
";

/// `GOOD` with `from` replaced by `to` (exactly once).
fn good_with(from: &str, to: &str) -> String {
    assert_eq!(GOOD.matches(from).count(), 1, "`{from}` must occur once");
    GOOD.replace(from, to)
}

#[test]
fn each_rule_is_enforced_with_a_precise_position() {
    assert!(ascii::read(GOOD, "good").is_ok());
    let cases: Vec<(String, usize, usize, &str)> = vec![
        (String::new(), 1, 0, "missing format line"),
        ("\n\n".into(), 1, 0, "missing format line"),
        (good_with("# oilfilm-ascii 1", "# oilfilm-ascii"), 1, 0, "lacks its version"),
        (good_with("# oilfilm-ascii 1", "# oilfilm-ascii one"), 1, 17, "not an integer"),
        (good_with("# oilfilm-ascii 1", "# oilfilm-ascii 99999999999"), 1, 17, "not an integer"),
        (good_with("# oilfilm-ascii 1", "# oilfilm-ascii 1 beta"), 1, 19, "after the format version"),
        (good_with("# oilfilm-ascii 1", "oilfilm-ascii 1"), 1, 0, "missing format line"),
        (good_with("# rig: zhou2004", "# rig zhou2004"), 2, 0, "# key: value"),
        (good_with("# rig: zhou2004", "# rig:   "), 2, 10, "has no value"),
        (good_with("# units: si", "# units: si\n# rig: other"), 6, 3, "given twice (first on line 2)"),
        (good_with("# units: si", "# units: SI"), 5, 10, "`si` or `volts`"),
        (good_with("# units: si", "# units: millivolts"), 5, 10, "`si` or `volts`"),
        (good_with("5000", "-5000"), 3, 19, "must be in (0, 1e7] Hz, got -5000.0"),
        (good_with("5000", "1e300"), 3, 19, "must be in (0, 1e7] Hz, got 1e300"),
        // Out of range: the allowed range, and the value at a bounded width (the issue saw a
        // 1e308 printed as a 309-digit number).
        (good_with("# start_time_s: 0", "# start_time_s: 1e308"), 6, 17, "[0, 2147483647] s"),
        (good_with("# start_time_s: 0", "# start_time_s: 9.3e9"), 6, 17, "got 9300000000.0"),
        (good_with("# start_time_s: 0", "# start_time_s: -1"), 6, 17, "[0, 2147483647] s"),
        (good_with("# start_time_s: 0", "# start_time_s: 2147483647"), 0, 0, ""),
        (good_with("# units: si", "# units: si\n# speed_rpm: 1e308"), 6, 14, "(0, 1e6] rpm, got 1e308"),
        (good_with("# units: si", "# units: si\n# speed_rpm: 0"), 6, 14, "(0, 1e6] rpm"),
        (good_with("# units: si", "# units: si\n# speed_rpm: 1500"), 0, 0, ""),
        (good_with("5000", "inf"), 3, 19, "not a finite number"),
        (good_with("5000", "1e999"), 3, 19, "not a finite number"),
        (good_with("1e-5", "-1e-5"), 4, 23, "non-negative"),
        (good_with("1e-5", "1e-4"), 4, 23, "not within the scan period"),
        (good_with("# start_time_s: 0", "# start_time_s: nan"), 6, 17, "not a finite number"),
        (good_with("# units: si", "# units: si\n# channel_offsets_s: 0 1e-5 2e-5"), 6, 22, "has 3 values but the column line names 10"),
        (good_with("# units: si", "# units: si\n# channel_offsets_s: 0 0 0 0 0 0 0 0 2e-4 0"), 6, 38, "shorter than the scan period"),
        (good_with("# units: si", "# units: si\n# channel_offsets_s: 0 0 0 0 x 0 0 0 0 0"), 6, 30, "`x` is not a number"),
        (good_with("# start_time_s: 0\n", "# start_time_s: 0\n## c\n"), 0, 0, ""),
        (GOOD.replace("scan probe_a_x", "index probe_a_x"), 7, 1, "expected the column line"),
        (GOOD.replace("scan probe_a_x", "scan  probe_a_x  bogus"), 7, 18, "unknown column `bogus`"),
        (good_with("1 5.1e-05", "# sample_rate_hz: 1\n1 5.1e-05"), 9, 1, "header line after the column line"),
        (good_with("1 5.1e-05", "0 5.1e-05"), 9, 1, "does not increase: the previous row is scan 0"),
        (good_with("1 5.1e-05", "7 5.1e-05"), 9, 1, "skips scans 1 to 6"),
        (good_with("1 5.1e-05", "-1 5.1e-05"), 9, 1, "not a non-negative integer"),
        (good_with("1 5.1e-05", "+1 5.1e-05"), 9, 1, "not a non-negative integer"),
        (good_with("1 5.1e-05", "1.0 5.1e-05"), 9, 1, "not a non-negative integer"),
        (good_with("1 5.1e-05", "99999999999999999999 5.1e-05"), 9, 1, "too large"),
        (good_with("5601 29\n", "5601 29 7\n"), 9, 62, "expected 11 fields (scan index and 10 channels), found 12"),
        (good_with("5601 29\n", "5601 inf\n"), 9, 59, "channel `temperature`: value `inf` is not a finite"),
        (good_with("5601 29\n", "5601 1e400\n"), 9, 59, "not a finite number"),
        (good_with("5601 29\n", "5601 29,5\n"), 9, 59, "not commas"),
        (good_with("5601 29\n", "5601 29°\n"), 9, 59, "`29°` is not a number"),
        ("# oilfilm-ascii 1\n# rig: r\n".into(), 2, 0, "ends before the column line"),
        (good_with("# rig: zhou2004", "# rig: zhou\r2004"), 2, 8, "control characters"),
        (good_with("# rig: zhou2004", "# rig: zhou\t2004"), 2, 8, "control characters"),
        (good_with("5600 29\n", "5600 2.9D+01\n"), 8, 55, "`2.9D+01` is not a number"),
    ];
    for (text, line, column, words) in cases {
        let result = ascii::read(&text, "case.txt");
        if words.is_empty() {
            assert!(result.is_ok(), "{text}: {result:?}");
            continue;
        }
        let (l, c, message) = parse_error(result);
        assert!(message.contains(words), "`{message}` lacks `{words}`\n{text}");
        assert!(message.len() < 400, "a message of bounded width: {message}");
        assert_eq!((l, c), (line, column), "{message}\n{text}");
    }
    // Long non-ASCII fields are shortened in messages, on character boundaries.
    let long = "☺".repeat(100);
    let (_, c, m) = parse_error(ascii::read(&GOOD.replace("probe_b_x", &long), "u"));
    assert_eq!(c, 26);
    assert!(m.contains("☺...") && m.chars().count() < 250, "{m}");
    let text = good_with("# sample_rate_hz: 5000", "# sample_rate_hz:\u{e9}5000");
    assert_eq!(parse_error(ascii::read(&text, "u")).1, 18);
}

/// Finite doubles of every kind: normal, subnormal, zero of both signs, extremes, and values
/// whose shortest decimal form is long.
fn awkward(rng: &mut ChaCha8Rng) -> f64 {
    loop {
        let x = match rng.random_range(0..6) {
            0 => f64::from_bits(rng.random::<u64>()),
            1 => rng.random_range(-1e-4..1e-4),
            2 => rng.random_range(-2000.0..2000.0),
            3 => [0.0, -0.0, f64::MIN_POSITIVE, 5e-324, f64::MAX, f64::MIN, 0.1 + 0.2, 1.0 / 3.0][rng.random_range(0..8)],
            4 => rng.random::<f64>() * 10f64.powi(rng.random_range(-300..300)),
            _ => f64::from_bits(rng.random_range(0..1u64 << 52)), // subnormal
        };
        if x.is_finite() {
            return x;
        }
    }
}

fn random_record(rng: &mut ChaCha8Rng, scans: usize) -> Record {
    let mut channels: Vec<String> = CHANNEL_NAMES.iter().map(|s| s.to_string()).collect();
    // A seeded shuffle of the scan order.
    for i in (1..channels.len()).rev() {
        channels.swap(i, rng.random_range(0..=i));
    }
    let sample_rate_hz = rng.random_range(100.0..100_000.0);
    let period = 1.0 / sample_rate_hz;
    let channel_interval_s = rng.random::<f64>() * period / 10.0;
    let channel_offsets_s = rng.random::<bool>().then(|| (0..10).map(|_| rng.random::<f64>() * period * 0.999).collect());
    let first = if rng.random::<bool>() { 0 } else { rng.random_range(0..u64::MAX - scans as u64) };
    Record {
        header: Header {
            version: 1,
            rig: "rigs/zhou 2004 (copy).toml".into(),
            sample_rate_hz,
            channel_interval_s,
            channel_offsets_s,
            units: if rng.random::<bool>() { Units::Si } else { Units::Volts },
            // Awkward values within the documented range (0 to ROS 2's int32 seconds).
            start_time_s: std::iter::repeat_with(|| awkward(rng).abs()).find(|t| *t <= ascii::MAX_START_TIME_S).expect("an endless iterator"),
            speed_rpm: rng.random::<bool>().then(|| 1.0 + rng.random::<f64>() * 5000.0),
            channels,
        },
        scan_index: (first..first + scans as u64).collect(),
        columns: (0..10).map(|_| (0..scans).map(|_| awkward(rng)).collect()).collect(),
    }
}

fn assert_bit_identical(a: &Record, b: &Record) {
    let bits = |x: &[f64]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(a.header.channels, b.header.channels);
    assert_eq!(a.scan_index, b.scan_index);
    for (ca, cb) in a.columns.iter().zip(&b.columns) {
        assert_eq!(bits(ca), bits(cb));
    }
    let h = |r: &Record| {
        let mut v = vec![r.header.sample_rate_hz, r.header.channel_interval_s, r.header.start_time_s];
        v.extend(r.header.channel_offsets_s.clone().unwrap_or_default());
        bits(&v)
    };
    assert_eq!(h(a), h(b));
    assert_eq!((&a.header.rig, a.header.units), (&b.header.rig, b.header.units));
}

#[test]
fn write_then_read_is_bit_identical() {
    let mut rng = ChaCha8Rng::seed_from_u64(2004);
    for case in 0..200 {
        let scans = rng.random_range(1..40);
        let record = random_record(&mut rng, scans);
        let text = ascii::write(&record).unwrap_or_else(|e| panic!("case {case}: {e}"));
        let back = ascii::read(&text, "roundtrip").unwrap_or_else(|e| panic!("case {case}: {e}\n{text}"));
        assert_bit_identical(&record, &back);
        // The streaming writer produces the same text.
        let mut w = Writer::new(Vec::new(), &record.header).expect("header");
        for (i, &n) in record.scan_index.iter().enumerate() {
            let row: Vec<f64> = record.columns.iter().map(|c| c[i]).collect();
            w.push(n, &row).expect("row");
        }
        assert_eq!(String::from_utf8(w.finish().expect("finish")).expect("utf8"), text);
    }
    // The example file survives a read-write-read cycle too.
    let (text, name) = data("example-si.txt");
    let r = ascii::read(&text, &name).expect("example");
    let again = ascii::read(&ascii::write(&r).expect("write"), "again").expect("read");
    assert_bit_identical(&r, &again);
    assert_eq!(r, again);
}

#[test]
fn writers_refuse_what_a_reader_would_refuse() {
    let header = Header::new_si("zhou2004", 5000.0, 1e-5);
    let row = [5e-5, -8e-5, 5e-5, -8e-5, 0.0, 0.0, 1.0, 2.0, 5600.0, 29.0];
    let mut w = Writer::new(Vec::new(), &header).expect("header");
    w.push(7, &row).expect("first scan may have any index");
    assert!(w.push(9, &row).is_err(), "skipped index");
    assert!(w.push(8, &row[..9]).is_err(), "too few values");
    let mut nan = row;
    nan[9] = f64::NAN;
    let err = w.push(8, &nan).expect_err("NaN").to_string();
    assert!(err.contains("temperature"), "{err}");
    w.push(8, &row).expect("next");
    let text = String::from_utf8(w.finish().expect("finish")).expect("utf8");
    assert_eq!(ascii::read(&text, "w").expect("read").scan_index, vec![7, 8]);

    assert!(Writer::new(Vec::new(), &header).expect("header").finish().is_err(), "no rows");
    let mut last = Writer::new(Vec::new(), &header).expect("header");
    last.push(u64::MAX, &row).expect("largest index");
    assert!(last.push(0, &row).is_err(), "nothing follows u64::MAX");

    let bad_headers: Vec<(Header, &str)> = vec![
        (Header { version: 2, ..header.clone() }, "header.version"),
        (Header { rig: "two\nlines".into(), ..header.clone() }, "header.rig"),
        (Header { rig: " padded".into(), ..header.clone() }, "header.rig"),
        (Header { rig: String::new(), ..header.clone() }, "header.rig"),
        (Header { sample_rate_hz: 0.0, ..header.clone() }, "header.sample_rate_hz"),
        (Header { channel_interval_s: f64::NAN, ..header.clone() }, "header.channel_interval_s"),
        (Header { channel_interval_s: 1e-4, ..header.clone() }, "header.channel_interval_s"),
        (Header { start_time_s: f64::INFINITY, ..header.clone() }, "header.start_time_s"),
        (Header { speed_rpm: Some(0.0), ..header.clone() }, "header.speed_rpm"),
        (Header { start_time_s: 9.3e9, ..header.clone() }, "header.start_time_s"),
        (Header { speed_rpm: Some(1e308), ..header.clone() }, "header.speed_rpm"),
        (Header { speed_rpm: Some(f64::NAN), ..header.clone() }, "header.speed_rpm"),
        (Header { channel_offsets_s: Some(vec![0.0; 9]), ..header.clone() }, "header.channel_offsets_s"),
        (Header { channel_offsets_s: Some(vec![1.0; 10]), ..header.clone() }, "header.channel_offsets_s"),
        (Header { channels: header.channels[1..].to_vec(), ..header.clone() }, "missing channel probe_a_x"),
        (Header { channels: [&header.channels[..], &["f1".to_string()]].concat(), ..header.clone() }, "appears twice"),
    ];
    for (h, words) in bad_headers {
        let err = Writer::new(Vec::new(), &h).err().expect(words).to_string();
        assert!(err.contains(words), "`{err}` lacks `{words}`");
    }

    let record = Record { header: header.clone(), scan_index: vec![0, 1], columns: vec![vec![0.0; 2]; 10] };
    assert!(ascii::write(&record).is_ok());
    let ragged = Record { columns: vec![vec![0.0; 2], vec![0.0; 1]], ..record.clone() };
    assert!(ascii::write(&ragged).is_err());
    let mut short = record.clone();
    short.columns[4].pop();
    assert!(ascii::write(&short).expect_err("short column").to_string().contains("frame_x"));
    let gap = Record { scan_index: vec![0, 2], ..record.clone() };
    assert!(ascii::write(&gap).is_err());
    let empty = Record { scan_index: vec![], columns: vec![vec![]; 10], ..record };
    assert!(ascii::write(&empty).is_err());
}

/// One random damaging edit of `bytes`.
fn mutate(rng: &mut ChaCha8Rng, bytes: &mut Vec<u8>) {
    const TOKENS: [&[u8]; 14] =
        [b"nan", b"inf", b"-", b"#", b"##", b":", b" ", b"\t", b"\r", b"\n", b"1e999", b"18446744073709551616", b"scan", "\u{feff}é☺".as_bytes()];
    if bytes.is_empty() {
        bytes.extend_from_slice(TOKENS[rng.random_range(0..TOKENS.len())]);
        return;
    }
    let at = rng.random_range(0..bytes.len());
    match rng.random_range(0..8) {
        0 => bytes[at] = rng.random::<u8>(),
        1 => bytes[at] ^= 1 << rng.random_range(0..8),
        2 => bytes.truncate(at),
        3 => {
            bytes.remove(at);
        }
        4 => {
            let t = TOKENS[rng.random_range(0..TOKENS.len())];
            bytes.splice(at..at, t.iter().copied());
        }
        _ => {
            // Line-level edits: swap, duplicate or drop lines.
            let mut lines: Vec<Vec<u8>> = bytes.split(|b| *b == b'\n').map(<[u8]>::to_vec).collect();
            let n = lines.len();
            let (i, j) = (rng.random_range(0..n), rng.random_range(0..n));
            match rng.random_range(0..3) {
                0 => lines.swap(i, j),
                1 => {
                    let copy = lines[i].clone();
                    lines.insert(j, copy);
                }
                _ => {
                    lines.remove(i);
                }
            }
            *bytes = lines.join(&b'\n');
        }
    }
}

/// The mutation search's first seed (`OILFILM_FUZZ_SEED` overrides it).
const FUZZ_SEED: u64 = 0xa5c11;

/// What a failing case of the mutation search says: its index and seed, and the command that
/// runs it alone.
fn fuzz_case_label(case: u64, seed: u64) -> String {
    format!(
        "case {case} (seed {seed}; alone: OILFILM_FUZZ_SEED={seed} OILFILM_FUZZ_CASES=1 cargo test -p oilfilm-identification --test identification \
         ascii::mutated_files_never_make_the_reader_panic)"
    )
}

#[test]
fn mutated_files_never_make_the_reader_panic() {
    let (example, _) = data("example-si.txt");
    let (volts, _) = data("example-volts-offsets.txt");
    let short: String = example.lines().take(15).map(|l| format!("{l}\n")).collect();
    assert_eq!(ascii::read(&short, "short").expect("short example").len(), 3);
    let (first, cases) = crate::fuzz::settings(FUZZ_SEED, 10_000);
    let start = std::time::Instant::now();
    let (mut ok, mut refused) = (0u64, 0u64);
    for case in 0..cases {
        // Everything a case does comes from its own seed, not from the cases before it, so
        // that it runs alone as it ran in the loop.
        let seed = first.wrapping_add(case);
        let mut rng = crate::fuzz::rng(seed);
        let label = fuzz_case_label(case, seed);
        // A short file half the time, so that the header takes more of the damage.
        let base = match rng.random_range(0..4) {
            0 | 2 => &short,
            1 => &example,
            _ => &volts,
        };
        let mut bytes = base.clone().into_bytes();
        for _ in 0..rng.random_range(1..5) {
            mutate(&mut rng, &mut bytes);
        }
        let text = String::from_utf8_lossy(&bytes);
        let outcome = std::panic::catch_unwind(|| ascii::read(&text, "mutant.txt"));
        let result = outcome.unwrap_or_else(|_| panic!("{label}: the reader panicked on\n{text}"));
        // The streaming reader gives the same record or the same error.
        let streamed = std::panic::catch_unwind(|| ascii::read_stream(text.as_bytes(), "mutant.txt"))
            .unwrap_or_else(|_| panic!("{label}: the streaming reader panicked on\n{text}"));
        match (&result, &streamed) {
            (Ok(a), Ok(b)) => assert_bit_identical(a, b),
            (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "{label}"),
            _ => panic!("{label}: read gave {result:?}, read_stream {streamed:?}"),
        }
        match result {
            Ok(record) => {
                ok += 1;
                assert!(record.columns.len() == 10 && record.columns.iter().all(|c| c.len() == record.len()), "{label}: ragged record");
                // Whatever reads also writes and reads back unchanged.
                let again = ascii::read(&ascii::write(&record).unwrap_or_else(|e| panic!("{label}: write: {e}")), "again")
                    .unwrap_or_else(|e| panic!("{label}: reread: {e}"));
                assert_bit_identical(&record, &again);
            }
            Err(IdentificationError::Parse { line, .. }) => {
                refused += 1;
                assert!(line >= 1 && line <= text.split('\n').count().max(1), "{label}: line {line}");
            }
            Err(other) => panic!("{label}: not a parse error: {other}"),
        }
    }
    println!("ascii record fuzz: {cases} cases from seed {first} in {:.2} s: {ok} still valid, {refused} refused", start.elapsed().as_secs_f64());
    // A case run alone is judged on itself (above); the loop's mix only over many cases.
    assert!(!crate::fuzz::mix_is_judged(cases) || (refused > cases / 2 && ok > cases / 80), "{ok} valid, {refused} refused");
}

#[test]
fn a_record_of_the_papers_size_streams_and_reads() {
    // Zhou et al.: 50,000 points per channel at 5 kHz.
    let header = Header::new_si("zhou2004", 5000.0, 1e-5);
    let mut w = Writer::new(Vec::new(), &header).expect("header");
    for n in 0..50_000u64 {
        let t = n as f64 / 5000.0;
        let s = (2.0 * std::f64::consts::PI * 20.0 * t).sin();
        let row = [5e-5 + 1e-6 * s, -8e-5, 5e-5, -8e-5, 0.0, 0.0, 100.0 * s, 0.0, 5600.0, 29.0];
        w.push(n, &row).expect("row");
    }
    let text = String::from_utf8(w.finish().expect("finish")).expect("utf8");
    let started = std::time::Instant::now();
    let r = ascii::read(&text, "big").expect("read");
    println!("read {} scans ({} bytes) in {:?}", r.len(), text.len(), started.elapsed());
    assert_eq!(r.len(), 50_000);
    assert_eq!(r.time_of(49_999, 0), 49_999.0 / 5000.0);
}

/// Feeds `text` line by line; returns what each line gave.
fn feed_all(reader: &mut LineReader, text: &str) -> Vec<Result<Fed, IdentificationError>> {
    text.split('\n').enumerate().map(|(i, line)| reader.feed(i + 1, line)).collect()
}

#[test]
fn the_line_reader_gives_the_header_then_rows_and_skips_bad_rows_with_their_position() {
    // A good record fed line by line: the header once, then each row with its scan index.
    let mut reader = LineReader::new("stream");
    let fed = feed_all(&mut reader, GOOD);
    let record = ascii::read(GOOD, "good").expect("good");
    let header: Vec<&Header> = fed
        .iter()
        .filter_map(|f| match f {
            Ok(Fed::Header(h)) => Some(h),
            _ => None,
        })
        .collect();
    assert_eq!(header, [&record.header]);
    let rows: Vec<&Row> = fed
        .iter()
        .filter_map(|f| match f {
            Ok(Fed::Row(r)) => Some(r),
            _ => None,
        })
        .collect();
    assert_eq!(rows.len(), 2);
    assert_eq!((rows[1].line, rows[1].scan_index), (9, 1));
    assert_eq!(rows[1].values, record.columns.iter().map(|c| c[1]).collect::<Vec<_>>());
    assert_eq!(reader.last_scan(), Some(1));

    // Bad rows after it: each reported with its line and column, none stops the reader.
    let more = [
        ("2 1 2 3", 0, "expected 11 fields"),
        ("2 5e-05 -8e-05 5e-05 -8e-05 1e-08 -2e-08 0.5 0.9 5600 29 extra", 58, "found 12"),
        ("2 5e-05 -8e-05 5e-05 -8e-05 1e-08 nan 0.5 0.9 5600 29", 35, "not a finite number"),
        ("x2 5e-05 -8e-05 5e-05 -8e-05 1e-08 -2e-08 0.5 0.9 5600 29", 1, "not a non-negative integer"),
        ("1 5e-05 -8e-05 5e-05 -8e-05 1e-08 -2e-08 0.5 0.9 5600 29", 1, "does not increase"),
        ("  # units: volts", 3, "header line after the column line"),
    ];
    for (k, (line, column, words)) in more.iter().enumerate() {
        match reader.feed(10 + k, line) {
            Ok(Fed::Bad(IdentificationError::Parse { file, line: l, column: c, message })) => {
                assert_eq!((file.as_str(), l, c), ("stream", 10 + k, *column), "{message}");
                assert!(message.contains(words), "{message}");
            }
            other => panic!("{line}: {other:?}"),
        }
    }
    assert_eq!(reader.last_scan(), Some(1), "no bad row moved the scan index");
    // Blank, comment and CR LF lines are fine; the next good row is read.
    assert_eq!(reader.feed(16, "\r\n"), Ok(Fed::Nothing));
    assert_eq!(reader.feed(17, "## note"), Ok(Fed::Nothing));
    let row = "2 5e-05 -8e-05 5e-05 -8e-05 1e-08 -2e-08 0.5 0.9 5600 29\r\n";
    assert!(matches!(reader.feed(18, row), Ok(Fed::Row(Row { line: 18, scan_index: 2, .. }))));
    // A gap: the row is delivered and the missing scans named.
    match reader.feed(19, "5 5e-05 -8e-05 5e-05 -8e-05 1e-08 -2e-08 0.5 0.9 5600 29") {
        Ok(Fed::Gap { row, gap }) => {
            assert_eq!((row.line, row.scan_index), (19, 5));
            assert_eq!(gap.to_string(), "stream:19:1: scan index 5 skips scans 3 to 4 (previous row is scan 2)");
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(reader.last_scan(), Some(5));
}

#[test]
fn a_header_error_stops_the_line_reader_for_good() {
    let text = good_with("# units: si", "# units: furlongs");
    let mut reader = LineReader::new("s");
    let fed = feed_all(&mut reader, &text);
    let first = fed.iter().position(Result::is_err).expect("an error");
    // The header is checked whole at the column line (line 7); the error names line 5.
    assert_eq!(first, 6, "at the column line");
    assert!(fed[first..].iter().all(|f| f == &fed[first]), "every later line gives the same error");
    assert_eq!(fed[first].as_ref().unwrap_err().to_string(), "s:5:10: units must be `si` or `volts`, found `furlongs`");
    assert!(reader.header().is_none());
    assert_eq!(reader.finish(9).unwrap_err(), fed[first].clone().unwrap_err());
    // A stream that ends in its header.
    let mut reader = LineReader::new("s");
    feed_all(&mut reader, "# oilfilm-ascii 1\n# rig: r");
    assert!(reader.finish(2).unwrap_err().to_string().starts_with("s:2:0: the file ends before the column line"));
}

#[test]
fn the_streaming_reader_names_the_line_and_column_of_a_byte_that_is_not_utf8() {
    let (text, _) = data("example-si.txt");
    let streamed = ascii::read_stream(text.as_bytes(), "example-si.txt").expect("the example streams");
    assert_bit_identical(&ascii::read(&text, "example-si.txt").unwrap(), &streamed);
    // CR LF line ends and no line end at the end of the file read the same.
    let crlf = text.replace('\n', "\r\n");
    assert_bit_identical(&streamed, &ascii::read_stream(crlf.trim_end().as_bytes(), "crlf").expect("CR LF"));
    let mut bytes = GOOD.as_bytes().to_vec();
    let at = GOOD.find("5601").unwrap() + 2;
    bytes[at] = 0xc3;
    let (line, column, message) = parse_error(ascii::read_stream(bytes.as_slice(), "bad.txt"));
    let expected_column = at - GOOD[..at].rfind('\n').unwrap();
    assert_eq!((line, column), (9, expected_column), "{message}");
    assert_eq!(&GOOD[at - expected_column + 1..at], "1 5.1e-05 -7.9e-05 5e-05 -8e-05 1e-08 -2e-08 3.6 5.2 56", "the column counts from 1");
    assert!(message.contains("0xc3") && message.contains("not UTF-8"), "{message}");
}
