//! Injectable effects: each is off unless configured, and each is set by one magnitude
//! (plus, where it must be said, which channel; `film_relaxation` by a stiffness and its
//! time constant). Later work hides them in simulated data and
//! requires the diagnosis to find them; the names here are the diagnosis catalog's names.
//!
//! | effect | where it acts | magnitude |
//! |---|---|---|
//! | `fluid_inertia` | film force gains `-M_a r''` (isotropic added mass) | `added_mass_kg` |
//! | `thermal_drift` | bearing temperature ramps; viscosity follows the oil law | `heating_rate_c_per_s` |
//! | `synchronous_runout` | bearing probes see a 1X orbit with no force cause | `amplitude_m` |
//! | `channel_delay` | one channel is sampled `delay_s` later than its multiplexer slot (its reading leads by `delay_s`; negative: it lags, as an amplifier's phase) | `delay_s` on `channel` |
//! | `probe_saturation` | one probe clips at a smaller range than calibrated | `limit_m` on `channel` |
//! | `support_friction` | Coulomb friction in the support rollers on the housing | `friction_force_n` |
//! | `housing_mass_mismatch` | true housing mass differs from the configured one | `mass_error_kg` |
//! | `film_relaxation` | a Maxwell element (spring `k_r` in series with a dashpot `k_r tau`) in parallel with the film; **not in the diagnosis catalog** | `stiffness_n_m`, `time_constant_s` |
//!
//! Amplitude nonlinearity needs no switch: it comes from the nonlinear film.
//!
//! `film_relaxation` is deliberately outside the catalog: it is a frequency-dependent film
//! that no candidate extension explains, so the diagnosis must call a record carrying it
//! `unexplained` rather than give it a catalog name (see [`FilmRelaxation`]).

use serde::{Deserialize, Serialize};

use crate::error::PhysicsError;

/// Fluid inertia: an isotropic added mass in the film, `dF_on_journal = -M_a r''`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FluidInertia {
    pub added_mass_kg: f64,
}

/// Thermal drift: the bearing temperature rises linearly over the record.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalDrift {
    pub heating_rate_c_per_s: f64,
}

/// Synchronous (1X) runout seen by all four bearing probes: the probe track on the journal
/// is off-centre, so the probes read a forward 1X orbit `amplitude (cos, sin)(phi + phase)`
/// where `phi` is the shaft angle. No force is associated with it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SynchronousRunout {
    pub amplitude_m: f64,
    #[serde(default)]
    pub phase_deg: f64,
}

/// One channel sampled `delay_s` later than its slot in the multiplex schedule (a mislabelled
/// multiplexer order): its reading leads the signal by `delay_s`. A negative `delay_s` is a
/// channel that lags (an amplifier's phase, an unmodelled anti-alias filter's group delay).
/// The diagnosis reports a found delay in the same convention.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelDelay {
    pub channel: String,
    pub delay_s: f64,
}

/// One displacement probe leaves its linear range at `limit_m` from its calibrated zero and
/// clips there.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeSaturation {
    pub channel: String,
    pub limit_m: f64,
}

/// Coulomb friction of magnitude `friction_force_n` opposing the housing's velocity.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SupportFriction {
    pub friction_force_n: f64,
}

/// The housing's true mass is the configured mass plus `mass_error_kg`; everything that
/// reads the configuration (conditioning, eq. 2) still uses the configured mass.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HousingMassMismatch {
    pub mass_error_kg: f64,
}

