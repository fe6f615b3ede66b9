//! The `sim_rig` graph in one process, on in-memory topics: the four node cores and their
//! polls exactly as the node binaries run them, turned round-robin until the DAQ finishes.
//! Tests, benchmarks and offline re-analysis use it; it is deterministic (no clock: the DAQ
//! runs as fast as the setpoints come).

use oilfilm_msgs::{CoefficientEstimate, ConditionedFrame, DaqFrame, ExciterCommand, RigStatus};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::operating_point::OperatingPoint;

use crate::conditioner::{ConditionerCore, ConditionerParams};
use crate::daq::{DaqParams, SimDaqCore};
use crate::error::NodeError;
use crate::estimator::{EstimatorCore, EstimatorParams};
use crate::exciter::{ExciterCore, ExciterParams};
use crate::poll::{self, ConditionerPorts, DaqPorts, EstimatorPorts, ExciterPorts, Pace, SimDaqState};
use crate::ports::memory::Bus;
use crate::ports::{Collect, Nothing, Replay};
use crate::stamp::Stamp;

/// Everything the graph published.
#[derive(Debug, Default, Clone)]
pub struct Recording {
    pub commands: Vec<ExciterCommand>,
    pub frames: Vec<DaqFrame>,
    pub status: Vec<RigStatus>,
    pub conditioned: Vec<ConditionedFrame>,
    pub estimates: Vec<CoefficientEstimate>,
}

/// The parameters of the four nodes.
#[derive(Debug, Clone, Default)]
pub struct GraphParams {
    pub exciter: ExciterParams,
    pub daq: DaqParams,
    pub conditioner: ConditionerParams,
    pub estimator: EstimatorParams,
}

impl GraphParams {
    /// The `sim_rig` graph as `launch_configs/params/sim_rig.yaml` sets it up (the default
    /// 23/37 Hz two-tone, 500-scan DAQ frames, the low-pass at 1.5 x 37 Hz, 1000-scan
    /// conditioned frames), run for `duration_s` of rig time from a fixed epoch, with
    /// estimator windows of `window` samples every `hop`. One difference: the conditioner keeps
    /// the node's default chain, `zero_phase`, where the file says `causal` (ADR 0014), because
    /// tests compare this graph with re-analyses whose params files do not name a chain; set
    /// `conditioner.chain` to run the launch file's.
    pub fn sim_rig(duration_s: f64, window: i64, hop: i64) -> Self {
        let mut p = Self::default();
        p.daq.duration_s = duration_s;
        p.daq.block_scans = 500;
        p.daq.start_stamp_ns = 1_700_000_000_000_000_000;
        p.conditioner.lowpass_cutoff_hz = 55.5;
        p.conditioner.block_scans = 1000;
        p.estimator.window = window;
        p.estimator.hop = hop;
        p.estimator.signal_band_hz = p.conditioner.lowpass_cutoff_hz;
        p
    }
}

