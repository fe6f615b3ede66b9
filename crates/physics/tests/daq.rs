//! Tests of the DAQ chain (Zhou et al. 2004, section 2.3): schedule, quantisation, noise,
//! calibration, the three DAQ effects, and configuration errors. Each test prints what it
//! measured (`cargo test -p oilfilm-physics --test daq -- --nocapture`).

use std::f64::consts::PI;

use nalgebra::{Matrix3, Vector3};
use oilfilm_physics::daq::{ChannelId, Daq, DaqConfig, DaqScan, PhysicalSignals};
use oilfilm_physics::effects::{ChannelDelay, Effects, ProbeSaturation, SynchronousRunout};
use oilfilm_physics::PhysicsError;

// ---------------------------------------------------------------------------------------
// helpers

/// The default configuration with every noise level set to zero.
fn quiet() -> DaqConfig {
    let mut cfg = DaqConfig::zhou2004();
    for c in &mut cfg.channels {
        c.noise_rms = 0.0;
    }
    cfg
}

fn no_effects() -> Effects {
    Effects::default()
}

/// A mid-range constant true value for every channel.
fn mid_values() -> [f64; 10] {
    let mut v = [0.0; 10];
    v[ChannelId::ProbeAX.index()] = 5.0e-6;
    v[ChannelId::ProbeAY.index()] = -60.0e-6;
    v[ChannelId::ProbeBX.index()] = 4.0e-6;
    v[ChannelId::ProbeBY.index()] = -58.0e-6;
    v[ChannelId::FrameX.index()] = -3.0e-6;
    v[ChannelId::FrameY.index()] = 40.0e-6;
    v[ChannelId::F1.index()] = 120.0;
    v[ChannelId::F2.index()] = -80.0;
    v[ChannelId::F3.index()] = 10_000.0;
    v[ChannelId::Temperature.index()] = 40.0;
    v
}

/// The field an `InvalidConfig` error names (panics with the error otherwise: a test failure).
fn field(err: PhysicsError) -> String {
    match err {
        PhysicsError::InvalidConfig { field, .. } => field,
        other => panic!("expected InvalidConfig, got {other:?}"),
    }
}

/// Least squares `y = c + a cos(w t) + b sin(w t)`; returns (c, a, b).
fn fit_1x(t: &[f64], y: &[f64], w: f64) -> (f64, f64, f64) {
    let mut ata = Matrix3::<f64>::zeros();
    let mut aty = Vector3::<f64>::zeros();
    for (&ti, &yi) in t.iter().zip(y) {
        let row = Vector3::new(1.0, (w * ti).cos(), (w * ti).sin());
        ata += row * row.transpose();
        aty += row * yi;
    }
    let sol = ata.try_inverse().expect("fit matrix invertible") * aty;
    (sol[0], sol[1], sol[2])
}

/// Runs `n` scans at the nominal scan starts and returns them.
fn run(daq: &mut Daq, cfg: &DaqConfig, n: u64, signals: &mut dyn FnMut(f64) -> PhysicalSignals) -> Vec<DaqScan> {
    (0..n).map(|i| daq.scan(i, i as f64 / cfg.sample_rate_hz, signals)).collect()
}

/// Decoded SI series of one channel, with its nominal sample times.
fn series(daq: &Daq, scans: &[DaqScan], ch: ChannelId) -> (Vec<f64>, Vec<f64>) {
    let cal = daq.calibration();
    let off = cal.sample_offset_s(ch).unwrap();
    let t = scans.iter().map(|s| s.scan_start_s + off).collect();
    let y = scans.iter().map(|s| cal.to_si(ch, s.volts_of(ch).unwrap()).unwrap()).collect();
    (t, y)
}

// ---------------------------------------------------------------------------------------
// names, defaults

#[test]
fn channel_names_units_and_serde_names_agree() {
    let names: Vec<&str> = ChannelId::ALL.iter().map(|c| c.name()).collect();
    println!("channels: {names:?}");
    assert_eq!(names, ["probe_a_x", "probe_a_y", "probe_b_x", "probe_b_y", "frame_x", "frame_y", "f1", "f2", "f3", "temperature"]);
    for (i, &c) in ChannelId::ALL.iter().enumerate() {
        assert_eq!(c.index(), i);
        assert_eq!(ChannelId::parse(c.name()).unwrap(), c);
        assert_eq!(serde_json::to_string(&c).unwrap(), format!("\"{}\"", c.name()));
        let expected_unit = if c.is_displacement_probe() {
            "m"
        } else if c == ChannelId::Temperature {
            "degC"
        } else {
            "N"
        };
        assert_eq!(c.unit(), expected_unit, "{c}");
    }
    assert_eq!(ChannelId::ALL.iter().filter(|c| c.is_bearing_probe()).count(), 4);
    assert!(!ChannelId::FrameX.is_bearing_probe() && ChannelId::FrameX.is_displacement_probe());
    assert_eq!(ChannelId::parse("probe_c_x"), Err(PhysicsError::UnknownChannel("probe_c_x".into())));
    assert!(ChannelId::parse("F1").is_err(), "names are case-sensitive snake_case");
}

