//! A **causal** conditioning chain for live use: the same steps as [`super::condition`],
//! run scan by scan with its state carried from one call to the next, so a sample is out a
//! fixed, short delay after it was acquired instead of after the zero-phase filter's edge
//! (ADR 0014).
//!
//! The coefficients are unchanged only if every column sees **exactly** the same causal
//! filter `H`: one low-pass on every dynamic column, the derivatives and the force at one
//! common delay ([`CausalDelays`]). Each sample goes through the same operations in the same
//! order whatever block it came in and whichever instruction set runs, so the output is the
//! same bit for bit however the scans are cut; `tests/causal_block_path.rs` keeps the plain
//! scan-by-scan chain as the reference.
//!
//! Why, the delays, the start and out-of-range readings:
//! docs/manual/conditioning.md#the-causal-chain.

use std::ops::Range;

use oilfilm_physics::daq::{Calibration, ChannelId, CHANNEL_COUNT};

use super::chain::{Constants, FrontOut, FrontScratch};
use super::lowpass::ForwardStream;
use super::range_check::LinearRange;
use super::{Chain, ConditioningConfig, Mechanics, RangeViolation};
use crate::record::RawUnits;
use crate::simd::{self, Kernel, Simd};
use crate::IdentificationError;

/// The causal low-pass's order for a configuration: twice `lowpass_order`, so that its
/// stop band falls as fast as the zero-phase chain's squared magnitude (`|H|^2` of order
/// `N` decays as `f^-2N`, one pass of order `2N` too).
pub fn causal_order(config: &ConditioningConfig) -> usize {
    2 * config.lowpass_order
}

/// The fixed delays of a causal chain, in scans.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct CausalDelays {
    /// How far the de-skew stencils reach ahead of their output (`L`).
    pub lookahead: usize,
    /// How far they reach back.
    pub lookback: usize,
    /// Twice the differentiator's half-length (`2 M`).
    pub derivative: usize,
    /// Samples for the low-pass's start transient to decay to 1e-7.
    pub settling: usize,
}

impl CausalDelays {
    /// A sample of time index `m` is out once scan `m + delay_scans()` is in.
    pub fn delay_scans(&self) -> usize {
        self.lookahead + self.derivative
    }

    /// Time index of the first sample out (scans since the chain started).
    pub fn first_index(&self) -> usize {
        self.lookback + self.settling + self.derivative
    }

    fn of(chain: &Chain) -> Self {
        let (lookback, lookahead) = chain.reach();
        Self { lookahead, lookback, derivative: 2 * chain.derivative.half_length(), settling: chain.lowpass.settling_samples() }
    }
}

/// The delays [`CausalChain::new`] will have for this calibration, configuration and rate.
pub fn delays(calibration: &Calibration, config: &ConditioningConfig, sample_rate_hz: f64) -> Result<CausalDelays, IdentificationError> {
    // The delays do not depend on the mechanics: any valid ones do.
    let mechanics = Mechanics { housing_mass_kg: 1.0, exciter_angles_deg: [45.0, 135.0], gravity_m_s2: 9.81 };
    Ok(CausalDelays::of(&Chain::causal(calibration, &mechanics, config, sample_rate_hz)?))
}

/// One channel's front end.
#[derive(Clone, Debug)]
struct Front {
    /// Column of the channel in a scan row.
    column: usize,
    range: LinearRange,
    /// The last in-range reading (in the stream's units), fed to the filters in place of an
    /// out-of-range one.
    last_good: f64,
}

/// Samples the chain has produced and not yet handed on, columns of equal length.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CausalOutput {
    /// Time index (scans since the chain started) of the first sample held.
    pub first_index: u64,
    pub x_m: Vec<f64>,
    pub y_m: Vec<f64>,
    pub vx_m_s: Vec<f64>,
    pub vy_m_s: Vec<f64>,
    pub ax_m_s2: Vec<f64>,
    pub ay_m_s2: Vec<f64>,
    /// Film force on the journal, eq. 2 (static + dynamic).
    pub fx_n: Vec<f64>,
    pub fy_n: Vec<f64>,
    /// De-skewed, not low-passed (only their means are used).
    pub temperature_c: Vec<f64>,
    pub static_load_n: Vec<f64>,
    /// False where an out-of-range reading can reach the sample.
    pub valid: Vec<bool>,
    /// Out-of-range readings met, by channel and run of consecutive scans, in the order met
    /// (`index` = scan since the chain started). The consumer removes those it has reported.
    pub violations: Vec<RangeViolation>,
}

