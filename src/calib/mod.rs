//! Camera calibration import (`star calib import`): the calibration files
//! users arrive with, turned into star's camera model.
//!
//! Takes in a file: OpenCV FileStorage YAML or XML (what `calibrateCamera`
//! users save, [`opencv`]), a Kalibr `camchain.yaml` ([`kalibr`]) or a ROS
//! `camera_info` YAML ([`ros`]). The format is detected from the content and
//! checked against the extension ([`detect`]). Gives out a [`Calibration`]:
//! a validated [`PinholeCamera`] (k1 k2 p1 p2 k3 distortion), the format
//! found, and the `[camera.intrinsics]` TOML section for star's config
//! ([`Calibration::to_toml`], or [`merge`] into an existing config).
//!
//! **Pixel centers.** OpenCV, ROS (whose `image_geometry` is OpenCV's model)
//! and Kalibr (whose corners come from OpenCV's detectors) all put the center
//! of pixel (0, 0) at coordinates (0, 0), as star does
//! ([`crate::geometry::camera`]): the principal point is copied unchanged.
//!
//! **Checks.** Models star does not implement (Kalibr omni, ds, eucm;
//! equidistant or fov distortion; OpenCV's rational, thin-prism and tilted
//! terms when not zero; skew) are refused with the model named. The values
//! go through star's own camera validation (positive focal lengths,
//! principal point inside the image, finite and bounded distortion) and the
//! frame capacity. Every error names the file and the key as the file
//! spells it (`cam0.intrinsics[0] (fu)`, `camera_matrix.data[2] (cx)`).

mod detect;
mod kalibr;
pub mod merge;
mod model;
mod opencv;
mod ros;
mod yaml;

use std::fmt;
use std::path::{Path, PathBuf};

use crate::geometry::PinholeCamera;

use detect::{detect, Document};

/// Largest calibration file read: real ones are a few kilobytes (an OpenCV
/// file with every view's corners, a few megabytes).
pub const MAX_FILE_BYTES: u64 = 64 << 20;

/// A calibration file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// OpenCV `FileStorage` YAML (`%YAML:1.0`, `!!opencv-matrix`).
    OpenCvYaml,
    /// OpenCV `FileStorage` XML (`<opencv_storage>`).
    OpenCvXml,
    /// Kalibr `camchain.yaml` (`cam0: {camera_model, intrinsics, ...}`).
    Kalibr,
    /// ROS `camera_info` YAML (`camera_matrix: {rows, cols, data}`).
    RosCameraInfo,
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Format::OpenCvYaml => "OpenCV FileStorage YAML",
            Format::OpenCvXml => "OpenCV FileStorage XML",
            Format::Kalibr => "Kalibr camchain YAML",
            Format::RosCameraInfo => "ROS camera_info YAML",
        })
    }
}

/// Errors importing a calibration file. Each names the file.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The file cannot be read (missing, not a regular file, too large, not UTF-8).
    #[error("cannot read calibration {path}: {reason}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
    /// The content is none of the formats star reads.
    #[error("{path}: unknown calibration format: {reason}; star reads OpenCV FileStorage YAML or XML (camera_matrix, distortion_coefficients, image_width, image_height), Kalibr camchain.yaml (cam0: camera_model, intrinsics, distortion_coeffs, resolution) and ROS camera_info YAML")]
    UnknownFormat {
        /// The file.
        path: PathBuf,
        /// What was found instead.
        reason: String,
    },
    /// The file is not well-formed YAML or XML (a syntax error, a truncated
    /// file): the parser's message, with the line and column.
    #[error("{path}: not valid {syntax}: {message}")]
    Syntax {
        /// The file.
        path: PathBuf,
        /// `YAML` or `XML`.
        syntax: &'static str,
        /// The parser's message.
        message: String,
    },
    /// A key the format requires is absent.
    #[error("{path} ({format}): missing key `{key}`")]
    MissingKey {
        /// The file.
        path: PathBuf,
        /// The format detected.
        format: Format,
        /// The key, dotted from the top of the file.
        key: String,
    },
    /// A key holds the wrong kind of value.
    #[error("{path} ({format}): key `{key}`: expected {expected}, found {found}")]
    WrongType {
        /// The file.
        path: PathBuf,
        /// The format detected.
        format: Format,
        /// The key.
        key: String,
        /// What was expected.
        expected: String,
        /// What was found.
        found: String,
    },
    /// A model star does not implement (a camera model, a distortion model,
    /// distortion terms beyond k1 k2 p1 p2 k3, skew).
    #[error("{path} ({format}): key `{key}`: {model} is not supported: {reason}")]
    UnsupportedModel {
        /// The file.
        path: PathBuf,
        /// The format detected.
        format: Format,
        /// The key.
        key: String,
        /// The model found.
        model: String,
        /// Why star cannot use it, and what to do.
        reason: String,
    },
    /// A Kalibr camchain has no camera of the requested name.
    #[error("{path} ({format}): no camera `{camera}`; the file has {}", .available.join(", "))]
    NoSuchCamera {
        /// The file.
        path: PathBuf,
        /// The format detected.
        format: Format,
        /// The name asked for.
        camera: String,
        /// The cameras the file has.
        available: Vec<String>,
    },
    /// An option does not apply to this format.
    #[error("{path} ({format}): {reason}")]
    BadOption {
        /// The file.
        path: PathBuf,
        /// The format detected.
        format: Format,
        /// What is wrong.
        reason: String,
    },
    /// A value is out of range.
    #[error("{path} ({format}): key `{key}` = {value}: {reason}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The format detected.
        format: Format,
        /// The key.
        key: String,
        /// The value found.
        value: f64,
        /// What was expected.
        reason: String,
    },
}

