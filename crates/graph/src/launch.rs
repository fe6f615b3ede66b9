//! Launch files as data: the ROS 2 launch YAML schema (`launch: - node: {pkg, exec, name,
//! namespace, param: [{from: FILE} | {name, value}]}`), so the file `oilfilm launch` reads
//! is one `ros2 launch` reads too. `$(dirname)` is the launch file's directory.
//! The in-memory runner builds its graph from the same files
//! ([`crate::runner::memory::Graph::from_launch`]); `oilfilm-nodes` starts each node as a
//! process ([`NodeLaunch::args`] are its `--ros-args`).

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::NodeError;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LaunchFile {
    launch: Vec<Entry>,
}

/// One entry of `launch:`: a `node` or an `arg` (a launch argument with a default, used as
/// `$(var NAME)` and set as `NAME:=VALUE` on the command line).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    node: Option<NodeEntry>,
    arg: Option<ArgEntry>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ArgEntry {
    name: String,
    default: Option<String>,
    #[allow(dead_code)]
    description: Option<String>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct NodeEntry {
    pkg: String,
    exec: String,
    name: Option<String>,
    namespace: Option<String>,
    #[serde(default)]
    param: Vec<ParamEntry>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(untagged, deny_unknown_fields)]
enum ParamEntry {
    From { from: String },
    Value { name: String, value: serde_yaml_ng::Value },
}

/// One node to start.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeLaunch {
    pub exec: String,
    pub name: String,
    pub namespace: String,
    pub args: Vec<String>,
}

/// Reads a launch file; the error names the file and what is wrong.
pub fn read(path: &Path) -> Result<Vec<NodeLaunch>, NodeError> {
    read_with(path, &[])
}