#[test]
fn zhou2004_defaults_validate_and_match_the_fixture_file() {
    let cfg = DaqConfig::zhou2004();
    cfg.validate("daq").unwrap();
    assert_eq!(cfg.scan_order(), ChannelId::ALL.to_vec());
    let from_file: DaqConfig = toml::from_str(include_str!("data/daq/zhou2004.toml")).unwrap();
    assert_eq!(from_file, cfg, "fixture and documented defaults drifted apart");
    let cal = cfg.calibration();
    println!("LSB = {:.3} uV, scan span = {} us of {} us", cal.lsb_v() * 1e6, 9.0 * cfg.channel_interval_s * 1e6, 1e6 / cfg.sample_rate_hz);
    for c in cal.channels() {
        let res = cal.resolution_si(c.channel).unwrap();
        println!(
            "{:12} {:>10.4e} V/{:4} offset {:5.2} V  linear [{:6.2}, {:6.2}] V  1 LSB = {:.3e} {}",
            c.channel.name(),
            c.sensitivity_v_per_unit,
            c.channel.unit(),
            c.offset_v,
            c.linear_range_v[0],
            c.linear_range_v[1],
            res,
            c.channel.unit()
        );
        // Every default linear range lies inside the ADC span, so leaving it is visible.
        assert!(c.linear_range_v[0] > -cfg.full_scale_v && c.linear_range_v[1] < cfg.full_scale_v, "{}", c.channel);
    }
    // The clearance (0.114 mm) fits the probes' linear range.
    let probe = cfg.channels.iter().find(|c| c.channel == ChannelId::ProbeAY).unwrap();
    assert!(probe.linear_range[0] < -0.114e-3 && probe.linear_range[1] > 0.114e-3);
    // Exciter force 1.5 kN and static load 20 kN (section 2.4) fit their sensors.
    let f1 = cfg.channels.iter().find(|c| c.channel == ChannelId::F1).unwrap();
    assert!(f1.linear_range[1] > 1500.0 && f1.linear_range[0] < -1500.0);
    let f3 = cfg.channels.iter().find(|c| c.channel == ChannelId::F3).unwrap();
    assert!(f3.linear_range[1] > 20_000.0 && f3.linear_range[0] < 0.0);
}

// ---------------------------------------------------------------------------------------
// schedule

#[test]
fn channel_k_is_sampled_k_intervals_after_the_scan_start() {
    // A scrambled scan order proves the schedule follows the scan order, not ChannelId order.
    let mut cfg = quiet();
    let order = [9usize, 6, 0, 4, 8, 1, 7, 2, 5, 3];
    cfg.channels = order.iter().map(|&i| cfg.channels[i].clone()).collect();
    cfg.validate("daq").unwrap();
    let mut daq = Daq::new(&cfg, &no_effects(), 7).unwrap();
    assert_eq!(daq.max_lookback_s(), 0.0);

    // Each channel ramps in time from `base` at a known rate; the decoded value gives the time.
    let base_rate = |c: ChannelId| -> (f64, f64) {
        match c {
            c if c.is_displacement_probe() => (-90.0e-6, 1.0), // m, m/s
            ChannelId::F1 | ChannelId::F2 => (-1000.0, 1.0e7), // N, N/s
            ChannelId::F3 => (5000.0, 1.0e8),
            _ => (20.0, 5.0e5), // degC, degC/s
        }
    };
    let interval = cfg.channel_interval_s;
    let mut worst: f64 = 0.0;
    for i in 0..6u64 {
        let start = 1.234 + i as f64 / cfg.sample_rate_hz;
        let mut asked = Vec::new();
        let scan = daq.scan(i, start, &mut |t| {
            asked.push(t);
            let mut s = PhysicalSignals::zero();
            for c in ChannelId::ALL {
                let (b, r) = base_rate(c);
                s.set(c, b + r * (t - start));
            }
            s
        });
        assert_eq!(scan.channels, cfg.scan_order());
        assert!(asked.iter().all(|&t| t >= start && t <= start + daq.max_lookahead_s() + 1e-12));
        for (k, &c) in scan.channels.iter().enumerate() {
            let (b, r) = base_rate(c);
            let si = daq.calibration().to_si(c, scan.volts[k]).unwrap();
            let t_decoded = (si - b) / r;
            let t_expected = k as f64 * interval;
            assert_eq!(cfg.sample_offset_s(c).unwrap(), t_expected);
            assert_eq!(daq.calibration().sample_offset_s(c).unwrap(), t_expected);
            if i == 0 {
                println!("slot {k} {:12} decoded at {:8.4} us (schedule {:5.1} us)", c.name(), t_decoded * 1e6, t_expected * 1e6);
            }
            worst = worst.max((t_decoded - t_expected).abs());
        }
    }
    println!("worst schedule error {:.4} us (interval {} us)", worst * 1e6, interval * 1e6);
    assert!(worst < 0.01 * interval, "schedule error {worst} s");
}

// ---------------------------------------------------------------------------------------
// quantisation

#[test]
fn lsb_is_two_full_scale_over_two_to_the_bits() {
    for bits in [8u32, 12, 16, 24] {
        let mut cfg = quiet();
        cfg.adc_bits = bits;
        let daq = Daq::new(&cfg, &no_effects(), 0).unwrap();
        let expected = 2.0 * cfg.full_scale_v / 2f64.powi(bits as i32);
        println!("{bits:2} bits: LSB = {:.6e} V", daq.lsb_v());
        assert_eq!(daq.lsb_v(), expected);
        assert_eq!(daq.calibration().lsb_v(), expected);
    }
}

