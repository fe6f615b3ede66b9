mod common;
use common::*;
use oilfilm_physics::effects::*;

#[test]
#[ignore]
fn explore() {
    let which = std::env::var("EFFECT").unwrap_or_default();
    let size: f64 = std::env::var("SIZE").ok().and_then(|s| s.parse().ok()).unwrap_or(0.0);
    let chan = std::env::var("CHAN").unwrap_or("probe_a_x".into());
    let rms: f64 = std::env::var("RMS").ok().and_then(|s| s.parse().ok()).unwrap_or(100.0);
    let mut r = rng(7);
    let (mut rig, speed, load) = base_case(&mut r, 11);
    let e = &mut rig.effects;
    match which.as_str() {
        "fluid_inertia" => e.fluid_inertia = Some(FluidInertia { added_mass_kg: size }),
        "thermal_drift" => e.thermal_drift = Some(ThermalDrift { heating_rate_c_per_s: size }),
        "synchronous_runout" => e.synchronous_runout = Some(SynchronousRunout { amplitude_m: size, phase_deg: 30.0 }),
        "channel_delay" => e.channel_delay = Some(ChannelDelay { channel: chan.clone(), delay_s: size }),
        "probe_saturation" => e.probe_saturation = Some(ProbeSaturation { channel: chan.clone(), limit_m: size }),
        "film_relaxation" => e.film_relaxation = Some(FilmRelaxation { stiffness_n_m: size, time_constant_s: 5.3e-3 }),
        "support_friction" => e.support_friction = Some(SupportFriction { friction_force_n: size }),
        _ => {}
    }
    let case = Case { rig, truth: Truth { effect: "x", parameter: None, channel: None, speed_rpm: speed, load_n: load }, seconds: 10.0, plan: multisine(rms) };
    let t0 = std::time::Instant::now();
    let d = run(&case);
    eprintln!("{:.2} s, speed {speed} load {load}", t0.elapsed().as_secs_f64());
    eprintln!("cause {} | {}", d.cause, d.reason);
    eprintln!("baseline {:?} structure {:?} evidence {:?}", d.baseline_heldout_nrmse, d.baseline_structure, d.evidence);
    for c in &d.candidates {
        eprintln!("  {:<24} score {:>8.4} nrmse {:>7.4} p {:>9.2e} dbic {:>9.1} folds {}/{} earns {} params {:?} se {:?} struct {:?} note {:?}",
            c.name.name(), c.score.unwrap_or(f64::NAN), c.heldout_nrmse.unwrap_or(f64::NAN), c.p_value.unwrap_or(f64::NAN), c.delta_bic.unwrap_or(f64::NAN), c.folds_improved, c.folds, c.earns, c.parameters, c.standard_errors, c.explained_fraction, c.note);
    }
    for a in &d.aliases { eprintln!("alias {:?}", a); }
}
