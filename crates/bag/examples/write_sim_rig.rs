//! Writes a bag of a short `sim_rig` run, for the interop tests:
//!
//!     write_sim_rig DIR [SECONDS]
//!
//! writes the bag directory DIR (zstd chunks, one file) and DIR.expected.yaml next to it:
//! every message in bag order as `{topic, type, log_time, value}`. YAML rather than JSON
//! because it carries NaN and infinities (refused estimates hold NaN), and Python reads it
//! with ruamel.yaml, which rosbags brings.

#[path = "common/sim_rig.rs"]
mod sim_rig;

use std::path::PathBuf;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let dir = PathBuf::from(args.next().ok_or_else(|| anyhow::anyhow!("usage: write_sim_rig DIR [SECONDS]"))?);
    let seconds: f64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(2.0);
    let rec = sim_rig::short_run(seconds);
    let msgs = sim_rig::published(&rec);
    let w = sim_rig::write_bag(&dir, &msgs, oilfilm_bag::WriterOptions::default())?;
    w.close()?;
    let expected: Vec<serde_yaml_ng::Value> = msgs
        .iter()
        .map(|m| {
            let mut map = serde_yaml_ng::Mapping::new();
            map.insert("topic".into(), m.topic.clone().into());
            map.insert("type".into(), m.type_name.into());
            map.insert("log_time".into(), m.log_time.into());
            map.insert("value".into(), m.value.clone());
            serde_yaml_ng::Value::Mapping(map)
        })
        .collect();
    let mut out = dir.clone().into_os_string();
    out.push(".expected.yaml");
    std::fs::write(&out, serde_yaml_ng::to_string(&expected)?)?;
    eprintln!("write_sim_rig: {} messages to {} and {}", msgs.len(), dir.display(), PathBuf::from(out).display());
    Ok(())
}
