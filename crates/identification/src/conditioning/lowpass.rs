//! Step 1 of Zhou et al. (2004), section 3.1: "feed the raw data to a low pass filter to
//! eliminate high frequency noise". Here: a **zero-phase** Butterworth low-pass, run forward
//! then backward (`filtfilt`), so that no channel is shifted in time by the filter.
//!
//! ## Design
//! Order-`N` Butterworth (maximally flat, no passband ripple) by the bilinear transform with
//! the cutoff pre-warped, `K = tan(pi f_c / f_s)`, as a cascade of second-order sections
//! (one first-order section when `N` is odd), each in direct form I. The section of the analog pole pair with damping `zeta_k = sin((2k + 1) pi / (2N))` is
//!
//! `H_k(z) = K^2 (1 + z^-1)^2 / [(1 + 2 zeta K + K^2) + 2 (K^2 - 1) z^-1 + (1 - 2 zeta K + K^2) z^-2]`.
//!
//! Run forward and backward, the magnitude is squared and the phase cancels exactly:
//!
//! `|H_ff(f)| = 1 / (1 + (tan(pi f / f_s) / K)^(2N))`,  `arg H_ff = 0`.
//!
//! Default (`f_c = 200 Hz`, `N = 4`, `f_s = 5 kHz`, [`Butterworth::gain`]):
//!
//! | frequency | forward-backward gain |
//! |---|---|
//! | 0-80 Hz | 1 down to 0.999367 (monotonic droop, 6.3e-4 = 5.5 mdB at 80 Hz; no ripple) |
//! | 200 Hz | 0.5 (-6 dB, the cutoff of the squared response) |
//! | 1 kHz | 8.4e-7 (-122 dB) |
//!
//! Every channel that enters eq. 1 and eq. 2 goes through the *same* filter, so this droop
//! is common to displacement, velocity, acceleration and force and cancels in the
//! least-squares fit (a common LTI filter applied to both sides of a linear relation
//! preserves it); only the *differences* between channels (deskew, differentiator) bias
//! the coefficients. The droop does show when a conditioned signal is compared with the
//! analytic one (the end-to-end test allows for it).
//!
//! ## Edges (Gustafsson 1996)
//! A forward-backward filter started from rest rings at both ends. F. Gustafsson,
//! "Determining the initial states in forward-backward filtering", IEEE Trans. Signal
//! Processing 44(4), 1996, shows how to choose the initial states so that forward-backward
//! and backward-forward runs agree (SciPy's `filtfilt(method="gust")`). We use the simpler,
//! widely used scheme of MATLAB's `filtfilt` and SciPy's default: the signal is extended at
//! each end by its **odd reflection** about the end sample (value and slope continuous),
//! and every section starts in its **DC steady state** for its first input, forward and
//! then backward. The extension is as long as the filter's settling time
//! ([`Butterworth::settling_samples`], where the slowest pole has decayed to 1e-7), and the
//! conditioned record still excludes that many samples at each end from
//! [`super::Conditioned::valid`], because the reflection is only a guess of the signal
//! beyond the record. A constant passes exactly and a ramp (which the reflection continues
//! exactly) to 1e-6 of its span, up to the last sample (tested).
//!
//! ## Cost
//! Per section, a forward and a backward pass over the column, five multiplies and four
//! adds per sample, arranged so that only one multiply and one subtract are on the
//! recursion's loop-carried path. [`Butterworth::filtfilt_many_in_place`] runs eight columns
//! in lock-step, and two sections per pass (the default's two sections: one pass forward,
//! one backward), so sixteen independent recursions overlap and each sample is read and
//! written once per direction; the columns go through the recursion in L1-resident tiles of
//! interleaved lanes, compiled for AVX2 when the CPU has it (same operations, same result bit
//! for bit); on an AVX2 CPU without AVX-512 a pair of sections runs in an intrinsics kernel
//! that keeps their state in registers ([`pair_avx2`], ADR 0016 amendment 4). Moving eight columns into and out of the interleaved lanes was a third of the
//! time when done sample by sample (sixteen scalar loads and stores per sample and pass); with
//! AVX2 it is done by 4 x 4 register transposes ([`transpose8`]). Ten columns of 300 000
//! samples: 7.4-8.0 ms against 8.9-9.8 ms sample by sample, in the same run on the shared
//! development machine. The only scratch memory is the two reflections and one tile.
//! [`super::condition`] feeds the forward pass from its front end tile by tile
//! (`filtfilt8_fed`: the same operations in the same order), so the eight columns are not
//! written out by the front end and read straight back by the filter. There the forward
//! pass's output stays in frames (a scratch of eight values per sample) until the backward
//! pass has made it final: two transposes per sample instead of four, and no write of the
//! unfiltered columns (ADR 0016, amendment 2).

use oilfilm_physics::daq::ChannelId;

#[cfg(target_arch = "x86_64")]
mod pair_avx2;

use super::{all_finite, first_non_finite};
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

/// One section's state for `L` lanes, direct form I rearranged so that the loop-carried
/// path is one multiply and one subtract:
///
/// `y[n] = (b0 x[n] + q[n]) - a1 y[n-1]`, with `q[n] = b1 x[n-1] + b2 x[n-2] - a2 y[n-2]`,
///
/// where `q[n+1]` is computed at step `n` from `x[n]`, `x[n-1]`, `y[n-1]`: values known
/// before `y[n]` is, so it runs in parallel with the recursion.
#[derive(Copy, Clone)]
struct Lanes<const L: usize> {
    /// `x[n-1]`, `y[n-1]`, `q[n]` before step `n`.
    x1: [f64; L],
    y1: [f64; L],
    q: [f64; L],
}

impl<const L: usize> Lanes<L> {
    /// Steady state for the constant input `v`: `x = v`, `y = g v` at every past sample.
    fn steady(s: &Section, v: [f64; L]) -> Self {
        let g = s.dc_gain();
        let y = v.map(|x| g * x);
        let q = std::array::from_fn(|l| s.b[1] * v[l] + s.b[2] * v[l] - s.a[1] * y[l]);
        Self { x1: v, y1: y, q }
    }

