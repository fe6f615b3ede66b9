//! Step 5 of Zhou et al. (2004), section 3.1: the relative displacement `r`, the **mean** of
//! the bearing probes at ends A and B (the film coefficients belong to the mid-plane), the
//! tilt `A - B` kept for diagnosis, and the housing's absolute displacement `X` from the
//! frame probes.
//!
//! Both are linear, so they commute with the (linear, identical for all channels) deskew,
//! low-pass and differentiator stages; [`super::condition`] applies them before filtering.
//!
//! Design: docs/manual/conditioning.md#step-5-relative-and-absolute-displacement.

/// `[(a + b) / 2, a - b]` for the readings `a`, `b` of the two ends.
#[inline(always)]
pub(crate) fn mean_and_difference(a: f64, b: f64) -> [f64; 2] {
    [0.5 * (a + b), a - b]
}