impl CausalOutput {
    /// Samples held.
    pub fn len(&self) -> usize {
        self.x_m.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x_m.is_empty()
    }

    /// Forgets the first `n` samples (all if fewer are held); the violations stay.
    pub fn consume(&mut self, n: usize) {
        let n = n.min(self.len());
        for c in [
            &mut self.x_m,
            &mut self.y_m,
            &mut self.vx_m_s,
            &mut self.vy_m_s,
            &mut self.ax_m_s2,
            &mut self.ay_m_s2,
            &mut self.fx_n,
            &mut self.fy_n,
            &mut self.temperature_c,
            &mut self.static_load_n,
        ] {
            c.drain(..n);
        }
        self.valid.drain(..n);
        self.first_index += n as u64;
    }
}

/// What one call leaves for the next (the last scans the de-skew stencils reach back to, the
/// last `2 M` low-passed samples and velocities the differentiators reach back to), and
/// scratch columns reused from call to call. Every column ends with the last sample of its
/// stage so far, so a stage takes the tail of its input.
#[derive(Clone, Debug, Default)]
struct Buffers {
    /// Readings (in range, or held) by channel index.
    raw: [Vec<f64>; CHANNEL_COUNT],
    /// This call's front-end output, its frames low-passed in place.
    front: FrontOut,
    /// Low-passed `x, y, tilt_x, tilt_y, X, Y, F_x, F_y`, then the unfiltered `f3` and
    /// temperature.
    filtered: [Vec<f64>; 10],
    /// `x', y', X', Y'`.
    velocity: [Vec<f64>; 4],
    /// This call's `x'', y'', X'', Y''`.
    acceleration: [Vec<f64>; 4],
    /// Scans of this call with an out-of-range reading, ascending.
    hits: Vec<u64>,
}

/// Forgets all but the last `keep` entries of each column.
fn keep_last(cols: &mut [Vec<f64>], keep: usize) {
    for c in cols {
        c.drain(..c.len().saturating_sub(keep));
    }
}

/// Scans a pass of the block path takes at most (a longer call is cut into passes).
const MAX_BLOCK: usize = 2_048;

/// Low-passed lanes the derivatives are taken of: `x, y, X, Y`.
const DIFFERENTIATED: [usize; 4] = [0, 1, 4, 5];

/// The causal chain's state. Build one per stream; push scans in order.
#[derive(Clone)]
pub struct CausalChain {
    chain: Chain,
    /// The front end's constants for the stream's units, by channel index.
    constants: [Constants; CHANNEL_COUNT],
    width: usize,
    /// By channel index.
    fronts: Vec<Front>,
    delays: CausalDelays,
    forward: Option<ForwardStream>,
    /// Scans pushed.
    scans: u64,
    /// Outputs with a time index below this are reached by a violation met already.
    invalid_until: u64,
    /// History carried between calls, and scratch.
    buf: Buffers,
    front: FrontScratch,
}

