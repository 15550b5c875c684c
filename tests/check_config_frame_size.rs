//! Issue 21: `star check-config` warns when the source is known to deliver
//! frames of another size than `[camera.intrinsics]` (a `pattern:` source;
//! a replay dataset's `camera.toml` or first frame), and says nothing when
//! the sizes agree. A warning does not fail the check.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::star_cli::STAR;
use common::wall::wall;

const WARNING: &str = "# warning:";

fn check_config(config: &Path, extra: &[&str]) -> Output {
    Command::new(STAR)
        .arg("check-config")
        .args(extra)
        .arg(config)
        .output()
        .unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "status {}\nstdout:\n{}\nstderr:\n{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// A one-frame dataset in `dir/name`: `camera.toml` says `calibrated`, the
/// frame is `image` pixels.
fn dataset(dir: &Path, name: &str, calibrated: (u32, u32), image: (u32, u32)) -> PathBuf {
    let ds = dir.join(name);
    std::fs::create_dir_all(ds.join("rgb")).unwrap();
    let (w, h) = calibrated;
    std::fs::write(
        ds.join("camera.toml"),
        format!(
            "width = {w}\nheight = {h}\nfx = 200.0\nfy = 200.0\ncx = {}\ncy = {}\n",
            f64::from(w) / 2.0 - 0.5,
            f64::from(h) / 2.0 - 0.5
        ),
    )
    .unwrap();
    std::fs::write(ds.join("rgb.txt"), "# timestamp filename\n1.0 rgb/1.png\n").unwrap();
    image::GrayImage::from_pixel(image.0, image.1, image::Luma([90]))
        .save(ds.join("rgb/1.png"))
        .unwrap();
    ds
}

/// A config with a 320x256 calibration, the wall map and `source`.
fn config(dir: &Path, name: &str, mesh: &Path, source: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(
        &path,
        format!(
            "[camera]\nsource = \"{source}\"\n\
             [camera.intrinsics]\nwidth = 320\nheight = 256\nfx = 210.0\nfy = 210.0\ncx = 159.5\ncy = 127.5\n\
             [map]\nmesh = \"{}\"\n[ipc]\niceoryx2_config = \"{}\"\n",
            mesh.display(),
            dir.join("no-iceoryx2.toml").display()
        ),
    )
    .unwrap();
    path
}

fn warnings(o: &Output) -> Vec<String> {
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .filter(|l| l.starts_with(WARNING))
        .map(str::to_string)
        .collect()
}

#[test]
fn check_config_warns_when_the_frame_size_is_not_the_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mesh = star::map::write_obj(&wall(), d, "wall").unwrap();

    // A dataset recorded at another size: its calibration and its frames.
    let small = dataset(d, "small", (160, 128), (160, 128));
    let cfg = config(
        d,
        "small.toml",
        &mesh,
        &format!("replay:{}", small.display()),
    );
    let o = check_config(&cfg, &[]);
    assert!(o.status.success(), "{}", text(&o));
    let w = warnings(&o);
    assert_eq!(w.len(), 2, "{}", text(&o));
    assert!(
        w[0].contains("small/camera.toml is 160x128")
            && w[0].contains("[camera.intrinsics] is 320x256"),
        "{}",
        text(&o)
    );
    assert!(w[1].contains("rgb/1.png is 160x128"), "{}", text(&o));

    // Its camera.toml agrees with the config, its frames do not.
    let frames = dataset(d, "frames", (320, 256), (320, 128));
    let cfg = config(
        d,
        "frames.toml",
        &mesh,
        &format!("replay:{}", frames.display()),
    );
    let o = check_config(&cfg, &[]);
    assert!(o.status.success(), "{}", text(&o));
    let w = warnings(&o);
    assert_eq!(w.len(), 1, "{}", text(&o));
    assert!(w[0].contains("rgb/1.png is 320x128"), "{}", text(&o));

    // Everything agrees: no warning.
    let same = dataset(d, "same", (320, 256), (320, 256));
    let cfg = config(d, "same.toml", &mesh, &format!("replay:{}", same.display()));
    let o = check_config(&cfg, &[]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(warnings(&o).is_empty(), "{}", text(&o));

    // A pattern source is known without opening anything.
    let cfg = config(d, "pattern.toml", &mesh, "pattern:640x512");
    let o = check_config(&cfg, &["--values-only"]);
    assert!(o.status.success(), "{}", text(&o));
    let w = warnings(&o);
    assert_eq!(w.len(), 1, "{}", text(&o));
    assert!(w[0].contains("pattern:640x512 is 640x512"), "{}", text(&o));
    let cfg = config(d, "pattern_ok.toml", &mesh, "pattern:320x256");
    let o = check_config(&cfg, &["--values-only"]);
    assert!(
        o.status.success() && warnings(&o).is_empty(),
        "{}",
        text(&o)
    );
}
