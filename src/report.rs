//! What the `rig` and `coefficients` commands compute and print.

use std::time::Instant;

use anyhow::Result;
use nalgebra::{Matrix2, Vector2};
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::{self, PipelineConfig, SpeedSource};
use oilfilm_identification::simulate::{self, SimulateOptions, SimulatedRecord};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::dimensionless;
use oilfilm_physics::film::Running;
use oilfilm_physics::operating_point::{self, EquilibriumOptions};
use oilfilm_physics::simulation::SimulatedRig;
use serde::Serialize;

pub const FRAME: &str = "x horizontal, y vertical up, journal turning from +x to +y; load on the journal along -y; \
coefficients in Lund's convention dF_on_journal = -(K dr + C dr'), rows = force, columns = motion";

/// A 2x2 matrix as rows, for JSON.
#[derive(Debug, Serialize)]
pub struct Rows(pub [[f64; 2]; 2]);

impl From<&Matrix2<f64>> for Rows {
    fn from(m: &Matrix2<f64>) -> Self {
        Rows([[m[(0, 0)], m[(0, 1)]], [m[(1, 0)], m[(1, 1)]]])
    }
}

#[derive(Debug, Serialize)]
pub struct OperatingPointReport {
    pub rig: String,
    pub frame: &'static str,
    pub film_model: String,
    pub speed_rpm: f64,
    pub bearing_load_n: f64,
    pub bearing_temperature_c: f64,
    pub viscosity_pa_s: f64,
    pub sommerfeld: f64,
    pub zhou_load_parameter: f64,
    pub eccentricity: f64,
    pub attitude_deg: f64,
    pub stiffness_n_m: Rows,
    pub damping_n_s_m: Rows,
    pub added_mass_kg: Option<Rows>,
    /// Squeeze-film Reynolds number rho omega c^2 / mu at the top of the exciter band: fluid
    /// inertia matters against damping roughly in proportion to it (Reinhardt & Lund 1975).
    pub squeeze_reynolds_at_band_top: f64,
    /// Lund: K c / W, B c omega / W, crate frame.
    pub lund_stiffness: Rows,
    pub lund_damping: Rows,
    /// Zhou: k psi^3 / (mu omega L), d psi^3 / (mu L), crate frame.
    pub zhou_stiffness: Rows,
    pub zhou_damping: Rows,
    pub solve_ms: f64,
}

pub fn operating_point(config: &RigConfig, running: &Running) -> Result<OperatingPointReport> {
    let mut film = config.film()?;
    let load = config.operating.bearing_load_n;
    let options = EquilibriumOptions { density_kg_m3: Some(config.oil.density_kg_m3(config.operating.bearing_temperature_c)), ..Default::default() };
    let started = Instant::now();
    let op = operating_point::solve(film.as_mut(), running, Vector2::new(0.0, -load), &options)?;
    let solve_ms = started.elapsed().as_secs_f64() * 1e3;
    let k = op.coefficients.stiffness_n_m;
    let c = op.coefficients.damping_n_s_m;
    let lund = dimensionless::lund(&k, &c, &config.bearing, running, load);
    let zhou = dimensionless::zhou(&k, &c, &config.bearing, running);
    Ok(OperatingPointReport {
        rig: config.name.clone(),
        frame: FRAME,
        film_model: format!("{:?}", config.film),
        speed_rpm: running.omega_rad_s * 30.0 / std::f64::consts::PI,
        bearing_load_n: load,
        bearing_temperature_c: config.operating.bearing_temperature_c,
        viscosity_pa_s: running.viscosity_pa_s,
        sommerfeld: op.sommerfeld,
        zhou_load_parameter: dimensionless::zhou_load_parameter(&config.bearing, running, load),
        eccentricity: op.eccentricity,
        attitude_deg: op.attitude_deg,
        stiffness_n_m: (&k).into(),
        damping_n_s_m: (&c).into(),
        added_mass_kg: op.coefficients.added_mass_kg.as_ref().map(Rows::from),
        squeeze_reynolds_at_band_top: config.oil.density_kg_m3(config.operating.bearing_temperature_c)
            * 2.0
            * std::f64::consts::PI
            * config.housing.exciter_band_hz[1]
            * config.bearing.clearance_m.powi(2)
            / running.viscosity_pa_s,
        lund_stiffness: (&lund.stiffness).into(),
        lund_damping: (&lund.damping).into(),
        zhou_stiffness: (&zhou.stiffness).into(),
        zhou_damping: (&zhou.damping).into(),
        solve_ms,
    })
}

fn print_matrix(name: &str, unit: &str, m: &Rows) {
    let [[a, b], [c, d]] = m.0;
    println!("  {name:<22} [{a:>11.4e} {b:>11.4e}; {c:>11.4e} {d:>11.4e}] {unit}");
}

