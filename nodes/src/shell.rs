//! The node binaries' `main`s: parse the ROS arguments and typed parameters, build the core,
//! connect its ports to DDS and turn [`crate::poll`] until SIGINT/SIGTERM.

use std::sync::atomic::Ordering;
use std::time::Duration;

use oilfilm_identification::simulate::limits_of;
use oilfilm_physics::config::RigConfig;
use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::conditioner::{ConditionerCore, ConditionerParams};
use crate::daq::{DaqParams, SimDaqCore};
use crate::dds::{init_logging, shutdown_flag, RosNode};
use crate::error::NodeError;
use crate::estimator::{EstimatorCore, EstimatorParams};
use crate::exciter::{ExciterCore, ExciterParams};
use crate::params::{self, NodeArgs};
use crate::poll::{self, ConditionerPorts, DaqPorts, EstimatorPorts, ExciterPorts, Pace, SimDaqState};
use crate::ports::Publish;
use crate::stamp::Stamp;
use crate::topics;

/// Idle wait of a loop turn that found nothing to do.
const IDLE: Duration = Duration::from_micros(500);

/// The rig file a `rig` parameter names (empty: the built-in Zhou et al. rig).
pub fn load_rig(path: &str) -> Result<RigConfig, NodeError> {
    if path.is_empty() {
        return Ok(RigConfig::zhou2004()?);
    }
    let text = std::fs::read_to_string(path).map_err(|e| NodeError::File { file: path.into(), reason: e.to_string() })?;
    Ok(RigConfig::from_toml_str(&text, path)?)
}

fn setup<P: DeserializeOwned + Serialize + Default>(name: &str) -> Result<(NodeArgs, P, serde_json::Map<String, serde_json::Value>), NodeError> {
    init_logging();
    let args = params::parse_args(name, std::env::args().skip(1))?;
    let (p, map) = params::load::<P>(&args)?;
    tracing::info!(node = %args.fully_qualified_name(), domain = crate::dds::domain_id()?, "starting");
    Ok((args, p, map))
}

pub fn exciter_main() -> Result<(), NodeError> {
    let (args, p, map) = setup::<ExciterParams>("exciter")?;
    let rig = load_rig(&p.rig)?;
    let hard = limits_of(&rig);
    let mut core = ExciterCore::new(hard, &p)?;
    let validate = Box::new(move |m: &serde_json::Map<String, serde_json::Value>| {
        let p: ExciterParams = params::typed(m).map_err(|e| e.to_string())?;
        p.validate(&hard).map_err(|e| e.to_string())
    });
    let mut ros = RosNode::new(&args, &map, validate)?;
    let mut requests = ros.subscription(&topics::EXCITER_REQUEST)?;
    let mut status = ros.subscription(&topics::RIG_STATUS)?;
    let mut commands = ros.publisher(&topics::EXCITER_COMMAND)?;
    let stop = shutdown_flag()?;
    while !stop.load(Ordering::SeqCst) {
        if let Some(m) = ros.parameter_change() {
            match params::typed::<ExciterParams>(&m).and_then(|p| core.set_params(&p)) {
                Ok(()) => tracing::info!("parameters changed: plan {:?}, limit {} N", core.plan().exciters, core.limits().max_force_n),
                Err(e) => tracing::warn!("parameter change not applied: {e}"),
            }
        }
        let turn = poll::exciter(&mut core, &mut ExciterPorts { requests: &mut requests, status: &mut status, commands: &mut commands }, Stamp::now())?;
        if turn.handled == 0 {
            std::thread::sleep(IDLE);
        }
    }
    // Safe stop: ramp both exciters to zero and hold.
    if let Some(cmd) = core.shutdown(Stamp::now()) {
        tracing::info!("stopping: ramp to zero over {} setpoints", cmd.force_1_n.len());
        commands.publish(cmd)?;
        std::thread::sleep(Duration::from_millis(200));
    }
    // Entities go before their participant, or DDS cannot remove them cleanly.
    drop((requests, status, commands));
    ros.shutdown();
    Ok(())
}

/// Accepts the values the node started with (ros2-client validates declarations too) and
/// refuses any change.
fn read_only(node: &'static str, initial: serde_json::Map<String, serde_json::Value>) -> crate::dds::Validator {
    Box::new(move |m| {
        if *m == initial {
            Ok(())
        } else {
            Err(format!("the {node} node's parameters are read-only while it runs: restart it with new ones"))
        }
    })
}

