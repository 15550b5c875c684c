//! Issue 24, input validation and `star check-config`: insane calibration
//! and mesh values are refused with the sane bound in the message; a mesh
//! whose materials are undefined or that has no colors loads with a warning
//! saying what that does to tracking; a mesh too large for memory is an
//! error naming the map and the bytes; and `check-config` opens every file
//! the config names (map, relocalization database, iceoryx2 config).

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::star_cli::{dataset, STAR};

fn check_config(config: &Path, extra: &[&str]) -> Output {
    let mut cmd = Command::new(STAR);
    cmd.args(["check-config"]).args(extra).arg(config);
    cmd.env("NO_COLOR", "1").output().unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "status {}\nstdout:\n{}\nstderr:\n{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// A star config naming `mesh`, plus `extra` TOML.
fn config_for(dir: &Path, mesh: &Path, extra: &str) -> PathBuf {
    let path = dir.join("star.toml");
    std::fs::write(
        &path,
        format!(
            "[map]\nmesh = \"{}\"\n[ipc]\niceoryx2_config = \"{}\"\n{extra}",
            mesh.display(),
            dir.join("no-iceoryx2.toml").display()
        ),
    )
    .unwrap();
    path
}

const GRAY: &str = "0.5 0.5 0.5";

fn triangle(v2: &str, color: &str) -> String {
    format!("v 0 0 0 {GRAY}\nv 1 0 0 {GRAY}\nv {v2} {color}\nf 1 2 3\n")
}

fn refused(what: &str, obj: &str, needles: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("map.obj");
    std::fs::write(&mesh, obj).unwrap();
    let o = check_config(&config_for(dir.path(), &mesh, ""), &[]);
    let all = text(&o);
    assert!(!o.status.success(), "{what}: accepted\n{all}");
    for needle in needles.iter().chain([&mesh.to_str().unwrap()]) {
        assert!(all.contains(needle), "{what}: no `{needle}` in\n{all}");
    }
}

#[test]
fn insane_vertices_and_colors_are_refused_with_the_bound() {
    refused(
        "coordinate 1e38",
        &triangle("0 1e38 0", GRAY),
        &[
            ":3:",
            "vertex coordinate 1e38 is outside the sane range -1e6..=1e6",
        ],
    );
    refused(
        "color 500",
        &triangle("0 1 0", "0.5 500 0.5"),
        &[
            ":3:",
            "vertex color 500 is outside the sane range 0..=1, or 0..=255",
        ],
    );
    refused(
        "color -3",
        &triangle("0 1 0", "-3 0.5 0.5"),
        &[":3:", "vertex color -3 is outside the sane range"],
    );
}

#[test]
fn insane_distortion_is_refused_with_the_bound() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("star.toml");
    let intrinsics = "[camera.intrinsics]\nwidth = 640\nheight = 512\nfx = 420.0\nfy = 420.0\ncx = 319.5\ncy = 255.5\n[camera.intrinsics.distortion]\n";
    std::fs::write(&cfg, format!("{intrinsics}k1 = 1e30\n")).unwrap();
    let o = check_config(&cfg, &["--values-only"]);
    let all = text(&o);
    assert!(!o.status.success(), "{all}");
    for needle in [
        "distortion.k1",
        "1000000000000000000000000000000",
        "-100..=100",
    ] {
        assert!(all.contains(needle), "no `{needle}` in\n{all}");
    }
    std::fs::write(&cfg, format!("{intrinsics}p2 = 3.0\n")).unwrap();
    let o = check_config(&cfg, &["--values-only"]);
    let all = text(&o);
    assert!(!o.status.success(), "{all}");
    assert!(
        all.contains("distortion.p2") && all.contains("-1..=1"),
        "{all}"
    );
}