pub fn print_operating_point(p: &OperatingPointReport) {
    println!("rig: {}", p.rig);
    println!("frame: {}", p.frame);
    println!("film model: {}", p.film_model);
    println!(
        "operating point: {:.0} rpm, W = {:.0} N, T = {:.2} C, mu = {:.5} Pa s -> S = {:.4}, F_Y = {:.4}",
        p.speed_rpm, p.bearing_load_n, p.bearing_temperature_c, p.viscosity_pa_s, p.sommerfeld, p.zhou_load_parameter
    );
    println!("equilibrium: eccentricity {:.4}, attitude {:.2} deg (solved in {:.2} ms)", p.eccentricity, p.attitude_deg, p.solve_ms);
    println!("coefficients ([xx xy; yx yy]):");
    print_matrix("stiffness K", "N/m", &p.stiffness_n_m);
    print_matrix("damping C", "N s/m", &p.damping_n_s_m);
    if let Some(m) = &p.added_mass_kg {
        print_matrix("added mass M (est.)", "kg", m);
        println!(
            "  squeeze Reynolds number at the top of the exciter band {:.3}: the added-mass force is ~{:.0} % of the damping force there",
            p.squeeze_reynolds_at_band_top,
            100.0 * p.squeeze_reynolds_at_band_top / 12.0
        );
    }
    print_matrix("Lund K c/W", "-", &p.lund_stiffness);
    print_matrix("Lund B c w/W", "-", &p.lund_damping);
    print_matrix("Zhou K psi^3/(mu w L)", "-", &p.zhou_stiffness);
    print_matrix("Zhou D psi^3/(mu L)", "-", &p.zhou_damping);
}

#[derive(Debug, Serialize)]
pub struct ChannelSummary {
    pub channel: &'static str,
    pub unit: &'static str,
    pub mean: f64,
    pub rms_about_mean: f64,
    pub min: f64,
    pub max: f64,
}

#[derive(Debug, Serialize)]
pub struct RecordReport {
    pub seconds: f64,
    pub scans: usize,
    pub excitation: String,
    /// d = max |r - r_mean| / c from the simulator's truth.
    pub amplitude_d: f64,
    pub channels: Vec<ChannelSummary>,
    /// Building the rig: equilibrium and, for a tabulated film, the force map.
    pub setup_s: f64,
    pub simulation_wall_s: f64,
    pub real_time_factor: f64,
}

/// Simulates `seconds` of a two-tone record (f1 at 23 Hz, f2 at 37 Hz) through the DAQ chain
/// and summarises every channel in SI; the record comes back for identification.
pub fn simulate_two_tone(config: &RigConfig, seconds: f64, amplitude_n: f64) -> Result<(RecordReport, SimulatedRecord)> {
    let (f_a, f_b) = (23.0, 37.0);
    let built = Instant::now();
    // Building the rig (equilibrium, force map) is timed apart from stepping it.
    SimulatedRig::new(config, 0.0)?;
    let setup_s = built.elapsed().as_secs_f64();
    let started = Instant::now();
    let rec = simulate::simulate(config, &ExcitationPlan::two_tone(f_a, f_b, amplitude_n), seconds, SimulateOptions { keep_states: true }, &mut |_| {})?;
    let wall = (started.elapsed().as_secs_f64() - setup_s).max(1e-9);
    let calibration = config.daq.calibration();
    let order = config.daq.scan_order();
    let n = rec.scans.len();
    let mut acc: Vec<(f64, f64, f64, f64)> = vec![(0.0, 0.0, f64::INFINITY, f64::NEG_INFINITY); order.len()];
    for scan in &rec.scans {
        for (k, (&ch, &v)) in order.iter().zip(&scan.volts).enumerate() {
            let x = calibration.to_si(ch, v)?;
            let a = &mut acc[k];
            a.0 += x;
            a.1 += x * x;
            a.2 = a.2.min(x);
            a.3 = a.3.max(x);
        }
    }
    let r0 = Vector2::new(rec.truth.journal.x_m, rec.truth.journal.y_m);
    let dmax = rec.states.as_deref().unwrap_or(&[]).iter().map(|s| (s.relative_m - r0).norm()).fold(0.0, f64::max);
    let channels = order
        .iter()
        .zip(acc)
        .map(|(&ch, (s, s2, lo, hi))| {
            let mean = s / n as f64;
            ChannelSummary { channel: ch.name(), unit: ch.unit(), mean, rms_about_mean: (s2 / n as f64 - mean * mean).max(0.0).sqrt(), min: lo, max: hi }
        })
        .collect();
    let report = RecordReport {
        seconds,
        scans: n,
        excitation: format!("two-tone: f1 {amplitude_n} N at {f_a} Hz, f2 {amplitude_n} N at {f_b} Hz"),
        amplitude_d: dmax / config.bearing.clearance_m,
        channels,
        setup_s,
        simulation_wall_s: wall,
        real_time_factor: seconds / wall,
    };
    Ok((report, rec))
}

