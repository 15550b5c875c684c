//! Rendering and describing the relocalization database's views (`star
//! reloc build`), on every core, resumable.
//!
//! Takes the map, the camera, the `[reloc]` section, the views
//! ([`super::grid`]: grid positions, trajectory samples, landmark views)
//! and either one renderer or a way to start one per worker; gives out the
//! [`RelocDatabase`]. The views are cut into work units (a grid position
//! with all its yaws and pitches, a trajectory sample with its five views,
//! a landmark view). Units are rendered in batches, each unit by whichever
//! worker takes it (a rayon pool, one renderer and one set of scratch
//! buffers per worker), and their results merged in unit order: the
//! entries and coarse points appended, the landmarks deduplicated in that
//! order, then the vocabulary trained on them. The result depends on
//! neither the thread count nor the batching, byte for byte, as long as
//! every worker's renderer draws the same (the CPU rasterizer does, for any
//! thread count). With a checkpoint ([`super::checkpoint`]), each batch is
//! appended to it as it is done, and a build started again with the same
//! inputs takes the units already there and renders only the rest.
//!
//! On the CPU rasterizer, a grid position's views and each landmark view
//! are first rendered with the far limit cut to twice `min_depth_m`
//! (clearance probes: only the nearby chunks are set up), and a position
//! or view that has geometry nearer than `min_depth_m` (inside or against
//! furniture or a wall) is dropped without a full render. A pixel nearer
//! than the cut has the same depth either way, so the probes drop exactly
//! what the full renders would. The probes draw both sides of every
//! triangle even if the views were to cull back faces: from inside a box
//! only the back of its faces is seen. (`star reloc build` draws both
//! sides everywhere, whatever `[render] cull_back_faces` says.) Each worker counts where its time goes
//! ([`super::build_stats`]).

use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Instant;

use nalgebra::{Translation3, Vector3};
use rayon::prelude::*;

use crate::geometry::look::camera_rotation;
use crate::geometry::{PinholeCamera, Pose};
use crate::map::Mesh;
use crate::render::cpu::CpuRenderer;
use crate::render::{RenderError, RenderedView, Renderer};

use super::build_stats::StageTimes;
use super::checkpoint::{Checkpoint, UnitOutput};
use super::coarse::{CoarseExtractor, CoarsePoint};
use super::config::RelocConfig;
use super::database::{map_fingerprint, RelocDatabase, RelocEntry, FNV_OFFSET};
use super::descriptor::{Descriptor, Thumbnailer};
use super::grid::{
    above_floor, grid_positions, landmark_grid_poses, landmark_positions, sample_along,
    thumb_render_camera, trajectory_views, AlongTrajectory, BuildError,
};
use super::landmarks::{Landmark, LandmarkCollector, LandmarkLifter};
use super::vocabulary::Vocabulary;

/// How a database build runs.
pub struct BuildOptions<'a> {
    /// Worker threads (0: one per core).
    pub threads: usize,
    /// Checkpoint file: resumed from when it holds units of the same build,
    /// appended to after each batch. The caller removes it
    /// ([`Checkpoint::remove`]) once the database is written.
    pub checkpoint: Option<PathBuf>,
    /// Stops (with [`BuildError::Stopped`]) once this many units are done:
    /// an interruption at a known point, for the tests.
    pub stop_after: Option<usize>,
    /// Called with the units done and the total, after each batch.
    pub progress: &'a mut dyn FnMut(usize, usize),
    /// Renders only every `sample_every`-th work unit (1 or 0: all) and
    /// ignores the checkpoint: a quick look at where a build's time would
    /// go ([`StageTimes`]), not a database to keep.
    pub sample_every: usize,
    /// Gets where the time went, summed over the workers.
    pub stage_times: Option<&'a mut StageTimes>,
    /// Far limit of the parallel build's views, meters (`None`: none).
    pub far_m: Option<f64>,
}

/// A work unit.
#[derive(Debug, Clone, Copy)]
enum Unit {
    /// A grid position: all its yaws and pitches at the thumbnail size.
    Position(Vector3<f64>),
    /// A trajectory sample: its five views at the thumbnail size.
    Sample(Pose),
    /// A full-resolution landmark view.
    Landmarks(Pose),
}

