//! `star bench reloc`: relocalization on the synthetic realistic scene
//! (prints figures, never pass/fail).
//!
//! Builds a database for the map mesh of the `realistic` preset's scene
//! (CPU renderer), then queries random free poses rendered from the truth
//! mesh (occluders, no map holes) through the lens distortion and the
//! realistic sensor model, and reports the success rate (accepted pose
//! within 5 cm and 2 degrees of the truth), false accepts, the distance
//! from the query to the best-ranked keyframe, the search time over 10k
//! keyframes, and the recovery time (landmark matching and PnP, then the
//! descriptor search when needed, render, align), as the service orders
//! them. The descriptor search also runs, untimed, after a landmark pose is
//! accepted, for the retrieval figures.
//!
//! Candidates are rendered by the configured `[render] renderer`, as in
//! the service; the database is built with the CPU rasterizer.
//! `STAR_BENCH_VERBOSE=1` prints, for each query of the whole-map search,
//! the verdict, where the best near keyframe ranked, the top candidates'
//! distances from the truth, whether the database entry nearest the truth
//! would have been accepted, and the alignment quality against a keyframe
//! rendered at the truth itself; `STAR_BENCH_DUMP=DIR` also writes each
//! query frame there as `qNNN.png`; `STAR_BENCH_ROLL_DEG=R` rolls the
//! queries uniformly within +-R degrees (the database views have no roll).

use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use nalgebra::{Translation3, Vector3};

use crate::config::Config;
use crate::geometry::look::camera_rotation;
use crate::geometry::Pose;
use crate::imgproc::{ImageF32, ImageU8};
use crate::offline::median_p99;
use crate::reloc::{build_database, try_candidate, Relocalizer, SearchRegion};
use crate::reloc::{Candidate, Query, Ranked, SearchIndex, LANDMARK_CANDIDATE, MAX_TOP_K};
use crate::render::cpu::CpuRenderer;
use crate::render::{RenderedView, Renderer};
use crate::rng::SplitMix64;
use crate::synth::corrupt::{DistortionWarp, SensorModel};
use crate::synth::preset::Preset;
use crate::synth::sequence::preset_scene;
use crate::track::{Aligner, Keyframe, Pyramid};

