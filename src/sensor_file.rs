//! Sensor files: a whole sensor (its gel, optics, camera and markers) as one file that a
//! single MJCF attribute loads (`sensor`), written by `tacrom calibrate --gel` or by hand.
//!
//! A sensor file is JSON:
//!
//! ```json
//! {
//!   "format": "tacrom-sensor-1",
//!   "description": "GelSight Mini, fitted to 16 ball presses",
//!   "attributes": {
//!     "size": "0.0189 0.0142 0.0023",
//!     "poisson": 0.45,
//!     "fov": [0.01888, 0.01416],
//!     "optics": "optics.json",
//!     "view": "camera"
//!   },
//!   "calibration": {"anything": "the plugin does not read it"}
//! }
//! ```
//!
//! `attributes` holds MJCF attributes with the values MJCF would give them (text, or a
//! number or a list of numbers, written as MJCF writes them); every attribute but `sensor`
//! itself may appear. A path in it (`optics`, and `model` where it names a folder beside
//! the file) is relative to the file's folder. The file's attributes are the sensor's
//! defaults: those the MJCF gives beside `sensor` override them. `description`,
//! `calibration` and `source` are for people and tools; any other key is refused, so that
//! a misspelt key fails the load instead of being ignored.
//!
//! `sensor` takes a path (a file, or a folder holding `sensor.json`) or the name of a
//! shipped sensor (`gelsight-mini`: `sensors/gelsight-mini/sensor.json`, found beside
//! the plugin library or in the checkout, see [`crate::shipped_dir`]).

use std::path::{Path, PathBuf};

use serde_json::{Map, Value};

/// The `format` of a sensor file.
pub const FORMAT: &str = "tacrom-sensor-1";
/// The file a sensor folder holds.
pub const FILE_NAME: &str = "sensor.json";
/// The sensors shipped with the plugin, by name.
pub const SHIPPED: &[&str] = &["gelsight-mini"];
/// Keys of a sensor file besides `format` and `attributes`, which the plugin does not read.
const INFORMATIONAL: &[&str] = &["description", "calibration", "source"];

/// A sensor file, read and checked.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorFile {
    /// Where it was read from.
    pub path: PathBuf,
    /// Its attributes as MJCF text, paths made relative to the working directory, in the
    /// order the plugin's attribute table lists them.
    pub attributes: Vec<(String, String)>,
}

/// The file the `sensor` attribute's `value` names: a shipped sensor's name, a folder
/// holding [`FILE_NAME`], or a file.
pub fn locate(value: &str) -> Result<PathBuf, String> {
    let value = value.trim();
    let path = Path::new(value);
    if SHIPPED.contains(&value) && !path.exists() {
        return crate::shipped_dir("sensors", value, FILE_NAME)
            .map(|d| d.join(FILE_NAME))
            .ok_or_else(|| {
                format!(
                    "the shipped sensor sensors/{value} was not found beside the plugin library \
                     or in its checkout"
                )
            });
    }
    let file = if path.is_dir() {
        path.join(FILE_NAME)
    } else {
        path.to_path_buf()
    };
    if file.is_file() {
        return Ok(file);
    }
    let shipped = SHIPPED.join(", ");
    Err(if path.is_dir() {
        format!("the folder holds no {FILE_NAME}")
    } else {
        format!("no such file (a sensor file, a folder holding {FILE_NAME}, or a shipped sensor: {shipped})")
    })
}

