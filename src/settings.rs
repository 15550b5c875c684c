//! The error every configuration section's `validate` returns: which key
//! (relative to the section), what is wrong, and the underlying error where
//! there is one. A leaf: the sections live in the modules that own them
//! (`track::TrackerConfig`, `camera::CameraConfig` ...), and `config` only
//! prefixes the section name and the file.

/// A value of a configuration section is out of range or inconsistent.
#[derive(Debug, thiserror::Error)]
#[error("key `{key}`: {reason}")]
pub struct SettingError {
    /// Dotted key, relative to the section until [`SettingError::within`]
    /// prefixes it (`pyramid_levels`, then `tracker.pyramid_levels`).
    pub key: String,
    /// What is wrong and what was expected.
    pub reason: String,
    /// The error behind it, when one was caught (a camera model's, a URI
    /// parser's).
    #[source]
    pub source: Option<Box<dyn std::error::Error + Send + Sync + 'static>>,
}

impl SettingError {
    /// `key` is wrong for `reason`.
    pub fn new(key: impl Into<String>, reason: impl Into<String>) -> Self {
        Self {
            key: key.into(),
            reason: reason.into(),
            source: None,
        }
    }

    /// `key` is wrong because of `source`, whose message becomes the reason.
    pub fn caused_by<E>(key: impl Into<String>, source: E) -> Self
    where
        E: std::error::Error + Send + Sync + 'static,
    {
        Self {
            key: key.into(),
            reason: source.to_string(),
            source: Some(Box::new(source)),
        }
    }

    /// The same error with `section.` put in front of its key.
    pub fn within(mut self, section: &str) -> Self {
        self.key = format!("{section}.{}", self.key);
        self
    }
}

/// Checks a list of `(key, ok, reason)` and returns the first that fails.
pub fn first_failure<const N: usize>(
    checks: [(&str, bool, String); N],
) -> Result<(), SettingError> {
    match checks.into_iter().find(|(_, ok, _)| !ok) {
        Some((key, _, reason)) => Err(SettingError::new(key, reason)),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn within_prefixes_the_key_and_keeps_the_source() {
        let io = std::io::Error::other("bad");
        let e = SettingError::caused_by("intrinsics", io).within("camera");
        assert_eq!(e.key, "camera.intrinsics");
        assert_eq!(e.to_string(), "key `camera.intrinsics`: bad");
        assert!(std::error::Error::source(&e).is_some());
    }

    #[test]
    fn first_failure_names_the_first_bad_key() {
        let r = first_failure([
            ("a", true, "fine".into()),
            ("b", false, "b is bad".into()),
            ("c", false, "c is bad".into()),
        ]);
        let e = r.expect_err("b fails");
        assert_eq!((e.key.as_str(), e.reason.as_str()), ("b", "b is bad"));
        assert!(first_failure([("a", true, String::new())]).is_ok());
    }
}
