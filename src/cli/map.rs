//! `star map info MESH`, `star map align MESH` and `star map plan MESH`:
//! what a user's map is like before flying with it, the
//! `[map.world_from_mesh]` that makes it z-up, and the map from above with
//! its relocalization database (`crate::output::plan`).
//!
//! `info` loads the map as the tracker would (through `--config`'s
//! `[map.world_from_mesh]` when given) and prints its size, colors, floor,
//! holes, render times and memory ([`crate::bench::map_survey`]); `--json`
//! prints the same as one JSON object. `align` finds the floor of the raw
//! file ([`crate::map::align`]) and writes the TOML snippet.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::{UnitQuaternion, Vector3};
use serde::Serialize;
use serde_json::json;

use crate::bench::map_survey::{
    estimate_memory, survey_holes, time_renderers, timing_views, HoleSurvey, MIN_HIT_FRACTION,
};
use crate::config::Config;
use crate::dataset::CameraFile;
use crate::geometry::{PinholeCamera, Pose};
use crate::map::align::{find_floor_plane, AlignParams, FloorPlane, UpHint};
use crate::map::floor::find_floor;
use crate::map::{MapFormat, Mesh, MeshTransformConfig};

/// `star map` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum MapCommand {
    /// Print a map's size, colors, floor, holes, keyframe render time on
    /// every renderer of this machine, and memory.
    Info(InfoArgs),
    /// Find the floor of a mesh in any frame (RANSAC) and write the
    /// `[map.world_from_mesh]` that makes the map z-up.
    Align(AlignArgs),
    /// Draw the map from above as a floor plan (PNG), with the
    /// relocalization database's views and landmarks and flown
    /// trajectories.
    Plan(PlanArgs),
}

/// Arguments of `star map plan`.
#[derive(Debug, clap::Args)]
pub struct PlanArgs {
    /// The map: .obj, .ply, .gltf or .glb.
    pub mesh: PathBuf,
    /// The PNG to write.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Configuration: its `[map.world_from_mesh]` places the mesh.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Relocalization database of this map: its views and landmarks are
    /// drawn.
    #[arg(long)]
    pub reloc: Option<PathBuf>,
    /// TUM trajectories to draw (ground truth, `star localize -o`, a flight
    /// log's `trajectory.txt`); repeat for several.
    #[arg(long)]
    pub trajectory: Vec<PathBuf>,
    /// Plan cell (one pixel), meters; larger for maps over 4000 cells a side.
    #[arg(long, default_value_t = 0.05)]
    pub cell_m: f64,
    /// Height of the floor, world meters; found in the map when not given.
    #[arg(long, allow_hyphen_values = true)]
    pub floor_z: Option<f64>,
}