/// The units of a build and what they are rendered with.
struct Plan {
    config: RelocConfig,
    units: Vec<Unit>,
    half_yaw_rad: f64,
    half_spacing_m: f64,
    camera: PinholeCamera,
    map_fingerprint: u64,
}

impl Plan {
    fn new(
        mesh: &Mesh,
        camera: &PinholeCamera,
        config: &RelocConfig,
        region: Option<([f32; 3], [f32; 3])>,
        along: &AlongTrajectory,
    ) -> Result<Self, BuildError> {
        let config = above_floor(mesh, config)?;
        let positions = grid_positions(mesh, &config, region)?;
        let half_yaw_rad = std::f64::consts::PI / config.yaw_steps.max(1) as f64;
        let samples = sample_along(&along.poses, along.spacing_m, half_yaw_rad);
        let mut landmark_poses =
            landmark_grid_poses(&config, &landmark_positions(mesh, &config, region));
        if config.landmark_spacing_m > 0.0 {
            landmark_poses.extend(sample_along(
                &along.poses,
                config.landmark_spacing_m,
                std::f64::consts::TAU / config.landmark_yaw_steps.max(1) as f64,
            ));
        }
        let units = positions
            .into_iter()
            .map(Unit::Position)
            .chain(samples.into_iter().map(Unit::Sample))
            .chain(landmark_poses.into_iter().map(Unit::Landmarks))
            .collect();
        Ok(Self {
            config,
            units,
            half_yaw_rad,
            half_spacing_m: 0.5 * along.spacing_m,
            camera: *camera,
            map_fingerprint: map_fingerprint(mesh),
        })
    }

    /// A hash of everything the result depends on, `renderer` naming what
    /// draws the views.
    fn key(&self, renderer: &str) -> u64 {
        let mut h = super::database::fnv1a64(FNV_OFFSET, &super::file::VERSION.to_le_bytes());
        h = super::database::fnv1a64(h, &self.map_fingerprint.to_le_bytes());
        let c = &self.camera;
        let d = &c.distortion;
        h = super::database::fnv1a64(h, &[c.width, c.height].map(u32::to_le_bytes).concat());
        for v in [c.fx, c.fy, c.cx, c.cy, d.k1, d.k2, d.p1, d.p2, d.k3] {
            h = super::database::fnv1a64(h, &v.to_le_bytes());
        }
        let settings = serde_json::to_string(&self.config).unwrap_or_default();
        h = super::database::fnv1a64(h, settings.as_bytes());
        h = super::database::fnv1a64(h, renderer.as_bytes());
        for u in &self.units {
            let (tag, p) = match u {
                Unit::Position(p) => (
                    0u8,
                    Pose::from_parts(Translation3::from(*p), Default::default()),
                ),
                Unit::Sample(p) => (1, *p),
                Unit::Landmarks(p) => (2, *p),
            };
            h = super::database::fnv1a64(h, &[tag]);
            let t = p.translation.vector;
            let q = p.rotation.coords;
            for v in [t.x, t.y, t.z, q[0], q[1], q[2], q[3]] {
                h = super::database::fnv1a64(h, &v.to_le_bytes());
            }
        }
        super::database::fnv1a64(h, &self.half_spacing_m.to_le_bytes())
    }
}

/// One worker's scratch: the views and the describers.
struct Scratch {
    /// Where this worker's time went.
    times: StageTimes,
    thumb_camera: PinholeCamera,
    pinhole: PinholeCamera,
    thumb_view: RenderedView,
    full_view: RenderedView,
    thumbnailer: Thumbnailer,
    coarse: CoarseExtractor,
    lifter: LandmarkLifter,
}

impl Scratch {
    fn new(camera: &PinholeCamera, config: &RelocConfig) -> Self {
        let thumb_camera = thumb_render_camera(camera);
        let pinhole = PinholeCamera {
            distortion: Default::default(),
            ..*camera
        };
        Self {
            times: StageTimes::default(),
            thumb_view: RenderedView::for_camera(&thumb_camera),
            full_view: RenderedView::for_camera(&pinhole),
            thumbnailer: Thumbnailer::new(),
            coarse: CoarseExtractor::new(&thumb_camera),
            lifter: LandmarkLifter::new(&pinhole, config),
            thumb_camera,
            pinhole,
        }
    }