impl CausalChain {
    /// A chain for scans whose readings of channel `c` sit at column `columns[c.index()]` of
    /// rows `width` wide, in `units`. Every field is checked; errors name it.
    pub fn new(
        columns: &[usize; CHANNEL_COUNT],
        width: usize,
        units: RawUnits,
        sample_rate_hz: f64,
        calibration: &Calibration,
        mechanics: &Mechanics,
        config: &ConditioningConfig,
    ) -> Result<Self, IdentificationError> {
        let chain = Chain::causal(calibration, mechanics, config, sample_rate_hz)?;
        let mut fronts = Vec::with_capacity(CHANNEL_COUNT);
        for ch in ChannelId::ALL {
            let column = columns[ch.index()];
            if column >= width {
                return Err(IdentificationError::BadInput { what: format!("channel `{ch}`"), reason: format!("column {column} of a {width}-column scan") });
            }
            if let Some(other) = ChannelId::ALL.iter().find(|o| **o != ch && columns[o.index()] == column) {
                return Err(IdentificationError::BadInput { what: format!("channel `{ch}`"), reason: format!("column {column} is also `{other}`'s") });
            }
            // The range test maps readings in SI to volts: whatever the units, a calibration
            // that cannot convert volts is refused.
            Constants::of(ch, RawUnits::Volts, calibration)?;
            let range = LinearRange::of(ch, units, calibration)?;
            // Mid-range, in the stream's units: what the filters see until the first in-range
            // reading (a non-finite value would stay in the low-pass's state).
            let [lo, hi] = match units {
                RawUnits::Volts => calibration.channel(ch)?.linear_range_v,
                RawUnits::Si => range.range_si,
            };
            let mid = 0.5 * (lo + hi);
            fronts.push(Front { column, range, last_good: if mid.is_finite() { mid } else { 0.0 } });
        }
        Ok(Self {
            delays: CausalDelays::of(&chain),
            constants: Constants::all(units, calibration)?,
            chain,
            width,
            fronts,
            forward: None,
            scans: 0,
            invalid_until: 0,
            buf: Buffers::default(),
            front: FrontScratch::default(),
        })
    }

    pub fn delays(&self) -> CausalDelays {
        self.delays
    }

    /// Scans pushed so far.
    pub fn scans(&self) -> u64 {
        self.scans
    }

    /// The time indices of the outputs a violation can reach (see the module notes).
    pub fn influence(&self, v: &RangeViolation) -> Range<u64> {
        let first = v.index as u64;
        let last = first + v.count.max(1) as u64 - 1;
        self.reached_by(first).start..self.reached_by(last).end
    }

    /// The time indices an out-of-range reading at scan `n` reaches: from the output that scan
    /// completes to the last whose stencils, low-pass settling and differentiators reach back
    /// to it.
    fn reached_by(&self, n: u64) -> Range<u64> {
        let d = self.delays;
        n.saturating_sub(d.delay_scans() as u64)..n + (d.lookback + d.settling + d.derivative) as u64 + 1
    }

    /// Pushes the scans of `values` (rows of `width` readings, scan order) and appends the
    /// samples they complete to `out`. At most [`MAX_BLOCK`] scans a pass: the scratch
    /// columns stay small (and in cache) however long a call is; the output does not depend
    /// on the cutting.
    pub fn push(&mut self, values: &[f64], out: &mut CausalOutput) -> Result<(), IdentificationError> {
        if !values.len().is_multiple_of(self.width) {
            return Err(IdentificationError::BadInput {
                what: "scan values".into(),
                reason: format!("{} values are not whole scans of {} readings", values.len(), self.width),
            });
        }
        for block in values.chunks(MAX_BLOCK * self.width) {
            simd::dispatch(self.chain.isa(), Push { c: self, values: block, out });
        }
        Ok(())
    }
}

/// One pass of [`CausalChain::push`] as a [`Kernel`].
struct Push<'a> {
    c: &'a mut CausalChain,
    values: &'a [f64],
    out: &'a mut CausalOutput,
}

impl Kernel for Push<'_> {
    type Output = ();

    /// The call's readings, the filters, and what the next call needs kept. `values` holds
    /// whole scans, at least one.
    #[inline(always)]
    fn run<S: Simd>(self, simd: S) {
        let Push { c, values, out } = self;
        let n0 = c.scans;
        c.read_scans(values, out);
        c.filter(simd, n0, out);
        if let Some(&n) = c.buf.hits.last() {
            // The last violation reaches furthest.
            c.invalid_until = c.reached_by(n).end;
        }
        let d = c.delays;
        keep_last(&mut c.buf.raw, d.lookahead + d.lookback);
        keep_last(&mut c.buf.filtered, d.derivative);
        keep_last(&mut c.buf.velocity, d.derivative);
    }
}

