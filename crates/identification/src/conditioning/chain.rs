//! The prepared conditioning chain: its filters designed once from the calibration, the
//! rig's mechanics and the configuration (as a planner prepares an FFT), and the front end
//! and the record driver every way of running the chain shares (ADR 0022).
//!
//! A record goes through [`Chain`] in one fused pass per filter direction
//! ([`Chain::condition_window_into`]): the front end runs tile by tile ([`front_tile`])
//! straight into the low-pass, whose backward pass feeds the derivatives and eq. 2
//! ([`Derivatives`]). Every value is formed by the same operations in the same order as the
//! stages written out plainly in `tests/reference.rs`: `tests/chain.rs` checks the bits.
//! The zero-phase stream ([`super::stream`]) and the causal chain ([`super::causal`]) are
//! drivers over the same object and kernels.
//!
//! Design: docs/manual/conditioning.md#one-prepared-chain.

use std::ops::Range;

use oilfilm_physics::daq::{Calibration, ChannelId, CHANNEL_COUNT};

use super::deskew::{stencil, FractionalDelay, MAX_TAPS};
use super::differentiate::{SavitzkyGolayDerivative, TwiceDescending};
use super::film_force::Applied;
use super::lowpass::{Butterworth, Consume8, Produce8, MAX_ORDER};
use super::{columns_of, kinematics, non_finite_error, range_check, too_short, Conditioned, ConditioningConfig, Mechanics, Work};
use crate::record::{RawRecord, RawUnits};
use crate::simd::{self, all_finite, first_non_finite, Isa, Kernel, Simd};
use crate::IdentificationError;

/// Scans per tile of the front end (ten channels of 256 samples: 20 kB, L1-resident).
pub(super) const TILE: usize = 256;

/// The conditioning chain for one calibration, rig and configuration at one sample rate.
#[derive(Clone, Debug)]
pub struct Chain {
    isa: Isa,
    sample_rate_hz: f64,
    calibration: Calibration,
    mechanics: Mechanics,
    pub(super) lowpass: Butterworth,
    pub(super) derivative: SavitzkyGolayDerivative,
    /// By channel index: the de-skew stencil (the identity without de-skew).
    pub(super) delays: [FractionalDelay; CHANNEL_COUNT],
    pub(super) applied: Applied,
    edge: usize,
}

impl Chain {
    /// Designs the zero-phase chain. Every field is checked; errors name it
    /// (`conditioning.lowpass_cutoff_hz`, `mechanics.housing_mass_kg`, ...).
    pub fn new(calibration: &Calibration, mechanics: &Mechanics, config: &ConditioningConfig, sample_rate_hz: f64) -> Result<Self, IdentificationError> {
        Self::with_order(calibration, mechanics, config, sample_rate_hz, config.lowpass_order)
    }

    /// Designs the causal chain ([`super::causal`]): its low-pass runs once, forward, so it
    /// has twice `lowpass_order` to fall as fast as the zero-phase `|H|^2`.
    pub fn causal(calibration: &Calibration, mechanics: &Mechanics, config: &ConditioningConfig, sample_rate_hz: f64) -> Result<Self, IdentificationError> {
        let order = super::causal::causal_order(config);
        if order > MAX_ORDER {
            let (most, got) = (MAX_ORDER / 2, config.lowpass_order);
            let reason = format!("the causal chain runs order 2 x lowpass_order, at most {MAX_ORDER}: lowpass_order must be <= {most}, got {got}");
            return Err(IdentificationError::invalid("conditioning.lowpass_order", reason));
        }
        Self::with_order(calibration, mechanics, config, sample_rate_hz, order)
    }

    fn with_order(calibration: &Calibration, mechanics: &Mechanics, config: &ConditioningConfig, fs: f64, order: usize) -> Result<Self, IdentificationError> {
        let lowpass = Butterworth::design(order, config.lowpass_cutoff_hz, fs)?;
        let derivative = SavitzkyGolayDerivative::new(config.differentiator_half_length, fs)?;
        config.check_taps()?;
        mechanics.validate()?;
        let mut delays: [FractionalDelay; CHANNEL_COUNT] = std::array::from_fn(|_| FractionalDelay::identity());
        if config.deskew {
            for ch in ChannelId::ALL {
                delays[ch.index()] = FractionalDelay::for_offset(calibration.sample_offset_s(ch)?, fs, config.deskew_taps)?;
            }
        }
        let trim = delays.iter().map(FractionalDelay::edge_samples).max().unwrap_or(0);
        let edge = trim + lowpass.settling_samples() + 2 * derivative.half_length();
        Ok(Self {
            isa: Isa::current(),
            sample_rate_hz: fs,
            calibration: calibration.clone(),
            mechanics: mechanics.clone(),
            lowpass,
            derivative,
            delays,
            applied: Applied::new(mechanics),
            edge,
        })
    }

