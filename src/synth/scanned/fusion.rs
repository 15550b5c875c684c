//! TSDF fusion of the scanning run through Open3D: the job file, the call
//! to `scripts/tsdf_fuse.py` (embedded in the binary and written next to
//! the job, so `star synth` works from any folder), and reading back the
//! fused mesh.
//!
//! Frames go to the script as two raw files (gray `u8` and depth `u16`
//! millimeters, frame after frame), the job as TOML (Python 3.11 reads it
//! with `tomllib`); the mesh comes back as raw little-endian arrays and the
//! script's statistics as TOML.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde::{Deserialize, Serialize};

use super::ScannedError;
use crate::map::{luma601_255, Mesh};

/// The fusion script, embedded so the binary carries it.
pub const FUSE_SCRIPT: &str = include_str!("../../../scripts/tsdf_fuse.py");

/// What the script needs (see the script's docstring).
#[derive(Debug, Clone, Serialize)]
pub struct FusionJob {
    /// Scan camera width, pixels.
    pub width: u32,
    /// Scan camera height, pixels.
    pub height: u32,
    /// Focal length x, pixels.
    pub fx: f64,
    /// Focal length y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Number of frames.
    pub frames: usize,
    /// Raw gray frames.
    pub gray_path: PathBuf,
    /// Raw 16-bit depth frames, millimeters.
    pub depth_path: PathBuf,
    /// Per frame, the camera pose in the mesh frame, 4x4 row-major.
    pub mesh_from_camera: Vec<[f64; 16]>,
    /// Depth units per meter.
    pub depth_scale: f64,
    /// Largest depth fused, meters.
    pub depth_trunc_m: f64,
    /// Voxel edge, meters.
    pub voxel_m: f64,
    /// TSDF truncation distance, meters.
    pub sdf_trunc_m: f64,
    /// Tile edge, meters.
    pub tile_m: f64,
    /// Tile overlap, voxels.
    pub overlap_voxels: u32,
    /// Lower corner of the fused box, mesh frame.
    pub bounds_min: [f64; 3],
    /// Upper corner of the fused box, mesh frame.
    pub bounds_max: [f64; 3],
    /// Frame-to-tile assignment: one depth point every this many pixels ...
    pub assign_step_px: u32,
    /// ... and at least this many of them in a tile.
    pub assign_min_points: u32,
    /// Output files' prefix.
    pub out_prefix: PathBuf,
}

/// The script's statistics (`PREFIX.stats.toml`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FusionStats {
    /// Open3D version.
    pub open3d: String,
    /// Tiles fused (with at least one frame).
    pub tiles: usize,
    /// Tile grid size.
    pub tile_grid: [i64; 3],
    /// Tile edge, meters.
    pub tile_m: f64,
    /// Voxels along a tile's edge, overlap included.
    pub tile_voxels: usize,
    /// Frame-into-tile integrations.
    pub integrations: usize,
    /// Vertices of the fused mesh.
    pub vertices: usize,
    /// Triangles of the fused mesh.
    pub triangles: usize,
    /// Time assigning frames to tiles, seconds.
    pub assign_s: f64,
    /// Time integrating, seconds.
    pub integrate_s: f64,
    /// Time extracting meshes, seconds.
    pub extract_s: f64,
    /// Script run time, seconds.
    pub total_s: f64,
    /// The script's peak resident memory, MB.
    pub max_rss_mb: f64,
}

/// Checks that `python` runs and imports open3d; returns its version.
pub fn check_python(python: &Path) -> Result<String, ScannedError> {
    let output = Command::new(python)
        .args(["-c", "import open3d; print(open3d.__version__)"])
        .output()
        .map_err(|e| ScannedError::Python {
            python: python.to_path_buf(),
            reason: e.to_string(),
        })?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        return Err(ScannedError::Python {
            python: python.to_path_buf(),
            reason: stderr
                .lines()
                .last()
                .unwrap_or("import open3d failed")
                .to_string(),
        });
    }
    Ok(String::from_utf8_lossy(&output.stdout).trim().to_string())
}

/// Runs the fusion with `python` in `work_dir`; returns the fused mesh
/// (mesh frame, gray from the fused colors) and the statistics.
pub fn run_fusion(
    python: &Path,
    job: &FusionJob,
    work_dir: &Path,
) -> Result<(Mesh, FusionStats), ScannedError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| ScannedError::Io { path, source }
    };
    let script = work_dir.join("tsdf_fuse.py");
    std::fs::write(&script, FUSE_SCRIPT).map_err(io(&script))?;
    let job_path = work_dir.join("fusion_job.toml");
    let text = toml::to_string(job).map_err(|e| ScannedError::Fusion(e.to_string()))?;
    std::fs::write(&job_path, text).map_err(io(&job_path))?;
    let output = Command::new(python)
        .arg(&script)
        .arg(&job_path)
        .env("OMP_NUM_THREADS", threads().to_string())
        .output()
        .map_err(|e| ScannedError::Python {
            python: python.to_path_buf(),
            reason: e.to_string(),
        })?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        let tail: Vec<&str> = stderr.lines().rev().take(12).collect();
        let tail: Vec<&str> = tail.into_iter().rev().collect();
        return Err(ScannedError::Fusion(format!(
            "{} {} exited with {}: {}",
            python.display(),
            script.display(),
            output.status,
            tail.join("\n")
        )));
    }
    let prefix = job.out_prefix.display().to_string();
    let stats_path = PathBuf::from(format!("{prefix}.stats.toml"));
    let stats_text = std::fs::read_to_string(&stats_path).map_err(io(&stats_path))?;
    let stats: FusionStats = toml::from_str(&stats_text)
        .map_err(|e| ScannedError::Fusion(format!("{}: {e}", stats_path.display())))?;
    let read = |suffix: &str| -> Result<Vec<u8>, ScannedError> {
        let path = PathBuf::from(format!("{prefix}.{suffix}"));
        std::fs::read(&path).map_err(io(&path))
    };
    let vertices = read("vertices.f32")?;
    let colors = read("colors.f32")?;
    let triangles = read("triangles.u32")?;
    let floats = |bytes: &[u8]| -> Vec<f32> {
        bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    };
    let positions: Vec<[f32; 3]> = floats(&vertices)
        .chunks_exact(3)
        .map(|p| [p[0], p[1], p[2]])
        .collect();
    let gray: Vec<f32> = floats(&colors)
        .chunks_exact(3)
        .map(|c| luma601_255([c[0], c[1], c[2]]))
        .collect();
    let indices: Vec<u32> = triangles
        .chunks_exact(4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    if positions.len() != stats.vertices
        || gray.len() != positions.len()
        || indices.len() != 3 * stats.triangles
    {
        return Err(ScannedError::Fusion(format!(
            "the fused mesh's files disagree with its statistics: {} vertices, {} colors, {} indices; stats say {} vertices, {} triangles",
            positions.len(),
            gray.len(),
            indices.len(),
            stats.vertices,
            stats.triangles
        )));
    }
    let mesh = Mesh {
        positions,
        gray,
        indices,
        ..Mesh::default()
    };
    mesh.validate().map_err(ScannedError::Map)?;
    Ok((mesh, stats))
}

/// Threads Open3D may use: all cores.
fn threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}
