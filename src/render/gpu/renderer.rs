//! [`GpuRenderer`]: device set-up, the pipeline, and the per-keyframe
//! render, copy and readback.
//!
//! Takes the mesh once and a pose plus intrinsics per render; gives out gray
//! and metric depth. Per render it tests the mesh chunks against the view
//! frustum, writes one uniform, records one render pass (one draw call per
//! run of adjacent visible chunks of one texture) and two copies, and maps
//! one staging buffer; every buffer and texture is allocated at
//! construction or when the image size changes, the draw list keeps its
//! capacity.
//!
//! With the occlusion cull (the default, on a resident mesh) the view is
//! drawn in two or three passes, the depth read back between them
//! (`super::occlusion`); the first pass then waits for the device.
//!
//! A mesh streamed under a GPU budget (`super::stream`) draws one call per
//! visible chunk from its slot, after uploading the chunks not resident.
//! When a view needs more chunks than the pool has slots, it is drawn in
//! several passes of at most that many chunks, in index-buffer order, each
//! submitted before the next one's uploads; later passes load the color
//! targets and the z-buffer instead of clearing them, so the image is the
//! one a single pass would give (same triangles, same order).

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::adapter::{self, AdapterClass, AdapterPreference};
use super::cull_timing::{CullDecision, CullTiming};
use super::draws::{self, Draw};
use super::frame::{FrameTargets, MapStatus};
use super::occlusion::{BoxView, GpuOcclusion, OcclusionStats};
use super::pass::{record_pass, PassInputs};
use super::pipeline;
use super::projection::{ViewUniform, NEAR_M, VIEW_UNIFORM_BYTES};
use super::stream::StreamStats;
use super::upload::{self, Geometry, GpuMesh, TextureFormat};
use super::GpuError;
use crate::geometry::{PinholeCamera, Pose};
use crate::map::Mesh;
use crate::render::chunks::{self, CullStats};
use crate::render::frustum::Frustum;
use crate::render::lod::LodView;
use crate::render::{check_request, RenderError, RenderedView, Renderer};

/// How long a render may take before it counts as a device failure.
const RENDER_TIMEOUT: Duration = Duration::from_secs(20);

/// The first error the device reported, shared with its error callbacks.
type Fault = Arc<Mutex<Option<String>>>;

fn record_fault(fault: &Fault, message: String) {
    let mut slot = fault.lock().unwrap_or_else(|p| p.into_inner());
    if slot.is_none() {
        *slot = Some(message);
    }
}

/// A render submitted with [`GpuRenderer::submit`], to be collected with
/// [`GpuRenderer::collect`].
#[must_use = "a submitted render holds a readback buffer until collected"]
#[derive(Debug)]
pub struct PendingRender {
    slot: usize,
    submission: wgpu::SubmissionIndex,
    /// Its number among the renderer's renders.
    render: u64,
}

/// Device memory of a [`GpuRenderer`], bytes, as allocated (the driver's
/// own overhead and alignment are not counted).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GpuMemory {
    /// Vertex and index buffers of the mesh: the whole mesh, or the chunk
    /// slot pool when it streams under a budget.
    pub mesh_buffer_bytes: u64,
    /// Mesh textures (and the 1x1 white texel).
    pub texture_bytes: u64,
    /// Render targets, z-buffer and readback staging buffers.
    pub target_bytes: u64,
}

impl GpuMemory {
    /// Everything.
    pub fn total_bytes(&self) -> u64 {
        self.mesh_buffer_bytes + self.texture_bytes + self.target_bytes
    }
}