impl CausalChain {
    /// The readings of the scans of `values` into the raw columns, an out-of-range one
    /// replaced by the last good one of its channel, and recorded: in `out`'s violations, its
    /// scan in `hits`.
    #[inline(always)]
    fn read_scans(&mut self, values: &[f64], out: &mut CausalOutput) {
        let n0 = self.scans;
        self.scans += (values.len() / self.width) as u64;
        let buf = &mut self.buf;
        // Row after row, one pass over the scans, into the columns' new ends taken as slices,
        // the channels' columns in a local array: the loop then keeps them in registers.
        let first_new = buf.raw[0].len();
        for col in &mut buf.raw {
            col.resize(first_new + values.len() / self.width, 0.0);
        }
        let columns: [usize; CHANNEL_COUNT] = std::array::from_fn(|k| self.fronts[k].column);
        let dst = buf.raw.each_mut().map(|col| &mut col[first_new..]);
        for (i, row) in values.chunks_exact(self.width).enumerate() {
            for k in 0..CHANNEL_COUNT {
                dst[k][i] = row[columns[k]];
            }
        }
        // Scan by scan, so that the violations are in the order met. A block in range, the
        // usual case, is told by a count over each column (it vectorises); only its last scan
        // is then gone over, for `last_good`.
        let in_range = self.fronts.iter().zip(&self.constants).zip(&buf.raw).all(|((f, k), col)| f.in_range(k, &col[first_new..]));
        let len = buf.raw[0].len();
        buf.hits.clear();
        let from = if in_range { len - 1 } else { first_new };
        for i in from..len {
            let n = n0 + (i - first_new) as u64;
            for ((f, k), col) in self.fronts.iter_mut().zip(&self.constants).zip(&mut buf.raw) {
                let (value, ok) = f.read(k, col[i]);
                if ok {
                    f.last_good = col[i];
                } else {
                    col[i] = f.last_good;
                    if buf.hits.last() != Some(&n) {
                        buf.hits.push(n);
                    }
                    let (channel, range_si) = (f.range.channel, f.range.range_si);
                    match out.violations.iter_mut().rev().find(|v| v.channel == channel) {
                        Some(v) if v.index as u64 + v.count as u64 == n => v.count += 1,
                        _ => out.violations.push(RangeViolation { channel, index: n as usize, value_si: value, range_si, count: 1 }),
                    }
                }
            }
        }
    }

    /// This call's scans `n0..` (in the raw columns) through the front end (calibration,
    /// de-skew, kinematics, applied force), the low-pass and the differentiators, and the
    /// outputs they complete into `out`.
    #[inline(always)]
    fn filter<S: Simd>(&mut self, simd: S, n0: u64, out: &mut CausalOutput) {
        let d = self.delays;
        let two_m = d.derivative;
        // How many samples this call's scans complete of a stage whose first sample scan `k`
        // completes. Scan `n` completes time index `m = n - L` once the stencils' reach back
        // is in (low-pass index `p = m - lookback`), the velocity at `p - M`, and the
        // acceleration and every output at `p - 2M` once the low-pass has settled.
        let new = |k: usize| (self.scans.saturating_sub(k as u64) - n0.saturating_sub(k as u64)) as usize;
        let lowpassed = new(d.lookahead + d.lookback);
        let velocities = new(d.lookahead + d.lookback + two_m);
        let outputs = new(d.first_index() + d.delay_scans());
        if lowpassed == 0 {
            return;
        }
        let buf = &mut self.buf;
        let front = &mut buf.front;
        front.frames.clear();
        front.load.clear();
        front.temp.clear();
        let m_end = self.scans as usize - d.lookahead;
        let raw_first = self.scans as usize - buf.raw[0].len();
        // The raw columns keep the last `L + lookback` scans, every reading the stencils reach:
        // this cannot fail.
        let _ = self.chain.front_frames(&self.constants, buf.raw.each_ref().map(Vec::as_slice), raw_first, m_end - lowpassed..m_end, &mut self.front, front);
        let FrontOut { frames, load, temp } = front;

        // The low-pass, started in the steady state of its first input.
        let lowpass = &self.chain.lowpass;
        let state = self.forward.get_or_insert_with(|| lowpass.forward_steady(frames[0]));
        lowpass.forward_run(state, frames);
        let start = buf.filtered[0].len();
        let [l0, l1, l2, l3, l4, l5, l6, l7, f3, temperature] = &mut buf.filtered;
        let mut lanes = [l0, l1, l2, l3, l4, l5, l6, l7];
        for l in &mut lanes {
            l.resize(start + lowpassed, 0.0);
        }
        simd.transpose8(&mut lanes.map(|l| &mut l[..]), start, frames, false);
        f3.extend_from_slice(load);
        temperature.extend_from_slice(temp);

        // Each derivative reaches `M` past its outputs on either side.
        if velocities == 0 {
            return;
        }
        for (v, &lane) in buf.velocity.iter_mut().zip(&DIFFERENTIATED) {
            let x = &buf.filtered[lane];
            let start = v.len();
            v.resize(start + velocities, 0.0);
            self.chain.derivative.interior_slices(simd, &x[x.len() - velocities - two_m..], &mut v[start..]);
        }
        if outputs == 0 {
            return;
        }
        for (a, v) in buf.acceleration.iter_mut().zip(&buf.velocity) {
            a.resize(outputs, 0.0);
            self.chain.derivative.interior_slices(simd, &v[v.len() - outputs - two_m..], a);
        }
        self.emit(outputs, out);
    }

