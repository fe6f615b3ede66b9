//! Step 5 of Zhou et al. (2004), section 3.1: "calculate the relative displacements and
//! absolute displacements".
//!
//! * **Relative displacement** `r = (x, y)`: the journal centre relative to the bearing
//!   centre, which the four bearing probes measure at bearing ends A and B. The film
//!   coefficients belong to the bearing's mid-plane, so `r` is the **mean** of the two ends;
//!   the **difference** `A - B` (the tilt/misalignment indicator) is kept for diagnosis: the
//!   rig's rollers should keep it constant, and a dynamic tilt means the plane-motion model
//!   of eq. 1 is incomplete.
//! * **Absolute displacement** `X = (X, Y)` of the housing: the two frame probes look at the
//!   housing from the stiff framework (the inertial reference), so they give `X` directly.
//!
//! Both are linear, so they commute with the (linear, identical for all channels) deskew,
//! low-pass and differentiator stages; [`super::condition`] applies them after filtering.

use crate::IdentificationError;

/// Journal motion relative to the bearing, from the two probe pairs.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct RelativeMotion {
    /// Mean of ends A and B (m).
    pub x_m: Vec<f64>,
    pub y_m: Vec<f64>,
    /// End A minus end B (m).
    pub tilt_x_m: Vec<f64>,
    pub tilt_y_m: Vec<f64>,
}

fn same_len(what: &str, a: &[f64], b: &[f64]) -> Result<(), IdentificationError> {
    if a.len() == b.len() {
        Ok(())
    } else {
        Err(IdentificationError::BadInput {
            what: what.to_string(),
            reason: format!("columns of {} and {} samples", a.len(), b.len()),
        })
    }
}

/// `mean = (a + b) / 2`, `diff = a - b` into caller buffers (all the same length).
pub fn mean_and_difference_into(
    a: &[f64],
    b: &[f64],
    mean: &mut [f64],
    diff: &mut [f64],
) -> Result<(), IdentificationError> {
    same_len("probe ends A and B", a, b)?;
    same_len("mean output", a, mean)?;
    same_len("difference output", a, diff)?;
    for (((m, d), &x), &y) in mean.iter_mut().zip(diff.iter_mut()).zip(a).zip(b) {
        *m = 0.5 * (x + y);
        *d = x - y;
    }
    Ok(())
}

/// In place: `a <- (a + b) / 2`, `b <- a - b` (same length).
pub fn mean_and_difference_in_place(
    a: &mut [f64],
    b: &mut [f64],
) -> Result<(), IdentificationError> {
    same_len("probe ends A and B", a, b)?;
    for (x, y) in a.iter_mut().zip(b.iter_mut()) {
        [*x, *y] = mean_and_difference(*x, *y);
    }
    Ok(())
}

/// `[(a + b) / 2, a - b]` for the readings `a`, `b` of the two ends.
#[inline(always)]
pub(crate) fn mean_and_difference(a: f64, b: f64) -> [f64; 2] {
    [0.5 * (a + b), a - b]
}

/// The relative displacement (mean of ends) and tilt (A - B) from the four bearing probes.
pub fn relative_motion(
    a_x: &[f64],
    a_y: &[f64],
    b_x: &[f64],
    b_y: &[f64],
) -> Result<RelativeMotion, IdentificationError> {
    let n = a_x.len();
    same_len("probe_a_x and probe_a_y", a_x, a_y)?;
    let mut r = RelativeMotion {
        x_m: vec![0.0; n],
        y_m: vec![0.0; n],
        tilt_x_m: vec![0.0; n],
        tilt_y_m: vec![0.0; n],
    };
    mean_and_difference_into(a_x, b_x, &mut r.x_m, &mut r.tilt_x_m)?;
    mean_and_difference_into(a_y, b_y, &mut r.y_m, &mut r.tilt_y_m)?;
    Ok(r)
}

/// The housing's absolute displacement `X = (frame_x, frame_y)`: the frame probes measure it
/// directly (identity, kept as a stage so the frame convention is stated in one place).
pub fn housing_displacement(
    frame_x: &[f64],
    frame_y: &[f64],
) -> Result<(Vec<f64>, Vec<f64>), IdentificationError> {
    same_len("frame_x and frame_y", frame_x, frame_y)?;
    Ok((frame_x.to_vec(), frame_y.to_vec()))
}
