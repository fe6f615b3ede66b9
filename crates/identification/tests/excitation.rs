//! Excitation design: constructors, limits, crest factor, spectrum, chirp, serde.

use std::f64::consts::PI;

use oilfilm_identification::excitation::{AmplitudeStep, ExcitationPlan, Limits, LineSet, Waveform, MAX_HARMONIC};
use oilfilm_identification::IdentificationError;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn paper() -> Limits {
    Limits::zhou2004()
}

/// Complex DFT of `x` (sampled at `fs`) at frequency `f`, normalised so a cosine of amplitude
/// `a` on a bin gives magnitude `a`.
fn dft(x: &[f64], fs: f64, f: f64) -> (f64, f64) {
    let n = x.len() as f64;
    let (mut re, mut im) = (0.0, 0.0);
    for (j, v) in x.iter().enumerate() {
        let arg = 2.0 * PI * ((f * j as f64 / fs).fract());
        re += v * arg.cos();
        im -= v * arg.sin();
    }
    (2.0 * re / n, 2.0 * im / n)
}

fn magnitude(c: (f64, f64)) -> f64 {
    c.0.hypot(c.1)
}

fn samples(plan: &ExcitationPlan, limits: &Limits, t0: f64, fs: f64, n: usize) -> [Vec<f64>; 2] {
    let mut out = [Vec::with_capacity(n), Vec::with_capacity(n)];
    for j in 0..n {
        let f = plan.force_at(t0 + j as f64 / fs, limits);
        out[0].push(f[0]);
        out[1].push(f[1]);
    }
    out
}

#[test]
fn every_constructor_validates_under_the_paper_limits() {
    let plans = [
        ("paper_sine", ExcitationPlan::paper_sine(50.0, 1000.0)),
        ("paper_sine at full force", ExcitationPlan::paper_sine(80.0, 1500.0)),
        ("two_tone", ExcitationPlan::two_tone(20.0, 30.0, 100.0)),
        ("multisine 1 s", ExcitationPlan::multisine([1.0, 80.0], 1.0, 300.0)),
        ("multisine 10 s", ExcitationPlan::multisine([0.5, 79.0], 10.0, 500.0)),
        ("multisine from DC", ExcitationPlan::multisine([0.0, 80.0], 0.5, 100.0)),
    ];
    for (name, plan) in &plans {
        plan.validate(&paper()).unwrap_or_else(|e| panic!("{name}: {e}"));
        for p in plan.peak_force_n() {
            assert!(p <= paper().max_force_n, "{name}: peak {p}");
        }
    }
}

#[test]
fn paper_sine_is_one_frequency_ninety_degrees_apart() {
    let plan = ExcitationPlan::paper_sine(40.0, 200.0);
    let [l1, l2] = plan.lines_hz();
    assert_eq!(l1, vec![40.0]);
    assert_eq!(l2, vec![40.0]);
    // After the ramp, when f1 crosses zero upwards f2 is at its negative peak (lags 90°).
    let t = 2.0; // 80 whole cycles of 40 Hz: f1 = 0 rising
    let f = plan.force_at(t, &paper());
    assert!(f[0].abs() < 1e-6, "{f:?}");
    assert!((f[1] + 200.0).abs() < 1e-6, "{f:?}");
}

#[test]
fn two_tone_lines_are_disjoint() {
    let plan = ExcitationPlan::two_tone(17.0, 31.0, 100.0);
    let [l1, l2] = plan.lines_hz();
    assert_eq!(l1, vec![17.0]);
    assert_eq!(l2, vec![31.0]);
    assert!(l1.iter().all(|f| !l2.contains(f)));

    let ms = ExcitationPlan::multisine([1.0, 80.0], 1.0, 200.0);
    let [m1, m2] = ms.lines_hz();
    assert_eq!(m1.len(), 40);
    assert_eq!(m2.len(), 40);
    assert!(m1.iter().all(|f| !m2.contains(f)), "multisine exciters share a line");
    assert!(m1.iter().all(|f| (*f as u64) % 2 == 1));
    assert!(m2.iter().all(|f| (*f as u64) & 1 == 0));
}