/// The wgpu renderer. See the [module docs](super).
#[derive(Debug)]
pub struct GpuRenderer {
    info: wgpu::AdapterInfo,
    texture_format: TextureFormat,
    class: AdapterClass,
    device: wgpu::Device,
    queue: wgpu::Queue,
    /// The keyframe pipeline drawing both sides of every triangle.
    pipeline: wgpu::RenderPipeline,
    /// The same, culling back faces ([`GpuRenderer::set_cull_back_faces`]).
    pipeline_front_only: wgpu::RenderPipeline,
    /// Whether back faces are culled (off by default).
    cull_back_faces: bool,
    view_uniform: wgpu::Buffer,
    view_group: wgpu::BindGroup,
    mesh: GpuMesh,
    /// Whether each chunk passed the frustum test in the current render.
    visible: Vec<bool>,
    /// The current render's draw calls (of one pass, when streaming).
    draws: Vec<Draw>,
    /// The current render's visible chunks, when streaming.
    wanted: Vec<u32>,
    /// Render passes recorded since start.
    passes: u64,
    /// Whether the warning about views drawn in several passes was given.
    warned_multi_pass: bool,
    /// Whether chunks outside the frustum are skipped (on by default).
    cull: bool,
    /// Whether clusters hidden behind what earlier passes drew are skipped
    /// (on by default; with the frustum cull, on a resident mesh).
    occlusion_cull: bool,
    /// When set, `occlusion_cull` is chosen render by render by timing
    /// both ways ([`GpuRenderer::set_occlusion_timed`]).
    cull_timing: Option<CullTiming>,
    /// Counts of the last render's frustum test.
    stats: CullStats,
    /// Far limit along the optical axis, meters; `None`: none.
    far_m: Option<f64>,
    frame: Option<FrameTargets>,
    max_dimension: u32,
    fault: Fault,
    renders: u64,
    fail_at: Option<u64>,
    /// The mesh's appearance spacing, meters, told with every view.
    detail_m: f32,
    /// Largest level-of-detail cell on the image, pixels (0: full detail).
    lod_max_px: f32,
}

/// How a [`GpuRenderer`] is built.
#[derive(Debug, Clone, Copy, Default)]
struct Options {
    /// Store textures as `R8Unorm` even where `R32Float` filters.
    force_unorm8: bool,
    /// Mesh budget, bytes (0: none).
    gpu_budget_bytes: u64,
    /// Level-of-detail cells up to this many pixels (0: full detail).
    lod_max_px: f32,
}

impl GpuRenderer {
    /// Opens a device on the best adapter of class `which`, uploads `mesh`
    /// and builds the pipeline. Logs the adapter chosen.
    pub fn new(mesh: Arc<Mesh>, which: AdapterPreference) -> Result<Self, GpuError> {
        Self::new_on(mesh, which, adapter::BACKENDS)
    }

    /// As [`GpuRenderer::new`], with the mesh's vertex and index data
    /// bounded by `gpu_budget_bytes` (0: no budget; see
    /// [`crate::render::RenderConfig::gpu_budget_mb`]): a mesh larger than
    /// that streams its chunks through a pool of slots of that size.
    /// Fails with [`GpuError::BudgetTooSmall`] when the budget cannot hold
    /// the largest chunk.
    pub fn new_with_budget(
        mesh: Arc<Mesh>,
        which: AdapterPreference,
        gpu_budget_bytes: u64,
    ) -> Result<Self, GpuError> {
        Self::new_configured(mesh, which, gpu_budget_bytes, 0.0)
    }

    /// As [`GpuRenderer::new_with_budget`], drawing chunks at a coarser
    /// level of detail where its error spans at most
    /// `lod_max_px` pixels (0: full detail; see [`crate::render::lod`] and
    /// [`crate::render::RenderConfig::lod_max_px`]).
    pub fn new_configured(
        mesh: Arc<Mesh>,
        which: AdapterPreference,
        gpu_budget_bytes: u64,
        lod_max_px: f32,
    ) -> Result<Self, GpuError> {
        let options = Options {
            force_unorm8: false,
            gpu_budget_bytes,
            lod_max_px,
        };
        Self::build(mesh, which, adapter::BACKENDS, options)
    }

    /// As [`GpuRenderer::new`], restricted to `backends` (e.g. to compare
    /// lavapipe through Vulkan with llvmpipe through GL).
    pub fn new_on(
        mesh: Arc<Mesh>,
        which: AdapterPreference,
        backends: wgpu::Backends,
    ) -> Result<Self, GpuError> {
        Self::build(mesh, which, backends, Options::default())
    }

    /// Test hook: as [`GpuRenderer::new`], but stores textures as `R8Unorm`
    /// even where `R32Float` is filterable, to test the fallback format.
    #[doc(hidden)]
    pub fn new_with_unorm8_textures(
        mesh: Arc<Mesh>,
        which: AdapterPreference,
    ) -> Result<Self, GpuError> {
        let options = Options {
            force_unorm8: true,
            ..Options::default()
        };
        Self::build(mesh, which, adapter::BACKENDS, options)
    }