/// Arguments of `star map info`.
#[derive(Debug, clap::Args)]
pub struct InfoArgs {
    /// The map: .obj, .ply, .gltf or .glb.
    pub mesh: PathBuf,
    /// Configuration: its `[map.world_from_mesh]` places the mesh, its
    /// `[camera.intrinsics]` sets the render size, its `[reloc]` heights
    /// the hole views' heights.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Camera calibration file (a dataset's `camera.toml`); overrides the config's intrinsics.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Views timed per renderer.
    #[arg(long, default_value_t = 7)]
    pub views: usize,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Which way is up in the mesh file, for `align`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum UpArg {
    /// Decide from the mesh: the floor has the furniture on it.
    Auto,
    /// +x
    #[value(name = "+x")]
    PlusX,
    /// -x
    #[value(name = "-x")]
    MinusX,
    /// +y (glTF)
    #[value(name = "+y")]
    PlusY,
    /// -y (a scanner's camera frame)
    #[value(name = "-y")]
    MinusY,
    /// +z
    #[value(name = "+z")]
    PlusZ,
    /// -z
    #[value(name = "-z")]
    MinusZ,
}

impl UpArg {
    fn hint(self) -> UpHint {
        let axis = match self {
            UpArg::Auto => return UpHint::Auto,
            UpArg::PlusX => [1.0, 0.0, 0.0],
            UpArg::MinusX => [-1.0, 0.0, 0.0],
            UpArg::PlusY => [0.0, 1.0, 0.0],
            UpArg::MinusY => [0.0, -1.0, 0.0],
            UpArg::PlusZ => [0.0, 0.0, 1.0],
            UpArg::MinusZ => [0.0, 0.0, -1.0],
        };
        UpHint::Near(axis)
    }
}

/// Arguments of `star map align`.
#[derive(Debug, clap::Args)]
pub struct AlignArgs {
    /// The map: .obj, .ply, .gltf or .glb, in any frame.
    pub mesh: PathBuf,
    /// Meters per mesh unit (0.001 for millimeters); written as `scale`.
    #[arg(long, default_value_t = 1.0)]
    pub scale: f64,
    /// Roughly which mesh axis points up, when the mesh alone cannot tell
    /// (within 45 degrees).
    #[arg(long, value_enum, default_value_t = UpArg::Auto, allow_hyphen_values = true)]
    pub up: UpArg,
    /// Write the snippet to this file too (it is always printed).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
}

/// Runs a `star map` subcommand.
pub fn run(cmd: &MapCommand) -> Result<()> {
    match cmd {
        MapCommand::Info(args) => info(args),
        MapCommand::Align(args) => align(args),
        MapCommand::Plan(args) => plan(args),
    }
}

fn plan(args: &PlanArgs) -> Result<()> {
    use crate::output::plan::{plan_png, PlanInput, CELL_M_RANGE};
    if !CELL_M_RANGE.contains(&args.cell_m) {
        bail!("--cell-m {} is outside 0.005..=1 m", args.cell_m);
    }
    if let Some(z) = args.floor_z {
        if !z.is_finite() {
            bail!("--floor-z {z} is not a finite height");
        }
    }
    let config = match &args.config {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    };
    let trajectories = args
        .trajectory
        .iter()
        .map(|p| {
            crate::dataset::Trajectory::read(p)
                .with_context(|| format!("reading trajectory {}", p.display()))
        })
        .collect::<Result<Vec<_>>>()?;
    let (mesh, _) = load(&args.mesh, &config.map)?;
    let floor_z_m = match args.floor_z {
        Some(z) => z,
        None => find_floor(&mesh).map(|f| f.z_m).with_context(|| {
            format!(
                "{}: no floor found (is the map z-up? `star map align`); give --floor-z",
                args.mesh.display()
            )
        })?,
    };
    let db = match &args.reloc {
        Some(path) => {
            let db = crate::reloc::RelocDatabase::read(path)
                .with_context(|| format!("reading relocalization database {}", path.display()))?;
            let fingerprint = crate::reloc::map_fingerprint(&mesh);
            if db.map_fingerprint != fingerprint {
                bail!(
                    "{} was built from another map than {} (fingerprint {:016x}, the map's {:016x}): its views would be drawn in the wrong places",
                    path.display(),
                    args.mesh.display(),
                    db.map_fingerprint,
                    fingerprint
                );
            }
            Some(db)
        }
        None => None,
    };
    let views_m = db
        .as_ref()
        .map_or_else(Vec::new, crate::output::plan::database_views_m);
    let landmarks_m: Vec<[f32; 3]> = db.as_ref().map_or_else(Vec::new, |db| {
        db.landmarks.iter().map(|l| l.world_m).collect()
    });
    let labels: Vec<String> = args
        .trajectory
        .iter()
        .map(|p| p.display().to_string())
        .collect();
    let tracks: Vec<(&str, &crate::dataset::Trajectory)> = labels
        .iter()
        .map(String::as_str)
        .zip(trajectories.iter())
        .collect();
    let bar = spinner("drawing the plan");
    let summary = plan_png(
        &PlanInput {
            mesh: &mesh,
            floor_z_m,
            cell_m: args.cell_m,
            views_m: &views_m,
            landmarks_m: &landmarks_m,
            trajectories: &tracks,
            marks: &[],
        },
        &args.output,
    );
    bar.finish_and_clear();
    let summary =
        summary.with_context(|| format!("drawing the plan of {}", args.mesh.display()))?;
    println!(
        "map plan: {} ({}x{} px, {:.3} m a pixel); floor z = {floor_z_m:.3} m: {:.1} m² of floor, {:.1} m² of walls and furniture{}",
        args.output.display(),
        summary.width_px,
        summary.height_px,
        summary.cell_m,
        summary.floor_m2,
        summary.obstacle_m2,
        match &db {
            Some(_) => format!(
                "; {} relocalization views ({} above no map: outside the building?) and {} landmarks drawn",
                summary.views, summary.views_off_map, summary.landmarks
            ),
            None => String::new(),
        }
    );
    Ok(())
}

fn spinner(message: &str) -> ProgressBar {
    let bar = ProgressBar::new_spinner();
    bar.set_message(message.to_string());
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}

fn load(path: &Path, placement: &crate::map::MapConfig) -> Result<(Mesh, f64)> {
    let bar = spinner(&format!("loading {}", path.display()));
    let start = Instant::now();
    let mesh = placement
        .load_mesh_from(path)
        .with_context(|| format!("loading map {}", path.display()));
    bar.finish_and_clear();
    Ok((mesh?, start.elapsed().as_secs_f64()))
}

/// `world_from_mesh` as the config writes it.
fn transform_config(pose: &Pose, scale: f64) -> MeshTransformConfig {
    let q = pose.rotation.into_inner();
    let t = pose.translation.vector;
    MeshTransformConfig {
        translation_m: [t.x, t.y, t.z],
        rpy_deg: None,
        quaternion_wxyz: Some([q.w, q.i, q.j, q.k]),
        rotation_rows: None,
        scale,
    }
}

#[derive(Serialize)]
struct Snippet<'a> {
    map: SnippetMap<'a>,
}

