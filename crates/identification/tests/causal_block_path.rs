//! The causal chain's block path (`conditioning::causal`, ADR 0014, 0022) against the chain
//! run scan by scan through ring buffers, written plainly here from the public designs (the
//! de-skew stencils, the order-2N Butterworth, the Savitzky-Golay taps, eq. 2): the same bits
//! for every cutting of the input, with out-of-range readings in it, on every instruction
//! set this CPU has.

use oilfilm_identification::conditioning::causal::{CausalChain, CausalOutput};
use oilfilm_identification::conditioning::deskew::FractionalDelay;
use oilfilm_identification::conditioning::differentiate::SavitzkyGolayDerivative;
use oilfilm_identification::conditioning::lowpass::{Butterworth, Section};
use oilfilm_identification::conditioning::{ConditioningConfig, Mechanics, RangeViolation};
use oilfilm_identification::pipeline;
use oilfilm_identification::record::RawUnits;
use oilfilm_identification::simd::{self, Isa};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::{Calibration, ChannelId, CHANNEL_COUNT};

/// A ring of `N`-wide rows, indexed by an ever-growing counter.
struct Ring<const N: usize> {
    rows: Vec<[f64; N]>,
    mask: usize,
}

impl<const N: usize> Ring<N> {
    /// Holds at least the last `span` rows.
    fn new(span: usize) -> Self {
        let len = span.max(1).next_power_of_two();
        Self { rows: vec![[0.0; N]; len], mask: len - 1 }
    }

    fn at(&self, i: u64) -> &[f64; N] {
        &self.rows[(i as usize) & self.mask]
    }

    fn set(&mut self, i: u64, row: [f64; N]) {
        self.rows[(i as usize) & self.mask] = row;
    }
}

/// One channel's front end as the chain documents it.
#[derive(Clone)]
struct Front {
    channel: ChannelId,
    column: usize,
    offset_v: f64,
    sensitivity: f64,
    /// Readings inside `(lo, hi)` volts (the linear range less half an LSB) are in range.
    lo_v: f64,
    hi_v: f64,
    range_si: [f64; 2],
    start: isize,
    weights: Vec<f64>,
    last_good: f64,
}

/// Everything the chain is designed from, taken from the public designs.
#[derive(Clone)]
struct Design {
    units: RawUnits,
    width: usize,
    fronts: Vec<Front>,
    sections: Vec<Section>,
    sg: Vec<f64>,
    /// Eq. 2's applied part: `(c1 f1 + c2 f2, s1 f1 + s2 f2 + (f3 - m g))`.
    cs: [f64; 4],
    mg: f64,
    mass: f64,
    /// Stencils' reach ahead and back, `2 M`, the low-pass's settling.
    lookahead: usize,
    lookback: usize,
    settling: usize,
}

