//! The conditioning stages written out plainly from the public designs, one whole column at a
//! time and one stage after the other: what the prepared chain (its fused front end, tiles
//! and vector kernels) is compared with bit for bit, and what the error-budget tests measure
//! the designs through.

use oilfilm_identification::conditioning::deskew::FractionalDelay;
use oilfilm_identification::conditioning::differentiate::SavitzkyGolayDerivative;
use oilfilm_identification::conditioning::lowpass::Butterworth;
use oilfilm_physics::daq::{Calibration, ChannelId};

/// Step 3: `(v - offset) / sensitivity`, by the reciprocal sensitivity as the chain does.
pub fn to_si(channel: ChannelId, volts: &[f64], calibration: &Calibration) -> Vec<f64> {
    let c = calibration.channel(channel).expect("a calibrated channel");
    let gain = 1.0 / c.sensitivity_v_per_unit;
    volts.iter().map(|v| (v - c.offset_v) * gain).collect()
}

/// Step 4: the interior stencil `w0 x[n + s] + w1 x[n + s + 1] + ...`, summed in that order,
/// where it lies inside the column; the stencil shifted inside the column elsewhere.
pub fn delay(d: &FractionalDelay, x: &[f64]) -> Vec<f64> {
    let (n, w) = (x.len(), d.weights());
    (0..n)
        .map(|i| match usize::try_from(i as isize + d.stencil_start()) {
            Ok(first) if first + w.len() <= n => (1..w.len()).fold(w[0] * x[first], |acc, j| acc + w[j] * x[first + j]),
            _ => d.edge_value(i, n, |j| x[j]),
        })
        .collect()
}

/// Step 1: the zero-phase low-pass, section after section: odd reflections of `settling`
/// samples, each section started in its DC steady state for its first input, forward, then
/// backward; each step `y = (b0 x + q) - a1 y[-1]`, `q = (b1 x + b2 x[-1]) - a2 y[-1]` (the
/// order that keeps one multiply and one subtract on the recursion's path).
pub fn filtfilt(lp: &Butterworth, x: &[f64]) -> Vec<f64> {
    let (n, pad) = (x.len(), lp.settling_samples().min(x.len() - 1));
    let left = (1..=pad).rev().map(|i| 2.0 * x[0] - x[i]);
    let right = (1..=pad).map(|i| 2.0 * x[n - 1] - x[n - 1 - i]);
    let mut ext: Vec<f64> = left.chain(x.iter().copied()).chain(right).collect();
    let pass = |v: &mut Vec<f64>| {
        for s in lp.sections() {
            let ([b0, b1, b2], [a1, a2]) = (s.b, s.a);
            let (mut x1, mut y1) = (v[0], (b0 + b1 + b2) / (1.0 + a1 + a2) * v[0]);
            let mut q = b1 * v[0] + b2 * v[0] - a2 * y1;
            for xi in v.iter_mut() {
                let y = (b0 * *xi + q) - a1 * y1;
                q = b1 * *xi + b2 * x1 - a2 * y1;
                (x1, y1, *xi) = (*xi, y, y);
            }
        }
    };
    pass(&mut ext);
    ext.reverse();
    pass(&mut ext);
    ext.reverse();
    ext[pad..pad + n].to_vec()
}

/// Step 6: the Savitzky-Golay derivative: an edge row within `M` of either end, the centred
/// sum `c_1 (x[i + 1] - x[i - 1]) + c_2 (x[i + 2] - x[i - 2]) + ...` in between.
pub fn derivative(sg: &SavitzkyGolayDerivative, x: &[f64]) -> Vec<f64> {
    let (n, m, c) = (x.len(), sg.half_length(), sg.coefficients());
    let w = 2 * m + 1;
    let [left, right] = sg.edge_weights();
    let row = |weights: &[f64], inputs: &[f64]| weights.iter().zip(inputs).map(|(a, b)| a * b).sum::<f64>();
    (0..n)
        .map(|i| match i {
            _ if i < m => row(&left[i * w..(i + 1) * w], &x[..w]),
            _ if i >= n - m => row(&right[(i + m - n) * w..(i + m - n + 1) * w], &x[n - w..]),
            _ => (2..=m).fold(c[0] * (x[i + 1] - x[i - 1]), |acc, k| acc + c[k - 1] * (x[i + k] - x[i - k])),
        })
        .collect()
}
