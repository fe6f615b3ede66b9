//! Step 1 of Zhou et al. (2004), section 3.1: a **zero-phase** Butterworth low-pass, run
//! forward then backward (`filtfilt`), so that no channel is shifted in time by the filter.
//! Bilinear transform with the cutoff pre-warped, a cascade of second-order sections in
//! direct form I.
//!
//! Edges as MATLAB's `filtfilt`: odd reflection at each end, every section started in its DC
//! steady state; the settling length is also trimmed from [`super::Conditioned::valid`].
//! Eight columns run in lock-step as the lanes of frames, and the forward output stays in
//! frames until the backward pass hands it on while it is in cache (ADR 0016).
//!
//! Design, gains, and why these edges rather than Gustafsson's (1996):
//! docs/manual/conditioning.md#step-1-low-pass.

use crate::simd::{self, all_finite, Isa, Kernel, Simd};
use crate::IdentificationError;

/// Highest order accepted (the default is 4; beyond 12 nothing useful is gained and the
/// settling time grows).
pub const MAX_ORDER: usize = 12;

/// Settling tolerance: the slowest pole's envelope has decayed to this at the trim length.
const SETTLE_TOL: f64 = 1.0e-7;

/// One second-order section, `a0 = 1`: `y = b0 x + b1 x[-1] + b2 x[-2] - a1 y[-1] - a2 y[-2]`.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Section {
    pub b: [f64; 3],
    pub a: [f64; 2],
}

impl Section {
    /// DC gain `(b0 + b1 + b2) / (1 + a1 + a2)`.
    fn dc_gain(&self) -> f64 {
        (self.b[0] + self.b[1] + self.b[2]) / (1.0 + self.a[0] + self.a[1])
    }

    /// Largest pole radius of `z^2 + a1 z + a2`.
    fn pole_radius(&self) -> f64 {
        let [a1, a2] = self.a;
        let disc = a1 * a1 - 4.0 * a2;
        if disc < 0.0 {
            a2.abs().sqrt()
        } else {
            let s = disc.sqrt();
            (0.5 * (-a1 + s)).abs().max((0.5 * (-a1 - s)).abs())
        }
    }
}

/// One section's state for the eight lanes of a frame, direct form I rearranged so that the
/// loop-carried path is one multiply and one subtract:
///
/// `y[n] = (b0 x[n] + q[n]) - a1 y[n-1]`, with `q[n] = b1 x[n-1] + b2 x[n-2] - a2 y[n-2]`,
///
/// where `q[n+1]` is computed at step `n` from `x[n]`, `x[n-1]`, `y[n-1]`: values known
/// before `y[n]` is, so it runs in parallel with the recursion.
#[derive(Copy, Clone, Debug)]
struct Lanes {
    /// `x[n-1]`, `y[n-1]`, `q[n]` before step `n`.
    x1: [f64; 8],
    y1: [f64; 8],
    q: [f64; 8],
}

impl Lanes {
    /// Steady state for the constant input `v`: `x = v`, `y = g v` at every past sample.
    fn steady(s: &Section, v: [f64; 8]) -> Self {
        let g = s.dc_gain();
        let y = v.map(|x| g * x);
        let q = std::array::from_fn(|l| s.b[1] * v[l] + s.b[2] * v[l] - s.a[1] * y[l]);
        Self { x1: v, y1: y, q }
    }

    #[inline(always)]
    fn step(&mut self, s: &Section, x: [f64; 8]) -> [f64; 8] {
        let [b0, b1, b2] = s.b;
        let [a1, a2] = s.a;
        let mut out = [0.0; 8];
        for l in 0..8 {
            let y = (b0 * x[l] + self.q[l]) - a1 * self.y1[l];
            self.q[l] = b1 * x[l] + b2 * self.x1[l] - a2 * self.y1[l];
            self.x1[l] = x[l];
            self.y1[l] = y;
            out[l] = y;
        }
        out
    }
}

/// Each of `sections` in the DC steady state for its own first input: `x0` for the first,
/// the previous section's first output for the others.
fn steady_cascade(sections: &[Section], x0: [f64; 8]) -> Vec<Lanes> {
    let mut v = x0;
    let mut lanes = Vec::with_capacity(sections.len());
    for s in sections {
        let mut st = Lanes::steady(s, v);
        lanes.push(st);
        v = st.step(s, v);
    }
    lanes
}