    /// The same chain with its kernels on `isa` (the widest this CPU has by default; a set
    /// the CPU lacks runs as [`Isa::Scalar`]). The bits do not depend on it.
    pub fn with_isa(mut self, isa: Isa) -> Self {
        self.isa = if isa.supported() { isa } else { Isa::Scalar };
        self
    }

    pub fn isa(&self) -> Isa {
        self.isa
    }

    pub fn calibration(&self) -> &Calibration {
        &self.calibration
    }

    pub fn mechanics(&self) -> &Mechanics {
        &self.mechanics
    }

    /// Scans at each end of a conditioned record that the edge effects spoil: the de-skew
    /// stencils' reach, the low-pass's settling to 1e-7 and twice the differentiator's
    /// half-length. A record of `n` scans is valid over `edge..n - edge`.
    pub fn edge(&self) -> usize {
        self.edge
    }

    /// How far the de-skew stencils reach before and after their output scan.
    pub(super) fn reach(&self) -> (usize, usize) {
        let back = self.delays.iter().map(|d| (-d.stencil_start()).max(0) as usize).max().unwrap_or(0);
        let ahead = self.delays.iter().map(|d| (d.stencil_start() + d.taps() as isize - 1).max(0) as usize).max().unwrap_or(0);
        (back, ahead)
    }

    /// Steps 1-7 on a whole record.
    pub fn condition(&self, raw: &RawRecord) -> Result<Conditioned, IdentificationError> {
        let mut out = Conditioned::default();
        self.condition_into(raw, &mut out)?;
        // The result is kept by the caller; the low-pass's scratch is not part of it.
        out.work.scratch = Vec::new();
        Ok(out)
    }

    /// [`Chain::condition`] into `out`'s buffers: record after record into the same
    /// `Conditioned` allocates nothing of size once they are large enough. On error `out`
    /// is left empty.
    pub fn condition_into(&self, raw: &RawRecord, out: &mut Conditioned) -> Result<(), IdentificationError> {
        self.condition_window_into(raw, 0..raw.len(), out)
    }

    /// Steps 1-7 on the scans `window` of `raw`, into `out`'s buffers (nothing of size is
    /// allocated once they are large enough). The result (indices, `valid`, range violations,
    /// bits) is the one a record of only those scans, starting `window.start` scans later,
    /// gives. On error `out` is left empty.
    pub fn condition_window_into(&self, raw: &RawRecord, window: Range<usize>, out: &mut Conditioned) -> Result<(), IdentificationError> {
        let result = self.fill(raw, window, out);
        if result.is_err() {
            *out = Conditioned { work: std::mem::take(&mut out.work), ..Conditioned::default() };
        }
        result
    }

