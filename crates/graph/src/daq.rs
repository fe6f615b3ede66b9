//! The DAQ node's core: frames of multiplexed scans from a source, with the rig's status.
//!
//! Sources: the simulated rig ([`SimDaqCore`]: the physics crate's rig and DAQ chain driven
//! by the exciter's setpoints), an ASCII record replayed and a live TCP stream in ASCII
//! format v1 ([`crate::replay`]). Every source publishes [`DaqFrame`]s of `block_scans`
//! scans, stamped on the rig's clock, and a [`RigStatus`] after each frame; the status
//! stamp is the rig clock "now" (the start of the next scan), which the exciter follows.

use std::collections::VecDeque;

use oilfilm_identification::simulate::limits_of;
use oilfilm_msgs::{Clock, DaqFrame, ExciterCommand, Header, RigStatus, BEARING_FRAME_ID};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::{Calibration, ChannelId, DaqScan};
use oilfilm_physics::rig::RigInput;
use oilfilm_physics::simulation::SimulatedRig;
use serde::{Deserialize, Serialize};

use crate::error::NodeError;
use crate::lines::LineDaq;
use crate::node::{skipped, Connect, Input, Node, Output, Start, Turn};
use crate::params::{NodeParams, Rule, Spec};
use crate::ports::Publish;
use crate::stamp::Stamp;
use crate::topics;

/// The DAQ node's parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DaqParams {
    /// Rig file (TOML); empty: the built-in Zhou et al. (2004) rig.
    pub rig: String,
    /// `sim` (the simulated rig), `ascii` (replay `file`), `foreign` (replay `file`, a TDMS,
    /// .mat or CSV record, through the channel map `map`) or `tcp` (connect to `address`).
    pub source: String,
    /// Record to replay (sources `ascii` and `foreign`).
    pub file: String,
    /// Channel map (TOML) of the foreign record (source `foreign`; docs/manual/foreign-records.md).
    pub map: String,
    /// `host:port` of the acquisition process (source `tcp`).
    pub address: String,
    /// Scans per published frame.
    pub block_scans: i64,
    /// Pace: 1 = real time, 4 = four times faster, 0 = as fast as the consumers allow (sim)
    /// or as the file can be read (ascii). Not used by `tcp`: the acquisition sets the pace.
    pub rate_factor: f64,
    /// Stop after this many seconds of rig time (0: run until stopped or the file ends;
    /// not used by `tcp`).
    pub duration_s: f64,
    /// Rig time of scan 0, ns since the epoch (0: the wall clock at start for `sim`, the
    /// record's `start_time_s` header for `ascii` and `tcp`).
    pub start_stamp_ns: i64,
    /// Sim: how long to wait for exciter setpoints before running a block with zero force,
    /// s of wall time (the rig goes on turning when the exciter node is absent).
    pub command_timeout_s: f64,
    /// Shaft speed, rpm, stated in rig/status (sim: the rig file's when 0; replay: the
    /// file's `speed_rpm` header when 0).
    pub speed_rpm: f64,
}

impl Default for DaqParams {
    fn default() -> Self {
        Self {
            rig: String::new(),
            source: "sim".into(),
            file: String::new(),
            map: String::new(),
            address: String::new(),
            block_scans: 500,
            rate_factor: 1.0,
            duration_s: 0.0,
            start_stamp_ns: 0,
            command_timeout_s: 2.0,
            speed_rpm: 0.0,
        }
    }
}

impl NodeParams for DaqParams {
    fn specs() -> Vec<Spec> {
        vec![
            Spec::fixed("rig", "rig file (TOML): the simulated rig, or the calibration of the real one; empty: the built-in Zhou et al. (2004) rig", Rule::Any),
            Spec::fixed("source", "sim (the simulated rig, driven by exciter/command), ascii (replay the record `file`), foreign (replay the TDMS, .mat or CSV record `file` through the channel map `map`) or tcp (the acquisition process's stream at `address`)", Rule::OneOf(&["sim", "ascii", "foreign", "tcp"])),
            Spec::fixed("file", "record to replay: ASCII format v1 (source ascii), TDMS, .mat or CSV (source foreign)", Rule::Any).with_constraints("not empty for sources ascii and foreign"),
            Spec::fixed("map", "channel map (TOML) of the foreign record (source foreign; docs/manual/foreign-records.md)", Rule::Any).with_constraints("not empty for source foreign"),
            Spec::fixed("address", "host:port of the acquisition process (source tcp)", Rule::Any).with_constraints("host:port for source tcp"),
            Spec::fixed("block_scans", "scans per published frame", Rule::Integer { min: 1, max: 1_000_000 }),
            Spec::fixed("rate_factor", "pace: 1 real time (stamps are wall time), 4 four times faster and 0 as fast as the consumers allow (stamps are sim time, published on /clock); not used by tcp", Rule::number(0.0, 1e6)),
            Spec::fixed("duration_s", "stop after this many seconds of rig time; 0: run until stopped or the file ends (not used by tcp)", Rule::number(0.0, 1e9)),
            Spec::fixed("start_stamp_ns", "rig time of scan 0, ns since the epoch; 0: the clock when the rig starts (sim), the record's start_time_s (ascii, tcp)", Rule::Integer { min: 0, max: i64::MAX }),
            Spec::fixed("command_timeout_s", "sim: how long to wait for exciter setpoints before running a block with the force held, s of wall time (the first block waits at least 10 s, for discovery)", Rule::above(0.0, 86_400.0)),
            Spec::fixed("speed_rpm", "shaft speed stated in rig/status, rpm; 0: the rig file's (sim) or the record's speed_rpm header (ascii, tcp)", Rule::number(0.0, 1e6)),
        ]
    }

