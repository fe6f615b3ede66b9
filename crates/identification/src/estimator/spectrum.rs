//! Excitation lines in the measured motion, and how much of each signal they carry.
//!
//! Sinusoidal excitation (Zhou et al. 2004 §2.4: 0–80 Hz sine waves from two exciters; the
//! review of Tiwari, Lees & Friswell, "Identification of dynamic bearing parameters: a review",
//! Shock and Vibration Digest 36 (2004) 99–124, §3) puts the information about the film into a
//! few spectral lines. What the regression can identify is decided by them: every regressor of
//! a direction excited at `L` lines lies in the `2L`-dimensional span of their cosines and
//! sines. This module finds the lines and the fraction of each signal's variance outside them
//! (noise, which in a regressor biases the fit towards zero: errors in variables).
//!
//! **Method.** Welch-averaged periodogram (P. D. Welch, IEEE Trans. Audio Electroacoust. 15
//! (1967) 70–73) with segments of the largest power of two not exceeding the window (at most
//! 2¹⁶), evenly spread with about 50 % overlap, a 4-term Blackman–Harris taper (sidelobes below −92 dB, main lobe ±4
//! bins: F. J. Harris, Proc. IEEE 66 (1978) 51–83), each segment's taper-weighted mean removed. Two real
//! signals share one complex radix-2 FFT (`z = x + i y`). A bin is a line when it is the
//! largest within ±4 bins, within 70 dB of the strongest bin, and at least 30 dB above the
//! median of its ±64-bin neighbourhood (a local floor, so low-pass coloured noise near DC is not
//! mistaken for a line). Its frequency is refined by Gaussian (log-parabolic) interpolation of
//! the three top bins. Lines closer than the main-lobe width (4 bins) are one line.

use rustfft::num_complex::Complex;

use crate::fft;
use crate::simd::{self, Isa, Kernel, Simd};

/// Half-width of the Blackman–Harris main lobe, in bins.
pub const MAIN_LOBE_BINS: usize = 4;
/// A line must stand this far (power ratio) above the local median floor: 30 dB.
const FLOOR_RATIO: f64 = 1.0e3;
/// ... and within this power ratio of the strongest bin: 70 dB.
const DYNAMIC_RANGE: f64 = 1.0e-7;
/// Half-width of the neighbourhood for the local floor.
const FLOOR_HALF_WIDTH: usize = 64;
/// Bins below this index are treated as drift, not excitation.
const FIRST_BIN: usize = 2 * MAIN_LOBE_BINS;
/// Shortest segment analysed.
const MIN_SEGMENT: usize = 64;
/// Longest segment.
const MAX_SEGMENT: usize = 1 << 16;

/// Lines found in a window's displacement and the noise fractions of its channels.
#[derive(Debug, Clone, PartialEq)]
pub struct LineAnalysis {
    /// Lines of x and of y (Hz, ascending).
    pub lines: [Vec<f64>; 2],
    /// Union of the two, lines within a main lobe merged (Hz, ascending).
    pub merged: Vec<f64>,
    /// Fraction of the displacement variance (x, y) carried by its lines.
    pub line_fraction: [f64; 2],
    /// Fraction of the velocity variance (x', y') outside the lines of the same direction.
    pub velocity_noise_fraction: [f64; 2],
    /// Bin spacing of the analysis, Hz (lines closer than `4 ×` this are merged).
    pub resolution_hz: f64,
    /// Per line of `lines` (same order): its signal-to-noise ratio in the regressors of its
    /// direction, the smaller of displacement and velocity. Each is the line's power (within
    /// its main lobe) over the power outside every line of that direction, i.e. over the whole
    /// regression band's noise ([`LINE_SNR_MIN`] says why that is the comparison).
    pub line_snr: [Vec<f64>; 2],
}

