//! The exciter never steps its force (issue 24): every transition (start, plan change,
//! amplitude change, stop, restart, shutdown, lost and returning subscriber, and transitions
//! in the middle of others) is a ramp, and no two consecutive setpoints differ by more than
//! the rig file's slew limit over the setpoint period. Checked on the setpoints as the rig's
//! exciter driver applies them: a later command replaces the future of earlier ones from its
//! first setpoint on (as the DAQ node's `Setpoints` does).

use std::f64::consts::PI;

use oilfilm_graph::exciter::{Exciter, ExciterCore, ExciterParams, ExciterPorts, HardLimits, MIN_RAMP_S};
use oilfilm_graph::node::Node;
use oilfilm_graph::ports::{memory::Bus, Publish};
use oilfilm_graph::stamp::Stamp;
use oilfilm_graph::NodeError;
use oilfilm_identification::excitation::Limits;
use oilfilm_msgs::{ExciterCommand, Header, RigStatus};

const RATE: f64 = 5000.0;
const T0: Stamp = Stamp(1_700_000_000_000_000_000);
/// A rig whose exciters slew at most 0.5 MN/s: 100 N between two setpoints at 5 kHz (a
/// 1000 N sine at 37 Hz moves up to 46.5 N).
const HARD: HardLimits = HardLimits { force: Limits { max_force_n: 1500.0, band_hz: [0.0, 80.0] }, max_slew_n_per_s: 5.0e5 };
const MAX_STEP: f64 = 5.0e5 / RATE;

/// The setpoints as the exciter driver applies them, from setpoint 0 at `T0`.
#[derive(Default)]
struct Driver {
    f: Vec<[f64; 2]>,
    stops: usize,
    /// The last command said stop: its last setpoint holds until the next command.
    holding: bool,
}

impl Driver {
    fn take(&mut self, c: &ExciterCommand) {
        assert_eq!(c.setpoint_rate_hz, RATE);
        let first = ((Stamp::from_time(&c.header.stamp).0 - T0.0) as f64 * RATE * 1e-9).round() as usize;
        assert!(first <= self.f.len() || self.holding, "command {} leaves a gap: starts at {first}, known up to {}", c.sequence, self.f.len());
        let hold = self.f.last().copied().unwrap_or_default();
        self.f.resize(first, hold);
        self.holding = c.stop;
        self.f.extend(c.force_1_n.iter().zip(&c.force_2_n).map(|(a, b)| [*a, *b]));
        self.stops += usize::from(c.stop);
    }

    /// The largest change between consecutive setpoints in `range` (and where).
    fn largest_step(&self, range: std::ops::Range<usize>) -> (f64, usize) {
        let end = range.end.min(self.f.len());
        (range.start.max(1)..end).map(|k| ((0..2).map(|j| (self.f[k][j] - self.f[k - 1][j]).abs()).fold(0.0, f64::max), k)).fold((0.0, 0), |a, b| {
            if b.0 > a.0 {
                b
            } else {
                a
            }
        })
    }

    fn peak(&self, range: std::ops::Range<usize>) -> f64 {
        self.f[range.start..range.end.min(self.f.len())].iter().flat_map(|f| f.iter()).fold(0.0, |m: f64, v| m.max(v.abs()))
    }
}

/// Feeds the rig clock from setpoint `from` for `seconds`, 0.1 s a status.
fn clock(core: &mut ExciterCore, d: &mut Driver, from: usize, seconds: f64) -> usize {
    let steps = (seconds * 10.0).round() as usize;
    for s in 0..=steps {
        let k = from + s * (RATE as usize / 10);
        if let Some(c) = core.on_rig_time(T0.after_samples(k as i64, RATE)) {
            d.take(&c);
        }
    }
    from + steps * (RATE as usize / 10)
}

fn two_tone(f1: f64, f2: f64, amplitude: f64, ramp_s: f64) -> ExciterCommand {
    let mut r = ExciterCommand { ramp_s, amplitude_scale: 1.0, ..Default::default() };
    r.waveform = [ExciterCommand::WAVEFORM_SINE; 2];
    r.frequency_hz = [f1, f2];
    r.amplitude_n = [amplitude; 2];
    r
}

fn stop() -> ExciterCommand {
    ExciterCommand { stop: true, ..Default::default() }
}

