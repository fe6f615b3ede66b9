//! A bounded, seeded fuzz loop over CDR decoding: [`decode`] of every message type never
//! panics on mutated bytes, never allocates from a length it has not checked against the
//! bytes left (a count of 0xFFFFFFFF is an error, not a 4 GB request), and every refusal
//! says where (the byte offset, within the input) and what (the field's dotted path).
//!
//! Corpus: rclpy's golden messages (`tests/data/cdr/*.json`, every case of every type) and
//! the seeds in `crates/msgs/tests/data/fuzz/cdr/` (`<Type>.<what>.cdr`: the rcl_interfaces
//! and builtin types the golden files lack, and invalid messages: a count and a string
//! length of 0xFFFFFFFF, a big-endian header, a cut frame). Each case mutates one seed
//! (bits flipped, cut anywhere, a length or count word set huge, bytes inserted, deleted or
//! repeated, or replaced by random bytes: `tests/support/fuzz.rs`) and decodes it as the
//! seed's type, or one time in eight as another type. What decodes must encode and decode
//! back to the same bytes; a decoded `DaqFrame` goes through the sample checks the nodes run
//! on it.
//!
//! Bounded: `OILFILM_FUZZ_CASES` (default 10 000, well under a second optimised) cases from
//! seed `OILFILM_FUZZ_SEED`; case `k` runs from seed + `k`, printed on failure, so
//! `OILFILM_FUZZ_SEED=<seed> OILFILM_FUZZ_CASES=1` reproduces it. `OILFILM_FUZZ_CASES=1000000`
//! fuzzes longer (a benchmark-length run; nothing here is judged on time).

use std::fmt::Debug;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

use oilfilm_msgs::cdr::{decode, decode_exact, encode, CdrError, RosMessage};
use oilfilm_msgs::{
    Clock, CoefficientEstimate, ConditionedFrame, DaqFrame, ExciterCommand, Header, Parameter, ParameterEvent, ParameterValue, RigStatus, Time,
};
use rand::RngExt;

use crate::fuzz;

const SEED: u64 = 0xcd8_f11e;

/// Decodes as `M`; what decodes is re-encoded and must decode to the same bytes again.
/// Returns the length of the re-encoded message.
fn decode_as<M: RosMessage + PartialEq + Debug>(bytes: &[u8]) -> Result<usize, CdrError> {
    let m: M = decode(bytes)?;
    let again = encode(&m);
    let back: M = decode_exact(&again).unwrap_or_else(|e| panic!("a decoded {} re-encoded does not decode: {e}", M::TYPE_NAME));
    assert_eq!(encode(&back), again, "a decoded {} does not round-trip", M::TYPE_NAME);
    // `decode_exact` agrees but for what follows the last field.
    match decode_exact::<M>(bytes) {
        Ok(_) => assert!(bytes.len() <= again.len() + 3, "decode_exact took {} trailing bytes", bytes.len() - again.len()),
        Err(e) => assert!(e.field.is_empty() && e.to_string().contains("left after the last field"), "decode_exact: {e}"),
    }
    Ok(again.len())
}

/// A DAQ frame also goes through the checks the conditioner and the bag tools run on it.
fn decode_daq_frame(bytes: &[u8]) -> Result<usize, CdrError> {
    let n = decode_as::<DaqFrame>(bytes)?;
    let f: DaqFrame = decode(bytes)?;
    let mut buf = Vec::new();
    match (f.check_samples(), f.samples(&mut buf).map(|s| s.len())) {
        (Ok(()), Ok(len)) => {
            assert_eq!(len, f.scan_count as usize * f.channel_names.len());
            let picks: Vec<usize> = (0..f.channel_names.len().min(3)).collect();
            let mut columns = vec![Vec::new(); picks.len()];
            f.extend_columns(&picks, &mut columns).unwrap_or_else(|e| panic!("checked samples, yet extend_columns: {e}"));
        }
        (Err(a), Err(b)) => assert!(!a.is_empty() && !b.is_empty()),
        (a, b) => panic!("check_samples {a:?} but samples {b:?}"),
    }
    Ok(n)
}

type Decoder = fn(&[u8]) -> Result<usize, CdrError>;

