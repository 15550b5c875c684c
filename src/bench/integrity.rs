//! `star bench integrity`: the figure that matters most, wrong poses sent
//! (more than 10 cm or 5 degrees from the truth), over cold starts, kidnaps
//! (teleports) and wrong initial hints, with the time each takes to recover.
//!
//! Stages: [`sequence`] writes a synthetic sequence of a preset; [`database`]
//! builds the relocalization database over the region it flies through
//! (the config's `[reloc]` grid, landmarks included); [`cold_starts`],
//! [`kidnaps`] and [`wrong_hints`] each run the offline STAR loop on
//! excerpts of the sequence from random, seeded places; [`print`] reports.
//! Frames are paced at the camera rate, as in flight, so the times to the
//! first correct pose (camera time) are those of this machine in flight.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result};
use nalgebra::{Translation3, Vector3};

use crate::config::Config;
use crate::dataset::{Dataset, Trajectory};
use crate::geometry::Pose;
use crate::map::Mesh;
use crate::offline::{
    is_wrong, localize_dataset, median_p99, pose_error, OfflineOptions, OfflineReport, StartMode,
};
use crate::reloc::{build_database_along, AlongTrajectory, RelocDatabase, Relocalizer};
use crate::render::cpu::CpuRenderer;
use crate::rng::SplitMix64;
use crate::synth::preset::Preset;
use crate::synth::sequence::{write_sequence, SequenceOptions};

/// What `star bench integrity` runs.
#[derive(Debug, Clone)]
pub struct IntegrityOptions {
    /// Preset of the sequence.
    pub preset: String,
    /// Seed of the sequence and of the random starts.
    pub seed: u64,
    /// Frames of the sequence.
    pub frames: usize,
    /// Cold starts, kidnaps and wrong hints, each.
    pub trials: usize,
    /// Configuration (`[reloc]`, `[tracker]`, `[keyframe]`, `[render]`).
    pub config: Config,
    /// Keep the sequence here (a temporary folder otherwise).
    pub keep: Option<PathBuf>,
    /// The scanned variant of the preset.
    pub scanned: bool,
    /// An existing dataset to run on instead of writing one.
    pub dataset: Option<PathBuf>,
    /// Read the database from this file when it exists, else write it there.
    pub database: Option<PathBuf>,
    /// Add views along the scanning run (`scan_groundtruth.txt`) to the
    /// database.
    pub scan_views: bool,
    /// Which kinds of trial to run.
    pub kinds: TrialKinds,
}

/// Which kinds of trial `star bench integrity` runs. Each kind draws its
/// random places from its own seeded stream, so running one kind alone
/// gives the same trials as running all three.
#[derive(Debug, Clone, Copy)]
pub struct TrialKinds {
    /// Cold starts without a pose.
    pub cold: bool,
    /// Kidnaps (teleports).
    pub kidnap: bool,
    /// Wrong initial hints.
    pub hint: bool,
}

impl Default for TrialKinds {
    fn default() -> Self {
        Self {
            cold: true,
            kidnap: true,
            hint: true,
        }
    }
}

impl std::str::FromStr for TrialKinds {
    type Err = anyhow::Error;

    /// Parses a comma-separated list of `cold`, `kidnap`, `hint` (or `all`).
    fn from_str(s: &str) -> Result<Self> {
        let mut kinds = Self {
            cold: false,
            kidnap: false,
            hint: false,
        };
        for word in s.split(',').map(str::trim) {
            match word {
                "cold" => kinds.cold = true,
                "kidnap" => kinds.kidnap = true,
                "hint" => kinds.hint = true,
                "all" => kinds = Self::default(),
                other => anyhow::bail!(
                    "unknown trial kind {other:?}: expected a comma-separated list of cold, kidnap, hint or all"
                ),
            }
        }
        Ok(kinds)
    }
}

