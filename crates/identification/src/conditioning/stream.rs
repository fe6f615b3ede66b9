//! The zero-phase chain as a stream (ADR 0019): the front end and the low-pass's forward
//! pass run once per scan, their state carried from call to call; each block's backward
//! pass, derivatives and eq. 2's inertial part run over the block and the low-pass's
//! settling past it, the backward pass starting in its DC steady state where a record's
//! reflection would stand. Outputs are bit for bit independent of how the scans are cut
//! into calls.
//!
//! A block whose window holds a reading the front end cannot turn into a finite value is
//! not conditioned here ([`ZeroPhaseStream::block`] returns `None`; the caller conditions
//! that window as a record, which names the reading).
//!
//! Design: docs/manual/conditioning.md#the-zero-phase-stream.

use oilfilm_physics::daq::{ChannelId, CHANNEL_COUNT};

use super::chain::{Constants, Derivatives, FrontOut, FrontScratch};
use super::lowpass::ForwardStream;
use super::{columns_of, range_check, Chain, RangeViolation};
use crate::record::{RawRecord, RawUnits};
use crate::simd::{self, Kernel, Simd};
use crate::IdentificationError;

/// A conditioned block ([`ZeroPhaseStream::block`]): the columns the estimator reads, one
/// value per scan of the block, and the step-2 violations in the block's window (indices
/// from the window's start, as [`Chain::condition_window_into`] gives them).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Block {
    pub x_m: Vec<f64>,
    pub y_m: Vec<f64>,
    pub vx_m_s: Vec<f64>,
    pub vy_m_s: Vec<f64>,
    pub ax_m_s2: Vec<f64>,
    pub ay_m_s2: Vec<f64>,
    pub fx_n: Vec<f64>,
    pub fy_n: Vec<f64>,
    pub temperature_c: Vec<f64>,
    pub range_violations: Vec<RangeViolation>,
}

/// The zero-phase chain over a stream of scans (see the module's documentation).
pub struct ZeroPhaseStream {
    chain: Chain,
    units: RawUnits,
    col_of: [usize; CHANNEL_COUNT],
    /// By channel index.
    constants: [Constants; CHANNEL_COUNT],
    /// The front end and the forward pass are done for stream scans `..produced`.
    produced: usize,
    /// Their outputs for scans `kept_from..produced`: the front end's, with its frames through
    /// the forward pass (its load is not kept).
    kept_from: usize,
    out: FrontOut,
    /// `None` until the next finite front-end output (at the start, and after one that is not).
    forward: Option<ForwardStream>,
    /// Scans whose front-end output is not finite, ascending (dropped once no block's
    /// window can reach them).
    bad: Vec<usize>,
    // Working memory, reused.
    front: FrontScratch,
    back: Vec<[f64; 8]>,
    /// The block's final low-passed columns and `[first, second]` derivatives of x, y, X, Y.
    columns: [Vec<f64>; 8],
    derived: [[Vec<f64>; 2]; 4],
}

impl ZeroPhaseStream {
    /// `chain` over a stream of records whose columns are `channels` (each of the ten once, any
    /// order) in `units`; an error names a missing channel or a calibration that cannot
    /// convert the readings.
    pub fn new(chain: Chain, channels: &[ChannelId], units: RawUnits) -> Result<Self, IdentificationError> {
        let col_of = columns_of(channels, "stream")?;
        let constants = Constants::all(units, chain.calibration())?;
        let back = chain.reach().0;
        Ok(Self {
            chain,
            units,
            col_of,
            constants,
            produced: back,
            kept_from: back,
            out: FrontOut::default(),
            forward: None,
            bad: Vec::new(),
            front: FrontScratch::default(),
            back: Vec::new(),
            columns: Default::default(),
            derived: Default::default(),
        })
    }

    /// Scans a block needs on either side: [`Chain::edge`].
    pub fn edge(&self) -> usize {
        self.chain.edge()
    }

    /// The first stream scan [`ZeroPhaseStream::advance`] still reads (the caller may drop
    /// the scans before it, and those before its next block's window).
    pub fn first_needed(&self) -> usize {
        self.produced - self.chain.reach().0
    }

    /// Runs the front end and the forward pass over every scan whose de-skew stencils `raw`
    /// covers; `raw.columns[*][0]` is stream scan `offset` (it must hold every scan from
    /// [`ZeroPhaseStream::first_needed`] on).
    pub fn advance(&mut self, raw: &RawRecord, offset: usize) -> Result<(), IdentificationError> {
        simd::dispatch(self.chain.isa(), Advance { s: self, raw, offset })
    }

