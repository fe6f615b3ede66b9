//! The campaign (Zhou et al. 2004, sections 3.2-3.3) on the simulated rig: the fits recover
//! known polynomials and refuse what they cannot determine; the quick campaign checks the
//! paper's claims and prints the numbers behind each verdict.
//!
//! One quick campaign (5 load points, 2 x 4 amplitude steps, 4 s records: about 7 s
//! optimised) is shared by the tests that judge it.

use std::sync::OnceLock;

use oilfilm_identification::campaign::{
    self, fit_cubic_no_linear, fit_quadratic, relative_variation, relative_variation_se, Campaign, CampaignConfig, LoadStudyConfig, OperatingSpec, Verdict,
    COEFFICIENT_NAMES, DIRECT,
};
use oilfilm_physics::config::RigConfig;

fn quick_campaign() -> &'static Campaign {
    static CAMPAIGN: OnceLock<Campaign> = OnceLock::new();
    CAMPAIGN.get_or_init(|| {
        let rig = RigConfig::zhou2004().expect("built-in rig");
        let started = std::time::Instant::now();
        let c = campaign::run_campaign(&rig, &CampaignConfig::quick(), &mut |_| {}).expect("quick campaign runs");
        println!("quick campaign: {:.1} s", started.elapsed().as_secs_f64());
        c
    })
}

#[test]
fn quadratic_fit_recovers_a_known_polynomial_exactly() {
    let (c0, c1, c2) = (0.3, -1.2, 0.7);
    let x = [0.1, 0.35, 0.5, 0.9, 1.4, 2.0];
    let y: Vec<f64> = x.iter().map(|v| c0 + c1 * v + c2 * v * v).collect();
    let f = fit_quadratic(&x, &y).unwrap();
    println!("quadratic: c0 {:.15} c1 {:.15} c2 {:.15} R^2 {} rms {:e}", f.c0, f.c1, f.c2, f.r_squared, f.rms_residual);
    assert!((f.c0 - c0).abs() < 1e-12 && (f.c1 - c1).abs() < 1e-12 && (f.c2 - c2).abs() < 1e-12, "{f:?}");
    assert!((f.r_squared - 1.0).abs() < 1e-12 && f.rms_residual < 1e-12);
    assert_eq!(f.points, 6);
    // Three points determine it exactly, with no degree of freedom left for a covariance.
    let f3 = fit_quadratic(&x[..3], &y[..3]).unwrap();
    assert!((f3.c2 - c2).abs() < 1e-10 && f3.covariance.is_none(), "{f3:?}");
}

#[test]
fn cubic_fit_without_linear_term_recovers_eq_10_exactly() {
    let (a, b, d0) = (15.0, -3.0, 2.1);
    let d = [0.005, 0.02, 0.05, 0.08, 0.1, 0.12];
    let y: Vec<f64> = d.iter().map(|v| a * v * v * v + b * v * v + d0).collect();
    let f = fit_cubic_no_linear(&d, &y).unwrap();
    println!("cubic: a {:.12} b {:.12} d0 {:.15} R^2 {}", f.a, f.b, f.d0, f.r_squared);
    assert!((f.a - a).abs() < 1e-8 && (f.b - b).abs() < 1e-9 && (f.d0 - d0).abs() < 1e-13, "{f:?}");
    assert!((f.r_squared - 1.0).abs() < 1e-12);
    // RV (eq. 11) is the fit's own relative change, and its standard error vanishes for an
    // exact fit.
    let rv = relative_variation(&f, 0.1).unwrap();
    let expected = (a * 1e-3 + b * 1e-2) / d0;
    println!("RV(0.1) = {rv:.12} (expected {expected:.12}), se {:?}", relative_variation_se(&f, 0.1));
    assert!((rv - expected).abs() < 1e-10);
    assert!(relative_variation_se(&f, 0.1).is_some_and(|se| se < 1e-9));
    assert_eq!(relative_variation(&f, 0.0).unwrap(), 0.0);
}

