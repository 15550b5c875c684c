//! Replay end to end. `replay_publishes_dataset_frames` runs a synthetic
//! dataset through the publish loop and checks that the tracker side sees
//! its pixels and dataset timestamps. `virtual_camera_round_trip` is the
//! hardware-in-the-loop path: `star replay DIR --to /dev/videoN` writes into
//! a v4l2loopback device and the V4L2 source reads the frames back; it is
//! skipped, with a message, where no loopback device exists.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;
use common as common_ipc;

use std::path::Path;

use star::camera::replay::ReplaySource;
use star::camera::{run_camera, FrameSource, RunnerSettings, SourceSettings};
use star::ipc::{create_node, FramePublisher, FrameSubscriber};

const STAMPS: [f64; 4] = [10.0, 10.05, 10.1, 10.15];

/// Frame `i` is a horizontal ramp offset by `40 * i`.
fn pixel(i: usize, x: u32) -> u8 {
    (x as usize * 2 + 40 * i) as u8
}

fn write_dataset(dir: &Path, width: u32, height: u32) {
    std::fs::create_dir_all(dir.join("rgb")).expect("mkdir");
    let mut list = String::from("# color images\n# timestamp filename\n");
    for (i, t) in STAMPS.iter().enumerate() {
        let name = format!("rgb/{t:.6}.png");
        image::GrayImage::from_fn(width, height, |x, _| image::Luma([pixel(i, x)]))
            .save(dir.join(&name))
            .expect("png");
        list.push_str(&format!("{t:.6} {name}\n"));
    }
    std::fs::write(dir.join("rgb.txt"), list).expect("rgb.txt");
}

#[test]
fn replay_publishes_dataset_frames() {
    let tmp = tempfile::tempdir().expect("tmp");
    write_dataset(tmp.path(), 48, 32);
    let _cleanup = common_ipc::Cleanup(common_ipc::prefix("replay"));
    let config = common_ipc::isolated_config("replay");
    let node = create_node("test-replay", &config).expect("node");
    let mut subscriber = FrameSubscriber::new(&node).expect("subscriber");
    let mut publisher = FramePublisher::new(&node).expect("publisher");
    let settings = SourceSettings {
        replay_speed: 5.0,
        ..SourceSettings::default()
    };
    let mut source = Some(ReplaySource::open(tmp.path(), &settings).expect("open"));
    let summary = run_camera(
        || match source.take() {
            Some(s) => Ok(Box::new(s) as Box<dyn FrameSource>),
            None => Err(star::camera::CameraError::EndOfStream),
        },
        &mut publisher,
        &|| false,
        &RunnerSettings::default(),
    )
    .expect("replay");
    assert!(summary.ended, "replay without loop ends");
    assert_eq!(summary.stats.published, STAMPS.len() as u64);
    // The subscriber was slower than the replay: it gets the newest frame.
    let last = subscriber.take_latest().expect("receive").expect("frame");
    let view = last.view().expect("valid");
    assert_eq!(view.header.sequence, 3);
    assert_eq!(view.header.dataset_stamp_ns, 10_150_000_000);
    assert_eq!(view.row(5).expect("row")[7], pixel(3, 7));
    assert!(view.header.capture_ns > 0);
}

#[cfg(feature = "v4l2")]
#[test]
fn virtual_camera_round_trip() {
    use star::camera::loopback::find_loopback_device;
    use star::camera::v4l2::V4l2Source;
    use star::ipc::{Frame, FrameSlot};

    let Some(device) = find_loopback_device() else {
        eprintln!(
            "SKIPPED virtual_camera_round_trip: no v4l2loopback device \
             (load it with `modprobe v4l2loopback devices=1 exclusive_caps=0`)"
        );
        return;
    };
    let tmp = tempfile::tempdir().expect("tmp");
    write_dataset(tmp.path(), 64, 48);
    let mut writer = std::process::Command::new(env!("CARGO_BIN_EXE_star"))
        .args(["replay", "--loop", "--speed", "1"])
        .arg(tmp.path())
        .arg("--to")
        .arg(&device)
        .spawn()
        .expect("spawn star replay");
    // Give the writer time to set the format before the reader opens.
    std::thread::sleep(std::time::Duration::from_millis(500));
    let settings = SourceSettings {
        width: 64,
        height: 48,
        fps: 20.0,
        ..SourceSettings::default()
    };
    let result = (|| {
        let mut source = V4l2Source::open(&device, &settings)?;
        let mut frame = Frame::boxed_zeroed();
        let mut matched = 0;
        for _ in 0..8 {
            source.next_frame(&mut FrameSlot::from_frame(&mut frame))?;
            let view = frame.view().expect("valid");
            let row = view.row(0).expect("row");
            if (0..STAMPS.len()).any(|i| row[3] == pixel(i, 3) && row[9] == pixel(i, 9)) {
                matched += 1;
            }
        }
        Ok::<_, star::camera::CameraError>(matched)
    })();
    let _ = writer.kill();
    let _ = writer.wait();
    let matched = result.expect("read back through V4L2");
    assert!(matched >= 6, "{matched} of 8 frames carried dataset pixels");
}
