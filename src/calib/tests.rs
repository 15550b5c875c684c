#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

use super::merge::merge_intrinsics;
use super::*;

const OPENCV4_YAML: &str = "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n\
camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 5.0000000000000000e+02, 0., 3.1950000000000000e+02, 0.,\n       5.0100000000000000e+02, 2.3950000000000000e+02, 0., 0., 1. ]\n\
distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n   dt: d\n   data: [ -1.0000000000000001e-01, 2.0000000000000000e-02, 0., 0., 0. ]\n";

fn import(name: &str, text: &str) -> Result<Calibration, ImportError> {
    import_text(Path::new(name), text, None)
}

#[test]
fn opencv_directive_and_tags_are_accepted() {
    let c = import("c.yaml", OPENCV4_YAML).expect("OpenCV 4 YAML");
    assert_eq!(c.format, Format::OpenCvYaml);
    assert_eq!((c.camera.width, c.camera.height), (640, 480));
    assert_eq!(
        (c.camera.fx, c.camera.fy, c.camera.cx, c.camera.cy),
        (500.0, 501.0, 319.5, 239.5)
    );
    assert_eq!(c.camera.distortion.k1, -0.1);
    // The directive line is kept as a line: a syntax error's line number
    // is the file's.
    let broken = OPENCV4_YAML.replace("image_height: 480", "image_height: [480");
    let err = import("c.yaml", &broken).expect_err("unclosed list");
    assert!(matches!(err, ImportError::Syntax { .. }), "{err}");
}

#[test]
fn the_output_parses_back_to_the_same_camera() {
    let c = import("c.yaml", OPENCV4_YAML).unwrap();
    let text = c.to_toml(Path::new("/calib/with\nnewline.yaml"));
    let table: toml::Table = toml::from_str(&text).expect("valid TOML");
    let camera: PinholeCamera = table["camera"]["intrinsics"]
        .clone()
        .try_into()
        .expect("a PinholeCamera");
    assert_eq!(camera, c.camera);
}

#[test]
fn rational_terms_must_be_zero() {
    let eight = OPENCV4_YAML
        .replace("rows: 5", "rows: 8")
        .replace("0., 0., 0. ]", "0., 0., 0., 0., 0., 0. ]");
    let c = import("c.yaml", &eight).expect("zero k4 k5 k6");
    assert_eq!(c.camera.distortion.k2, 0.02);
    let k5 = eight.replace("0., 0., 0., 0., 0., 0. ]", "0., 0., 0., 0., 0.5, 0. ]");
    let err = import("c.yaml", &k5).expect_err("k5 set");
    let msg = err.to_string();
    assert!(
        msg.contains("distortion_coefficients.data[6] (k5)") && msg.contains("rational"),
        "{msg}"
    );
}

#[test]
fn skew_and_bad_rows_are_refused_with_the_key() {
    let skew = OPENCV4_YAML.replace("5.0000000000000000e+02, 0.,", "5.0e+02, 1.5,");
    let msg = import("c.yaml", &skew).expect_err("skew").to_string();
    assert!(msg.contains("camera_matrix.data[1] (skew)"), "{msg}");
    let row = OPENCV4_YAML.replace("0., 0., 1. ]", "0., 0., 2. ]");
    let msg = import("c.yaml", &row).expect_err("K[2][2] = 2").to_string();
    assert!(msg.contains("camera_matrix.data[8]"), "{msg}");
}

#[test]
fn principal_point_outside_the_image_names_the_key() {
    let outside = OPENCV4_YAML.replace("3.1950000000000000e+02", "7.0e+02");
    let msg = import("c.yaml", &outside)
        .expect_err("cx = 700")
        .to_string();
    assert!(
        msg.contains("c.yaml") && msg.contains("camera_matrix.data[2] (cx)") && msg.contains("700"),
        "{msg}"
    );
}

#[test]
fn extension_and_content_must_agree() {
    let msg = import("c.xml", OPENCV4_YAML)
        .expect_err("yaml in .xml")
        .to_string();
    assert!(msg.contains("extension is .xml"), "{msg}");
    let msg = import("c.yml", "<?xml version=\"1.0\"?>\n<opencv_storage/>")
        .expect_err("xml in .yml")
        .to_string();
    assert!(msg.contains("content is XML"), "{msg}");
    let msg = import("c.xml", "<?xml version=\"1.0\"?>\n<svg/>")
        .expect_err("not opencv")
        .to_string();
    assert!(msg.contains("<svg>"), "{msg}");
}

#[test]
fn camera_option_is_for_kalibr_only() {
    let err = import_text(Path::new("c.yaml"), OPENCV4_YAML, Some("cam1")).expect_err("--camera");
    assert!(err.to_string().contains("Kalibr camchains only"), "{err}");
}

#[test]
fn merge_replaces_values_and_keeps_comments() {
    let config = "# top comment\n[camera]\nsource = \"v4l2:/dev/video2\"\n\n\
                  [camera.intrinsics]\nwidth = 640 # the sensor\nheight = 512\nfx = 1.0\nfy = 1.0\ncx = 0.0\ncy = 0.0\n\n\
                  [tracker]\npyramid_levels = 3\n";
    let c = import("c.yaml", OPENCV4_YAML).unwrap();
    let merged = merge_intrinsics(config, &c.camera).expect("merged");
    assert!(merged.contains("# top comment"), "{merged}");
    assert!(merged.contains("width = 640 # the sensor"), "{merged}");
    assert!(merged.contains("pyramid_levels = 3"), "{merged}");
    let table: toml::Table = toml::from_str(&merged).expect("valid TOML");
    let camera: PinholeCamera = table["camera"]["intrinsics"].clone().try_into().unwrap();
    assert_eq!(camera, c.camera);
    assert_eq!(
        table["camera"]["source"].as_str(),
        Some("v4l2:/dev/video2"),
        "{merged}"
    );
    // A config without the section gets one.
    let merged = merge_intrinsics("[tracker]\npyramid_levels = 3\n", &c.camera).unwrap();
    let table: toml::Table = toml::from_str(&merged).expect("valid TOML");
    let camera: PinholeCamera = table["camera"]["intrinsics"].clone().try_into().unwrap();
    assert_eq!(camera, c.camera);
    let err = merge_intrinsics("camera = 3\n", &c.camera).expect_err("camera is a value");
    assert!(err.to_string().contains("`camera`"), "{err}");
}