    fn build(
        mesh: Arc<Mesh>,
        which: AdapterPreference,
        backends: wgpu::Backends,
        options: Options,
    ) -> Result<Self, GpuError> {
        let mut seen = Vec::new();
        // One backend at a time: GL (and its EGL probing) only when no
        // Vulkan adapter of the class works.
        for backend in adapter::BACKEND_ORDER {
            if !backends.contains(backend) {
                continue;
            }
            for candidate in adapter::enumerate(&adapter::new_instance(backend)) {
                let info = candidate.get_info();
                let class = adapter::classify(&info);
                if class != which.class() {
                    seen.push(format!("{} ({:?}): {class:?}", info.name, info.backend));
                    continue;
                }
                match Self::on_adapter(&candidate, &mesh, options) {
                    Ok(renderer) => {
                        tracing::info!(
                            adapter = %info.name,
                            backend = ?info.backend,
                            device_type = ?info.device_type,
                            driver = %info.driver,
                            class = %which,
                            "wgpu renderer ready"
                        );
                        return Ok(renderer);
                    }
                    // Invalid meshes and budgets fail on every adapter:
                    // report at once.
                    Err(e @ (GpuError::Mesh(_) | GpuError::BudgetTooSmall { .. })) => {
                        return Err(e)
                    }
                    Err(e) => {
                        tracing::warn!(adapter = %info.name, error = %e, "wgpu adapter unusable");
                        seen.push(format!("{} ({:?}): {e}", info.name, info.backend));
                    }
                }
            }
        }
        Err(GpuError::NoAdapter {
            preference: which,
            seen: if seen.is_empty() {
                "none".into()
            } else {
                seen.join("; ")
            },
        })
    }