/// A calibration read from a file.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// The camera, validated.
    pub camera: PinholeCamera,
    /// The format detected.
    pub format: Format,
    /// The camera's name: the Kalibr camera picked, or ROS `camera_name`.
    pub camera_name: Option<String>,
}

/// The file being read and the format detected: what every error names.
#[derive(Debug, Clone, Copy)]
struct Ctx<'a> {
    path: &'a Path,
    format: Format,
}

impl Ctx<'_> {
    fn missing(&self, key: impl Into<String>) -> ImportError {
        ImportError::MissingKey {
            path: self.path.to_owned(),
            format: self.format,
            key: key.into(),
        }
    }

    fn wrong_type(
        &self,
        key: impl Into<String>,
        expected: impl Into<String>,
        found: impl Into<String>,
    ) -> ImportError {
        ImportError::WrongType {
            path: self.path.to_owned(),
            format: self.format,
            key: key.into(),
            expected: expected.into(),
            found: found.into(),
        }
    }

    fn unsupported(
        &self,
        key: impl Into<String>,
        model: impl Into<String>,
        reason: impl Into<String>,
    ) -> ImportError {
        ImportError::UnsupportedModel {
            path: self.path.to_owned(),
            format: self.format,
            key: key.into(),
            model: model.into(),
            reason: reason.into(),
        }
    }

    fn invalid(
        &self,
        key: impl Into<String>,
        value: f64,
        reason: impl Into<String>,
    ) -> ImportError {
        ImportError::Invalid {
            path: self.path.to_owned(),
            format: self.format,
            key: key.into(),
            value,
            reason: reason.into(),
        }
    }
}

/// Reads `path` and imports it. `camera` picks a camera of a Kalibr
/// camchain (default `cam0`); it is an error for the other formats.
pub fn import_file(path: &Path, camera: Option<&str>) -> Result<Calibration, ImportError> {
    let read_err = |reason: String| ImportError::Read {
        path: path.to_owned(),
        reason,
    };
    let meta = std::fs::metadata(path).map_err(|e| read_err(e.to_string()))?;
    // A FIFO would block the read forever.
    if !meta.is_file() {
        return Err(read_err("not a regular file".into()));
    }
    if meta.len() > MAX_FILE_BYTES {
        return Err(read_err(format!(
            "{} bytes; a calibration file is at most {MAX_FILE_BYTES}",
            meta.len()
        )));
    }
    let bytes = std::fs::read(path).map_err(|e| read_err(e.to_string()))?;
    let text = String::from_utf8(bytes).map_err(|e| {
        read_err(format!(
            "not UTF-8 text (byte {}): not a calibration file",
            e.utf8_error().valid_up_to()
        ))
    })?;
    import_text(path, &text, camera)
}

/// Imports calibration `text` read from `path` (used for the extension and
/// in errors).
pub fn import_text(
    path: &Path,
    text: &str,
    camera: Option<&str>,
) -> Result<Calibration, ImportError> {
    let (format, document) = detect(path, text)?;
    let ctx = Ctx { path, format };
    if let (Some(name), false) = (camera, format == Format::Kalibr) {
        return Err(ImportError::BadOption {
            path: path.to_owned(),
            format,
            reason: format!(
                "--camera {name} applies to Kalibr camchains only (one camera per {format} file)"
            ),
        });
    }
    let calibration = match document {
        Document::Xml => opencv::from_xml(ctx, text)?,
        Document::Yaml(value) => match format {
            Format::Kalibr => kalibr::from_yaml(ctx, &value, camera.unwrap_or("cam0"))?,
            Format::RosCameraInfo => ros::from_yaml(ctx, &value)?,
            Format::OpenCvYaml | Format::OpenCvXml => opencv::from_yaml(ctx, &value)?,
        },
    };
    Ok(calibration)
}

impl Calibration {
    /// The `[camera.intrinsics]` section for star's config, with a comment
    /// naming `source` and the format.
    pub fn to_toml(&self, source: &Path) -> String {
        let c = &self.camera;
        let d = &c.distortion;
        let name = match &self.camera_name {
            Some(n) => format!(", camera {}", comment_safe(n)),
            None => String::new(),
        };
        format!(
            "# Imported by `star calib import` from {} ({}{name}).\n\
             # Pixel centers at integer coordinates, as in OpenCV, ROS and Kalibr:\n\
             # the principal point is the file's, unchanged.\n\
             [camera.intrinsics]\n\
             width = {}\nheight = {}\nfx = {:?}\nfy = {:?}\ncx = {:?}\ncy = {:?}\n\n\
             # Radial-tangential distortion, OpenCV order.\n\
             [camera.intrinsics.distortion]\n\
             k1 = {:?}\nk2 = {:?}\np1 = {:?}\np2 = {:?}\nk3 = {:?}\n",
            comment_safe(&source.display().to_string()),
            self.format,
            c.width,
            c.height,
            c.fx,
            c.fy,
            c.cx,
            c.cy,
            d.k1,
            d.k2,
            d.p1,
            d.p2,
            d.k3
        )
    }
}

/// `text` with control characters escaped, so it cannot end a TOML comment.
fn comment_safe(text: &str) -> String {
    text.chars().flat_map(char::escape_debug).collect()
}

#[cfg(test)]
mod tests;