/// Runs the benchmark with `queries` random poses.
pub fn run(config_path: Option<&std::path::Path>, queries: usize, seed: u64) -> Result<()> {
    let config = match config_path {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    };
    let rc = &config.reloc;
    if queries == 0 {
        anyhow::bail!("--queries must be at least 1");
    }
    let preset = Preset::by_name("realistic").context("preset `realistic`")?;
    let scene = preset_scene(&preset, seed);
    let camera = preset.camera;
    let map = Arc::new(scene.map.clone());
    let mut map_r = CpuRenderer::new(map.clone())?;
    // Candidates are rendered as the service renders them: by the
    // `[render] renderer` of the configuration (auto: a hardware adapter,
    // else lavapipe, else the CPU rasterizer).
    let kind = config.render.renderer;
    let mut candidate_r = crate::render::select::make_renderer(kind, map.clone())
        .with_context(|| format!("starting the `{kind:?}` renderer"))?;

    let t0 = Instant::now();
    let bar = indicatif::ProgressBar::new(0);
    let db = build_database(&map, &camera, &mut map_r, rc, &mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })?;
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

    // Queries: truth mesh, distortion, sensor model.
    let mut truth_r = CpuRenderer::new(Arc::new(scene.truth.clone()))?;
    let warp = DistortionWarp::new(&camera)?;
    let render_camera = *warp.render_camera();
    let sensor = SensorModel::new(preset.photometric, &camera, seed);
    let mut qview = RenderedView::for_camera(&render_camera);
    let mut warped = ImageF32::new(0, 0, 0.0);
    let mut frame = ImageU8::new(0, 0, 0);
    let pinhole = camera.pinhole();
    // As the STAR loop builds them: one pyramid level more than tracking.
    let tracker = crate::track::build_config(&config.tracker);
    let mut kview = RenderedView::for_camera(&pinhole);
    // Keyframes for a candidate and each of its re-renders (recycled ones
    // come back only after the candidate is done).
    let renders_per_candidate = 1 + rc.refine_renders as usize;
    let mut spare: Vec<Box<Keyframe>> = (0..renders_per_candidate)
        .map(|_| Box::new(Keyframe::new(&pinhole, &tracker)))
        .collect();
    let mut returned = Vec::with_capacity(renders_per_candidate);
    let mut aligner = Aligner::new(&tracker);
    let mut pyramid = Pyramid::new(
        camera.width as usize,
        camera.height as usize,
        tracker.pyramid_levels as usize,
    );
    let mut reloc = Relocalizer::new(db.clone(), rc, &camera)?;

    let (z_lo, z_hi) = rc
        .heights_m
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &h| {
            (a.min(h), b.max(h))
        });
    let pitch_mid = rc.pitches_deg.iter().sum::<f64>() / rc.pitches_deg.len() as f64;
    let verbose = std::env::var_os("STAR_BENCH_VERBOSE").is_some();
    let max_roll_deg = std::env::var("STAR_BENCH_ROLL_DEG")
        .ok()
        .map(|v| {
            v.parse::<f64>()
                .ok()
                .filter(|r| r.is_finite() && *r >= 0.0 && *r < 90.0)
                .with_context(|| format!("STAR_BENCH_ROLL_DEG={v}: expected degrees in 0..90"))
        })
        .transpose()?;
    let mut rng = SplitMix64::new(seed ^ 0x7e10c);
    let (mut done, mut tries) = (0usize, 0usize);
    let mut global = Tally {
        rank_candidates: rc.rank_candidates,
        ..Tally::default()
    };
    let mut window = Tally {
        rank_candidates: rc.rank_candidates,
        ..Tally::default()
    };
    while done < queries && tries < queries * 100 {
        tries += 1;
        let p = Vector3::new(
            rng.range(scene.free_min_m[0], scene.free_max_m[0]),
            rng.range(scene.free_min_m[1], scene.free_max_m[1]),
            rng.range(z_lo, z_hi),
        );
        if !scene.is_free([p.x, p.y, p.z], 0.4) {
            continue;
        }
        let yaw = rng.range(-std::f64::consts::PI, std::f64::consts::PI);
        let pitch = (pitch_mid + rng.range(-5.0, 5.0)).to_radians();
        // STAR_BENCH_ROLL_DEG=R: queries rolled uniformly within +-R deg
        // (the database views have none; no draw without it, so the default
        // queries stay the same).
        let roll = max_roll_deg.map_or(0.0, |r| rng.range(-r, r).to_radians());
        let truth = Pose::from_parts(Translation3::from(p), camera_rotation(yaw, pitch, roll));
        truth_r.render(&truth, &render_camera, &mut qview)?;
        let hits = qview.depth_m.data().iter().filter(|&&d| d > 0.0).count();
        if hits < qview.depth_m.data().len() * 6 / 10 {
            continue;
        }
        done += 1;
        warp.warp_gray(&qview.gray, &mut warped);
        sensor.apply(&warped, done as u64, rng.range(0.0, 60.0), &mut frame);
        pyramid.fill_from_u8(frame.data(), frame.width());
        // The paper's protocol: a 2 m window around where the vehicle was
        // last known (here the truth displaced by up to 0.5 m).
        let center_m = p + Vector3::new(rng.range(-0.5, 0.5), rng.range(-0.5, 0.5), 0.0);
        let regions = [
            (SearchRegion::Everywhere, &mut global),
            (
                SearchRegion::Near {
                    center_m,
                    radius_m: 2.0,
                },
                &mut window,
            ),
        ];
        for (region, tally) in regions {
            let t_query = Instant::now();
            let Some(query) =
                reloc.describe(frame.data(), frame.width(), frame.height(), frame.width())
            else {
                tally.rejected += 1;
                continue;
            };
            // As the service: the landmark pose first, then (when it is
            // missing or refused) the database views by descriptor.
            let t_landmarks = Instant::now();
            let landmark = reloc.landmark_candidate(
                frame.data(),
                frame.width(),
                frame.height(),
                frame.width(),
                region,
            );
            tally
                .landmark_ms
                .push(t_landmarks.elapsed().as_secs_f64() * 1e3);
            let mut candidates: Vec<Candidate> = Vec::new();
            if let Some((c, found)) = landmark {
                let e = truth.inverse() * c.world_from_camera;
                let right =
                    e.translation.vector.norm() <= 0.1 && e.rotation.angle().to_degrees() <= 3.0;
                tally.located += 1;
                tally.located_right += usize::from(right);
                tally
                    .located_inliers
                    .push((found.inliers, found.matches, right));
                candidates.push(c);
            }
            let mut verdict = None;
            let mut untimed_ms = 0.0;
            let mut tried = 0;
            for pass in 0..2 {
                if pass == 1 {
                    // The descriptor search runs for the retrieval figures
                    // even when the landmark pose was accepted; it counts in
                    // the recovery time only when it was needed.
                    let t_rank = Instant::now();
                    let ranked = reloc.search_ranked(&query, region, &mut aligner, &pyramid);
                    candidates.extend_from_slice(ranked);
                    let rank_ms = t_rank.elapsed().as_secs_f64() * 1e3;
                    tally.rank_ms.push(rank_ms);
                    if verdict.is_some() {
                        untimed_ms += rank_ms;
                        break;
                    }
                }
                while tried < candidates.len() {
                    let c = candidates[tried];
                    tried += 1;
                    let r = &c.ranked;
                    let mut render = |world_from_keyframe: &Pose, kf: &mut Keyframe| {
                        let t_render = Instant::now();
                        candidate_r
                            .render(world_from_keyframe, &pinhole, &mut kview)
                            .ok()?;
                        tally.renders += 1;
                        let t_prepare = Instant::now();
                        kf.prepare(&kview, *world_from_keyframe, u64::from(r.index), &tracker);
                        tally.prepare_ms += t_prepare.elapsed().as_secs_f64() * 1e3;
                        tally.render_ms += t_render.elapsed().as_secs_f64() * 1e3;
                        Some(())
                    };
                    verdict = attempt(
                        &mut aligner,
                        &pyramid,
                        &camera,
                        rc,
                        (&c.world_from_camera, c.yaw_rad),
                        (&mut spare, &mut returned),
                        &mut render,
                    );
                    if verdict.is_some() {
                        tally.from_landmarks += usize::from(r.index == LANDMARK_CANDIDATE);
                        break;
                    }
                }
            }
            let ms = t_query.elapsed().as_secs_f64() * 1e3 - untimed_ms;
            tally.recovery_ms.push(ms);
            if let Some(first) = candidates.first() {
                tally
                    .retrieved_m
                    .push((first.world_from_camera.translation.vector - p).norm());
            }
            if let Some(first) = candidates
                .iter()
                .find(|c| c.ranked.index != LANDMARK_CANDIDATE)
            {
                tally
                    .descriptor_m
                    .push((first.world_from_camera.translation.vector - p).norm());
            }
            // Retrieval alone: is a candidate near the truth among the
            // landmark pose and the top k?
            let is_near = |world_from_camera: &Pose| {
                let e = truth.inverse() * world_from_camera;
                e.translation.vector.norm() <= 0.5 && e.rotation.angle().to_degrees() <= 20.0
            };
            let near_truth = candidates.iter().any(|c| is_near(&c.world_from_camera));
            tally.retrieved_near += usize::from(near_truth);
            if matches!(region, SearchRegion::Everywhere) {
                // Where the nearest good keyframe sits in the full ranking:
                // what a re-ranking stage over the top N could recover.
                let distance = |e: &crate::reloc::RelocEntry| {
                    query
                        .iter()
                        .map(|q| q.hamming(&e.descriptor))
                        .min()
                        .unwrap_or(u32::MAX)
                };
                let near_best = db
                    .entries
                    .iter()
                    .filter(|e| is_near(&e.world_from_camera))
                    .map(distance)
                    .min();
                let rank =
                    near_best.map(|best| db.entries.iter().filter(|e| distance(e) < best).count());
                tally.near_rank.push(rank.unwrap_or(usize::MAX));
            }
            if verbose && matches!(region, SearchRegion::Everywhere) {
                // Diagnostics: would the nearest database entry (by pose)
                // have been accepted, had retrieval found it?
                let nearest = db
                    .entries
                    .iter()
                    .enumerate()
                    .min_by(|a, b| {
                        let score = |e: &crate::reloc::RelocEntry| {
                            let d = truth.inverse() * e.world_from_camera;
                            d.translation.vector.norm() + 0.01 * d.rotation.angle().to_degrees()
                        };
                        score(a.1).total_cmp(&score(b.1))
                    })
                    .map(|(i, _)| i);
                let mut oracle = "none".to_string();
                if let Some(i) = nearest {
                    let e = &db.entries[i];
                    let mut render = |world_from_keyframe: &Pose, kf: &mut Keyframe| {
                        candidate_r
                            .render(world_from_keyframe, &pinhole, &mut kview)
                            .ok()?;
                        kf.prepare(&kview, *world_from_keyframe, i as u64, &tracker);
                        Some(())
                    };
                    let found = attempt(
                        &mut aligner,
                        &pyramid,
                        &camera,
                        rc,
                        (&e.world_from_camera, Some(0.0)),
                        (&mut spare, &mut returned),
                        &mut render,
                    );
                    let d = truth.inverse() * e.world_from_camera;
                    let dist = query
                        .iter()
                        .map(|q| q.hamming(&e.descriptor))
                        .min()
                        .unwrap_or(0);
                    oracle = match found {
                        Some(v) => {
                            let err = truth.inverse() * v.world_from_camera;
                            format!(
                                "nearest entry {:.2} m {:.0} deg (hamming {dist}): accepted, off {:.3} m",
                                d.translation.vector.norm(),
                                d.rotation.angle().to_degrees(),
                                err.translation.vector.norm()
                            )
                        }
                        None => format!(
                            "nearest entry {:.2} m {:.0} deg (hamming {dist}): refused",
                            d.translation.vector.norm(),
                            d.rotation.angle().to_degrees()
                        ),
                    };
                }
                // And at the truth itself: keyframe rendered there, aligned
                // from the identity.
                let mut at_truth = String::new();
                if let Some(mut kf) = spare.pop() {
                    if candidate_r.render(&truth, &pinhole, &mut kview).is_ok() {
                        kf.prepare(&kview, truth, 0, &tracker);
                        let a = aligner.align(&kf, &pyramid, &camera, Pose::identity());
                        let q = a.quality;
                        let corr = |level| {
                            crate::track::correlations(
                                &kf,
                                &pyramid,
                                &camera,
                                &a.camera_from_keyframe,
                                level,
                            )
                        };
                        let (c0, c1, c2) = (corr(0), corr(1), corr(2));
                        let trimmed = |c: Option<crate::track::Correlations>| {
                            c.map_or(f32::NAN, |c| c.trimmed)
                        };
                        let off = a.camera_from_keyframe.translation.vector.norm();
                        at_truth = format!(
                            "at truth: inliers {:.2} visible {:.2} residual {:.1} ncc {:.2}/{:.2}/{:.2} trimmed {:.2}/{:.2}/{:.2} gain {:.2} off {off:.3} m",
                            q.inlier_ratio,
                            q.visible_ratio,
                            q.residual_rms,
                            q.correlation,
                            c1.map_or(f32::NAN, |c| c.all),
                            c2.map_or(f32::NAN, |c| c.all),
                            trimmed(c0),
                            trimmed(c1),
                            trimmed(c2),
                            a.gain
                        );
                    }
                    spare.push(kf);
                }
                let top1 = candidates.first().map_or(0, |c| c.ranked.distance);
                let cands: Vec<String> = candidates
                    .iter()
                    .map(|c| {
                        let d = truth.inverse() * c.world_from_camera;
                        format!(
                            "{:.2}m/{:.0}d/h{}/c{:.2}",
                            d.translation.vector.norm(),
                            d.rotation.angle().to_degrees(),
                            c.ranked.distance,
                            c.score
                        )
                    })
                    .collect();
                let oracle = format!("{oracle}; candidates {}", cands.join(" "));
                if let Some(dir) = std::env::var_os("STAR_BENCH_DUMP") {
                    let dir = std::path::Path::new(&dir);
                    let path = dir.join(format!("q{done:03}.png"));
                    if let Err(e) = crate::dataset::write_gray8(&path, &frame) {
                        eprintln!("STAR_BENCH_DUMP: {e}");
                    }
                }
                println!(
                    "    query {done}: {} near rank {:?}, top-1 hamming {top1}; {oracle}; {at_truth}",
                    if verdict.is_some() { "accepted" } else { "REFUSED" },
                    tally.near_rank.last()
                );
            }
            match verdict {
                None => tally.rejected += 1,
                Some(v) => {
                    let err = truth.inverse() * v.world_from_camera;
                    let err_m = err.translation.vector.norm();
                    let err_deg = err.rotation.angle().to_degrees();
                    if err_m <= 0.05 && err_deg <= 2.0 {
                        tally.success += 1;
                        tally
                            .success_ncc
                            .push((v.correlation, v.trimmed_correlation));
                        tally.success_given_near += usize::from(near_truth);
                        tally.success_ms.push(ms);
                    } else {
                        let q = v.alignment.quality;
                        tally.wrong.push((
                            err_m,
                            err_deg,
                            format!(
                                "inliers {:.2}, visible {:.2}, residual {:.1}, correlation {:.2}, trimmed {:.2} keeping {:.2}, gain {:.2}",
                                q.inlier_ratio,
                                q.visible_ratio,
                                q.residual_rms,
                                v.correlation,
                                v.trimmed_correlation,
                                v.kept,
                                v.alignment.gain
                            ),
                        ));
                    }
                }
            }
        }
    }
    println!(
        "  queries: {done} random free poses (clearance 0.4 m, z {z_lo}..{z_hi} m, yaw any, pitch {pitch_mid}+-5 deg, roll +-{} deg, >= 60 % of the view on the map), truth mesh + distortion + realistic sensor model; top_k {}",
        max_roll_deg.unwrap_or(0.0),
        rc.top_k
    );
    global.print("whole map", done);
    window.print(
        "2 m window (paper protocol; centre = truth + up to 0.5 m)",
        done,
    );
    search_timing(&db, rc.top_k as usize, seed);
    Ok(())
}