/// A line determines coefficients only if it stands this far above the broadband noise of
/// every regressor of its direction (power ratio; see [`LineAnalysis::determining`]).
///
/// **Why.** Least squares sees each regressor as its lines plus the noise of the whole band
/// the low-pass passes. In the design directions that one line alone spans (for a single
/// strong sine plus a weak line: the two dimensions beside the sine's `span{cos, sin}`), the
/// regressors are that line plus all the band's noise, and the noise does not correlate with
/// the force: errors in variables attenuate the fit along those directions by
/// `noise / (line + noise) = 1 / (1 + SNR)`, and the residual, hence every residual-based
/// standard error, shows nothing of it. Worse, the noise fills those directions of the Gram
/// matrix, so the window looks well conditioned and its standard errors small. `SNR ≥ 3`
/// keeps that attenuation at or below 25 %, the default limit on a direct coefficient's
/// relative standard error ([`super::EstimatorConfig::max_relative_se`]).
///
/// Measured (Zhou rig file, 0.1 um probes, 100 N sine at 37 Hz on both exciters, 10 s, the
/// adaptive 55.5 Hz low-pass): the bellows' 0.2 % ripple puts a 3.0 Hz line in the motion at
/// 9 % of the sine's amplitude, but its velocity (`ω` twelve times smaller than at 37 Hz) is
/// below the differentiated probe noise of the band: SNR 0.08 in x', 0.13 in y' (-11 and
/// -9 dB). Counted as a line it made the design formally of rank 4, and the window came out
/// with kxx = -1.04e7 N/m against a truth of +8.28e7 and dyy 70 % low, at standard errors of
/// 2-3 %: 40 standard errors off. Without probe noise (and at 10 N, so the film stays linear)
/// the same 3 Hz line gives kxx within 10 %: the line itself is honest, the noise beside it
/// is what decides. The velocity's SNR does not depend on the sine's amplitude (the ripple's
/// motion and the probe noise are both fixed; 50 and 300 N give the same 0.08 and 0.13), which
/// is why a rule on the amplitude ratio of the lines would not do. A two-tone 23/37 Hz record
/// at the same noise keeps both lines far above the threshold (SNR 40-1500).
pub const LINE_SNR_MIN: f64 = 3.0;

impl LineAnalysis {
    fn empty() -> Self {
        Self {
            lines: [Vec::new(), Vec::new()],
            merged: Vec::new(),
            line_fraction: [f64::NAN; 2],
            velocity_noise_fraction: [f64::NAN; 2],
            resolution_hz: f64::NAN,
            line_snr: [Vec::new(), Vec::new()],
        }
    }

    /// The lines of direction `d` that stand at least [`LINE_SNR_MIN`] above the noise of its
    /// displacement and velocity: the lines that can determine coefficients (Hz, ascending).
    pub fn determining(&self, d: usize) -> Vec<f64> {
        self.lines[d].iter().zip(&self.line_snr[d]).filter(|(_, s)| **s >= LINE_SNR_MIN).map(|(f, _)| *f).collect()
    }

    /// The union of both directions' [`determining`](Self::determining) lines, merged as
    /// [`merged`](Self::merged) is.
    pub fn determining_merged(&self) -> Vec<f64> {
        let all: Vec<f64> = self.determining(0).into_iter().chain(self.determining(1)).collect();
        merge_lines(all, MAIN_LOBE_BINS as f64 * self.resolution_hz)
    }

    /// Lines of direction `d` too weak to determine coefficients, with their SNR.
    pub fn weak(&self, d: usize) -> Vec<(f64, f64)> {
        self.lines[d].iter().zip(&self.line_snr[d]).filter(|(_, s)| !(**s >= LINE_SNR_MIN)).map(|(f, s)| (*f, *s)).collect()
    }
}

/// Kept for callers of the former radix-2 transform: the tables [`fft_with`] no longer
/// needs (empty).
pub fn twiddles(_n: usize) -> (Vec<f64>, Vec<f64>) {
    (Vec::new(), Vec::new())
}

/// In-place complex forward DFT of `re + i im` through [`crate::fft`]; `re` and `im` of one
/// length, else nothing is done.
pub fn fft(re: &mut [f64], im: &mut [f64]) {
    if re.len() != im.len() {
        return;
    }
    let mut z: Vec<Complex<f64>> = re.iter().zip(im.iter()).map(|(&r, &i)| Complex::new(r, i)).collect();
    fft::forward(&mut z);
    for ((r, i), c) in re.iter_mut().zip(im.iter_mut()).zip(z) {
        (*r, *i) = (c.re, c.im);
    }
}

/// [`fft`]; the tables are not used (kept for the callers of the former radix-2 transform).
pub fn fft_with(re: &mut [f64], im: &mut [f64], _tc: &[f64], _ts: &[f64]) {
    fft(re, im);
}

/// Per-segment-length tables shared by the Welch passes of one window.
struct Tables {
    taper: Vec<f64>,
    /// Sum of the taper.
    taper_sum: f64,
}

thread_local! {
    /// The tables of the last segment length used on this thread: every window of a run has
    /// the same length, and building them costs ~3 trigonometric calls per sample.
    static TABLES: std::cell::RefCell<Option<std::rc::Rc<Tables>>> = const { std::cell::RefCell::new(None) };
}

impl Tables {
    fn cached(seg: usize) -> std::rc::Rc<Tables> {
        TABLES.with(|cell| {
            let mut slot = cell.borrow_mut();
            match slot.as_ref() {
                Some(t) if t.taper.len() == seg => t.clone(),
                _ => {
                    let t = std::rc::Rc::new(Tables::new(seg));
                    *slot = Some(t.clone());
                    t
                }
            }
        })
    }

    fn new(seg: usize) -> Self {
        let taper: Vec<f64> = (0..seg)
            .map(|k| {
                let x = 2.0 * std::f64::consts::PI * k as f64 / seg as f64;
                0.35875 - 0.48829 * x.cos() + 0.14128 * (2.0 * x).cos() - 0.01168 * (3.0 * x).cos()
            })
            .collect();
        let taper_sum = taper.iter().sum();
        Self { taper, taper_sum }
    }
}