    fn on_adapter(
        adapter: &wgpu::Adapter,
        mesh: &Mesh,
        options: Options,
    ) -> Result<Self, GpuError> {
        let Options {
            force_unorm8,
            gpu_budget_bytes,
            lod_max_px,
        } = options;
        let info = adapter.get_info();
        let limits = adapter.limits();
        let texture_format = if force_unorm8 {
            TextureFormat::Unorm8
        } else {
            TextureFormat::for_features(adapter.features())
        };
        let required_features = match texture_format {
            TextureFormat::Float32 => wgpu::Features::FLOAT32_FILTERABLE,
            TextureFormat::Unorm8 => wgpu::Features::empty(),
        };
        let lod_max_px = crate::render::lod::cell_limit_px(lod_max_px);
        let (chunked, plan) = upload::validate(mesh, &limits, gpu_budget_bytes, lod_max_px > 0.0)?;
        let detail_m = chunked.detail_m;
        let device_error = |message: String| GpuError::Device {
            adapter: info.name.clone(),
            message,
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("star keyframe renderer"),
            required_features,
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| device_error(e.to_string()))?;

        let fault: Fault = Arc::default();
        let on_error = Arc::clone(&fault);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            record_fault(&on_error, e.to_string());
        }));
        let on_lost = Arc::clone(&fault);
        device.set_device_lost_callback(move |reason, message| {
            record_fault(&on_lost, format!("device lost ({reason:?}): {message}"));
        });

        let view_layout = pipeline::view_layout(&device);
        let texture_layout = upload::texture_layout(&device);
        let view_uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("star view uniform"),
            size: VIEW_UNIFORM_BYTES,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let view_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("star view"),
            layout: &view_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: view_uniform.as_entire_binding(),
            }],
        });
        let pipeline = pipeline::create(&device, &view_layout, &texture_layout, false);
        let pipeline_front_only = pipeline::create(&device, &view_layout, &texture_layout, true);
        let gpu_mesh = upload::upload(
            &device,
            &queue,
            &texture_layout,
            texture_format,
            mesh,
            chunked,
            plan,
        );
        if let Some(message) = fault.lock().unwrap_or_else(|p| p.into_inner()).take() {
            return Err(device_error(message));
        }
        tracing::info!(
            adapter = %info.name,
            ?texture_format,
            buffer_mb = gpu_mesh.buffer_bytes as f64 / 1e6,
            texture_mb = gpu_mesh.texture_bytes as f64 / 1e6,
            chunks = gpu_mesh.lod.fine_chunks,
            coarse_chunks = gpu_mesh.lod.coarse_chunks(),
            streams = plan.is_some(),
            budget_mb = gpu_budget_bytes as f64 / 1e6,
            slots = plan.map_or(0, |p| p.slots),
            slot_kb = plan.map_or(0.0, |p| p.slot_bytes() as f64 / 1e3),
            whole_mesh_mb = gpu_mesh.resident_bytes as f64 / 1e6,
            "mesh uploaded to the device"
        );
        Ok(Self {
            texture_format,
            class: adapter::classify(&info),
            max_dimension: limits.max_texture_dimension_2d,
            info,
            device,
            queue,
            pipeline,
            pipeline_front_only,
            cull_back_faces: false,
            view_uniform,
            view_group,
            visible: Vec::with_capacity(gpu_mesh.chunks.len()),
            draws: Vec::with_capacity(gpu_mesh.chunks.len()),
            wanted: Vec::with_capacity(gpu_mesh.chunks.len()),
            passes: 0,
            warned_multi_pass: false,
            mesh: gpu_mesh,
            cull: true,
            occlusion_cull: true,
            cull_timing: None,
            stats: CullStats::default(),
            far_m: None,
            frame: None,
            fault,
            renders: 0,
            fail_at: None,
            detail_m,
            lod_max_px,
        })
    }

    /// What the driver reports about the adapter in use.
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.info
    }

    /// How mesh textures are stored on this adapter.
    pub fn texture_format(&self) -> TextureFormat {
        self.texture_format
    }

    /// Whether the adapter is a hardware GPU or a software rasterizer.
    pub fn class(&self) -> AdapterClass {
        self.class
    }

    /// Turns the skipping of chunks outside the view frustum on (the
    /// default) or off (every chunk drawn; for tests and benchmarks).
    pub fn set_frustum_cull(&mut self, on: bool) {
        self.cull = on;
    }

    /// Culls back faces (triangles clockwise on the image) when `on`; off
    /// by default, every triangle drawn from both sides. For a map whose
    /// triangles are all counter-clockwise seen from where they can be
    /// seen (`[render] cull_back_faces`).
    pub fn set_cull_back_faces(&mut self, on: bool) {
        self.cull_back_faces = on;
        if let Some(occlusion) = self.mesh.occlusion.as_mut() {
            occlusion.set_cull_back_faces(on);
        }
    }

    /// Turns the occlusion cull on (the default) or off. It works with the
    /// frustum cull, on a mesh resident on the device (a streamed one is
    /// drawn with the frustum cull only); see `super::occlusion`.
    pub fn set_occlusion_cull(&mut self, on: bool) {
        self.occlusion_cull = on;
        self.cull_timing = None;
    }

    /// Uses the occlusion cull where it makes renders faster on this
    /// device: renders are timed with it and with the frustum cull alone,
    /// in short blocks, and the faster is kept until the next trial
    /// (`super::cull_timing`). The image is the same either way. Only a
    /// resident mesh has the cull; a streamed one is left as it is.
    pub fn set_occlusion_timed(&mut self) {
        if self.mesh.occlusion.is_some() {
            self.occlusion_cull = true;
            self.cull_timing = Some(CullTiming::new());
        }
    }

    /// The last timed choice of the occlusion cull
    /// ([`GpuRenderer::set_occlusion_timed`]), once a trial has finished.
    pub fn cull_decision(&self) -> Option<CullDecision> {
        self.cull_timing
            .as_ref()
            .and_then(CullTiming::last_decision)
    }

    /// Counts of the occlusion cull since start (all zero when it never
    /// ran).
    pub fn occlusion_stats(&self) -> OcclusionStats {
        self.mesh
            .occlusion
            .as_ref()
            .map_or_else(OcclusionStats::default, GpuOcclusion::stats)
    }

    /// Chunk and triangle counts of the last render's frustum test.
    pub fn cull_stats(&self) -> CullStats {
        self.stats
    }

    /// Sets the far limit (`None`, the default: none): the far clip plane
    /// of the projection, and chunks wholly beyond it are not drawn.
    pub fn set_far_m(&mut self, far_m: Option<f64>) {
        self.far_m = far_m.filter(|f| f.is_finite() && *f > NEAR_M);
    }

    /// Sets the largest level-of-detail cell on the image, pixels (0: full
    /// detail). Only a renderer built ([`GpuRenderer::new_configured`])
    /// with a positive size has coarse chunks to choose from.
    pub fn set_lod_max_px(&mut self, lod_max_px: f32) {
        self.lod_max_px = crate::render::lod::cell_limit_px(lod_max_px);
    }

    /// Device memory the renderer has allocated: the mesh (vertex and
    /// index buffers, textures) and, once a render has sized them, the
    /// render targets and readback buffers.
    pub fn memory(&self) -> GpuMemory {
        GpuMemory {
            mesh_buffer_bytes: self.mesh.buffer_bytes,
            texture_bytes: self.mesh.texture_bytes,
            target_bytes: self.frame.as_ref().map_or(0, FrameTargets::bytes),
        }
    }

    /// Streaming counts since start: the slot pool's size (0 slots when the
    /// whole mesh is resident), renders, passes, chunk uploads and
    /// evictions.
    pub fn stream_stats(&self) -> StreamStats {
        let mut stats = StreamStats {
            renders: self.renders,
            passes: self.passes,
            ..StreamStats::default()
        };
        if let Geometry::Streamed(pool) = &self.mesh.geometry {
            let plan = pool.plan();
            (stats.slots, stats.slot_bytes) = (plan.slots, plan.slot_bytes());
            (stats.uploads, stats.evictions) = pool.counts();
        }
        stats
    }

    /// Test hook: the next `n` renders succeed, every later one fails with
    /// [`GpuError::Injected`], as a lost device would.
    #[doc(hidden)]
    pub fn inject_failure_after(&mut self, n: u64) {
        self.fail_at = Some(self.renders + n);
    }

    fn check_fault(&self) -> Result<(), GpuError> {
        match self
            .fault
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .as_ref()
        {
            Some(message) => Err(GpuError::Device {
                adapter: self.info.name.clone(),
                message: message.clone(),
            }),
            None => Ok(()),
        }
    }

    /// Records and submits a render of `camera` (distortion ignored) at
    /// `world_from_camera`, and starts its readback. Up to two renders may be
    /// pending; collect each with [`GpuRenderer::collect`].
    pub fn submit(
        &mut self,
        world_from_camera: &Pose,
        camera: &PinholeCamera,
    ) -> Result<PendingRender, GpuError> {
        self.check_fault()?;
        if let Some(at) = self.fail_at {
            if self.renders >= at {
                return Err(GpuError::Injected {
                    renders: self.renders,
                });
            }
        }
        let (w, h) = (camera.width, camera.height);
        if w == 0 || h == 0 || w > self.max_dimension || h > self.max_dimension {
            return Err(GpuError::TargetSize {
                width: w,
                height: h,
                max_dimension: self.max_dimension,
            });
        }
        let frustum =
            Frustum::new(world_from_camera, camera, NEAR_M).with_far(world_from_camera, self.far_m);
        let frustum = self.cull.then_some(&frustum);
        let lod = LodView::new(world_from_camera, camera, self.lod_max_px);
        let lod = lod.as_ref();
        let frame = match self.frame.take() {
            Some(f) if f.size() == (w, h) => f,
            Some(f) if f.any_busy() => {
                self.frame = Some(f);
                return Err(GpuError::Busy);
            }
            _ => FrameTargets::new(&self.device, w, h),
        };
        let frame = self.frame.insert(frame);
        let slot = frame.free_slot().ok_or(GpuError::Busy)?;

        let view = ViewUniform::new(world_from_camera, camera, NEAR_M, self.far_m);
        self.queue
            .write_buffer(&self.view_uniform, 0, bytemuck::bytes_of(&view));
        let new_encoder = || {
            self.device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("star keyframe"),
                })
        };
        let render = self.renders;
        let keyframe_pipeline = if self.cull_back_faces {
            &self.pipeline_front_only
        } else {
            &self.pipeline
        };
        let occlusion = match (&mut self.mesh.occlusion, frustum) {
            (Some(occ), Some(frustum)) if self.occlusion_cull => Some((occ, frustum)),
            (Some(occ), _) => {
                occ.forget();
                None
            }
            (None, _) => None,
        };
        let submission = match &mut self.mesh.geometry {
            Geometry::Resident { vertices, indices } => {
                let inputs = PassInputs {
                    pipeline: keyframe_pipeline,
                    view_group: &self.view_group,
                    texture_groups: &self.mesh.texture_groups,
                    vertices,
                    indices,
                };
                match occlusion {
                    Some((occ, frustum)) => {
                        self.stats = chunks::mark_visible(
                            &self.mesh.chunks,
                            &self.mesh.lod,
                            lod,
                            Some(frustum),
                            &mut self.visible,
                        );
                        let t = world_from_camera.translation.vector;
                        let view = BoxView::new(world_from_camera, camera, NEAR_M);
                        occ.begin(
                            render,
                            (&view, frustum, [t.x, t.y, t.z]),
                            &self.visible,
                            &mut self.draws,
                        );
                        let mut first = true;
                        loop {
                            let last = !occ.more();
                            if self.draws.is_empty() && !last {
                                // Nothing to draw before the test: it would
                                // hide nothing.
                                occ.clear_tiles();
                                occ.next_pass(&mut self.draws);
                                continue;
                            }
                            let mut encoder = new_encoder();
                            record_pass(&mut encoder, frame, &inputs, &self.draws, first, last);
                            first = false;
                            self.passes += 1;
                            if last {
                                frame.record_copies(&mut encoder, slot);
                                break self.queue.submit([encoder.finish()]);
                            }
                            frame.record_probe_copy(&mut encoder);
                            let submission = self.queue.submit([encoder.finish()]);
                            frame.request_probe_map();
                            let waited = self.device.poll(wgpu::PollType::Wait {
                                submission_index: Some(submission),
                                timeout: Some(RENDER_TIMEOUT),
                            });
                            let width = w as usize;
                            let read = frame.read_probe(|rows| occ.fill_tiles(rows, width));
                            if waited.is_err() {
                                return Err(GpuError::Timeout {
                                    adapter: self.info.name.clone(),
                                    waited_secs: RENDER_TIMEOUT.as_secs(),
                                });
                            }
                            if !read {
                                return Err(GpuError::MapFailed {
                                    adapter: self.info.name.clone(),
                                });
                            }
                            occ.next_pass(&mut self.draws);
                        }
                    }
                    None => {
                        self.stats = draws::select(
                            (&self.mesh.chunks, &self.mesh.lod),
                            &self.mesh.chunk_texture,
                            (lod, frustum),
                            &mut self.visible,
                            &mut self.draws,
                        );
                        let mut encoder = new_encoder();
                        record_pass(&mut encoder, frame, &inputs, &self.draws, true, true);
                        frame.record_copies(&mut encoder, slot);
                        self.passes += 1;
                        self.queue.submit([encoder.finish()])
                    }
                }
            }
            Geometry::Streamed(pool) => {
                self.stats = draws::visible_chunks(
                    (&self.mesh.chunks, &self.mesh.lod),
                    &self.mesh.chunk_texture,
                    (lod, frustum),
                    &mut self.visible,
                    &mut self.wanted,
                );
                let per_pass = pool.plan().slots.max(1);
                let passes = self.wanted.len().div_ceil(per_pass).max(1);
                if passes > 1 && !self.warned_multi_pass {
                    self.warned_multi_pass = true;
                    tracing::warn!(
                        visible_chunks = self.wanted.len(),
                        slots = per_pass,
                        passes,
                        "a view needs more mesh chunks than render.gpu_budget_mb holds: \
                         drawn in several passes, uploading chunks again each render \
                         (same image, slower; a larger budget avoids it)"
                    );
                }
                let mut pass = 0;
                loop {
                    let start = pass * per_pass;
                    let end = (start + per_pass).min(self.wanted.len());
                    let batch = self.wanted.get(start..end).unwrap_or(&[]);
                    // Uploads land before the next submit, after the
                    // previous pass's.
                    pool.load(
                        &self.queue,
                        &self.mesh.chunks,
                        &self.mesh.chunk_texture,
                        batch,
                        &mut self.draws,
                    );
                    let inputs = PassInputs {
                        pipeline: keyframe_pipeline,
                        view_group: &self.view_group,
                        texture_groups: &self.mesh.texture_groups,
                        vertices: &pool.vertices,
                        indices: &pool.indices,
                    };
                    let last = pass + 1 == passes;
                    let mut encoder = new_encoder();
                    record_pass(&mut encoder, frame, &inputs, &self.draws, pass == 0, last);
                    if last {
                        frame.record_copies(&mut encoder, slot);
                    }
                    self.passes += 1;
                    let submission = self.queue.submit([encoder.finish()]);
                    pass += 1;
                    if last {
                        break submission;
                    }
                }
            }
        };
        frame.request_map(slot);
        self.renders += 1;
        Ok(PendingRender {
            slot,
            submission,
            render,
        })
    }

    /// Waits for a submitted render and copies it into `out`, which must be
    /// sized for the camera it was submitted with.
    pub fn collect(
        &mut self,
        pending: PendingRender,
        out: &mut RenderedView,
    ) -> Result<(), GpuError> {
        let adapter = || self.info.name.clone();
        let Some(frame) = self.frame.as_mut() else {
            return Err(GpuError::MapFailed { adapter: adapter() });
        };
        let (w, h) = frame.size();
        if (out.gray.width(), out.gray.height()) != (w as usize, h as usize)
            || (out.depth_m.width(), out.depth_m.height()) != (w as usize, h as usize)
        {
            frame.release(pending.slot);
            return Err(GpuError::TargetSize {
                width: out.gray.width() as u32,
                height: out.gray.height() as u32,
                max_dimension: self.max_dimension,
            });
        }
        out.detail_m = self.detail_m;
        // The map callback runs inside poll once the copy has completed.
        for _ in 0..2 {
            match frame.status(pending.slot) {
                MapStatus::Mapped => break,
                MapStatus::Failed => {
                    frame.release(pending.slot);
                    return Err(GpuError::MapFailed { adapter: adapter() });
                }
                MapStatus::Pending => {}
            }
            let waited = self.device.poll(wgpu::PollType::Wait {
                submission_index: Some(pending.submission.clone()),
                timeout: Some(RENDER_TIMEOUT),
            });
            if waited.is_err() {
                frame.release(pending.slot);
                return Err(GpuError::Timeout {
                    adapter: adapter(),
                    waited_secs: RENDER_TIMEOUT.as_secs(),
                });
            }
        }
        if frame.status(pending.slot) != MapStatus::Mapped {
            frame.release(pending.slot);
            return Err(GpuError::MapFailed { adapter: adapter() });
        }
        let unpacked = frame.unpack(pending.slot, out);
        self.check_fault()?;
        if let Some(occ) = self.mesh.occlusion.as_mut() {
            if unpacked && occ.drawing(pending.render) {
                let width = w as usize;
                let mut rows = out.depth_m.data().chunks_exact(width.max(1));
                occ.fill_tiles(&mut rows, width);
                occ.finish(pending.render);
            }
        }
        if unpacked {
            Ok(())
        } else {
            Err(GpuError::MapFailed { adapter: adapter() })
        }
    }
}

