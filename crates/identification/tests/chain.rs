//! The prepared conditioning chain on records and windows of them: a window conditions as a
//! record of its scans, a chain refuses a record at another rate, and the fused chain gives
//! the bits of the stages written out plainly ([`crate::reference`]) and run one after the
//! other, on every instruction set this CPU has.

use crate::{reference, volts_record};

use oilfilm_identification::conditioning::{condition, deskew, differentiate, lowpass, Chain, Conditioned, ConditioningConfig, Mechanics};
use oilfilm_identification::record::RawRecord;
use oilfilm_identification::simd::Isa;
use oilfilm_identification::IdentificationError;
use oilfilm_physics::daq::{ChannelId, DaqConfig};
use volts_record::volts_record;

/// A window of a record conditions exactly as a record of its scans: windows of clean
/// readings, windows with a range violation (indexed from the window's start), the whole
/// record, and one conditioning buffer reused across
/// them. A window past the record's end is refused, naming it.
#[test]
fn a_window_conditions_as_a_record_of_its_scans() {
    let calibration = DaqConfig::zhou2004().calibration();
    let mechanics = Mechanics { housing_mass_kg: 60.0, exciter_angles_deg: [45.0, 135.0], gravity_m_s2: 9.81 };
    let config = ConditioningConfig::default();
    let mut raw = volts_record(6000, &calibration, 11);
    raw.start_time_s = 2.5;
    // Far outside the probe's range (and finite): step 2 reports it.
    raw.columns[2][3500] = 1.0e3;
    let chain = Chain::new(&calibration, &mechanics, &config, raw.sample_rate_hz).unwrap();
    let mut work = Conditioned::default();
    for window in [0..6000, 1000..4234, 2500..5000, 3766..6000, 1000..4234] {
        let alone = RawRecord {
            start_time_s: raw.start_time_s + window.start as f64 / raw.sample_rate_hz,
            columns: raw.columns.iter().map(|c| c[window.clone()].to_vec()).collect(),
            ..raw.clone()
        };
        let expected = condition(&alone, &calibration, &mechanics, &config).unwrap();
        chain.condition_window_into(&raw, window.clone(), &mut work).unwrap();
        assert!(work == expected, "window {window:?}");
        let flagged = window.contains(&3500);
        assert_eq!(!work.range_violations.is_empty(), flagged, "window {window:?}");
        if flagged {
            assert_eq!(work.range_violations[0].index, 3500 - window.start);
        }
    }
    let e = chain.condition_window_into(&raw, 5000..7000, &mut work).unwrap_err().to_string();
    assert!(e.contains("window") && e.contains("6000"), "{e}");
}

/// A chain is designed for one sample rate: a record at another is refused, naming it.
#[test]
fn a_record_at_another_rate_is_refused() {
    let calibration = DaqConfig::zhou2004().calibration();
    let mechanics = Mechanics { housing_mass_kg: 60.0, exciter_angles_deg: [45.0, 135.0], gravity_m_s2: 9.81 };
    let chain = Chain::new(&calibration, &mechanics, &ConditioningConfig::default(), 4000.0).unwrap();
    let e = chain.condition(&volts_record(3000, &calibration, 7)).unwrap_err();
    assert!(matches!(&e, IdentificationError::InvalidParameter { field, .. } if field == "sample_rate_hz"), "{e}");
}

