//! Node parameters the ROS 2 way: `--ros-args` on the command line (`--params-file FILE`,
//! `-p name:=value`, `-r __node:=name`, `-r __ns:=/namespace`) and params files in ROS 2's
//! YAML format:
//!
//! ```yaml
//! /oilfilm/estimator:        # or `estimator`, or `/**` for every node
//!   ros__parameters:
//!     window: 50000
//! ```
//!
//! Values land in the node's typed parameter struct (serde, unknown names rejected), so a
//! misspelt parameter is an error naming the file and the name, never silently ignored.

use std::collections::HashMap;
use std::path::PathBuf;

use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::{Map, Value};

use crate::error::NodeError;

/// What values a parameter takes: its ROS 2 descriptor's range or allowed values, and the
/// check every value passes at load time (params file, `-p`) and at set time (the parameter
/// services), so a value that would leave the node useless is refused where it is given.
#[derive(Debug, Clone, PartialEq)]
pub enum Rule {
    /// Any value of the parameter's type (a path, an address).
    Any,
    /// An integer in `[min, max]`.
    Integer { min: i64, max: i64 },
    /// A finite number in `[min, max]`; `above_min`: strictly above `min`.
    Number { min: f64, max: f64, above_min: bool },
    /// One of these words.
    OneOf(&'static [&'static str]),
    /// A list whose every entry is one of these words, or empty.
    ListOf(&'static [&'static str]),
}

/// A range bound as a person reads it: `1e300`, not three hundred digits; `.inf` as YAML
/// and `ros2 param set` spell infinity.
fn bound(x: f64) -> String {
    if x.is_infinite() {
        if x > 0.0 { ".inf" } else { "-.inf" }.to_string()
    } else if x != 0.0 && !(1e-3..1e6).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        x.to_string()
    }
}

impl Rule {
    /// A number in `[min, max]`.
    pub const fn number(min: f64, max: f64) -> Self {
        Rule::Number { min, max, above_min: false }
    }

    /// A number in `(min, max]`.
    pub const fn above(min: f64, max: f64) -> Self {
        Rule::Number { min, max, above_min: true }
    }

    /// The rule in words, as a refusal and the descriptor's `additional_constraints` say it.
    pub fn describe(&self) -> String {
        match self {
            Rule::Any => String::new(),
            Rule::Integer { min, max } => format!("an integer in [{min}, {max}]"),
            Rule::Number { min, max, above_min: false } => format!("a number in [{}, {}]", bound(*min), bound(*max)),
            Rule::Number { min, max, above_min: true } => format!("a number above {}, at most {}", bound(*min), bound(*max)),
            Rule::OneOf(words) => format!("one of: {}", words.join(", ")),
            Rule::ListOf(words) => format!("a list of: {}", words.join(", ")),
        }
    }

    /// Checks one value; the error says the rule.
    pub fn check(&self, value: &Value) -> Result<(), String> {
        let fail = |got: &dyn std::fmt::Display| Err(format!("must be {}, got {got}", self.describe()));
        match (self, value) {
            (Rule::Any, _) => Ok(()),
            (Rule::Integer { min, max }, Value::Number(n)) => match n.as_i64() {
                Some(i) if (*min..=*max).contains(&i) => Ok(()),
                _ => fail(n),
            },
            (Rule::Number { min, max, above_min }, Value::Number(n)) => {
                let x = n.as_f64().unwrap_or(f64::NAN);
                let low_ok = if *above_min { x > *min } else { x >= *min };
                if low_ok && x <= *max {
                    Ok(())
                } else {
                    fail(n)
                }
            }
            // serde_json has no NaN: a NaN from the parameter services arrives as null.
            (Rule::Number { .. }, Value::Null) => fail(&"NaN"),
            (Rule::OneOf(words), Value::String(s)) if words.contains(&s.as_str()) => Ok(()),
            (Rule::OneOf(_), Value::String(s)) => fail(&format!("`{s}`")),
            (Rule::ListOf(words), Value::Array(items)) => match items.iter().find(|v| !v.as_str().is_some_and(|s| words.contains(&s))) {
                None => Ok(()),
                Some(bad) => fail(bad),
            },
            (_, other) => fail(other),
        }
    }
}

/// One parameter of a node, as its ROS 2 descriptor shows it (`ros2 param describe`).
#[derive(Debug, Clone, PartialEq)]
pub struct Spec {
    pub name: &'static str,
    /// What it is and what it does, unit included.
    pub description: &'static str,
    pub rule: Rule,
    /// Rules that involve other parameters or the rig file, in words (empty: none); checked
    /// by the node's [`NodeParams::validate`] and when it is built.
    pub constraints: &'static str,
    /// Fixed while the node runs (a set is refused: restart the node with the new value).
    pub read_only: bool,
}

