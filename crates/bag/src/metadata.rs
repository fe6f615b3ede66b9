//! `metadata.yaml` of a rosbag2 bag and the QoS profiles in it: a pure model (no I/O) that
//! serialises to and parses from YAML text.
//!
//! We write version 9 (rosbag2 Jazzy's): rosbags 0.11 refuses versions above 9. In version
//! 9 a topic's `offered_qos_profiles` is a YAML list of profiles with lower-case names
//! (`keep_last`, `reliable`, ...); versions up to 8 store the same list as one YAML string
//! with numeric enums. We parse both. The MCAP channel metadata `offered_qos_profiles` is that
//! list as YAML text ([`qos_to_channel_metadata`]) and must describe the same profiles as
//! metadata.yaml, or rosbags silently matches no channel and returns no messages.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// The metadata.yaml version we write.
pub const METADATA_VERSION: u32 = 9;
/// The highest version we read (and rosbags 0.11 reads).
pub const MAX_METADATA_VERSION: u32 = 9;

/// The file as a whole: everything sits under `rosbag2_bagfile_information`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetadataFile {
    pub rosbag2_bagfile_information: BagInfo,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BagInfo {
    pub version: u32,
    pub storage_identifier: String,
    pub duration: Duration,
    pub starting_time: StartingTime,
    pub message_count: u64,
    pub topics_with_message_count: Vec<TopicWithCount>,
    #[serde(default)]
    pub compression_format: String,
    #[serde(default)]
    pub compression_mode: String,
    pub relative_file_paths: Vec<String>,
    #[serde(default)]
    pub files: Vec<FileInfo>,
    #[serde(default)]
    pub custom_data: Option<BTreeMap<String, String>>,
    #[serde(default)]
    pub ros_distro: String,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Duration {
    pub nanoseconds: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct StartingTime {
    pub nanoseconds_since_epoch: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TopicWithCount {
    pub topic_metadata: TopicMetadata,
    pub message_count: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TopicMetadata {
    pub name: String,
    #[serde(rename = "type")]
    pub type_name: String,
    pub serialization_format: String,
    #[serde(default, deserialize_with = "de_qos_list")]
    pub offered_qos_profiles: Vec<QosProfile>,
    /// RIHS01 hash of the type description (`RIHS01_` + 64 hex digits), as rosidl computes
    /// it; empty is "not known". rosbags' AnyReader checks a present one against the
    /// schema, so the writer fills it only when it can compute it.
    #[serde(default)]
    pub type_description_hash: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FileInfo {
    pub path: String,
    pub starting_time: StartingTime,
    pub duration: Duration,
    pub message_count: u64,
}

/// A ROS 2 QoS profile as rosbag2 stores it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct QosProfile {
    pub history: History,
    pub depth: u32,
    pub reliability: Reliability,
    pub durability: Durability,
    pub deadline: QosTime,
    pub lifespan: QosTime,
    pub liveliness: Liveliness,
    pub liveliness_lease_duration: QosTime,
    pub avoid_ros_namespace_conventions: bool,
}

/// A QoS duration. rosbag2 writes "infinite" as [`QosTime::INFINITE`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct QosTime {
    pub sec: i64,
    pub nsec: i64,
}

impl QosTime {
    /// `RMW_DURATION_INFINITE` split as rosbag2 writes it.
    pub const INFINITE: QosTime = QosTime { sec: 9_223_372_036, nsec: 854_775_807 };
}

impl QosProfile {
    /// Keep-last `depth`, reliable or best effort, transient-local or volatile, automatic
    /// liveliness, infinite deadline, lifespan and lease: what our nodes offer.
    pub fn keep_last(depth: u32, reliable: bool, transient_local: bool) -> Self {
        Self {
            history: History::KeepLast,
            depth,
            reliability: if reliable { Reliability::Reliable } else { Reliability::BestEffort },
            durability: if transient_local { Durability::TransientLocal } else { Durability::Volatile },
            deadline: QosTime::INFINITE,
            lifespan: QosTime::INFINITE,
            liveliness: Liveliness::Automatic,
            liveliness_lease_duration: QosTime::INFINITE,
            avoid_ros_namespace_conventions: false,
        }
    }
}

/// Declares a QoS enum stored by lower-case name (version 9) or by number (version <= 8).
macro_rules! qos_enum {
    ($name:ident { $($variant:ident = $num:literal as $text:literal),* $(,)? }) => {
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        pub enum $name { $($variant),* }

        impl $name {
            pub fn name(self) -> &'static str {
                match self { $(Self::$variant => $text),* }
            }
            pub fn from_number(n: i64) -> Option<Self> {
                match n { $($num => Some(Self::$variant),)* _ => None }
            }
            pub fn from_name(s: &str) -> Option<Self> {
                match s.to_ascii_lowercase().as_str() { $($text => Some(Self::$variant),)* _ => None }
            }
        }

        impl Serialize for $name {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_str(self.name())
            }
        }

        impl<'de> Deserialize<'de> for $name {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let v = serde_yaml_ng::Value::deserialize(d)?;
                let parsed = match &v {
                    serde_yaml_ng::Value::Number(n) => n.as_i64().and_then(Self::from_number),
                    serde_yaml_ng::Value::String(s) => Self::from_name(s),
                    _ => None,
                };
                parsed.ok_or_else(|| serde::de::Error::custom(format!(
                    "{}: `{}` is not a QoS {}", stringify!($name), serde_yaml_ng::to_string(&v).unwrap_or_default().trim(), stringify!($name).to_lowercase())))
            }
        }
    };
}