/// Runs `sim_rig` for `params.daq.duration_s` of rig time (which must be > 0). Returns what
/// every topic carried and the simulated film's operating point (its linear coefficients are
/// the truth tests judge against; no node reads it).
pub fn run_sim_rig(rig: &RigConfig, params: &GraphParams) -> Result<(Recording, OperatingPoint), NodeError> {
    if params.daq.duration_s.is_nan() || params.daq.duration_s <= 0.0 {
        return Err(NodeError::parameter("duration_s", "the in-memory graph needs a finite run (> 0 s)"));
    }
    let hard = oilfilm_identification::simulate::limits_of(rig);
    let mut exciter = ExciterCore::new(hard, &params.exciter)?;
    let epoch = Stamp(if params.daq.start_stamp_ns != 0 { params.daq.start_stamp_ns } else { 1_700_000_000_000_000_000 });
    let mut daq = SimDaqCore::new(rig, &params.daq, epoch)?;
    let truth = *daq.operating_point();
    let mut conditioner = ConditionerCore::new(rig.clone(), &params.conditioner)?;
    let mut estimator = EstimatorCore::new(rig.clone(), params.estimator.clone())?;

    let (commands, frames, status, conditioned, estimates) =
        (Bus::<ExciterCommand>::new(), Bus::<DaqFrame>::new(), Bus::<RigStatus>::new(), Bus::<ConditionedFrame>::new(), Bus::<CoefficientEstimate>::new());
    let mut rec = (commands.subscriber(), frames.subscriber(), status.subscriber(), conditioned.subscriber(), estimates.subscriber());
    let (mut ex_status, mut ex_out) = (status.subscriber(), commands.publisher());
    let (mut daq_cmd, mut daq_frames, mut daq_status) = (commands.subscriber(), frames.publisher(), status.publisher());
    let (mut co_in, mut co_out) = (frames.subscriber(), conditioned.publisher());
    let (mut es_in, mut es_status, mut es_out) = (conditioned.subscriber(), status.subscriber(), estimates.publisher());
    let mut no_requests = Nothing;
    let pace = Pace { rate_factor: 0.0, wall_start: Stamp(0), command_timeout_s: f64::INFINITY, duration_s: params.daq.duration_s };
    let mut daq_state = SimDaqState::default();
    loop {
        let wall = Stamp(0);
        let d = poll::sim_daq(&mut daq, &mut daq_state, &mut DaqPorts { commands: &mut daq_cmd, frames: &mut daq_frames, status: &mut daq_status }, &pace, wall)?;
        let e = poll::exciter(&mut exciter, &mut ExciterPorts { requests: &mut no_requests, status: &mut ex_status, commands: &mut ex_out })?;
        let c = poll::conditioner(&mut conditioner, &mut ConditionerPorts { frames: &mut co_in, conditioned: &mut co_out })?;
        let s = poll::estimator(&mut estimator, &mut EstimatorPorts { conditioned: &mut es_in, status: &mut es_status, estimates: &mut es_out })?;
        if d.finished && e.handled + c.handled + s.handled == 0 {
            break;
        }
        if d.handled + e.handled + c.handled + s.handled == 0 {
            // The DAQ waits for setpoints and the exciter for the rig clock: cannot happen
            // with both present, but never spin for ever.
            return Err(NodeError::Closed("in-memory graph stalled".into()));
        }
    }
    let recording = Recording { commands: rec.0.drain(), frames: rec.1.drain(), status: rec.2.drain(), conditioned: rec.3.drain(), estimates: rec.4.drain() };
    Ok((recording, truth))
}

/// Offline re-analysis: recorded DAQ frames and rig status through a fresh conditioner and
/// estimator, as the `replay` graph runs them. `conditioner.chain` must be the chain the live
/// graph ran (its params file says; frames conditioned causally carry the flag
/// `chain=causal`): with it the replay equals the live graph bit for bit. Status messages are taken before the frames
/// (the estimator needs the speed first; the speed does not change during a run).
pub fn reanalyse(
    rig: &RigConfig,
    conditioner: &ConditionerParams,
    estimator: &EstimatorParams,
    frames: &[DaqFrame],
    status: &[RigStatus],
) -> Result<Recording, NodeError> {
    let inputs = status.iter().cloned().map(Input::Status).chain(frames.iter().cloned().map(Input::Frame));
    reanalyse_stream(rig, conditioner, estimator, inputs)
}

/// One recorded input of the re-analysis, in the order read.
#[derive(Debug, Clone, PartialEq)]
pub enum Input {
    Frame(DaqFrame),
    Status(RigStatus),
}

/// [`reanalyse`] on inputs as they arrive (e.g. decoded from a bag on other threads): each
/// frame goes through the conditioner when it comes, status messages are kept for the
/// estimator, which then takes all of them before the conditioned frames, as [`reanalyse`]
/// does. The result is [`reanalyse`]'s for the same frames and status, bit for bit.
pub fn reanalyse_stream(
    rig: &RigConfig,
    conditioner: &ConditionerParams,
    estimator: &EstimatorParams,
    inputs: impl IntoIterator<Item = Input>,
) -> Result<Recording, NodeError> {
    let mut cond = ConditionerCore::new(rig.clone(), conditioner)?;
    let mut est = EstimatorCore::new(rig.clone(), estimator.clone())?;
    let mut frames_in = Inputs { inputs: inputs.into_iter(), status: Vec::new() };
    let conditioned = Bus::<ConditionedFrame>::new();
    let (mut rec, mut es_in, mut co_out) = (conditioned.subscriber(), conditioned.subscriber(), conditioned.publisher());
    let mut estimates = Collect::default();
    poll::conditioner(&mut cond, &mut ConditionerPorts { frames: &mut frames_in, conditioned: &mut co_out })?;
    let mut status_in = Replay::new(frames_in.status);
    poll::estimator(&mut est, &mut EstimatorPorts { conditioned: &mut es_in, status: &mut status_in, estimates: &mut estimates })?;
    Ok(Recording { conditioned: rec.drain(), estimates: estimates.0, ..Recording::default() })
}

