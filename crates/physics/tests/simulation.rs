//! The rig and its DAQ chain together: a record is reproducible, and each DAQ-side effect
//! shows in the recorded channels the way its physics says (and only there).

use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::ChannelId;
use oilfilm_physics::effects::{ChannelDelay, ProbeSaturation, SynchronousRunout};
use oilfilm_physics::film::FilmModelConfig;
use oilfilm_physics::rig::RigInput;
use oilfilm_physics::simulation::{SimulatedRig, SimulatedScan};

fn config() -> RigConfig {
    let mut c = RigConfig::zhou2004().unwrap();
    c.film = FilmModelConfig::Short;
    c
}

fn two_tone(t: f64) -> RigInput {
    let w = 2.0 * std::f64::consts::PI;
    let ramp = (t / 0.05).min(1.0);
    RigInput { exciter_n: [150.0 * ramp * (w * 23.0 * t).sin(), 150.0 * ramp * (w * 37.0 * t).sin()] }
}

fn record(config: &RigConfig, seconds: f64) -> Vec<SimulatedScan> {
    let mut sim = SimulatedRig::new(config, 0.0).unwrap();
    let period = sim.period_s();
    let n = (seconds / period).round() as usize;
    (1..=n).map(|i| sim.step(&two_tone(i as f64 * period), i as f64 * period).unwrap()).collect()
}

/// Channel `ch` of every scan, in SI through the calibration.
fn channel(config: &RigConfig, scans: &[SimulatedScan], ch: ChannelId) -> Vec<f64> {
    let cal = config.daq.calibration();
    scans.iter().map(|s| cal.to_si(ch, s.scan.volts_of(ch).unwrap()).unwrap()).collect()
}

/// Amplitude and phase of `f` in `y` sampled at `t` (least squares on cos, sin, mean).
fn tone(t: &[f64], y: &[f64], f: f64) -> (f64, f64) {
    let w = 2.0 * std::f64::consts::PI * f;
    let mut a = nalgebra::DMatrix::<f64>::zeros(t.len(), 3);
    let b = nalgebra::DVector::<f64>::from_column_slice(y);
    for (i, &ti) in t.iter().enumerate() {
        a[(i, 0)] = (w * ti).cos();
        a[(i, 1)] = (w * ti).sin();
        a[(i, 2)] = 1.0;
    }
    let x = a.svd(true, true).solve(&b, 1e-14).unwrap();
    // y ~ c cos + s sin = A cos(wt - phi)
    (x[0].hypot(x[1]), x[1].atan2(x[0]))
}

#[test]
fn a_record_is_reproducible_bit_for_bit_and_seeds_matter() {
    let c = config();
    let a = record(&c, 0.2);
    let b = record(&c, 0.2);
    assert!(a.iter().zip(&b).all(|(x, y)| x.scan.counts == y.scan.counts && x.truth == y.truth));
    let mut c2 = c.clone();
    c2.simulation.seed += 1;
    let d = record(&c2, 0.2);
    let differing = a.iter().zip(&d).filter(|(x, y)| x.scan.counts != y.scan.counts).count();
    println!("{differing} of {} scans differ with another seed; truth identical: {}", a.len(), a.iter().zip(&d).all(|(x, y)| x.truth == y.truth));
    assert!(differing > a.len() / 2);
    assert!(a.iter().zip(&d).all(|(x, y)| x.truth == y.truth), "the seed drives only the sensor noise");
}

#[test]
fn recorded_probes_follow_the_true_motion_within_noise_and_quantisation() {
    let c = config();
    let scans = record(&c, 0.3);
    let x = channel(&c, &scans, ChannelId::ProbeAX);
    // The scan of period [t_{n-1}, t_n] samples probe_a_x at its start (channel 0): compare
    // with the previous scan's truth (the state at that start).
    let err: Vec<f64> = scans.windows(2).zip(x.iter().skip(1)).map(|(w, xi)| xi - w[0].truth.relative_m.x).collect();
    let rms = (err.iter().map(|e| e * e).sum::<f64>() / err.len() as f64).sqrt();
    println!("probe_a_x rms error against truth {rms:.3e} m (noise 1e-7 m, LSB 7.6e-9 m)");
    assert!(rms < 1.2e-7 && rms > 0.8e-7, "recorded error {rms:e} should be the 0.1 um sensor noise");
}

