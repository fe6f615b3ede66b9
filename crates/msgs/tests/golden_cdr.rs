//! Each Rust type serialises byte for byte as rclpy does (tests/data/cdr/*.json, written by
//! tests/interop/check_msgs.py with rclpy.serialization), and decodes rclpy's bytes back to
//! the same value. Fast-CDR leaves alignment padding unzeroed, so the padding bytes (which
//! our writer reports and zeros) are the only ones not compared.

use std::fmt::Debug;
use std::path::PathBuf;

use oilfilm_msgs::cdr::{decode, decode_exact, encode, encode_with_padding, RosMessage};
use oilfilm_msgs::{Clock, CoefficientEstimate, ConditionedFrame, DaqFrame, ExciterCommand, Header, RigStatus, Time};
use serde::de::DeserializeOwned;

fn fixture_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/cdr")
}

fn unhex(s: &str) -> Vec<u8> {
    assert!(s.len().is_multiple_of(2), "odd hex length");
    (0..s.len()).step_by(2).map(|i| u8::from_str_radix(&s[i..i + 2], 16).expect("hex")).collect()
}

/// Compare every fixture case of `T`; returns the number of cases.
fn check<T: RosMessage + DeserializeOwned + PartialEq + Debug>(file: &str) -> usize {
    let path = fixture_dir().join(file);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let doc: serde_json::Value = serde_json::from_str(&text).expect("fixture JSON");
    assert_eq!(doc["type"], T::TYPE_NAME, "{file}: type");
    let cases = doc["cases"].as_array().expect("cases");
    assert!(!cases.is_empty(), "{file}: no cases");
    for case in cases {
        let name = case["name"].as_str().expect("name");
        let value: T = serde_json::from_value(case["value"].clone()).or_fixture_panic(file, name);
        let golden = unhex(case["cdr_hex"].as_str().expect("cdr_hex"));
        let layout = encode_with_padding(&value);
        let (ours, padding) = (layout.bytes, layout.padding);
        // rclpy's buffer is as long as Fast-CDR's size calculator says: the data, then bytes
        // for the alignment it counted for empty sequences (unwritten: any value, often what
        // the previous message left in the buffer).
        assert_eq!(
            layout.fastcdr_length,
            golden.len(),
            "{file}/{name}: length (ours {} + calculator slack {} vs rclpy {})",
            ours.len(),
            layout.fastcdr_length - ours.len(),
            golden.len()
        );
        let is_padding = |i: usize| padding.iter().any(|r| r.contains(&i));
        for (i, (a, b)) in ours.iter().zip(&golden).enumerate() {
            if is_padding(i) {
                assert_eq!(*a, 0, "{file}/{name}: our padding byte {i} is not zero");
            } else {
                assert_eq!(a, b, "{file}/{name}: byte {i} differs (ours {a:02x}, rclpy {b:02x}); padding at {padding:?}");
            }
        }
        assert_eq!(encode(&value), ours, "{file}/{name}: encode and encode_with_padding disagree");
        let back: T = decode(&golden).unwrap_or_else(|e| panic!("{file}/{name}: decoding rclpy's bytes: {e}"));
        assert_eq!(back, value, "{file}/{name}: rclpy's bytes decode to another value");
        let again: T = decode_exact(&ours).unwrap_or_else(|e| panic!("{file}/{name}: decoding our bytes: {e}"));
        assert_eq!(again, value, "{file}/{name}: round trip");
    }
    cases.len()
}

trait OrFixturePanic<T> {
    fn or_fixture_panic(self, file: &str, case: &str) -> T;
}
impl<T> OrFixturePanic<T> for Result<T, serde_json::Error> {
    fn or_fixture_panic(self, file: &str, case: &str) -> T {
        self.unwrap_or_else(|e| panic!("{file}/{case}: the fixture's value does not fit the Rust type: {e}"))
    }
}

#[test]
fn exciter_command_matches_rclpy() {
    assert!(check::<ExciterCommand>("ExciterCommand.json") >= 2);
}

#[test]
fn daq_frame_matches_rclpy() {
    assert!(check::<DaqFrame>("DaqFrame.json") >= 2);
}

#[test]
fn conditioned_frame_matches_rclpy() {
    assert!(check::<ConditionedFrame>("ConditionedFrame.json") >= 2);
}

#[test]
fn coefficient_estimate_matches_rclpy() {
    assert!(check::<CoefficientEstimate>("CoefficientEstimate.json") >= 2);
}

#[test]
fn rig_status_matches_rclpy() {
    assert!(check::<RigStatus>("RigStatus.json") >= 3);
}