/// The most a shaped ramp of `ramp_s` adds to a setpoint change, on top of the waveform's
/// own: `pi A / (2 n)` for a raised cosine over `n` setpoints.
fn ramp_step(amplitude: f64, ramp_s: f64) -> f64 {
    PI * amplitude / (2.0 * ramp_s.max(MIN_RAMP_S) * RATE)
}

/// A sine's largest change between setpoints.
fn sine_step(frequency_hz: f64, amplitude: f64) -> f64 {
    2.0 * PI * frequency_hz * amplitude / RATE
}

fn core(params: ExciterParams) -> ExciterCore {
    ExciterCore::new(HARD, &ExciterParams { setpoint_rate_hz: RATE, ..params }).unwrap()
}

fn running_1000_n() -> (ExciterCore, Driver, usize) {
    let mut c = core(ExciterParams { amplitude_n: 1000.0, ramp_s: 0.5, ..Default::default() });
    let mut d = Driver::default();
    let k = clock(&mut c, &mut d, 0, 3.0);
    (c, d, k)
}

#[test]
fn start_ramps_up_from_rest() {
    let (_, d, _) = running_1000_n();
    assert_eq!(d.f[0], [0.0, 0.0], "the first setpoint is at rest");
    let (step, at) = d.largest_step(0..d.f.len());
    let bound = sine_step(37.0, 1000.0) + ramp_step(1000.0, 0.5);
    println!("start: largest step {step:.2} N at setpoint {at} (bound {bound:.2}, slew {MAX_STEP})");
    assert!(step <= bound && step <= MAX_STEP, "start steps by {step} N at {at}");
    assert!(d.peak(2500..15_000) > 990.0, "the full amplitude is reached after the ramp");
}

#[test]
fn a_plan_change_ramps_down_then_up_never_a_step() {
    // The case: a running 1000 N two-tone switched to another plan with ramp_s 0.5.
    let (mut c, mut d, k) = running_1000_n();
    let from = d.f.len();
    c.request(&two_tone(31.0, 47.0, 600.0, 0.5)).unwrap();
    clock(&mut c, &mut d, k, 3.0);
    let (step, at) = d.largest_step(from - 1..d.f.len());
    let bound = sine_step(37.0, 1000.0) + ramp_step(1000.0, 0.5);
    println!("plan change: largest step {step:.2} N at setpoint {at} (bound {bound:.2}, slew {MAX_STEP})");
    assert!(step <= bound && step <= MAX_STEP, "plan change steps by {step} N at {at}");
    // Down through zero before the new plan: the old ramped out over 0.5 s (2500 setpoints).
    assert!(d.peak(from + 2499..from + 2502) < 1e-3, "zero between the plans: {:?}", &d.f[from + 2499..from + 2502]);
    assert!(d.peak(from + 5100..d.f.len()) > 590.0, "the new plan at full amplitude after its ramp");
}

#[test]
fn an_amplitude_change_cross_fades_and_keeps_the_phase() {
    let (mut c, mut d, k) = running_1000_n();
    let from = d.f.len();
    c.request(&two_tone(23.0, 37.0, 300.0, 0.5)).unwrap();
    clock(&mut c, &mut d, k, 2.0);
    let (step, at) = d.largest_step(from - 1..d.f.len());
    assert!(step <= sine_step(37.0, 1000.0) + ramp_step(700.0, 0.5) && step <= MAX_STEP, "amplitude change steps by {step} N at {at}");
    // After the cross-fade the force is the 300 N plan on the first plan's clock: the phase
    // ran on (a restarted plan would be at phase 0 at `from`).
    for k in from + 2600..from + 2700 {
        let t = k as f64 / RATE;
        let want = [300.0 * (2.0 * PI * (23.0 * t).fract()).sin(), 300.0 * (2.0 * PI * (37.0 * t).fract()).sin()];
        assert!((d.f[k][0] - want[0]).abs() < 1e-9 && (d.f[k][1] - want[1]).abs() < 1e-9, "setpoint {k}: {:?} vs {want:?}", d.f[k]);
    }
    // Through the parameters: the same cross-fade.
    let mut p = ExciterParams { amplitude_n: 1000.0, ramp_s: 0.5, setpoint_rate_hz: RATE, ..Default::default() };
    let mut c = core(p.clone());
    let mut d = Driver::default();
    let k = clock(&mut c, &mut d, 0, 2.0);
    p.amplitude_n = 150.0;
    c.set_params(&p).unwrap();
    clock(&mut c, &mut d, k, 2.0);
    let (step, at) = d.largest_step(0..d.f.len());
    assert!(step <= sine_step(37.0, 1000.0) + ramp_step(1000.0, 0.5), "amplitude_n set: step {step} N at {at}");
    assert!((d.peak(d.f.len() - 5000..d.f.len()) - 150.0).abs() < 1.0);
}