    /// [`Chain::condition_window_into`], each column written in its own buffer.
    fn fill(&self, raw: &RawRecord, window: Range<usize>, out: &mut Conditioned) -> Result<(), IdentificationError> {
        raw.validate_shape()?;
        if window.end > raw.len() || window.start > window.end {
            return Err(IdentificationError::BadInput { what: "window".into(), reason: format!("scans {window:?} of a record of {} scans", raw.len()) });
        }
        if raw.sample_rate_hz.to_bits() != self.sample_rate_hz.to_bits() {
            return Err(IdentificationError::invalid(
                "sample_rate_hz",
                format!("the record has {} Hz, the chain was designed for {} Hz", raw.sample_rate_hz, self.sample_rate_hz),
            ));
        }
        let col_of = columns_of(&raw.channels, "record")?;
        let n = window.len();
        if n <= 2 * self.edge {
            return Err(too_short(n, self.edge));
        }
        let valid = self.edge..n - self.edge;
        let mut tiles = FrontTiles::new(self, raw, &window, &col_of)?;
        #[rustfmt::skip]
        let Conditioned {
            t_s, x_m, y_m, tilt_x_m, tilt_y_m, vx_m_s, vy_m_s, ax_m_s2, ay_m_s2, housing_x_m, housing_y_m, housing_ax_m_s2, housing_ay_m_s2,
            fx_n, fy_n, temperature_c, static_load_n, range_violations, work: Work { velocity: [hvx, hvy], scratch }, ..
        } = &mut *out;
        #[rustfmt::skip]
        let columns = [
            &mut *t_s, &mut *x_m, &mut *y_m, &mut *tilt_x_m, &mut *tilt_y_m, &mut *vx_m_s, &mut *vy_m_s, &mut *ax_m_s2, &mut *ay_m_s2,
            &mut *housing_x_m, &mut *housing_y_m, &mut *housing_ax_m_s2, &mut *housing_ay_m_s2, &mut *fx_n, &mut *fy_n, &mut *temperature_c,
            &mut *static_load_n, &mut *hvx, &mut *hvy,
        ];
        for v in columns {
            // Every value is overwritten: a buffer long enough is only cut, a short one
            // replaced by zeroed memory straight from the allocator (no fill pass).
            if v.capacity() < n {
                *v = vec![0.0; n];
            }
            v.resize(n, 0.0);
        }
        range_violations.clear();
        // The record's load and temperature columns are the front end's while it runs.
        std::mem::swap(&mut tiles.s.load, static_load_n);
        std::mem::swap(&mut tiles.s.temp, temperature_c);
        let filter = Filter {
            chain: self,
            producer: &mut tiles,
            dynamic: [x_m, y_m, tilt_x_m, tilt_y_m, housing_x_m, housing_y_m, fx_n, fy_n].map(|c| &mut c[..]),
            derived: [[vx_m_s, ax_m_s2], [vy_m_s, ay_m_s2], [hvx, housing_ax_m_s2], [hvy, housing_ay_m_s2]].map(|p| p.map(|c| &mut c[..])),
            times: t_s,
            scratch,
            valid: valid.clone(),
            t0: raw.start_time_s + window.start as f64 / self.sample_rate_hz,
        };
        let filtered = simd::dispatch(self.isa, filter);
        std::mem::swap(&mut tiles.s.load, &mut out.static_load_n);
        std::mem::swap(&mut tiles.s.temp, &mut out.temperature_c);
        let mut outcome = filtered?.ok_or_else(|| IdentificationError::invalid("conditioning", "the derivatives did not cover the record"))?;
        if tiles.bad > 0 || raw.units == RawUnits::Si {
            // The front end counted what it could not use (or does not check an SI record's
            // range): name it.
            self.explain(&tiles.chans, raw.units, &mut out.range_violations)?;
            outcome.finite &= all_finite(&out.temperature_c);
        }
        // Finite inputs can still overflow in the filters (|x| near f64::MAX): never hand a
        // non-finite number on. The stages checked their final outputs as they wrote them;
        // only if one of them saw a non-finite value are the columns searched, to name it.
        if !outcome.finite {
            let o = &*out;
            for (name, col) in [
                ("x_m", &o.x_m),
                ("y_m", &o.y_m),
                ("tilt_x_m", &o.tilt_x_m),
                ("tilt_y_m", &o.tilt_y_m),
                ("ax_m_s2", &o.ax_m_s2),
                ("ay_m_s2", &o.ay_m_s2),
                ("fx_n", &o.fx_n),
                ("fy_n", &o.fy_n),
                ("temperature_c", &o.temperature_c),
            ] {
                if let Some(i) = first_non_finite(col) {
                    return Err(IdentificationError::BadInput {
                        what: format!("conditioned `{name}`, sample {i}"),
                        reason: "not finite after conditioning: an input magnitude overflowed".into(),
                    });
                }
            }
        }
        out.static_force_n = outcome.static_force_n;
        out.valid = valid;
        Ok(())
    }