    /// Appends the last `count` outputs: this call's accelerations, the velocities `M` and the
    /// low-passed samples `2M` before the end of their columns.
    #[inline(always)]
    fn emit(&self, count: usize, out: &mut CausalOutput) {
        let d = self.delays;
        let buf = &self.buf;
        // The last output is completed by the last scan.
        let time0 = self.scans - (d.delay_scans() + count) as u64;
        if out.is_empty() {
            out.first_index = time0;
        }
        let start = out.len();
        let tail = |col: &Vec<f64>, past: usize| col.len() - past - count..col.len() - past;
        let [x, y, _, _, _, _, fx, fy, f3, temperature] = buf.filtered.each_ref().map(|c| &c[tail(c, d.derivative)]);
        let [vx, vy, _, _] = buf.velocity.each_ref().map(|c| &c[tail(c, d.derivative / 2)]);
        let [ax, ay, hx, hy] = &buf.acceleration;
        out.x_m.extend_from_slice(x);
        out.y_m.extend_from_slice(y);
        out.vx_m_s.extend_from_slice(vx);
        out.vy_m_s.extend_from_slice(vy);
        out.ax_m_s2.extend_from_slice(ax);
        out.ay_m_s2.extend_from_slice(ay);
        let m = self.chain.mechanics().housing_mass_kg;
        out.fx_n.extend(fx.iter().zip(hx).map(|(f, a)| f - m * a));
        out.fy_n.extend(fy.iter().zip(hy).map(|(f, a)| f - m * a));
        out.static_load_n.extend_from_slice(f3);
        out.temperature_c.extend_from_slice(temperature);
        // Valid: finite, and out of the reach of every out-of-range reading (the earlier calls'
        // end at `invalid_until`). The reaches are in order, so no sample is cleared twice.
        out.valid.resize(start + count, true);
        let valid = &mut out.valid[start..];
        for col in [&out.x_m, &out.y_m, &out.vx_m_s, &out.vy_m_s, &out.ax_m_s2, &out.ay_m_s2, &out.fx_n, &out.fy_n] {
            for (ok, v) in valid.iter_mut().zip(&col[start..]) {
                *ok &= v.is_finite();
            }
        }
        let (end, mut cleared) = (time0 + count as u64, time0);
        for reached in std::iter::once(0..self.invalid_until).chain(buf.hits.iter().map(|&n| self.reached_by(n))) {
            let (from, to) = (reached.start.max(cleared), reached.end.min(end));
            if from < to {
                valid[(from - time0) as usize..(to - time0) as usize].fill(false);
                cleared = to;
            }
        }
    }
}

impl Front {
    /// A reading's SI value, by the chain's own conversion (`k`), and whether it is in range:
    /// inside the linear range and converting to a finite value.
    #[inline(always)]
    fn read(&self, k: &Constants, r: f64) -> (f64, bool) {
        let value = match self.range.units {
            RawUnits::Volts => k.si(r),
            RawUnits::Si => r,
        };
        (value, self.range.contains(r) & value.is_finite())
    }

    /// Whether every reading of `col` is in range.
    #[inline(always)]
    fn in_range(&self, k: &Constants, col: &[f64]) -> bool {
        // A count rather than a short-circuit `all`, so that the loop vectorises.
        col.iter().filter(|&&r| !self.read(k, r).1).count() == 0
    }
}