#[test]
fn undefined_materials_and_colorless_meshes_warn_of_the_consequence() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("m.mtl"), "newmtl wall\nKd 0.4 0.5 0.6\n").unwrap();
    let mesh = dir.path().join("undefined.obj");
    std::fs::write(
        &mesh,
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl paint\nf 1 2 3\n",
    )
    .unwrap();
    let o = check_config(&config_for(dir.path(), &mesh, ""), &[]);
    let all = text(&o);
    for needle in [
        "material is not defined",
        "paint",
        "render flat white",
        "nothing to align to",
    ] {
        assert!(all.contains(needle), "no `{needle}` in\n{all}");
    }

    let mesh = dir.path().join("plain.obj");
    std::fs::write(&mesh, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let o = check_config(&config_for(dir.path(), &mesh, ""), &[]);
    let all = text(&o);
    assert!(all.contains("the mesh has no colors"), "{all}");
    assert!(all.contains("nothing to align to"), "{all}");

    // A colored mesh does not warn.
    let mesh = dir.path().join("colored.obj");
    std::fs::write(&mesh, triangle("0 1 0", GRAY)).unwrap();
    let o = check_config(&config_for(dir.path(), &mesh, ""), &[]);
    let all = text(&o);
    assert!(o.status.success(), "{all}");
    assert!(!all.contains("WARN"), "{all}");
}

/// A sparse terabyte of zeros named `.obj`: the OBJ text is read line by
/// line, never whole, so it is refused at its first line (one megabyte
/// without a newline), with the file and the line, under an 8 GiB address
/// space. (The mesh's own arrays are reserved with `try_reserve` and named
/// in bytes when they do not fit: `MapError::OutOfMemory`.)
#[test]
fn a_terabyte_obj_of_zeros_is_refused_at_its_first_line() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("huge.obj");
    // A sparse terabyte: nothing is written to disk.
    let size: u64 = 1 << 40;
    std::fs::File::create(&mesh).unwrap().set_len(size).unwrap();
    let mut cmd = Command::new(STAR);
    cmd.args(["check-config"])
        .arg(config_for(dir.path(), &mesh, ""));
    // SAFETY: setrlimit is async-signal-safe; the child only lowers its own
    // address-space limit (8 GiB) so the test holds wherever overcommit is
    // permissive.
    unsafe {
        cmd.pre_exec(|| {
            let limit = libc::rlimit {
                rlim_cur: 8 << 30,
                rlim_max: 8 << 30,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let o = cmd.output().unwrap();
    let all = text(&o);
    assert!(!o.status.success(), "{all}");
    for needle in [
        &format!("{}:1: ", mesh.display()),
        "longer than 1048576 bytes: not OBJ text",
    ] {
        assert!(all.contains(needle), "no `{needle}` in\n{all}");
    }
}

#[test]
fn check_config_opens_every_file_it_names() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset();
    let map = ds.join("map/map.obj");
    let cam = std::fs::read_to_string(ds.join("camera.toml")).unwrap();
    let cam: String = cam
        .lines()
        .filter(|l| !l.starts_with("depth_scale"))
        .map(|l| l.replace("[distortion]", "[camera.intrinsics.distortion]") + "\n")
        .collect();
    let grid =
        "[reloc]\ngrid_spacing_m = 2.0\nheights_m = [1.2]\nyaw_steps = 2\npitches_deg = [0.0]\n";
    let build_cfg = dir.path().join("build.toml");
    std::fs::write(&build_cfg, grid).unwrap();
    let db = dir.path().join("map.reloc");
    let o = Command::new(STAR)
        .args(["--log", "warn", "reloc", "build", "--map"])
        .arg(&map)
        .arg("--camera")
        .arg(ds.join("camera.toml"))
        .arg("--config")
        .arg(&build_cfg)
        .arg("-o")
        .arg(&db)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));

    // Everything in order: one line per file.
    let iox = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/iceoryx2.toml");
    let good = format!(
        "[reloc]\ndatabase = \"{}\"\n[camera.intrinsics]\n{cam}",
        db.display()
    );
    let cfg = config_for(dir.path(), &map, &good);
    let text_cfg = std::fs::read_to_string(&cfg).unwrap().replace(
        &dir.path().join("no-iceoryx2.toml").display().to_string(),
        &iox.display().to_string(),
    );
    std::fs::write(&cfg, &text_cfg).unwrap();
    let o = check_config(&cfg, &[]);
    let all = text(&o);
    assert!(o.status.success(), "{all}");
    for needle in [
        format!("# map {}:", map.display()),
        format!("# relocalization database {}:", db.display()),
        format!("# iceoryx2 config {}: parsed", iox.display()),
    ] {
        assert!(all.contains(&needle), "no `{needle}` in\n{all}");
    }

    // The database against other intrinsics.
    let other = text_cfg.replace("fx = 420.0", "fx = 300.0");
    assert_ne!(other, text_cfg, "the dataset's fx changed; update the test");
    std::fs::write(&cfg, &other).unwrap();
    let o = check_config(&cfg, &[]);
    let all = text(&o);
    assert!(!o.status.success(), "{all}");
    assert!(
        all.contains("reloc.database") && all.contains(db.to_str().unwrap()),
        "{all}"
    );

    // A broken iceoryx2 config.
    let bad_iox = dir.path().join("bad-iceoryx2.toml");
    std::fs::write(&bad_iox, "[global\nprefix = ").unwrap();
    std::fs::write(
        &cfg,
        text_cfg.replace(&iox.display().to_string(), &bad_iox.display().to_string()),
    )
    .unwrap();
    let o = check_config(&cfg, &[]);
    let all = text(&o);
    assert!(!o.status.success(), "{all}");
    assert!(
        all.contains("ipc.iceoryx2_config") && all.contains(bad_iox.to_str().unwrap()),
        "{all}"
    );

    // A missing map, named; `--values-only` does not open it.
    std::fs::write(
        &cfg,
        text_cfg.replace(map.to_str().unwrap(), "/nonexistent/map.obj"),
    )
    .unwrap();
    let o = check_config(&cfg, &[]);
    let all = text(&o);
    assert!(!o.status.success(), "{all}");
    assert!(
        all.contains("map.mesh") && all.contains("/nonexistent/map.obj"),
        "{all}"
    );
    assert!(check_config(&cfg, &["--values-only"]).status.success());
}