    /// Names what the front end could not use, from its channels `chans` (in [`ChannelId::ALL`]
    /// order, their readings in `units`): a reading that is not finite, or that does not
    /// convert to a finite value, is an error naming its channel and sample; readings out of
    /// the linear range (step 2) are reported in `violations`.
    fn explain(&self, chans: &[FrontChannel<'_>], units: RawUnits, violations: &mut Vec<super::RangeViolation>) -> Result<(), IdentificationError> {
        for (ch, c) in ChannelId::ALL.into_iter().zip(chans) {
            let column = c.readings;
            if let Some(i) = column.iter().position(|&v| !c.k.si(v).is_finite()) {
                if !column[i].is_finite() {
                    return Err(non_finite_error(ch, i, column[i], units.name()));
                }
                let sensitivity = self.calibration.channel(ch)?.sensitivity_v_per_unit;
                return Err(IdentificationError::BadInput {
                    what: format!("channel `{ch}`, sample {i}"),
                    reason: format!("{} V does not convert to a finite {} with sensitivity {sensitivity}", column[i], ch.unit()),
                });
            }
            if let Some(v) = range_check::check(ch, column, units, &self.calibration)? {
                violations.push(v);
            }
        }
        Ok(())
    }
}

/// What the filter pass tells the record driver: whether every final output is finite, and
/// eq. 2's static part.
#[derive(Clone, Copy, Default)]
struct Outcome {
    finite: bool,
    static_force_n: [f64; 2],
}

/// The low-pass, the derivatives and eq. 2 over a window fed by `producer`, as a [`Kernel`].
struct Filter<'a, P> {
    chain: &'a Chain,
    producer: &'a mut P,
    dynamic: [&'a mut [f64]; 8],
    /// `[first, second]` derivative of x, y, X, Y.
    derived: [[&'a mut [f64]; 2]; 4],
    times: &'a mut [f64],
    scratch: &'a mut Vec<f64>,
    valid: Range<usize>,
    t0: f64,
}

impl<P: Produce8<Error = IdentificationError>> Kernel for Filter<'_, P> {
    /// `None`: the derivatives did not cover the window.
    type Output = Result<Option<Outcome>, IdentificationError>;

    #[inline(always)]
    fn run<S: Simd>(self, simd: S) -> Self::Output {
        let Filter { chain, producer, mut dynamic, derived, times, scratch, valid, t0 } = self;
        let mut d = Derivatives::new(simd, chain, derived);
        let filtered = chain.lowpass.filtfilt8_fed(simd, dynamic.each_mut().map(|c| &mut **c), scratch, TILE, producer, &mut d)?;
        if !d.complete() {
            return Ok(None);
        }
        let finite = filtered && d.finite();
        let [.., fx, fy] = &dynamic;
        Ok(Some(Outcome { finite, static_force_n: static_part_and_times(fx, fy, valid, t0, chain.sample_rate_hz, times) }))
    }
}

/// What the backward pass hands its final output to ([`Consume8`]), range by range while it
/// is in cache: the first and second derivatives of `x`, `y` (r', r'') and of the housing's
/// `X`, `Y` (velocity, `X''`), and eq. 2's inertial part `F -= m X''` on the film force. The
/// same operations on the same values as the stages after the low-pass, only in another order
/// of samples, so the same bits.
pub(super) struct Derivatives<'a, S> {
    simd: S,
    sg: &'a SavitzkyGolayDerivative,
    mass_kg: f64,
    /// `[first, second]` derivative of x, y, X, Y.
    out: [[&'a mut [f64]; 2]; 4],
    state: [TwiceDescending; 4],
    /// r'' (x, y) and the forces all finite so far.
    finite: bool,
    /// Every column had the length of the filtered ones.
    fits: bool,
    /// The last call had `from == 0`.
    at_start: bool,
}

impl<'a, S: Simd> Derivatives<'a, S> {
    pub(super) fn new(simd: S, chain: &'a Chain, out: [[&'a mut [f64]; 2]; 4]) -> Self {
        Self {
            simd,
            sg: &chain.derivative,
            mass_kg: chain.mechanics.housing_mass_kg,
            out,
            state: Default::default(),
            finite: true,
            fits: true,
            at_start: false,
        }
    }

    /// Every output is written.
    pub(super) fn complete(&self) -> bool {
        self.fits && self.at_start
    }

    pub(super) fn finite(&self) -> bool {
        self.finite
    }
}

impl<S: Simd> Consume8 for Derivatives<'_, S> {
    type Error = IdentificationError;

