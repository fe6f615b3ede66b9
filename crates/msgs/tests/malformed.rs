//! Malformed bytes are refused with an error naming the field, never a panic.

use oilfilm_msgs::cdr::{decode, decode_exact, encode};
use oilfilm_msgs::{CoefficientEstimate, DaqFrame, Header, RigStatus, Time};

fn sample_daq() -> DaqFrame {
    DaqFrame {
        header: Header { stamp: Time { sec: 3, nanosec: 4 }, frame_id: "oilfilm_bearing".into() },
        sequence: 5,
        channel_names: vec!["f1".into(), "f2".into()],
        channel_units: vec!["N".into(), "N".into()],
        channel_offsets_s: vec![0.0, 1e-5],
        scan_count: 1,
        values: vec![1.0, 2.0],
        rig: "zhou2004".into(),
        ..Default::default()
    }
}

/// The same frame with counts: both appended fields present.
fn sample_counts() -> DaqFrame {
    DaqFrame { units: DaqFrame::UNITS_COUNTS, values: Vec::new(), volts_per_count: vec![3.0e-4, 3.0e-4], counts: vec![-7, 12_000], ..sample_daq() }
}

oilfilm_msgs::ros_message! {
    /// `DaqFrame` as first released, before `volts_per_count` and `counts` were appended: what
    /// a bag recorded then holds.
    pub struct DaqFrameV1 = "oilfilm_msgs/msg/DaqFrame", definition = ""; {
        pub header: Header,
        pub sequence: u64,
        pub first_scan: u64,
        pub sample_rate_hz: f64,
        pub units: u8,
        pub channel_names: Vec<String>,
        pub channel_units: Vec<String>,
        pub channel_offsets_s: Vec<f64>,
        pub scan_count: u32,
        pub values: Vec<f64>,
        pub rig: String,
    }
    constants {}
}

/// The fields a first-release writer would have sent of `f`.
fn as_v1(f: &DaqFrame) -> DaqFrameV1 {
    DaqFrameV1 {
        header: f.header.clone(),
        sequence: f.sequence,
        first_scan: f.first_scan,
        sample_rate_hz: f.sample_rate_hz,
        units: f.units,
        channel_names: f.channel_names.clone(),
        channel_units: f.channel_units.clone(),
        channel_offsets_s: f.channel_offsets_s.clone(),
        scan_count: f.scan_count,
        values: f.values.clone(),
        rig: f.rig.clone(),
    }
}

#[test]
fn every_truncation_is_an_error_not_a_panic() {
    let bytes = encode(&sample_counts());
    // The appended fields follow the first release's bytes unchanged: a cut where those end
    // (or in the padding after them) is a complete old frame, every other cut an error.
    let old = encode(&as_v1(&sample_counts()));
    assert_eq!(bytes[..old.len()], old[..]);
    let mut complete_old = 0;
    for n in 0..bytes.len() {
        match decode::<DaqFrame>(&bytes[..n]) {
            Err(e) => assert!(e.offset <= n, "{e}"),
            Ok(f) => {
                assert!((old.len()..old.len() + 4).contains(&n), "a cut at {n} of {} decoded: {f:?}", bytes.len());
                assert!(f.counts.is_empty() && f.volts_per_count.is_empty(), "{f:?}");
                complete_old += 1;
            }
        }
    }
    assert!(complete_old >= 1, "the cut at the first release's end ({}) must decode", old.len());
}

#[test]
fn a_frame_recorded_before_the_appended_fields_decodes_with_them_empty() {
    let volts = DaqFrame {
        first_scan: 9,
        sample_rate_hz: 5000.0,
        units: DaqFrame::UNITS_VOLTS,
        channel_units: vec!["V".into(), "V".into()],
        values: vec![0.25, -1.5],
        ..sample_daq()
    };
    let old = encode(&as_v1(&volts));
    let now: DaqFrame = decode_exact(&old).expect("an old frame decodes");
    assert_eq!(now, volts);
    now.check_samples().expect("an old frame's samples are where its units say");
    // And a frame with counts carries them through a round trip.
    let c = sample_counts();
    assert_eq!(decode_exact::<DaqFrame>(&encode(&c)).expect("round trip"), c);
}

