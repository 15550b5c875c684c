//! Tests of the sim camera: the scene check, the pose chain (the inverse of
//! the MAVLink conversion), and a frame end to end from a stand-in
//! autopilot that streams SIM_STATE over TCP.

use std::io::{BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

use mavlink::dialects::common::{
    MavAutopilot, MavCmd, MavMessage, MavModeFlag, MavState, MavType, HEARTBEAT_DATA,
    SIM_STATE_DATA,
};
use mavlink::{MavHeader, MavlinkVersion};
use nalgebra::{Translation3, UnitQuaternion, Vector3};

use super::truth::VehicleState;
use super::*;
use crate::geometry::TransformConfig;
use crate::ipc::Frame;
use crate::mavlink_io::FrameConverter;
use crate::synth::preset::Preset;
use crate::synth::sequence::{write_sequence, SequenceOptions};

fn dataset(preset: &str) -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("tmp");
    let options = SequenceOptions {
        preset: Preset::by_name(preset).expect("preset"),
        seed: 5,
        frames: 1,
        write_depth: false,
    };
    write_sequence(dir.path(), &options, &mut |_| {}).expect("synth");
    dir
}

fn small_camera() -> PinholeCamera {
    let preset = Preset::by_name("realistic").expect("preset");
    PinholeCamera {
        distortion: preset.camera.distortion,
        ..PinholeCamera::new(160, 128, 105.0, 105.0, 79.5, 63.5)
    }
}

/// The harness's transforms (`hil_tests/conftest.py`).
fn settings(fps: f64) -> SimSettings {
    SimSettings {
        camera: small_camera(),
        fps,
        ned_from_world: TransformConfig::from_rpy_deg([1.0, -2.0, 0.5], [180.0, 0.0, 90.0])
            .to_pose(),
        body_from_camera: TransformConfig::from_rpy_deg([0.1, 0.0, 0.05], [90.0, 0.0, 90.0])
            .to_pose(),
        frame_timeout_ms: 2000,
    }
}

#[test]
fn rebuilds_the_scene_of_a_dataset_and_checks_it() {
    let ds = dataset("realistic");
    let scene = SimScene::load(ds.path()).expect("scene");
    assert_eq!(scene.preset, "realistic");
    assert_eq!(scene.seed, 5);
    assert!(scene.blur.is_some() && scene.photometric.noise_sigma > 0.0);
    // The truth mesh (occluders, no holes) is larger than the map.
    let map = crate::map::load_obj(&ds.path().join("map/map.obj")).expect("map");
    assert!(scene.image_mesh.triangle_count() > map.triangle_count());
    assert_eq!(
        SimScene::dir_of_map(&ds.path().join("map").join("map.obj")).as_deref(),
        Some(ds.path())
    );
    assert_eq!(SimScene::dir_of_map(Path::new("/x/room.obj")), None);
}

#[test]
fn refuses_scenes_it_cannot_rebuild_saying_why() {
    let ds = dataset("ideal");
    let toml_path = ds.path().join("synth.toml");
    let text = std::fs::read_to_string(&toml_path).expect("synth.toml");
    let scene_seed_line = text
        .lines()
        .find(|l| l.starts_with("scene_seed = "))
        .expect("scene_seed")
        .to_string();
    let other_scene = if scene_seed_line == "scene_seed = 1" {
        "scene_seed = 2"
    } else {
        "scene_seed = 1"
    };
    let cases = [
        (
            text.replace("name = \"ideal\"", "name = \"nope\""),
            "unknown preset `nope`",
        ),
        (
            text.replace("noise_sigma = 0.0", "noise_sigma = 1.0"),
            "differ from this star's preset",
        ),
        (
            format!("{text}\n[scanned]\nvoxel_m = 0.01\n"),
            "scanned dataset",
        ),
        (
            text.replace(&scene_seed_line, other_scene),
            "not this dataset's scene",
        ),
        (text.replace("seed = 5\n", ""), "`seed` missing"),
        ("name = [".to_string(), "not TOML"),
    ];
    for (bad, why) in cases {
        std::fs::write(&toml_path, &bad).expect("write");
        let err = SimScene::load(ds.path()).expect_err(why).to_string();
        assert!(err.contains(why), "{why}: {err}");
    }
    let err = SimScene::load(Path::new("/nonexistent/ds")).expect_err("missing");
    assert!(
        err.to_string().contains("/nonexistent/ds/synth.toml"),
        "{err}"
    );
    let uri = SimUri {
        link: "tcpout:127.0.0.1:9".into(),
        scene: None,
        origin: None,
    };
    let err = SimCamera::new(&uri, Path::new("/x/room.obj"), settings(50.0))
        .err()
        .expect("no scene");
    assert!(err.to_string().contains("?scene="), "{err}");
}

