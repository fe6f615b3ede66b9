//! Writes a bag of a short `sim_rig` run, for the interop tests:
//!
//!     write_sim_rig DIR [SECONDS [zstd|lz4|none [SPLIT_SECONDS]]]
//!
//! writes the bag directory DIR (zstd chunks by default; one file, or a new file every
//! SPLIT_SECONDS of log time) and DIR.expected.yaml next to it:
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
    let compression = match args.next().as_deref() {
        None | Some("zstd") => oilfilm_bag::Compression::Zstd,
        Some("lz4") => oilfilm_bag::Compression::Lz4,
        Some("none") => oilfilm_bag::Compression::None,
        Some(other) => anyhow::bail!("compression `{other}`: zstd, lz4 or none"),
    };
    let split_s: Option<f64> = args.next().map(|s| s.parse()).transpose()?;
    let rec = sim_rig::short_run(seconds);
    let msgs = sim_rig::published(&rec);
    let w = sim_rig::write_bag(
        &dir,
        &msgs,
        oilfilm_bag::WriterOptions { compression, split_duration_ns: split_s.map(|s| (s * 1e9) as u64), ..Default::default() },
    )?;
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
