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

mod kalibr;
pub mod merge;
mod opencv;
mod ros;
mod yaml;

use std::fmt;
use std::path::{Path, PathBuf};

use crate::geometry::{CameraError, Distortion, PinholeCamera};
use crate::ipc::{FRAME_MAX_HEIGHT, FRAME_MAX_WIDTH};

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

/// A parsed document, ready for the format's reader.
enum Document {
    /// XML: parsed again by [`opencv::from_xml`] (roxmltree borrows the text).
    Xml,
    /// YAML, parsed.
    Yaml(serde_yaml_ng::Value),
}

/// Detects the format from the content, and checks it against the
/// extension (`.xml` must hold XML, `.yaml`/`.yml` must not).
fn detect(path: &Path, text: &str) -> Result<(Format, Document), ImportError> {
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

/// Where each of star's camera parameters came from in the file: the key
/// an error names.
struct SourceKeys {
    width: String,
    height: String,
    fx: String,
    fy: String,
    cx: String,
    cy: String,
    /// `k1 k2 p1 p2 k3`; `None` where the format has no such coefficient.
    distortion: [Option<String>; 5],
}

impl SourceKeys {
    /// The file's key for star's parameter `name` (as [`CameraError`] names it).
    fn of(&self, name: &str) -> String {
        let d = |i: usize| {
            self.distortion[i]
                .clone()
                .unwrap_or_else(|| name.to_string())
        };
        match name {
            "width" => self.width.clone(),
            "height" => self.height.clone(),
            "fx" => self.fx.clone(),
            "fy" => self.fy.clone(),
            "cx" => self.cx.clone(),
            "cy" => self.cy.clone(),
            "distortion.k1" => d(0),
            "distortion.k2" => d(1),
            "distortion.p1" => d(2),
            "distortion.p2" => d(3),
            "distortion.k3" => d(4),
            other => other.to_string(),
        }
    }
}

/// star's validation of `camera` (focal lengths, principal point inside the
/// image, distortion bounds) and the frame capacity; errors name the
/// file's key.
fn checked(
    ctx: Ctx<'_>,
    camera: PinholeCamera,
    keys: &SourceKeys,
) -> Result<PinholeCamera, ImportError> {
    if let Err(CameraError::InvalidParameter {
        name,
        value,
        reason,
    }) = camera.validate()
    {
        return Err(ctx.invalid(keys.of(name), value, reason));
    }
    for (key, value, max) in [
        (&keys.width, camera.width, FRAME_MAX_WIDTH),
        (&keys.height, camera.height, FRAME_MAX_HEIGHT),
    ] {
        if value > max {
            return Err(ctx.invalid(
                key.clone(),
                f64::from(value),
                format!("star's frames hold at most {FRAME_MAX_WIDTH}x{FRAME_MAX_HEIGHT} pixels"),
            ));
        }
    }
    Ok(camera)
}

/// Distortion `k1 k2 p1 p2 k3` from OpenCV-ordered `coeffs` (4, 5, 8, 12 or
/// 14 of them, as `calibrateCamera` writes). Terms beyond `k3` (rational
/// `k4 k5 k6`, thin prism `s1..s4`, tilt `tauX tauY`) must be zero: star's
/// model does not have them. `key` is the list's key, `index_key(i)` the
/// key of coefficient `i` in errors.
fn opencv_distortion(
    ctx: Ctx<'_>,
    key: &str,
    coeffs: &[f64],
    allowed_counts: &[usize],
    index_key: impl Fn(usize) -> String,
) -> Result<Distortion, ImportError> {
    if !allowed_counts.contains(&coeffs.len()) {
        let allowed: Vec<String> = allowed_counts.iter().map(usize::to_string).collect();
        return Err(ctx.wrong_type(
            key,
            format!("{} coefficients", allowed.join(", ")),
            format!("{} coefficients", coeffs.len()),
        ));
    }
    const EXTRA: [&str; 9] = ["k4", "k5", "k6", "s1", "s2", "s3", "s4", "tauX", "tauY"];
    for (i, (&value, name)) in coeffs.iter().skip(5).zip(EXTRA).enumerate() {
        if value != 0.0 {
            let model = match i {
                0..=2 => "OpenCV's rational model (k4 k5 k6)",
                3..=6 => "OpenCV's thin-prism model (s1 s2 s3 s4)",
                _ => "OpenCV's tilted-sensor model (tauX tauY)",
            };
            return Err(ctx.unsupported(
                format!("{} ({name})", index_key(i + 5)),
                model,
                format!(
                    "{name} = {value}, and star's camera model has k1 k2 p1 p2 k3 only; recalibrate without that model (OpenCV: without CALIB_RATIONAL_MODEL, CALIB_THIN_PRISM_MODEL, CALIB_TILTED_MODEL)"
                ),
            ));
        }
    }
    let at = |i: usize| coeffs.get(i).copied().unwrap_or(0.0);
    Ok(Distortion {
        k1: at(0),
        k2: at(1),
        p1: at(2),
        p2: at(3),
        k3: at(4),
    })
}

/// An OpenCV-style matrix: `rows`, `cols` and row-major `data`.
#[derive(Debug, Clone)]
struct Matrix {
    rows: usize,
    cols: usize,
    data: Vec<f64>,
}

impl Matrix {
    /// Checks that `data` holds `rows * cols` values.
    fn consistent(self, ctx: Ctx<'_>, key: &str) -> Result<Self, ImportError> {
        if self.rows.checked_mul(self.cols) != Some(self.data.len()) {
            return Err(ctx.wrong_type(
                format!("{key}.data"),
                format!("rows x cols = {} x {} values", self.rows, self.cols),
                format!("{} values", self.data.len()),
            ));
        }
        Ok(self)
    }
}

/// `fx fy cx cy` from a 3x3 camera matrix `[fx 0 cx; 0 fy cy; 0 0 1]`; skew
/// is refused (star's model has none), and the other entries must be those
/// of a camera matrix.
fn camera_matrix(ctx: Ctx<'_>, key: &str, m: &Matrix) -> Result<[f64; 4], ImportError> {
    if (m.rows, m.cols) != (3, 3) {
        return Err(ctx.wrong_type(
            key,
            "a 3x3 camera matrix",
            format!("{}x{} (rows x cols)", m.rows, m.cols),
        ));
    }
    let at = |i: usize| m.data.get(i).copied().unwrap_or(f64::NAN);
    let skew = at(1);
    if skew != 0.0 {
        return Err(ctx.unsupported(
            format!("{key}.data[1] (skew)"),
            format!("a camera matrix with skew {skew}"),
            "star's pinhole model has no skew; recalibrate with the skew fixed at zero (OpenCV's default)",
        ));
    }
    for (i, want) in [(3, 0.0), (6, 0.0), (7, 0.0), (8, 1.0)] {
        if at(i) != want {
            return Err(ctx.invalid(
                format!("{key}.data[{i}]"),
                at(i),
                format!("a camera matrix has {want} there (row 3 is 0 0 1, row 2 starts with 0)"),
            ));
        }
    }
    Ok([at(0), at(4), at(2), at(5)])
}

/// The camera from entries in OpenCV's layout (OpenCV FileStorage, ROS
/// camera_info): the 3x3 `camera_matrix` and the `distortion_coefficients`
/// vector, of one of `counts` lengths.
fn opencv_camera(
    ctx: Ctx<'_>,
    (width, height): (u32, u32),
    (width_key, height_key): (&str, &str),
    k: &Matrix,
    d: &Matrix,
    counts: &[usize],
) -> Result<PinholeCamera, ImportError> {
    const K: &str = "camera_matrix";
    const D: &str = "distortion_coefficients";
    let [fx, fy, cx, cy] = camera_matrix(ctx, K, k)?;
    if d.rows != 1 && d.cols != 1 {
        return Err(ctx.wrong_type(
            D,
            "a vector (1xN or Nx1)",
            format!("{}x{} (rows x cols)", d.rows, d.cols),
        ));
    }
    let distortion = opencv_distortion(ctx, D, &d.data, counts, |i| format!("{D}.data[{i}]"))?;
    let names = ["k1", "k2", "p1", "p2", "k3"];
    let keys = SourceKeys {
        width: width_key.into(),
        height: height_key.into(),
        fx: format!("{K}.data[0] (fx)"),
        fy: format!("{K}.data[4] (fy)"),
        cx: format!("{K}.data[2] (cx)"),
        cy: format!("{K}.data[5] (cy)"),
        distortion: std::array::from_fn(|i| {
            (i < d.data.len()).then(|| format!("{D}.data[{i}] ({})", names[i]))
        }),
    };
    let camera = PinholeCamera {
        distortion,
        ..PinholeCamera::new(width, height, fx, fy, cx, cy)
    };
    checked(ctx, camera, &keys)
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
