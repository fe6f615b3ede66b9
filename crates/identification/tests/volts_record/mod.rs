//! A volts record of the rig's ten channels for the conditioning's tests.

use oilfilm_identification::record::{RawRecord, RawUnits};
use oilfilm_physics::daq::{Calibration, ChannelId};

/// A volts record of smooth motion plus noise, every reading inside its probe's linear
/// range (so the fused front end runs), from a small deterministic generator.
pub fn volts_record(n: usize, calibration: &Calibration, seed: u64) -> RawRecord {
    let mut state = seed;
    let mut uniform = move || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let fs = 5000.0;
    let columns = ChannelId::ALL
        .iter()
        .enumerate()
        .map(|(k, &ch)| {
            let c = calibration.channel(ch).unwrap();
            let margin = 0.5 * calibration.lsb_v();
            let (lo, hi) = (c.linear_range_v[0] + margin, c.linear_range_v[1] - margin);
            let (lo, hi) = (lo.max(-10.0), hi.min(10.0));
            let (mid, span) = (0.5 * (lo + hi), 0.5 * (hi - lo));
            (0..n)
                .map(|i| {
                    let t = i as f64 / fs;
                    let phase = 2.0 * std::f64::consts::PI * (23.0 + k as f64) * t;
                    mid + span * (0.3 * phase.sin() + 0.05 * (uniform() - 0.5))
                })
                .collect()
        })
        .collect();
    RawRecord { sample_rate_hz: fs, start_time_s: 0.0, channels: ChannelId::ALL.to_vec(), units: RawUnits::Volts, columns }
}
