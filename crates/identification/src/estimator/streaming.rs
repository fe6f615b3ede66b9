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
//! [`WindowFactors`] is that least-squares stage on its own (rows in, window factors out).
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

/// The least-squares stage of streaming on its own: rows in, the triangular factor of every
/// completed window out, reusing the factors of `gcd(window, hop)`-row blocks.
#[derive(Debug, Clone)]
pub struct WindowFactors {
    window: usize,
    hop: usize,
    block: usize,
    cols: usize,
    /// Rows received.
    count: usize,
    /// Rows of the current, incomplete block (column-wise).
    partial: Vec<Vec<f64>>,
    queue: Queue,
    /// End (exclusive) of the next window to emit.
    next_end: usize,
}

impl WindowFactors {
    /// `cols` columns per row (regressors then right-hand sides).
    pub fn new(window: usize, hop: usize, cols: usize) -> Result<Self, IdentificationError> {
        if window == 0 {
            return Err(IdentificationError::invalid("window", "must be at least 1 sample"));
        }
        if hop == 0 {
            return Err(IdentificationError::invalid("hop", "must be at least 1 sample (0 would never advance)"));
        }
        if cols == 0 {
            return Err(IdentificationError::invalid("cols", "need at least one column"));
        }
        let block = gcd(window, hop);
        Ok(Self {
            window,
            hop,
            block,
            cols,
            count: 0,
            partial: (0..cols).map(|_| Vec::with_capacity(block)).collect(),
            queue: Queue::new(cols),
            next_end: window,
        })
    }

    /// Block length, `gcd(window, hop)`.
    pub fn block_len(&self) -> usize {
        self.block
    }

    /// Rows received so far.
    pub fn rows(&self) -> usize {
        self.count
    }

    fn complete_block(&mut self, summary: BlockSummary, out: &mut Vec<(usize, BlockSummary)>) {
        self.count += self.block;
        self.queue.push(summary);
        if self.count == self.next_end {
            out.push((self.next_end - self.window, self.queue.combined()));
            self.next_end = self.next_end.saturating_add(self.hop);
        }
        // Drop blocks that end before the next window starts.
        let first_needed = (self.next_end - self.window) / self.block;
        let pushed = self.count / self.block;
        while self.queue.len > 0 && pushed - self.queue.len < first_needed {
            self.queue.pop();
        }
    }

    /// Push rows given as columns of one length (the shortest is used). Returns
    /// `(window start, window factor)` for every window completed; nothing (and no rows taken)
    /// if the number of columns is not the one given to [`WindowFactors::new`].
    pub fn push_rows(&mut self, cols: &[&[f64]]) -> Vec<(usize, BlockSummary)> {
        let mut out = Vec::new();
        if cols.len() != self.cols {
            return out;
        }
        let n = cols.iter().map(|c| c.len()).min().unwrap_or(0);
        let g = self.block;
        let mut i = 0;
        while i < n {
            let have = self.partial[0].len();
            if have == 0 && n - i >= g {
                // A whole block straight from the caller's slices, no copy.
                let view: Vec<&[f64]> = cols.iter().map(|c| &c[i..i + g]).collect();
                self.complete_block(BlockSummary::from_columns(&view), &mut out);
                i += g;
                continue;
            }
            let take = (g - have).min(n - i);
            for (dst, src) in self.partial.iter_mut().zip(cols) {
                dst.extend_from_slice(&src[i..i + take]);
            }
            i += take;
            if self.partial[0].len() == g {
                let view: Vec<&[f64]> = self.partial.iter().map(|c| c.as_slice()).collect();
                let summary = BlockSummary::from_columns(&view);
                for c in &mut self.partial {
                    c.clear();
                }
                self.complete_block(summary, &mut out);
            }
        }
        out
    }

    /// Push one row (ignored if its length is not the column count).
    pub fn push_row(&mut self, row: &[f64]) -> Option<(usize, BlockSummary)> {
        if row.len() != self.cols {
            return None;
        }
        let view: Vec<&[f64]> = row.iter().map(std::slice::from_ref).collect();
        self.push_rows(&view).pop()
    }
}

/// Streaming form of [`super::estimate_windows`].
#[derive(Debug, Clone)]
pub struct StreamingEstimator {
    config: EstimatorConfig,
    /// Design columns (regressors, then fx, fy), each a mirrored ring of `2 * window`.
    ring: Vec<Vec<f64>>,
    names: Vec<&'static str>,
    count: usize,
    factors: WindowFactors,
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
        let mut ring = Vec::with_capacity(q);
        for _ in 0..q {
            let mut col: Vec<f64> = Vec::new();
            let len = w.checked_mul(2).ok_or_else(|| IdentificationError::invalid("window", "too large"))?;
            col.try_reserve_exact(len).map_err(|_| {
                IdentificationError::invalid("window", format!("cannot allocate a ring buffer for a window of {w} samples"))
            })?;
            col.resize(len, 0.0);
            ring.push(col);
        }
        let factors = WindowFactors::new(w, config.hop, q)?;
        Ok(Self { config, ring, names, count: 0, factors })
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
        self.factors.block_len()
    }

    /// Push one sample; returns a window estimate when one completes.
    pub fn push(&mut self, sample: &Sample) -> Option<WindowEstimate> {
        let w = self.config.window;
        let all: [f64; 8] = [sample.x_m, sample.y_m, sample.vx_m_s, sample.vy_m_s, sample.ax_m_s2, sample.ay_m_s2, sample.fx_n, sample.fy_n];
        let row: Vec<f64> = match self.config.model {
            ModelOrder::Kc => vec![all[0], all[1], all[2], all[3], all[6], all[7]],
            ModelOrder::Kcm => all.to_vec(),
        };
        let pos = self.count % w;
        for (col, &v) in self.ring.iter_mut().zip(&row) {
            col[pos] = v;
            col[pos + w] = v;
        }
        self.count += 1;
        let (start, summary) = self.factors.push_row(&row)?;
        let s = start % w;
        let cols: Vec<(&'static str, &[f64])> =
            self.names.iter().zip(&self.ring).map(|(name, c)| (*name, &c[s..s + w])).collect();
        Some(analyse_window(&cols, start, Some(&summary), None, None, &self.config))
    }

    /// Push a block of samples; returns the windows that complete.
    pub fn push_all(&mut self, samples: &[Sample]) -> Vec<WindowEstimate> {
        samples.iter().filter_map(|s| self.push(s)).collect()
    }
}
