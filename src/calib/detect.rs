//! Which calibration format a file holds: from its content (XML with an
//! `<opencv_storage>` root; YAML with OpenCV's directive or `dt` matrices,
//! with a ROS camera_info's `distortion_model`, or with Kalibr's `camN`
//! cameras), checked against its extension.

use std::path::Path;

use super::{kalibr, opencv, yaml, Format, ImportError};

/// A parsed document, ready for the format's reader.
pub(super) enum Document {
    /// XML: parsed again by [`opencv::from_xml`] (roxmltree borrows the text).
    Xml,
    /// YAML, parsed.
    Yaml(serde_yaml_ng::Value),
}

/// Detects the format from the content, and checks it against the
/// extension (`.xml` must hold XML, `.yaml`/`.yml` must not).
pub(super) fn detect(path: &Path, text: &str) -> Result<(Format, Document), ImportError> {
    let unknown = |reason: String| ImportError::UnknownFormat {
        path: path.to_owned(),
        reason,
    };
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let body = text.trim_start_matches('\u{feff}').trim_start();
    if body.is_empty() {
        return Err(unknown("the file is empty".into()));
    }
    let is_xml = body.starts_with('<');
    match (ext.as_deref(), is_xml) {
        (Some("xml"), false) => {
            return Err(unknown(
                "the extension is .xml but the content is not XML".into(),
            ))
        }
        (Some(e @ ("yaml" | "yml")), true) => {
            return Err(unknown(format!(
                "the extension is .{e} but the content is XML"
            )))
        }
        _ => {}
    }
    if is_xml {
        let root = opencv::xml_root_name(path, text)?;
        if root != "opencv_storage" {
            return Err(unknown(format!(
                "XML whose root element is <{root}>, not OpenCV's <opencv_storage>"
            )));
        }
        return Ok((Format::OpenCvXml, Document::Xml));
    }
    let value = yaml::parse(path, text)?;
    let Some(map) = yaml::untag(&value).as_mapping() else {
        return Err(unknown(format!(
            "the YAML document is {}, not a mapping of keys",
            yaml::describe(&value)
        )));
    };
    let opencv_directive = body.starts_with("%YAML:");
    let key = |k: &str| map.get(k).map(yaml::untag);
    let format = match key("camera_matrix") {
        Some(m) if opencv_directive || yaml::has_key(m, "dt") || yaml::is_opencv_tagged(m) => {
            Format::OpenCvYaml
        }
        Some(_)
            if ["distortion_model", "camera_name", "projection_matrix"]
                .iter()
                .any(|k| map.contains_key(*k)) =>
        {
            Format::RosCameraInfo
        }
        Some(_) => {
            return Err(unknown(
                "a `camera_matrix` that is neither OpenCV's (no `dt`, no !!opencv-matrix tag) nor part of a ROS camera_info (no `distortion_model`)".into(),
            ))
        }
        None if opencv_directive => Format::OpenCvYaml,
        None if !kalibr::camera_names(map).is_empty() => Format::Kalibr,
        None => {
            let keys: Vec<String> = map.keys().take(8).map(yaml::key_text).collect();
            return Err(unknown(format!(
                "YAML with top-level keys {} and no `camera_matrix` or `cam0`",
                if keys.is_empty() {
                    "(none)".to_string()
                } else {
                    keys.join(", ")
                }
            )));
        }
    };
    Ok((format, Document::Yaml(value)))
}