/// Crest factor of the same tones with every phase zero, computed numerically over one period.
fn zero_phase_crest(w: &Waveform, period_s: f64) -> f64 {
    let tones = w.tones();
    let m = 1 << 15;
    let (mut peak, mut sum2) = (0.0_f64, 0.0);
    for j in 0..m {
        let t = period_s * j as f64 / m as f64;
        let v: f64 = tones.iter().map(|k| k.amplitude_n * (2.0 * PI * k.frequency_hz * t).cos()).sum();
        peak = peak.max(v.abs());
        sum2 += v * v;
    }
    peak / (sum2 / m as f64).sqrt()
}

#[test]
fn schroeder_multisine_has_a_low_crest_factor() {
    let cases = [
        ([1.0, 10.0], 1.0, LineSet::All),
        ([1.0, 20.0], 1.0, LineSet::Odd),
        ([1.0, 20.0], 1.0, LineSet::Even),
        ([5.0, 15.0], 1.0, LineSet::All),
        ([1.0, 80.0], 1.0, LineSet::Odd),
        ([1.0, 80.0], 1.0, LineSet::Even),
        ([1.0, 80.0], 1.0, LineSet::All),
        ([0.1, 80.0], 10.0, LineSet::Odd),
    ];
    for (band_hz, period_s, line_set) in cases {
        let w = Waveform::Multisine { band_hz, period_s, rms_n: 100.0, line_set };
        let n = w.lines_hz().len();
        assert!(n >= 10);
        let cf = w.crest_factor();
        let cf0 = zero_phase_crest(&w, period_s);
        println!(
            "multisine {band_hz:?} Hz, period {period_s} s, {line_set:?}: {n} lines, \
             crest factor {cf:.3} (zero phase {cf0:.3}, sqrt(2N) = {:.3})",
            (2.0 * n as f64).sqrt()
        );
        assert!(cf < 2.0, "crest factor {cf} for {n} lines");
        assert!(cf < 0.6 * cf0, "Schroeder {cf} vs zero phase {cf0}");
        // The peak the validator uses is an upper bound, tight to 0.1 %.
        let bound = w.peak_force_n();
        let sampled = cf * 100.0;
        assert!(bound >= sampled && bound <= sampled * 1.0011, "bound {bound} sampled {sampled}");
    }
    let sine = Waveform::Sine { frequency_hz: 13.0, amplitude_n: 10.0, phase_deg: 0.0 };
    assert!((sine.crest_factor() - 2f64.sqrt()).abs() < 1e-3);
    assert_eq!(Waveform::Off.crest_factor(), 0.0);
}

#[test]
fn multisine_peak_is_the_true_peak_not_rms_times_root_two() {
    // 40 odd lines: crest about 1.69. rms 1000 N looks fine by rms*sqrt(2) = 1414 N < 1500 N,
    // but the actual waveform peaks near 1690 N.
    let w = |rms_n| Waveform::Multisine { band_hz: [1.0, 80.0], period_s: 1.0, rms_n, line_set: LineSet::Odd };
    let plan = ExcitationPlan { exciters: [w(1000.0), Waveform::Off], ramp_s: 0.0, amplitude_steps: vec![] };
    let err = plan.validate(&paper()).expect_err("true peak exceeds the limit");
    let text = err.to_string();
    assert!(matches!(err, IdentificationError::ExcitationLimit(_)), "{text}");
    assert!(text.contains("exciter 1") && text.contains("peak force") && text.contains("crest"), "{text}");
    // Check it against the signal itself, unclamped by a generous limit.
    let loose = Limits { max_force_n: 1e6, band_hz: [0.0, 80.0] };
    let [x, _] = samples(&plan, &loose, 0.0, 50_000.0, 50_000);
    let peak = x.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    assert!(peak > 1500.0 && peak > 1000.0 * 2f64.sqrt(), "peak {peak}");

    let ok = ExcitationPlan { exciters: [w(850.0), Waveform::Off], ramp_s: 0.0, amplitude_steps: vec![] };
    ok.validate(&paper()).expect("rms 850 N peaks below 1500 N");
}