impl SensorFile {
    /// Reads and checks the sensor file the `sensor` attribute's `value` names
    /// ([`locate`]). The message names what is wrong (the caller names the attribute).
    pub fn read(value: &str) -> Result<SensorFile, String> {
        let path = locate(value)?;
        let text = std::fs::read_to_string(&path)
            .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        Self::parse(&path, &text).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Checks the text of the sensor file at `path`.
    pub fn parse(path: &Path, text: &str) -> Result<SensorFile, String> {
        let root: Value = serde_json::from_str(text).map_err(|e| format!("not JSON: {e}"))?;
        let Value::Object(root) = root else {
            return Err("expected a JSON object".into());
        };
        match root.get("format") {
            Some(Value::String(f)) if f == FORMAT => {}
            Some(f) => return Err(format!("format {f} is not {FORMAT:?}")),
            None => return Err(format!("no \"format\" (expected {FORMAT:?})")),
        }
        if let Some(k) = root.keys().find(|k| {
            !matches!(k.as_str(), "format" | "attributes") && !INFORMATIONAL.contains(&k.as_str())
        }) {
            return Err(format!(
                "unknown key \"{k}\" (a sensor file has \"format\", \"attributes\", {})",
                INFORMATIONAL
                    .iter()
                    .map(|k| format!("\"{k}\""))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        let attributes = match root.get("attributes") {
            None => Map::new(),
            Some(Value::Object(a)) => a.clone(),
            Some(_) => return Err("\"attributes\" is not an object".into()),
        };
        let folder = path.parent().unwrap_or(Path::new(""));
        for name in attributes.keys() {
            if name == crate::attributes::SENSOR.name {
                return Err("attribute \"sensor\": a sensor file cannot name another".into());
            }
            if crate::attributes::named(name).is_none() {
                return Err(format!("unknown attribute \"{name}\""));
            }
        }
        let mut out = Vec::new();
        for a in crate::attributes::TABLE {
            let Some(v) = attributes.get(a.name) else {
                continue;
            };
            let text = mjcf_text(v).ok_or_else(|| {
                format!(
                    "attribute \"{}\" = {v}: expected text, a number or a list of numbers",
                    a.name
                )
            })?;
            let text = match a.name {
                "optics" => folder.join(text.trim()).display().to_string(),
                "model" => {
                    let beside = folder.join(text.trim());
                    if beside.is_dir() {
                        beside.display().to_string()
                    } else {
                        text
                    }
                }
                _ => text,
            };
            if !text.trim().is_empty() {
                out.push((a.name.to_owned(), text));
            }
        }
        Ok(SensorFile {
            path: path.to_path_buf(),
            attributes: out,
        })
    }
}

/// `v` as MJCF writes it: text as it is, a number, numbers separated by spaces.
fn mjcf_text(v: &Value) -> Option<String> {
    match v {
        Value::String(s) => Some(s.clone()),
        Value::Number(n) => Some(n.to_string()),
        Value::Bool(b) => Some(b.to_string()),
        Value::Array(items) => items
            .iter()
            .map(|i| match i {
                Value::Number(n) => Some(n.to_string()),
                Value::String(s) => Some(s.clone()),
                _ => None,
            })
            .collect::<Option<Vec<_>>>()
            .map(|w| w.join(" ")),
        _ => None,
    }
}

/// A sensor file holding `attributes` (MJCF text), as `tacrom calibrate --gel` writes it:
/// the JSON text, with `description` and `calibration` for people and tools.
pub fn to_json(attributes: &[(String, String)], description: &str, calibration: Value) -> String {
    let mut a = Map::new();
    for (k, v) in attributes {
        a.insert(k.clone(), Value::String(v.clone()));
    }
    let mut root = Map::new();
    root.insert("format".into(), Value::String(FORMAT.into()));
    root.insert("description".into(), Value::String(description.into()));
    root.insert("attributes".into(), Value::Object(a));
    root.insert("calibration".into(), calibration);
    serde_json::to_string_pretty(&Value::Object(root)).expect("JSON of strings") + "\n"
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<SensorFile, String> {
        SensorFile::parse(Path::new("/sensors/mine/sensor.json"), text)
    }

    /// Text, numbers and lists all become MJCF text; the optics path is the file's
    /// folder's; the table's order is kept whatever the file's.
    #[test]
    fn attributes_become_mjcf_text_with_paths_beside_the_file() {
        let f = parse(
            r#"{"format": "tacrom-sensor-1", "description": "x",
                "attributes": {"optics": "optics.json", "poisson": 0.45,
                               "size": [0.02, 0.015, 0.002], "view": "camera"}}"#,
        )
        .unwrap();
        let get = |k: &str| {
            f.attributes
                .iter()
                .find(|(a, _)| a == k)
                .map(|(_, v)| v.as_str())
        };
        assert_eq!(get("poisson"), Some("0.45"));
        assert_eq!(get("size"), Some("0.02 0.015 0.002"));
        assert_eq!(get("optics"), Some("/sensors/mine/optics.json"));
        let order: Vec<_> = f.attributes.iter().map(|(a, _)| a.as_str()).collect();
        let table: Vec<_> = crate::attributes::TABLE
            .iter()
            .map(|a| a.name)
            .filter(|n| order.contains(n))
            .collect();
        assert_eq!(order, table);
    }

    /// What `to_json` writes reads back as the same attributes.
    #[test]
    fn a_written_file_reads_back() {
        let attributes = vec![
            ("size".to_owned(), "0.02 0.015 0.002".to_owned()),
            ("poisson".to_owned(), "0.4".to_owned()),
        ];
        let text = to_json(&attributes, "d", serde_json::json!({"presses": 3}));
        assert_eq!(parse(&text).unwrap().attributes, attributes);
    }

    /// Each fault is named: not JSON, no or another format, an unknown key or attribute,
    /// a nested `sensor`, a value of the wrong kind.
    #[test]
    fn bad_files_are_refused_with_the_fault_named() {
        let cases = [
            ("{", "not JSON"),
            (r#"{"attributes": {}}"#, "no \"format\""),
            (r#"{"format": "tacrom-sensor-9"}"#, "is not"),
            (
                r#"{"format": "tacrom-sensor-1", "atributes": {}}"#,
                "unknown key \"atributes\"",
            ),
            (
                r#"{"format": "tacrom-sensor-1", "attributes": {"youngs": "1"}}"#,
                "unknown attribute \"youngs\"",
            ),
            (
                r#"{"format": "tacrom-sensor-1", "attributes": {"sensor": "a"}}"#,
                "cannot name another",
            ),
            (
                r#"{"format": "tacrom-sensor-1", "attributes": {"poisson": {"v": 1}}}"#,
                "attribute \"poisson\"",
            ),
            (
                r#"{"format": "tacrom-sensor-1", "attributes": []}"#,
                "not an object",
            ),
        ];
        for (text, fault) in cases {
            let e = parse(text).unwrap_err();
            assert!(e.contains(fault), "{text}: {e}");
        }
    }

    /// A missing file or folder says what `sensor` takes.
    #[test]
    fn a_missing_file_names_what_sensor_takes() {
        let e = SensorFile::read("/no/such/sensor.json").unwrap_err();
        assert!(e.contains("gelsight-mini"), "{e}");
    }
}
