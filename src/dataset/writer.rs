//! Writing a dataset folder in the layout [`super::Dataset`] reads.
//!
//! Frame files can be written from several threads at once (`&self`); the
//! lists and ground truth are written once at the end by
//! [`DatasetWriter::finish`], in time order.

use std::path::{Path, PathBuf};

use super::{write_gray16, write_gray8, CameraFile, DatasetError, FrameEntry, Trajectory};
use crate::imgproc::{ImageF32, ImageU8};

/// Writes a dataset folder: `camera.toml` at creation, frames as they come,
/// lists and ground truth at the end.
#[derive(Debug)]
pub struct DatasetWriter {
    root: PathBuf,
    camera_file: CameraFile,
}

fn create_dir(path: &Path) -> Result<(), DatasetError> {
    std::fs::create_dir_all(path).map_err(|e| DatasetError::io(path, e))
}

impl DatasetWriter {
    /// Creates `dir` (and `rgb/`, `depth/`, `map/` inside it) and writes
    /// `camera.toml`. Existing files with the same names are overwritten.
    pub fn create(dir: &Path, camera_file: CameraFile) -> Result<Self, DatasetError> {
        for sub in ["rgb", "depth", "map"] {
            create_dir(&dir.join(sub))?;
        }
        camera_file.write(&dir.join("camera.toml"))?;
        Ok(Self {
            root: dir.to_path_buf(),
            camera_file,
        })
    }

    /// The dataset folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The `map/` folder, where the mesh goes.
    pub fn map_dir(&self) -> PathBuf {
        self.root.join("map")
    }

    fn check_size(&self, path: &Path, width: usize, height: usize) -> Result<(), DatasetError> {
        let c = &self.camera_file.camera;
        if width != c.width as usize || height != c.height as usize {
            return Err(DatasetError::ImageSize {
                path: path.to_path_buf(),
                found_w: width as u32,
                found_h: height as u32,
                want_w: c.width,
                want_h: c.height,
            });
        }
        Ok(())
    }

    /// Writes frame `rgb/<stamp>.png` (8-bit gray) and returns its list entry.
    pub fn write_rgb(&self, timestamp_s: f64, image: &ImageU8) -> Result<FrameEntry, DatasetError> {
        let entry = FrameEntry {
            timestamp_s,
            path: PathBuf::from(format!("rgb/{timestamp_s:.6}.png")),
        };
        let path = self.root.join(&entry.path);
        self.check_size(&path, image.width(), image.height())?;
        write_gray8(&path, image)?;
        Ok(entry)
    }

    /// Writes depth frame `depth/<stamp>.png` (16-bit, `depth_scale` units
    /// per meter; 0 where there is no depth or it does not fit in 16 bits)
    /// and returns its list entry.
    pub fn write_depth_m(
        &self,
        timestamp_s: f64,
        depth_m: &ImageF32,
    ) -> Result<FrameEntry, DatasetError> {
        let entry = FrameEntry {
            timestamp_s,
            path: PathBuf::from(format!("depth/{timestamp_s:.6}.png")),
        };
        let path = self.root.join(&entry.path);
        self.check_size(&path, depth_m.width(), depth_m.height())?;
        let scale = self.camera_file.depth_scale;
        let raw: Vec<u16> = depth_m
            .data()
            .iter()
            .map(|&d| {
                let units = (d as f64 * scale).round();
                if units > 0.0 && units <= u16::MAX as f64 {
                    units as u16
                } else {
                    0
                }
            })
            .collect();
        write_gray16(&path, depth_m.width() as u32, depth_m.height() as u32, &raw)?;
        Ok(entry)
    }

    /// Writes `rgb.txt`, `depth.txt` (when `depth` is not empty) and
    /// `groundtruth.txt` (when given). Entries must be in time order.
    pub fn finish(
        &self,
        rgb: &[FrameEntry],
        depth: &[FrameEntry],
        ground_truth: Option<&Trajectory>,
    ) -> Result<(), DatasetError> {
        super::write_text(
            &self.root.join("rgb.txt"),
            &super::format_frame_list("gray images (8-bit PNG)", rgb),
        )?;
        if !depth.is_empty() {
            let header = format!(
                "depth images (16-bit PNG, {} units per meter, 0 = no depth)",
                self.camera_file.depth_scale
            );
            super::write_text(
                &self.root.join("depth.txt"),
                &super::format_frame_list(&header, depth),
            )?;
        }
        if let Some(gt) = ground_truth {
            gt.write(&self.root.join("groundtruth.txt"))?;
        }
        Ok(())
    }
}
