//! Round trip and error tests of a whole dataset folder.

use super::*;
use crate::geometry::exp_se3;
use nalgebra::Vector6;

fn camera_file() -> CameraFile {
    CameraFile {
        camera: PinholeCamera::new(8, 6, 5.0, 5.0, 3.5, 2.5),
        depth_scale: TUM_DEPTH_SCALE,
    }
}

fn frame(i: usize) -> ImageU8 {
    ImageU8::from_vec(
        8,
        6,
        (0..48).map(|p| ((p * 5 + i * 11) % 256) as u8).collect(),
    )
    .expect("8x6")
}

/// Writes a 3-frame dataset with depth and ground truth.
fn write_sample(dir: &Path) -> Trajectory {
    let writer = DatasetWriter::create(dir, camera_file()).expect("create");
    let mut gt = Trajectory::default();
    let (mut rgb, mut depth) = (Vec::new(), Vec::new());
    for i in 0..3 {
        let stamp = 10.0 + 0.02 * i as f64;
        rgb.push(writer.write_rgb(stamp, &frame(i)).expect("rgb"));
        let d = ImageF32::new(8, 6, 1.0 + i as f32);
        depth.push(writer.write_depth_m(stamp, &d).expect("depth"));
        gt.push(
            stamp,
            exp_se3(&Vector6::new(i as f64, 0.0, 1.0, 0.0, 0.1, 0.0)),
        );
    }
    writer.finish(&rgb, &depth, Some(&gt)).expect("finish");
    gt
}

#[test]
fn written_dataset_reads_back() {
    let dir = tempfile::tempdir().expect("tempdir");
    let gt = write_sample(dir.path());
    let ds = Dataset::open(dir.path()).expect("open");
    assert_eq!(ds.len(), 3);
    assert_eq!(ds.frames[1].timestamp_s, 10.02);
    assert_eq!(ds.ground_truth.as_ref().expect("gt").stamps_s, gt.stamps_s);
    assert_eq!(*ds.camera(), camera_file().camera);
    for i in 0..3 {
        assert_eq!(ds.load_frame(i).expect("frame"), frame(i));
    }
    let (mut depth, mut scratch) = (ImageF32::new(1, 1, 0.0), Vec::new());
    ds.load_depth_m_into(2, &mut depth, &mut scratch)
        .expect("depth");
    assert!(depth.data().iter().all(|&d| (d - 3.0).abs() < 1e-6));
    assert!(matches!(
        ds.load_frame(3),
        Err(DatasetError::FrameIndex {
            index: 3,
            count: 3,
            ..
        })
    ));
}

#[test]
fn load_frame_into_reuses_the_buffer() {
    let dir = tempfile::tempdir().expect("tempdir");
    write_sample(dir.path());
    let ds = Dataset::open(dir.path()).expect("open");
    let (mut out, mut scratch) = (ImageU8::new(8, 6, 0), Vec::new());
    let ptr = out.data().as_ptr();
    ds.load_frame_into(1, &mut out, &mut scratch)
        .expect("frame");
    assert_eq!(out, frame(1));
    assert_eq!(out.data().as_ptr(), ptr, "no reallocation");
}

#[test]
fn missing_files_are_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let err = Dataset::open(dir.path()).unwrap_err();
    assert!(
        matches!(&err, DatasetError::MissingFile { path } if path.ends_with("camera.toml")),
        "{err}"
    );
    write_sample(dir.path());
    std::fs::remove_file(dir.path().join("rgb.txt")).expect("rm");
    let err = Dataset::open(dir.path()).unwrap_err();
    assert!(
        matches!(&err, DatasetError::MissingFile { path } if path.ends_with("rgb.txt")),
        "{err}"
    );
}

#[test]
fn bad_lists_and_images_are_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    write_sample(dir.path());
    let rgb = dir.path().join("rgb.txt");
    std::fs::write(
        &rgb,
        "# header\n10.0 rgb/10.000000.png\n9.0 rgb/10.020000.png\n",
    )
    .expect("write");
    assert!(matches!(
        Dataset::open(dir.path()),
        Err(DatasetError::NonMonotonic { line: 3, .. })
    ));
    std::fs::write(&rgb, "# only comments\n").expect("write");
    assert!(matches!(
        Dataset::open(dir.path()),
        Err(DatasetError::NoFrames { .. })
    ));
    std::fs::write(
        &rgb,
        "10.0 rgb/10.000000.png\n10.5 rgb/bad.png\n11.0 rgb/small.png\n12.0 rgb/none.png\n",
    )
    .expect("write");
    std::fs::write(
        dir.path().join("rgb/bad.png"),
        b"\x89PNG\r\n\x1a\ntruncated",
    )
    .expect("write");
    write_gray8(&dir.path().join("rgb/small.png"), &ImageU8::new(4, 4, 0)).expect("write");
    let ds = Dataset::open(dir.path()).expect("lists are fine");
    assert!(ds.load_frame(0).is_ok());
    assert!(matches!(ds.load_frame(1), Err(DatasetError::Decode { .. })));
    assert!(matches!(
        ds.load_frame(2),
        Err(DatasetError::ImageSize {
            found_w: 4,
            want_w: 8,
            ..
        })
    ));
    assert!(matches!(
        ds.load_frame(3),
        Err(DatasetError::MissingFile { .. })
    ));
    std::fs::write(
        dir.path().join("groundtruth.txt"),
        "10 0 0 0 0 0 0 1\n10.02 0 0\n",
    )
    .expect("write");
    let err = Dataset::open(dir.path()).unwrap_err();
    assert!(err.to_string().contains("groundtruth.txt:2"), "{err}");
}

#[test]
fn writer_rejects_wrong_image_size() {
    let dir = tempfile::tempdir().expect("tempdir");
    let writer = DatasetWriter::create(dir.path(), camera_file()).expect("create");
    let err = writer.write_rgb(1.0, &ImageU8::new(3, 3, 0)).unwrap_err();
    assert!(matches!(
        err,
        DatasetError::ImageSize {
            found_w: 3,
            want_w: 8,
            ..
        }
    ));
}
