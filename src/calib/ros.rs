//! ROS `camera_info` YAML, as `camera_calibration` and
//! `camera_calibration_parsers` write it: `image_width`, `image_height`,
//! `camera_name`, `camera_matrix` and `distortion_coefficients`
//! (`{rows, cols, data}`), `distortion_model`. The rectification and
//! projection matrices (stereo) are ignored: star uses the raw image.
//!
//! `plumb_bob` is OpenCV's `k1 k2 p1 p2 k3`; `rational_polynomial` adds
//! `k4 k5 k6`, accepted only when those are zero; `equidistant` (fisheye)
//! is refused.

use serde_yaml_ng::Value;

use super::yaml::Node;
use super::{model, Calibration, Ctx, ImportError};

/// Reads a camera_info document.
pub(super) fn from_yaml(ctx: Ctx<'_>, value: &Value) -> Result<Calibration, ImportError> {
    let root = Node::root(ctx, value);
    let width = root.get("image_width")?.pixels()?;
    let height = root.get("image_height")?.pixels()?;
    let camera_name = match root.opt("camera_name")? {
        Some(n) => Some(n.str()?.to_string()),
        None => None,
    };
    let k = root.get("camera_matrix")?.matrix()?;
    let model_node = root.get("distortion_model")?;
    let model = model_node.str()?;
    // An empty list is how ROS says "no distortion".
    let counts: &[usize] = match model {
        "plumb_bob" => &[0, 5],
        "rational_polynomial" => &[0, 8],
        other => {
            let what = match other {
                "equidistant" => "the equidistant (fisheye) distortion model",
                _ => "the distortion model",
            };
            return Err(ctx.unsupported(
                model_node.key,
                format!("{what} `{other}`"),
                "star's distortion is radial-tangential: `plumb_bob`, or `rational_polynomial` with k4 k5 k6 zero",
            ));
        }
    };
    let d = root.get("distortion_coefficients")?.matrix()?;
    let camera = model::opencv_camera(
        ctx,
        (width, height),
        ("image_width", "image_height"),
        &k,
        &d,
        counts,
    )?;
    Ok(Calibration {
        camera,
        format: ctx.format,
        camera_name,
    })
}