/// Segment starts spread evenly from the first to the last possible one, as many as give
/// about 50 % overlap (at least two when the window is longer than a segment, so no sample is
/// left out).
fn segment_starts(n: usize, seg: usize) -> Vec<usize> {
    if n < seg || seg < 2 {
        return Vec::new();
    }
    let span = n - seg;
    if span == 0 {
        return vec![0];
    }
    let count = ((span as f64 / (seg / 2) as f64).round() as usize + 1).max(2);
    (0..count).map(|i| (i * span + (count - 1) / 2) / (count - 1)).collect()
}

/// Welch sums of two real signals computed together (`z = a + i b`), one segment at a time.
/// The segment's complex buffer is the thread's scratch ([`SEGMENT`]): only the sums are
/// state.
#[derive(Clone)]
struct WelchPair {
    pa: Vec<f64>,
    pb: Vec<f64>,
}

thread_local! {
    /// The complex buffer a segment is tapered into and transformed in: written in full before
    /// every transform, so one per thread serves every [`WelchPair`] (it was one per pair,
    /// 256 KiB allocated and zeroed twice per window at 16 384-point segments).
    static SEGMENT: std::cell::RefCell<Vec<Complex<f64>>> = const { std::cell::RefCell::new(Vec::new()) };
}

impl WelchPair {
    fn new(seg: usize) -> Self {
        let nb = seg / 2 + 1;
        Self { pa: vec![0.0; nb], pb: vec![0.0; nb] }
    }

    /// Adds the periodograms of one segment (`a`, `b` at least a segment long; the first
    /// segment's worth is used).
    fn add_segment(&mut self, a: &[f64], b: &[f64], tables: &Tables) {
        let seg = tables.taper.len();
        if seg < 2 || a.len() < seg || b.len() < seg || self.pa.len() != seg / 2 + 1 || self.pb.len() != seg / 2 + 1 {
            return;
        }
        SEGMENT.with(|cell| {
            let z = &mut *cell.borrow_mut();
            z.resize(seg, Complex::new(0.0, 0.0));
            let z = &mut z[..seg];
            taper_into(z, &a[..seg], &b[..seg], tables);
            fft::forward(z);
            accumulate(&mut self.pa, &mut self.pb, z);
        });
    }
}

/// `z = (a - m_a) w + i (b - m_b) w` with `m` the taper-weighted means (removing them leaves
/// the tapered segment with exactly zero DC: a plain mean would leave a small constant that
/// leaks into the lowest bins). All slices one segment long.
fn taper_into(z: &mut [Complex<f64>], a: &[f64], b: &[f64], tables: &Tables) {
    struct K<'a>(&'a mut [Complex<f64>], &'a [f64], &'a [f64], &'a Tables);
    impl Kernel for K<'_> {
        type Output = ();
        #[inline(always)]
        fn run<S: Simd>(self, _: S) {
            taper_into_kernel(self.0, self.1, self.2, self.3);
        }
    }
    simd::dispatch(Isa::current(), K(z, a, b, tables));
}

#[inline(always)]
fn taper_into_kernel(z: &mut [Complex<f64>], a: &[f64], b: &[f64], tables: &Tables) {
    let taper = &tables.taper[..];
    let wsum = tables.taper_sum;
    let (sa, sb) = weighted_sums(a, b, taper);
    let (ma, mb) = (sa / wsum, sb / wsum);
    for (((zk, av), bv), w) in z.iter_mut().zip(a).zip(b).zip(taper) {
        *zk = Complex::new((av - ma) * w, (bv - mb) * w);
    }
}

/// Adds `|X_k|^2` to `pa[k]` and `|Y_k|^2` to `pb[k]`, `k = 0..=N/2`, for the spectra `X`, `Y`
/// of the real and imaginary parts of the signal whose transform is `z`:
/// `X_k = (Z_k + conj Z_{N-k}) / 2`, `Y_k = (Z_k - conj Z_{N-k}) / (2i)`; `Z_N` is `Z_0`.
fn accumulate(pa: &mut [f64], pb: &mut [f64], z: &[Complex<f64>]) {
    struct K<'a>(&'a mut [f64], &'a mut [f64], &'a [Complex<f64>]);
    impl Kernel for K<'_> {
        type Output = ();
        #[inline(always)]
        fn run<S: Simd>(self, _: S) {
            accumulate_kernel(self.0, self.1, self.2);
        }
    }
    simd::dispatch(Isa::current(), K(pa, pb, z));
}