    fn validate(&self) -> Result<(), NodeError> {
        DaqParams::validate(self)
    }
}

impl DaqParams {
    pub fn validate(&self) -> Result<(), NodeError> {
        if !["sim", "ascii", "foreign", "tcp"].contains(&self.source.as_str()) {
            return Err(NodeError::parameter(
                "source",
                format!("`{}`: expected `sim`, `ascii` (replay `file`), `foreign` (replay `file` through `map`) or `tcp` (connect to `address`)", self.source),
            ));
        }
        if (self.source == "ascii" || self.source == "foreign") && self.file.is_empty() {
            return Err(NodeError::parameter("file", format!("source `{}` needs the record's path", self.source)));
        }
        if self.source == "foreign" && self.map.is_empty() {
            return Err(NodeError::parameter("map", "source `foreign` needs the record's channel map (TOML)"));
        }
        if self.source == "tcp" && self.address.is_empty() {
            return Err(NodeError::parameter("address", "source `tcp` needs host:port"));
        }
        if self.source == "tcp" && !self.address.rsplit_once(':').is_some_and(|(host, port)| !host.is_empty() && port.parse::<u16>().is_ok()) {
            return Err(NodeError::parameter("address", format!("`{}`: expected host:port", self.address)));
        }
        if !(1..=1_000_000).contains(&self.block_scans) {
            return Err(NodeError::parameter("block_scans", format!("must be in 1..=1000000, got {}", self.block_scans)));
        }
        if !(self.rate_factor.is_finite() && self.rate_factor >= 0.0) {
            return Err(NodeError::parameter("rate_factor", format!("must be finite and >= 0, got {}", self.rate_factor)));
        }
        if !(self.duration_s.is_finite() && self.duration_s >= 0.0) {
            return Err(NodeError::parameter("duration_s", format!("must be finite and >= 0, got {}", self.duration_s)));
        }
        if !(self.command_timeout_s.is_finite() && self.command_timeout_s > 0.0) {
            return Err(NodeError::parameter("command_timeout_s", format!("must be finite and > 0, got {}", self.command_timeout_s)));
        }
        if !(self.speed_rpm.is_finite() && self.speed_rpm >= 0.0) {
            return Err(NodeError::parameter("speed_rpm", format!("must be finite and >= 0, got {}", self.speed_rpm)));
        }
        Ok(())
    }
}

/// Exciter setpoints on the rig clock, zero-order hold.
#[derive(Debug, Default, Clone)]
pub struct Setpoints {
    /// (time, [f1, f2]) in increasing time.
    points: VecDeque<(Stamp, [f64; 2])>,
    /// Setpoints are known up to (excluding) this time.
    covered_until: Option<Stamp>,
    /// The clamp applied to every setpoint (the exciters' hard limit).
    max_force_n: f64,
}

impl Setpoints {
    pub fn new(max_force_n: f64) -> Self {
        Self { points: VecDeque::new(), covered_until: None, max_force_n }
    }