#[test]
fn fits_refuse_under_determined_and_bad_input() {
    let cases: Vec<(&str, Vec<f64>, Vec<f64>)> = vec![
        ("two points", vec![0.1, 0.2], vec![1.0, 2.0]),
        ("three points at two abscissae", vec![0.1, 0.1, 0.2], vec![1.0, 1.1, 2.0]),
        ("one abscissa repeated", vec![0.3; 6], vec![1.0, 1.1, 1.2, 1.3, 1.4, 1.5]),
        ("NaN", vec![0.1, 0.2, f64::NAN, 0.4], vec![1.0, 2.0, 3.0, 4.0]),
        ("length mismatch", vec![0.1, 0.2, 0.3, 0.4], vec![1.0, 2.0, 3.0]),
        ("empty", vec![], vec![]),
    ];
    for (what, x, y) in &cases {
        let q = fit_quadratic(x, y);
        let c = fit_cubic_no_linear(x, y);
        println!("{what}: quadratic {:?}; cubic {:?}", q.as_ref().err().map(ToString::to_string), c.as_ref().err().map(ToString::to_string));
        assert!(q.is_err(), "quadratic accepted {what}");
        assert!(c.is_err(), "cubic accepted {what}");
    }
    // Under-determined is said in words.
    let e = fit_cubic_no_linear(&[0.1, 0.2], &[1.0, 2.0]).unwrap_err().to_string();
    assert!(e.contains("under-determined"), "{e}");
    // RV needs KD(0) != 0.
    let zero = fit_cubic_no_linear(&[0.0, 0.05, 0.1, 0.12], &[0.0, 1.0, 2.0, 2.5]).unwrap();
    let e = relative_variation(&campaign::CubicNoLinearFit { d0: 0.0, ..zero }, 0.1).unwrap_err().to_string();
    println!("RV with KD(0) = 0: {e}");
    assert!(e.contains("undefined"));
}

