//! Decimated standard errors (`EstimatorConfig::signal_band_hz`, see the estimator's
//! `uncertainty` module, "Decimated standard errors"): on band-limited records the standard
//! errors computed from every `q`-th sample agree with those from every sample, the
//! coefficients stay bit for bit the same, and the decimated errors still cover the truth.
//!
//! Records: the coverage test's design (`tests/coverage.rs`: short film, two-tone 23/37 Hz at
//! 55 N, 40 dB probe noise, 16-bit DAQ, a random probe offset within one LSB per record, the
//! low-pass at 60 Hz) sampled at 20 kHz for 10 s, one window of about 195 000 samples, so the
//! standard errors are decimated 41-fold, the band's bound (20 kHz / (8 x 60 Hz)): about 4 750
//! samples left, near the 2 000-sample floor (`SE_MIN_SAMPLES`), which the sim_rig's 5 kHz
//! windows (11-fold, 2 273 samples) and the node benchmark's 100 kHz ones (100-fold) reach.

use crate::simulated_rig;

use simulated_rig::*;

use nalgebra::Matrix2;
use oilfilm_identification::estimator::{se_decimation, EstimatorConfig};
use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::pipeline::PipelineConfig;
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_identification::IdentificationError;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const NAMES: [&str; 8] = ["kxx", "kxy", "kyx", "kyy", "dxx", "dxy", "dyx", "dyy"];

fn flat(k: &Matrix2<f64>, c: &Matrix2<f64>) -> [f64; 8] {
    [k[(0, 0)], k[(0, 1)], k[(1, 0)], k[(1, 1)], c[(0, 0)], c[(0, 1)], c[(1, 0)], c[(1, 1)]]
}

#[test]
fn decimation_factor_follows_the_band_and_the_sample_floor() {
    // The node benchmark's window: 2 s at 100 kHz, low-pass 55.5 Hz: the 2 000-sample floor.
    assert_eq!(se_decimation(200_000, 100_000.0, Some(55.5)), 100);
    // The band bound: 8 x 200 Hz = 1.6 kHz of 5 kHz allows 3.
    assert_eq!(se_decimation(1_000_000, 5_000.0, Some(200.0)), 3);
    // The sim_rig window, 5 s at 5 kHz, 55.5 Hz: the band bound, 11 (2 273 samples left).
    assert_eq!(se_decimation(25_000, 5_000.0, Some(55.5)), 11);
    // A window too short for the floor stays whole; no band, no decimation.
    assert_eq!(se_decimation(3_999, 5_000.0, Some(55.5)), 1);
    assert_eq!(se_decimation(200_000, 100_000.0, None), 1);
    // A band too wide for the rate: no decimation.
    assert_eq!(se_decimation(200_000, 1_000.0, Some(100.0)), 1);
}

#[test]
fn a_band_outside_the_record_is_refused_by_name() {
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY, 2_500.0, 9_000.0] {
        let cfg = EstimatorConfig { signal_band_hz: Some(bad), ..EstimatorConfig::default() };
        match cfg.validate() {
            Err(IdentificationError::InvalidParameter { field, .. }) => assert_eq!(field, "signal_band_hz", "band {bad}"),
            other => panic!("band {bad}: {other:?}"),
        }
    }
    let ok = EstimatorConfig { signal_band_hz: Some(200.0), ..EstimatorConfig::default() };
    assert!(ok.validate().is_ok());
    // Absent from TOML/JSON: None, and not written back (old files and outputs unchanged).
    let json = serde_json::to_string(&EstimatorConfig::default()).unwrap();
    assert!(!json.contains("signal_band_hz"), "{json}");
}