    /// The block of `len` scans from stream scan `start`, once the stream has been advanced
    /// over its window (`start + len + edge` scans in); `raw` as for
    /// [`ZeroPhaseStream::advance`], holding the window. `Ok(None)`: the front end could not
    /// make every reading of the window finite (or the scans are not there yet); condition
    /// the window as a record instead ([`Chain::condition_window_into`]).
    pub fn block(&mut self, start: usize, len: usize, raw: &RawRecord, offset: usize) -> Result<Option<Block>, IdentificationError> {
        let edge = self.edge();
        let m = self.chain.derivative.half_length();
        let settle = self.chain.lowpass.settling_samples();
        let window = start.checked_sub(edge).map(|a| a..start + len + edge);
        let back = start.checked_sub(2 * m).map(|a| a..start + len + 2 * m + settle);
        let (Some(window), Some(back)) = (window, back) else { return Ok(None) };
        if back.start < self.kept_from || back.end > self.produced || window.start < offset || window.end > offset + raw.len() {
            return Ok(None);
        }
        // Any unusable reading the window's front end reads: the windowed conditioning says which.
        let (lookback, lookahead) = self.chain.reach();
        let reach = window.start.saturating_sub(lookback)..window.end + lookahead;
        if self.bad.iter().any(|b| reach.contains(b)) {
            return Ok(None);
        }
        self.back.clear();
        self.back.extend_from_slice(&self.out.frames[back.start - self.kept_from..back.end - self.kept_from]);
        let n = len + 4 * m;
        for c in self.columns.iter_mut().chain(self.derived.iter_mut().flatten()) {
            c.resize(n, 0.0);
        }
        simd::dispatch(self.chain.isa(), Backward { s: self, n })?;
        let out = 2 * m..2 * m + len;
        let cut = |c: &Vec<f64>| c[out.clone()].to_vec();
        let [x, y, _, _, _, _, fx, fy] = &self.columns;
        let [[vx, ax], [vy, ay], ..] = &self.derived;
        let mut block = Block {
            x_m: cut(x),
            y_m: cut(y),
            vx_m_s: cut(vx),
            vy_m_s: cut(vy),
            ax_m_s2: cut(ax),
            ay_m_s2: cut(ay),
            fx_n: cut(fx),
            fy_n: cut(fy),
            temperature_c: self.out.temp[start - self.kept_from..start + len - self.kept_from].to_vec(),
            range_violations: Vec::new(),
        };
        for ch in ChannelId::ALL {
            let column = &raw.columns[self.col_of[ch.index()]][window.start - offset..window.end - offset];
            if let Some(v) = range_check::check(ch, column, self.units, self.chain.calibration())? {
                block.range_violations.push(v);
            }
        }
        Ok(Some(block))
    }

    /// Drops what no block from stream scan `next` on needs (in batches: a move of what is
    /// kept every few blocks).
    pub fn release_before(&mut self, next: usize) {
        let keep = next.saturating_sub(2 * self.chain.derivative.half_length()).max(self.kept_from).min(self.produced);
        let dead = keep - self.kept_from;
        if dead > 0 && dead >= 4 * (self.produced - keep) {
            self.out.frames.drain(..dead);
            self.out.temp.drain(..dead);
            self.kept_from = keep;
        }
        let reach_from = next.saturating_sub(self.edge() + self.chain.reach().0);
        self.bad.retain(|&b| b >= reach_from);
    }
}

/// [`ZeroPhaseStream::advance`] as a [`Kernel`].
struct Advance<'a> {
    s: &'a mut ZeroPhaseStream,
    raw: &'a RawRecord,
    offset: usize,
}

impl Kernel for Advance<'_> {
    type Output = Result<(), IdentificationError>;

    #[inline(always)]
    fn run<S: Simd>(self, _: S) -> Self::Output {
        let Advance { s, raw, offset } = self;
        let end = (offset + raw.len()).saturating_sub(s.chain.reach().1);
        if s.produced >= end {
            return Ok(());
        }
        if s.first_needed() < offset {
            return Err(IdentificationError::BadInput {
                what: "stream".into(),
                reason: format!("scans from {} needed, the record starts at {offset}", s.first_needed()),
            });
        }
        let cols: [&[f64]; CHANNEL_COUNT] = std::array::from_fn(|k| raw.columns.get(s.col_of[k]).map_or(&[][..], Vec::as_slice));
        let new_from = s.out.frames.len();
        s.out.load.clear();
        s.chain.front_frames(&s.constants, cols, offset, s.produced..end, &mut s.front, &mut s.out)?;
        let FrontOut { frames, temp, .. } = &mut s.out;
        // The forward pass over the new frames, restarting in steady state after any frame
        // (or temperature) that is not finite.
        let mut i = new_from;
        while i < frames.len() {
            let mut j = i;
            while j < frames.len() && frames[j].iter().fold(temp[j].is_finite(), |ok, v| ok & v.is_finite()) {
                j += 1;
            }
            if j > i {
                let st = s.forward.get_or_insert_with(|| s.chain.lowpass.forward_steady(frames[i]));
                s.chain.lowpass.forward_run(st, &mut frames[i..j]);
            }
            if j < frames.len() {
                s.bad.push(s.produced + (j - new_from));
                s.forward = None;
                j += 1;
            }
            i = j;
        }
        s.produced = end;
        Ok(())
    }
}

/// A block's backward pass, derivatives and eq. 2's inertial part as a [`Kernel`]: the
/// forward output `back[..n]` is the block with the differentiators' reach on either side,
/// `back[n..]` the low-pass's settling past it (where a record's reflection would stand).
struct Backward<'a> {
    s: &'a mut ZeroPhaseStream,
    n: usize,
}

impl Kernel for Backward<'_> {
    type Output = Result<(), IdentificationError>;

    #[inline(always)]
    fn run<S: Simd>(self, simd: S) -> Self::Output {
        let s = self.s;
        let (store, right) = s.back.split_at_mut(self.n);
        let mut d = Derivatives::new(simd, &s.chain, s.derived.each_mut().map(|p| p.each_mut().map(|c| &mut c[..])));
        let mut cols = s.columns.each_mut().map(|c| &mut c[..]);
        s.chain.lowpass.backward_consumed(simd, &mut cols, store, right, &mut d)?;
        if !d.complete() {
            return Err(IdentificationError::invalid("conditioning", "the derivatives did not cover the block"));
        }
        Ok(())
    }
}