#[test]
fn stop_ramps_to_zero_and_holds_then_a_request_starts_again() {
    let (mut c, mut d, k) = running_1000_n();
    let from = d.f.len();
    c.request(&stop()).unwrap();
    let k = clock(&mut c, &mut d, k, 2.0);
    let (step, at) = d.largest_step(from - 1..d.f.len());
    assert!(step <= sine_step(37.0, 1000.0) + ramp_step(1000.0, 0.5) && step <= MAX_STEP, "stop steps by {step} N at {at}");
    assert!(d.peak(from + 2500..d.f.len()) == 0.0, "zero held after the ramp");
    assert!(d.stops > 0, "commands say stop");
    // A new plan from rest: its own ramp.
    let again = d.f.len();
    c.request(&two_tone(23.0, 37.0, 800.0, 0.3)).unwrap();
    clock(&mut c, &mut d, k, 2.0);
    let (step, at) = d.largest_step(again - 1..d.f.len());
    assert!(step <= sine_step(37.0, 800.0) + ramp_step(800.0, 0.3), "restart steps by {step} N at {at}");
    assert!(d.peak(d.f.len() - 2000..d.f.len()) > 790.0);
}

#[test]
fn shutdown_is_one_command_down_to_zero() {
    let (mut c, mut d, _) = running_1000_n();
    let from = d.f.len();
    let last = c.shutdown().expect("a final command");
    assert!(last.stop && *last.force_1_n.last().unwrap() == 0.0 && *last.force_2_n.last().unwrap() == 0.0);
    d.take(&last);
    let (step, at) = d.largest_step(from - 1..d.f.len());
    assert!(step <= sine_step(37.0, 1000.0) + ramp_step(1000.0, 0.5) && step <= MAX_STEP, "shutdown steps by {step} N at {at}");
}

#[test]
fn a_lost_subscriber_ramps_down_and_a_returning_one_starts_from_zero() {
    let (mut c, mut d, k) = running_1000_n();
    let from = d.f.len();
    let down = c.subscriber_lost().expect("the ramp down");
    assert!(down.stop);
    d.take(&down);
    assert_eq!(*d.f.last().unwrap(), [0.0, 0.0]);
    assert!(c.subscriber_lost().is_none(), "lost once");
    // While nobody listens the rig clock may run on; the plan starts again at the rig's
    // time once a subscriber is back, from zero.
    let k = clock(&mut c, &mut d, k, 1.0);
    c.subscriber_back();
    let back = d.f.len();
    clock(&mut c, &mut d, k + 20_000, 2.0);
    let (step, at) = d.largest_step(from - 1..d.f.len());
    println!("lost and back: largest step {step:.2} N at {at}; restarted at setpoint {back}..");
    assert!(step <= sine_step(37.0, 1000.0) + ramp_step(1000.0, 0.5) && step <= MAX_STEP, "lost/back steps by {step} N at {at}");
    assert!(d.peak(d.f.len() - 1000..d.f.len()) > 990.0, "running again");
}

#[test]
fn transitions_inside_transitions_and_zero_ramps_stay_within_the_slew_limit() {
    let (mut c, mut d, k) = running_1000_n();
    // A change during a cross-fade, a stop during the ramp down, a start during the stop,
    // each 0.1 s after the last, with ramp_s 0 (the shortest transition, MIN_RAMP_S).
    c.request(&two_tone(23.0, 37.0, 500.0, 0.0)).unwrap();
    let k = clock(&mut c, &mut d, k, 0.1);
    c.request(&two_tone(29.0, 41.0, 1000.0, 0.0)).unwrap();
    let k = clock(&mut c, &mut d, k, 0.1);
    c.request(&stop()).unwrap();
    let k = clock(&mut c, &mut d, k, 0.02);
    c.request(&two_tone(17.0, 53.0, 1200.0, 0.0)).unwrap();
    clock(&mut c, &mut d, k, 1.0);
    let (step, at) = d.largest_step(0..d.f.len());
    println!("nested: largest step {step:.2} N at {at}");
    assert!(step <= MAX_STEP + 1e-9, "step {step} N at {at}");
}