impl Design {
    fn of(columns: &[usize; CHANNEL_COUNT], width: usize, units: RawUnits, cal: &Calibration, mech: &Mechanics, config: &ConditioningConfig) -> Self {
        let fs = cal.sample_rate_hz();
        let fronts: Vec<Front> = ChannelId::ALL
            .iter()
            .map(|&ch| {
                let c = cal.channel(ch).unwrap();
                let (offset_v, sensitivity) = (c.offset_v, c.sensitivity_v_per_unit);
                let [a, b] = c.linear_range_v.map(|v| (v - offset_v) / sensitivity);
                let (start, weights) = if config.deskew {
                    let d = FractionalDelay::for_offset(cal.sample_offset_s(ch).unwrap(), fs, config.deskew_taps).unwrap();
                    (d.stencil_start(), d.weights().to_vec())
                } else {
                    (0, vec![1.0])
                };
                let margin = 0.5 * cal.lsb_v();
                Front {
                    channel: ch,
                    column: columns[ch.index()],
                    offset_v,
                    sensitivity,
                    lo_v: c.linear_range_v[0] + margin,
                    hi_v: c.linear_range_v[1] - margin,
                    range_si: [a.min(b), a.max(b)],
                    start,
                    weights,
                    // Mid-range, in the stream's units: what the filters see until the first
                    // in-range reading.
                    last_good: match units {
                        RawUnits::Volts => 0.5 * (c.linear_range_v[0] + c.linear_range_v[1]),
                        RawUnits::Si => 0.5 * (a + b),
                    },
                }
            })
            .collect();
        let lp = Butterworth::design(2 * config.lowpass_order, config.lowpass_cutoff_hz, fs).unwrap();
        let sg = SavitzkyGolayDerivative::new(config.differentiator_half_length, fs).unwrap();
        let [a1, a2] = mech.exciter_angles_deg.map(f64::to_radians);
        let lookahead = fronts.iter().map(|f| f.start + f.weights.len() as isize - 1).max().unwrap().max(0) as usize;
        let lookback = fronts.iter().map(|f| -f.start).max().unwrap().max(0) as usize;
        Self {
            units,
            width,
            fronts,
            sections: lp.sections().to_vec(),
            sg: sg.coefficients().to_vec(),
            cs: [a1.cos(), a2.cos(), a1.sin(), a2.sin()],
            mg: mech.housing_mass_kg * mech.gravity_m_s2,
            mass: mech.housing_mass_kg,
            lookahead,
            lookback,
            settling: lp.settling_samples(),
        }
    }
}

/// The chain scan by scan: its design, the low-pass's state per section (`x[n-1]`, `y[n-1]`,
/// `q[n]` of six lanes), the counters and the rings.
struct ScanByScan {
    d: Design,
    iir: Vec<[[f64; 6]; 3]>,
    scans: u64,
    lowpassed: u64,
    invalid_through: Option<u64>,
    raw: Ring<CHANNEL_COUNT>,
    filtered: Ring<8>,
    velocity: Ring<4>,
}

impl ScanByScan {
    fn new(d: Design) -> Self {
        let m = d.sg.len();
        Self {
            iir: vec![[[0.0; 6]; 3]; d.sections.len()],
            scans: 0,
            lowpassed: 0,
            invalid_through: None,
            raw: Ring::new(d.lookahead + d.lookback + 1),
            filtered: Ring::new(4 * m + 1),
            velocity: Ring::new(2 * m + 1),
            d,
        }
    }

    fn push(&mut self, values: &[f64], out: &mut CausalOutput) {
        for row in values.chunks_exact(self.d.width) {
            self.push_scan(row, out);
        }
    }

    /// One sample of six lanes through the sections; `first` starts each in the DC steady
    /// state of its first input. `y = (b0 x + q) - a1 y[n-1]`, `q = (b1 x + b2 x[n-1]) -
    /// a2 y[n-1]`.
    fn lowpass(&mut self, mut x: [f64; 6], first: bool) -> [f64; 6] {
        for (s, [x1, y1, q]) in self.d.sections.iter().zip(self.iir.iter_mut()) {
            let ([b0, b1, b2], [a1, a2]) = (s.b, s.a);
            if first {
                let g = (b0 + b1 + b2) / (1.0 + a1 + a2);
                *x1 = x;
                *y1 = x.map(|v| g * v);
                *q = std::array::from_fn(|l| b1 * x[l] + b2 * x[l] - a2 * y1[l]);
            }
            for l in 0..6 {
                let y = (b0 * x[l] + q[l]) - a1 * y1[l];
                q[l] = b1 * x[l] + b2 * x1[l] - a2 * y1[l];
                (x1[l], y1[l], x[l]) = (x[l], y, y);
            }
        }
        x
    }

