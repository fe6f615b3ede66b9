//! The CPU's vector instructions, chosen in one place.
//!
//! The crate's hot loops are written once: plain Rust marked `#[inline(always)]` where the
//! compiler's own vectorisation serves, a method of `Simd` with one implementation per
//! instruction set where it was measured slower. `dispatch` is the one place that asks the
//! CPU: it runs a `Kernel` inside a function compiled for the chosen set, so that every loop
//! the kernel inlines is compiled for it too, and hands it that set's token. Only `dispatch`
//! makes a token, and only after the CPU was found to have its set: that is what makes the
//! intrinsics behind the tokens sound.
//!
//! No kernel uses a fused multiply-add and every sum is formed in the same order in every
//! implementation, so every set gives the bits of [`Isa::Scalar`]. `OILFILM_SIMD=scalar`,
//! `avx2` or `avx512` caps the set for a whole process.
//!
//! See docs/manual/conditioning.md#instruction-sets.

use std::cell::Cell;
use std::sync::OnceLock;

/// An instruction set a [`Kernel`] can be compiled for.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum Isa {
    /// The target's baseline (SSE2 on x86-64).
    Scalar,
    /// x86-64 with AVX2 (four `f64` lanes, sixteen registers).
    Avx2,
    /// x86-64 with AVX-512F (eight `f64` lanes, 32 registers).
    Avx512,
}

impl Isa {
    pub const ALL: [Isa; 3] = [Isa::Scalar, Isa::Avx2, Isa::Avx512];