#[test]
fn a_waveform_that_starts_at_full_force_is_slewed_at_the_rig_limit() {
    // A sine at 90 deg with no ramp would start at 1000 N: the slew limiter takes it there
    // at exactly the rig file's limit, and from then on it is the waveform itself.
    let mut r = two_tone(23.0, 37.0, 1000.0, 0.0);
    r.phase_rad = [PI / 2.0; 2];
    let mut c = core(ExciterParams { plan: "off".into(), ..Default::default() });
    let mut d = Driver::default();
    c.request(&r).unwrap();
    clock(&mut c, &mut d, 0, 0.5);
    let (step, _) = d.largest_step(0..d.f.len());
    assert!((step - MAX_STEP).abs() < 1e-9, "the limiter moves at its limit: {step}");
    let caught = (1..200).find(|&k| d.f[k][0] > 0.0 && (d.f[k][0] - d.f[k - 1][0]).abs() < MAX_STEP - 1e-9).expect("catches the waveform");
    assert!(caught <= 11, "1000 N at 100 N a setpoint: ~10 setpoints, got {caught}");
}

#[test]
fn plans_steeper_than_the_slew_limit_are_refused_with_the_reason() {
    // 1400 N at 79 Hz rises at 0.69 MN/s: inside the force and band limits, beyond 0.5 MN/s.
    let mut c = core(ExciterParams::default());
    let e = c.request(&two_tone(79.0, 23.0, 1400.0, 0.5)).unwrap_err().to_string();
    assert!(e.contains("slew limit") && e.contains("exciter_max_slew_n_per_s"), "{e}");
    let p = ExciterParams { frequency_2_hz: 79.0, amplitude_n: 1400.0, setpoint_rate_hz: RATE, ..Default::default() };
    let e = c.set_params(&p).unwrap_err().to_string();
    assert!(e.contains("plan") && e.contains("slew limit"), "{e}");
    assert!(ExciterCore::new(HARD, &p).is_err());
    // A multisine whose lines' slopes sum beyond the limit but whose signal does not rise
    // that fast is accepted (its steepest rise is computed, not bounded).
    let mut m = ExciterCommand { ramp_s: 0.5, amplitude_scale: 1.0, ..Default::default() };
    m.waveform = [ExciterCommand::WAVEFORM_MULTISINE; 2];
    m.band_low_hz = [5.0; 2];
    m.band_high_hz = [80.0; 2];
    m.period_s = [1.0; 2];
    m.rms_n = [350.0; 2];
    m.line_set = [ExciterCommand::LINES_ODD, ExciterCommand::LINES_EVEN];
    c.request(&m).unwrap();
}

#[test]
fn random_transitions_never_exceed_the_slew_limit() {
    let mut c = core(ExciterParams { amplitude_n: 1000.0, ..Default::default() });
    let mut d = Driver::default();
    let mut k = 0;
    let mut x: u64 = 0x2545_F491_4F6C_DD1D;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let mut lost = false;
    for _ in 0..300 {
        match next() % 6 {
            0 => c.request(&stop()).unwrap(),
            1 => c.request(&two_tone(10.0 + (next() % 60) as f64, 20.0 + (next() % 50) as f64, (next() % 1000) as f64, (next() % 8) as f64 * 0.1)).unwrap(),
            2 => c.request(&two_tone(23.0, 37.0, (next() % 1000) as f64, (next() % 8) as f64 * 0.1)).unwrap(),
            3 if !lost => {
                if let Some(cmd) = c.subscriber_lost() {
                    d.take(&cmd);
                }
                lost = true;
            }
            4 if lost => {
                c.subscriber_back();
                lost = false;
            }
            _ => {}
        }
        k = clock(&mut c, &mut d, k, (next() % 7) as f64 * 0.1);
    }
    if let Some(cmd) = c.shutdown() {
        d.take(&cmd);
    }
    let (step, at) = d.largest_step(0..d.f.len());
    println!("300 random transitions over {} setpoints: largest step {step:.2} N at {at}", d.f.len());
    assert!(step <= MAX_STEP + 1e-9, "step {step} N at {at}");
    assert!(d.peak(0..d.f.len()) <= 1500.0);
    assert_eq!(*d.f.last().unwrap(), [0.0, 0.0], "shutdown ends at zero");
}

