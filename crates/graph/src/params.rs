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
//!
//! A params file may give only some of a node's parameters (the rest keep their defaults),
//! so a file cut short after its last whole line reads as a valid one. Two things keep a cut
//! file from passing unseen: a file whose text does not end with a line end is refused (a
//! cut almost never falls just after one, and a value cut in the middle, `window: 25` of
//! `window: 25000`, would read as another valid value), and a node says once at load which
//! of its parameters are at their defaults although a params file had its section
//! ([`Sources::defaults_note`]), naming the files.

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
/// and key (or the `-p` override) that gave it; and which took their defaults.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Sources {
    /// Parameter name -> (file, node section) or the override as written.
    given: HashMap<String, Given>,
    /// The params files that had a section for the node, in the order given.
    sectioned: Vec<String>,
    /// The parameters neither a file nor an override gave, with their default values.
    defaulted: Vec<(String, Value)>,
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

    /// The parameters at their defaults although a params file had the node's section, with
    /// their values (empty when no file had the section: then no file was meant for it).
    pub fn defaulted(&self) -> &[(String, Value)] {
        if self.sectioned.is_empty() {
            &[]
        } else {
            &self.defaulted
        }
    }

    /// What node `node` says at load when params files had its section but left some of
    /// its parameters out: the files and those parameters with their default values. A
    /// file may leave parameters out on purpose; one cut short after a whole line leaves out
    /// what followed, and this line is where that shows. `None` when nothing was left out.
    pub fn defaults_note(&self, node: &str) -> Option<String> {
        let left = self.defaulted();
        if left.is_empty() {
            return None;
        }
        let values: Vec<String> = left.iter().map(|(k, v)| format!("{k}={v}")).collect();
        Some(format!(
            "{node}: {} of its parameters not in its section of {} (nor given with -p), so at their defaults: {}",
            left.len(),
            self.sectioned.join(", "),
            values.join(", ")
        ))
    }
}