impl Spec {
    /// A parameter that can change while the node runs.
    pub const fn live(name: &'static str, description: &'static str, rule: Rule) -> Self {
        Self { name, description, rule, constraints: "", read_only: false }
    }

    /// A parameter fixed while the node runs.
    pub const fn fixed(name: &'static str, description: &'static str, rule: Rule) -> Self {
        Self { name, description, rule, constraints: "", read_only: true }
    }

    /// With rules involving other parameters, in words.
    pub const fn with_constraints(mut self, constraints: &'static str) -> Self {
        self.constraints = constraints;
        self
    }

    /// Everything the descriptor's `additional_constraints` says: the rule and the rest.
    pub fn additional_constraints(&self) -> String {
        match (self.rule.describe(), self.constraints) {
            (r, "") => r,
            (r, c) if r.is_empty() => c.to_string(),
            (r, c) => format!("{r}; {c}"),
        }
    }
}

/// A node's typed parameters: every field a ROS 2 parameter with a [`Spec`], checked one by
/// one against its rule and then together by [`NodeParams::validate`].
pub trait NodeParams: Serialize + DeserializeOwned + Default + Clone {
    /// One spec per field, in field order.
    fn specs() -> Vec<Spec>;

    /// Rules across parameters (and anything the specs' rules cannot say); the error names
    /// the parameter. Checks needing the rig file are the node's, when it is built.
    fn validate(&self) -> Result<(), NodeError> {
        Ok(())
    }
}

/// The JSON kind of a value, as a ROS 2 parameter type.
fn kind(v: &Value) -> &'static str {
    match v {
        Value::Bool(_) => "bool",
        Value::Number(n) if n.is_i64() || n.is_u64() => "integer",
        Value::Number(_) => "double",
        Value::String(_) => "string",
        Value::Array(_) => "array",
        Value::Null => "NaN or nothing",
        Value::Object(_) => "mapping",
    }
}

/// Checks that every value of `map` has its parameter's type (an integer is taken for a
/// double; a list for a list); the error names the parameter and both types.
pub fn check_types<P: NodeParams>(map: &Map<String, Value>) -> Result<(), NodeError> {
    let Ok(Value::Object(defaults)) = serde_json::to_value(P::default()) else {
        return Err(NodeError::parameter("(defaults)", "parameters must be a struct"));
    };
    for (name, v) in map {
        let Some(d) = defaults.get(name) else { continue };
        let (want, got) = (kind(d), kind(v));
        let same = want == got || (want == "double" && got == "integer") || (want == "double" && got == "NaN or nothing");
        if !same {
            return Err(NodeError::parameter(name, format!("must be of type {want}, got {got} {v}")));
        }
    }
    Ok(())
}

/// Checks every value of `map` against its spec's rule; the error names the parameter.
pub fn check_rules<P: NodeParams>(map: &Map<String, Value>) -> Result<(), NodeError> {
    for spec in P::specs() {
        if let Some(v) = map.get(spec.name) {
            spec.rule.check(v).map_err(|reason| NodeError::parameter(spec.name, reason))?;
        }
    }
    Ok(())
}

/// The typed parameters of a whole map, each value checked against its rule and the set
/// against [`NodeParams::validate`]: what a set through the parameter services must pass
/// before the node is asked to apply it.
pub fn checked<P: NodeParams>(map: &Map<String, Value>) -> Result<P, NodeError> {
    check_types::<P>(map)?;
    check_rules::<P>(map)?;
    let p: P = typed(map)?;
    p.validate()?;
    Ok(p)
}

/// Where each parameter's value came from, so that an error about a value names the file
/// and key (or the `-p` override) that gave it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Sources {
    /// Parameter name -> (file, node section) or the override as written.
    given: HashMap<String, Given>,
}

#[derive(Debug, Clone, PartialEq)]
enum Given {
    File { file: String, section: String },
    Override(String),
}

impl Sources {
    /// `error` as the user wrote the value: a parameter error becomes the file's, naming the
    /// key under its node section, or the `-p` override's; others pass unchanged.
    pub fn locate(&self, error: NodeError) -> NodeError {
        let NodeError::Parameter { name, reason } = &error else { return error };
        match self.given.get(name) {
            Some(Given::File { file, section }) => NodeError::File { file: file.clone(), reason: format!("`{section}` key `{name}`: {reason}") },
            Some(Given::Override(text)) => NodeError::parameter(format!("-p {text}"), reason.clone()),
            None => error,
        }
    }
}

