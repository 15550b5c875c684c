//! Dataset replay source (`replay:DIR`): plays the frames listed in a TUM
//! layout folder's `rgb.txt` at the recorded rate times a speed factor,
//! optionally looping.
//!
//! Takes in the dataset folder; gives out gray frames stamped with the
//! monotonic time each was due on the replay schedule (`capture_ns`: the
//! exposure time, as a V4L2 kernel timestamp marks capture rather than
//! delivery, so a replay delayed by a busy machine still carries exact
//! capture times) and their dataset time (`dataset_stamp_ns`) so evaluation
//! can associate poses with ground truth.
//! Decoding a PNG allocates; replay is a test tool, not the flight path.
//!
//! A frame that is missing, does not decode, is not a regular file (a FIFO
//! would block the reader forever) or differs in size from the first frame
//! is a [`CameraError::Dataset`] naming the file: the run stops with an
//! error rather than publish a partial replay. The wait for a frame's due
//! time sleeps in slices of at most 50 ms and ends early with
//! [`CameraError::Stopped`] once a stop signal arrived, so a slow replay or
//! a long gap between stamps never delays a shutdown.
//!
//! The frame list is read here with a minimal `rgb.txt` parser; when the
//! shared `dataset` module lands this can call `dataset::Dataset` instead.

use std::path::{Path, PathBuf};
use std::time::Duration;

use super::{CameraError, FrameSource, SourceSettings};
use crate::clock::monotonic_now_ns;
use crate::ipc::{FrameHeader, FrameSlot, FRAME_MAX_HEIGHT, FRAME_MAX_WIDTH};
use crate::service::signals::sleep_unless_shutdown;

/// One line of `rgb.txt`.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayEntry {
    /// Dataset timestamp, seconds.
    pub timestamp_s: f64,
    /// Image path, relative to the dataset folder.
    pub path: PathBuf,
}

/// Reads `DIR/rgb.txt`: `timestamp path` per line, `#` comments; timestamps
/// must increase. Errors name the file and line.
pub fn read_frame_list(dir: &Path) -> Result<Vec<ReplayEntry>, CameraError> {
    let file = dir.join("rgb.txt");
    let mut text = String::new();
    crate::dataset::open_regular_file(&file)
        .and_then(|mut f| {
            std::io::Read::read_to_string(&mut f, &mut text)
                .map_err(|e| crate::dataset::DatasetError::io(&file, e))
        })
        .map_err(|e| CameraError::Dataset {
            path: file.clone(),
            reason: format!("cannot read: {e}"),
        })?;
    let mut entries: Vec<ReplayEntry> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let bad = |reason: String| CameraError::Dataset {
            path: file.clone(),
            reason: format!("line {}: {reason}", i + 1),
        };
        let mut tokens = line.split_whitespace();
        let (Some(stamp), Some(path), None) = (tokens.next(), tokens.next(), tokens.next()) else {
            return Err(bad(format!("expected `timestamp path`, found `{line}`")));
        };
        let timestamp_s = stamp
            .parse::<f64>()
            .ok()
            .filter(|t| t.is_finite())
            .ok_or_else(|| bad(format!("expected a timestamp in seconds, found `{stamp}`")))?;
        if let Some(prev) = entries.last() {
            if timestamp_s <= prev.timestamp_s {
                return Err(bad(format!(
                    "timestamp {timestamp_s} does not increase (previous {})",
                    prev.timestamp_s
                )));
            }
        }
        entries.push(ReplayEntry {
            timestamp_s,
            path: PathBuf::from(path),
        });
    }
    if entries.is_empty() {
        return Err(CameraError::Dataset {
            path: file,
            reason: "no frames listed".into(),
        });
    }
    Ok(entries)
}

/// Plays a dataset folder.
pub struct ReplaySource {
    dir: PathBuf,
    entries: Vec<ReplayEntry>,
    speed: f64,
    looping: bool,
    next: usize,
    /// Monotonic time that corresponds to the first frame's dataset time.
    start_mono_ns: Option<u64>,
    /// The first frame's size: every later frame must match it.
    size: Option<(u32, u32)>,
}