    /// One sample.
    #[inline(always)]
    fn step(&mut self, s: &Section, x: [f64; L]) -> [f64; L] {
        let [b0, b1, b2] = s.b;
        let [a1, a2] = s.a;
        let mut out = [0.0; L];
        for l in 0..L {
            let y = (b0 * x[l] + self.q[l]) - a1 * self.y1[l];
            self.q[l] = b1 * x[l] + b2 * self.x1[l] - a2 * self.y1[l];
            self.x1[l] = x[l];
            self.y1[l] = y;
            out[l] = y;
        }
        out
    }
}

/// Sections run together in one pass over the data (see [`Butterworth::filtfilt_lanes`]).
const FUSED: usize = 2;

/// `S` cascaded sections for `L` lanes: one step feeds each section's output to the next.
/// Each section's recursion is independent of the others' (only its input comes from the
/// previous section), so `S` sections in one pass are `S * L` chains the CPU overlaps, and
/// the data is read and written once instead of `S` times.
#[derive(Copy, Clone)]
struct Cascade<'a, const L: usize, const S: usize> {
    sections: &'a [Section; S],
    lanes: [Lanes<L>; S],
}

impl<'a, const L: usize, const S: usize> Cascade<'a, L, S> {
    /// Every section in its DC steady state for its own first input, when the cascade's first
    /// input is `x0`: section `k`'s first input is section `k - 1`'s first output, computed
    /// here by the same arithmetic as the step that will produce it (so the result is the
    /// same, bit for bit, as running the sections one after the other over the whole signal).
    fn steady(sections: &'a [Section; S], x0: [f64; L]) -> Self {
        let mut v = x0;
        let lanes = std::array::from_fn(|k| {
            let mut st = Lanes::steady(&sections[k], v);
            let first = st;
            v = st.step(&sections[k], v);
            first
        });
        Self { sections, lanes }
    }

    #[inline(always)]
    fn step(&mut self, x: [f64; L]) -> [f64; L] {
        let mut v = x;
        for (st, s) in self.lanes.iter_mut().zip(self.sections) {
            v = st.step(s, v);
        }
        v
    }
}

/// `st` over `frames` of eight lanes in place, from the first frame to the last or (with
/// `reverse`) back, its state carried: the same outputs and state as `st.step` frame by
/// frame. A group of two Butterworth sections on an AVX2 CPU without AVX-512 runs in
/// [`pair_avx2`], which keeps their state in registers (same operations, same bits); the
/// rest runs the generic step, on a local copy of the state (behind a reference the
/// compiler kept it in memory, a load and a store per lane and sample).
#[inline(always)]
fn run8<const S: usize>(st: &mut Cascade<'_, 8, S>, frames: &mut [[f64; 8]], reverse: bool) {
    #[cfg(target_arch = "x86_64")]
    {
        let sections: &[Section] = st.sections;
        if let (Ok(sections), Ok(lanes)) = (<&[Section; 2]>::try_from(sections), <&mut [Lanes<8>; 2]>::try_from(&mut st.lanes[..])) {
            if pair_avx2::applies(sections) {
                // SAFETY: `applies` checked that the CPU has AVX2, `run`'s only requirement.
                unsafe { pair_avx2::run(sections, lanes, frames, reverse) };
                return;
            }
        }
    }
    let mut local = *st;
    if reverse {
        for f in frames.iter_mut().rev() {
            *f = local.step(*f);
        }
    } else {
        for f in frames.iter_mut() {
            *f = local.step(*f);
        }
    }
    *st = local;
}

/// The forward pass's state for a stream of eight lanes ([`Butterworth::forward_steady`],
/// [`Butterworth::forward_run`]): each group of [`FUSED`] sections, and the lone last section
/// of an odd count of them.
#[derive(Clone)]
pub(super) struct ForwardStream {
    groups: Vec<[Lanes<8>; FUSED]>,
    last: Option<[Lanes<8>; 1]>,
}

/// What [`Butterworth::filtfilt8_fed`] filters: `produce(a, b, cols)` writes samples `a..b`
/// of the eight columns into `cols`, eight buffers of `b - a` values (sample `a + i` at index
/// `i`; not the output columns). A trait with an `#[inline(always)]` method rather than a closure,
/// so that the producer's code is compiled into the caller's `target_feature` function (a
/// closure is a function of its own, compiled without the caller's features).
pub(crate) trait Produce8 {
    type Error;
    fn produce(&mut self, from: usize, to: usize, cols: &mut [&mut [f64]; 8]) -> Result<(), Self::Error>;
}

/// What [`Butterworth::filtfilt8_fed`] hands its output to as the backward pass makes it
/// final: `consume(from, cols)` when samples `from..` of the eight columns are final, with
/// `from` decreasing from call to call and 0 in the last call. It may change the final
/// samples (the filter does not read them again).
pub(crate) trait Consume8 {
    type Error;
    fn consume(&mut self, from: usize, cols: &mut [&mut [f64]; 8]) -> Result<(), Self::Error>;
}

/// Samples per call of [`Consume8::consume`] (eight columns of them: 32 kB).
const CONSUME_CHUNK: usize = 512;

/// Samples per tile of [`cascade_pass`] (a tile of eight lanes is 2 kB, L1-resident).
const TILE: usize = 32;

