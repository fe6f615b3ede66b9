//! Step 2 of Zhou et al. (2004), section 3.1: "all of the data in this file are considered
//! invalid if an eddy current sensor's output is out of its own linear range".
//!
//! The test is exactly [`Calibration::within_linear_range`]; records given in SI are mapped
//! back to volts and tested the same way. It runs on the **raw** samples, before any filter,
//! because a filter would smear a clipped plateau below the threshold. It never acts
//! silently: [`check`] reports, and [`super::condition`] carries every violation so that
//! the estimator refuses the record ([`super::Conditioned::require_in_range`]).
//!
//! Design: docs/manual/conditioning.md#step-2-linear-range-check.

use oilfilm_physics::daq::{Calibration, ChannelId};

use super::{first_non_finite, non_finite_error, RangeViolation};
use crate::record::RawUnits;
use crate::IdentificationError;

/// Checks one column of `channel` (in `units`) against its calibrated linear range.
/// `Ok(None)` when every sample is inside; a non-finite sample is a `BadInput`.
pub fn check(channel: ChannelId, column: &[f64], units: RawUnits, calibration: &Calibration) -> Result<Option<RangeViolation>, IdentificationError> {
    let c = calibration.channel(channel)?;
    let [lo_v, hi_v] = c.linear_range_v;
    let (lo, hi) = volts_bounds(channel, calibration)?;
    let (offset, sens) = (c.offset_v, c.sensitivity_v_per_unit);
    if !(sens.is_finite() && sens != 0.0) {
        return Err(IdentificationError::invalid(format!("calibration.{channel}.sensitivity_v_per_unit"), format!("must be finite and non-zero, got {sens}")));
    }
    let a = (lo_v - offset) / sens;
    let b = (hi_v - offset) / sens;
    let range_si = [a.min(b), a.max(b)];

    // `volts > lo && volts < hi`, as `Calibration::within_linear_range`. One branch-free
    // counting pass (it vectorises); NaN and infinities fail the test, so they are counted
    // too, and only when something is counted is the column searched again, for a
    // non-finite sample (an error) or the first out-of-range one.
    let to_v = |x: f64| match units {
        RawUnits::Volts => x,
        RawUnits::Si => offset + sens * x,
    };
    let out_of_range = |x: f64| {
        let v = to_v(x);
        !(v > lo && v < hi)
    };
    let count = match units {
        RawUnits::Volts => column.iter().map(|&v| !(v > lo && v < hi) as usize).sum::<usize>(),
        RawUnits::Si => column.iter().map(|&x| out_of_range(x) as usize).sum::<usize>(),
    };
    if count == 0 {
        return Ok(None);
    }
    if let Some(i) = first_non_finite(column) {
        return Err(non_finite_error(channel, i, column[i], units.name()));
    }
    // count > 0, so some sample is out of range: `position` finds it.
    let Some(index) = column.iter().position(|&x| out_of_range(x)) else {
        return Ok(None);
    };
    let raw = column[index];
    let value_si = match units {
        RawUnits::Volts => (raw - offset) / sens,
        RawUnits::Si => raw,
    };
    Ok(Some(RangeViolation { channel, index, value_si, range_si, count }))
}

/// The open interval of readings (V) that count as inside `channel`'s linear range: a reading
/// `v` is in range when `v > lo && v < hi`.
pub(crate) fn volts_bounds(channel: ChannelId, calibration: &Calibration) -> Result<(f64, f64), IdentificationError> {
    let [lo_v, hi_v] = calibration.channel(channel)?.linear_range_v;
    let margin = 0.5 * calibration.lsb_v();
    Ok((lo_v + margin, hi_v - margin))
}