    #[inline(always)]
    fn consume(&mut self, from: usize, cols: &mut [&mut [f64]; 8]) -> Result<(), IdentificationError> {
        let [x, y, _, _, hx, hy, fx, fy] = cols;
        let [[vx, ax], [vy, ay], [hvx, hax], [hvy, hay]] = &mut self.out;
        let [sx, sy, shx, shy] = &mut self.state;
        let (sg, simd, m) = (self.sg, self.simd, self.mass_kg);
        let results = [
            sg.twice_descending(simd, sx, from, x, vx, ax),
            sg.twice_descending(simd, sy, from, y, vy, ay),
            sg.twice_descending(simd, shx, from, hx, hvx, hax),
            sg.twice_descending(simd, shy, from, hy, hvy, hay),
        ];
        // Eq. 2's inertial part on the housing accelerations made final just now.
        let mut force_finite = true;
        for (result, force, acc) in [(&results[2], &mut **fx, &**hax), (&results[3], &mut **fy, &**hay)] {
            if let Some((_, made)) = result {
                force_finite &= subtract_inertia(&mut force[made.clone()], &acc[made.clone()], m);
            }
        }
        self.fits &= results.iter().all(Option::is_some);
        self.finite &= force_finite && results[..2].iter().all(|r| r.as_ref().is_some_and(|r| r.0));
        self.at_start = from == 0;
        Ok(())
    }
}

/// Eq. 2's inertial part on a block, `f -= m a`; whether every result is finite.
#[inline(always)]
fn subtract_inertia(force: &mut [f64], acc: &[f64], mass_kg: f64) -> bool {
    // Locals, not captured state: written through a reference on every sample they kept
    // this loop scalar (a store and a reload per sample).
    let (m, mut finite) = (mass_kg, true);
    for (f, &a) in force.iter_mut().zip(acc) {
        *f -= m * a;
        finite &= f.is_finite();
    }
    finite
}

/// Eq. 2's static part (the mean of `fx`, `fy` over `valid`) and the scans' times, `t[i] =
/// t0 + i / fs`, in one pass: the static part's two sums are chains of dependent adds in index
/// order, bound by an add's latency per sample, and the times' divisions, four at a time, run
/// beside them in the pipes the chains leave idle. The same operations in the same order as
/// two plain sums (from -0.0, as `Iterator::sum`) and a plain loop over the times, so the same
/// bits (`tests/chain.rs` checks them).
#[inline(always)]
fn static_part_and_times(fx: &[f64], fy: &[f64], valid: Range<usize>, t0: f64, fs: f64, t: &mut [f64]) -> [f64; 2] {
    #[inline(always)]
    fn times(t: &mut [f64], from: usize, t0: f64, fs: f64) {
        for (i, t) in t.iter_mut().enumerate() {
            *t = t0 + (from + i) as f64 / fs;
        }
    }
    // `valid` lies inside the columns (checked by the caller); clamped anyway.
    let b = valid.end.min(t.len()).min(fx.len()).min(fy.len());
    let a = valid.start.min(b);
    let (fx, fy) = (&fx[a..b], &fy[a..b]);
    let (before, rest) = t.split_at_mut(a);
    let (inside, after) = rest.split_at_mut(b - a);
    times(before, 0, t0, fs);
    // From -0.0, as `Iterator::sum`.
    let (mut sx, mut sy) = (-0.0, -0.0);
    let (tc, tr) = inside.as_chunks_mut::<4>();
    let (xc, xr) = fx.as_chunks::<4>();
    let (yc, yr) = fy.as_chunks::<4>();
    for (q, ((tq, xq), yq)) in tc.iter_mut().zip(xc).zip(yc).enumerate() {
        let i = a + 4 * q;
        *tq = std::array::from_fn(|l| t0 + (i + l) as f64 / fs);
        for l in 0..4 {
            sx += xq[l];
            sy += yq[l];
        }
    }
    times(tr, a + 4 * tc.len(), t0, fs);
    for (&x, &y) in xr.iter().zip(yr) {
        sx += x;
        sy += y;
    }
    times(after, b, t0, fs);
    let k = (b - a) as f64;
    [sx / k, sy / k]
}

