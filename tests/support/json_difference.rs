//! Comparing two JSON documents of one shape number by number.

/// The largest relative difference of the numbers of two JSON documents of one shape whose
/// other values are equal; `Err` names the first place they are not.
pub fn largest_difference(a: &serde_json::Value, b: &serde_json::Value, at: &str) -> Result<f64, String> {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap_or(f64::NAN), y.as_f64().unwrap_or(f64::NAN));
            Ok(if x == y { 0.0 } else { (x - y).abs() / x.abs().max(y.abs()) })
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => {
            x.iter().zip(y).enumerate().try_fold(0.0f64, |m, (i, (p, q))| largest_difference(p, q, &format!("{at}[{i}]")).map(|d| m.max(d)))
        }
        (Value::Object(x), Value::Object(y)) if x.len() == y.len() => x.iter().try_fold(0.0f64, |m, (k, p)| {
            let q = y.get(k).ok_or_else(|| format!("{at}.{k} missing"))?;
            largest_difference(p, q, &format!("{at}.{k}")).map(|d| m.max(d))
        }),
        _ if a == b => Ok(0.0),
        _ => Err(format!("{at}: {a} against {b}")),
    }
}
