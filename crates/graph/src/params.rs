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

use std::path::PathBuf;

use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::{Map, Value};

use crate::error::NodeError;

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
/// (`/**`, `name`, `/namespace/name`, in file order), then the `-p` overrides.
pub fn load<P: DeserializeOwned + Serialize + Default>(args: &NodeArgs) -> Result<(P, Map<String, Value>), NodeError> {
    let mut map = match serde_json::to_value(P::default()) {
        Ok(Value::Object(m)) => m,
        _ => return Err(NodeError::parameter("(defaults)", "parameters must be a struct")),
    };
    let known: Vec<String> = map.keys().cloned().collect();
    for file in &args.params_files {
        let name = file.display().to_string();
        let text = std::fs::read_to_string(file).map_err(|e| NodeError::File { file: name.clone(), reason: e.to_string() })?;
        for (k, v) in sections(&text, &name, args)? {
            if !known.contains(&k) {
                return Err(NodeError::File { file: name, reason: format!("unknown parameter `{k}` for node {} (known: {})", args.fully_qualified_name(), known.join(", ")) });
            }
            map.insert(k, v);
        }
    }
    for (k, v) in &args.overrides {
        if !known.contains(k) {
            return Err(NodeError::parameter(k, format!("unknown parameter (known: {})", known.join(", "))));
        }
        let yaml: serde_yaml_ng::Value = serde_yaml_ng::from_str(v).map_err(|e| NodeError::parameter(k, format!("value `{v}`: {e}")))?;
        map.insert(k.clone(), to_json(&yaml).map_err(|e| NodeError::parameter(k, e))?);
    }
    let typed = typed::<P>(&map)?;
    Ok((typed, map))
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

/// The `ros__parameters` entries that apply to the node, in file order.
fn sections(text: &str, file: &str, args: &NodeArgs) -> Result<Vec<(String, Value)>, NodeError> {
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
            out.push((k.to_string(), to_json(v).map_err(|e| err(format!("`{k}`: {e}")))?));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
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
        // Invalid: an unknown chain, a wrong type, an order the causal chain cannot double.
        std::fs::write(&file, "conditioner:\n  ros__parameters:\n    chain: causual\n").unwrap();
        let (p, _) = load::<ConditionerParams>(&node).unwrap();
        let e = p.validate().unwrap_err().to_string();
        assert!(e.contains("chain") && e.contains("causual") && e.contains("zero_phase, causal"), "{e}");
        std::fs::write(&file, "conditioner:\n  ros__parameters:\n    chain: 3\n").unwrap();
        let e = load::<ConditionerParams>(&node).unwrap_err().to_string();
        assert!(e.contains("invalid type"), "{e}");
        std::fs::write(&file, "conditioner:\n  ros__parameters:\n    chain: causal\n    lowpass_order: 7\n").unwrap();
        let (p, _) = load::<ConditionerParams>(&node).unwrap();
        let e = p.validate().unwrap_err().to_string();
        assert!(e.contains("lowpass_order") && e.contains("<= 6"), "{e}");
        let a = parse_args("conditioner", args(&["--ros-args", "-p", "chain:=causal"])).unwrap();
        assert_eq!(load::<ConditionerParams>(&a).unwrap().0.chain().unwrap(), Chain::Causal);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