#[test]
fn config_rejects_unknown_fields_and_bad_numbers() {
    let text = serde_json::to_string(&CampaignConfig::quick()).unwrap();
    let back: CampaignConfig = serde_json::from_str(&text).unwrap();
    assert_eq!(back, CampaignConfig::quick());
    let e = serde_json::from_str::<CampaignConfig>(r#"{"record": {"snr": 40}}"#).unwrap_err().to_string();
    println!("unknown field: {e}");
    assert!(e.contains("unknown field"));
    let mut bad = CampaignConfig::quick();
    bad.record.frequency_ratios = [0.4, 0.4];
    let e = bad.validate().unwrap_err().to_string();
    println!("{e}");
    assert!(e.contains("frequency_ratios"));
    let mut bad = CampaignConfig::quick();
    bad.amplitude.steps = 2;
    assert!(bad.validate().unwrap_err().to_string().contains("amplitude.steps"));
    // A load beyond the bellows is refused, naming the point.
    let rig = RigConfig::zhou2004().unwrap();
    let mut bad = CampaignConfig::quick();
    bad.load.points[0].load_n = 25_000.0;
    let e = campaign::run_load_study(&rig, &bad, &mut |_| {}).unwrap_err().to_string();
    println!("{e}");
    assert!(e.contains("load.points[0]") && e.contains("bellows"), "{e}");
}

#[test]
fn a_record_is_reproducible_bit_for_bit() {
    let rig = RigConfig::zhou2004().unwrap();
    let mut cfg = CampaignConfig::quick();
    cfg.record.analysed_s = 1.0;
    cfg.load = LoadStudyConfig {
        points: vec![
            OperatingSpec { speed_rpm: 1500.0, load_n: 3000.0, temperature_c: None },
            OperatingSpec { speed_rpm: 1500.0, load_n: 6000.0, temperature_c: None },
            OperatingSpec { speed_rpm: 1500.0, load_n: 9000.0, temperature_c: None },
        ],
        model_curve_points: 3,
        ..LoadStudyConfig::quick()
    };
    let a = campaign::run_load_study(&rig, &cfg, &mut |_| {}).unwrap();
    let b = campaign::run_load_study(&rig, &cfg, &mut |_| {}).unwrap();
    let seeds: Vec<u64> = a.points.iter().map(|p| p.spec.seed).collect();
    println!("seeds {seeds:?}, Kxx {:?}", a.points.iter().map(|p| p.identified.map(|c| c.kxx)).collect::<Vec<_>>());
    assert_eq!(seeds, vec![rig.simulation.seed, rig.simulation.seed + 1, rig.simulation.seed + 2]);
    assert_eq!(serde_json::to_string(&a).unwrap(), serde_json::to_string(&b).unwrap());
}

#[test]
fn load_study_identifies_the_film_and_its_direct_coefficients_grow_with_fy() {
    let c = quick_campaign();
    let ls = &c.load_study;
    for p in &ls.points {
        let id = p.identified.expect("every quick load point is identified");
        println!(
            "{:>5.0} rpm {:>6.0} N: F_Y {:.3} (model {:.3}), d {:.4}; Kxx {:.3} Kyy {:.3} Dxx {:.3} Dyy {:.3}; rel. diff to model {:?}",
            p.spec.speed_rpm,
            p.spec.load_n,
            p.load_parameter,
            p.model.load_parameter,
            p.amplitude_d,
            id.kxx,
            id.kyy,
            id.dxx,
            id.dyy,
            p.relative_difference_to_model.map(|d| d.as_array().map(|v| (1000.0 * v).round() / 10.0))
        );
        // The small-amplitude records land where they were aimed, and identify the direct
        // terms within 5 % of the film model (40 dB probes, 4 s).
        assert!((p.amplitude_d - 0.01).abs() < 0.002, "d = {}", p.amplitude_d);
        assert!((p.load_parameter / p.model.load_parameter - 1.0).abs() < 0.01);
        let diff = p.relative_difference_to_model.unwrap().as_array();
        for &k in &DIRECT {
            assert!(diff[k].abs() < 0.05, "{} off the model by {:.1} % at F_Y {:.2}", COEFFICIENT_NAMES[k], 100.0 * diff[k], p.load_parameter);
        }
    }
    for t in &ls.trends {
        println!(
            "{}: fit {:.3} -> {:.3} over F_Y {:.2}-{:.2} (sign {:+}, |.| grows {}), model {:.3} -> {:.3}, R^2 {:.4}",
            t.name,
            t.fit_at_min_fy,
            t.fit_at_max_fy,
            t.fy_range[0],
            t.fy_range[1],
            t.slope_sign,
            t.grows_in_magnitude,
            t.model_at_min_fy,
            t.model_at_max_fy,
            t.fit.r_squared
        );
    }
    // The paper's finding in Zhou's normalisation: the direct terms grow with F_Y, in the
    // identification as in the model, and by a lot (more than 2x over the range).
    for &k in &DIRECT {
        let t = &ls.trends[k];
        assert_eq!(t.slope_sign, 1, "{} does not grow with F_Y", t.name);
        assert_eq!(t.model_slope_sign, 1, "the model's {} does not grow with F_Y", t.name);
        assert!(t.fit_at_max_fy > 2.0 * t.fit_at_min_fy, "{}: {} -> {}", t.name, t.fit_at_min_fy, t.fit_at_max_fy);
    }
    assert!(c.findings.direct_coefficients_grow_with_fy);
    // Not every coefficient grows: Kxy (x-force per vertical displacement) turns over in the
    // model and the identification alike; the findings must say so, not hide it.
    let kxy = &ls.trends[1];
    assert!(kxy.model_extremum.is_some() && !kxy.grows_in_magnitude, "{kxy:?}");
    assert!(c.findings.not_growing_in_magnitude.contains(&"Kxy".to_string()));
}

#[test]
fn relative_variation_grows_with_amplitude() {
    let c = quick_campaign();
    for s in [&c.amplitude_study.low, &c.amplitude_study.high] {
        println!("{} ({:.0} rpm, {:.0} N): largest force {:.0} N ({})", s.label, s.speed_rpm, s.load_n, s.max_force_n, s.max_force_limited_by);
        for st in &s.steps {
            println!("  F {:>5.0} N: d {:.4} (predicted {:.4})", st.spec.amplitude_n, st.amplitude_d, st.excitation.predicted_d);
        }
        for f in &s.fits {
            println!(
                "  {}: d0 {:.4} b {:.3} a {:.3} R^2 {:.4}; RV({:.3}) {:+.2} %, |RV| monotone {}",
                f.name,
                f.fit.d0,
                f.fit.b,
                f.fit.a,
                f.fit.r_squared,
                s.max_d,
                100.0 * f.rv_at_max_d,
                f.abs_rv_monotone
            );
        }
        // The sweep spans the paper's range of d.
        assert!(s.steps.first().is_some_and(|st| st.amplitude_d < 0.008), "smallest d too large");
        assert!(s.max_d > 0.08, "{}: largest d only {}", s.label, s.max_d);
    }
    for (label, dmax, half, full) in &c.findings.mean_abs_rv_growth {
        println!("{label}: mean |RV| {:.2} % at d {:.3}, {:.2} % at d {dmax:.3}", 100.0 * half, 0.5 * dmax, 100.0 * full);
        // Larger by far at the largest d than at half of it, and clearly above noise.
        assert!(*full > 2.0 * *half && *full > 0.02, "{label}: {half} -> {full}");
    }
    assert!(c.findings.rv_grows_with_d);
}

/// The paper (Figs 9-10) found RV larger at F_Y 1.3 than at 0.35 at the same d (over 20 % at
/// d = 0.05 for the stiffness terms at 1.3). The simulated isoviscous film does not show it:
/// at d = 0.05 and at the largest common d the mean |RV| is smaller at F_Y 1.3 by more than
/// two standard errors (quick run: 0.63 against 1.56 % and 3.09 against 5.36 %). This test
/// pins that finding (so that a change in the film or the identification that moves it is
/// noticed) rather than asserting the paper's claim, which fails here. The film itself shows
/// the same without rig or identification (tests/rv_vs_load_film.rs,
/// docs/findings/rv-vs-load.md).
#[test]
fn relative_variation_is_not_larger_at_high_fy_unlike_the_paper() {
    let c = quick_campaign();
    let f = &c.findings;
    for at in [&f.rv_at_common_d, &f.rv_at_d_005] {
        println!(
            "d = {:.3}: mean |RV| {:.2} % (se {:?}) at {} vs {:.2} % (se {:?}) at {}: {:?}; larger at high F_Y for {} of 8",
            at.d,
            100.0 * at.mean_abs_rv_high_fy,
            at.mean_abs_rv_high_fy_se,
            c.amplitude_study.high.label,
            100.0 * at.mean_abs_rv_low_fy,
            at.mean_abs_rv_low_fy_se,
            c.amplitude_study.low.label,
            at.verdict,
            at.larger_at_high_fy
        );
        for r in &at.coefficients {
            println!("    {}: {:+.2} % vs {:+.2} %", r.name, 100.0 * r.rv_high_fy, 100.0 * r.rv_low_fy);
        }
    }
    // Compared at a common d inside both sweeps.
    assert!(f.common_d > 0.08 && !f.rv_at_common_d.extrapolated_low_fy && !f.rv_at_common_d.extrapolated_high_fy);
    assert!(!f.rv_at_d_005.extrapolated_low_fy && !f.rv_at_d_005.extrapolated_high_fy);
    // At d = 0.05 the high F_Y varies less, by more than two standard errors.
    assert_eq!(f.rv_at_d_005.verdict, Verdict::Smaller, "{:?}", f.rv_at_d_005);
    // And at the largest common d.
    assert_eq!(f.rv_at_common_d.verdict, Verdict::Smaller, "{:?}", f.rv_at_common_d);
    // Coefficient by coefficient, most are smaller at the high F_Y too.
    assert!(
        f.rv_at_d_005.larger_at_high_fy <= 2 && f.rv_at_common_d.larger_at_high_fy <= 3,
        "{} and {} of 8 larger",
        f.rv_at_d_005.larger_at_high_fy,
        f.rv_at_common_d.larger_at_high_fy
    );
    assert!(!f.rv_faster_at_high_fy);
}

#[test]
fn most_sensitive_names_one_of_the_eight() {
    let c = quick_campaign();
    let f = &c.findings;
    println!(
        "most sensitive at d = {:.3}: {} (RV {:+.2} % at {}); per F_Y {:?}",
        f.common_d,
        f.most_sensitive,
        100.0 * f.most_sensitive_rv,
        f.most_sensitive_at,
        f.most_sensitive_per_fy
    );
    for n in &f.notes {
        println!("  {n}");
    }
    assert!(COEFFICIENT_NAMES.contains(&f.most_sensitive.as_str()), "{}", f.most_sensitive);
    // It is the largest |RV| in the comparison it names.
    let largest = f.rv_at_common_d.coefficients.iter().flat_map(|r| [r.rv_low_fy.abs(), r.rv_high_fy.abs()]).fold(0.0, f64::max);
    assert_eq!(f.most_sensitive_rv.abs(), largest);
    assert!(f.most_sensitive_rv.abs() > 0.02, "a most-sensitive RV of {} is noise", f.most_sensitive_rv);
}