    /// Whether this CPU can run kernels compiled for the set.
    pub fn supported(self) -> bool {
        match self {
            Isa::Scalar => true,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => std::arch::is_x86_feature_detected!("avx2"),
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => std::arch::is_x86_feature_detected!("avx512f"),
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// Every set this CPU has, narrowest first.
    pub fn available() -> Vec<Isa> {
        Isa::ALL.into_iter().filter(|i| i.supported()).collect()
    }

    /// The set kernels run on: the one [`with_isa`] set for this thread, else the widest this
    /// CPU has, capped by `OILFILM_SIMD` when that names a set.
    pub fn current() -> Isa {
        static PROCESS: OnceLock<Isa> = OnceLock::new();
        FORCED.with(Cell::get).unwrap_or_else(|| {
            *PROCESS.get_or_init(|| {
                let cap = std::env::var("OILFILM_SIMD").ok().and_then(|v| Isa::ALL.into_iter().find(|i| i.name() == v.trim()));
                let widest = Isa::ALL.into_iter().rev().find(|i| i.supported()).unwrap_or(Isa::Scalar);
                match cap {
                    Some(c) if c.supported() && (c as u8) < (widest as u8) => c,
                    _ => widest,
                }
            })
        })
    }

    /// `scalar`, `avx2`, `avx512`.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Scalar => "scalar",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }
}

thread_local! {
    static FORCED: Cell<Option<Isa>> = const { Cell::new(None) };
}

/// Runs `f` with [`Isa::current`] answering `isa` on this thread (a set the CPU lacks runs as
/// [`Isa::Scalar`]): how the tests run one computation on every set and compare the bits.
pub fn with_isa<R>(isa: Isa, f: impl FnOnce() -> R) -> R {
    let isa = if isa.supported() { isa } else { Isa::Scalar };
    let before = FORCED.with(|c| c.replace(Some(isa)));
    let out = f();
    FORCED.with(|c| c.set(before));
    out
}

/// A computation to compile once per instruction set: `run` and everything it calls
/// `#[inline(always)]` become part of the set's copy.
pub(crate) trait Kernel {
    type Output;
    fn run<S: Simd>(self, simd: S) -> Self::Output;
}

/// Runs `kernel` compiled for `isa`, or for [`Isa::Scalar`] when the CPU lacks `isa`.
pub(crate) fn dispatch<K: Kernel>(isa: Isa, kernel: K) -> K::Output {
    #[cfg(target_arch = "x86_64")]
    {
        if isa == Isa::Avx512 && isa.supported() {
            // SAFETY: a `target_feature` function's only requirement is that the CPU has the
            // feature, checked on the line above.
            return unsafe { x86::on_avx512(kernel) };
        }
        if isa == Isa::Avx2 && isa.supported() {
            // SAFETY: as above.
            return unsafe { x86::on_avx2(kernel) };
        }
    }
    let _ = isa;
    kernel.run(Scalar(()))
}

/// The kernels one instruction set implements its own way; the default of each is the
/// portable loop every set's results are compared with.
pub(crate) trait Simd: Copy {
    /// Moves samples `start .. start + frames.len()` of eight columns into frames of eight
    /// lanes (`to_frames`) or back: plain data movement.
    #[inline(always)]
    fn transpose8(self, cols: &mut [&mut [f64]; 8], start: usize, frames: &mut [[f64; 8]], to_frames: bool) {
        for (i, f) in frames.iter_mut().enumerate() {
            for (l, c) in cols.iter_mut().enumerate() {
                if to_frames {
                    f[l] = c[start + i];
                } else {
                    c[start + i] = f[l];
                }
            }
        }
    }

    /// [`mean`] of a column.
    #[inline(always)]
    fn mean(self, c: &[f64]) -> f64 {
        mean(c)
    }

    /// The Savitzky-Golay interior `dst[i] = sum_k c[k - 1] (x[i + M + k] - x[i + M - k])`,
    /// `k = 1..=M` summed in that order (`x` reaches `M` past `dst` on each side).
    #[inline(always)]
    fn derivative<const M: usize>(self, c: &[f64; M], x: &[f64], dst: &mut [f64]) {
        for (j, o) in dst.iter_mut().enumerate() {
            *o = derivative_point(c, x, j + M);
        }
    }
}

/// Mean of a column, summed relative to its first value (so the sum carries the variation,
/// not the offset) with eight independent partial sums combined pairwise: the portable
/// [`Simd::mean`] (the estimator's window means).
#[inline(always)]
pub(crate) fn mean(c: &[f64]) -> f64 {
    let Some(&shift) = c.first() else { return f64::NAN };
    let mut acc = [0.0f64; 8];
    let mut chunks = c.chunks_exact(8);
    for ch in &mut chunks {
        for l in 0..8 {
            acc[l] += ch[l] - shift;
        }
    }
    let tail: f64 = chunks.remainder().iter().map(|v| v - shift).sum();
    let s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7])) + tail;
    shift + s / c.len() as f64
}

/// Whether every value of `x` is finite, branch-free: `v - v` is 0 for a finite `v` and NaN
/// for an infinite or NaN one, and a NaN stays in a sum. Sixteen partial sums (four AVX2
/// vectors), so that the adds' latency is hidden.
#[inline(always)]
#[allow(clippy::eq_op)] // `v - v` is the point: 0 or NaN, never folded for floats.
pub(crate) fn all_finite(x: &[f64]) -> bool {
    let (chunks, rest) = x.as_chunks::<16>();
    let mut acc = [0.0f64; 16];
    for c in chunks {
        for l in 0..16 {
            acc[l] += c[l] - c[l];
        }
    }
    let mut sum = acc.iter().sum::<f64>();
    for v in rest {
        sum += v - v;
    }
    sum == 0.0
}

/// Index of the first value of `x` that is NaN or infinite: blocks of finite values are
/// passed over by [`all_finite`], and only the block holding one is searched.
pub(crate) fn first_non_finite(x: &[f64]) -> Option<usize> {
    const BLOCK: usize = 256;
    let (k, block) = x.chunks(BLOCK).enumerate().find(|(_, b)| !all_finite(b))?;
    block.iter().position(|v| !v.is_finite()).map(|i| k * BLOCK + i)
}