#[inline(always)]
fn accumulate_kernel(pa: &mut [f64], pb: &mut [f64], z: &[Complex<f64>]) {
    let seg = z.len();
    let nb = seg / 2 + 1;
    if seg < 2 || pa.len() < nb || pb.len() < nb {
        return;
    }
    #[inline(always)]
    fn add(pa: &mut f64, pb: &mut f64, zk: Complex<f64>, zn: Complex<f64>) {
        let (xr, xi) = (0.5 * (zk.re + zn.re), 0.5 * (zk.im - zn.im));
        let (yr, yi) = (0.5 * (zk.im + zn.im), -0.5 * (zk.re - zn.re));
        *pa += xr * xr + xi * xi;
        *pb += yr * yr + yi * yi;
    }
    add(&mut pa[0], &mut pb[0], z[0], z[0]);
    for (((a, b), zk), zn) in pa[1..nb].iter_mut().zip(&mut pb[1..nb]).zip(&z[1..nb]).zip(z[seg - nb + 1..].iter().rev()) {
        add(a, b, *zk, *zn);
    }
}

/// `(Σ a_k w_k, Σ b_k w_k)`, each exactly the test-only `weighted_sum` (the same partial sums
/// in the same order), in one pass over the taper.
#[inline(always)]
fn weighted_sums(a: &[f64], b: &[f64], w: &[f64]) -> (f64, f64) {
    let n = a.len().min(b.len()).min(w.len());
    let (a, b, w) = (&a[..n], &b[..n], &w[..n]);
    let mut acc_a = [0.0f64; 4];
    let mut acc_b = [0.0f64; 4];
    let mut ac = a.chunks_exact(4);
    let mut bc = b.chunks_exact(4);
    let mut wc = w.chunks_exact(4);
    for ((x, y), t) in (&mut ac).zip(&mut bc).zip(&mut wc) {
        for l in 0..4 {
            acc_a[l] += x[l] * t[l];
            acc_b[l] += y[l] * t[l];
        }
    }
    let tail_a: f64 = ac.remainder().iter().zip(wc.remainder()).map(|(x, t)| x * t).sum();
    let tail_b: f64 = bc.remainder().iter().zip(wc.remainder()).map(|(y, t)| y * t).sum();
    ((acc_a[0] + acc_a[2]) + (acc_a[1] + acc_a[3]) + tail_a, (acc_b[0] + acc_b[2]) + (acc_b[1] + acc_b[3]) + tail_b)
}

/// `Σ v_k w_k` with four independent partial sums (one running sum is a chain of dependent
/// additions: it cost as much as the FFT of the segment). The definition [`weighted_sums`]
/// must equal, bit for bit (tested).
#[cfg(test)]
fn weighted_sum(v: &[f64], w: &[f64]) -> f64 {
    let mut acc = [0.0f64; 4];
    let mut vc = v.chunks_exact(4);
    let mut wc = w.chunks_exact(4);
    for (a, b) in (&mut vc).zip(&mut wc) {
        for l in 0..4 {
            acc[l] += a[l] * b[l];
        }
    }
    let tail: f64 = vc.remainder().iter().zip(wc.remainder()).map(|(a, b)| a * b).sum();
    (acc[0] + acc[2]) + (acc[1] + acc[3]) + tail
}

/// The line search of one window of `n` samples, fed as its samples arrive.
///
/// The Welch segments sit at fixed offsets in the window, so each can be transformed as
/// soon as its samples are in; [`LineSearch::finish`] transforms the rest and analyses the
/// spectra. Segments are summed in the same order as [`analyse`] sums them, so the result is
/// [`analyse`]'s, bit for bit, however the samples were fed. What a node does while waiting
/// for the end of a window, instead of after it.
#[derive(Clone)]
pub struct LineSearch {
    n: usize,
    sample_rate_hz: f64,
    /// `None` when the window is too short for the analysis (or the rate not positive).
    tables: Option<std::rc::Rc<Tables>>,
    starts: Vec<usize>,
    /// Segments transformed so far.
    done: usize,
    displacement: WelchPair,
    velocity: WelchPair,
}

impl std::fmt::Debug for LineSearch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LineSearch").field("n", &self.n).field("segments", &self.starts.len()).field("done", &self.done).finish()
    }
}

impl LineSearch {
    /// The search of a window of `n` samples at `sample_rate_hz`.
    pub fn new(n: usize, sample_rate_hz: f64) -> Self {
        let usable = n >= MIN_SEGMENT && sample_rate_hz > 0.0;
        let seg = if usable { (1usize << (usize::BITS - 1 - n.leading_zeros())).min(MAX_SEGMENT) } else { 0 };
        let tables = usable.then(|| Tables::cached(seg));
        Self {
            n,
            sample_rate_hz,
            tables,
            starts: if usable { segment_starts(n, seg) } else { Vec::new() },
            done: 0,
            displacement: WelchPair::new(seg),
            velocity: WelchPair::new(seg),
        }
    }