    /// Takes a command's setpoints; later commands overwrite the future of earlier ones.
    pub fn accept(&mut self, cmd: &ExciterCommand) -> Result<(), NodeError> {
        let bad = |reason: String| NodeError::BadMessage { topic: crate::topics::EXCITER_COMMAND.name.into(), sequence: cmd.sequence, reason };
        let rate = cmd.setpoint_rate_hz;
        if cmd.force_1_n.len() != cmd.force_2_n.len() {
            return Err(bad(format!("force_1_n has {} setpoints, force_2_n {}", cmd.force_1_n.len(), cmd.force_2_n.len())));
        }
        if cmd.force_1_n.is_empty() {
            return Ok(());
        }
        if !(rate.is_finite() && rate > 0.0) {
            return Err(bad(format!("setpoint_rate_hz must be finite and > 0, got {rate}")));
        }
        let first = Stamp::from_time(&cmd.header.stamp);
        while self.points.back().is_some_and(|(t, _)| *t >= first) {
            self.points.pop_back();
        }
        let max = self.max_force_n;
        let clamp = |v: f64| if v.is_finite() { v.clamp(-max, max) } else { 0.0 };
        for (k, (a, b)) in cmd.force_1_n.iter().zip(&cmd.force_2_n).enumerate() {
            self.points.push_back((first.after_samples(k as i64, rate), [clamp(*a), clamp(*b)]));
        }
        let end = first.after_samples(cmd.force_1_n.len() as i64, rate);
        self.covered_until = Some(if cmd.stop {
            // A stop holds its last (zero) setpoint for ever.
            Stamp(i64::MAX)
        } else {
            end
        });
        Ok(())
    }

    /// True when setpoints are known up to `t` (inclusive).
    pub fn covers(&self, t: Stamp) -> bool {
        self.covered_until.is_some_and(|c| c > t)
    }

    /// The force at `t`: the last setpoint at or before `t`, zero before the first. Drops
    /// setpoints that no later time can need.
    pub fn at(&mut self, t: Stamp) -> [f64; 2] {
        while self.points.len() >= 2 && self.points[1].0 <= t {
            self.points.pop_front();
        }
        match self.points.front() {
            Some((s, f)) if *s <= t => *f,
            _ => [0.0; 2],
        }
    }
}

/// The ADC's volts per count when its codes fit `int16` (a card of up to 16 bits): its frames
/// then carry the codes (UNITS_COUNTS), as a card's driver delivers them; volts otherwise.
fn counts_lsb(cal: &Calibration) -> Option<f64> {
    (cal.adc_bits() <= 16).then(|| cal.lsb_v())
}

/// Scans simulated offline (`oilfilm_identification::simulate`) as the DAQ node publishes
/// them: frames of `block` scans stamped from `epoch` on, the rig's channels in scan order with
/// their multiplex offsets, then `aux_k` channels reading 0 V up to `channels` (a card with
/// more inputs than the rig uses), and the ADC's counts when they are lossless (a card of up
/// to 16 bits), volts otherwise. For benchmarks and profiles that need the node's frames
/// without running the node.
pub fn frames_of_scans(rig: &RigConfig, scans: &[DaqScan], block: usize, channels: usize, epoch: Stamp) -> Result<Vec<DaqFrame>, NodeError> {
    let cal = rig.daq.calibration();
    let order = cal.scan_order();
    let mut names: Vec<String> = order.iter().map(|c| c.name().to_string()).collect();
    let mut offsets: Vec<f64> = order.iter().map(|&c| cal.sample_offset_s(c)).collect::<Result<_, _>>()?;
    for k in names.len()..channels {
        names.push(format!("aux_{k}"));
        offsets.push(k as f64 * rig.daq.channel_interval_s);
    }
    let width = names.len();
    let rate = rig.daq.sample_rate_hz;
    let lsb = counts_lsb(&cal).map(|lsb| vec![lsb; width]);
    Ok(scans
        .chunks(block.max(1))
        .enumerate()
        .map(|(k, scans)| {
            let first_scan = (k * block.max(1)) as u64;
            let mut values = Vec::with_capacity(scans.len() * width);
            for s in scans {
                values.extend_from_slice(&s.volts);
                values.extend(std::iter::repeat_n(0.0, width.saturating_sub(s.volts.len())));
            }
            let mut frame = DaqFrame {
                header: Header { stamp: epoch.after_samples(first_scan as i64, rate).to_time(), frame_id: BEARING_FRAME_ID.into() },
                sequence: k as u64,
                first_scan,
                sample_rate_hz: rate,
                units: DaqFrame::UNITS_VOLTS,
                channel_names: names.clone(),
                channel_units: vec!["V".into(); width],
                channel_offsets_s: offsets.clone(),
                scan_count: scans.len() as u32,
                values,
                rig: rig.name.clone(),
                ..Default::default()
            };
            if let Some(lsb) = &lsb {
                // The ADC's volts are code x LSB, so this holds for every frame of it.
                frame.pack_counts(lsb);
            }
            frame
        })
        .collect())
}

