//! Issue 21, calibration import: `star calib import` on the same camera
//! written by OpenCV 4 and 5 (FileStorage YAML and XML, from
//! `tests/data/calib/make_opencv_fixtures.py`), by Kalibr (`camchain.yaml`)
//! and as a ROS `camera_info` gives the same `[camera.intrinsics]`, which
//! star's config loader accepts; every bad input is refused with a message
//! naming the file and the problem, never a panic; `--merge` rewrites a
//! config in place.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use star::config::Config;
use star::geometry::PinholeCamera;

const STAR: &str = env!("CARGO_BIN_EXE_star");

/// EuRoC MAV cam0, as the fixtures give it.
fn euroc_cam0() -> PinholeCamera {
    let mut c = PinholeCamera::new(752, 480, 458.654, 457.296, 367.215, 248.375);
    c.distortion.k1 = -0.28340811;
    c.distortion.k2 = 0.07395907;
    c.distortion.p1 = 0.00019359;
    c.distortion.p2 = 1.76187114e-05;
    c
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/calib")
        .join(name)
}

fn star(args: &[&str]) -> Output {
    Command::new(STAR).args(args).output().unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "status {}\nstdout:\n{}\nstderr:\n{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// The camera of a star config file (loaded and validated as star does).
fn intrinsics_of(config: &Path) -> PinholeCamera {
    Config::load(config)
        .unwrap_or_else(|e| panic!("{} is not a valid star config: {e}", config.display()))
        .camera
        .intrinsics
}

fn max_difference(a: &PinholeCamera, b: &PinholeCamera) -> f64 {
    assert_eq!((a.width, a.height), (b.width, b.height));
    let (da, db) = (&a.distortion, &b.distortion);
    [
        a.fx - b.fx,
        a.fy - b.fy,
        a.cx - b.cx,
        a.cy - b.cy,
        da.k1 - db.k1,
        da.k2 - db.k2,
        da.p1 - db.p1,
        da.p2 - db.p2,
        da.k3 - db.k3,
    ]
    .iter()
    .fold(0.0, |m, d| m.max(d.abs()))
}

#[test]
fn every_format_gives_the_same_intrinsics() {
    let dir = tempfile::tempdir().unwrap();
    let want = euroc_cam0();
    for (file, detected) in [
        ("opencv4.yaml", "OpenCV FileStorage YAML"),
        ("opencv5.yaml", "OpenCV FileStorage YAML"),
        ("opencv4.xml", "OpenCV FileStorage XML"),
        ("opencv5.xml", "OpenCV FileStorage XML"),
        ("camchain.yaml", "Kalibr camchain YAML, camera cam0"),
        ("camera_info.yaml", "ROS camera_info YAML"),
    ] {
        let out = dir.path().join(format!("{file}.toml"));
        let o = star(&[
            "calib",
            "import",
            fixture(file).to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{file}: {}", text(&o));
        assert!(
            String::from_utf8_lossy(&o.stdout).contains(&format!("detected {detected}")),
            "{file}: {}",
            text(&o)
        );
        let got = intrinsics_of(&out);
        let diff = max_difference(&got, &want);
        assert!(
            diff <= 1e-9,
            "{file}: {got:?} differs by {diff} from {want:?}"
        );
        // Without -o the section goes to stdout, the detection to stderr.
        let o = star(&["calib", "import", fixture(file).to_str().unwrap()]);
        assert!(o.status.success(), "{file}: {}", text(&o));
        assert_eq!(
            String::from_utf8_lossy(&o.stdout),
            std::fs::read_to_string(&out).unwrap(),
            "{file}"
        );
        assert!(
            String::from_utf8_lossy(&o.stderr).contains(detected),
            "{file}: {}",
            text(&o)
        );
    }
    // The other camera of the camchain differs: the choice is real.
    let out = dir.path().join("cam1.toml");
    let o = star(&[
        "calib",
        "import",
        fixture("camchain.yaml").to_str().unwrap(),
        "--camera",
        "cam1",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let cam1 = intrinsics_of(&out);
    assert_eq!((cam1.fx, cam1.cx), (457.587, 379.999));
}

/// Runs `star calib import` on `contents` saved as `name` (plus `extra`
/// arguments) and checks that it fails, not by a panic, with a message
/// holding the file's path and every one of `needles`.
fn expect_refusal(dir: &Path, name: &str, contents: &[u8], extra: &[&str], needles: &[&str]) {
    let path = dir.join(name);
    std::fs::write(&path, contents).unwrap();
    let mut args = vec!["calib", "import", path.to_str().unwrap()];
    args.extend_from_slice(extra);
    let o = star(&args);
    assert_eq!(o.status.code(), Some(1), "{name}: {}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains(path.to_str().unwrap()), "{name}: {}", text(&o));
    for needle in needles {
        assert!(
            err.contains(needle),
            "{name}: no `{needle}` in {}",
            text(&o)
        );
    }
}

fn read(name: &str) -> String {
    std::fs::read_to_string(fixture(name)).unwrap()
}

/// `text` with `from` replaced by `to`; panics when `from` is absent (the
/// test would otherwise check an unchanged file).
fn edit(text: &str, from: &str, to: &str) -> String {
    assert!(text.contains(from), "`{from}` not in the fixture");
    text.replacen(from, to, 1)
}

/// `text` cut right after `needle`.
fn cut_after(text: &str, needle: &str) -> String {
    let at = text.find(needle).expect("needle in the fixture") + needle.len();
    text[..at].to_string()
}

#[test]
fn unknown_formats_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    expect_refusal(
        d,
        "settings.yaml",
        b"name: front\nexposure: 3\n",
        &[],
        &["unknown calibration format", "name, exposure", "Kalibr"],
    );
    expect_refusal(
        d,
        "image.png",
        &[0x89, b'P', b'N', b'G', 0xff, 0xfe],
        &[],
        &["not UTF-8"],
    );
    expect_refusal(
        d,
        "empty.yaml",
        b"\n\n",
        &[],
        &["unknown calibration format", "empty"],
    );
    expect_refusal(
        d,
        "scene.xml",
        b"<?xml version=\"1.0\"?>\n<scene><camera/></scene>\n",
        &[],
        &["unknown calibration format", "<scene>"],
    );
    expect_refusal(
        d,
        "calib.xml",
        read("opencv4.yaml").as_bytes(),
        &[],
        &["extension is .xml but the content is not XML"],
    );
}

#[test]
fn kalibr_models_star_lacks_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let chain = read("camchain.yaml");
    let omni = edit(
        &edit(&chain, "camera_model: pinhole", "camera_model: omni"),
        "intrinsics: [458.654,",
        "intrinsics: [0.81, 458.654,",
    );
    expect_refusal(
        d,
        "omni.yaml",
        omni.as_bytes(),
        &[],
        &[
            "cam0.camera_model",
            "omni",
            "not supported",
            "pinhole-radtan",
        ],
    );
    for (model, says) in [("ds", "double-sphere"), ("eucm", "extended unified")] {
        let other = edit(
            &chain,
            "camera_model: pinhole",
            &format!("camera_model: {model}"),
        );
        expect_refusal(d, &format!("{model}.yaml"), other.as_bytes(), &[], &[says]);
    }
    let equidistant = edit(
        &chain,
        "distortion_model: radtan",
        "distortion_model: equidistant",
    );
    expect_refusal(
        d,
        "equidistant.yaml",
        equidistant.as_bytes(),
        &[],
        &["cam0.distortion_model", "equidistant", "not supported"],
    );
    let fov = edit(&chain, "distortion_model: radtan", "distortion_model: fov");
    expect_refusal(
        d,
        "fov.yaml",
        fov.as_bytes(),
        &[],
        &["fov", "not supported"],
    );
    // Each camera is checked on its own: an omni cam1 is refused, and does
    // not block cam0.
    let at = chain.rfind("camera_model: pinhole").unwrap();
    let cam1_omni = format!(
        "{}camera_model: omni{}",
        &chain[..at],
        &chain[at + "camera_model: pinhole".len()..]
    );
    expect_refusal(
        d,
        "cam1omni.yaml",
        cam1_omni.as_bytes(),
        &["--camera", "cam1"],
        &["cam1.camera_model", "omni"],
    );
    let o = star(&["calib", "import", d.join("cam1omni.yaml").to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    expect_refusal(
        d,
        "chain.yaml",
        chain.as_bytes(),
        &["--camera", "left"],
        &["no camera `left`", "cam0, cam1"],
    );
    expect_refusal(
        d,
        "info.yaml",
        read("camera_info.yaml").as_bytes(),
        &["--camera", "cam1"],
        &["Kalibr camchains only"],
    );
    let rational = edit(
        &edit(
            &read("camera_info.yaml"),
            "plumb_bob",
            "rational_polynomial",
        ),
        "cols: 5\n  data: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0]",
        "cols: 8\n  data: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0, 0.1, 0, 0]",
    );
    expect_refusal(
        d,
        "rational.yaml",
        rational.as_bytes(),
        &[],
        &[
            "distortion_coefficients.data[5] (k4)",
            "rational",
            "k1 k2 p1 p2 k3 only",
        ],
    );
}

#[test]
fn missing_keys_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let no_distortion = cut_after(&read("opencv5.yaml"), "248.375, 0., 0., 1. ]\n");
    expect_refusal(
        d,
        "nodist.yaml",
        no_distortion.as_bytes(),
        &[],
        &[
            "missing key `distortion_coefficients`",
            "OpenCV FileStorage YAML",
        ],
    );
    let no_width = edit(&read("opencv4.xml"), "<image_width>752</image_width>", "");
    expect_refusal(
        d,
        "nowidth.xml",
        no_width.as_bytes(),
        &[],
        &["missing key `image_width`"],
    );
    let no_intrinsics = edit(
        &read("camchain.yaml"),
        "  intrinsics: [458.654, 457.296, 367.215, 248.375]\n",
        "",
    );
    expect_refusal(
        d,
        "nointr.yaml",
        no_intrinsics.as_bytes(),
        &[],
        &["missing key `cam0.intrinsics`"],
    );
    let no_height = edit(&read("camera_info.yaml"), "image_height: 480\n", "");
    expect_refusal(
        d,
        "noheight.yaml",
        no_height.as_bytes(),
        &[],
        &["missing key `image_height`"],
    );
    let no_data = edit(
        &read("camera_info.yaml"),
        "  data: [458.654, 0, 367.215, 0, 457.296, 248.375, 0, 0, 1]\n",
        "",
    );
    expect_refusal(
        d,
        "nodata.yaml",
        no_data.as_bytes(),
        &[],
        &["missing key `camera_matrix.data`"],
    );
}

#[test]
fn non_positive_focal_lengths_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let zero = edit(&read("opencv5.yaml"), "data: [ 458.654,", "data: [ 0.,");
    expect_refusal(
        d,
        "zero.yaml",
        zero.as_bytes(),
        &[],
        &["camera_matrix.data[0] (fx)", "focal length > 0"],
    );
    let negative = edit(
        &read("opencv4.xml"),
        "457.29599999999999",
        "-457.29599999999999",
    );
    expect_refusal(
        d,
        "neg.xml",
        negative.as_bytes(),
        &[],
        &["camera_matrix.data[4] (fy)", "-457.296"],
    );
    let kalibr = edit(
        &read("camchain.yaml"),
        "intrinsics: [458.654,",
        "intrinsics: [-458.654,",
    );
    expect_refusal(
        d,
        "negk.yaml",
        kalibr.as_bytes(),
        &[],
        &["cam0.intrinsics[0] (fu)", "focal length > 0"],
    );
    let ros = edit(
        &read("camera_info.yaml"),
        "0, 457.296, 248.375",
        "0, 0, 248.375",
    );
    expect_refusal(
        d,
        "zeroros.yaml",
        ros.as_bytes(),
        &[],
        &["camera_matrix.data[4] (fy)"],
    );
    let nan = edit(&read("camchain.yaml"), "0.07395907", ".nan");
    expect_refusal(
        d,
        "nan.yaml",
        nan.as_bytes(),
        &[],
        &["cam0.distortion_coeffs[1] (k2)", "finite"],
    );
}

#[test]
fn wrongly_shaped_matrices_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // rows x cols disagrees with the data.
    let rows = edit(
        &read("opencv5.yaml"),
        "rows: 3\n   cols: 3",
        "rows: 3\n   cols: 4",
    );
    expect_refusal(
        d,
        "rows.yaml",
        rows.as_bytes(),
        &[],
        &[
            "camera_matrix.data",
            "rows x cols = 3 x 4 values",
            "found 9 values",
        ],
    );
    // Consistent, but not a camera matrix: ROS's 3x4 projection matrix
    // given as the camera matrix.
    let projection = edit(
        &read("camera_info.yaml"),
        "  cols: 3\n  data: [458.654, 0, 367.215, 0, 457.296, 248.375, 0, 0, 1]",
        "  cols: 4\n  data: [458.654, 0, 367.215, 0, 0, 457.296, 248.375, 0, 0, 0, 1, 0]",
    );
    expect_refusal(
        d,
        "proj.yaml",
        projection.as_bytes(),
        &[],
        &["key `camera_matrix`", "a 3x3 camera matrix", "3x4"],
    );
    let xml = edit(&read("opencv4.xml"), "<rows>5</rows>", "<rows>6</rows>");
    expect_refusal(
        d,
        "dist.xml",
        xml.as_bytes(),
        &[],
        &["distortion_coefficients.data", "6 x 1", "found 5 values"],
    );
    let square = edit(
        &read("opencv4.yaml"),
        "rows: 5\n   cols: 1",
        "rows: 5\n   cols: 5",
    );
    expect_refusal(
        d,
        "square.yaml",
        square.as_bytes(),
        &[],
        &["distortion_coefficients"],
    );
    let count = edit(
        &read("camchain.yaml"),
        "1.76187114e-05]",
        "1.76187114e-05, 0.0]",
    );
    expect_refusal(
        d,
        "count.yaml",
        count.as_bytes(),
        &[],
        &["cam0.distortion_coeffs", "4 numbers", "5 numbers"],
    );
}

#[test]
fn truncated_files_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (name, fixture_name, after, says) in [
        (
            "cut.yaml",
            "opencv4.yaml",
            "data: [ -0.28340810999999999, 0.0739",
            "not valid YAML",
        ),
        ("cut.xml", "opencv5.xml", "<rows>5</rows>", "not valid XML"),
        (
            "cutk.yaml",
            "camchain.yaml",
            "intrinsics: [458.654, 457",
            "not valid YAML",
        ),
        (
            "cutr.yaml",
            "camera_info.yaml",
            "distortion_coefficients:\n  rows: 1\n",
            "missing key `distortion_coefficients.cols`",
        ),
        (
            "cutm.yaml",
            "opencv5.yaml",
            "camera_matrix: !!opencv-matrix\n",
            "camera_matrix",
        ),
    ] {
        let cut = cut_after(&read(fixture_name), after);
        expect_refusal(d, name, cut.as_bytes(), &[], &[says]);
    }
}

#[test]
fn merge_rewrites_a_config_in_place() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("star.toml");
    let shipped =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/star.toml"))
            .unwrap();
    std::fs::write(&config, &shipped).unwrap();
    let before = Config::load(&config).unwrap();
    let o = star(&[
        "calib",
        "import",
        fixture("opencv4.xml").to_str().unwrap(),
        "--merge",
        config.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let after = Config::load(&config).unwrap();
    assert!(max_difference(&after.camera.intrinsics, &euroc_cam0()) <= 1e-9);
    // Everything else is as it was, comments included.
    let mut rest = after.clone();
    rest.camera.intrinsics = before.camera.intrinsics;
    assert_eq!(rest, before);
    let merged = std::fs::read_to_string(&config).unwrap();
    for line in shipped.lines().filter(|l| l.starts_with('#')) {
        assert!(merged.contains(line), "lost comment `{line}`:\n{merged}");
    }
    // A calibration the config cannot hold leaves the config untouched.
    let too_big = edit(
        &edit(
            &read("camchain.yaml"),
            "resolution: [752, 480]",
            "resolution: [4000, 3000]",
        ),
        "367.215, 248.375",
        "2000.0, 1500.0",
    );
    let big = dir.path().join("big.yaml");
    std::fs::write(&big, too_big).unwrap();
    let o = star(&[
        "calib",
        "import",
        big.to_str().unwrap(),
        "--merge",
        config.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("cam0.resolution[0]"),
        "{}",
        text(&o)
    );
    assert_eq!(std::fs::read_to_string(&config).unwrap(), merged);
}
