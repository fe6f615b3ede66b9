//! RIHS01 type description hashes (ROS 2 REP 2011), as `rosidl_generator_type_description`
//! computes them at build time and rosbag2 stores them per topic (`type_description_hash`
//! in metadata.yaml, `topic_type_hash` in MCAP channel metadata).
//!
//! The hash is SHA-256 over the "hashable" type description as compact-ish JSON (Python's
//! `json.dumps` defaults: `", "` and `": "` separators, keys in the order below):
//!
//! ```text
//! {"type_description": {"type_name": "pkg/msg/T", "fields": [FIELD, ...]},
//!  "referenced_type_descriptions": [{"type_name": ..., "fields": [...]}, ...]}
//! FIELD = {"name": "x", "type": {"type_id": N, "capacity": N, "string_capacity": N,
//!          "nested_type_name": "pkg/msg/U" or ""}}
//! ```
//!
//! Default values and comments are left out of the hashable form; referenced types are every
//! type reachable from the root (each once), sorted by name; a message without fields gets
//! the one field `uint8 structure_needs_at_least_one_member`. `type_id` is the
//! `type_description_interfaces/FieldType` number of the element type, plus 48 for a fixed
//! array, 96 for a bounded sequence, 144 for an unbounded one. A `.msg` `char` is a `uint8`
//! to rosidl (its msg-to-IDL mapping), `byte` an octet.
//!
//! Pure: the definitions come from a lookup, as for [`crate::spec::schema_text`].

use std::collections::BTreeMap;
use std::fmt::Write as _;

use sha2::{Digest, Sha256};

use crate::spec::{base_type, parse_msg, PRIMITIVES};

/// A field type in the hashable description.
#[derive(Debug, Clone, PartialEq, Eq)]
struct FieldType {
    type_id: u32,
    capacity: u64,
    string_capacity: u64,
    nested_type_name: String,
}

#[derive(Debug, Clone, PartialEq, Eq)]
struct TypeDescription {
    type_name: String,
    fields: Vec<(String, FieldType)>,
}

/// `type_description_interfaces/msg/FieldType` ids of the element types.
fn element_type_id(base: &str, bounded_string: bool) -> Option<u32> {
    Some(match base {
        "int8" => 2,
        "uint8" | "char" => 3,
        "int16" => 4,
        "uint16" => 5,
        "int32" => 6,
        "uint32" => 7,
        "int64" => 8,
        "uint64" => 9,
        "float32" => 10,
        "float64" => 11,
        "bool" => 15,
        "byte" => 16,
        "string" if bounded_string => 21,
        "string" => 17,
        "wstring" if bounded_string => 22,
        "wstring" => 18,
        _ => return None,
    })
}

/// `pkg/Type` or `pkg/msg/Type` -> (`pkg`, `Type`).
fn split_type(t: &str) -> Option<(&str, &str)> {
    let parts: Vec<&str> = t.split('/').collect();
    match parts.as_slice() {
        [p, t] if !p.is_empty() && !t.is_empty() => Some((p, t)),
        [p, "msg", t] if !p.is_empty() && !t.is_empty() => Some((p, t)),
        _ => None,
    }
}

/// Parses a field type as written in a (qualified) .msg: `float64[4]`, `string<=8[<=3]`,
/// `pkg/Type[]`.
fn field_type(ty: &str) -> Result<FieldType, String> {
    let (element, array) = match ty.find('[') {
        Some(i) => {
            let inner = ty[i..].strip_prefix('[').and_then(|s| s.strip_suffix(']')).ok_or_else(|| format!("`{ty}`: bad array brackets"))?;
            (&ty[..i], Some(inner))
        }
        None => (ty, None),
    };
    let number = |s: &str| s.trim().parse::<u64>().map_err(|_| format!("`{ty}`: `{s}` is not a size"));
    let (increment, capacity) = match array {
        None => (0, 0),
        Some("") => (144, 0),
        Some(s) => match s.strip_prefix("<=") {
            Some(n) => (96, number(n)?),
            None => (48, number(s)?),
        },
    };
    let base = base_type(element);
    let string_capacity = match element.split_once("<=") {
        Some((_, n)) => number(n)?,
        None => 0,
    };
    if PRIMITIVES.contains(&base) {
        let id = element_type_id(base, string_capacity > 0).ok_or_else(|| format!("`{ty}`: no type description id for `{base}`"))?;
        return Ok(FieldType { type_id: id + increment, capacity, string_capacity, nested_type_name: String::new() });
    }
    let (p, t) = split_type(base).ok_or_else(|| format!("`{ty}`: `{base}` is not pkg/Type"))?;
    Ok(FieldType { type_id: 1 + increment, capacity, string_capacity: 0, nested_type_name: format!("{p}/msg/{t}") })
}

