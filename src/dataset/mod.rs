//! Datasets in the TUM RGB-D layout, for replay and evaluation.
//!
//! A dataset folder holds:
//! - `rgb.txt`: `timestamp path` lines (`#` comments), timestamps in seconds,
//!   strictly increasing;
//! - `rgb/*.png`: the camera frames (8-bit gray or color; color is converted
//!   to gray with Rec.601 luma);
//! - optional `groundtruth.txt`: TUM trajectory, `world_from_camera`;
//! - optional `depth.txt` + `depth/*.png`: 16-bit depth, `depth_scale` units
//!   per meter;
//! - `camera.toml`: see [`CameraFile`];
//! - `map/`: the mesh (`map/map.obj` for synthetic datasets).
//!
//! This module owns reading ([`Dataset`]) and writing ([`DatasetWriter`])
//! that layout, and the TUM trajectory format ([`Trajectory`]). Bad input
//! gives a [`DatasetError`] naming the file, line and what was expected.

mod camera_file;
mod list;
mod png_io;
mod trajectory;
mod writer;

use std::path::{Path, PathBuf};

pub use camera_file::{CameraFile, TUM_DEPTH_SCALE};
pub use list::{format_frame_list, parse_frame_list, FrameEntry};
pub use png_io::{decode_gray_into, decode_u16, luma601, write_gray16, write_gray8};
pub use trajectory::{Trajectory, TrajectoryWriter};
pub use writer::DatasetWriter;

use crate::geometry::PinholeCamera;
use crate::imgproc::{ImageF32, ImageU8};

/// Errors reading or writing a dataset.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A required file does not exist.
    #[error("missing file {path}")]
    MissingFile {
        /// The file.
        path: PathBuf,
    },
    /// The path exists but is not a regular file (a FIFO, a device, a
    /// folder): reading it could block forever or never end.
    #[error("{} is a {kind}, not a regular file", path.display())]
    NotRegularFile {
        /// The path.
        path: PathBuf,
        /// What it is instead (`FIFO`, `directory`, ...).
        kind: &'static str,
    },
    /// Reading or writing a file failed for another reason.
    #[error("cannot access {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A line of a text file does not have the expected fields.
    #[error("{}:{line}: expected {expected}, found `{found}`", path.display())]
    Malformed {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What the line or field should hold.
        expected: &'static str,
        /// The offending text.
        found: String,
    },
    /// A timestamp is not larger than the one before it.
    #[error("{}:{line}: timestamp {found_s} is not after the previous one {previous_s}", path.display())]
    NonMonotonic {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// The timestamp on the previous data line.
        previous_s: f64,
        /// The timestamp on this line.
        found_s: f64,
    },
    /// `camera.toml` is not valid TOML, has unknown keys or bad values.
    #[error("invalid camera file {}: {message}", path.display())]
    CameraFile {
        /// The file.
        path: PathBuf,
        /// What is wrong, with the key.
        message: String,
    },
    /// An image file does not decode.
    #[error("cannot decode image {}: {message}", path.display())]
    Decode {
        /// The image file.
        path: PathBuf,
        /// The decoder's message.
        message: String,
    },
    /// An image file could not be encoded.
    #[error("cannot encode image {}: {message}", path.display())]
    Encode {
        /// The image file.
        path: PathBuf,
        /// The encoder's message.
        message: String,
    },
    /// An image is not the size given in `camera.toml`.
    #[error("image {} is {found_w}x{found_h} but camera.toml says {want_w}x{want_h}", path.display())]
    ImageSize {
        /// The image file.
        path: PathBuf,
        /// Width found.
        found_w: u32,
        /// Height found.
        found_h: u32,
        /// Width expected.
        want_w: u32,
        /// Height expected.
        want_h: u32,
    },
    /// A frame index past the end of the list.
    #[error("frame {index} requested but {list} lists {count} frames")]
    FrameIndex {
        /// The requested index.
        index: usize,
        /// Number of frames.
        count: usize,
        /// Which list (`rgb.txt` or `depth.txt`).
        list: &'static str,
    },
    /// `rgb.txt` lists no frames.
    #[error("{} lists no frames", path.display())]
    NoFrames {
        /// The list file.
        path: PathBuf,
    },
}

impl DatasetError {
    /// Maps an I/O error on `path`, turning "not found" into [`DatasetError::MissingFile`].
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        if source.kind() == std::io::ErrorKind::NotFound {
            DatasetError::MissingFile {
                path: path.to_path_buf(),
            }
        } else {
            DatasetError::Io {
                path: path.to_path_buf(),
                source,
            }
        }
    }
}

/// What a file type is called in errors.
pub fn file_kind(file_type: std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if file_type.is_file() {
        "regular file"
    } else if file_type.is_dir() {
        "directory"
    } else if file_type.is_fifo() {
        "FIFO"
    } else if file_type.is_socket() {
        "socket"
    } else if file_type.is_char_device() {
        "character device"
    } else if file_type.is_block_device() {
        "block device"
    } else {
        "special file"
    }
}

