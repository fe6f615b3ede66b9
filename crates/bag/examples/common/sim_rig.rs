//! A short run of the in-memory `sim_rig` graph written to a bag: shared by the
//! `write_sim_rig` example and the crate's tests (included with `#[path]`).
#![allow(dead_code)]

use std::path::Path;

use oilfilm_bag::{BagWriter, QosProfile, TopicSpec, WriterOptions};
use oilfilm_graph::runner::memory::{run_sim_rig, GraphParams, Recording};
use oilfilm_graph::topics::{self, Topic};
use oilfilm_msgs::RosMessage;
use oilfilm_physics::config::RigConfig;

/// One message as published: its topic (qualified), type, log time (its header stamp), CDR
/// bytes and its value as YAML-able data.
#[derive(Debug, Clone)]
pub struct Published {
    pub topic: String,
    pub type_name: &'static str,
    pub log_time: u64,
    pub data: Vec<u8>,
    pub value: serde_yaml_ng::Value,
}

/// `duration_s` of the Zhou rig with the default two-tone plan, 5 kHz in blocks of 500
/// scans, estimates over 1 s windows every 0.5 s (so every topic carries messages).
pub fn short_run(duration_s: f64) -> Recording {
    let p = GraphParams::sim_rig(duration_s, 5_000, 2_500).expect("the shipped sim_rig launch file loads");
    // The crate's examples and tests run only with a rig the physics crate builds itself.
    let rig = RigConfig::zhou2004().expect("the built-in Zhou 2004 rig is valid");
    run_sim_rig(&rig, &p).expect("the short sim_rig run works").0
}

fn stamp_ns(h: &oilfilm_msgs::Header) -> u64 {
    (h.stamp.sec as i64 * 1_000_000_000 + h.stamp.nanosec as i64).max(0) as u64
}

fn entries<M: RosMessage + serde::Serialize>(topic: &Topic, msgs: &[M], header: impl Fn(&M) -> &oilfilm_msgs::Header) -> Vec<Published> {
    msgs.iter()
        .map(|m| Published {
            topic: topics::qualified(topics::NAMESPACE, topic),
            type_name: M::TYPE_NAME,
            log_time: stamp_ns(header(m)),
            data: oilfilm_msgs::encode(m),
            value: serde_yaml_ng::to_value(m).expect("our messages are plain data"),
        })
        .collect()
}

/// Every message of the recording in log-time order (stable: topic order among equal times).
pub fn published(rec: &Recording) -> Vec<Published> {
    let mut all = Vec::new();
    all.extend(entries(&topics::EXCITER_COMMAND, &rec.commands, |m| &m.header));
    all.extend(entries(&topics::DAQ_FRAMES, &rec.frames, |m| &m.header));
    all.extend(entries(&topics::RIG_STATUS, &rec.status, |m| &m.header));
    all.extend(entries(&topics::CONDITIONED, &rec.conditioned, |m| &m.header));
    all.extend(entries(&topics::ESTIMATES, &rec.estimates, |m| &m.header));
    all.sort_by_key(|p| p.log_time);
    all
}

/// The topic of the bag for one of the graph's topics, with its QoS.
pub fn topic_spec(t: &Topic) -> TopicSpec {
    let qos = QosProfile::keep_last(t.qos.depth as u32, t.qos.reliable, t.qos.transient_local);
    TopicSpec::ours(&topics::qualified(topics::NAMESPACE, t), t.type_name, vec![qos]).expect("our types have schema text")
}

/// Writes every topic of the graph (`exciter/request` stays empty) and `msgs` to `dir`.
pub fn write_bag(dir: &Path, msgs: &[Published], options: WriterOptions) -> oilfilm_bag::Result<BagWriter> {
    let mut w = BagWriter::create(dir, options)?;
    let mut ids = std::collections::BTreeMap::new();
    for t in topics::ALL {
        let spec = topic_spec(t);
        ids.insert(spec.name.clone(), w.add_topic(spec)?);
    }
    for m in msgs {
        w.write(ids[&m.topic], m.log_time, &m.data)?;
    }
    Ok(w)
}