#[test]
fn decimated_standard_errors_agree_with_the_full_ones_and_cover_the_truth() {
    let mut base = short_rig();
    base.daq.sample_rate_hz = 20_000.0;
    base.daq.channel_interval_s = 1.0 / (base.daq.sample_rate_hz * base.daq.channels.len() as f64);
    let plan = ExcitationPlan::two_tone(23.0, 37.0, 55.0);
    let seconds = 10.0;
    let rms = displacement_rms(&base, &plan, seconds);
    let mut rig = base.clone();
    let probe_noise = forty_db_noise(rms);
    set_probe_noise(&mut rig, probe_noise);
    let lsb_v = 2.0 * rig.daq.full_scale_v / 2f64.powi(rig.daq.adc_bits as i32);

    // One window per record (a window longer than the record is the record).
    let mut full = PipelineConfig { adaptive_lowpass: false, ..PipelineConfig::default() };
    full.conditioning.lowpass_cutoff_hz = 60.0;
    full.estimator.window = 10_000_000;
    full.estimator.hop = 10_000_000;
    let mut decimated = full.clone();
    decimated.estimator.signal_band_hz = Some(60.0);

    let seeds = 30;
    let (mut errors, mut ses) = (Vec::new(), Vec::new());
    let mut worst = (0.0f64, 0, 0u64);
    let mut q_seen = usize::MAX;
    for seed in 2000..2000 + seeds as u64 {
        rig.simulation.seed = seed;
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed);
        for c in rig.daq.channels.iter_mut().filter(|c| c.channel.is_displacement_probe()) {
            c.offset_v = lsb_v * (rng.random::<f64>() - 0.5);
        }
        let rec = simulate::simulate(&rig, &plan, seconds, SimulateOptions::default(), &mut |_| {}).unwrap();
        let truth = flat(&rec.truth.coefficients.stiffness_n_m, &rec.truth.coefficients.damping_n_s_m);
        let (id_full, id_dec) = (identify(&rig, &rec, &full), identify(&rig, &rec, &decimated));
        let (a, b) = (solved(&id_full), solved(&id_dec));
        let w = &id_dec.windows[0].estimate;
        q_seen = q_seen.min(se_decimation(w.end - w.start, 20_000.0, Some(60.0)));
        // The coefficients do not depend on how their errors are computed.
        assert_eq!((a.stiffness_n_m, a.damping_n_s_m), (b.stiffness_n_m, b.damping_n_s_m), "seed {seed}: coefficients changed");
        assert_eq!(id_full.windows[0].estimate.residual_rms_n, w.residual_rms_n, "seed {seed}: residual RMS changed");
        let (se_a, se_b) = (flat(&a.stiffness_se, &a.damping_se), flat(&b.stiffness_se, &b.damping_se));
        for j in 0..8 {
            let r = se_b[j] / se_a[j] - 1.0;
            if r.abs() > worst.0.abs() {
                worst = (r, j, seed);
            }
        }
        let est = flat(&b.stiffness_n_m, &b.damping_n_s_m);
        errors.push(std::array::from_fn::<f64, 8, _>(|j| est[j] - truth[j]));
        ses.push(se_b);
    }
    assert!(q_seen >= 40, "the test is meant to decimate about 41-fold, got {q_seen}");
    println!("{seeds} seeds at 20 kHz, SE decimated {q_seen}-fold: largest SE change {:+.2} % ({} seed {})", 100.0 * worst.0, NAMES[worst.1], worst.2);
    assert!(worst.0.abs() < 0.01, "decimated SE of {} differs by {:+.2} % (seed {})", NAMES[worst.1], 100.0 * worst.0, worst.2);

    // Coverage with the decimated errors (30 seeds: the bounds allow the sampling error).
    let n = seeds as f64;
    println!("coef   mean err/SE  SD/SE  coverage(±1.96 SE)");
    for j in 0..8 {
        let mean = errors.iter().map(|e| e[j]).sum::<f64>() / n;
        let sd = (errors.iter().map(|e| (e[j] - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        let se = ses.iter().map(|s| s[j]).sum::<f64>() / n;
        let cover = errors.iter().zip(&ses).filter(|(e, s)| e[j].abs() <= 1.96 * s[j]).count() as f64 / n;
        println!("{:<5} {:+10.2} {:6.2} {:8.3}", NAMES[j], mean / se, sd / se, cover);
        assert!(cover >= 0.8, "{}: coverage {cover:.3} of {seeds} seeds is not about 95 %", NAMES[j]);
        assert!((mean / se).abs() < 0.7, "{}: mean error {:+.2} standard errors", NAMES[j], mean / se);
        assert!((0.65..1.45).contains(&(sd / se)), "{}: scatter / SE = {:.2}", NAMES[j], sd / se);
    }
}