/// One trial's outcome.
#[derive(Debug, Clone, Copy)]
struct Trial {
    wrong: usize,
    sent: usize,
    /// Camera time from the start (cold, hint) or from the jump (kidnap) to
    /// the first correct pose sent, s (paced at 50 Hz, camera time is wall
    /// time); `None` when none came. Until 2026-12-06 it was the first pose
    /// sent, correct or not, and wall time for cold starts and hints: the
    /// same wherever no pose was wrong.
    recovered_s: Option<f64>,
    /// The first wrong pose sent, if any: what sent it is what a reader of
    /// the bench asks next (a look-alike metres away, or a correct place a
    /// few centimetres past the line).
    first_wrong: Option<WrongPose>,
}

/// A wrong pose sent, as a trial's line reports it.
#[derive(Debug, Clone, Copy)]
struct WrongPose {
    /// Camera time from the start (cold, hint) or the jump (kidnap), s;
    /// negative before a kidnap's jump.
    after_s: f64,
    /// Distance from the truth, m.
    position_m: f64,
    /// Rotation from the truth, degrees.
    rotation_deg: f64,
    /// Kidnaps: distance from the last true position before the jump (the
    /// motion prior's centre), m.
    from_prior_m: Option<f64>,
}

/// Runs the bench and prints its figures.
pub fn run(options: &IntegrityOptions) -> Result<()> {
    let (tmp, root) = match &options.dataset {
        Some(root) => (None, root.clone()),
        None => {
            let tmp = tempfile_dir(options.keep.as_deref())?;
            let root = tmp.join("seq");
            (Some(tmp), root)
        }
    };
    let dataset = match options.dataset {
        Some(_) => Dataset::open(&root)
            .with_context(|| format!("opening the dataset {}", root.display()))?,
        None => sequence(&root, options)?,
    };
    let truth = dataset
        .ground_truth
        .clone()
        .context("the synthetic sequence has ground truth")?;
    let mesh = Arc::new(map_of(&root)?);
    let along = match options.scan_views {
        true => {
            let path = root.join("scan_groundtruth.txt");
            let scan = Trajectory::read(&path).with_context(|| {
                format!(
                    "reading the scanning run {} (--scan-views needs a scanned dataset)",
                    path.display()
                )
            })?;
            AlongTrajectory {
                poses: scan.poses,
                spacing_m: 0.5 * options.config.reloc.grid_spacing_m,
            }
        }
        false => AlongTrajectory::default(),
    };
    let db = flown_region_database(
        &mesh,
        &dataset,
        &truth,
        &options.config,
        &along,
        options.database.as_deref(),
    )?;
    println!(
        "integrity: {} seed {}: {} frames, map {} triangles; database {} views, {} landmarks over the flown region",
        match &options.dataset {
            Some(root) => format!("dataset {}", root.display()),
            None if options.scanned => format!("preset {} (scanned)", options.preset),
            None => format!("preset {}", options.preset),
        },
        options.seed,
        dataset.len(),
        mesh.triangle_count(),
        db.entries.len(),
        db.landmarks.len()
    );
    let runner = Runner {
        dataset: &dataset,
        truth: &truth,
        mesh: &mesh,
        db: &db,
        config: &options.config,
        twins: crate::reloc::twins::GeometricTwins::new(&mesh, &options.config.reloc),
    };
    // One random stream per kind, so that a kind run alone repeats itself.
    let stream = |k: u64| SplitMix64::new(options.seed ^ 0x1a7e_9e11 ^ (k << 32));
    let kinds = options.kinds;
    let mut cold = Vec::new();
    if kinds.cold {
        cold = cold_starts(&runner, options.trials, &mut stream(1))?;
        print("cold start (no pose)", &cold, 2.0);
    }
    let mut kidnap = Vec::new();
    if kinds.kidnap {
        kidnap = kidnaps(&runner, options.trials, &mut stream(2))?;
        print(
            "kidnap (teleport > 1 m), camera time after the jump",
            &kidnap,
            1.0,
        );
    }
    let mut hints = Vec::new();
    if kinds.hint {
        hints = wrong_hints(&runner, options.trials, &mut stream(3))?;
        print("wrong hint 1-3 m off", &hints, 2.0);
    }
    let all: Vec<Trial> = cold.iter().chain(&kidnap).chain(&hints).copied().collect();
    let wrong: usize = all.iter().map(|t| t.wrong).sum();
    let sent: usize = all.iter().map(|t| t.sent).sum();
    println!(
        "integrity: wrong poses sent {wrong} of {sent} over {} runs",
        all.len()
    );
    if let (Some(tmp), None) = (tmp, &options.keep) {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    Ok(())
}

/// The relocalization database over the region `dataset` flies through:
/// read from `path` when that file exists (and was built from `mesh`),
/// else built (and written to `path` when given).
pub(crate) fn flown_region_database(
    mesh: &Mesh,
    dataset: &Dataset,
    truth: &Trajectory,
    config: &Config,
    along: &AlongTrajectory,
    path: Option<&Path>,
) -> Result<RelocDatabase> {
    Ok(match path {
        Some(path) if path.exists() => {
            let db = RelocDatabase::read(path)
                .with_context(|| format!("reading the database {}", path.display()))?;
            if db.map_fingerprint != crate::reloc::map_fingerprint(mesh) {
                anyhow::bail!(
                    "the database {} was built from another map; delete it to rebuild",
                    path.display()
                );
            }
            db
        }
        Some(path) => {
            let db = database(mesh, dataset, truth, config, along)?;
            db.write(path)
                .with_context(|| format!("writing the database {}", path.display()))?;
            db
        }
        None => database(mesh, dataset, truth, config, along)?,
    })
}

/// The dataset's map in the world frame: `map/map.obj`, placed by the
/// `[map.world_from_mesh]` of `star.toml` beside it when there is one (a
/// scanned dataset's map is in the scanner's frame).
pub(crate) fn map_of(root: &Path) -> Result<Mesh> {
    let obj = root.join("map").join("map.obj");
    let placement = root.join("star.toml");
    let mesh = if placement.exists() {
        Config::load(&placement)
            .with_context(|| format!("loading {}", placement.display()))?
            .map
            .load_mesh_from(&obj)
    } else {
        crate::map::load_obj(&obj)
    };
    mesh.with_context(|| format!("loading the map {}", obj.display()))
}

fn tempfile_dir(keep: Option<&Path>) -> Result<PathBuf> {
    let dir = match keep {
        Some(dir) => dir.to_path_buf(),
        None => std::env::temp_dir().join(format!("star-bench-integrity-{}", std::process::id())),
    };
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    Ok(dir)
}

/// Writes the preset's sequence to `root` and opens it.
fn sequence(root: &Path, options: &IntegrityOptions) -> Result<Dataset> {
    let preset = Preset::by_name(&options.preset)
        .with_context(|| format!("unknown preset `{}`", options.preset))?;
    let preset = if options.scanned {
        preset.scanned()
    } else {
        preset
    };
    let sequence = SequenceOptions {
        preset,
        seed: options.seed,
        frames: options.frames,
        write_depth: false,
    };
    write_sequence(root, &sequence, &mut |_| {}).context("writing the sequence")?;
    Dataset::open(root).context("opening the sequence")
}

/// The database over the region the sequence flies through, 0.5 m around
/// it, at the sequence's mean height (the flight's height band), with the
/// views `along` a trajectory.
fn database(
    mesh: &Mesh,
    dataset: &Dataset,
    truth: &Trajectory,
    config: &Config,
    along: &AlongTrajectory,
) -> Result<RelocDatabase> {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in &truth.poses {
        for k in 0..3 {
            lo[k] = lo[k].min(p.translation.vector[k] as f32);
            hi[k] = hi[k].max(p.translation.vector[k] as f32);
        }
    }
    let mean_z =
        truth.poses.iter().map(|p| p.translation.z).sum::<f64>() / truth.len().max(1) as f64;
    let mut reloc = config.reloc.clone();
    reloc.heights_m = vec![mean_z];
    reloc.landmark_heights_m = vec![mean_z];
    // The flight's heights are world heights.
    reloc.floor_z_m = Some(0.0);
    reloc.bounds_margin_m = 0.0;
    let pad = 0.5;
    let region = (
        [lo[0] - pad, lo[1] - pad, (mean_z - 0.1) as f32],
        [hi[0] + pad, hi[1] + pad, (mean_z + 0.1) as f32],
    );
    let mut renderer = CpuRenderer::new(Arc::new(mesh.clone())).context("CPU renderer")?;
    let bar = indicatif::ProgressBar::new(0);
    let db = build_database_along(
        mesh,
        dataset.camera(),
        &mut renderer,
        &reloc,
        Some(region),
        along,
        &mut |done, total| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        },
    )
    .context("building the database")?;
    bar.finish_and_clear();
    Ok(db)
}

