//! Issue 21: frames whose size is not the calibration's are refused by the
//! tracker, counted, logged once per size (not per frame) and reported in
//! the summary; tracking resumes when frames of the calibrated size come
//! back. In process ([`Tracker::step`] on iceoryx2 frames this test
//! publishes) and as `star run` (a `pattern:` camera of another size than
//! `[camera.intrinsics]`: the summary and the exit say why nothing tracked).

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::io::Write;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::star_cli::spawn;
use common::wall::wall;
use nalgebra::{Translation3, UnitQuaternion};
use star::clock::monotonic_now_ns;
use star::config::{Config, RendererKind};
use star::geometry::{PinholeCamera, Pose};
use star::ipc::{create_node, load_iceoryx_config, FrameHeader, FramePublisher};
use star::render::cpu::CpuRenderer;
use star::render::{RenderedView, Renderer};
use star::tracker::{Step, StopWhen, Tracker};

const WIDTH: u32 = 320;
const HEIGHT: u32 = 256;
/// The warning the tracker logs when a refused frame's size is new.
const WARNING: &str = "not the calibrated size";

fn camera() -> PinholeCamera {
    PinholeCamera::new(WIDTH, HEIGHT, 210.0, 210.0, 159.5, 127.5)
}

fn pose_at(i: usize) -> Pose {
    let t = i as f64 * 0.02;
    Pose::from_parts(
        Translation3::new(0.1 * t.sin(), 0.05 * t.sin(), 0.0),
        UnitQuaternion::from_euler_angles(0.0, 0.02 * t.sin(), 0.0),
    )
}

/// Log lines written by this process's tracing subscriber.
#[derive(Clone, Default)]
struct Captured(Arc<Mutex<Vec<u8>>>);

