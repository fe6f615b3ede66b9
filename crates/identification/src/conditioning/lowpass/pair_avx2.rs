//! The low-pass's hot loop on an AVX2 CPU without AVX-512: a group of two second-order
//! sections ([`super::Cascade`]) over eight lanes of frames, with the recursion's state in
//! registers.
//!
//! The generic [`super::Cascade::step`] compiled for AVX2 needs two sections x three state
//! vectors x two halves of eight lanes = 12 of the 16 vector registers for state alone, plus
//! the ten coefficients; the compiler kept most of the state on the stack, a store and a
//! reload per state vector and sample, some of them on the recursion's loop-carried path
//! (perf: the backward pass alone was a fifth of `condition_into` on such a host). Here:
//!
//! - `b2 x[n-1]` is the product `b0 x[n-1]` formed one sample earlier, when `b2 == b0`
//!   bit for bit (every Butterworth section: `b = [g, 2 g, g]`): the same operation on the
//!   same operands, so the same value, carried as `p` in place of `x[n-1]`. One multiply
//!   fewer per section and lane (four instead of five).
//! - `p` goes through memory (volatile accesses, which the compiler keeps there): it is
//!   formed from the input and used a sample later, off the recursion's loop-carried path.
//!   With it out of the way, `y[n-1]` and `q` of the four (section, lane group) pairs, eight
//!   vectors, stay in registers beside the coefficients; left to itself the compiler spilled
//!   some of those instead (the attempts in ADR 0016, amendments 1 and 3). The assembly's only
//!   stack traffic in the loop is the four products and the coefficients' loads.
//!
//! Every output is `(b0 x + q) - a1 y[n-1]` and every `q` is `(b1 x + b2 x[n-1]) - a2
//! y[n-1]`, as in [`super::Lanes::step`]: the same operations in the same order, so the same
//! result bit for bit (ADR 0016; `kernel_equals_the_generic_cascade_bit_for_bit` below, and
//! the front end's bit-for-bit tests, which take this path on such a host).

use std::arch::x86_64::{__m256d, _mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_set1_pd, _mm256_set_pd, _mm256_storeu_pd, _mm256_sub_pd};

use super::{Lanes, Section};

/// Whether [`run`] may be called for these sections on this CPU: `b2 == b0` bit for bit in
/// both, and the CPU has AVX2 but not AVX-512F (whose 32 registers hold the generic loop's
/// state: there the generic loop is kept).
#[inline(always)]
pub(super) fn applies(sections: &[Section; 2]) -> bool {
    sections.iter().all(|s| s.b[2].to_bits() == s.b[0].to_bits())
        && std::arch::is_x86_feature_detected!("avx2")
        && !std::arch::is_x86_feature_detected!("avx512f")
}

/// One half (four lanes) of one section's state in registers.
#[derive(Copy, Clone)]
struct Half {
    /// `y[n-1]`, `q[n]`.
    y1: __m256d,
    q: __m256d,
}

/// One section's coefficients, each in all four lanes.
struct Coefficients {
    b0: __m256d,
    b1: __m256d,
    a1: __m256d,
    a2: __m256d,
}

/// Lanes `4 h .. 4 h + 4` of an array of eight.
#[target_feature(enable = "avx2")]
#[inline]
fn half(v: &[f64; 8], h: usize) -> __m256d {
    let o = 4 * h;
    _mm256_set_pd(v[o + 3], v[o + 2], v[o + 1], v[o])
}

/// Writes a vector into lanes `4 h .. 4 h + 4` of an array of eight.
#[target_feature(enable = "avx2")]
#[inline]
fn put(v: &mut [f64; 8], h: usize, x: __m256d) {
    let (halves, _) = v.as_chunks_mut::<4>();
    // SAFETY: `halves[h]` is four `f64`, the width of the unaligned store.
    unsafe { _mm256_storeu_pd(halves[h].as_mut_ptr(), x) };
}

