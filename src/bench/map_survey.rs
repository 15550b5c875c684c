//! The figures `star map info` gives about a user's own map: the holes seen
//! from a coarse grid of views, the keyframe render time of every renderer
//! this machine has, and the memory the map takes.
//!
//! Takes the map (world frame), the transform that levels it (floor at
//! z = 0, z up: the world itself for a z-up map, else the one
//! [`crate::map::align`] finds) and the camera; gives out [`HoleSurvey`],
//! [`RendererTiming`]s and a [`MemoryEstimate`]. Nothing here passes or
//! fails: the CLI prints the figures.

use std::sync::Arc;
use std::time::Instant;

use nalgebra::Translation3;

use crate::geometry::look::camera_rotation;
use crate::geometry::{PinholeCamera, Pose};
use crate::map::Mesh;
use crate::render::cpu::CpuRenderer;
use crate::render::gpu::{AdapterPreference, GpuRenderer};
use crate::render::{RenderError, RenderedView, Renderer};

/// Spacing of the hole grid, meters.
pub const HOLE_GRID_M: f64 = 1.0;
/// Headings per grid position.
pub const HOLE_YAWS: usize = 8;
/// Pitch of the hole views, degrees (a little down, as flown).
pub const HOLE_PITCH_DEG: f64 = -10.0;
/// A view sees "mostly nothing" below this fraction of pixels on the map.
pub const MIN_HIT_FRACTION: f64 = 0.5;
/// Width of the hole views, pixels (the camera scaled down).
pub const HOLE_VIEW_WIDTH_PX: u32 = 80;
/// Most grid positions per height (the grid coarsens beyond).
pub const MAX_HOLE_POSITIONS: usize = 400;

/// The holes of a map as seen from a grid of views.
#[derive(Debug, Clone, PartialEq)]
pub struct HoleSurvey {
    /// Views rendered.
    pub views: usize,
    /// Views with less than [`MIN_HIT_FRACTION`] of their pixels on the map.
    pub empty_views: usize,
    /// `empty_views / views`.
    pub empty_fraction: f64,
    /// Grid spacing used, meters.
    pub grid_m: f64,
    /// Heights above the floor, meters.
    pub heights_m: Vec<f64>,
    /// Every view: its pose (world_from_camera) and the fraction of its
    /// pixels on the map.
    pub hits: Vec<(Pose, f64)>,
}

/// The keyframe render time of one renderer on the map.
#[derive(Debug, Clone, PartialEq)]
pub struct RendererTiming {
    /// Which renderer: `CPU rasterizer`, `wgpu hardware adapter`, `wgpu software adapter`.
    pub renderer: &'static str,
    /// Its own name (the adapter), when it started.
    pub name: Option<String>,
    /// Median render time over the timed views, milliseconds.
    pub median_ms: Option<f64>,
    /// Slowest of the timed views, milliseconds.
    pub max_ms: Option<f64>,
    /// Views timed (after one untimed warm-up render).
    pub views: usize,
    /// Why it is not available, or failed.
    pub error: Option<String>,
}

/// Memory the map takes, estimated from buffer sizes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MemoryEstimate {
    /// The mesh's arrays in the process (positions, gray, uvs, indices, textures).
    pub mesh_bytes: u64,
    /// The CPU rasterizer's chunked copy and its per-pixel buffers.
    pub cpu_renderer_bytes: u64,
    /// The wgpu renderer's buffers on the GPU: vertices, indices, textures,
    /// render targets and readback buffers.
    pub gpu_bytes: u64,
}