/// One channel's front-end constants.
#[derive(Copy, Clone, Debug)]
pub(super) struct Constants {
    pub(super) offset: f64,
    pub(super) gain: f64,
    /// Readings `v` with `v > lo && v < hi` are in the linear range.
    pub(super) lo: f64,
    pub(super) hi: f64,
    /// Every reading in the linear range converts to a finite value: `(v - offset) gain` is
    /// monotone in `v` (rounding is), so its values there lie between those at `lo` and `hi`,
    /// and those are finite. The per-reading check of the converted value is then skipped.
    pub(super) si_bounded: bool,
}

impl Constants {
    /// For readings of `ch` in `units`: an error naming the channel when a calibration in
    /// volts cannot convert them.
    pub(super) fn of(ch: ChannelId, units: RawUnits, calibration: &Calibration) -> Result<Self, IdentificationError> {
        if units == RawUnits::Si {
            return Ok(Self::SI);
        }
        let c = calibration.channel(ch)?;
        let (offset, sensitivity) = (c.offset_v, c.sensitivity_v_per_unit);
        if !(sensitivity.is_finite() && sensitivity != 0.0 && offset.is_finite()) {
            return Err(IdentificationError::invalid(
                format!("calibration.{ch}"),
                format!("sensitivity {sensitivity} V/unit and offset {offset} V must be finite, sensitivity non-zero"),
            ));
        }
        let (lo, hi) = range_check::volts_bounds(ch, calibration)?;
        Ok(Self::new(offset, 1.0 / sensitivity, lo, hi))
    }

    /// Every channel's constants for readings in `units`, by channel index.
    pub(super) fn all(units: RawUnits, calibration: &Calibration) -> Result<[Self; CHANNEL_COUNT], IdentificationError> {
        let mut k = [Self::SI; CHANNEL_COUNT];
        for ch in ChannelId::ALL {
            k[ch.index()] = Self::of(ch, units, calibration)?;
        }
        Ok(k)
    }

    /// Step 3: a reading's value in the channel's SI unit.
    #[inline(always)]
    pub(super) fn si(&self, v: f64) -> f64 {
        (v - self.offset) * self.gain
    }

    /// For readings already in SI: `(v - 0) 1 = v`, no range (the drivers check step 2 on
    /// the raw readings), non-finite readings counted.
    pub(super) const SI: Self = Self { offset: 0.0, gain: 1.0, lo: f64::NEG_INFINITY, hi: f64::INFINITY, si_bounded: false };

    fn new(offset: f64, gain: f64, lo: f64, hi: f64) -> Self {
        let si_bounded = ((lo - offset) * gain).is_finite() && ((hi - offset) * gain).is_finite();
        Self { offset, gain, lo, hi, si_bounded }
    }
}

/// One channel of a front-end call: its constants, stencil and raw readings.
pub(super) struct FrontChannel<'a> {
    pub(super) readings: &'a [f64],
    pub(super) k: Constants,
    pub(super) delay: &'a FractionalDelay,
    pub(super) interior: Range<usize>,
}

/// The front end's working memory ([`front_tile`]): the tile of de-skewed channels, the
/// stencil's converted readings, the bellows' load and the temperature by scan (a record's
/// own columns, or a stream tile's), and over a stream the tile's eight dynamic lanes.
#[derive(Clone)]
pub(super) struct FrontScratch {
    tile: Box<[[f64; TILE]; CHANNEL_COUNT]>,
    input: [f64; TILE + MAX_TAPS],
    load: Vec<f64>,
    temp: Vec<f64>,
    lanes: [Vec<f64>; 8],
}

impl Default for FrontScratch {
    fn default() -> Self {
        Self { tile: Box::new([[0.0; TILE]; CHANNEL_COUNT]), input: [0.0; TILE + MAX_TAPS], load: Vec::new(), temp: Vec::new(), lanes: Default::default() }
    }
}

/// What the front end appends over a stream ([`Chain::front_frames`]): each scan's eight
/// dynamic lanes `[x, y, tilt_x, tilt_y, X, Y, Fx, Fy]` (applied force), its bellows' load and
/// its temperature.
#[derive(Clone, Debug, Default)]
pub(super) struct FrontOut {
    pub(super) frames: Vec<[f64; 8]>,
    pub(super) load: Vec<f64>,
    pub(super) temp: Vec<f64>,
}