/// The simulated rig behind the DAQ node.
pub struct SimDaqCore {
    sim: SimulatedRig,
    rig_name: String,
    calibration: Calibration,
    channels: Vec<ChannelId>,
    offsets_s: Vec<f64>,
    rate_hz: f64,
    epoch: Stamp,
    block_scans: usize,
    next_scan: u64,
    sequence: u64,
    setpoints: Setpoints,
    speed_rad_s: f64,
    static_load_n: f64,
    temperature_c: f64,
    exciting: bool,
    /// Blocks run without (complete) setpoints.
    pub blocks_without_setpoints: u64,
    /// [`counts_lsb`] of the rig's ADC.
    volts_per_count: Option<f64>,
}

impl SimDaqCore {
    /// A rig at equilibrium with scan 0 at `epoch` (the rig file's seed makes it
    /// reproducible).
    pub fn new(rig: &RigConfig, params: &DaqParams, epoch: Stamp) -> Result<Self, NodeError> {
        params.validate()?;
        let sim = SimulatedRig::new(rig, 0.0)?;
        let calibration = rig.daq.calibration();
        let channels = calibration.scan_order();
        let offsets_s = channels.iter().map(|&c| calibration.sample_offset_s(c)).collect::<Result<Vec<_>, _>>()?;
        let speed_rpm = if params.speed_rpm > 0.0 { params.speed_rpm } else { rig.operating.speed_rpm };
        // Before the first block: the bellows carry the film load plus the housing's weight.
        let bellows = rig.operating.bearing_load_n + rig.housing.mass_kg * rig.housing.gravity_m_s2;
        Ok(Self {
            rate_hz: rig.daq.sample_rate_hz,
            sim,
            rig_name: rig.name.clone(),
            channels,
            offsets_s,
            epoch,
            block_scans: params.block_scans as usize,
            next_scan: 0,
            sequence: 0,
            setpoints: Setpoints::new(limits_of(rig).max_force_n),
            speed_rad_s: speed_rpm * std::f64::consts::PI / 30.0,
            static_load_n: bellows,
            temperature_c: rig.operating.bearing_temperature_c,
            exciting: false,
            blocks_without_setpoints: 0,
            volts_per_count: counts_lsb(&calibration),
            calibration,
        })
    }

    pub fn sample_rate_hz(&self) -> f64 {
        self.rate_hz
    }

    /// The simulated film's operating point (the truth behind the record; no node reads it).
    pub fn operating_point(&self) -> &oilfilm_physics::operating_point::OperatingPoint {
        self.sim.operating_point()
    }

    /// Rig time of scan 0.
    pub fn epoch(&self) -> Stamp {
        self.epoch
    }

    /// Puts scan 0 at `epoch`, while no scan has run (later: nothing changes).
    pub fn start_at(&mut self, epoch: Stamp) {
        if self.next_scan == 0 {
            self.epoch = epoch;
        }
    }

    /// The rig clock now: the start of the next scan.
    pub fn now(&self) -> Stamp {
        self.epoch.after_samples(self.next_scan as i64, self.rate_hz)
    }

    /// Rig time at the end of the next block (the last force it needs).
    pub fn next_block_end(&self) -> Stamp {
        self.epoch.after_samples((self.next_scan + self.block_scans as u64) as i64, self.rate_hz)
    }

    /// Setpoints from the exciter.
    pub fn command(&mut self, cmd: &ExciterCommand) -> Result<(), NodeError> {
        self.setpoints.accept(cmd)
    }

    /// True when the exciter's setpoints cover the next block.
    pub fn ready(&self) -> bool {
        self.setpoints.covers(self.next_block_end())
    }

    /// Simulates the next block (forces held at their last setpoint where none is known,
    /// zero before the first) and returns its frame.
    pub fn produce(&mut self) -> Result<DaqFrame, NodeError> {
        if !self.ready() {
            self.blocks_without_setpoints += 1;
        }
        let first_scan = self.next_scan;
        let n = self.block_scans;
        let width = self.channels.len();
        let mut values = Vec::with_capacity(n * width);
        for i in 1..=n as u64 {
            let scan = first_scan + i;
            let at = self.epoch.after_samples(scan as i64, self.rate_hz);
            let input = RigInput { exciter_n: self.setpoints.at(at) };
            let s = self.sim.step(&input, scan as f64 * self.sim.period_s())?;
            values.extend_from_slice(&s.scan.volts);
            self.static_load_n = s.truth.bellows_n;
            self.temperature_c = s.truth.temperature_c;
            self.exciting = input.exciter_n.iter().any(|f| *f != 0.0);
        }
        self.next_scan += n as u64;
        let mut frame = DaqFrame {
            header: Header { stamp: self.epoch.after_samples(first_scan as i64, self.rate_hz).to_time(), frame_id: BEARING_FRAME_ID.into() },
            sequence: self.sequence,
            first_scan,
            sample_rate_hz: self.rate_hz,
            units: DaqFrame::UNITS_VOLTS,
            channel_names: self.channels.iter().map(|c| c.name().to_string()).collect(),
            channel_units: vec!["V".to_string(); width],
            channel_offsets_s: self.offsets_s.clone(),
            scan_count: n as u32,
            values,
            rig: self.rig_name.clone(),
            ..Default::default()
        };
        if let Some(lsb) = self.volts_per_count {
            // The ADC's volts are code x LSB and its codes fit int16: always lossless.
            frame.pack_counts(&vec![lsb; width]);
        }
        self.sequence += 1;
        Ok(frame)
    }