#[test]
fn a_fifo_config_or_material_library_is_refused_not_waited_on() {
    let dir = tempfile::tempdir().unwrap();
    let mkfifo = |path: &Path| {
        let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
        // SAFETY: mkfifo with a valid C string.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
    };
    let fifo_cfg = dir.path().join("fifo.toml");
    mkfifo(&fifo_cfg);
    let mtl = dir.path().join("fifo.mtl");
    mkfifo(&mtl);
    let mesh = dir.path().join("map.obj");
    std::fs::write(
        &mesh,
        "mtllib fifo.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n",
    )
    .unwrap();
    let cfg = config_for(dir.path(), &mesh, "");
    for (config, named) in [(&fifo_cfg, &fifo_cfg), (&cfg, &mtl)] {
        let mut run = common::star_cli::spawn(&["check-config", config.to_str().unwrap()]);
        let (status, _) = run.wait_timeout(
            std::time::Duration::from_secs(60),
            std::time::Instant::now(),
        );
        let err = run.drain_log();
        assert!(!status.success(), "{err}");
        assert!(
            err.contains(named.to_str().unwrap()) && err.contains("not a regular file"),
            "{err}"
        );
    }
}

/// An error that names its cause in its own message (`cannot read FILE:
/// the I/O error`) prints that cause once, not again as the next link of
/// the chain.
#[test]
fn an_error_prints_each_cause_once() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.obj");
    let o = Command::new(STAR)
        .args(["map", "info"])
        .arg(&missing)
        .env("NO_COLOR", "1")
        .output()
        .unwrap();
    assert!(!o.status.success(), "{}", text(&o));
    let stderr = String::from_utf8_lossy(&o.stderr);
    let cause = std::fs::metadata(&missing).unwrap_err().to_string();
    assert!(stderr.contains(&cause), "{}", text(&o));
    assert_eq!(stderr.matches(&cause).count(), 1, "{}", text(&o));

    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[keyframe]\nfar_m = 0.3\n").unwrap();
    let o = check_config(&bad, &["--values-only"]);
    assert!(!o.status.success(), "{}", text(&o));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(stderr.matches("keyframe.far_m").count(), 1, "{}", text(&o));
}