#[test]
fn samples_decode_counts_and_name_what_is_inconsistent() {
    let c = sample_counts();
    let mut buf = vec![99.0];
    assert_eq!(c.samples(&mut buf).expect("counts"), [-7.0 * 3.0e-4, 12_000.0 * 3.0e-4]);
    let ranges = DaqFrame { volts_per_count: vec![3.0e-4, 1.0e-3], scan_count: 2, counts: vec![-7, 12_000, 5, -5], ..sample_counts() };
    assert_eq!(ranges.samples(&mut buf).expect("a range per channel"), [-7.0 * 3.0e-4, 12_000.0 * 1.0e-3, 5.0 * 3.0e-4, -5.0 * 1.0e-3]);
    let v = sample_daq();
    assert_eq!(v.samples(&mut buf).expect("values"), [1.0, 2.0]);
    let cases: [(DaqFrame, &str); 6] = [
        (DaqFrame { counts: vec![1], ..sample_counts() }, "1 counts, but scan_count 1 x 2 channels = 2"),
        (DaqFrame { volts_per_count: vec![3.0e-4], ..sample_counts() }, "1 volts_per_count for 2 channel_names"),
        (DaqFrame { volts_per_count: vec![3.0e-4, f64::NAN], ..sample_counts() }, "volts_per_count[1] (channel `f2`) = NaN"),
        (DaqFrame { values: vec![1.0, 2.0], ..sample_counts() }, "values holds 2 element(s); it must be empty with UNITS_COUNTS"),
        (DaqFrame { counts: vec![1, 2], ..sample_daq() }, "counts holds 2 element(s); it must be empty with UNITS_SI"),
        (DaqFrame { units: 7, ..sample_daq() }, "units = 7 is none of"),
    ];
    for (frame, want) in cases {
        let e = frame.samples(&mut buf).expect_err(want);
        assert!(e.contains(want), "{e} (wanted `{want}`)");
    }
}

/// `extend_columns` appends what `samples` gives, channel by channel, for counts with one
/// range or a range per channel and for values, over more scans than one tile, any picks in
/// any order; a bad pick or an inconsistent frame is refused with nothing appended.
#[test]
fn extend_columns_appends_the_samples_of_the_picked_channels() {
    let width = 3;
    let scans = 600;
    let names: Vec<String> = ["xa", "ya", "f1"].iter().map(|s| s.to_string()).collect();
    let counts: Vec<i16> = (0..scans * width).map(|i| ((i * 7919) % 65_536) as i32 - 32_768).map(|q| q as i16).collect();
    let base = DaqFrame {
        channel_names: names.clone(),
        channel_units: vec!["V".into(); width],
        channel_offsets_s: vec![0.0; width],
        scan_count: scans as u32,
        ..sample_counts()
    };
    let frames = [
        DaqFrame { units: DaqFrame::UNITS_COUNTS, counts: counts.clone(), volts_per_count: vec![3.0e-4; width], ..base.clone() },
        DaqFrame { units: DaqFrame::UNITS_COUNTS, counts: counts.clone(), volts_per_count: vec![3.0e-4, 1.0e-3, 7.0e-5], ..base.clone() },
        DaqFrame {
            units: DaqFrame::UNITS_VOLTS,
            counts: Vec::new(),
            volts_per_count: Vec::new(),
            values: counts.iter().map(|&q| f64::from(q) * 0.37).collect(),
            ..base.clone()
        },
    ];
    for frame in &frames {
        let mut buf = Vec::new();
        let all = frame.samples(&mut buf).expect("consistent").to_vec();
        let picks = [2, 0];
        let mut columns = vec![vec![-1.0], Vec::new()];
        frame.extend_columns(&picks, &mut columns).expect("consistent");
        for (k, &c) in picks.iter().enumerate() {
            let want: Vec<f64> = all[c..].iter().step_by(width).copied().collect();
            let got = if k == 0 { &columns[k][1..] } else { &columns[k][..] };
            assert_eq!(
                got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                "units {} channel {c}",
                frame.units
            );
        }
        assert_eq!(columns[0][0], -1.0, "appended after what the column held");
        let e = frame.extend_columns(&[0, 3], &mut columns).expect_err("no channel 3");
        assert!(e.contains("channel 3") && e.contains("3 channels"), "{e}");
        assert_eq!(columns[1].len(), scans, "nothing appended on error");
    }
    let ragged = DaqFrame { counts: vec![1; scans * width - 1], ..frames[0].clone() };
    let e = ragged.extend_columns(&[0], &mut [Vec::new()]).expect_err("ragged");
    assert!(e.contains("counts, but scan_count"), "{e}");
}

