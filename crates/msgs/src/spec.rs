//! Reading `.msg` definitions (the single source of truth) and writing the `ros2msg` schema
//! text a bag stores for a type.

use std::collections::{BTreeSet, HashSet};

/// One field of a .msg: `float64[4] stiffness_n_m`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FieldSpec {
    pub name: String,
    /// The type as written, with a same-package type qualified (`Foo` -> `pkg/Foo`).
    pub ty: String,
    /// Default value as written, if any.
    pub default: Option<String>,
}

/// One constant of a .msg: `uint8 MODEL_KC=0`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConstantSpec {
    pub name: String,
    pub ty: String,
    pub value: String,
}

#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct MsgSpec {
    pub fields: Vec<FieldSpec>,
    pub constants: Vec<ConstantSpec>,
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{line}: {what}")]
pub struct SpecError {
    /// 1-based line number.
    pub line: usize,
    pub what: String,
}

/// The primitive types of .msg files.
pub const PRIMITIVES: &[&str] =
    &["bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "string", "wstring"];

/// The base type of a field type: `float64[4]` -> `float64`, `string<=8[]` -> `string`.
pub fn base_type(ty: &str) -> &str {
    let t = ty.split('[').next().unwrap_or(ty);
    t.split("<=").next().unwrap_or(t)
}

/// Parse a .msg text. `package` qualifies types named without a package.
pub fn parse_msg(text: &str, package: &str) -> Result<MsgSpec, SpecError> {
    let mut spec = MsgSpec::default();
    for (i, raw) in text.lines().enumerate() {
        let line_no = i + 1;
        let err = |what: String| SpecError { line: line_no, what };
        let trimmed = raw.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let mut parts = trimmed.splitn(2, char::is_whitespace);
        let ty = parts.next().unwrap_or_default();
        let rest = parts.next().unwrap_or_default().trim_start();
        if rest.is_empty() {
            return Err(err(format!("`{trimmed}`: a type without a name")));
        }
        let base = base_type(ty);
        let ty = if PRIMITIVES.contains(&base) || base.contains('/') { ty.to_string() } else { format!("{package}/{ty}") };
        // A constant: NAME=value (a string constant's value is the rest of the line).
        let name_end = rest.find(|c: char| c == '=' || c.is_whitespace() || c == '#').unwrap_or(rest.len());
        let name = &rest[..name_end];
        let after = rest[name_end..].trim_start();
        if name.is_empty() || !name.chars().next().is_some_and(|c| c.is_ascii_alphabetic()) {
            return Err(err(format!("`{trimmed}`: bad name")));
        }
        if !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(err(format!("`{name}`: names are letters, digits and underscores")));
        }
        if let Some(v) = after.strip_prefix('=') {
            let value = if base == "string" || base == "wstring" { v.trim().to_string() } else { strip_comment(v).trim().to_string() };
            if value.is_empty() {
                return Err(err(format!("constant `{name}` has no value")));
            }
            spec.constants.push(ConstantSpec { name: name.into(), ty, value });
        } else {
            if name.chars().any(|c| c.is_ascii_uppercase()) {
                return Err(err(format!("field `{name}`: field names are lower case")));
            }
            let default = strip_comment(after).trim();
            spec.fields.push(FieldSpec { name: name.into(), ty, default: (!default.is_empty()).then(|| default.to_string()) });
        }
    }
    Ok(spec)
}

fn strip_comment(s: &str) -> &str {
    s.split('#').next().unwrap_or(s)
}

/// How a dependency is named after `MSG: ` in the schema text.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SchemaNaming {
    /// As the field type is written in the .msg (`std_msgs/Header`): what rosbag2's
    /// `LocalMessageDefinitionSource` writes.
    AsWritten,
    /// Fully qualified (`std_msgs/msg/Header`): the form in rosbag2's
    /// `docs/message_definition_encoding.md`. Readers accept both.
    Qualified,
}

/// The `ros2msg` schema text of `root` (`pkg/msg/Type` or `pkg/Type`): its .msg text, then
/// each dependency once, depth first, a message's dependencies in sorted order, each after
/// a line of 80 `=` and a line `MSG: <type>`, joined by newlines (the order rosbag2 uses).
///
/// `lookup(package, type)` returns a type's .msg text.
pub fn schema_text<'a>(root: &str, naming: SchemaNaming, lookup: &dyn Fn(&str, &str) -> Option<&'a str>) -> Result<String, String> {
    let (pkg, ty) = split_type(root).ok_or_else(|| format!("`{root}` is not pkg/Type or pkg/msg/Type"))?;
    let mut seen = HashSet::new();
    let mut out = String::new();
    append(pkg, ty, naming, lookup, &mut seen, &mut out, 0)?;
    Ok(out)
}

fn split_type(t: &str) -> Option<(&str, &str)> {
    let parts: Vec<&str> = t.split('/').collect();
    match parts.as_slice() {
        [p, t] => Some((p, t)),
        [p, "msg", t] => Some((p, t)),
        _ => None,
    }
}

fn append<'a>(
    pkg: &str,
    ty: &str,
    naming: SchemaNaming,
    lookup: &dyn Fn(&str, &str) -> Option<&'a str>,
    seen: &mut HashSet<String>,
    out: &mut String,
    depth: usize,
) -> Result<(), String> {
    if depth > 32 {
        return Err(format!("dependencies of {pkg}/{ty} nest deeper than 32"));
    }
    let text = lookup(pkg, ty).ok_or_else(|| format!("no definition for {pkg}/msg/{ty}"))?;
    out.push_str(text);
    let spec = parse_msg(text, pkg).map_err(|e| format!("{pkg}/msg/{ty}.msg line {e}"))?;
    let deps: BTreeSet<String> = spec.fields.iter().map(|f| base_type(&f.ty).to_string()).filter(|b| !PRIMITIVES.contains(&b.as_str())).collect();
    for dep in deps {
        let (dp, dt) = split_type(&dep).ok_or_else(|| format!("`{dep}` in {pkg}/msg/{ty} is not pkg/Type"))?;
        if !seen.insert(format!("{dp}/{dt}")) {
            continue;
        }
        out.push('\n');
        out.push_str(&"=".repeat(80));
        out.push_str("\nMSG: ");
        match naming {
            SchemaNaming::AsWritten => out.push_str(&dep),
            SchemaNaming::Qualified => out.push_str(&format!("{dp}/msg/{dt}")),
        }
        out.push('\n');
        append(dp, dt, naming, lookup, seen, out, depth + 1)?;
    }
    Ok(())
}