/// Reads a launch file with launch arguments `(name, value)` (`name:=value`).
pub fn read_with(path: &Path, launch_args: &[(String, String)]) -> Result<Vec<NodeLaunch>, NodeError> {
    let file = path.display().to_string();
    let text = crate::params::read_yaml(path)?;
    let doc: LaunchFile = serde_yaml_ng::from_str(&text).map_err(|e| NodeError::File { file: file.clone(), reason: e.to_string() })?;
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let dir = if dir.as_os_str().is_empty() { PathBuf::from(".") } else { dir };
    // Absolute, so `$(dirname)/x` and `x` mean the same file wherever the nodes start.
    let dir = std::fs::canonicalize(&dir).map_err(|e| NodeError::File { file: file.clone(), reason: format!("its directory: {e}") })?;
    let mut vars: Vec<(String, Option<String>)> = Vec::new();
    let mut nodes = Vec::new();
    for (i, e) in doc.launch.into_iter().enumerate() {
        match (e.node, e.arg) {
            (Some(n), None) => nodes.push(n),
            (None, Some(a)) => vars.push((a.name, a.default)),
            _ => return Err(NodeError::File { file, reason: format!("launch[{i}]: each entry is one `node` or one `arg`") }),
        }
    }
    for (k, _) in launch_args {
        if !vars.iter().any(|(n, _)| n == k) {
            return Err(NodeError::File {
                file,
                reason: format!("no launch argument `{k}` (declared: {})", vars.iter().map(|v| v.0.as_str()).collect::<Vec<_>>().join(", ")),
            });
        }
    }
    let mut values = Vec::new();
    for (name, default) in vars {
        match launch_args.iter().rev().find(|(k, _)| *k == name).map(|(_, v)| v.clone()).or(default) {
            Some(v) => values.push((name, v)),
            None => return Err(NodeError::File { file, reason: format!("launch argument `{name}` has no default: give {name}:=VALUE") }),
        }
    }
    let substitute = |text: &str| -> String {
        let mut t = text.to_string();
        for (k, v) in &values {
            t = t.replace(&format!("$(var {k})"), v);
        }
        t
    };
    let mut out = Vec::new();
    for n in nodes {
        if n.pkg != "oilfilm" {
            return Err(NodeError::File { file, reason: format!("node `{}`: package `{}` is not ours (pkg: oilfilm)", n.exec, n.pkg) });
        }
        let name = n.name.clone().unwrap_or_else(|| n.exec.trim_start_matches("oilfilm-").to_string());
        let namespace = n.namespace.clone().unwrap_or_else(|| crate::topics::NAMESPACE.into());
        let mut args = vec!["--ros-args".into(), "-r".into(), format!("__node:={name}"), "-r".into(), format!("__ns:={namespace}")];
        for p in &n.param {
            match p {
                ParamEntry::From { from } => {
                    let resolved = substitute(from).replace("$(dirname)", &dir.display().to_string());
                    let resolved = if Path::new(&resolved).is_absolute() { PathBuf::from(resolved) } else { dir.join(resolved) };
                    if !resolved.exists() {
                        return Err(NodeError::File { file, reason: format!("node `{name}`: params file {} does not exist", resolved.display()) });
                    }
                    args.extend(["--params-file".into(), resolved.display().to_string()]);
                }
                ParamEntry::Value { name: k, value } => {
                    let v = serde_yaml_ng::to_string(value).map_err(|e| NodeError::File { file: file.clone(), reason: e.to_string() })?;
                    // An argument substituted to nothing is the empty string, as in ROS 2
                    // launch, not YAML's null (which no string parameter takes).
                    let v = substitute(v.trim());
                    args.extend(["-p".into(), format!("{k}:={}", if v.is_empty() { "''" } else { v.as_str() })]);
                }
            }
        }
        out.push(NodeLaunch { exec: n.exec, name, namespace, args });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sim_rig_launch_file_reads() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../launch_configs/sim_rig.launch.yaml");
        let nodes = read(&path).unwrap();
        let names: Vec<&str> = nodes.iter().map(|n| n.name.as_str()).collect();
        assert_eq!(names, ["exciter", "daq", "conditioner", "estimator"]);
        assert!(nodes.iter().all(|n| n.args.iter().any(|a| a.ends_with("params/sim_rig.yaml"))));
        // Each node's section of the params file loads into its typed parameters.
        for n in &nodes {
            let args = crate::params::parse_args(&n.name, n.args.clone()).unwrap();
            let r = match n.name.as_str() {
                "exciter" => crate::params::load::<crate::exciter::ExciterParams>(&args).map(|_| ()),
                "daq" => crate::params::load::<crate::daq::DaqParams>(&args).map(|_| ()),
                "conditioner" => crate::params::load::<crate::conditioner::ConditionerParams>(&args).map(|_| ()),
                _ => crate::params::load::<crate::estimator::EstimatorParams>(&args).map(|_| ()),
            };
            r.unwrap_or_else(|e| panic!("{}: {e}", n.name));
        }
    }

    #[test]
    fn every_launch_file_reads_and_its_params_load() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../launch_configs");
        let mut seen = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if !path.to_string_lossy().ends_with(".launch.yaml") {
                continue;
            }
            seen += 1;
            let nodes = read_with(&path, &[]).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            for n in &nodes {
                let args = crate::params::parse_args(&n.name, n.args.clone()).unwrap();
                let r = match n.name.as_str() {
                    "exciter" => crate::params::load::<crate::exciter::ExciterParams>(&args).map(|_| ()),
                    "daq" => crate::params::load::<crate::daq::DaqParams>(&args).and_then(|(p, _)| p.validate()),
                    "conditioner" => crate::params::load::<crate::conditioner::ConditionerParams>(&args).map(|_| ()),
                    "recorder" => crate::params::load::<crate::recorder::RecorderParams>(&args).and_then(|(p, _)| p.writer_options().map(|_| ())),
                    "player" => crate::params::load::<crate::player::PlayerParams>(&args).and_then(|(p, _)| p.options().map(|_| ())),
                    _ => crate::params::load::<crate::estimator::EstimatorParams>(&args).map(|_| ()),
                };
                r.unwrap_or_else(|e| panic!("{} / {}: {e}", path.display(), n.name));
            }
        }
        assert!(seen >= 4, "sim_rig, replay, live_rig and record_sim_rig");
        let replay = dir.join("replay.launch.yaml");
        let nodes = read_with(&replay, &[("file".into(), "/tmp/x.txt".into())]).unwrap();
        assert!(nodes.iter().any(|n| n.args.iter().any(|a| a == "file:=/tmp/x.txt")), "{nodes:?}");
        assert!(read_with(&replay, &[("fil".into(), "x".into())]).unwrap_err().to_string().contains("no launch argument `fil`"));
        let record = read_with(&dir.join("record_sim_rig.launch.yaml"), &[("bag".into(), "/tmp/b1".into())]).unwrap();
        assert_eq!(record[0].name, "recorder");
        assert!(record[0].args.iter().any(|a| a == "output:=/tmp/b1"), "{:?}", record[0].args);
        assert_eq!(record.len(), 5);
    }

    #[test]
    fn a_bad_launch_file_names_the_problem() {
        let dir = std::env::temp_dir().join(format!("oilfilm-launch-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("bad.yaml");
        std::fs::write(&f, "launch:\n- node:\n    pkg: oilfilm\n    exec: oilfilm-daq\n    param:\n    - from: missing.yaml\n").unwrap();
        let e = read(&f).unwrap_err().to_string();
        assert!(e.contains("bad.yaml") && e.contains("missing.yaml"), "{e}");
        std::fs::write(&f, "launch:\n- nod:\n    pkg: oilfilm\n").unwrap();
        assert!(read(&f).unwrap_err().to_string().contains("bad.yaml"));
        // Passed: nothing to look at (a failing run keeps the file).
        let _ = std::fs::remove_dir_all(&dir);
    }
}