    fn push_scan(&mut self, row: &[f64], out: &mut CausalOutput) {
        let n = self.scans;
        self.scans += 1;
        let (m2, reach) = (2 * self.d.sg.len(), (self.d.lookback + self.d.settling + 2 * self.d.sg.len()) as u64);
        // Range check; an out-of-range reading holds the last good reading.
        let mut held = [0.0; CHANNEL_COUNT];
        for (k, f) in self.d.fronts.iter_mut().enumerate() {
            let r = row[f.column];
            let (volts, value) = match self.d.units {
                RawUnits::Volts => (r, (r - f.offset_v) * (1.0 / f.sensitivity)),
                RawUnits::Si => (f.offset_v + f.sensitivity * r, r),
            };
            if volts > f.lo_v && volts < f.hi_v && value.is_finite() {
                f.last_good = r;
            } else {
                self.invalid_through = Some(self.invalid_through.map_or(n + reach, |t| t.max(n + reach)));
                match out.violations.iter_mut().rev().find(|v| v.channel == f.channel) {
                    Some(v) if v.index as u64 + v.count as u64 == n => v.count += 1,
                    _ => out.violations.push(RangeViolation { channel: f.channel, index: n as usize, value_si: value, range_si: f.range_si, count: 1 }),
                }
            }
            held[k] = f.last_good;
        }
        self.raw.set(n, held);
        if n < (self.d.lookahead + self.d.lookback) as u64 {
            return;
        }
        // Calibration and de-skew: time index m = n - L.
        let m = n - self.d.lookahead as u64;
        let mut s = [0.0; CHANNEL_COUNT];
        for (k, f) in self.d.fronts.iter().enumerate() {
            let si = |i: i64| match self.d.units {
                RawUnits::Volts => (self.raw.at(i as u64)[k] - f.offset_v) * (1.0 / f.sensitivity),
                RawUnits::Si => self.raw.at(i as u64)[k],
            };
            let base = m as i64 + f.start as i64;
            let mut acc = f.weights[0] * si(base);
            for (j, &w) in f.weights.iter().enumerate().skip(1) {
                acc += w * si(base + j as i64);
            }
            s[k] = acc;
        }
        let [a_x, a_y, b_x, b_y, frame_x, frame_y, f1, f2, f3, temperature] = s;
        let [c1, c2, s1, s2] = self.d.cs;
        let (fx, fy) = (c1 * f1 + c2 * f2, s1 * f1 + s2 * f2 + (f3 - self.d.mg));
        let p = self.lowpassed;
        self.lowpassed += 1;
        let y = self.lowpass([0.5 * (a_x + b_x), 0.5 * (a_y + b_y), frame_x, frame_y, fx, fy], p == 0);
        self.filtered.set(p, [y[0], y[1], y[2], y[3], y[4], y[5], f3, temperature]);
        // Velocity at p - M, acceleration (and every output) at p - 2M.
        let sg = self.d.sg.clone();
        let mh = sg.len() as u64;
        if p < 2 * mh {
            return;
        }
        let derivative = |at: &dyn Fn(u64) -> [f64; 4], i: u64| -> [f64; 4] {
            std::array::from_fn(|l| {
                let mut acc = sg[0] * (at(i + 1)[l] - at(i - 1)[l]);
                for (k, &c) in sg.iter().enumerate().skip(1) {
                    acc += c * (at(i + k as u64 + 1)[l] - at(i - k as u64 - 1)[l]);
                }
                acc
            })
        };
        let q = p - mh;
        let v = derivative(
            &|i| {
                let f = self.filtered.at(i);
                [f[0], f[1], f[2], f[3]]
            },
            q,
        );
        self.velocity.set(q, v);
        // Time index of the low-passed sample `r`: the first de-skewed one is `lookback`.
        let r = p - 2 * mh;
        let time = r + self.d.lookback as u64;
        if r < (self.d.settling + m2) as u64 {
            return;
        }
        let a = derivative(&|i| *self.velocity.at(i), r);
        let here = *self.filtered.at(r);
        let vel = *self.velocity.at(r);
        if out.is_empty() {
            out.first_index = time;
        }
        let (fx, fy) = (here[4] - self.d.mass * a[2], here[5] - self.d.mass * a[3]);
        for (col, v) in [
            (&mut out.x_m, here[0]),
            (&mut out.y_m, here[1]),
            (&mut out.vx_m_s, vel[0]),
            (&mut out.vy_m_s, vel[1]),
            (&mut out.ax_m_s2, a[0]),
            (&mut out.ay_m_s2, a[1]),
            (&mut out.fx_n, fx),
            (&mut out.fy_n, fy),
            (&mut out.static_load_n, here[6]),
            (&mut out.temperature_c, here[7]),
        ] {
            col.push(v);
        }
        let finite = [here[0], here[1], vel[0], vel[1], a[0], a[1], fx, fy].iter().all(|v| v.is_finite());
        out.valid.push(finite && self.invalid_through.is_none_or(|t| time > t));
    }
}

