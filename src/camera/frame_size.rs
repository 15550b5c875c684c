//! The size of the frames a configured source will deliver, where it is
//! known before the source runs: a `pattern:WxH` source's size, and a
//! `replay:` dataset's `camera.toml` and first image. `star check-config`
//! compares these with `[camera.intrinsics]`, whose size the tracker
//! requires of every frame.
//!
//! V4L2 and Aravis cameras are asked for the calibrated size; what the
//! driver delivers is known only once the camera is opened (`star camera`
//! warns when the driver picked another size, and the tracker refuses and
//! counts such frames).

use std::path::Path;

use super::{CameraError, SourceUri};
use crate::dataset::CameraFile;

/// A frame size the source is known to deliver, and where it comes from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct KnownSize {
    /// Where the size comes from, for messages (`camera.source pattern:160x128`,
    /// `dataset calibration /data/seq/camera.toml`).
    pub origin: String,
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
}

/// The sizes `uri` is known to deliver. `open_files` allows reading a
/// replay dataset's `camera.toml` (when present) and the header of its
/// first frame; without it only the URI is looked at.
pub fn known_frame_sizes(uri: &SourceUri, open_files: bool) -> Result<Vec<KnownSize>, CameraError> {
    match uri {
        SourceUri::Pattern { width, height } => Ok(vec![KnownSize {
            origin: format!("camera.source {uri}"),
            width: *width,
            height: *height,
        }]),
        SourceUri::Replay(dir) if open_files => replay_sizes(dir),
        SourceUri::Replay(_) | SourceUri::V4l2(_) | SourceUri::Aravis(_) => Ok(Vec::new()),
        // A simulated camera renders at the calibration's own size.
        SourceUri::Sim(_) => Ok(Vec::new()),
    }
}

fn replay_sizes(dir: &Path) -> Result<Vec<KnownSize>, CameraError> {
    let mut sizes = Vec::new();
    let calibration = dir.join("camera.toml");
    if calibration.exists() {
        let file = CameraFile::read(&calibration).map_err(|e| CameraError::Dataset {
            path: calibration.clone(),
            reason: e.to_string(),
        })?;
        sizes.push(KnownSize {
            origin: format!("dataset calibration {}", calibration.display()),
            width: file.camera.width,
            height: file.camera.height,
        });
    }
    let entries = super::replay::read_frame_list(dir)?;
    if let Some(first) = entries.first() {
        let path = dir.join(&first.path);
        let bad = |reason: String| CameraError::Dataset {
            path: path.clone(),
            reason,
        };
        let file = crate::dataset::open_regular_file(&path)
            .map_err(|e| bad(format!("cannot read the frame: {e}")))?;
        let (width, height) = image::ImageReader::new(std::io::BufReader::new(file))
            .with_guessed_format()
            .map_err(|e| bad(format!("cannot read the frame: {e}")))?
            .into_dimensions()
            .map_err(|e| bad(format!("cannot read the image header: {e}")))?;
        sizes.push(KnownSize {
            origin: format!("first frame {}", path.display()),
            width,
            height,
        });
    }
    Ok(sizes)
}