/// What `--ros-args` said.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct NodeArgs {
    pub name: String,
    pub namespace: String,
    pub params_files: Vec<PathBuf>,
    /// `-p name:=value`, value as written.
    pub overrides: Vec<(String, String)>,
    /// Arguments before `--ros-args` (the node's own).
    pub other: Vec<String>,
}

impl NodeArgs {
    /// `/namespace/name`.
    pub fn fully_qualified_name(&self) -> String {
        format!("{}/{}", self.namespace.trim_end_matches('/'), self.name)
    }
}

/// Parses a node's command line (without the program name).
pub fn parse_args(default_name: &str, args: impl IntoIterator<Item = String>) -> Result<NodeArgs, NodeError> {
    let mut out = NodeArgs { name: default_name.into(), namespace: crate::topics::NAMESPACE.into(), ..Default::default() };
    let mut ros = false;
    let mut it = args.into_iter();
    let need = |flag: &str, v: Option<String>| v.ok_or_else(|| NodeError::parameter(flag, "missing its value"));
    while let Some(a) = it.next() {
        match a.as_str() {
            "--ros-args" => ros = true,
            "--" => ros = false,
            _ if !ros => out.other.push(a),
            "--params-file" => out.params_files.push(need("--params-file", it.next())?.into()),
            "-p" | "--param" => {
                let kv = need("-p", it.next())?;
                let (k, v) = kv.split_once(":=").ok_or_else(|| NodeError::parameter(&kv, "write -p name:=value"))?;
                out.overrides.push((k.to_string(), v.to_string()));
            }
            "-r" | "--remap" => {
                let kv = need("-r", it.next())?;
                match kv.split_once(":=") {
                    Some(("__node", v)) | Some(("__name", v)) => out.name = v.to_string(),
                    Some(("__ns", v)) => out.namespace = if v.starts_with('/') { v.to_string() } else { format!("/{v}") },
                    _ => return Err(NodeError::parameter(&kv, "only __node:= and __ns:= remaps are supported")),
                }
            }
            "--log-level" => {
                need("--log-level", it.next())?;
            }
            other => return Err(NodeError::parameter(other, "unknown ROS argument (supported: --params-file, -p, -r __node:=, -r __ns:=, --log-level)")),
        }
    }
    if out.name.is_empty() || !out.name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(NodeError::parameter("__node", format!("`{}` is not a valid node name", out.name)));
    }
    Ok(out)
}

/// The parameters of `args`' node: defaults, then each params file's matching sections
/// (`/**`, `name`, `/namespace/name`, in file order), then the `-p` overrides; every value
/// checked against its rule and the set validated, an error naming the file and key (or the
/// override) that gave the bad value.
pub fn load<P: NodeParams>(args: &NodeArgs) -> Result<(P, Map<String, Value>), NodeError> {
    load_located(args).map(|(p, map, _)| (p, map))
}

/// [`load`], with where each value came from (to name it in errors found later, when the
/// node is built against its rig file: [`Sources::locate`]).
pub fn load_located<P: NodeParams>(args: &NodeArgs) -> Result<(P, Map<String, Value>, Sources), NodeError> {
    let mut map = match serde_json::to_value(P::default()) {
        Ok(Value::Object(m)) => m,
        _ => return Err(NodeError::parameter("(defaults)", "parameters must be a struct")),
    };
    let known: Vec<String> = map.keys().cloned().collect();
    let mut sources = Sources::default();
    for file in &args.params_files {
        let name = file.display().to_string();
        let text = std::fs::read_to_string(file).map_err(|e| NodeError::File { file: name.clone(), reason: e.to_string() })?;
        for (section, k, v) in sections(&text, &name, args)? {
            if k == USE_SIM_TIME {
                // Every ROS 2 node has it; the runner reads it from the overrides and files.
                continue;
            }
            if !known.contains(&k) {
                return Err(NodeError::File { file: name, reason: format!("unknown parameter `{k}` for node {} (known: {})", args.fully_qualified_name(), known.join(", ")) });
            }
            sources.given.insert(k.clone(), Given::File { file: name.clone(), section });
            map.insert(k, v);
        }
    }
    for (k, v) in &args.overrides {
        if k == USE_SIM_TIME {
            continue;
        }
        if !known.contains(k) {
            return Err(NodeError::parameter(k, format!("unknown parameter (known: {})", known.join(", "))));
        }
        let yaml: serde_yaml_ng::Value = serde_yaml_ng::from_str(v).map_err(|e| NodeError::parameter(k, format!("value `{v}`: {e}")))?;
        map.insert(k.clone(), to_json(&yaml).map_err(|e| NodeError::parameter(k, e))?);
        sources.given.insert(k.clone(), Given::Override(format!("{k}:={v}")));
    }
    let typed = checked::<P>(&map).map_err(|e| sources.locate(e))?;
    Ok((typed, map, sources))
}

