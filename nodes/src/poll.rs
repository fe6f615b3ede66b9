//! One turn of each node: take what is waiting on its input ports, run the core, publish.
//! The DDS shell ([`crate::dds`]) calls these in a loop; tests call them directly.
//!
//! A message the core cannot use is logged (with its topic, sequence number and reason) and
//! skipped: the node keeps running. Only a failing output port is an error.

use oilfilm_msgs::{CoefficientEstimate, ConditionedFrame, DaqFrame, ExciterCommand, RigStatus};

use crate::conditioner::ConditionerCore;
use crate::daq::SimDaqCore;
use crate::error::NodeError;
use crate::estimator::EstimatorCore;
use crate::exciter::ExciterCore;
use crate::ports::{Publish, Receive};
use crate::stamp::Stamp;

/// What one turn did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Turn {
    /// Messages taken plus messages published.
    pub handled: usize,
    /// The node has nothing more to do (a DAQ at the end of its duration or file).
    pub finished: bool,
}

/// Skipped input: logged as a warning, counted.
fn skipped(node: &str, e: &NodeError) {
    tracing::warn!(node, "skipped: {e}");
}

pub struct ExciterPorts<'a> {
    pub requests: &'a mut dyn Receive<ExciterCommand>,
    pub status: &'a mut dyn Receive<RigStatus>,
    pub commands: &'a mut dyn Publish<ExciterCommand>,
}

/// Requests first (a new plan applies from the next setpoint), then the newest rig time.
pub fn exciter(core: &mut ExciterCore, ports: &mut ExciterPorts) -> Result<Turn, NodeError> {
    let mut turn = Turn::default();
    while let Some(req) = ports.requests.receive()? {
        turn.handled += 1;
        match core.request(&req) {
            Ok(()) => tracing::info!(node = "exciter", "request {} accepted{}", req.sequence, if req.stop { ": stopping" } else { "" }),
            Err(e) => skipped("exciter", &e),
        }
    }
    let mut rig_time = None;
    while let Some(status) = ports.status.receive()? {
        turn.handled += 1;
        rig_time = Some(Stamp::from_time(&status.header.stamp));
    }
    if let Some(t) = rig_time {
        if let Some(cmd) = core.on_rig_time(t) {
            ports.commands.publish(cmd)?;
            turn.handled += 1;
        }
    }
    Ok(turn)
}

pub struct DaqPorts<'a> {
    pub commands: &'a mut dyn Receive<ExciterCommand>,
    pub frames: &'a mut dyn Publish<DaqFrame>,
    pub status: &'a mut dyn Publish<RigStatus>,
}

/// Pacing of a simulated DAQ.
#[derive(Debug, Clone, Copy)]
pub struct Pace {
    /// 1 = real time, 0 = as fast as the setpoints come.
    pub rate_factor: f64,
    /// Wall time the run started.
    pub wall_start: Stamp,
    /// Wall time to wait for setpoints before running a block with the force held.
    pub command_timeout_s: f64,
    /// Stop after this much rig time (0: never).
    pub duration_s: f64,
}

/// State of the simulated DAQ's shell between turns.
#[derive(Debug, Default)]
pub struct SimDaqState {
    status_sent: bool,
    waiting_since: Option<Stamp>,
}

/// Takes setpoints, then runs the next block when it is due (by the pace) and its setpoints
/// are there (or the wait timed out).
pub fn sim_daq(core: &mut SimDaqCore, state: &mut SimDaqState, ports: &mut DaqPorts, pace: &Pace, wall: Stamp) -> Result<Turn, NodeError> {
    let mut turn = Turn::default();
    while let Some(cmd) = ports.commands.receive()? {
        turn.handled += 1;
        if let Err(e) = core.command(&cmd) {
            skipped("daq", &e);
        }
    }
    if !state.status_sent {
        ports.status.publish(core.status())?;
        state.status_sent = true;
        turn.handled += 1;
    }
    let epoch_elapsed_s = core.now().seconds_since(core_epoch(core));
    if pace.duration_s > 0.0 && epoch_elapsed_s >= pace.duration_s - 0.5 / core.sample_rate_hz() {
        turn.finished = true;
        return Ok(turn);
    }
    let block_end_s = core.next_block_end().seconds_since(core_epoch(core));
    if pace.rate_factor > 0.0 && block_end_s > wall.seconds_since(pace.wall_start) * pace.rate_factor {
        return Ok(turn);
    }
    if !core.ready() {
        let since = *state.waiting_since.get_or_insert(wall);
        if wall.seconds_since(since) < pace.command_timeout_s {
            return Ok(turn);
        }
        tracing::warn!(node = "daq", "no exciter setpoints for the block ending at {:.3} s after {} s: running it with the force held", block_end_s, pace.command_timeout_s);
    }
    state.waiting_since = None;
    let frame = core.produce()?;
    ports.frames.publish(frame)?;
    ports.status.publish(core.status())?;
    turn.handled += 2;
    Ok(turn)
}

fn core_epoch(core: &SimDaqCore) -> Stamp {
    core.epoch()
}

pub struct ConditionerPorts<'a> {
    pub frames: &'a mut dyn Receive<DaqFrame>,
    pub conditioned: &'a mut dyn Publish<ConditionedFrame>,
}

pub fn conditioner(core: &mut ConditionerCore, ports: &mut ConditionerPorts) -> Result<Turn, NodeError> {
    let mut turn = Turn::default();
    while let Some(frame) = ports.frames.receive()? {
        turn.handled += 1;
        match core.push(&frame) {
            Ok(out) => {
                for c in out {
                    ports.conditioned.publish(c)?;
                    turn.handled += 1;
                }
            }
            Err(e) => skipped("conditioner", &e),
        }
    }
    Ok(turn)
}

pub struct EstimatorPorts<'a> {
    pub conditioned: &'a mut dyn Receive<ConditionedFrame>,
    pub status: &'a mut dyn Receive<RigStatus>,
    pub estimates: &'a mut dyn Publish<CoefficientEstimate>,
}

pub fn estimator(core: &mut EstimatorCore, ports: &mut EstimatorPorts) -> Result<Turn, NodeError> {
    let mut turn = Turn::default();
    while let Some(status) = ports.status.receive()? {
        turn.handled += 1;
        core.rig_status(&status);
    }
    while let Some(frame) = ports.conditioned.receive()? {
        turn.handled += 1;
        match core.push(&frame) {
            Ok(out) => {
                for e in out {
                    if e.solved {
                        tracing::info!(node = "estimator", "window {}..{}: solved", e.window_start_sample, e.window_end_sample);
                    } else {
                        tracing::info!(node = "estimator", "window {}..{}: refused: {}", e.window_start_sample, e.window_end_sample, e.refusal_reason);
                    }
                    ports.estimates.publish(e)?;
                    turn.handled += 1;
                }
            }
            Err(e) => skipped("estimator", &e),
        }
    }
    Ok(turn)
}
