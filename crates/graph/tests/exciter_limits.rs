//! The exciter never publishes a setpoint beyond its limits, whatever request or parameter
//! it is given: hostile requests (NaN, infinities, huge amplitudes, bad enums, negative
//! periods, out-of-band lines), random ones, and parameter sets that try to raise the limit.

use oilfilm_graph::exciter::{ExciterCore, ExciterParams, HardLimits};
use oilfilm_graph::stamp::Stamp;
use oilfilm_identification::excitation::Limits;
use oilfilm_msgs::ExciterCommand;

const HARD: HardLimits = HardLimits { force: Limits { max_force_n: 1500.0, band_hz: [0.0, 80.0] }, max_slew_n_per_s: 1.0e6 };

/// Every setpoint the core publishes over `seconds` of rig time, in 0.1 s status steps.
fn run(core: &mut ExciterCore, from: Stamp, seconds: f64) -> Vec<ExciterCommand> {
    let mut out = Vec::new();
    let steps = (seconds * 10.0) as i64;
    for k in 0..=steps {
        if let Some(c) = core.on_rig_time(Stamp(from.0 + k * 100_000_000)) {
            out.push(c);
        }
    }
    out
}

fn assert_within(cmds: &[ExciterCommand], limit: f64, what: &str) {
    let mut n = 0;
    for c in cmds {
        assert_eq!(c.force_1_n.len(), c.force_2_n.len(), "{what}");
        assert!(c.max_force_n <= limit, "{what}: reported limit {} above {limit}", c.max_force_n);
        for f in c.force_1_n.iter().chain(&c.force_2_n) {
            n += 1;
            assert!(f.is_finite() && f.abs() <= limit, "{what}: setpoint {f} beyond {limit} N");
        }
    }
    assert!(n > 0, "{what}: no setpoints at all");
}

struct Xorshift(u64);
impl Xorshift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    /// A plausible value near or at the limits (a request a user might really send).
    fn plausible(&mut self, max: f64) -> f64 {
        let u = (self.next() % 10_001) as f64 / 10_000.0;
        u * max
    }

    /// A hostile f64: ordinary, huge, tiny, negative, NaN or infinite.
    fn value(&mut self) -> f64 {
        let pool = [
            0.0,
            -0.0,
            1.0,
            37.0,
            80.0,
            80.0001,
            1e3,
            1499.9,
            1500.0,
            1500.1,
            1e9,
            1e308,
            -1e308,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MIN_POSITIVE,
            -5.0,
            0.5,
            1e-12,
        ];
        let v = pool[(self.next() % pool.len() as u64) as usize];
        if self.next().is_multiple_of(3) {
            v * (self.next() % 1000) as f64 / 100.0
        } else {
            v
        }
    }
}

#[test]
fn hostile_requests_never_exceed_the_limit() {
    let mut core = ExciterCore::new(HARD, &ExciterParams::default()).unwrap();
    let t0 = Stamp(1_700_000_000_000_000_000);
    let mut all = run(&mut core, t0, 1.0);
    let mut rng = Xorshift(0x9E37_79B9_7F4A_7C15);
    let (mut accepted, mut rejected) = (0, 0);
    for i in 0..400 {
        let mut r = ExciterCommand { sequence: i, ..Default::default() };
        for j in 0..2 {
            r.waveform[j] = (rng.next() % 6) as u8;
            r.amplitude_n[j] = rng.value();
            r.frequency_hz[j] = rng.value();
            r.phase_rad[j] = rng.value();
            r.rms_n[j] = rng.value();
            r.period_s[j] = rng.value();
            r.band_low_hz[j] = rng.value();
            r.band_high_hz[j] = rng.value();
            r.line_set[j] = (rng.next() % 4) as u8;
            r.chirp_start_hz[j] = rng.value();
            r.chirp_end_hz[j] = rng.value();
            r.sweep_s[j] = rng.value();
        }
        r.ramp_s = rng.value();
        r.amplitude_scale = rng.value();
        if i % 2 == 0 {
            // Plausible: sines or multisines up to the exact limits (1500 N, 80 Hz).
            for j in 0..2 {
                r.waveform[j] = if rng.next().is_multiple_of(2) { ExciterCommand::WAVEFORM_SINE } else { ExciterCommand::WAVEFORM_MULTISINE };
                r.amplitude_n[j] = rng.plausible(1500.0);
                r.frequency_hz[j] = 1.0 + rng.plausible(79.0);
                r.rms_n[j] = rng.plausible(600.0);
                r.period_s[j] = 0.5 + rng.plausible(2.0);
                r.band_low_hz[j] = 1.0 + rng.plausible(20.0);
                r.band_high_hz[j] = 30.0 + rng.plausible(50.0);
                r.line_set[j] = (rng.next() % 3) as u8;
            }
            r.ramp_s = rng.plausible(1.0);
            r.amplitude_scale = rng.plausible(1.0);
        }
        // A request's own setpoints and limits are ignored, however large.
        r.force_1_n = vec![1e9; 3];
        r.max_force_n = 1e12;
        match core.request(&r) {
            Ok(()) => accepted += 1,
            Err(e) => {
                rejected += 1;
                assert!(e.to_string().contains("exciter/request"), "{e}");
            }
        }
        let from = Stamp(t0.0 + (i as i64 + 1) * 1_000_000_000);
        all.extend(run(&mut core, from, 0.3));
    }
    println!("hostile requests: {accepted} accepted, {rejected} rejected");
    assert!(rejected > 200, "the hostile half must be rejected");
    assert!(accepted > 50, "plausible requests up to the limits must be accepted");
    assert_within(&all, HARD.force.max_force_n, "hostile requests");

    // A legitimate request that hits the limit exactly is accepted and stays within it.
    let mut r = ExciterCommand { ramp_s: 0.0, amplitude_scale: 1.0, ..Default::default() };
    r.waveform = [ExciterCommand::WAVEFORM_SINE; 2];
    r.frequency_hz = [23.0, 37.0];
    r.amplitude_n = [1500.0, 1500.0];
    core.request(&r).unwrap();
    let cmds = run(&mut core, Stamp(t0.0 + 1_000_000_000_000), 1.0);
    assert_within(&cmds, 1500.0, "at the limit");
    let peak = cmds.iter().flat_map(|c| c.force_1_n.iter()).fold(0.0_f64, |m, f| m.max(f.abs()));
    assert!(peak > 1490.0, "the full amplitude is delivered ({peak})");
}