/// The cascade over the `L` columns in place, forward or backward in time. The columns are
/// copied tile by tile into frames of `L` lanes (one vector load per sample instead of `L`
/// scalar ones with a bounds check each), run through the cascade and copied back.
#[inline(always)]
fn cascade_pass<const L: usize, const S: usize>(
    st: &mut Cascade<'_, L, S>,
    cols: &mut [&mut [f64]; L],
    n: usize,
    backward: bool,
) -> bool {
    let mut frames = [[0.0; L]; TILE];
    let mut done = 0;
    let mut finite = true;
    while done < n {
        let t = TILE.min(n - done);
        let start = if backward { n - done - t } else { done };
        let frames = &mut frames[..t];
        to_frames(cols, start, frames);
        // Plain loops (a closure here was not inlined: a call per sample).
        if backward {
            for f in frames.iter_mut().rev() {
                *f = st.step(*f);
            }
        } else {
            for f in frames.iter_mut() {
                *f = st.step(*f);
            }
        }
        finite &= all_finite(frames.as_flattened());
        to_columns(cols, start, frames);
        done += t;
    }
    finite
}

#[derive(Copy, Clone, PartialEq, Eq)]
enum Direction {
    ToFrames,
    ToColumns,
}

/// Moves samples `start .. start + t` of eight columns into (or out of) `t` frames of eight
/// lanes (`frames` flattened, `frames[8 i + l]` is sample `start + i` of column `l`) by 4 x 4
/// register transposes, when there are eight columns and the CPU has AVX2; returns `false`
/// (nothing moved) otherwise, and the caller moves them one by one. Plain data movement:
/// the same values either way. Per four samples of four columns: four vector loads, eight
/// shuffles, four vector stores, instead of sixteen scalar loads and stores.
#[inline(always)]
fn transpose8<const L: usize>(
    cols: &mut [&mut [f64]; L],
    start: usize,
    frames: &mut [f64],
    dir: Direction,
) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        if L == 8 && std::arch::is_x86_feature_detected!("avx512f") {
            let t = frames.len() / 8;
            let mut c: [&mut [f64]; L] = cols.each_mut().map(|c| &mut c[start..start + t]);
            // SAFETY: the CPU has AVX-512F (checked above).
            unsafe { transpose8_avx512(c.as_mut_slice(), frames, dir) };
            return true;
        }
        if L == 8 && std::arch::is_x86_feature_detected!("avx2") {
            let t = frames.len() / 8;
            let mut c: [&mut [f64]; L] = cols.each_mut().map(|c| &mut c[start..start + t]);
            // SAFETY: the CPU has AVX2 (checked above).
            unsafe { transpose8_avx2(c.as_mut_slice(), frames, dir) };
            return true;
        }
    }
    let _ = (cols, start, frames, dir);
    false
}

/// [`transpose8`] for eight columns of `frames.len() / 8` samples each.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn transpose8_avx2(cols: &mut [&mut [f64]], frames: &mut [f64], dir: Direction) {
    use std::arch::x86_64::{
        __m256d, _mm256_loadu_pd, _mm256_permute2f128_pd, _mm256_storeu_pd, _mm256_unpackhi_pd,
        _mm256_unpacklo_pd,
    };
    let t = frames.len() / 8;
    if cols.len() != 8 || cols.iter().any(|c| c.len() != t) {
        return;
    }
    // r[j] = four consecutive values of row j -> f[k] = the k-th value of each row.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn tr(r: [__m256d; 4]) -> [__m256d; 4] {
        let t0 = _mm256_unpacklo_pd(r[0], r[1]);
        let t1 = _mm256_unpackhi_pd(r[0], r[1]);
        let t2 = _mm256_unpacklo_pd(r[2], r[3]);
        let t3 = _mm256_unpackhi_pd(r[2], r[3]);
        [
            _mm256_permute2f128_pd::<0x20>(t0, t2),
            _mm256_permute2f128_pd::<0x20>(t1, t3),
            _mm256_permute2f128_pd::<0x31>(t0, t2),
            _mm256_permute2f128_pd::<0x31>(t1, t3),
        ]
    }
    let body = t / 4 * 4;
    for i in (0..body).step_by(4) {
        for half in 0..2 {
            let l0 = 4 * half;
            // SAFETY: i + 4 <= t = every column's length, and frames has 8 t values: the
            // loads and stores touch cols[l0 + j][i .. i + 4] and frames[8 (i + k) + l0 ..
            // + 4] for j, k < 4.
            unsafe {
                if dir == Direction::ToFrames {
                    let r = std::array::from_fn(|j| _mm256_loadu_pd(cols[l0 + j].as_ptr().add(i)));
                    for (k, f) in tr(r).into_iter().enumerate() {
                        _mm256_storeu_pd(frames.as_mut_ptr().add(8 * (i + k) + l0), f);
                    }
                } else {
                    let r = std::array::from_fn(|k| _mm256_loadu_pd(frames.as_ptr().add(8 * (i + k) + l0)));
                    for (j, c) in tr(r).into_iter().enumerate() {
                        _mm256_storeu_pd(cols[l0 + j].as_mut_ptr().add(i), c);
                    }
                }
            }
        }
    }
    for i in body..t {
        for (l, c) in cols.iter_mut().enumerate() {
            if dir == Direction::ToFrames {
                frames[8 * i + l] = c[i];
            } else {
                c[i] = frames[8 * i + l];
            }
        }
    }
}

