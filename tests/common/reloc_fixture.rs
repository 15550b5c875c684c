//! The relocalization fixture of the end-to-end recovery and integrity
//! tests: a short `realistic` sequence and a small database over the region
//! it flies through, and datasets spliced from it with faults.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

use std::path::{Path, PathBuf};
use std::sync::Arc;

use star::config::Config;
use star::dataset::{write_gray8, Dataset, Trajectory};
use star::geometry::Pose;
use star::imgproc::ImageU8;
use star::offline::{localize_dataset, OfflineOptions, OfflineReport};
use star::reloc::{build_database_in, RelocConfig, RelocDatabase, Relocalizer};
use star::render::cpu::CpuRenderer;
use star::synth::preset::Preset;
use star::synth::sequence::{write_sequence, SequenceOptions};

/// Frames of the fixture sequence.
pub const FRAMES: usize = 200;
/// The frame where the faults start.
pub const FAULT_START: usize = 50;

/// One synthetic sequence (realistic preset) and a small database over the
/// region it flies through, shared by both cases.
pub struct Fixture {
    pub _tmp: tempfile::TempDir,
    pub root: std::path::PathBuf,
    pub gt: Trajectory,
    pub db: RelocDatabase,
    pub config: Config,
    /// The box the database's views were taken in (the flight's, padded).
    pub region: ([f32; 3], [f32; 3]),
}

/// The fixture of seed 3, built once per test binary and shared by its
/// tests, which only read it (each test built its own before, and
/// `integrity.rs`'s look-alike room three; sharing took a minute off
/// `integrity.rs`: docs/ci.md).
/// Its folder is removed when the process exits.
pub fn fixture() -> &'static Fixture {
    static SHARED: std::sync::OnceLock<Fixture> = std::sync::OnceLock::new();
    SHARED.get_or_init(|| {
        let fx = fixture_with_seed(3);
        remove_at_exit(fx._tmp.path());
        fx
    })
}

/// Folders to remove when the process exits: a `static` is never
/// dropped, so the shared fixture's `TempDir` would stay behind.
static AT_EXIT: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

