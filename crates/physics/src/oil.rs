//! Lubricating oil: density and viscosity as functions of temperature.
//!
//! Three viscosity laws are offered:
//!
//! * [`ViscosityLaw::Constant`]: isoviscous, for cross-checks against textbook examples.
//! * [`ViscosityLaw::Walther`]: the Walther equation (Walther 1931, Erdoel und Teer 7),
//!   standardised in ASTM D341 ("Viscosity-temperature charts for liquid petroleum products"),
//!   `log10(log10(nu + 0.7)) = a - b log10(T)`, with `nu` the **kinematic** viscosity in cSt
//!   and `T` in kelvin. ASTM D341 adds small correction terms to the `0.7` below about
//!   2 cSt; they are left out, so the law is meant for `nu` above ~2 cSt (every lubricating
//!   oil in its working range). The dynamic viscosity is `mu = rho(T) nu`.
//! * [`ViscosityLaw::Vogel`]: Vogel's equation (Vogel 1921, Physikalische Zeitschrift 22; also
//!   called Vogel-Fulcher-Tammann) on the **dynamic** viscosity,
//!   `mu = a exp(b / (T_C + c))`, `T_C` in degrees Celsius.
//!
//! Density falls with temperature through a volumetric expansion coefficient:
//! `rho(T) = rho_15 / (1 + alpha (T - 15 C))`.
//!
//! All laws are used only in [`VALID_RANGE_C`] (-30 C to 200 C); outside it the viscosity
//! functions return an error rather than extrapolate.

use serde::{Deserialize, Serialize};

use crate::error::PhysicsError;

/// Temperature range, degrees Celsius, in which the viscosity laws are evaluated.
pub const VALID_RANGE_C: (f64, f64) = (-30.0, 200.0);

/// Volumetric thermal expansion typical of mineral oils, 1/C (used by
/// [`Oil::from_two_points`], which has no expansion argument).
pub const TYPICAL_THERMAL_EXPANSION_PER_C: f64 = 6.5e-4;

/// Reference temperature of the density, C.
const DENSITY_REFERENCE_C: f64 = 15.0;
/// The Walther constant of ASTM D341, cSt.
const WALTHER_OFFSET_CST: f64 = 0.7;
const KELVIN_OFFSET: f64 = 273.15;

/// Viscosity-temperature law. In TOML: `law = "walther"` plus the law's fields.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "law", rename_all = "snake_case", deny_unknown_fields)]
pub enum ViscosityLaw {
    /// Dynamic viscosity independent of temperature, Pa s.
    Constant { viscosity_pa_s: f64 },
    /// ASTM D341 (Walther): `log10(log10(nu_cSt + 0.7)) = a - b log10(T_K)`.
    Walther { a: f64, b: f64 },
    /// Vogel: `mu = a_pa_s exp(b_c / (T_C + c_c))`.
    Vogel { a_pa_s: f64, b_c: f64, c_c: f64 },
}

/// A lubricating oil.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Oil {
    pub name: String,
    /// Density at 15 C, kg/m^3.
    pub density_kg_m3: f64,
    /// Volumetric thermal expansion coefficient, 1/C: density falls as temperature rises.
    pub thermal_expansion_per_c: f64,
    pub law: ViscosityLaw,
}

impl Oil {
    /// The turbine oil 22# of Zhou et al. (2004): dynamic viscosity 48.65 mPa s at 20 C and
    /// 28.25 mPa s at 30 C, with a Walther (ASTM D341) law through both points.
    ///
    /// The paper prints the two numbers the other way round (28.25 at 20 C, 48.65 at 30 C),
    /// which would make the viscosity *rise* with temperature; the values are swapped here.
    /// They are consistent with an ISO VG 22 turbine oil (about 22 cSt at 40 C). The density
    /// (870 kg/m^3 at 15 C) and expansion (6.5e-4 /C) are typical values for such an oil, not
    /// data from the paper. Dynamic viscosities are converted to kinematic ones with the
    /// density at each temperature before fitting.
    pub fn turbine_22() -> Self {
        let density = 870.0;
        let expansion = TYPICAL_THERMAL_EXPANSION_PER_C;
        let (a, b) = walther_through(density, expansion, (20.0, 48.65e-3), (30.0, 28.25e-3));
        Self { name: "turbine oil 22#".to_string(), density_kg_m3: density, thermal_expansion_per_c: expansion, law: ViscosityLaw::Walther { a, b } }
    }