pub fn daq_main() -> Result<(), NodeError> {
    let (args, p, map) = setup::<DaqParams>("daq")?;
    p.validate()?;
    let rig = load_rig(&p.rig)?;
    let epoch = if p.start_stamp_ns != 0 { Stamp(p.start_stamp_ns) } else { Stamp::now() };
    let mut core = SimDaqCore::new(&rig, &p, epoch)?;
    let mut ros = RosNode::new(&args, &map, read_only("daq", map.clone()))?;
    let mut commands = ros.subscription(&topics::EXCITER_COMMAND)?;
    let mut frames = ros.publisher(&topics::DAQ_FRAMES)?;
    let mut status = ros.publisher(&topics::RIG_STATUS)?;
    let stop = shutdown_flag()?;
    let pace = Pace { rate_factor: p.rate_factor, wall_start: Stamp::now(), command_timeout_s: p.command_timeout_s, duration_s: p.duration_s };
    let mut state = SimDaqState::default();
    while !stop.load(Ordering::SeqCst) {
        let turn = poll::sim_daq(&mut core, &mut state, &mut DaqPorts { commands: &mut commands, frames: &mut frames, status: &mut status }, &pace, Stamp::now())?;
        if turn.finished {
            tracing::info!("duration reached: {} s of rig time", p.duration_s);
            // Give reliable readers a moment to take the last frames.
            std::thread::sleep(Duration::from_millis(500));
            break;
        }
        if turn.handled == 0 {
            std::thread::sleep(IDLE);
        }
    }
    drop((commands, frames, status));
    ros.shutdown();
    Ok(())
}

pub fn conditioner_main() -> Result<(), NodeError> {
    let (args, p, map) = setup::<ConditionerParams>("conditioner")?;
    let rig = load_rig(&p.rig)?;
    let mut core = ConditionerCore::new(rig, &p)?;
    let mut ros = RosNode::new(&args, &map, read_only("conditioner", map.clone()))?;
    let mut frames = ros.subscription(&topics::DAQ_FRAMES)?;
    let mut conditioned = ros.publisher(&topics::CONDITIONED)?;
    let stop = shutdown_flag()?;
    while !stop.load(Ordering::SeqCst) {
        let turn = poll::conditioner(&mut core, &mut ConditionerPorts { frames: &mut frames, conditioned: &mut conditioned })?;
        if turn.handled == 0 {
            std::thread::sleep(IDLE);
        }
    }
    drop((frames, conditioned));
    ros.shutdown();
    Ok(())
}

pub fn estimator_main() -> Result<(), NodeError> {
    let (args, p, map) = setup::<EstimatorParams>("estimator")?;
    let rig = load_rig(&p.rig)?;
    let mut core = EstimatorCore::new(rig, p)?;
    let validate = Box::new(|m: &serde_json::Map<String, serde_json::Value>| {
        let p: EstimatorParams = params::typed(m).map_err(|e| e.to_string())?;
        p.config(5000.0).map(|_| ()).map_err(|e| e.to_string())
    });
    let mut ros = RosNode::new(&args, &map, validate)?;
    let mut conditioned = ros.subscription(&topics::CONDITIONED)?;
    let mut status = ros.subscription(&topics::RIG_STATUS)?;
    let mut estimates = ros.publisher(&topics::ESTIMATES)?;
    let stop = shutdown_flag()?;
    while !stop.load(Ordering::SeqCst) {
        if let Some(m) = ros.parameter_change() {
            match params::typed::<EstimatorParams>(&m).and_then(|p| core.set_params(p)) {
                Ok(()) => tracing::info!("parameters changed: window {}, hop {}", core.params().window, core.params().hop),
                Err(e) => tracing::warn!("parameter change not applied: {e}"),
            }
        }
        let turn = poll::estimator(&mut core, &mut EstimatorPorts { conditioned: &mut conditioned, status: &mut status, estimates: &mut estimates })?;
        if turn.handled == 0 {
            std::thread::sleep(IDLE);
        }
    }
    drop((conditioned, status, estimates));
    ros.shutdown();
    Ok(())
}
