//! The zero-phase chain as a stream (`conditioning::stream`, ADR 0019): its blocks against
//! the windowed and whole-record conditioning, independent of how the scans come in and of
//! the instruction set, and what it leaves to the windows.

use crate::volts_record;

use oilfilm_identification::conditioning::stream::{Block, ZeroPhaseStream};
use oilfilm_identification::conditioning::{condition, Chain, Conditioned, ConditioningConfig, Mechanics};
use oilfilm_identification::record::RawRecord;
use oilfilm_identification::simd::Isa;
use oilfilm_physics::daq::DaqConfig;
use volts_record::volts_record;

fn mechanics() -> Mechanics {
    Mechanics { housing_mass_kg: 60.0, exciter_angles_deg: [45.0, 135.0], gravity_m_s2: 9.81 }
}

/// The launch files' low-pass (55.5 Hz): the edge the node uses.
fn config() -> ConditioningConfig {
    ConditioningConfig { lowpass_cutoff_hz: 55.5, ..ConditioningConfig::default() }
}

/// Feeds `raw` to a fresh stream (on `isa`) in cuts of `cut` scans (the stream's record
/// keeps every scan, as a node that never drops any), taking each block of `len` scans
/// from `edge` on as soon as its window is in; the blocks and their starts.
fn blocks_on(isa: Isa, raw: &RawRecord, cut: usize, len: usize) -> Vec<(usize, Option<Block>)> {
    let calibration = DaqConfig::zhou2004().calibration();
    let mut zp =
        ZeroPhaseStream::new(Chain::new(&calibration, &mechanics(), &config(), raw.sample_rate_hz).unwrap().with_isa(isa), &raw.channels, raw.units).unwrap();
    let mut fed = RawRecord { columns: vec![Vec::new(); raw.channels.len()], ..raw.clone() };
    let mut next = zp.edge();
    let mut out = Vec::new();
    let mut at = 0;
    while at < raw.len() {
        let to = (at + cut).min(raw.len());
        for (f, c) in fed.columns.iter_mut().zip(&raw.columns) {
            f.extend_from_slice(&c[at..to]);
        }
        at = to;
        zp.advance(&fed, 0).unwrap();
        while next + len + zp.edge() <= fed.len() {
            out.push((next, zp.block(next, len, &fed, 0).unwrap()));
            next += len;
            zp.release_before(next);
        }
    }
    out
}

fn blocks(raw: &RawRecord, cut: usize, len: usize) -> Vec<(usize, Option<Block>)> {
    blocks_on(Isa::current(), raw, cut, len)
}

/// Largest difference of the block's columns from `reference`'s samples `at..` (the
/// windowed conditioning or the whole record's), relative to each column's largest value.
fn worst(b: &Block, reference: &Conditioned, at: usize) -> f64 {
    let pairs: [(&[f64], &[f64]); 9] = [
        (&b.x_m, &reference.x_m),
        (&b.y_m, &reference.y_m),
        (&b.vx_m_s, &reference.vx_m_s),
        (&b.vy_m_s, &reference.vy_m_s),
        (&b.ax_m_s2, &reference.ax_m_s2),
        (&b.ay_m_s2, &reference.ay_m_s2),
        (&b.fx_n, &reference.fx_n),
        (&b.fy_n, &reference.fy_n),
        (&b.temperature_c, &reference.temperature_c),
    ];
    pairs
        .iter()
        .map(|(got, want)| {
            let want = &want[at..at + got.len()];
            let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            got.iter().zip(want).fold(0.0f64, |m, (g, w)| m.max((g - w).abs())) / scale
        })
        .fold(0.0, f64::max)
}