#[test]
fn slow_ramp_decodes_within_half_an_lsb() {
    let cfg = quiet();
    let mut daq = Daq::new(&cfg, &no_effects(), 0).unwrap();
    let lsb = daq.lsb_v();
    let n = 100_000u64;
    // Every channel ramps across 2 %..98 % of its linear range: steps of well under 1 LSB.
    let ramp = |c: ChannelId, frac: f64| {
        let lr = cfg.channels.iter().find(|x| x.channel == c).unwrap().linear_range;
        let (lo, hi) = (lr[0] + 0.02 * (lr[1] - lr[0]), lr[1] - 0.02 * (lr[1] - lr[0]));
        lo + frac * (hi - lo)
    };
    let total_s = n as f64 / cfg.sample_rate_hz;
    let mut worst = [0.0f64; 10];
    let mut codes_seen = std::collections::BTreeSet::new();
    for i in 0..n {
        let start = i as f64 / cfg.sample_rate_hz;
        let scan = daq.scan(i, start, &mut |t| {
            let mut s = PhysicalSignals::zero();
            for c in ChannelId::ALL {
                s.set(c, ramp(c, t / total_s));
            }
            s
        });
        for (k, c) in scan.channels.iter().enumerate() {
            let cc = &cfg.channels[k];
            let t = start + k as f64 * cfg.channel_interval_s;
            let ideal_v = cc.offset_v + cc.sensitivity_v_per_unit * ramp(*c, t / total_s);
            assert_eq!(scan.volts[k], scan.counts[k] as f64 * lsb);
            worst[k] = worst[k].max((scan.volts[k] - ideal_v).abs());
            if *c == ChannelId::F1 {
                codes_seen.insert(scan.counts[k]);
            }
        }
    }
    for (k, c) in cfg.scan_order().iter().enumerate() {
        println!("{:12} worst |volts - ideal| = {:.4} LSB", c.name(), worst[k] / lsb);
        assert!(worst[k] <= 0.5 * lsb * (1.0 + 1e-9), "{c}: {} LSB", worst[k] / lsb);
        // It is a quantiser, not a pass-through: the error reaches nearly half an LSB.
        assert!(worst[k] > 0.45 * lsb, "{c}: {} LSB", worst[k] / lsb);
    }
    // A slow ramp visits every code between its ends (no missing codes).
    let (lo, hi) = (*codes_seen.first().unwrap(), *codes_seen.last().unwrap());
    println!("f1 codes {lo}..={hi}: {} distinct", codes_seen.len());
    assert_eq!(codes_seen.len() as i64, (hi - lo + 1) as i64);
}

#[test]
fn amplifier_output_clips_at_full_scale() {
    // Widen f1's linear range so the amplifier, not the sensor, reaches the rails (+-2.5 kN).
    let mut cfg = quiet();
    let k = cfg.channels.iter().position(|c| c.channel == ChannelId::F1).unwrap();
    cfg.channels[k].linear_range = [-1.0e5, 1.0e5];
    let mut daq = Daq::new(&cfg, &no_effects(), 0).unwrap();
    let lsb = daq.lsb_v();
    let top = (1i32 << 15) - 1;
    for (force, code) in [(3000.0, top), (2500.0, top), (1.0e5, top), (-3000.0, -top - 1), (-2500.0, -top - 1)] {
        let scan = daq.scan(0, 0.0, &mut |_| {
            let mut s = PhysicalSignals::zero();
            s.set(ChannelId::F1, force);
            s
        });
        let v = scan.volts_of(ChannelId::F1).unwrap();
        println!("f1 = {force:8.1} N -> code {:6}, {v:.6} V", scan.count_of(ChannelId::F1).unwrap());
        assert_eq!(scan.count_of(ChannelId::F1).unwrap(), code);
    }
    // The rails decode to -full_scale and +full_scale - LSB.
    let up = daq.scan(1, 0.0, &mut |_| {
        let mut s = PhysicalSignals::zero();
        s.set(ChannelId::F1, 5000.0);
        s
    });
    assert_eq!(up.volts_of(ChannelId::F1).unwrap(), 10.0 - lsb);
    let down = daq.scan(2, 0.0, &mut |_| {
        let mut s = PhysicalSignals::zero();
        s.set(ChannelId::F1, -5000.0);
        s
    });
    assert_eq!(down.volts_of(ChannelId::F1).unwrap(), -10.0);

    // With the default sensor, 3 kN stops at the sensor's linear edge (+8 V), below the rail,
    // and the range check flags it.
    let cfg = quiet();
    let mut daq = Daq::new(&cfg, &no_effects(), 0).unwrap();
    let scan = daq.scan(0, 0.0, &mut |_| {
        let mut s = PhysicalSignals::zero();
        s.set(ChannelId::F1, 3000.0);
        s.set(ChannelId::F2, 1999.0);
        s
    });
    let v = scan.volts_of(ChannelId::F1).unwrap();
    println!("default f1 sensor at 3 kN reads {v:.5} V");
    assert!((v - 8.0).abs() <= 0.5 * lsb);
    assert!(!daq.calibration().within_linear_range(ChannelId::F1, v).unwrap());
    assert!(daq.calibration().within_linear_range(ChannelId::F2, scan.volts_of(ChannelId::F2).unwrap()).unwrap());
}

// ---------------------------------------------------------------------------------------
// noise