    /// An oil with a Walther law through two (temperature C, dynamic viscosity Pa s) points,
    /// density `density_kg_m3` at 15 C and [`TYPICAL_THERMAL_EXPANSION_PER_C`].
    ///
    /// Both points must lie in [`VALID_RANGE_C`] at different temperatures, and the viscosity
    /// must fall as the temperature rises.
    pub fn from_two_points(name: impl Into<String>, density_kg_m3: f64, point_1: (f64, f64), point_2: (f64, f64)) -> Result<Self, PhysicsError> {
        let expansion = TYPICAL_THERMAL_EXPANSION_PER_C;
        check_density("oil.density_kg_m3", density_kg_m3)?;
        let points = checked_points(&[point_1, point_2])?;
        for (i, &(t, mu)) in points.iter().enumerate() {
            let nu_cst = mu / density_at(density_kg_m3, expansion, t) * 1e6;
            if nu_cst <= 1.0 - WALTHER_OFFSET_CST {
                return Err(PhysicsError::invalid(
                    format!("oil viscosity point {}", i + 1),
                    format!("kinematic viscosity {nu_cst:.4} cSt is below the 0.3 cSt the Walther law can represent"),
                ));
            }
        }
        let (a, b) = walther_through(density_kg_m3, expansion, points[0], points[1]);
        let oil = Self { name: name.into(), density_kg_m3, thermal_expansion_per_c: expansion, law: ViscosityLaw::Walther { a, b } };
        oil.validate("oil")?;
        Ok(oil)
    }

    /// An oil with a Vogel law through three (temperature C, dynamic viscosity Pa s) points
    /// (exact fit), density `density_kg_m3` at 15 C and [`TYPICAL_THERMAL_EXPANSION_PER_C`].
    pub fn from_three_points_vogel(
        name: impl Into<String>,
        density_kg_m3: f64,
        point_1: (f64, f64),
        point_2: (f64, f64),
        point_3: (f64, f64),
    ) -> Result<Self, PhysicsError> {
        check_density("oil.density_kg_m3", density_kg_m3)?;
        let p = checked_points(&[point_1, point_2, point_3])?;
        let (t1, t2, t3) = (p[0].0, p[1].0, p[2].0);
        let (y1, y2, y3) = (p[0].1.ln(), p[1].1.ln(), p[2].1.ln());
        // ln mu = ln a + b/(T + c): the ratio of the two log-differences fixes c linearly.
        let ratio = (y1 - y2) / (y2 - y3);
        let denominator = ratio * (t3 - t2) - (t2 - t1);
        let c = ((t2 - t1) * t3 - ratio * (t3 - t2) * t1) / denominator;
        let b = (y1 - y2) * (t1 + c) * (t2 + c) / (t2 - t1);
        let a = (y1 - b / (t1 + c)).exp();
        if !(a.is_finite() && b.is_finite() && c.is_finite()) || b <= 0.0 || c <= -VALID_RANGE_C.0 {
            return Err(PhysicsError::invalid(
                "oil viscosity points",
                format!("no Vogel law with b > 0 and c > {} C passes through these three points (got a = {a:e} Pa s, b = {b} C, c = {c} C)", -VALID_RANGE_C.0),
            ));
        }
        let oil = Self {
            name: name.into(),
            density_kg_m3,
            thermal_expansion_per_c: TYPICAL_THERMAL_EXPANSION_PER_C,
            law: ViscosityLaw::Vogel { a_pa_s: a, b_c: b, c_c: c },
        };
        oil.validate("oil")?;
        Ok(oil)
    }