/// Every message type, by its full name.
const TYPES: [(&str, Decoder); 11] = [
    ("builtin_interfaces/msg/Time", decode_as::<Time>),
    ("std_msgs/msg/Header", decode_as::<Header>),
    ("rosgraph_msgs/msg/Clock", decode_as::<Clock>),
    ("rcl_interfaces/msg/ParameterValue", decode_as::<ParameterValue>),
    ("rcl_interfaces/msg/Parameter", decode_as::<Parameter>),
    ("rcl_interfaces/msg/ParameterEvent", decode_as::<ParameterEvent>),
    ("oilfilm_msgs/msg/ExciterCommand", decode_as::<ExciterCommand>),
    ("oilfilm_msgs/msg/DaqFrame", decode_daq_frame),
    ("oilfilm_msgs/msg/ConditionedFrame", decode_as::<ConditionedFrame>),
    ("oilfilm_msgs/msg/CoefficientEstimate", decode_as::<CoefficientEstimate>),
    ("oilfilm_msgs/msg/RigStatus", decode_as::<RigStatus>),
];

fn type_index(name: &str) -> usize {
    TYPES.iter().position(|(t, _)| *t == name || t.ends_with(&format!("/{name}"))).unwrap_or_else(|| panic!("no message type `{name}`"))
}

fn seed_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fuzz/cdr")
}

/// A seed: where it comes from, its type (index into [`TYPES`]) and its bytes.
struct Seed {
    name: String,
    ty: usize,
    bytes: Vec<u8>,
}

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len() / 2).map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).expect("hex")).collect()
}

fn corpus() -> Vec<Seed> {
    let mut seeds = Vec::new();
    let golden = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/cdr");
    let mut files: Vec<PathBuf> =
        std::fs::read_dir(&golden).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|x| x == "json")).collect();
    files.sort();
    for p in files {
        let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        let ty = type_index(doc["type"].as_str().expect("type"));
        for case in doc["cases"].as_array().expect("cases") {
            let name = format!("{}/{}", p.file_name().unwrap().to_string_lossy(), case["name"].as_str().unwrap());
            seeds.push(Seed { name, ty, bytes: unhex(case["cdr_hex"].as_str().unwrap()) });
        }
    }
    let mut files: Vec<PathBuf> =
        std::fs::read_dir(seed_dir()).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|x| x == "cdr")).collect();
    files.sort();
    for p in files {
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        let ty = type_index(name.split('.').next().unwrap());
        seeds.push(Seed { name, ty, bytes: std::fs::read(&p).unwrap() });
    }
    seeds
}

/// The largest single allocation a decode of `len` bytes may ask for: a sequence's capacity
/// is its count, checked against the bytes left at the element's smallest encoded size (a
/// `Parameter` of at least 48 bytes is about 200 in memory).
fn allocation_bound(len: usize) -> usize {
    8 * len + 4096
}

/// What a refusal must say: where (an offset within the input) and what (the field, but
/// for the encapsulation header).
fn check_error(e: &CdrError, len: usize, case: &str) {
    let text = e.to_string();
    assert!(e.offset <= len, "{case}: the error's offset {} is past the {len} bytes: {text}", e.offset);
    assert!(text.contains(&format!("at byte {}", e.offset)), "{case}: {text}");
    assert!(!e.field.is_empty() || e.offset == 0, "{case}: no field named past the header: {text}");
    assert!(e.what.len() >= 8 && text.len() < 400, "{case}: {text}");
}