    /// The rig's status now.
    pub fn status(&self) -> RigStatus {
        RigStatus {
            header: Header { stamp: self.now().to_time(), frame_id: BEARING_FRAME_ID.into() },
            speed_rad_s: self.speed_rad_s,
            static_load_n: self.static_load_n,
            bearing_temperature_degc: self.temperature_c,
            state: if self.exciting { RigStatus::STATE_EXCITING } else { RigStatus::STATE_RUNNING },
            message: if self.blocks_without_setpoints > 0 {
                format!("simulated rig; {} block(s) ran without exciter setpoints (force held)", self.blocks_without_setpoints)
            } else {
                "simulated rig".to_string()
            },
            // The simulated rig makes its scans on the node's own turns: none can be dropped.
            frames_dropped: 0,
        }
    }

    pub fn calibration(&self) -> &Calibration {
        &self.calibration
    }
}

/// How long a DAQ waits for a subscriber of its frames before publishing anyway, s (frames
/// published before a subscriber is discovered are lost to it: the topic is volatile).
pub const READER_WAIT_S: f64 = 10.0;

/// How often a DAQ waiting for the exciter's setpoints says its status again, s. The exciter
/// answers a status, and one published before its subscription was matched is lost to it
/// (volatile topic): said once, a lost first status would hold the rig for the whole wait.
pub const STATUS_REPEAT_S: f64 = 0.25;

/// The DAQ node: the simulated rig driven by the exciter's setpoints, or a line source
/// (ASCII record, TCP stream), by its `source` parameter.
// One `Daq` a process, made once and never moved in a loop: the variants' sizes cost nothing.
#[allow(clippy::large_enum_variant)]
pub enum Daq {
    Sim(SimDaq),
    Lines(LineDaq),
}

pub struct DaqPorts<'a> {
    /// The exciter's setpoints (the simulated rig only: a line source does not subscribe).
    pub commands: Option<Input<'a, ExciterCommand>>,
    pub frames: Output<'a, DaqFrame>,
    pub status: Output<'a, RigStatus>,
}

impl Daq {
    /// The simulated rig, if that is the source.
    pub fn sim(&self) -> Option<&SimDaqCore> {
        match self {
            Daq::Sim(s) => Some(&s.core),
            Daq::Lines(_) => None,
        }
    }
}

impl Node for Daq {
    const NAME: &'static str = "daq";
    type Params = DaqParams;
    type Ports<'a> = DaqPorts<'a>;
    const CLOCK_SOURCE: Option<&'static str> =
        Some("the DAQ is the rig's clock: its stamps are wall time at rate_factor 1 and it publishes /clock when it runs faster or replays");

    /// Scan 0 of the simulated rig is at `start_stamp_ns`, or at `start.now` when 0.
    fn new(params: &DaqParams, start: &Start) -> Result<Self, NodeError> {
        params.validate()?;
        if params.source == "ascii" && std::path::Path::new(&params.file).is_dir() {
            return Err(NodeError::parameter(
                "file",
                format!(
                    "{} is a directory, not an ASCII record; a rosbag2 bag is re-estimated with `oilfilm launch launch_configs/replay_bag.launch.yaml bag:={}` (or offline: `oilfilm identify {}`)",
                    params.file, params.file, params.file
                ),
            ));
        }
        let rig = (start.rig)(&params.rig)?;
        if params.source == "sim" {
            let epoch = if params.start_stamp_ns != 0 { Stamp(params.start_stamp_ns) } else { start.now };
            Ok(Daq::Sim(SimDaq {
                core: SimDaqCore::new(&rig, params, epoch)?,
                params: params.clone(),
                reader_wait: None,
                wall_start: None,
                status_at: None,
                waiting_since: None,
            }))
        } else {
            Ok(Daq::Lines(LineDaq::new(params, &rig)?))
        }
    }