    /// Window length and rate this search is for.
    pub fn window(&self) -> (usize, f64) {
        (self.n, self.sample_rate_hz)
    }

    /// Transform every segment that lies within the first samples of the window given
    /// (`x`, `y`, `vx`, `vy` from the window's first sample; the shortest length counts).
    pub fn advance(&mut self, x: &[f64], y: &[f64], vx: &[f64], vy: &[f64]) {
        let Some(tables) = self.tables.clone() else { return };
        let have = x.len().min(y.len()).min(vx.len()).min(vy.len()).min(self.n);
        let seg = tables.taper.len();
        while let Some(&s0) = self.starts.get(self.done) {
            if s0 + seg > have {
                break;
            }
            self.displacement.add_segment(&x[s0..], &y[s0..], &tables);
            self.velocity.add_segment(&vx[s0..], &vy[s0..], &tables);
            self.done += 1;
        }
    }

    /// The analysis of the whole window (`x`, `y`, `vx`, `vy`: all `n` samples of it, the
    /// same as were fed to [`LineSearch::advance`]).
    pub fn finish(mut self, x: &[f64], y: &[f64], vx: &[f64], vy: &[f64]) -> LineAnalysis {
        self.advance(x, y, vx, vy);
        let Some(tables) = &self.tables else { return LineAnalysis::empty() };
        if self.done < self.starts.len() {
            // Fewer samples than the window: nothing honest to report.
            return LineAnalysis::empty();
        }
        let df = self.sample_rate_hz / tables.taper.len() as f64;
        lines_of(&self.displacement.pa, &self.displacement.pb, &self.velocity.pa, &self.velocity.pb, df)
    }
}

/// Welch power spectra (bins `0..=N/2`) of two real signals computed together.
fn welch_pair(a: &[f64], b: &[f64], tables: &Tables) -> (Vec<f64>, Vec<f64>) {
    let seg = tables.taper.len();
    let n = a.len().min(b.len());
    let mut w = WelchPair::new(seg);
    for s0 in segment_starts(n, seg) {
        w.add_segment(&a[s0..], &b[s0..], tables);
    }
    (w.pa, w.pb)
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    *m
}

/// Line bins (fractional) of one power spectrum.
fn find_lines(pw: &[f64]) -> Vec<f64> {
    let nb = pw.len();
    if nb <= FIRST_BIN + MAIN_LOBE_BINS + 1 {
        return Vec::new();
    }
    let top = pw[FIRST_BIN..].iter().cloned().fold(0.0, f64::max);
    if !(top > 0.0) || !top.is_finite() {
        return Vec::new();
    }
    let mut out = Vec::new();
    for k in FIRST_BIN..nb - 1 {
        let v = pw[k];
        if v < DYNAMIC_RANGE * top {
            continue;
        }
        let lo = k.saturating_sub(MAIN_LOBE_BINS);
        let hi = (k + MAIN_LOBE_BINS).min(nb - 1);
        // Strict maximum on the left, non-strict on the right: one bin per plateau.
        if (lo..k).any(|i| pw[i] >= v) || ((k + 1)..=hi).any(|i| pw[i] > v) {
            continue;
        }
        let flo = k.saturating_sub(FLOOR_HALF_WIDTH).max(1);
        let fhi = (k + FLOOR_HALF_WIDTH).min(nb - 1);
        let neighbourhood: Vec<f64> = (flo..=fhi).filter(|&i| i + 2 * MAIN_LOBE_BINS < k || i > k + 2 * MAIN_LOBE_BINS).map(|i| pw[i]).collect();
        let floor = median(neighbourhood);
        if !(v > FLOOR_RATIO * floor) {
            continue;
        }
        let (l, c, r) = (pw[k - 1].max(f64::MIN_POSITIVE).ln(), v.ln(), pw[k + 1].max(f64::MIN_POSITIVE).ln());
        let den = l - 2.0 * c + r;
        let delta = if den < 0.0 { (0.5 * (l - r) / den).clamp(-0.5, 0.5) } else { 0.0 };
        out.push(k as f64 + delta);
    }
    out
}

/// Fraction of the power of `pw` within a main lobe of the given (fractional) bins.
fn fraction_in(pw: &[f64], bins: &[f64]) -> f64 {
    let total: f64 = pw[1..].iter().sum();
    if !(total > 0.0) {
        return f64::NAN;
    }
    let mask = near_lines(pw.len(), bins);
    let mut inside = 0.0;
    for k in 1..pw.len() {
        if mask[k] {
            inside += pw[k];
        }
    }
    inside / total
}

/// Whether bin `k` lies within the main lobe of line bin `b`.
fn near(k: usize, b: f64) -> bool {
    (k as f64 - b).abs() <= MAIN_LOBE_BINS as f64 + 0.5
}

