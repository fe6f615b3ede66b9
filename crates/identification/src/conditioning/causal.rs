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
//! ## Bit for bit
//! Each scan goes through the same operations in the same order whatever block it came in,
//! so the output does not depend on how the input was cut (tested with several block sizes).

use std::ops::Range;

use oilfilm_physics::daq::{Calibration, ChannelId, CHANNEL_COUNT};

use super::{deskew, differentiate, film_force, lowpass, range_check, ConditioningConfig, Mechanics, RangeViolation, RawUnits};
use crate::IdentificationError;

/// Columns through the low-pass: `x, y` (relative), `X, Y` (housing), `F_x, F_y` (applied).
const LANES: usize = 6;

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
}

/// The delays [`CausalChain::new`] will have for this calibration, configuration and rate.
pub fn delays(calibration: &Calibration, config: &ConditioningConfig, sample_rate_hz: f64) -> Result<CausalDelays, IdentificationError> {
    let (lp, sg, stencils) = design(calibration, config, sample_rate_hz)?;
    Ok(delays_of(&lp, &sg, &stencils))
}

type Stencil = (isize, Vec<f64>);

fn design(calibration: &Calibration, config: &ConditioningConfig, fs: f64) -> Result<(lowpass::Butterworth, differentiate::SavitzkyGolayDerivative, Vec<Stencil>), IdentificationError> {
    config.validate(fs)?;
    let order = causal_order(config);
    if order > lowpass::MAX_ORDER {
        return Err(IdentificationError::invalid(
            "conditioning.lowpass_order",
            format!("the causal chain runs order 2 x lowpass_order, at most {}: lowpass_order must be <= {}, got {}", lowpass::MAX_ORDER, lowpass::MAX_ORDER / 2, config.lowpass_order),
        ));
    }
    let lp = lowpass::Butterworth::design(order, config.lowpass_cutoff_hz, fs)?;
    let sg = differentiate::SavitzkyGolayDerivative::new(config.differentiator_half_length, fs)?;
    let mut stencils = Vec::with_capacity(CHANNEL_COUNT);
    for &ch in &ChannelId::ALL {
        if config.deskew {
            let d = deskew::FractionalDelay::for_offset(calibration.sample_offset_s(ch)?, fs, config.deskew_taps)?;
            stencils.push((d.stencil_start(), d.weights().to_vec()));
        } else {
            stencils.push((0, vec![1.0]));
        }
    }
    Ok((lp, sg, stencils))
}

