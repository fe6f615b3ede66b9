//! RIHS01 type description hashes of our types, pinned.
//!
//! The expected values are not ours: they are the `type_hashes` that rosidl's own generator
//! (`rosidl_generator_type_description`, kilted, from PyPI) wrote into
//! `share/oilfilm_msgs/msg/*.json` when tests/interop/setup-ros-venv.sh built msgs/ with
//! the .msg files of this commit, and those of std_msgs/builtin_interfaces in that venv.
//! Editing a .msg changes its hash: regenerate with the interop build and update here.
//! (The bag interop test checks the same hashes with rosbags' independent implementation.)

use oilfilm_msgs::type_hash::{definitions_of_schema, hashable_json, type_hash};
use oilfilm_msgs::{definition, schema_text, spec::SchemaNaming, type_description_hash, MESSAGE_TYPES};

const ROSIDL: &[(&str, &str)] = &[
    ("builtin_interfaces/msg/Time", "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197"),
    ("std_msgs/msg/Header", "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01"),
    ("oilfilm_msgs/msg/ExciterCommand", "RIHS01_3f0168b421d1e2f74d09080d63e8122a131876379f54f12b3cf3474b403da50d"),
    ("oilfilm_msgs/msg/DaqFrame", "RIHS01_c585104ebcfacd42cf1edf9c7e0f8e30514a750d29ebc98c3ec9061ad3e29dcd"),
    ("oilfilm_msgs/msg/ConditionedFrame", "RIHS01_633b5d90c5b55cb9db92692e77cc0d9acf4fbf0abb6f9ace2856033bf3f0f6bf"),
    ("oilfilm_msgs/msg/CoefficientEstimate", "RIHS01_87439f95ec86f7e098f608d8472d186def30124d2281d58163d57711d7450643"),
    ("oilfilm_msgs/msg/RigStatus", "RIHS01_7bb35ce97b1bc57635b09d1a4a04c17c959cb7f22165786d9d5504fb0179fde1"),
    // The recorder's /parameter_events (rcl_interfaces' share/rcl_interfaces/msg/ParameterEvent.json).
    ("rcl_interfaces/msg/ParameterEvent", "RIHS01_043e627780fcad87a22d225bc2a037361dba713fca6a6b9f4b869a5aa0393204"),
    ("rcl_interfaces/msg/Parameter", "RIHS01_ddfe6442cffc462317adb5c92536a7b6dd55858c5c3e1e328165a6b73c2831af"),
    ("rcl_interfaces/msg/ParameterValue", "RIHS01_115fc089a387e23c7ecd3525c9189c379109119d6ab82e8dfbde0fdf6a7f9b68"),
];

#[test]
fn hashes_equal_rosidls() {
    for (ty, want) in ROSIDL {
        assert_eq!(type_description_hash(ty).as_deref(), Ok(*want), "{ty}");
    }
    for ty in MESSAGE_TYPES {
        assert!(ROSIDL.iter().any(|(t, _)| t == ty), "{ty} has no pinned hash");
    }
}