/// The bins `1..` of `line_bin`'s main lobe that exist in `0..nb`, in order: every `k` with
/// [`near`]`(k, line_bin)` (the range is widened by one bin each side and each bin tested, so
/// the set is exactly the predicate's, without a pass over every bin).
fn lobe(nb: usize, line_bin: f64) -> impl Iterator<Item = usize> {
    let reach = MAIN_LOBE_BINS as f64 + 1.5;
    let lo = if line_bin - reach > 1.0 { (line_bin - reach).floor() as usize } else { 1 };
    let hi = if line_bin + reach < nb as f64 { (line_bin + reach).ceil() as usize } else { nb };
    (lo.max(1)..hi.min(nb).max(lo.max(1))).filter(move |&k| near(k, line_bin))
}

/// `mask[k]`: bin `k` is within the main lobe of any line of `bins`.
fn near_lines(nb: usize, bins: &[f64]) -> Vec<bool> {
    let mut mask = vec![false; nb];
    for &b in bins {
        for k in lobe(nb, b) {
            mask[k] = true;
        }
    }
    mask
}

/// Per line bin: its main-lobe power over the power outside every line of `bins` (bins 1..).
/// Infinite when nothing is outside, NaN without power. (Each line's lobe and the outside are
/// summed in bin order, as a pass over every bin with the same predicate would.)
fn line_snr(pw: &[f64], bins: &[f64]) -> Vec<f64> {
    let mask = near_lines(pw.len(), bins);
    let outside: f64 = (1..pw.len()).filter(|&k| !mask[k]).map(|k| pw[k]).sum();
    lobe_snr(pw, bins, outside)
}

/// Sums over bins `1..` of one spectrum: all of them, those within a line's main lobe (the
/// mask), those outside.
#[derive(Debug, Clone, Copy)]
struct BandSums {
    total: f64,
    inside: f64,
    outside: f64,
}

/// [`BandSums`] of four spectra of one length with their masks, in one pass: each of the
/// twelve sums adds its bins in order, as [`fraction_in`] and [`line_snr`] do one at a time.
fn band_sums(pw: [&[f64]; 4], mask: [&[bool]; 4]) -> [BandSums; 4] {
    let nb = pw.iter().map(|p| p.len()).chain(mask.iter().map(|m| m.len())).min().unwrap_or(0);
    let mut total = [0.0f64; 4];
    let mut inside = [0.0f64; 4];
    let mut outside = [0.0f64; 4];
    for k in 1..nb {
        for s in 0..4 {
            let v = pw[s][k];
            total[s] += v;
            if mask[s][k] {
                inside[s] += v;
            } else {
                outside[s] += v;
            }
        }
    }
    std::array::from_fn(|s| BandSums { total: total[s], inside: inside[s], outside: outside[s] })
}

/// [`fraction_in`] from the spectrum's [`BandSums`].
fn fraction_of(s: BandSums) -> f64 {
    if !(s.total > 0.0) {
        return f64::NAN;
    }
    s.inside / s.total
}

/// [`line_snr`] given the power outside every line (`outside`, from [`BandSums`]).
fn lobe_snr(pw: &[f64], bins: &[f64], outside: f64) -> Vec<f64> {
    bins.iter()
        .map(|&b| {
            let line: f64 = lobe(pw.len(), b).map(|k| pw[k]).sum();
            if outside > 0.0 {
                line / outside
            } else if line > 0.0 {
                f64::INFINITY
            } else {
                f64::NAN
            }
        })
        .collect()
}

/// Merge sorted frequencies closer than `tol`.
pub fn merge_lines(mut all: Vec<f64>, tol: f64) -> Vec<f64> {
    all.sort_by(|a, b| a.total_cmp(b));
    let mut out: Vec<f64> = Vec::new();
    for f in all {
        match out.last() {
            Some(&last) if f - last < tol => {}
            _ => out.push(f),
        }
    }
    out
}

/// Analyse one window: lines of `x`, `y`; noise fractions of `vx`, `vy` at those lines.
pub fn analyse(x: &[f64], y: &[f64], vx: &[f64], vy: &[f64], sample_rate_hz: f64) -> LineAnalysis {
    let n = x.len().min(y.len()).min(vx.len()).min(vy.len());
    LineSearch::new(n, sample_rate_hz).finish(&x[..n], &y[..n], &vx[..n], &vy[..n])
}