impl ReplaySource {
    /// Reads the frame list of `dir`. `settings.replay_speed` scales the
    /// rate, `settings.replay_loop` restarts at the end.
    pub fn open(dir: &Path, settings: &SourceSettings) -> Result<Self, CameraError> {
        if !super::replay_speed_is_sane(settings.replay_speed) {
            return Err(CameraError::Unsupported {
                device: format!("replay:{}", dir.display()),
                reason: format!(
                    "speed must be within {}..={}, found {:?}",
                    super::MIN_REPLAY_SPEED,
                    super::MAX_REPLAY_SPEED,
                    settings.replay_speed
                ),
            });
        }
        Ok(Self {
            dir: dir.to_owned(),
            entries: read_frame_list(dir)?,
            speed: settings.replay_speed,
            looping: settings.replay_loop,
            next: 0,
            start_mono_ns: None,
            size: None,
        })
    }

    /// Number of frames in the dataset.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether the dataset lists no frame (never true after `open`).
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    fn load(
        dir: &Path,
        entry: &ReplayEntry,
        expected: &mut Option<(u32, u32)>,
        slot: &mut FrameSlot<'_>,
    ) -> Result<(), CameraError> {
        let path = dir.join(&entry.path);
        let bad = |reason: String| CameraError::Dataset {
            path: path.clone(),
            reason,
        };
        let file = crate::dataset::open_regular_file(&path)
            .map_err(|e| bad(format!("cannot read the frame: {e}")))?;
        let image = image::ImageReader::new(std::io::BufReader::new(file))
            .with_guessed_format()
            .map_err(|e| bad(format!("cannot read the frame: {e}")))?
            .decode()
            .map_err(|e| bad(format!("cannot decode image: {e}")))?
            .into_luma8();
        let (w, h) = image.dimensions();
        if w > FRAME_MAX_WIDTH || h > FRAME_MAX_HEIGHT || w == 0 || h == 0 {
            return Err(bad(format!(
                "image is {w}x{h}, frames hold 1x1 to {FRAME_MAX_WIDTH}x{FRAME_MAX_HEIGHT}"
            )));
        }
        let (want_w, want_h) = *expected.get_or_insert((w, h));
        if (w, h) != (want_w, want_h) {
            return Err(bad(format!(
                "image is {w}x{h} but the first frame is {want_w}x{want_h}"
            )));
        }
        let bytes = image.as_raw();
        let Some(pixels) = slot.pixels.get_mut(..bytes.len()) else {
            return Err(bad(format!(
                "image of {} bytes does not fit a frame",
                bytes.len()
            )));
        };
        pixels.copy_from_slice(bytes);
        *slot.header = FrameHeader::gray8(0, w, h);
        slot.header.dataset_stamp_ns = (entry.timestamp_s * 1e9).round() as i64;
        Ok(())
    }
}

impl FrameSource for ReplaySource {
    fn describe(&self) -> String {
        format!(
            "replay {} ({} frames, speed {}x{})",
            self.dir.display(),
            self.entries.len(),
            self.speed,
            if self.looping { ", looping" } else { "" }
        )
    }

