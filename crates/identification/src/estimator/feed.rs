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
use crate::simd::first_non_finite;

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