/// Where two outputs first differ in any bit, or `None`.
fn first_difference(a: &CausalOutput, b: &CausalOutput) -> Option<String> {
    if a.first_index != b.first_index {
        return Some(format!("first_index {} against {}", a.first_index, b.first_index));
    }
    let columns = |o: &CausalOutput| {
        [&o.x_m, &o.y_m, &o.vx_m_s, &o.vy_m_s, &o.ax_m_s2, &o.ay_m_s2, &o.fx_n, &o.fy_n, &o.temperature_c, &o.static_load_n].map(|c| c.clone())
    };
    let names = ["x_m", "y_m", "vx_m_s", "vy_m_s", "ax_m_s2", "ay_m_s2", "fx_n", "fy_n", "temperature_c", "static_load_n"];
    for ((name, x), y) in names.iter().zip(columns(a)).zip(columns(b)) {
        if x.len() != y.len() {
            return Some(format!("{name}: {} samples against {}", x.len(), y.len()));
        }
        if let Some(i) = x.iter().zip(&y).position(|(p, q)| p.to_bits() != q.to_bits()) {
            return Some(format!("{name}[{i}]: {:e} against {:e}", x[i], y[i]));
        }
    }
    if a.valid != b.valid {
        return Some(format!("valid differs first at {:?}", a.valid.iter().zip(&b.valid).position(|(p, q)| p != q)));
    }
    let key = |v: &RangeViolation| (v.channel, v.index, v.count, v.value_si.to_bits(), v.range_si.map(f64::to_bits));
    if a.violations.iter().map(key).ne(b.violations.iter().map(key)) {
        return Some(format!("violations {:?} against {:?}", a.violations, b.violations));
    }
    None
}

/// xorshift64: deterministic noise without a dependency.
struct Noise(u64);

