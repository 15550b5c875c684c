//! From a file's entries to star's camera model: the camera matrix and
//! OpenCV-ordered distortion shared by the OpenCV and ROS readers, and the
//! final validation, whose errors name the file's own keys.

use super::{Ctx, ImportError};
use crate::geometry::{CameraError, Distortion, PinholeCamera};
use crate::ipc::{FRAME_MAX_HEIGHT, FRAME_MAX_WIDTH};

/// Where each of star's camera parameters came from in the file: the key
/// an error names.
pub(super) struct SourceKeys {
    /// The image width's key.
    pub(super) width: String,
    /// The image height's key.
    pub(super) height: String,
    /// The key of the focal length along x.
    pub(super) fx: String,
    /// The key of the focal length along y.
    pub(super) fy: String,
    /// The key of the principal point's x.
    pub(super) cx: String,
    /// The key of the principal point's y.
    pub(super) cy: String,
    /// `k1 k2 p1 p2 k3`; `None` where the format has no such coefficient.
    pub(super) distortion: [Option<String>; 5],
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
pub(super) fn checked(
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
pub(super) struct Matrix {
    pub(super) rows: usize,
    pub(super) cols: usize,
    pub(super) data: Vec<f64>,
}

impl Matrix {
    /// Checks that `data` holds `rows * cols` values.
    pub(super) fn consistent(self, ctx: Ctx<'_>, key: &str) -> Result<Self, ImportError> {
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
pub(super) fn opencv_camera(
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