/// Estimates the memory of `mesh` rendered at `camera`'s size.
pub fn estimate_memory(mesh: &Mesh, camera: &PinholeCamera) -> MemoryEstimate {
    let v = mesh.positions.len() as u64;
    let i = mesh.indices.len() as u64;
    let t = i / 3;
    let texels: u64 = mesh.textures.iter().map(|x| x.texels.len() as u64).sum();
    let pixels = u64::from(camera.width) * u64::from(camera.height);
    let uv_bytes = if mesh.uvs.is_empty() { 0 } else { 8 };
    let mesh_bytes = v * (12 + 4 + uv_bytes) + 4 * i + 4 * texels;
    // The chunked copy (vertices, indices, source triangle numbers) and the
    // per-pixel triangle numbers.
    let cpu_renderer_bytes = v * (12 + 4 + uv_bytes) + 4 * i + 4 * t + 4 * pixels;
    // GpuVertex is 24 bytes; R32Float textures; two R32Float targets and a
    // Depth32Float z-buffer; two staging buffers of both planes.
    let gpu_bytes = 24 * v + 4 * i + 4 * texels + 12 * pixels + 2 * 8 * pixels;
    MemoryEstimate {
        mesh_bytes,
        cpu_renderer_bytes,
        gpu_bytes,
    }
}

/// The camera of the hole views: `camera` scaled to
/// [`HOLE_VIEW_WIDTH_PX`] wide (same field of view).
fn hole_camera(camera: &PinholeCamera) -> PinholeCamera {
    let s = f64::from(HOLE_VIEW_WIDTH_PX) / f64::from(camera.width.max(1));
    let mut c = camera.pinhole();
    c.width = HOLE_VIEW_WIDTH_PX;
    c.height = ((f64::from(camera.height) * s).round() as u32).max(1);
    c.fx *= s;
    c.fy *= s;
    c.cx = (c.cx + 0.5) * s - 0.5;
    c.cy = (c.cy + 0.5) * s - 0.5;
    c
}

/// Renders the grid of views (every [`HOLE_GRID_M`] over the map's leveled
/// bounds, at `heights_m` above the floor, [`HOLE_YAWS`] headings) and
/// counts those that see mostly nothing. `world_from_level` maps the
/// leveled frame (floor at z = 0) into the map's frame.
pub fn survey_holes(
    mesh: &Arc<Mesh>,
    world_from_level: &Pose,
    camera: &PinholeCamera,
    heights_m: &[f64],
    progress: &mut dyn FnMut(usize, usize),
) -> Result<HoleSurvey, RenderError> {
    let level_from_world = world_from_level.inverse();
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for p in &mesh.positions {
        let q = level_from_world
            * nalgebra::Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        for k in 0..2 {
            lo[k] = lo[k].min(q[k]);
            hi[k] = hi[k].max(q[k]);
        }
    }
    let mut grid_m = HOLE_GRID_M;
    let cells = |g: f64| {
        (
            ((hi[0] - lo[0]) / g).floor().max(0.0) as usize,
            ((hi[1] - lo[1]) / g).floor().max(0.0) as usize,
        )
    };
    while {
        let (nx, ny) = cells(grid_m);
        nx.max(1) * ny.max(1) > MAX_HOLE_POSITIONS
    } {
        grid_m *= 1.5;
    }
    let (nx, ny) = cells(grid_m);
    // Cell centers, inset from the bounds.
    let axis = |k: usize, n: usize| -> Vec<f64> {
        if n == 0 {
            vec![0.5 * (lo[k] + hi[k])]
        } else {
            let margin = 0.5 * ((hi[k] - lo[k]) - (n as f64 - 1.0) * grid_m);
            (0..n).map(|i| lo[k] + margin + i as f64 * grid_m).collect()
        }
    };
    let (xs, ys) = (axis(0, nx), axis(1, ny));
    let cam = hole_camera(camera);
    let mut renderer = CpuRenderer::new(Arc::clone(mesh))?;
    let mut view = RenderedView::for_camera(&cam);
    let total = xs.len() * ys.len() * heights_m.len() * HOLE_YAWS;
    let mut hits = Vec::with_capacity(total);
    let mut empty = 0;
    for &h in heights_m {
        for &x in &xs {
            for &y in &ys {
                for k in 0..HOLE_YAWS {
                    let yaw = std::f64::consts::TAU * k as f64 / HOLE_YAWS as f64;
                    let level_from_camera = Pose::from_parts(
                        Translation3::new(x, y, h),
                        camera_rotation(yaw, HOLE_PITCH_DEG.to_radians(), 0.0),
                    );
                    let pose = world_from_level * level_from_camera;
                    renderer.render(&pose, &cam, &mut view)?;
                    let n = view.depth_m.data().len().max(1);
                    let hit = view
                        .depth_m
                        .data()
                        .iter()
                        .filter(|&&d| RenderedView::is_hit(d))
                        .count() as f64
                        / n as f64;
                    if hit < MIN_HIT_FRACTION {
                        empty += 1;
                    }
                    hits.push((pose, hit));
                    progress(hits.len(), total);
                }
            }
        }
    }
    Ok(HoleSurvey {
        views: hits.len(),
        empty_views: empty,
        empty_fraction: empty as f64 / hits.len().max(1) as f64,
        grid_m,
        heights_m: heights_m.to_vec(),
        hits,
    })
}

