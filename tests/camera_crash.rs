//! The tracker side survives a camera crash: a `star camera` process is
//! killed with SIGKILL while a subscriber receives its frames; the
//! subscriber reports the camera silent, keeps running, and resumes when a
//! new camera process starts (which cleans up the dead one's resources).

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;
use common as common_ipc;

use std::ops::ControlFlow;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use star::ipc::{create_node, FrameEvent, FrameSubscriber};

fn spawn_camera(config: &std::path::Path) -> Child {
    Command::new(env!("CARGO_BIN_EXE_star"))
        .args(["camera", "--source", "pattern:64x48", "--config"])
        .arg(config)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("spawn star camera")
}

#[derive(Debug, PartialEq)]
enum Phase {
    First,
    Killed,
    Restarted,
}

#[test]
fn tracker_keeps_running_and_resumes_after_camera_crash() {
    let _cleanup = common_ipc::Cleanup(common_ipc::prefix("crash"));
    let tmp = tempfile::tempdir().expect("tmp");
    let star_config =
        common_ipc::write_isolated_configs(tmp.path(), "crash", "[camera]\nfps = 100.0\n");
    let iox = star::ipc::load_iceoryx_config(&tmp.path().join("iceoryx2.toml"), None)
        .expect("iceoryx2 config");
    let node = create_node("test-crash-tracker", &iox).expect("node");
    let mut subscriber = FrameSubscriber::new(&node).expect("subscriber");

    let mut camera = spawn_camera(&star_config);
    let mut phase = Phase::First;
    let mut frames_in_phase = 0u32;
    let mut silent_after_kill = 0u32;
    let mut silent_total = 0u32;
    let end = subscriber
        .run(Duration::from_millis(200), |event| {
            match event {
                FrameEvent::Frame(view) => {
                    assert_eq!((view.header.width, view.header.height), (64, 48));
                    frames_in_phase += 1;
                }
                FrameEvent::Silent => {
                    silent_total += 1;
                    if phase == Phase::Killed {
                        silent_after_kill += 1;
                    }
                    // Generous bound (15 s of silence) so a stuck test fails instead of hanging.
                    if silent_total > 75 {
                        return ControlFlow::Break(());
                    }
                }
            }
            match phase {
                Phase::First if frames_in_phase >= 20 => {
                    camera.kill().expect("kill camera");
                    let _ = camera.wait();
                    phase = Phase::Killed;
                    frames_in_phase = 0;
                }
                Phase::Killed if silent_after_kill >= 2 => {
                    camera = spawn_camera(&star_config);
                    phase = Phase::Restarted;
                    frames_in_phase = 0;
                }
                Phase::Restarted if frames_in_phase >= 20 => return ControlFlow::Break(()),
                _ => {}
            }
            ControlFlow::Continue(())
        })
        .expect("subscriber run");
    let _ = camera.kill();
    let _ = camera.wait();

    assert_eq!(end, star::ipc::RunEnd::Stopped);
    assert_eq!(phase, Phase::Restarted, "frames resumed after the restart");
    assert!(
        frames_in_phase >= 20,
        "got {frames_in_phase} frames after restart"
    );
    let stats = subscriber.stats();
    assert!(stats.silent_periods >= 2, "{stats:?}");
    assert_eq!(stats.publisher_changes, 1, "{stats:?}");
    assert_eq!(stats.rejected, 0);
}