/// One candidate through [`try_candidate`] from `world_from_candidate`
/// (with the yaw the search matched at), keyframes drawn from `spare` and
/// filled by `render`; every keyframe is back in `spare` afterwards
/// (`returned` holds the recycled ones meanwhile).
#[allow(clippy::vec_box)] // `try_candidate` hands keyframes over boxed
fn attempt(
    aligner: &mut Aligner,
    pyramid: &Pyramid,
    camera: &crate::geometry::PinholeCamera,
    rc: &crate::reloc::RelocConfig,
    (world_from_candidate, shift_yaw_rad): (&Pose, Option<f64>),
    (spare, returned): (&mut Vec<Box<Keyframe>>, &mut Vec<Box<Keyframe>>),
    render: &mut dyn FnMut(&Pose, &mut Keyframe) -> Option<()>,
) -> Option<crate::reloc::Verified> {
    let mut draw = |world_from_keyframe: &Pose| {
        let mut kf = spare.pop()?;
        if render(world_from_keyframe, &mut kf).is_some() {
            Some(kf)
        } else {
            spare.push(kf);
            None
        }
    };
    let found = try_candidate(
        aligner,
        pyramid,
        camera,
        rc,
        world_from_candidate,
        shift_yaw_rad,
        &mut draw,
        &mut |kf: Box<Keyframe>| returned.push(kf),
    );
    spare.append(returned);
    found.map(|(v, kf)| {
        spare.push(kf);
        v
    })
}

