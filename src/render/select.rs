//! Renderer choice and runtime fallback: `render.renderer` in the config to
//! a working [`Renderer`].
//!
//! Takes a [`RendererKind`] and the mesh; gives out a [`FallbackRenderer`]
//! holding the chain of renderers to try:
//! - `auto`: a hardware wgpu adapter (Vulkan, then GL), then the CPU
//!   rasterizer; the first that starts is used. Mesa's software adapters are
//!   not in this chain: the CPU rasterizer is faster than lavapipe on every
//!   map measured (38 against 139 ms on a 3.7M-triangle scan, about even on
//!   a 24k-triangle room), and a slow keyframe is what let `aggressive
//!   --scanned` send wrong poses (docs/design-decisions.md, "`auto` prefers
//!   the CPU rasterizer to a software GPU");
//! - `gpu`: a hardware adapter must start, then as `auto`;
//! - `software`: the software adapter must start, then the CPU rasterizer;
//! - `cpu`: the CPU rasterizer only.
//!
//! When the active renderer fails at runtime (a backend error: device lost,
//! out of memory, a timeout, even a panic inside wgpu), the next renderer of
//! the chain is started and the same view is rendered again, so tracking
//! never stops for a renderer failure. Each switch is logged at `warn`.
//! Request errors (wrong buffer size, non-finite pose) are returned as they
//! are: the next renderer would refuse them too.
//!
//! The map is held only while a later stage may still have to be started
//! from it. Once the last stage (the CPU rasterizer) is active, the
//! renderer holds its own chunked copy and the map's textures, and nothing
//! else: a caller that gave its only reference frees the map's vertex and
//! index arrays.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::cpu::CpuRenderer;
use super::gpu::{AdapterClass, AdapterPreference, GpuRenderer};
use super::{RenderError, RenderedView, Renderer};
use crate::geometry::{PinholeCamera, Pose};
use crate::map::Mesh;

/// Which renderer draws keyframes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum RendererKind {
    /// Hardware adapter, then the CPU rasterizer (never a software
    /// adapter: the CPU rasterizer is faster).
    #[default]
    Auto,
    /// A hardware wgpu adapter, which must exist at start; on a runtime
    /// failure, the CPU rasterizer.
    Gpu,
    /// wgpu's software adapter (Mesa lavapipe/llvmpipe), which must exist at
    /// start; on a runtime failure, the CPU rasterizer.
    Software,
    /// The built-in CPU rasterizer.
    Cpu,
}

/// Default of `render.far_m`, meters: beyond any one room, so a room-sized
/// map renders exactly as without a far limit.
pub const DEFAULT_FAR_M: f64 = 30.0;

/// Accepted `render.far_m`, meters (0 turns the limit off).
pub const FAR_M_RANGE: std::ops::RangeInclusive<f64> = 1.0..=10_000.0;

/// Largest accepted `render.gpu_budget_mb`, MB (10 TB: beyond any device).
pub const MAX_GPU_BUDGET_MB: f64 = 1e7;

/// Bytes in the MB of `render.gpu_budget_mb` (as in every MB `star` logs).
pub const BYTES_PER_MB: f64 = 1e6;