    /// Renders and describes `unit`.
    fn run(
        &mut self,
        renderer: &mut Drawer,
        plan: &Plan,
        unit: &Unit,
    ) -> Result<UnitOutput, BuildError> {
        let config = &plan.config;
        let mut out = UnitOutput::default();
        let n_pixels = (self.thumb_camera.width * self.thumb_camera.height) as f64;
        match unit {
            Unit::Position(p) => {
                if self.too_close(renderer, config, p)? {
                    // Inside or against furniture or a wall: the position
                    // is dropped without a full render.
                    self.times.positions_skipped += 1;
                    return Ok(UnitOutput::default());
                }
                for &pitch_deg in &config.pitches_deg {
                    for yaw_rad in config.yaws_rad() {
                        let world_from_camera = Pose::from_parts(
                            Translation3::from(*p),
                            camera_rotation(yaw_rad, pitch_deg.to_radians(), 0.0),
                        );
                        let seen = self.thumbnail(renderer, &world_from_camera)?;
                        if (seen.nearest_m as f64) < config.min_depth_m {
                            // Inside or against furniture: the whole
                            // position is dropped.
                            return Ok(UnitOutput::default());
                        }
                        if (seen.hits as f64) >= config.min_valid_fraction * n_pixels {
                            self.describe(config, world_from_camera, &mut out);
                        }
                    }
                }
            }
            Unit::Sample(sample) => {
                let views = trajectory_views(sample, plan.half_yaw_rad, plan.half_spacing_m);
                for world_from_camera in views {
                    let seen = self.thumbnail(renderer, &world_from_camera)?;
                    if (seen.nearest_m as f64) >= config.min_depth_m
                        && (seen.hits as f64) >= config.min_valid_fraction * n_pixels
                    {
                        self.describe(config, world_from_camera, &mut out);
                    }
                }
            }
            Unit::Landmarks(world_from_camera) => {
                let t = Instant::now();
                let probe = renderer.probe(
                    world_from_camera,
                    &self.pinhole,
                    &mut self.full_view,
                    2.0 * config.min_depth_m,
                );
                self.times.probe_views += u64::from(probe.is_some());
                self.times.probe_s += t.elapsed().as_secs_f64();
                if let Some(seen) = probe {
                    if (seen?.nearest_m as f64) < config.min_depth_m {
                        self.times.landmarks_skipped += 1;
                        return Ok(out);
                    }
                }
                let t = Instant::now();
                let seen = render_view(
                    renderer,
                    world_from_camera,
                    &self.pinhole,
                    &mut self.full_view,
                )?;
                self.times.landmark_views += 1;
                self.times.render_landmark_s += t.elapsed().as_secs_f64();
                if seen.nearest_m as f64 >= config.min_depth_m {
                    let t = Instant::now();
                    self.lifter.lift(
                        &self.full_view,
                        &self.pinhole,
                        world_from_camera,
                        &mut out.features,
                    );
                    self.times.lift_s += t.elapsed().as_secs_f64();
                }
            }
        }
        Ok(out)
    }

    /// Whether a view of the grid position `p` has geometry nearer than
    /// `min_depth_m`, decided from renders cut at twice that depth (only
    /// the chunks within it are set up): what the full renders would find,
    /// exactly, since a pixel nearer than the cut has the same depth with
    /// and without it. `false` when the renderer cannot cut (then the full
    /// renders decide).
    fn too_close(
        &mut self,
        renderer: &mut Drawer,
        config: &RelocConfig,
        p: &Vector3<f64>,
    ) -> Result<bool, BuildError> {
        let cut_m = 2.0 * config.min_depth_m;
        for &pitch_deg in &config.pitches_deg {
            for yaw_rad in config.yaws_rad() {
                let world_from_camera = Pose::from_parts(
                    Translation3::from(*p),
                    camera_rotation(yaw_rad, pitch_deg.to_radians(), 0.0),
                );
                let t = Instant::now();
                let seen = renderer.probe(
                    &world_from_camera,
                    &self.thumb_camera,
                    &mut self.thumb_view,
                    cut_m,
                );
                self.times.probe_views += 1;
                self.times.probe_s += t.elapsed().as_secs_f64();
                let Some(seen) = seen else {
                    return Ok(false);
                };
                if (seen?.nearest_m as f64) < config.min_depth_m {
                    return Ok(true);
                }
            }
        }
        Ok(false)
    }

