//! Writes the bag fuzzer's seed bags, small valid bags as the recorder writes them, that
//! `tests/fuzz.rs` mutates (beside the bags it writes itself at its start):
//!
//!     write_fuzz_seeds DIR
//!
//! into `DIR/seed_plain` (uncompressed chunks, one file), `DIR/seed_split` (lz4 chunks, a new
//! file every 20 ms of log time) and `DIR/seed_zstd_every_type` (zstd chunks of every topic
//! the graph publishes and `/parameter_events`), none of which may exist. The messages are
//! the first of each topic of a 0.8 s run of the in-memory `sim_rig` graph (the nodes as
//! `oilfilm launch` runs them: DAQ frames of ADC counts, rig status, exciter setpoints,
//! conditioned frames and an estimate), so the seeds hold what a real recording holds; few
//! and short ones (frames and blocks of 100 scans, 50 ms of setpoints ahead, 0.2 s windows),
//! as a fuzz case copies and reads a whole bag. The committed seeds are
//! `crates/bag/tests/data/fuzz/`, written with
//!
//!     cargo run -p oilfilm-bag --example write_fuzz_seeds -- crates/bag/tests/data/fuzz

#[path = "common/sim_rig.rs"]
mod sim_rig;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Context;
use oilfilm_bag::{BagWriter, Compression, QosProfile, TopicSpec, WriterOptions};
use oilfilm_graph::runner::memory::{run_sim_rig, GraphParams};
use oilfilm_graph::topics;
use oilfilm_msgs::{Parameter, ParameterEvent, ParameterValue, RosMessage, Time};
use oilfilm_physics::config::RigConfig;

/// The first `cap` messages of each topic in `caps` (by its name under the namespace), in
/// log-time order.
fn first_of_each(msgs: &[sim_rig::Published], caps: &[(&topics::Topic, usize)]) -> Vec<sim_rig::Published> {
    let mut taken: BTreeMap<String, usize> = BTreeMap::new();
    msgs.iter()
        .filter(|m| {
            let Some(&(_, cap)) = caps.iter().find(|(t, _)| topics::qualified(topics::NAMESPACE, t) == m.topic) else { return false };
            let n = taken.entry(m.topic.clone()).or_default();
            *n += 1;
            *n <= cap
        })
        .cloned()
        .collect()
}

/// Writes `msgs` (and `events` on `/parameter_events`, when given) to a new bag `dir`.
fn write(dir: &Path, msgs: &[sim_rig::Published], events: &[(u64, ParameterEvent)], options: WriterOptions) -> anyhow::Result<()> {
    let mut w = BagWriter::create(dir, options)?;
    let mut ids = BTreeMap::new();
    for m in msgs {
        if !ids.contains_key(&m.topic) {
            let t = topics::ALL.iter().find(|t| topics::qualified(topics::NAMESPACE, t) == m.topic).context("a topic of the graph")?;
            ids.insert(m.topic.clone(), w.add_topic(sim_rig::topic_spec(t))?);
        }
    }
    let events_id = if events.is_empty() {
        None
    } else {
        let t = topics::PARAMETER_EVENTS;
        let qos = QosProfile::keep_last(t.qos.depth as u32, t.qos.reliable, t.qos.transient_local);
        Some(w.add_topic(TopicSpec::ours(t.name, ParameterEvent::TYPE_NAME, vec![qos]).map_err(anyhow::Error::msg)?)?)
    };
    // Log-time order across the topics, as a recorder receives them.
    let mut all: Vec<(u64, Option<&sim_rig::Published>, Option<&ParameterEvent>)> = msgs.iter().map(|m| (m.log_time, Some(m), None)).collect();
    all.extend(events.iter().map(|(t, e)| (*t, None, Some(e))));
    all.sort_by_key(|(t, _, _)| *t);
    for (t, m, e) in all {
        match (m, e, events_id) {
            (Some(m), _, _) => w.write(ids[&m.topic], t, &m.data)?,
            (None, Some(e), Some(id)) => w.write_message(id, t, e)?,
            _ => {}
        }
    }
    w.close()?;
    Ok(())
}

