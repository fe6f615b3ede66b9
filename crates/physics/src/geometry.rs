//! Bearing geometry: diameter, length, clearance and the arcs that carry a film.

use serde::{Deserialize, Serialize};

use crate::error::PhysicsError;

/// Which arcs of the bearing carry a film.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum BearingKind {
    /// Plain 360 degree bearing: one periodic film.
    Plain,
    /// Two axial grooves at ambient pressure, diametrically opposite. With the default
    /// `groove_centre_deg = 0` the grooves sit on the horizontal diameter (theta = 0 and 180
    /// degrees) and a vertical load points at the middle of the lower pad, as in Lund & Thomsen
    /// (1978). Each pad spans `180 - groove_arc_deg` degrees.
    TwoAxialGroove {
        /// Angular width of each groove, degrees (Lund & Thomsen: 20).
        groove_arc_deg: f64,
        /// Angle of the first groove's centre from +x towards +y, degrees.
        #[serde(default)]
        groove_centre_deg: f64,
    },
}

/// One arc that carries a film, from `start_rad` to `end_rad` (end > start, measured from +x
/// towards +y, may exceed 2 pi).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pad {
    pub start_rad: f64,
    pub end_rad: f64,
}

/// Bearing geometry in SI units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BearingGeometry {
    pub diameter_m: f64,
    pub length_m: f64,
    /// Radial clearance `c` (pad clearance for a grooved bearing).
    pub clearance_m: f64,
    pub kind: BearingKind,
}

impl BearingGeometry {
    /// The Zhou et al. (2004) test bearing: D 152 mm, L 88.3 mm, c 0.114 mm. The paper does
    /// not state the groove layout; a two-axial-groove bearing with 20 degree grooves on the
    /// horizontal diameter is assumed (the commonest industrial layout, and the one the
    /// Lund & Thomsen tables describe).
    pub fn zhou2004() -> Self {
        Self { diameter_m: 0.152, length_m: 0.0883, clearance_m: 0.114e-3, kind: BearingKind::TwoAxialGroove { groove_arc_deg: 20.0, groove_centre_deg: 0.0 } }
    }

    pub fn radius_m(&self) -> f64 {
        0.5 * self.diameter_m
    }

    /// Length over diameter.
    pub fn slenderness(&self) -> f64 {
        self.length_m / self.diameter_m
    }

    /// Relative clearance psi = c / R.
    pub fn relative_clearance(&self) -> f64 {
        self.clearance_m / self.radius_m()
    }

    /// The film-carrying arcs. A plain bearing has a single periodic arc [0, 2 pi).
    pub fn pads(&self) -> Vec<Pad> {
        use std::f64::consts::PI;
        match self.kind {
            BearingKind::Plain => vec![Pad { start_rad: 0.0, end_rad: 2.0 * PI }],
            BearingKind::TwoAxialGroove { groove_arc_deg, groove_centre_deg } => {
                let half_groove = 0.5 * groove_arc_deg.to_radians();
                let c0 = groove_centre_deg.to_radians();
                (0..2)
                    .map(|k| {
                        let centre = c0 + k as f64 * PI;
                        Pad { start_rad: centre + half_groove, end_rad: centre + PI - half_groove }
                    })
                    .collect()
            }
        }
    }

    /// Checks every field; `prefix` is the dotted path of this geometry in its config file.
    pub fn validate(&self, prefix: &str) -> Result<(), PhysicsError> {
        let positive = |name: &str, v: f64| -> Result<(), PhysicsError> {
            if !v.is_finite() || v <= 0.0 {
                return Err(PhysicsError::invalid(format!("{prefix}.{name}"), format!("must be a positive finite length in metres, got {v:?}")));
            }
            Ok(())
        };
        positive("diameter_m", self.diameter_m)?;
        positive("length_m", self.length_m)?;
        positive("clearance_m", self.clearance_m)?;
        if self.clearance_m >= 0.05 * self.radius_m() {
            return Err(PhysicsError::invalid(
                format!("{prefix}.clearance_m"),
                format!("{} m is not a thin film against radius {} m (Reynolds lubrication needs c/R << 1)", self.clearance_m, self.radius_m()),
            ));
        }
        if let BearingKind::TwoAxialGroove { groove_arc_deg, groove_centre_deg } = self.kind {
            if !groove_arc_deg.is_finite() || !(0.0..90.0).contains(&groove_arc_deg) {
                return Err(PhysicsError::invalid(format!("{prefix}.kind.groove_arc_deg"), format!("must lie in [0, 90) degrees, got {groove_arc_deg:?}")));
            }
            if !groove_centre_deg.is_finite() {
                return Err(PhysicsError::invalid(format!("{prefix}.kind.groove_centre_deg"), format!("must be finite, got {groove_centre_deg:?}")));
            }
        }
        Ok(())
    }
}
