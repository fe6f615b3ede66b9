//! Throughput of the conditioning chain on a record the size of the paper's (50 000 scans of
//! 10 channels at 5 kHz): the range check and the low-pass on their own, then the whole chain
//! on the record in volts and in SI, and the causal chain.
//!
//! `cargo run --release -p oilfilm-identification --example bench_conditioning [scans] [repeats] [into|causal|blocks]`
//! (`into`: only the whole `condition_into`, `causal`: only the causal chain, e.g. under
//! `perf record`; `blocks`: the whole record against windows of it conditioned block by block
//! by one prepared `Chain`, alternating)
//!
//! "samples" are channel samples: a 50 000-scan record has 500 000. Each figure is the best
//! of `repeats` runs (default 15), to show the code's speed rather than the machine's load.

use std::f64::consts::PI;
use std::hint::black_box;
use std::time::Instant;

use oilfilm_identification::conditioning::causal::{CausalChain, CausalOutput};
use oilfilm_identification::conditioning::{condition, lowpass, range_check, Chain, Conditioned, ConditioningConfig, Mechanics};
use oilfilm_identification::record::{RawRecord, RawUnits};
use oilfilm_physics::daq::{Calibration, ChannelId, Daq, DaqConfig, DaqScan, PhysicalSignals};
use oilfilm_physics::effects::Effects;