struct Runner<'a> {
    dataset: &'a Dataset,
    truth: &'a Trajectory,
    mesh: &'a Arc<Mesh>,
    db: &'a RelocDatabase,
    config: &'a Config,
    /// The map's geometric twins, built once for every trial.
    twins: crate::reloc::twins::GeometricTwins,
}

impl Runner<'_> {
    /// Runs frames `order` of the sequence (truth to match), paced, from
    /// `start`.
    fn run(
        &self,
        order: &[usize],
        start: StartMode,
        hint: Option<Pose>,
    ) -> Result<(OfflineReport, Trajectory)> {
        let mut ds = self.dataset.clone();
        let stamps: Vec<f64> = self.dataset.frames.iter().map(|f| f.timestamp_s).collect();
        let mut truth = Trajectory::default();
        ds.frames = order
            .iter()
            .enumerate()
            .map(|(k, &i)| {
                let mut f = self.dataset.frames[i].clone();
                f.path = self.dataset.root.join(&f.path);
                f.timestamp_s = stamps[0] + k as f64 / 50.0;
                truth.push(f.timestamp_s, self.truth.poses[i]);
                f
            })
            .collect();
        ds.ground_truth = Some(truth.clone());
        let renderer =
            crate::render::select::make_configured_renderer(&self.config.render, self.mesh.clone())
                .context("renderer")?;
        let options = OfflineOptions {
            world_from_camera_start: hint,
            realtime: true,
            relocalizer: Some(
                Relocalizer::new(self.db.clone(), &self.config.reloc, ds.camera())?
                    .with_twins(self.twins.clone()),
            ),
            start,
            ..OfflineOptions::default()
        };
        let report = localize_dataset(&ds, renderer, self.config, &options, |_| {})?;
        Ok((report, truth))
    }
}