    /// The frames go out through a [`ClockTap`] when the stamps are not the wall clock's
    /// ([`publishes_clock`]), so `/clock` follows the rig time of the last frame.
    fn connect<C: Connect>(&self, c: &mut C) -> Result<DaqPorts<'static>, NodeError> {
        let (commands, params) = match self {
            Daq::Sim(s) => (Some(c.input(&topics::EXCITER_COMMAND)?), &s.params),
            Daq::Lines(l) => (None, l.params()),
        };
        let mut frames = c.output(&topics::DAQ_FRAMES)?;
        if publishes_clock(params) {
            frames = Box::new(ClockTap { frames, clock: c.output(&topics::CLOCK)? });
        }
        Ok(DaqPorts { commands, frames, status: c.output(&topics::RIG_STATUS)? })
    }

    fn turn(&mut self, now: Stamp, ports: &mut DaqPorts<'_>) -> Result<Turn, NodeError> {
        match self {
            Daq::Sim(s) => s.turn(now, ports),
            Daq::Lines(l) => l.turn(now, ports),
        }
    }

    fn finish(&mut self, _now: Stamp, ports: &mut DaqPorts<'_>) -> Result<(), NodeError> {
        match self {
            Daq::Sim(_) => Ok(()),
            Daq::Lines(l) => l.finish(ports),
        }
    }
}

/// Whether the DAQ's stamps are not the wall clock's, so it publishes them on `/clock` (the
/// ROS time source of nodes with `use_sim_time`): a simulated rig running faster or slower
/// than real time or from a given `start_stamp_ns`, and an ASCII replay (stamped with the
/// record's time). A simulated rig at `rate_factor` 1 is stamped with the wall clock, and a
/// TCP stream with the acquisition's clock: ROS time is the wall clock's there.
pub fn publishes_clock(p: &DaqParams) -> bool {
    match p.source.as_str() {
        "sim" => p.rate_factor != 1.0 || p.start_stamp_ns != 0,
        "ascii" => true,
        _ => false,
    }
}

/// The frames' port, publishing on `/clock`, after each frame, the rig time just after its
/// last scan (the time of the next scan).
struct ClockTap<'a> {
    frames: Output<'a, DaqFrame>,
    clock: Output<'a, Clock>,
}

impl Publish<DaqFrame> for ClockTap<'_> {
    fn publish(&mut self, frame: DaqFrame) -> Result<(), NodeError> {
        let end = (frame.sample_rate_hz > 0.0).then(|| Stamp::from_time(&frame.header.stamp).after_samples(i64::from(frame.scan_count), frame.sample_rate_hz));
        self.frames.publish(frame)?;
        if let Some(end) = end {
            self.clock.publish(Clock { clock: end.to_time() })?;
        }
        Ok(())
    }

    fn readers(&mut self) -> Option<usize> {
        self.frames.readers()
    }

    fn flush(&mut self, timeout: std::time::Duration) -> Result<bool, NodeError> {
        self.frames.flush(timeout)
    }
}

/// The simulated DAQ node: the core and its pacing on the runner's clock.
pub struct SimDaq {
    core: SimDaqCore,
    params: DaqParams,
    /// When the wait for a subscriber of the frames began.
    reader_wait: Option<Stamp>,
    /// The clock when the rig started running (after that wait): block `k` is due
    /// `k` blocks of rig time later, divided by `rate_factor`.
    wall_start: Option<Stamp>,
    /// When the last status went out (the runner's clock).
    status_at: Option<Stamp>,
    /// Since when the next block has waited for setpoints.
    waiting_since: Option<Stamp>,
}

/// `t` plus `s` seconds.
fn later(t: Stamp, s: f64) -> Stamp {
    Stamp(t.0.saturating_add((s * 1e9).ceil() as i64))
}