    /// Adds the entry of the thumbnail view rendered at `world_from_camera`
    /// (none without contrast).
    /// Renders the thumbnail at `world_from_camera` into the scratch view,
    /// timed as a thumbnail render.
    fn thumbnail(
        &mut self,
        renderer: &mut Drawer,
        world_from_camera: &Pose,
    ) -> Result<Seen, BuildError> {
        let (camera, view) = (&self.thumb_camera, &mut self.thumb_view);
        self.times
            .render_thumb(|| render_view(renderer, world_from_camera, camera, view))
    }

    fn describe(&mut self, config: &RelocConfig, world_from_camera: Pose, out: &mut UnitOutput) {
        let view = &self.thumb_view;
        let (w, h) = (view.gray.width(), view.gray.height());
        let t = Instant::now();
        let described = self.thumbnailer.describe_f32(
            view.gray.data(),
            Some(view.depth_m.data()),
            w,
            h,
            config.min_contrast_gray,
        );
        self.times.describe_s += t.elapsed().as_secs_f64();
        let Some(descriptor) = described else {
            return;
        };
        let t = Instant::now();
        let n = self.coarse.extract(view, &mut out.points) as u32;
        self.times.coarse_s += t.elapsed().as_secs_f64();
        out.entries.push((world_from_camera, descriptor, n));
    }
}

/// What a database view saw of the map.
struct Seen {
    /// Pixels that hit the map.
    hits: usize,
    /// Nearest depth, meters (infinite when nothing was hit).
    nearest_m: f32,
}

/// What a build worker draws the views with.
pub enum Drawer<'a> {
    /// Any renderer (the one-thread build).
    Any(&'a mut dyn Renderer),
    /// The CPU rasterizer, views drawn with the far limit `far_m`; it also
    /// draws the clearance probes ([`Scratch::too_close`]) cut short.
    Cpu {
        /// The rasterizer.
        renderer: &'a mut CpuRenderer,
        /// Far limit of the views, meters (`None`: none).
        far_m: Option<f64>,
    },
}

impl Drawer<'_> {
    /// Renders a database view.
    fn render(
        &mut self,
        world_from_camera: &Pose,
        camera: &PinholeCamera,
        view: &mut RenderedView,
    ) -> Result<(), RenderError> {
        match self {
            Drawer::Any(r) => r.render(world_from_camera, camera, view),
            Drawer::Cpu { renderer, far_m } => {
                renderer.set_far_m(*far_m);
                renderer.render(world_from_camera, camera, view)
            }
        }
    }

    /// Renders only what lies within `cut_m` of the camera (along the
    /// optical axis) and counts it; `None` when this renderer cannot.
    fn probe(
        &mut self,
        world_from_camera: &Pose,
        camera: &PinholeCamera,
        view: &mut RenderedView,
        cut_m: f64,
    ) -> Option<Result<Seen, BuildError>> {
        let Drawer::Cpu { renderer, far_m } = self else {
            return None;
        };
        if far_m.is_some_and(|f| f < cut_m) {
            return None;
        }
        renderer.set_far_m(Some(cut_m));
        // Both sides: a camera inside a box or a wall sees only the back of
        // its faces (`star reloc build` draws both sides everywhere; this
        // holds for any renderer handed in).
        let cull_back_faces = renderer.cull_back_faces();
        renderer.set_cull_back_faces(false);
        let mut cut = Drawer::Any(&mut **renderer);
        let seen = render_view(&mut cut, world_from_camera, camera, view);
        renderer.set_cull_back_faces(cull_back_faces);
        Some(seen)
    }
}