/// Times the whole-map search over 10k keyframes (the database replicated
/// when smaller).
fn search_timing(db: &crate::reloc::RelocDatabase, k: usize, seed: u64) {
    const TARGET: usize = 10_000;
    let mut big = db.clone();
    if big.entries.is_empty() {
        println!("  search: empty database");
        return;
    }
    let replicated = big.entries.len() < TARGET;
    big.entries.truncate(TARGET);
    while big.entries.len() < TARGET {
        let n = (TARGET - big.entries.len()).min(db.entries.len());
        big.entries.extend_from_slice(&db.entries[..n]);
    }
    let mut rng = SplitMix64::new(seed ^ 0x5ea6c4);
    let mut random = || {
        crate::reloc::Descriptor([
            rng.next_u64(),
            rng.next_u64(),
            rng.next_u64(),
            rng.next_u64(),
        ])
    };
    let queries: Vec<Query> = (0..1000)
        .map(|_| std::array::from_fn(|_| random()))
        .collect();
    let index = SearchIndex::new(&big);
    let mut best = [Ranked::default(); MAX_TOP_K];
    let mut samples_ms = Vec::with_capacity(queries.len());
    let mut checksum = 0u64;
    for q in &queries {
        let t = Instant::now();
        let n = index.top_k(q, SearchRegion::Everywhere, k, &mut best);
        samples_ms.push(t.elapsed().as_secs_f64() * 1e3);
        checksum = checksum.wrapping_add(best[..n].iter().map(|b| b.index as u64).sum::<u64>());
    }
    let (med, p99) = median_p99(&samples_ms);
    println!(
        "  search over {} keyframes{} (top {k}, {} query shifts, 1000 queries): median {med:.4} ms, p99 {p99:.4} ms (checksum {checksum})",
        big.entries.len(),
        if replicated {
            format!(" ({} replicated to 10k)", db.entries.len())
        } else {
            format!(" (the first 10k of {})", db.entries.len())
        },
        queries[0].len(),
    );
}