/// rclpy's bytes of the fixture's `exciting` status as it serialised them before
/// `frames_dropped` was appended (what a bag recorded then holds): they decode, strictly,
/// to the same status with nothing dropped.
#[test]
fn rclpys_rig_status_from_before_frames_dropped_decodes_with_it_zero() {
    let old = unhex(
        "0001000014f15365ffc99a3b100000006f696c66696c6d5f62656172696e6700000000003b43d5598ca263403333333333e3b54054e3a59bc4003d40020000001200000074776f2d746f6e652032302f333020487a00",
    );
    let got: RigStatus = decode_exact(&old).expect("an old status decodes");
    let want = RigStatus {
        header: Header { stamp: Time { sec: 1_700_000_020, nanosec: 999_999_999 }, frame_id: "oilfilm_bearing".into() },
        speed_rad_s: 157.07963267948966,
        static_load_n: 5603.2,
        bearing_temperature_degc: 29.003,
        state: RigStatus::STATE_EXCITING,
        message: "two-tone 20/30 Hz".into(),
        frames_dropped: 0,
    };
    assert_eq!(got, want);
}

/// The player's /clock message: rclpy's bytes for a bag log time and for zero.
#[test]
fn clock_matches_rclpy() {
    assert!(check::<Clock>("Clock.json") >= 2);
    let c = Clock { clock: Time { sec: 1_700_000_000, nanosec: 123_456_789 } };
    assert_eq!(encode(&c), unhex("0001000000f1536515cd5b07"));
}

/// rclpy: Header(stamp=Time(sec=1, nanosec=2), frame_id="ab") serialises to this.
#[test]
fn header_matches_rclpy() {
    let h = Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: "ab".into() };
    assert_eq!(encode(&h), unhex("00010000010000000200000003000000616200"));
}

/// An empty float64[] is its count alone: no padding for absent elements. The count of
/// x_m ends 4 bytes past an 8-byte boundary, so a writer that aligned the elements anyway
/// would insert 4 bytes before y_m's count.
#[test]
fn empty_float64_sequence_takes_no_padding() {
    let empty = ConditionedFrame { header: Header { stamp: Time { sec: 0, nanosec: 0 }, frame_id: String::new() }, ..Default::default() };
    let mut want = vec![0x00, 0x01, 0x00, 0x00];
    want.extend([0, 0, 0, 0, 0, 0, 0, 0]); // stamp (offsets 0..8)
    want.extend([1, 0, 0, 0, 0]); // frame_id "" = length 1 (the NUL), NUL (8..13)
    want.extend([0, 0, 0]); // pad to 16 for the uint64
    want.extend([0; 8]); // sequence (16..24)
    want.extend([0; 8]); // first_sample (24..32)
    want.extend([0; 8]); // sample_rate_hz (32..40)
    want.extend([0; 4 * 9]); // 8 empty float64[] and valid: 9 counts (40..76)
    want.extend([0; 4]); // pad to 80 for the float64
    want.extend([0; 8]); // bearing_temperature_degc (80..88)
    want.extend([0; 4]); // flags: its count (88..92)
    assert_eq!(encode(&empty), want);
    assert_eq!(decode_exact::<ConditionedFrame>(&want).expect("decode"), empty);

    // One element: now the element is aligned to 8 after its count.
    let one = ConditionedFrame { x_m: vec![1.0], ..empty.clone() };
    let layout = encode_with_padding(&empty);
    // What rclpy would return: Fast-CDR's calculator counts 4 bytes of alignment for x_m's
    // absent elements, shifting the rest, and so on: the data stays 84 bytes.
    assert!(layout.fastcdr_length > want.len());
    let layout = encode_with_padding(&one);
    let (bytes, padding) = (layout.bytes, layout.padding);
    // + 4 padding + 8 element, - the 4 bytes of padding before bearing_temperature_degc,
    // which is now 8-aligned without it.
    assert_eq!(bytes.len(), want.len() + 4 + 8 - 4);
    assert!(padding.contains(&(4 + 44..4 + 48)), "padding {padding:?}");
    assert_eq!(&bytes[4 + 48..4 + 56], &1.0f64.to_le_bytes());
}

#[test]
fn float_sequence_of_nan_round_trips() {
    let e = CoefficientEstimate { stiffness_n_m: [f64::NAN; 4], excitation_frequencies_hz: vec![f64::NAN, f64::INFINITY], ..Default::default() };
    let back: CoefficientEstimate = decode(&encode(&e)).expect("decode");
    assert!(back.stiffness_n_m.iter().all(|v| v.is_nan()));
    assert!(back.excitation_frequencies_hz[0].is_nan() && back.excitation_frequencies_hz[1].is_infinite());
}
