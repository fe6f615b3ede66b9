//! A bounded, seeded fuzz loop over the YAML inputs: params files (each node's typed
//! parameters and their checks) and launch files never panic, never hang, and every file
//! error names the file.
//!
//! Corpus: the shipped params and launch files (`launch_configs/`) and the hostile seeds in
//! `tests/data/fuzz/yaml/` (an alias bomb, a misspelt section, wrong types, deep nesting, a
//! truncated file). Each case mutates one seed (bytes flipped, YAML punctuation inserted,
//! ranges deleted or repeated, lines duplicated) and reads it as one node's params file (in
//! memory, the checks a file gets) and, every tenth case, as a launch file (from a file: the
//! launch reader resolves paths). Bounded: `OILFILM_FUZZ_CASES` (default 10 000) cases from
//! seed `OILFILM_FUZZ_SEED`; case `k` runs from seed + `k` alone (its seed, not its index,
//! picks the node and whether the launch reader runs), printed on failure, so
//! `OILFILM_FUZZ_SEED=<seed> OILFILM_FUZZ_CASES=1` runs that case alone.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::time::Instant;

use oilfilm_graph::conditioner::ConditionerParams;
use oilfilm_graph::daq::DaqParams;
use oilfilm_graph::error::NodeError;
use oilfilm_graph::estimator::EstimatorParams;
use oilfilm_graph::exciter::ExciterParams;
use oilfilm_graph::params::{self, NodeArgs};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SEED: u64 = 0x9a_11_f1_1e;

fn corpus() -> Vec<(String, Vec<u8>)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files: Vec<PathBuf> = Vec::new();
    for dir in [root.join("../../launch_configs"), root.join("../../launch_configs/params"), root.join("tests/data/fuzz/yaml")] {
        let mut here: Vec<PathBuf> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|x| x == "yaml"))
            .collect();
        here.sort();
        files.extend(here);
    }
    files.into_iter().map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap())).collect()
}

fn mutate(rng: &mut ChaCha8Rng, bytes: &mut Vec<u8>) {
    const PUNCTUATION: &[u8] = b"[]{}:-?&*!|>'\"#,%@`\n \t\\\x00\xff";
    let n = bytes.len().max(1);
    match rng.random_range(0..6) {
        0 if !bytes.is_empty() => {
            let i = rng.random_range(0..bytes.len());
            bytes[i] ^= 1 << rng.random_range(0..8);
        }
        1 => {
            let i = rng.random_range(0..=bytes.len());
            let c = PUNCTUATION[rng.random_range(0..PUNCTUATION.len())];
            let times = if rng.random_range(0..8) == 0 { rng.random_range(1..200) } else { 1 };
            bytes.splice(i..i, std::iter::repeat_n(c, times));
        }
        2 if !bytes.is_empty() => {
            let a = rng.random_range(0..bytes.len());
            let b = (a + rng.random_range(1..64)).min(bytes.len());
            bytes.drain(a..b);
        }
        3 if !bytes.is_empty() => {
            let a = rng.random_range(0..bytes.len());
            let b = (a + rng.random_range(1..32)).min(bytes.len());
            let piece = bytes[a..b].to_vec();
            for _ in 0..rng.random_range(1..20) {
                bytes.splice(b..b, piece.iter().copied());
            }
        }
        4 => {
            bytes.truncate(rng.random_range(0..n));
        }
        _ => {
            let lines: Vec<&[u8]> = bytes.split(|&b| b == b'\n').collect();
            let k = rng.random_range(0..lines.len());
            let mut out = Vec::with_capacity(bytes.len() + lines[k].len() + 1);
            for (i, l) in lines.iter().enumerate() {
                out.extend_from_slice(l);
                out.push(b'\n');
                if i == k {
                    out.extend_from_slice(l);
                    out.push(b'\n');
                }
            }
            *bytes = out;
        }
    }
}