#[test]
fn noise_rms_matches_the_configuration() {
    let cfg = DaqConfig::zhou2004();
    let mut daq = Daq::new(&cfg, &no_effects(), 2004).unwrap();
    let truth = mid_values();
    let n = 20_000u64;
    let scans = run(&mut daq, &cfg, n, &mut |_| PhysicalSignals { values: truth, shaft_angle_rad: 0.0 });
    for c in &cfg.channels {
        let (_, y) = series(&daq, &scans, c.channel);
        let err: Vec<f64> = y.iter().map(|v| v - truth[c.channel.index()]).collect();
        let mean = err.iter().sum::<f64>() / n as f64;
        let rms = (err.iter().map(|e| e * e).sum::<f64>() / n as f64).sqrt();
        println!(
            "{:12} noise rms measured {:.4e} configured {:.4e} {} (ratio {:.4}), mean {:.2e}",
            c.channel.name(),
            rms,
            c.noise_rms,
            c.channel.unit(),
            rms / c.noise_rms,
            mean
        );
        assert!((rms / c.noise_rms - 1.0).abs() < 0.05, "{}: rms {rms} vs {}", c.channel, c.noise_rms);
        assert!(mean.abs() < 4.0 * c.noise_rms / (n as f64).sqrt() + 0.5 * daq.calibration().resolution_si(c.channel).unwrap());
    }
    // Channels draw independent noise: correlation between two probes is small.
    let (_, a) = series(&daq, &scans, ChannelId::ProbeAX);
    let (_, b) = series(&daq, &scans, ChannelId::ProbeAY);
    let ma = a.iter().sum::<f64>() / n as f64;
    let mb = b.iter().sum::<f64>() / n as f64;
    let cov: f64 = a.iter().zip(&b).map(|(x, y)| (x - ma) * (y - mb)).sum::<f64>();
    let corr = cov / (a.iter().map(|x| (x - ma).powi(2)).sum::<f64>() * b.iter().map(|y| (y - mb).powi(2)).sum::<f64>()).sqrt();
    println!("correlation probe_a_x/probe_a_y noise: {corr:.4}");
    assert!(corr.abs() < 0.04);
}

#[test]
fn same_seed_is_bit_identical_and_different_seeds_differ() {
    let cfg = DaqConfig::zhou2004();
    let truth = mid_values();
    let mut sig = |t: f64| {
        let mut s = PhysicalSignals { values: truth, shaft_angle_rad: 0.0 };
        s.set(ChannelId::F1, 500.0 * (2.0 * PI * 40.0 * t).sin());
        s
    };
    let mut d1 = Daq::new(&cfg, &no_effects(), 11).unwrap();
    let mut d1b = Daq::new(&cfg, &no_effects(), 11).unwrap();
    let mut d2 = Daq::new(&cfg, &no_effects(), 12).unwrap();
    let a = run(&mut d1, &cfg, 500, &mut sig);
    let b = run(&mut d1b, &cfg, 500, &mut sig);
    let c = run(&mut d2, &cfg, 500, &mut sig);
    assert_eq!(a, b, "same seed, same signals must give identical scans");
    let differing = a.iter().zip(&c).flat_map(|(x, y)| x.counts.iter().zip(&y.counts)).filter(|(p, q)| p != q).count();
    println!("seed 11 vs 12: {differing} of {} codes differ", 500 * 10);
    assert!(differing > 4000, "different seeds must give different noise");

    // A scan depends on its index, not on which scans came before it.
    let mut fresh = Daq::new(&cfg, &no_effects(), 11).unwrap();
    let alone = fresh.scan(337, 337.0 / cfg.sample_rate_hz, &mut sig);
    assert_eq!(alone, a[337]);
    // ... and different indices draw different noise.
    let repeat = fresh.scan(338, 337.0 / cfg.sample_rate_hz, &mut sig);
    assert_ne!(repeat.counts, alone.counts);

    // Silencing one channel leaves the others' noise unchanged.
    let mut cfg_q = cfg.clone();
    cfg_q.channels[0].noise_rms = 0.0;
    let mut dq = Daq::new(&cfg_q, &no_effects(), 11).unwrap();
    let q = run(&mut dq, &cfg_q, 500, &mut sig);
    for (x, y) in a.iter().zip(&q) {
        assert_eq!(x.counts[1..], y.counts[1..]);
    }
}

// ---------------------------------------------------------------------------------------
// calibration

#[test]
fn calibration_round_trip_recovers_every_channel_within_quantisation() {
    // Defaults plus a variant with an inverted sensor and offsets, so gain and offset both matter.
    let mut odd = quiet();
    odd.channels[1].sensitivity_v_per_unit = -3.0e4;
    odd.channels[1].offset_v = 1.5;
    odd.channels[6].offset_v = -2.0;
    odd.adc_bits = 12;
    for cfg in [quiet(), odd] {
        let mut daq = Daq::new(&cfg, &no_effects(), 5).unwrap();
        let cal = daq.calibration().clone();
        let json = serde_json::to_string(&cal).unwrap();
        assert_eq!(serde_json::from_str::<oilfilm_physics::daq::Calibration>(&json).unwrap(), cal);
        let mut worst = [0.0f64; 10];
        for j in 0..=200u64 {
            let frac = j as f64 / 200.0;
            let truth: [f64; 10] = std::array::from_fn(|i| {
                let lr = cfg.channels.iter().find(|c| c.channel.index() == i).unwrap().linear_range;
                lr[0] + frac * (lr[1] - lr[0])
            });
            let scan = daq.scan(j, 0.0, &mut |_| PhysicalSignals { values: truth, shaft_angle_rad: 0.0 });
            for (k, &c) in scan.channels.iter().enumerate() {
                let si = cal.to_si(c, scan.volts[k]).unwrap();
                let res = cal.resolution_si(c).unwrap();
                worst[k] = worst[k].max((si - truth[c.index()]).abs() / res);
            }
        }
        for (k, c) in cfg.scan_order().iter().enumerate() {
            println!("{} bits {:12} worst round-trip error {:.4} LSB", cfg.adc_bits, c.name(), worst[k]);
            assert!(worst[k] <= 0.5 + 1e-6, "{c}: {} LSB", worst[k]);
        }
    }
    let cal = DaqConfig::zhou2004().calibration();
    assert!(matches!(cal.to_si(ChannelId::F1, f64::NAN), Err(PhysicsError::NonFinite { .. })));
    assert_eq!(cal.to_si(ChannelId::F3, -7.5).unwrap(), 0.0);
    assert!((cal.to_si(ChannelId::Temperature, 0.0).unwrap() - 50.0).abs() < 1e-12);
    let [lo, hi] = cal.linear_range_v(ChannelId::ProbeBY).unwrap();
    assert!((lo + 8.0).abs() < 1e-12 && (hi - 8.0).abs() < 1e-12);
    assert_eq!(cal.sample_rate_hz(), 5000.0);
}

