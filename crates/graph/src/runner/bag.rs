//! The bag runner: recorded DAQ frames and rig status (a bag's, decoded) through a fresh
//! conditioner and estimator node, as the replay graph runs them. With the chain the live
//! graph ran (its params file says; frames conditioned causally carry the flag
//! `chain=causal`) the estimates equal the live ones bit for bit: the very nodes take the
//! very messages in the order that matters (every status before the conditioned frames: the
//! estimator needs the speed first, and the speed does not change during a run).
//!
//! The ports here lend what is being read (an iterator over a bag's decoded messages)
//! instead of owning a topic, so a bag streams through the nodes without being held whole.

use oilfilm_msgs::{ConditionedFrame, DaqFrame, RigStatus};
use oilfilm_physics::config::RigConfig;

use super::memory::{Recording, EPOCH};
use crate::conditioner::{Conditioner, ConditionerParams, ConditionerPorts};
use crate::error::NodeError;
use crate::estimator::{Estimator, EstimatorParams, EstimatorPorts};
use crate::node::{Node, Start};
use crate::ports::memory::{Bus, Publisher};
use crate::ports::{Collect, Publish, Receive, Replay};
use crate::topics;

/// One recorded input of the re-analysis, in the order read.
#[derive(Debug, Clone, PartialEq)]
pub enum Input {
    Frame(DaqFrame),
    Status(RigStatus),
}

/// A node of the re-analysis on `rig` (whatever rig file its parameters name).
fn node<N: Node>(rig: &RigConfig, params: &N::Params) -> Result<N, NodeError> {
    let load = |_: &str| Ok(rig.clone());
    N::new(params, &Start { now: EPOCH, rig: &load, namespace: topics::NAMESPACE })
}

/// Recorded frames and status through a fresh conditioner and estimator: status first.
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
    let mut cond = node::<Conditioner>(rig, conditioner)?;
    let mut est = node::<Estimator>(rig, estimator)?;
    let (status, conditioned) = (Bus::<RigStatus>::new(), Bus::<ConditionedFrame>::new());
    let (status_in, mut recorded, estimator_in) = (status.subscriber(), conditioned.subscriber(), conditioned.subscriber());
    let frames = Frames { inputs: inputs.into_iter(), status: status.publisher() };
    cond.turn(EPOCH, &mut ConditionerPorts { frames: Box::new(frames), conditioned: Box::new(conditioned.publisher()) })?;
    let mut estimates = Collect::default();
    est.turn(EPOCH, &mut EstimatorPorts { conditioned: Box::new(estimator_in), status: Box::new(status_in), estimates: Box::new(&mut estimates) })?;
    Ok(Recording { conditioned: recorded.drain(), estimates: estimates.0, ..Recording::default() })
}

/// The frames of a stream of inputs, as a port; the status messages met on the way go to
/// the status topic.
struct Frames<I> {
    inputs: I,
    status: Publisher<RigStatus>,
}

impl<I: Iterator<Item = Input>> Receive<DaqFrame> for Frames<I> {
    fn receive(&mut self) -> Result<Option<DaqFrame>, NodeError> {
        for input in self.inputs.by_ref() {
            match input {
                Input::Frame(f) => return Ok(Some(f)),
                Input::Status(s) => self.status.publish(s)?,
            }
        }
        Ok(None)
    }
}