/// Best wall time (s) of `repeats` runs of `f`.
fn best_of(repeats: usize, mut f: impl FnMut()) -> f64 {
    (0..repeats)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn report(name: &str, samples: usize, seconds: f64) {
    println!("{name:<44} {samples:>9} samples  {:>9.3} ms  {:>8.1} M samples/s", seconds * 1e3, samples as f64 / seconds / 1e6);
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let scans: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(50_000);
    let repeats: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(15).max(1);
    let only = args.next();
    let (only_into, only_causal) = (only.as_deref() == Some("into"), only.as_deref() == Some("causal"));

    // A record through the DAQ model: a few sines per channel, default sensor noise.
    let cfg = DaqConfig::zhou2004();
    let fs = cfg.sample_rate_hz;
    let mut daq = Daq::new(&cfg, &Effects::default(), 1)?;
    let mut signals = |t: f64| {
        let mut s = PhysicalSignals::zero();
        let w = 2.0 * PI * t;
        for (k, &ch) in ChannelId::ALL.iter().enumerate() {
            let (c, a) = match ch {
                ChannelId::F1 | ChannelId::F2 => (0.0, 400.0),
                ChannelId::F3 => (9000.0, 30.0),
                ChannelId::Temperature => (40.0, 0.2),
                _ => (-20e-6, 30e-6),
            };
            let f = 7.0 + 8.0 * k as f64;
            s.set(ch, c + a * ((w * f).sin() + 0.3 * (w * 80.0 + k as f64).sin()));
        }
        s
    };
    let recs: Vec<DaqScan> = (0..scans as u64).map(|i| daq.scan(i, i as f64 / fs, &mut signals)).collect();
    let raw = RawRecord::from_scans(&recs, fs)?;
    let cal = daq.calibration().clone();
    let conf = ConditioningConfig::default();
    let mech = Mechanics { housing_mass_kg: 60.0, exciter_angles_deg: [45.0, 135.0], gravity_m_s2: 9.81 };
    let n = raw.len();
    let channels = raw.channels.len();
    let all = n * channels;
    println!("record: {n} scans x {channels} channels = {all} samples at {fs} Hz; best of {repeats} runs");
    // The chain designed in each call, as `condition` does.
    let condition_into = |raw: &RawRecord, out: &mut Conditioned| Chain::new(&cal, &mech, &conf, fs).and_then(|c| c.condition_into(raw, out));
    if only_into {
        // `... [scans] [repeats] into`: only `condition_into`, for a profiler.
        let mut out = condition(&raw, &cal, &mech, &conf)?;
        let t = best_of(repeats, || {
            condition_into(&raw, &mut out).unwrap(); // validated above
            black_box(&out);
        });
        report("condition_into (reusing the output buffers)", all, t);
        return Ok(());
    }

    if only.as_deref() == Some("blocks") {
        // `... [scans] [repeats] blocks`: the whole record against block by block (ADR 0020),
        // in alternating rounds so that both see the same machine.
        let mut whole = condition(&raw, &cal, &mech, &conf)?;
        let mut out = whole.clone();
        let chain = Chain::new(&cal, &mech, &conf, raw.sample_rate_hz)?;
        let edge = chain.edge();
        let sizes = [50_000usize, 25_000, 12_500, 10_000, 5_000];
        let mut best = [f64::INFINITY; 6];
        for _ in 0..repeats {
            best[0] = best[0].min(best_of(1, || {
                condition_into(&raw, &mut whole).unwrap(); // validated above
                black_box(&whole);
            }));
            for (b, &size) in best[1..].iter_mut().zip(&sizes) {
                *b = b.min(best_of(1, || {
                    // Each block with the chain's edge on either side, so the whole block is valid.
                    let mut a = edge;
                    while a < raw.len() - edge {
                        let e = (a + size).min(raw.len() - edge);
                        chain.condition_window_into(&raw, a - edge..e + edge, &mut out).unwrap(); // conditions whole above
                        black_box(&out);
                        a = e;
                    }
                }));
            }
        }
        report("condition_into, the whole record", all, best[0]);
        for (b, size) in best[1..].iter().zip(sizes) {
            report(&format!("block by block, {size}-scan blocks"), all, *b);
        }
        return Ok(());
    }

    if only_causal {
        report("causal chain (order 8 at 55.5 Hz, 1000-scan blocks)", all, causal(&raw, &cal, &mech, repeats));
        return Ok(());
    }

    let t = best_of(repeats, || {
        black_box(RawRecord::from_scans(black_box(&recs), fs).unwrap()); // same input as above
    });
    report("RawRecord::from_scans (transpose)", all, t);

    let t = best_of(repeats, || {
        for (&ch, col) in raw.channels.iter().zip(&raw.columns) {
            black_box(range_check::check(ch, col, raw.units, &cal).unwrap()); // validated record
        }
    });
    report("range_check::check (step 2, on its own)", all, t);

    let lp = lowpass::Butterworth::design(conf.lowpass_order, conf.lowpass_cutoff_hz, fs)?;
    let mut cols = raw.columns.clone();
    let mut scratch = Vec::new();
    let t = best_of(repeats, || {
        // Filters the previous run's output again: same cost, values stay finite.
        lp.filtfilt_many_in_place(&mut cols, &mut scratch).unwrap(); // equal lengths
        black_box(&cols);
    });
    report("lowpass::filtfilt_many_in_place (8 lanes)", all, t);

    let t = best_of(repeats, || {
        black_box(condition(&raw, &cal, &mech, &conf).unwrap()); // validated above
    });
    report("condition (steps 1-7, all ten channels)", all, t);
    let mut out = condition(&raw, &cal, &mech, &conf)?;
    let t = best_of(repeats, || {
        condition_into(&raw, &mut out).unwrap(); // validated above
        black_box(&out);
    });
    report("condition_into (reusing the output buffers)", all, t);
    let mut si = raw.clone();
    si.units = RawUnits::Si;
    for (&ch, col) in si.channels.iter().zip(si.columns.iter_mut()) {
        let c = cal.channel(ch)?;
        col.iter_mut().for_each(|v| *v = (*v - c.offset_v) / c.sensitivity_v_per_unit);
    }
    let t = best_of(repeats, || {
        condition_into(&si, &mut out).unwrap(); // the same record in SI
        black_box(&out);
    });
    report("condition_into, the record in SI", all, t);

    report("causal chain (order 8 at 55.5 Hz, 1000-scan blocks)", all, causal(&raw, &cal, &mech, repeats));
    Ok(())
}

/// Best time of the causal chain (the conditioner node's `chain: causal`, at the sim_rig
/// launch file's 55.5 Hz) fed as the node feeds it: rows of scans, 1 000 at a time, its output
/// handed on after each block.
fn causal(raw: &RawRecord, cal: &Calibration, mech: &Mechanics, repeats: usize) -> f64 {
    let (n, channels) = (raw.len(), raw.channels.len());
    let rows: Vec<f64> = (0..n).flat_map(|i| raw.columns.iter().map(move |c| c[i])).collect();
    let columns = std::array::from_fn(|k| raw.channels.iter().position(|c| c.index() == k).unwrap()); // all ten channels
    let conf = ConditioningConfig { lowpass_cutoff_hz: 55.5, ..ConditioningConfig::default() };
    let mut out = CausalOutput::default();
    best_of(repeats, || {
        let mut chain = CausalChain::new(&columns, channels, RawUnits::Volts, raw.sample_rate_hz, cal, mech, &conf).unwrap(); // a valid design
        for block in rows.chunks(1_000 * channels) {
            chain.push(block, &mut out).unwrap(); // whole scans
            black_box(&out);
            out.consume(out.len());
        }
    })
}
