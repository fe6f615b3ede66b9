//! The readers against files of every layout they take: each gives back exactly the values
//! written (bit for bit), in scans of the rig's channels; and broken files are refused with
//! the file, the channel and the place named.

use std::path::{Path, PathBuf};

use oilfilm_foreign::fixtures::{self, MatLayout, TdmsChannel, TdmsLayout};
use oilfilm_foreign::map::ChannelMap;
use oilfilm_foreign::{Block, ForeignError, ForeignRecord, RecordSpeed};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::ChannelId;

const N: usize = 2345;

/// A record of the ten channels (volts-like numbers with awkward bits) and a speed in Hz.
fn record() -> (Vec<Vec<f64>>, Vec<f64>) {
    let mut state = 0x2545F4914F6CDD1Du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let columns: Vec<Vec<f64>> = (0..10).map(|c| (0..N).map(|i| (i as f64 * 0.01 * (c + 1) as f64).sin() * 3.0 + next() * 1e-3).collect()).collect();
    let speed: Vec<f64> = (0..N).map(|i| 25.0 + 1e-3 * (i as f64 * 0.002).cos()).collect();
    (columns, speed)
}

fn names() -> Vec<&'static str> {
    ChannelId::ALL.iter().map(|c| c.name()).collect()
}

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("oilfilm-foreign-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A map of every rig channel in volts from `source(k)`, the speed from `speed`.
fn map(format: &str, timing: &str, source: impl Fn(usize) -> String, speed: &str, extra: &str) -> ChannelMap {
    let mut text = format!("format = \"{format}\"\n{extra}\n[timing]\n{timing}\nmultiplexer = \"sequential\"\nchannel_interval_s = 1e-5\n");
    for (k, c) in names().iter().enumerate() {
        text.push_str(&format!("[[channel]]\nrig = \"{c}\"\n{}\nunit = \"V\"\n", source(k)));
    }
    text.push_str(speed);
    ChannelMap::from_toml_str(&text, Path::new("test.map.toml")).unwrap()
}

fn read_all(path: &Path, map: &ChannelMap) -> Result<(ForeignRecord, Vec<f64>, Vec<f64>), ForeignError> {
    let rig = RigConfig::zhou2004().unwrap();
    let mut rec = ForeignRecord::open(path, map, &rig.daq.calibration())?;
    let (mut values, mut speed) = (Vec::new(), Vec::new());
    let mut block = Block::default();
    let mut expected_first = 0;
    while rec.next_block(500, &mut block)? > 0 {
        assert_eq!(block.first_scan, expected_first);
        expected_first += block.scans as u64;
        values.extend_from_slice(&block.values);
        speed.extend_from_slice(&block.speed_rpm);
    }
    Ok((rec, values, speed))
}

fn check_same(values: &[f64], speed: &[f64], columns: &[Vec<f64>], speed_hz: &[f64]) {
    assert_eq!(values.len(), N * 10);
    for (i, scan) in values.chunks_exact(10).enumerate() {
        for c in 0..10 {
            assert_eq!(scan[c].to_bits(), columns[c][i].to_bits(), "scan {i} channel {c}");
        }
    }
    assert_eq!(speed.len(), N);
    for (got, hz) in speed.iter().zip(speed_hz) {
        assert_eq!(*got, hz * 60.0);
    }
}

const GROUPS: [&str; 10] = ["Probes", "Probes", "Probes", "Probes", "Frame", "Frame", "Forces", "Forces", "Forces", "Temperatures"];

fn tdms_channels<'a>(columns: &'a [Vec<f64>], speed: &'a [f64]) -> Vec<TdmsChannel<'a>> {
    let mut v: Vec<TdmsChannel> = names()
        .iter()
        .enumerate()
        .map(|(k, name)| TdmsChannel { group: GROUPS[k], name, values: &columns[k], properties: vec![("wf_increment", 1.0 / 5000.0)] })
        .collect();
    v.push(TdmsChannel { group: "Tacho", name: "speed", values: speed, properties: vec![] });
    v
}

#[test]
fn tdms_contiguous_interleaved_big_endian_all_read_back_bit_for_bit() {
    let (columns, speed) = record();
    let d = dir("tdms");
    for (k, layout) in [
        TdmsLayout { segments: 1, interleaved: false, big_endian: false },
        TdmsLayout { segments: 4, interleaved: false, big_endian: false },
        TdmsLayout { segments: 3, interleaved: true, big_endian: false },
        TdmsLayout { segments: 5, interleaved: true, big_endian: true },
    ]
    .into_iter()
    .enumerate()
    {
        let path = d.join(format!("r{k}.tdms"));
        fixtures::tdms(&path, &tdms_channels(&columns, &speed), layout).unwrap();
        let by_name = map(
            "tdms",
            "sample_rate_from = \"wf_increment\"",
            |k| format!("from = \"{}/{}\"", GROUPS[k], names()[k]),
            "[speed]\nfrom = \"Tacho/speed\"\nunit = \"Hz\"\n",
            "",
        );
        let (rec, values, got_speed) = read_all(&path, &by_name).unwrap_or_else(|e| panic!("{layout:?}: {e}"));
        assert_eq!(rec.sample_rate_hz, 5000.0);
        assert_eq!(rec.scans, Some(N as u64));
        assert!(rec.volts);
        assert_eq!(rec.offsets_s[9], 9.0 * 1e-5);
        assert!(matches!(rec.speed, RecordSpeed::Channel { .. }));
        check_same(&values, &got_speed, &columns, &speed);
        // The same channels by their position in their group.
        let position = |k: usize| GROUPS[..k].iter().filter(|g| **g == GROUPS[k]).count();
        let by_index = map(
            "tdms",
            "sample_rate_hz = 5000",
            |k| format!("from = \"{}\"\nindex = {}", GROUPS[k], position(k)),
            "[speed]\nfrom = \"Tacho/speed\"\nunit = \"Hz\"\n",
            "",
        );
        let (_, values, got_speed) = read_all(&path, &by_index).unwrap();
        check_same(&values, &got_speed, &columns, &speed);
    }
}

#[test]
fn mat_variables_struct_and_matrix_compressed_or_not_read_back_bit_for_bit() {
    let (columns, speed) = record();
    let d = dir("mat");
    let mut cols: Vec<(&str, &[f64])> = names().into_iter().zip(columns.iter().map(Vec::as_slice)).collect();
    cols.push(("speed", &speed));
    let scalars = [("fs", 5000.0)];
    for compress in [false, true] {
        let path = d.join(format!("vars-{compress}.mat"));
        fixtures::mat(&path, &cols, &scalars, MatLayout::Variables, compress).unwrap();
        let m = map("mat", "sample_rate_from = \"fs\"", |k| format!("from = \"{}\"", names()[k]), "[speed]\nfrom = \"speed\"\nunit = \"Hz\"\n", "");
        let (rec, values, got_speed) = read_all(&path, &m).unwrap();
        assert_eq!(rec.sample_rate_hz, 5000.0);
        check_same(&values, &got_speed, &columns, &speed);

        let path = d.join(format!("struct-{compress}.mat"));
        fixtures::mat(&path, &cols, &scalars, MatLayout::Struct("rec"), compress).unwrap();
        let m = map("mat", "sample_rate_from = \"rec.fs\"", |k| format!("from = \"rec.{}\"", names()[k]), "[speed]\nfrom = \"rec.speed\"\nunit = \"Hz\"\n", "");
        let (_, values, got_speed) = read_all(&path, &m).unwrap();
        check_same(&values, &got_speed, &columns, &speed);

        let path = d.join(format!("matrix-{compress}.mat"));
        fixtures::mat(&path, &cols, &scalars, MatLayout::Matrix("data"), compress).unwrap();
        let m = map("mat", "sample_rate_hz = 5000", |k| format!("from = \"data\"\nindex = {k}"), "[speed]\nfrom = \"data\"\nindex = 10\nunit = \"Hz\"\n", "");
        let (_, values, got_speed) = read_all(&path, &m).unwrap();
        check_same(&values, &got_speed, &columns, &speed);
    }
}

#[test]
fn csv_with_a_units_row_and_a_time_column_reads_back_bit_for_bit() {
    let (columns, speed) = record();
    let d = dir("csv");
    let time: Vec<f64> = (0..N).map(|i| 12.5 + i as f64 / 5000.0).collect();
    let mut cols: Vec<(&str, &[f64])> = vec![("time", &time)];
    cols.extend(names().into_iter().zip(columns.iter().map(Vec::as_slice)));
    cols.push(("speed", &speed));
    let mut units = vec!["s"];
    units.extend(["V"; 10]);
    units.push("Hz");
    let path = d.join("r.csv");
    fixtures::csv(&path, &cols, Some(&units)).unwrap();
    let m = map(
        "csv",
        "sample_rate_from = \"time\"",
        |k| format!("from = \"{}\"", names()[k]),
        "[speed]\nfrom = \"speed\"\nunit = \"Hz\"\n",
        "[csv]\nunits_row = true",
    );
    let (rec, values, got_speed) = read_all(&path, &m).unwrap();
    assert_eq!(rec.sample_rate_hz, 5000.0);
    assert_eq!(rec.start_time_s, 12.5);
    check_same(&values, &got_speed, &columns, &speed);
    let by_index = map("csv", "sample_rate_hz = 5000", |k| format!("index = {}", k + 1), "[speed]\nindex = 11\nunit = \"Hz\"\n", "[csv]\nunits_row = true");
    let (_, values, got_speed) = read_all(&path, &by_index).unwrap();
    check_same(&values, &got_speed, &columns, &speed);
}

/// The message of a refused file.
fn refusal(result: Result<(ForeignRecord, Vec<f64>, Vec<f64>), ForeignError>) -> String {
    match result {
        Ok(_) => panic!("the file was read"),
        Err(e) => e.to_string(),
    }
}

fn says(message: &str, words: &[&str]) {
    eprintln!("refused: {message}");
    for w in words {
        assert!(message.contains(w), "`{message}` should say `{w}`");
    }
}

#[test]
fn broken_files_are_refused_naming_file_channel_and_place() {
    let (columns, speed) = record();
    let d = dir("bad");
    let tdms_map = map("tdms", "sample_rate_hz = 5000", |k| format!("from = \"{}/{}\"", GROUPS[k], names()[k]), "", "");

    // A TDMS file cut inside its last segment.
    let path = d.join("cut.tdms");
    fixtures::tdms(&path, &tdms_channels(&columns, &speed), TdmsLayout { segments: 4, interleaved: false, big_endian: false }).unwrap();
    let len = std::fs::metadata(&path).unwrap().len();
    let f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
    f.set_len(len - 1000).unwrap();
    says(&refusal(read_all(&path, &tdms_map)), &["cut.tdms", "segment 3 at byte", "truncated"]);
    // ... and inside a lead-in.
    let f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
    fixtures::tdms(&path, &tdms_channels(&columns, &speed), TdmsLayout { segments: 1, interleaved: false, big_endian: false }).unwrap();
    let whole = std::fs::read(&path).unwrap();
    std::fs::write(&path, [whole.as_slice(), &whole[..10]].concat()).unwrap();
    drop(f);
    says(&refusal(read_all(&path, &tdms_map)), &["segment 1 at byte", "lead-in", "truncated"]);

    // A mapped channel the file lacks.
    let path = d.join("missing.tdms");
    let mut chans = tdms_channels(&columns, &speed);
    chans.retain(|c| c.name != "f2");
    fixtures::tdms(&path, &chans, TdmsLayout { segments: 1, interleaved: false, big_endian: false }).unwrap();
    says(&refusal(read_all(&path, &tdms_map)), &["missing.tdms", "`Forces/f2` (f2)", "channel[7]", "no such channel", "`Forces/f1`"]);

    // Channels of different lengths: two files' segments one after the other (a valid TDMS
    // file), the second holding `frame_x` three values short.
    let path = d.join("lengths.tdms");
    let mut chans = tdms_channels(&columns, &speed);
    chans.retain(|c| c.name != "frame_x");
    fixtures::tdms(&path, &chans, TdmsLayout { segments: 2, interleaved: false, big_endian: false }).unwrap();
    let mut both = std::fs::read(&path).unwrap();
    let short = TdmsChannel { group: "Frame", name: "frame_x", values: &columns[4][..N - 3], properties: vec![] };
    fixtures::tdms(&path, &[short], TdmsLayout { segments: 1, interleaved: false, big_endian: false }).unwrap();
    both.extend(std::fs::read(&path).unwrap());
    std::fs::write(&path, both).unwrap();
    says(
        &refusal(read_all(&path, &tdms_map)),
        &["lengths.tdms", "differ in length", "`Frame/frame_x` (frame_x): 2342", "`Probes/probe_a_x` (probe_a_x): 2345"],
    );

    // A .mat variable of the wrong kind: a struct, and a matrix without a column.
    let path = d.join("kinds.mat");
    let mut cols: Vec<(&str, &[f64])> = names().into_iter().zip(columns.iter().map(Vec::as_slice)).collect();
    cols.push(("speed", &speed));
    fixtures::mat(&path, &cols, &[], MatLayout::Struct("rec"), true).unwrap();
    let m = map("mat", "sample_rate_hz = 5000", |k| if k == 2 { "from = \"rec\"".into() } else { format!("from = \"rec.{}\"", names()[k]) }, "", "");
    says(&refusal(read_all(&path, &m)), &["kinds.mat", "`rec` (probe_b_x)", "is a struct", "not real numbers"]);
    let path = d.join("matrix.mat");
    fixtures::mat(&path, &cols, &[], MatLayout::Matrix("data"), false).unwrap();
    let m = map("mat", "sample_rate_hz = 5000", |k| if k == 0 { "from = \"data\"".into() } else { format!("from = \"data\"\nindex = {k}") }, "", "");
    says(&refusal(read_all(&path, &m)), &["matrix.mat", "probe_a_x", "2345x11 matrix", "give index"]);
    // A text file called .mat, and a v7.3 (HDF5) one.
    let path = d.join("text.mat");
    std::fs::write(&path, "x,y\n1,2\n".repeat(40)).unwrap();
    says(&refusal(read_all(&path, &m)), &["text.mat", "not a MAT-file"]);
    let mut h5 = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: HDF5 schema 1.00 .".to_vec();
    h5.resize(600, 0);
    std::fs::write(&path, h5).unwrap();
    says(&refusal(read_all(&path, &m)), &["MATLAB 7.3", "save(file, '-v7')"]);
    // A compressed .mat cut short.
    let path = d.join("cut.mat");
    fixtures::mat(&path, &cols, &[], MatLayout::Struct("rec"), true).unwrap();
    let whole = std::fs::read(&path).unwrap();
    std::fs::write(&path, &whole[..whole.len() - 500]).unwrap();
    let m = map("mat", "sample_rate_hz = 5000", |k| format!("from = \"rec.{}\"", names()[k]), "", "");
    says(&refusal(read_all(&path, &m)), &["cut.mat", "byte 128", "truncated"]);

    // Ragged CSV: a row short of fields.
    let path = d.join("ragged.csv");
    let cols: Vec<(&str, &[f64])> = names().into_iter().zip(columns.iter().map(Vec::as_slice)).collect();
    fixtures::csv(&path, &cols, None).unwrap();
    let mut text = std::fs::read_to_string(&path).unwrap();
    text.push_str("1.0,2.0,3.0\n4.0,5.0,6.0,7.0,8.0,9.0,1.0,2.0,3.0,4.0\n");
    std::fs::write(&path, &text).unwrap();
    let m = map("csv", "sample_rate_hz = 5000", |k| format!("from = \"{}\"", names()[k]), "", "");
    says(&refusal(read_all(&path, &m)), &["ragged.csv", &format!("line {} (data row {})", N + 2, N + 1), "3 fields, the header has 10"]);
    // A mapped column the header lacks.
    let m2 = map("csv", "sample_rate_hz = 5000", |k| if k == 6 { "from = \"F1\"".into() } else { format!("from = \"{}\"", names()[k]) }, "", "");
    says(&refusal(read_all(&path, &m2)), &["ragged.csv", "`F1` (f1)", "line 1", "no column `F1`"]);
    // Comma decimals (pandas' decimal=',' with sep=';').
    let path = d.join("comma.csv");
    std::fs::write(&path, format!("{}\n{}\n", names().join(";"), ["0,125"; 10].join(";"))).unwrap();
    let m = map("csv", "sample_rate_hz = 5000", |k| format!("from = \"{}\"", names()[k]), "", "[csv]\ndelimiter = \";\"");
    says(&refusal(read_all(&path, &m)), &["comma.csv", "line 2, column 0", "`0,125` has a comma as its decimal separator"]);
    // The same with a comma delimiter: the numbers split, the rows are ragged, and it says why.
    std::fs::write(&path, format!("{}\n{}\n", names().join(","), ["0,125"; 10].join(","))).unwrap();
    let m = map("csv", "sample_rate_hz = 5000", |k| format!("from = \"{}\"", names()[k]), "", "");
    says(&refusal(read_all(&path, &m)), &["comma.csv", "line 2", "20 fields, the header has 10", "comma decimal separator"]);
    // A units row that disagrees with the map.
    let path = d.join("units.csv");
    let mut units = vec!["V"; 10];
    units[6] = "kN";
    fixtures::csv(&path, &cols, Some(&units)).unwrap();
    let m = map("csv", "sample_rate_hz = 5000", |k| format!("from = \"{}\"", names()[k]), "", "[csv]\nunits_row = true");
    says(&refusal(read_all(&path, &m)), &["units.csv", "(f1)", "line 2, column 6", "the units row says `kN`, the map's channel[6].unit `V`"]);
}
