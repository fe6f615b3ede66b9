//! Step 3 of Zhou et al. (2004), section 3.1: "convert every channel's data (voltage) into a
//! corresponding physical value". `si = (volts - offset_v) / sensitivity_v_per_unit`, the
//! same affine map as [`Calibration::to_si`], applied to a whole column.
//!
//! The column is converted in one vectorisable pass (multiplication by the reciprocal
//! sensitivity, so a result may differ from [`Calibration::to_si`] in the last bit); the
//! finiteness of the output is checked in a second branch-free pass, and a NaN or infinite
//! reading is a [`IdentificationError::BadInput`] naming the channel and the sample index.
//! A real ADC never yields NaN (see `oilfilm_physics::daq`), so a NaN here means the record
//! was damaged between the card and us; it is never carried into the numbers.

use oilfilm_physics::daq::{Calibration, ChannelId};

use super::{first_non_finite, non_finite_error};
use crate::IdentificationError;

/// Converts one column of readings (V) of `channel` to its SI unit.
pub fn to_si(channel: ChannelId, volts: &[f64], calibration: &Calibration) -> Result<Vec<f64>, IdentificationError> {
    let mut out = vec![0.0; volts.len()];
    to_si_into(channel, volts, calibration, &mut out)?;
    Ok(out)
}

/// [`to_si`] into a caller-owned buffer of the same length (no allocation).
pub fn to_si_into(channel: ChannelId, volts: &[f64], calibration: &Calibration, out: &mut [f64]) -> Result<(), IdentificationError> {
    if out.len() != volts.len() {
        return Err(IdentificationError::BadInput {
            what: format!("calibrate `{channel}` output"),
            reason: format!("buffer has {} samples, input {}", out.len(), volts.len()),
        });
    }
    let c = calibration.channel(channel)?;
    let offset = c.offset_v;
    // `Calibration` comes from a validated `DaqConfig` (sensitivity finite and non-zero), but a
    // deserialised one is not validated: refuse a zero or non-finite sensitivity here.
    let sensitivity = c.sensitivity_v_per_unit;
    if !(sensitivity.is_finite() && sensitivity != 0.0 && offset.is_finite()) {
        return Err(IdentificationError::invalid(
            format!("calibration.{channel}"),
            format!("sensitivity {sensitivity} V/unit and offset {offset} V must be finite, sensitivity non-zero"),
        ));
    }
    let gain = 1.0 / sensitivity;
    for (o, &v) in out.iter_mut().zip(volts) {
        *o = (v - offset) * gain;
    }
    // One check of the output covers the input too: a non-finite reading converts to a
    // non-finite value. Only then is the cause looked for (NaN input, or an overflow of a
    // huge finite reading with a tiny sensitivity).
    if let Some(i) = first_non_finite(out) {
        if !volts[i].is_finite() {
            return Err(non_finite_error(channel, i, volts[i], "volts"));
        }
        return Err(IdentificationError::BadInput {
            what: format!("channel `{channel}`, sample {i}"),
            reason: format!("{} V does not convert to a finite {} with sensitivity {sensitivity}", volts[i], channel.unit()),
        });
    }
    Ok(())
}
