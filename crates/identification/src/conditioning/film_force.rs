//! Step 7 of Zhou et al. (2004), section 3.1, with their eq. 2 (section 2.2): the oil-film
//! force from the housing's equation of motion.
//!
//! The housing (mass `m`) carries the exciter forces `f1`, `f2` along their axes at angles
//! `a1`, `a2` from `+x` (paper: 45 and 135 degrees), the bellows' pull `f3` along `+y`,
//! gravity `-m g e_y`, and the film's reaction `-F` (`F` = film force **on the journal**,
//! crate convention). Newton for the housing, `m X'' = F_exc + (f3 - m g) e_y - F`, gives
//!
//! `F = f1 (cos a1, sin a1) + f2 (cos a2, sin a2) + (f3 - m g) e_y - m X''`,
//!
//! which is the paper's eq. 2 in our frame (`f_X = f1 cos45 - f2 cos45 - m X''`,
//! `f_Y = f1 sin45 + f2 sin45 + f3 - m g - m Y''`). The **static part** is the mean over the
//! record's valid scans ([`super::Conditioned::static_force_n`]), the **dynamic part** (the
//! paper's film-force increment) the rest.

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