/// Film relaxation: a frequency-dependent film, OUTSIDE the diagnosis catalog. It exists so
/// that tests can hide an effect the catalog does not name and require the verdict
/// `unexplained`.
///
/// A Maxwell element (a spring `k_r` in series with a dashpot `k_r tau`) acts in parallel with
/// the film, the same on both axes. With `r` the journal relative to the bearing and `z` the
/// element's internal coordinate (the spring-dashpot junction), per axis
///
/// ```text
/// tau z' = r - z,        dF_on_journal = -k_r (r - z)
/// ```
///
/// (Lund's sign convention, as the film's `-(K dr + C dr')`). Under harmonic motion
/// `r = R e^{i w t}` the element adds the complex stiffness `k_r i w tau / (1 + i w tau)`, so
/// the apparent film coefficients depend on frequency:
///
/// ```text
/// K_app(w) = K + k_r (w tau)^2 / (1 + (w tau)^2)     rises from K towards K + k_r,
/// C_app(w) = C + k_r tau / (1 + (w tau)^2)           falls back towards C,
/// ```
///
/// both changing across the band around `1 / (2 pi tau)`. No K-C-M model with constant
/// coefficients reproduces this (an added mass makes the stiffness fall with `w^2`; this
/// rises and saturates). It carries no static load: at rest `z = r` and the element's force
/// vanishes, so the equilibrium is the film's own.
///
/// Physically it stands for a viscoelastic or aerated (compressible) oil film, whose squeeze
/// pressure lags the motion by a relaxation time. That a gas phase in an oscillating squeeze
/// film makes its force depend on frequency (stiffening, with less damping, as the frequency
/// rises) is shown by Haber & Etsion, "Analysis of an oscillatory oil squeeze film containing
/// a central gas bubble", ASLE Trans. 28(2), 1985, 253-260, and Hashimoto, "Squeeze film
/// characteristics between parallel circular plates containing a single central air bubble in
/// the inertial flow regime", ASME J. Tribol. 117(3), 1995, 513-518. The single Maxwell
/// element here is a modelling device with that qualitative behaviour, not a fit to their
/// results.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilmRelaxation {
    /// `k_r`: the stiffness the element adds well above `1 / (2 pi tau)`, N/m.
    pub stiffness_n_m: f64,
    /// `tau`: the element's relaxation time, s.
    pub time_constant_s: f64,
}

/// The set of injected effects. All off by default.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Effects {
    pub fluid_inertia: Option<FluidInertia>,
    pub thermal_drift: Option<ThermalDrift>,
    pub synchronous_runout: Option<SynchronousRunout>,
    pub channel_delay: Option<ChannelDelay>,
    pub probe_saturation: Option<ProbeSaturation>,
    pub support_friction: Option<SupportFriction>,
    pub housing_mass_mismatch: Option<HousingMassMismatch>,
    /// Outside the diagnosis catalog: see [`FilmRelaxation`].
    pub film_relaxation: Option<FilmRelaxation>,
}

impl Effects {
    /// True when no effect is injected.
    pub fn is_none(&self) -> bool {
        *self == Self::default()
    }

    /// Checks every magnitude; `prefix` is the dotted path of this table in its file.
    /// Channel names are checked by the DAQ, which knows its channels.
    pub fn validate(&self, prefix: &str) -> Result<(), PhysicsError> {
        let check = |field: &str, v: f64, allow_negative: bool| -> Result<(), PhysicsError> {
            if !v.is_finite() || (!allow_negative && v < 0.0) {
                return Err(PhysicsError::invalid(
                    format!("{prefix}.{field}"),
                    if allow_negative { format!("must be finite, got {v:?}") } else { format!("must be finite and >= 0, got {v:?}") },
                ));
            }
            Ok(())
        };
        if let Some(e) = &self.fluid_inertia {
            check("fluid_inertia.added_mass_kg", e.added_mass_kg, false)?;
        }
        if let Some(e) = &self.thermal_drift {
            check("thermal_drift.heating_rate_c_per_s", e.heating_rate_c_per_s, true)?;
        }
        if let Some(e) = &self.synchronous_runout {
            check("synchronous_runout.amplitude_m", e.amplitude_m, false)?;
            check("synchronous_runout.phase_deg", e.phase_deg, true)?;
        }
        if let Some(e) = &self.channel_delay {
            check("channel_delay.delay_s", e.delay_s, true)?;
        }
        if let Some(e) = &self.probe_saturation {
            check("probe_saturation.limit_m", e.limit_m, false)?;
            if e.limit_m == 0.0 {
                return Err(PhysicsError::invalid(format!("{prefix}.probe_saturation.limit_m"), "must be > 0"));
            }
        }
        if let Some(e) = &self.support_friction {
            check("support_friction.friction_force_n", e.friction_force_n, false)?;
        }
        if let Some(e) = &self.housing_mass_mismatch {
            check("housing_mass_mismatch.mass_error_kg", e.mass_error_kg, true)?;
        }
        if let Some(e) = &self.film_relaxation {
            check("film_relaxation.stiffness_n_m", e.stiffness_n_m, false)?;
            let tau = e.time_constant_s;
            if !tau.is_finite() || tau <= 0.0 {
                return Err(PhysicsError::invalid(format!("{prefix}.film_relaxation.time_constant_s"), format!("must be finite and > 0, got {tau:?}")));
            }
        }
        Ok(())
    }
}