/// One section, one half, one sample: returns `y[n]` and updates the state, as
/// [`super::Lanes::step`]. `p` is `b2 x[n-1]`, kept in memory (see [`run`]).
#[target_feature(enable = "avx2")]
#[inline]
fn step(c: &Coefficients, s: &mut Half, p: &mut __m256d, x: __m256d) -> __m256d {
    let bx = _mm256_mul_pd(c.b0, x);
    let y = _mm256_sub_pd(_mm256_add_pd(bx, s.q), _mm256_mul_pd(c.a1, s.y1));
    // SAFETY: `p` is a valid, aligned `__m256d`.
    let p_prev = unsafe { std::ptr::read_volatile(p) };
    s.q = _mm256_sub_pd(_mm256_add_pd(_mm256_mul_pd(c.b1, x), p_prev), _mm256_mul_pd(c.a2, s.y1));
    // `b2 x[n]` for the next sample: `b2 == b0` (checked by `applies`), so this product is it.
    // SAFETY: as above.
    unsafe { std::ptr::write_volatile(p, bx) };
    s.y1 = y;
    y
}

/// One frame through both sections, in place: `st` and `p` are `[first section's lanes
/// 0-3, its lanes 4-7, second section's lanes 0-3, its lanes 4-7]`.
#[target_feature(enable = "avx2")]
#[inline]
fn frame(c: &[Coefficients; 2], st: &mut [Half; 4], p: &mut [__m256d; 4], f: &mut [f64; 8]) {
    let (halves, _) = f.as_chunks_mut::<4>();
    let (lo, hi) = (halves[0].as_mut_ptr(), halves[1].as_mut_ptr());
    let [a_lo, a_hi, b_lo, b_hi] = st;
    let [pa_lo, pa_hi, pb_lo, pb_hi] = p;
    // SAFETY: `lo` and `hi` each point at four `f64` of this frame, the width of the
    // unaligned loads and stores.
    unsafe {
        let ya_lo = step(&c[0], a_lo, pa_lo, _mm256_loadu_pd(lo));
        let ya_hi = step(&c[0], a_hi, pa_hi, _mm256_loadu_pd(hi));
        _mm256_storeu_pd(lo, step(&c[1], b_lo, pb_lo, ya_lo));
        _mm256_storeu_pd(hi, step(&c[1], b_hi, pb_hi, ya_hi));
    }
}

/// A section's coefficients in all four lanes.
#[target_feature(enable = "avx2")]
#[inline]
fn coefficients(s: &Section) -> Coefficients {
    Coefficients { b0: _mm256_set1_pd(s.b[0]), b1: _mm256_set1_pd(s.b[1]), a1: _mm256_set1_pd(s.a[0]), a2: _mm256_set1_pd(s.a[1]) }
}

/// One section's state for lanes `4 h .. 4 h + 4`, and `p = b2 x[n-1]` formed as the
/// generic step would form it next.
#[target_feature(enable = "avx2")]
#[inline]
fn state(s: &Section, l: &Lanes<8>, h: usize) -> (Half, __m256d) {
    (Half { y1: half(&l.y1, h), q: half(&l.q, h) }, _mm256_mul_pd(_mm256_set1_pd(s.b[2]), half(&l.x1, h)))
}

/// Runs the two sections over `frames` in place, from the first frame to the last or (with
/// `reverse`) from the last to the first, starting from and leaving their state in `lanes`
/// exactly as `frames.len()` calls of [`super::Cascade::step`] would.
///
/// The caller checks [`applies`] (the sections' `b2 == b0`, the CPU's AVX2) first. Plain
/// loops and `#[inline]` helpers with the same target feature, no closures: a closure would
/// be compiled without AVX2 (ADR 0016, amendment 1).
#[target_feature(enable = "avx2")]
pub(super) fn run(sections: &[Section; 2], lanes: &mut [Lanes<8>; 2], frames: &mut [[f64; 8]], reverse: bool) {
    let Some(last) = (if reverse { frames.first() } else { frames.last() }).copied() else {
        return;
    };
    let c = [coefficients(&sections[0]), coefficients(&sections[1])];
    let parts = [
        state(&sections[0], &lanes[0], 0),
        state(&sections[0], &lanes[0], 1),
        state(&sections[1], &lanes[1], 0),
        state(&sections[1], &lanes[1], 1),
    ];
    let mut st = [parts[0].0, parts[1].0, parts[2].0, parts[3].0];
    // `p` through memory (volatile accesses, which the compiler keeps there): it is off the
    // recursion's loop-carried path (formed from the input, used a sample later), and with
    // it out of the way `y[n-1]` and `q` of all four halves stay in registers. Left to
    // itself the compiler spilled some of those instead, on the recursion's path.
    let mut p = [parts[0].1, parts[1].1, parts[2].1, parts[3].1];
    if reverse {
        for f in frames.iter_mut().rev() {
            frame(&c, &mut st, &mut p, f);
        }
    } else {
        for f in frames.iter_mut() {
            frame(&c, &mut st, &mut p, f);
        }
    }
    // Back to the generic state: `x[n-1]` of the first section is the last input, of the
    // second the first section's last output.
    lanes[0].x1 = last;
    for (k, pair) in st.chunks_exact(2).enumerate() {
        let l = &mut lanes[k];
        for (h, s) in pair.iter().enumerate() {
            put(&mut l.y1, h, s.y1);
            put(&mut l.q, h, s.q);
        }
    }
    lanes[1].x1 = lanes[0].y1;
}