/// Sections run together in one pass over the data. Each section's recursion is independent
/// of the others' (only its input comes from the previous section), so a pair in one pass is
/// sixteen chains the CPU overlaps, and the data is read and written once instead of twice.
const FUSED: usize = 2;

/// A group of sections (a pair, or the lone last section of an odd order) over `frames` in
/// place, forward or (`reverse`) backward, its state carried in `lanes`.
#[inline(always)]
fn run_group(sections: &[Section], lanes: &mut [Lanes], frames: &mut [[f64; 8]], reverse: bool) {
    if sections.len() == FUSED {
        run_fused::<FUSED>(sections, lanes, frames, reverse);
    } else {
        run_fused::<1>(sections, lanes, frames, reverse);
    }
}

/// [`run_group`] for `S` sections, known at compile time so that the loop over them unrolls.
/// It runs on local copies of the sections and their state: behind a reference the compiler
/// kept the state in memory, a load and a store per lane and sample. (Why no hand-written
/// kernel: ADR 0022.)
#[inline(always)]
fn run_fused<const S: usize>(sections: &[Section], lanes: &mut [Lanes], frames: &mut [[f64; 8]], reverse: bool) {
    let sections: [Section; S] = std::array::from_fn(|i| sections[i]);
    let mut state: [Lanes; S] = std::array::from_fn(|i| lanes[i]);
    if reverse {
        for f in frames.iter_mut().rev() {
            *f = cascade_step(&sections, &mut state, *f);
        }
    } else {
        for f in frames.iter_mut() {
            *f = cascade_step(&sections, &mut state, *f);
        }
    }
    lanes.copy_from_slice(&state);
}

/// One frame through `sections` in turn. Always inlined: a call per frame would also be
/// compiled apart from the caller's instruction set.
#[inline(always)]
fn cascade_step(sections: &[Section], state: &mut [Lanes], x: [f64; 8]) -> [f64; 8] {
    let mut v = x;
    for (st, s) in state.iter_mut().zip(sections) {
        v = st.step(s, v);
    }
    v
}

/// The state of a forward pass over a stream of eight lanes ([`Butterworth::forward_steady`],
/// [`Butterworth::forward_run`]): each section's.
#[derive(Clone, Debug)]
pub(crate) struct ForwardStream {
    lanes: Vec<Lanes>,
}

/// What [`Butterworth::filtfilt8_fed`] filters: `produce(a, b, cols)` writes samples `a..b`
/// of the eight columns into `cols`, eight buffers of `b - a` values (sample `a + i` at index
/// `i`). A trait with an `#[inline(always)]` method rather than a closure, so that the
/// producer's code is compiled into the caller's instruction set.
pub(crate) trait Produce8 {
    type Error;
    fn produce(&mut self, from: usize, to: usize, cols: &mut [&mut [f64]; 8]) -> Result<(), Self::Error>;
}

/// What the backward pass hands its output to as it makes it final: `consume(from, cols)`
/// when samples `from..` of the eight columns are final, `from` decreasing from call to call
/// and 0 in the last. It may change the final samples (the filter does not read them again).
pub(crate) trait Consume8 {
    type Error;
    fn consume(&mut self, from: usize, cols: &mut [&mut [f64]; 8]) -> Result<(), Self::Error>;
}

/// Samples per call of [`Consume8::consume`] (eight columns of them: 32 kB).
const CONSUME_CHUNK: usize = 512;

/// Eight columns as a [`Produce8`].
struct FromColumns<'a>([&'a [f64]; 8]);

impl Produce8 for FromColumns<'_> {
    type Error = IdentificationError;
    #[inline(always)]
    fn produce(&mut self, from: usize, to: usize, cols: &mut [&mut [f64]; 8]) -> Result<(), IdentificationError> {
        for (dst, src) in cols.iter_mut().zip(self.0) {
            dst.copy_from_slice(&src[from..to]);
        }
        Ok(())
    }
}

/// A [`Consume8`] that leaves the output as it is.
struct Keep;

impl Consume8 for Keep {
    type Error = IdentificationError;
    #[inline(always)]
    fn consume(&mut self, _: usize, _: &mut [&mut [f64]; 8]) -> Result<(), IdentificationError> {
        Ok(())
    }
}

/// Samples per range [`Filtfilt`] copies in from its columns (eight of them: 128 kB).
const RANGE: usize = 2048;