qos_enum!(History { SystemDefault = 0 as "system_default", KeepLast = 1 as "keep_last", KeepAll = 2 as "keep_all", Unknown = 3 as "unknown" });
qos_enum!(Reliability { SystemDefault = 0 as "system_default", Reliable = 1 as "reliable", BestEffort = 2 as "best_effort", Unknown = 3 as "unknown", BestAvailable = 4 as "best_available" });
qos_enum!(Durability { SystemDefault = 0 as "system_default", TransientLocal = 1 as "transient_local", Volatile = 2 as "volatile", Unknown = 3 as "unknown", BestAvailable = 4 as "best_available" });
qos_enum!(Liveliness { SystemDefault = 0 as "system_default", Automatic = 1 as "automatic", ManualByNode = 2 as "manual_by_node", ManualByTopic = 3 as "manual_by_topic", Unknown = 4 as "unknown", BestAvailable = 5 as "best_available" });

/// `offered_qos_profiles` is a list (version 9) or a YAML string holding the list (<= 8);
/// an empty string is no profiles.
fn de_qos_list<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<QosProfile>, D::Error> {
    let v = serde_yaml_ng::Value::deserialize(d)?;
    match v {
        serde_yaml_ng::Value::Null => Ok(Vec::new()),
        serde_yaml_ng::Value::String(s) => parse_qos_text(&s).map_err(serde::de::Error::custom),
        other => serde_yaml_ng::from_value(other).map_err(serde::de::Error::custom),
    }
}

/// The QoS list from YAML text (channel metadata, or a version <= 8 metadata.yaml).
pub fn parse_qos_text(text: &str) -> Result<Vec<QosProfile>, String> {
    if text.trim().is_empty() {
        return Ok(Vec::new());
    }
    serde_yaml_ng::from_str(text).map_err(|e| format!("offered_qos_profiles: {e}"))
}

/// The QoS list as the YAML text stored in MCAP channel metadata `offered_qos_profiles`.
pub fn qos_to_channel_metadata(profiles: &[QosProfile]) -> String {
    if profiles.is_empty() {
        return String::new();
    }
    // Serialising plain structs of numbers, bools and fixed names to YAML cannot fail.
    serde_yaml_ng::to_string(profiles).map(|s| s.trim_end().to_string()).unwrap_or_default()
}

impl BagInfo {
    /// The YAML of the fields alone (rosbag2's `serialized_metadata`).
    pub fn to_yaml(&self) -> String {
        // As MetadataFile::to_yaml: plain data, serialising cannot fail.
        serde_yaml_ng::to_string(self).unwrap_or_default()
    }
}

