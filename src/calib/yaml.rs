//! YAML for the calibration readers: parsing (OpenCV's `%YAML:1.0`
//! directive normalized, its `!!opencv-matrix` tags accepted) and typed
//! access to a key path whose errors name the key.

use std::path::Path;

use serde_yaml_ng::{Mapping, Value};

use super::model::Matrix;
use super::{Ctx, ImportError};

/// Parses `text`. OpenCV writes `%YAML:1.0` (a colon where YAML wants a
/// space), which YAML parsers refuse: that first line becomes `%YAML 1.1`,
/// keeping the line numbers of errors right. OpenCV's `!!opencv-matrix`
/// (and `!!opencv-nd-matrix`) tags parse as tagged mappings; [`untag`]
/// looks through them.
pub(super) fn parse(path: &Path, text: &str) -> Result<Value, ImportError> {
    let text = text.trim_start_matches('\u{feff}');
    let normalized;
    let text = match text.strip_prefix("%YAML:") {
        Some(rest) => {
            // The version OpenCV gives (1.0) is not one libyaml accepts;
            // 1.1 is what the file's plain scalars follow.
            let after_version = rest.find(['\n', '\r']).map_or("", |i| &rest[i..]);
            normalized = format!("%YAML 1.1{after_version}");
            normalized.as_str()
        }
        None => text,
    };
    serde_yaml_ng::from_str(text).map_err(|e| ImportError::Syntax {
        path: path.to_owned(),
        syntax: "YAML",
        message: e.to_string(),
    })
}

/// The value inside any tags (`!!opencv-matrix {rows: ...}` is the mapping).
pub(super) fn untag(mut value: &Value) -> &Value {
    while let Value::Tagged(t) = value {
        value = &t.value;
    }
    value
}

/// True when `value` carries an OpenCV tag (`!!opencv-matrix`).
pub(super) fn is_opencv_tagged(value: &Value) -> bool {
    matches!(value, Value::Tagged(t) if t.tag.to_string().contains("opencv-"))
}

/// True when `value` is a mapping with key `key`.
pub(super) fn has_key(value: &Value, key: &str) -> bool {
    untag(value)
        .as_mapping()
        .is_some_and(|m| m.contains_key(key))
}

/// A key of a mapping as text, for messages.
pub(super) fn key_text(key: &Value) -> String {
    match untag(key) {
        Value::String(s) => s.clone(),
        other => describe(other),
    }
}

/// What `value` is, for "expected X, found Y".
pub(super) fn describe(value: &Value) -> String {
    match untag(value) {
        Value::Null => "nothing (null; is the file truncated?)".into(),
        Value::Bool(b) => format!("the boolean {b}"),
        Value::Number(n) => format!("the number {n}"),
        Value::String(s) if s.is_empty() => "an empty string (is the file truncated?)".into(),
        Value::String(s) => format!("the string {s:?}"),
        Value::Sequence(s) => format!("a list of {}", s.len()),
        Value::Mapping(m) => format!("a mapping of {} keys", m.len()),
        Value::Tagged(_) => "a tagged value".into(),
    }
}

/// A value in the document and its dotted key, for errors.
#[derive(Clone)]
pub(super) struct Node<'a> {
    pub(super) ctx: Ctx<'a>,
    pub(super) key: String,
    pub(super) value: &'a Value,
}

impl<'a> Node<'a> {
    /// The document's root.
    pub(super) fn root(ctx: Ctx<'a>, value: &'a Value) -> Self {
        Self {
            ctx,
            key: String::new(),
            value: untag(value),
        }
    }

    fn mapping(&self) -> Result<&'a Mapping, ImportError> {
        self.value.as_mapping().ok_or_else(|| {
            self.ctx
                .wrong_type(self.key.clone(), "a mapping", describe(self.value))
        })
    }

    /// `name` below this node, or `None` when absent.
    pub(super) fn opt(&self, name: &str) -> Result<Option<Node<'a>>, ImportError> {
        Ok(self.mapping()?.get(name).map(|v| Node {
            ctx: self.ctx,
            key: self.child_key(name),
            value: untag(v),
        }))
    }

    /// `name` below this node.
    pub(super) fn get(&self, name: &str) -> Result<Node<'a>, ImportError> {
        self.opt(name)?
            .ok_or_else(|| self.ctx.missing(self.child_key(name)))
    }

    /// The dotted key of `name` below this node.
    fn child_key(&self, name: &str) -> String {
        if self.key.is_empty() {
            name.to_string()
        } else {
            format!("{}.{name}", self.key)
        }
    }

    /// The value as an image size in pixels (a positive integer).
    pub(super) fn pixels(&self) -> Result<u32, ImportError> {
        self.value
            .as_u64()
            .and_then(|v| u32::try_from(v).ok())
            .filter(|v| *v > 0)
            .ok_or_else(|| {
                self.ctx.wrong_type(
                    self.key.clone(),
                    "a positive integer (pixels)",
                    describe(self.value),
                )
            })
    }

    /// The value as a count (a non-negative integer).
    pub(super) fn count(&self) -> Result<usize, ImportError> {
        self.value
            .as_u64()
            .and_then(|v| usize::try_from(v).ok())
            .ok_or_else(|| {
                self.ctx.wrong_type(
                    self.key.clone(),
                    "a non-negative integer",
                    describe(self.value),
                )
            })
    }

    /// The value as a string.
    pub(super) fn str(&self) -> Result<&'a str, ImportError> {
        self.value.as_str().ok_or_else(|| {
            self.ctx
                .wrong_type(self.key.clone(), "a string", describe(self.value))
        })
    }

    /// The value as a list of numbers.
    pub(super) fn numbers(&self) -> Result<Vec<f64>, ImportError> {
        let list = self.value.as_sequence().ok_or_else(|| {
            self.ctx
                .wrong_type(self.key.clone(), "a list of numbers", describe(self.value))
        })?;
        list.iter()
            .enumerate()
            .map(|(i, v)| {
                number(untag(v)).ok_or_else(|| {
                    self.ctx
                        .wrong_type(format!("{}[{i}]", self.key), "a number", describe(v))
                })
            })
            .collect()
    }

    /// The value as an OpenCV-style matrix mapping `{rows, cols, data}`
    /// (OpenCV's also has `dt`, ROS's not); `data` must hold rows x cols values.
    pub(super) fn matrix(&self) -> Result<Matrix, ImportError> {
        if let Some(dt) = self.opt("dt")? {
            let text = dt.str()?;
            if !matches!(text, "d" | "f") {
                return Err(self.ctx.wrong_type(
                    dt.key,
                    "`d` or `f` (one channel of double or float)",
                    format!("{text:?}"),
                ));
            }
        }
        let rows = self.get("rows")?.count()?;
        let cols = self.get("cols")?.count()?;
        let data = self.get("data")?.numbers()?;
        Matrix { rows, cols, data }.consistent(self.ctx, &self.key)
    }
}

/// A YAML number as `f64`; `.inf` and `.nan` included (validation refuses them).
fn number(value: &Value) -> Option<f64> {
    match value {
        Value::Number(n) => n.as_f64(),
        _ => None,
    }
}
