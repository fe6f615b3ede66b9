//! Malformed bytes are refused with an error naming the field, never a panic.

use oilfilm_msgs::cdr::{decode, decode_exact, encode};
use oilfilm_msgs::{CoefficientEstimate, DaqFrame, Header, RigStatus, Time};

fn sample_daq() -> DaqFrame {
    DaqFrame {
        header: Header {
            stamp: Time { sec: 3, nanosec: 4 },
            frame_id: "oilfilm_bearing".into(),
        },
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

#[test]
fn every_truncation_is_an_error_not_a_panic() {
    let bytes = encode(&sample_daq());
    for n in 0..bytes.len() {
        let e = decode::<DaqFrame>(&bytes[..n]).expect_err("truncated");
        assert!(e.offset <= n, "{e}");
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

    let s = RigStatus {
        message: "x".into(),
        ..Default::default()
    };
    let mut bytes = encode(&s);
    let nul = bytes.len() - 1;
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
    assert!(decode::<RigStatus>(&be)
        .expect_err("big endian")
        .to_string()
        .contains("big-endian"));
    let mut long = bytes.clone();
    long.extend([0, 0, 0]);
    decode_exact::<RigStatus>(&long).expect("3 bytes of trailing padding are accepted");
    long.push(0);
    assert!(decode_exact::<RigStatus>(&long).is_err());
    decode::<RigStatus>(&long).expect("decode ignores what follows the last field");
}

#[test]
fn time_from_seconds() {
    assert_eq!(
        Time::from_seconds(1.5),
        Time {
            sec: 1,
            nanosec: 500_000_000
        }
    );
    assert_eq!(
        Time::from_seconds(-1.7),
        Time {
            sec: -2,
            nanosec: 300_000_000
        }
    );
    assert_eq!(Time::from_seconds(f64::NAN), Time::default());
    assert_eq!(Time::from_seconds(1e12).sec, i32::MAX);
    assert_eq!(
        Time::from_seconds(0.9999999999),
        Time { sec: 1, nanosec: 0 }
    );
    assert!(
        (Time {
            sec: -2,
            nanosec: 300_000_000
        }
        .as_seconds()
            + 1.7)
            .abs()
            < 1e-12
    );
}