impl Trial {
    /// One line for this trial, so that a failing one can be rerun alone.
    fn print(&self, kind: &str, place: &str) {
        let recovered = match self.recovered_s {
            Some(s) => format!("first correct pose after {s:.2} s"),
            None => "never recovered".to_owned(),
        };
        let first_wrong = self.first_wrong.map_or(String::new(), |w| {
            let prior = w.from_prior_m.map_or(String::new(), |m| {
                format!(", {m:.2} m from the last position before the jump")
            });
            format!(
                " (the first at {:.2} s: {:.1} cm, {:.2} deg from the truth{prior})",
                w.after_s,
                100.0 * w.position_m,
                w.rotation_deg
            )
        });
        println!(
            "    {kind} ({place}): {recovered}; wrong poses {} of {}{first_wrong}",
            self.wrong, self.sent
        );
    }
}

/// The first pose of `estimate` (the poses sent) that is wrong against
/// `truth`, its time counted from `from_s` (the run's dataset time);
/// `prior_position` (a kidnap's last true position before the jump) gives
/// its distance from there.
fn first_wrong(
    estimate: &Trajectory,
    truth: &Trajectory,
    from_s: f64,
    prior_position: Option<Vector3<f64>>,
) -> Option<WrongPose> {
    estimate
        .stamps_s
        .iter()
        .zip(&estimate.poses)
        .find_map(|(t, pose)| {
            let error = pose_error(truth, *t, pose).filter(|e| is_wrong(*e))?;
            Some(WrongPose {
                after_s: t - from_s,
                position_m: error.0,
                rotation_deg: error.1,
                from_prior_m: prior_position.map(|p| (pose.translation.vector - p).norm()),
            })
        })
}

/// Camera time from `from_s` (the run's dataset time) to the first pose of
/// `estimate` (the poses sent) at or after it that is correct (not wrong
/// against `truth`, as the integrity count judges it); `None` when none
/// came.
fn first_correct_s(estimate: &Trajectory, truth: &Trajectory, from_s: f64) -> Option<f64> {
    estimate
        .stamps_s
        .iter()
        .zip(&estimate.poses)
        .filter(|(t, _)| **t >= from_s)
        .find(|(t, pose)| pose_error(truth, **t, pose).is_some_and(|e| !is_wrong(e)))
        .map(|(t, _)| t - from_s)
}