/// A file error must name the file; any other error is a parameter's (it names the name).
fn check_error(e: &NodeError, file: &str, case: &str) {
    let text = e.to_string();
    assert!(text.len() < 4096, "{case}: an error of bounded length: {} bytes", text.len());
    if let NodeError::File { file: f, .. } = e {
        assert!(f.ends_with(file), "{case}: the error names {f}, not {file}");
    }
}

#[test]
fn mutated_params_and_launch_files_never_panic_or_hang_and_name_the_file() {
    let corpus = corpus();
    assert!(corpus.len() >= 10, "the shipped files and the seeds: {}", corpus.len());
    let cases: u64 = std::env::var("OILFILM_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(10_000);
    let seed: u64 = std::env::var("OILFILM_FUZZ_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(SEED);
    let dir = std::env::temp_dir().join(format!("oilfilm-yaml-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // In a directory of its own: a launch file's relative params paths do not resolve there,
    // which is one more error to name the file.
    let case_file = dir.join("case.yaml");
    let name = case_file.display().to_string();
    let args = |node: &str| NodeArgs { name: node.into(), namespace: "/oilfilm".into(), params_files: vec![case_file.clone()], ..Default::default() };
    let (mut loaded, mut refused, mut slowest) = (0u64, 0u64, std::time::Duration::ZERO);
    let start = Instant::now();
    for case in 0..cases {
        let case_seed = seed.wrapping_add(case);
        let mut rng = ChaCha8Rng::seed_from_u64(case_seed);
        let (seed_name, base) = &corpus[rng.random_range(0..corpus.len())];
        let mut bytes = base.clone();
        for _ in 0..rng.random_range(1..5) {
            mutate(&mut rng, &mut bytes);
        }
        let t = Instant::now();
        let outcome = catch_unwind(AssertUnwindSafe(|| {
            // The params readers in memory (the same checks as from a file), one node's
            // parameters a case in turn; the launch reader, which reads files, every tenth.
            let texts = params::check_yaml(bytes.clone(), &name).map(|text| vec![(name.clone(), text)]);
            let node = texts.and_then(|texts| match case_seed % 4 {
                0 => params::load_texts::<EstimatorParams>(&args("estimator"), &texts).and_then(|(p, _, _)| p.config(5000.0).map(|_| ())),
                1 => params::load_texts::<ConditionerParams>(&args("conditioner"), &texts).and_then(|(p, _, _)| p.validate()),
                2 => params::load_texts::<DaqParams>(&args("daq"), &texts).map(|_| ()),
                _ => params::load_texts::<ExciterParams>(&args("exciter"), &texts).map(|_| ()),
            });
            let mut results = vec![node];
            if case_seed % 10 == 0 {
                std::fs::write(&case_file, &bytes).unwrap();
                results.push(oilfilm_graph::launch::read(&case_file).map(|_| ()));
            }
            results
        }));
        let results = outcome.unwrap_or_else(|_| panic!("case {case} (seed {case_seed}, from {seed_name}): a panic on\n{}", String::from_utf8_lossy(&bytes)));
        slowest = slowest.max(t.elapsed());
        for r in &results {
            match r {
                Ok(()) => loaded += 1,
                Err(e) => {
                    refused += 1;
                    check_error(e, &name, &format!("case {case} (seed {case_seed}, from {seed_name})"));
                }
            }
        }
    }
    let total = start.elapsed();
    println!(
        "yaml fuzz: {cases} cases (a node's params each, the launch reader every tenth) in {:.2} s (slowest case {:.1} ms): {loaded} read, {refused} refused",
        total.as_secs_f64(),
        slowest.as_secs_f64() * 1e3
    );
    // A case run alone is judged on itself (above); the mix of outcomes only over many.
    assert!(!crate::fuzz::mix_is_judged(cases) || (refused > 0 && loaded > 0), "the mutations reach both outcomes: {loaded} read, {refused} refused");
    let _ = std::fs::remove_dir_all(&dir);
}
