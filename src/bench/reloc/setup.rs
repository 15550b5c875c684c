//! The bench's fixed parts: the map and its database, where the queries
//! come from (the realistic scene of a seed, rendered, or the frames of an
//! existing dataset), the candidate renderer the service would use, and
//! the buffers the queries and candidates reuse.

use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};

use crate::config::Config;
use crate::dataset::{Dataset, Trajectory};
use crate::geometry::PinholeCamera;
use crate::imgproc::{ImageF32, ImageU8};
use crate::reloc::local_contrast::LocalContrast;
use crate::reloc::{build_parallel, BuildOptions, RelocDatabase, Relocalizer};
use crate::render::cpu::CpuRenderer;
use crate::render::{RenderedView, Renderer};
use crate::synth::corrupt::{DistortionWarp, SensorModel};
use crate::synth::preset::Preset;
use crate::synth::sequence::preset_scene;
use crate::synth::Scene;
use crate::track::{Aligner, Keyframe, Pyramid, TrackerConfig};

/// Where the queries come from.
// Built once per bench run; the synthetic side is boxed only so that the
// two stay near in size.
#[allow(clippy::large_enum_variant)]
pub(super) enum Queries {
    /// Random free poses of a synthetic scene, rendered.
    Synthetic(Box<Synthetic>),
    /// Random frames of a dataset with ground truth (one pose per frame).
    Dataset {
        dataset: Dataset,
        truth: Trajectory,
        /// PNG decoding scratch.
        scratch: Vec<u8>,
    },
}

/// The synthetic scene the queries are rendered from.
pub(super) struct Synthetic {
    pub(super) scene: Scene,
    /// Renders the queries from the truth mesh.
    pub(super) truth_r: CpuRenderer,
    pub(super) warp: DistortionWarp,
    pub(super) render_camera: PinholeCamera,
    pub(super) sensor: SensorModel,
    pub(super) qview: RenderedView,
    pub(super) warped: ImageF32,
    /// Query heights, the database's.
    pub(super) z_range_m: (f64, f64),
    /// Query pitch: the middle of the database's pitches.
    pub(super) pitch_mid_deg: f64,
    /// `STAR_BENCH_ROLL_DEG`.
    pub(super) max_roll_deg: Option<f64>,
}

/// Everything the queries run against.
pub(super) struct Bench {
    pub(super) config: Config,
    pub(super) camera: PinholeCamera,
    pub(super) db: RelocDatabase,
    pub(super) reloc: Relocalizer,
    /// Renders the candidates: the configured `[render] renderer`.
    pub(super) candidate_r: Box<dyn Renderer>,
    pub(super) queries: Queries,
    pub(super) frame: ImageU8,
    pub(super) pinhole: PinholeCamera,
    /// As the STAR loop builds keyframes: one pyramid level more than tracking.
    pub(super) tracker: TrackerConfig,
    pub(super) kview: RenderedView,
    /// Keyframes for a candidate and each of its re-renders (recycled ones
    /// come back only after the candidate is done); boxed, as
    /// `try_candidate` hands them over.
    #[allow(clippy::vec_box)]
    pub(super) spare: Vec<Box<Keyframe>>,
    #[allow(clippy::vec_box)]
    pub(super) returned: Vec<Box<Keyframe>>,
    pub(super) aligners: [Aligner; 2],
    pub(super) pyramid: Pyramid,
    /// `STAR_BENCH_NORMALIZE_PX`: candidates are aligned on locally
    /// normalized images ([`LocalContrast`]); the frame's such pyramid.
    pub(super) contrast: Option<(LocalContrast, Pyramid)>,
    /// `STAR_BENCH_NORMALIZE_GATE=plain`: a pose found on local contrast
    /// is judged on the plain images.
    pub(super) judge_plain: bool,
    /// Whether an accepted pose's rivals at other places are verified
    /// ([`crate::reloc::rivals`]; off with `STAR_BENCH_NO_RIVALS`).
    pub(super) check_rivals: bool,
    /// Whether each query's landmark search is compared with brute force
    /// over every landmark, after the query (the recall figure; off with
    /// `STAR_BENCH_NO_RECALL`: a scan of the whole landmark table, which
    /// triples the bench's run time and leaves the next query's renders
    /// with a cold cache).
    pub(super) landmark_recall: bool,
}