#[test]
fn the_camera_pose_is_the_inverse_of_the_mavlink_conversion() {
    let s = settings(50.0);
    let ned_from_body = Pose::from_parts(
        Translation3::new(0.7, -1.2, -1.0),
        UnitQuaternion::from_euler_angles(0.05, -0.03, 2.0),
    );
    let world_from_camera = s.ned_from_world.inverse() * ned_from_body * s.body_from_camera;
    let sent = FrameConverter::new(s.ned_from_world, s.body_from_camera)
        .ned_pose(&world_from_camera)
        .ned_from_body;
    assert!((sent.translation.vector - ned_from_body.translation.vector).norm() < 1e-12);
    assert!(sent.rotation.angle_to(&ned_from_body.rotation) < 1e-12);
}

/// A stand-in autopilot on a TCP port: HEARTBEATs, and once asked
/// (SET_MESSAGE_INTERVAL of SIM_STATE), a still vehicle's SIM_STATE at 100 Hz.
struct FakeSitl {
    port: u16,
    stop: Arc<AtomicBool>,
    asked: Arc<AtomicU64>,
    thread: Option<std::thread::JoinHandle<()>>,
}

const HOME_LAT_E7: i32 = -353_632_610;
const HOME_LON_E7: i32 = 1_491_652_300;

fn still_state() -> SIM_STATE_DATA {
    // 30 steps of 1e-7 deg north (0.334 m), 110 east (0.999 m), 1.5 m up,
    // yaw 30 deg.
    let half = 15f32.to_radians();
    SIM_STATE_DATA {
        q1: half.cos(),
        q4: half.sin(),
        lat_int: HOME_LAT_E7 + 30,
        lon_int: HOME_LON_E7 + 110,
        alt: 585.5,
        ..SIM_STATE_DATA::default()
    }
}

impl FakeSitl {
    fn start() -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
        let port = listener.local_addr().expect("addr").port();
        let stop = Arc::new(AtomicBool::new(false));
        let asked = Arc::new(AtomicU64::new(0));
        let thread = {
            let (stop, asked) = (stop.clone(), asked.clone());
            std::thread::spawn(move || {
                let (stream, _) = listener.accept().expect("accept");
                stream.set_nodelay(true).expect("nodelay");
                stream
                    .set_read_timeout(Some(Duration::from_millis(5)))
                    .expect("timeout");
                let mut writer = stream.try_clone().expect("clone");
                let mut peek = mavlink::MavlinkReader::new(BufReader::new(stream));
                let header = MavHeader {
                    system_id: 1,
                    component_id: 1,
                    sequence: 0,
                };
                let heartbeat = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
                    custom_mode: 0,
                    mavtype: MavType::MAV_TYPE_QUADROTOR,
                    autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
                    base_mode: MavModeFlag::empty(),
                    system_status: MavState::MAV_STATE_STANDBY,
                    mavlink_version: 3,
                });
                let mut ticks = 0u64;
                while !stop.load(Ordering::Relaxed) {
                    if ticks % 100 == 0 {
                        let _ = mavlink::write_versioned_msg(
                            &mut writer,
                            MavlinkVersion::V2,
                            header,
                            &heartbeat,
                        );
                    }
                    if asked.load(Ordering::Relaxed) > 0 {
                        let _ = mavlink::write_versioned_msg(
                            &mut writer,
                            MavlinkVersion::V2,
                            header,
                            &MavMessage::SIM_STATE(still_state()),
                        );
                    }
                    let _ = writer.flush();
                    if let Ok((_, MavMessage::COMMAND_LONG(c))) =
                        peek.read_any_message::<MavMessage>()
                    {
                        if c.command == MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL && c.param1 == 108.0 {
                            asked.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                    ticks += 1;
                    std::thread::sleep(Duration::from_millis(10));
                }
            })
        };
        Self {
            port,
            stop,
            asked,
            thread: Some(thread),
        }
    }
}

