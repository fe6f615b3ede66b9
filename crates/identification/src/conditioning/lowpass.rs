//! Step 1 of Zhou et al. (2004), section 3.1: "feed the raw data to a low pass filter to
//! eliminate high frequency noise". Here: a **zero-phase** Butterworth low-pass, run forward
//! then backward (`filtfilt`), so that no channel is shifted in time by the filter.
//!
//! ## Design
//! Order-`N` Butterworth (maximally flat, no passband ripple) by the bilinear transform with
//! the cutoff pre-warped, `K = tan(pi f_c / f_s)`, as a cascade of second-order sections
//! (one first-order section when `N` is odd), each in transposed direct form II. The
//! section of the analog pole pair with damping `zeta_k = sin((2k + 1) pi / (2N))` is
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
//! and backward-forward runs agree; we use the simpler and widely used approximation of
//! MATLAB's and SciPy's `filtfilt` (which cite him): the signal is extended at each end by
//! its **odd reflection** about the end sample (value and slope continuous), and every
//! section starts in its **DC steady state** for the first extended sample, forward and then
//! backward. The extension is as long as the filter's settling time
//! ([`Butterworth::settling_samples`], where the slowest pole has decayed to 1e-7), and the
//! conditioned record still excludes that many samples at each end from
//! [`super::Conditioned::valid`], because the reflection is only a guess of the signal
//! beyond the record.
//!
//! ## Cost
//! Two passes of `ceil(N/2)` sections over the extended column, five multiply-adds per
//! section and sample; one scratch buffer (reusable through [`Butterworth::filtfilt_into`]).

use oilfilm_physics::daq::ChannelId;

use super::first_non_finite;
use crate::IdentificationError;

/// Highest order accepted (the default is 4; beyond 12 nothing useful is gained and the
/// settling time grows).
pub const MAX_ORDER: usize = 12;

/// Settling tolerance: the slowest pole's envelope has decayed to this at the trim length.
const SETTLE_TOL: f64 = 1.0e-7;

/// One second-order section, transposed direct form II, `a0 = 1`.
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

    /// State `[z1, z2]` of the section in steady state for a constant input `x`.
    fn steady_state(&self, x: f64) -> [f64; 2] {
        let y = self.dc_gain() * x;
        let z2 = self.b[2] * x - self.a[1] * y;
        let z1 = y - self.b[0] * x;
        [z1, z2]
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

    /// Runs the cascade over `buf` in place, starting each section in its steady state for
    /// the constant input `buf[0]`.
    fn run_forward(&self, buf: &mut [f64]) {
        for s in &self.sections {
            // Section by section: each pass is one short recursion over the buffer. A section
            // started in steady state for its first input outputs exactly that level times
            // its DC gain first, so the next section's first input is its own steady level.
            let Some(&x0) = buf.first() else { return };
            let [b0, b1, b2] = s.b;
            let [a1, a2] = s.a;
            let [mut z1, mut z2] = s.steady_state(x0);
            for v in buf.iter_mut() {
                let x = *v;
                let y = b0 * x + z1;
                z1 = b1 * x - a1 * y + z2;
                z2 = b2 * x - a2 * y;
                *v = y;
            }
        }
    }

    /// Builds the odd-reflection extension of `input` in `scratch` and runs the cascade
    /// forward and backward over it; returns the padding length. The original sample `i`
    /// ends up at `scratch[scratch.len() - 1 - pad - i]` (the buffer is left reversed).
    fn extend_and_run(
        &self,
        input: &[f64],
        scratch: &mut Vec<f64>,
    ) -> Result<usize, IdentificationError> {
        let n = input.len();
        if n < 2 {
            return Err(IdentificationError::BadInput {
                what: "low-pass input".into(),
                reason: format!("{n} samples, need at least 2"),
            });
        }
        let pad = self.settling.min(n - 1);
        scratch.clear();
        scratch.reserve(n + 2 * pad);
        let (first, last) = (input[0], input[n - 1]);
        // Odd reflection about each end sample: ext[pad - i] = 2 x[0] - x[i], i = pad..1,
        // and ext[pad + n - 1 + i] = 2 x[n - 1] - x[n - 1 - i], i = 1..pad.
        scratch.extend(input[1..=pad].iter().rev().map(|&x| 2.0 * first - x));
        scratch.extend_from_slice(input);
        scratch.extend(
            input[n - 1 - pad..n - 1]
                .iter()
                .rev()
                .map(|&x| 2.0 * last - x),
        );
        // Forward from the steady state for the first extended sample, then backward from
        // the steady state for the last forward output (as SciPy's `filtfilt`).
        self.run_forward(scratch);
        scratch.reverse();
        self.run_forward(scratch);
        Ok(pad)
    }

    /// Zero-phase filtering of `input` into `out` (same length, at least 2 samples), using
    /// `scratch` (resized as needed) for the extended signal.
    pub fn filtfilt_into(
        &self,
        input: &[f64],
        out: &mut [f64],
        scratch: &mut Vec<f64>,
    ) -> Result<(), IdentificationError> {
        let n = input.len();
        if out.len() != n {
            return Err(IdentificationError::BadInput {
                what: "low-pass output".into(),
                reason: format!("buffer has {} samples, input {n}", out.len()),
            });
        }
        let pad = self.extend_and_run(input, scratch)?;
        for (o, &v) in out.iter_mut().zip(scratch[pad..pad + n].iter().rev()) {
            *o = v;
        }
        Ok(())
    }

    /// Zero-phase filtering of `buf` in place (at least 2 samples), using `scratch`.
    pub fn filtfilt_in_place(
        &self,
        buf: &mut [f64],
        scratch: &mut Vec<f64>,
    ) -> Result<(), IdentificationError> {
        let n = buf.len();
        let pad = self.extend_and_run(buf, scratch)?;
        for (o, &v) in buf.iter_mut().zip(scratch[pad..pad + n].iter().rev()) {
            *o = v;
        }
        Ok(())
    }

    /// Zero-phase filtering, allocating the output.
    pub fn filtfilt(&self, input: &[f64]) -> Result<Vec<f64>, IdentificationError> {
        let mut out = vec![0.0; input.len()];
        let mut scratch = Vec::new();
        self.filtfilt_into(input, &mut out, &mut scratch)?;
        Ok(out)
    }
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