impl Chain {
    /// Channel `ch`'s part of a front-end call on `readings`.
    fn front_channel<'a>(&'a self, ch: ChannelId, readings: &'a [f64], k: Constants) -> FrontChannel<'a> {
        let delay = &self.delays[ch.index()];
        FrontChannel { readings, k, delay, interior: delay.interior(readings.len()) }
    }

    /// The front end over the output scans `out` of a stream whose raw readings of channel
    /// `k` are `cols[k]` from scan `first` on (they must hold every reading the stencils of
    /// `out` reach), appended to `into`. How many readings it found unusable.
    #[inline(always)]
    pub(super) fn front_frames(
        &self,
        constants: &[Constants; CHANNEL_COUNT],
        cols: [&[f64]; CHANNEL_COUNT],
        first: usize,
        out: Range<usize>,
        s: &mut FrontScratch,
        into: &mut FrontOut,
    ) -> Result<usize, IdentificationError> {
        let (back, ahead) = self.reach();
        // The lanes are the tile's dynamic columns: out of the scratch while it is lent too.
        let mut lanes = std::mem::take(&mut s.lanes);
        for l in &mut lanes {
            l.resize(TILE, 0.0);
        }
        let (mut p, mut bad) = (out.start, 0);
        while p < out.end {
            let q = (p + TILE).min(out.end);
            let (w0, w1) = (p - back - first, q + ahead - first);
            let mut chans = Vec::with_capacity(CHANNEL_COUNT);
            for ch in ChannelId::ALL {
                let readings = cols[ch.index()].get(w0..w1).ok_or_else(|| IdentificationError::BadInput {
                    what: format!("column `{ch}`"),
                    reason: format!("scans {}..{} of the stream missing", w0 + first, w1 + first),
                })?;
                chans.push(self.front_channel(ch, readings, constants[ch.index()]));
            }
            let o = back..back + (q - p);
            s.load.resize(o.end, 0.0);
            s.temp.resize(o.end, 0.0);
            bad += front_tile(&chans, &self.applied, w1 - w0, o.start, o.clone(), s, &mut lanes.each_mut().map(|l| &mut l[..]));
            into.frames.extend((0..q - p).map(|i| std::array::from_fn(|l| lanes[l][i])));
            into.load.extend_from_slice(&s.load[o.clone()]);
            into.temp.extend_from_slice(&s.temp[o]);
            p = q;
        }
        s.lanes = lanes;
        Ok(bad)
    }
}

/// The fused record's producer: the front end tile by tile as the low-pass asks for samples.
struct FrontTiles<'a> {
    chans: Vec<FrontChannel<'a>>,
    applied: Applied,
    len: usize,
    /// The record's load and temperature columns are the scratch's while it runs.
    s: FrontScratch,
    /// Readings out of range or not finite so far.
    bad: usize,
}

impl<'a> FrontTiles<'a> {
    /// The front end over `window` of `raw`, whose channel `c` is column `col_of[c.index()]`
    /// (the caller checked both): an error when a calibration cannot convert the readings.
    fn new(chain: &'a Chain, raw: &'a RawRecord, window: &Range<usize>, col_of: &[usize; CHANNEL_COUNT]) -> Result<Self, IdentificationError> {
        let len = window.len();
        let constants = Constants::all(raw.units, &chain.calibration)?;
        let mut chans = Vec::with_capacity(CHANNEL_COUNT);
        for ch in ChannelId::ALL {
            let readings = &raw.columns[col_of[ch.index()]][window.clone()];
            if len < chain.delays[ch.index()].taps() {
                return Err(too_short(len, chain.edge));
            }
            chans.push(chain.front_channel(ch, readings, constants[ch.index()]));
        }
        Ok(Self { chans, applied: chain.applied, len, s: FrontScratch::default(), bad: 0 })
    }
}

impl Produce8 for FrontTiles<'_> {
    type Error = IdentificationError;

    #[inline(always)]
    fn produce(&mut self, from: usize, to: usize, cols: &mut [&mut [f64]; 8]) -> Result<(), IdentificationError> {
        let mut o0 = from;
        while o0 < to {
            let o1 = (o0 + TILE).min(to);
            self.bad += front_tile(&self.chans, &self.applied, self.len, from, o0..o1, &mut self.s, cols);
            o0 = o1;
        }
        Ok(())
    }
}

