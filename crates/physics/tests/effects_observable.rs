//! What the diagnosis will see: an injected film effect must be observable in the DAQ record
//! itself (noise, 16-bit codes, multiplexed sampling), not only in the simulator's truth, at
//! the scale docs/manual/physics.md recommends, and with the evidence that tells it from its nearest
//! catalog neighbour.
//!
//! `film_relaxation` (outside the catalog) and `fluid_inertia` (in it) both make the complex
//! stiffness depend on frequency; the record separates them by the sign of the change:
//! relaxation stiffens the film as the frequency rises, added mass softens it (`-M_a w^2`).
//!
//! The film force comes from the recorded channels through eq. 2 of Zhou et al. (2004) at one
//! frequency: `F = F_exc + m w^2 X` (the bellows and weight are constant), with `X` from the
//! frame probes and `r` from the mean of the two bearing probes; every channel's phasor is
//! taken at its own multiplexed sampling instant.

use nalgebra::{Complex, Matrix2, Vector2};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::ChannelId;
use oilfilm_physics::effects::{FilmRelaxation, FluidInertia};
use oilfilm_physics::rig::RigInput;
use oilfilm_physics::simulation::SimulatedRig;

type C64 = Complex<f64>;
type CMatrix2 = Matrix2<C64>;

const TWO_PI: f64 = 2.0 * std::f64::consts::PI;
/// Sine amplitude per exciter, N: a few um of motion, d ~ 0.03, far above the 0.1 um noise.
const AMPLITUDE_N: f64 = 400.0;

fn zhou() -> RigConfig {
    let mut c = RigConfig::zhou2004().expect("built-in rig parses");
    // No bellows ripple: its 3 Hz line is no part of these single-frequency measurements.
    c.static_load.ripple_fraction = 0.0;
    c
}

/// Phasors at `f` of the recorded relative motion, housing motion and exciter force (vectors
/// in x, y) for exciter `k` alone, over 2 s after 0.3 s of settling.
fn record_phasors(config: &RigConfig, k: usize, f: f64) -> [[C64; 2]; 3] {
    let mut sim = SimulatedRig::new(config, 0.0).expect("rig builds");
    let period = sim.period_s();
    let interval = config.daq.channel_interval_s;
    let cal = config.daq.calibration();
    let (n_settle, n_record) = ((0.3 / period).round() as usize, (2.0 / period).round() as usize);
    let w = TWO_PI * f;
    // Projections on cos and sin per channel, each at its own sampling instant.
    let mut proj = [[0.0_f64; 2]; 10];
    let mut sums = [0.0_f64; 10];
    // (channel, sampling instant, SI value) of every reading kept.
    let mut readings: Vec<(ChannelId, f64, f64)> = Vec::with_capacity(10 * n_record);
    for i in 1..=n_settle + n_record {
        let t = i as f64 * period;
        let mut input = RigInput::default();
        input.exciter_n[k] = AMPLITUDE_N * (t / 0.1).min(1.0) * (w * t).sin();
        let s = sim.step(&input, t).expect("rig steps");
        if i > n_settle {
            for (slot, (&ch, &v)) in s.scan.channels.iter().zip(&s.scan.volts).enumerate() {
                readings.push((ch, s.scan.scan_start_s + slot as f64 * interval, cal.to_si(ch, v).expect("calibrated channel")));
            }
        }
    }
    for &(ch, _, v) in &readings {
        sums[ch.index()] += v;
    }
    let n = n_record as f64;
    for &(ch, t, v) in &readings {
        let (s, c) = (w * t).sin_cos();
        let y = v - sums[ch.index()] / n;
        proj[ch.index()][0] += y * c;
        proj[ch.index()][1] += y * s;
    }
    // a cos + b sin = Re((a - i b) e^{i w t})
    let p = |ch: ChannelId| C64::new(2.0 * proj[ch.index()][0] / n, -2.0 * proj[ch.index()][1] / n);
    let d = |deg: f64| Vector2::new(deg.to_radians().cos(), deg.to_radians().sin());
    let dirs = [d(config.housing.exciter_angles_deg[0]), d(config.housing.exciter_angles_deg[1])];
    let (f1, f2) = (p(ChannelId::F1), p(ChannelId::F2));
    let exciter = [f1 * dirs[0].x + f2 * dirs[1].x, f1 * dirs[0].y + f2 * dirs[1].y];
    let r = [(p(ChannelId::ProbeAX) + p(ChannelId::ProbeBX)) * 0.5, (p(ChannelId::ProbeAY) + p(ChannelId::ProbeBY)) * 0.5];
    let housing = [p(ChannelId::FrameX), p(ChannelId::FrameY)];
    [r, housing, exciter]
}

