//! `--stats-json FILE`: a render's statistics as one JSON document for scripts, built from the same
//! `hslt.*` fields the EXR header carries, so the two never disagree. Dotted keys nest
//! (`hslt.mlt.lens.proposed` → `{"mlt": {"lens": {"proposed": …}}}`) and values that read as
//! numbers or booleans are written as such.

use crate::image::Metadata;
use serde_json::{Map, Number, Value};

/// The JSON document of a render's metadata (its `hslt.*` keys; others are left out).
pub fn stats_document(meta: &Metadata) -> Value {
    let mut root = Map::new();
    for (key, value) in meta {
        let Some(path) = key.strip_prefix("hslt.") else { continue };
        insert(&mut root, &path.split('.').collect::<Vec<_>>(), typed(value));
    }
    Value::Object(root)
}

fn insert(map: &mut Map<String, Value>, path: &[&str], value: Value) {
    let [head, rest @ ..] = path else { return };
    if rest.is_empty() {
        match map.get_mut(*head) {
            // A key that is also a prefix of others (none today) keeps both: the leaf as "value".
            Some(Value::Object(inner)) => {
                inner.insert("value".into(), value);
            }
            _ => {
                map.insert(head.to_string(), value);
            }
        }
        return;
    }
    let entry = map.entry(head.to_string()).or_insert_with(|| Value::Object(Map::new()));
    if !entry.is_object() {
        let leaf = entry.take();
        let mut inner = Map::new();
        inner.insert("value".into(), leaf);
        *entry = Value::Object(inner);
    }
    if let Value::Object(inner) = entry {
        insert(inner, rest, value);
    }
}

/// "12" → 12, "0.36" → 0.36, "true" → true; anything else (and non-finite numbers) stays a string.
fn typed(text: &str) -> Value {
    if let Ok(i) = text.parse::<i64>() {
        return Value::Number(i.into());
    }
    if let Ok(u) = text.parse::<u64>() {
        return Value::Number(u.into());
    }
    if let Some(n) = text.parse::<f64>().ok().and_then(Number::from_f64) {
        return Value::Number(n);
    }
    match text {
        "true" => Value::Bool(true),
        "false" => Value::Bool(false),
        _ => Value::String(text.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dotted_keys_nest_and_values_are_typed() {
        let meta: Metadata = [
            ("hslt.integrator", "pssmlt"),
            ("hslt.seed", "7"),
            ("hslt.elapsed_seconds", "1.250"),
            ("hslt.interrupted", "false"),
            ("hslt.mlt.acceptance", "0.3586"),
            ("hslt.mlt.lens.proposed", "328"),
            ("hslt.mlt.lens.failed.occluded", "25"),
            ("hslt.mlt.hslt.direction", "camera"),
            ("hslt.mlt.normalization", "NaN"),
            ("other.key", "left out"),
        ]
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
        let doc = stats_document(&meta);
        assert_eq!(doc["integrator"], "pssmlt");
        assert_eq!(doc["seed"], 7);
        assert_eq!(doc["elapsed_seconds"], 1.25);
        assert_eq!(doc["interrupted"], false);
        assert_eq!(doc["mlt"]["acceptance"], 0.3586);
        assert_eq!(doc["mlt"]["lens"]["proposed"], 328);
        assert_eq!(doc["mlt"]["lens"]["failed"]["occluded"], 25);
        assert_eq!(doc["mlt"]["hslt"]["direction"], "camera");
        assert_eq!(doc["mlt"]["normalization"], "NaN");
        assert!(doc.get("other").is_none());
    }

    #[test]
    fn a_key_that_is_also_a_prefix_keeps_both_values() {
        let meta: Metadata = vec![
            ("hslt.a".into(), "1".into()),
            ("hslt.a.b".into(), "2".into()),
            ("hslt.c.d".into(), "3".into()),
        ];
        let mut more = meta.clone();
        more.push(("hslt.c".into(), "4".into()));
        let doc = stats_document(&more);
        assert_eq!(doc["a"]["value"], 1);
        assert_eq!(doc["a"]["b"], 2);
        assert_eq!(doc["c"]["d"], 3);
        assert_eq!(doc["c"]["value"], 4);
    }
}
