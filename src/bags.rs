//! Reading a rosbag2 bag of the node graph for `oilfilm identify BAG` and its benchmark.

use anyhow::{bail, Result};
use oilfilm_bag::{ReadOptions, Shortfall};
use oilfilm_graph::runner::bag::Input;
use oilfilm_physics::config::RigConfig;

/// Whether a bag topic is an input of the re-analysis: the DAQ frames and the rig status
/// (what else a bag holds, e.g. the conditioned frames, is neither read nor decoded).
fn is_input(_topic: &str, type_name: &str) -> bool {
    use oilfilm_msgs::RosMessage;
    type_name == oilfilm_msgs::DaqFrame::TYPE_NAME || type_name == oilfilm_msgs::RigStatus::TYPE_NAME
}

fn decode_input(m: &oilfilm_bag::MessageRef) -> oilfilm_bag::Result<Input> {
    use oilfilm_msgs::RosMessage;
    Ok(if m.type_name == oilfilm_msgs::DaqFrame::TYPE_NAME { Input::Frame(m.decode()?) } else { Input::Status(m.decode()?) })
}

/// Threads that decompress and decode a bag's chunks when nothing else runs: one per core.
pub fn reader_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Threads that decompress and decode a bag's chunks while this thread conditions the
/// frames: the other cores (at least one).
pub fn reader_threads_beside_analysis() -> usize {
    reader_threads().saturating_sub(1).max(1)
}

/// The DAQ frames and rig status of a bag, in log-time order: what `oilfilm identify BAG`
/// feeds the conditioner and estimator, all decoded first (tests and the benchmark's
/// read-only row; `identify --replay` streams them, [`reanalyse_bag`]). A strict read: a
/// bag that is damaged or differs from its `metadata.yaml` is an error.
pub fn read_bag_inputs(dir: &std::path::Path, threads: usize) -> Result<(Vec<oilfilm_msgs::DaqFrame>, Vec<oilfilm_msgs::RigStatus>)> {
    read_bag_inputs_with(dir, threads, ReadOptions::STRICT).map(|(f, s, _)| (f, s))
}

/// [`read_bag_inputs`] with `options`, and what a partial read could not deliver: the one
/// reading of a bag's inputs that `identify` and `diagnose` share (one reader, one set of
/// checks, so the same messages).
pub fn read_bag_inputs_with(
    dir: &std::path::Path,
    threads: usize,
    options: ReadOptions,
) -> Result<(Vec<oilfilm_msgs::DaqFrame>, Vec<oilfilm_msgs::RigStatus>, Vec<Shortfall>)> {
    let bag = oilfilm_bag::Bag::open(dir)?;
    let (mut frames, mut status) = (Vec::new(), Vec::new());
    let ((), shortfalls) = bag.read_topics_with(options, &is_input, &decode_input, threads, |inputs| {
        for i in inputs {
            match i {
                Input::Frame(f) => frames.push(f),
                Input::Status(s) => status.push(s),
            }
        }
    })?;
    if frames.is_empty() {
        bail!("{}: the bag holds no DAQ frames (topic {}); nothing to analyse", dir.display(), oilfilm_graph::topics::DAQ_FRAMES.name);
    }
    Ok((frames, status, shortfalls))
}

/// What a bag re-analysis produced: the estimates (the `Recording` holds nothing else), how
/// many frames and status messages went in, and what a partial read could not deliver.
pub struct Reanalysis {
    pub recording: oilfilm_graph::runner::memory::Recording,
    pub frames: usize,
    pub status: usize,
    pub shortfalls: Vec<Shortfall>,
}

/// A bag's DAQ frames and rig status through a fresh conditioner and estimator, with the
/// estimates of `runner::bag::reanalyse` bit for bit: the status first (its chunks are small and
/// the estimator takes every status before the frames, as the replay graph does), then the
/// frames, conditioned on this thread as worker threads read and decode the chunks after
/// them, each handed to the estimator on a thread of its own
/// (`runner::bag::reanalyse_overlapped`). Returns the estimates (the `Recording` holds nothing
/// else) and how many frames and status messages went in. A strict read.
pub fn reanalyse_bag(
    dir: &std::path::Path,
    rig: &RigConfig,
    conditioner: &oilfilm_graph::conditioner::ConditionerParams,
    estimator: &oilfilm_graph::estimator::EstimatorParams,
    threads: usize,
) -> Result<(oilfilm_graph::runner::memory::Recording, usize, usize)> {
    let r = reanalyse_bag_with(dir, rig, conditioner, estimator, threads, ReadOptions::STRICT)?;
    Ok((r.recording, r.frames, r.status))
}

/// [`reanalyse_bag`] with `options`.
pub fn reanalyse_bag_with(
    dir: &std::path::Path,
    rig: &RigConfig,
    conditioner: &oilfilm_graph::conditioner::ConditionerParams,
    estimator: &oilfilm_graph::estimator::EstimatorParams,
    threads: usize,
    options: ReadOptions,
) -> Result<Reanalysis> {
    use oilfilm_msgs::RosMessage;
    let bag = oilfilm_bag::Bag::open(dir)?;
    let is_status = |_: &str, type_name: &str| type_name == oilfilm_msgs::RigStatus::TYPE_NAME;
    let is_frame = |_: &str, type_name: &str| type_name == oilfilm_msgs::DaqFrame::TYPE_NAME;
    let (status, mut shortfalls): (Vec<oilfilm_msgs::RigStatus>, _) = bag.read_topics_with(options, &is_status, &|m| m.decode(), threads, |s| s.collect())?;
    let status_count = status.len();
    let mut frames = 0usize;
    let (out, more) = bag.read_topics_with(options, &is_frame, &|m| m.decode::<oilfilm_msgs::DaqFrame>(), threads, |inputs| {
        let counted = inputs.inspect(|_| frames += 1);
        oilfilm_graph::runner::bag::reanalyse_overlapped(rig, conditioner, estimator, status, counted)
    })?;
    let recording = out?;
    merge_shortfalls(&mut shortfalls, more);
    if frames == 0 {
        bail!("{}: the bag holds no DAQ frames (topic {}); nothing to identify", dir.display(), oilfilm_graph::topics::DAQ_FRAMES.name);
    }
    Ok(Reanalysis { recording, frames, status: status_count, shortfalls })
}

