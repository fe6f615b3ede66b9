//! Reading a rosbag2 bag of the node graph for `oilfilm identify BAG` and its benchmark.

use anyhow::{bail, Result};
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
/// read-only row; `identify` streams them, [`reanalyse_bag`]).
pub fn read_bag_inputs(dir: &std::path::Path, threads: usize) -> Result<(Vec<oilfilm_msgs::DaqFrame>, Vec<oilfilm_msgs::RigStatus>)> {
    let bag = oilfilm_bag::Bag::open(dir)?;
    let (mut frames, mut status) = (Vec::new(), Vec::new());
    bag.read_topics(&is_input, &decode_input, threads, |inputs| {
        for i in inputs {
            match i {
                Input::Frame(f) => frames.push(f),
                Input::Status(s) => status.push(s),
            }
        }
    })?;
    if frames.is_empty() {
        bail!("{}: the bag holds no DAQ frames (topic {}); nothing to identify", dir.display(), oilfilm_graph::topics::DAQ_FRAMES.name);
    }
    Ok((frames, status))
}

/// A bag's DAQ frames and rig status through a fresh conditioner and estimator, with the
/// estimates of `runner::bag::reanalyse` bit for bit: the status first (its chunks are small and
/// the estimator takes every status before the frames, as the replay graph does), then the
/// frames, conditioned on this thread as worker threads read and decode the chunks after
/// them, each handed to the estimator on a thread of its own
/// (`runner::bag::reanalyse_overlapped`). Returns the estimates (the `Recording` holds nothing
/// else) and how many frames and status messages went in.
pub fn reanalyse_bag(
    dir: &std::path::Path,
    rig: &RigConfig,
    conditioner: &oilfilm_graph::conditioner::ConditionerParams,
    estimator: &oilfilm_graph::estimator::EstimatorParams,
    threads: usize,
) -> Result<(oilfilm_graph::runner::memory::Recording, usize, usize)> {
    use oilfilm_msgs::RosMessage;
    let bag = oilfilm_bag::Bag::open(dir)?;
    let is_status = |_: &str, type_name: &str| type_name == oilfilm_msgs::RigStatus::TYPE_NAME;
    let is_frame = |_: &str, type_name: &str| type_name == oilfilm_msgs::DaqFrame::TYPE_NAME;
    let status: Vec<oilfilm_msgs::RigStatus> = bag.read_topics(&is_status, &|m| m.decode(), threads, |s| s.collect())?;
    let status_count = status.len();
    let mut frames = 0usize;
    let out = bag.read_topics(&is_frame, &|m| m.decode::<oilfilm_msgs::DaqFrame>(), threads, |inputs| {
        let counted = inputs.inspect(|_| frames += 1);
        oilfilm_graph::runner::bag::reanalyse_overlapped(rig, conditioner, estimator, status, counted)
    })??;
    if frames == 0 {
        bail!("{}: the bag holds no DAQ frames (topic {}); nothing to identify", dir.display(), oilfilm_graph::topics::DAQ_FRAMES.name);
    }
    Ok((out, frames, status_count))
}