/// Renders `view` at `world_from_camera` and counts what it saw.
fn render_view(
    renderer: &mut Drawer,
    world_from_camera: &Pose,
    camera: &PinholeCamera,
    view: &mut RenderedView,
) -> Result<Seen, BuildError> {
    renderer
        .render(world_from_camera, camera, view)
        .map_err(|source| {
            let p = world_from_camera.translation.vector;
            BuildError::Render {
                position_m: [p.x, p.y, p.z],
                source,
            }
        })?;
    let mut seen = Seen {
        hits: 0,
        nearest_m: f32::INFINITY,
    };
    for &d in view.depth_m.data() {
        if RenderedView::is_hit(d) {
            seen.hits += 1;
            seen.nearest_m = seen.nearest_m.min(d);
        }
    }
    Ok(seen)
}

/// Builds the database for `mesh` seen by `camera`, rendering through
/// `renderer` (which must draw `mesh`). `progress` gets the work units done
/// and the total.
pub fn build_database(
    mesh: &Mesh,
    camera: &PinholeCamera,
    renderer: &mut dyn Renderer,
    config: &RelocConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RelocDatabase, BuildError> {
    build_database_in(mesh, camera, renderer, config, None, progress)
}

/// [`build_database`] with the grid limited to `region` (`[min, max]`
/// corners, world, meters) instead of the mesh bounds.
pub fn build_database_in(
    mesh: &Mesh,
    camera: &PinholeCamera,
    renderer: &mut dyn Renderer,
    config: &RelocConfig,
    region: Option<([f32; 3], [f32; 3])>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RelocDatabase, BuildError> {
    let along = AlongTrajectory::default();
    build_database_along(mesh, camera, renderer, config, region, &along, progress)
}

/// Builds the database for `mesh` seen by `camera` on one thread, rendering
/// through `renderer` (which must draw `mesh`); views on the grid (inside
/// `region`, `[min, max]` corners, when given) and along `along` (see
/// [`super::grid`]). `progress` gets the work units done and the total.
pub fn build_database_along(
    mesh: &Mesh,
    camera: &PinholeCamera,
    renderer: &mut dyn Renderer,
    config: &RelocConfig,
    region: Option<([f32; 3], [f32; 3])>,
    along: &AlongTrajectory,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RelocDatabase, BuildError> {
    let plan = Plan::new(mesh, camera, config, region, along)?;
    let mut scratch = Scratch::new(camera, &plan.config);
    let mut options = BuildOptions {
        threads: 1,
        checkpoint: None,
        stop_after: None,
        progress,
        sample_every: 1,
        stage_times: None,
        far_m: None,
    };
    // One unit per batch: no checkpoint to write, and progress per unit.
    let mut drawer = Drawer::Any(renderer);
    let outputs = run_units(&plan, &mut options, "", 1, &mut |units| {
        units
            .iter()
            .map(|u| scratch.run(&mut drawer, &plan, u))
            .collect()
    })?;
    Ok(assemble(&plan, outputs))
}

/// Builds the database as [`build_database_along`] does, on
/// `options.threads` workers, each rendering through a CPU rasterizer from
/// `make_renderer` (which must draw `mesh`, the same for every worker) with
/// the far limit `options.far_m`; `renderer` names it in the checkpoint's
/// key.
#[allow(clippy::too_many_arguments)]
pub fn build_parallel(
    mesh: &Mesh,
    camera: &PinholeCamera,
    config: &RelocConfig,
    region: Option<([f32; 3], [f32; 3])>,
    along: &AlongTrajectory,
    renderer: &str,
    make_renderer: &(dyn Fn() -> Result<CpuRenderer, RenderError> + Sync),
    mut options: BuildOptions,
) -> Result<RelocDatabase, BuildError> {
    let mut plan = Plan::new(mesh, camera, config, region, along)?;
    if options.sample_every > 1 {
        let every = options.sample_every;
        plan.units = plan.units.into_iter().step_by(every).collect();
        options.checkpoint = None;
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(options.threads)
        .thread_name(|i| format!("star-reloc-build-{i}"))
        .build()
        .map_err(|e| {
            BuildError::RendererStart(RenderError::Backend(format!(
                "cannot start the build threads: {e}"
            )))
        })?;
    let far_m = options.far_m;
    let workers: Mutex<Vec<(CpuRenderer, Scratch)>> = Mutex::new(Vec::new());
    let run_one = |unit: &Unit| -> Result<UnitOutput, BuildError> {
        let taken = workers.lock().ok().and_then(|mut w| w.pop());
        let (mut renderer, mut scratch) = match taken {
            Some(w) => w,
            None => (
                make_renderer().map_err(BuildError::RendererStart)?,
                Scratch::new(camera, &plan.config),
            ),
        };
        let mut drawer = Drawer::Cpu {
            renderer: &mut renderer,
            far_m,
        };
        let out = scratch.run(&mut drawer, &plan, unit);
        if let Ok(mut w) = workers.lock() {
            w.push((renderer, scratch));
        }
        out
    };
    let threads = pool.current_num_threads();
    tracing::info!(
        threads,
        units = plan.units.len(),
        "building the relocalization database"
    );
    let outputs = run_units(&plan, &mut options, renderer, BATCH_UNITS, &mut |units| {
        pool.install(|| units.par_iter().map(run_one).collect())
    });
    let mut times = StageTimes::default();
    if let Ok(w) = workers.lock() {
        for (_, scratch) in w.iter() {
            times.add(&scratch.times);
        }
    }
    tracing::info!(%times, "relocalization database build stages");
    if let Some(out) = options.stage_times {
        *out = times;
    }
    Ok(assemble(&plan, outputs?))
}

/// Renders a batch of units, giving their outputs in order.
type RunBatch<'a> = dyn FnMut(&[Unit]) -> Result<Vec<UnitOutput>, BuildError> + 'a;

/// Work units per batch of the parallel build (per checkpoint record).
const BATCH_UNITS: usize = 64;

/// Runs the plan's units `batch_units` at a time through `run_batch`,
/// resuming from and appending to the checkpoint when there is one.
fn run_units(
    plan: &Plan,
    options: &mut BuildOptions,
    renderer: &str,
    batch_units: usize,
    run_batch: &mut RunBatch,
) -> Result<Vec<UnitOutput>, BuildError> {
    let total = plan.units.len();
    let (mut checkpoint, mut outputs) = match &options.checkpoint {
        Some(path) => {
            let (c, done) = Checkpoint::open(path, plan.key(renderer), total)?;
            (Some(c), done)
        }
        None => (None, Vec::new()),
    };
    (options.progress)(outputs.len(), total);
    while outputs.len() < total {
        let start = outputs.len();
        let mut end = (start + batch_units.max(1)).min(total);
        if let Some(stop) = options.stop_after {
            if start >= stop {
                return Err(BuildError::Stopped { done: start, total });
            }
            end = end.min(stop);
        }
        let done = run_batch(&plan.units[start..end])?;
        if let Some(c) = &mut checkpoint {
            c.append(start, &done)?;
        }
        outputs.extend(done);
        (options.progress)(outputs.len(), total);
    }
    Ok(outputs)
}

/// The database from the units' outputs, in unit order.
fn assemble(plan: &Plan, outputs: Vec<UnitOutput>) -> RelocDatabase {
    let mut entries = Vec::new();
    let mut points: Vec<CoarsePoint> = Vec::new();
    let mut collector = LandmarkCollector::default();
    for o in outputs {
        let mut at = points.len();
        for (world_from_camera, descriptor, n) in o.entries {
            entries.push(RelocEntry {
                world_from_camera,
                descriptor,
                coarse_start: at as u32,
                coarse_len: n,
            });
            at += n as usize;
        }
        points.extend(o.points);
        for f in o.features {
            collector.insert(f);
        }
    }
    let (landmarks, vocabulary) = organize(collector.finish());
    RelocDatabase {
        camera: plan.camera,
        map_fingerprint: plan.map_fingerprint,
        entries,
        coarse_points: points.into_iter().collect(),
        landmarks,
        vocabulary,
        path: PathBuf::new(),
    }
}

/// The landmarks' vocabulary, and the landmarks sorted leaf after leaf
/// (in their order within a leaf).
pub fn organize(landmarks: Vec<Landmark>) -> (Vec<Landmark>, Vocabulary) {
    let descriptors: Vec<Descriptor> = landmarks.iter().map(|l| l.descriptor).collect();
    let (vocabulary, leaf_of) = Vocabulary::train(&descriptors);
    let mut order: Vec<usize> = (0..landmarks.len()).collect();
    order.sort_by_key(|&i| leaf_of[i]);
    (order.iter().map(|&i| landmarks[i]).collect(), vocabulary)
}
