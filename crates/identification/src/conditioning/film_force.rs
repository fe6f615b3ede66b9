//! Step 7 of Zhou et al. (2004), section 3.1, with their eq. 2 (section 2.2): the oil-film
//! force from the housing's equation of motion, in our frame (`F` = film force **on the
//! journal**, crate convention),
//!
//! `F = f1 (cos a1, sin a1) + f2 (cos a2, sin a2) + (f3 - m g) e_y - m X''`.
//!
//! The **static part** is the mean over the record's valid scans
//! ([`super::Conditioned::static_force_n`]), the **dynamic part** the rest.
//!
//! Derivation: docs/manual/conditioning.md#step-7-the-film-force-eq-2.

use super::Mechanics;

/// The applied part of eq. 2 at one sample, for a validated [`Mechanics`].
#[derive(Copy, Clone, Debug)]
pub(crate) struct Applied {
    c1: f64,
    s1: f64,
    c2: f64,
    s2: f64,
    mg: f64,
}

impl Applied {
    pub(crate) fn new(mechanics: &Mechanics) -> Self {
        let [a1, a2] = mechanics.exciter_angles_deg.map(f64::to_radians);
        let (c1, s1, c2, s2) = (a1.cos(), a1.sin(), a2.cos(), a2.sin());
        let mg = mechanics.housing_mass_kg * mechanics.gravity_m_s2;
        Self { c1, s1, c2, s2, mg }
    }

    /// `[fx, fy]` from the exciter forces `f1`, `f2` and the bellows' load `f3`.
    #[inline(always)]
    pub(crate) fn at(&self, f1: f64, f2: f64, f3: f64) -> [f64; 2] {
        let Self { c1, s1, c2, s2, mg } = *self;
        [c1 * f1 + c2 * f2, s1 * f1 + s2 * f2 + (f3 - mg)]
    }
}
