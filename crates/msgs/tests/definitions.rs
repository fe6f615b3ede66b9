//! The .msg files in msgs/msg/ are the single source of truth: the Rust types' fields
//! (names, order, types) and constants must agree with them, and the bag schema text is
//! generated from them.

use std::path::PathBuf;

use oilfilm_msgs::cdr::RosMessage;
use oilfilm_msgs::spec::{parse_msg, SchemaNaming};
use oilfilm_msgs::{schema_text, Clock, CoefficientEstimate, ConditionedFrame, DaqFrame, ExciterCommand, Header, RigStatus, Time, MESSAGE_TYPES};

fn msg_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../msgs/msg")
}

fn check<T: RosMessage>() {
    let (pkg, ty) = T::TYPE_NAME.split_once("/msg/").expect("pkg/msg/Type");
    let text = if pkg == "oilfilm_msgs" {
        let path = msg_dir().join(format!("{ty}.msg"));
        let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert_eq!(text, T::DEFINITION, "{ty}: the embedded definition is stale");
        text
    } else {
        T::DEFINITION.to_string()
    };
    let spec = parse_msg(&text, pkg).unwrap_or_else(|e| panic!("{ty}.msg:{e}"));
    let from_msg: Vec<(String, String)> = spec.fields.iter().map(|f| (f.name.clone(), f.ty.clone())).collect();
    let from_rust: Vec<(String, String)> = T::fields().into_iter().map(|(n, t)| (n.to_string(), t)).collect();
    assert_eq!(from_rust, from_msg, "{ty}: Rust fields (left) differ from the .msg (right)");
    assert!(spec.fields.iter().all(|f| f.default.is_none()), "{ty}: defaults are not mirrored in Rust");
    let consts_msg: Vec<(&str, &str, &str)> = spec.constants.iter().map(|c| (c.name.as_str(), c.ty.as_str(), c.value.as_str())).collect();
    assert_eq!(T::CONSTANTS.to_vec(), consts_msg, "{ty}: constants (Rust left, .msg right)");
}

#[test]
fn rust_types_agree_with_the_msg_files() {
    check::<ExciterCommand>();
    check::<DaqFrame>();
    check::<ConditionedFrame>();
    check::<CoefficientEstimate>();
    check::<RigStatus>();
    check::<Header>();
    check::<Time>();
    check::<Clock>();
}

#[test]
fn every_msg_file_has_a_rust_type() {
    let mut files: Vec<String> = std::fs::read_dir(msg_dir())
        .expect("msgs/msg")
        .filter_map(|e| e.ok())
        .filter_map(|e| e.file_name().to_str()?.strip_suffix(".msg").map(|s| format!("oilfilm_msgs/msg/{s}")))
        .collect();
    files.sort();
    let mut ours: Vec<String> = MESSAGE_TYPES.iter().map(|s| s.to_string()).collect();
    ours.sort();
    assert_eq!(ours, files);
    let cmake = std::fs::read_to_string(msg_dir().join("../CMakeLists.txt")).expect("CMakeLists.txt");
    for t in MESSAGE_TYPES {
        let file = format!("\"msg/{}.msg\"", t.rsplit('/').next().unwrap_or(t));
        assert!(cmake.contains(&file), "CMakeLists.txt does not list {file}");
    }
}

#[test]
fn parser_reads_what_msg_files_may_hold() {
    let spec = parse_msg("# comment\nint32 a 5  # default\nstring<=8[] names\nFoo foo\nstring S=a # b\nuint8 K = 3 # c\n", "pkg").expect("parse");
    let f: Vec<(&str, &str)> = spec.fields.iter().map(|f| (f.name.as_str(), f.ty.as_str())).collect();
    assert_eq!(f, [("a", "int32"), ("names", "string<=8[]"), ("foo", "pkg/Foo")]);
    assert_eq!(spec.fields[0].default.as_deref(), Some("5"));
    assert_eq!(spec.constants[0].value, "a # b");
    assert_eq!(spec.constants[1].value, "3");
    assert!(parse_msg("float64\n", "pkg").is_err());
    assert_eq!(parse_msg("float64 Bad\n", "pkg").expect_err("upper case").line, 1);
}

const SEP: &str = "================================================================================";

/// The schema is the type's .msg text, then each dependency once (depth first, sorted),
/// each after a line of 80 `=` and `MSG: <type>`, as rosbag2 writes it.
#[test]
fn schema_text_layout() {
    assert_eq!(SEP.len(), 80);
    let time = Time::DEFINITION;
    let header = Header::DEFINITION;
    for t in [ExciterCommand::TYPE_NAME, DaqFrame::TYPE_NAME, ConditionedFrame::TYPE_NAME, RigStatus::TYPE_NAME] {
        let own = oilfilm_msgs::definition("oilfilm_msgs", t.rsplit('/').next().unwrap_or(t)).expect("ours");
        let want = format!("{own}\n{SEP}\nMSG: std_msgs/Header\n{header}\n{SEP}\nMSG: builtin_interfaces/Time\n{time}");
        assert_eq!(schema_text(t, SchemaNaming::AsWritten).expect("schema"), want, "{t}");
    }
    // CoefficientEstimate uses Time directly too: sorted, builtin_interfaces/Time comes
    // first, and std_msgs/Header's Time is not repeated.
    let want = format!("{}\n{SEP}\nMSG: builtin_interfaces/Time\n{time}\n{SEP}\nMSG: std_msgs/Header\n{header}", CoefficientEstimate::DEFINITION);
    assert_eq!(schema_text(CoefficientEstimate::TYPE_NAME, SchemaNaming::AsWritten).expect("schema"), want);
    let q = schema_text(CoefficientEstimate::TYPE_NAME, SchemaNaming::Qualified).expect("schema");
    assert!(q.contains(&format!("\n{SEP}\nMSG: builtin_interfaces/msg/Time\n")));
    assert!(q.contains(&format!("\n{SEP}\nMSG: std_msgs/msg/Header\n")));
    assert_eq!(q.matches(SEP).count(), 2);
    // Leaf types have no dependencies.
    assert_eq!(schema_text("builtin_interfaces/msg/Time", SchemaNaming::AsWritten).expect("schema"), time);
    assert!(schema_text("nope/msg/Nope", SchemaNaming::AsWritten).is_err());
}
