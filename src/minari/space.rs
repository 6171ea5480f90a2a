//! Minari's serialized Gymnasium spaces (`observation_space`, `action_space` in metadata.json),
//! read and written.
//!
//! Minari stores a space as a JSON string made by Python's `json.dumps`, which writes unbounded
//! Box bounds as the bare tokens `Infinity` / `-Infinity` (and NaN as `NaN`): not JSON, so
//! serde_json refuses them. pgser needs only the type, dtype and shape, so [`lenient_json`]
//! turns those tokens into nulls before parsing, and the writer spells them as Python does,
//! because Minari parses the bounds back into the Box.

use anyhow::{Context, Result, bail};
use serde_json::Value;

use super::OBS_KEYS;

/// A float `Box` space of one dimension.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BoxSpace {
    pub dim: usize,
    /// Bytes per value: 4 (float32) or 8 (float64).
    pub size: usize,
}

impl BoxSpace {
    pub fn dtype(&self) -> &'static str {
        if self.size == 4 { "float32" } else { "float64" }
    }

    /// The space as Minari serializes a Box (`minari.serialization`), with these bounds.
    pub fn to_json(&self, low: f64, high: f64) -> String {
        let bound = |v: f64| {
            let one = if v == f64::INFINITY {
                "Infinity".to_string()
            } else if v == f64::NEG_INFINITY {
                "-Infinity".to_string()
            } else {
                format!("{v:?}")
            };
            vec![one; self.dim].join(", ")
        };
        format!(
            r#"{{"type": "Box", "dtype": "{}", "shape": [{}], "low": [{}], "high": [{}]}}"#,
            self.dtype(),
            self.dim,
            bound(low),
            bound(high)
        )
    }
}

/// The spaces of a goal-conditioned dataset: observation, achieved_goal, desired_goal, action.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Spaces {
    pub obs: [BoxSpace; 3],
    pub action: BoxSpace,
}

impl Spaces {
    /// Parse metadata.json's two space strings (`at` names the file in errors). Returns the
    /// spaces and the Dict's other keys, each with its subspace as the text metadata.json has it
    /// (Gymnasium's JSON, `Infinity` bounds included), which an export writes back.
    pub fn parse(at: &str, observation: &str, action: &str) -> Result<(Spaces, Vec<(String, String)>)> {
        let obs = parse_json(at, "observation_space", observation)?;
        let act = parse_json(at, "action_space", action)?;
        let kind = |v: &Value| v.get("type").and_then(|t| t.as_str()).unwrap_or("(no type)").to_string();
        if kind(&obs) != "Dict" {
            let shape = obs.get("shape").map(|s| format!(" of shape {s}")).unwrap_or_default();
            bail!(
                "{at}: the observation space is a {}{shape}, not a Dict with observation / achieved_goal / \
                 desired_goal: not a goal-conditioned dataset, which a pgser trajectory table needs",
                kind(&obs)
            );
        }
        let Some(sub) = obs.get("subspaces").and_then(|s| s.as_object()) else {
            bail!("{at}: the observation space is a Dict without subspaces");
        };
        let missing: Vec<&str> = OBS_KEYS.iter().copied().filter(|k| !sub.contains_key(*k)).collect();
        if !missing.is_empty() {
            let have: Vec<&str> = sub.keys().map(String::as_str).collect();
            bail!(
                "{at}: the Dict observation has no '{}' (it has {}): not a goal-conditioned dataset",
                missing.join("', '"),
                have.join(", ")
            );
        }
        let obs = OBS_KEYS.map(|k| float_box(at, &format!("observations/{k}"), &sub[k]));
        let spaces = Spaces { obs: try_all(obs)?, action: float_box(at, "actions", &act)? };
        if spaces.obs[1].dim != spaces.obs[2].dim {
            bail!(
                "{at}: achieved_goal has {} values but desired_goal {}: goals must have one dimension",
                spaces.obs[1].dim,
                spaces.obs[2].dim
            );
        }
        let mut extra = Vec::new();
        for k in sub.keys().filter(|k| !OBS_KEYS.contains(&k.as_str())) {
            let raw = raw_subspace(observation, k)
                .with_context(|| format!("{at}: the observation space's {k:?} cannot be found in its text"))?;
            extra.push((k.clone(), raw));
        }
        Ok((spaces, extra))
    }
}

/// The shape a serialized Box space names (`"shape": [2, 2]`), if any.
pub fn box_shape(raw: &str) -> Option<Vec<usize>> {
    let v: Value = serde_json::from_str(&lenient_json(raw)).ok()?;
    v.get("shape")?.as_array()?.iter().map(|d| d.as_u64().map(|d| d as usize)).collect()
}

/// The text of subspace `key` of a serialized Dict space: the object after `"subspaces"`'s
/// `"key":`, braces matched outside strings.
fn raw_subspace(text: &str, key: &str) -> Option<String> {
    let after = &text[text.find("\"subspaces\"")?..];
    let start = after.find(&format!("\"{key}\":"))? + key.len() + 3;
    let body = &after[start..];
    let open = body.find('{')?;
    let (mut depth, mut in_string, mut escaped) = (0usize, false, false);
    for (i, c) in body[open..].char_indices() {
        if in_string {
            in_string = escaped || c != '"';
            escaped = !escaped && c == '\\';
            continue;
        }
        match c {
            '"' => in_string = true,
            '{' => depth += 1,
            '}' => {
                depth -= 1;
                if depth == 0 {
                    return Some(body[open..open + i + 1].to_string());
                }
            }
            _ => {}
        }
    }
    None
}