#[test]
fn the_hashed_json_has_rosidls_shape() {
    let json = hashable_json("builtin_interfaces/msg/Time", &definition).unwrap();
    assert_eq!(
        json,
        r#"{"type_description": {"type_name": "builtin_interfaces/msg/Time", "fields": [{"name": "sec", "type": {"type_id": 6, "capacity": 0, "string_capacity": 0, "nested_type_name": ""}}, {"name": "nanosec", "type": {"type_id": 7, "capacity": 0, "string_capacity": 0, "nested_type_name": ""}}]}, "referenced_type_descriptions": []}"#
    );
    // Header references Time (sorted references, nested name fully qualified).
    let json = hashable_json("std_msgs/Header", &definition).unwrap();
    assert!(json.contains(r#""nested_type_name": "builtin_interfaces/msg/Time""#), "{json}");
    assert!(json.ends_with(r#""referenced_type_descriptions": [{"type_name": "builtin_interfaces/msg/Time", "fields": [{"name": "sec", "type": {"type_id": 6, "capacity": 0, "string_capacity": 0, "nested_type_name": ""}}, {"name": "nanosec", "type": {"type_id": 7, "capacity": 0, "string_capacity": 0, "nested_type_name": ""}}]}]}"#), "{json}");
}

#[test]
fn array_sequence_and_string_kinds_get_their_ids() {
    let text = "float64[4] a\nfloat64[] b\nuint8[<=3] c\nstring<=8 d\nstring<=8[2] e\nbool[] f\nbyte g\nchar h\n";
    let lookup = |p: &str, t: &str| (p == "x" && t == "T").then_some(text);
    let json = hashable_json("x/msg/T", &lookup).unwrap();
    for (name, id, cap, scap) in
        [("a", 59, 4, 0), ("b", 155, 0, 0), ("c", 99, 3, 0), ("d", 21, 0, 8), ("e", 69, 2, 8), ("f", 159, 0, 0), ("g", 16, 0, 0), ("h", 3, 0, 0)]
    {
        let want = format!(r#"{{"name": "{name}", "type": {{"type_id": {id}, "capacity": {cap}, "string_capacity": {scap}, "nested_type_name": ""}}}}"#);
        assert!(json.contains(&want), "{name}: {want} not in {json}");
    }
    // A message with no fields gets rosidl's placeholder member.
    let empty = |_: &str, _: &str| Some("# only a comment\n");
    let json = hashable_json("x/msg/Empty", &empty).unwrap();
    assert!(json.contains(r#""name": "structure_needs_at_least_one_member", "type": {"type_id": 3"#), "{json}");
}

#[test]
fn the_hash_from_a_bag_schema_equals_the_hash_from_the_msg_files() {
    for ty in MESSAGE_TYPES {
        for naming in [SchemaNaming::Qualified, SchemaNaming::AsWritten] {
            let schema = schema_text(ty, naming).unwrap();
            let defs = definitions_of_schema(ty, &schema).unwrap();
            let lookup = |p: &str, t: &str| defs.get(&(p.to_string(), t.to_string())).map(String::as_str);
            assert_eq!(type_hash(ty, &lookup).unwrap(), type_description_hash(ty).unwrap(), "{ty} {naming:?}");
        }
    }
}

#[test]
fn a_missing_dependency_or_bad_type_is_an_error_naming_it() {
    let lookup = |p: &str, t: &str| (p == "x" && t == "T").then_some("y/U inner\n");
    let e = type_hash("x/msg/T", &lookup).unwrap_err();
    assert!(e.contains("y/msg/U"), "{e}");
    let e = type_hash("not a type", &definition).unwrap_err();
    assert!(e.contains("not a type"), "{e}");
    let lookup = |_: &str, _: &str| Some("float64[x] a\n");
    let e = type_hash("x/msg/T", &lookup).unwrap_err();
    assert!(e.contains("field a") && e.contains("`x` is not a size"), "{e}");
}

/// A `/parameter_events` message as our recorder keeps it: its CDR reads back the same,
/// nested sequences of parameters included.
#[test]
fn a_parameter_event_round_trips() {
    use oilfilm_msgs::{decode, encode, Parameter, ParameterEvent, ParameterValue, Time};
    let e = ParameterEvent {
        stamp: Time { sec: 17, nanosec: 5 },
        node: "/oilfilm/estimator".into(),
        new_parameters: vec![
            Parameter { name: "window".into(), value: ParameterValue { r#type: 2, integer_value: 25_000, ..Default::default() } },
            Parameter { name: "model".into(), value: ParameterValue { r#type: 4, string_value: "kc".into(), ..Default::default() } },
            Parameter { name: "topics".into(), value: ParameterValue { r#type: 9, string_array_value: vec!["a".into(), "b".into()], ..Default::default() } },
        ],
        changed_parameters: vec![Parameter { name: "use_sim_time".into(), value: ParameterValue { r#type: 1, bool_value: true, ..Default::default() } }],
        deleted_parameters: vec![],
    };
    assert_eq!(decode::<ParameterEvent>(&encode(&e)).unwrap(), e);
}
