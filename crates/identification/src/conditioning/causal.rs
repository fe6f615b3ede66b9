//! A **causal** conditioning chain for live use: the same steps as [`super::condition`]
//! (calibration, linear-range check, de-skew, low-pass, kinematics, Savitzky-Golay
//! derivatives, eq. 2), run scan by scan with its state carried from one call to the next, so
//! a sample is out a fixed, short delay after it was acquired instead of after the zero-phase
//! filter's edge (ADR 0014).
//!
//! ## Why a causal filter leaves the coefficients alone
//! The film model `F = K r + C r' (+ M r'')` is linear and time-invariant. Applying one causal
//! LTI filter `H` to the force and to every regressor gives `H F = K (H r) + C (H r') (+ ...)`
//! with the same `K`, `C`, `M`: only the weighting of the noise changes. The zero-phase chain
//! is one choice of `H`; this chain is another. What must hold is that every column sees
//! **exactly** the same `H`: after de-skew (which puts the channels on one time base; its
//! common integer delay is part of `H`), one low-pass on every dynamic column, and the
//! derivatives and the force evaluated at one common delay.
//!
//! ## The stages and their delays (scans)
//! | stage | here | delay |
//! |---|---|---|
//! | calibration, range check | per reading, on the raw value | 0 |
//! | de-skew | the same Lagrange stencils as [`super::deskew`], output at scan `n - L` | `L` = the furthest stencil reaches ahead |
//! | kinematics, applied force | `r` = mean of ends A, B; `(c1 f1 + c2 f2, s1 f1 + s2 f2 + f3 - m g)` | 0 |
//! | low-pass | Butterworth of order `2 N` ([`causal_order`]), forward only, on `x, y, X, Y, F_x, F_y` | none counted (its phase is part of `H`) |
//! | derivatives | Savitzky-Golay, centred, twice: `r'` at `p - M`, `r''` at `p - 2M` | `2 M`, the same for `r, r', r'', X'', F` |
//! | eq. 2 | `F = F_applied - m X''` at the common delay | 0 |
//!
//! So a sample of time index `m` (scans since the chain started) is out when scan
//! `m + delay_scans()` is pushed ([`CausalDelays::delay_scans`]: `L + 2M`, 11 scans for the
//! 5 kHz defaults). Its time index means: the scan whose start time the de-skew and the
//! differentiators align it to. The low-pass's own phase lag (its group delay, about
//! 15 ms at DC for order 8 at 55.5 Hz) is **not** removed: it is common to every column and
//! so part of `H`. A consumer comparing conditioned signals with the rig's own time (not
//! needed for the coefficients) must allow for it.
//!
//! ## Start
//! The low-pass starts in the DC steady state of its first input (as [`super::lowpass`]
//! does); its transient has decayed to `1e-7` after `settling` samples. The first sample
//! out is time index [`CausalDelays::first_index`] = lookback + settling + `2M`: as the
//! zero-phase chain trims its record's ends. From then on every pushed scan gives exactly
//! one sample.
//!
//! ## Out-of-range and non-finite readings
//! A reading out of its channel's linear range (paper step 2; non-finite readings count as
//! out of range) is reported as a [`RangeViolation`] (index = the scan since the chain
//! started, `count` = consecutive readings of that channel) and every output it can reach
//! is marked invalid: the de-skew stencils, the low-pass until it has settled, and the
//! differentiators' reach ([`CausalChain::influence`]). The filters are fed the channel's
//! last in-range value instead, so the state stays finite and bounded and the chain goes
//! on once the probe is back.
//!
//! ## Bit for bit, block by block
//! A call runs stage by stage over its whole block on the prepared chain's kernels
//! ([`super::Chain`]: the front end's de-skew stencils, the low-pass's forward pass over
//! frames of eight lanes, the differentiator's interior), with what the next call needs
//! carried over: the last scans the stencils reach back to, the low-pass's state, the last
//! `2M` low-passed samples and velocities. Each sample goes through the same operations in
//! the same order whatever block it came in and whichever instruction set runs, so the output
//! depends on neither. The unit tests keep a scan-by-scan chain, written plainly, as the
//! reference and compare bits for many cuttings, with out-of-range readings in them.

