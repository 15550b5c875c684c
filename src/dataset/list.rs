//! Line-oriented TUM text files: `rgb.txt`/`depth.txt` frame lists
//! (`timestamp path`) and the shared tokenizer that the trajectory reader
//! uses. Blank lines and lines starting with `#` are skipped; fields are
//! separated by whitespace. Every error names the file and the 1-based line.

use std::path::{Path, PathBuf};

use super::DatasetError;

/// One entry of a frame list: capture time and image path relative to the
/// dataset folder.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameEntry {
    /// Capture time in seconds (the TUM timestamp).
    pub timestamp_s: f64,
    /// Image path relative to the dataset folder, e.g. `rgb/0.020000.png`.
    pub path: PathBuf,
}

/// The non-comment, non-blank lines of `text` with their 1-based line numbers.
pub(crate) fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, line)| (i + 1, line.trim()))
        .filter(|(_, line)| !line.is_empty() && !line.starts_with('#'))
}

/// Parses one float field; `what` names the field in the error.
pub(crate) fn parse_f64(
    file: &Path,
    line: usize,
    token: &str,
    what: &'static str,
) -> Result<f64, DatasetError> {
    match token.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(DatasetError::Malformed {
            path: file.to_path_buf(),
            line,
            expected: what,
            found: token.to_string(),
        }),
    }
}

/// Checks that timestamps strictly increase.
pub(crate) fn check_monotonic(
    file: &Path,
    line: usize,
    previous_s: Option<f64>,
    timestamp_s: f64,
) -> Result<(), DatasetError> {
    match previous_s {
        Some(prev) if timestamp_s <= prev => Err(DatasetError::NonMonotonic {
            path: file.to_path_buf(),
            line,
            previous_s: prev,
            found_s: timestamp_s,
        }),
        _ => Ok(()),
    }
}

/// Parses a frame list (`rgb.txt` or `depth.txt`) read from `file`.
pub fn parse_frame_list(file: &Path, text: &str) -> Result<Vec<FrameEntry>, DatasetError> {
    let mut entries: Vec<FrameEntry> = Vec::new();
    for (line, content) in data_lines(text) {
        let mut tokens = content.split_whitespace();
        let (Some(stamp), Some(path), None) = (tokens.next(), tokens.next(), tokens.next()) else {
            return Err(DatasetError::Malformed {
                path: file.to_path_buf(),
                line,
                expected: "two fields `timestamp path`",
                found: content.to_string(),
            });
        };
        let timestamp_s = parse_f64(file, line, stamp, "a finite timestamp in seconds")?;
        check_monotonic(
            file,
            line,
            entries.last().map(|e| e.timestamp_s),
            timestamp_s,
        )?;
        entries.push(FrameEntry {
            timestamp_s,
            path: PathBuf::from(path),
        });
    }
    Ok(entries)
}

/// Formats a frame list with a header comment, one `timestamp path` per line.
pub fn format_frame_list(header: &str, entries: &[FrameEntry]) -> String {
    let mut text = format!("# {header}\n# timestamp filename\n");
    for e in entries {
        text.push_str(&format!("{} {}\n", e.timestamp_s, e.path.display()));
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_comments_and_entries() {
        let text =
            "# color images\n# timestamp filename\n\n1.5 rgb/1.5.png\n  1.52   rgb/1.52.png  \n";
        let list = parse_frame_list(Path::new("rgb.txt"), text).expect("valid");
        assert_eq!(list.len(), 2);
        assert_eq!(list[1].timestamp_s, 1.52);
        assert_eq!(list[1].path, PathBuf::from("rgb/1.52.png"));
    }

    #[test]
    fn malformed_line_names_file_and_line() {
        let text = "# c\n1.0 a.png\n1.1\n";
        let err = parse_frame_list(Path::new("/d/rgb.txt"), text).unwrap_err();
        match &err {
            DatasetError::Malformed { path, line, .. } => {
                assert_eq!(path, Path::new("/d/rgb.txt"));
                assert_eq!(*line, 3);
            }
            other => panic!("unexpected {other:?}"),
        }
        assert!(err.to_string().contains("/d/rgb.txt:3"), "{err}");
        let err = parse_frame_list(Path::new("rgb.txt"), "abc a.png\n").unwrap_err();
        assert!(matches!(err, DatasetError::Malformed { line: 1, .. }));
        let err = parse_frame_list(Path::new("rgb.txt"), "nan a.png\n").unwrap_err();
        assert!(matches!(err, DatasetError::Malformed { line: 1, .. }));
        let err = parse_frame_list(Path::new("rgb.txt"), "1 a.png extra\n").unwrap_err();
        assert!(matches!(err, DatasetError::Malformed { line: 1, .. }));
    }

    #[test]
    fn non_monotonic_timestamps_are_rejected() {
        let text = "1.0 a.png\n2.0 b.png\n2.0 c.png\n";
        let err = parse_frame_list(Path::new("rgb.txt"), text).unwrap_err();
        assert!(
            matches!(err, DatasetError::NonMonotonic { line: 3, previous_s, found_s, .. } if previous_s == 2.0 && found_s == 2.0)
        );
    }

    #[test]
    fn format_then_parse_roundtrips() {
        let entries = vec![
            FrameEntry {
                timestamp_s: 0.02,
                path: "rgb/0.020000.png".into(),
            },
            FrameEntry {
                timestamp_s: 1305031102.175304,
                path: "rgb/x.png".into(),
            },
        ];
        let text = format_frame_list("rgb", &entries);
        assert_eq!(
            parse_frame_list(Path::new("x"), &text).expect("valid"),
            entries
        );
    }
}
