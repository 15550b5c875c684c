//! Keyframe rendering: a gray image and a metric depth image of the map at a
//! pose, through the [`Renderer`] trait.
//!
//! Implementations: `cpu` (the tiled software rasterizer, the last fallback
//! and the reference the GPU output is tested against) and `gpu` (wgpu).
//! `select` turns `render.renderer` from the config into a renderer that
//! falls back down the chain (hardware GPU, software GPU, CPU) on failure.
//! Both split the mesh into spatial chunks once (`chunks`) and draw only the
//! chunks that meet the view frustum (`frustum`), and of those only what is
//! not hidden behind what they drew first (`tiles`, the occlusion test both
//! share).
//! Renderers take the mesh once at construction and render an ideal pinhole
//! view (distortion is removed from camera frames instead). Pixel centers are
//! at integer coordinates, as everywhere in `star`.
//!
//! Poses arrive as `f64` nalgebra and are rounded to `f32` glam once per
//! render: [`glam::Mat4`] in the wgpu `View` uniform
//! ([`gpu::projection::ViewUniform`]), [`glam::Affine3A`] / [`glam::Vec3A`]
//! for the CPU rasterizer's vertex transform and clip planes. The rest of
//! the CPU pipeline is not glam: projection and interpolation are scalar
//! `f64` and edge functions fixed-point integers (results must not move),
//! and clipped vertices keep `[f32; 3]` beside their gray and uv.

use crate::geometry::{PinholeCamera, Pose};
use crate::imgproc::ImageF32;

pub mod chunks;
pub mod cpu;
pub mod frustum;
pub mod gpu;
pub mod lod;
pub mod select;
pub(crate) mod tiles;

pub use select::{RenderConfig, RendererKind};

/// Depth value of a pixel that sees no surface (unmapped space or a hole).
pub const NO_DEPTH: f32 = 0.0;

/// Errors from a renderer.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// The output buffers do not match the requested camera size.
    #[error("render target is {found_w}x{found_h} but the camera is {want_w}x{want_h}")]
    TargetSize {
        /// Target width.
        found_w: usize,
        /// Target height.
        found_h: usize,
        /// Camera width.
        want_w: u32,
        /// Camera height.
        want_h: u32,
    },
    /// The pose or intrinsics contain NaN or infinity.
    #[error("render request is not finite: {0}")]
    NotFinite(&'static str),
    /// A render setting cannot be used with this map (e.g.
    /// `render.gpu_budget_mb` below the map's largest chunk); the message
    /// names the key and what it needs.
    #[error("{0}")]
    Setting(String),
    /// The rendering backend failed (device lost, out of memory, ...).
    #[error("renderer backend failed: {0}")]
    Backend(String),
    /// The mesh cannot be rendered: a field is inconsistent or out of range.
    #[error("invalid mesh: {field}[{index}]: {reason}")]
    InvalidMesh {
        /// The [`crate::map::Mesh`] field, e.g. `indices` or `positions`.
        field: &'static str,
        /// The element index within that field.
        index: usize,
        /// What was expected and what was found.
        reason: String,
    },
}

/// One rendered view: gray intensity (0..=255) and metric depth (the z
/// coordinate in the camera optical frame, meters; [`NO_DEPTH`] where nothing
/// was hit). Allocated once and reused for every render.
#[derive(Debug, Clone)]
pub struct RenderedView {
    /// Gray intensity, 0..=255; 0 where nothing was hit.
    pub gray: ImageF32,
    /// Depth along the optical axis in meters; [`NO_DEPTH`] where nothing was hit.
    pub depth_m: ImageF32,
    /// How fine the rendered map's appearance is, meters
    /// ([`crate::map::Mesh::detail_spacing_m`]; 0: full detail): set by
    /// the renderer with every view, read by the keyframe to find the
    /// pyramid levels the map supports (`track::Keyframe::gate_level`).
    pub detail_m: f32,
}

impl RenderedView {
    /// Buffers for a `width x height` view, cleared to "no hit".
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            gray: ImageF32::new(width, height, 0.0),
            depth_m: ImageF32::new(width, height, NO_DEPTH),
            detail_m: 0.0,
        }
    }

    /// Buffers sized for `camera`.
    pub fn for_camera(camera: &PinholeCamera) -> Self {
        Self::new(camera.width as usize, camera.height as usize)
    }

    /// True when pixel depth `d` is a surface hit.
    #[inline]
    pub fn is_hit(depth_m: f32) -> bool {
        depth_m > 0.0
    }

    /// Checks the buffers match `camera`.
    pub fn check_size(&self, camera: &PinholeCamera) -> Result<(), RenderError> {
        let (w, h) = (self.gray.width(), self.gray.height());
        if w != camera.width as usize
            || h != camera.height as usize
            || self.depth_m.width() != w
            || self.depth_m.height() != h
        {
            return Err(RenderError::TargetSize {
                found_w: w,
                found_h: h,
                want_w: camera.width,
                want_h: camera.height,
            });
        }
        Ok(())
    }
}

/// Renders the map at a pose. The mesh is given at construction.
pub trait Renderer: Send {
    /// A short human-readable name, e.g. `cpu` or `wgpu: Intel(R) UHD (Vulkan)`.
    fn name(&self) -> String;

    /// Renders the view of an ideal pinhole `camera` (distortion ignored)
    /// at `world_from_camera` into `out`, which must be sized for `camera`.
    fn render(
        &mut self,
        world_from_camera: &Pose,
        camera: &PinholeCamera,
        out: &mut RenderedView,
    ) -> Result<(), RenderError>;

    /// Culls back faces (triangles clockwise on the image) from the next
    /// render on when `on`, where the renderer can (`[render]
    /// cull_back_faces`); a renderer that cannot draws both sides.
    fn set_cull_back_faces(&mut self, _on: bool) {}

    /// Whether back faces are culled.
    fn cull_back_faces(&self) -> bool {
        false
    }

    /// Sets the far limit from the next render on (`None`: none): surfaces
    /// deeper along the optical axis render as no hit, and what lies wholly
    /// beyond is not drawn. A renderer that cannot draws everything.
    fn set_far_m(&mut self, _far_m: Option<f64>) {}

    /// The far limit, meters; `None`: none.
    fn far_m(&self) -> Option<f64> {
        None
    }
}

/// Checks that a render request is finite; shared by every renderer.
pub fn check_request(world_from_camera: &Pose, camera: &PinholeCamera) -> Result<(), RenderError> {
    let t = world_from_camera.translation.vector;
    let q = world_from_camera.rotation.coords;
    if !(t.iter().all(|v| v.is_finite()) && q.iter().all(|v| v.is_finite())) {
        return Err(RenderError::NotFinite("pose"));
    }
    if camera.validate().is_err() {
        return Err(RenderError::NotFinite("intrinsics"));
    }
    Ok(())
}