fn trial(
    report: &OfflineReport,
    recovered_s: Option<f64>,
    first_wrong: Option<WrongPose>,
) -> Trial {
    let integrity = report.integrity.unwrap_or_default();
    Trial {
        wrong: integrity.wrong_poses,
        sent: report.estimate.len(),
        recovered_s,
        first_wrong,
    }
}

/// A 3 s excerpt (150 frames at 50 Hz) from a random frame: the frame
/// indices.
fn excerpt(n: usize, rng: &mut SplitMix64) -> Vec<usize> {
    let length = 150.min(n);
    let first = rng.below(n - length + 1);
    (first..first + length).collect()
}

/// Cold starts: 3 s excerpts from random frames, no pose given.
fn cold_starts(runner: &Runner, trials: usize, rng: &mut SplitMix64) -> Result<Vec<Trial>> {
    let n = runner.dataset.len();
    (0..trials)
        .map(|_| {
            let order = excerpt(n, rng);
            let (report, truth) = runner.run(&order, StartMode::Cold, None)?;
            let start_s = truth.stamps_s.first().copied().unwrap_or(0.0);
            let t = trial(
                &report,
                first_correct_s(&report.estimate, &truth, start_s),
                first_wrong(&report.estimate, &truth, start_s, None),
            );
            t.print("cold start", &format!("frames {}..", order[0]));
            Ok(t)
        })
        .collect()
}

/// Kidnaps: 1 s tracked from a trusted start, then a jump to a random
/// frame more than 1 m away, 2 s after it.
fn kidnaps(runner: &Runner, trials: usize, rng: &mut SplitMix64) -> Result<Vec<Trial>> {
    let n = runner.dataset.len();
    let (before, after) = (50.min(n / 3), 100.min(n / 2));
    let position = |i: usize| runner.truth.poses[i].translation.vector;
    let mut out = Vec::with_capacity(trials);
    for _ in 0..trials {
        let a = rng.below(n - before);
        let mut b = rng.below(n - after);
        for _ in 0..100 {
            if (position(b) - position(a + before - 1)).norm() > 1.0 {
                break;
            }
            b = rng.below(n - after);
        }
        let order: Vec<usize> = (a..a + before).chain(b..b + after).collect();
        let jump_m = (position(b) - position(a + before - 1)).norm();
        let (report, truth) =
            runner.run(&order, StartMode::Trusted, Some(runner.truth.poses[a]))?;
        // The first correct pose after the jump, in frames at 50 Hz.
        let jump_s = before as f64 / 50.0;
        let first_stamp = truth.stamps_s.first().copied().unwrap_or(0.0);
        let jump_at_s = first_stamp + jump_s;
        let t = trial(
            &report,
            first_correct_s(&report.estimate, &truth, jump_at_s),
            first_wrong(
                &report.estimate,
                &truth,
                jump_at_s,
                Some(position(a + before - 1)),
            ),
        );
        t.print(
            "kidnap",
            &format!(
                "frames {a}..{} then {b}..{}, {jump_m:.2} m",
                a + before,
                b + after
            ),
        );
        out.push(t);
    }
    Ok(out)
}

/// Wrong hints: 3 s excerpts from random frames, the start pose given 1 to
/// 3 m away from the truth in a random horizontal direction.
fn wrong_hints(runner: &Runner, trials: usize, rng: &mut SplitMix64) -> Result<Vec<Trial>> {
    let n = runner.dataset.len();
    (0..trials)
        .map(|_| {
            let order = excerpt(n, rng);
            let truth = runner.truth.poses[order[0]];
            let angle = rng.range(0.0, std::f64::consts::TAU);
            let offset_m = rng.range(1.0, 3.0);
            let shift = Vector3::new(angle.cos(), angle.sin(), 0.0) * offset_m;
            let hint = Pose::from_parts(
                Translation3::from(truth.translation.vector + shift),
                truth.rotation,
            );
            let (report, truth) = runner.run(&order, StartMode::Hint, Some(hint))?;
            let start_s = truth.stamps_s.first().copied().unwrap_or(0.0);
            let t = trial(
                &report,
                first_correct_s(&report.estimate, &truth, start_s),
                first_wrong(&report.estimate, &truth, start_s, None),
            );
            t.print(
                "wrong hint",
                &format!("frames {}.., {offset_m:.2} m off", order[0]),
            );
            Ok(t)
        })
        .collect()
}

