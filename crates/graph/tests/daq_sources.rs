//! The DAQ node's line sources (ASCII replay and TCP stream, `oilfilm_graph::replay`), fed
//! by the shell's own reading functions: a simulated record written with the project's ASCII
//! writer comes back frame by frame bit for bit and identifies; malformed rows are reported
//! one by one with their line and column and skipped, losing no good row; a gap shows in the
//! frames and the conditioner restarts there; a TCP stream with a bad line and a reconnection
//! gives the file's frames.

use std::io::{BufReader, Write};
use std::net::TcpListener;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use oilfilm_graph::conditioner::ConditionerParams;
use oilfilm_graph::daq::DaqParams;
use oilfilm_graph::error::NodeError;
use oilfilm_graph::estimator::EstimatorParams;
use oilfilm_graph::exciter::ExciterParams;
use oilfilm_graph::lines::{read_lines, run_ascii_source, run_tcp_source, Backoff, ReplayPace};
use oilfilm_graph::replay::{Produced, ReplayCore};
use oilfilm_graph::runner::bag::reanalyse;
use oilfilm_graph::stamp::Stamp;
use oilfilm_identification::ascii::{self, Record, Units};
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_msgs::{DaqFrame, RigStatus};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::ChannelId;
use oilfilm_physics::operating_point::OperatingPoint;

const BLOCK: usize = 500;

struct Fixture {
    rig: RigConfig,
    truth: OperatingPoint,
    record: Record,
    text: String,
}

/// 5 s of the simulated Zhou rig under the exciter's default two-tone (23 and 37 Hz), in
/// volts, written with `ascii::write`. Simulated once for all tests.
fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let rig = RigConfig::zhou2004().unwrap();
        let plan = ExciterParams::default().plan().unwrap();
        let sim = simulate::simulate(&rig, &plan, 5.0, SimulateOptions::default(), &mut |_| {}).unwrap();
        let record = sim.to_ascii(&rig, Units::Volts).unwrap();
        let text = ascii::write(&record).unwrap();
        Fixture { rig, truth: sim.truth, record, text }
    })
}

fn params() -> DaqParams {
    DaqParams { source: "ascii".into(), file: "record.txt".into(), block_scans: BLOCK as i64, ..DaqParams::default() }
}

/// What a source gave: frames with their status, and every bad-row report.
#[derive(Default)]
struct Sink {
    frames: Vec<(DaqFrame, RigStatus)>,
    reports: Vec<NodeError>,
}

impl Sink {
    fn take(&mut self, out: Produced) -> Result<(), NodeError> {
        self.frames.extend(out.frames);
        self.reports.extend(out.bad_row);
        Ok(())
    }

    fn frames(&self) -> Vec<DaqFrame> {
        self.frames.iter().map(|(f, _)| f.clone()).collect()
    }

    fn status(&self) -> Vec<RigStatus> {
        self.frames.iter().map(|(_, s)| s.clone()).collect()
    }

    /// (line, column) of each report.
    fn positions(&self) -> Vec<(usize, usize)> {
        self.reports
            .iter()
            .map(|e| match e {
                NodeError::BadRecord { line, column, .. } => (*line, *column),
                other => panic!("not a BadRecord: {other}"),
            })
            .collect()
    }
}

/// Replays `text` as the node does (the shell's ASCII source, as fast as possible).
fn replay(text: &str, name: &str) -> (Sink, ReplayCore) {
    let f = fixture();
    let mut core = ReplayCore::new(&f.rig, &params(), "ascii replay", name).unwrap();
    let mut sink = Sink::default();
    let pace = ReplayPace { rate_factor: 0.0, duration_s: 0.0 };
    run_ascii_source(text.as_bytes(), &mut core, &pace, &|| false, &mut |out| sink.take(out)).unwrap();
    (sink, core)
}