/// Logs `note` unless this process has already logged it: a node's parameters are loaded
/// more than once in one process (a launch file's nodes are checked when it is read, then
/// loaded again when they are built), and the note is one line at load, not one per load.
fn log_once(note: &str) {
    use std::hash::{Hash, Hasher};
    static LOGGED: std::sync::Mutex<std::collections::BTreeSet<u64>> = std::sync::Mutex::new(std::collections::BTreeSet::new());
    let mut h = std::collections::hash_map::DefaultHasher::new();
    note.hash(&mut h);
    // A poisoned lock only means another thread panicked while logging: the set is intact.
    let first = LOGGED.lock().unwrap_or_else(std::sync::PoisonError::into_inner).insert(h.finish());
    if first {
        tracing::info!("{note}");
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
/// override) that gave the bad value. Each file is read through [`read_yaml`]'s checks.
pub fn load<P: NodeParams>(args: &NodeArgs) -> Result<(P, Map<String, Value>), NodeError> {
    load_located(args).map(|(p, map, _)| (p, map))
}

/// [`load`], with where each value came from (to name it in errors found later, when the
/// node is built against its rig file: [`Sources::locate`]).
pub fn load_located<P: NodeParams>(args: &NodeArgs) -> Result<(P, Map<String, Value>, Sources), NodeError> {
    let texts = args.params_files.iter().map(|f| Ok((f.display().to_string(), read_yaml(f)?))).collect::<Result<Vec<_>, NodeError>>()?;
    load_texts(args, &texts)
}

/// [`load_located`] with the params files' texts given, `(name, text)` in order (each already
/// through [`check_yaml`]); `args.params_files` is not read.
pub fn load_texts<P: NodeParams>(args: &NodeArgs, texts: &[(String, String)]) -> Result<(P, Map<String, Value>, Sources), NodeError> {
    let mut map = match serde_json::to_value(P::default()) {
        Ok(Value::Object(m)) => m,
        _ => return Err(NodeError::parameter("(defaults)", "parameters must be a struct")),
    };
    let known: Vec<String> = map.keys().cloned().collect();
    let mut sources = Sources::default();
    for (name, text) in texts {
        let name = name.clone();
        let (applies, entries) = sections(text, &name, args)?;
        if applies {
            sources.sectioned.push(name.clone());
        }
        for (section, k, v) in entries {
            if k == USE_SIM_TIME {
                // Every ROS 2 node has it; the runner reads it from the overrides and files.
                continue;
            }
            if !known.contains(&k) {
                return Err(NodeError::File {
                    file: name,
                    reason: format!("unknown parameter `{k}` for node {} (known: {})", args.fully_qualified_name(), known.join(", ")),
                });
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
    sources.defaulted = map.iter().filter(|(k, _)| !sources.given.contains_key(*k)).map(|(k, v)| (k.clone(), v.clone())).collect();
    if let Some(note) = sources.defaults_note(&args.fully_qualified_name()) {
        log_once(&note);
    }
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
        for (_, k, v) in sections(&text, &name, args)?.1 {
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

/// The largest params, launch or rig file read, bytes: a graph's files are a few kB, and the
/// YAML parser's time grows faster than the size on pathological input, so a huge file is
/// refused before it is read.
pub const MAX_YAML_BYTES: u64 = 1 << 20;
/// The deepest nesting accepted in a params or launch file (flow brackets, block sequences
/// and indentation levels alike): theirs is 3 or 4.
pub const MAX_YAML_DEPTH: usize = 32;

/// The text of a params or launch file, checked before any parsing: at most
/// [`MAX_YAML_BYTES`], UTF-8 (else the line and column of the first bad byte), ending with a
/// line end (else it is taken as cut short: the line, column and byte where it ends), nested
/// at most [`MAX_YAML_DEPTH`] deep, no alias. Errors name the file.
pub fn read_yaml(path: &std::path::Path) -> Result<String, NodeError> {
    use std::io::Read;
    let file = path.display().to_string();
    let err = |reason: String| NodeError::File { file: file.clone(), reason };
    let f = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
    let mut bytes = Vec::new();
    f.take(MAX_YAML_BYTES + 1).read_to_end(&mut bytes).map_err(|e| err(e.to_string()))?;
    check_yaml(bytes, &file)
}

/// [`read_yaml`]'s checks on a file's bytes: its text, or an error naming `file`.
pub fn check_yaml(bytes: Vec<u8>, file: &str) -> Result<String, NodeError> {
    let err = |reason: String| NodeError::File { file: file.to_string(), reason };
    let text = check_config_text(bytes, file, "a params or launch file")?;
    check_yaml_depth(&text).map_err(|r| match r {
        Refused::Deep(line, column, depth) => {
            err(format!("line {line} column {column}: nested {depth} deep, more than the {MAX_YAML_DEPTH} a params or launch file may be"))
        }
        Refused::Alias(line, column) => {
            err(format!("line {line} column {column}: a YAML alias (`*name`); params and launch files take none (nor does ROS 2's own params parser)"))
        }
    })?;
    Ok(text)
}

/// A configuration file's text (a rig file, say), read with the checks every configuration
/// file gets before it is parsed: at most [`MAX_YAML_BYTES`], UTF-8, ending with a line end.
/// `kind` says what the file is in errors (`"a rig file"`).
pub fn read_config_text(path: &std::path::Path, kind: &str) -> Result<String, NodeError> {
    use std::io::Read;
    let file = path.display().to_string();
    let err = |reason: String| NodeError::File { file: file.clone(), reason };
    let f = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
    let mut bytes = Vec::new();
    f.take(MAX_YAML_BYTES + 1).read_to_end(&mut bytes).map_err(|e| err(e.to_string()))?;
    check_config_text(bytes, &file, kind)
}

/// [`read_config_text`]'s checks on a file's bytes: at most [`MAX_YAML_BYTES`], UTF-8 (else
/// the line and column of the first bad byte), ending with a line end (else it is taken as
/// cut short: the line, column and byte where it ends). Errors name `file`.
fn check_config_text(bytes: Vec<u8>, file: &str, kind: &str) -> Result<String, NodeError> {
    let err = |reason: String| NodeError::File { file: file.to_string(), reason };
    if bytes.len() as u64 > MAX_YAML_BYTES {
        return Err(err(format!("larger than {MAX_YAML_BYTES} bytes, the most {kind} may be")));
    }
    let text = String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let before = &e.as_bytes()[..at];
        let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
        let start = before.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
        let column = String::from_utf8_lossy(&before[start..]).chars().count() + 1;
        err(format!("line {line} column {column}: byte {at} is not UTF-8 text"))
    })?;
    if !text.is_empty() && !text.ends_with('\n') {
        return Err(err(unterminated(&text, kind)));
    }
    Ok(text)
}

/// The refusal of a text whose last line has no line end: where it ends and what the line
/// holds (its first 60 characters). Every editor and writer ends a file's last line; a file
/// that does not was most likely cut short (a copy or write interrupted), and its last value
/// may be cut too, a number shortened into another valid number. Launch and rig files are
/// read through the same check: a cut launch file loses the nodes that followed, a rig file
/// cut in its last value (`clearance_m = 1.14e-4` as `1.1`) would still parse.
fn unterminated(text: &str, kind: &str) -> String {
    let start = text.rfind('\n').map_or(0, |p| p + 1);
    let last = &text[start..];
    let line = text[..start].matches('\n').count() + 1;
    let column = last.chars().count() + 1;
    let shown: String = last.chars().take(60).collect();
    let more = if last.chars().count() > 60 { "..." } else { "" };
    format!(
        "line {line} column {column} (byte {}): the file ends without a line end after `{shown}{more}`: cut short? \
         ({kind} ends with a line end; if that line is whole, add one)",
        text.len()
    )
}

/// Why [`check_yaml_depth`] refused a text.
enum Refused {
    /// Nested deeper than [`MAX_YAML_DEPTH`]: line, column, depth.
    Deep(usize, usize, usize),
    /// An alias (`*name`): line, column.
    Alias(usize, usize),
}

/// An upper bound on the nesting of YAML `text`, checked line by line in linear time: open
/// flow brackets outside quotes, plus block sequence dashes and indentation steps; and no
/// alias. `Err` with the line and column where it is first refused.
fn check_yaml_depth(text: &str) -> Result<(), Refused> {
    let mut flow = 0usize;
    let mut indents: Vec<usize> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let content = line.trim_start_matches(' ');
        let indent = line.len() - content.len();
        if flow == 0 && !content.is_empty() && !content.starts_with('#') {
            while indents.last().is_some_and(|&i| i >= indent) {
                indents.pop();
            }
            indents.push(indent);
        }
        let mut block = indents.len();
        let mut rest = content;
        while let Some(after) = rest.strip_prefix("- ").or_else(|| rest.strip_prefix("? ")) {
            block += 1;
            rest = after.trim_start_matches(' ');
        }
        if block > MAX_YAML_DEPTH {
            return Err(Refused::Deep(n + 1, indent + 1, block));
        }
        let mut quote: Option<char> = None;
        for (c, ch) in line.char_indices() {
            match (quote, ch) {
                (None, '#') if c == 0 || line[..c].ends_with(' ') => break,
                (None, '\'' | '"') => quote = Some(ch),
                (Some(q), _) if ch == q => quote = None,
                (None, '[' | '{') => {
                    flow += 1;
                    if flow + block > MAX_YAML_DEPTH {
                        return Err(Refused::Deep(n + 1, line[..c].chars().count() + 1, flow + block));
                    }
                }
                (None, ']' | '}') => flow = flow.saturating_sub(1),
                // An alias: a plain token starting with `*`. Aliases can expand a few hundred
                // bytes into millions of nodes (seconds of parsing), and ROS 2's own params
                // parser takes none, so none is taken here.
                (None, '*')
                    if (c == 0 || matches!(line.as_bytes()[c - 1], b' ' | b'[' | b'{' | b',' | b'\t'))
                        && line[c + 1..].starts_with(|x: char| !x.is_whitespace()) =>
                {
                    return Err(Refused::Alias(n + 1, line[..c].chars().count() + 1));
                }
                _ => {}
            }
        }
    }
    Ok(())
}

/// Edit distance of two short names (a misspelt section name is within 2 of the node's).
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut diagonal = row[0];
        row[0] = i + 1;
        for (j, &cb) in b.iter().enumerate() {
            let next = (diagonal + usize::from(ca != cb)).min(row[j] + 1).min(row[j + 1] + 1);
            diagonal = row[j + 1];
            row[j + 1] = next;
        }
    }
    row[b.len()]
}

/// A params file's entries for one node: (section, name, value).
type Entries = Vec<(String, String, Value)>;

/// Whether the file has a section for the node, and the `ros__parameters` entries that apply
/// to it, in file order: (section, name, value). A file with no section for the node but one
/// whose name is a near miss of its name (`/oilfilm/estimatr` for `/oilfilm/estimator`) is
/// an error: it would leave the node on its defaults without a word. (Other nodes' sections
/// are normal: one file often serves a whole graph.)
fn sections(text: &str, file: &str, args: &NodeArgs) -> Result<(bool, Entries), NodeError> {
    let err = |reason: String| NodeError::File { file: file.to_string(), reason };
    let doc: serde_yaml_ng::Value = serde_yaml_ng::from_str(text).map_err(|e| err(e.to_string()))?;
    let serde_yaml_ng::Value::Mapping(top) = doc else {
        return Err(err("a params file is a mapping of node names to `ros__parameters`".into()));
    };
    let fq = args.fully_qualified_name();
    let mut out = Vec::new();
    let (mut applies, mut near_misses) = (false, Vec::new());
    for (key, body) in top {
        let Some(key) = key.as_str() else { return Err(err("node names must be strings".into())) };
        if !(key == "/**" || key == args.name || key == fq || key == fq.trim_start_matches('/')) {
            let bare = key.trim_start_matches('/');
            if bare.len() >= 3 && (edit_distance(bare, fq.trim_start_matches('/')) <= 2 || edit_distance(bare, &args.name) <= 2) {
                near_misses.push(key.to_string());
            }
            continue;
        }
        applies = true;
        let params = body.get("ros__parameters").ok_or_else(|| err(format!("`{key}` has no `ros__parameters`")))?;
        let serde_yaml_ng::Value::Mapping(params) = params else {
            return Err(err(format!("`{key}.ros__parameters` must be a mapping")));
        };
        for (k, v) in params {
            let Some(k) = k.as_str() else { return Err(err(format!("`{key}`: parameter names must be strings"))) };
            out.push((key.to_string(), k.to_string(), to_json(v).map_err(|e| err(format!("`{k}`: {e}")))?));
        }
    }
    if let (false, Some(key)) = (applies, near_misses.first()) {
        return Err(err(format!("no section for node `{fq}`, but `{key}`: a misspelling? (a section applies as `/**`, `{}` or `{fq}`)", args.name)));
    }
    Ok((applies, out))
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
        Value::Array(a) if a.iter().all(Value::is_i64) && !a.is_empty() => {
            P { r#type: 7, integer_array_value: a.iter().filter_map(Value::as_i64).collect(), ..P::default() }
        }
        Value::Array(a) if a.iter().all(Value::is_number) && !a.is_empty() => {
            P { r#type: 8, double_array_value: a.iter().filter_map(Value::as_f64).collect(), ..P::default() }
        }
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
    let mut new_parameters: Vec<oilfilm_msgs::Parameter> =
        params.iter().map(|(k, v)| oilfilm_msgs::Parameter { name: k.clone(), value: to_ros_value(v) }).collect();
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
        std::fs::write(
            &file,
            "/**:\n  ros__parameters:\n    window: 1000\n/oilfilm/estimator:\n  ros__parameters:\n    hop: 500\nother:\n  ros__parameters:\n    bogus: 1\n",
        )
        .unwrap();
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

    /// A misspelt node section, a huge file and deep nesting are refused, each fast and
    /// naming the file; other nodes' sections are not an error.
    #[test]
    fn misspelt_sections_huge_files_and_deep_nesting_are_refused() {
        let dir = std::env::temp_dir().join(format!("oilfilm-params-guard-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("g.yaml");
        let node = parse_args("estimator", args(&["--ros-args", "--params-file", file.to_str().unwrap()])).unwrap();
        std::fs::write(&file, "/oilfilm/estimatr:\n  ros__parameters:\n    window: 1000\n").unwrap();
        let e = load::<EstimatorParams>(&node).unwrap_err().to_string();
        assert!(e.contains("g.yaml") && e.contains("`/oilfilm/estimatr`") && e.contains("misspelling"), "{e}");
        // The node's own section beside a sibling's near-miss name, and other nodes' sections.
        std::fs::write(&file, "/oilfilm/estimator:\n  ros__parameters:\n    window: 1000\n/oilfilm/estimator2:\n  ros__parameters:\n    window: 2000\n/oilfilm/daq:\n  ros__parameters:\n    source: sim\n").unwrap();
        assert_eq!(load::<EstimatorParams>(&node).unwrap().0.window, 1000);
        std::fs::write(&file, "/oilfilm/daq:\n  ros__parameters:\n    source: sim\n").unwrap();
        assert_eq!(load::<EstimatorParams>(&node).unwrap().0.window, EstimatorParams::default().window);

        // Deep nesting, flow and block: refused by the linear pre-check, with a position.
        for (text, words) in [
            (format!("estimator:\n  ros__parameters:\n    window: {}1{}\n", "[".repeat(100_000), "]".repeat(100_000)), "line 3 column"),
            (format!("estimator:\n  ros__parameters:\n    w: {}\n", "{a: ".repeat(60_000)), "line 3 column"),
            (format!("{}x\n", "- ".repeat(100_000)), "line 1 column 1"),
            ((0..200).map(|d| format!("{}k{d}:\n", " ".repeat(d))).collect::<String>(), "nested 33 deep"),
        ] {
            std::fs::write(&file, &text).unwrap();
            let start = std::time::Instant::now();
            let e = load::<EstimatorParams>(&node).unwrap_err().to_string();
            assert!(e.contains("g.yaml") && e.contains("deep") && e.contains(words), "{e}");
            // Linear: well under a second even unoptimised (the parser itself took 21 s).
            assert!(start.elapsed() < std::time::Duration::from_secs(5), "{:?}", start.elapsed());
        }
        let big = format!("estimator:\n  ros__parameters:\n    window: 1000\n#{}\n", "x".repeat(MAX_YAML_BYTES as usize));
        std::fs::write(&file, big).unwrap();
        let e = load::<EstimatorParams>(&node).unwrap_err().to_string();
        assert!(e.contains("g.yaml") && e.contains("larger than 1048576 bytes"), "{e}");
        std::fs::write(&file, b"estimator:\n  ros__parameters:\n    model: k\xffc\n").unwrap();
        let e = load::<EstimatorParams>(&node).unwrap_err().to_string();
        assert!(e.contains("line 3 column 13") && e.contains("not UTF-8"), "{e}");
        // A window of 1e12 samples (it once aborted the process allocating 727 GB): refused
        // with its range before anything is allocated.
        let huge = parse_args("estimator", args(&["--ros-args", "-p", "window:=1000000000000"])).unwrap();
        let e = load::<EstimatorParams>(&huge).unwrap_err().to_string();
        assert!(e.contains("window") && e.contains("10000000") && e.contains("1000000000000"), "{e}");
        // An alias bomb: refused before the parser expands it.
        std::fs::write(&file, "a: &a [x, x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a]\nestimator:\n  ros__parameters:\n    window: 1000\n").unwrap();
        let e = load::<EstimatorParams>(&node).unwrap_err().to_string();
        assert!(e.contains("g.yaml") && e.contains("line 2 column 8") && e.contains("alias"), "{e}");
        // A real file passes the pre-check.
        let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../launch_configs/params/sim_rig.yaml");
        read_yaml(&shipped).unwrap();
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
