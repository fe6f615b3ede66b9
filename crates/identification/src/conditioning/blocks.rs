//! A whole record conditioned block by block: each block of scans is conditioned as a window
//! of the record ([`super::condition_window_into`]) that reaches [`super::edge_samples`] scans
//! past it on each side, so the whole block is valid, and is handed to the caller before the
//! next one is conditioned into the same buffers (ADR 0020).
//!
//! Why: [`super::condition`] over a minute of data writes 17 columns of 300 000 samples and
//! the low-pass's forward frames, some 60 MB, which no cache holds, and a least-squares stage
//! then reads its six columns back from memory. A block of 10 000-25 000 scans (3-7 MB
//! conditioned) stays in cache from the front end to whatever the caller does with it, and the
//! buffers are reused block after block, so the conditioned data no longer grow with the
//! record (the raw record is still read whole). Measured
//! on a 32 MB-L3 host (ADR 0020): 19-24 % less time than the whole record for the
//! conditioning alone, none for 50 000-scan blocks. The cost is the overlap (`2 edge` scans
//! per block: 362 at the defaults) and the filters' edges: a block's samples differ from the
//! whole record's by what the edge trim leaves of the start-up transients, within the
//! settling tolerance (1e-7) of each column's largest value (3.2e-8 in this module's test).

use std::ops::Range;

use oilfilm_physics::daq::Calibration;

use super::{condition_window_into, edge_samples, too_short, Conditioned, ConditioningConfig, Mechanics, RawRecord};
use crate::IdentificationError;

/// The blocks [`condition_by_block`] conditions: the valid scans of the whole record
/// (`edge..n - edge`, as [`super::condition`] marks them) cut into consecutive ranges of
/// `block` scans, the last one shorter if `block` does not divide them.
pub fn block_ranges(scans: usize, edge: usize, block: usize) -> impl Iterator<Item = Range<usize>> {
    let valid = edge.min(scans)..scans.saturating_sub(edge).max(edge.min(scans));
    let block = block.max(1);
    (valid.start..valid.end).step_by(block).map(move |a| a..(a + block).min(valid.end))
}

/// Conditions `raw` block by block, [`block_ranges`] of `block` scans, and calls
/// `each(range, conditioned)` for each in record order: `range` is the block's scans in the
/// record, `conditioned` holds the window `range.start - edge .. range.end + edge` with
/// `conditioned.valid` the block (indices, range violations and the times as
/// [`super::condition_window_into`] gives them: the window's sample 0 is record scan
/// `range.start - edge`). `out`'s buffers are reused from block to block.
///
/// A `block` of 0 is an invalid parameter; a record too short for one valid scan is refused
/// as [`super::condition`] refuses it. An error in a block names the record scan its window
/// starts at beside the sample within it, and stops the run: the blocks before it have been
/// handed to `each`.
pub fn condition_by_block<E: From<IdentificationError>>(
    raw: &RawRecord,
    calibration: &Calibration,
    mechanics: &Mechanics,
    config: &ConditioningConfig,
    block: usize,
    out: &mut Conditioned,
    mut each: impl FnMut(Range<usize>, &Conditioned) -> Result<(), E>,
) -> Result<(), E> {
    if block == 0 {
        return Err(IdentificationError::invalid("block", "0 scans; a block holds at least one").into());
    }
    // A ragged record is the whole record's fault, not a block's: refused before the blocks.
    raw.validate_shape()?;
    let edge = edge_samples(calibration, config, raw.sample_rate_hz)?;
    let n = raw.len();
    if n <= 2 * edge {
        // As `condition` refuses it (the same edge, the same error).
        return Err(too_short(n, edge).into());
    }
    for range in block_ranges(n, edge, block) {
        let window = range.start - edge..range.end + edge;
        condition_window_into(raw, window.clone(), calibration, mechanics, config, out).map_err(|e| in_window(e, &window))?;
        debug_assert_eq!(out.valid, edge..edge + range.len());
        each(range, out)?;
    }
    Ok(())
}