extern "C" fn remove_folders() {
    if let Ok(dirs) = AT_EXIT.lock() {
        for dir in dirs.iter() {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

fn remove_at_exit(dir: &Path) {
    let mut dirs = AT_EXIT.lock().expect("at-exit list");
    if dirs.is_empty() {
        // SAFETY: `remove_folders` is a plain function that only touches
        // the file system and a static; registering it has no other effect.
        let registered = unsafe { libc::atexit(remove_folders) };
        assert_eq!(registered, 0, "atexit");
    }
    dirs.push(dir.to_path_buf());
}

/// The fixture for sequence seed `seed`.
pub fn fixture_with_seed(seed: u64) -> Fixture {
    let tmp = tempfile::tempdir().expect("tmp");
    let root = tmp.path().join("seq");
    let options = SequenceOptions {
        preset: Preset::by_name("realistic").expect("preset"),
        seed,
        frames: FRAMES,
        write_depth: false,
    };
    write_sequence(&root, &options, &mut |_| {}).expect("sequence");
    let ds = Dataset::open(&root).expect("dataset");
    let gt = ds.ground_truth.clone().expect("ground truth");
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in &gt.poses {
        for k in 0..3 {
            lo[k] = lo[k].min(p.translation.vector[k] as f32);
            hi[k] = hi[k].max(p.translation.vector[k] as f32);
        }
    }
    let mean_z = gt.poses.iter().map(|p| p.translation.z).sum::<f64>() / gt.len() as f64;
    let mut config = Config::default();
    config.render.renderer = star::config::RendererKind::Cpu;
    config.reloc = RelocConfig {
        grid_spacing_m: 0.3,
        heights_m: vec![mean_z],
        // The flight's heights are world heights.
        floor_z_m: Some(0.0),
        yaw_steps: 24,
        bounds_margin_m: 0.0,
        landmark_spacing_m: 0.4,
        landmark_heights_m: vec![mean_z],
        ..RelocConfig::default()
    };
    let pad = 0.3;
    let region = (
        [lo[0] - pad, lo[1] - pad, (mean_z - 0.1) as f32],
        [hi[0] + pad, hi[1] + pad, (mean_z + 0.1) as f32],
    );
    let mesh = Arc::new(star::map::load_obj(&root.join("map").join("map.obj")).expect("map"));
    let mut renderer = CpuRenderer::new(mesh.clone()).expect("renderer");
    let db = build_database_in(
        &mesh,
        ds.camera(),
        &mut renderer,
        &config.reloc,
        Some(region),
        &mut |_, _| {},
    )
    .expect("database");
    assert!(db.entries.len() > 100, "{} entries", db.entries.len());
    assert!(
        db.landmarks.len() > 1000,
        "{} landmarks",
        db.landmarks.len()
    );
    Fixture {
        _tmp: tmp,
        root,
        gt,
        db,
        config,
        region,
    }
}

/// Writes a dataset at `dir` whose frame `i` shows `source(i)` (a frame index
/// of the fixture sequence, or `None` for black) at the original stamps,
/// with ground truth to match.
pub fn spliced(fx: &Fixture, dir: &Path, source: impl Fn(usize) -> Option<usize>) -> Dataset {
    std::fs::create_dir_all(dir).expect("dir");
    std::fs::copy(fx.root.join("camera.toml"), dir.join("camera.toml")).expect("camera");
    let black = dir.join("black.png");
    write_gray8(&black, &ImageU8::new(640, 512, 0)).expect("black");
    let ds = Dataset::open(&fx.root).expect("dataset");
    let mut rgb = String::from("# timestamp filename\n");
    let mut gt = Trajectory::default();
    for i in 0..FRAMES {
        let stamp_s = ds.frames[i].timestamp_s;
        match source(i) {
            Some(j) => {
                let path = fx.root.join(&ds.frames[j].path);
                rgb.push_str(&format!("{stamp_s:.6} {}\n", path.display()));
                gt.push(stamp_s, fx.gt.poses[j]);
            }
            None => {
                rgb.push_str(&format!("{stamp_s:.6} {}\n", black.display()));
                // The truth still moves on during a blackout.
                gt.push(stamp_s, fx.gt.poses[i]);
            }
        }
    }
    std::fs::write(dir.join("rgb.txt"), rgb).expect("rgb.txt");
    gt.write(&dir.join("groundtruth.txt")).expect("gt");
    Dataset::open(dir).expect("spliced dataset")
}

pub fn run(fx: &Fixture, ds: &Dataset) -> OfflineReport {
    run_with(fx, ds, OfflineOptions::default(), true)
}

/// Runs `ds` with `options`, and the fixture's database when `database`.
pub fn run_with(
    fx: &Fixture,
    ds: &Dataset,
    mut options: OfflineOptions,
    database: bool,
) -> OfflineReport {
    let mesh = star::map::load_obj(&fx.root.join("map").join("map.obj")).expect("map");
    let renderer = Box::new(CpuRenderer::new(Arc::new(mesh)).expect("renderer"));
    if database {
        let reloc = Relocalizer::new(fx.db.clone(), &fx.config.reloc, ds.camera()).expect("reloc");
        options.relocalizer = Some(reloc);
    }
    localize_dataset(ds, renderer, &fx.config, &options, |_| {}).expect("localize")
}

/// Writes a dataset at `dir` whose frame `i` is the image `frame(i).0` with
/// ground truth `frame(i).1`, at the fixture's stamps.
pub fn assembled(fx: &Fixture, dir: &Path, frame: impl Fn(usize) -> (PathBuf, Pose)) -> Dataset {
    std::fs::create_dir_all(dir).expect("dir");
    std::fs::copy(fx.root.join("camera.toml"), dir.join("camera.toml")).expect("camera");
    let ds = Dataset::open(&fx.root).expect("dataset");
    let mut rgb = String::from("# timestamp filename\n");
    let mut gt = Trajectory::default();
    for i in 0..FRAMES {
        let stamp_s = ds.frames[i].timestamp_s;
        let (path, truth) = frame(i);
        rgb.push_str(&format!("{stamp_s:.6} {}\n", path.display()));
        gt.push(stamp_s, truth);
    }
    std::fs::write(dir.join("rgb.txt"), rgb).expect("rgb.txt");
    gt.write(&dir.join("groundtruth.txt")).expect("gt");
    Dataset::open(dir).expect("assembled dataset")
}

/// The path of the fixture's frame `i`.
pub fn frame_path(fx: &Fixture, i: usize) -> PathBuf {
    let ds = Dataset::open(&fx.root).expect("dataset");
    fx.root.join(&ds.frames[i].path)
}

/// Writes a gray image `fill(x, y)` of the fixture's size to `path`.
pub fn write_image(path: &Path, fill: impl Fn(usize, usize) -> u8) -> PathBuf {
    let mut img = ImageU8::new(640, 512, 0);
    for (i, v) in img.data_mut().iter_mut().enumerate() {
        *v = fill(i % 640, i / 640);
    }
    write_gray8(path, &img).expect("image");
    path.to_path_buf()
}