impl SimDaq {
    /// Takes setpoints, then runs the next block when it is due (by `rate_factor`: 0 = as
    /// soon as its setpoints are there) and its setpoints are there (or the wait for them
    /// timed out: the force is held).
    fn turn(&mut self, now: Stamp, ports: &mut DaqPorts<'_>) -> Result<Turn, NodeError> {
        let mut turn = Turn::default();
        if let Some(commands) = &mut ports.commands {
            while let Some(cmd) = commands.receive()? {
                turn.handled += 1;
                if let Err(e) = self.core.command(&cmd) {
                    skipped("daq", &e);
                }
            }
        }
        let wall_start = match self.wall_start {
            Some(w) => w,
            None => {
                let since = *self.reader_wait.get_or_insert(now);
                let readers = ports.frames.readers();
                if readers == Some(0) && now.seconds_since(since) < READER_WAIT_S {
                    return Ok(Turn { wake: Some(later(now, 0.02)), ..turn });
                }
                if readers == Some(0) {
                    tracing::warn!(node = "daq", "no subscriber on {} after {READER_WAIT_S} s: publishing anyway", topics::DAQ_FRAMES.name);
                }
                if self.params.start_stamp_ns == 0 {
                    // Scan 0 is now, not when the node was built: at rate_factor 1 a frame's
                    // stamps are then the wall clock's when it is published.
                    self.core.start_at(now);
                }
                *self.wall_start.insert(now)
            }
        };
        if self.status_at.is_none() {
            self.say_status(now, ports, &mut turn)?;
        }
        let p = &self.params;
        let epoch = self.core.epoch();
        let elapsed_s = self.core.now().seconds_since(epoch);
        if p.duration_s > 0.0 && elapsed_s >= p.duration_s - 0.5 / self.core.sample_rate_hz() {
            tracing::info!(node = "daq", "duration reached: {} s of rig time", p.duration_s);
            turn.finished = true;
            return Ok(turn);
        }
        let block_end_s = self.core.next_block_end().seconds_since(epoch);
        if p.rate_factor > 0.0 && block_end_s > now.seconds_since(wall_start) * p.rate_factor {
            return Ok(Turn { wake: Some(later(wall_start, block_end_s / p.rate_factor)), ..turn });
        }
        if !self.core.ready() {
            let since = *self.waiting_since.get_or_insert(now);
            // The first block's setpoints also wait on discovery (the exciter hears the rig
            // status published above, then its setpoints reach this node: seconds on a loaded
            // machine), so the first block waits as long as for a subscriber; later blocks
            // wait `command_timeout_s` for a running exciter.
            let timeout_s = if self.core.now() == epoch { p.command_timeout_s.max(READER_WAIT_S) } else { p.command_timeout_s };
            if now.seconds_since(since) < timeout_s {
                let said = self.status_at.unwrap_or(now);
                let said = if now.seconds_since(said) >= STATUS_REPEAT_S { self.say_status(now, ports, &mut turn)? } else { said };
                return Ok(Turn { wake: Some(later(since, timeout_s).min(later(said, STATUS_REPEAT_S))), ..turn });
            }
            tracing::warn!(
                node = "daq",
                "no exciter setpoints for the block ending at {:.3} s after {} s: running it with the force held",
                block_end_s,
                timeout_s
            );
        }
        self.waiting_since = None;
        let frame = self.core.produce()?;
        ports.frames.publish(frame)?;
        turn.handled += 1;
        self.say_status(now, ports, &mut turn)?;
        Ok(turn)
    }