/// The fused chain (calibration, range check, de-skew, the linear combinations and the
/// low-pass's forward pass tile by tile; the backward pass handing its output to both
/// derivatives and eq. 2's inertia) against the stages run one after the other on the same
/// readings: the same bits, at record lengths that cut the tiles and the reflections
/// differently (the shortest has fewer samples than the low-pass's reflection beyond the
/// edges it trims), in volts and in SI, with a reading out of range, and at half-lengths of
/// the differentiator with and without a compiled kernel; the times and eq. 2's static part
/// too.
#[test]
fn fused_chain_equals_the_stages_bit_for_bit() {
    let calibration = DaqConfig::zhou2004().calibration();
    let mechanics = Mechanics { housing_mass_kg: 60.0, exciter_angles_deg: [45.0, 135.0], gravity_m_s2: 9.81 };
    for (config, n) in [
        (ConditioningConfig::default(), 1201),
        (ConditioningConfig::default(), 4099),
        (ConditioningConfig { lowpass_cutoff_hz: 55.5, ..ConditioningConfig::default() }, 3 * 256 * 7 + 5),
        (ConditioningConfig { lowpass_order: 5, ..ConditioningConfig::default() }, 2600),
        (ConditioningConfig { differentiator_half_length: 2, deskew_taps: 3, ..ConditioningConfig::default() }, 1500),
        (ConditioningConfig { differentiator_half_length: 9, deskew_taps: 7, ..ConditioningConfig::default() }, 1777),
    ] {
        for si_units in [false, true] {
            let mut raw = volts_record(n, &calibration, n as u64);
            raw.start_time_s = 12.345_678_9;
            // A reading out of its range (and finite): reported, and conditioned as it is.
            raw.columns[1][n / 2] = 1.0e3;
            if si_units {
                for (&ch, column) in raw.channels.iter().zip(raw.columns.iter_mut()) {
                    *column = reference::to_si(ch, column, &calibration);
                }
                raw.units = oilfilm_identification::record::RawUnits::Si;
            }
            let chain = Chain::new(&calibration, &mechanics, &config, raw.sample_rate_hz).unwrap();
            let by_isa: Vec<(Isa, Conditioned)> = Isa::available().into_iter().map(|isa| (isa, chain.clone().with_isa(isa).condition(&raw).unwrap())).collect();
            let c = &by_isa[0].1;
            assert_eq!(c.range_violations.len(), 1, "{:?}", c.range_violations);
            assert_eq!((c.range_violations[0].channel, c.range_violations[0].index), (raw.channels[1], n / 2));

            let mut si: Vec<Vec<f64>> = Vec::new();
            for (&ch, column) in ChannelId::ALL.iter().zip(&raw.columns) {
                let v = if si_units { column.clone() } else { reference::to_si(ch, column, &calibration) };
                let d = deskew::FractionalDelay::for_offset(calibration.sample_offset_s(ch).unwrap(), raw.sample_rate_hz, config.deskew_taps).unwrap();
                si.push(reference::delay(&d, &v));
            }
            let [mut a_x, mut a_y, mut b_x, mut b_y, frame_x, frame_y, mut f1, mut f2, f3, temperature]: [Vec<f64>; 10] = si.try_into().unwrap();
            // The mean of ends A and B, and their difference.
            for (a, b) in a_x.iter_mut().zip(b_x.iter_mut()).chain(a_y.iter_mut().zip(b_y.iter_mut())) {
                (*a, *b) = (0.5 * (*a + *b), *a - *b);
            }
            // Eq. 2's applied part, `(c1 f1 + c2 f2, s1 f1 + s2 f2 + (f3 - m g))`.
            let [a1, a2] = mechanics.exciter_angles_deg.map(f64::to_radians);
            let mg = mechanics.housing_mass_kg * mechanics.gravity_m_s2;
            for i in 0..n {
                (f1[i], f2[i]) = (a1.cos() * f1[i] + a2.cos() * f2[i], a1.sin() * f1[i] + a2.sin() * f2[i] + (f3[i] - mg));
            }
            let lp = lowpass::Butterworth::design(config.lowpass_order, config.lowpass_cutoff_hz, raw.sample_rate_hz).unwrap();
            let dynamic = [a_x, a_y, b_x, b_y, frame_x, frame_y, f1, f2];
            let mut dynamic: Vec<Vec<f64>> = dynamic.iter().map(|c| reference::filtfilt(&lp, c)).collect();
            // The two derivatives (which follow the fused low-pass's backward pass) and eq. 2's
            // inertial term, stage by stage.
            let sg = differentiate::SavitzkyGolayDerivative::new(config.differentiator_half_length, raw.sample_rate_hz).unwrap();
            let twice = |x: &[f64]| {
                let v = reference::derivative(&sg, x);
                let a = reference::derivative(&sg, &v);
                (v, a)
            };
            let (vx, ax) = twice(&dynamic[0]);
            let (vy, ay) = twice(&dynamic[1]);
            let (_, hax) = twice(&dynamic[4]);
            let (_, hay) = twice(&dynamic[5]);
            let m = mechanics.housing_mass_kg;
            for (f, a) in dynamic[6].iter_mut().zip(&hax) {
                *f -= m * a;
            }
            for (f, a) in dynamic[7].iter_mut().zip(&hay) {
                *f -= m * a;
            }
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
            // The scans' times, and eq. 2's static part as the plain mean over `valid`.
            let times: Vec<f64> = (0..n).map(|i| raw.start_time_s + i as f64 / raw.sample_rate_hz).collect();
            let valid = c.valid.clone();
            let static_part = [6, 7].map(|k| dynamic[k][valid.clone()].iter().sum::<f64>() / valid.len() as f64);
            for (isa, c) in &by_isa {
                assert!(bits(&c.t_s) == bits(&times), "t_s differs (n = {n}, {config:?}, SI {si_units}, {isa:?})");
                assert_eq!(c.static_force_n.map(f64::to_bits), static_part.map(f64::to_bits), "static part (n = {n}, {config:?}, {isa:?})");
                for (name, fused, staged) in [
                    ("vx_m_s", &c.vx_m_s, &vx),
                    ("ax_m_s2", &c.ax_m_s2, &ax),
                    ("vy_m_s", &c.vy_m_s, &vy),
                    ("ay_m_s2", &c.ay_m_s2, &ay),
                    ("housing_ax_m_s2", &c.housing_ax_m_s2, &hax),
                    ("housing_ay_m_s2", &c.housing_ay_m_s2, &hay),
                    ("x_m", &c.x_m, &dynamic[0]),
                    ("y_m", &c.y_m, &dynamic[1]),
                    ("tilt_x_m", &c.tilt_x_m, &dynamic[2]),
                    ("tilt_y_m", &c.tilt_y_m, &dynamic[3]),
                    ("housing_x_m", &c.housing_x_m, &dynamic[4]),
                    ("housing_y_m", &c.housing_y_m, &dynamic[5]),
                    ("fx_n", &c.fx_n, &dynamic[6]),
                    ("fy_n", &c.fy_n, &dynamic[7]),
                    ("static_load_n", &c.static_load_n, &f3),
                    ("temperature_c", &c.temperature_c, &temperature),
                ] {
                    assert!(bits(fused) == bits(staged), "{name} differs (n = {n}, {config:?}, SI {si_units}, {isa:?})");
                }
            }
        }
    }
}
