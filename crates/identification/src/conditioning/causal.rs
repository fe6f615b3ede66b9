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
    channel: ChannelId,
    /// Column of the channel in a scan row.
    column: usize,
    /// The channel's constants for readings in volts, and its sensitivity (V per SI unit).
    volts: Constants,
    sensitivity: f64,
    range_si: [f64; 2],
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
/// scratch columns reused from call to call.
#[derive(Clone, Debug, Default)]
struct Buffers {
    /// Readings (in range, or held) by channel index, scans `raw_first ..`.
    raw: [Vec<f64>; CHANNEL_COUNT],
    raw_first: u64,
    /// This call's front-end output, its frames low-passed in place.
    front: FrontOut,
    /// Low-passed `x, y, tilt_x, tilt_y, X, Y, F_x, F_y`, then the unfiltered `f3` and
    /// temperature, low-pass indices `filtered_first ..`.
    filtered: [Vec<f64>; 10],
    filtered_first: u64,
    /// `x', y', X', Y'`, indices `velocity_first ..`.
    velocity: [Vec<f64>; 4],
    velocity_first: u64,
    /// This call's `x'', y'', X'', Y''`.
    acceleration: [Vec<f64>; 4],
    /// Scans of this call with an out-of-range reading, ascending.
    hits: Vec<u64>,
    /// Whether this call's outputs are finite.
    finite: Vec<bool>,
}