    /// Parses an oil from TOML (the fields of [`Oil`], the law as a `[law]` table with a `law`
    /// key) and validates it.
    pub fn from_toml_str(text: &str) -> Result<Self, PhysicsError> {
        let oil: Self = toml::from_str(text).map_err(|e| PhysicsError::ConfigParse { origin: " (oil)".to_string(), message: e.to_string() })?;
        oil.validate("oil")?;
        Ok(oil)
    }

    /// Dynamic viscosity at `temperature_c`, Pa s. Errors for NaN or a temperature outside
    /// [`VALID_RANGE_C`] (-30 C to 200 C), and for an oil whose law gives no finite positive
    /// viscosity there.
    pub fn viscosity_pa_s(&self, temperature_c: f64) -> Result<f64, PhysicsError> {
        check_temperature(temperature_c)?;
        let mu = self.viscosity_unchecked(temperature_c);
        if !mu.is_finite() || mu <= 0.0 {
            return Err(PhysicsError::invalid("oil.law", format!("gives viscosity {mu} Pa s at {temperature_c} C for oil `{}`", self.name)));
        }
        Ok(mu)
    }

    /// Density at `temperature_c`, kg/m^3: `rho_15 / (1 + alpha (T - 15))`. Not range-checked
    /// (NaN in, NaN out).
    pub fn density_kg_m3(&self, temperature_c: f64) -> f64 {
        density_at(self.density_kg_m3, self.thermal_expansion_per_c, temperature_c)
    }

    /// Temperature (C) at which the oil has `viscosity_pa_s`, found by bisection over
    /// [`VALID_RANGE_C`]. Errors when the viscosity is not reached in that range, and for a
    /// constant-viscosity oil.
    pub fn temperature_for_viscosity_c(&self, viscosity_pa_s: f64) -> Result<f64, PhysicsError> {
        if !viscosity_pa_s.is_finite() || viscosity_pa_s <= 0.0 {
            return Err(PhysicsError::invalid("viscosity", format!("must be positive and finite to find its temperature, got {viscosity_pa_s:?} Pa s")));
        }
        if let ViscosityLaw::Constant { .. } = self.law {
            return Err(PhysicsError::invalid("oil.law", format!("oil `{}` has a constant viscosity: no temperature corresponds to a viscosity", self.name)));
        }
        let (mut cold, mut hot) = VALID_RANGE_C;
        let mu_cold = self.viscosity_pa_s(cold)?;
        let mu_hot = self.viscosity_pa_s(hot)?;
        if !(mu_hot <= viscosity_pa_s && viscosity_pa_s <= mu_cold) {
            return Err(PhysicsError::invalid(
                "viscosity",
                format!("{viscosity_pa_s} Pa s is outside what oil `{}` reaches between {cold} C ({mu_cold} Pa s) and {hot} C ({mu_hot} Pa s)", self.name),
            ));
        }
        for _ in 0..200 {
            let mid = 0.5 * (cold + hot);
            if mid <= cold || mid >= hot {
                break;
            }
            if self.viscosity_unchecked(mid) > viscosity_pa_s {
                cold = mid;
            } else {
                hot = mid;
            }
        }
        Ok(0.5 * (cold + hot))
    }

