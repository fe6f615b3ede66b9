use std::time::Instant;
use oilfilm_identification::estimator::{estimate_window, EstimatorConfig, Signals};
fn main() {
    let n = 50_000;
    let fs = 5000.0;
    let mut st: u64 = 12345;
    let mut noise = move || { st ^= st << 13; st ^= st >> 7; st ^= st << 17; (st >> 11) as f64 / (1u64 << 53) as f64 - 0.5 };
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); 6];
    for i in 0..n {
        let t = i as f64 / fs;
        let w1 = 2.0 * std::f64::consts::PI * 17.0; let w2 = 2.0 * std::f64::consts::PI * 43.0;
        let w3 = 2.0 * std::f64::consts::PI * 23.0; let w4 = 2.0 * std::f64::consts::PI * 37.0;
        let x = 5e-6 * (w1 * t).cos() + 3e-6 * (w2 * t).cos(); let vx = -5e-6 * w1 * (w1 * t).sin() - 3e-6 * w2 * (w2 * t).sin();
        let y = 4e-6 * (w3 * t).cos() + 2.5e-6 * (w4 * t).cos(); let vy = -4e-6 * w3 * (w3 * t).sin() - 2.5e-6 * w4 * (w4 * t).sin();
        let fx = -(1.2e8 * x + 2e5 * vx) + 5.0 * noise(); let fy = -(2e8 * y + 3e5 * vy) + 5.0 * noise();
        for (c, v) in cols.iter_mut().zip([x + 5e-8 * noise(), y + 5e-8 * noise(), vx + 1e-5 * noise(), vy + 1e-5 * noise(), fx, fy]) { c.push(v); }
    }
    let s = Signals { x_m: &cols[0], y_m: &cols[1], vx_m_s: &cols[2], vy_m_s: &cols[3], ax_m_s2: None, ay_m_s2: None, fx_n: &cols[4], fy_n: &cols[5] };
    let cfg = EstimatorConfig::default();
    let t = Instant::now();
    let mut w = None;
    for _ in 0..50 { w = Some(estimate_window(&s, 0..n, &cfg).unwrap()); }
    println!("full {:.3} ms {:?}", t.elapsed().as_secs_f64() * 20.0, w.map(|w| (w.frequencies_hz, w.flags)));
}
