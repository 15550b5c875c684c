//! `star render`: draw the map at one pose with the CPU rasterizer and write
//! the gray image (8-bit PNG) and optionally the depth (16-bit PNG, mm).
//!
//! Takes a mesh (OBJ, PLY, glTF or GLB), a pose (`tx ty tz qx qy qz qw`, TUM order,
//! world_from_camera) and a camera from `camera.toml`, from `star.toml`
//! (`[camera.intrinsics]`), or the default, each intrinsic overridable on
//! the command line. Distortion is ignored: the output is the ideal pinhole
//! view, as keyframes are.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context, Result};

use crate::config::Config;
use crate::dataset::{write_gray16, write_gray8, CameraFile};
use crate::geometry::PinholeCamera;
use crate::render::cpu::CpuRenderer;
use crate::render::{RenderedView, Renderer};

use super::pose_arg::parse_pose;

/// Arguments of `star render`.
#[derive(Debug, clap::Args)]
pub struct RenderArgs {
    /// Map mesh (.obj, .ply, .gltf or .glb); default: `[map].mesh` of `--config`.
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// Camera pose "tx ty tz qx qy qz qw" (TUM order, world_from_camera).
    #[arg(long, allow_hyphen_values = true)]
    pub pose: String,
    /// Camera calibration file (dataset `camera.toml`).
    #[arg(long, conflicts_with = "config")]
    pub camera: Option<PathBuf>,
    /// Configuration file; its `[camera.intrinsics]` and `[map].mesh` are used.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Image width, pixels (overrides the camera).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height, pixels (overrides the camera).
    #[arg(long)]
    pub height: Option<u32>,
    /// Focal length x, pixels (overrides the camera).
    #[arg(long)]
    pub fx: Option<f64>,
    /// Focal length y, pixels (overrides the camera).
    #[arg(long)]
    pub fy: Option<f64>,
    /// Principal point x, pixels, pixel centers at integers (overrides the camera).
    #[arg(long)]
    pub cx: Option<f64>,
    /// Principal point y, pixels (overrides the camera).
    #[arg(long)]
    pub cy: Option<f64>,
    /// Output gray image (8-bit PNG).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Output depth image (16-bit PNG, millimeters, 0 = no surface).
    #[arg(long)]
    pub depth_out: Option<PathBuf>,
    /// Render threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// The camera from the arguments: file, then overrides; validated.
fn camera(args: &RenderArgs, config: Option<&Config>) -> Result<PinholeCamera> {
    let mut cam = match (&args.camera, config) {
        (Some(path), _) => {
            CameraFile::read(path)
                .with_context(|| format!("reading camera {}", path.display()))?
                .camera
        }
        (None, Some(config)) => config.camera.intrinsics,
        (None, None) => Config::default().camera.intrinsics,
    };
    cam = cam.pinhole();
    if let Some(w) = args.width {
        cam.width = w;
    }
    if let Some(h) = args.height {
        cam.height = h;
    }
    for (arg, field) in [
        (args.fx, &mut cam.fx),
        (args.fy, &mut cam.fy),
        (args.cx, &mut cam.cx),
        (args.cy, &mut cam.cy),
    ] {
        if let Some(v) = arg {
            *field = v;
        }
    }
    cam.validate().context("invalid camera for rendering")?;
    Ok(cam)
}

/// Converts metric depth to 16-bit millimeters (0 = no surface, saturating
/// at 65.535 m).
fn depth_to_mm(depth_m: &[f32]) -> Vec<u16> {
    depth_m
        .iter()
        .map(|&d| {
            if RenderedView::is_hit(d) {
                (f64::from(d) * 1000.0).round().clamp(1.0, 65535.0) as u16
            } else {
                0
            }
        })
        .collect()
}

/// Runs `star render`.
pub fn run(args: &RenderArgs) -> Result<()> {
    let config = args
        .config
        .as_deref()
        .map(|p| Config::load(p).with_context(|| format!("loading config {}", p.display())))
        .transpose()?;
    let world_from_camera = parse_pose(&args.pose).context("invalid --pose")?;
    let cam = camera(args, config.as_ref())?;
    let map_path = match (&args.map, &config) {
        (Some(p), _) => p.clone(),
        (None, Some(c)) => c.map.mesh.clone(),
        (None, None) => bail!("no map: give --map MESH or --config with [map].mesh"),
    };
    let placement = config.as_ref().map(|c| c.map.clone()).unwrap_or_default();
    let mesh = placement
        .load_mesh_from(&map_path)
        .with_context(|| format!("loading map {}", map_path.display()))?;
    let triangles = mesh.triangle_count();
    let mesh = Arc::new(mesh);
    let mut renderer = match args.threads {
        Some(n) => CpuRenderer::with_threads(mesh, n),
        None => CpuRenderer::new(mesh),
    }
    .context("building the CPU renderer")?;
    // As the service renders this config's map; both sides without one.
    renderer.set_cull_back_faces(config.as_ref().is_some_and(|c| c.render.cull_back_faces));
    let mut view = RenderedView::for_camera(&cam);
    let start = Instant::now();
    renderer
        .render(&world_from_camera, &cam, &mut view)
        .context("rendering")?;
    let render_ms = start.elapsed().as_secs_f64() * 1e3;
    let hits = view
        .depth_m
        .data()
        .iter()
        .filter(|&&d| RenderedView::is_hit(d))
        .count();
    tracing::info!(
        triangles,
        render_ms,
        threads = renderer.threads(),
        "rendered {}x{}",
        cam.width,
        cam.height
    );
    write_gray8(&args.output, &view.gray.to_u8())
        .with_context(|| format!("writing {}", args.output.display()))?;
    if let Some(path) = &args.depth_out {
        let mm = depth_to_mm(view.depth_m.data());
        write_gray16(path, cam.width, cam.height, &mm)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    println!(
        "render: {} ({}x{}, {triangles} triangles, {:.1}% of pixels hit) in {render_ms:.1} ms",
        args.output.display(),
        cam.width,
        cam.height,
        100.0 * hits as f64 / (cam.width as f64 * cam.height as f64)
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_is_written_in_millimeters() {
        assert_eq!(
            depth_to_mm(&[0.0, 1.2345, 70.0, 0.0001]),
            vec![0, 1235, 65535, 1]
        );
    }
}