#[test]
fn synchronous_runout_appears_at_1x_in_the_bearing_probes_with_no_force_cause() {
    let mut c = config();
    let base = record(&c, 1.0);
    let amplitude = 5.0e-6;
    c.effects.synchronous_runout = Some(SynchronousRunout { amplitude_m: amplitude, phase_deg: 0.0 });
    let with = record(&c, 1.0);
    let one_x = c.operating.speed_rpm / 60.0; // 25 Hz
    let t: Vec<f64> = with.iter().map(|s| s.scan.scan_start_s).collect();
    for ch in [ChannelId::ProbeAX, ChannelId::ProbeAY, ChannelId::ProbeBX, ChannelId::ProbeBY] {
        let (a_with, _) = tone(&t, &channel(&c, &with, ch), one_x);
        let (a_base, _) = tone(&t, &channel(&c, &base, ch), one_x);
        println!("{:<10} 1X amplitude with runout {a_with:.3e} m, without {a_base:.3e} m", ch.name());
        assert!((a_with - amplitude).abs() < 0.02 * amplitude);
        assert!(a_base < 0.01 * amplitude);
    }
    // No force cause: the true motion, the frame probes and the film force are untouched.
    assert!(base.iter().zip(&with).all(|(a, b)| a.truth == b.truth));
    for ch in [ChannelId::FrameX, ChannelId::FrameY, ChannelId::F1, ChannelId::F2] {
        assert_eq!(channel(&c, &base, ch), channel(&c, &with, ch), "{} must not see probe runout", ch.name());
    }
}

#[test]
fn a_channel_delay_shifts_that_channels_phase_against_the_others_by_omega_tau() {
    // delay_s > 0: f1 is sampled later than its slot, so it leads the other channels; < 0: it
    // lags them. Either way its phase against a channel at its own schedule moves by w tau.
    let mut c = config();
    let base = record(&c, 1.0);
    let t: Vec<f64> = base.iter().map(|s| s.scan.scan_start_s).collect();
    let relative = |c: &RigConfig, rec: &[SimulatedScan]| {
        let (_, p1) = tone(&t, &channel(c, rec, ChannelId::F1), 23.0);
        let (_, pr) = tone(&t, &channel(c, rec, ChannelId::ProbeAX), 23.0);
        p1 - pr
    };
    let before = relative(&c, &base);
    for tau in [3.0e-4, -3.0e-4] {
        c.effects.channel_delay = Some(ChannelDelay { channel: "f1".into(), delay_s: tau });
        let with = record(&c, 1.0);
        // y ~ A cos(w t - phi): a reading that leads by tau has phi smaller by w tau.
        let shift = relative(&c, &with) - before;
        let expected = -2.0 * std::f64::consts::PI * 23.0 * tau;
        println!("tau {:+.0} us: f1 phase against probe_a_x moved {shift:+.6} rad, expected {expected:+.6} rad", tau * 1e6);
        assert!((shift - expected).abs() < 0.01 * expected.abs());
        if tau < 0.0 {
            assert_eq!(channel(&c, &base, ChannelId::F2), channel(&c, &with, ChannelId::F2), "a lag moves the delayed channel alone");
        }
    }
}

#[test]
fn probe_saturation_clips_one_probe_at_its_limit() {
    // At the default point the journal sits ~30 um along +x (attitude ~70 deg from the load).
    let mut c = config();
    let limit = 2.0e-5;
    c.effects.probe_saturation = Some(ProbeSaturation { channel: "probe_a_x".into(), limit_m: limit });
    let scans = record(&c, 0.3);
    let a = channel(&c, &scans, ChannelId::ProbeAX);
    let b = channel(&c, &scans, ChannelId::ProbeBX);
    let (a_max, b_max) = (a.iter().cloned().fold(f64::NEG_INFINITY, f64::max), b.iter().cloned().fold(f64::NEG_INFINITY, f64::max));
    let clipped = a.iter().filter(|v| (*v - limit).abs() < 1e-8).count();
    println!("probe_a_x max {a_max:.4e} m (limit {limit:e}, {clipped} of {} samples clipped), probe_b_x max {b_max:.4e} m", a.len());
    assert!((a_max - limit).abs() < 1e-8, "the saturated probe sits at its limit");
    assert!(clipped > a.len() / 2, "the probe spends the record clipped");
    assert!(b_max > limit + 5e-6, "the healthy probe sees the journal beyond the limit");
}