#[test]
fn pack_counts_only_when_lossless() {
    let lsb = 2.0 * 10.0 / 65536.0;
    let volts = DaqFrame { units: DaqFrame::UNITS_VOLTS, values: vec![-7.0 * lsb, 12_000.0 * lsb], ..sample_daq() };
    let mut packed = volts.clone();
    assert!(packed.pack_counts(&[lsb, lsb]));
    assert_eq!((packed.units, packed.counts.as_slice(), packed.values.len()), (DaqFrame::UNITS_COUNTS, &[-7i16, 12_000][..], 0));
    let mut buf = Vec::new();
    assert_eq!(packed.samples(&mut buf).expect("counts"), volts.values, "the counts decode to the very same volts");
    for values in [vec![0.3 * lsb, 0.0], vec![40_000.0 * lsb, 0.0], vec![f64::NAN, 0.0], vec![-0.0, 0.0]] {
        let mut f = DaqFrame { values, ..volts.clone() };
        let before = format!("{f:?}");
        assert!(!f.pack_counts(&[lsb, lsb]), "{before}");
        assert_eq!(format!("{f:?}"), before, "unchanged when not lossless (compared as text: NaN)");
    }
    let mut si = sample_daq();
    assert!(!si.pack_counts(&[lsb, lsb]), "SI values are not counts");
}
oilfilm_msgs::ros_message! {
    /// `RigStatus` as first released, before `frames_dropped` was appended: what a bag
    /// recorded then holds.
    pub struct RigStatusV1 = "oilfilm_msgs/msg/RigStatus", definition = ""; {
        pub header: Header,
        pub speed_rad_s: f64,
        pub static_load_n: f64,
        pub bearing_temperature_degc: f64,
        pub state: u8,
        pub message: String,
    }
    constants {}
}

/// A status recorded before `frames_dropped` existed decodes with it 0; one with it keeps
/// it; and a cut anywhere in the appended field (or its padding) is an error, not a status
/// with a made-up count. The message lengths put the end of `message` at each offset modulo
/// 8, so the padding before the `uint64` takes every length from 0 to 7.
#[test]
fn a_status_recorded_before_frames_dropped_decodes_with_it_zero_and_a_cut_one_is_refused() {
    for len in 0..8 {
        let s = RigStatus {
            header: Header { stamp: Time { sec: 3, nanosec: 4 }, frame_id: "oilfilm_bearing".into() },
            speed_rad_s: 157.0,
            state: RigStatus::STATE_RUNNING,
            message: "m".repeat(len),
            frames_dropped: 0x0102_0304_0506_0708,
            ..Default::default()
        };
        let old = RigStatusV1 {
            header: s.header.clone(),
            speed_rad_s: s.speed_rad_s,
            static_load_n: s.static_load_n,
            bearing_temperature_degc: s.bearing_temperature_degc,
            state: s.state,
            message: s.message.clone(),
        };
        let old_bytes = encode(&old);
        let got: RigStatus = decode_exact(&old_bytes).expect("an old status decodes");
        assert_eq!(got, RigStatus { frames_dropped: 0, ..s.clone() }, "message of {len} bytes");
        let bytes = encode(&s);
        assert_eq!(bytes[..old_bytes.len()], old_bytes[..], "the field follows the first release's bytes unchanged");
        assert_eq!(decode_exact::<RigStatus>(&bytes).expect("round trip"), s);
        for n in old_bytes.len()..bytes.len() {
            match decode::<RigStatus>(&bytes[..n]) {
                Ok(got) => {
                    assert!(n < old_bytes.len() + 4, "message of {len} bytes: a cut at {n} of {} decoded: {got:?}", bytes.len());
                    assert_eq!(got.frames_dropped, 0, "a cut in the padding is an old status");
                }
                Err(e) => assert!(n >= old_bytes.len() + 4 && e.to_string().contains("frames_dropped"), "message of {len} bytes, cut at {n}: {e}"),
            }
        }
    }
}