/// The parameter every ROS 2 node has: whether its clock follows `/clock`.
pub const USE_SIM_TIME: &str = "use_sim_time";

/// `use_sim_time` as the node's params files and overrides give it (default false); the
/// error names the file or override when it is not a boolean.
pub fn use_sim_time(args: &NodeArgs) -> Result<bool, NodeError> {
    let mut value = false;
    let as_bool = |v: &Value, whence: &str| v.as_bool().ok_or_else(|| NodeError::parameter(USE_SIM_TIME, format!("{whence}: must be true or false, got {v}")));
    for file in &args.params_files {
        let name = file.display().to_string();
        let text = std::fs::read_to_string(file).map_err(|e| NodeError::File { file: name.clone(), reason: e.to_string() })?;
        for (_, k, v) in sections(&text, &name, args)? {
            if k == USE_SIM_TIME {
                value = as_bool(&v, &name)?;
            }
        }
    }
    for (k, v) in &args.overrides {
        if k == USE_SIM_TIME {
            let yaml: serde_yaml_ng::Value = serde_yaml_ng::from_str(v).map_err(|e| NodeError::parameter(k, format!("value `{v}`: {e}")))?;
            value = as_bool(&to_json(&yaml).map_err(|e| NodeError::parameter(k, e))?, &format!("-p {k}:={v}"))?;
        }
    }
    Ok(value)
}

/// The typed parameters of a map; errors name the parameter.
pub fn typed<P: DeserializeOwned>(map: &Map<String, Value>) -> Result<P, NodeError> {
    serde_json::from_value(Value::Object(map.clone())).map_err(|e| {
        let text = e.to_string();
        let name = text.split('`').nth(1).unwrap_or("(parameters)").to_string();
        NodeError::parameter(name, text)
    })
}

fn to_json(v: &serde_yaml_ng::Value) -> Result<Value, String> {
    serde_json::to_value(v).map_err(|e| e.to_string())
}

/// The `ros__parameters` entries that apply to the node, in file order: (section, name, value).
fn sections(text: &str, file: &str, args: &NodeArgs) -> Result<Vec<(String, String, Value)>, NodeError> {
    let err = |reason: String| NodeError::File { file: file.to_string(), reason };
    let doc: serde_yaml_ng::Value = serde_yaml_ng::from_str(text).map_err(|e| err(e.to_string()))?;
    let serde_yaml_ng::Value::Mapping(top) = doc else {
        return Err(err("a params file is a mapping of node names to `ros__parameters`".into()));
    };
    let fq = args.fully_qualified_name();
    let mut out = Vec::new();
    for (key, body) in top {
        let Some(key) = key.as_str() else { return Err(err("node names must be strings".into())) };
        if !(key == "/**" || key == args.name || key == fq || key == fq.trim_start_matches('/')) {
            continue;
        }
        let params = body.get("ros__parameters").ok_or_else(|| err(format!("`{key}` has no `ros__parameters`")))?;
        let serde_yaml_ng::Value::Mapping(params) = params else {
            return Err(err(format!("`{key}.ros__parameters` must be a mapping")));
        };
        for (k, v) in params {
            let Some(k) = k.as_str() else { return Err(err(format!("`{key}`: parameter names must be strings"))) };
            out.push((key.to_string(), k.to_string(), to_json(v).map_err(|e| err(format!("`{k}`: {e}")))?));
        }
    }
    Ok(out)
}

