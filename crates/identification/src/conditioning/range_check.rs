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

use super::{non_finite_error, RangeViolation};
use crate::record::RawUnits;
use crate::simd::first_non_finite;
use crate::IdentificationError;

/// Checks one column of `channel` (in `units`) against its calibrated linear range.
/// `Ok(None)` when every sample is inside; a non-finite sample is a `BadInput`.
pub fn check(channel: ChannelId, column: &[f64], units: RawUnits, calibration: &Calibration) -> Result<Option<RangeViolation>, IdentificationError> {
    let range = LinearRange::of(channel, units, calibration)?;
    // One branch-free counting pass (it vectorises); NaN and infinities are outside, so they
    // are counted too, and only when something is counted is the column searched again, for
    // a non-finite sample (an error) or the first one outside.
    let count = column.iter().filter(|&&r| !range.contains(r)).count();
    if count == 0 {
        return Ok(None);
    }
    if let Some(i) = first_non_finite(column) {
        return Err(non_finite_error(channel, i, column[i], units.name()));
    }
    let Some(index) = column.iter().position(|&r| !range.contains(r)) else {
        return Ok(None); // count > 0: not reached
    };
    // The value as `Calibration::to_si` gives it.
    let value_si = match units {
        RawUnits::Volts => (column[index] - range.offset_v) / range.sensitivity,
        RawUnits::Si => column[index],
    };
    Ok(Some(RangeViolation { channel, index, value_si, range_si: range.range_si, count }))
}

/// The open interval of readings (V) that count as inside `channel`'s linear range: a reading
/// `v` is in range when `v > lo && v < hi`.
pub(crate) fn volts_bounds(channel: ChannelId, calibration: &Calibration) -> Result<(f64, f64), IdentificationError> {
    let [lo_v, hi_v] = calibration.channel(channel)?.linear_range_v;
    let margin = 0.5 * calibration.lsb_v();
    Ok((lo_v + margin, hi_v - margin))
}

/// A channel's calibrated linear range, for its readings in given units.
#[derive(Copy, Clone, Debug)]
pub(crate) struct LinearRange {
    pub(crate) channel: ChannelId,
    pub(crate) units: RawUnits,
    offset_v: f64,
    /// Volts per SI unit, finite and non-zero.
    sensitivity: f64,
    /// Readings inside are strictly between these volts ([`volts_bounds`]).
    lo: f64,
    hi: f64,
    /// The range in the channel's SI unit, `[low, high]`.
    pub(crate) range_si: [f64; 2],
}

impl LinearRange {
    /// Inlined, so that a caller's loop over readings sees its own units and is compiled for
    /// them alone, not converting every reading both ways.
    #[inline(always)]
    pub(crate) fn of(channel: ChannelId, units: RawUnits, calibration: &Calibration) -> Result<Self, IdentificationError> {
        let c = calibration.channel(channel)?;
        let (lo, hi) = volts_bounds(channel, calibration)?;
        let (offset_v, sensitivity) = (c.offset_v, c.sensitivity_v_per_unit);
        if !(sensitivity.is_finite() && sensitivity != 0.0) {
            return Err(IdentificationError::invalid(
                format!("calibration.{channel}.sensitivity_v_per_unit"),
                format!("must be finite and non-zero, got {sensitivity}"),
            ));
        }
        let [a, b] = c.linear_range_v.map(|v| (v - offset_v) / sensitivity);
        Ok(Self { channel, units, offset_v, sensitivity, lo, hi, range_si: [a.min(b), a.max(b)] })
    }

    /// Whether reading `r` is inside, as [`Calibration::within_linear_range`] tests its volts.
    /// NaN and infinities are not.
    #[inline(always)]
    pub(crate) fn contains(&self, r: f64) -> bool {
        let volts = match self.units {
            RawUnits::Volts => r,
            RawUnits::Si => self.offset_v + self.sensitivity * r,
        };
        volts > self.lo && volts < self.hi
    }
}
