//! Reading scenario files, with errors that name file, line, column and field.

use std::path::Path;

use super::locate::Nodes;
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
    load_for_frames(path, None)
}

/// [`load`], checking the scenario for `frames` frames instead of its own `run.frames` (as `record --frames`
/// runs it: the trajectories' bounds are checked over the frames that will run).
///
/// # Errors
/// [`ScenarioError`] naming the file, line, column and field.
pub fn load_for_frames(path: &Path, frames: Option<u64>) -> Result<CheckedScenario, ScenarioError> {
    let text = std::fs::read_to_string(path).map_err(|e| ScenarioError {
        file: path.display().to_string(),
        line: 0,
        column: 0,
        field: String::new(),
        message: format!("cannot read: {e}"),
    })?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    load_str_for_frames(&text, Format::from_path(path), path, &base, frames)
}

/// Parses and checks scenario `text`; `source` names it in errors, `base_dir` resolves relative paths.
///
/// # Errors
/// [`ScenarioError`] naming the file, line, column and field.
pub fn load_str(text: &str, format: Format, source: &Path, base_dir: &Path) -> Result<CheckedScenario, ScenarioError> {
    load_str_for_frames(text, format, source, base_dir, None)
}

fn load_str_for_frames(
    text: &str,
    format: Format,
    source: &Path,
    base_dir: &Path,
    frames: Option<u64>,
) -> Result<CheckedScenario, ScenarioError> {
    let file = source.display().to_string();
    let nodes = || match format {
        Format::Toml => Nodes::toml(text),
        Format::Json => Nodes::json(text),
    };
    let parse_error = |span: Option<(usize, usize)>, message: String| {
        let nodes = nodes();
        let node = match span {
            Some(span) => nodes.at_span(span),
            None => nodes.get(""),
        };
        // A value is the culprit if a value of the expected type in its place makes the message go away without
        // a complaint about the stand-in itself (fields are not always read in document order).
        let (stand_in, named) = if message == "expected value" || message == "wanted string or table" {
            // a name in place of the number: the field that takes names then says the name is unknown
            ("\"0\"", "invalid type: string \"0\"")
        } else if message.contains("expected a boolean") {
            ("true", "boolean `true`")
        } else if message.contains("expected a string") {
            ("\"0\"", "string \"0\"")
        } else {
            ("0", "integer `0`")
        };
        let culprit = |n: &super::locate::Node| {
            let mut t = text.to_owned();
            t.replace_range(n.span.0..n.span.1, stand_in);
            let again = match format {
                Format::Toml => toml::from_str::<Scenario>(&t).err().map(|e| e.message().trim().to_owned()),
                Format::Json => serde_json::from_str::<Scenario>(&t).err().map(|e| e.to_string()),
            };
            again.is_none_or(|m| !m.starts_with(message.as_str()) && !m.contains(named))
        };
        let (field, at) = match node {
            Some(node) => nodes.refine_with(node, &message, &culprit),
            None => (String::new(), None),
        };
        let offset = at.map(|n| n.key_start).or(span.map(|s| s.0)).unwrap_or(0);
        let (line, column) = line_col(text, offset);
        ScenarioError { file: file.clone(), line, column, field, message }
    };
    let spec: Scenario = match format {
        Format::Toml => toml::from_str(text).map_err(|e| {
            let span = e.span().map(|s| (s.start, s.end));
            parse_error(span, e.message().trim().to_owned())
        })?,
        Format::Json => serde_json::from_str(text).map_err(|e| {
            let message = e.to_string();
            let message = message.split(" at line ").next().unwrap_or(&message).to_owned();
            if e.line() == 0 {
                return parse_error(None, message);
            }
            // serde_json's column counts the characters before its position: the byte there is the one after a
            // value it read (a wrong string, a table missing a field) or the first of one it refused on sight (a
            // list or a table where a number belongs); both lie in the value's span, end included
            let offset = offset_of(text, e.line(), e.column());
            parse_error(Some((offset, offset)), message)
        })?,
    };
    let mut spec = spec;
    if let Some(n) = frames {
        spec.run.frames = n;
    }
    spec.checked_in(source, base_dir).map_err(|FieldError { path, message, at }| {
        if let Some(csv) = at {
            return ScenarioError {
                file: csv.file,
                line: csv.line,
                column: csv.column,
                field: path,
                message: format!("{message} (the trajectory file named by {file})"),
            };
        }
        let nodes = nodes();
        let (line, column) = nodes.nearest(&path).map_or((0, 0), |n| line_col(text, n.key_start));
        ScenarioError { file: file.clone(), line, column, field: path, message }
    })
}

/// `path:line:column: field `…`: message` for a fault found after loading (building the simulation), with
/// the field located in the scenario's text as far as it is present.
pub fn located(path: &Path, field: &str, message: &str) -> ScenarioError {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let nodes = match Format::from_path(path) {
        Format::Toml => Nodes::toml(&text),
        Format::Json => Nodes::json(&text),
    };
    let (line, column) = nodes.nearest(field).map_or((0, 0), |n| line_col(&text, n.key_start));
    ScenarioError {
        file: path.display().to_string(),
        line,
        column,
        field: field.to_owned(),
        message: message.to_owned(),
    }
}

/// 1-based line and column of byte `offset`.
pub(crate) fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

fn offset_of(text: &str, line: usize, column: usize) -> usize {
    let mut offset = 0;
    for (i, l) in text.split_inclusive('\n').enumerate() {
        if i + 1 == line {
            return offset + column.min(l.len());
        }
        offset += l.len();
    }
    text.len()
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
        assert_eq!(e.field, "sensor.apperture");
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
        assert_eq!(e.field, "sensor.width");
    }
}
