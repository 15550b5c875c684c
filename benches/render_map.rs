//! Milliseconds per 640x512 keyframe of the CPU rasterizer and the wgpu
//! renderer (software adapter: lavapipe/llvmpipe, or a hardware GPU with
//! `STAR_BENCH_ADAPTER=hardware`; render plus readback) on
//! the map of a dataset, at 50 poses evenly strided through its
//! `groundtruth.txt` (every 10th of 500; each rendered `ROUNDS` times): median and p95, with the
//! mesh size and the share of triangles in chunks that pass the frustum
//! test (what the renderers set up and draw; for the CPU rasterizer less
//! the chunks its occlusion cull skips), mean and range over the poses, and
//! for the CPU rasterizer the screen triangles it binned and the mesh
//! triangles that own a pixel, mean per view. Both renderers are also timed with the chunk cull off (every
//! triangle set up and drawn, as before the cull), for a comparison within
//! one run.
//!
//! Each argument is a dataset folder: its map is `star.toml`'s `[map]`
//! where the folder has one (placed by `[map.world_from_mesh]`), else
//! `map/map.obj` as stored; the camera is its `camera.toml`. Both renderers
//! render with the far limit of that `star.toml`'s `[render] far_m` (else
//! the default, 30 m), as `star track` would; `STAR_BENCH_FAR_M=X`
//! overrides it (0: none). Likewise the level of detail, `[render]
//! lod_max_px` (default 2 px; `STAR_BENCH_LOD_PX=X` overrides it, 0: full
//! detail): the default cull is timed with it and without it (full
//! detail), the other culls at full detail. And `[render]
//! cull_back_faces` (default off; `STAR_BENCH_CULL_BACK=1` or `0`
//! overrides it), for every renderer and cull.
//!
//! `STAR_BENCH_GPU_BUDGET_MB=X` (MB, 10^6 bytes) also times the wgpu
//! renderer (cull on) with `[render] gpu_budget_mb = X`: a map larger than
//! that streams its chunks through a slot pool; printed with the pool's
//! size and the chunk uploads, evictions and render passes per render
//! (over the timed renders and one untimed round before them, after a
//! first round that fills the pool).
//!
//! Also printed: the map's load time, the process's resident memory
//! (VmRSS) after loading and with each renderer built, and the wgpu
//! renderer's device memory (mesh buffers, textures, targets).
//!
//! `--every N` takes the poses every `N` frames of the ground truth
//! instead, all of them, so that consecutive renders are as far apart in
//! time on every dataset (the 50 evenly strided poses of a 3000-frame
//! floor are 6 times farther apart than a 500-frame room's, which a
//! renderer that reuses the previous render's visibility pays for; the
//! tracker renders a keyframe every 6 degrees or 8 % of the depth, at
//! most 1 s apart: `--every 10` is 0.2 s at 50 Hz).
//!
//! The wgpu renderer is also timed with the occlusion cull chosen in flight
//! (`set_occlusion_timed`, a hardware adapter's default), with the choice
//! and its trial's medians.
//!
//! `--cpu-default` times only the CPU rasterizer with its default cull;
//! `--gpu-only` only the wgpu renderer with its cull on (and the budget);
//! `--interleaved` times only that (with `--gpu-only`, the wgpu renderer
//! instead), on all the datasets in alternating
//! blocks (so that a changing machine load falls on each alike), and prints
//! each median's ratio to the first dataset's.
//!
//! Run: `cargo bench --bench render_map -- /tmp/sc1 /tmp/rs1` (a TSDF map
//! of `star synth --scanned`, and `star synth --preset realistic`); for
//! the building scale figures, datasets of `star synth --preset building
//! --rooms 1`, `--rooms 4` and the whole floor (docs/building-scale.md).

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use star::config::Config;
use star::dataset::{CameraFile, Trajectory};
use star::geometry::{PinholeCamera, Pose};
use star::map::Mesh;
use star::render::chunks::ChunkedMesh;
use star::render::cpu::CpuRenderer;
use star::render::gpu::{AdapterPreference, GpuRenderer};
use star::render::{RenderedView, Renderer};