/// A parameter value as `rcl_interfaces/msg/ParameterValue` (a NaN double arrives here as
/// `null`: it is sent as NaN).
pub fn to_ros_value(v: &Value) -> oilfilm_msgs::ParameterValue {
    use oilfilm_msgs::ParameterValue as P;
    match v {
        Value::Bool(b) => P { r#type: 1, bool_value: *b, ..P::default() },
        Value::Number(n) if n.is_i64() => P { r#type: 2, integer_value: n.as_i64().unwrap_or_default(), ..P::default() },
        Value::Number(n) => P { r#type: 3, double_value: n.as_f64().unwrap_or(f64::NAN), ..P::default() },
        Value::Null => P { r#type: 3, double_value: f64::NAN, ..P::default() },
        Value::String(s) => P { r#type: 4, string_value: s.clone(), ..P::default() },
        Value::Array(a) if a.iter().all(Value::is_i64) && !a.is_empty() => P { r#type: 7, integer_array_value: a.iter().filter_map(Value::as_i64).collect(), ..P::default() },
        Value::Array(a) if a.iter().all(Value::is_number) && !a.is_empty() => P { r#type: 8, double_array_value: a.iter().filter_map(Value::as_f64).collect(), ..P::default() },
        Value::Array(a) => P { r#type: 9, string_array_value: a.iter().filter_map(|s| s.as_str().map(str::to_string)).collect(), ..P::default() },
        Value::Object(_) => P::default(),
    }
}

/// `rcl_interfaces/msg/ParameterValue` as a parameter value (`None`: not set).
pub fn from_ros_value(p: &oilfilm_msgs::ParameterValue) -> Option<Value> {
    let number = |x: f64| serde_json::Number::from_f64(x).map_or(Value::Null, Value::Number);
    Some(match p.r#type {
        1 => Value::Bool(p.bool_value),
        2 => Value::from(p.integer_value),
        3 => number(p.double_value),
        4 => Value::String(p.string_value.clone()),
        5 => Value::from(p.byte_array_value.clone()),
        6 => Value::from(p.bool_array_value.clone()),
        7 => Value::from(p.integer_array_value.clone()),
        8 => Value::Array(p.double_array_value.iter().map(|x| number(*x)).collect()),
        9 => Value::from(p.string_array_value.clone()),
        _ => return None,
    })
}

/// The event a node publishes on `/parameter_events` when it starts: every parameter it
/// declared (`use_sim_time` included), at `now`.
pub fn declaration_event(fully_qualified: &str, params: &Map<String, Value>, use_sim_time: bool, now: crate::stamp::Stamp) -> oilfilm_msgs::ParameterEvent {
    let mut new_parameters: Vec<oilfilm_msgs::Parameter> = params.iter().map(|(k, v)| oilfilm_msgs::Parameter { name: k.clone(), value: to_ros_value(v) }).collect();
    new_parameters.push(oilfilm_msgs::Parameter { name: USE_SIM_TIME.into(), value: to_ros_value(&Value::Bool(use_sim_time)) });
    oilfilm_msgs::ParameterEvent { stamp: now.to_time(), node: fully_qualified.to_string(), new_parameters, ..Default::default() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rule_states_its_bounds_as_a_person_reads_them() {
        assert_eq!(Rule::number(1.0, 1e300).describe(), "a number in [1, 1e300]");
        assert_eq!(Rule::above(0.0, f64::INFINITY).describe(), "a number above 0, at most .inf");
        assert_eq!(Rule::number(0.5, 1e7).describe(), "a number in [0.5, 1e7]");
        assert_eq!(Rule::number(0.0, 3600.0).describe(), "a number in [0, 3600]");
    }
    use crate::estimator::EstimatorParams;

    fn args(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn ros_args_files_and_overrides() {
        let dir = std::env::temp_dir().join(format!("oilfilm-params-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("p.yaml");
        std::fs::write(&file, "/**:\n  ros__parameters:\n    window: 1000\n/oilfilm/estimator:\n  ros__parameters:\n    hop: 500\nother:\n  ros__parameters:\n    bogus: 1\n").unwrap();
        let a = parse_args("estimator", args(&["--ros-args", "--params-file", file.to_str().unwrap(), "-p", "model:=kcm", "-p", "speed_rpm:=1500"])).unwrap();
        let (p, _) = load::<EstimatorParams>(&a).unwrap();
        assert_eq!((p.window, p.hop, p.model.as_str(), p.speed_rpm), (1000, 500, "kcm", 1500.0));

        std::fs::write(&file, "estimator:\n  ros__parameters:\n    windw: 1000\n").unwrap();
        let e = load::<EstimatorParams>(&a).unwrap_err().to_string();
        assert!(e.contains("p.yaml") && e.contains("unknown parameter `windw`"), "{e}");
        // A window the model cannot use: refused at load time, naming the file and key.
        std::fs::write(&file, "/oilfilm/estimator:\n  ros__parameters:\n    window: 10\n    hop: 10\n").unwrap();
        let e = load::<EstimatorParams>(&a).unwrap_err().to_string();
        assert!(e.contains("p.yaml") && e.contains("`/oilfilm/estimator` key `window`") && e.contains("[80,") && e.contains("got 10"), "{e}");
        let kcm = parse_args("estimator", args(&["--ros-args", "--params-file", file.to_str().unwrap(), "-p", "model:=kcm"])).unwrap();
        std::fs::write(&file, "/oilfilm/estimator:\n  ros__parameters:\n    window: 100\n").unwrap();
        let e = load::<EstimatorParams>(&kcm).unwrap_err().to_string();
        assert!(e.contains("key `window`") && e.contains("kcm") && e.contains("at least 112"), "{e}");
        // use_sim_time is every node's, read beside the typed parameters.
        let sim = parse_args("estimator", args(&["--ros-args", "-p", "use_sim_time:=true"])).unwrap();
        assert!(load::<EstimatorParams>(&sim).is_ok() && use_sim_time(&sim).unwrap());
        let bad = parse_args("estimator", args(&["--ros-args", "-p", "use_sim_time:=1"])).unwrap();
        assert!(use_sim_time(&bad).unwrap_err().to_string().contains("true or false"));
        let a = parse_args("estimator", args(&["--ros-args", "-p", "window:=abc"])).unwrap();
        let e = load::<EstimatorParams>(&a).unwrap_err().to_string();
        assert!(e.contains("window") || e.contains("invalid type"), "{e}");
        assert!(parse_args("x", args(&["--ros-args", "-p", "novalue"])).is_err());
        let a = parse_args("x", args(&["--ros-args", "-r", "__node:=est2", "-r", "__ns:=rig2"])).unwrap();
        assert_eq!(a.fully_qualified_name(), "/rig2/est2");
        // Passed: nothing to look at (a failing run keeps the file).
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_conditioners_chain_is_typed_and_checked() {
        use crate::conditioner::{Chain, ConditionerParams};
        let dir = std::env::temp_dir().join(format!("oilfilm-params-chain-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("c.yaml");
        let node = parse_args("conditioner", args(&["--ros-args", "--params-file", file.to_str().unwrap()])).unwrap();
        // Valid: both chains, and the default when the file does not say (bags recorded
        // before the parameter existed were conditioned zero-phase).
        for (text, chain) in [
            ("conditioner:\n  ros__parameters:\n    chain: causal\n", Chain::Causal),
            ("/oilfilm/conditioner:\n  ros__parameters:\n    chain: zero_phase\n    lowpass_order: 6\n", Chain::ZeroPhase),
            ("conditioner:\n  ros__parameters:\n    block_scans: 500\n", Chain::ZeroPhase),
        ] {
            std::fs::write(&file, text).unwrap();
            let (p, map) = load::<ConditionerParams>(&node).unwrap();
            p.validate().unwrap();
            assert_eq!(p.chain().unwrap(), chain, "{text}");
            assert_eq!(map.get("chain").and_then(|v| v.as_str()), Some(chain.name()), "declared for the parameter services");
        }
        // Invalid, refused where they are given, naming the file and the key: an unknown
        // chain, a wrong type, an order the causal chain cannot double.
        let refused = |text: &str| {
            std::fs::write(&file, text).unwrap();
            load::<ConditionerParams>(&node).unwrap_err().to_string()
        };
        let e = refused("conditioner:\n  ros__parameters:\n    chain: causual\n");
        assert!(e.contains("c.yaml") && e.contains("key `chain`") && e.contains("causual") && e.contains("zero_phase, causal"), "{e}");
        let e = refused("conditioner:\n  ros__parameters:\n    chain: 3\n");
        assert!(e.contains("c.yaml") && e.contains("key `chain`") && e.contains("type string"), "{e}");
        let e = refused("conditioner:\n  ros__parameters:\n    chain: causal\n    lowpass_order: 7\n");
        assert!(e.contains("c.yaml") && e.contains("key `lowpass_order`") && e.contains("<= 6"), "{e}");
        let e = refused("conditioner:\n  ros__parameters:\n    lowpass_cutoff_hz: .nan\n");
        assert!(e.contains("key `lowpass_cutoff_hz`") && e.contains("got NaN"), "{e}");
        let a = parse_args("conditioner", args(&["--ros-args", "-p", "chain:=causal"])).unwrap();
        assert_eq!(load::<ConditionerParams>(&a).unwrap().0.chain().unwrap(), Chain::Causal);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
