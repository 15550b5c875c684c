//! OpenCV `FileStorage` calibrations, YAML and XML, as `calibrateCamera`
//! users save them: `image_width`, `image_height`, `camera_matrix` and
//! `distortion_coefficients` (`opencv-matrix`: `rows`, `cols`, `dt`,
//! `data`). Other keys (`calibration_time`, `avg_reprojection_error`,
//! per-view matrices) are ignored.

use std::path::Path;

use serde_yaml_ng::Value;

use super::model::{self, Matrix};
use super::yaml::Node;
use super::{Calibration, Ctx, ImportError};

/// The distortion vector lengths `calibrateCamera` writes.
const DISTORTION_COUNTS: [usize; 5] = [4, 5, 8, 12, 14];

/// Reads an OpenCV FileStorage YAML document.
pub(super) fn from_yaml(ctx: Ctx<'_>, value: &Value) -> Result<Calibration, ImportError> {
    let root = Node::root(ctx, value);
    let width = root.get("image_width")?.pixels()?;
    let height = root.get("image_height")?.pixels()?;
    let k = root.get("camera_matrix")?.matrix()?;
    let d = root.get("distortion_coefficients")?.matrix()?;
    build(ctx, width, height, &k, &d)
}

/// The root element's name of XML `text` (a syntax error names the line).
pub(super) fn xml_root_name(path: &Path, text: &str) -> Result<String, ImportError> {
    let doc = parse_xml(path, text)?;
    Ok(doc.root_element().tag_name().name().to_string())
}

fn parse_xml<'t>(path: &Path, text: &'t str) -> Result<roxmltree::Document<'t>, ImportError> {
    roxmltree::Document::parse(text).map_err(|e| ImportError::Syntax {
        path: path.to_owned(),
        syntax: "XML",
        message: e.to_string(),
    })
}

/// Reads an OpenCV FileStorage XML document (`<opencv_storage>`).
pub(super) fn from_xml(ctx: Ctx<'_>, text: &str) -> Result<Calibration, ImportError> {
    let doc = parse_xml(ctx.path, text)?;
    let root = doc.root_element();
    let width = pixels(ctx, element(ctx, root, "image_width", "image_width")?)?;
    let height = pixels(ctx, element(ctx, root, "image_height", "image_height")?)?;
    let k = xml_matrix(ctx, root, "camera_matrix")?;
    let d = xml_matrix(ctx, root, "distortion_coefficients")?;
    build(ctx, width, height, &k, &d)
}

/// The calibration from the four OpenCV entries.
fn build(
    ctx: Ctx<'_>,
    width: u32,
    height: u32,
    k: &Matrix,
    d: &Matrix,
) -> Result<Calibration, ImportError> {
    let camera = model::opencv_camera(
        ctx,
        (width, height),
        ("image_width", "image_height"),
        k,
        d,
        &DISTORTION_COUNTS,
    )?;
    Ok(Calibration {
        camera,
        format: ctx.format,
        camera_name: None,
    })
}

/// The child element `name` of `parent`; `key` names it in errors.
fn element<'a, 'input>(
    ctx: Ctx<'_>,
    parent: roxmltree::Node<'a, 'input>,
    name: &str,
    key: &str,
) -> Result<(roxmltree::Node<'a, 'input>, String), ImportError> {
    parent
        .children()
        .find(|n| n.is_element() && n.tag_name().name() == name)
        .map(|n| (n, key.to_string()))
        .ok_or_else(|| ctx.missing(key))
}

/// The element's text, trimmed.
fn text<'a>(node: &roxmltree::Node<'a, '_>) -> &'a str {
    node.text().unwrap_or("").trim()
}

fn found(text: &str) -> String {
    if text.is_empty() {
        "nothing".into()
    } else {
        format!("{text:?}")
    }
}

fn pixels(
    ctx: Ctx<'_>,
    (node, key): (roxmltree::Node<'_, '_>, String),
) -> Result<u32, ImportError> {
    let t = text(&node);
    t.parse::<u32>()
        .ok()
        .filter(|v| *v > 0)
        .ok_or_else(|| ctx.wrong_type(key, "a positive integer (pixels)", found(t)))
}

fn count(
    ctx: Ctx<'_>,
    (node, key): (roxmltree::Node<'_, '_>, String),
) -> Result<usize, ImportError> {
    let t = text(&node);
    t.parse::<usize>()
        .map_err(|_| ctx.wrong_type(key, "a non-negative integer", found(t)))
}

/// A number as OpenCV writes it (`1.`, `-2.5e-01`, `.Inf`, `-.Inf`, `.Nan`).
fn number(token: &str) -> Option<f64> {
    match token {
        ".Inf" | "+.Inf" => Some(f64::INFINITY),
        "-.Inf" => Some(f64::NEG_INFINITY),
        ".Nan" => Some(f64::NAN),
        t => t.parse().ok(),
    }
}

/// `<key type_id="opencv-matrix"><rows/><cols/><dt/><data/></key>`.
fn xml_matrix(
    ctx: Ctx<'_>,
    root: roxmltree::Node<'_, '_>,
    key: &str,
) -> Result<Matrix, ImportError> {
    let (node, _) = element(ctx, root, key, key)?;
    match node.attribute("type_id") {
        Some("opencv-matrix") => {}
        other => {
            return Err(ctx.wrong_type(
                key,
                "an element with type_id=\"opencv-matrix\"",
                match other {
                    Some(t) => format!("type_id={t:?}"),
                    None => "no type_id".into(),
                },
            ))
        }
    }
    let sub = |name: &str| format!("{key}.{name}");
    let rows = count(ctx, element(ctx, node, "rows", &sub("rows"))?)?;
    let cols = count(ctx, element(ctx, node, "cols", &sub("cols"))?)?;
    let (dt_node, dt_key) = element(ctx, node, "dt", &sub("dt"))?;
    let dt = text(&dt_node);
    if !matches!(dt, "d" | "f") {
        return Err(ctx.wrong_type(
            dt_key,
            "`d` or `f` (one channel of double or float)",
            found(dt),
        ));
    }
    let (data_node, data_key) = element(ctx, node, "data", &sub("data"))?;
    let data = text(&data_node)
        .split_whitespace()
        .enumerate()
        .map(|(i, token)| {
            number(token)
                .ok_or_else(|| ctx.wrong_type(format!("{data_key}[{i}]"), "a number", found(token)))
        })
        .collect::<Result<Vec<f64>, _>>()?;
    Matrix { rows, cols, data }.consistent(ctx, key)
}