impl Buffers {
    /// Forgets all but the last `keep` entries of `cols` (whose first entry has index
    /// `*first`).
    fn keep_last<const N: usize>(cols: &mut [Vec<f64>; N], first: &mut u64, keep: usize) {
        let len = cols[0].len();
        if len > keep {
            for c in cols.iter_mut() {
                c.drain(..len - keep);
            }
            *first += (len - keep) as u64;
        }
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
    units: RawUnits,
    width: usize,
    fronts: Vec<Front>,
    delays: CausalDelays,
    forward: Option<ForwardStream>,
    /// Scans pushed.
    scans: u64,
    /// Samples through the low-pass.
    lowpassed: u64,
    /// Outputs with a time index `<=` this are invalid (a violation reaches them).
    invalid_through: Option<u64>,
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
        for &ch in &ChannelId::ALL {
            let column = columns[ch.index()];
            if column >= width {
                return Err(IdentificationError::BadInput { what: format!("channel `{ch}`"), reason: format!("column {column} of a {width}-column scan") });
            }
            if let Some(other) = ChannelId::ALL.iter().find(|o| **o != ch && columns[o.index()] == column) {
                return Err(IdentificationError::BadInput { what: format!("channel `{ch}`"), reason: format!("column {column} is also `{other}`'s") });
            }
            let volts = Constants::of(ch, RawUnits::Volts, calibration)?;
            let c = calibration.channel(ch)?;
            let (offset_v, sensitivity) = (c.offset_v, c.sensitivity_v_per_unit);
            let [a, b] = c.linear_range_v.map(|v| (v - offset_v) / sensitivity);
            // Mid-range: what the filters see until the first in-range reading.
            let mid = match units {
                RawUnits::Volts => 0.5 * (c.linear_range_v[0] + c.linear_range_v[1]),
                RawUnits::Si => 0.5 * (a + b),
            };
            let last_good = if mid.is_finite() { mid } else { 0.0 };
            fronts.push(Front { channel: ch, column, volts, sensitivity, range_si: [a.min(b), a.max(b)], last_good });
        }
        let constants = Constants::all(units, calibration)?;
        Ok(Self {
            delays: CausalDelays::of(&chain),
            constants,
            chain,
            units,
            width,
            fronts,
            forward: None,
            scans: 0,
            lowpassed: 0,
            invalid_through: None,
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
        let d = self.delays;
        let first = v.index as u64;
        let last = first + v.count.max(1) as u64 - 1;
        first.saturating_sub((d.lookahead + d.derivative) as u64)..last + (d.lookback + d.settling + d.derivative) as u64 + 1
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

    /// The whole call stage by stage: calibrate every scan into channel columns, de-skew the
    /// columns, the kinematics and applied force into frames, the low-pass over the frames,
    /// the differentiators over the columns, eq. 2. `values` holds whole scans, at least one.
    #[inline(always)]
    fn run<S: Simd>(self, simd: S) {
        let Push { c, values, out } = self;
        let width = c.width;
        let scans = values.len() / width;
        let n0 = c.scans;
        c.scans += scans as u64;
        let d = c.delays;
        let (ahead, back, two_m) = (d.lookahead as u64, d.lookback as u64, d.derivative as u64);
        let half = two_m / 2;
        let buf = &mut c.buf;

        // The readings into the raw columns, range-checked. The raw columns hold the scans
        // since `raw_first`, so scan `n0` goes at their current end.
        let e0 = (n0 - buf.raw_first) as usize;
        for col in buf.raw.iter_mut() {
            col.resize(e0 + scans, 0.0);
        }
        {
            // The readings into the channel columns, row after row.
            let dst = buf.raw.each_mut().map(|c| &mut c[e0..e0 + scans]);
            let columns: [usize; CHANNEL_COUNT] = std::array::from_fn(|k| c.fronts[k].column);
            for (i, row) in values.chunks_exact(width).enumerate() {
                for k in 0..CHANNEL_COUNT {
                    dst[k][i] = row[columns[k]];
                }
            }
        }
        let mut in_range = true;
        for (f, col) in c.fronts.iter().zip(&buf.raw) {
            in_range &= f.in_range(c.units, &col[e0..]);
        }
        buf.hits.clear();
        if in_range {
            for (f, col) in c.fronts.iter_mut().zip(&buf.raw) {
                f.last_good = col[e0 + scans - 1];
            }
        } else {
            // A reading out of range somewhere: again, scan by scan, holding the last good
            // value and recording the violations in the order met.
            for (i, row) in values.chunks_exact(width).enumerate() {
                let n = n0 + i as u64;
                for (f, col) in c.fronts.iter_mut().zip(buf.raw.iter_mut()) {
                    let (value, ok) = f.read(c.units, row[f.column]);
                    if ok {
                        f.last_good = row[f.column];
                    } else {
                        if buf.hits.last() != Some(&n) {
                            buf.hits.push(n);
                        }
                        match out.violations.iter_mut().rev().find(|v| v.channel == f.channel) {
                            Some(v) if v.index as u64 + v.count as u64 == n => v.count += 1,
                            _ => out.violations.push(RangeViolation { channel: f.channel, index: n as usize, value_si: value, range_si: f.range_si, count: 1 }),
                        }
                    }
                    col[e0 + i] = f.last_good;
                }
            }
        }

        // The front end (calibration, de-skew, kinematics, applied force): scan `n` gives
        // time index `m = n - L`, once the stencils' reach back is in.
        let (first_n, end_n) = (n0.max(ahead + back), n0 + scans as u64);
        if first_n < end_n {
            let count = (end_n - first_n) as usize;
            let m0 = (first_n - ahead) as usize;
            let front = &mut buf.front;
            front.frames.clear();
            front.load.clear();
            front.temp.clear();
            let cols = buf.raw.each_ref().map(Vec::as_slice);
            // The raw columns keep the last `L + lookback` scans, every reading the stencils
            // of `m0..` reach: this cannot fail.
            let _ = c.chain.front_frames(&c.constants, cols, buf.raw_first as usize, m0..m0 + count, &mut c.front, front);
            let FrontOut { frames, load: f3, temp: temperature } = front;

            // Low-pass: index `p = m - lookback`, started in the steady state of its first input.
            let p0 = c.lowpassed;
            c.lowpassed += count as u64;
            let st = c.forward.get_or_insert_with(|| c.chain.lowpass.forward_steady(frames[0]));
            c.chain.lowpass.forward_run(st, frames);
            let fe = (p0 - buf.filtered_first) as usize;
            for col in buf.filtered.iter_mut() {
                col.resize(fe + count, 0.0);
            }
            let [l0, l1, l2, l3, l4, l5, l6, l7, o_f3, o_t] = &mut buf.filtered;
            simd.transpose8(&mut [l0, l1, l2, l3, l4, l5, l6, l7].map(|c| &mut c[..]), fe, frames, false);
            o_f3[fe..].copy_from_slice(&f3[..count]);
            o_t[fe..].copy_from_slice(&temperature[..count]);

            // Velocity at `q = p - M` for every `p >= 2M`.
            let p_end = p0 + count as u64;
            let pv = p0.max(two_m);
            if pv < p_end {
                let nv = (p_end - pv) as usize;
                let q0 = pv - half;
                // The velocity columns end just before `q0` (or are empty and start there).
                buf.velocity_first = q0 - buf.velocity[0].len() as u64;
                let ve = buf.velocity[0].len();
                let from = (q0 - half - buf.filtered_first) as usize;
                for (v, &lane) in buf.velocity.iter_mut().zip(&DIFFERENTIATED) {
                    v.resize(ve + nv, 0.0);
                    c.chain.derivative.interior_slices(simd, &buf.filtered[lane][from..], &mut v[ve..]);
                }
                // Acceleration and every output at `r = p - 2M`, once the low-pass has settled.
                let r0 = (pv - two_m).max(d.settling as u64 + two_m);
                let r_end = p_end - two_m;
                if r0 < r_end {
                    let no = (r_end - r0) as usize;
                    let from = (r0 - half - buf.velocity_first) as usize;
                    for (a, v) in buf.acceleration.iter_mut().zip(&buf.velocity) {
                        a.resize(no, 0.0);
                        c.chain.derivative.interior_slices(simd, &v[from..], a);
                    }
                    c.emit(r0, no, out);
                }
            }
        }
        let buf = &mut c.buf;
        let reach = back + (d.settling as u64) + two_m;
        if let Some(&n) = buf.hits.last() {
            // `n + reach` grows with `n`: the last violation reaches furthest.
            c.invalid_through = Some(c.invalid_through.map_or(n + reach, |t| t.max(n + reach)));
        }
        Buffers::keep_last(&mut buf.raw, &mut buf.raw_first, (ahead + back) as usize);
        Buffers::keep_last(&mut buf.filtered, &mut buf.filtered_first, two_m as usize);
        Buffers::keep_last(&mut buf.velocity, &mut buf.velocity_first, two_m as usize);
    }
}

impl CausalChain {
    /// Appends the `count` outputs from index `r0` of the low-pass (time index `r0 +
    /// lookback`): this call's accelerations are in the acceleration columns.
    #[inline(always)]
    fn emit(&mut self, r0: u64, count: usize, out: &mut CausalOutput) {
        let buf = &self.buf;
        let d = self.delays;
        let (fo, vo) = ((r0 - buf.filtered_first) as usize, (r0 - buf.velocity_first) as usize);
        let time0 = r0 + d.lookback as u64;
        if out.is_empty() {
            out.first_index = time0;
        }
        let start = out.len();
        let [x, y, _, _, _, _, fx, fy, f3, temperature] = &buf.filtered;
        let [ax, ay, hx, hy] = &buf.acceleration;
        out.x_m.extend_from_slice(&x[fo..fo + count]);
        out.y_m.extend_from_slice(&y[fo..fo + count]);
        out.vx_m_s.extend_from_slice(&buf.velocity[0][vo..vo + count]);
        out.vy_m_s.extend_from_slice(&buf.velocity[1][vo..vo + count]);
        out.ax_m_s2.extend_from_slice(&ax[..count]);
        out.ay_m_s2.extend_from_slice(&ay[..count]);
        let m = self.chain.mechanics().housing_mass_kg;
        out.fx_n.extend(fx[fo..fo + count].iter().zip(&hx[..count]).map(|(f, a)| f - m * a));
        out.fy_n.extend(fy[fo..fo + count].iter().zip(&hy[..count]).map(|(f, a)| f - m * a));
        out.static_load_n.extend_from_slice(&f3[fo..fo + count]);
        out.temperature_c.extend_from_slice(&temperature[fo..fo + count]);
        // Valid: finite, and no violation met by the scan that completed the sample
        // (`time + L + 2M`) reaches it.
        let cols = [&out.x_m, &out.y_m, &out.vx_m_s, &out.vy_m_s, &out.ax_m_s2, &out.ay_m_s2, &out.fx_n, &out.fy_n].map(|c| &c[start..start + count]);
        let mut finite = std::mem::take(&mut self.buf.finite);
        finite.clear();
        finite.resize(count, true);
        for c in cols {
            for (f, v) in finite.iter_mut().zip(c) {
                *f &= v.is_finite();
            }
        }
        let reach = (d.lookback + d.settling + d.derivative) as u64;
        let delay = d.delay_scans() as u64;
        let mut through = self.invalid_through;
        let mut hits = self.buf.hits.iter().peekable();
        let mut i = 0;
        out.valid.reserve(count);
        while i < count {
            // The violations met up to the scan completing sample `i`; `through` then holds
            // until the scan of the next violation.
            let scan = time0 + i as u64 + delay;
            while let Some(&&n) = hits.peek() {
                if n > scan {
                    break;
                }
                through = Some(through.map_or(n + reach, |t| t.max(n + reach)));
                hits.next();
            }
            let end = hits.peek().map_or(count, |&&n| ((n - delay - time0) as usize).min(count));
            out.valid.extend(finite[i..end].iter().zip(time0 + i as u64..).map(|(&f, time)| f && through.is_none_or(|t| time > t)));
            i = end;
        }
        self.buf.finite = finite;
    }
}

impl Front {
    /// A reading's SI value and whether it is in range (finite, inside the linear range).
    #[inline(always)]
    fn read(&self, units: RawUnits, r: f64) -> (f64, bool) {
        let k = &self.volts;
        let (volts, value) = match units {
            RawUnits::Volts => (r, k.si(r)),
            RawUnits::Si => (k.offset + self.sensitivity * r, r),
        };
        (value, (volts > k.lo) & (volts < k.hi) & value.is_finite())
    }

    /// Whether every reading of `col` is in range (the caller then redoes the block holding
    /// values if one is not).
    #[inline(always)]
    fn in_range(&self, units: RawUnits, col: &[f64]) -> bool {
        // A count rather than a short-circuit `all`, so that the loop vectorises.
        col.iter().map(|&r| u64::from(!self.read(units, r).1)).sum::<u64>() == 0
    }
}
