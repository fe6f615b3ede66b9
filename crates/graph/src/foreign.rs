//! The DAQ node's foreign source: a record from another tool (TDMS, .mat, CSV) read through
//! its channel map ([`oilfilm_foreign`]) and published as the DAQ node publishes a replayed
//! ASCII record: [`DaqFrame`]s of `block_scans` consecutive scans, each followed by a
//! [`RigStatus`].
//!
//! * Channels in the map's order, with its multiplexer offsets; `first_scan` counts from the
//!   file's first scan; stamps `start_time_s + scan / rate` (integer nanoseconds), or the
//!   `start_stamp_ns` parameter for scan 0.
//! * Units: volts when every channel of the map is in V or mV (the rig's calibration converts
//!   them downstream, as for our own card), else SI (m, N, degC) with any volts converted by
//!   the rig's calibration here.
//! * Status after each frame, stamped at the start of the next scan: speed from the
//!   `speed_rpm` parameter, else the map's source (a number, a file property, or the frame's
//!   mean of a speed channel), else the rig file's; static load the frame's mean |f3|,
//!   temperature its mean, both in SI.
//!
//! Reading is the only I/O; errors name the file, the channel and the scan.

use std::path::Path;

use oilfilm_foreign::{Block, ChannelMap, ForeignRecord, RecordSpeed};
use oilfilm_msgs::{DaqFrame, Header, RigStatus, BEARING_FRAME_ID};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::{Calibration, ChannelId};

use crate::daq::DaqParams;
use crate::error::NodeError;
use crate::stamp::Stamp;

/// A foreign record as DAQ frames and rig status.
pub struct ForeignSource {
    record: ForeignRecord,
    block_scans: usize,
    epoch: Stamp,
    rig_name: String,
    calibration: Calibration,
    /// The speed the status states when it is one number, and what the message says of it.
    speed: Option<(f64, String)>,
    names: Vec<String>,
    units: Vec<String>,
    f3: Option<usize>,
    temperature: Option<usize>,
    sequence: u64,
    block: Block,
}

impl ForeignSource {
    /// Opens `file` through the map `map_path` for `rig` (its calibration converts volts when
    /// the map mixes units); `params` gives `block_scans`, `speed_rpm`, `start_stamp_ns`.
    pub fn open(file: &Path, map_path: &Path, rig: &RigConfig, params: &DaqParams) -> Result<Self, NodeError> {
        let map = ChannelMap::load(map_path)?;
        Self::with_map(file, &map, rig, params)
    }

    pub fn with_map(file: &Path, map: &ChannelMap, rig: &RigConfig, params: &DaqParams) -> Result<Self, NodeError> {
        let calibration = rig.daq.calibration();
        let record = ForeignRecord::open(file, map, &calibration)?;
        let position = |c: ChannelId| record.channels.iter().position(|x| *x == c);
        let speed = if params.speed_rpm > 0.0 {
            Some((params.speed_rpm, "speed from the speed_rpm parameter".to_string()))
        } else {
            match &record.speed {
                RecordSpeed::Rpm { rpm, from } => Some((*rpm, format!("speed from {from}"))),
                RecordSpeed::Channel { .. } => None,
                RecordSpeed::RigFile => Some((rig.operating.speed_rpm, "speed not in the record: the rig file's speed assumed".to_string())),
            }
        };
        let epoch = if params.start_stamp_ns != 0 { Stamp(params.start_stamp_ns) } else { Stamp((record.start_time_s * 1e9).round() as i64) };
        Ok(Self {
            block_scans: params.block_scans.max(1) as usize,
            epoch,
            rig_name: rig.name.clone(),
            calibration,
            speed,
            names: record.channels.iter().map(|c| c.name().to_string()).collect(),
            units: record.channel_units().into_iter().map(str::to_string).collect(),
            f3: position(ChannelId::F3),
            temperature: position(ChannelId::Temperature),
            record,
            sequence: 0,
            block: Block::default(),
        })
    }

    pub fn record(&self) -> &ForeignRecord {
        &self.record
    }

    /// The speed every status states, rpm, when it is one number (a parameter, the map, the
    /// file or the rig file); `None` when each frame's status has its channel's mean.
    pub fn stated_speed_rpm(&self) -> Option<f64> {
        self.speed.as_ref().map(|(rpm, _)| *rpm)
    }

    /// Frames made so far.
    pub fn frames(&self) -> u64 {
        self.sequence
    }

    /// The next frame and the status after it; `None` at the end of the record.
    pub fn next_frame(&mut self) -> Result<Option<(DaqFrame, RigStatus)>, NodeError> {
        let n = self.record.next_block(self.block_scans, &mut self.block)?;
        if n == 0 {
            return Ok(None);
        }
        let b = &self.block;
        let width = self.names.len();
        let rate = self.record.sample_rate_hz;
        let scan_stamp = |scan: u64| self.epoch.after_samples(i64::try_from(scan).unwrap_or(i64::MAX), rate);
        let volts = self.record.volts;
        let mean_si = |position: Option<usize>, channel: ChannelId| {
            let Some(p) = position else { return f64::NAN };
            // Every scan has `width` values and `p` < `width`.
            let sum: f64 =
                b.values.chunks_exact(width).map(|scan| if volts { self.calibration.to_si(channel, scan[p]).unwrap_or(f64::NAN) } else { scan[p] }).sum();
            sum / n as f64
        };
        let (speed_rpm, speed_note) = match &self.speed {
            Some((rpm, note)) => (*rpm, note.clone()),
            None => (b.speed_rpm.iter().sum::<f64>() / n as f64, "speed: the frame's mean of the record's speed channel".to_string()),
        };
        let frame = DaqFrame {
            header: Header { stamp: scan_stamp(b.first_scan).to_time(), frame_id: BEARING_FRAME_ID.into() },
            sequence: self.sequence,
            first_scan: b.first_scan,
            sample_rate_hz: rate,
            units: if volts { DaqFrame::UNITS_VOLTS } else { DaqFrame::UNITS_SI },
            channel_names: self.names.clone(),
            channel_units: self.units.clone(),
            channel_offsets_s: self.record.offsets_s.clone(),
            scan_count: n as u32,
            values: b.values.clone(),
            rig: self.rig_name.clone(),
            volts_per_count: Vec::new(),
            counts: Vec::new(),
        };
        let status = RigStatus {
            header: Header { stamp: scan_stamp(b.first_scan + n as u64).to_time(), frame_id: BEARING_FRAME_ID.into() },
            speed_rad_s: speed_rpm * std::f64::consts::PI / 30.0,
            static_load_n: mean_si(self.f3, ChannelId::F3).abs(),
            bearing_temperature_degc: mean_si(self.temperature, ChannelId::Temperature),
            state: RigStatus::STATE_RUNNING,
            message: format!("{} record {}; {speed_note}", self.record.format.name(), self.record.path.display()),
            // A file's reader waits for room in the node's queue: nothing is dropped.
            frames_dropped: 0,
        };
        self.sequence += 1;
        Ok(Some((frame, status)))
    }
}