/// Prints one family of trials: wrong poses, how many recovered within
/// `within_s`, and the recovery time's median and p95 over those that did.
fn print(what: &str, trials: &[Trial], within_s: f64) {
    let wrong: usize = trials.iter().map(|t| t.wrong).sum();
    let sent: usize = trials.iter().map(|t| t.sent).sum();
    let mut times: Vec<f64> = trials.iter().filter_map(|t| t.recovered_s).collect();
    let in_time = times.iter().filter(|&&s| s <= within_s).count();
    times.sort_by(f64::total_cmp);
    let (median, _) = median_p99(&times);
    let p95 = times
        .get(((times.len() as f64 * 0.95).ceil() as usize).saturating_sub(1))
        .copied()
        .unwrap_or(f64::NAN);
    println!(
        "  {what}: {} runs, wrong poses sent {wrong} of {sent}; first correct pose within {within_s} s in {in_time} of {} ({:.0} %), never in {}; time to it median {median:.2} s, p95 {p95:.2} s",
        trials.len(),
        trials.len(),
        100.0 * in_time as f64 / trials.len().max(1) as f64,
        trials.len() - times.len()
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at_x(x_m: f64) -> Pose {
        Pose::from_parts(Translation3::new(x_m, 0.0, 1.4), Default::default())
    }

    #[test]
    fn recovery_is_the_first_correct_pose_sent_not_the_first_pose() {
        let mut truth = Trajectory::default();
        for k in 0..10 {
            truth.push(k as f64 * 0.02, at_x(0.0));
        }
        let mut estimate = Trajectory::default();
        // Before the jump (not counted), then a wrong pose, then a right one.
        estimate.push(0.02, at_x(0.0));
        estimate.push(0.10, at_x(2.0));
        estimate.push(0.14, at_x(0.05));
        let s = first_correct_s(&estimate, &truth, 0.06).unwrap_or(f64::NAN);
        assert!((s - 0.08).abs() < 1e-9, "{s}");
        assert_eq!(first_correct_s(&estimate, &truth, 0.15), None);
        // Only wrong poses after it: never recovered.
        let mut wrong = Trajectory::default();
        wrong.push(0.10, at_x(0.5));
        assert_eq!(first_correct_s(&wrong, &truth, 0.0), None);
    }

    #[test]
    fn the_first_wrong_pose_is_reported_with_its_error_and_distance_from_the_prior() {
        let mut truth = Trajectory::default();
        for k in 0..10 {
            truth.push(k as f64 * 0.02, at_x(0.0));
        }
        let mut estimate = Trajectory::default();
        estimate.push(0.02, at_x(0.05)); // 5 cm: correct
        estimate.push(0.10, at_x(0.12)); // 12 cm: the first wrong one
        estimate.push(0.14, at_x(2.0)); // wrong too, not the first
        let w = first_wrong(&estimate, &truth, 0.06, Some(Vector3::new(1.0, 0.0, 1.4)))
            .expect("a wrong pose");
        assert!((w.after_s - 0.04).abs() < 1e-9, "{}", w.after_s);
        assert!((w.position_m - 0.12).abs() < 1e-9, "{}", w.position_m);
        assert!(w.rotation_deg.abs() < 1e-9);
        let from_prior_m = w.from_prior_m.unwrap_or(f64::NAN);
        assert!((from_prior_m - 0.88).abs() < 1e-9, "{from_prior_m}");
        // None wrong: nothing to report.
        let mut right = Trajectory::default();
        right.push(0.10, at_x(0.02));
        assert!(first_wrong(&right, &truth, 0.0, None).is_none());
    }
}