/// `[render]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderConfig {
    /// `auto`, `gpu`, `software` or `cpu`.
    pub renderer: RendererKind,
    /// Far limit of keyframe renders, meters along the optical axis:
    /// surfaces beyond it render as "no depth" (never selected as tracking
    /// points) and mesh chunks wholly beyond it are not drawn at all. 0
    /// turns it off.
    pub far_m: f64,
    /// Device memory the wgpu renderer may use for the mesh's vertex and
    /// index data, MB (10^6 bytes). 0, the default: no budget, the whole
    /// mesh is uploaded at start. A mesh larger than a nonzero budget is
    /// streamed: a fixed pool of chunk slots of this size, filled with the
    /// visible chunks as renders need them (least recently used evicted).
    /// Textures, targets and the CPU rasterizer are not bounded by it.
    pub gpu_budget_mb: f64,
    /// Whether both renderers skip what is hidden behind what they drew
    /// first (exact: the image is the same; default on). The CPU
    /// rasterizer culls chunks, clusters and triangles between its
    /// batches; wgpu draws a resident mesh in two passes with the depth of
    /// the first read back between them (`render::gpu` docs). On a
    /// hardware adapter, where that readback may cost more than it saves,
    /// wgpu times renders with and without the cull in flight and keeps
    /// the faster (`render::gpu::cull_timing`); on lavapipe it is always
    /// on. Off: the frustum and far limit only.
    pub occlusion_cull: bool,
    /// Level of detail (`render::lod`): runs of 4, 16 and 64 chunks also
    /// have coarser copies, their vertices pooled in cells of 2, 4 and 8
    /// times the median edge and the run's border kept exact; a render
    /// draws the coarsest copy whose error spans at most this many pixels
    /// at the copy's nearest point. A vertex-colored copy's error is its
    /// cell (its gray is averaged over the cell); a textured copy's is
    /// measured against the fine chunks (0 where they are flat and mapped
    /// affinely, so such a copy is drawn at every distance). 0 turns it
    /// off (every triangle drawn, and no copies built).
    pub lod_max_px: f64,
    /// Whether both renderers cull back faces: a triangle clockwise on the
    /// image is not drawn. Off by default (both sides drawn, as a map of
    /// unknown winding needs). On only for a map whose triangles are
    /// counter-clockwise seen from where the camera can be (the front
    /// facing free space): `star synth` maps are wound so; a TSDF scan's
    /// fronts face where it was scanned from, but a view through a hole
    /// in the scan sees back faces (4-9 % of the pixels differ on the
    /// scanned 4 rooms). On the `building` floor it takes a tenth off a
    /// CPU keyframe and changes at most 4 pixels of a view, where a back
    /// face showed through a crack between two surfaces
    /// (docs/building-scale.md). Only keyframes near a tracked pose are
    /// culled: relocalization candidates, whose poses are not verified, and
    /// the database's views are drawn from both sides.
    pub cull_back_faces: bool,
}

/// Default of `render.lod_max_px`, pixels.
pub const DEFAULT_LOD_MAX_PX: f64 = 2.0;

/// Accepted `render.lod_max_px`, pixels (0 turns it off).
pub const LOD_MAX_PX_RANGE: std::ops::RangeInclusive<f64> = 0.0..=64.0;

impl Default for RenderConfig {
    fn default() -> Self {
        Self {
            renderer: RendererKind::default(),
            far_m: DEFAULT_FAR_M,
            gpu_budget_mb: 0.0,
            occlusion_cull: true,
            lod_max_px: DEFAULT_LOD_MAX_PX,
            cull_back_faces: false,
        }
    }
}

impl RenderConfig {
    /// Checks `far_m`: 0 (off) or within [`FAR_M_RANGE`]; `gpu_budget_mb`:
    /// 0 (none) or positive up to [`MAX_GPU_BUDGET_MB`]. Whether a budget
    /// holds the map's largest chunk is checked when the wgpu renderer
    /// starts on that map.
    pub fn validate(&self) -> Result<(), crate::settings::SettingError> {
        crate::settings::first_failure([
            (
                "far_m",
                self.far_m == 0.0 || FAR_M_RANGE.contains(&self.far_m),
                format!(
                    "expected 0 (no limit) or {}..={} m, found {}",
                    FAR_M_RANGE.start(),
                    FAR_M_RANGE.end(),
                    self.far_m
                ),
            ),
            (
                "gpu_budget_mb",
                (0.0..=MAX_GPU_BUDGET_MB).contains(&self.gpu_budget_mb),
                format!(
                    "expected 0 (no budget: the whole mesh on the device) or a size \
                     in MB (10^6 bytes) up to {MAX_GPU_BUDGET_MB}, found {}",
                    self.gpu_budget_mb
                ),
            ),
            (
                "lod_max_px",
                LOD_MAX_PX_RANGE.contains(&self.lod_max_px),
                format!(
                    "expected 0 (full detail) or a cell size in pixels up to {}, found {}",
                    LOD_MAX_PX_RANGE.end(),
                    self.lod_max_px
                ),
            ),
        ])
    }

    /// The level-of-detail cell limit as the renderers take it, pixels (0:
    /// full detail).
    pub fn lod_px(&self) -> f32 {
        // Validated: finite, 0..=64.
        self.lod_max_px as f32
    }