// ---------------------------------------------------------------------------------------
// effects

/// Phase (rad) of `y = R sin(w t + phase)` by least squares.
fn phase_of(t: &[f64], y: &[f64], w: f64) -> (f64, f64) {
    let (_, a_cos, b_sin) = fit_1x(t, y, w);
    (a_cos.atan2(b_sin), a_cos.hypot(b_sin))
}

#[test]
fn channel_delay_shifts_the_phase_against_the_other_channels_by_two_pi_f_tau() {
    let cfg = DaqConfig::zhou2004();
    // delay_s > 0: sampled later than its slot, the reading leads; < 0: it lags.
    for (f_hz, tau) in [(50.0, 200.0e-6), (80.0, 1.0e-3), (20.0, 3.0e-3), (50.0, -200.0e-6), (20.0, -3.0e-3)] {
        let w = 2.0 * PI * f_hz;
        let effects = Effects { channel_delay: Some(ChannelDelay { channel: "f1".into(), delay_s: tau }), ..Effects::default() };
        let mut plain = Daq::new(&cfg, &no_effects(), 3).unwrap();
        let mut delayed = Daq::new(&cfg, &effects, 3).unwrap();
        assert_eq!(delayed.max_lookback_s(), f64::abs(tau));
        let mut earliest: f64 = 0.0;
        let mut sig = |t: f64, start: f64| {
            earliest = earliest.min(t - start);
            let mut s = PhysicalSignals { values: mid_values(), shaft_angle_rad: 0.0 };
            s.set(ChannelId::F1, 1000.0 * (w * t).sin());
            s.set(ChannelId::F2, 800.0 * (w * t).cos());
            s
        };
        let n = 5000u64; // 1 s: an integer number of cycles
        let mut a = Vec::new();
        let mut b = Vec::new();
        for i in 0..n {
            let start = i as f64 / cfg.sample_rate_hz;
            a.push(plain.scan(i, start, &mut |t| sig(t, start)));
            b.push(delayed.scan(i, start, &mut |t| sig(t, start)));
        }
        assert!(earliest >= -f64::abs(tau) - 1e-12, "asked {earliest} s before the scan start");
        // Phases of f1 against f2 (same frequency, f2 on its own schedule) in each record.
        let (t, ya) = series(&plain, &a, ChannelId::F1);
        let (_, yb) = series(&delayed, &b, ChannelId::F1);
        let (_, ra2) = series(&plain, &a, ChannelId::F2);
        let (_, rb2) = series(&delayed, &b, ChannelId::F2);
        let (pa, ra) = phase_of(&t, &ya, w);
        let (pb, rb) = phase_of(&t, &yb, w);
        let (pa2, _) = phase_of(&t, &ra2, w);
        let (pb2, _) = phase_of(&t, &rb2, w);
        // y = R sin(w t + phase): a reading that leads by tau has its phase larger by w tau.
        let shift = (pb - pb2) - (pa - pa2);
        let expected = w * tau;
        println!(
            "f = {f_hz} Hz, tau = {:+.0} us: f1 against f2 moved {shift:+.6} rad (expected {expected:+.6}, rel. error {:.2e}); amplitudes {ra:.2}/{rb:.2} N",
            tau * 1e6,
            (shift - expected).abs() / expected.abs()
        );
        assert!((shift - expected).abs() < 0.01 * expected.abs());
        for (x, y) in a.iter().zip(&b) {
            if tau < 0.0 {
                // A lag moves the named channel alone.
                for c in ChannelId::ALL.iter().filter(|&&c| c != ChannelId::F1) {
                    assert_eq!(x.count_of(*c), y.count_of(*c));
                }
            } else {
                // A lead keeps the named channel on its schedule and moves the others.
                assert_eq!(x.count_of(ChannelId::F1), y.count_of(ChannelId::F1));
            }
        }
    }
}

