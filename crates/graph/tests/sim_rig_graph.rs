//! The `sim_rig` graph (exciter -> simulated DAQ -> conditioner -> estimator) on in-memory
//! topics, with the parameters of `launch_configs/sim_rig.launch.yaml` (the run's length and
//! windows, and where said the chain, set on top), running the very nodes the binaries run: accuracy against the
//! simulated film's linear coefficients, refusal of the paper's single sine, replay equal to
//! live bit for bit, independence of frame boundaries, and the DAQ equal to the offline
//! simulator bit for bit.

use oilfilm_graph::runner::bag::reanalyse;
use oilfilm_graph::runner::memory::{run_sim_rig, Recording};
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_msgs::cdr::encode;
use oilfilm_msgs::{CoefficientEstimate, DaqFrame};
use oilfilm_physics::config::RigConfig;

use crate::common;
use common::{params, rig_at_40_db};

fn bytes(e: &[CoefficientEstimate]) -> Vec<Vec<u8>> {
    e.iter().map(encode).collect()
}

#[test]
fn sim_rig_recovers_the_film_coefficients_and_replay_equals_live() {
    recovers_and_replays("zero_phase");
}

/// The same with the causal conditioning chain (ADR 0014): the same tolerances, replay equal
/// to live, frame boundaries irrelevant.
#[test]
fn sim_rig_with_the_causal_chain_recovers_the_film_coefficients_and_replay_equals_live() {
    recovers_and_replays("causal");
}