    /// Publishes the rig's status now; returns when (the runner's clock).
    fn say_status(&mut self, now: Stamp, ports: &mut DaqPorts<'_>, turn: &mut Turn) -> Result<Stamp, NodeError> {
        ports.status.publish(self.core.status())?;
        self.status_at = Some(now);
        turn.handled += 1;
        Ok(now)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use oilfilm_identification::excitation::ExcitationPlan;
    use oilfilm_identification::simulate::{simulate, SimulateOptions};

    fn samples(f: &DaqFrame) -> Vec<f64> {
        let mut buf = Vec::new();
        f.samples(&mut buf).unwrap().to_vec()
    }

    #[test]
    fn frames_of_scans_are_the_scans_as_counts_with_aux_channels_at_zero() {
        let rig = RigConfig::zhou2004().unwrap();
        let rec = simulate(&rig, &ExcitationPlan::two_tone(23.0, 37.0, 100.0), 0.05, SimulateOptions::default(), &mut |_| {}).unwrap();
        let frames = frames_of_scans(&rig, &rec.scans, 100, 12, Stamp(0)).unwrap();
        assert_eq!(frames.iter().map(|f| f.scan_count).collect::<Vec<_>>(), [100, 100, 50]);
        assert_eq!(frames[2].first_scan, 200);
        assert_eq!(frames[1].header.stamp, Stamp(0).after_samples(100, rig.daq.sample_rate_hz).to_time());
        let mut scan = 0;
        for f in &frames {
            assert_eq!((f.units, f.values.len()), (DaqFrame::UNITS_COUNTS, 0));
            assert_eq!(&f.channel_names[10..], ["aux_10", "aux_11"]);
            for row in samples(f).chunks_exact(12) {
                assert_eq!(&row[..10], rec.scans[scan].volts.as_slice(), "scan {scan}: the ADC's volts exactly");
                assert_eq!(&row[10..], [0.0, 0.0]);
                scan += 1;
            }
        }
        assert_eq!(scan, rec.scans.len());
    }

    #[test]
    fn a_card_of_more_than_16_bits_sends_volts() {
        let mut rig = RigConfig::zhou2004().unwrap();
        rig.daq.adc_bits = 24;
        let rec = simulate(&rig, &ExcitationPlan::two_tone(23.0, 37.0, 100.0), 0.01, SimulateOptions::default(), &mut |_| {}).unwrap();
        let frames = frames_of_scans(&rig, &rec.scans, 25, 10, Stamp(0)).unwrap();
        assert!(frames.iter().all(|f| f.units == DaqFrame::UNITS_VOLTS && f.counts.is_empty() && f.volts_per_count.is_empty()));
        assert_eq!(samples(&frames[0])[..10], rec.scans[0].volts[..]);

        let params = DaqParams { block_scans: 50, ..DaqParams::default() };
        let mut core = SimDaqCore::new(&rig, &params, Stamp(0)).unwrap();
        let f = core.produce().unwrap();
        assert_eq!((f.units, f.values.len(), f.counts.len()), (DaqFrame::UNITS_VOLTS, 500, 0));
        rig.daq.adc_bits = 16;
        let mut core = SimDaqCore::new(&rig, &params, Stamp(0)).unwrap();
        let f = core.produce().unwrap();
        assert_eq!((f.units, f.values.len(), f.counts.len()), (DaqFrame::UNITS_COUNTS, 0, 500));
        assert_eq!(f.volts_per_count, vec![rig.daq.calibration().lsb_v(); 10]);
        f.check_samples().unwrap();
    }

    /// The exciter answers a status with setpoints, and a status published before its
    /// subscription is matched is lost to it. An exciter discovered after the DAQ's first
    /// status must still hear one soon, not when the first block's wait of 10 s has run out.
    #[test]
    fn a_rig_waiting_for_setpoints_says_its_status_again() {
        use crate::ports::memory::Bus;
        use crate::ports::Receive;
        let rig = RigConfig::zhou2004().unwrap();
        let load = |_: &str| Ok(rig.clone());
        let t0 = Stamp(1_700_000_000_000_000_000);
        let start = Start { now: t0, rig: &load, namespace: crate::topics::NAMESPACE };
        let params = DaqParams { block_scans: 500, rate_factor: 1.0, ..DaqParams::default() };
        let mut daq = Daq::new(&params, &start).unwrap();
        let (commands, frames, status) = (Bus::<ExciterCommand>::new(), Bus::<DaqFrame>::new(), Bus::<RigStatus>::new());
        let mut frames_tap = frames.subscriber();
        let mut ports =
            DaqPorts { commands: Some(Box::new(commands.subscriber())), frames: Box::new(frames.publisher()), status: Box::new(status.publisher()) };

        // The conditioner is there, the exciter not yet: the first status goes to nobody.
        let first = daq.turn(t0, &mut ports).unwrap();
        assert_eq!(first.handled, 1, "the first status is published at once");
        let mut wake = first.wake.expect("waits for setpoints");
        let late = later(t0, 0.6);
        let mut status_tap = status.subscriber();
        let mut heard = None;
        let mut now = t0;
        while heard.is_none() && now < later(t0, READER_WAIT_S) {
            now = wake.max(late);
            let turn = daq.turn(now, &mut ports).unwrap();
            wake = turn.wake.expect("still waiting for setpoints");
            assert!(wake > now, "wakes later, not in a loop");
            heard = status_tap.receive().unwrap().map(|s| (now, s));
        }
        let (at, said) = heard.expect("a subscriber that came after the first status hears one during the wait");
        assert!(at.seconds_since(late) <= STATUS_REPEAT_S, "heard {} s after it subscribed", at.seconds_since(late));
        assert_eq!(Stamp::from_time(&said.header.stamp), t0, "the rig clock has not run: no scan yet");
        assert!(frames_tap.receive().unwrap().is_none(), "no frame before the setpoints");

        // The exciter answers; the first block runs as soon as it is due.
        let rate = rig.daq.sample_rate_hz;
        let cmd = ExciterCommand {
            header: Header { stamp: t0.to_time(), ..Default::default() },
            setpoint_rate_hz: rate,
            force_1_n: vec![10.0; 2600],
            force_2_n: vec![-10.0; 2600],
            ..Default::default()
        };
        commands.publisher().publish(cmd).unwrap();
        let turn = daq.turn(now, &mut ports).unwrap();
        let frame = frames_tap.receive().unwrap().expect("the first block ran once its setpoints came");
        assert_eq!((frame.first_scan, Stamp::from_time(&frame.header.stamp)), (0, t0));
        assert_eq!(turn.handled, 3, "the command taken, a frame and a status published");
    }
}