/// Every scan of the frames: (scan index, values).
fn scans(frames: &[DaqFrame]) -> Vec<(u64, Vec<f64>)> {
    let mut out = Vec::new();
    for f in frames {
        let width = f.channel_names.len();
        assert_eq!(f.values.len(), f.scan_count as usize * width);
        for (k, scan) in f.values.chunks_exact(width).enumerate() {
            out.push((f.first_scan + k as u64, scan.to_vec()));
        }
    }
    out
}

/// The record's scans, except those at `missing` positions.
fn record_scans(record: &Record, missing: &[usize]) -> Vec<(u64, Vec<f64>)> {
    (0..record.len()).filter(|i| !missing.contains(i)).map(|i| (record.scan_index[i], record.columns.iter().map(|c| c[i]).collect())).collect()
}

fn bits(s: &[(u64, Vec<f64>)]) -> Vec<(u64, Vec<u64>)> {
    s.iter().map(|(n, v)| (*n, v.iter().map(|x| x.to_bits()).collect())).collect()
}

fn conditioner_params() -> ConditionerParams {
    // 1.5 x the highest line (37 Hz).
    ConditionerParams { lowpass_cutoff_hz: 55.5, block_scans: 1000, ..ConditionerParams::default() }
}

fn estimator_params() -> EstimatorParams {
    EstimatorParams { window: 10_000, hop: 5_000, ..EstimatorParams::default() }
}

#[test]
fn a_replayed_record_gives_its_values_bit_for_bit_and_identifies() {
    let f = fixture();
    let (sink, core) = replay(&f.text, "record.txt");
    let h = &f.record.header;
    let n = f.record.len();
    assert!(sink.reports.is_empty(), "{:?}", sink.reports);
    assert_eq!((core.malformed_rows(), core.gaps()), (0, 0));
    let frames = sink.frames();
    assert_eq!(frames.len(), n.div_ceil(BLOCK));
    assert_eq!(bits(&scans(&frames)), bits(&record_scans(&f.record, &[])));

    let epoch = Stamp((h.start_time_s * 1e9).round() as i64);
    let calibration = f.rig.daq.calibration();
    let column = |name: &str| f.record.column(name).unwrap();
    for (k, (frame, status)) in sink.frames.iter().enumerate() {
        let first = f.record.scan_index[0] + (k * BLOCK) as u64;
        let count = BLOCK.min(n - k * BLOCK);
        assert_eq!(frame.sequence, k as u64);
        assert_eq!(frame.first_scan, first);
        assert_eq!(frame.scan_count as usize, count);
        assert_eq!(Stamp::from_time(&frame.header.stamp), epoch.after_samples(first as i64, h.sample_rate_hz));
        assert_eq!(frame.sample_rate_hz, h.sample_rate_hz);
        assert_eq!(frame.units, DaqFrame::UNITS_VOLTS);
        assert_eq!(frame.channel_names, h.channels);
        assert!(frame.channel_units.iter().all(|u| u == "V"));
        let offsets: Vec<f64> = (0..h.channels.len()).map(|p| h.channel_offset_s(p).unwrap()).collect();
        assert_eq!(frame.channel_offsets_s, offsets);
        assert_eq!(frame.rig, h.rig);
        // The status after the frame: at the next scan, the header's speed, the frame's mean
        // static load and temperature in SI.
        assert_eq!(Stamp::from_time(&status.header.stamp), epoch.after_samples((first + count as u64) as i64, h.sample_rate_hz));
        assert_eq!(status.speed_rad_s, h.speed_rpm.unwrap() * std::f64::consts::PI / 30.0);
        let mean = |name: &str, ch: ChannelId| {
            let rows = k * BLOCK..k * BLOCK + count;
            column(name)[rows].iter().map(|v| calibration.to_si(ch, *v).unwrap()).sum::<f64>() / count as f64
        };
        assert_eq!(status.static_load_n, mean("f3", ChannelId::F3).abs());
        assert_eq!(status.bearing_temperature_degc, mean("temperature", ChannelId::Temperature));
        assert!(status.static_load_n > 1000.0 && (20.0..80.0).contains(&status.bearing_temperature_degc));
        assert!(status.message.contains("speed from the record's header"), "{}", status.message);
    }

    // Through the conditioner and the estimator: every window solved, near the film's
    // coefficients.
    let out = reanalyse(&f.rig, &conditioner_params(), &estimator_params(), &frames, &sink.status()).unwrap();
    assert!(!out.conditioned.is_empty());
    assert_eq!(out.conditioned.iter().filter(|c| c.flags.iter().any(|f| f.contains("stream"))).count(), 1, "one stream start, no restart");
    assert!(out.estimates.len() >= 2, "{} estimates", out.estimates.len());
    let kt = f.truth.coefficients.stiffness_n_m;
    for e in &out.estimates {
        assert!(e.solved, "window {}..{} refused: {}", e.window_start_sample, e.window_end_sample, e.refusal_reason);
        assert!(e.flags.iter().any(|f| f == "speed from rig/status"), "{:?}", e.flags);
        for (k, name) in ["xx", "yy"].iter().enumerate() {
            let (i, j) = (k, k);
            let rel = (e.stiffness_n_m[2 * i + j] - kt[(i, j)]) / kt[(i, j)];
            assert!(rel.abs() < 0.1, "k{name} {:.4e} vs truth {:.4e}", e.stiffness_n_m[2 * i + j], kt[(i, j)]);
        }
    }
}

