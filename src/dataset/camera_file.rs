//! `camera.toml`: the calibration of a dataset.
//!
//! The keys are those of [`PinholeCamera`] (`width`, `height`, `fx`, `fy`,
//! `cx`, `cy`, optional `[distortion]` with `k1 k2 p1 p2 k3`) plus
//! `depth_scale`, the number of 16-bit depth PNG units per meter (5000 in
//! TUM RGB-D). Unknown keys are rejected.
//!
//! ```toml
//! width = 640
//! height = 512
//! fx = 420.0
//! fy = 420.0
//! cx = 319.5
//! cy = 255.5
//! depth_scale = 5000.0
//!
//! [distortion]
//! k1 = -0.1
//! ```

use std::path::Path;

use crate::geometry::PinholeCamera;

use super::DatasetError;

/// TUM RGB-D's depth scale: 5000 units per meter.
pub const TUM_DEPTH_SCALE: f64 = 5000.0;

/// The contents of `camera.toml`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraFile {
    /// Intrinsics and distortion of the stored images.
    pub camera: PinholeCamera,
    /// Depth PNG units per meter (`depth_m = value / depth_scale`).
    pub depth_scale: f64,
}

impl CameraFile {
    /// Parses `camera.toml` text read from `path` (used in errors).
    pub fn parse(path: &Path, text: &str) -> Result<Self, DatasetError> {
        let parse_err = |message: String| DatasetError::CameraFile {
            path: path.to_path_buf(),
            message,
        };
        let mut table: toml::Table = toml::from_str(text).map_err(|e| parse_err(e.to_string()))?;
        let depth_scale = match table.remove("depth_scale") {
            None => TUM_DEPTH_SCALE,
            Some(toml::Value::Float(v)) => v,
            Some(toml::Value::Integer(v)) => v as f64,
            Some(other) => {
                return Err(parse_err(format!(
                    "key `depth_scale`: expected a number, found {other}"
                )))
            }
        };
        if !(depth_scale.is_finite() && depth_scale > 0.0) {
            return Err(parse_err(format!(
                "key `depth_scale`: expected a finite number > 0, found {depth_scale}"
            )));
        }
        let camera: PinholeCamera = table.try_into().map_err(|e| parse_err(e.to_string()))?;
        camera.validate().map_err(|e| parse_err(e.to_string()))?;
        Ok(Self {
            camera,
            depth_scale,
        })
    }

    /// Reads and validates `camera.toml`.
    pub fn read(path: &Path) -> Result<Self, DatasetError> {
        let text = super::read_text(path)?;
        Self::parse(path, &text)
    }

    /// Formats as `camera.toml` text.
    pub fn to_toml_string(&self) -> String {
        let c = &self.camera;
        let d = &c.distortion;
        format!(
            "# Calibration of the images in this dataset (pixel centers at integers).\n\
             width = {}\nheight = {}\nfx = {:?}\nfy = {:?}\ncx = {:?}\ncy = {:?}\n\
             # 16-bit depth PNG units per meter.\ndepth_scale = {:?}\n\n\
             [distortion]\nk1 = {:?}\nk2 = {:?}\np1 = {:?}\np2 = {:?}\nk3 = {:?}\n",
            c.width,
            c.height,
            c.fx,
            c.fy,
            c.cx,
            c.cy,
            self.depth_scale,
            d.k1,
            d.k2,
            d.p1,
            d.p2,
            d.k3
        )
    }

    /// Writes `camera.toml`.
    pub fn write(&self, path: &Path) -> Result<(), DatasetError> {
        super::write_text(path, &self.to_toml_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Distortion;

    #[test]
    fn roundtrip_and_defaults() {
        let file = CameraFile {
            camera: PinholeCamera {
                distortion: Distortion {
                    k1: -0.12,
                    k2: 0.03,
                    p1: 1e-4,
                    p2: -2e-4,
                    k3: 0.0,
                },
                ..PinholeCamera::new(640, 512, 420.0, 420.5, 319.5, 255.5)
            },
            depth_scale: 1000.0,
        };
        let text = file.to_toml_string();
        assert_eq!(
            CameraFile::parse(Path::new("c.toml"), &text).expect("valid"),
            file
        );

        let minimal = "width = 4\nheight = 3\nfx = 2\nfy = 2\ncx = 1.5\ncy = 1\n";
        let parsed =
            CameraFile::parse(Path::new("c.toml"), minimal).expect("integers are accepted");
        assert_eq!(parsed.depth_scale, TUM_DEPTH_SCALE);
        assert!(parsed.camera.distortion.is_zero());
    }

    #[test]
    fn bad_files_are_rejected_with_the_key() {
        let p = Path::new("/data/camera.toml");
        let err = CameraFile::parse(
            p,
            "width = 4\nheight = 3\nfx = 2\nfy = 2\ncx = 1\ncy = 1\nfoo = 1\n",
        )
        .unwrap_err();
        assert!(err.to_string().contains("foo"), "{err}");
        assert!(err.to_string().contains("/data/camera.toml"), "{err}");
        let err = CameraFile::parse(
            p,
            "width = 4\nheight = 3\nfx = -2\nfy = 2\ncx = 1\ncy = 1\n",
        )
        .unwrap_err();
        assert!(err.to_string().contains("fx"), "{err}");
        let err =
            CameraFile::parse(p, "width = 4\nheight = 3\nfx = 2\nfy = 2\ncx = 1\n").unwrap_err();
        assert!(err.to_string().contains("cy"), "{err}");
        let err = CameraFile::parse(
            p,
            "width = 4\nheight = 3\nfx = 2\nfy = 2\ncx = 1\ncy = 1\ndepth_scale = 0\n",
        )
        .unwrap_err();
        assert!(err.to_string().contains("depth_scale"), "{err}");
        assert!(CameraFile::parse(p, "width = [").is_err());
    }
}