/// Figures of one search mode.
#[derive(Debug, Default)]
struct Tally {
    success: usize,
    /// Successes among the queries with a near keyframe in the top k.
    success_given_near: usize,
    /// Queries with a keyframe within 0.5 m / 20 deg of the truth in the top k.
    retrieved_near: usize,
    rejected: usize,
    /// Wrong accepts: error (m, deg) and the quality they passed with.
    wrong: Vec<(f64, f64, String)>,
    /// Query to the first candidate (the landmark pose when there is one), m.
    retrieved_m: Vec<f64>,
    /// Query to the descriptor search's best-ranked candidate, m.
    descriptor_m: Vec<f64>,
    recovery_ms: Vec<f64>,
    success_ms: Vec<f64>,
    renders: usize,
    /// Time spent rendering and preparing keyframes, ms.
    render_ms: f64,
    /// Of which keyframe preparation (point selection), ms.
    prepare_ms: f64,
    /// Whole-map rank (0 = first) of the best near keyframe, per query.
    near_rank: Vec<usize>,
    /// Search and coarse ranking of the candidates, per query, ms.
    rank_ms: Vec<f64>,
    /// Correlation and trimmed correlation of the successes.
    success_ncc: Vec<(f32, f32)>,
    /// `reloc.rank_candidates`.
    rank_candidates: u32,
    /// Landmark stage (features, matching, PnP) per query, ms.
    landmark_ms: Vec<f64>,
    /// Queries the landmarks gave a pose for, and of those within 10 cm /
    /// 3 deg of the truth.
    located: usize,
    located_right: usize,
    /// Per located query: inliers, matches, right.
    located_inliers: Vec<(usize, usize, bool)>,
    /// Accepted poses that came from the landmark candidate.
    from_landmarks: usize,
}

