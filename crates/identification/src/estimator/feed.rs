//! One window's analysis done as its samples arrive, so that little is left after its last.
//!
//! A [`WindowFeed`] is given the window's samples in order, in pieces of any size, and keeps
//! what the estimate needs from them: the line search's Welch segments
//! ([`LineSearch`]), the window's QR factor built [`CHUNK_ROWS`](super::window::CHUNK_ROWS)
//! rows at a time ([`SummaryBuilder`]), the every-`q`-th samples the standard errors use
//! (`q` = [`se_decimation`](super::se_decimation)) and the first non-finite sample of each
//! column. Every piece sits at a fixed offset from the window's first sample and is combined
//! in sample order, so [`super::estimate_window_fed`] gives [`super::estimate_window`]'s
//! result bit for bit, however the samples were cut into frames: only the time after the last
//! sample is shorter (the last partial chunk and segment, the small FFTs of the decimated
//! errors, the solve).

use super::spectrum::LineSearch;
use super::window::{BlockSummary, SummaryBuilder};
use super::{se_decimation, EstimatorConfig, ModelOrder, Signals};

/// The analysis of one window, fed as its samples arrive.
#[derive(Debug, Clone)]
pub struct WindowFeed {
    n: usize,
    sample_rate_hz: f64,
    model: ModelOrder,
    q: usize,
    /// Samples taken so far.
    fed: usize,
    search: LineSearch,
    summary: SummaryBuilder,
    /// Samples `0, q, 2q, ...` of every design column (regressors, then fx, fy).
    decimated: Vec<Vec<f64>>,
    /// First non-finite sample of every design column.
    first_bad: Vec<Option<usize>>,
}

/// What a complete feed hands the estimate.
pub(crate) struct FedWindow {
    pub search: LineSearch,
    pub summary: BlockSummary,
    pub decimated: Vec<Vec<f64>>,
    pub q: usize,
    pub first_bad: Vec<Option<usize>>,
}

impl WindowFeed {
    /// The feed of a window of `config.window` samples with `config`'s rate, model and
    /// standard-error decimation.
    pub fn new(config: &EstimatorConfig) -> Self {
        let n = config.window;
        let cols = config.model.regressors() + 2;
        let q = se_decimation(n, config.sample_rate_hz, config.signal_band_hz);
        Self {
            n,
            sample_rate_hz: config.sample_rate_hz,
            model: config.model,
            q,
            fed: 0,
            search: LineSearch::new(n, config.sample_rate_hz),
            summary: SummaryBuilder::new(cols),
            decimated: (0..cols).map(|_| Vec::with_capacity(n.div_ceil(q))).collect(),
            first_bad: vec![None; cols],
        }
    }

    /// True when this feed is for windows of `config` (length, rate, model, decimation).
    pub fn fits(&self, config: &EstimatorConfig) -> bool {
        self.n == config.window
            && self.sample_rate_hz == config.sample_rate_hz
            && self.model == config.model
            && self.q == se_decimation(config.window, config.sample_rate_hz, config.signal_band_hz)
    }

    /// Samples taken so far.
    pub fn samples(&self) -> usize {
        self.fed
    }

    /// Take the samples of `signals` not taken yet. `signals` starts at the window's first
    /// sample (as [`LineSearch::advance`]); samples past the window's end are ignored, and so
    /// is a call missing a column the model needs.
    pub fn advance(&mut self, signals: &Signals) {
        if signals.check(self.model).is_err() {
            return;
        }
        let have = signals.len().min(self.n);
        if have <= self.fed {
            return;
        }
        let range = self.fed..have;
        let design = signals.design(self.model, range.clone());
        let cols: Vec<&[f64]> = design.iter().map(|(_, c)| *c).collect();
        self.summary.push(&cols);
        let first_kept = range.start.div_ceil(self.q) * self.q - range.start;
        for ((c, dec), bad) in cols.iter().zip(&mut self.decimated).zip(&mut self.first_bad) {
            dec.extend(c.iter().skip(first_kept).step_by(self.q));
            if bad.is_none() {
                *bad = first_non_finite(c).map(|i| range.start + i);
            }
        }
        self.search.advance(&signals.x_m[..have], &signals.y_m[..have], &signals.vx_m_s[..have], &signals.vy_m_s[..have]);
        self.fed = have;
    }

    /// Everything the estimate takes from a feed of all `n` samples (`None` otherwise).
    pub(crate) fn into_window(self, n: usize) -> Option<FedWindow> {
        (self.fed == n && self.n == n).then(|| FedWindow {
            search: self.search,
            summary: self.summary.finish(),
            decimated: self.decimated,
            q: self.q,
            first_bad: self.first_bad,
        })
    }
}

/// Index of the first sample of `c` that is NaN or infinite: `c.iter().position(|v|
/// !v.is_finite())`, with whole blocks of finite samples passed over by a vectorised test.
fn first_non_finite(c: &[f64]) -> Option<usize> {
    const BLOCK: usize = 256;
    for (k, block) in c.chunks(BLOCK).enumerate() {
        if !all_finite(block) {
            return block.iter().position(|v| !v.is_finite()).map(|i| k * BLOCK + i);
        }
    }
    None
}

/// True when every value is finite: `v * 0` is (signed) zero for a finite value and NaN
/// otherwise, and a sum of zeros stays zero while a NaN stays NaN.
fn all_finite(c: &[f64]) -> bool {
    let mut acc = [0.0f64; 8];
    let mut chunks = c.chunks_exact(8);
    for ch in &mut chunks {
        for l in 0..8 {
            acc[l] += ch[l] * 0.0;
        }
    }
    let tail = chunks.remainder().iter().fold(0.0, |a, v| a + v * 0.0);
    acc.iter().sum::<f64>() + tail == 0.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_non_finite_is_the_first_nan_or_infinity() {
        let mut c: Vec<f64> = (0..1_000).map(|k| (k as f64 * 0.3).sin() * 1e300).collect();
        assert_eq!(first_non_finite(&c), None);
        assert_eq!(first_non_finite(&[]), None);
        for (at, bad) in [(999, f64::NAN), (0, f64::INFINITY), (517, f64::NEG_INFINITY), (255, f64::NAN), (256, f64::MAX)] {
            let old = c[at];
            c[at] = bad;
            let want = c.iter().position(|v| !v.is_finite());
            assert_eq!(first_non_finite(&c), want, "{bad} at {at}");
            c[at] = old;
        }
        // Two bad samples: the first counts.
        c[700] = f64::NAN;
        c[300] = f64::INFINITY;
        assert_eq!(first_non_finite(&c), Some(300));
    }
}