/// Up to `count` views that see the most of the map, spread over the list.
pub fn timing_views(survey: &HoleSurvey, count: usize) -> Vec<Pose> {
    let mut seeing: Vec<&(Pose, f64)> = survey
        .hits
        .iter()
        .filter(|(_, hit)| *hit >= MIN_HIT_FRACTION)
        .collect();
    if seeing.is_empty() {
        seeing = survey.hits.iter().collect();
    }
    let step = (seeing.len() / count.max(1)).max(1);
    seeing
        .iter()
        .step_by(step)
        .take(count)
        .map(|(p, _)| *p)
        .collect()
}

fn time_one(
    renderer: &mut dyn Renderer,
    camera: &PinholeCamera,
    poses: &[Pose],
) -> Result<Vec<f64>, RenderError> {
    let mut view = RenderedView::for_camera(camera);
    if let Some(first) = poses.first() {
        renderer.render(first, camera, &mut view)?; // warm-up
    }
    let mut times_ms = Vec::with_capacity(poses.len());
    for pose in poses {
        let start = Instant::now();
        renderer.render(pose, camera, &mut view)?;
        times_ms.push(start.elapsed().as_secs_f64() * 1e3);
    }
    Ok(times_ms)
}

/// Times every renderer this machine has (CPU rasterizer, wgpu hardware
/// adapter, wgpu software adapter) on `poses` at `camera`'s size.
pub fn time_renderers(
    mesh: &Arc<Mesh>,
    camera: &PinholeCamera,
    poses: &[Pose],
) -> Vec<RendererTiming> {
    let camera = camera.pinhole();
    let mut out = Vec::new();
    let stages: [(&'static str, Option<AdapterPreference>); 3] = [
        ("CPU rasterizer", None),
        ("wgpu hardware adapter", Some(AdapterPreference::Hardware)),
        ("wgpu software adapter", Some(AdapterPreference::Software)),
    ];
    for (label, stage) in stages {
        let started: Result<Box<dyn Renderer>, String> = match stage {
            None => CpuRenderer::new(Arc::clone(mesh))
                .map(|r| Box::new(r) as Box<dyn Renderer>)
                .map_err(|e| e.to_string()),
            Some(which) => GpuRenderer::new(Arc::clone(mesh), which)
                .map(|r| Box::new(r) as Box<dyn Renderer>)
                .map_err(|e| e.to_string()),
        };
        let timing = match started {
            Err(error) => RendererTiming {
                renderer: label,
                name: None,
                median_ms: None,
                max_ms: None,
                views: 0,
                error: Some(error),
            },
            Ok(mut renderer) => {
                let name = renderer.name();
                match time_one(renderer.as_mut(), &camera, poses) {
                    Ok(mut times) => {
                        times.sort_by(f64::total_cmp);
                        RendererTiming {
                            renderer: label,
                            name: Some(name),
                            median_ms: times.get(times.len() / 2).copied(),
                            max_ms: times.last().copied(),
                            views: times.len(),
                            error: None,
                        }
                    }
                    Err(e) => RendererTiming {
                        renderer: label,
                        name: Some(name),
                        median_ms: None,
                        max_ms: None,
                        views: 0,
                        error: Some(e.to_string()),
                    },
                }
            }
        };
        out.push(timing);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hole_camera_keeps_the_field_of_view() {
        let c = PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
        let h = hole_camera(&c);
        assert_eq!((h.width, h.height), (80, 64));
        assert!(
            (h.fx - 52.5).abs() < 1e-9 && (h.cx - 39.5).abs() < 1e-9,
            "{h:?}"
        );
    }
}