/// The lines and fractions from the Welch spectra of the displacements and velocities.
fn lines_of(px: &[f64], py: &[f64], pvx: &[f64], pvy: &[f64], df: f64) -> LineAnalysis {
    let bx = find_lines(px);
    let by = find_lines(py);
    let (line_fraction, velocity_noise_fraction, line_snr) = if [py.len(), pvx.len(), pvy.len()].iter().all(|&l| l == px.len()) {
        // The sums of the four spectra side by side: independent chains of additions, each
        // still over its bins in order (the same bits as one function per sum, tested).
        let (mx, my) = (near_lines(px.len(), &bx), near_lines(px.len(), &by));
        let [sx, sy, svx, svy] = band_sums([px, py, pvx, pvy], [&mx, &my, &mx, &my]);
        let snr = |pd: &[f64], pv: &[f64], b: &[f64], od: f64, ov: f64| -> Vec<f64> {
            lobe_snr(pd, b, od).into_iter().zip(lobe_snr(pv, b, ov)).map(|(a, v)| if a.is_nan() || v.is_nan() { f64::NAN } else { a.min(v) }).collect()
        };
        (
            [fraction_of(sx), fraction_of(sy)],
            [1.0 - fraction_of(svx), 1.0 - fraction_of(svy)],
            [snr(px, pvx, &bx, sx.outside, svx.outside), snr(py, pvy, &by, sy.outside, svy.outside)],
        )
    } else {
        let snr = |pd: &[f64], pv: &[f64], b: &[f64]| -> Vec<f64> {
            line_snr(pd, b).into_iter().zip(line_snr(pv, b)).map(|(a, v)| if a.is_nan() || v.is_nan() { f64::NAN } else { a.min(v) }).collect()
        };
        ([fraction_in(px, &bx), fraction_in(py, &by)], [1.0 - fraction_in(pvx, &bx), 1.0 - fraction_in(pvy, &by)], [snr(px, pvx, &bx), snr(py, pvy, &by)])
    };
    let lx: Vec<f64> = bx.iter().map(|b| b * df).collect();
    let ly: Vec<f64> = by.iter().map(|b| b * df).collect();
    let merged = merge_lines(lx.iter().chain(ly.iter()).cloned().collect(), MAIN_LOBE_BINS as f64 * df);
    LineAnalysis { lines: [lx, ly], merged, line_fraction, velocity_noise_fraction, resolution_hz: df, line_snr }
}