#[test]
fn every_single_byte_corruption_decodes_or_errors() {
    let bytes = encode(&sample_daq());
    for i in 0..bytes.len() {
        for v in [0x00, 0x7f, 0xff] {
            let mut b = bytes.clone();
            b[i] = v;
            let _ = decode::<DaqFrame>(&b);
        }
    }
}

#[test]
fn errors_name_the_field() {
    let mut bytes = encode(&sample_daq());
    // The count of channel_names sits after header (4 + 28 + pad 4), sequence, first_scan,
    // sample_rate_hz, units (+3 pad): offset 4 + 60.
    bytes[4 + 60..4 + 64].copy_from_slice(&1_000_000u32.to_le_bytes());
    let e = decode::<DaqFrame>(&bytes).expect_err("huge count");
    assert_eq!(e.field, "channel_names", "{e}");

    let mut bytes = encode(&sample_daq());
    bytes[4 + 8..4 + 12].copy_from_slice(&0u32.to_le_bytes());
    let e = decode::<DaqFrame>(&bytes).expect_err("zero-length string");
    assert_eq!(e.field, "header.frame_id", "{e}");

    let s = RigStatus { message: "x".into(), ..Default::default() };
    let mut bytes = encode(&s);
    // The message's NUL: after it come the padding and `frames_dropped`.
    let nul = bytes.windows(2).position(|w| w == b"x\0").expect("the message is encoded") + 1;
    bytes[nul] = b'y';
    let e = decode::<RigStatus>(&bytes).expect_err("no NUL");
    assert_eq!(e.field, "message", "{e}");

    let mut bytes = encode(&CoefficientEstimate::default());
    // `solved` (bool) follows model (uint8) right after window_end_sample.
    let solved_at = 4 + 16 + 8 + 8 + 8 + 8 + 8 + 1;
    bytes[solved_at] = 2;
    let e = decode::<CoefficientEstimate>(&bytes).expect_err("bool 2");
    assert_eq!(e.field, "solved", "{e}");
}

#[test]
fn header_and_trailing_bytes_are_checked() {
    let bytes = encode(&RigStatus::default());
    let mut be = bytes.clone();
    be[1] = 0x00;
    assert!(decode::<RigStatus>(&be).expect_err("big endian").to_string().contains("big-endian"));
    let mut long = bytes.clone();
    long.extend([0, 0, 0]);
    decode_exact::<RigStatus>(&long).expect("3 bytes of trailing padding are accepted");
    long.push(0);
    assert!(decode_exact::<RigStatus>(&long).is_err());
    decode::<RigStatus>(&long).expect("decode ignores what follows the last field");
}

#[test]
fn time_from_seconds() {
    assert_eq!(Time::from_seconds(1.5), Time { sec: 1, nanosec: 500_000_000 });
    assert_eq!(Time::from_seconds(-1.7), Time { sec: -2, nanosec: 300_000_000 });
    assert_eq!(Time::from_seconds(f64::NAN), Time::default());
    assert_eq!(Time::from_seconds(1e12).sec, i32::MAX);
    assert_eq!(Time::from_seconds(0.9999999999), Time { sec: 1, nanosec: 0 });
    assert!((Time { sec: -2, nanosec: 300_000_000 }.as_seconds() + 1.7).abs() < 1e-12);
}