impl Tally {
    fn print(&self, what: &str, done: usize) {
        let pct = |n: usize| 100.0 * n as f64 / done.max(1) as f64;
        if !self.near_rank.is_empty() {
            let within = |k: usize| self.near_rank.iter().filter(|&&r| r < k).count();
            println!(
                "  whole-map rank of the best keyframe within 0.5 m / 20 deg: top 4 {}, top 16 {}, top 64 {}, top 256 {}, none near {} (of {done})",
                within(4),
                within(16),
                within(64),
                within(256),
                self.near_rank.iter().filter(|&&r| r == usize::MAX).count()
            );
        }
        println!("  search {what}:");
        println!(
            "    success (accepted, within 5 cm / 2 deg): {}/{done} = {:.1} %   no pose: {} = {:.1} %   accepted but off: {} = {:.1} %",
            self.success,
            pct(self.success),
            self.rejected,
            pct(self.rejected),
            self.wrong.len(),
            pct(self.wrong.len())
        );
        println!(
            "    retrieval: a candidate (where it is rendered) within 0.5 m / 20 deg of the truth among the top k for {}/{done} = {:.1} %; success on those {}/{} = {:.1} %",
            self.retrieved_near,
            pct(self.retrieved_near),
            self.success_given_near,
            self.retrieved_near,
            100.0 * self.success_given_near as f64 / self.retrieved_near.max(1) as f64
        );
        for (m, deg, quality) in &self.wrong {
            println!("      accepted but off by {m:.3} m, {deg:.2} deg ({quality})");
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let (dmed_m, dp99_m) = median_p99(&self.descriptor_m);
        println!(
            "    query -> best-ranked database keyframe (where the coarse alignment moved it): mean {:.3} m, median {dmed_m:.3} m, p99 {dp99_m:.3} m",
            mean(&self.descriptor_m)
        );
        let mean_m = mean(&self.retrieved_m);
        let (med_m, p99_m) = median_p99(&self.retrieved_m);
        println!(
            "    query -> first candidate (the landmark pose when found) distance: mean {mean_m:.3} m, median {med_m:.3} m, p99 {p99_m:.3} m ({} candidate renders, {:.1} ms each, of which keyframe preparation {:.1} ms; rendering {:.0} % of the recovery time)",
            self.renders,
            self.render_ms / self.renders.max(1) as f64,
            self.prepare_ms / self.renders.max(1) as f64,
            100.0 * self.render_ms / self.recovery_ms.iter().sum::<f64>().max(1e-9)
        );
        if std::env::var_os("STAR_BENCH_VERBOSE").is_some() {
            let mut all: Vec<f64> = self.success_ncc.iter().map(|c| c.0 as f64).collect();
            let mut trimmed: Vec<f64> = self.success_ncc.iter().map(|c| c.1 as f64).collect();
            all.sort_by(f64::total_cmp);
            trimmed.sort_by(f64::total_cmp);
            let low = |v: &[f64]| {
                v.iter()
                    .take(5)
                    .map(|x| format!("{x:.2}"))
                    .collect::<Vec<_>>()
                    .join(" ")
            };
            println!(
                "    lowest correlations of the successes: all {}; trimmed {}",
                low(&all),
                low(&trimmed)
            );
        }
        let (lmed, lp99) = median_p99(&self.landmark_ms);
        println!(
            "    landmarks: a pose for {}/{done}, within 10 cm / 3 deg for {}; accepted from it {}; features + matching + PnP median {lmed:.1} ms, p99 {lp99:.1} ms",
            self.located, self.located_right, self.from_landmarks
        );
        if std::env::var_os("STAR_BENCH_VERBOSE").is_some() {
            let wrong: Vec<String> = self
                .located_inliers
                .iter()
                .filter(|l| !l.2)
                .map(|l| format!("{}/{}", l.0, l.1))
                .collect();
            let right: Vec<String> = self
                .located_inliers
                .iter()
                .filter(|l| l.2)
                .map(|l| format!("{}/{}", l.0, l.1))
                .collect();
            println!(
                "      inliers/matches of the wrong poses: {}; of the right ones: {}",
                wrong.join(" "),
                right.join(" ")
            );
        }
        let (rmed, rp99) = median_p99(&self.rank_ms);
        println!(
            "    search and coarse ranking of the {} best by Hamming distance: median {rmed:.1} ms, p99 {rp99:.1} ms",
            self.rank_candidates
        );
        let (med, p99) = median_p99(&self.recovery_ms);
        let (smed, sp99) = median_p99(&self.success_ms);
        println!(
            "    recovery time (describe, landmarks + PnP, the search when needed, render, align; 640x512): all queries median {med:.1} ms, p99 {p99:.1} ms; successful ones median {smed:.1} ms, p99 {sp99:.1} ms"
        );
    }
}
