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
//! window/record ([`static_part`]), the **dynamic part** (the paper's film-force increment)
//! the rest.

use std::ops::Range;

use super::Mechanics;
use crate::IdentificationError;

/// Eq. 2 into caller buffers: all inputs and outputs the same length. Forces in N, housing
/// acceleration in m/s^2.
#[allow(clippy::too_many_arguments)] // five named input columns and two outputs, all plain
pub fn eq2_into(
    f1: &[f64],
    f2: &[f64],
    f3: &[f64],
    housing_ax: &[f64],
    housing_ay: &[f64],
    mechanics: &Mechanics,
    fx: &mut [f64],
    fy: &mut [f64],
) -> Result<(), IdentificationError> {
    mechanics.validate()?;
    let n = f1.len();
    for (name, len) in [
        ("f2", f2.len()),
        ("f3", f3.len()),
        ("housing_ax", housing_ax.len()),
        ("housing_ay", housing_ay.len()),
        ("fx output", fx.len()),
        ("fy output", fy.len()),
    ] {
        if len != n {
            return Err(IdentificationError::BadInput { what: format!("eq. 2 `{name}`"), reason: format!("{len} samples, f1 has {n}") });
        }
    }
    let (applied, m) = (Applied::new(mechanics), mechanics.housing_mass_kg);
    for i in 0..n {
        let [x, y] = applied.at(f1[i], f2[i], f3[i]);
        (fx[i], fy[i]) = (x - m * housing_ax[i], y - m * housing_ay[i]);
    }
    Ok(())
}

/// The applied part of eq. 2, in place: `f1`, `f2` become the exciters' force plus the
/// bellows' load minus the housing's weight, `(c1 f1 + c2 f2, s1 f1 + s2 f2 + f3 - m g)`.
/// Linear in the sensor columns, so it commutes with the (linear, time-invariant) low-pass:
/// conditioning forms it before filtering and filters two columns instead of three.
pub(crate) fn applied_in_place(f1_to_fx: &mut [f64], f2_to_fy: &mut [f64], f3: &[f64], mechanics: &Mechanics) -> Result<(), IdentificationError> {
    mechanics.validate()?;
    let n = f1_to_fx.len();
    if f2_to_fy.len() != n || f3.len() != n {
        return Err(IdentificationError::BadInput { what: "eq. 2 columns".into(), reason: "f1, f2 and f3 differ in length".into() });
    }
    let applied = Applied::new(mechanics);
    let (fy, f3) = (&mut f2_to_fy[..n], &f3[..n]);
    for i in 0..n {
        [f1_to_fx[i], fy[i]] = applied.at(f1_to_fx[i], fy[i], f3[i]);
    }
    Ok(())
}

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

/// Eq. 2, allocating `(fx, fy)`.
pub fn eq2(
    f1: &[f64],
    f2: &[f64],
    f3: &[f64],
    housing_ax: &[f64],
    housing_ay: &[f64],
    mechanics: &Mechanics,
) -> Result<(Vec<f64>, Vec<f64>), IdentificationError> {
    let mut fx = vec![0.0; f1.len()];
    let mut fy = vec![0.0; f1.len()];
    eq2_into(f1, f2, f3, housing_ax, housing_ay, mechanics, &mut fx, &mut fy)?;
    Ok((fx, fy))
}

/// [`static_part`]'s check of its window: non-empty, inside both columns.
pub(crate) fn check_static_window(fx: &[f64], fy: &[f64], range: &Range<usize>) -> Result<(), IdentificationError> {
    if range.is_empty() || range.end > fx.len() || range.end > fy.len() {
        return Err(IdentificationError::BadInput {
            what: "static film force window".into(),
            reason: format!("range {range:?} is empty or outside the {} / {} samples", fx.len(), fy.len()),
        });
    }
    Ok(())
}

/// The static film force: the mean of `fx`, `fy` over `range` (non-empty, inside both).
pub fn static_part(fx: &[f64], fy: &[f64], range: Range<usize>) -> Result<[f64; 2], IdentificationError> {
    check_static_window(fx, fy, &range)?;
    let k = range.len() as f64;
    // Both sums in one loop: each is still added up in index order from -0.0 (as `Iterator::
    // sum` of f64 does: the same result, bit for bit), and the two chains of dependent adds
    // overlap.
    let (mut sx, mut sy) = (-0.0, -0.0);
    for (&x, &y) in fx[range.clone()].iter().zip(&fy[range]) {
        sx += x;
        sy += y;
    }
    Ok([sx / k, sy / k])
}
