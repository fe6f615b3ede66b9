//! The typed rig file: the built-in rig, a valid fixture using every option, and invalid
//! variants whose errors must name the offending field.

use oilfilm_physics::config::{RigConfig, ZHOU2004_TOML};
use oilfilm_physics::daq::DaqConfig;
use oilfilm_physics::film::FilmModelConfig;
use oilfilm_physics::geometry::BearingGeometry;
use oilfilm_physics::oil::Oil;
use oilfilm_physics::rig::Rig;
use oilfilm_physics::simulation::SimulatedRig;

const VALID_FIXTURE: &str = include_str!("data/config/short-film-plain-bearing.toml");

#[test]
fn the_built_in_rig_is_the_papers_rig() {
    let c = RigConfig::zhou2004().expect("built-in rig");
    assert_eq!(c.bearing, BearingGeometry::zhou2004());
    // The file's oil is the library's turbine oil 22#, and its DAQ the documented default.
    assert_eq!(c.oil, Oil::turbine_22());
    assert_eq!(c.daq, DaqConfig::zhou2004());
    let mu = c.oil.viscosity_pa_s(c.operating.bearing_temperature_c).unwrap();
    println!("bearing temperature {} C -> viscosity {mu} Pa s", c.operating.bearing_temperature_c);
    assert!((mu - 0.03).abs() < 1e-5, "the default operating point is the paper's 0.03 Pa s, got {mu}");
    assert_eq!(c.operating.speed_rpm, 1500.0);
    assert_eq!(c.operating.bearing_load_n, 5000.0);
    assert!(c.effects.is_none());
}

#[test]
fn the_built_in_rig_round_trips_through_toml() {
    let c = RigConfig::zhou2004().unwrap();
    let text = c.to_toml_string().unwrap();
    let back = RigConfig::from_toml_str(&text, "round trip").unwrap();
    assert_eq!(c, back);
}

#[test]
fn a_file_using_every_option_loads_and_simulates() {
    let c = RigConfig::from_toml_str(VALID_FIXTURE, "short-film-plain-bearing.toml").expect("valid fixture");
    assert_eq!(c.film, FilmModelConfig::Short);
    assert!(c.effects.channel_delay.is_some() && c.effects.support_friction.is_some());
    let mut sim = SimulatedRig::new(&c, 0.0).expect("rig builds");
    let period = sim.period_s();
    for i in 1..=500 {
        let t = i as f64 * period;
        let f = 50.0 * (2.0 * std::f64::consts::PI * 30.0 * t).sin();
        sim.step(&oilfilm_physics::rig::RigInput { exciter_n: [f, -f] }, t).expect("steps");
    }
    println!("fixture rig eccentricity {:.4}", sim.operating_point().eccentricity);
}

/// Replaces `from` (which must occur in the built-in text) by `to`.
fn mutate(from: &str, to: &str) -> String {
    assert!(ZHOU2004_TOML.contains(from), "built-in rig text has no `{from}`");
    ZHOU2004_TOML.replacen(from, to, 1)
}