/// [`reanalyse`]'s estimates (bit for bit) with the rig status known before the frames
/// (e.g. read from a bag's status chunks first): the conditioner runs on the calling thread
/// as the frames arrive and hands each conditioned frame to the estimator on a thread of its
/// own, so the two overlap instead of taking turns. The same nodes take the same messages in
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
    let mut cond = node::<Conditioner>(rig, conditioner)?;
    // A few frames in flight: enough to ride over one window's estimate, little memory.
    let (tx, rx) = std::sync::mpsc::sync_channel::<ConditionedFrame>(16);
    std::thread::scope(|s| {
        let worker = s.spawn(move || -> Result<Vec<oilfilm_msgs::CoefficientEstimate>, NodeError> {
            // Made on its thread: the node keeps thread-local FFT tables (not `Send`). If it
            // cannot be made, the channel closes and the conditioner stops at its next frame.
            let mut est = node::<Estimator>(rig, estimator)?;
            let mut estimates = Collect::default();
            est.turn(
                EPOCH,
                &mut EstimatorPorts { conditioned: Box::new(Channel(rx)), status: Box::new(Replay::new(status)), estimates: Box::new(&mut estimates) },
            )?;
            Ok(estimates.0)
        });
        let mut ports = ConditionerPorts { frames: Box::new(Iter(frames.into_iter())), conditioned: Box::new(ChannelOut(tx)) };
        let conditioned = cond.turn(EPOCH, &mut ports);
        // Closing the channel ends the estimator's turn.
        drop(ports);
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

impl Receive<ConditionedFrame> for Channel {
    fn receive(&mut self) -> Result<Option<ConditionedFrame>, NodeError> {
        Ok(self.0.recv().ok())
    }
}

/// The conditioner's end of [`reanalyse_overlapped`]'s channel.
struct ChannelOut(std::sync::mpsc::SyncSender<ConditionedFrame>);

impl Publish<ConditionedFrame> for ChannelOut {
    fn publish(&mut self, message: ConditionedFrame) -> Result<(), NodeError> {
        self.0.send(message).map_err(|_| NodeError::Closed("the re-analysis estimator stopped taking frames".into()))
    }
}

/// Messages from an iterator, as a port (taken one at a time, as they are decoded).
struct Iter<I>(I);

impl<M, I: Iterator<Item = M>> Receive<M> for Iter<I> {
    fn receive(&mut self) -> Result<Option<M>, NodeError> {
        Ok(self.0.next())
    }
}

/// The parameters a bag's nodes ran with, from its `/parameter_events` (ADR 0026): for each
/// node, the parameters it declared when it started, with every change recorded before the
/// bag's first DAQ frame; and the changes recorded after it, which no single parameter set
/// can reproduce.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecordedParameters {
    /// Fully qualified node name -> its parameters (`use_sim_time` left out).
    pub nodes: Vec<(String, serde_json::Map<String, serde_json::Value>)>,
    /// `node: parameter` changed after the first DAQ frame.
    pub changed_later: Vec<String>,
}

impl RecordedParameters {
    /// The recorded parameters of the one node whose parameters are `P`'s (recognised by
    /// their names, so a renamed node is found too; with several, the one named `name`).
    /// `None` when the bag has no such node.
    pub fn of<P: crate::params::NodeParams>(&self, name: &str) -> Result<Option<(String, P)>, NodeError> {
        let names: Vec<&str> = P::specs().iter().map(|s| s.name).collect();
        let fits = |m: &serde_json::Map<String, serde_json::Value>| m.len() == names.len() && names.iter().all(|n| m.contains_key(*n));
        let candidates: Vec<&(String, serde_json::Map<String, serde_json::Value>)> = self.nodes.iter().filter(|(_, m)| fits(m)).collect();
        let chosen = match candidates.as_slice() {
            [] => return Ok(None),
            [one] => *one,
            several => match several.iter().find(|(n, _)| n.rsplit('/').next() == Some(name)) {
                Some(c) => *c,
                None => {
                    let all: Vec<&str> = several.iter().map(|(n, _)| n.as_str()).collect();
                    return Err(NodeError::parameter(
                        "(recorded parameters)",
                        format!("the bag holds several nodes of this kind ({}) and none is named `{name}`: give the parameters with --params", all.join(", ")),
                    ));
                }
            },
        };
        let p = crate::params::checked::<P>(&chosen.1).map_err(|e| NodeError::parameter("(recorded parameters)", format!("{}: {e}", chosen.0)))?;
        Ok(Some((chosen.0.clone(), p)))
    }
}

/// Folds `events` (log time, event), in log-time order, into the parameters in force at
/// `first_frame` (log time of the first DAQ frame; `None`: the end).
pub fn recorded_parameters(events: &[(u64, oilfilm_msgs::ParameterEvent)], first_frame: Option<u64>) -> RecordedParameters {
    let mut out = RecordedParameters::default();
    for (t, e) in events {
        let later = first_frame.is_some_and(|f| *t > f);
        let at = match out.nodes.iter().position(|(n, _)| *n == e.node) {
            Some(i) => i,
            None => {
                out.nodes.push((e.node.clone(), serde_json::Map::new()));
                out.nodes.len() - 1
            }
        };
        let declared = !e.new_parameters.is_empty();
        for p in e.new_parameters.iter().chain(&e.changed_parameters) {
            if p.name == crate::params::USE_SIM_TIME {
                continue;
            }
            let Some(v) = crate::params::from_ros_value(&p.value) else { continue };
            if later && !declared {
                if out.nodes[at].1.get(&p.name) != Some(&v) {
                    out.changed_later.push(format!("{}: {}", e.node, p.name));
                }
                continue;
            }
            out.nodes[at].1.insert(p.name.clone(), v);
        }
    }
    out
}

/// [`recorded_parameters`] of the bag at `dir` (an empty set when it has no
/// `/parameter_events`: bags recorded before the recorder kept them).
pub fn recorded_parameters_of(bag: &oilfilm_bag::Bag) -> Result<RecordedParameters, NodeError> {
    recorded_parameters_with(bag, oilfilm_bag::ReadOptions::STRICT)
}

/// [`recorded_parameters_of`] read with `options`: with `allow_partial`, from what is readable
/// (the shortfalls are the main read's to report, not this one's).
pub fn recorded_parameters_with(bag: &oilfilm_bag::Bag, options: oilfilm_bag::ReadOptions) -> Result<RecordedParameters, NodeError> {
    use oilfilm_msgs::RosMessage;
    let is_event = |_: &str, ty: &str| ty == oilfilm_msgs::ParameterEvent::TYPE_NAME;
    let (events, _): (Vec<(u64, oilfilm_msgs::ParameterEvent)>, _) =
        bag.read_topics_with(options, &is_event, &|m| m.decode::<oilfilm_msgs::ParameterEvent>().map(|e| (m.log_time, e)), 1, |s| s.collect())?;
    let is_frame = |_: &str, ty: &str| ty == DaqFrame::TYPE_NAME;
    let (first_frame, _): (Option<u64>, _) = bag.read_topics_with(options, &is_frame, &|m| Ok(m.log_time), 1, |s| s.next())?;
    Ok(recorded_parameters(&events, first_frame))
}