/// `e` from the window `window` of a record: a bad input's subject names the window, whose
/// sample numbers it gives.
fn in_window(e: IdentificationError, window: &Range<usize>) -> IdentificationError {
    match e {
        IdentificationError::BadInput { what, reason } => IdentificationError::BadInput {
            what: format!("{what} of the block window starting at record scan {}", window.start),
            reason,
        },
        other => other,
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::volts_record;
    use super::super::{condition, RawUnits};
    use super::*;
    use oilfilm_physics::daq::DaqConfig;

    fn mechanics() -> Mechanics {
        Mechanics { housing_mass_kg: 60.0, exciter_angles_deg: [45.0, 135.0], gravity_m_s2: 9.81 }
    }

    #[test]
    fn blocks_tile_the_valid_scans() {
        let cut: Vec<_> = block_ranges(1000, 100, 300).collect();
        assert_eq!(cut, [100..400, 400..700, 700..900]);
        let one: Vec<_> = block_ranges(1000, 100, 800).collect();
        assert_eq!((one.len(), one.first()), (1, Some(&(100..900))));
        assert_eq!(block_ranges(200, 100, 10).count(), 0);
        assert_eq!(block_ranges(150, 100, 10).count(), 0);
    }

    /// The blocks cover the whole record's valid scans once, in order, and each agrees with
    /// the whole record's conditioning to the settling tolerance in every column (relative to
    /// the column's largest value), and is not a copy of it (the low-pass's edges differ).
    #[test]
    fn blocks_agree_with_the_whole_record_to_the_settling_tolerance() {
        let calibration = DaqConfig::zhou2004().calibration();
        let config = ConditioningConfig::default();
        let mut raw = volts_record(9000, &calibration, 5);
        raw.start_time_s = 1.25;
        let whole = condition(&raw, &calibration, &mechanics(), &config).unwrap();
        let edge = edge_samples(&calibration, &config, raw.sample_rate_hz).unwrap();
        assert_eq!(whole.valid, edge..9000 - edge);
        let mut covered = Vec::new();
        let (mut worst, mut differs) = (0.0f64, false);
        let mut out = Conditioned::default();
        condition_by_block(&raw, &calibration, &mechanics(), &config, 2000, &mut out, |range, c| -> Result<(), IdentificationError> {
            covered.push(range.clone());
            let base = range.start - c.valid.start;
            for (name, part, all) in [
                ("t", &c.t_s, &whole.t_s),
                ("x", &c.x_m, &whole.x_m),
                ("y", &c.y_m, &whole.y_m),
                ("tilt x", &c.tilt_x_m, &whole.tilt_x_m),
                ("vx", &c.vx_m_s, &whole.vx_m_s),
                ("vy", &c.vy_m_s, &whole.vy_m_s),
                ("ax", &c.ax_m_s2, &whole.ax_m_s2),
                ("housing ay", &c.housing_ay_m_s2, &whole.housing_ay_m_s2),
                ("fx", &c.fx_n, &whole.fx_n),
                ("fy", &c.fy_n, &whole.fy_n),
                ("load", &c.static_load_n, &whole.static_load_n),
            ] {
                let scale = whole.valid.clone().map(|i| all[i].abs()).fold(0.0, f64::max);
                for i in c.valid.clone() {
                    let d = (part[i] - all[base + i]).abs() / scale;
                    assert!(d <= 3e-7, "{name} at record scan {}: {} against {}", base + i, part[i], all[base + i]);
                    worst = worst.max(d);
                    differs |= part[i] != all[base + i];
                }
            }
            Ok(())
        })
        .unwrap();
        let mut expected = Vec::new();
        let mut a = edge;
        while a < 9000 - edge {
            expected.push(a..(a + 2000).min(9000 - edge));
            a += 2000;
        }
        assert_eq!(covered, expected);
        assert!(differs && worst > 0.0, "the blocks must be conditioned apart from the whole record");
    }

    /// A block of 0, a record with no valid scan, a ragged record and a NaN reading are
    /// refused; only the NaN's error names the window it is in, and the blocks before it were
    /// handed on.
    #[test]
    fn bad_blocks_and_bad_readings_are_refused_by_name() {
        let calibration = DaqConfig::zhou2004().calibration();
        let config = ConditioningConfig::default();
        let mut out = Conditioned::default();
        let raw = volts_record(6000, &calibration, 9);
        let ok = |_: Range<usize>, _: &Conditioned| -> Result<(), IdentificationError> { Ok(()) };
        let e = condition_by_block(&raw, &calibration, &mechanics(), &config, 0, &mut out, ok).unwrap_err();
        assert!(matches!(&e, IdentificationError::InvalidParameter { field, .. } if field == "block"), "{e}");

        let edge = edge_samples(&calibration, &config, raw.sample_rate_hz).unwrap();
        let short = RawRecord { columns: raw.columns.iter().map(|c| c[..2 * edge].to_vec()).collect(), ..raw.clone() };
        let e = condition_by_block(&short, &calibration, &mechanics(), &config, 100, &mut out, ok).unwrap_err().to_string();
        assert!(e.contains("record length"), "{e}");

        let mut ragged = raw.clone();
        ragged.columns[3].pop();
        let e = condition_by_block(&ragged, &calibration, &mechanics(), &config, 1000, &mut out, ok).unwrap_err().to_string();
        assert!(!e.contains("block window") && e.contains(&format!("{}", ragged.channels[3])), "a whole-record fault: {e}");

        let mut bad = raw.clone();
        assert_eq!(bad.units, RawUnits::Volts);
        bad.columns[6][4000] = f64::NAN;
        let mut seen = Vec::new();
        let e = condition_by_block(&bad, &calibration, &mechanics(), &config, 1000, &mut out, |r, _| -> Result<(), IdentificationError> {
            seen.push(r);
            Ok(())
        })
        .unwrap_err()
        .to_string();
        // Blocks of 1000 from `edge`: the first block whose window (the block and `edge` scans
        // on either side) reaches scan 4000 is the first refused.
        let first_bad = block_ranges(6000, edge, 1000).position(|r| r.end + edge > 4000).unwrap();
        assert_eq!(seen.len(), first_bad);
        let start = block_ranges(6000, edge, 1000).nth(first_bad).unwrap().start - edge;
        assert!(e.contains("f1") && e.contains(&format!("sample {}", 4000 - start)) && e.contains(&format!("record scan {start}")), "{e}");
    }
}