impl Noise {
    /// Uniform in `[0, 1)`.
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Scans of the rig's channels (scan order, then `extra` unused columns) moving inside
/// their linear ranges, with out-of-range, NaN and infinite readings put in: at the
/// very start, single ones, two channels at once, and a 40-scan run.
fn record(cal: &Calibration, units: RawUnits, scans: usize, extra: usize, seed: u64) -> (Vec<f64>, [usize; CHANNEL_COUNT], usize) {
    let order = cal.scan_order();
    let width = order.len() + extra;
    let mut columns = [0; CHANNEL_COUNT];
    for (k, c) in order.iter().enumerate() {
        columns[c.index()] = k;
    }
    let mut noise = Noise(seed);
    let fs = cal.sample_rate_hz();
    let mut values = vec![0.0; scans * width];
    for (k, &ch) in order.iter().enumerate() {
        let c = cal.channel(ch).unwrap();
        let [lo, hi] = c.linear_range_v;
        let (mid, amp) = (0.5 * (lo + hi), 0.25 * (hi - lo));
        let (f1, f2) = (17.0 + 3.0 * k as f64, 41.0 + 5.0 * k as f64);
        for i in 0..scans {
            let t = i as f64 / fs;
            let v = mid
                + amp * (0.6 * (std::f64::consts::TAU * f1 * t).sin() + 0.3 * (std::f64::consts::TAU * f2 * t + 0.4).cos() + 0.1 * (2.0 * noise.next() - 1.0));
            values[i * width + k] = v;
        }
    }
    for i in 0..scans {
        for k in order.len()..width {
            values[i * width + k] = 1e300 * noise.next();
        }
    }
    let at = |scan: usize, ch: ChannelId| scan * width + columns[ch.index()];
    let high = |ch: ChannelId| cal.channel(ch).unwrap().linear_range_v[1] + 1.0;
    let mut bad = vec![
        (0, ChannelId::F1, high(ChannelId::F1)),
        (scans / 5, ChannelId::ProbeAX, f64::NAN),
        (scans / 3, ChannelId::F3, f64::INFINITY),
        (scans / 3, ChannelId::ProbeBY, -1e9),
    ];
    bad.extend((0..40).map(|i| (scans / 2 + i, ChannelId::FrameY, high(ChannelId::FrameY))));
    bad.push((scans - 30, ChannelId::Temperature, f64::NEG_INFINITY));
    for (scan, ch, v) in bad {
        values[at(scan, ch)] = v;
    }
    if units == RawUnits::Si {
        for (k, &ch) in order.iter().enumerate() {
            let c = cal.channel(ch).unwrap();
            for i in 0..scans {
                let v = &mut values[i * width + k];
                *v = (*v - c.offset_v) / c.sensitivity_v_per_unit;
            }
        }
    }
    (values, columns, width)
}

/// Block sizes (scans) for one cutting of `scans`: `fixed` if given, else varied.
fn cutting(scans: usize, fixed: Option<usize>, noise: &mut Noise) -> Vec<usize> {
    let mut sizes = Vec::new();
    let mut left = scans;
    while left > 0 {
        let s = fixed.unwrap_or_else(|| 1 + (noise.next() * 700.0) as usize).min(left);
        sizes.push(s);
        left -= s;
    }
    sizes
}

/// A chain on `isa` fed `values` in blocks of `sizes` scans.
#[allow(clippy::too_many_arguments)] // the chain's design and the input, as the test varies them
fn run_blocks(
    isa: Isa,
    columns: &[usize; CHANNEL_COUNT],
    width: usize,
    units: RawUnits,
    cal: &Calibration,
    mech: &Mechanics,
    config: &ConditioningConfig,
    values: &[f64],
    sizes: &[usize],
) -> CausalOutput {
    simd::with_isa(isa, || {
        let mut chain = CausalChain::new(columns, width, units, cal.sample_rate_hz(), cal, mech, config).unwrap();
        let mut out = CausalOutput::default();
        let mut at = 0;
        for &s in sizes {
            chain.push(&values[at * width..(at + s) * width], &mut out).unwrap();
            at += s;
        }
        out
    })
}

#[test]
fn the_block_path_equals_the_scan_by_scan_chain_bit_for_bit() {
    let rig = RigConfig::zhou2004().unwrap();
    let cal = rig.daq.calibration();
    let mech = pipeline::mechanics_of(&rig);
    let base = ConditioningConfig { lowpass_cutoff_hz: 55.5, ..ConditioningConfig::default() };
    // The launch files' chain, then other orders (every fixed section count), no de-skew,
    // other stencils and differentiators, and a higher cutoff (a short settling).
    let configs = [
        (base.clone(), RawUnits::Volts, 12_000, 0),
        (ConditioningConfig { lowpass_order: 1, lowpass_cutoff_hz: 200.0, ..base.clone() }, RawUnits::Si, 6_000, 3),
        (ConditioningConfig { lowpass_order: 2, lowpass_cutoff_hz: 150.0, deskew: false, ..base.clone() }, RawUnits::Volts, 6_000, 1),
        (
            ConditioningConfig { lowpass_order: 3, lowpass_cutoff_hz: 150.0, differentiator_half_length: 3, deskew_taps: 6, ..base.clone() },
            RawUnits::Volts,
            6_000,
            0,
        ),
        (ConditioningConfig { lowpass_order: 5, lowpass_cutoff_hz: 300.0, differentiator_half_length: 8, ..base.clone() }, RawUnits::Si, 6_000, 6),
        (ConditioningConfig { lowpass_order: 6, lowpass_cutoff_hz: 400.0, deskew_taps: 2, ..base.clone() }, RawUnits::Volts, 6_000, 2),
    ];
    let mut noise = Noise(0x9E37_79B9_7F4A_7C15);
    for (n, (config, units, scans, extra)) in configs.iter().enumerate() {
        let (values, columns, width) = record(&cal, *units, *scans, *extra, 1 + n as u64);
        let fresh = CausalChain::new(&columns, width, *units, cal.sample_rate_hz(), &cal, &mech, config).unwrap();
        let mut reference = ScanByScan::new(Design::of(&columns, width, *units, &cal, &mech, config));
        let mut expected = CausalOutput::default();
        reference.push(&values, &mut expected);
        // The record must exercise what is compared: samples out, violations of every
        // kind met, and both valid and invalid samples.
        let d = fresh.delays();
        assert_eq!(expected.len(), scans - d.first_index() - d.delay_scans(), "config {n}");
        assert!(expected.violations.len() >= 6 && expected.violations.iter().any(|v| v.count == 40), "config {n}: {:?}", expected.violations);
        assert!(expected.valid.iter().any(|&v| v) && expected.valid.iter().any(|&v| !v), "config {n}");
        for isa in Isa::available() {
            let mut cuttings: Vec<Vec<usize>> = [1, 7, 500, 1_024, 4_999, *scans].iter().map(|&b| cutting(*scans, Some(b), &mut noise)).collect();
            cuttings.push(cutting(*scans, None, &mut noise));
            cuttings.push(cutting(*scans, None, &mut noise));
            for sizes in &cuttings {
                let got = run_blocks(isa, &columns, width, *units, &cal, &mech, config, &values, sizes);
                if let Some(diff) = first_difference(&got, &expected) {
                    panic!("config {n}, {isa:?}, blocks {:?}...: {diff}", &sizes[..sizes.len().min(5)]);
                }
            }
        }
    }
}

#[test]
fn the_comparison_sees_one_coefficient_changed_by_one_ulp() {
    // What the test above compares would catch a single coefficient of any stage off by the
    // least bit: a de-skew tap, a low-pass coefficient, a differentiator tap.
    let rig = RigConfig::zhou2004().unwrap();
    let cal = rig.daq.calibration();
    let mech = pipeline::mechanics_of(&rig);
    let config = ConditioningConfig { lowpass_cutoff_hz: 55.5, ..ConditioningConfig::default() };
    let (values, columns, width) = record(&cal, RawUnits::Volts, 8_000, 0, 7);
    let design = Design::of(&columns, width, RawUnits::Volts, &cal, &mech, &config);
    let got = run_blocks(Isa::current(), &columns, width, RawUnits::Volts, &cal, &mech, &config, &values, &cutting(8_000, Some(500), &mut Noise(3)));
    let expected = |d: Design| {
        let mut out = CausalOutput::default();
        ScanByScan::new(d).push(&values, &mut out);
        out
    };
    type Coefficient = fn(&mut Design) -> &mut f64;
    let coefficients: [(&str, Coefficient); 3] =
        [("de-skew tap", |d| &mut d.fronts[2].weights[1]), ("low-pass b1", |d| &mut d.sections[1].b[1]), ("differentiator c2", |d| &mut d.sg[1])];
    for (what, coefficient) in coefficients {
        let mut changed = design.clone();
        let v = coefficient(&mut changed);
        *v = f64::from_bits(v.to_bits() + 1);
        assert!(first_difference(&got, &expected(changed)).is_some(), "{what} one ulp off went unnoticed");
    }
    // And unchanged, the same.
    assert_eq!(first_difference(&got, &expected(design)), None);
}