/// [`transpose8`] by 8 x 8 register transposes (AVX-512): per eight samples of the eight
/// columns, eight vector loads, 24 shuffles and eight vector stores, where the 4 x 4 blocks
/// of [`transpose8_avx2`] take sixteen, 32 and sixteen. An 8 x 8 transpose is its own
/// inverse, so one kernel serves both directions. Samples beyond the last multiple of eight
/// move one by one.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn transpose8_avx512(cols: &mut [&mut [f64]], frames: &mut [f64], dir: Direction) {
    use std::arch::x86_64::{
        __m512d, _mm512_loadu_pd, _mm512_shuffle_f64x2, _mm512_storeu_pd, _mm512_unpackhi_pd,
        _mm512_unpacklo_pd,
    };
    let t = frames.len() / 8;
    if cols.len() != 8 || cols.iter().any(|c| c.len() != t) {
        return;
    }
    // r[j] = eight consecutive values of row j -> the k-th value of every row, k = 0..8.
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn tr(r: [__m512d; 8]) -> [__m512d; 8] {
        // 128-bit lane k of lo[j] holds rows 2j, 2j + 1 at value 2k; of hi[j], at 2k + 1.
        let lo: [__m512d; 4] = std::array::from_fn(|j| _mm512_unpacklo_pd(r[2 * j], r[2 * j + 1]));
        let hi: [__m512d; 4] = std::array::from_fn(|j| _mm512_unpackhi_pd(r[2 * j], r[2 * j + 1]));
        // Lanes (0, 2 | 0, 2) and (1, 3 | 1, 3) of two vectors, twice: the lanes of value 2k
        // (or 2k + 1) of rows 0-1, 2-3, 4-5, 6-7 end up side by side.
        let pick = |v: [__m512d; 4]| -> [__m512d; 4] {
            let e0 = _mm512_shuffle_f64x2::<0x88>(v[0], v[1]);
            let e1 = _mm512_shuffle_f64x2::<0xDD>(v[0], v[1]);
            let f0 = _mm512_shuffle_f64x2::<0x88>(v[2], v[3]);
            let f1 = _mm512_shuffle_f64x2::<0xDD>(v[2], v[3]);
            [
                _mm512_shuffle_f64x2::<0x88>(e0, f0), // value 0 (or 1)
                _mm512_shuffle_f64x2::<0x88>(e1, f1), // value 2 (or 3)
                _mm512_shuffle_f64x2::<0xDD>(e0, f0), // value 4 (or 5)
                _mm512_shuffle_f64x2::<0xDD>(e1, f1), // value 6 (or 7)
            ]
        };
        let even = pick(lo);
        let odd = pick(hi);
        [even[0], odd[0], even[1], odd[1], even[2], odd[2], even[3], odd[3]]
    }
    let body = t / 8 * 8;
    for i in (0..body).step_by(8) {
        // SAFETY: i + 8 <= t = every column's length, and frames has 8 t values: the loads
        // and stores touch cols[j][i .. i + 8] and frames[8 (i + k) .. + 8] for j, k < 8.
        unsafe {
            if dir == Direction::ToFrames {
                let r = std::array::from_fn(|j| _mm512_loadu_pd(cols[j].as_ptr().add(i)));
                for (k, f) in tr(r).into_iter().enumerate() {
                    _mm512_storeu_pd(frames.as_mut_ptr().add(8 * (i + k)), f);
                }
            } else {
                let r = std::array::from_fn(|k| _mm512_loadu_pd(frames.as_ptr().add(8 * (i + k))));
                for (j, c) in tr(r).into_iter().enumerate() {
                    _mm512_storeu_pd(cols[j].as_mut_ptr().add(i), c);
                }
            }
        }
    }
    for i in body..t {
        for (l, c) in cols.iter_mut().enumerate() {
            if dir == Direction::ToFrames {
                frames[8 * i + l] = c[i];
            } else {
                c[i] = frames[8 * i + l];
            }
        }
    }
}

/// `S` sections forward over the left extension, the columns and the right extension.
#[inline(always)]
fn forward<const L: usize, const S: usize>(
    sections: &[Section; S],
    left: &mut [[f64; L]],
    cols: &mut [&mut [f64]; L],
    n: usize,
    right: &mut [[f64; L]],
) {
    // A section started in steady state for its first input outputs that level times its
    // DC gain first, so the next section's first input is its own steady level.
    let x0 = left
        .first()
        .copied()
        .unwrap_or(std::array::from_fn(|l| cols[l][0]));
    let mut st = Cascade::steady(sections, x0);
    for f in left.iter_mut() {
        *f = st.step(*f);
    }
    cascade_pass(&mut st, cols, n, false);
    for f in right.iter_mut() {
        *f = st.step(*f);
    }
}

/// `S` sections backward over the right extension and the columns; whether every output
/// written to the columns is finite.
#[inline(always)]
fn backward<const L: usize, const S: usize>(
    sections: &[Section; S],
    cols: &mut [&mut [f64]; L],
    n: usize,
    right: &mut [[f64; L]],
) -> bool {
    let x0 = right
        .last()
        .copied()
        .unwrap_or(std::array::from_fn(|l| cols[l][n - 1]));
    let mut st = Cascade::steady(sections, x0);
    for f in right.iter_mut().rev() {
        *f = st.step(*f);
    }
    cascade_pass(&mut st, cols, n, true)
}

/// Samples `start .. start + frames.len()` of `L` columns into frames of `L` lanes (by
/// [`transpose8`] where it can, else one by one).
#[inline(always)]
fn to_frames<const L: usize>(cols: &mut [&mut [f64]; L], start: usize, frames: &mut [[f64; L]]) {
    let t = frames.len();
    if !transpose8(cols, start, frames.as_flattened_mut(), Direction::ToFrames) {
        for (l, col) in cols.iter().enumerate() {
            for (f, &x) in frames.iter_mut().zip(&col[start..start + t]) {
                f[l] = x;
            }
        }
    }
}

/// Frames of `L` lanes into samples `start .. start + frames.len()` of `L` columns.
#[inline(always)]
fn to_columns<const L: usize>(cols: &mut [&mut [f64]; L], start: usize, frames: &mut [[f64; L]]) {
    let t = frames.len();
    if !transpose8(cols, start, frames.as_flattened_mut(), Direction::ToColumns) {
        for (l, col) in cols.iter_mut().enumerate() {
            for (x, f) in col[start..start + t].iter_mut().zip(frames.iter()) {
                *x = f[l];
            }
        }
    }
}

/// [`backward`] over frames kept by the forward pass (in place), for all but the last group.
#[inline(always)]
fn backward_frames<const S: usize>(sections: &[Section; S], store: &mut [[f64; 8]], right: &mut [[f64; 8]]) {
    let x0 = right.last().copied().unwrap_or_else(|| store.last().copied().unwrap_or([0.0; 8]));
    let mut st = Cascade::steady(sections, x0);
    for f in right.iter_mut().rev() {
        *f = st.step(*f);
    }
    run8(&mut st, store, true);
}

