//! Where the conditioner node's frame-to-conditioned time goes at 100 kHz x 16 channels:
//! the chain's compute per block (block plus the filters' edge on each side) and the CDR
//! serialisation of the ConditionedFrame (the encoder rustdds uses), per block size.
//!
//! `cargo run --release -p oilfilm-nodes --example profile_conditioner`

use std::time::Instant;

use oilfilm_identification::excitation::ExcitationPlan;
use oilfilm_identification::simulate::{self, SimulateOptions};
use oilfilm_msgs::{DaqFrame, Header, BEARING_FRAME_ID};
use oilfilm_nodes::conditioner::{ConditionerCore, ConditionerParams};
use oilfilm_physics::config::RigConfig;

fn main() -> anyhow::Result<()> {
    let (rate, channels, daq_block, seconds) = (100_000.0, 16usize, 1_000usize, 3.0);
    let mut rig = RigConfig::zhou2004()?;
    rig.daq.sample_rate_hz = rate;
    rig.daq.channel_interval_s = 1.0 / (rate * channels as f64);
    let rec = simulate::simulate(&rig, &ExcitationPlan::two_tone(23.0, 37.0, 300.0), seconds, SimulateOptions::default(), &mut |_| {})?;
    let cal = rig.daq.calibration();
    let order = cal.scan_order();
    let mut names: Vec<String> = order.iter().map(|c| c.name().to_string()).collect();
    let mut offsets: Vec<f64> = order.iter().map(|&c| cal.sample_offset_s(c)).collect::<Result<_, _>>()?;
    for k in names.len()..channels {
        names.push(format!("aux_{k}"));
        offsets.push(k as f64 * rig.daq.channel_interval_s);
    }
    let frames: Vec<DaqFrame> = rec
        .scans
        .chunks(daq_block)
        .enumerate()
        .map(|(k, scans)| {
            let mut values = Vec::with_capacity(scans.len() * channels);
            for s in scans {
                values.extend_from_slice(&s.volts);
                values.extend(std::iter::repeat_n(0.0, channels - s.volts.len()));
            }
            DaqFrame {
                header: Header { frame_id: BEARING_FRAME_ID.into(), ..Default::default() },
                sequence: k as u64,
                first_scan: (k * daq_block) as u64,
                sample_rate_hz: rate,
                units: DaqFrame::UNITS_VOLTS,
                channel_names: names.clone(),
                channel_units: vec!["V".into(); channels],
                channel_offsets_s: offsets.clone(),
                scan_count: scans.len() as u32,
                values,
                rig: rig.name.clone(),
            }
        })
        .collect();
    println!("{} frames of {daq_block} scans x {channels} channels at {rate} Hz", frames.len());
    for block in [10_000i64, 5_000, 2_000, 1_000] {
        let params = ConditionerParams { lowpass_cutoff_hz: 55.5, block_scans: block, ..ConditionerParams::default() };
        let mut core = ConditionerCore::new(rig.clone(), &params)?;
        let (mut push_idle, mut push_out, mut ser) = (Vec::new(), Vec::new(), Vec::new());
        let mut bytes = 0;
        for f in &frames {
            let t0 = Instant::now();
            let out = core.push(f)?;
            let dt = t0.elapsed().as_secs_f64() * 1e3;
            if out.is_empty() { push_idle.push(dt) } else { push_out.push(dt) }
            for c in &out {
                let t0 = Instant::now();
                let v = ros2_client::dds::rustdds::cdr_encoding::to_vec::<_, byteorder::LittleEndian>(c)?;
                ser.push(t0.elapsed().as_secs_f64() * 1e3);
                bytes = v.len();
            }
        }
        let med = |v: &mut Vec<f64>| { v.sort_by(f64::total_cmp); v.get(v.len() / 2).copied().unwrap_or(f64::NAN) };
        let max = |v: &Vec<f64>| v.iter().copied().fold(f64::NAN, f64::max);
        println!(
            "block {block:>6}: edge {:?} scans; push producing a block median {:.2} ms (max {:.2}), other pushes {:.3} ms; CDR serialisation {:.2} ms (max {:.2}) for {bytes} bytes",
            core.edge_scans(),
            med(&mut push_out), max(&push_out), med(&mut push_idle), med(&mut ser), max(&ser)
        );
    }
    Ok(())
}