/// The frames of a stream of inputs, as a port; the status messages met on the way are kept.
struct Inputs<I> {
    inputs: I,
    status: Vec<RigStatus>,
}

impl<I: Iterator<Item = Input>> crate::ports::Receive<DaqFrame> for Inputs<I> {
    fn receive(&mut self) -> Result<Option<DaqFrame>, NodeError> {
        for input in self.inputs.by_ref() {
            match input {
                Input::Frame(f) => return Ok(Some(f)),
                Input::Status(s) => self.status.push(s),
            }
        }
        Ok(None)
    }
}

/// [`reanalyse`]'s estimates (bit for bit) with the rig status known before the frames
/// (e.g. read from a bag's status chunks first): the conditioner runs on the calling thread
/// as the frames arrive and hands each conditioned frame to the estimator on a thread of its
/// own, so the two overlap instead of taking turns. The same cores take the same messages in
/// the same order as in [`reanalyse`] (every status, then the conditioned frames in order),
/// so the estimates are the same. The conditioned frames are not kept (`Recording` holds
/// the estimates only): offline re-analysis wants the coefficients, and keeping a copy of
/// every conditioned frame cost as much as passing it on.
pub fn reanalyse_overlapped(
    rig: &RigConfig,
    conditioner: &ConditionerParams,
    estimator: &EstimatorParams,
    status: Vec<RigStatus>,
    frames: impl IntoIterator<Item = DaqFrame>,
) -> Result<Recording, NodeError> {
    let mut cond = ConditionerCore::new(rig.clone(), conditioner)?;
    // A few frames in flight: enough to ride over one window's estimate, little memory.
    let (tx, rx) = std::sync::mpsc::sync_channel::<ConditionedFrame>(16);
    let (rig, estimator) = (rig.clone(), estimator.clone());
    std::thread::scope(|s| {
        let worker = s.spawn(move || -> Result<Vec<CoefficientEstimate>, NodeError> {
            // Made on its thread: the core keeps thread-local FFT tables (not `Send`). If it
            // cannot be made, the channel closes and the conditioner stops at its next frame.
            let mut est = EstimatorCore::new(rig, estimator)?;
            let mut conditioned = Channel(rx);
            let mut status_in = Replay::new(status);
            let mut estimates = Collect::default();
            poll::estimator(&mut est, &mut EstimatorPorts { conditioned: &mut conditioned, status: &mut status_in, estimates: &mut estimates })?;
            Ok(estimates.0)
        });
        let mut frames_in = Frames(frames.into_iter());
        let mut out = ChannelOut(tx);
        let conditioned = poll::conditioner(&mut cond, &mut ConditionerPorts { frames: &mut frames_in, conditioned: &mut out });
        // Closing the channel ends the estimator's loop.
        drop(out);
        let estimates = match worker.join() {
            Ok(r) => r,
            Err(_) => Err(NodeError::Closed("the re-analysis estimator thread panicked".into())),
        };
        // The estimator's error first: the conditioner's would only say it stopped listening.
        let estimates = estimates?;
        conditioned?;
        Ok(Recording { estimates, ..Recording::default() })
    })
}

/// The estimator's end of [`reanalyse_overlapped`]'s channel: blocks for the next frame,
/// `None` once the conditioner has closed it.
struct Channel(std::sync::mpsc::Receiver<ConditionedFrame>);

impl crate::ports::Receive<ConditionedFrame> for Channel {
    fn receive(&mut self) -> Result<Option<ConditionedFrame>, NodeError> {
        Ok(self.0.recv().ok())
    }
}

/// The conditioner's end of [`reanalyse_overlapped`]'s channel.
struct ChannelOut(std::sync::mpsc::SyncSender<ConditionedFrame>);

impl crate::ports::Publish<ConditionedFrame> for ChannelOut {
    fn publish(&mut self, message: ConditionedFrame) -> Result<(), NodeError> {
        self.0.send(message).map_err(|_| NodeError::Closed("the re-analysis estimator stopped taking frames".into()))
    }
}

/// Frames from an iterator, as a port (taken one at a time, as they are decoded).
struct Frames<I>(I);

impl<I: Iterator<Item = DaqFrame>> crate::ports::Receive<DaqFrame> for Frames<I> {
    fn receive(&mut self) -> Result<Option<DaqFrame>, NodeError> {
        Ok(self.0.next())
    }
}
