//! Kalibr `camchain.yaml` (and `camchain-imucam.yaml`): one mapping per
//! camera (`cam0`, `cam1`, ...) with `camera_model`, `intrinsics`,
//! `distortion_model`, `distortion_coeffs` and `resolution`.
//!
//! star reads the `pinhole` camera model with `radtan` distortion
//! (`[k1 k2 r1 r2]`, OpenCV's `k1 k2 p1 p2`) or `none`; the other models
//! (`omni`, `ds`, `eucm`; `equidistant`, `fov`) are refused by name.

use serde_yaml_ng::{Mapping, Value};

use super::model::{self, SourceKeys};
use super::yaml::{self, Node};
use super::{Calibration, Ctx, ImportError};
use crate::geometry::{Distortion, PinholeCamera};

/// The camera names (`camN` keys with a mapping value) of a camchain, in
/// file order.
pub(super) fn camera_names(map: &Mapping) -> Vec<String> {
    map.iter()
        .filter_map(|(k, v)| {
            let name = k.as_str()?;
            let is_cam = name
                .strip_prefix("cam")
                .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()));
            (is_cam && yaml::untag(v).is_mapping()).then(|| name.to_string())
        })
        .collect()
}

/// Reads camera `camera` of a camchain document.
pub(super) fn from_yaml(
    ctx: Ctx<'_>,
    value: &Value,
    camera: &str,
) -> Result<Calibration, ImportError> {
    let root = Node::root(ctx, value);
    let names = root
        .value
        .as_mapping()
        .map(camera_names)
        .unwrap_or_default();
    if !names.iter().any(|n| n == camera) {
        return Err(ImportError::NoSuchCamera {
            path: ctx.path.to_owned(),
            format: ctx.format,
            camera: camera.to_string(),
            available: names,
        });
    }
    let cam = root.get(camera)?;
    let model_node = cam.get("camera_model")?;
    let model = model_node.str()?;
    if model != "pinhole" {
        let what = match model {
            "omni" => "the unified (omni) camera model",
            "ds" => "the double-sphere (ds) camera model",
            "eucm" => "the extended unified (eucm) camera model",
            _ => "the camera model",
        };
        return Err(ctx.unsupported(
            model_node.key,
            format!("{what} `{model}`"),
            "star's camera is pinhole with radial-tangential distortion; recalibrate with Kalibr's `pinhole-radtan` model",
        ));
    }
    let intrinsics_node = cam.get("intrinsics")?;
    let intrinsics = intrinsics_node.numbers()?;
    let [fu, fv, pu, pv] = intrinsics[..] else {
        return Err(ctx.wrong_type(
            intrinsics_node.key,
            "4 numbers [fu, fv, pu, pv] (pinhole)",
            format!("{} numbers", intrinsics.len()),
        ));
    };
    let resolution_node = cam.get("resolution")?;
    let resolution = resolution_node.numbers()?;
    let size =
        |v: f64| (v.fract() == 0.0 && v >= 1.0 && v <= f64::from(u32::MAX)).then_some(v as u32);
    let (Some(width), Some(height), 2) = (
        resolution.first().copied().and_then(size),
        resolution.get(1).copied().and_then(size),
        resolution.len(),
    ) else {
        return Err(ctx.wrong_type(
            resolution_node.key,
            "2 positive integers [width, height]",
            format!("{resolution:?}"),
        ));
    };
    let distortion_model_node = cam.get("distortion_model")?;
    let distortion_model = distortion_model_node.str()?;
    let coeffs_node = cam.opt("distortion_coeffs")?;
    let coeffs = match &coeffs_node {
        Some(n) => n.numbers()?,
        None => Vec::new(),
    };
    let coeffs_key = format!("{camera}.distortion_coeffs");
    let distortion = match distortion_model {
        "radtan" => match coeffs[..] {
            [k1, k2, r1, r2] => Distortion {
                k1,
                k2,
                p1: r1,
                p2: r2,
                k3: 0.0,
            },
            _ if coeffs_node.is_none() => return Err(ctx.missing(coeffs_key)),
            _ => {
                return Err(ctx.wrong_type(
                    coeffs_key,
                    "4 numbers [k1, k2, r1, r2] (radtan)",
                    format!("{} numbers", coeffs.len()),
                ))
            }
        },
        "none" if coeffs.iter().all(|c| *c == 0.0) => Distortion::default(),
        "none" => {
            return Err(ctx.wrong_type(
                coeffs_key,
                "no coefficients, or zeros (distortion_model none)",
                format!("{coeffs:?}"),
            ))
        }
        other => {
            let what = match other {
                "equidistant" => "the equidistant (fisheye) distortion model",
                "fov" => "the field-of-view (fov) distortion model",
                _ => "the distortion model",
            };
            return Err(ctx.unsupported(
                distortion_model_node.key,
                format!("{what} `{other}`"),
                "star's distortion is radial-tangential (k1 k2 p1 p2 k3); recalibrate with Kalibr's `pinhole-radtan` model",
            ));
        }
    };
    let key = |suffix: &str| format!("{camera}.{suffix}");
    let keys = SourceKeys {
        width: key("resolution[0]"),
        height: key("resolution[1]"),
        fx: key("intrinsics[0] (fu)"),
        fy: key("intrinsics[1] (fv)"),
        cx: key("intrinsics[2] (pu)"),
        cy: key("intrinsics[3] (pv)"),
        distortion: [
            Some(key("distortion_coeffs[0] (k1)")),
            Some(key("distortion_coeffs[1] (k2)")),
            Some(key("distortion_coeffs[2] (r1)")),
            Some(key("distortion_coeffs[3] (r2)")),
            None,
        ],
    };
    let camera_model = PinholeCamera {
        distortion,
        ..PinholeCamera::new(width, height, fu, fv, pu, pv)
    };
    Ok(Calibration {
        camera: model::checked(ctx, camera_model, &keys)?,
        format: ctx.format,
        camera_name: Some(camera.to_string()),
    })
}
