//! The typed rig configuration.
//!
//! One TOML file describes a rig: bearing geometry, film model, oil, housing and exciters,
//! static load, default operating point, journal motion, DAQ chain, simulation settings and
//! injected effects. Every table rejects unknown keys, and [`RigConfig::validate`] checks every
//! number, naming the offending field by its dotted path (`bearing.clearance_m`).
//!
//! The paper's rig is the built-in default: `launch_configs/rigs/zhou2004.toml`, compiled in
//! and returned by [`RigConfig::zhou2004`]. Reading files is the caller's job (this crate does
//! no I/O); [`RigConfig::from_toml_str`] takes the text and a name for error messages.

use nalgebra::Vector2;
use serde::{Deserialize, Serialize};

use crate::daq::DaqConfig;
use crate::effects::Effects;
use crate::error::PhysicsError;
use crate::film::finite::{FiniteBearing, GridSpec};
use crate::film::map::{FilmMap, MapSpec};
use crate::film::short::ShortBearing;
use crate::film::{Film, FilmModelConfig, Running};
use crate::geometry::BearingGeometry;
use crate::oil::Oil;
use crate::operating_point::{self, EquilibriumOptions};

/// The text of the built-in Zhou et al. (2004) rig.
pub const ZHOU2004_TOML: &str = include_str!("../../../launch_configs/rigs/zhou2004.toml");

/// The exciters' slew limit when a rig file does not state one, N/s: 0.2 MN/s, 40 N per
/// setpoint at 5 kHz (slower than any plan of the built-in rig needs; a ramp to 1.5 kN then
/// takes 7.5 ms, well inside the exciter's own ramps).
pub const DEFAULT_EXCITER_MAX_SLEW_N_PER_S: f64 = 2.0e5;

fn default_exciter_max_slew() -> f64 {
    DEFAULT_EXCITER_MAX_SLEW_N_PER_S
}

/// Housing and exciters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HousingConfig {
    /// Mass of everything that moves with the bearing, kg (eq. 2's `m`).
    pub mass_kg: f64,
    /// Direction of each exciter's push on the housing, degrees from +x towards +y.
    pub exciter_angles_deg: [f64; 2],
    /// The exciters' force limit, N (the paper's: 1.5 kN).
    pub exciter_max_force_n: f64,
    /// The exciters' frequency band, Hz (the paper's: 0-80 Hz).
    pub exciter_band_hz: [f64; 2],
    /// The fastest an exciter's force may change, N/s: no setpoint differs from the one
    /// before by more than this over the setpoint period, through every transition (start,
    /// plan change, stop). A safety limit of the exciters and their amplifiers. A rig sheet
    /// written for analysis may leave it out: then the conservative
    /// [`DEFAULT_EXCITER_MAX_SLEW_N_PER_S`] holds (the analysis never reads it).
    #[serde(default = "default_exciter_max_slew")]
    pub exciter_max_slew_n_per_s: f64,
    pub gravity_m_s2: f64,
}

/// The pneumatic bellows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StaticLoadConfig {
    /// Relative amplitude of the pneumatic ripple on the bellows force.
    pub ripple_fraction: f64,
    pub ripple_hz: f64,
    /// Largest bellows force, N (the paper: 0-20 kN in its tests).
    pub max_force_n: f64,
}

/// The operating point a simulation starts from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OperatingConfig {
    pub speed_rpm: f64,
    /// Static load carried by the film, N. The bellows supply this plus the housing weight.
    pub bearing_load_n: f64,
    pub bearing_temperature_c: f64,
}

/// Journal motion. Fixed in space unless it runs on a 1X orbit (shaft unbalance or a bent
/// journal: real motion that loads the film, unlike probe runout).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct JournalConfig {
    pub orbit_amplitude_m: f64,
    pub orbit_phase_deg: f64,
}

/// Simulation settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimulationConfig {
    /// Seed of every random number in a simulated record.
    pub seed: u64,
    /// Integrator steps per DAQ scan.
    pub substeps: usize,
}

/// A whole rig.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigConfig {
    pub name: String,
    pub bearing: BearingGeometry,
    pub film: FilmModelConfig,
    pub oil: Oil,
    pub housing: HousingConfig,
    pub static_load: StaticLoadConfig,
    pub operating: OperatingConfig,
    #[serde(default)]
    pub journal: JournalConfig,
    pub daq: DaqConfig,
    pub simulation: SimulationConfig,
    #[serde(default)]
    pub effects: Effects,
}

fn positive(field: &str, v: f64) -> Result<(), PhysicsError> {
    if !v.is_finite() || v <= 0.0 {
        return Err(PhysicsError::invalid(field, format!("must be positive and finite, got {v:?}")));
    }
    Ok(())
}

fn finite(field: &str, v: f64) -> Result<(), PhysicsError> {
    if !v.is_finite() {
        return Err(PhysicsError::invalid(field, format!("must be finite, got {v:?}")));
    }
    Ok(())
}

impl RigConfig {
    /// The paper's rig, from the built-in file.
    pub fn zhou2004() -> Result<Self, PhysicsError> {
        Self::from_toml_str(ZHOU2004_TOML, "launch_configs/rigs/zhou2004.toml")
    }

    /// Parses and validates a rig file. `origin` names it in errors (a path, usually).
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self, PhysicsError> {
        let config: Self =
            toml::from_str(text).map_err(|e| PhysicsError::ConfigParse { origin: format!(" {origin}"), message: e.to_string().trim_end().to_string() })?;
        config.validate()?;
        Ok(config)
    }

    /// Serialises back to TOML.
    pub fn to_toml_string(&self) -> Result<String, PhysicsError> {
        toml::to_string_pretty(self).map_err(|e| PhysicsError::ConfigParse { origin: String::new(), message: e.to_string() })
    }