#[test]
fn multisine_spectrum_has_energy_only_on_its_lines() {
    let rms = 200.0;
    let plan = ExcitationPlan::multisine([1.0, 80.0], 1.0, rms);
    let fs = 5000.0;
    // One whole period after the ramp: every line sits on a DFT bin.
    let x = samples(&plan, &paper(), 3.0, fs, 5000);
    let line_amplitude = rms * (2.0 / 40.0_f64).sqrt();
    for (e, xs) in x.iter().enumerate() {
        let lines = &plan.lines_hz()[e];
        for k in 0..=200u32 {
            let f = k as f64;
            let mag = magnitude(dft(xs, fs, f));
            if lines.contains(&f) {
                assert!((mag - line_amplitude).abs() < 1e-9 * rms, "exciter {} line {f} Hz: {mag}", e + 1);
            } else {
                assert!(mag < 1e-9 * rms, "exciter {} off-line {f} Hz: {mag}", e + 1);
            }
        }
        // The phases are Schroeder's: check two of them against the tones.
        for tone in plan.exciters[e].tones().iter().take(3) {
            let (re, im) = dft(xs, fs, tone.frequency_hz);
            let phase = im.atan2(re);
            let expected = (tone.phase_rad + PI).rem_euclid(2.0 * PI) - PI;
            let diff = (phase - expected + PI).rem_euclid(2.0 * PI) - PI;
            assert!(diff.abs() < 1e-9, "phase at {} Hz: {phase} vs {expected}", tone.frequency_hz);
        }
    }
}

/// Instantaneous frequency from upward zero crossings (linearly interpolated).
fn upward_crossings(x: &[f64], fs: f64, t0: f64) -> Vec<f64> {
    x.windows(2).enumerate().filter(|(_, w)| w[0] < 0.0 && w[1] >= 0.0).map(|(j, w)| t0 + (j as f64 + w[0] / (w[0] - w[1])) / fs).collect()
}

#[test]
fn chirp_sweeps_from_start_to_end_and_repeats_without_a_jump() {
    for (start, end) in [(5.0, 60.0), (70.0, 10.0)] {
        let sweep = 8.0;
        let plan = ExcitationPlan {
            exciters: [Waveform::Chirp { start_hz: start, end_hz: end, sweep_s: sweep, amplitude_n: 100.0 }, Waveform::Off],
            ramp_s: 0.0,
            amplitude_steps: vec![],
        };
        plan.validate(&paper()).expect("chirp within limits");
        assert!(plan.lines_hz()[0].is_empty(), "a chirp has no lines");
        let fs = 20_000.0;
        // Two and a half sweeps: the second sweep must repeat the first.
        let n = (2.5 * sweep * fs) as usize;
        let [x, _] = samples(&plan, &paper(), 0.0, fs, n);
        let crossings = upward_crossings(&x, fs, 0.0);
        let mut checked = 0;
        for pair in crossings.windows(2) {
            let mid = 0.5 * (pair[0] + pair[1]);
            let tau = mid % sweep;
            // Skip the cycle that straddles a restart.
            if tau < 0.2 || tau > sweep - 0.2 {
                continue;
            }
            let measured = 1.0 / (pair[1] - pair[0]);
            let expected = start + (end - start) * tau / sweep;
            assert!((measured - expected).abs() < 0.005 * expected.max(1.0), "t {mid}: {measured} Hz vs {expected} Hz");
            checked += 1;
        }
        assert!(checked > 500, "{checked} cycles checked");
        // Near the start of each sweep the frequency is `start`, near the end `end`.
        // Continuity across the restart: no step larger than the steepest slope allows.
        let max_step = 100.0 * 2.0 * PI * start.max(end) / fs * 1.01;
        for w in x.windows(2) {
            assert!((w[1] - w[0]).abs() <= max_step, "force jumps by {}", w[1] - w[0]);
        }
        let cf = plan.exciters[0].crest_factor();
        println!("chirp {start}->{end} Hz: crest factor {cf:.4}");
        assert!((cf - 2f64.sqrt()).abs() < 0.01);
    }
}