/// Every block agrees with the whole record's conditioning and with the windowed
/// conditioning of its window to within the filters' settling tolerance, and the blocks'
/// bits do not depend on how the scans came in (one at a time, 7, 500 or all at once)
/// nor on the instruction set.
#[test]
fn blocks_match_the_windowed_conditioning_and_do_not_depend_on_the_cuts() {
    let calibration = DaqConfig::zhou2004().calibration();
    let raw = volts_record(9_000, &calibration, 5);
    let whole = condition(&raw, &calibration, &mechanics(), &config()).unwrap();
    let reference = blocks(&raw, 500, 1_000);
    assert!(reference.len() >= 6, "{} blocks", reference.len());
    let mut window = Conditioned::default();
    let (mut vs_whole, mut vs_window) = (0.0f64, 0.0f64);
    for (start, b) in &reference {
        let b = b.as_ref().expect("clean readings: every block from the stream");
        assert!(b.range_violations.is_empty());
        assert_eq!(b.x_m.len(), 1_000);
        vs_whole = vs_whole.max(worst(b, &whole, *start));
        let edge = whole.valid.start;
        Chain::new(&calibration, &mechanics(), &config(), raw.sample_rate_hz)
            .unwrap()
            .condition_window_into(&raw, start - edge..start + 1_000 + edge, &mut window)
            .unwrap();
        vs_window = vs_window.max(worst(b, &window, edge));
    }
    println!("largest relative difference: {vs_whole:.2e} from the whole record, {vs_window:.2e} from the windows");
    assert!(vs_whole < 1e-6 && vs_window < 1e-6, "{vs_whole:e} {vs_window:e}");
    // A stream that conditions nothing differently fails the first; the transients are
    // not nothing either.
    assert!(vs_window > 0.0);
    for cut in [1, 7, 9_000] {
        assert!(blocks(&raw, cut, 1_000) == reference, "cut {cut}");
    }
    for isa in Isa::available() {
        assert!(blocks_on(isa, &raw, 500, 1_000) == reference, "{isa:?}");
    }
}

/// A NaN reading: the blocks whose window holds it are left to the windowed conditioning
/// (`None`), and the forward pass starts again after it, so the blocks whose window
/// starts after it agree with the record's conditioning as before. An out-of-range
/// reading is reported by the blocks whose window holds it, as the windowed conditioning
/// reports it.
#[test]
fn a_nan_is_left_to_the_windows_and_a_range_violation_reported_as_they_report_it() {
    let calibration = DaqConfig::zhou2004().calibration();
    let clean = volts_record(12_000, &calibration, 9);
    let whole = condition(&clean, &calibration, &mechanics(), &config()).unwrap();
    let edge = whole.valid.start;
    let mut raw = clean.clone();
    raw.columns[3][4_321] = f64::NAN;
    let mut window = Conditioned::default();
    let mut after = 0;
    for (start, b) in blocks(&raw, 500, 1_000) {
        let reaches = start - edge <= 4_321 + 8 && 4_321 < start + 1_000 + edge + 8;
        match b {
            None => assert!(reaches, "block {start}: left to the windows without a NaN near"),
            Some(b) => {
                assert!(!reaches || !(start - edge..start + 1_000 + edge).contains(&4_321), "block {start} conditioned across the NaN");
                let d = worst(&b, &whole, start);
                assert!(d < 1e-6, "block {start}: {d:e}");
                after += usize::from(start > 4_321);
            }
        }
    }
    assert!(after >= 3, "{after} blocks after the NaN");
    let mut raw = clean;
    raw.columns[0][6_100] = 1.0e3;
    for (start, b) in blocks(&raw, 500, 1_000) {
        let b = b.expect("finite readings");
        let w = start - edge..start + 1_000 + edge;
        Chain::new(&calibration, &mechanics(), &config(), raw.sample_rate_hz).unwrap().condition_window_into(&raw, w.clone(), &mut window).unwrap();
        assert_eq!(b.range_violations, window.range_violations, "block {start}");
        assert_eq!(b.range_violations.is_empty(), !w.contains(&6_100), "block {start}");
    }
}