#[derive(Serialize)]
struct SnippetMap<'a> {
    world_from_mesh: &'a MeshTransformConfig,
}

fn snippet_toml(t: &MeshTransformConfig) -> Result<String> {
    toml::to_string(&Snippet {
        map: SnippetMap { world_from_mesh: t },
    })
    .context("writing the TOML snippet")
}

fn align(args: &AlignArgs) -> Result<()> {
    let (lo, hi) = crate::map::MESH_SCALE_RANGE;
    if !(args.scale >= lo && args.scale <= hi) {
        bail!(
            "--scale {} is outside {lo:e}..={hi:e} meters per mesh unit",
            args.scale
        );
    }
    let placement = crate::map::MapConfig {
        world_from_mesh: MeshTransformConfig {
            scale: args.scale,
            ..MeshTransformConfig::default()
        },
        ..crate::map::MapConfig::default()
    };
    let (mesh, _) = load(&args.mesh, &placement)?;
    let bar = spinner("finding planes");
    let found = find_floor_plane(&mesh, &AlignParams::default(), args.up.hint());
    bar.finish_and_clear();
    let found = found.with_context(|| {
        format!(
            "{}: cannot align: no floor found (give --up AXIS if the mesh alone cannot tell which way is up)",
            args.mesh.display()
        )
    })?;
    let level = found.world_from_mesh();
    let transform = transform_config(&level, args.scale);
    let f = &found.floor;
    let text = format!(
        "# Written by `star map align {}`: the floor found by RANSAC\n\
         # (normal [{:.4}, {:.4}, {:.4}] in the mesh frame, scaled to meters; {:.1} m^2;\n\
         # {:.1} m below the mesh origin) goes to z = 0 with +z up.\n\
         # Yaw about the vertical is free: this is the smallest rotation that\n\
         # levels the floor, so the mesh keeps its own heading, and the mesh\n\
         # origin stays at x = y = 0. Add a yaw about z (and x, y) to match\n\
         # your world's axes: the snippet fixes only the floor.\n{}",
        args.mesh.display(),
        f.normal[0],
        f.normal[1],
        f.normal[2],
        f.area_m2,
        f.offset_m.abs(),
        snippet_toml(&transform)?
    );
    println!(
        "map align: {} planes found; floor {:.1} m^2, tilted {:.1} deg from the file's +z, the mesh origin {:.3} m above it",
        found.planes.len(),
        f.area_m2,
        found.tilt_from_z_deg(),
        level.translation.z
    );
    println!("{text}");
    if let Some(out) = &args.output {
        std::fs::write(out, &text).with_context(|| format!("writing {}", out.display()))?;
        println!("map align: wrote {}", out.display());
    }
    Ok(())
}

/// The fraction of the surface area with a color: textured, or vertex
/// gray other than the 255 that uncolored vertices get.
fn colored_fraction(mesh: &Mesh) -> f64 {
    let mut textured = vec![false; mesh.triangle_count()];
    for g in &mesh.groups {
        if g.texture.is_some() {
            let first = g.first_index as usize / 3;
            let end = first + g.index_count as usize / 3;
            for t in textured.iter_mut().take(end).skip(first) {
                *t = true;
            }
        }
    }
    let (mut colored, mut total) = (0.0, 0.0);
    for (k, t) in mesh.indices.chunks_exact(3).enumerate() {
        let p = |i: u32| {
            let v = mesh.positions.get(i as usize).copied().unwrap_or_default();
            Vector3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))
        };
        let area = 0.5 * (p(t[1]) - p(t[0])).cross(&(p(t[2]) - p(t[0]))).norm();
        total += area;
        let gray = |i: u32| mesh.gray.get(i as usize).copied().unwrap_or(255.0);
        if textured.get(k).copied().unwrap_or(false) || t.iter().any(|&i| gray(i) < 254.5) {
            colored += area;
        }
    }
    if total > 0.0 {
        colored / total
    } else {
        0.0
    }
}