    fn next_frame(&mut self, slot: &mut FrameSlot<'_>) -> Result<(), CameraError> {
        if self.next >= self.entries.len() {
            if !self.looping {
                return Err(CameraError::EndOfStream);
            }
            self.next = 0;
            self.start_mono_ns = None;
        }
        let index = self.next;
        self.next += 1;
        let (Some(entry), Some(first)) = (self.entries.get(index), self.entries.first()) else {
            return Err(CameraError::EndOfStream);
        };
        let first_s = first.timestamp_s;
        // Decode before waiting so the frame goes out on time.
        Self::load(&self.dir, entry, &mut self.size, slot)?;
        let start = *self.start_mono_ns.get_or_insert_with(monotonic_now_ns);
        let offset_ns = ((entry.timestamp_s - first_s) / self.speed * 1e9).round() as u64;
        let due = start.saturating_add(offset_ns);
        let now = monotonic_now_ns();
        if due > now && !sleep_unless_shutdown(Duration::from_nanos(due - now)) {
            return Err(CameraError::Stopped);
        }
        slot.header.capture_ns = due;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ipc::Frame;

    fn write_dataset(dir: &Path, stamps: &[f64]) {
        std::fs::create_dir_all(dir.join("rgb")).expect("mkdir");
        let mut list = String::from("# timestamp filename\n");
        for (i, t) in stamps.iter().enumerate() {
            let name = format!("rgb/{t:.6}.png");
            image::GrayImage::from_pixel(6, 4, image::Luma([10 * i as u8 + 1]))
                .save(dir.join(&name))
                .expect("png");
            list.push_str(&format!("{t:.6} {name}\n"));
        }
        std::fs::write(dir.join("rgb.txt"), list).expect("rgb.txt");
    }

    #[test]
    fn replays_in_order_with_dataset_stamps_then_ends() {
        let tmp = tempfile::tempdir().expect("tmp");
        write_dataset(tmp.path(), &[100.0, 100.01, 100.02]);
        let settings = SourceSettings {
            replay_speed: 10.0,
            ..SourceSettings::default()
        };
        let mut src = ReplaySource::open(tmp.path(), &settings).expect("open");
        let mut frame = Frame::boxed_zeroed();
        let mut stamps = Vec::new();
        let started = std::time::Instant::now();
        for i in 0..3 {
            let mut slot = FrameSlot::from_frame(&mut frame);
            src.next_frame(&mut slot).expect("frame");
            let view = frame.view().expect("valid");
            assert_eq!(view.pixels[0], 10 * i + 1);
            stamps.push((view.header.dataset_stamp_ns, view.header.capture_ns));
        }
        assert_eq!(stamps[1].0, 100_010_000_000);
        // Stamped on the schedule (10 ms of dataset time at 10x: 1 ms), and
        // delivered no sooner than due.
        assert_eq!(stamps[1].1 - stamps[0].1, 1_000_000);
        assert_eq!(stamps[2].1 - stamps[0].1, 2_000_000);
        assert!(started.elapsed() >= std::time::Duration::from_millis(2));
        let mut slot = FrameSlot::from_frame(&mut frame);
        assert!(matches!(
            src.next_frame(&mut slot),
            Err(CameraError::EndOfStream)
        ));
    }

    #[test]
    fn looping_starts_over() {
        let tmp = tempfile::tempdir().expect("tmp");
        write_dataset(tmp.path(), &[1.0, 1.001]);
        let settings = SourceSettings {
            replay_loop: true,
            ..SourceSettings::default()
        };
        let mut src = ReplaySource::open(tmp.path(), &settings).expect("open");
        let mut frame = Frame::boxed_zeroed();
        for expected in [1u8, 11, 1, 11] {
            let mut slot = FrameSlot::from_frame(&mut frame);
            src.next_frame(&mut slot).expect("frame");
            assert_eq!(frame.pixels[0], expected);
        }
    }

    #[test]
    fn malformed_lists_name_file_and_line() {
        let tmp = tempfile::tempdir().expect("tmp");
        std::fs::write(tmp.path().join("rgb.txt"), "1.0 a.png\n0.5 b.png\n").expect("write");
        let err = read_frame_list(tmp.path()).expect_err("non-monotonic");
        let msg = err.to_string();
        assert!(msg.contains("rgb.txt") && msg.contains("line 2"), "{msg}");
        std::fs::write(tmp.path().join("rgb.txt"), "abc a.png\n").expect("write");
        assert!(read_frame_list(tmp.path()).is_err());
        std::fs::write(tmp.path().join("rgb.txt"), "# nothing\n").expect("write");
        assert!(read_frame_list(tmp.path()).is_err());
        assert!(read_frame_list(&tmp.path().join("missing")).is_err());
    }
}