/// Eight columns through [`Butterworth::filtfilt8_fed`] as a [`Kernel`].
struct Filtfilt<'a> {
    lp: &'a Butterworth,
    inputs: [&'a [f64]; 8],
    outputs: [&'a mut [f64]; 8],
    scratch: &'a mut Vec<f64>,
}

impl Kernel for Filtfilt<'_> {
    type Output = Result<bool, IdentificationError>;
    #[inline(always)]
    fn run<S: Simd>(self, simd: S) -> Self::Output {
        self.lp.filtfilt8_fed(simd, self.outputs, self.scratch, RANGE, &mut FromColumns(self.inputs), &mut Keep)
    }
}

/// A digital Butterworth low-pass used forward-backward.
#[derive(Clone, Debug, PartialEq)]
pub struct Butterworth {
    order: usize,
    cutoff_hz: f64,
    sample_rate_hz: f64,
    sections: Vec<Section>,
    settling: usize,
}

impl Butterworth {
    /// Designs an order-`order` low-pass with its -3 dB point (of the single pass) at
    /// `cutoff_hz`; `0 < cutoff_hz < sample_rate_hz / 2`, `1 <= order <= MAX_ORDER`.
    pub fn design(order: usize, cutoff_hz: f64, sample_rate_hz: f64) -> Result<Self, IdentificationError> {
        if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
            return Err(IdentificationError::invalid("sample_rate_hz", format!("must be finite and > 0, got {sample_rate_hz}")));
        }
        let nyquist = 0.5 * sample_rate_hz;
        if !(cutoff_hz.is_finite() && cutoff_hz > 0.0 && cutoff_hz < nyquist) {
            return Err(IdentificationError::invalid(
                "conditioning.lowpass_cutoff_hz",
                format!("must be above 0 and below the Nyquist frequency {nyquist} Hz (sample rate {sample_rate_hz} Hz), got {cutoff_hz}"),
            ));
        }
        if !(1..=MAX_ORDER).contains(&order) {
            return Err(IdentificationError::invalid("conditioning.lowpass_order", format!("must be in 1..={MAX_ORDER}, got {order}")));
        }
        let k = (std::f64::consts::PI * cutoff_hz / sample_rate_hz).tan();
        let k2 = k * k;
        let mut sections = Vec::with_capacity(order.div_ceil(2));
        for i in 0..order / 2 {
            let zeta = ((2 * i + 1) as f64 * std::f64::consts::PI / (2 * order) as f64).sin();
            let a0 = 1.0 + 2.0 * zeta * k + k2;
            let g = k2 / a0;
            sections.push(Section { b: [g, 2.0 * g, g], a: [2.0 * (k2 - 1.0) / a0, (1.0 - 2.0 * zeta * k + k2) / a0] });
        }
        if order % 2 == 1 {
            let g = k / (1.0 + k);
            sections.push(Section { b: [g, g, 0.0], a: [(k - 1.0) / (k + 1.0), 0.0] });
        }
        let r = sections.iter().map(Section::pole_radius).fold(0.0, f64::max);
        // 0 < r < 1 for a stable design with 0 < K < inf; guard anyway.
        if !(r > 0.0 && r < 1.0) {
            return Err(IdentificationError::invalid(
                "conditioning.lowpass_cutoff_hz",
                format!("design for {cutoff_hz} Hz at {sample_rate_hz} Hz has pole radius {r}"),
            ));
        }
        let settling = (SETTLE_TOL.ln() / r.ln()).ceil().max(1.0) as usize;
        Ok(Self { order, cutoff_hz, sample_rate_hz, sections, settling })
    }

    pub fn sections(&self) -> &[Section] {
        &self.sections
    }

    /// Samples for the slowest pole's envelope to fall to 1e-7: the reflection length at
    /// each end, and the samples [`super::condition`] trims at each end for this stage.
    pub fn settling_samples(&self) -> usize {
        self.settling
    }

    /// Theoretical forward-backward gain at `freq_hz` (zero phase):
    /// `1 / (1 + (tan(pi f / f_s) / tan(pi f_c / f_s))^(2N))`.
    pub fn gain(&self, freq_hz: f64) -> f64 {
        let pi = std::f64::consts::PI;
        let ratio = (pi * freq_hz / self.sample_rate_hz).tan() / (pi * self.cutoff_hz / self.sample_rate_hz).tan();
        1.0 / (1.0 + ratio.abs().powi(2 * self.order as i32))
    }

    /// Zero-phase filtering of one column (at least 2 samples), allocating the output.
    pub fn filtfilt(&self, input: &[f64]) -> Result<Vec<f64>, IdentificationError> {
        let mut column = [input.to_vec()];
        self.filtfilt_many_in_place(&mut column, &mut Vec::new())?;
        let [out] = column;
        Ok(out)
    }

    /// Zero-phase filtering of several columns of one length (at least 2 samples) in place,
    /// eight at a time: the same result as [`Butterworth::filtfilt`] on each.
    pub fn filtfilt_many_in_place(&self, columns: &mut [Vec<f64>], scratch: &mut Vec<f64>) -> Result<(), IdentificationError> {
        let Some(n) = columns.first().map(Vec::len) else { return Ok(()) };
        if let Some((k, c)) = columns.iter().enumerate().find(|(_, c)| c.len() != n) {
            return Err(IdentificationError::BadInput { what: format!("low-pass column {k}"), reason: format!("{} samples, column 0 has {n}", c.len()) });
        }
        if n < 2 {
            return Err(IdentificationError::BadInput { what: "low-pass input".into(), reason: format!("{n} samples, need at least 2") });
        }
        // The lanes a group of fewer than eight columns leaves over filter zeros.
        let zeros = vec![0.0; n];
        let mut filtered: [Vec<f64>; 8] = std::array::from_fn(|_| vec![0.0; n]);
        for group in columns.chunks_mut(8) {
            let inputs = std::array::from_fn(|l| group.get(l).map_or(&zeros[..], Vec::as_slice));
            let outputs = filtered.each_mut().map(|c| &mut c[..]);
            simd::dispatch(Isa::current(), Filtfilt { lp: self, inputs, outputs, scratch })?;
            for (c, f) in group.iter_mut().zip(&filtered) {
                c.copy_from_slice(f);
            }
        }
        Ok(())
    }

    /// The zero-phase filter on eight columns of `n >= 2` samples that `producer` writes as
    /// the filter goes: `produce(a, b, range)` writes samples `a..b` (adjacent ranges of at
    /// most `step` samples covering `0..n` in order; the first may be longer, to cover the
    /// left reflection's `pad + 1` samples); each range goes through the forward pass while it
    /// is still in cache. The forward pass keeps its output in frames of eight lanes in
    /// `scratch` (with the reflections: `(n + 2 pad) x 8` values, plus the range buffers), and
    /// [`Butterworth::backward_consumed`] runs on those frames and hands each chunk to
    /// `consumer` as it makes it final. Whether every output is finite.
    ///
    /// Each lane goes through the same operations in the same order as a filter of that
    /// column alone: the reflections are formed from the unfiltered samples (the right one's
    /// copied aside before their range is filtered), each group of sections starts in steady
    /// state for its first reflected input, and a recursion does not care where its input
    /// was cut into ranges (its state is carried).
    #[inline(always)]
    pub(crate) fn filtfilt8_fed<S: Simd, P: Produce8, C: Consume8<Error = P::Error>>(
        &self,
        simd: S,
        cols: [&mut [f64]; 8],
        scratch: &mut Vec<f64>,
        step: usize,
        producer: &mut P,
        consumer: &mut C,
    ) -> Result<bool, P::Error> {
        let n = cols.iter().map(|c| c.len()).min().unwrap_or(0);
        let mut cols = cols.map(|c| &mut c[..n]);
        if n < 2 {
            // Nothing to filter (the callers check the length first): produce and leave.
            producer.produce(0, n, &mut cols)?;
            consumer.consume(0, &mut cols)?;
            return Ok(cols.iter().all(|c| all_finite(c)));
        }
        let step = step.max(1);
        let pad = self.settling.min(n - 1);
        // The range `a..b` being filtered. The first reaches sample `pad`, which the left
        // reflection needs unfiltered, and is the longest.
        let mut a = 0;
        let mut b = (pad + 1).max(step).min(n);
        // Every value of the scratch is written before it is read, so it is grown when too
        // short and never cleared (that would write a record's worth of zeros for nothing):
        // the frames, then a range buffer per lane.
        let frame_values = (2 * pad + n) * 8;
        let needed = frame_values + 8 * b;
        if scratch.len() < needed {
            scratch.resize(needed, 0.0);
        }
        let (frames, ranges) = scratch[..needed].split_at_mut(frame_values);
        let (left, rest) = frames.as_chunks_mut::<8>().0.split_at_mut(pad);
        let (right, store) = rest.split_at_mut(pad);
        let mut ranges = ranges.chunks_exact_mut(b);
        // `ranges` is eight chunks of `b >= 1` values, so each `next` has one.
        let mut range_cols: [&mut [f64]; 8] = std::array::from_fn(|_| ranges.next().unwrap_or_default());
        let mut fresh = range_cols.each_mut().map(|c| &mut c[..b]);
        producer.produce(0, b, &mut fresh)?;
        simd.transpose8(&mut fresh, 0, &mut store[..b], true);
        // ext[-i] = 2 x[0] - x[i], stored at left[pad - i].
        for i in 1..=pad {
            left[pad - i] = std::array::from_fn(|l| 2.0 * store[0][l] - store[i][l]);
        }
        let mut st = self.forward_steady(left[0]);
        self.forward_run(&mut st, left);
        // Forward over each range in turn, after copying aside the unfiltered samples the right
        // reflection needs: x[n - 1 - i] to right[i - 1] for i in 1..=pad, and x[n - 1].
        let last = loop {
            for j in (n - 1 - pad).max(a)..(n - 1).min(b) {
                right[n - 2 - j] = store[j];
            }
            let last = store[b - 1];
            self.forward_run(&mut st, &mut store[a..b]);
            if b == n {
                break last;
            }
            a = b;
            b = (a + step).min(n);
            let mut fresh = range_cols.each_mut().map(|c| &mut c[..b - a]);
            producer.produce(a, b, &mut fresh)?;
            simd.transpose8(&mut fresh, 0, &mut store[a..b], true);
        };
        // The right reflection, 2 x[n - 1] - x[n - 1 - i].
        for f in right.iter_mut() {
            *f = std::array::from_fn(|l| 2.0 * last[l] - f[l]);
        }
        self.forward_run(&mut st, right);
        self.backward_consumed(simd, &mut cols, store, right, consumer)
    }

    /// The forward pass of a stream in the state it has before its first input `x0`: each
    /// section in the DC steady state for its own first input.
    pub(crate) fn forward_steady(&self, x0: [f64; 8]) -> ForwardStream {
        ForwardStream { lanes: steady_cascade(&self.sections, x0) }
    }

    /// The forward pass over `frames` (in place, in time order), its state carried in `st`:
    /// frames fed in any cuts give the same outputs, bit for bit.
    #[inline(always)]
    pub(crate) fn forward_run(&self, st: &mut ForwardStream, frames: &mut [[f64; 8]]) {
        for (sections, lanes) in self.sections.chunks(FUSED).zip(st.lanes.chunks_mut(FUSED)) {
            run_group(sections, lanes, frames, false);
        }
    }

    /// The backward pass over `store` (the forward output, in place) with `right` the
    /// forward output past it (a reflection, or a stream's samples past a block), group after
    /// group from the end of `right`, each group starting in the DC steady state for its
    /// first input. The last group's output is final: it goes into `cols` and to `consumer`
    /// chunk by chunk from the end. Whether every final output is finite.
    #[inline(always)]
    pub(crate) fn backward_consumed<S: Simd, C: Consume8>(
        &self,
        simd: S,
        cols: &mut [&mut [f64]; 8],
        store: &mut [[f64; 8]],
        right: &mut [[f64; 8]],
        consumer: &mut C,
    ) -> Result<bool, C::Error> {
        let mut finite = true;
        let mut groups = self.sections.chunks(FUSED).peekable();
        while let Some(g) = groups.next() {
            let x0 = right.last().or(store.last()).copied().unwrap_or([0.0; 8]);
            let mut lanes = steady_cascade(g, x0);
            run_group(g, &mut lanes, right, true);
            if groups.peek().is_some() {
                run_group(g, &mut lanes, store, true);
                continue;
            }
            let mut end = store.len();
            for chunk in store.rchunks_mut(CONSUME_CHUNK) {
                let from = end - chunk.len();
                run_group(g, &mut lanes, chunk, true);
                finite &= all_finite(chunk.as_flattened());
                simd.transpose8(cols, from, chunk, false);
                consumer.consume(from, cols)?;
                end = from;
            }
        }
        Ok(finite)
    }
}