#[test]
fn parameters_can_lower_the_limit_never_raise_it() {
    let mut core = ExciterCore::new(HARD, &ExciterParams { amplitude_n: 400.0, ..Default::default() }).unwrap();
    let t0 = Stamp(0);
    for bad in [1500.1, 1e9, f64::INFINITY, f64::NAN, -1.0] {
        let p = ExciterParams { max_force_n: bad, ..Default::default() };
        let e = core.set_params(&p).unwrap_err().to_string();
        assert!(e.contains("max_force_n"), "{bad}: {e}");
        assert!(ExciterCore::new(HARD, &p).is_err(), "{bad} accepted at start");
    }
    // Lowered to 300 N: a 400 N plan is now outside the limit, refused with the reason...
    let p = ExciterParams { max_force_n: 300.0, amplitude_n: 400.0, ..Default::default() };
    assert!(core.set_params(&p).unwrap_err().to_string().contains("outside the limits"));
    // ...and a 250 N plan runs within 300 N.
    let p = ExciterParams { max_force_n: 300.0, amplitude_n: 250.0, ..Default::default() };
    core.set_params(&p).unwrap();
    assert_within(&run(&mut core, t0, 2.0), 300.0, "lowered limit");
    for (name, p) in [
        ("setpoint_rate_hz", ExciterParams { setpoint_rate_hz: f64::NAN, ..Default::default() }),
        ("lookahead_s", ExciterParams { lookahead_s: 1e9, ..Default::default() }),
        ("band_limit_low_hz", ExciterParams { band_limit_low_hz: 0.0, band_limit_high_hz: 1e6, ..Default::default() }),
        ("plan", ExciterParams { plan: "boom".into(), ..Default::default() }),
        ("plan", ExciterParams { frequency_2_hz: 120.0, ..Default::default() }),
    ] {
        let e = ExciterCore::new(HARD, &p).err().unwrap_or_else(|| panic!("{name} accepted")).to_string();
        assert!(e.contains(name), "{name}: {e}");
    }
}

#[test]
fn stop_ramps_to_zero_and_holds() {
    let mut core = ExciterCore::new(HARD, &ExciterParams { ramp_s: 0.2, ..Default::default() }).unwrap();
    let t0 = Stamp(0);
    run(&mut core, t0, 2.0);
    let last = core.shutdown().expect("a final command");
    assert!(last.stop);
    assert_eq!(*last.force_1_n.last().unwrap(), 0.0);
    assert_eq!(*last.force_2_n.last().unwrap(), 0.0);
    // The ramp never jumps: consecutive setpoints differ by less than the waveform's slope allows.
    let max_step = last.force_1_n.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max);
    assert!(max_step < 2.0 * std::f64::consts::PI * 37.0 * 100.0 / 5000.0 * 1.5, "step {max_step}");
    // After the stop, later rig times give zeros only.
    for c in run(&mut core, Stamp(3_000_000_000), 1.0) {
        assert!(c.force_1_n.iter().chain(&c.force_2_n).all(|f| *f == 0.0));
    }
}