fn try_all(boxes: [Result<BoxSpace>; 3]) -> Result<[BoxSpace; 3]> {
    let [a, b, c] = boxes;
    Ok([a?, b?, c?])
}

fn parse_json(at: &str, key: &str, text: &str) -> Result<Value> {
    serde_json::from_str(&lenient_json(text))
        .map_err(|e| anyhow::anyhow!("{at}: {key} is not a serialized space ({e})"))
}

/// A Box of one dimension and a float dtype, or an error naming `key`.
fn float_box(at: &str, key: &str, v: &Value) -> Result<BoxSpace> {
    let kind = v.get("type").and_then(|t| t.as_str()).unwrap_or("(no type)");
    if kind != "Box" {
        bail!("{at}: {key} is a {kind} space; pgser needs float Box spaces");
    }
    let dtype = v.get("dtype").and_then(|d| d.as_str()).unwrap_or("(no dtype)");
    let size = match dtype {
        "float32" => 4,
        "float64" => 8,
        other => bail!("{at}: {key} holds {other} values; pgser needs float32 or float64"),
    };
    let shape: Option<Vec<usize>> = v
        .get("shape")
        .and_then(|s| s.as_array())
        .map(|s| s.iter().filter_map(|d| d.as_u64()).map(|d| d as usize).collect());
    match shape.as_deref() {
        Some(&[dim]) if dim > 0 => Ok(BoxSpace { dim, size }),
        _ => bail!(
            "{at}: {key} has shape {}; pgser needs vectors (one dimension)",
            v.get("shape").unwrap_or(&Value::Null)
        ),
    }
}

/// Python's `json.dumps` output with its non-JSON number tokens (`Infinity`, `-Infinity`,
/// `NaN`) outside strings replaced by `null`.
fn lenient_json(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let (mut in_string, mut escaped) = (false, false);
    let mut rest = text;
    while let Some(c) = rest.chars().next() {
        if in_string {
            in_string = escaped || c != '"';
            escaped = !escaped && c == '\\';
        } else if c == '"' {
            in_string = true;
        } else if let Some(token) = ["-Infinity", "Infinity", "NaN"].into_iter().find(|t| rest.starts_with(t)) {
            out.push_str("null");
            rest = &rest[token.len()..];
            continue;
        }
        out.push(c);
        rest = &rest[c.len_utf8()..];
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const FETCH_OBS: &str = r#"{"type": "Dict", "subspaces": {"achieved_goal": {"type": "Box", "dtype": "float64", "shape": [3], "low": [-Infinity, -Infinity, -Infinity], "high": [Infinity, Infinity, Infinity]}, "desired_goal": {"type": "Box", "dtype": "float64", "shape": [3], "low": [-Infinity, -Infinity, -Infinity], "high": [Infinity, Infinity, Infinity]}, "observation": {"type": "Box", "dtype": "float64", "shape": [10], "low": [-Infinity], "high": [Infinity]}, "image": {"type": "Box", "dtype": "uint8", "shape": [2]}}}"#;
    const FETCH_ACT: &str = r#"{"type": "Box", "dtype": "float32", "shape": [4], "low": [-1.0, -1.0, -1.0, -1.0], "high": [1.0, 1.0, 1.0, 1.0]}"#;

    #[test]
    fn python_infinities_parse_and_extra_keys_are_reported() {
        let (s, extra) = Spaces::parse("m.json", FETCH_OBS, FETCH_ACT).unwrap();
        let skipped: Vec<String> = extra.iter().map(|(k, _)| format!("observations/{k}")).collect();
        assert_eq!(extra[0].1, r#"{"type": "Box", "dtype": "uint8", "shape": [2]}"#);
        assert_eq!(s.obs.map(|b| (b.dim, b.size)), [(10, 8), (3, 8), (3, 8)]);
        assert_eq!((s.action.dim, s.action.size), (4, 4));
        assert_eq!(skipped, ["observations/image"]);
    }

    #[test]
    fn tokens_inside_strings_are_kept() {
        assert_eq!(lenient_json(r#"{"a\"NaN": [NaN, -Infinity]}"#), r#"{"a\"NaN": [null, null]}"#);
    }

    #[test]
    fn written_boxes_read_back() {
        let b = BoxSpace { dim: 2, size: 4 };
        assert_eq!(
            b.to_json(-1.0, f64::INFINITY),
            r#"{"type": "Box", "dtype": "float32", "shape": [2], "low": [-1.0, -1.0], "high": [Infinity, Infinity]}"#
        );
        assert_eq!(float_box("x", "actions", &parse_json("x", "a", &b.to_json(-1.0, 1.0)).unwrap()).unwrap(), b);
    }

    #[test]
    fn a_box_observation_is_not_goal_conditioned() {
        let e = Spaces::parse("m.json", FETCH_ACT, FETCH_ACT).unwrap_err().to_string();
        assert!(e.contains("is a Box of shape [4]") && e.contains("not a goal-conditioned dataset"), "{e}");
    }
}