    /// The GPU budget as the wgpu renderer takes it, bytes: 0 when off.
    pub fn gpu_budget_bytes(&self) -> u64 {
        // Validated: finite, 0..=1e13 bytes.
        (self.gpu_budget_mb.max(0.0) * BYTES_PER_MB) as u64
    }

    /// The far limit as the renderers take it: `None` when off.
    pub fn far_limit_m(&self) -> Option<f64> {
        (self.far_m > 0.0).then_some(self.far_m)
    }
}

/// One renderer of a fallback chain.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// The wgpu renderer on an adapter of this class.
    Gpu(AdapterPreference),
    /// The CPU rasterizer.
    Cpu,
}

impl Stage {
    fn describe(self) -> &'static str {
        match self {
            Stage::Gpu(AdapterPreference::Hardware) => "wgpu hardware adapter",
            Stage::Gpu(AdapterPreference::Software) => "wgpu software adapter",
            Stage::Cpu => "CPU rasterizer",
        }
    }
}

const HARDWARE: Stage = Stage::Gpu(AdapterPreference::Hardware);
const SOFTWARE: Stage = Stage::Gpu(AdapterPreference::Software);

/// The renderers `kind` may use, in the order they are tried.
pub fn chain(kind: RendererKind) -> &'static [Stage] {
    match kind {
        RendererKind::Auto | RendererKind::Gpu => &[HARDWARE, Stage::Cpu],
        RendererKind::Software => &[SOFTWARE, Stage::Cpu],
        RendererKind::Cpu => &[Stage::Cpu],
    }
}

/// The renderer currently in use.
#[derive(Debug)]
enum Active {
    Gpu(Box<GpuRenderer>),
    Cpu(Box<CpuRenderer>),
}

/// What every renderer of a chain is started with.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Settings {
    /// Far limit, meters; `None`: none.
    far_m: Option<f64>,
    /// wgpu mesh budget, bytes; 0: none.
    gpu_budget_bytes: u64,
    /// Whether the occlusion cull is off (`render.occlusion_cull = false`).
    no_occlusion_cull: bool,
    /// Level-of-detail cell limit, pixels; 0: full detail.
    lod_max_px: f32,
    /// Whether back faces are culled (`render.cull_back_faces`).
    cull_back_faces: bool,
}

impl Active {
    fn start(stage: Stage, mesh: &Arc<Mesh>, settings: Settings) -> Result<Self, RenderError> {
        match stage {
            Stage::Gpu(which) => {
                let mut r = GpuRenderer::new_configured(
                    Arc::clone(mesh),
                    which,
                    settings.gpu_budget_bytes,
                    settings.lod_max_px,
                )?;
                r.set_far_m(settings.far_m);
                r.set_cull_back_faces(settings.cull_back_faces);
                if settings.no_occlusion_cull {
                    r.set_occlusion_cull(false);
                } else if r.class() == AdapterClass::Hardware {
                    // Whether the readback between passes pays depends on
                    // the device: timed in flight.
                    r.set_occlusion_timed();
                } else {
                    r.set_occlusion_cull(true);
                }
                Ok(Active::Gpu(Box::new(r)))
            }
            Stage::Cpu => {
                let mut r = CpuRenderer::with_lod(Arc::clone(mesh), settings.lod_max_px)?;
                r.set_far_m(settings.far_m);
                r.set_cull_back_faces(settings.cull_back_faces);
                r.set_occlusion_cull(!settings.no_occlusion_cull);
                Ok(Active::Cpu(Box::new(r)))
            }
        }
    }

    fn renderer(&mut self) -> &mut dyn Renderer {
        match self {
            Active::Gpu(r) => r.as_mut(),
            Active::Cpu(r) => r.as_mut(),
        }
    }
}

/// A renderer that falls back down its chain on failure. See the
/// [module docs](self).
#[derive(Debug)]
pub struct FallbackRenderer {
    /// The map, kept while a later stage of the chain may still have to
    /// be started from it; dropped once the last stage is active, so that
    /// the map's vertex and index arrays are not held twice beside the
    /// renderer's chunked copy (about 300 MB on a scanned floor).
    mesh: Option<Arc<Mesh>>,
    settings: Settings,
    chain: &'static [Stage],
    index: usize,
    active: Active,
}