fn delays_of(lp: &lowpass::Butterworth, sg: &differentiate::SavitzkyGolayDerivative, stencils: &[Stencil]) -> CausalDelays {
    let ahead = stencils.iter().map(|(s, w)| s + w.len() as isize - 1).max().unwrap_or(0).max(0) as usize;
    let back = stencils.iter().map(|(s, _)| -s).max().unwrap_or(0).max(0) as usize;
    CausalDelays { lookahead: ahead, lookback: back, derivative: 2 * sg.half_length(), settling: lp.settling_samples() }
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

/// One second-order section's state for every lane, direct form I.
#[derive(Copy, Clone, Debug, Default)]
struct SectionState {
    x1: [f64; LANES],
    x2: [f64; LANES],
    y1: [f64; LANES],
    y2: [f64; LANES],
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

/// A ring of `N`-wide rows, indexed by an ever-growing counter.
#[derive(Clone, Debug)]
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

    #[inline(always)]
    fn at(&self, i: u64) -> &[f64; N] {
        &self.rows[(i as usize) & self.mask]
    }

    #[inline(always)]
    fn set(&mut self, i: u64, row: [f64; N]) {
        self.rows[(i as usize) & self.mask] = row;
    }
}

/// The causal chain's state. Build one per stream; push scans in order.
#[derive(Clone)]
pub struct CausalChain {
    units: RawUnits,
    width: usize,
    fronts: Vec<Front>,
    applied: film_force::Applied,
    mass_kg: f64,
    sections: Vec<lowpass::Section>,
    /// `c_1 .. c_M`, per second.
    sg: Vec<f64>,
    delays: CausalDelays,
    /// SI readings (in-range, or held) by channel index.
    raw: Ring<CHANNEL_COUNT>,
    /// Low-passed `x, y, X, Y, F_x, F_y`, then the unfiltered `f3`, temperature.
    filtered: Ring<8>,
    /// `x', y', X', Y'`.
    velocity: Ring<4>,
    iir: Vec<SectionState>,
    /// Scans pushed.
    scans: u64,
    /// Samples through the low-pass.
    lowpassed: u64,
    /// Outputs with a time index `<=` this are invalid (a violation reaches them).
    invalid_through: Option<u64>,
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
        mechanics.validate()?;
        let (lp, sg, stencils) = design(calibration, config, sample_rate_hz)?;
        let delays = delays_of(&lp, &sg, &stencils);
        let mut fronts = Vec::with_capacity(CHANNEL_COUNT);
        for (&ch, (start, weights)) in ChannelId::ALL.iter().zip(stencils) {
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
                return Err(IdentificationError::invalid(format!("calibration.{ch}.sensitivity_v_per_unit"), format!("must be finite and non-zero with a finite offset, got {sensitivity} V/unit, offset {offset_v} V")));
            }
            let (lo_v, hi_v) = range_check::volts_bounds(ch, calibration)?;
            let [a, b] = c.linear_range_v.map(|v| (v - offset_v) / sensitivity);
            // Mid-range: what the filters see until the first in-range reading.
            let mid = 0.5 * (a + b);
            fronts.push(Front { channel: ch, column, offset_v, sensitivity, gain: 1.0 / sensitivity, lo_v, hi_v, range_si: [a.min(b), a.max(b)], start, weights, last_good: if mid.is_finite() { mid } else { 0.0 } });
        }
        let m = sg.half_length();
        Ok(Self {
            units,
            width,
            fronts,
            applied: film_force::Applied::new(mechanics),
            mass_kg: mechanics.housing_mass_kg,
            sections: lp.sections().to_vec(),
            sg: sg.coefficients().to_vec(),
            raw: Ring::new(delays.lookahead + delays.lookback + 1),
            filtered: Ring::new(4 * m + 1),
            velocity: Ring::new(2 * m + 1),
            iir: vec![SectionState::default(); lp.sections().len()],
            delays,
            scans: 0,
            lowpassed: 0,
            invalid_through: None,
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
    /// samples they complete to `out`.
    pub fn push(&mut self, values: &[f64], out: &mut CausalOutput) -> Result<(), IdentificationError> {
        if !values.len().is_multiple_of(self.width) {
            return Err(IdentificationError::BadInput { what: "scan values".into(), reason: format!("{} values are not whole scans of {} readings", values.len(), self.width) });
        }
        for row in values.chunks_exact(self.width) {
            self.push_scan(row, out);
        }
        Ok(())
    }

    fn push_scan(&mut self, row: &[f64], out: &mut CausalOutput) {
        let n = self.scans;
        self.scans += 1;
        // Calibration and range check.
        let mut si = [0.0; CHANNEL_COUNT];
        for (k, f) in self.fronts.iter_mut().enumerate() {
            let r = row[f.column];
            let (volts, value) = match self.units {
                RawUnits::Volts => (r, (r - f.offset_v) * f.gain),
                RawUnits::Si => (f.offset_v + f.sensitivity * r, r),
            };
            if volts > f.lo_v && volts < f.hi_v && value.is_finite() {
                f.last_good = value;
            } else {
                let d = self.delays;
                let through = n + (d.lookback + d.settling + d.derivative) as u64;
                self.invalid_through = Some(self.invalid_through.map_or(through, |t| t.max(through)));
                match out.violations.iter_mut().rev().find(|v| v.channel == f.channel) {
                    Some(v) if v.index as u64 + v.count as u64 == n => v.count += 1,
                    _ => out.violations.push(RangeViolation { channel: f.channel, index: n as usize, value_si: value, range_si: f.range_si, count: 1 }),
                }
            }
            si[k] = f.last_good;
        }
        self.raw.set(n, si);
        let d = self.delays;
        if n < (d.lookahead + d.lookback) as u64 {
            return;
        }
        // De-skew: time index m = n - L.
        let m = n - d.lookahead as u64;
        let mut s = [0.0; CHANNEL_COUNT];
        for (k, f) in self.fronts.iter().enumerate() {
            let base = m as i64 + f.start as i64;
            let mut acc = 0.0;
            for (j, &w) in f.weights.iter().enumerate() {
                acc += w * self.raw.at((base + j as i64) as u64)[k];
            }
            s[k] = acc;
        }
        let [a_x, a_y, b_x, b_y, frame_x, frame_y, f1, f2, f3, temperature] = s;
        let [fx, fy] = self.applied.at(f1, f2, f3);
        let lanes = [0.5 * (a_x + b_x), 0.5 * (a_y + b_y), frame_x, frame_y, fx, fy];
        let p = self.lowpassed;
        self.lowpassed += 1;
        let y = self.lowpass(lanes, p == 0);
        self.filtered.set(p, [y[0], y[1], y[2], y[3], y[4], y[5], f3, temperature]);
        // Velocity at p - M, acceleration (and every output) at p - 2M.
        let mh = self.sg.len() as u64;
        if p < 2 * mh {
            return;
        }
        let q = p - mh;
        let mut v = [0.0; 4];
        for (k, &c) in self.sg.iter().enumerate() {
            let (ahead, behind) = (self.filtered.at(q + k as u64 + 1), self.filtered.at(q - k as u64 - 1));
            for l in 0..4 {
                v[l] += c * (ahead[l] - behind[l]);
            }
        }
        self.velocity.set(q, v);
        // Time index of the low-passed sample `r`: the first de-skewed one is `lookback`.
        let r = p - 2 * mh;
        let time = r + d.lookback as u64;
        if r < (d.settling + d.derivative) as u64 {
            return;
        }
        let mut a = [0.0; 4];
        for (k, &c) in self.sg.iter().enumerate() {
            let (ahead, behind) = (self.velocity.at(r + k as u64 + 1), self.velocity.at(r - k as u64 - 1));
            for l in 0..4 {
                a[l] += c * (ahead[l] - behind[l]);
            }
        }
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
        let fx = here[4] - self.mass_kg * a[2];
        let fy = here[5] - self.mass_kg * a[3];
        out.fx_n.push(fx);
        out.fy_n.push(fy);
        out.static_load_n.push(here[6]);
        out.temperature_c.push(here[7]);
        let finite = [here[0], here[1], vel[0], vel[1], a[0], a[1], fx, fy].iter().all(|v| v.is_finite());
        out.valid.push(finite && self.invalid_through.is_none_or(|t| time > t));
    }

    /// One sample of every lane through the cascade; `first`: start every section in the DC
    /// steady state of this input.
    #[inline(always)]
    fn lowpass(&mut self, mut x: [f64; LANES], first: bool) -> [f64; LANES] {
        for (s, st) in self.sections.iter().zip(self.iir.iter_mut()) {
            let [b0, b1, b2] = s.b;
            let [a1, a2] = s.a;
            if first {
                let g = (b0 + b1 + b2) / (1.0 + a1 + a2);
                let y = x.map(|v| g * v);
                *st = SectionState { x1: x, x2: x, y1: y, y2: y };
            }
            let mut y = [0.0; LANES];
            for l in 0..LANES {
                y[l] = b0 * x[l] + b1 * st.x1[l] + b2 * st.x2[l] - a1 * st.y1[l] - a2 * st.y2[l];
            }
            st.x2 = st.x1;
            st.x1 = x;
            st.y2 = st.y1;
            st.y1 = y;
            x = y;
        }
        x
    }
}