fn camera_for(args: &InfoArgs, config: &Config) -> Result<PinholeCamera> {
    let camera = match &args.camera {
        Some(p) => {
            CameraFile::read(p)
                .with_context(|| format!("reading camera {}", p.display()))?
                .camera
        }
        None => config.camera.intrinsics,
    };
    Ok(camera.pinhole())
}

fn mb(bytes: u64) -> f64 {
    bytes as f64 / 1e6
}

fn info(args: &InfoArgs) -> Result<()> {
    let config = match &args.config {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    };
    let camera = camera_for(args, &config)?;
    let format = MapFormat::from_path(&args.mesh)?;
    let (mesh, load_s) = load(&args.mesh, &config.map)?;
    let (lo, hi) = mesh
        .bounds()
        .with_context(|| format!("{}: the map has no vertices", args.mesh.display()))?;
    let colored = colored_fraction(&mesh);
    let detail_m = mesh.detail_spacing_m();
    let texels: usize = mesh.textures.iter().map(|t| t.texels.len()).sum();

    // The floor, in the frame the tracker sees (the config's placement).
    let bar = spinner("finding the floor");
    let floor = find_floor_plane(&mesh, &AlignParams::default(), UpHint::Auto);
    bar.finish_and_clear();
    let z_up_floor = find_floor(&mesh).ok();
    let old = config.map.world_from_mesh.rigid().to_pose();
    let suggested = floor.as_ref().ok().map(|f| {
        transform_config(
            &(f.world_from_mesh() * old),
            config.map.world_from_mesh.scale,
        )
    });

    // Holes, from the leveled frame (the world itself when no floor).
    let world_from_level = match &floor {
        Ok(f) => f.world_from_mesh().inverse(),
        Err(_) => Pose::from_parts(
            nalgebra::Translation3::new(0.0, 0.0, f64::from(lo[2])),
            UnitQuaternion::identity(),
        ),
    };
    let mesh = Arc::new(mesh);
    let heights = config.reloc.heights_m.clone();
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{spinner} hole views [{bar:40}] {pos}/{len} eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let holes = survey_holes(
        &mesh,
        &world_from_level,
        &camera,
        &heights,
        &mut |done, total| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        },
    )
    .context("rendering the hole views")?;
    bar.finish_and_clear();
    let bar = spinner("timing the renderers");
    let poses = timing_views(&holes, args.views);
    let timings = time_renderers(&mesh, &camera, &poses);
    bar.finish_and_clear();
    let memory = estimate_memory(&mesh, &camera);

    let floor_json = match &floor {
        Ok(f) => json!({
            "normal": f.floor.normal,
            "height_m": f.floor.offset_m,
            "area_m2": f.floor.area_m2,
            "tilt_from_z_deg": f.tilt_from_z_deg(),
            "planes_found": f.planes.len(),
            "find_floor_z_m": z_up_floor.map(|z| z.z_m),
            "world_from_mesh": suggested,
        }),
        Err(e) => json!({"error": e.to_string(), "find_floor_z_m": z_up_floor.map(|z| z.z_m)}),
    };
    let report = json!({
        "mesh": args.mesh,
        "format": format.name(),
        "load_s": load_s,
        "vertices": mesh.positions.len(),
        "triangles": mesh.triangle_count(),
        "textures": mesh.textures.len(),
        "texels": texels,
        "bounds_m": {"min": lo, "max": hi, "size": [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]]},
        "colored_fraction": colored,
        "detail_spacing_m": detail_m,
        "floor": floor_json,
        "holes": {
            "views": holes.views,
            "empty_views": holes.empty_views,
            "empty_fraction": holes.empty_fraction,
            "grid_m": holes.grid_m,
            "heights_m": holes.heights_m,
            "min_hit_fraction": MIN_HIT_FRACTION,
        },
        "camera": {"width": camera.width, "height": camera.height},
        "renderers": timings.iter().map(|t| json!({
            "renderer": t.renderer,
            "name": t.name,
            "available": t.error.is_none(),
            "median_ms": t.median_ms,
            "max_ms": t.max_ms,
            "views": t.views,
            "error": t.error,
        })).collect::<Vec<_>>(),
        "memory": {
            "estimated_from": "buffer sizes",
            "cpu_mesh_bytes": memory.mesh_bytes,
            "cpu_renderer_bytes": memory.cpu_renderer_bytes,
            "gpu_bytes": memory.gpu_bytes,
        },
    });
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    print_info(
        args,
        format,
        load_s,
        &mesh,
        (lo, hi),
        colored,
        detail_m,
        &floor,
        z_up_floor.map(|f| f.z_m),
        suggested.as_ref(),
        &holes,
        &timings,
        &memory,
        &camera,
    )
}

