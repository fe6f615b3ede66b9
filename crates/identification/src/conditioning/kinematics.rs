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
//! low-pass and differentiator stages; [`super::condition`] applies them before filtering.

/// `[(a + b) / 2, a - b]` for the readings `a`, `b` of the two ends.
#[inline(always)]
pub(crate) fn mean_and_difference(a: f64, b: f64) -> [f64; 2] {
    [0.5 * (a + b), a - b]
}