    /// Logarithmic viscosity-temperature slope `(1/mu) dmu/dT`, 1/C: negative for a real oil,
    /// zero for a constant-viscosity one. Same range checks as [`Oil::viscosity_pa_s`].
    pub fn viscosity_temperature_slope_per_c(&self, temperature_c: f64) -> Result<f64, PhysicsError> {
        // Also checks the temperature and that the law is finite there.
        self.viscosity_pa_s(temperature_c)?;
        let slope = match self.law {
            ViscosityLaw::Constant { .. } => 0.0,
            ViscosityLaw::Walther { a, b } => {
                let alpha = self.thermal_expansion_per_c;
                let density_slope = -alpha / (1.0 + alpha * (temperature_c - DENSITY_REFERENCE_C));
                let t_k = temperature_c + KELVIN_OFFSET;
                // Y = log10(Z) = 10^(a - b log10 T), Z = nu + 0.7: dZ/dT = -ln(10) b Y Z / T.
                let y = 10f64.powf(a - b * t_k.log10());
                let z = 10f64.powf(y);
                let nu = z - WALTHER_OFFSET_CST;
                density_slope - std::f64::consts::LN_10 * b * y * z / (t_k * nu)
            }
            ViscosityLaw::Vogel { b_c, c_c, .. } => {
                let shifted = temperature_c + c_c;
                -b_c / (shifted * shifted)
            }
        };
        PhysicsError::check_finite("oil viscosity-temperature slope", slope)
    }

    /// Checks every field; `prefix` is the dotted path of this oil in its config file, and
    /// errors name the field (`oil.density_kg_m3`, `oil.law.b`).
    pub fn validate(&self, prefix: &str) -> Result<(), PhysicsError> {
        if self.name.trim().is_empty() {
            return Err(PhysicsError::invalid(format!("{prefix}.name"), "must not be empty"));
        }
        check_density(&format!("{prefix}.density_kg_m3"), self.density_kg_m3)?;
        let alpha = self.thermal_expansion_per_c;
        if !alpha.is_finite() || !(0.0..0.005).contains(&alpha) {
            return Err(PhysicsError::invalid(
                format!("{prefix}.thermal_expansion_per_c"),
                format!("must lie in [0, 0.005) per C (mineral oils: about 6.5e-4), got {alpha:?}"),
            ));
        }
        let field = |name: &str| format!("{prefix}.law.{name}");
        match self.law {
            ViscosityLaw::Constant { viscosity_pa_s } => {
                if !viscosity_pa_s.is_finite() || viscosity_pa_s <= 0.0 {
                    return Err(PhysicsError::invalid(field("viscosity_pa_s"), format!("must be positive and finite, got {viscosity_pa_s:?}")));
                }
            }
            ViscosityLaw::Walther { a, b } => {
                if !a.is_finite() {
                    return Err(PhysicsError::invalid(field("a"), format!("must be finite, got {a:?}")));
                }
                if !b.is_finite() || b <= 0.0 {
                    return Err(PhysicsError::invalid(field("b"), format!("must be positive (viscosity falls with temperature) and finite, got {b:?}")));
                }
            }
            ViscosityLaw::Vogel { a_pa_s, b_c, c_c } => {
                if !a_pa_s.is_finite() || a_pa_s <= 0.0 {
                    return Err(PhysicsError::invalid(field("a_pa_s"), format!("must be positive and finite, got {a_pa_s:?}")));
                }
                if !b_c.is_finite() || b_c <= 0.0 {
                    return Err(PhysicsError::invalid(field("b_c"), format!("must be positive (viscosity falls with temperature) and finite, got {b_c:?}")));
                }
                if !c_c.is_finite() || c_c <= -VALID_RANGE_C.0 {
                    return Err(PhysicsError::invalid(
                        field("c_c"),
                        format!("must exceed {} C so that T + c stays positive down to {} C, got {c_c:?}", -VALID_RANGE_C.0, VALID_RANGE_C.0),
                    ));
                }
            }
        }
        // Monotone laws: finite and positive at both ends means finite and positive throughout.
        for t in [VALID_RANGE_C.0, VALID_RANGE_C.1] {
            let mu = self.viscosity_unchecked(t);
            if !mu.is_finite() || mu <= 0.0 {
                return Err(PhysicsError::invalid(
                    format!("{prefix}.law"),
                    format!("gives viscosity {mu} Pa s at {t} C; the law must be finite and positive over {VALID_RANGE_C:?} C"),
                ));
            }
        }
        Ok(())
    }