    /// Checks every field; the first problem found is returned with its dotted path.
    pub fn validate(&self) -> Result<(), PhysicsError> {
        self.bearing.validate("bearing")?;
        if let FilmModelConfig::Finite { n_theta, n_z, .. } = self.film {
            GridSpec { n_theta, n_z }.validate("film")?;
        }
        self.oil.validate("oil")?;
        let h = &self.housing;
        positive("housing.mass_kg", h.mass_kg)?;
        for (i, a) in h.exciter_angles_deg.iter().enumerate() {
            finite(&format!("housing.exciter_angles_deg[{i}]"), *a)?;
        }
        let (a0, a1) = (h.exciter_angles_deg[0].to_radians(), h.exciter_angles_deg[1].to_radians());
        if (a0 - a1).sin().abs() < 0.1 {
            return Err(PhysicsError::invalid("housing.exciter_angles_deg", "the two exciters must push along independent directions"));
        }
        positive("housing.exciter_max_force_n", h.exciter_max_force_n)?;
        let [f_lo, f_hi] = h.exciter_band_hz;
        if !f_lo.is_finite() || !f_hi.is_finite() || f_lo < 0.0 || f_hi <= f_lo {
            return Err(PhysicsError::invalid("housing.exciter_band_hz", format!("must be [low, high] with 0 <= low < high, got [{f_lo:?}, {f_hi:?}]")));
        }
        if f_hi >= 0.5 * self.daq.sample_rate_hz {
            return Err(PhysicsError::invalid(
                "housing.exciter_band_hz",
                format!("upper edge {f_hi:?} Hz must stay below the DAQ's Nyquist frequency {:?} Hz", 0.5 * self.daq.sample_rate_hz),
            ));
        }
        positive("housing.exciter_max_slew_n_per_s", h.exciter_max_slew_n_per_s)?;
        positive("housing.gravity_m_s2", h.gravity_m_s2)?;
        let s = &self.static_load;
        if !s.ripple_fraction.is_finite() || !(0.0..0.2).contains(&s.ripple_fraction) {
            return Err(PhysicsError::invalid("static_load.ripple_fraction", format!("must lie in [0, 0.2), got {:?}", s.ripple_fraction)));
        }
        if !s.ripple_hz.is_finite() || s.ripple_hz < 0.0 {
            return Err(PhysicsError::invalid("static_load.ripple_hz", format!("must be >= 0, got {:?}", s.ripple_hz)));
        }
        positive("static_load.max_force_n", s.max_force_n)?;
        let o = &self.operating;
        positive("operating.speed_rpm", o.speed_rpm)?;
        positive("operating.bearing_load_n", o.bearing_load_n)?;
        let bellows = o.bearing_load_n + h.mass_kg * h.gravity_m_s2;
        if bellows > s.max_force_n {
            return Err(PhysicsError::invalid(
                "operating.bearing_load_n",
                format!("needs a bellows force of {bellows:.3e} N (load + housing weight), above static_load.max_force_n = {:?} N", s.max_force_n),
            ));
        }
        finite("operating.bearing_temperature_c", o.bearing_temperature_c)?;
        self.oil.viscosity_pa_s(o.bearing_temperature_c).map_err(|e| PhysicsError::invalid("operating.bearing_temperature_c", e.to_string()))?;
        let j = &self.journal;
        if !j.orbit_amplitude_m.is_finite() || j.orbit_amplitude_m < 0.0 || j.orbit_amplitude_m >= 0.5 * self.bearing.clearance_m {
            return Err(PhysicsError::invalid(
                "journal.orbit_amplitude_m",
                format!("must lie in [0, c/2) = [0, {:e}) m, got {:?}", 0.5 * self.bearing.clearance_m, j.orbit_amplitude_m),
            ));
        }
        finite("journal.orbit_phase_deg", j.orbit_phase_deg)?;
        self.daq.validate("daq")?;
        if !(1..=64).contains(&self.simulation.substeps) {
            return Err(PhysicsError::invalid("simulation.substeps", format!("must lie in 1..=64, got {:?}", self.simulation.substeps)));
        }
        self.effects.validate("effects")?;
        Ok(())
    }

    /// The operating point's running condition (speed and the oil's viscosity at the bearing
    /// temperature).
    pub fn running(&self) -> Result<Running, PhysicsError> {
        Ok(Running::from_rpm(self.operating.speed_rpm, self.oil.viscosity_pa_s(self.operating.bearing_temperature_c)?))
    }

    /// The configured film model, untabulated: what a coefficient calculation should use.
    pub fn film(&self) -> Result<Box<dyn Film + Send>, PhysicsError> {
        Ok(match self.film {
            FilmModelConfig::Short => Box::new(ShortBearing::new(self.bearing)?),
            FilmModelConfig::Finite { n_theta, n_z, .. } => Box::new(FiniteBearing::new(self.bearing, GridSpec { n_theta, n_z })?),
        })
    }

    /// The film the rig simulation integrates: the configured model, tabulated around the
    /// equilibrium under `load_on_journal_n` when the configuration asks for it.
    pub fn film_for_rig(&self, running: &Running, load_on_journal_n: Vector2<f64>) -> Result<Box<dyn Film + Send>, PhysicsError> {
        let mut film = self.film()?;
        if let FilmModelConfig::Finite { tabulate: true, .. } = self.film {
            let op = operating_point::solve(film.as_mut(), running, load_on_journal_n, &EquilibriumOptions::default())?;
            let map = FilmMap::build(film, op.journal.x_m, op.journal.y_m, MapSpec::default())?;
            film = Box::new(map);
        }
        Ok(film)
    }
}