impl Write for Captured {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Publishes one `width` x `height` frame and steps the tracker until it
/// has dealt with it; returns that step. A first frame lost while the
/// ports connect is sent again.
fn send(
    publisher: &mut FramePublisher,
    tracker: &mut Tracker,
    stop: &mut StopWhen,
    (width, height): (u32, u32),
    pixels: &[u8],
) -> Step {
    for _attempt in 0..3 {
        publisher
            .publish_with(|slot| {
                *slot.header = FrameHeader::gray8(0, width, height);
                slot.header.capture_ns = monotonic_now_ns();
                slot.pixels[..pixels.len()].copy_from_slice(pixels);
                Ok::<(), std::convert::Infallible>(())
            })
            .expect("publish");
        let sent = Instant::now();
        while sent.elapsed() < Duration::from_secs(5) {
            match tracker.step(stop).expect("step") {
                Step::Waited => continue,
                step => return step,
            }
        }
    }
    panic!("the tracker never took a {width}x{height} frame");
}

#[test]
fn wrong_size_frames_are_refused_counted_and_logged_once_per_size() {
    let log = Captured::default();
    let writer = log.clone();
    tracing_subscriber::fmt()
        .with_writer(move || writer.clone())
        .with_env_filter("warn")
        .with_ansi(false)
        .init();
    let _cleanup = common::Cleanup(common::prefix("fsize"));
    let dir = tempfile::tempdir().unwrap();
    let mesh_path = star::map::write_obj(&wall(), dir.path(), "wall").unwrap();
    let map = Arc::new(star::map::load_obj(&mesh_path).unwrap());
    let mut truth = CpuRenderer::new(map).unwrap();
    let mut view = RenderedView::for_camera(&camera());
    let mut image = |i: usize| {
        truth.render(&pose_at(i), &camera(), &mut view).unwrap();
        view.gray.to_u8().data().to_vec()
    };

    let mut config = Config::default();
    config.camera.intrinsics = camera();
    config.map.mesh = mesh_path;
    config.render.renderer = RendererKind::Cpu;
    config.mavlink.enabled = false;
    config.ipc.iceoryx2_config = dir.path().join("iceoryx2.toml");
    config.ipc.silence_timeout_ms = 10_000;
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/iceoryx2.toml");
    let iox = std::fs::read_to_string(shipped).unwrap().replace(
        "prefix = \"iox2_\"",
        &format!("prefix = \"{}\"", common::prefix("fsize")),
    );
    std::fs::write(&config.ipc.iceoryx2_config, iox).unwrap();
    config.validate(Path::new("track_frame_size")).unwrap();

    let shutdown = Arc::new(AtomicBool::new(false));
    let mut tracker = star::tracker::start(&config, Some(pose_at(0)), shutdown).expect("start");
    let node = create_node(
        "test-frame-size-camera",
        &load_iceoryx_config(&config.ipc.iceoryx2_config, None).unwrap(),
    )
    .unwrap();
    let mut publisher = FramePublisher::new(&node).unwrap();
    let mut stop = StopWhen::default();

    let good = (WIDTH, HEIGHT);
    let mut steps = Vec::new();
    for i in 0..10 {
        steps.push(send(
            &mut publisher,
            &mut tracker,
            &mut stop,
            good,
            &image(i),
        ));
    }
    assert!(steps.contains(&Step::Tracked), "{steps:?}");
    // Two runs of frames of other sizes (a camera that changed mode twice).
    for (size, count) in [((160, 128), 6), ((WIDTH, HEIGHT / 2), 4)] {
        let pixels = vec![100u8; (size.0 * size.1) as usize];
        for _ in 0..count {
            let step = send(&mut publisher, &mut tracker, &mut stop, size, &pixels);
            assert_eq!(step, Step::Rejected, "a {size:?} frame");
        }
    }
    let mut resumed = Vec::new();
    for i in 10..20 {
        resumed.push(send(
            &mut publisher,
            &mut tracker,
            &mut stop,
            good,
            &image(i),
        ));
    }
    assert!(resumed.contains(&Step::Tracked), "{resumed:?}");

    let summary = tracker.finish(&mut stop).unwrap();
    assert_eq!(summary.wrong_size.frames, 10, "{summary:?}");
    assert_eq!(summary.wrong_size.found, Some((320, 128)), "{summary:?}");
    assert_eq!(summary.wrong_size.calibrated, Some((WIDTH, HEIGHT)));
    assert_eq!(summary.rejected, 10, "{summary:?}");
    assert_eq!(summary.frames, 20, "{summary:?}");
    let text = String::from_utf8(log.0.lock().unwrap().clone()).unwrap();
    let warnings: Vec<&str> = text.lines().filter(|l| l.contains(WARNING)).collect();
    assert_eq!(
        warnings.len(),
        2,
        "one warning per size, not per frame:\n{text}"
    );
    assert!(
        warnings[0].contains("160x128") && warnings[0].contains("320x256"),
        "{text}"
    );
    assert!(warnings[1].contains("320x128"), "{text}");
}

#[test]
fn star_run_reports_wrong_size_frames() {
    let dir = tempfile::tempdir().unwrap();
    let tag = "fsizerun";
    let _cleanup = common::Cleanup(common::prefix(tag));
    let mesh = star::map::write_obj(&wall(), dir.path(), "wall").unwrap();
    let c = camera();
    let config = common::write_isolated_configs(
        dir.path(),
        tag,
        &format!(
            "[camera]\nsource = \"pattern:160x128\"\n\
             [camera.intrinsics]\nwidth = {}\nheight = {}\nfx = {:?}\nfy = {:?}\ncx = {:?}\ncy = {:?}\n\
             [map]\nmesh = \"{}\"\n[render]\nrenderer = \"cpu\"\n[mavlink]\nenabled = false\n\
             [tracker]\ninit_pose = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]\n",
            c.width,
            c.height,
            c.fx,
            c.fy,
            c.cx,
            c.cy,
            mesh.display()
        ),
    );
    let mut run = spawn(&["--log", "warn", "run", "--config", config.to_str().unwrap()]);
    assert!(
        run.wait_for(WARNING, Duration::from_secs(60)),
        "no warning:\n{}",
        run.drain_log()
    );
    // Let more frames be refused (the pattern runs at 50 Hz).
    std::thread::sleep(Duration::from_millis(500));
    let (status, _) = run.signal_and_wait(libc::SIGTERM, Duration::from_secs(20));
    let err = run.drain_log();
    let out = run.stdout();
    assert_eq!(status.code(), Some(1), "stdout:\n{out}\nstderr:\n{err}");
    assert_eq!(err.matches(WARNING).count(), 1, "{err}");
    // "rejected N (wrong size N)": every rejected frame was of the wrong size.
    let line = out
        .lines()
        .find(|l| l.starts_with("track: frames processed"))
        .unwrap_or_else(|| panic!("no summary:\n{out}"));
    let after = |key: &str| -> u64 {
        line.split(key)
            .nth(1)
            .and_then(|s| s.split([' ', ')']).next())
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("no `{key}` in {line}"))
    };
    let (rejected, wrong) = (after("rejected "), after("(wrong size "));
    assert!(wrong >= 2, "{line}");
    assert_eq!(rejected, wrong, "{line}");
    assert!(
        err.contains(&format!(
            "tracked nothing: {wrong} frames refused because they are 160x128 and the calibration ([camera.intrinsics]) is 320x256"
        )),
        "{err}"
    );
}