impl Bench {
    /// Builds the scene of `seed`, its database and the renderers, and
    /// prints what was built.
    pub(super) fn new(config_path: Option<&std::path::Path>, seed: u64) -> Result<Self> {
        let config = match config_path {
            Some(p) => Config::load(p)?,
            None => Config::default(),
        };
        let rc = &config.reloc;
        let preset = Preset::by_name("realistic").context("preset `realistic`")?;
        let scene = preset_scene(&preset, seed);
        let camera = preset.camera;
        let map = Arc::new(scene.map.clone());
        // Candidates are rendered as the service renders them: by the
        // `[render] renderer` of the configuration (auto: a hardware adapter,
        // else the CPU rasterizer), both sides drawn (`RenderRequest::candidate`).
        let kind = config.render.renderer;
        let candidate_r = candidate_renderer(&config.render, map.clone())
            .with_context(|| format!("starting the `{kind:?}` renderer"))?;

        let t0 = Instant::now();
        let bar = indicatif::ProgressBar::new(0);
        // One CPU rasterizer per core: the same database as one renderer
        // on one thread, byte for byte.
        let lod_px = config.render.lod_px();
        // Both sides drawn, as `star reloc build` draws them.
        let first_renderer = CpuRenderer::with_lod(map.clone(), lod_px)?;
        let make_renderer = || Ok(first_renderer.share());
        let db = build_parallel(
            &map,
            &camera,
            rc,
            None,
            &Default::default(),
            "cpu",
            &make_renderer,
            BuildOptions {
                threads: 0,
                checkpoint: None,
                stop_after: None,
                progress: &mut |done, total| {
                    bar.set_length(total as u64);
                    bar.set_position(done as u64);
                },
                sample_every: 1,
                stage_times: None,
                far_m: None,
            },
        )?;
        bar.finish_and_clear();
        let build_s = t0.elapsed().as_secs_f64();
        println!(
            "reloc bench: realistic scene seed {seed}, map {} triangles, camera {}x{}",
            map.triangle_count(),
            camera.width,
            camera.height
        );
        println!(
            "  candidates rendered by {} (`[render] renderer = {kind:?}`)",
            candidate_r.name()
        );
        println!(
            "  database: {} keyframes (grid {} m, heights {:?} m, {} yaws, pitches {:?} deg) and {} landmarks, built in {build_s:.1} s with the CPU renderer",
            db.entries.len(),
            rc.grid_spacing_m,
            rc.heights_m,
            rc.yaw_steps,
            rc.pitches_deg,
            db.landmarks.len()
        );
        println!(
            "  database file {:.1} MB; landmark vocabulary {} words, {} leaves; whole-map probes {:?}",
            db.to_bytes().len() as f64 / 1e6,
            db.vocabulary.words.len(),
            db.vocabulary.leaves.len(),
            probes_from_env().unwrap_or_default()
        );

        // Queries: truth mesh, distortion, sensor model.
        let truth_r = CpuRenderer::new(Arc::new(scene.truth.clone()))?;
        let warp = DistortionWarp::new(&camera)?;
        let render_camera = *warp.render_camera();
        let sensor = SensorModel::new(preset.photometric, &camera, seed);
        let reloc = Relocalizer::new(db.clone(), rc, &camera)?.with_map(&map);
        // World heights: the configured ones above the map's floor.
        let z_range_m = crate::reloc::above_floor(&map, rc)?
            .heights_m
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &h| {
                (a.min(h), b.max(h))
            });
        let pitch_mid_deg = rc.pitches_deg.iter().sum::<f64>() / rc.pitches_deg.len() as f64;
        let max_roll_deg = std::env::var("STAR_BENCH_ROLL_DEG")
            .ok()
            .map(|v| {
                v.parse::<f64>()
                    .ok()
                    .filter(|r| r.is_finite() && *r >= 0.0 && *r < 90.0)
                    .with_context(|| format!("STAR_BENCH_ROLL_DEG={v}: expected degrees in 0..90"))
            })
            .transpose()?;
        let queries = Queries::Synthetic(Box::new(Synthetic {
            qview: RenderedView::for_camera(&render_camera),
            warped: ImageF32::new(0, 0, 0.0),
            scene,
            truth_r,
            warp,
            render_camera,
            sensor,
            z_range_m,
            pitch_mid_deg,
            max_roll_deg,
        }));
        Self::assemble(config, camera, db, reloc, candidate_r, queries)
    }

    /// The bench over an existing dataset (`dataset`, with one ground-truth
    /// pose per frame): its map placed by `config` (`[map]`), its database
    /// `db`, and random frames of it as the queries.
    pub(super) fn from_dataset(
        config: Config,
        dataset: Dataset,
        mesh: Arc<crate::map::Mesh>,
        db: RelocDatabase,
    ) -> Result<Self> {
        let truth = dataset
            .ground_truth
            .clone()
            .context("the dataset has no groundtruth.txt: the queries need the truth")?;
        anyhow::ensure!(
            truth.len() == dataset.len(),
            "the dataset's groundtruth.txt has {} poses for {} frames: the bench needs one per frame (a `star synth` dataset)",
            truth.len(),
            dataset.len()
        );
        let camera = *dataset.camera();
        let kind = config.render.renderer;
        let candidate_r = candidate_renderer(&config.render, mesh.clone())
            .with_context(|| format!("starting the `{kind:?}` renderer"))?;
        println!(
            "reloc bench: dataset {}, {} frames, map {} triangles, camera {}x{}",
            dataset.root.display(),
            dataset.len(),
            mesh.triangle_count(),
            camera.width,
            camera.height
        );
        println!(
            "  candidates rendered by {} (`[render] renderer = {kind:?}`); database {} keyframes and {} landmarks",
            candidate_r.name(),
            db.entries.len(),
            db.landmarks.len()
        );
        let reloc = Relocalizer::new(db.clone(), &config.reloc, &camera)?.with_map(&mesh);
        let queries = Queries::Dataset {
            dataset,
            truth,
            scratch: Vec::new(),
        };
        Self::assemble(config, camera, db, reloc, candidate_r, queries)
    }

    fn assemble(
        config: Config,
        camera: PinholeCamera,
        db: RelocDatabase,
        mut reloc: Relocalizer,
        candidate_r: Box<dyn Renderer>,
        queries: Queries,
    ) -> Result<Self> {
        if let Some(probes) = probes_from_env() {
            println!("  whole-map landmark probes from STAR_BENCH_PROBES: {probes:?}");
            reloc.landmarks_mut().set_probes(probes);
        }
        let pinhole = camera.pinhole();
        let tracker = crate::track::build_config(&config.tracker);
        let renders_per_candidate = 1 + config.reloc.refine_renders as usize;
        let spare: Vec<Box<Keyframe>> = (0..renders_per_candidate)
            .map(|_| Box::new(Keyframe::new(&pinhole, &tracker)))
            .collect();
        let judge_plain = std::env::var("STAR_BENCH_NORMALIZE_GATE").as_deref() == Ok("plain");
        let contrast = contrast_from_env()?.map(|(radius_px, floor_gray)| {
            println!(
                "  candidates aligned on local contrast (STAR_BENCH_NORMALIZE_PX): windows of radius {radius_px} px, standard deviation floor {floor_gray} gray; judged on the {} images",
                if judge_plain { "plain" } else { "normalized" }
            );
            (
                LocalContrast::new(
                    camera.width as usize,
                    camera.height as usize,
                    radius_px,
                    floor_gray,
                ),
                Pyramid::new(
                    camera.width as usize,
                    camera.height as usize,
                    tracker.pyramid_levels as usize,
                ),
            )
        });
        Ok(Self {
            contrast,
            judge_plain,
            kview: RenderedView::for_camera(&pinhole),
            frame: ImageU8::new(0, 0, 0),
            returned: Vec::with_capacity(renders_per_candidate),
            aligners: [Aligner::new(&tracker), Aligner::new(&tracker)],
            pyramid: Pyramid::new(
                camera.width as usize,
                camera.height as usize,
                tracker.pyramid_levels as usize,
            ),
            config,
            camera,
            db,
            reloc,
            candidate_r,
            queries,
            pinhole,
            tracker,
            spare,
            check_rivals: std::env::var_os("STAR_BENCH_NO_RIVALS").is_none(),
            landmark_recall: std::env::var_os("STAR_BENCH_NO_RECALL").is_none(),
        })
    }

    /// Prints how the queries were drawn.
    pub(super) fn print_queries(&self, done: usize) {
        match &self.queries {
            Queries::Synthetic(s) => {
                let (z_lo, z_hi) = s.z_range_m;
                println!(
                    "  queries: {done} random free poses (clearance 0.4 m, z {z_lo}..{z_hi} m, yaw any, pitch {}+-5 deg, roll +-{} deg, >= 60 % of the view on the map), truth mesh + distortion + realistic sensor model; top_k {}",
                    s.pitch_mid_deg,
                    s.max_roll_deg.unwrap_or(0.0),
                    self.config.reloc.top_k
                );
            }
            Queries::Dataset { dataset, .. } => println!(
                "  queries: {done} random frames of the dataset's {} (its own images, as the camera saw them); top_k {}",
                dataset.len(),
                self.config.reloc.top_k
            ),
        }
    }
}