#[cfg(test)]
mod tests {
    use super::super::{Butterworth, Cascade};
    use super::*;

    /// Deterministic values spanning many magnitudes, with subnormal and zero inputs among
    /// them (where a product formed another way would round differently).
    fn frames(n: usize, seed: u64) -> Vec<[f64; 8]> {
        let mut s = seed | 1;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        (0..n)
            .map(|i| {
                std::array::from_fn(|l| {
                    let r = next();
                    let unit = (r >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                    match (i + l) % 97 {
                        0 => 0.0,
                        1 => f64::MIN_POSITIVE * unit,
                        2 => 1e300 * unit,
                        _ => unit * 10f64.powi((r % 13) as i32 - 6),
                    }
                })
            })
            .collect()
    }

    fn same(a: &[[f64; 8]], b: &[[f64; 8]]) -> bool {
        a.len() == b.len() && a.iter().flatten().zip(b.iter().flatten()).all(|(x, y)| x.to_bits() == y.to_bits())
    }

    #[test]
    fn kernel_equals_the_generic_cascade_bit_for_bit() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("skipped: this CPU has no AVX2");
            return;
        }
        let mut checked = 0;
        for (order, cutoff_hz) in [(4, 200.0), (4, 1.0), (8, 900.0), (4, 2400.0)] {
            let lp = Butterworth::design(order, cutoff_hz, 5000.0).expect("a valid design");
            for g in lp.sections().chunks_exact(2) {
                let g: &[Section; 2] = g.try_into().expect("chunks of two");
                assert_eq!(g[0].b[2].to_bits(), g[0].b[0].to_bits(), "Butterworth sections have b2 == b0");
                for (n, reverse) in [(0, false), (1, true), (7, false), (513, false), (513, true)] {
                    let input = frames(n, 0x5EED + n as u64 + order as u64);
                    let start = frames(1, 99)[0];
                    let (mut generic, mut kernel) = (Cascade::steady(g, start), Cascade::steady(g, start));
                    // Some steps first, so the state is not the steady one.
                    for f in frames(5, 7) {
                        generic.step(f);
                        kernel.step(f);
                    }
                    let mut expected = input.clone();
                    let indices: Vec<usize> = if reverse { (0..n).rev().collect() } else { (0..n).collect() };
                    for i in indices {
                        expected[i] = generic.step(expected[i]);
                    }
                    let mut got = input.clone();
                    // SAFETY: AVX2 checked at the top of the test.
                    unsafe { run(g, &mut kernel.lanes, &mut got, reverse) };
                    assert!(same(&got, &expected), "order {order}, {cutoff_hz} Hz, {n} frames, reverse {reverse}");
                    // The state left behind continues the same way.
                    let tail = frames(3, 11);
                    let (mut a, mut b) = (tail.clone(), tail);
                    for f in a.iter_mut() {
                        *f = generic.step(*f);
                    }
                    for f in b.iter_mut() {
                        *f = kernel.step(*f);
                    }
                    assert!(same(&a, &b), "state after order {order}, {n} frames, reverse {reverse}");
                    // The outputs really moved (the comparison is not of two copies of the input).
                    assert!(n == 0 || !same(&got, &input));
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 5 * (1 + 1 + 2 + 1));
    }
}