/// The last group of sections backward over the frames kept by the forward pass, chunk by
/// chunk from the end: each chunk, once final, moves into the columns and goes to `consumer`
/// (the state is carried from chunk to chunk: the same operations in the same order as one
/// pass over the whole). Whether every output is finite.
#[inline(always)]
fn backward_frames_consumed<const S: usize, C: Consume8>(
    sections: &[Section; S],
    cols: &mut [&mut [f64]; 8],
    store: &mut [[f64; 8]],
    right: &mut [[f64; 8]],
    consumer: &mut C,
) -> Result<bool, C::Error> {
    let x0 = right.last().copied().unwrap_or_else(|| store.last().copied().unwrap_or([0.0; 8]));
    let mut st = Cascade::steady(sections, x0);
    for f in right.iter_mut().rev() {
        *f = st.step(*f);
    }
    let mut finite = true;
    let mut end = store.len();
    while end > 0 {
        let start = end.saturating_sub(CONSUME_CHUNK);
        let chunk = &mut store[start..end];
        run8(&mut st, chunk, true);
        finite &= all_finite(chunk.as_flattened());
        to_columns(cols, start, chunk);
        consumer.consume(start, cols)?;
        end = start;
    }
    Ok(finite)
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
    pub fn design(
        order: usize,
        cutoff_hz: f64,
        sample_rate_hz: f64,
    ) -> Result<Self, IdentificationError> {
        if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
            return Err(IdentificationError::invalid(
                "sample_rate_hz",
                format!("must be finite and > 0, got {sample_rate_hz}"),
            ));
        }
        let nyquist = 0.5 * sample_rate_hz;
        if !(cutoff_hz.is_finite() && cutoff_hz > 0.0 && cutoff_hz < nyquist) {
            return Err(IdentificationError::invalid(
                "conditioning.lowpass_cutoff_hz",
                format!(
                    "must be above 0 and below the Nyquist frequency {nyquist} Hz (sample rate {sample_rate_hz} Hz), got {cutoff_hz}"
                ),
            ));
        }
        if !(1..=MAX_ORDER).contains(&order) {
            return Err(IdentificationError::invalid(
                "conditioning.lowpass_order",
                format!("must be in 1..={MAX_ORDER}, got {order}"),
            ));
        }
        let k = (std::f64::consts::PI * cutoff_hz / sample_rate_hz).tan();
        let k2 = k * k;
        let mut sections = Vec::with_capacity(order.div_ceil(2));
        for i in 0..order / 2 {
            let zeta = ((2 * i + 1) as f64 * std::f64::consts::PI / (2 * order) as f64).sin();
            let a0 = 1.0 + 2.0 * zeta * k + k2;
            let g = k2 / a0;
            sections.push(Section {
                b: [g, 2.0 * g, g],
                a: [2.0 * (k2 - 1.0) / a0, (1.0 - 2.0 * zeta * k + k2) / a0],
            });
        }
        if order % 2 == 1 {
            let g = k / (1.0 + k);
            sections.push(Section {
                b: [g, g, 0.0],
                a: [(k - 1.0) / (k + 1.0), 0.0],
            });
        }
        let r = sections
            .iter()
            .map(Section::pole_radius)
            .fold(0.0, f64::max);
        // 0 < r < 1 for a stable design with 0 < K < inf; guard anyway.
        let settling = if r > 0.0 && r < 1.0 {
            (SETTLE_TOL.ln() / r.ln()).ceil().max(1.0) as usize
        } else {
            return Err(IdentificationError::invalid(
                "conditioning.lowpass_cutoff_hz",
                format!("design for {cutoff_hz} Hz at {sample_rate_hz} Hz has pole radius {r}"),
            ));
        };
        Ok(Self {
            order,
            cutoff_hz,
            sample_rate_hz,
            sections,
            settling,
        })
    }

    pub fn order(&self) -> usize {
        self.order
    }

    pub fn cutoff_hz(&self) -> f64 {
        self.cutoff_hz
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
        let ratio = (pi * freq_hz / self.sample_rate_hz).tan()
            / (pi * self.cutoff_hz / self.sample_rate_hz).tan();
        1.0 / (1.0 + ratio.abs().powi(2 * self.order as i32))
    }

    /// Filters `L` columns of equal length `n >= 2` forward and backward, in place. Each
    /// column is extended at both ends by its odd reflection (`pad` samples, kept in
    /// `scratch`), each section starts in its DC steady state for its first input, runs
    /// forward, then starts again in steady state for its first input of the time-reversed
    /// signal and runs backward (as SciPy's `filtfilt`). The columns themselves are never
    /// copied, and the backward pass stops at the first real sample (the left extension's
    /// backward outputs would be discarded). Two sections per pass (see [`Cascade`]); `L`
    /// lanes are independent recursions the CPU overlaps (one lane alone is bound by the
    /// latency of its recursion, eight by arithmetic throughput).
    /// Returns whether every output is finite.
    fn filtfilt_lanes<const L: usize>(&self, cols: [&mut [f64]; L], scratch: &mut Vec<f64>) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the only requirement of a `target_feature` function is that the CPU
                // has the feature, which was checked on the line above.
                return unsafe { self.filtfilt_lanes_avx512(cols, scratch) };
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: as above.
                return unsafe { self.filtfilt_lanes_avx2(cols, scratch) };
            }
        }
        self.filtfilt_lanes_body(cols, scratch)
    }

    /// [`Butterworth::filtfilt_lanes`] compiled for AVX-512: eight lanes per instruction, and
    /// 32 vector registers, enough for two sections' state and coefficients (with AVX2's 16
    /// some went to the stack and back on every sample); 20 % less time for eight columns of
    /// 4000 samples (1.9 against 2.4 ns per sample and column, best of six interleaved
    /// runs). The same operations in the same order (Rust forms no fused multiply-add even
    /// where the CPU has it), so the same result bit for bit.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn filtfilt_lanes_avx512<const L: usize>(&self, cols: [&mut [f64]; L], scratch: &mut Vec<f64>) -> bool {
        self.filtfilt_lanes_body(cols, scratch)
    }

    /// [`Butterworth::filtfilt_lanes`] compiled for AVX2: four lanes per instruction instead
    /// of two. The same multiplies and adds in the same order (no fused multiply-add, which
    /// Rust never forms on its own), so the result is the same bit for bit on any CPU.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn filtfilt_lanes_avx2<const L: usize>(&self, cols: [&mut [f64]; L], scratch: &mut Vec<f64>) -> bool {
        self.filtfilt_lanes_body(cols, scratch)
    }

    #[inline(always)]
    fn filtfilt_lanes_body<const L: usize>(&self, cols: [&mut [f64]; L], scratch: &mut Vec<f64>) -> bool {
        let n = cols[0].len();
        let mut cols = cols.map(|c| &mut c[..n]);
        let pad = self.settling.min(n - 1);
        scratch.clear();
        scratch.resize(2 * pad * L, 0.0);
        let (frames, _) = scratch.as_chunks_mut::<L>();
        let (left, right) = frames.split_at_mut(pad);
        // ext[-i] = 2 x[0] - x[i] (stored at left[pad - i]) and
        // ext[n - 1 + i] = 2 x[n - 1] - x[n - 1 - i] (stored at right[i - 1]), i = 1..=pad.
        for i in 1..=pad {
            for l in 0..L {
                left[pad - i][l] = 2.0 * cols[l][0] - cols[l][i];
                right[i - 1][l] = 2.0 * cols[l][n - 1] - cols[l][n - 1 - i];
            }
        }
        // The sections in groups of `FUSED` per pass (each group's first input is the previous
        // group's output, exactly as section after section).
        let mut groups = self.sections.chunks_exact(FUSED);
        for g in &mut groups {
            if let Ok(g) = <&[Section; FUSED]>::try_from(g) {
                forward(g, left, &mut cols, n, right);
            }
        }
        for s in groups.remainder() {
            forward(std::array::from_ref(s), left, &mut cols, n, right);
        }
        self.backward_all(&mut cols, n, right)
    }

    /// Every group of sections backward over the right reflection and the columns, group
    /// after group; the last pass writes the result, so its finiteness is the answer.
    #[inline(always)]
    fn backward_all<const L: usize>(&self, cols: &mut [&mut [f64]; L], n: usize, right: &mut [[f64; L]]) -> bool {
        let mut finite = true;
        let mut groups = self.sections.chunks_exact(FUSED);
        for g in &mut groups {
            if let Ok(g) = <&[Section; FUSED]>::try_from(g) {
                finite = backward(g, cols, n, right);
            }
        }
        for s in groups.remainder() {
            finite = backward(std::array::from_ref(s), cols, n, right);
        }
        finite
    }

    /// Zero-phase filtering of `input` into `out` (same length, at least 2 samples), using
    /// `scratch` (resized as needed) for the extended signal.
    pub fn filtfilt_into(
        &self,
        input: &[f64],
        out: &mut [f64],
        scratch: &mut Vec<f64>,
    ) -> Result<(), IdentificationError> {
        if out.len() != input.len() {
            return Err(IdentificationError::BadInput {
                what: "low-pass output".into(),
                reason: format!("buffer has {} samples, input {}", out.len(), input.len()),
            });
        }
        out.copy_from_slice(input);
        self.filtfilt_in_place(out, scratch)
    }

    /// Zero-phase filtering of `buf` in place (at least 2 samples), using `scratch`.
    pub fn filtfilt_in_place(
        &self,
        buf: &mut [f64],
        scratch: &mut Vec<f64>,
    ) -> Result<(), IdentificationError> {
        check_len(buf.len())?;
        self.filtfilt_lanes::<1>([buf], scratch);
        Ok(())
    }

    /// Zero-phase filtering of several columns of one length (at least 2 samples) in place,
    /// eight at a time: the same result as [`Butterworth::filtfilt_in_place`] on each, bit for
    /// bit, several times faster.
    pub fn filtfilt_many_in_place(
        &self,
        columns: &mut [Vec<f64>],
        scratch: &mut Vec<f64>,
    ) -> Result<(), IdentificationError> {
        self.filtfilt_many_in_place_finite(columns, scratch).map(|_| ())
    }

    /// [`Butterworth::filtfilt_many_in_place`], telling whether every output is finite
    /// (checked as the outputs are written, so the caller need not read the columns again).
    pub(crate) fn filtfilt_many_in_place_finite(
        &self,
        columns: &mut [Vec<f64>],
        scratch: &mut Vec<f64>,
    ) -> Result<bool, IdentificationError> {
        let Some(n) = columns.first().map(Vec::len) else {
            return Ok(true);
        };
        check_len(n)?;
        if let Some((k, c)) = columns.iter().enumerate().find(|(_, c)| c.len() != n) {
            return Err(IdentificationError::BadInput {
                what: format!("low-pass column {k}"),
                reason: format!("{} samples, column 0 has {n}", c.len()),
            });
        }
        // Eight lanes in lock-step: the recursion of each lane waits on its own previous
        // output, so independent lanes fill the multiply-add pipeline (latency hiding).
        let mut finite = true;
        let mut groups = columns.chunks_exact_mut(8);
        for g in &mut groups {
            if let [a, b, c, d, e, f, g2, h] = g {
                finite &= self.filtfilt_lanes::<8>([a, b, c, d, e, f, g2, h], scratch);
            }
        }
        let mut rest = groups.into_remainder().chunks_exact_mut(4);
        for g in &mut rest {
            if let [a, b, c, d] = g {
                finite &= self.filtfilt_lanes::<4>([a, b, c, d], scratch);
            }
        }
        for g in rest.into_remainder().chunks_mut(2) {
            match g {
                [a, b] => finite &= self.filtfilt_lanes::<2>([a, b], scratch),
                [a] => finite &= self.filtfilt_lanes::<1>([a], scratch),
                _ => {}
            }
        }
        Ok(finite)
    }

    /// [`Butterworth::filtfilt_many_in_place_finite`] on eight columns of `n >= 2` samples
    /// that `producer` writes as the filter goes: `produce(a, b, range)` must write samples
    /// `a..b` of all eight columns into `range` (see [`Produce8`]); it is called with adjacent
    /// ranges of at most `step` samples (the first may be longer: it covers the left
    /// reflection's `pad + 1` samples) that cover `0..n` in order, and an error from it is
    /// returned as is. Each range goes through the forward pass while it is still in cache,
    /// instead of being written out by the producer and read back by the filter.
    ///
    /// The forward pass keeps its output in frames of eight lanes in `scratch` (with the
    /// reflections: `(n + 2 pad) x 8` values, plus the range buffers), and the backward pass
    /// runs on those frames and moves each chunk into `cols` as it makes it final. So each
    /// sample is transposed twice (columns to frames after it is produced, frames to columns
    /// when it is final), not four times, and the output columns are written once, by the
    /// backward pass (ADR 0016, amendment 2). `scratch` is grown when too short, never cleared.
    ///
    /// The same operations in the same order as the two-step version, so the same result
    /// bit for bit: the reflections are formed from the unfiltered samples (the right one's
    /// are copied aside before their range is filtered), each group of sections starts in
    /// steady state for its first reflected input exactly as there, and a section's
    /// recursion does not care where its input was cut into ranges (its state is carried).
    #[inline(always)]
    pub(crate) fn filtfilt8_fed<P: Produce8, C: Consume8<Error = P::Error>>(
        &self,
        cols: [&mut [f64]; 8],
        scratch: &mut Vec<f64>,
        step: usize,
        producer: &mut P,
        consumer: &mut C,
    ) -> Result<bool, P::Error> {
        const L: usize = 8;
        let n = cols.iter().map(|c| c.len()).min().unwrap_or(0);
        let mut cols = cols.map(|c| &mut c[..n]);
        // `producer` is called directly, never through a local closure: a closure is a
        // function of its own, compiled without the target features of the function this is
        // inlined into (ADR 0016, amendment 1).
        if n < 2 {
            // Nothing to filter (the callers check the length first): produce and leave.
            producer.produce(0, n, &mut cols)?;
            consumer.consume(0, &mut cols)?;
            return Ok(cols.iter().all(|c| c.iter().all(|v| v.is_finite())));
        }
        let step = step.max(1);
        let pad = self.settling.min(n - 1);
        // The first range reaches sample `pad`, which the left reflection needs unfiltered.
        let mut produced = (pad + 1).max(step).min(n);
        // `scratch`: the two reflections and the forward pass's output for every sample, in
        // frames of eight lanes (the backward pass reads them as they are, instead of the
        // forward pass transposing them back into the columns and the backward pass out
        // again), then eight short columns a range is produced into. Those stay in cache:
        // the unfiltered samples are never written out to the output columns, which the
        // backward pass writes first. Every value is written before it is read, so the
        // scratch is grown when too short and never cleared (a record's worth of zeros
        // written for nothing was 5 % of the whole call).
        let cap = produced.max(step.min(n));
        let needed = (2 * pad + n) * L + cap * L;
        if scratch.len() < needed {
            scratch.resize(needed, 0.0);
        }
        let (frame_part, range_part) = scratch[..needed].split_at_mut((2 * pad + n) * L);
        let (frames, _) = frame_part.as_chunks_mut::<L>();
        let (left, rest) = frames.split_at_mut(pad);
        let (right, store) = rest.split_at_mut(pad);
        let mut range_cols: [&mut [f64]; L] = {
            // `range_part` is `L` chunks of `cap >= 1` values (n >= 2), so each `next` has one;
            // the empty default is never taken.
            let mut parts = range_part.chunks_exact_mut(cap);
            std::array::from_fn(|_| parts.next().unwrap_or_default())
        };
        let mut fresh = range_cols.each_mut().map(|c| &mut c[..produced]);
        producer.produce(0, produced, &mut fresh)?;
        for i in 1..=pad {
            for l in 0..L {
                left[pad - i][l] = 2.0 * fresh[l][0] - fresh[l][i];
            }
        }
        // Each group of sections in steady state for its first input (the previous group's
        // first output of the left reflection), run over the left reflection.
        let mut groups = self.sections.chunks_exact(FUSED);
        let mut states: Vec<Cascade<'_, L, FUSED>> = Vec::with_capacity(MAX_ORDER / FUSED);
        for g in &mut groups {
            if let Ok(g) = <&[Section; FUSED]>::try_from(g) {
                let x0 = left.first().copied().unwrap_or(std::array::from_fn(|l| cols[l][0]));
                let mut st = Cascade::steady(g, x0);
                for f in left.iter_mut() {
                    *f = st.step(*f);
                }
                states.push(st);
            }
        }
        let mut last: Option<Cascade<'_, L, 1>> = None;
        if let Some(s) = groups.remainder().first() {
            let x0 = left.first().copied().unwrap_or(std::array::from_fn(|l| cols[l][0]));
            let mut st = Cascade::steady(std::array::from_ref(s), x0);
            for f in left.iter_mut() {
                *f = st.step(*f);
            }
            last = Some(st);
        }

        // Forward over each produced range: first copy aside what the right reflection needs
        // (samples n-1-pad .. n-1, unfiltered), then move the range into frames and filter it.
        let mut last_sample = [0.0; L];
        let mut a = 0;
        loop {
            let mut fresh = range_cols.each_mut().map(|c| &mut c[..produced - a]);
            let tail = (n - 1 - pad).max(a)..(n - 1).min(produced);
            for j in tail {
                for l in 0..L {
                    right[n - 2 - j][l] = fresh[l][j - a];
                }
            }
            if produced == n {
                last_sample = std::array::from_fn(|l| fresh[l][n - 1 - a]);
            }
            let range = &mut store[a..produced];
            to_frames(&mut fresh, 0, range);
            for st in states.iter_mut() {
                run8(st, range, false);
            }
            if let Some(st) = last.as_mut() {
                run8(st, range, false);
            }
            if produced == n {
                break;
            }
            a = produced;
            produced = (a + step).min(n);
            let mut fresh = range_cols.each_mut().map(|c| &mut c[..produced - a]);
            producer.produce(a, produced, &mut fresh)?;
        }
        // right[i - 1] held x[n - 1 - i]; the reflection is 2 x[n - 1] - x[n - 1 - i].
        for f in right.iter_mut() {
            for l in 0..L {
                f[l] = 2.0 * last_sample[l] - f[l];
            }
        }
        for st in states.iter_mut() {
            for f in right.iter_mut() {
                *f = st.step(*f);
            }
        }
        if let Some(st) = last.as_mut() {
            for f in right.iter_mut() {
                *f = st.step(*f);
            }
        }

        // Backward, group after group, as in the two-step version, over the frames; the last
        // group's output is final, and goes into the columns and to the consumer chunk by
        // chunk as it is written.
        let groups = self.sections.len().div_ceil(FUSED);
        let mut chunks = self.sections.chunks(FUSED);
        for _ in 1..groups {
            if let Some(g) = chunks.next() {
                match <&[Section; FUSED]>::try_from(g) {
                    Ok(g) => backward_frames(g, store, right),
                    Err(_) => backward_frames(std::array::from_ref(&g[0]), store, right),
                }
            }
        }
        match chunks.next() {
            Some(g) => match <&[Section; FUSED]>::try_from(g) {
                Ok(g) => backward_frames_consumed(g, &mut cols, store, right, consumer),
                Err(_) => backward_frames_consumed(std::array::from_ref(&g[0]), &mut cols, store, right, consumer),
            },
            None => {
                // No section: the output is the input.
                to_columns(&mut cols, 0, store);
                consumer.consume(0, &mut cols)?;
                Ok(true)
            }
        }
    }

    /// The forward pass of a stream (ADR 0019) in the state it has before its first input
    /// `x0`: each group of sections in the DC steady state for its own first input, as
    /// [`Butterworth::filtfilt8_fed`] starts them on its left reflection.
    pub(super) fn forward_steady(&self, x0: [f64; 8]) -> ForwardStream {
        let mut v = x0;
        let mut groups = Vec::with_capacity(MAX_ORDER / FUSED);
        let mut chunks = self.sections.chunks_exact(FUSED);
        for g in &mut chunks {
            if let Ok(g) = <&[Section; FUSED]>::try_from(g) {
                let st = Cascade::steady(g, v);
                v = { st }.step(v);
                groups.push(st.lanes);
            }
        }
        let last = chunks.remainder().first().map(|s| Cascade::steady(std::array::from_ref(s), v).lanes);
        ForwardStream { groups, last }
    }

    /// The forward pass over `frames` (in place, in time order), its state carried in `st`:
    /// frames fed in any cuts give the same outputs, bit for bit.
    #[inline(always)]
    pub(super) fn forward_run(&self, st: &mut ForwardStream, frames: &mut [[f64; 8]]) {
        for (lanes, g) in st.groups.iter_mut().zip(self.sections.chunks_exact(FUSED)) {
            if let Ok(sections) = <&[Section; FUSED]>::try_from(g) {
                let mut c = Cascade { sections, lanes: *lanes };
                run8(&mut c, frames, false);
                *lanes = c.lanes;
            }
        }
        if let (Some(lanes), Some(s)) = (st.last.as_mut(), self.sections.chunks_exact(FUSED).remainder().first()) {
            let mut c = Cascade { sections: std::array::from_ref(s), lanes: *lanes };
            for f in frames.iter_mut() {
                *f = c.step(*f);
            }
            *lanes = c.lanes;
        }
    }

    /// The backward pass over `frames` (in place, from the last to the first), each group of
    /// sections started in the DC steady state for its first input (the last frame as the
    /// previous group left it): [`backward_frames`] with no reflection, the frames past a
    /// block standing in for it.
    #[inline(always)]
    pub(super) fn backward_from_steady(&self, frames: &mut [[f64; 8]]) {
        for g in self.sections.chunks(FUSED) {
            match <&[Section; FUSED]>::try_from(g) {
                Ok(g) => backward_frames(g, frames, &mut []),
                Err(_) => backward_frames(std::array::from_ref(&g[0]), frames, &mut []),
            }
        }
    }

    /// Zero-phase filtering, allocating the output.
    pub fn filtfilt(&self, input: &[f64]) -> Result<Vec<f64>, IdentificationError> {
        let mut out = vec![0.0; input.len()];
        let mut scratch = Vec::new();
        self.filtfilt_into(input, &mut out, &mut scratch)?;
        Ok(out)
    }
}

fn check_len(n: usize) -> Result<(), IdentificationError> {
    if n < 2 {
        return Err(IdentificationError::BadInput {
            what: "low-pass input".into(),
            reason: format!("{n} samples, need at least 2"),
        });
    }
    Ok(())
}

/// One-call zero-phase low-pass of one channel: designs the filter and runs it.
/// NaN input is a `BadInput` naming the channel and sample.
pub fn filtfilt(
    channel: ChannelId,
    column: &[f64],
    order: usize,
    cutoff_hz: f64,
    sample_rate_hz: f64,
) -> Result<Vec<f64>, IdentificationError> {
    if let Some(i) = first_non_finite(column) {
        return Err(super::non_finite_error(channel, i, column[i], "sample"));
    }
    Butterworth::design(order, cutoff_hz, sample_rate_hz)?.filtfilt(column)
}