use std::ops::Range;

use oilfilm_physics::daq::{Calibration, ChannelId, CHANNEL_COUNT};

use super::chain::stencil_any;
use super::lowpass::ForwardStream;
use super::{kinematics, range_check, Chain, ConditioningConfig, Mechanics, RangeViolation, RawUnits};
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
        let stencils = stencils(chain);
        let ahead = stencils.iter().map(|(s, w)| s + w.len() as isize - 1).max().unwrap_or(0).max(0) as usize;
        let back = stencils.iter().map(|(s, _)| -s).max().unwrap_or(0).max(0) as usize;
        Self { lookahead: ahead, lookback: back, derivative: 2 * chain.derivative.half_length(), settling: chain.lowpass.settling_samples() }
    }
}

/// The de-skew stencil of each channel (start relative to the output, weights); the identity
/// without de-skew.
fn stencils(chain: &Chain) -> Vec<(isize, Vec<f64>)> {
    chain.delays.iter().map(|d| d.as_ref().map_or((0, vec![1.0]), |d| (d.stencil_start(), d.weights().to_vec()))).collect()
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
    offset_v: f64,
    sensitivity: f64,
    gain: f64,
    /// Readings inside `(lo, hi)` volts are in range.
    lo_v: f64,
    hi_v: f64,
    range_si: [f64; 2],
    start: isize,
    weights: Vec<f64>,
    /// The last in-range value (SI), fed to the filters in place of an out-of-range one.
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
        for c in [&mut self.x_m, &mut self.y_m, &mut self.vx_m_s, &mut self.vy_m_s, &mut self.ax_m_s2, &mut self.ay_m_s2, &mut self.fx_n, &mut self.fy_n, &mut self.temperature_c, &mut self.static_load_n] {
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
    /// SI readings (in-range, or held) by channel index, scans `raw_first ..`.
    raw: [Vec<f64>; CHANNEL_COUNT],
    raw_first: u64,
    /// This call's de-skewed samples by channel index.
    deskewed: [Vec<f64>; CHANNEL_COUNT],
    /// This call's `[x, y, tilt_x, tilt_y, X, Y, F_x, F_y]` (applied force), low-passed in place.
    frames: Vec<[f64; 8]>,
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
        for (&ch, (start, weights)) in ChannelId::ALL.iter().zip(stencils(&chain)) {
            let column = columns[ch.index()];
            if column >= width {
                return Err(IdentificationError::BadInput { what: format!("channel `{ch}`"), reason: format!("column {column} of a {width}-column scan") });
            }
            if let Some(other) = ChannelId::ALL.iter().find(|o| **o != ch && columns[o.index()] == column) {
                return Err(IdentificationError::BadInput { what: format!("channel `{ch}`"), reason: format!("column {column} is also `{other}`'s") });
            }
            let c = calibration.channel(ch)?;
            let (offset_v, sensitivity) = (c.offset_v, c.sensitivity_v_per_unit);
            if !(sensitivity.is_finite() && sensitivity != 0.0 && offset_v.is_finite()) {
                return Err(IdentificationError::invalid(
                    format!("calibration.{ch}.sensitivity_v_per_unit"),
                    format!("must be finite and non-zero with a finite offset, got {sensitivity} V/unit, offset {offset_v} V"),
                ));
            }
            let (lo_v, hi_v) = range_check::volts_bounds(ch, calibration)?;
            let [a, b] = c.linear_range_v.map(|v| (v - offset_v) / sensitivity);
            // Mid-range: what the filters see until the first in-range reading.
            let mid = 0.5 * (a + b);
            let last_good = if mid.is_finite() { mid } else { 0.0 };
            fronts.push(Front { channel: ch, column, offset_v, sensitivity, gain: 1.0 / sensitivity, lo_v, hi_v, range_si: [a.min(b), a.max(b)], start, weights, last_good });
        }
        Ok(Self {
            delays: CausalDelays::of(&chain),
            chain,
            units,
            width,
            fronts,
            forward: None,
            scans: 0,
            lowpassed: 0,
            invalid_through: None,
            buf: Buffers::default(),
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
            return Err(IdentificationError::BadInput { what: "scan values".into(), reason: format!("{} values are not whole scans of {} readings", values.len(), self.width) });
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

        // Calibration and range check, channel by channel into the raw columns. The raw
        // columns hold the scans since `raw_first`, so scan `n0` goes at their current end.
        let e0 = (n0 - buf.raw_first) as usize;
        for col in buf.raw.iter_mut() {
            col.resize(e0 + scans, 0.0);
        }
        {
            // The readings into the channel columns, row after row, then converted in place.
            let dst = buf.raw.each_mut().map(|c| &mut c[e0..e0 + scans]);
            let columns: [usize; CHANNEL_COUNT] = std::array::from_fn(|k| c.fronts[k].column);
            for (i, row) in values.chunks_exact(width).enumerate() {
                for k in 0..CHANNEL_COUNT {
                    dst[k][i] = row[columns[k]];
                }
            }
        }
        let mut in_range = true;
        for (f, col) in c.fronts.iter().zip(buf.raw.iter_mut()) {
            in_range &= f.calibrate(c.units, &mut col[e0..]);
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
                        f.last_good = value;
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

        // De-skew: scan `n` gives time index `m = n - L`, once the stencils' reach back is in.
        let (first_n, end_n) = (n0.max(ahead + back), n0 + scans as u64);
        if first_n < end_n {
            let count = (end_n - first_n) as usize;
            let m0 = first_n - ahead;
            for ((f, raw), y) in c.fronts.iter().zip(&buf.raw).zip(buf.deskewed.iter_mut()) {
                // `m0 + start >= m0 - lookback >= raw_first` (the raw columns keep the last
                // `L + lookback` scans) and the stencil's last reading is `<= end_n - 1`.
                let from = (m0 as i64 + f.start as i64 - buf.raw_first as i64) as usize;
                y.resize(count, 0.0);
                stencil_any(&f.weights, &raw[from..], y);
            }
            // Kinematics (`r` = the mean of ends A and B, tilt = their difference) and the
            // applied force, as frames of the low-pass's eight lanes.
            let [a_x, a_y, b_x, b_y, frame_x, frame_y, f1, f2, f3, temperature] = &buf.deskewed;
            buf.frames.clear();
            buf.frames.extend((0..count).map(|i| {
                let [x, tx] = kinematics::mean_and_difference(a_x[i], b_x[i]);
                let [y, ty] = kinematics::mean_and_difference(a_y[i], b_y[i]);
                let [fx, fy] = c.chain.applied.at(f1[i], f2[i], f3[i]);
                [x, y, tx, ty, frame_x[i], frame_y[i], fx, fy]
            }));

            // Low-pass: index `p = m - lookback`, started in the steady state of its first input.
            let p0 = c.lowpassed;
            c.lowpassed += count as u64;
            let st = c.forward.get_or_insert_with(|| c.chain.lowpass.forward_steady(buf.frames[0]));
            c.chain.lowpass.forward_run(st, &mut buf.frames);
            let fe = (p0 - buf.filtered_first) as usize;
            for col in buf.filtered.iter_mut() {
                col.resize(fe + count, 0.0);
            }
            let [l0, l1, l2, l3, l4, l5, l6, l7, o_f3, o_t] = &mut buf.filtered;
            simd.transpose8(&mut [l0, l1, l2, l3, l4, l5, l6, l7].map(|c| &mut c[..]), fe, &mut buf.frames, false);
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
        let (volts, value) = match units {
            RawUnits::Volts => (r, (r - self.offset_v) * self.gain),
            RawUnits::Si => (self.offset_v + self.sensitivity * r, r),
        };
        (value, (volts > self.lo_v) & (volts < self.hi_v) & value.is_finite())
    }

    /// The channel's readings in `col` converted to SI in place; `false` if any is out of
    /// range (the caller then redoes the block holding values).
    #[inline(always)]
    fn calibrate(&self, units: RawUnits, col: &mut [f64]) -> bool {
        // A count rather than a short-circuit `all`, so that the loop vectorises.
        let mut bad = 0u64;
        for c in col.iter_mut() {
            let (v, ok) = self.read(units, *c);
            *c = v;
            bad += u64::from(!ok);
        }
        bad == 0
    }
}

#[cfg(test)]
mod tests {
    //! The block path against the chain run scan by scan through ring buffers, written
    //! plainly here as the reference: the same bits for every cutting of the input, with
    //! out-of-range readings in it, on every instruction set.

    use super::*;
    use crate::pipeline;
    use crate::simd::Isa;
    use oilfilm_physics::config::RigConfig;

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

    /// The scan-by-scan chain: a fresh [`CausalChain`]'s design and state, the low-pass's
    /// state per section (`x[n-1]`, `y[n-1]`, `q[n]` of six lanes) and the rings.
    struct ScanByScan {
        c: CausalChain,
        iir: Vec<[[f64; 6]; 3]>,
        raw: Ring<CHANNEL_COUNT>,
        filtered: Ring<8>,
        velocity: Ring<4>,
    }

    impl ScanByScan {
        fn new(fresh: &CausalChain) -> Self {
            let (d, m) = (fresh.delays, fresh.chain.derivative.half_length());
            let sections = fresh.chain.lowpass.sections().len();
            Self { c: fresh.clone(), iir: vec![[[0.0; 6]; 3]; sections], raw: Ring::new(d.lookahead + d.lookback + 1), filtered: Ring::new(4 * m + 1), velocity: Ring::new(2 * m + 1) }
        }

        fn push(&mut self, values: &[f64], out: &mut CausalOutput) {
            for row in values.chunks_exact(self.c.width) {
                self.push_scan(row, out);
            }
        }

        /// One sample of six lanes through the sections; `first` starts each in the DC steady
        /// state of its first input. `y = (b0 x + q) - a1 y[n-1]`, `q = (b1 x + b2 x[n-1]) -
        /// a2 y[n-1]`.
        fn lowpass(&mut self, mut x: [f64; 6], first: bool) -> [f64; 6] {
            for (s, [x1, y1, q]) in self.c.chain.lowpass.sections().iter().zip(self.iir.iter_mut()) {
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
            let n = self.c.scans;
            self.c.scans += 1;
            // Calibration and range check.
            let mut si = [0.0; CHANNEL_COUNT];
            for (k, f) in self.c.fronts.iter_mut().enumerate() {
                let r = row[f.column];
                let (volts, value) = match self.c.units {
                    RawUnits::Volts => (r, (r - f.offset_v) * f.gain),
                    RawUnits::Si => (f.offset_v + f.sensitivity * r, r),
                };
                if volts > f.lo_v && volts < f.hi_v && value.is_finite() {
                    f.last_good = value;
                } else {
                    let d = self.c.delays;
                    let through = n + (d.lookback + d.settling + d.derivative) as u64;
                    self.c.invalid_through = Some(self.c.invalid_through.map_or(through, |t| t.max(through)));
                    match out.violations.iter_mut().rev().find(|v| v.channel == f.channel) {
                        Some(v) if v.index as u64 + v.count as u64 == n => v.count += 1,
                        _ => out.violations.push(RangeViolation { channel: f.channel, index: n as usize, value_si: value, range_si: f.range_si, count: 1 }),
                    }
                }
                si[k] = f.last_good;
            }
            self.raw.set(n, si);
            let d = self.c.delays;
            if n < (d.lookahead + d.lookback) as u64 {
                return;
            }
            // De-skew: time index m = n - L.
            let m = n - d.lookahead as u64;
            let mut s = [0.0; CHANNEL_COUNT];
            for (k, f) in self.c.fronts.iter().enumerate() {
                let base = m as i64 + f.start as i64;
                let mut acc = f.weights[0] * self.raw.at(base as u64)[k];
                for (j, &w) in f.weights.iter().enumerate().skip(1) {
                    acc += w * self.raw.at((base + j as i64) as u64)[k];
                }
                s[k] = acc;
            }
            let [a_x, a_y, b_x, b_y, frame_x, frame_y, f1, f2, f3, temperature] = s;
            let [fx, fy] = self.c.chain.applied.at(f1, f2, f3);
            let p = self.c.lowpassed;
            self.c.lowpassed += 1;
            let y = self.lowpass([0.5 * (a_x + b_x), 0.5 * (a_y + b_y), frame_x, frame_y, fx, fy], p == 0);
            self.filtered.set(p, [y[0], y[1], y[2], y[3], y[4], y[5], f3, temperature]);
            // Velocity at p - M, acceleration (and every output) at p - 2M.
            let sg = self.c.chain.derivative.coefficients().to_vec();
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
            let v = derivative(&|i| {
                let f = self.filtered.at(i);
                [f[0], f[1], f[2], f[3]]
            }, q);
            self.velocity.set(q, v);
            // Time index of the low-passed sample `r`: the first de-skewed one is `lookback`.
            let r = p - 2 * mh;
            let time = r + d.lookback as u64;
            if r < (d.settling + d.derivative) as u64 {
                return;
            }
            let a = derivative(&|i| *self.velocity.at(i), r);
            let here = *self.filtered.at(r);
            let vel = *self.velocity.at(r);
            if out.is_empty() {
                out.first_index = time;
            }
            out.x_m.push(here[0]);
            out.y_m.push(here[1]);
            out.vx_m_s.push(vel[0]);
            out.vy_m_s.push(vel[1]);
            out.ax_m_s2.push(a[0]);
            out.ay_m_s2.push(a[1]);
            let mass = self.c.chain.mechanics().housing_mass_kg;
            let fx = here[4] - mass * a[2];
            let fy = here[5] - mass * a[3];
            out.fx_n.push(fx);
            out.fy_n.push(fy);
            out.static_load_n.push(here[6]);
            out.temperature_c.push(here[7]);
            let finite = [here[0], here[1], vel[0], vel[1], a[0], a[1], fx, fy].iter().all(|v| v.is_finite());
            out.valid.push(finite && self.c.invalid_through.is_none_or(|t| time > t));
        }
    }

    /// Where two outputs first differ in any bit, or `None`.
    fn first_difference(a: &CausalOutput, b: &CausalOutput) -> Option<String> {
        if a.first_index != b.first_index {
            return Some(format!("first_index {} against {}", a.first_index, b.first_index));
        }
        let columns = |o: &CausalOutput| [&o.x_m, &o.y_m, &o.vx_m_s, &o.vy_m_s, &o.ax_m_s2, &o.ay_m_s2, &o.fx_n, &o.fy_n, &o.temperature_c, &o.static_load_n].map(|c| c.clone());
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
                let v = mid + amp * (0.6 * (std::f64::consts::TAU * f1 * t).sin() + 0.3 * (std::f64::consts::TAU * f2 * t + 0.4).cos() + 0.1 * (2.0 * noise.next() - 1.0));
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
        let mut bad = vec![(0, ChannelId::F1, high(ChannelId::F1)), (scans / 5, ChannelId::ProbeAX, f64::NAN), (scans / 3, ChannelId::F3, f64::INFINITY), (scans / 3, ChannelId::ProbeBY, -1e9)];
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

    fn run_blocks(chain: &CausalChain, isa: Isa, values: &[f64], sizes: &[usize]) -> CausalOutput {
        let mut chain = chain.clone();
        chain.chain = chain.chain.with_isa(isa);
        let mut out = CausalOutput::default();
        let mut at = 0;
        for &s in sizes {
            let block = &values[at * chain.width..(at + s) * chain.width];
            chain.push(block, &mut out).unwrap();
            at += s;
        }
        out
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
            (ConditioningConfig { lowpass_order: 3, lowpass_cutoff_hz: 150.0, differentiator_half_length: 3, deskew_taps: 6, ..base.clone() }, RawUnits::Volts, 6_000, 0),
            (ConditioningConfig { lowpass_order: 5, lowpass_cutoff_hz: 300.0, differentiator_half_length: 8, ..base.clone() }, RawUnits::Si, 6_000, 6),
            (ConditioningConfig { lowpass_order: 6, lowpass_cutoff_hz: 400.0, deskew_taps: 2, ..base.clone() }, RawUnits::Volts, 6_000, 2),
        ];
        let mut noise = Noise(0x9E37_79B9_7F4A_7C15);
        for (n, (config, units, scans, extra)) in configs.iter().enumerate() {
            let (values, columns, width) = record(&cal, *units, *scans, *extra, 1 + n as u64);
            let fresh = CausalChain::new(&columns, width, *units, cal.sample_rate_hz(), &cal, &mech, config).unwrap();
            let mut reference = ScanByScan::new(&fresh);
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
                    let got = run_blocks(&fresh, isa, &values, sizes);
                    if let Some(diff) = first_difference(&got, &expected) {
                        panic!("config {n}, {isa:?}, blocks {:?}...: {diff}", &sizes[..sizes.len().min(5)]);
                    }
                }
            }
        }
    }

    #[test]
    fn the_comparison_sees_one_tap_changed_by_one_ulp() {
        // What the test above compares would catch a single coefficient of any stage off by
        // the least bit: a de-skew tap, a low-pass coefficient, a differentiator tap.
        let rig = RigConfig::zhou2004().unwrap();
        let cal = rig.daq.calibration();
        let config = ConditioningConfig { lowpass_cutoff_hz: 55.5, ..ConditioningConfig::default() };
        let (values, columns, width) = record(&cal, RawUnits::Volts, 8_000, 0, 7);
        let fresh = CausalChain::new(&columns, width, RawUnits::Volts, cal.sample_rate_hz(), &cal, &pipeline::mechanics_of(&rig), &config).unwrap();
        let sizes = cutting(8_000, Some(500), &mut Noise(3));
        let got = run_blocks(&fresh, Isa::current(), &values, &sizes);
        type Coefficient = fn(&mut CausalChain) -> &mut f64;
        let coefficients: [(&str, Coefficient); 3] = [
            ("de-skew tap", |c| &mut c.fronts[2].weights[1]),
            ("low-pass b1", |c| &mut c.chain.lowpass.sections_mut()[1].b[1]),
            ("differentiator c2", |c| &mut c.chain.derivative.coefficients_mut()[1]),
        ];
        for (what, coefficient) in coefficients {
            let mut changed = fresh.clone();
            let v = coefficient(&mut changed);
            *v = f64::from_bits(v.to_bits() + 1);
            let mut reference = ScanByScan::new(&changed);
            let mut expected = CausalOutput::default();
            reference.push(&values, &mut expected);
            assert!(first_difference(&got, &expected).is_some(), "{what} one ulp off went unnoticed");
        }
        // And unchanged, the same.
        let mut expected = CausalOutput::default();
        ScanByScan::new(&fresh).push(&values, &mut expected);
        assert_eq!(first_difference(&got, &expected), None);
    }
}