#[test]
fn synchronous_runout_is_a_forward_1x_orbit_on_the_bearing_probes_only() {
    let cfg = DaqConfig::zhou2004();
    let amplitude = 10.0e-6;
    let phase_deg: f64 = 30.0;
    let omega = 2.0 * PI * 25.0; // 1500 rpm
    let effects = Effects { synchronous_runout: Some(SynchronousRunout { amplitude_m: amplitude, phase_deg }), ..Effects::default() };
    let mut with = Daq::new(&cfg, &effects, 9).unwrap();
    let mut without = Daq::new(&cfg, &no_effects(), 9).unwrap();
    let truth = mid_values();
    let mut sig = |t: f64| PhysicalSignals { values: truth, shaft_angle_rad: omega * t + 0.4 };
    let n = 5000u64;
    let a = run(&mut with, &cfg, n, &mut sig);
    let b = run(&mut without, &cfg, n, &mut sig);

    // Complex 1X phasor P with y = Re(P e^{i(omega t + 0.4)}): P = a - i b.
    let phasor = |daq: &Daq, scans: &[DaqScan], c: ChannelId| {
        let (t, y) = series(daq, scans, c);
        let shifted: Vec<f64> = t.iter().map(|t| t + 0.4 / omega).collect();
        let (_, ca, sb) = fit_1x(&shifted, &y, omega);
        (ca, -sb)
    };
    let ph = phase_deg.to_radians();
    for c in ChannelId::ALL {
        let (re, im) = phasor(&with, &a, c);
        let (re0, im0) = phasor(&without, &b, c);
        let mag = re.hypot(im);
        let unit = c.unit();
        println!("{:12} 1X with runout {:.4e} {unit} at {:7.2} deg; without {:.3e} {unit}", c.name(), mag, im.atan2(re).to_degrees(), re0.hypot(im0));
        if c.is_bearing_probe() {
            // x reads A cos(phi + phase): P = A e^{i phase}; y reads A sin(...): P = -i A e^{i phase}.
            let (er, ei) = if matches!(c, ChannelId::ProbeAX | ChannelId::ProbeBX) {
                (amplitude * ph.cos(), amplitude * ph.sin())
            } else {
                (amplitude * ph.sin(), -amplitude * ph.cos())
            };
            let miss = (re - er).hypot(im - ei);
            assert!(miss < 0.01 * amplitude, "{c}: phasor ({re:e}, {im:e}) vs ({er:e}, {ei:e})");
            assert!(re0.hypot(im0) < 0.01 * amplitude, "{c} shows 1X without runout");
        } else {
            // Frame probes, forces, temperature: untouched, sample for sample.
            for (x, y) in a.iter().zip(&b) {
                assert_eq!(x.count_of(c), y.count_of(c), "{c} changed by runout");
            }
            if c.is_frame_probe() {
                assert!(mag < 0.01 * amplitude, "{c} shows 1X {mag:e}");
            }
        }
    }
    // Forward orbit: y lags x by a quarter turn at both ends (P_y = -i P_x).
    for (x, y) in [(ChannelId::ProbeAX, ChannelId::ProbeAY), (ChannelId::ProbeBX, ChannelId::ProbeBY)] {
        let (xr, xi) = phasor(&with, &a, x);
        let (yr, yi) = phasor(&with, &a, y);
        // Forward and backward whirl amplitudes |P_x + i P_y| / 2 and |P_x - i P_y| / 2.
        let forward = (xr - yi).hypot(xi + yr) / 2.0;
        let backward = (xr + yi).hypot(xi - yr) / 2.0;
        println!("{x}/{y}: forward {forward:.4e} m, backward {backward:.4e} m");
        assert!(backward < 0.01 * amplitude && (forward - amplitude).abs() < 0.01 * amplitude);
    }
}

#[test]
fn probe_saturation_clips_the_named_probe_about_its_zero() {
    let peak = 80.0e-6;
    let limit = 50.0e-6;
    let extremes = |cfg: &DaqConfig, effects: &Effects| -> Vec<(ChannelId, f64, f64)> {
        let mut daq = Daq::new(cfg, effects, 1).unwrap();
        let scans = run(&mut daq, cfg, 2000, &mut |t| {
            let mut s = PhysicalSignals { values: mid_values(), shaft_angle_rad: 0.0 };
            for c in ChannelId::ALL.iter().filter(|c| c.is_displacement_probe()) {
                s.set(*c, peak * (2.0 * PI * 10.0 * t).sin());
            }
            s
        });
        ChannelId::ALL
            .iter()
            .filter(|c| c.is_displacement_probe())
            .map(|&c| {
                let (_, y) = series(&daq, &scans, c);
                (c, y.iter().cloned().fold(f64::INFINITY, f64::min), y.iter().cloned().fold(f64::NEG_INFINITY, f64::max))
            })
            .collect()
    };
    let res = DaqConfig::zhou2004().calibration().resolution_si(ChannelId::ProbeAY).unwrap();
    let sat = |ch: &str| Effects { probe_saturation: Some(ProbeSaturation { channel: ch.into(), limit_m: limit }), ..Effects::default() };

    // Zero offset: the calibrated zero is 0 m, so the probe clips at +-limit.
    let mut cfg = quiet();
    // ... and with an amplifier offset of +1 V on probe_b_x its zero is -25 um: clips at -75/+25 um.
    let kb = cfg.channels.iter().position(|c| c.channel == ChannelId::ProbeBX).unwrap();
    cfg.channels[kb].offset_v = 1.0;
    for (name, centre) in [("probe_a_y", 0.0), ("probe_b_x", -25.0e-6), ("frame_x", 0.0)] {
        let target = ChannelId::parse(name).unwrap();
        for (c, lo, hi) in extremes(&cfg, &sat(name)) {
            println!("saturation on {name}: {:10} min {:8.3} um max {:8.3} um", c.name(), lo * 1e6, hi * 1e6);
            let (elo, ehi) = if c == target { ((centre - limit).max(-peak), (centre + limit).min(peak)) } else { (-peak, peak) };
            assert!((lo - elo).abs() <= res && (hi - ehi).abs() <= res, "{c}: [{lo:e}, {hi:e}] vs [{elo:e}, {ehi:e}]");
        }
    }
    // A limit wider than the linear range: the linear range (+-0.2 mm) still governs.
    let wide = Effects { probe_saturation: Some(ProbeSaturation { channel: "probe_a_x".into(), limit_m: 1.0e-3 }), ..Effects::default() };
    let mut daq = Daq::new(&quiet(), &wide, 0).unwrap();
    let scan = daq.scan(0, 0.0, &mut |_| {
        let mut s = PhysicalSignals::zero();
        s.set(ChannelId::ProbeAX, 0.25e-3);
        s
    });
    let x = daq.calibration().to_si(ChannelId::ProbeAX, scan.volts_of(ChannelId::ProbeAX).unwrap()).unwrap();
    println!("limit 1 mm, true 0.25 mm reads {:.4} mm", x * 1e3);
    assert!((x - 0.2e-3).abs() <= res);
}