/// `STAR_BENCH_NORMALIZE_PX=R` (window radius, pixels, at least 1) and
/// `STAR_BENCH_NORMALIZE_FLOOR=G` (standard deviation floor, gray levels,
/// default [`NORMALIZE_FLOOR_GRAY`]): align candidates on local contrast.
fn contrast_from_env() -> Result<Option<(usize, f32)>> {
    let Ok(radius) = std::env::var("STAR_BENCH_NORMALIZE_PX") else {
        return Ok(None);
    };
    let radius_px: usize = radius
        .trim()
        .parse()
        .ok()
        .filter(|&r| r >= 1)
        .with_context(|| {
            format!(
                "STAR_BENCH_NORMALIZE_PX: expected a whole number of pixels >= 1, found {radius:?}"
            )
        })?;
    let floor_gray = match std::env::var("STAR_BENCH_NORMALIZE_FLOOR") {
        Ok(v) => v
            .trim()
            .parse::<f32>()
            .ok()
            .filter(|f| f.is_finite() && *f > 0.0)
            .with_context(|| {
                format!("STAR_BENCH_NORMALIZE_FLOOR: expected gray levels > 0, found {v:?}")
            })?,
        Err(_) => NORMALIZE_FLOOR_GRAY,
    };
    Ok(Some((radius_px, floor_gray)))
}