pub fn print_record(r: &RecordReport) {
    println!();
    println!("simulated record: {} scans over {} s, {}", r.scans, r.seconds, r.excitation);
    println!("excitation amplitude d = max|r - r0|/c = {:.4}", r.amplitude_d);
    println!("{:<12} {:>5} {:>13} {:>13} {:>13} {:>13}", "channel", "unit", "mean", "rms", "min", "max");
    for c in &r.channels {
        println!("{:<12} {:>5} {:>13.5e} {:>13.5e} {:>13.5e} {:>13.5e}", c.channel, c.unit, c.mean, c.rms_about_mean, c.min, c.max);
    }
    println!("simulated {:.2} s in {:.3} s wall: {:.1}x real time (rig set-up {:.3} s)", r.seconds, r.simulation_wall_s, r.real_time_factor, r.setup_s);
}

/// The simulated record identified by the pipeline, against the film model's coefficients.
#[derive(Debug, Serialize)]
pub struct IdentifiedReport {
    pub windows: usize,
    pub refusal: Option<String>,
    pub lowpass_cutoff_hz: f64,
    pub identified_stiffness_n_m: Option<Rows>,
    pub identified_damping_n_s_m: Option<Rows>,
    pub stiffness_se: Option<Rows>,
    pub damping_se: Option<Rows>,
    pub model_stiffness_n_m: Rows,
    pub model_damping_n_s_m: Rows,
    pub flags: Vec<String>,
    pub identify_ms: f64,
}

pub fn identify_record(config: &RigConfig, rec: &SimulatedRecord) -> Result<IdentifiedReport> {
    let started = Instant::now();
    let raw = rec.raw()?;
    let cal = pipeline::calibration_for(config, &raw, &pipeline::rig_offsets(config, &raw)?)?;
    let id = pipeline::identify(&raw, &cal, config, rec.speed_rpm, SpeedSource::Record, &PipelineConfig::default())?;
    let identify_ms = started.elapsed().as_secs_f64() * 1e3;
    let first = id.windows.first().and_then(|w| w.estimate.result.as_ref().ok());
    let refusal = id.refusal.clone().or_else(|| id.windows.first().and_then(|w| w.estimate.result.as_ref().err().map(|r| r.to_string())));
    Ok(IdentifiedReport {
        windows: id.windows.len(),
        refusal,
        lowpass_cutoff_hz: id.lowpass_cutoff_hz,
        identified_stiffness_n_m: first.map(|c| (&c.stiffness_n_m).into()),
        identified_damping_n_s_m: first.map(|c| (&c.damping_n_s_m).into()),
        stiffness_se: first.map(|c| (&c.stiffness_se).into()),
        damping_se: first.map(|c| (&c.damping_se).into()),
        model_stiffness_n_m: (&rec.truth.coefficients.stiffness_n_m).into(),
        model_damping_n_s_m: (&rec.truth.coefficients.damping_n_s_m).into(),
        flags: id.windows.iter().flat_map(|w| w.estimate.flags.clone()).collect(),
        identify_ms,
    })
}

pub fn print_identified(r: &IdentifiedReport) {
    println!();
    println!(
        "identified from the record ({} window(s), low-pass {:.1} Hz, {:.1} ms) against the simulated film's own coefficients:",
        r.windows, r.lowpass_cutoff_hz, r.identify_ms
    );
    if let Some(reason) = &r.refusal {
        println!("  REFUSED: {reason}");
        return;
    }
    let (Some(k), Some(c), Some(sk), Some(sc)) = (&r.identified_stiffness_n_m, &r.identified_damping_n_s_m, &r.stiffness_se, &r.damping_se) else {
        return;
    };
    println!(
        "  {:<4} {:>13} {:>11} {:>13} {:>8} | {:>13} {:>11} {:>13} {:>8}",
        "", "K identified", "SE", "K film", "diff", "C identified", "SE", "C film", "diff"
    );
    for (n, (i, j)) in ["xx", "xy", "yx", "yy"].iter().zip([(0, 0), (0, 1), (1, 0), (1, 1)]) {
        let (ki, kf) = (k.0[i][j], r.model_stiffness_n_m.0[i][j]);
        let (ci, cf) = (c.0[i][j], r.model_damping_n_s_m.0[i][j]);
        println!(
            "  {n:<4} {ki:>13.5e} {:>11.3e} {kf:>13.5e} {:>+7.2}% | {ci:>13.5e} {:>11.3e} {cf:>13.5e} {:>+7.2}%",
            sk.0[i][j],
            100.0 * (ki - kf) / kf.abs(),
            sc.0[i][j],
            100.0 * (ci - cf) / cf.abs()
        );
    }
    for f in &r.flags {
        println!("  note: {f}");
    }
}