// ---------------------------------------------------------------------------------------
// errors and non-finite inputs

#[test]
fn invalid_configuration_names_the_field() {
    type Mutation = Box<dyn Fn(&mut DaqConfig)>;
    fn m(f: impl Fn(&mut DaqConfig) + 'static) -> Mutation {
        Box::new(f)
    }
    let cases: Vec<(&str, Mutation, &str)> = vec![
        ("duplicate channel", m(|c| c.channels[3].channel = ChannelId::ProbeAX), "daq.channels[3].channel"),
        (
            "missing channel",
            m(|c| {
                c.channels.remove(8);
            }),
            "daq.channels",
        ),
        ("interval too long", m(|c| c.channel_interval_s = 30.0e-6), "daq.channel_interval_s"),
        ("negative interval", m(|c| c.channel_interval_s = -1.0e-6), "daq.channel_interval_s"),
        ("NaN sensitivity", m(|c| c.channels[2].sensitivity_v_per_unit = f64::NAN), "daq.channels[2].sensitivity_v_per_unit"),
        ("zero sensitivity", m(|c| c.channels[7].sensitivity_v_per_unit = 0.0), "daq.channels[7].sensitivity_v_per_unit"),
        ("infinite offset", m(|c| c.channels[4].offset_v = f64::INFINITY), "daq.channels[4].offset_v"),
        ("negative noise", m(|c| c.channels[5].noise_rms = -1.0), "daq.channels[5].noise_rms"),
        ("reversed range", m(|c| c.channels[1].linear_range = [1.0e-4, -1.0e-4]), "daq.channels[1].linear_range"),
        ("NaN range", m(|c| c.channels[9].linear_range[1] = f64::NAN), "daq.channels[9].linear_range"),
        ("range beyond the ADC", m(|c| c.channels[0].offset_v = 100.0), "daq.channels[0].linear_range"),
        ("7 bits", m(|c| c.adc_bits = 7), "daq.adc_bits"),
        ("25 bits", m(|c| c.adc_bits = 25), "daq.adc_bits"),
        ("zero rate", m(|c| c.sample_rate_hz = 0.0), "daq.sample_rate_hz"),
        ("NaN rate", m(|c| c.sample_rate_hz = f64::NAN), "daq.sample_rate_hz"),
        ("negative full scale", m(|c| c.full_scale_v = -10.0), "daq.full_scale_v"),
    ];
    for (what, mutate, expected) in cases {
        let mut cfg = DaqConfig::zhou2004();
        mutate(&mut cfg);
        let err = cfg.validate("daq").unwrap_err();
        println!("{what:22} -> {err}");
        let err2 = Daq::new(&cfg, &no_effects(), 0).expect_err("Daq::new must refuse it too");
        assert_eq!(err, err2);
        assert_eq!(field(err), expected, "{what}");
    }
    // The missing channel is named in the reason.
    let mut cfg = DaqConfig::zhou2004();
    cfg.channels.remove(8);
    let msg = cfg.validate("daq").unwrap_err().to_string();
    assert!(msg.contains("f3"), "{msg}");
    // The prefix is the caller's.
    let mut cfg = DaqConfig::zhou2004();
    cfg.channels[2].sensitivity_v_per_unit = f64::NAN;
    assert_eq!(field(cfg.validate("rig.daq").unwrap_err()), "rig.daq.channels[2].sensitivity_v_per_unit");
    assert_eq!(field(cfg.validate("").unwrap_err()), "channels[2].sensitivity_v_per_unit");
    // Interval limit is strict: 10 channels x 22.2 us = 200 us does not fit in 200 us.
    let mut cfg = DaqConfig::zhou2004();
    cfg.channel_interval_s = 1.0 / 5000.0 / 9.0;
    assert!(cfg.validate("daq").is_err());
    cfg.channel_interval_s = 0.0; // a simultaneous-sampling card is allowed
    cfg.validate("daq").unwrap();
}

#[test]
fn unknown_keys_and_names_are_parse_errors() {
    let err = toml::from_str::<DaqConfig>(include_str!("data/daq/unknown_key.toml")).unwrap_err().to_string();
    println!("unknown key: {err}");
    assert!(err.contains("gain"), "{err}");
    let top = "bogus = 1\n".to_string() + &std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/daq/zhou2004.toml")).unwrap();
    let err = toml::from_str::<DaqConfig>(&top).unwrap_err().to_string();
    println!("unknown top-level key: {err}");
    assert!(err.contains("bogus"), "{err}");
    let bad_name = include_str!("data/daq/zhou2004.toml").replace("\"probe_b_y\"", "\"probe_c_y\"");
    let err = toml::from_str::<DaqConfig>(&bad_name).unwrap_err().to_string();
    println!("unknown channel name: {err}");
    assert!(err.contains("probe_c_y"), "{err}");
}