/// Plans that must be refused, with words the refusal must contain.
fn hostile_plans() -> Vec<(ExcitationPlan, Vec<&'static str>)> {
    let sine = |frequency_hz, amplitude_n, phase_deg| Waveform::Sine { frequency_hz, amplitude_n, phase_deg };
    let ms = |band_hz, period_s, rms_n| Waveform::Multisine { band_hz, period_s, rms_n, line_set: LineSet::All };
    let chirp = |start_hz, end_hz, sweep_s, amplitude_n| Waveform::Chirp { start_hz, end_hz, sweep_s, amplitude_n };
    let ok = sine(20.0, 100.0, 0.0);
    let one = |w: Waveform| ExcitationPlan { exciters: [ok.clone(), w], ramp_s: 0.5, amplitude_steps: vec![] };
    let first = |w: Waveform| ExcitationPlan { exciters: [w, ok.clone()], ramp_s: 0.0, amplitude_steps: vec![] };
    let steps = |scale, dwell_s| ExcitationPlan {
        exciters: [sine(20.0, 1000.0, 0.0), ok.clone()],
        ramp_s: 0.5,
        amplitude_steps: vec![AmplitudeStep { scale: 0.5, dwell_s: 5.0 }, AmplitudeStep { scale, dwell_s }],
    };
    let nan = f64::NAN;
    let inf = f64::INFINITY;
    vec![
        (first(sine(20.0, 1e9, 0.0)), vec!["exciter 1", "peak force", "max_force_n"]),
        (one(sine(20.0, 1e9, 0.0)), vec!["exciter 2", "exciters[1]", "peak force"]),
        (one(sine(20.0, 1500.1, 0.0)), vec!["exciter 2", "peak force"]),
        (first(sine(20.0, nan, 0.0)), vec!["exciters[0].amplitude_n", "exciter 1", "NaN"]),
        (one(sine(20.0, -500.0, 0.0)), vec!["exciters[1].amplitude_n", "non-negative"]),
        (one(sine(inf, 100.0, 0.0)), vec!["exciters[1].frequency_hz", "inf"]),
        (first(sine(nan, 100.0, 0.0)), vec!["exciters[0].frequency_hz"]),
        (first(sine(-20.0, 100.0, 0.0)), vec!["exciters[0].frequency_hz"]),
        (one(sine(120.0, 100.0, 0.0)), vec!["exciter 2", "frequency_hz", "outside the rig band"]),
        (one(sine(20.0, 100.0, nan)), vec!["exciters[1].phase_deg"]),
        (first(ms([1.0, 80.0], 1.0, 1e6)), vec!["exciter 1", "peak force", "crest"]),
        (one(ms([1.0, 200.0], 1.0, 10.0)), vec!["exciter 2", "multisine line", "outside the rig band"]),
        (one(ms([100.0, 200.0], 1.0, 10.0)), vec!["exciter 2", "outside the rig band"]),
        (first(ms([1.0, 80.0], nan, 10.0)), vec!["exciters[0].period_s"]),
        (first(ms([1.0, 80.0], -1.0, 10.0)), vec!["exciters[0].period_s"]),
        (first(ms([1.0, 80.0], 1e12, 10.0)), vec!["exciters[0].band_hz", "harmonics exceeds"]),
        (first(ms([1.0, 80.0], 1.0, inf)), vec!["exciters[0].rms_n"]),
        (first(ms([1.0, 80.0], 1.0, -3.0)), vec!["exciters[0].rms_n"]),
        (first(ms([nan, 80.0], 1.0, 3.0)), vec!["exciters[0].band_hz"]),
        (first(ms([50.0, 10.0], 1.0, 3.0)), vec!["exciters[0].band_hz"]),
        (first(ms([10.2, 10.8], 1.0, 3.0)), vec!["exciters[0].band_hz", "no harmonic"]),
        (one(chirp(5.0, 60.0, 10.0, inf)), vec!["exciters[1].amplitude_n"]),
        (one(chirp(5.0, 60.0, 0.0, 100.0)), vec!["exciters[1].sweep_s"]),
        (one(chirp(5.0, 1e6, 10.0, 100.0)), vec!["exciter 2", "chirp end_hz", "outside the rig band"]),
        (one(chirp(nan, 60.0, 10.0, 100.0)), vec!["exciters[1].start_hz"]),
        (one(chirp(5.0, 60.0, 10.0, 2000.0)), vec!["exciter 2", "peak force"]),
        (steps(2.0, 5.0), vec!["exciter 1", "peak force", "amplitude-step scale 2"]),
        (steps(1e300, 5.0), vec!["exciter 1", "peak force"]),
        (steps(nan, 5.0), vec!["amplitude_steps[1].scale"]),
        (steps(-1.0, 5.0), vec!["amplitude_steps[1].scale"]),
        (steps(1.0, 0.0), vec!["amplitude_steps[1].dwell_s"]),
        (steps(1.0, nan), vec!["amplitude_steps[1].dwell_s"]),
        (steps(1.0, 0.7), vec!["amplitude_steps[1].dwell_s", "ramp"]),
        (ExcitationPlan { ramp_s: nan, ..ExcitationPlan::two_tone(10.0, 20.0, 100.0) }, vec!["ramp_s"]),
        (ExcitationPlan { ramp_s: -1.0, ..ExcitationPlan::two_tone(10.0, 20.0, 100.0) }, vec!["ramp_s"]),
    ]
}

