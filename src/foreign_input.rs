//! Records from other tools (TDMS, .mat, CSV) with `--map`: `oilfilm identify` and `oilfilm
//! diagnose` read them block by block into the raw record the batch identification takes
//! (as `identify BAG` reads an imported bag's frames); `identify --map --replay` streams them
//! through the node conditioner and estimator as the DAQ node's foreign source publishes
//! them (the estimates of `oilfilm import` then `identify BAG --replay`, bit for bit).

use std::cell::RefCell;
use std::path::Path;

use anyhow::{Context, Result};
use oilfilm_foreign::{Block, ChannelMap, ForeignRecord, RecordSpeed};
use oilfilm_graph::daq::DaqParams;
use oilfilm_graph::foreign::ForeignSource;
use oilfilm_identification::pipeline::{self, SpeedSource};
use oilfilm_identification::record::{RawRecord, RawUnits};
use oilfilm_msgs::{Header, RigStatus};
use oilfilm_physics::config::RigConfig;

use crate::records::IdentifyArgs;

/// The DAQ node's parameters for a foreign record read offline: its default frame size, the
/// speed from the record.
pub fn daq_params() -> DaqParams {
    DaqParams { source: "foreign".into(), ..DaqParams::default() }
}

/// `oilfilm identify FILE --map MAP --replay`.
pub fn identify(args: &IdentifyArgs, map_path: &Path) -> Result<crate::Outcome> {
    let name = args.file.display().to_string();
    anyhow::ensure!(!args.file.is_dir(), "{name} is a directory: --map is for a TDMS, .mat or CSV file");
    let rig = args.source.load()?;
    let map = ChannelMap::load(map_path)?;
    let (conditioner, mut estimator, _) = crate::records::node_params(args)?;
    crate::records::apply_estimator_options(args, &mut estimator)?;
    let daq = daq_params();
    let mut source = ForeignSource::with_map(&args.file, &map, &rig, &daq)?;
    // The estimator takes every status before the frames (as a bag's re-analysis does) and
    // keeps the last speed. One number: one status says it. A speed channel: the statuses of
    // the whole record, from a first pass over it.
    let status = match source.stated_speed_rpm() {
        Some(rpm) => vec![RigStatus {
            header: Header::default(),
            speed_rad_s: rpm * std::f64::consts::PI / 30.0,
            state: RigStatus::STATE_RUNNING,
            ..RigStatus::default()
        }],
        None => {
            let mut first = ForeignSource::with_map(&args.file, &map, &rig, &daq)?;
            let mut status = Vec::new();
            while let Some((_, s)) = first.next_frame()? {
                status.push(s);
            }
            status
        }
    };
    let failed: RefCell<Option<anyhow::Error>> = RefCell::new(None);
    let frames = std::iter::from_fn(|| match source.next_frame() {
        Ok(next) => next.map(|(frame, _)| frame),
        Err(e) => {
            *failed.borrow_mut() = Some(e.into());
            None
        }
    });
    let out =
        oilfilm_graph::runner::bag::reanalyse_overlapped(&rig, &conditioner, &estimator, status, frames).with_context(|| format!("re-analysing {name}"))?;
    if let Some(e) = failed.into_inner() {
        return Err(e);
    }
    let frames = source.frames();
    let record = source.record();
    if args.json {
        let doc = serde_json::json!({
            "record": name,
            "map": map_path.display().to_string(),
            "format": record.format.name(),
            "frame": pipeline::FRAME,
            "frames": frames,
            "conditioner": conditioner,
            "estimator": estimator,
            "estimates": out.estimates,
        });
        println!("{}", serde_json::to_string_pretty(&doc)?);
        return Ok(outcome(&name, &out.estimates));
    }
    println!(
        "{name} ({} through {}): {frames} DAQ frames of {} Hz {} through the node conditioner and estimator",
        record.format.name(),
        map_path.display(),
        record.sample_rate_hz,
        if record.volts { "volts" } else { "SI values" }
    );
    println!("frame: {}", pipeline::FRAME);
    for e in &out.estimates {
        crate::launch::print_estimate(e);
    }
    println!("{} estimate(s), {} solved", out.estimates.len(), out.estimates.iter().filter(|e| e.solved).count());
    Ok(outcome(&name, &out.estimates))
}

/// Done when a window was solved; refused (a non-zero exit) when none was.
fn outcome(name: &str, estimates: &[oilfilm_msgs::CoefficientEstimate]) -> crate::Outcome {
    match estimates.iter().filter(|e| e.solved).count() {
        0 => crate::Outcome::Refused(format!("{name}: {} estimate(s), none solved", estimates.len())),
        _ => crate::Outcome::Done,
    }
}

/// A foreign record as one raw record for the diagnosis, with its calibration and speed.
pub struct Loaded {
    pub raw: RawRecord,
    pub calibration: oilfilm_physics::daq::Calibration,
    /// Each channel's offset in the scan (the map's multiplexer schedule), s.
    pub offsets_s: Vec<f64>,
    pub speed_rpm: Option<f64>,
}

/// Reads `file` through the map `map_path` into columns, a block at a time (the file itself
/// is never held whole). The speed: the map's number or property, or the mean of its speed
/// channel over the record; `None` when the record does not say.
pub fn load_raw(file: &Path, map_path: &Path, rig: &RigConfig) -> Result<Loaded> {
    let map = ChannelMap::load(map_path)?;
    let mut rec = ForeignRecord::open(file, &map, &rig.daq.calibration())?;
    let width = rec.channels.len();
    let capacity = rec.scans.unwrap_or(0).min(1 << 28) as usize;
    let mut columns: Vec<Vec<f64>> = (0..width).map(|_| Vec::with_capacity(capacity)).collect();
    let (mut speed_sum, mut block) = (0.0, Block::default());
    while rec.next_block(1 << 16, &mut block)? > 0 {
        for scan in block.values.chunks_exact(width) {
            for (c, v) in columns.iter_mut().zip(scan) {
                c.push(*v);
            }
        }
        speed_sum += block.speed_rpm.iter().sum::<f64>();
    }
    let scans = columns.first().map_or(0, Vec::len);
    let speed_rpm = match &rec.speed {
        RecordSpeed::Rpm { rpm, .. } => Some(*rpm),
        RecordSpeed::Channel { .. } if scans > 0 => Some(speed_sum / scans as f64),
        _ => None,
    };
    let raw = RawRecord {
        sample_rate_hz: rec.sample_rate_hz,
        start_time_s: rec.start_time_s,
        channels: rec.channels.clone(),
        units: if rec.volts { RawUnits::Volts } else { RawUnits::Si },
        columns,
    };
    let calibration =
        pipeline::calibration_for(rig, &raw, &rec.offsets_s).with_context(|| format!("{}: the rig's calibration on the map's schedule", file.display()))?;
    Ok(Loaded { raw, calibration, offsets_s: rec.offsets_s.clone(), speed_rpm })
}

/// Where a diagnosed foreign record's speed came from.
pub fn speed_source(user: Option<f64>, record: Option<f64>, rig: &RigConfig) -> (f64, SpeedSource) {
    match (user, record) {
        (Some(v), _) => (v, SpeedSource::User),
        (None, Some(v)) => (v, SpeedSource::Record),
        (None, None) => (rig.operating.speed_rpm, SpeedSource::RigFile),
    }
}