fn describe<'a>(
    pkg: &str,
    ty: &str,
    lookup: &dyn Fn(&str, &str) -> Option<&'a str>,
    all: &mut BTreeMap<String, TypeDescription>,
    depth: usize,
) -> Result<(), String> {
    let name = format!("{pkg}/msg/{ty}");
    if all.contains_key(&name) {
        return Ok(());
    }
    if depth > 32 {
        return Err(format!("dependencies of {name} nest deeper than 32"));
    }
    let text = lookup(pkg, ty).ok_or_else(|| format!("no definition for {name}"))?;
    let spec = parse_msg(text, pkg).map_err(|e| format!("{name}.msg line {e}"))?;
    let mut fields = Vec::with_capacity(spec.fields.len().max(1));
    for f in &spec.fields {
        fields.push((f.name.clone(), field_type(&f.ty).map_err(|e| format!("{name}: field {}: {e}", f.name))?));
    }
    if fields.is_empty() {
        fields.push(("structure_needs_at_least_one_member".into(), FieldType { type_id: 3, capacity: 0, string_capacity: 0, nested_type_name: String::new() }));
    }
    let nested: Vec<String> = fields.iter().map(|(_, t)| t.nested_type_name.clone()).filter(|n| !n.is_empty()).collect();
    all.insert(name, TypeDescription { type_name: format!("{pkg}/msg/{ty}"), fields });
    for n in nested {
        // Built by field_type as `pkg/msg/Type`, so it splits.
        let (p, t) = split_type(&n).ok_or_else(|| format!("`{n}` is not pkg/msg/Type"))?;
        describe(p, t, lookup, all, depth + 1)?;
    }
    Ok(())
}

/// A JSON string literal as Python's `json.dumps` writes it (ASCII only, `\uXXXX` escapes).
fn json_string(s: &str, out: &mut String) {
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            '\u{8}' => out.push_str("\\b"),
            '\u{c}' => out.push_str("\\f"),
            c if (c as u32) < 0x20 || (c as u32) > 0x7e => {
                let mut buf = [0u16; 2];
                for unit in c.encode_utf16(&mut buf) {
                    // Writing to a String cannot fail.
                    let _ = write!(out, "\\u{unit:04x}");
                }
            }
            c => out.push(c),
        }
    }
    out.push('"');
}

fn json_description(d: &TypeDescription, out: &mut String) {
    out.push_str("{\"type_name\": ");
    json_string(&d.type_name, out);
    out.push_str(", \"fields\": [");
    for (i, (name, t)) in d.fields.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        out.push_str("{\"name\": ");
        json_string(name, out);
        // Writing to a String cannot fail.
        let _ = write!(
            out,
            ", \"type\": {{\"type_id\": {}, \"capacity\": {}, \"string_capacity\": {}, \"nested_type_name\": ",
            t.type_id, t.capacity, t.string_capacity
        );
        json_string(&t.nested_type_name, out);
        out.push_str("}}");
    }
    out.push_str("]}");
}

/// The hashable type description of `root` (`pkg/msg/Type` or `pkg/Type`) as the JSON text
/// that is hashed. `lookup(package, type)` returns a type's .msg text.
pub fn hashable_json<'a>(root: &str, lookup: &dyn Fn(&str, &str) -> Option<&'a str>) -> Result<String, String> {
    let (pkg, ty) = split_type(root).ok_or_else(|| format!("`{root}` is not pkg/Type or pkg/msg/Type"))?;
    let mut all = BTreeMap::new();
    describe(pkg, ty, lookup, &mut all, 0)?;
    let root_name = format!("{pkg}/msg/{ty}");
    let mut out = String::from("{\"type_description\": ");
    // describe() inserted the root first.
    let root_desc = all.remove(&root_name).ok_or_else(|| format!("{root_name} was not described"))?;
    json_description(&root_desc, &mut out);
    out.push_str(", \"referenced_type_descriptions\": [");
    for (i, d) in all.values().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        json_description(d, &mut out);
    }
    out.push_str("]}");
    Ok(out)
}

/// The RIHS01 hash of `root`: `RIHS01_` and 64 lower-case hex digits.
pub fn type_hash<'a>(root: &str, lookup: &dyn Fn(&str, &str) -> Option<&'a str>) -> Result<String, String> {
    let json = hashable_json(root, lookup)?;
    let digest = Sha256::digest(json.as_bytes());
    let mut out = String::with_capacity(7 + 64);
    out.push_str("RIHS01_");
    for b in digest {
        // Writing to a String cannot fail.
        let _ = write!(out, "{b:02x}");
    }
    Ok(out)
}

/// The definitions in a `ros2msg` schema text (the root's .msg, then each dependency after a
/// line of 80 `=` and `MSG: pkg/Type` or `MSG: pkg/msg/Type`), keyed by (`pkg`, `Type`).
pub fn definitions_of_schema(root: &str, schema_text: &str) -> Result<BTreeMap<(String, String), String>, String> {
    let (pkg, ty) = split_type(root).ok_or_else(|| format!("`{root}` is not pkg/Type or pkg/msg/Type"))?;
    let mut out = BTreeMap::new();
    let mut current = (pkg.to_string(), ty.to_string());
    let mut text = String::new();
    let mut lines = schema_text.lines().peekable();
    while let Some(line) = lines.next() {
        if line.len() == 80 && line.bytes().all(|b| b == b'=') {
            if let Some(next) = lines.peek().and_then(|l| l.strip_prefix("MSG: ")) {
                let name = next.trim();
                let (p, t) = split_type(name).ok_or_else(|| format!("schema of {root}: `MSG: {name}` is not pkg/Type"))?;
                out.insert(std::mem::replace(&mut current, (p.to_string(), t.to_string())), std::mem::take(&mut text));
                lines.next();
                continue;
            }
        }
        text.push_str(line);
        text.push('\n');
    }
    out.insert(current, text);
    Ok(out)
}