impl Renderer for GpuRenderer {
    fn name(&self) -> String {
        format!("wgpu: {} ({:?})", self.info.name, self.info.backend)
    }

    fn set_cull_back_faces(&mut self, on: bool) {
        GpuRenderer::set_cull_back_faces(self, on);
    }

    fn cull_back_faces(&self) -> bool {
        self.cull_back_faces
    }

    fn set_far_m(&mut self, far_m: Option<f64>) {
        GpuRenderer::set_far_m(self, far_m);
    }

    fn far_m(&self) -> Option<f64> {
        self.far_m
    }

    fn render(
        &mut self,
        world_from_camera: &Pose,
        camera: &PinholeCamera,
        out: &mut RenderedView,
    ) -> Result<(), RenderError> {
        check_request(world_from_camera, camera)?;
        out.check_size(camera)?;
        let timed = self.cull_timing.as_ref().map(CullTiming::next_uses_cull);
        if let Some(on) = timed {
            self.occlusion_cull = on;
        }
        let start = Instant::now();
        let pending = self.submit(world_from_camera, camera)?;
        self.collect(pending, out)?;
        if let (Some(on), Some(timing)) = (timed, self.cull_timing.as_mut()) {
            if let Some(d) = timing.record(on, start.elapsed().as_secs_f64()) {
                tracing::info!(
                    occlusion_cull = d.occlusion,
                    with_cull_ms = d.with_cull_s * 1e3,
                    frustum_only_ms = d.frustum_only_s * 1e3,
                    trial = timing.trials(),
                    "occlusion cull timed on this device"
                );
            }
        }
        Ok(())
    }
}