/// One output of [`Simd::derivative`], centred on `x[i]`.
#[inline(always)]
pub(crate) fn derivative_point<const M: usize>(c: &[f64; M], x: &[f64], i: usize) -> f64 {
    let mut acc = c[0] * (x[i + 1] - x[i - 1]);
    for k in 2..M + 1 {
        acc += c[k - 1] * (x[i + k] - x[i - k]);
    }
    acc
}

/// The baseline's token: every kernel is the portable default.
#[derive(Copy, Clone)]
pub(crate) struct Scalar(());

#[cfg(test)]
impl Scalar {
    /// The baseline needs no check: its token is always sound.
    pub(crate) fn token() -> Self {
        Scalar(())
    }
}

impl Simd for Scalar {}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::{derivative_point, Kernel, Simd};

    /// AVX2's token. Made only by [`on_avx2`], which runs only on a CPU with AVX2.
    #[derive(Copy, Clone)]
    pub(crate) struct Avx2(());

    /// AVX-512F's token. Made only by [`on_avx512`], which runs only on a CPU with AVX-512F.
    #[derive(Copy, Clone)]
    pub(crate) struct Avx512(());

    #[target_feature(enable = "avx2")]
    pub(super) fn on_avx2<K: Kernel>(kernel: K) -> K::Output {
        kernel.run(Avx2(()))
    }

    #[target_feature(enable = "avx512f")]
    pub(super) fn on_avx512<K: Kernel>(kernel: K) -> K::Output {
        kernel.run(Avx512(()))
    }

    impl Simd for Avx2 {
        #[inline(always)]
        fn transpose8(self, cols: &mut [&mut [f64]; 8], start: usize, frames: &mut [[f64; 8]], to_frames: bool) {
            // SAFETY: an `Avx2` token exists only on a CPU with AVX2.
            unsafe { transpose8_avx2(cols, start, frames, to_frames) }
        }

        #[inline(always)]
        fn derivative<const M: usize>(self, c: &[f64; M], x: &[f64], dst: &mut [f64]) {
            // SAFETY: as above.
            unsafe { derivative_avx2(c, x, dst) }
        }

        #[inline(always)]
        fn mean(self, c: &[f64]) -> f64 {
            // SAFETY: as above.
            unsafe { mean_avx2(c) }
        }
    }

    impl Simd for Avx512 {
        #[inline(always)]
        fn transpose8(self, cols: &mut [&mut [f64]; 8], start: usize, frames: &mut [[f64; 8]], to_frames: bool) {
            // SAFETY: an `Avx512` token exists only on a CPU with AVX-512F, which implies AVX2.
            unsafe { transpose8_avx2(cols, start, frames, to_frames) }
        }

        #[inline(always)]
        fn derivative<const M: usize>(self, c: &[f64; M], x: &[f64], dst: &mut [f64]) {
            // SAFETY: as above.
            unsafe { derivative_avx512(c, x, dst) }
        }

        #[inline(always)]
        fn mean(self, c: &[f64]) -> f64 {
            // SAFETY: AVX-512F implies AVX2.
            unsafe { mean_avx2(c) }
        }
    }

    /// [`Simd::transpose8`] by 4 x 4 register transposes: per four samples of four columns,
    /// four vector loads, eight shuffles, four vector stores instead of sixteen scalar moves.
    #[target_feature(enable = "avx2")]
    fn transpose8_avx2(cols: &mut [&mut [f64]; 8], start: usize, frames: &mut [[f64; 8]], to_frames: bool) {
        #[inline]
        #[target_feature(enable = "avx2")]
        fn tr(r: [__m256d; 4]) -> [__m256d; 4] {
            let (t0, t1) = (_mm256_unpacklo_pd(r[0], r[1]), _mm256_unpackhi_pd(r[0], r[1]));
            let (t2, t3) = (_mm256_unpacklo_pd(r[2], r[3]), _mm256_unpackhi_pd(r[2], r[3]));
            [
                _mm256_permute2f128_pd::<0x20>(t0, t2),
                _mm256_permute2f128_pd::<0x20>(t1, t3),
                _mm256_permute2f128_pd::<0x31>(t0, t2),
                _mm256_permute2f128_pd::<0x31>(t1, t3),
            ]
        }
        let t = frames.len();
        let mut c: [&mut [f64]; 8] = cols.each_mut().map(|c| &mut c[start..start + t]);
        let body = t / 4 * 4;
        let f = frames.as_flattened_mut();
        for i in (0..body).step_by(4) {
            for l0 in [0, 4] {
                // SAFETY: i + 4 <= t, every `c[j]` holds t values and `f` 8 t: the accesses are
                // c[l0 + j][i .. i + 4] and f[8 (i + k) + l0 ..][..4] for j, k < 4.
                unsafe {
                    if to_frames {
                        let r = std::array::from_fn(|j| _mm256_loadu_pd(c[l0 + j].as_ptr().add(i)));
                        for (k, v) in tr(r).into_iter().enumerate() {
                            _mm256_storeu_pd(f.as_mut_ptr().add(8 * (i + k) + l0), v);
                        }
                    } else {
                        let r = std::array::from_fn(|k| _mm256_loadu_pd(f.as_ptr().add(8 * (i + k) + l0)));
                        for (j, v) in tr(r).into_iter().enumerate() {
                            _mm256_storeu_pd(c[l0 + j].as_mut_ptr().add(i), v);
                        }
                    }
                }
            }
        }
        tail(&mut c, f, body, t, to_frames);
    }

    /// The samples past the transposed blocks, one by one.
    #[inline(always)]
    fn tail(c: &mut [&mut [f64]; 8], f: &mut [f64], from: usize, to: usize, to_frames: bool) {
        for i in from..to {
            for (l, col) in c.iter_mut().enumerate() {
                if to_frames {
                    f[8 * i + l] = col[i];
                } else {
                    col[i] = f[8 * i + l];
                }
            }
        }
    }

    /// [`Simd::derivative`] with intrinsics, `$w` outputs per vector: four vectors of
    /// outputs per step share their loads (`4 W` outputs read `3 W + 2 M + 1` distinct
    /// shifted vectors; the compiler's own vectorisation built each from half loads and
    /// blends). Each output's sum in the order of [`derivative_point`], the same bits.
    macro_rules! derivative_kernel {
        ($name:ident, $feature:literal, $w:literal, $v:ty, $set1:ident, $load:ident, $store:ident, $add:ident, $sub:ident, $mul:ident) => {
            #[target_feature(enable = $feature)]
            fn $name<const M: usize>(c: &[f64; M], x: &[f64], dst: &mut [f64]) {
                assert!(x.len() >= dst.len() + 2 * M, "the differentiator's input reaches M past its output");
                let cv: [$v; M] = std::array::from_fn(|k| $set1(c[k]));
                let wide = dst.len() / (4 * $w) * (4 * $w);
                let body = dst.len() / $w * $w;
                let mut j = 0;
                while j < wide {
                    // SAFETY: j + 4 W <= dst.len(): the loads read x[j + M + s ..][..W] for
                    // -M <= s <= 3 W + M, inside x[.. dst.len() + 2 M] (asserted above).
                    unsafe {
                        let p = x.as_ptr().add(j + M);
                        let d = |q: usize, k: usize| $sub($load(p.add(q * $w + k)), $load(p.add(q * $w).sub(k)));
                        let mut acc: [$v; 4] = std::array::from_fn(|q| $mul(cv[0], d(q, 1)));
                        for k in 2..M + 1 {
                            for q in 0..4 {
                                acc[q] = $add(acc[q], $mul(cv[k - 1], d(q, k)));
                            }
                        }
                        for q in 0..4 {
                            $store(dst.as_mut_ptr().add(j + q * $w), acc[q]);
                        }
                    }
                    j += 4 * $w;
                }
                while j < body {
                    // SAFETY: j + W <= dst.len(), the loads as above.
                    unsafe {
                        let p = x.as_ptr().add(j + M);
                        let d = |k: usize| $sub($load(p.add(k)), $load(p.sub(k)));
                        let mut acc = $mul(cv[0], d(1));
                        for k in 2..M + 1 {
                            acc = $add(acc, $mul(cv[k - 1], d(k)));
                        }
                        $store(dst.as_mut_ptr().add(j), acc);
                    }
                    j += $w;
                }
                for (j, o) in dst.iter_mut().enumerate().skip(body) {
                    *o = derivative_point(c, x, j + M);
                }
            }
        };
    }

    /// [`Simd::mean`] with its eight partial sums in two AVX registers (lanes 0-3 and 4-7):
    /// each lane adds the same differences in the same order, and they are combined as the
    /// portable mean combines them, so the same bits. (The compiler's own vectorisation of the
    /// portable mean shuffled two-lane halves and cost as much as the QR of the chunk.)
    #[target_feature(enable = "avx2")]
    fn mean_avx2(c: &[f64]) -> f64 {
        let Some(&shift) = c.first() else { return f64::NAN };
        let mut chunks = c.chunks_exact(8);
        let s = _mm256_set1_pd(shift);
        let (mut lo, mut hi) = (_mm256_setzero_pd(), _mm256_setzero_pd());
        for ch in &mut chunks {
            // SAFETY: `ch` holds 8 doubles; unaligned loads.
            let (a, b) = unsafe { (_mm256_loadu_pd(ch.as_ptr()), _mm256_loadu_pd(ch.as_ptr().add(4))) };
            lo = _mm256_add_pd(lo, _mm256_sub_pd(a, s));
            hi = _mm256_add_pd(hi, _mm256_sub_pd(b, s));
        }
        let mut acc = [0.0f64; 8];
        // SAFETY: `acc` holds 8 doubles; unaligned stores.
        unsafe {
            _mm256_storeu_pd(acc.as_mut_ptr(), lo);
            _mm256_storeu_pd(acc.as_mut_ptr().add(4), hi);
        }
        let tail: f64 = chunks.remainder().iter().map(|v| v - shift).sum();
        let total = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7])) + tail;
        shift + total / c.len() as f64
    }

    derivative_kernel!(derivative_avx2, "avx2", 4, __m256d, _mm256_set1_pd, _mm256_loadu_pd, _mm256_storeu_pd, _mm256_add_pd, _mm256_sub_pd, _mm256_mul_pd);
    derivative_kernel!(
        derivative_avx512,
        "avx512f",
        8,
        __m512d,
        _mm512_set1_pd,
        _mm512_loadu_pd,
        _mm512_storeu_pd,
        _mm512_add_pd,
        _mm512_sub_pd,
        _mm512_mul_pd
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// xorshift values over many magnitudes, with zeros and subnormals among them.
    fn values(n: usize, seed: u64) -> Vec<f64> {
        let mut s = seed | 1;
        (0..n)
            .map(|i| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                let unit = (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                match i % 97 {
                    0 => 0.0,
                    1 => f64::MIN_POSITIVE * unit,
                    _ => unit * 10f64.powi((s % 13) as i32 - 6),
                }
            })
            .collect()
    }

    struct Kernels {
        frames: Vec<[f64; 8]>,
        x: Vec<f64>,
    }

    /// Every [`Simd`] kernel on the same data, its outputs as bits.
    impl Kernel for Kernels {
        type Output = Vec<u64>;
        fn run<S: Simd>(self, simd: S) -> Vec<u64> {
            let mut bits = Vec::new();
            let n = self.frames.len();
            let mut cols: Vec<Vec<f64>> = (0..8).map(|l| self.frames.iter().map(|f| f[l]).collect()).collect();
            let mut frames = vec![[0.0; 8]; n - 3];
            let mut c: [&mut [f64]; 8] = {
                let mut it = cols.iter_mut();
                std::array::from_fn(|_| it.next().map(Vec::as_mut_slice).unwrap_or_default())
            };
            simd.transpose8(&mut c, 3, &mut frames, true);
            bits.extend(frames.as_flattened().iter().map(|v| v.to_bits()));
            simd.transpose8(&mut c, 2, &mut frames, false);
            bits.extend(c.iter().flat_map(|c| c.iter().map(|v| v.to_bits())));
            for m in [4usize, 5, 6] {
                let cf = values(m, m as u64);
                let mut dst = vec![0.0; self.x.len() - 2 * m];
                match m {
                    4 => simd.derivative::<4>(&cf[..].try_into().unwrap(), &self.x, &mut dst),
                    5 => simd.derivative::<5>(&cf[..].try_into().unwrap(), &self.x, &mut dst),
                    _ => simd.derivative::<6>(&cf[..].try_into().unwrap(), &self.x, &mut dst),
                }
                bits.extend(dst.iter().map(|v| v.to_bits()));
            }
            bits.extend([&self.x[..], &self.x[3..], &self.x[..5]].map(|c| simd.mean(c).to_bits()));
            bits
        }
    }

    /// Each instruction set this CPU has gives the portable kernels' bits (transposes both
    /// ways at odd offsets, the differentiator at every compiled half-length, the mean,
    /// lengths that leave tails). The whole chain's drivers are compared the same way in their own tests.
    #[test]
    fn every_instruction_set_gives_the_scalar_bits() {
        for n in [4, 5, 37, 1029] {
            let flat = values(8 * n, n as u64);
            let (frames, _) = flat.as_chunks::<8>();
            let run = |isa| dispatch(isa, Kernels { frames: frames.to_vec(), x: values(n + 40, 3) });
            let scalar = run(Isa::Scalar);
            assert!(scalar.len() > 8 * n);
            for isa in Isa::available() {
                assert!(run(isa) == scalar, "{isa:?}, {n} frames");
            }
        }
        println!("sets compared with the scalar kernels: {:?}", Isa::available());
    }

    /// `all_finite` and `first_non_finite` against the definition, on lengths that cut the
    /// chunks of sixteen and the blocks of 256, with the extremes that `v - v` must still take
    /// to 0 (the largest finite, subnormals, -0) and each kind of non-finite value at each
    /// position; of two, the first counts.
    #[test]
    fn finiteness_agrees_with_the_definition() {
        for n in [0, 1, 7, 8, 9, 15, 16, 17, 33, 40, 255, 256, 257, 700] {
            let clean: Vec<f64> = (0..n).map(|i| [f64::MAX, -f64::MAX, 5e-324, -0.0, 1.5, -2.5e-300, f64::MIN_POSITIVE][i % 7]).collect();
            assert!(all_finite(&clean) && first_non_finite(&clean).is_none(), "{n} finite values");
            for at in (0..n).filter(|at| n < 64 || at % 37 == 0 || at % 256 == 255 || at % 256 == 0) {
                for bad in [f64::INFINITY, f64::NEG_INFINITY, f64::NAN, -f64::NAN] {
                    let mut x = clean.clone();
                    x[at] = bad;
                    assert!(!all_finite(&x), "{bad} at {at} of {n}");
                    assert_eq!(first_non_finite(&x), Some(at), "{bad} at {at} of {n}");
                    x[n - 1] = f64::NAN;
                    assert_eq!(first_non_finite(&x), Some(at), "then NaN last, {bad} at {at} of {n}");
                }
            }
        }
    }

    #[test]
    fn forcing_a_set_is_undone_and_a_missing_set_runs_scalar() {
        let before = Isa::current();
        for isa in Isa::ALL {
            let seen = with_isa(isa, Isa::current);
            assert_eq!(seen, if isa.supported() { isa } else { Isa::Scalar });
        }
        assert_eq!(Isa::current(), before);
    }
}