/// Builds the renderer `kind` asks for, boxed, without a far limit; see
/// [`FallbackRenderer::new`].
pub fn make_renderer(
    kind: RendererKind,
    mesh: Arc<Mesh>,
) -> Result<Box<dyn Renderer>, RenderError> {
    Ok(Box::new(FallbackRenderer::new(kind, mesh)?))
}

/// Builds the renderer `[render]` asks for (kind, far limit and GPU
/// budget), boxed.
pub fn make_configured_renderer(
    config: &RenderConfig,
    mesh: Arc<Mesh>,
) -> Result<Box<dyn Renderer>, RenderError> {
    Ok(Box::new(FallbackRenderer::configured(config, mesh)?))
}

impl FallbackRenderer {
    /// Starts the first renderer of `kind`'s chain that works. With `gpu`
    /// or `software` the first one must work: asking for it explicitly
    /// makes its absence an error. Logs the renderer chosen.
    pub fn new(kind: RendererKind, mesh: Arc<Mesh>) -> Result<Self, RenderError> {
        Self::with_far(kind, mesh, None)
    }

    /// As [`FallbackRenderer::new`], every renderer of the chain with the
    /// far limit `far_m` (see [`RenderConfig::far_m`]).
    pub fn with_far(
        kind: RendererKind,
        mesh: Arc<Mesh>,
        far_m: Option<f64>,
    ) -> Result<Self, RenderError> {
        let settings = Settings {
            far_m,
            ..Settings::default()
        };
        Self::start(kind, mesh, settings)
    }

    /// As [`FallbackRenderer::new`], with everything `[render]` sets: the
    /// kind, the far limit and the wgpu mesh budget
    /// ([`RenderConfig::gpu_budget_mb`]). A budget below the map's largest
    /// chunk is an error, not a reason to fall back.
    pub fn configured(config: &RenderConfig, mesh: Arc<Mesh>) -> Result<Self, RenderError> {
        let settings = Settings {
            far_m: config.far_limit_m(),
            gpu_budget_bytes: config.gpu_budget_bytes(),
            no_occlusion_cull: !config.occlusion_cull,
            lod_max_px: config.lod_px(),
            cull_back_faces: config.cull_back_faces,
        };
        Self::start(config.renderer, mesh, settings)
    }

    fn start(kind: RendererKind, mesh: Arc<Mesh>, settings: Settings) -> Result<Self, RenderError> {
        let chain = chain(kind);
        let strict = matches!(kind, RendererKind::Gpu | RendererKind::Software);
        let mut errors = Vec::new();
        for (index, &stage) in chain.iter().enumerate() {
            match Active::start(stage, &mesh, settings) {
                Ok(active) => {
                    let last = index + 1 >= chain.len();
                    let mut renderer = Self {
                        mesh: (!last).then_some(mesh),
                        settings,
                        chain,
                        index,
                        active,
                    };
                    tracing::info!(
                        renderer = %renderer.active.renderer().name(),
                        ?kind,
                        far_m = ?settings.far_m,
                        gpu_budget_mb = settings.gpu_budget_bytes as f64 / BYTES_PER_MB,
                        occlusion_cull = !settings.no_occlusion_cull,
                        cull_back_faces = settings.cull_back_faces,
                        "keyframe renderer chosen"
                    );
                    return Ok(renderer);
                }
                // A setting the map cannot be rendered with is the
                // operator's to fix, whatever the chain.
                Err(e @ RenderError::Setting(_)) => return Err(e),
                Err(e) => {
                    tracing::info!(stage = stage.describe(), error = %e, "renderer unavailable");
                    if strict && index == 0 {
                        return Err(e);
                    }
                    errors.push(format!("{}: {e}", stage.describe()));
                }
            }
        }
        Err(RenderError::Backend(format!(
            "no renderer could start: {}",
            errors.join("; ")
        )))
    }

    /// The stage of the chain in use.
    pub fn active_stage(&self) -> Stage {
        self.chain.get(self.index).copied().unwrap_or(Stage::Cpu)
    }

    /// Test hook: makes the active GPU renderer fail after `n` more renders
    /// (see [`GpuRenderer::inject_failure_after`]); false if it is not a GPU one.
    #[doc(hidden)]
    pub fn inject_failure_after(&mut self, n: u64) -> bool {
        match &mut self.active {
            Active::Gpu(r) => {
                r.inject_failure_after(n);
                true
            }
            Active::Cpu(_) => false,
        }
    }