/// Force setpoints at many times: over 100 s densely enough to hit every peak of an 80 Hz
/// sine, plus hostile times.
fn assert_force_within(plan: &ExcitationPlan, limits: &Limits, what: &str) {
    let max = if limits.max_force_n.is_finite() && limits.max_force_n > 0.0 { limits.max_force_n } else { 0.0 };
    let specials = [-1.0, -0.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e12, 1e300, f64::MAX, f64::MIN_POSITIVE];
    let times = (0..40_000).map(|j| j as f64 * 0.0025 + 1.3e-5).chain(specials);
    for t in times {
        for (e, f) in plan.force_at(t, limits).into_iter().enumerate() {
            assert!(f.is_finite() && f.abs() <= max, "{what}: exciter {} at t = {t}: {f} N", e + 1);
        }
    }
}

#[test]
fn hostile_plans_are_refused_with_their_exciter_and_field_named_and_force_at_still_clamps() {
    let limits = paper();
    for (plan, words) in hostile_plans() {
        let err = plan.validate(&limits).expect_err(&format!("{plan:?} must be refused"));
        let text = err.to_string();
        for w in &words {
            assert!(text.contains(w), "`{text}` lacks `{w}`");
        }
        assert_force_within(&plan, &limits, &text);
    }
    // A 1e9 N sine hits the clamp exactly, not beyond.
    let plan = ExcitationPlan::paper_sine(20.0, 1e9);
    let peak = (0..10_000).map(|j| plan.force_at(2.0 + j as f64 * 1e-4, &limits)[0].abs()).fold(0.0, f64::max);
    assert_eq!(peak, limits.max_force_n);
}

#[test]
fn hostile_limits_are_refused_and_give_zero_force() {
    let plan = ExcitationPlan::two_tone(10.0, 20.0, 100.0);
    for (limits, field) in [
        (Limits { max_force_n: f64::NAN, band_hz: [0.0, 80.0] }, "limits.max_force_n"),
        (Limits { max_force_n: -1.0, band_hz: [0.0, 80.0] }, "limits.max_force_n"),
        (Limits { max_force_n: f64::INFINITY, band_hz: [0.0, 80.0] }, "limits.max_force_n"),
        (Limits { max_force_n: 1500.0, band_hz: [80.0, 0.0] }, "limits.band_hz"),
        (Limits { max_force_n: 1500.0, band_hz: [0.0, f64::NAN] }, "limits.band_hz"),
    ] {
        let err = plan.validate(&limits).expect_err("bad limits");
        assert!(err.to_string().contains(field), "{err}");
        if !(limits.max_force_n.is_finite() && limits.max_force_n > 0.0) {
            for j in 0..1000 {
                assert_eq!(plan.force_at(j as f64 * 0.01, &limits), [0.0, 0.0]);
            }
        }
        assert_force_within(&plan, &limits, field);
    }
}