/// Fraction of the variance of `a` (direction x) and `b` (direction y) outside the lines
/// `lines` found for their direction, by the same Welch analysis as [`analyse`]: the noise
/// fraction of two further regressors (the accelerations of the added-mass model). NaN where
/// it cannot be estimated (window too short, no power, or the analysis found nothing).
pub fn noise_fraction(a: &[f64], b: &[f64], lines: &LineAnalysis, sample_rate_hz: f64) -> [f64; 2] {
    let n = a.len().min(b.len());
    if n < MIN_SEGMENT || !(sample_rate_hz > 0.0) || !(lines.resolution_hz > 0.0) {
        return [f64::NAN; 2];
    }
    let seg = (1usize << (usize::BITS - 1 - n.leading_zeros())).min(MAX_SEGMENT);
    let tables = Tables::cached(seg);
    let (pa, pb) = welch_pair(&a[..n], &b[..n], &tables);
    let bins = |d: usize| -> Vec<f64> { lines.lines[d].iter().map(|f| f / lines.resolution_hz).collect() };
    [1.0 - fraction_in(&pa, &bins(0)), 1.0 - fraction_in(&pb, &bins(1))]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fused taper-weighted sums are the single ones, bit for bit, at every tail length.
    #[test]
    fn weighted_sums_are_weighted_sum() {
        for n in [0usize, 1, 3, 4, 7, 64, 16_387] {
            let a: Vec<f64> = (0..n).map(|k| 1e-5 * (k as f64 * 0.37).sin() + 2e-5).collect();
            let b: Vec<f64> = (0..n).map(|k| 3.0 * (k as f64 * 1.1).cos() - 1e3).collect();
            let w: Vec<f64> = (0..n).map(|k| 0.5 - 0.5 * (k as f64 * 0.01).cos()).collect();
            let (sa, sb) = weighted_sums(&a, &b, &w);
            assert_eq!((sa.to_bits(), sb.to_bits()), (weighted_sum(&a, &w).to_bits(), weighted_sum(&b, &w).to_bits()), "n {n}");
        }
    }

    #[test]
    fn fft_matches_dft() {
        let n = 16;
        let mut re: Vec<f64> = (0..n).map(|k| (k as f64 * 0.7).sin() + 0.1 * k as f64).collect();
        let mut im: Vec<f64> = (0..n).map(|k| (k as f64 * 1.3).cos()).collect();
        let (r0, i0) = (re.clone(), im.clone());
        fft(&mut re, &mut im);
        for f in 0..n {
            let (mut sr, mut si) = (0.0, 0.0);
            for t in 0..n {
                let a = -2.0 * std::f64::consts::PI * (f * t) as f64 / n as f64;
                sr += r0[t] * a.cos() - i0[t] * a.sin();
                si += r0[t] * a.sin() + i0[t] * a.cos();
            }
            assert!((sr - re[f]).abs() < 1e-12 && (si - im[f]).abs() < 1e-12);
        }
    }

    /// The line-lobe sums from each lobe's own bins are the passes over every bin with the same
    /// predicate, bit for bit (lines at the edges, fractional, outside the spectrum, NaN).
    #[test]
    fn lobe_sums_equal_the_passes_over_every_bin() {
        let nb = 8_193;
        let pw: Vec<f64> = (0..nb).map(|k| 1e-12 * (1.0 + ((k * 7919) % 1013) as f64) * (1.0 + (k as f64 * 0.37).sin().abs())).collect();
        let cases: [&[f64]; 6] =
            [&[], &[94.2, 151.7], &[1.0, 2.5, nb as f64 - 1.0], &[0.0, nb as f64 + 0.4], &[f64::NAN, 40.0, f64::INFINITY], &[30.49, 30.51, 4_000.0]];
        for bins in cases {
            let near_any = |k: usize| bins.iter().any(|&b| near(k, b));
            let outside: f64 = (1..nb).filter(|&k| !near_any(k)).map(|k| pw[k]).sum();
            let snr: Vec<f64> = bins
                .iter()
                .map(|&b| {
                    let line: f64 = (1..nb).filter(|&k| near(k, b)).map(|k| pw[k]).sum();
                    if outside > 0.0 {
                        line / outside
                    } else if line > 0.0 {
                        f64::INFINITY
                    } else {
                        f64::NAN
                    }
                })
                .collect();
            assert_eq!(format!("{:?}", line_snr(&pw, bins)), format!("{snr:?}"), "lines {bins:?}");
            let total: f64 = pw[1..].iter().sum();
            let mut inside = 0.0;
            for k in 1..nb {
                if near_any(k) {
                    inside += pw[k];
                }
            }
            assert_eq!(fraction_in(&pw, bins).to_bits(), (inside / total).to_bits(), "lines {bins:?}");
            // The four-at-once sums are the one-at-a-time ones.
            let pw2: Vec<f64> = pw.iter().rev().copied().collect();
            let (m1, m2) = (near_lines(nb, bins), near_lines(nb, &[100.0]));
            let sums = band_sums([&pw, &pw2, &pw2, &pw], [&m1, &m1, &m2, &m2]);
            for (s, (p, b)) in sums.iter().zip([(&pw, bins), (&pw2, bins), (&pw2, &[100.0][..]), (&pw, &[100.0][..])]) {
                assert_eq!(fraction_of(*s).to_bits(), fraction_in(p, b).to_bits(), "lines {b:?}");
                assert_eq!(format!("{:?}", lobe_snr(p, b, s.outside)), format!("{:?}", line_snr(p, b)), "lines {b:?}");
            }
        }
    }

    #[test]
    fn line_search_fed_in_pieces_is_bitwise_analyse() {
        let fs = 5000.0;
        let n = 150_001;
        let sig = |f: f64, ph: f64| -> Vec<f64> {
            (0..n).map(|t| (2.0 * std::f64::consts::PI * f * t as f64 / fs + ph).sin() + 1e-4 * ((t * 7919) % 101) as f64).collect()
        };
        let (x, y, vx, vy) = (sig(23.0, 0.1), sig(37.0, 0.7), sig(23.0, 1.1), sig(37.0, 2.0));
        let whole = format!("{:?}", analyse(&x, &y, &vx, &vy, fs));
        for step in [1_000, 33_333, n] {
            let mut search = LineSearch::new(n, fs);
            let mut have = 0;
            while have < n {
                have = (have + step).min(n);
                search.advance(&x[..have], &y[..have], &vx[..have], &vy[..have]);
            }
            assert_eq!(format!("{:?}", search.finish(&x, &y, &vx, &vy)), whole, "fed {step} at a time");
        }
        // Finishing with fewer samples than the window reports nothing.
        let short = LineSearch::new(n, fs).finish(&x[..n - 1], &y[..n - 1], &vx[..n - 1], &vy[..n - 1]);
        assert!(short.merged.is_empty() && short.line_fraction[0].is_nan());
    }

    #[test]
    fn finds_two_lines() {
        let fs = 5000.0;
        let n = 20_000;
        let x: Vec<f64> = (0..n)
            .map(|t| {
                let s = t as f64 / fs;
                (2.0 * std::f64::consts::PI * 20.0 * s).sin() + 0.5 * (2.0 * std::f64::consts::PI * 47.3 * s).cos()
            })
            .collect();
        let y: Vec<f64> = (0..n).map(|t| (2.0 * std::f64::consts::PI * 31.0 * t as f64 / fs).sin()).collect();
        let a = analyse(&x, &y, &x, &y, fs);
        assert_eq!(a.lines[0].len(), 2, "{:?}", a.lines);
        assert!((a.lines[0][0] - 20.0).abs() < 0.05 && (a.lines[0][1] - 47.3).abs() < 0.05, "{:?}", a.lines);
        assert_eq!(a.lines[1].len(), 1);
        assert_eq!(a.merged.len(), 3);
        assert!(a.line_fraction[0] > 0.999);
    }
}