/// Default standard deviation floor of `STAR_BENCH_NORMALIZE_PX`, gray
/// levels (4 scanned rooms: 6 kept 73 of 100 cold starts, 12 kept 68).
const NORMALIZE_FLOOR_GRAY: f32 = 6.0;

/// `STAR_BENCH_PROBES=WORDS,LEAVES`: the whole-map landmark search's
/// probes ([`crate::reloc::landmark_index::Probes`]) instead of the
/// defaults.
pub(super) fn probes_from_env() -> Option<crate::reloc::landmark_index::Probes> {
    let v = std::env::var("STAR_BENCH_PROBES").ok()?;
    let (w, l) = v.split_once(',')?;
    Some(crate::reloc::landmark_index::Probes {
        words: w.trim().parse().ok()?,
        leaves: l.trim().parse().ok()?,
    })
}

/// The renderer of relocalization candidates: `[render]`'s, drawing both
/// sides of every triangle, as the service draws candidates (their poses are
/// not verified: see `localizer::worker::RenderRequest::candidate`).
fn candidate_renderer(
    render: &crate::render::select::RenderConfig,
    mesh: Arc<crate::map::Mesh>,
) -> Result<Box<dyn Renderer>, crate::render::RenderError> {
    let render = crate::render::select::RenderConfig {
        cull_back_faces: false,
        ..render.clone()
    };
    crate::render::select::make_configured_renderer(&render, mesh)
}