/// Random plans built from hostile numbers: whatever validate says, force_at stays finite and
/// within the limit.
#[test]
fn random_hostile_plans_never_escape_the_clamp() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x0f11_f11e);
    let pool = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -1.0, 0.0, -0.0, 1e-300, 1e300, 0.01, 0.5, 1.0, 10.0, 79.9, 80.0, 200.0, 1499.0, 1e6];
    let pick = |rng: &mut ChaCha8Rng| {
        if rng.random_range(0..3) == 0 {
            rng.random_range(-100.0..2000.0)
        } else {
            pool[rng.random_range(0..pool.len())]
        }
    };
    let limits = paper();
    let mut refused = 0;
    for case in 0..300 {
        let waveform = |rng: &mut ChaCha8Rng| match rng.random_range(0..4) {
            0 => Waveform::Off,
            1 => Waveform::Sine { frequency_hz: pick(rng), amplitude_n: pick(rng), phase_deg: pick(rng) },
            2 => Waveform::Multisine {
                band_hz: [pick(rng), pick(rng)],
                // Bounded periods keep the line count (and the test time) small.
                period_s: [f64::NAN, -1.0, 0.0, 0.01, 0.5, 1.0, 1e9, f64::INFINITY][rng.random_range(0..8)],
                rms_n: pick(rng),
                line_set: [LineSet::All, LineSet::Odd, LineSet::Even][rng.random_range(0..3)],
            },
            _ => Waveform::Chirp { start_hz: pick(rng), end_hz: pick(rng), sweep_s: pick(rng), amplitude_n: pick(rng) },
        };
        let exciters = [waveform(&mut rng), waveform(&mut rng)];
        let amplitude_steps = (0..rng.random_range(0..3)).map(|_| AmplitudeStep { scale: pick(&mut rng), dwell_s: pick(&mut rng) }).collect();
        let plan = ExcitationPlan { exciters, ramp_s: pick(&mut rng), amplitude_steps };
        let valid = plan.validate(&limits).is_ok();
        refused += usize::from(!valid);
        for j in 0..2000 {
            let t = j as f64 * 0.0137;
            for f in plan.force_at(t, &limits) {
                assert!(f.is_finite() && f.abs() <= limits.max_force_n, "case {case}: {plan:?} at {t}: {f}");
            }
        }
        if valid {
            for p in plan.peak_force_n() {
                assert!(p <= limits.max_force_n, "case {case}: validated plan peaks at {p}");
            }
        }
    }
    assert!(refused > 100, "only {refused} of 300 random hostile plans refused");
}

#[test]
fn amplitude_steps_ramp_between_levels_and_end_at_zero() {
    let plan = ExcitationPlan {
        amplitude_steps: vec![
            AmplitudeStep { scale: 0.25, dwell_s: 4.0 },
            AmplitudeStep { scale: 1.0, dwell_s: 4.0 },
            AmplitudeStep { scale: 0.5, dwell_s: 4.0 },
        ],
        ..ExcitationPlan::two_tone(10.0, 20.0, 1000.0)
    };
    plan.validate(&paper()).expect("steps within limits");
    assert_eq!(plan.duration_s(), Some(12.0));
    assert_eq!(ExcitationPlan::two_tone(10.0, 20.0, 1.0).duration_s(), None);
    assert_eq!(plan.scale_at(-0.1), 0.0);
    assert_eq!(plan.scale_at(0.0), 0.0);
    assert!((plan.scale_at(0.5) - 0.125).abs() < 1e-12);
    assert_eq!(plan.scale_at(2.0), 0.25);
    assert_eq!(plan.scale_at(6.0), 1.0);
    assert_eq!(plan.scale_at(10.0), 0.5);
    assert!((plan.scale_at(11.5) - 0.25).abs() < 1e-12, "{}", plan.scale_at(11.5));
    assert_eq!(plan.scale_at(12.0), 0.0);
    assert_eq!(plan.force_at(12.5, &paper()), [0.0, 0.0]);
    // The scale moves smoothly: never a jump bigger than the raised cosine's steepest slope.
    let dt = 1e-3;
    let mut previous = 0.0;
    for j in 0..13_000 {
        let s = plan.scale_at(j as f64 * dt);
        assert!((s - previous).abs() <= PI / 2.0 * dt / plan.ramp_s * 1.0001 + 1e-15, "jump at {}", j as f64 * dt);
        assert!(s <= 1.0);
        previous = s;
    }
    assert_eq!(plan.peak_force_n(), [1000.0, 1000.0]);
}

