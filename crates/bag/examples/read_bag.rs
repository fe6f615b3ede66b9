//! Reads a bag with our reader and prints every message decoded, as YAML on stdout:
//!
//!     read_bag DIR
//!
//! a list of `{topic, type, log_time, value}` in the reader's order. The interop test feeds
//! it a bag written by rosbags and compares the values with what it wrote.

use oilfilm_bag::{Bag, OilfilmMessage};

fn main() -> anyhow::Result<()> {
    let dir = std::env::args().nth(1).ok_or_else(|| anyhow::anyhow!("usage: read_bag DIR"))?;
    let bag = Bag::open(&dir)?;
    let mut out = Vec::new();
    for m in bag.messages()? {
        let value = match m.decode_ours()? {
            OilfilmMessage::ExciterCommand(v) => serde_yaml_ng::to_value(v)?,
            OilfilmMessage::DaqFrame(v) => serde_yaml_ng::to_value(v)?,
            OilfilmMessage::ConditionedFrame(v) => serde_yaml_ng::to_value(v)?,
            OilfilmMessage::CoefficientEstimate(v) => serde_yaml_ng::to_value(v)?,
            OilfilmMessage::RigStatus(v) => serde_yaml_ng::to_value(v)?,
            OilfilmMessage::ParameterEvent(v) => serde_yaml_ng::to_value(v)?,
        };
        let mut map = serde_yaml_ng::Mapping::new();
        map.insert("topic".into(), m.topic.to_string().into());
        map.insert("type".into(), m.type_name.to_string().into());
        map.insert("log_time".into(), m.log_time.into());
        map.insert("value".into(), value);
        out.push(serde_yaml_ng::Value::Mapping(map));
    }
    print!("{}", serde_yaml_ng::to_string(&out)?);
    Ok(())
}