/// (line, column, words of the message) of an expected report.
type Expected = Vec<(usize, usize, &'static str)>;

/// The fixture's text with bad lines injected; returns the text, the expected reports, and
/// the record positions of the rows left out.
fn damaged() -> (String, Expected, Vec<usize>) {
    let f = fixture();
    let lines: Vec<&str> = f.text.lines().collect();
    let first_row = lines.iter().position(|l| l.starts_with("scan ")).unwrap() + 1;
    let row = |i: usize| lines[first_row + i];
    // Each entry: after record row `i`, the line to insert (None: none), and whether row
    // `i` itself is left out (a skipped scan).
    let mut out: Vec<String> = lines[..first_row].iter().map(|l| l.to_string()).collect();
    let mut expected = Vec::new();
    let missing = vec![2600];
    for i in 0..f.record.len() {
        if missing.contains(&i) {
            continue;
        }
        // CR LF line ends on a stretch of rows: legal, no report.
        if (1000..1010).contains(&i) {
            out.push(format!("{}\r", row(i)));
        } else {
            out.push(row(i).to_string());
        }
        let next = || row(i + 1).split(' ').collect::<Vec<_>>();
        let bad: Option<(String, usize, &str)> = match i {
            // Ragged: the next row without its last value.
            700 => Some((next()[..10].join(" "), 0, "expected 11 fields")),
            // Ragged the other way: an extra field, reported where it starts.
            710 => {
                let line = format!("{} 7", row(i + 1));
                let column = line.len();
                Some((line, column, "found 12"))
            }
            // A bad number in channel 4 (the fifth field).
            1500 => {
                let mut fields = next();
                fields[4] = "1.2.3";
                let column = fields[..4].iter().map(|s| s.len() + 1).sum::<usize>() + 1;
                Some((fields.join(" "), column, "`1.2.3` is not a number"))
            }
            // The same row again: its scan index does not increase.
            2000 => Some((row(i).to_string(), 1, "does not increase")),
            // A stray header line.
            3000 => Some(("# units: si".to_string(), 1, "header line after the column line")),
            // Blank and comment lines: legal, no report.
            3500 => Some((String::new(), 0, "")),
            3600 => Some(("## operator: probe B re-zeroed".to_string(), 0, "")),
            _ => None,
        };
        if let Some((line, column, words)) = bad {
            out.push(line);
            if !words.is_empty() {
                expected.push((out.len(), column, words));
            }
        }
        // The row after the skipped scan: reported as a gap, kept.
        if missing.contains(&(i + 1)) {
            expected.push((out.len() + 1, 1, "skips scan"));
        }
    }
    (out.join("\n") + "\n", expected, missing)
}

#[test]
fn malformed_rows_are_reported_with_their_position_and_skipped_and_a_gap_restarts_the_conditioner() {
    let f = fixture();
    let (text, expected, missing) = damaged();
    let (sink, core) = replay(&text, "damaged.txt");

    // One report per bad row, in order, naming the file, line and column.
    let want: Vec<(usize, usize)> = expected.iter().map(|(l, c, _)| (*l, *c)).collect();
    assert_eq!(sink.positions(), want, "{:#?}", sink.reports);
    for (e, (line, column, words)) in sink.reports.iter().zip(&expected) {
        let shown = e.to_string();
        assert!(shown.starts_with(&format!("damaged.txt:{line}:{column}: ")), "{shown}");
        assert!(shown.contains(words), "{shown} lacks {words}");
    }
    assert_eq!((core.malformed_rows(), core.gaps()), (5, 1));

    // No good row lost: the frames hold every scan of the record but the skipped one, bit
    // for bit, and no frame spans the gap.
    let frames = sink.frames();
    assert_eq!(bits(&scans(&frames)), bits(&record_scans(&f.record, &missing)));
    let skipped = f.record.scan_index[missing[0]];
    let before = frames.iter().find(|fr| fr.first_scan < skipped && fr.first_scan + fr.scan_count as u64 >= skipped).unwrap();
    assert_eq!(before.first_scan + before.scan_count as u64, skipped, "the frame before the gap ends at it");
    assert!(frames.iter().any(|fr| fr.first_scan == skipped + 1), "a frame starts after the gap");
    assert!(frames.iter().all(|fr| !(fr.first_scan..fr.first_scan + fr.scan_count as u64).contains(&skipped)));
    let messages: Vec<&str> = sink.frames.iter().map(|(_, s)| s.message.as_str()).collect();
    assert!(messages.last().unwrap().contains("5 malformed row(s) skipped; 1 gap(s)"), "{messages:?}");

    // The conditioner says where its stream restarted.
    let out = reanalyse(&f.rig, &conditioner_params(), &estimator_params(), &frames, &sink.status()).unwrap();
    let restarts: Vec<&String> = out.conditioned.iter().flat_map(|c| &c.flags).filter(|f| f.contains("restarted")).collect();
    assert_eq!(restarts.len(), 1, "{restarts:?}");
    assert!(restarts[0].contains(&format!("stream restarted at scan {}: 1 scans missing (expected scan {skipped})", skipped + 1)), "{}", restarts[0]);
    assert!(out.estimates.iter().any(|e| e.solved));
}

#[test]
fn a_bad_header_is_fatal_with_its_position() {
    let f = fixture();
    let text = f.text.replacen("# units: volts", "# units: millivolts", 1);
    let mut core = ReplayCore::new(&f.rig, &params(), "ascii replay", "bad.txt").unwrap();
    let pace = ReplayPace { rate_factor: 0.0, duration_s: 0.0 };
    let mut sink = Sink::default();
    let err = run_ascii_source(text.as_bytes(), &mut core, &pace, &|| false, &mut |out| sink.take(out)).unwrap_err();
    let line = f.text.lines().position(|l| l == "# units: volts").unwrap() + 1;
    assert_eq!(err.to_string(), format!("bad.txt:{line}:10: units must be `si` or `volts`, found `millivolts`"));
    assert!(sink.frames.is_empty());
    // A record cut inside its header is refused at its last line.
    let cut: String = f.text.lines().take(3).map(|l| format!("{l}\n")).collect();
    let mut core = ReplayCore::new(&f.rig, &params(), "ascii replay", "cut.txt").unwrap();
    let err = run_ascii_source(cut.as_bytes(), &mut core, &pace, &|| false, &mut |out| sink.take(out)).unwrap_err();
    assert!(err.to_string().starts_with("cut.txt:3:0: the file ends before the column line"), "{err}");
}

#[test]
fn read_lines_numbers_lines_keeps_line_ends_and_reports_an_unterminated_last_line() {
    let mut got = Vec::new();
    let text: &[u8] = b"a\r\n\nb\xff c\nlast";
    let end = read_lines(BufReader::with_capacity(2, text), &|| false, &mut |n, l, cut| {
        assert!(!cut);
        got.push((n, l.to_string()));
        Ok(())
    })
    .unwrap();
    assert_eq!(got, [(1, "a\r\n".to_string()), (2, "\n".to_string()), (3, "b\u{fffd} c\n".to_string())]);
    match end {
        oilfilm_graph::lines::LinesEnd::Eof { unterminated } => assert_eq!(unterminated, Some((4, "last".to_string()))),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_tcp_stream_with_a_bad_line_and_a_reconnection_gives_the_files_frames() {
    let f = fixture();
    let (file, _) = replay(&f.text, "record.txt");
    let lines: Vec<&str> = f.text.lines().collect();
    let first_row = lines.iter().position(|l| l.starts_with("scan ")).unwrap() + 1;
    let header = &lines[..first_row];
    let rows = &lines[first_row..];
    // The first connection carries 4000 rows (8 frames) with a garbage line after row
    // 1234, then half of row 4000 and drops; the second a new header and the rest.
    let split = 8 * BLOCK;
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let address = listener.local_addr().unwrap().to_string();
    let (header_text, first, second): (String, Vec<String>, Vec<String>) = {
        let h: String = header.iter().map(|l| format!("{l}\n")).collect();
        let mut first: Vec<String> = rows[..split].iter().map(|l| format!("{l}\n")).collect();
        first.insert(1235, "1234 oops\n".to_string());
        first.push(rows[split][..20].to_string());
        (h, first, rows[split..].iter().map(|l| format!("{l}\r\n")).collect())
    };
    let bad_line = header.len() + 1236;
    let server = std::thread::spawn(move || {
        for body in [first, second] {
            let (mut s, _) = listener.accept().unwrap();
            s.write_all(header_text.as_bytes()).unwrap();
            for chunk in body.chunks(700) {
                s.write_all(chunk.concat().as_bytes()).unwrap();
            }
        }
        // The listener closes: further connections are refused until the client stops.
    });

    let mut core = ReplayCore::new(&f.rig, &DaqParams { source: "tcp".into(), address: address.clone(), ..params() }, "tcp stream", &address).unwrap();
    let last_scan = *f.record.scan_index.last().unwrap();
    let sink = std::cell::RefCell::new(Sink::default());
    let backoff = Backoff { initial: Duration::from_millis(10), max: Duration::from_millis(50) };
    // Stops once the last scan is out. The deadline only keeps a broken build from hanging
    // the suite; nothing is judged on time.
    let deadline = Instant::now() + Duration::from_secs(120);
    let stop = || Instant::now() > deadline || sink.borrow().frames.last().is_some_and(|(fr, _)| fr.first_scan + fr.scan_count as u64 > last_scan);
    run_tcp_source(&address, &mut core, &backoff, &stop, &mut |out| sink.borrow_mut().take(out)).unwrap();
    server.join().unwrap();
    let sink = sink.into_inner();

    assert_eq!(sink.positions(), [(bad_line, 0)], "{:?}", sink.reports);
    assert!(sink.reports[0].to_string().starts_with(&format!("tcp://{address}#1:{bad_line}:0: expected 11 fields")), "{}", sink.reports[0]);
    assert_eq!(core.malformed_rows(), 1);
    // The same frames as the file's replay: values, stamps, sequence, everything.
    assert_eq!(sink.frames(), file.frames());
    let statuses = sink.status();
    for (a, b) in statuses.iter().zip(file.status()) {
        assert_eq!(
            (&a.header.stamp, a.speed_rad_s, a.static_load_n, a.bearing_temperature_degc),
            (&b.header.stamp, b.speed_rad_s, b.static_load_n, b.bearing_temperature_degc)
        );
    }
    assert!(statuses[0].message.starts_with(&format!("tcp stream of tcp://{address}#1")), "{}", statuses[0].message);
    assert!(statuses.last().unwrap().message.starts_with(&format!("tcp stream of tcp://{address}#2")));
}

#[test]
fn daq_params_accept_the_ascii_and_tcp_sources_with_what_they_need() {
    let p = |source: &str, file: &str, address: &str| DaqParams { source: source.into(), file: file.into(), address: address.into(), ..DaqParams::default() };
    assert!(p("ascii", "run.txt", "").validate().is_ok());
    assert!(p("tcp", "", "daq-host:5000").validate().is_ok());
    assert!(p("tcp", "", "[::1]:5000").validate().is_ok());
    for (bad, name) in [
        (p("ascii", "", ""), "file"),
        (p("tcp", "", ""), "address"),
        (p("tcp", "", "daq-host"), "address"),
        (p("tcp", "", "h:99999"), "address"),
        (p("udp", "", ""), "source"),
    ] {
        match bad.validate() {
            Err(NodeError::Parameter { name: n, .. }) => assert_eq!(n, name),
            other => panic!("{bad:?}: {other:?}"),
        }
    }
}

/// A flood of bad lines gives one warning a second with the count held back, not one a line.
#[test]
fn bad_row_warnings_are_limited_to_one_a_second_with_a_count() {
    use oilfilm_graph::lines::WarnLimiter;
    let mut w = WarnLimiter::new(Duration::from_secs(1));
    let t0 = Instant::now();
    // 4000 bad lines in 2.5 s (1 MiB of garbage at about the rate a socket delivers it).
    let shown: Vec<(u64, u64)> = (0..4000u64)
        .filter_map(|k| {
            let at = t0 + Duration::from_micros(k * 625);
            w.admit(at).map(|held| (k, held))
        })
        .collect();
    assert_eq!(shown.iter().map(|&(k, _)| k).collect::<Vec<_>>(), [0, 1600, 3200], "one at the start, then one a second");
    assert_eq!(shown.iter().map(|&(_, h)| h).collect::<Vec<_>>(), [0, 1599, 1599], "each says how many it stands for");
    assert_eq!(w.take_held(), 799, "the rest, for the end-of-stream summary");
    assert_eq!(w.take_held(), 0);
}

/// A TCP source faster than the node: the queue holds at most its stated number of outputs
/// and the rest are dropped and counted, not held in memory; output without frames is not
/// queued at all. Every status the node takes carries the count so far in `frames_dropped`:
/// 0 before the flood, the whole count on the statuses still queued when it ended.
#[test]
fn a_flooded_queue_drops_and_counts_frames_instead_of_growing() {
    use oilfilm_graph::lines::{DroppingSender, FrameQueue, QUEUE_FRAMES};
    use std::sync::atomic::{AtomicU64, Ordering};
    use std::sync::mpsc::TryRecvError;
    use std::sync::Arc;
    let (tx, rx) = std::sync::mpsc::sync_channel(QUEUE_FRAMES);
    let dropped = Arc::new(AtomicU64::new(0));
    let mut sender = DroppingSender::new(tx, Arc::clone(&dropped));
    let queue = FrameQueue::new(rx, Arc::clone(&dropped));
    // A status that claims drops of its own: the queue's count replaces it.
    let one = || Produced { frames: vec![(DaqFrame::default(), RigStatus { frames_dropped: 12345, ..RigStatus::default() })], bad_row: None };
    let take_all = |queue: &FrameQueue| -> Vec<u64> {
        let mut counts = Vec::new();
        loop {
            match queue.take(Duration::ZERO) {
                Ok(out) => counts.extend(out.frames.iter().map(|(_, s)| s.frames_dropped)),
                Err(TryRecvError::Empty) => return counts,
                Err(TryRecvError::Disconnected) => panic!("the sending end is alive"),
            }
        }
    };
    sender.send(one()).unwrap();
    assert_eq!(take_all(&queue), [0], "nothing dropped yet");
    for _ in 0..100 * QUEUE_FRAMES {
        sender.send(one()).unwrap();
        sender.send(Produced { frames: Vec::new(), bad_row: None }).unwrap();
    }
    let count = dropped.load(Ordering::SeqCst);
    assert_eq!(count, 99 * QUEUE_FRAMES as u64, "every other frame is counted as dropped");
    let taken = take_all(&queue);
    assert_eq!(taken.len(), QUEUE_FRAMES, "the queue holds its limit");
    assert!(taken.iter().all(|&n| n == count), "every status taken says {count} dropped: {taken:?}");
    sender.send(one()).unwrap();
    assert_eq!(take_all(&queue), [count], "room again once the node takes frames; the count stays (cumulative)");
    drop(queue);
    assert!(sender.send(one()).is_err(), "a stopped node ends the reading");
}

/// An ASCII replay in the in-memory runner holds bounded memory whatever the record's length:
/// the reader reads ahead at most its queue, and a turn of the node hands on at most that
/// many frames (before, a turn took frames for as long as the reader kept adding them, so a
/// fast reader could make one turn publish without end before the nodes downstream ran); and
/// every frame of the record still arrives. Gzip-compressed, the same frames.
#[test]
fn an_ascii_replay_hands_on_a_bounded_number_of_frames_a_turn_and_all_of_them() {
    use flate2::write::GzEncoder;
    use oilfilm_graph::daq::Daq;
    use oilfilm_graph::lines::QUEUE_FRAMES;
    use oilfilm_graph::runner::memory::Graph;
    use oilfilm_graph::topics;
    let f = fixture();
    let dir = std::env::temp_dir().join(format!("oilfilm-daq-sources-bounded-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (plain, gz) = (dir.join("record.txt"), dir.join("record.txt.gz"));
    std::fs::write(&plain, &f.text).unwrap();
    let mut enc = GzEncoder::new(std::fs::File::create(&gz).unwrap(), flate2::Compression::fast());
    enc.write_all(f.text.as_bytes()).unwrap();
    enc.finish().unwrap();
    // Frames of one scan: many more frames than the queue holds, each quicker to read than
    // the reader's queue takes to empty.
    let block = 1;
    let mut runs = Vec::new();
    for file in [&plain, &gz] {
        let p = DaqParams { file: file.display().to_string(), block_scans: block, rate_factor: 0.0, ..params() };
        let mut g = Graph::new(topics::NAMESPACE);
        g.add::<Daq>("daq", &p, Some(&f.rig)).unwrap();
        let mut tap = g.tap::<DaqFrame>(&topics::DAQ_FRAMES).unwrap();
        let (mut most, mut frames) = (0, Vec::new());
        g.run_with(&mut || {
            // Slower than the reader: its queue is full at every turn.
            std::thread::sleep(Duration::from_millis(1));
            let turn = tap.drain();
            most = most.max(turn.len());
            frames.extend(turn);
            Ok(())
        })
        .unwrap();
        assert!(most <= QUEUE_FRAMES, "{}: a turn handed on {most} frames (at most {QUEUE_FRAMES})", file.display());
        assert_eq!(frames.len(), f.record.len().div_ceil(block as usize), "{}: every frame", file.display());
        runs.push(bits(&scans(&frames)));
    }
    assert_eq!(runs[0], bits(&record_scans(&f.record, &[])), "the record's values");
    assert_eq!(runs[1], runs[0], "the gzip record gives the same frames");
    let _ = std::fs::remove_dir_all(&dir);
}