#[test]
fn plans_round_trip_through_toml_and_unknown_keys_are_refused() {
    let plan = ExcitationPlan {
        exciters: [
            Waveform::Multisine { band_hz: [0.5, 79.5], period_s: 2.0, rms_n: 123.456, line_set: LineSet::Odd },
            Waveform::Chirp { start_hz: 1.0, end_hz: 80.0, sweep_s: 10.0, amplitude_n: 0.1 + 0.2 },
        ],
        ramp_s: 0.75,
        amplitude_steps: vec![AmplitudeStep { scale: 0.3, dwell_s: 5.0 }, AmplitudeStep { scale: 1.0, dwell_s: 7.5 }],
    };
    for plan in [
        plan,
        ExcitationPlan::paper_sine(33.3, 987.6),
        ExcitationPlan {
            exciters: [Waveform::Off, Waveform::Sine { frequency_hz: 1.0 / 3.0, amplitude_n: 1.0, phase_deg: -45.0 }],
            ramp_s: 0.0,
            amplitude_steps: vec![],
        },
    ] {
        let text = toml::to_string(&plan).expect("serialise");
        let back: ExcitationPlan = toml::from_str(&text).expect("parse back");
        assert_eq!(back, plan, "{text}");
    }

    let hand = r#"
        ramp_s = 1.0
        [[exciters]]
        kind = "sine"
        frequency_hz = 30.0
        amplitude_n = 100.0
        [[exciters]]
        kind = "multisine"
        band_hz = [1.0, 80.0]
        period_s = 1.0
        rms_n = 50.0
    "#;
    let plan: ExcitationPlan = toml::from_str(hand).expect("hand-written plan");
    assert_eq!(plan.exciters[0], Waveform::Sine { frequency_hz: 30.0, amplitude_n: 100.0, phase_deg: 0.0 });
    assert!(matches!(plan.exciters[1], Waveform::Multisine { line_set: LineSet::All, .. }));
    assert!(plan.amplitude_steps.is_empty());
    plan.validate(&paper()).expect("valid");

    let bad = [
        (hand.replace("ramp_s", "ramp_time_s"), "ramp_time_s"),
        (hand.replace("frequency_hz", "frequncy_hz"), "frequncy_hz"),
        (hand.replace("rms_n = 50.0", "rms_n = 50.0\ncrest = 1.5"), "crest"),
        (hand.replace("kind = \"sine\"", "kind = \"square\""), "square"),
        (hand.replace("period_s = 1.0", "period_s = 1.0\nline_set = \"prime\""), "prime"),
        (format!("{hand}\n[[amplitude_steps]]\nscale = 1.0\ndwell_s = 2.0\nrepeat = 3\n"), "repeat"),
    ];
    for (text, word) in bad {
        let err = toml::from_str::<ExcitationPlan>(&text).expect_err(&format!("must refuse `{word}`"));
        assert!(err.to_string().contains(word), "{err}");
    }
    let limits: Limits = toml::from_str("max_force_n = 1500.0\nband_hz = [0.0, 80.0]\n").expect("limits");
    assert_eq!(limits, paper());
    assert!(toml::from_str::<Limits>("max_force_n = 1500.0\nband_hz = [0.0, 80.0]\nmin_force_n = 0.0\n").is_err());
}

#[test]
fn excessive_multisine_lengths_are_refused_not_attempted() {
    // The longest allowed multisine validates, and quickly.
    let period_s = MAX_HARMONIC as f64 / 80.0;
    let longest = ExcitationPlan::multisine([0.0, 80.0], period_s, 400.0);
    let started = std::time::Instant::now();
    longest.validate(&paper()).expect("the longest multisine is allowed");
    let lines = longest.lines_hz();
    println!(
        "validated {} + {} lines in {:?}; crest factors {:.3}, {:.3}",
        lines[0].len(),
        lines[1].len(),
        started.elapsed(),
        longest.exciters[0].crest_factor(),
        longest.exciters[1].crest_factor()
    );
    assert_eq!(lines[0].len() + lines[1].len(), MAX_HARMONIC as usize);
    let started = std::time::Instant::now();
    let mut sum = 0.0;
    for j in 0..1000 {
        sum += longest.force_at(2.0 + j as f64 * 2e-4, &paper())[0];
    }
    println!("force_at with {} lines: {:?} per call ({sum:.1})", lines[0].len(), started.elapsed() / 1000);

    let f_max = 80.0;
    let period_s = (MAX_HARMONIC as f64 + 1.0) / f_max;
    let w = Waveform::Multisine { band_hz: [1.0, f_max], period_s, rms_n: 1.0, line_set: LineSet::All };
    assert!(w.lines_hz().is_empty());
    assert!(w.peak_force_n().is_nan());
    let plan = ExcitationPlan { exciters: [w, Waveform::Off], ramp_s: 0.0, amplitude_steps: vec![] };
    assert!(plan.validate(&paper()).is_err());
    assert_eq!(plan.force_at(1.0, &paper()), [0.0, 0.0]);
}
