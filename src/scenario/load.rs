//! Reading scenario files, with errors that name file, line, column and field.

use std::path::{Path, PathBuf};

use super::{CheckedScenario, FieldError, Scenario};

/// A scenario that cannot be used: where and why.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioError {
    /// The file.
    pub file: String,
    /// 1-based line, 0 if unknown.
    pub line: usize,
    /// 1-based column, 0 if unknown.
    pub column: usize,
    /// The field, as a dotted path, if known.
    pub field: String,
    /// What is wrong.
    pub message: String,
}

impl std::fmt::Display for ScenarioError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.file)?;
        if self.line > 0 {
            write!(f, ":{}:{}", self.line, self.column)?;
        }
        if !self.field.is_empty() {
            write!(f, ": field `{}`", self.field)?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for ScenarioError {}

/// File format of a scenario.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// TOML.
    Toml,
    /// JSON.
    Json,
}

impl Format {
    /// From a file extension: `.json` is JSON, anything else TOML.
    pub fn from_path(path: &Path) -> Self {
        match path.extension().and_then(|e| e.to_str()) {
            Some(e) if e.eq_ignore_ascii_case("json") => Format::Json,
            _ => Format::Toml,
        }
    }
}

/// Reads, parses and checks the scenario at `path`.
///
/// # Errors
/// [`ScenarioError`] naming the file, line, column and field.
pub fn load(path: &Path) -> Result<CheckedScenario, ScenarioError> {
    let text = std::fs::read_to_string(path).map_err(|e| ScenarioError {
        file: path.display().to_string(),
        line: 0,
        column: 0,
        field: String::new(),
        message: format!("cannot read: {e}"),
    })?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    load_str(&text, Format::from_path(path), path, &base)
}

/// Parses and checks scenario `text`; `source` names it in errors, `base_dir` resolves relative paths.
///
/// # Errors
/// [`ScenarioError`] naming the file, line, column and field.
pub fn load_str(text: &str, format: Format, source: &Path, base_dir: &Path) -> Result<CheckedScenario, ScenarioError> {
    let file = source.display().to_string();
    let spec: Scenario = match format {
        Format::Toml => toml::from_str(text).map_err(|e| {
            let offset = e.span().map(|s| s.start).unwrap_or(0);
            let (line, column) = line_col(text, offset);
            ScenarioError {
                file: file.clone(),
                line,
                column,
                field: toml_key_at(text, offset),
                message: e.message().trim().to_owned(),
            }
        })?,
        Format::Json => serde_json::from_str(text).map_err(|e| {
            let offset = offset_of(text, e.line(), e.column());
            let message = e.to_string();
            let message = message.split(" at line ").next().unwrap_or(&message).to_owned();
            ScenarioError {
                file: file.clone(),
                line: e.line(),
                column: e.column(),
                field: json_key_before(text, offset),
                message,
            }
        })?,
    };
    let checked = spec.check(base_dir).map_err(|FieldError { path, message }| {
        let (line, column) = match format {
            Format::Toml => locate_toml(text, &path),
            Format::Json => locate_json(text, &path),
        }
        .map(|o| line_col(text, o))
        .unwrap_or((0, 0));
        ScenarioError { file: file.clone(), line, column, field: path, message }
    })?;
    Ok(CheckedScenario {
        spec,
        source: PathBuf::from(source),
        observer_trajectory: checked.observer,
        target_trajectories: checked.targets,
        sky_image: checked.sky_image,
        sensor: checked.sensor,
    })
}

/// 1-based line and column of byte `offset`.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

fn offset_of(text: &str, line: usize, column: usize) -> usize {
    let mut offset = 0;
    for (i, l) in text.split_inclusive('\n').enumerate() {
        if i + 1 == line {
            return offset + column.saturating_sub(1).min(l.len());
        }
        offset += l.len();
    }
    text.len()
}

/// The key on the TOML line holding `offset` (`key = …`), or the table header there.
fn toml_key_at(text: &str, offset: usize) -> String {
    let start = text[..offset.min(text.len())].rfind('\n').map_or(0, |i| i + 1);
    let line = text[start..].lines().next().unwrap_or("");
    let line = line.trim();
    if let Some((key, _)) = line.split_once('=') {
        return key.trim().trim_matches('"').to_owned();
    }
    line.trim_matches(|c| c == '[' || c == ']').to_owned()
}

