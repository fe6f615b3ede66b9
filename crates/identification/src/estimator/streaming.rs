//! Streaming estimation: push samples, windows come out every `hop` samples.
//!
//! Overlapping windows share most of their rows, so the least-squares work is done once per
//! row, not once per window. The stream is cut into blocks of `g = gcd(window, hop)` samples;
//! every window is a whole number of consecutive blocks. Each block is reduced once, on
//! arrival, to its [`BlockSummary`] (count, means, triangular factor of the centred rows; the
//! force columns ride along as extra columns). A window's factor is the TSQR combination of its
//! blocks' factors (Demmel, Grigori, Hoemmen & Langou, SIAM J. Sci. Comput. 34 (2012);
//! Golub & Van Loan 4th ed. §5.2, block QR), kept in a sliding-window aggregation queue
//! ("two stacks": the back stack keeps one running combination, the front stack the
//! combinations of each suffix), so each block is combined O(1) times on average however many
//! windows it belongs to. The normal equations are never formed.
//!
//! The rest of a window's analysis (line search, HAC standard errors, refusals, flags) needs
//! the samples themselves, so the last `window` samples are kept in a mirrored ring buffer
//! (each sample stored twice, `window` apart, so every window is one contiguous slice) and the
//! window goes through exactly the same code as [`super::estimate_windows`]. Results agree with
//! the batch estimator to rounding.

use super::window::BlockSummary;
use super::{analyse_window, EstimatorConfig, ModelOrder, WindowEstimate};
use crate::IdentificationError;

/// One sample of every channel. Accelerations are ignored by the `Kc` model.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sample {
    pub x_m: f64,
    pub y_m: f64,
    pub vx_m_s: f64,
    pub vy_m_s: f64,
    pub ax_m_s2: f64,
    pub ay_m_s2: f64,
    pub fx_n: f64,
    pub fy_n: f64,
}

/// Sliding-window aggregation of block summaries (front stack with suffix combinations, back
/// stack with one running combination).
#[derive(Debug, Clone)]
struct Queue {
    cols: usize,
    front: Vec<BlockSummary>, // combination of this element and every newer one in `front`
    back: Vec<BlockSummary>,
    back_all: BlockSummary,
    len: usize,
}

impl Queue {
    fn new(cols: usize) -> Self {
        Self { cols, front: Vec::new(), back: Vec::new(), back_all: BlockSummary::empty(cols), len: 0 }
    }

    fn push(&mut self, s: BlockSummary) {
        self.back_all = self.back_all.merge(&s);
        self.back.push(s);
        self.len += 1;
    }

    fn pop(&mut self) {
        if self.front.is_empty() {
            // Move the back stack over, newest first, building suffix combinations.
            let mut acc = BlockSummary::empty(self.cols);
            while let Some(s) = self.back.pop() {
                acc = s.merge(&acc);
                self.front.push(acc.clone());
            }
            self.back_all = BlockSummary::empty(self.cols);
        }
        if self.front.pop().is_some() {
            self.len -= 1;
        }
    }

    fn combined(&self) -> BlockSummary {
        match self.front.last() {
            Some(f) => f.merge(&self.back_all),
            None => self.back_all.clone(),
        }
    }
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 { a } else { gcd(b, a % b) }
}

/// Streaming form of [`super::estimate_windows`].
#[derive(Debug, Clone)]
pub struct StreamingEstimator {
    config: EstimatorConfig,
    /// Design columns (regressors, then fx, fy), each a mirrored ring of `2 * window`.
    ring: Vec<Vec<f64>>,
    names: Vec<&'static str>,
    block: usize,
    count: usize,
    queue: Queue,
    /// End (exclusive) of the next window to emit.
    next_end: usize,
}

impl StreamingEstimator {
    /// Check the configuration and set up empty buffers (`(p + 2) × 2 × window` doubles).
    pub fn new(config: EstimatorConfig) -> Result<Self, IdentificationError> {
        config.validate()?;
        let names: Vec<&'static str> = match config.model {
            ModelOrder::Kc => vec!["x_m", "y_m", "vx_m_s", "vy_m_s", "fx_n", "fy_n"],
            ModelOrder::Kcm => vec!["x_m", "y_m", "vx_m_s", "vy_m_s", "ax_m_s2", "ay_m_s2", "fx_n", "fy_n"],
        };
        let q = names.len();
        let w = config.window;
        let ring = vec![vec![0.0; 2 * w]; q];
        let block = gcd(w, config.hop);
        Ok(Self { next_end: w, config, ring, names, block, count: 0, queue: Queue::new(q) })
    }

    /// The configuration.
    pub fn config(&self) -> &EstimatorConfig {
        &self.config
    }

    /// Samples pushed so far.
    pub fn samples(&self) -> usize {
        self.count
    }

    /// Block length used for factor reuse, `gcd(window, hop)`.
    pub fn block_len(&self) -> usize {
        self.block
    }

    /// Push one sample; returns a window estimate when one completes.
    pub fn push(&mut self, sample: &Sample) -> Option<WindowEstimate> {
        let w = self.config.window;
        let values: [f64; 8] = [sample.x_m, sample.y_m, sample.vx_m_s, sample.vy_m_s, sample.ax_m_s2, sample.ay_m_s2, sample.fx_n, sample.fy_n];
        let pick: &[usize] = match self.config.model {
            ModelOrder::Kc => &[0, 1, 2, 3, 6, 7],
            ModelOrder::Kcm => &[0, 1, 2, 3, 4, 5, 6, 7],
        };
        let pos = self.count % w;
        for (col, &src) in self.ring.iter_mut().zip(pick) {
            col[pos] = values[src];
            col[pos + w] = values[src];
        }
        self.count += 1;
        let g = self.block;
        if self.count % g == 0 {
            // Block [count - g, count): aligned to g, and g divides w, so it does not wrap.
            let s = (self.count - g) % w;
            let cols: Vec<&[f64]> = self.ring.iter().map(|c| &c[s..s + g]).collect();
            self.queue.push(BlockSummary::from_columns(&cols));
        }
        // Drop blocks that end before the next window starts.
        let next_start_block = (self.next_end - w) / g;
        let pushed = self.count / g;
        while self.queue.len > 0 && pushed - self.queue.len < next_start_block {
            self.queue.pop();
        }
        if self.count < self.next_end {
            return None;
        }
        let start = self.next_end - w;
        self.next_end += self.config.hop;
        let summary = self.queue.combined();
        let s = start % w;
        let cols: Vec<(&'static str, &[f64])> =
            self.names.iter().zip(&self.ring).map(|(name, c)| (*name, &c[s..s + w])).collect();
        Some(analyse_window(&cols, start, Some(&summary), &self.config))
    }

    /// Push a block of samples; returns the windows that complete.
    pub fn push_all(&mut self, samples: &[Sample]) -> Vec<WindowEstimate> {
        samples.iter().filter_map(|s| self.push(s)).collect()
    }
}