    /// Starts the next renderer of the chain that works after `failure`.
    fn fall_back(&mut self, failure: &str) -> Result<(), RenderError> {
        let from = self.active.renderer().name();
        for index in self.index + 1..self.chain.len() {
            let Some(&stage) = self.chain.get(index) else {
                break;
            };
            let Some(mesh) = self.mesh.as_ref() else {
                break;
            };
            match Active::start(stage, mesh, self.settings) {
                Ok(active) => {
                    self.active = active;
                    self.index = index;
                    if index + 1 >= self.chain.len() {
                        self.mesh = None;
                    }
                    tracing::warn!(
                        from = %from,
                        to = %self.active.renderer().name(),
                        error = failure,
                        "keyframe renderer failed; switched to the next one"
                    );
                    return Ok(());
                }
                Err(e) => {
                    tracing::warn!(stage = stage.describe(), error = %e, "fallback renderer unavailable");
                }
            }
        }
        Err(RenderError::Backend(format!(
            "{from} failed ({failure}) and no fallback renderer is left"
        )))
    }
}

impl Renderer for FallbackRenderer {
    fn name(&self) -> String {
        match &self.active {
            Active::Gpu(r) => r.name(),
            Active::Cpu(r) => r.name(),
        }
    }

    fn set_cull_back_faces(&mut self, on: bool) {
        // A later stage of the chain starts with it too.
        self.settings.cull_back_faces = on;
        self.active.renderer().set_cull_back_faces(on);
    }

    fn cull_back_faces(&self) -> bool {
        self.settings.cull_back_faces
    }

    fn set_far_m(&mut self, far_m: Option<f64>) {
        // A later stage of the chain starts with it too.
        self.settings.far_m = far_m;
        self.active.renderer().set_far_m(far_m);
    }

    fn far_m(&self) -> Option<f64> {
        self.settings.far_m
    }