    /// The law evaluated without range checks.
    fn viscosity_unchecked(&self, temperature_c: f64) -> f64 {
        match self.law {
            ViscosityLaw::Constant { viscosity_pa_s } => viscosity_pa_s,
            ViscosityLaw::Walther { a, b } => {
                let t_k = temperature_c + KELVIN_OFFSET;
                let nu_cst = 10f64.powf(10f64.powf(a - b * t_k.log10())) - WALTHER_OFFSET_CST;
                self.density_kg_m3(temperature_c) * nu_cst * 1e-6
            }
            ViscosityLaw::Vogel { a_pa_s, b_c, c_c } => a_pa_s * (b_c / (temperature_c + c_c)).exp(),
        }
    }
}

fn density_at(density_15: f64, expansion: f64, temperature_c: f64) -> f64 {
    density_15 / (1.0 + expansion * (temperature_c - DENSITY_REFERENCE_C))
}

fn check_density(field: &str, density: f64) -> Result<(), PhysicsError> {
    if !density.is_finite() || !(500.0..=2500.0).contains(&density) {
        return Err(PhysicsError::invalid(field, format!("must be a liquid lubricant's density at 15 C, 500 to 2500 kg/m^3, got {density:?}")));
    }
    Ok(())
}

fn check_temperature(temperature_c: f64) -> Result<(), PhysicsError> {
    PhysicsError::check_finite("oil temperature (C)", temperature_c)?;
    let (lo, hi) = VALID_RANGE_C;
    if !(lo..=hi).contains(&temperature_c) {
        return Err(PhysicsError::invalid(
            "oil temperature",
            format!("{temperature_c:?} C is outside the {lo} C to {hi} C range the viscosity laws are valid in"),
        ));
    }
    Ok(())
}

/// Checks (temperature C, viscosity Pa s) points and returns them sorted by temperature, with
/// distinct temperatures and viscosity strictly falling.
fn checked_points(points: &[(f64, f64)]) -> Result<Vec<(f64, f64)>, PhysicsError> {
    for (i, &(t, mu)) in points.iter().enumerate() {
        let field = format!("oil viscosity point {}", i + 1);
        if !t.is_finite() || !(VALID_RANGE_C.0..=VALID_RANGE_C.1).contains(&t) {
            return Err(PhysicsError::invalid(field, format!("temperature {t} C must lie in {} C to {} C", VALID_RANGE_C.0, VALID_RANGE_C.1)));
        }
        if !mu.is_finite() || mu <= 0.0 {
            return Err(PhysicsError::invalid(field, format!("viscosity must be positive and finite, got {mu:?} Pa s")));
        }
    }
    let mut sorted = points.to_vec();
    sorted.sort_by(|p, q| p.0.total_cmp(&q.0));
    for pair in sorted.windows(2) {
        let ((t1, mu1), (t2, mu2)) = (pair[0], pair[1]);
        if t2 - t1 < 1e-6 {
            return Err(PhysicsError::invalid("oil viscosity points", format!("two points share the temperature {t1} C")));
        }
        if mu2 >= mu1 {
            return Err(PhysicsError::invalid(
                "oil viscosity points",
                format!("viscosity must fall as temperature rises, but {mu1} Pa s at {t1} C is followed by {mu2} Pa s at {t2} C"),
            ));
        }
    }
    Ok(sorted)
}

/// Walther constants `(a, b)` through two (temperature C, dynamic viscosity Pa s) points.
/// Pure arithmetic; callers check that the points are distinct and above 0.3 cSt.
fn walther_through(density_15: f64, expansion: f64, p1: (f64, f64), p2: (f64, f64)) -> (f64, f64) {
    let walther_coordinates = |(t, mu): (f64, f64)| {
        let nu_cst = mu / density_at(density_15, expansion, t) * 1e6;
        ((t + KELVIN_OFFSET).log10(), (nu_cst + WALTHER_OFFSET_CST).log10().log10())
    };
    let (x1, y1) = walther_coordinates(p1);
    let (x2, y2) = walther_coordinates(p2);
    let b = (y1 - y2) / (x2 - x1);
    (y1 + b * x1, b)
}