/// Calibration (step 3), range count (step 2), de-skew (step 4) and the linear combinations
/// of steps 5 and 7 for the scans `o.start..o.end` (at most [`TILE`]) of a window of `len`
/// scans whose dynamic columns start at scan `base`: `dynamic` = `[x, y, tilt_x, tilt_y,
/// frame_x, frame_y, fx (applied), fy (applied)]`, the scratch's load and temperature indexed
/// by scan. Returns how many readings it found out of range or not finite: zero exactly when
/// every reading of the tile is usable (a reading just past the tile, which its stencil reads,
/// may be counted too; the callers only ask for zero).
#[inline(always)]
fn front_tile(
    chans: &[FrontChannel<'_>],
    applied: &Applied,
    len: usize,
    base: usize,
    o: Range<usize>,
    s: &mut FrontScratch,
    dynamic: &mut [&mut [f64]; 8],
) -> usize {
    let FrontScratch { tile, input, load, temp, .. } = s;
    let tile = &mut **tile;
    let (o0, o1) = (o.start, o.end);
    let mut bad = 0;
    for (k, (c, t)) in chans.iter().zip(tile.iter_mut()).enumerate() {
        // The frame probes, the bellows' load and the temperature are not combined with
        // other channels: de-skewed straight into their columns.
        let t: &mut [f64] = match k {
            4 => &mut dynamic[4][o0 - base..o1 - base],
            5 => &mut dynamic[5][o0 - base..o1 - base],
            8 => &mut load[o0..o1],
            9 => &mut temp[o0..o1],
            _ => &mut t[..o1 - o0],
        };
        let k = c.k;
        let (lo, hi, si_bounded) = (k.lo, k.hi, k.si_bounded);
        let si = |v: f64| k.si(v);
        // Outputs a..b use the interior stencil, on readings i0..i1 (inside the record).
        let a = o0.max(c.interior.start).min(o1);
        let b = o1.min(c.interior.end).max(a);
        let (w, taps) = (c.delay.weights(), c.delay.taps());
        let i0 = (a as isize + c.delay.stencil_start()).max(0) as usize;
        let i1 = i0 + (b - a) + taps - 1;
        // Where the stencil's readings cover the tile's (every tile but those at the record's
        // ends), the range check runs in the loop that converts them: one pass instead of
        // two. `&` and `|`, not `&&`: no branch per reading, so the count vectorises.
        let check_while_converting = si_bounded && a == o0 && b == o1 && i0 <= o0 && i1 >= o1;
        if !check_while_converting {
            for &v in &c.readings[o0..o1] {
                bad += (!((v > lo) & (v < hi)) | (!si_bounded & !si(v).is_finite())) as usize;
            }
        }
        if a < b {
            let x = &mut input[..i1 - i0];
            if check_while_converting {
                for (x, &v) in x.iter_mut().zip(&c.readings[i0..i1]) {
                    *x = si(v);
                    bad += !((v > lo) & (v < hi)) as usize;
                }
            } else {
                for (x, &v) in x.iter_mut().zip(&c.readings[i0..i1]) {
                    *x = si(v);
                }
            }
            stencil(w, x, &mut t[a - o0..b - o0]);
        }
        for n in (o0..a).chain(b..o1) {
            t[n - o0] = c.delay.edge_value(n, len, |i| si(c.readings[i]));
        }
    }
    let [a_x, a_y, b_x, b_y, _, _, f1, f2, _, _] = &*tile;
    let [x, y, tilt_x, tilt_y, _, _, fx, fy] = dynamic;
    let f3 = &load[o0..o1];
    for (i, n) in (o0 - base..o1 - base).enumerate() {
        [x[n], tilt_x[n]] = kinematics::mean_and_difference(a_x[i], b_x[i]);
        [y[n], tilt_y[n]] = kinematics::mean_and_difference(a_y[i], b_y[i]);
        [fx[n], fy[n]] = applied.at(f1[i], f2[i], f3[i]);
    }
    // The temperature is final here (it is not filtered): checked while it is in L1.
    for v in &temp[o0..o1] {
        bad += !v.is_finite() as usize;
    }
    bad
}