impl Drop for FakeSitl {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[test]
fn renders_the_vehicles_true_pose_on_a_fixed_capture_grid() {
    let ds = dataset("realistic");
    let sitl = FakeSitl::start();
    let origin = GeoPoint {
        lat_deg: f64::from(HOME_LAT_E7) * 1e-7,
        lon_deg: f64::from(HOME_LON_E7) * 1e-7,
        alt_m: 584.0,
    };
    let uri = SimUri {
        link: format!("tcpout:127.0.0.1:{}", sitl.port),
        scene: Some(ds.path().to_path_buf()),
        origin: Some(origin),
    };
    let s = settings(50.0);
    let sim = SimCamera::new(&uri, Path::new("/unused"), s.clone()).expect("sim camera");
    let mut source = sim.open().expect("open");
    assert!(
        source.describe().contains("160x128"),
        "{}",
        source.describe()
    );
    let mut frame = Frame::boxed_zeroed();
    let mut stamps = Vec::new();
    let mut images = Vec::new();
    for _ in 0..3 {
        let mut slot = FrameSlot::from_frame(&mut frame);
        source.next_frame(&mut slot).expect("frame");
        stamps.push(slot.header.capture_ns);
        let mut image = ImageU8::new(0, 0, 0);
        frame.view().expect("valid").copy_to(&mut image);
        images.push(image);
    }
    assert!(
        sitl.asked.load(Ordering::Relaxed) >= 1,
        "SIM_STATE was asked for"
    );
    // Capture instants exactly one period apart (none late on this load).
    let gaps: Vec<u64> = stamps.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(
        gaps.iter().all(|g| g % 20_000_000 == 0 && *g > 0),
        "{gaps:?}"
    );
    // The same frame, made directly at the expected pose, with the same
    // frame index, time and seed: equal bytes.
    let state = VehicleState::from_sim_state(&still_state(), &origin).expect("state");
    let world_from_camera = s.ned_from_world.inverse() * state.ned_from_body * s.body_from_camera;
    let scene = sim.scene();
    let mut camera = SyntheticCamera::new(
        scene.image_mesh.clone(),
        &s.camera,
        scene.photometric,
        scene.blur,
        scene.seed,
    )
    .expect("camera");
    let t_s = (stamps[2] - stamps[0]) as f64 * 1e-9;
    camera
        .expose(|_| world_from_camera, t_s, |_, _, _| {})
        .expect("render");
    let mut expected = ImageU8::new(0, 0, 0);
    camera.develop(None, 2, t_s, &mut expected);
    assert_eq!(images[2], expected);
    // The pose lies 1.5 m up, 0.33 m north, 1.0 m east of the origin.
    let p = state.ned_from_body.translation.vector;
    assert!((p - Vector3::new(0.334, 1.0, -1.5)).norm() < 0.01, "{p}");
}

#[test]
fn a_silent_simulator_is_a_timeout_and_a_closed_one_is_a_disconnect() {
    let ds = dataset("ideal");
    // Accepts, says nothing, then closes.
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = listener.local_addr().expect("addr").port();
    let server = std::thread::spawn(move || {
        let (stream, _) = listener.accept().expect("accept");
        std::thread::sleep(Duration::from_millis(600));
        drop::<TcpStream>(stream);
    });
    let uri = SimUri {
        link: format!("tcpout:127.0.0.1:{port}"),
        scene: Some(ds.path().to_path_buf()),
        origin: None,
    };
    let mut s = settings(50.0);
    s.frame_timeout_ms = 300;
    let sim = SimCamera::new(&uri, Path::new("/unused"), s).expect("sim camera");
    let mut source = sim.open().expect("open");
    let mut frame = Frame::boxed_zeroed();
    let err = source
        .next_frame(&mut FrameSlot::from_frame(&mut frame))
        .expect_err("silent");
    assert!(matches!(err, CameraError::Timeout { .. }), "{err}");
    server.join().expect("server");
    let err = source
        .next_frame(&mut FrameSlot::from_frame(&mut frame))
        .expect_err("closed");
    assert!(matches!(err, CameraError::Disconnected { .. }), "{err}");
    // Nobody listening: an open error, which the camera loop retries.
    drop(source);
    let err = sim.open().err().expect("refused");
    assert!(matches!(err, CameraError::Open { .. }), "{err}");
}