/// Opens `path` for reading only if it is a regular file. The file is opened
/// non-blocking first (opening a FIFO without a writer would block forever),
/// checked, then switched back to blocking reads; so a FIFO, a device or a
/// folder is refused at once with an error naming it.
pub fn open_regular_file(path: &Path) -> Result<std::fs::File, DatasetError> {
    use std::os::fd::AsRawFd;
    use std::os::unix::fs::OpenOptionsExt;
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
        .map_err(|e| DatasetError::io(path, e))?;
    let file_type = file
        .metadata()
        .map_err(|e| DatasetError::io(path, e))?
        .file_type();
    if !file_type.is_file() {
        return Err(DatasetError::NotRegularFile {
            path: path.to_path_buf(),
            kind: file_kind(file_type),
        });
    }
    // SAFETY: fcntl on a descriptor this function owns; F_GETFL/F_SETFL
    // only change the file status flags.
    let cleared = unsafe {
        let fd = file.as_raw_fd();
        let flags = libc::fcntl(fd, libc::F_GETFL);
        flags >= 0 && libc::fcntl(fd, libc::F_SETFL, flags & !libc::O_NONBLOCK) == 0
    };
    if !cleared {
        return Err(DatasetError::io(path, std::io::Error::last_os_error()));
    }
    Ok(file)
}

pub(crate) fn read_text(path: &Path) -> Result<String, DatasetError> {
    let mut text = String::new();
    std::io::Read::read_to_string(&mut open_regular_file(path)?, &mut text)
        .map_err(|e| DatasetError::io(path, e))?;
    Ok(text)
}

pub(crate) fn write_text(path: &Path, text: &str) -> Result<(), DatasetError> {
    std::fs::write(path, text).map_err(|e| DatasetError::io(path, e))
}

/// An opened dataset folder: frame lists, calibration and ground truth.
/// Images are decoded on demand.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// The dataset folder.
    pub root: PathBuf,
    /// Calibration from `camera.toml`.
    pub camera_file: CameraFile,
    /// Frames from `rgb.txt`, in time order.
    pub frames: Vec<FrameEntry>,
    /// Depth frames from `depth.txt` (empty when absent), in time order.
    pub depth_frames: Vec<FrameEntry>,
    /// Ground truth from `groundtruth.txt`, when present.
    pub ground_truth: Option<Trajectory>,
}

impl Dataset {
    /// Opens `dir`: reads `camera.toml`, `rgb.txt`, and `depth.txt` and
    /// `groundtruth.txt` when they exist. Does not decode images.
    pub fn open(dir: &Path) -> Result<Self, DatasetError> {
        let camera_file = CameraFile::read(&dir.join("camera.toml"))?;
        let rgb_path = dir.join("rgb.txt");
        let frames = parse_frame_list(&rgb_path, &read_text(&rgb_path)?)?;
        if frames.is_empty() {
            return Err(DatasetError::NoFrames { path: rgb_path });
        }
        let depth_path = dir.join("depth.txt");
        let depth_frames = if depth_path.exists() {
            parse_frame_list(&depth_path, &read_text(&depth_path)?)?
        } else {
            Vec::new()
        };
        let gt_path = dir.join("groundtruth.txt");
        let ground_truth = if gt_path.exists() {
            Some(Trajectory::read(&gt_path)?)
        } else {
            None
        };
        tracing::debug!(
            dir = %dir.display(),
            frames = frames.len(),
            depth_frames = depth_frames.len(),
            ground_truth = ground_truth.as_ref().map_or(0, Trajectory::len),
            "opened dataset"
        );
        Ok(Self {
            root: dir.to_path_buf(),
            camera_file,
            frames,
            depth_frames,
            ground_truth,
        })
    }

    /// The camera of the stored images.
    pub fn camera(&self) -> &PinholeCamera {
        &self.camera_file.camera
    }

    /// Number of frames in `rgb.txt`.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// True when there are no frames (never for an opened dataset).
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    fn entry<'a>(
        list: &'a [FrameEntry],
        index: usize,
        name: &'static str,
    ) -> Result<&'a FrameEntry, DatasetError> {
        list.get(index).ok_or(DatasetError::FrameIndex {
            index,
            count: list.len(),
            list: name,
        })
    }

    fn expected_size(&self) -> Option<(u32, u32)> {
        Some((self.camera().width, self.camera().height))
    }

    /// Decodes frame `index` as 8-bit gray.
    pub fn load_frame(&self, index: usize) -> Result<ImageU8, DatasetError> {
        let mut out = ImageU8::new(0, 0, 0);
        self.load_frame_into(index, &mut out, &mut Vec::new())?;
        Ok(out)
    }

    /// Decodes frame `index` as 8-bit gray into `out`, reusing its buffer
    /// and `scratch` (used for color images).
    pub fn load_frame_into(
        &self,
        index: usize,
        out: &mut ImageU8,
        scratch: &mut Vec<u8>,
    ) -> Result<(), DatasetError> {
        let entry = Self::entry(&self.frames, index, "rgb.txt")?;
        decode_gray_into(
            &self.root.join(&entry.path),
            self.expected_size(),
            out,
            scratch,
        )
    }

    /// Decodes depth frame `index` (of `depth.txt`) into meters in `out`
    /// (resized in place); 0 (= [`crate::render::NO_DEPTH`]) where the
    /// sensor had no reading.
    pub fn load_depth_m_into(
        &self,
        index: usize,
        out: &mut ImageF32,
        scratch: &mut Vec<u16>,
    ) -> Result<(), DatasetError> {
        let entry = Self::entry(&self.depth_frames, index, "depth.txt")?;
        decode_u16(&self.root.join(&entry.path), self.expected_size(), scratch)?;
        let scale = 1.0 / self.camera_file.depth_scale;
        let (w, h) = (self.camera().width as usize, self.camera().height as usize);
        out.resize(w, h, 0.0);
        for (d, &raw) in out.data_mut().iter_mut().zip(scratch.iter()) {
            *d = (raw as f64 * scale) as f32;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