#[test]
fn effect_channels_are_resolved_and_checked() {
    let cfg = DaqConfig::zhou2004();
    let delay = |ch: &str, d: f64| Effects { channel_delay: Some(ChannelDelay { channel: ch.into(), delay_s: d }), ..Effects::default() };
    let sat = |ch: &str, l: f64| Effects { probe_saturation: Some(ProbeSaturation { channel: ch.into(), limit_m: l }), ..Effects::default() };
    let cases: Vec<(&str, Effects, &str)> = vec![
        ("unknown delay channel", delay("f4", 1e-4), "effects.channel_delay.channel"),
        ("NaN delay", delay("f1", f64::NAN), "effects.channel_delay.delay_s"),
        ("unknown saturation channel", sat("bogus", 1e-5), "effects.probe_saturation.channel"),
        ("saturation on a force", sat("f1", 1e-5), "effects.probe_saturation.channel"),
        ("saturation on temperature", sat("temperature", 1e-5), "effects.probe_saturation.channel"),
        ("zero limit", sat("probe_a_x", 0.0), "effects.probe_saturation.limit_m"),
    ];
    for (what, effects, expected) in cases {
        let err = Daq::new(&cfg, &effects, 0).expect_err("must be refused");
        println!("{what:28} -> {err}");
        assert_eq!(field(err), expected, "{what}");
    }
    // A saturation band that misses the linear range entirely: zero at +225 um, range +-200 um.
    let mut far = cfg.clone();
    far.channels[0].offset_v = -9.0;
    far.validate("daq").unwrap();
    let err = Daq::new(&far, &sat("probe_a_x", 10e-6), 0).err().unwrap();
    println!("band outside range -> {err}");
    assert_eq!(field(err), "effects.probe_saturation.limit_m");
    // Valid names resolve, frame probes included.
    for ch in ["probe_a_x", "probe_b_y", "frame_x", "frame_y"] {
        Daq::new(&cfg, &sat(ch, 20e-6), 0).unwrap();
    }
    for c in ChannelId::ALL {
        let d = Daq::new(&cfg, &delay(c.name(), 5e-5), 0).unwrap();
        assert_eq!(d.max_lookback_s(), 5e-5);
    }
    // Effects that act in the rig are accepted and ignored here.
    let rig_only = Effects { support_friction: Some(oilfilm_physics::effects::SupportFriction { friction_force_n: 3.0 }), ..Effects::default() };
    let mut a = Daq::new(&cfg, &rig_only, 4).unwrap();
    let mut b = Daq::new(&cfg, &no_effects(), 4).unwrap();
    let mut sig = |_| PhysicalSignals { values: mid_values(), shaft_angle_rad: 1.0 };
    assert_eq!(a.scan(0, 0.0, &mut sig), b.scan(0, 0.0, &mut sig));
}

#[test]
fn non_finite_inputs_go_to_a_rail_without_panicking() {
    let cfg = DaqConfig::zhou2004();
    let top = (1i32 << 15) - 1;
    let mut daq = Daq::new(&cfg, &no_effects(), 0).unwrap();
    let scan = daq.scan(0, 0.0, &mut |_| {
        let mut s = PhysicalSignals { values: mid_values(), shaft_angle_rad: f64::NAN };
        s.set(ChannelId::ProbeBX, f64::NAN);
        s.set(ChannelId::F1, f64::INFINITY);
        s.set(ChannelId::F2, f64::NEG_INFINITY);
        s.set(ChannelId::F3, 1.0e300); // finite but absurd: the sensor clips at its edge
        s
    });
    println!("counts {:?}, non-finite samples {}", scan.counts, daq.non_finite_samples());
    assert_eq!(scan.count_of(ChannelId::ProbeBX).unwrap(), -top - 1);
    assert_eq!(scan.count_of(ChannelId::F1).unwrap(), top);
    assert_eq!(scan.count_of(ChannelId::F2).unwrap(), -top - 1);
    assert_eq!(daq.non_finite_samples(), 3);
    let cal = daq.calibration();
    for c in [ChannelId::ProbeBX, ChannelId::F1, ChannelId::F2, ChannelId::F3] {
        let v = scan.volts_of(c).unwrap();
        assert!(v.is_finite());
        assert!(!cal.within_linear_range(c, v).unwrap(), "{c} at {v} V must fail the range check");
    }
    // Shaft angle NaN is harmless without runout ...
    assert!(cal.within_linear_range(ChannelId::ProbeAX, scan.volts_of(ChannelId::ProbeAX).unwrap()).unwrap());
    // ... and rails the bearing probes with it.
    let runout = Effects { synchronous_runout: Some(SynchronousRunout { amplitude_m: 5e-6, phase_deg: 0.0 }), ..Effects::default() };
    let mut daq = Daq::new(&cfg, &runout, 0).unwrap();
    let scan = daq.scan(0, f64::NAN, &mut |_| PhysicalSignals { values: mid_values(), shaft_angle_rad: f64::NAN });
    assert_eq!(daq.non_finite_samples(), 4);
    for c in ChannelId::ALL {
        let code = scan.count_of(c).unwrap();
        assert_eq!(code == -top - 1, c.is_bearing_probe(), "{c}: {code}");
    }
}