    fn render(
        &mut self,
        world_from_camera: &Pose,
        camera: &PinholeCamera,
        out: &mut RenderedView,
    ) -> Result<(), RenderError> {
        loop {
            let result = match &mut self.active {
                // A panic inside wgpu or a driver is a backend failure too.
                Active::Gpu(r) => catch_unwind(AssertUnwindSafe(|| {
                    r.render(world_from_camera, camera, out)
                }))
                .unwrap_or_else(|_| Err(RenderError::Backend("wgpu renderer panicked".into()))),
                Active::Cpu(r) => r.render(world_from_camera, camera, out),
            };
            match result {
                Err(RenderError::Backend(failure)) if self.index + 1 < self.chain.len() => {
                    self.fall_back(&failure)?;
                }
                other => return other,
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn far_limit_defaults_to_30_m_and_is_validated() {
        let c = RenderConfig::default();
        assert_eq!(
            (c.far_m, c.far_limit_m()),
            (DEFAULT_FAR_M, Some(DEFAULT_FAR_M))
        );
        let off = RenderConfig {
            far_m: 0.0,
            ..RenderConfig::default()
        };
        off.validate().expect("0 turns it off");
        assert_eq!(off.far_limit_m(), None);
        for bad in [0.5, -3.0, f64::NAN, 1e9] {
            let err = RenderConfig {
                far_m: bad,
                ..RenderConfig::default()
            }
            .validate()
            .expect_err("out of range");
            assert!(err.to_string().contains("far_m"), "{err}");
        }
    }

    #[test]
    fn gpu_budget_defaults_to_none_and_is_validated() {
        let c = RenderConfig::default();
        assert_eq!((c.gpu_budget_mb, c.gpu_budget_bytes()), (0.0, 0));
        let set = RenderConfig {
            gpu_budget_mb: 64.5,
            ..RenderConfig::default()
        };
        set.validate().expect("a budget");
        assert_eq!(set.gpu_budget_bytes(), 64_500_000);
        for bad in [-1.0, f64::NAN, f64::INFINITY, 1e8] {
            let err = RenderConfig {
                gpu_budget_mb: bad,
                ..RenderConfig::default()
            }
            .validate()
            .expect_err("out of range");
            assert!(err.to_string().contains("gpu_budget_mb"), "{err}");
        }
        let parsed: RenderConfig = toml::from_str("gpu_budget_mb = 256").expect("an integer");
        assert_eq!(parsed.gpu_budget_bytes(), 256_000_000);
    }

    #[test]
    fn level_of_detail_defaults_to_2_px_and_is_validated() {
        let c = RenderConfig::default();
        assert_eq!((c.lod_max_px, c.lod_px()), (DEFAULT_LOD_MAX_PX, 2.0));
        let off: RenderConfig = toml::from_str("lod_max_px = 0").expect("an integer");
        off.validate().expect("0 turns it off");
        assert_eq!(off.lod_px(), 0.0);
        for bad in [-1.0, f64::NAN, f64::INFINITY, 65.0] {
            let err = RenderConfig {
                lod_max_px: bad,
                ..RenderConfig::default()
            }
            .validate()
            .expect_err("out of range");
            assert!(err.to_string().contains("lod_max_px"), "{err}");
        }
        // It reaches the renderer chain's settings.
        let chain = FallbackRenderer::configured(
            &RenderConfig {
                renderer: RendererKind::Cpu,
                lod_max_px: 3.5,
                ..RenderConfig::default()
            },
            Arc::new(Mesh::default()),
        )
        .expect("the CPU rasterizer starts on an empty mesh");
        assert_eq!(chain.settings.lod_max_px, 3.5);
    }

    #[test]
    fn back_faces_are_drawn_unless_the_config_culls_them() {
        assert!(!RenderConfig::default().cull_back_faces);
        let on: RenderConfig = toml::from_str("cull_back_faces = true").expect("a bool");
        assert!(on.cull_back_faces);
        assert!(toml::from_str::<RenderConfig>("cull_back_faces = 1").is_err());
        let chain = FallbackRenderer::configured(
            &RenderConfig {
                renderer: RendererKind::Cpu,
                ..on
            },
            Arc::new(Mesh::default()),
        )
        .expect("the CPU rasterizer starts on an empty mesh");
        assert!(chain.settings.cull_back_faces);
    }

    #[test]
    fn occlusion_cull_is_on_unless_the_config_turns_it_off() {
        assert!(RenderConfig::default().occlusion_cull);
        let parsed: RenderConfig = toml::from_str("far_m = 10").expect("valid");
        assert!(parsed.occlusion_cull);
        let off: RenderConfig = toml::from_str("occlusion_cull = false").expect("a bool");
        assert!(!off.occlusion_cull);
        assert!(toml::from_str::<RenderConfig>("occlusion_cull = 0").is_err());
        // It reaches the renderer chain's settings.
        let mesh = Arc::new(Mesh::default());
        let chain = FallbackRenderer::configured(
            &RenderConfig {
                renderer: RendererKind::Cpu,
                ..off
            },
            mesh,
        )
        .expect("the CPU rasterizer starts on an empty mesh");
        assert!(chain.settings.no_occlusion_cull);
    }

    #[test]
    fn chains_end_with_the_cpu_rasterizer() {
        assert_eq!(chain(RendererKind::Auto), &[HARDWARE, Stage::Cpu]);
        assert_eq!(chain(RendererKind::Gpu), &[HARDWARE, Stage::Cpu]);
        assert_eq!(chain(RendererKind::Software), &[SOFTWARE, Stage::Cpu]);
        assert_eq!(chain(RendererKind::Cpu), &[Stage::Cpu]);
    }

    #[test]
    fn cpu_kind_uses_the_rasterizer_and_cannot_be_failed() {
        let mesh = Arc::new(Mesh {
            positions: vec![[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]],
            gray: vec![1.0; 3],
            uvs: vec![[0.0, 0.0]; 3],
            indices: vec![0, 1, 2],
            groups: vec![crate::map::MeshGroup {
                first_index: 0,
                index_count: 3,
                texture: None,
            }],
            textures: Vec::new(),
        });
        let mut r =
            FallbackRenderer::new(RendererKind::Cpu, Arc::clone(&mesh)).expect("cpu starts");
        assert_eq!(
            Arc::strong_count(&mesh),
            1,
            "the last stage of the chain keeps no reference to the map"
        );
        assert_eq!(r.active_stage(), Stage::Cpu);
        assert_eq!(r.name(), "cpu");
        assert!(!r.inject_failure_after(0), "no GPU renderer to fail");
    }
}