impl MetadataFile {
    pub fn to_yaml(&self) -> String {
        // Plain structs of strings, numbers and maps of strings: serialising cannot fail.
        serde_yaml_ng::to_string(self).unwrap_or_default()
    }

    /// Parses metadata.yaml text; refuses versions above [`MAX_METADATA_VERSION`] and
    /// storage other than MCAP.
    pub fn parse(text: &str) -> Result<Self, String> {
        let file: MetadataFile = serde_yaml_ng::from_str(text).map_err(|e| e.to_string())?;
        let info = &file.rosbag2_bagfile_information;
        if info.version > MAX_METADATA_VERSION {
            return Err(format!("version {} is newer than {MAX_METADATA_VERSION}, the newest this reader knows", info.version));
        }
        if info.storage_identifier != "mcap" {
            return Err(format!("storage `{}` is not mcap (sqlite3 bags are not read here)", info.storage_identifier));
        }
        if !info.compression_mode.is_empty() && !info.compression_mode.eq_ignore_ascii_case("none") {
            return Err(format!(
                "compression mode `{}` (whole-file or per-message compression) is not read here; MCAP chunk compression is",
                info.compression_mode
            ));
        }
        Ok(file)
    }
}

impl MetadataFile {
    /// The metadata of an MCAP bag of `files` (in order) holding `topics` (with their total
    /// message counts). Compression is inside the MCAP chunks, so format and mode are empty.
    pub fn for_mcap(topics: Vec<TopicWithCount>, files: Vec<FileInfo>, ros_distro: &str) -> Self {
        let start = files.iter().filter(|f| f.message_count > 0).map(|f| f.starting_time.nanoseconds_since_epoch).min();
        let end = files.iter().filter(|f| f.message_count > 0).map(|f| f.starting_time.nanoseconds_since_epoch.saturating_add(f.duration.nanoseconds)).max();
        let (start, duration) = match (start, end) {
            (Some(s), Some(e)) => (s, e.saturating_sub(s)),
            _ => (0, 0),
        };
        MetadataFile {
            rosbag2_bagfile_information: BagInfo {
                version: METADATA_VERSION,
                storage_identifier: "mcap".into(),
                duration: Duration { nanoseconds: duration },
                starting_time: StartingTime { nanoseconds_since_epoch: start },
                message_count: files.iter().map(|f| f.message_count).sum(),
                topics_with_message_count: topics,
                compression_format: String::new(),
                compression_mode: String::new(),
                relative_file_paths: files.iter().map(|f| f.path.clone()).collect(),
                files,
                custom_data: None,
                ros_distro: ros_distro.into(),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn qos_text_round_trips_and_uses_v9_names() {
        let q = vec![QosProfile::keep_last(200, true, false), QosProfile::keep_last(10, false, true)];
        let text = qos_to_channel_metadata(&q);
        assert!(text.contains("history: keep_last"), "{text}");
        assert!(text.contains("reliability: best_effort"), "{text}");
        assert!(text.contains("durability: transient_local"), "{text}");
        assert_eq!(parse_qos_text(&text).unwrap(), q);
    }

    #[test]
    fn numeric_v8_qos_parses() {
        let text = "- history: 1\n  depth: 5\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n  avoid_ros_namespace_conventions: false";
        let q = parse_qos_text(text).unwrap();
        assert_eq!(q[0].history, History::KeepLast);
        assert_eq!(q[0].durability, Durability::Volatile);
        assert_eq!(q[0].depth, 5);
    }

    #[test]
    fn newer_version_is_refused_by_name() {
        let text = "rosbag2_bagfile_information:\n  version: 10\n  storage_identifier: mcap\n  duration: {nanoseconds: 0}\n  starting_time: {nanoseconds_since_epoch: 0}\n  message_count: 0\n  topics_with_message_count: []\n  relative_file_paths: []\n";
        let e = MetadataFile::parse(text).unwrap_err();
        assert!(e.contains("version 10"), "{e}");
    }
}