#[test]
fn mutated_messages_of_every_type_decode_or_are_refused_with_the_field_and_offset() {
    let corpus = corpus();
    let (first, cases) = fuzz::settings(SEED, 10_000);
    let start = std::time::Instant::now();
    let (mut decoded, mut refused, mut largest) = (0u64, 0u64, 0usize);
    let mut refused_as: Vec<u64> = vec![0; TYPES.len()];
    for case in 0..cases {
        let seed = first.wrapping_add(case);
        let mut rng = fuzz::rng(seed);
        let s = &corpus[rng.random_range(0..corpus.len())];
        let mut bytes = s.bytes.clone();
        let what = fuzz::mutate_some(&mut rng, &mut bytes);
        let ty = if rng.random_range(0..8) == 0 { rng.random_range(0..TYPES.len()) } else { s.ty };
        let label = format!("case {case} (seed {seed}): {} from {} ({what})", TYPES[ty].0, s.name);
        let (outcome, bytes_asked) = fuzz::largest_allocation(seed, || catch_unwind(AssertUnwindSafe(|| (TYPES[ty].1)(&bytes))));
        let result = outcome.unwrap_or_else(|_| panic!("{label}: a panic on {bytes:02x?}"));
        assert!(bytes_asked <= allocation_bound(bytes.len()), "{label}: an allocation of {bytes_asked} bytes for {} bytes of input", bytes.len());
        largest = largest.max(bytes_asked);
        match result {
            Ok(_) => decoded += 1,
            Err(e) => {
                refused += 1;
                refused_as[ty] += 1;
                check_error(&e, bytes.len(), &label);
            }
        }
    }
    println!(
        "cdr fuzz: {cases} cases from seed {first} ({} seeds) in {:.2} s: {decoded} decoded, {refused} refused (largest allocation {largest} bytes)",
        corpus.len(),
        start.elapsed().as_secs_f64()
    );
    assert!(!fuzz::mix_is_judged(cases) || (decoded > 0 && refused > cases / 2), "the mutations reach both outcomes: {decoded} decoded, {refused} refused");
    if cases >= 10_000 {
        let never: Vec<&str> = TYPES.iter().zip(&refused_as).filter(|(_, n)| **n == 0).map(|((t, _), _)| *t).collect();
        assert!(never.is_empty(), "no mutated message was refused as {never:?}");
    }
}

/// Not fuzz cases: every 4-byte word of every seed set to 0xFFFFFFFF in turn (where a
/// length or count is, it must be refused, not allocated), and the seeds that are invalid
/// refused with the field and offset their name promises.
#[test]
fn a_length_of_0xffffffff_anywhere_is_refused_without_allocating() {
    let corpus = corpus();
    let (mut refused, mut words) = (0, 0);
    for s in &corpus {
        for at in (4..s.bytes.len().saturating_sub(3)).step_by(4) {
            let mut bytes = s.bytes.clone();
            bytes[at..at + 4].copy_from_slice(&[0xff; 4]);
            words += 1;
            let (result, asked) = fuzz::largest_allocation(0, || (TYPES[s.ty].1)(&bytes));
            assert!(asked <= allocation_bound(bytes.len()), "{} with word {at} = 0xFFFFFFFF: {asked} bytes allocated", s.name);
            if let Err(e) = result {
                refused += 1;
                check_error(&e, bytes.len(), &format!("{} with word {at} = 0xFFFFFFFF", s.name));
            }
        }
    }
    // Most words are counts, lengths, or data the type constrains; some are float payload.
    assert!(refused * 4 > words, "{refused} of {words} words refused");

    let want: [(&str, &str, usize, &str); 4] = [
        ("DaqFrame.count-ffffffff.cdr", "channel_names", 64, "count 4294967295 exceeds"),
        ("RigStatus.string-length-ffffffff.cdr", "message", 64, "count 4294967295 exceeds"),
        ("ParameterEvent.cut.cdr", "new_parameters[1].value.string_array_value[0]", 168, "count 20 exceeds"),
        ("Header.big-endian.cdr", "", 0, "big-endian"),
    ];
    for (file, field, offset, words) in want {
        let s = corpus.iter().find(|s| s.name == file).unwrap_or_else(|| panic!("{file} is not in the corpus"));
        let e = (TYPES[s.ty].1)(&s.bytes).expect_err(file);
        assert_eq!(e.field, field, "{file}: {e}");
        assert_eq!(e.offset, offset, "{file}: {e}");
        assert!(e.to_string().contains(words), "{file}: {e}");
    }
    // And the valid seeds decode exactly.
    for s in corpus.iter().filter(|s| s.name.contains(".valid")) {
        (TYPES[s.ty].1)(&s.bytes).unwrap_or_else(|e| panic!("{}: {e}", s.name));
    }
}