/// The last `"key":` before `offset` in JSON text.
fn json_key_before(text: &str, offset: usize) -> String {
    let before = &text[..offset.min(text.len())];
    let Some(colon) = before.rfind("\":") else { return String::new() };
    let key_end = colon;
    let key_start = before[..key_end].rfind('"').map_or(0, |i| i + 1);
    before[key_start..key_end].to_owned()
}

/// Splits `a.b[2].c` into keys and indices.
fn path_parts(path: &str) -> Vec<(String, Option<usize>)> {
    path.split('.')
        .filter(|p| !p.is_empty())
        .map(|p| match p.split_once('[') {
            Some((k, rest)) => (k.to_owned(), rest.trim_end_matches(']').parse().ok()),
            None => (p.to_owned(), None),
        })
        .collect()
}

/// Byte offset of the deepest part of `path` that exists in the TOML document.
fn locate_toml(text: &str, path: &str) -> Option<usize> {
    use toml::de::{DeTable, DeValue};
    let doc = DeTable::parse(text).ok()?;
    let mut table: &DeTable = doc.get_ref();
    let mut best = None;
    for (key, index) in path_parts(path) {
        let (k, v) = table.get_key_value(key.as_str())?;
        best = Some(k.span().start);
        let mut value = v;
        if let Some(i) = index {
            if let DeValue::Array(items) = value.get_ref() {
                let item = items.get(i)?;
                best = Some(item.span().start);
                value = item;
            } else {
                return best;
            }
        }
        match value.get_ref() {
            DeValue::Table(t) => table = t,
            _ => return best,
        }
    }
    best
}

/// Byte offset of the last key of `path` found in order in the JSON text (a textual search).
fn locate_json(text: &str, path: &str) -> Option<usize> {
    let mut from = 0;
    let mut best = None;
    for (key, _) in path_parts(path) {
        let needle = format!("\"{key}\"");
        match text[from..].find(&needle) {
            Some(i) => {
                from += i + needle.len();
                best = Some(from - needle.len());
            }
            None => break,
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
[sensor]
width = 64
height = 48
pixel_pitch_um = 17
focal_length_mm = 100
aperture_mm = 100
band_um = [8, 12]

[observer]
trajectory = { kind = "constant_velocity", position_m = [0, 0, 8000] }
pointing = { mode = "yaw_pitch_roll", yaw_deg = 0 }
"#;

    fn load_toml(text: &str) -> Result<CheckedScenario, ScenarioError> {
        load_str(text, Format::Toml, Path::new("s.toml"), Path::new("."))
    }

    #[test]
    fn minimal_scenario_loads() {
        let s = load_toml(MINIMAL).unwrap();
        assert_eq!(s.sensor.intrinsics.width, 64);
        assert_eq!(s.spec.run.frames, 100);
    }

    #[test]
    fn unknown_field_names_line_and_field() {
        let text = MINIMAL.replace("aperture_mm = 100", "aperture_mm = 100\napperture = 3");
        let e = load_toml(&text).unwrap_err();
        assert_eq!(e.line, 8, "{e}");
        assert!(e.message.contains("apperture"), "{e}");
        assert_eq!(e.field, "apperture");
    }

    #[test]
    fn semantic_error_is_located() {
        let text = format!("{MINIMAL}\n[sensor.adc]\nnoise_dn = 2.0\nbit_depth = 40\n");
        // [sensor.adc] after [observer] is still valid TOML
        let e = load_toml(&text).unwrap_err();
        assert_eq!(e.field, "sensor.adc.bit_depth", "{e}");
        assert_eq!(e.line, 16, "{e}");
        assert!(e.to_string().starts_with("s.toml:16:1: field `sensor.adc.bit_depth`"), "{e}");
    }

    #[test]
    fn json_errors_have_positions() {
        let e =
            load_str("{\n  \"sensor\": {\"width\": \"wide\"}\n}", Format::Json, Path::new("s.json"), Path::new("."))
                .unwrap_err();
        assert_eq!(e.line, 2);
        assert_eq!(e.field, "width");
    }
}