fn recovers_and_replays(chain: &str) {
    let mut p = params(21.0);
    p.conditioner.chain = chain.into();
    let plan = p.exciter.plan().unwrap();
    let rig = rig_at_40_db(&plan);
    let (rec, truth) = run_sim_rig(&rig, &p).unwrap();
    assert!(!rec.commands.is_empty() && !rec.frames.is_empty() && !rec.conditioned.is_empty());
    assert_eq!(rec.estimates.len(), 2, "windows [25k, 75k) and [50k, 100k) of 105k scans");
    assert_eq!(rec.conditioned.iter().all(|c| c.flags.iter().any(|f| f == "chain=causal")), chain == "causal", "{chain}: flags {:?}", rec.conditioned[0].flags);
    println!("{chain}: first conditioned sample {}, {} frames", rec.conditioned[0].first_sample, rec.conditioned.len());
    if chain == "causal" {
        // Causal blocks sit at multiples of block_scans, as the estimator's windows sit at
        // multiples of hop.
        let block = p.conditioner.block_scans as u64;
        assert!(
            rec.conditioned.iter().all(|c| c.first_sample % block == 0 && c.x_m.len() as u64 == block),
            "{:?}",
            rec.conditioned.iter().map(|c| c.first_sample).take(3).collect::<Vec<_>>()
        );
    }
    let kt = truth.coefficients.stiffness_n_m;
    let ct = truth.coefficients.damping_n_s_m;
    for e in &rec.estimates {
        assert!(e.solved, "window {}..{} refused: {}", e.window_start_sample, e.window_end_sample, e.refusal_reason);
        assert!(e.condition_number.is_finite() && e.condition_number > 1.0);
        assert_eq!(e.rank, 4);
        for (k, name) in ["xx", "xy", "yx", "yy"].iter().enumerate() {
            let (i, j) = (k / 2, k % 2);
            let ke = (e.stiffness_n_m[k] - kt[(i, j)]) / kt[(i, j)];
            let ce = (e.damping_n_s_m[k] - ct[(i, j)]) / ct[(i, j)];
            println!(
                "{chain} window {}: k{name} {:.5e} (truth {:.5e}, {:+.3} %, SE {:.2e})  d{name} {:.5e} (truth {:.5e}, {:+.3} %)",
                e.window_start_sample,
                e.stiffness_n_m[k],
                kt[(i, j)],
                100.0 * ke,
                e.stiffness_se_n_m[k],
                e.damping_n_s_m[k],
                ct[(i, j)],
                100.0 * ce
            );
            assert!(ke.abs() < 0.01, "k{name}: {:.3} % off", 100.0 * ke);
            assert!(ce.abs() < 0.02, "d{name}: {:.3} % off", 100.0 * ce);
        }
        // The operating point the estimator measured is the simulated one.
        assert!((e.load_n - truth.load_n).abs() / truth.load_n < 0.01, "load {} vs {}", e.load_n, truth.load_n);
        assert!((e.speed_rad_s - truth.running.omega_rad_s).abs() < 1e-9);
        assert!(e.flags.iter().any(|f| f == "speed from rig/status"), "{:?}", e.flags);
        assert!(e.amplitude_d > 0.0 && e.amplitude_d < 0.5);
        assert!(e.load_parameter_fy.is_finite() && e.stiffness_zhou.iter().all(|v| v.is_finite()));
    }

    // Replay equals live, bit for bit: the recorded frames through a fresh conditioner and
    // estimator.
    let replay = reanalyse(&rig, &p.conditioner, &p.estimator, &rec.frames, &rec.status).unwrap();
    assert_eq!(replay.conditioned.len(), rec.conditioned.len());
    for (a, b) in replay.conditioned.iter().zip(&rec.conditioned) {
        assert_eq!(encode(a), encode(b), "conditioned frame {}", a.sequence);
    }
    assert_eq!(bytes(&replay.estimates), bytes(&rec.estimates), "replayed estimates differ from live ones");

    // Frame boundaries do not matter: the same scans cut into 333-scan frames.
    for size in [333, 1, 4_999] {
        let recut = recut(&rec.frames, size);
        let replay = reanalyse(&rig, &p.conditioner, &p.estimator, &recut, &rec.status).unwrap();
        let span = |c: &[oilfilm_msgs::ConditionedFrame]| (c.first().map(|f| f.first_sample), c.last().map(|f| f.first_sample + f.x_m.len() as u64));
        assert_eq!(
            replay.conditioned.len(),
            rec.conditioned.len(),
            "{chain}: {size}-scan frames: conditioned samples {:?}, live {:?}",
            span(&replay.conditioned),
            span(&rec.conditioned)
        );
        for (a, b) in replay.conditioned.iter().zip(&rec.conditioned) {
            assert!(
                encode(a) == encode(b),
                "{chain}: conditioned frame {} (first sample {} / {}) depends on the framing ({size}-scan frames)",
                a.sequence,
                a.first_sample,
                b.first_sample
            );
        }
        assert_eq!(bytes(&replay.estimates), bytes(&rec.estimates), "{chain}: estimates depend on how the scans were framed ({size}-scan frames)");
    }

    // The DAQ node's frames are the offline simulator's record, bit for bit.
    let offline = simulate::simulate(&rig, &plan, 21.0, SimulateOptions { keep_states: false }, &mut |_| {}).unwrap();
    // It sends the 16-bit ADC's counts; times its LSB they are the simulator's volts, exactly.
    assert!(rec.frames.iter().all(|f| f.units == oilfilm_msgs::DaqFrame::UNITS_COUNTS && f.values.is_empty()));
    let mut buf = Vec::new();
    let volts: Vec<f64> = rec.frames.iter().flat_map(|f| f.samples(&mut buf).unwrap().to_vec()).collect();
    let expected: Vec<f64> = offline.scans.iter().flat_map(|s| s.volts.iter().copied()).collect();
    assert_eq!(volts.len(), expected.len());
    assert!(volts.iter().zip(&expected).all(|(a, b)| a.to_bits() == b.to_bits()), "graph DAQ differs from `oilfilm simulate`");
}