/// Adds `more` to `into`, each difference once (every read of a bag checks its directory).
pub fn merge_shortfalls(into: &mut Vec<Shortfall>, more: Vec<Shortfall>) {
    for s in more {
        if !into.contains(&s) {
            into.push(s);
        }
    }
}

/// Prints what a partial read could not deliver (nothing when it was complete).
pub fn print_shortfalls(name: &str, shortfalls: &[Shortfall]) {
    if shortfalls.is_empty() {
        return;
    }
    println!("PARTIAL: {name} was read with --allow-partial and is incomplete; these results leave out:");
    for s in shortfalls {
        println!("  - {s}");
    }
}

/// A bag's DAQ frames as one raw record on the frames' schedule, and the speed its rig
/// status states: what the batch identification (`oilfilm identify BAG`) reads, as it reads
/// an ASCII record.
pub struct BagRecord {
    pub raw: oilfilm_identification::record::RawRecord,
    /// Conversion offset of each of `raw`'s channels after its scan start (s).
    pub offsets_s: Vec<f64>,
    /// The first non-zero shaft speed of the rig status messages (rpm).
    pub speed_rpm: Option<f64>,
    /// Channels of the frames that are not the rig's ten (left out).
    pub ignored: Vec<String>,
    /// What a partial read could not deliver (empty after a strict read).
    pub shortfalls: Vec<Shortfall>,
    /// What was read: DAQ frames, their scans, rig status messages.
    pub read: BagRead,
}

/// How much of a bag a command analysed (in its JSON as `bag_read`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct BagRead {
    pub daq_frames: usize,
    pub scans: usize,
    pub rig_status: usize,
}

/// [`BagRecord`] of the bag at `dir`: its DAQ frames in order, which must be consecutive (a
/// gap is an error naming the frame) and share one channel layout, units and rate. What
/// `oilfilm identify BAG` and `oilfilm diagnose BAG` both analyse.
pub fn record_of_bag(dir: &std::path::Path, options: ReadOptions) -> Result<BagRecord> {
    use oilfilm_identification::record::{RawRecord, RawUnits};
    use oilfilm_physics::daq::ChannelId;
    let name = dir.display().to_string();
    let (frames, status, shortfalls) = read_bag_inputs_with(dir, reader_threads(), options)?;
    let first = &frames[0];
    let kept: Vec<(usize, ChannelId)> = first.channel_names.iter().enumerate().filter_map(|(k, c)| ChannelId::parse(c).ok().map(|id| (k, id))).collect();
    let ignored = first.channel_names.iter().filter(|c| ChannelId::parse(c).is_err()).cloned().collect();
    let width = first.channel_names.len();
    let mut columns = vec![Vec::new(); kept.len()];
    let (mut next_scan, mut decoded) = (first.first_scan, Vec::new());
    for (i, f) in frames.iter().enumerate() {
        if f.channel_names != first.channel_names
            || f.units != first.units
            || f.sample_rate_hz != first.sample_rate_hz
            || f.channel_offsets_s != first.channel_offsets_s
        {
            bail!("{name}: DAQ frame {i} (sequence {}) changes the channel layout, schedule, units or rate of frame 0", f.sequence);
        }
        if f.first_scan != next_scan {
            bail!("{name}: DAQ frame {i} (sequence {}) starts at scan {}, expected {next_scan}: the record has a gap", f.sequence, f.first_scan);
        }
        let samples = f.samples(&mut decoded).map_err(|reason| anyhow::anyhow!("{name}: DAQ frame {i} (sequence {}): {reason}", f.sequence))?;
        for scan in samples.chunks_exact(width) {
            for (c, &(k, _)) in columns.iter_mut().zip(&kept) {
                c.push(scan[k]);
            }
        }
        next_scan += u64::from(f.scan_count);
    }
    let raw = RawRecord {
        sample_rate_hz: first.sample_rate_hz,
        start_time_s: first.first_scan as f64 / first.sample_rate_hz,
        channels: kept.iter().map(|&(_, id)| id).collect(),
        units: if first.units == oilfilm_msgs::DaqFrame::UNITS_SI { RawUnits::Si } else { RawUnits::Volts },
        columns,
    };
    let offsets_s = kept.iter().map(|&(k, _)| first.channel_offsets_s.get(k).copied().unwrap_or(f64::NAN)).collect();
    let speed_rpm = status.iter().map(|s| s.speed_rad_s * 30.0 / std::f64::consts::PI).find(|&v| v > 0.0);
    let read = BagRead { daq_frames: frames.len(), scans: raw.columns.first().map_or(0, Vec::len), rig_status: status.len() };
    Ok(BagRecord { raw, offsets_s, speed_rpm, ignored, shortfalls, read })
}