#[test]
fn invalid_files_name_the_field() {
    let cases: Vec<(&str, String, &str)> = vec![
        ("negative clearance", mutate("clearance_m = 0.114e-3", "clearance_m = -0.114e-3"), "bearing.clearance_m"),
        ("NaN diameter", mutate("diameter_m = 0.152", "diameter_m = nan"), "bearing.diameter_m"),
        ("clearance not thin", mutate("clearance_m = 0.114e-3", "clearance_m = 0.01"), "bearing.clearance_m"),
        ("unknown key", mutate("[housing]\n", "[housing]\nmass_lb = 3.0\n"), "mass_lb"),
        ("unknown table", mutate("[journal]\n", "[journall]\n"), "journall"),
        ("wrong type", mutate("mass_kg = 60.0", "mass_kg = \"sixty\""), "mass_kg"),
        ("zero mass", mutate("mass_kg = 60.0", "mass_kg = 0.0"), "housing.mass_kg"),
        ("parallel exciters", mutate("exciter_angles_deg = [45.0, 135.0]", "exciter_angles_deg = [45.0, 225.0]"), "housing.exciter_angles_deg"),
        ("no slew limit", mutate("exciter_max_slew_n_per_s = 1.0e6", "exciter_max_slew_n_per_s = 0.0"), "housing.exciter_max_slew_n_per_s"),
        ("band above Nyquist", mutate("exciter_band_hz = [0.0, 80.0]", "exciter_band_hz = [0.0, 3000.0]"), "housing.exciter_band_hz"),
        ("load beyond the bellows", mutate("bearing_load_n = 5000.0", "bearing_load_n = 50000.0"), "operating.bearing_load_n"),
        ("negative speed", mutate("speed_rpm = 1500.0", "speed_rpm = -1500.0"), "operating.speed_rpm"),
        ("temperature outside the oil law", mutate("bearing_temperature_c = 28.81", "bearing_temperature_c = 400.0"), "operating.bearing_temperature_c"),
        ("orbit larger than the film", mutate("orbit_amplitude_m = 0.0", "orbit_amplitude_m = 1.0e-4"), "journal.orbit_amplitude_m"),
        ("substeps zero", mutate("substeps = 2", "substeps = 0"), "simulation.substeps"),
        ("grid too coarse", mutate("n_theta = ", "n_theta = 2 #"), "film.n_theta"),
        ("negative density", mutate("density_kg_m3 = 870.0", "density_kg_m3 = -870.0"), "oil.density_kg_m3"),
        ("negative added mass", mutate("[effects]\n", "[effects]\nfluid_inertia = { added_mass_kg = -3.0 }\n"), "effects.fluid_inertia.added_mass_kg"),
        ("unknown effect", mutate("[effects]\n", "[effects]\nmisalignment = { angle_deg = 1.0 }\n"), "misalignment"),
        ("DAQ rate NaN", mutate("sample_rate_hz = 5000.0", "sample_rate_hz = nan"), "daq.sample_rate_hz"),
    ];
    for (label, text, field) in cases {
        let err = RigConfig::from_toml_str(&text, "zhou2004-variant.toml").expect_err(label).to_string();
        println!("{label:<32} -> {err}");
        assert!(err.contains(field), "{label}: error `{err}` does not name `{field}`");
    }
}

#[test]
fn an_unreachable_operating_point_names_the_load() {
    // 19 kN at 1 rpm: the film cannot carry it below eccentricity 0.98.
    let mut c = RigConfig::zhou2004().unwrap();
    c.film = FilmModelConfig::Short;
    c.operating.speed_rpm = 1.0;
    c.operating.bearing_load_n = 19000.0;
    c.validate().expect("the file itself is valid");
    let err = Rig::new(&c, 0.0, 0.0).expect_err("no equilibrium").to_string();
    println!("{err}");
    assert!(err.contains("operating.bearing_load_n") && err.contains("equilibrium"), "{err}");
}

#[test]
fn effects_on_unknown_channels_are_refused_by_name() {
    let text = mutate("[effects]\n", "[effects]\nchannel_delay = { channel = \"probe_c_x\", delay_s = 1.0e-4 }\n");
    let c = RigConfig::from_toml_str(&text, "x.toml").expect("parses: channel names are checked by the DAQ");
    let err = SimulatedRig::new(&c, 0.0).expect_err("unknown channel").to_string();
    println!("{err}");
    assert!(err.contains("effects.channel_delay.channel"), "{err}");
}

#[test]
fn a_rig_sheet_without_the_exciters_slew_limit_loads_with_the_conservative_default() {
    // Rig sheets written for analysis (the outside records' among them) do not state the
    // exciters' slew limit; they must still load, the conservative default holding.
    let text = mutate("exciter_max_slew_n_per_s = 1.0e6\n", "");
    assert!(!text.contains("exciter_max_slew_n_per_s"), "the mutation removed the key");
    let c = RigConfig::from_toml_str(&text, "sheet.toml").expect("loads without the slew limit");
    assert_eq!(c.housing.exciter_max_slew_n_per_s, oilfilm_physics::config::DEFAULT_EXCITER_MAX_SLEW_N_PER_S);
}