#[allow(clippy::too_many_arguments)]
fn print_info(
    args: &InfoArgs,
    format: MapFormat,
    load_s: f64,
    mesh: &Mesh,
    (lo, hi): ([f32; 3], [f32; 3]),
    colored: f64,
    detail_m: f32,
    floor: &Result<FloorPlane, crate::map::align::AlignError>,
    z_up_floor_m: Option<f64>,
    suggested: Option<&MeshTransformConfig>,
    holes: &HoleSurvey,
    timings: &[crate::bench::map_survey::RendererTiming],
    memory: &crate::bench::map_survey::MemoryEstimate,
    camera: &PinholeCamera,
) -> Result<()> {
    println!(
        "map {} ({}), loaded in {load_s:.2} s",
        args.mesh.display(),
        format.name()
    );
    println!(
        "  {} triangles, {} vertices, {} textures; {:.0} % of the surface colored",
        mesh.triangle_count(),
        mesh.positions.len(),
        mesh.textures.len(),
        100.0 * colored
    );
    if detail_m > 0.0 {
        println!(
            "  appearance sampled every {:.1} mm (median texel or vertex spacing); with [reloc] gate_at_map_detail, relocalization's verification reads only the pyramid levels no finer than that",
            1e3 * detail_m
        );
    } else {
        println!("  appearance: flat colors only (no texture, no vertex color gradient)");
    }
    println!(
        "  bounds [{:.2}, {:.2}, {:.2}] .. [{:.2}, {:.2}, {:.2}] m ({:.2} x {:.2} x {:.2})",
        lo[0],
        lo[1],
        lo[2],
        hi[0],
        hi[1],
        hi[2],
        hi[0] - lo[0],
        hi[1] - lo[1],
        hi[2] - lo[2]
    );
    match floor {
        Ok(f) => {
            let n = f.floor.normal;
            println!(
                "  floor: normal [{:.4}, {:.4}, {:.4}] ({:.2} deg from +z), {:.1} m^2, at {:.3} m along it ({} planes found)",
                n[0], n[1], n[2], f.tilt_from_z_deg(), f.floor.area_m2, f.floor.offset_m, f.planes.len()
            );
            if f.tilt_from_z_deg() < 1.0 && f.floor.offset_m.abs() < 0.05 {
                println!("  the map is z-up with its floor at z = 0");
            } else if let Some(t) = suggested {
                println!(
                    "  to make it z-up with the floor at z = 0 (yaw kept), set:\n{}",
                    snippet_toml(t)?
                );
            }
        }
        Err(e) => println!("  floor: {e}"),
    }
    if let Some(z) = z_up_floor_m {
        println!("  floor height for the relocalization grid (z-up): {z:.3} m");
    }
    println!(
        "  holes: {} of {} views ({:.0} %) see the map on less than {:.0} % of the image (grid {:.1} m, heights {:?} m above the floor, {} headings)",
        holes.empty_views,
        holes.views,
        100.0 * holes.empty_fraction,
        100.0 * MIN_HIT_FRACTION,
        holes.grid_m,
        holes.heights_m,
        crate::bench::map_survey::HOLE_YAWS
    );
    println!(
        "  keyframe render time at {}x{}:",
        camera.width, camera.height
    );
    for t in timings {
        match (&t.error, t.median_ms) {
            (None, Some(median)) => println!(
                "    {} ({}): median {median:.1} ms, max {:.1} ms over {} views",
                t.renderer,
                t.name.as_deref().unwrap_or("?"),
                t.max_ms.unwrap_or(f64::NAN),
                t.views
            ),
            (Some(e), _) => println!("    {}: not available ({e})", t.renderer),
            (None, None) => println!("    {}: no view timed", t.renderer),
        }
    }
    println!(
        "  memory (estimated from buffer sizes): mesh {:.1} MB, CPU rasterizer {:.1} MB more, GPU {:.1} MB",
        mb(memory.mesh_bytes),
        mb(memory.cpu_renderer_bytes),
        mb(memory.gpu_bytes)
    );
    Ok(())
}
