//! Reading the judge's YAML inputs: typed parsing that names file, line and
//! key path on any error, and refuses oversized files and alias bombs.

use std::path::Path;

use serde::de::DeserializeOwned;

use crate::scene::MAX_YAML_BYTES;

/// Unusable judge input (exit code 2): which file, where, what.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{file}{line}: {key}{what}")]
pub struct JudgeInputError {
    pub file: String,
    pub line: String,
    pub key: String,
    pub what: String,
}

impl JudgeInputError {
    /// An error at a key path of a file (no line known).
    pub fn new(file: &str, key: &str, what: impl Into<String>) -> Self {
        let key = if key.is_empty() {
            String::new()
        } else {
            format!("key `{key}`: ")
        };
        JudgeInputError {
            file: file.into(),
            line: String::new(),
            key,
            what: what.into(),
        }
    }

    /// Adds a line number (1-based).
    pub fn at_line(mut self, line: Option<usize>) -> Self {
        if let Some(l) = line {
            self.line = format!(":{l}");
        }
        self
    }
}

/// Reads and parses a YAML file into `T`; returns the text too (for hashes
/// and line look-ups).
pub fn load_yaml_typed<T: DeserializeOwned>(path: &Path) -> Result<(T, String), JudgeInputError> {
    let at = path.display().to_string();
    let meta = std::fs::metadata(path)
        .map_err(|e| JudgeInputError::new(&at, "", format!("cannot read: {e}")))?;
    if meta.is_dir() {
        return Err(JudgeInputError::new(
            &at,
            "",
            "is a directory, not a YAML file",
        ));
    }
    if meta.len() > MAX_YAML_BYTES {
        return Err(JudgeInputError::new(
            &at,
            "",
            format!(
                "{} bytes is over the {MAX_YAML_BYTES}-byte limit",
                meta.len()
            ),
        ));
    }
    let text = std::fs::read_to_string(path)
        .map_err(|e| JudgeInputError::new(&at, "", format!("cannot read: {e}")))?;
    crate::scene::refuse_deep_nesting(&text).map_err(|what| JudgeInputError::new(&at, "", what))?;
    let de = serde_yaml::Deserializer::from_str(&text);
    match serde_path_to_error::deserialize::<_, T>(de) {
        Ok(v) => Ok((v, text)),
        Err(e) => {
            let path = e.path().to_string();
            let inner = e.into_inner();
            let line = inner.location().map(|l| l.line());
            let key = if path == "." || path.is_empty() {
                String::new()
            } else {
                path
            };
            Err(JudgeInputError::new(&at, &key, inner.to_string()).at_line(line))
        }
    }
}

/// The 1-based line of the first line of `text` containing `needle`.
pub fn find_line(text: &str, needle: &str) -> Option<usize> {
    text.lines().position(|l| l.contains(needle)).map(|i| i + 1)
}