/// The same scans in frames of `size`.
fn recut(frames: &[DaqFrame], size: usize) -> Vec<DaqFrame> {
    let first = &frames[0];
    let width = first.channel_names.len();
    // The DAQ node sends its 16-bit ADC's counts; the recut frames carry them the same way.
    let values: Vec<f64> = frames.iter().flat_map(|f| f.values.iter().copied()).collect();
    let counts: Vec<i16> = frames.iter().flat_map(|f| f.counts.iter().copied()).collect();
    let scans = (values.len() + counts.len()) / width;
    let t0 = oilfilm_graph::stamp::Stamp::from_time(&first.header.stamp);
    (0..scans)
        .step_by(size)
        .enumerate()
        .map(|(k, s)| {
            let n = size.min(scans - s);
            DaqFrame {
                header: oilfilm_msgs::Header { stamp: t0.after_samples(s as i64, first.sample_rate_hz).to_time(), frame_id: first.header.frame_id.clone() },
                sequence: k as u64,
                first_scan: first.first_scan + s as u64,
                scan_count: n as u32,
                values: values.get(s * width..(s + n) * width).map_or_else(Vec::new, <[f64]>::to_vec),
                counts: counts.get(s * width..(s + n) * width).map_or_else(Vec::new, <[i16]>::to_vec),
                ..first.clone()
            }
        })
        .collect()
}

#[test]
fn the_papers_single_sine_is_refused_not_answered() {
    for chain in ["zero_phase", "causal"] {
        single_sine(chain);
    }
}

fn single_sine(chain: &str) {
    let mut p = params(16.0);
    p.conditioner.chain = chain.into();
    p.exciter.plan = "sine".into();
    p.exciter.frequency_1_hz = 37.0;
    let rig = RigConfig::zhou2004().unwrap();
    let (rec, _) = run_sim_rig(&rig, &p).unwrap();
    assert!(!rec.estimates.is_empty());
    for e in &rec.estimates {
        println!("lines {:?} cond {:.3e} rank {} flags {:?} se {:?}", e.excitation_frequencies_hz, e.condition_number, e.rank, e.flags, e.stiffness_se_n_m);
        assert!(!e.solved, "a single sine cannot give eight coefficients, got {:?}", e.stiffness_n_m);
        assert!(e.stiffness_n_m.iter().all(|v| v.is_nan()), "a refusal carries no numbers");
        assert!(!e.refusal_reason.is_empty());
        println!("refused: {}", e.refusal_reason);
    }
}

#[test]
fn a_lost_frame_restarts_the_stream_and_is_said() {
    for chain in ["zero_phase", "causal"] {
        lost_frame(chain);
    }
}

fn lost_frame(chain: &str) {
    let mut p = params(13.0);
    p.conditioner.chain = chain.into();
    let rig = RigConfig::zhou2004().unwrap();
    let (rec, _) = run_sim_rig(&rig, &p).unwrap();
    let mut frames = rec.frames.clone();
    frames.remove(40); // scans 20 000 .. 20 500
    let replay = reanalyse(&rig, &p.conditioner, &p.estimator, &frames, &rec.status).unwrap();
    let restart = replay.conditioned.iter().find(|c| c.flags.iter().any(|f| f.contains("restarted"))).expect("a restart flag");
    assert!(restart.flags.iter().any(|f| f.contains("500 scans missing")), "{:?}", restart.flags);
    // No conditioned sample claims to cover the lost scans.
    for c in &replay.conditioned {
        let (a, b) = (c.first_sample, c.first_sample + c.x_m.len() as u64);
        assert!(b <= 20_000 || a >= 20_500, "frame {a}..{b} covers the lost scans");
    }
    // Frames from another rig or malformed are skipped, the stream goes on.
    let mut bad = rec.frames[..5].to_vec();
    bad[2].counts.pop();
    bad[3].rig = "other".into();
    let out = reanalyse(&rig, &p.conditioner, &p.estimator, &bad, &rec.status).unwrap();
    assert!(out.conditioned.iter().all(|c| c.first_sample + (c.x_m.len() as u64) <= 1000));
}

#[allow(dead_code)]
fn _uses(_: Recording) {}