/// The complex stiffness `H` (`dF_on_journal = -H r`) at `f` seen in two records, one per
/// exciter, through eq. 2 with the configured housing mass.
fn recorded_stiffness(config: &RigConfig, f: f64) -> CMatrix2 {
    let w = TWO_PI * f;
    let m = config.housing.mass_kg;
    let runs = [record_phasors(config, 0, f), record_phasors(config, 1, f)];
    let col = |run: &[[C64; 2]; 3], i: usize| -> (C64, C64) {
        let [r, x, e] = run;
        // Film force on the journal = exciter + m w^2 X (eq. 2 at one frequency).
        (r[i], e[i] + x[i] * (w * w * m))
    };
    let (r00, f00) = col(&runs[0], 0);
    let (r10, f10) = col(&runs[0], 1);
    let (r01, f01) = col(&runs[1], 0);
    let (r11, f11) = col(&runs[1], 1);
    let r = CMatrix2::new(r00, r01, r10, r11);
    let force = CMatrix2::new(f00, f01, f10, f11);
    -force * r.try_inverse().expect("independent motions from the two exciters")
}

#[test]
fn relaxation_stiffens_and_added_mass_softens_the_recorded_film_across_the_band() {
    let (f_lo, f_hi) = (10.0, 70.0);
    let relax = FilmRelaxation { stiffness_n_m: 1.5e7, time_constant_s: 1.0 / (TWO_PI * 30.0) };
    let added_mass_kg = 45.0;
    let null = zhou();
    let mut relaxed = zhou();
    relaxed.effects.film_relaxation = Some(relax);
    let mut inertial = zhou();
    inertial.effects.fluid_inertia = Some(FluidInertia { added_mass_kg });

    let k_film = oilfilm_physics::rig::Rig::new(&null, 0.0, 0.0).unwrap().operating_point().coefficients.stiffness_n_m[(0, 0)];
    // Change of Re Hxx from f_lo to f_hi, per record kind.
    let change = |c: &RigConfig| -> f64 {
        let (lo, hi) = (recorded_stiffness(c, f_lo), recorded_stiffness(c, f_hi));
        println!(
            "  Re Hxx {:.4e} -> {:.4e} N/m, Im Hxx / w {:.4e} -> {:.4e} N s/m",
            lo[(0, 0)].re,
            hi[(0, 0)].re,
            lo[(0, 0)].im / (TWO_PI * f_lo),
            hi[(0, 0)].im / (TWO_PI * f_hi)
        );
        hi[(0, 0)].re - lo[(0, 0)].re
    };
    println!("no effect:");
    let d_null = change(&null);
    println!("film_relaxation k_r {:.2e} N/m, tau {:.3e} s:", relax.stiffness_n_m, relax.time_constant_s);
    let d_relax = change(&relaxed);
    println!("fluid_inertia {added_mass_kg} kg:");
    let d_mass = change(&inertial);

    // What the models say the effect adds to Re Hxx between the two frequencies.
    let re_element = |f: f64| {
        let wt = TWO_PI * f * relax.time_constant_s;
        relax.stiffness_n_m * wt * wt / (1.0 + wt * wt)
    };
    let expect_relax = re_element(f_hi) - re_element(f_lo);
    let expect_mass = -added_mass_kg * TWO_PI * TWO_PI * (f_hi * f_hi - f_lo * f_lo);
    let (rel_relax, rel_mass) = ((d_relax - d_null) / k_film, (d_mass - d_null) / k_film);
    println!(
        "Re Hxx change {f_lo}->{f_hi} Hz in % of Kxx {k_film:.4e}: none {:+.2}, film_relaxation {:+.2} (model {:+.2}), fluid_inertia {:+.2} (model {:+.2})",
        100.0 * d_null / k_film,
        100.0 * (d_relax / k_film),
        100.0 * (d_null + expect_relax) / k_film,
        100.0 * d_mass / k_film,
        100.0 * (d_null + expect_mass) / k_film
    );
    // Without an effect the recorded stiffness barely depends on frequency.
    assert!(d_null.abs() < 0.02 * k_film, "the null record's stiffness moved {:.2}% of Kxx", 100.0 * d_null / k_film);
    // Each effect's change, net of the null record's, is what its model says, within 1% of K.
    assert!(
        (d_relax - d_null - expect_relax).abs() < 0.01 * k_film,
        "relaxation: {:.2}% of K against a model {:.2}%",
        100.0 * rel_relax,
        100.0 * expect_relax / k_film
    );
    assert!(
        (d_mass - d_null - expect_mass).abs() < 0.01 * k_film,
        "added mass: {:.2}% of K against a model {:.2}%",
        100.0 * rel_mass,
        100.0 * expect_mass / k_film
    );
    // The separating evidence: opposite signs, each well beyond the null record's change.
    assert!(rel_relax > 0.08 && rel_mass < -0.08, "relaxation must stiffen ({rel_relax:+.3}) and added mass soften ({rel_mass:+.3}) the film across the band");
}