/// Renders of each pose.
const ROUNDS: usize = 3;
/// Poses rendered (fewer when the ground truth is shorter).
const MAX_POSES: usize = 50;

/// A field of /proc/self/status, MB.
fn status_mb(key: &str) -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with(key))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<f64>().ok())
        .map_or(0.0, |kb| kb / 1024.0)
}

/// `--every N`: poses every `N` frames of the ground truth, all of them
/// (the same spacing in time on every dataset); else `None`: at most
/// [`MAX_POSES`] evenly strided through it.
fn every_frames() -> Option<usize> {
    let args: Vec<String> = std::env::args().collect();
    let at = args.iter().position(|a| a == "--every")?;
    let n: usize = args
        .get(at + 1)
        .and_then(|v| v.parse().ok())
        .expect("--every N: a whole number of frames");
    assert!(n > 0, "--every N: at least 1 frame");
    Some(n)
}

/// A dataset's map, camera, poses, far limit and level of detail (px).
type Loaded = (Mesh, PinholeCamera, Vec<Pose>, Option<f64>, f32);

fn load(dir: &Path) -> Loaded {
    let config_path = dir.join("star.toml");
    let (mesh, far_m, lod_px) = if config_path.exists() {
        let config = Config::load(&config_path).expect("star.toml");
        (
            config.map.load_mesh().expect("map"),
            config.render.far_limit_m(),
            config.render.lod_px(),
        )
    } else {
        let config = Config::default();
        (
            config
                .map
                .load_mesh_from(&dir.join("map/map.obj"))
                .expect("map/map.obj"),
            config.render.far_limit_m(),
            config.render.lod_px(),
        )
    };
    let camera = CameraFile::read(&dir.join("camera.toml"))
        .expect("camera.toml")
        .camera
        .pinhole();
    let truth = Trajectory::read(&dir.join("groundtruth.txt")).expect("groundtruth.txt");
    let poses = match every_frames() {
        Some(n) => truth.poses.iter().step_by(n).copied().collect(),
        None => truth
            .poses
            .iter()
            .step_by((truth.poses.len() / MAX_POSES).max(1))
            .take(MAX_POSES)
            .copied()
            .collect(),
    };
    let far_m = match std::env::var("STAR_BENCH_FAR_M") {
        Ok(v) => {
            let f: f64 = v.parse().expect("STAR_BENCH_FAR_M: meters");
            (f > 0.0).then_some(f)
        }
        Err(_) => far_m,
    };
    let lod_px = match std::env::var("STAR_BENCH_LOD_PX") {
        Ok(v) => v.parse().expect("STAR_BENCH_LOD_PX: pixels"),
        Err(_) => lod_px,
    };
    (mesh, camera, poses, far_m, lod_px)
}

/// Whether `dir`'s renders cull back faces: `STAR_BENCH_CULL_BACK` (`1` or
/// `0`), else its `star.toml`'s `[render] cull_back_faces`, else off.
fn cull_back_faces(dir: &Path) -> bool {
    match std::env::var("STAR_BENCH_CULL_BACK").as_deref() {
        Ok("1") => true,
        Ok("0") => false,
        Ok(other) => panic!("STAR_BENCH_CULL_BACK={other}: expected 1 or 0"),
        Err(_) => {
            let config_path = dir.join("star.toml");
            config_path.exists()
                && Config::load(&config_path)
                    .expect("star.toml")
                    .render
                    .cull_back_faces
        }
    }
}