/// What the estimator announces when it starts, then a change of its hop.
fn parameter_events(at_ns: u64) -> Vec<(u64, ParameterEvent)> {
    let stamp = Time { sec: (at_ns / 1_000_000_000) as i32, nanosec: (at_ns % 1_000_000_000) as u32 };
    let int = |name: &str, v: i64| Parameter { name: name.into(), value: ParameterValue { r#type: 2, integer_value: v, ..Default::default() } };
    let declared = ParameterEvent {
        stamp: stamp.clone(),
        node: "/oilfilm/estimator".into(),
        new_parameters: vec![
            int("window", 5000),
            int("hop", 2500),
            Parameter { name: "model".into(), value: ParameterValue { r#type: 4, string_value: "kc".into(), ..Default::default() } },
            Parameter { name: "use_sim_time".into(), value: ParameterValue { r#type: 1, bool_value: false, ..Default::default() } },
        ],
        ..Default::default()
    };
    let changed = ParameterEvent { stamp, node: "/oilfilm/estimator".into(), changed_parameters: vec![int("hop", 5000)], ..Default::default() };
    vec![(at_ns, declared), (at_ns + 1, changed)]
}

fn main() -> anyhow::Result<()> {
    let Some(root) = std::env::args().nth(1).map(PathBuf::from) else {
        anyhow::bail!("usage: write_fuzz_seeds DIR");
    };
    let mut p = GraphParams::sim_rig(0.8, 1000, 1000)?;
    p.daq.block_scans = 100;
    p.conditioner.block_scans = 100;
    p.exciter.lookahead_s = 0.05;
    let (rec, _) = run_sim_rig(&RigConfig::zhou2004()?, &p).context("running the sim_rig graph")?;
    let msgs = sim_rig::published(&rec);
    let first_ns = msgs.first().map(|m| m.log_time).context("the run published nothing")?;
    let small = WriterOptions { chunk_size: 8 << 10, ..WriterOptions::default() };

    // Uncompressed: a few chunks of frames, status and setpoints.
    let plain = first_of_each(&msgs, &[(&topics::EXCITER_COMMAND, 2), (&topics::DAQ_FRAMES, 3), (&topics::RIG_STATUS, 3)]);
    write(&root.join("seed_plain"), &plain, &[], WriterOptions { compression: Compression::None, ..small.clone() })?;

    // Split: a file every 20 ms of log time, one frame and its status in each.
    let split = first_of_each(&msgs, &[(&topics::DAQ_FRAMES, 3), (&topics::RIG_STATUS, 3)]);
    write(&root.join("seed_split"), &split, &[], WriterOptions { compression: Compression::Lz4, split_duration_ns: Some(20_000_000), ..small.clone() })?;

    // zstd, every type: what a whole-graph recording holds, a few of each.
    let every = first_of_each(
        &msgs,
        &[(&topics::EXCITER_COMMAND, 2), (&topics::DAQ_FRAMES, 2), (&topics::RIG_STATUS, 2), (&topics::CONDITIONED, 1), (&topics::ESTIMATES, 1)],
    );
    write(&root.join("seed_zstd_every_type"), &every, &parameter_events(first_ns), WriterOptions { compression: Compression::Zstd, ..small })?;

    for name in ["seed_plain", "seed_split", "seed_zstd_every_type"] {
        let dir = root.join(name);
        let sizes: Vec<String> = std::fs::read_dir(&dir)?
            .filter_map(|e| e.ok())
            .filter_map(|e| Some(format!("{} {} B", e.file_name().to_string_lossy(), e.metadata().ok()?.len())))
            .collect();
        println!("{}: {}", dir.display(), sizes.join(", "));
    }
    Ok(())
}