/// A commands port whose subscriber count the test sets, and which logs what the node did
/// with it: "command", "stop" (a command with `stop` set) and "flush".
struct Commands {
    bus: oilfilm_graph::ports::memory::Publisher<ExciterCommand>,
    readers: std::rc::Rc<std::cell::Cell<usize>>,
    log: std::rc::Rc<std::cell::RefCell<Vec<&'static str>>>,
}

impl Publish<ExciterCommand> for Commands {
    fn publish(&mut self, m: ExciterCommand) -> Result<(), NodeError> {
        self.log.borrow_mut().push(if m.stop { "stop" } else { "command" });
        self.bus.publish(m)
    }
    fn readers(&mut self) -> Option<usize> {
        Some(self.readers.get())
    }
    fn flush(&mut self, _timeout: std::time::Duration) -> Result<bool, NodeError> {
        self.log.borrow_mut().push("flush");
        Ok(true)
    }
}

#[test]
fn the_node_ramps_down_when_its_last_subscriber_goes_and_restarts_when_one_is_back() {
    let rig = oilfilm_physics::config::RigConfig::zhou2004().unwrap();
    let load = |_: &str| Ok(rig.clone());
    let params = ExciterParams { amplitude_n: 500.0, ..Default::default() };
    let mut node = Exciter::new(&params, &oilfilm_graph::node::Start { now: T0, rig: &load, namespace: "/oilfilm" }).unwrap();
    let (requests, status, commands) = (Bus::<ExciterCommand>::new(), Bus::<RigStatus>::new(), Bus::<ExciterCommand>::new());
    let readers = std::rc::Rc::new(std::cell::Cell::new(1));
    let log = std::rc::Rc::new(std::cell::RefCell::new(Vec::new()));
    let mut out = commands.subscriber();
    let mut ports = ExciterPorts {
        requests: Box::new(requests.subscriber()),
        status: Box::new(status.subscriber()),
        commands: Box::new(Commands { bus: commands.publisher(), readers: readers.clone(), log: log.clone() }),
    };
    let mut rig_clock = status.publisher();
    let mut d = Driver::default();
    let mut tick = |node: &mut Exciter, ports: &mut ExciterPorts, k: i64| {
        rig_clock.publish(RigStatus { header: Header { stamp: T0.after_samples(k, RATE).to_time(), ..Default::default() }, ..Default::default() }).unwrap();
        node.turn(T0, ports).unwrap();
    };
    for k in 0..20 {
        tick(&mut node, &mut ports, k * 500);
    }
    readers.set(0);
    tick(&mut node, &mut ports, 20 * 500);
    assert!(node.core().is_waiting_for_subscriber());
    readers.set(2);
    for k in 21..40 {
        tick(&mut node, &mut ports, k * 500);
    }
    node.finish(T0, &mut ports).unwrap();
    // Its last act: the ramp to zero, then the wait for every subscriber to have it.
    assert_eq!(log.borrow().iter().rev().take(2).rev().copied().collect::<Vec<_>>(), ["stop", "flush"]);
    assert_eq!(log.borrow().iter().filter(|e| **e == "flush").count(), 1, "no wait while running: {:?}", log.borrow());
    let cmds = out.drain();
    for c in &cmds {
        d.take(c);
    }
    assert!(cmds.iter().any(|c| c.stop) && !cmds.last().unwrap().force_1_n.is_empty());
    let (step, at) = d.largest_step(0..d.f.len());
    assert!(step <= sine_step(37.0, 500.0) + ramp_step(500.0, 0.5), "step {step} N at {at}");
    assert!(d.peak(15_000..17_000) > 490.0, "running again after the subscriber came back");
    assert_eq!(*d.f.last().unwrap(), [0.0, 0.0]);
}