/// Median and p95 of `samples_ms` (sorted in place).
fn median_p95(samples_ms: &mut [f64]) -> (f64, f64) {
    samples_ms.sort_by(f64::total_cmp);
    let at = |q: f64| samples_ms[((samples_ms.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.95))
}

/// Times `ROUNDS` renders of every pose after one warm-up render of each.
fn time_renders(
    renderer: &mut dyn Renderer,
    camera: &PinholeCamera,
    poses: &[Pose],
) -> (f64, f64, usize) {
    let mut out = RenderedView::for_camera(camera);
    for p in poses {
        renderer.render(p, camera, &mut out).expect("render");
    }
    let mut samples_ms = Vec::with_capacity(ROUNDS * poses.len());
    for _ in 0..ROUNDS {
        for p in poses {
            let t = Instant::now();
            renderer.render(p, camera, &mut out).expect("render");
            samples_ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    let n = samples_ms.len();
    let (median, p95) = median_p95(&mut samples_ms);
    (median, p95, n)
}

/// Which measurements to take.
#[derive(Clone, Copy)]
struct Only {
    /// `--cpu-default`: only the CPU rasterizer with its default cull.
    cpu_default: bool,
    /// `--gpu-only`: only the wgpu renderer, cull on (and with
    /// `STAR_BENCH_GPU_BUDGET_MB`, with that budget).
    gpu_only: bool,
}

fn bench_dataset(dir: &Path, only: Only) {
    let rss_before_mb = status_mb("VmRSS:");
    let t = Instant::now();
    let (mesh, camera, poses, far_m, lod_px) = load(dir);
    let cull_back = cull_back_faces(dir);
    let triangles = mesh.triangle_count();
    let texels: usize = mesh.textures.iter().map(|t| t.texels.len()).sum();
    println!(
        "{}: {} triangles, {} vertices, {} textures ({:.1} Mtexels), {} poses, {}x{}, far limit {:?} m, level of detail {lod_px} px, back faces {}",
        dir.display(),
        triangles,
        mesh.positions.len(),
        mesh.textures.len(),
        texels as f64 / 1e6,
        poses.len(),
        camera.width,
        camera.height,
        far_m,
        if cull_back { "culled" } else { "drawn" },
    );
    println!(
        "  map loaded in {:.2} s; resident memory {:.0} MB (+{:.0} MB for the map)",
        t.elapsed().as_secs_f64(),
        status_mb("VmRSS:"),
        status_mb("VmRSS:") - rss_before_mb,
    );
    let mesh = Arc::new(mesh);

    if !only.gpu_only {
        let t = Instant::now();
        let mut cpu = CpuRenderer::with_lod(Arc::clone(&mesh), lod_px).expect("valid mesh");
        cpu.set_far_m(far_m);
        cpu.set_cull_back_faces(cull_back);
        let built_s = t.elapsed().as_secs_f64();
        println!(
            "  cpu renderer: {:.0} MB for the chunked mesh and textures ({} coarse chunks); resident memory {:.0} MB",
            cpu.mesh_bytes() as f64 / 1e6,
            cpu.coarse_chunks(),
            status_mb("VmRSS:"),
        );
        let split_vertices = ChunkedMesh::build(&mesh).expect("chunks").positions.len();
        let mut out = RenderedView::for_camera(&camera);
        let (mut binned, mut seen_triangles) = (0, 0);
        let fractions: Vec<f64> = poses
            .iter()
            .map(|p| {
                cpu.render(p, &camera, &mut out).expect("render");
                binned += cpu.binned_triangles();
                seen_triangles += cpu.seen(&out).2;
                cpu.cull_stats().visible_fraction()
            })
            .collect();
        let stats = cpu.cull_stats();
        println!(
            "  {} chunks, {split_vertices} vertices with copies at chunk borders \
             (renderer built in {built_s:.2} s); visible triangles: mean {:.1} %, min {:.1} %, max {:.1} %",
            stats.chunks,
            100.0 * fractions.iter().sum::<f64>() / fractions.len().max(1) as f64,
            100.0 * fractions.iter().copied().fold(f64::INFINITY, f64::min),
            100.0 * fractions.iter().copied().fold(0.0, f64::max),
        );
        println!(
            "  per view: {:.0} screen triangles binned, {:.0} mesh triangles seen (owning a pixel)",
            binned as f64 / poses.len().max(1) as f64,
            seen_triangles as f64 / poses.len().max(1) as f64,
        );
        // Frustum and occlusion cull (the default) with the level of
        // detail, then at full detail: that cull, frustum only, none.
        let modes = [
            (true, true, lod_px, "frustum + occlusion, level of detail"),
            (true, true, 0.0, "frustum + occlusion, full detail"),
            (true, false, 0.0, "frustum only, full detail"),
            (false, false, 0.0, "off, full detail"),
        ];
        let modes = if only.cpu_default {
            &modes[..1]
        } else {
            &modes[..]
        };
        for &(cull, occlusion, px, what) in modes {
            cpu.set_frustum_cull(cull);
            cpu.set_occlusion_cull(occlusion);
            cpu.set_lod_max_px(px);
            let (median, p95, n) = time_renders(&mut cpu, &camera, &poses);
            println!(
                "  cpu ({} threads, cull {what}): median {median:.1} ms, p95 {p95:.1} ms over {n} renders; {:.0} k triangles set up in the last",
                cpu.threads(),
                cpu.cull_stats().visible_triangles as f64 / 1e3,
            );
        }
        drop(cpu);
        if only.cpu_default {
            return;
        }
    }

    let t = Instant::now();
    match GpuRenderer::new_configured(Arc::clone(&mesh), adapter(), 0, lod_px) {
        Ok(mut gpu) => {
            gpu.set_far_m(far_m);
            gpu.set_cull_back_faces(cull_back);
            let built_s = t.elapsed().as_secs_f64();
            let mut out = RenderedView::for_camera(&camera);
            if let Some(p) = poses.first() {
                gpu.render(p, &camera, &mut out).expect("render");
            }
            let memory = gpu.memory();
            println!(
                "  {} (built in {built_s:.2} s); device memory {:.0} MB (mesh buffers {:.0} MB, textures {:.0} MB, targets {:.1} MB); resident memory {:.0} MB",
                gpu.name(),
                memory.total_bytes() as f64 / 1e6,
                memory.mesh_buffer_bytes as f64 / 1e6,
                memory.texture_bytes as f64 / 1e6,
                memory.target_bytes as f64 / 1e6,
                status_mb("VmRSS:"),
            );
            // Frustum and occlusion cull (the default), frustum only, none.
            let modes = [
                (true, true, "frustum + occlusion"),
                (true, false, "frustum only"),
                (false, false, "off"),
            ];
            let modes = if only.gpu_only {
                &modes[..1]
            } else {
                &modes[..]
            };
            for &(cull, occlusion, what) in modes {
                gpu.set_frustum_cull(cull);
                gpu.set_occlusion_cull(occlusion);
                let before = gpu.occlusion_stats();
                let (median, p95, n) = time_renders(&mut gpu, &camera, &poses);
                let after = gpu.occlusion_stats();
                let renders = (after.renders - before.renders) as f64;
                let occlusion_counts = if renders > 0.0 {
                    format!(
                        "; per render {:.2} passes, {:.0} of {:.0} clusters in view drawn ({:.0} in the first pass; {:.0} k triangles; {:.0} draw calls), \
                         {:.0} % with the previous render's clusters first",
                        (after.passes - before.passes) as f64 / renders,
                        (after.clusters_drawn - before.clusters_drawn) as f64 / renders,
                        (after.clusters_in_view - before.clusters_in_view) as f64 / renders,
                        (after.clusters_first_pass - before.clusters_first_pass) as f64 / renders,
                        (after.triangles_drawn - before.triangles_drawn) as f64 / renders / 1e3,
                        (after.draw_calls - before.draw_calls) as f64 / renders,
                        100.0 * (after.coherent_renders - before.coherent_renders) as f64 / renders,
                    )
                } else {
                    String::new()
                };
                println!(
                    "  wgpu {} (cull {what}): median {median:.1} ms, p95 {p95:.1} ms over {n} renders{occlusion_counts}",
                    adapter_label(),
                );
            }
            if !only.gpu_only {
                // The cull timed in flight, as a hardware adapter's renderer
                // runs by default (`render::gpu::cull_timing`).
                gpu.set_frustum_cull(true);
                gpu.set_occlusion_timed();
                let (median, p95, n) = time_renders(&mut gpu, &camera, &poses);
                let decision = gpu.cull_decision().map_or_else(
                    || "no trial finished".to_string(),
                    |d| {
                        format!(
                            "kept {} (trial medians: {:.1} ms with the cull, {:.1} ms frustum only)",
                            if d.occlusion { "the cull" } else { "the frustum cull alone" },
                            d.with_cull_s * 1e3,
                            d.frustum_only_s * 1e3
                        )
                    },
                );
                println!(
                    "  wgpu {} (cull timed): median {median:.1} ms, p95 {p95:.1} ms over {n} renders; {decision}",
                    adapter_label(),
                );
            }
            drop(gpu);
            if let Some(budget_mb) = gpu_budget_mb() {
                bench_gpu_budget(&mesh, &camera, &poses, far_m, budget_mb, cull_back);
            }
        }
        Err(e) => println!("  wgpu {}: no adapter, skipped ({e})", adapter_label()),
    }
}

/// `STAR_BENCH_GPU_BUDGET_MB`, when set.
fn gpu_budget_mb() -> Option<f64> {
    let v = std::env::var("STAR_BENCH_GPU_BUDGET_MB").ok()?;
    let mb: f64 = v.parse().expect("STAR_BENCH_GPU_BUDGET_MB: MB");
    assert!(
        mb.is_finite() && mb > 0.0,
        "STAR_BENCH_GPU_BUDGET_MB: positive MB"
    );
    Some(mb)
}

/// The adapter class the wgpu renderer is timed on: software (lavapipe,
/// llvmpipe) unless `STAR_BENCH_ADAPTER=hardware` asks for a hardware GPU.
fn adapter() -> AdapterPreference {
    match std::env::var("STAR_BENCH_ADAPTER").as_deref() {
        Ok("hardware") => AdapterPreference::Hardware,
        Ok("software") | Err(_) => AdapterPreference::Software,
        Ok(other) => panic!("STAR_BENCH_ADAPTER={other}: expected hardware or software"),
    }
}

/// [`adapter`]'s class in words.
fn adapter_label() -> &'static str {
    match adapter() {
        AdapterPreference::Hardware => "hardware",
        AdapterPreference::Software => "software",
    }
}

/// The wgpu renderer (cull on) with a GPU budget of `budget_mb`.
fn bench_gpu_budget(
    mesh: &Arc<Mesh>,
    camera: &PinholeCamera,
    poses: &[Pose],
    far_m: Option<f64>,
    budget_mb: f64,
    cull_back: bool,
) {
    let budget_bytes = (budget_mb * 1e6) as u64;
    let mut gpu = match GpuRenderer::new_with_budget(Arc::clone(mesh), adapter(), budget_bytes) {
        Ok(gpu) => gpu,
        Err(e) => {
            println!(
                "  wgpu {}, budget {budget_mb} MB: skipped ({e})",
                adapter_label()
            );
            return;
        }
    };
    gpu.set_far_m(far_m);
    gpu.set_cull_back_faces(cull_back);
    let mut out = RenderedView::for_camera(camera);
    for p in poses {
        gpu.render(p, camera, &mut out).expect("render");
    }
    let before = gpu.stream_stats();
    let (median, p95, n) = time_renders(&mut gpu, camera, poses);
    let after = gpu.stream_stats();
    let renders = (after.renders - before.renders).max(1) as f64;
    let per = |a: u64, b: u64| (a - b) as f64 / renders;
    let memory = gpu.memory();
    println!(
        "  wgpu {} (cull on, gpu_budget_mb {budget_mb}: {}): median {median:.1} ms, p95 {p95:.1} ms over {n} renders; \
         per render {:.1} chunk uploads, {:.1} evictions, {:.2} passes; device memory {:.0} MB (mesh buffers {:.1} MB)",
        adapter_label(),
        if after.slots == 0 {
            "the mesh fits, resident".to_string()
        } else {
            format!("{} slots of {:.0} kB", after.slots, after.slot_bytes as f64 / 1e3)
        },
        per(after.uploads, before.uploads),
        per(after.evictions, before.evictions),
        per(after.passes, before.passes),
        memory.total_bytes() as f64 / 1e6,
        memory.mesh_buffer_bytes as f64 / 1e6,
    );
}

/// Blocks of each dataset's renders in turn.
const INTERLEAVED_ROUNDS: usize = 6;

/// One dataset of [`bench_interleaved`]: its renderer, camera, poses,
/// output and render times.
struct Interleaved {
    renderer: Box<dyn Renderer>,
    camera: PinholeCamera,
    poses: Vec<Pose>,
    out: RenderedView,
    samples_ms: Vec<f64>,
}

/// The CPU rasterizer (default cull) on every dataset, in alternating
/// blocks: all poses of the first dataset, then of the second, and so on,
/// [`INTERLEAVED_ROUNDS`] times, so that a change of the machine's load
/// falls on all of them alike (a block keeps its renders in trajectory
/// order, as a tracker renders keyframes). Prints each median and p95 and
/// the ratio of each median to the first dataset's.
fn bench_interleaved(dirs: &[PathBuf], gpu: bool) {
    let mut runs: Vec<Interleaved> = dirs
        .iter()
        .map(|dir| {
            let (mesh, camera, poses, far_m, lod_px) = load(dir);
            let cull_back = cull_back_faces(dir);
            let renderer: Box<dyn Renderer> = if gpu {
                let mut r = GpuRenderer::new_configured(Arc::new(mesh), adapter(), 0, lod_px)
                    .expect("a wgpu adapter of STAR_BENCH_ADAPTER's class");
                r.set_far_m(far_m);
                r.set_cull_back_faces(cull_back);
                Box::new(r)
            } else {
                let mut r = CpuRenderer::with_lod(Arc::new(mesh), lod_px).expect("valid mesh");
                r.set_far_m(far_m);
                r.set_cull_back_faces(cull_back);
                Box::new(r)
            };
            let out = RenderedView::for_camera(&camera);
            Interleaved {
                renderer,
                camera,
                poses,
                out,
                samples_ms: Vec::new(),
            }
        })
        .collect();
    for r in &mut runs {
        for p in &r.poses {
            r.renderer.render(p, &r.camera, &mut r.out).expect("render");
        }
    }
    for _ in 0..INTERLEAVED_ROUNDS {
        for r in &mut runs {
            for p in &r.poses {
                let t = Instant::now();
                r.renderer.render(p, &r.camera, &mut r.out).expect("render");
                r.samples_ms.push(t.elapsed().as_secs_f64() * 1e3);
            }
        }
    }
    println!(
        "interleaved, {} (default cull), {INTERLEAVED_ROUNDS} alternating blocks of each dataset's poses:",
        runs.first().map_or(String::new(), |r| r.renderer.name()),
    );
    let mut first_median = None;
    for (dir, r) in dirs.iter().zip(&mut runs) {
        let n = r.samples_ms.len();
        let (median, p95) = median_p95(&mut r.samples_ms);
        let first = *first_median.get_or_insert(median);
        println!(
            "  {}: median {median:.1} ms, p95 {p95:.1} ms over {n} renders; {:.2}x the first",
            dir.display(),
            median / first,
        );
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    // Dataset folders: the arguments that are neither flags nor the value
    // of `--every`.
    let dirs: Vec<PathBuf> = args
        .iter()
        .enumerate()
        .filter(|(i, a)| {
            !a.starts_with("--")
                && (*i == 0 || args.get(i - 1).map(String::as_str) != Some("--every"))
        })
        .map(|(_, a)| PathBuf::from(a))
        .collect();
    if dirs.is_empty() {
        println!("render_map: no dataset given (cargo bench --bench render_map -- DATASET...)");
        return;
    }
    if std::env::args().any(|a| a == "--interleaved") {
        bench_interleaved(&dirs, std::env::args().any(|a| a == "--gpu-only"));
        return;
    }
    let only = Only {
        cpu_default: std::env::args().any(|a| a == "--cpu-default"),
        gpu_only: std::env::args().any(|a| a == "--gpu-only"),
    };
    for dir in &dirs {
        bench_dataset(dir, only);
    }
}
