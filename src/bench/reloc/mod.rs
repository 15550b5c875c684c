//! `star bench reloc`: relocalization on the synthetic realistic scene
//! (prints figures, never pass/fail).
//!
//! Stages: [`setup`] builds the scene, the database and the renderers;
//! [`query`] draws and renders a random query; [`recover`] runs it through
//! the service's recovery order and rival rule (landmark pose, then the
//! descriptor's candidates, then the rivals of a pose the prior cannot
//! vouch for), cold (no prior) and near the last position (the prior of a
//! service lost for as long as gives a 2 m reach, facing the truth's
//! heading), and with `--kidnaps` from a last known pose at another
//! frame of a dataset's flight (the truth beyond the prior's reach, then
//! within it); [`diagnose`] explains a whole-map query
//! (`STAR_BENCH_VERBOSE`); [`tally`] keeps and prints the figures and times
//! the search. `--plan PNG` draws the map from above with the database's
//! views and each whole-map query ringed by its outcome
//! (`crate::output::plan`).
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
//! `STAR_BENCH_NORMALIZE_PX=R` (and `STAR_BENCH_NORMALIZE_FLOOR=G`)
//! aligns and gates each candidate on locally normalized images, the
//! frame's and the render's ([`crate::reloc::local_contrast`]; the service
//! does not yet); `STAR_BENCH_NORMALIZE_GATE=plain` judges the pose it
//! converges to on the plain images. `STAR_BENCH_PROBES=W,L` sets the
//! whole-map landmark search's probes (words, leaves);
//! `STAR_BENCH_LANDMARK_SCALES=4,16,40` adds the landmark matching figures
//! on the landmarks replicated into look-alike rooms ([`scale`]). The landmark search's recall (the share of corners whose
//! nearest landmark over the whole map it finds) compares each query with
//! every landmark after the query's timing ends; `STAR_BENCH_NO_RECALL=1`
//! leaves it out (it triples the run time, and its scan leaves the next
//! query's renders a cold cache). `--log star::bench=debug` prints one
//! line per query: its recovery time, renders, rivals verified, and
//! whether a landmark pose came and was the one accepted.

mod diagnose;
mod query;
mod recover;
mod scale;
mod setup;
mod tally;

use anyhow::Result;

use crate::geometry::Pose;
use crate::reloc::MotionPrior;
use crate::rng::SplitMix64;

use setup::Bench;
use tally::Tally;

/// The radius of the window around the last position, meters (the
/// paper's protocol); the near queries' prior is the service's after as
/// long a loss as gives it this reach ([`MotionPrior::lost_s_for_radius`]).
const WINDOW_RADIUS_M: f64 = 2.0;
/// Mixes the query number into the kidnapped priors' seed.
const KIDNAP_STREAM: u64 = 0x9e37_79b9_7f4a_7c15;

/// Where `star bench reloc` draws its queries.
#[derive(Debug, Clone, Default)]
pub struct DatasetSource {
    /// An existing `star synth` dataset (its `star.toml`, when present,
    /// places the map); its frames are the queries.
    pub dataset: std::path::PathBuf,
    /// Its database over the flown region: read when the file exists, else
    /// built and written there.
    pub database: Option<std::path::PathBuf>,
    /// Also search each query from kidnapped priors ([`KIDNAP_M`]).
    pub kidnaps: bool,
}

/// A kidnapped prior's last known pose is the truth of another frame of
/// the flight this far from the query, horizontally, meters. Its reach is
/// then half that distance (the truth beyond it: a pose taken on the prior
/// alone is wrong), and that distance plus [`KIDNAP_PAST_TRUTH_M`] (the
/// truth within reach, and so may a look-alike be).
const KIDNAP_M: (f64, f64) = (1.5, 5.0);
/// How far the second kidnapped prior reaches past the truth, meters.
const KIDNAP_PAST_TRUTH_M: f64 = 0.5;

/// Runs the benchmark with `queries` random poses of the realistic scene
/// of `seed`, or random frames of `source`.
pub fn run(
    config_path: Option<&std::path::Path>,
    queries: usize,
    seed: u64,
    source: Option<&DatasetSource>,
    plan: Option<&std::path::Path>,
) -> Result<()> {
    if queries == 0 {
        anyhow::bail!("--queries must be at least 1");
    }
    let mut bench = match source {
        None => Bench::new(config_path, seed)?,
        Some(source) => dataset_bench(config_path, source)?,
    };
    let verbose = std::env::var_os("STAR_BENCH_VERBOSE").is_some();
    let mut rng = SplitMix64::new(seed ^ 0x7e10c);
    let (mut done, mut tries) = (0usize, 0usize);
    let rank_candidates = bench.config.reloc.rank_candidates;
    let mut global = Tally::new(rank_candidates);
    let mut window = Tally::new(rank_candidates);
    // Kidnapped priors: the truth beyond the reach, and within it.
    let kidnaps = source.is_some_and(|s| s.kidnaps);
    let mut kidnap_short = Tally::new(rank_candidates);
    let mut kidnap_reach = Tally::new(rank_candidates);
    let mut kidnapped = 0usize;
    let scales = scale::scales_from_env();
    let near_lost_s = MotionPrior::lost_s_for_radius(WINDOW_RADIUS_M, &bench.config.reloc);
    let near_turn_deg = (bench.config.reloc.search_yaw_deg
        + bench.config.reloc.max_yaw_rate_deg_s * near_lost_s)
        .min(180.0);
    let mut frames: Vec<Vec<crate::reloc::Descriptor>> = Vec::new();
    // Where each whole-map query was, by its outcome, for `--plan`.
    let mut cold: [Vec<[f64; 2]>; 3] = Default::default();
    while done < queries && tries < queries * 100 {
        tries += 1;
        let Some(query) = bench.draw_query(&mut rng, done + 1)? else {
            continue;
        };
        done += 1;
        // The paper's protocol: a 2 m window around where the vehicle was
        // last known (here the truth displaced by up to 0.5 m), facing the
        // truth's way, lost for as long as gives the window its radius.
        let center_m = query.position_m
            + nalgebra::Vector3::new(rng.range(-0.5, 0.5), rng.range(-0.5, 0.5), 0.0);
        let last = Pose::from_parts(nalgebra::Translation3::from(center_m), query.truth.rotation);
        let near = MotionPrior::new(&last, near_lost_s, &bench.config.reloc);
        let priors = [(None, &mut global), (Some(near), &mut window)];
        for (prior, tally) in priors {
            if prior.is_some() {
                bench.draw_last_keyframe(&last);
            }
            let Some(outcome) = bench.recover(&query, prior, tally) else {
                tally.rejected += 1;
                if prior.is_none() {
                    cold[1].push([query.position_m.x, query.position_m.y]);
                }
                continue;
            };
            if prior.is_none() {
                let k = match tally::judge(&query, &outcome) {
                    tally::QueryResult::Success => 0,
                    tally::QueryResult::Refused => 1,
                    tally::QueryResult::Wrong => 2,
                };
                cold[k].push([query.position_m.x, query.position_m.y]);
                if !scales.is_empty() {
                    frames.push(bench.reloc.landmarks_mut().last_query().to_vec());
                }
                tally.near_rank.push(bench.near_rank(&query, &outcome));
                if verbose {
                    bench.diagnose(&query, &outcome, done, tally);
                }
            }
            tally.record(&query, &outcome);
        }
        if kidnaps {
            // Its own stream per query: the other searches draw as without.
            let mut stream =
                SplitMix64::new(seed ^ 0x6b1d_4a95 ^ (done as u64).wrapping_mul(KIDNAP_STREAM));
            if let Some(last) = bench.kidnapped_from(&mut stream, &query, KIDNAP_M) {
                kidnapped += 1;
                let offset = last.translation.vector - query.position_m;
                let distance_m = offset.x.hypot(offset.y);
                let searches = [
                    (0.5 * distance_m, &mut kidnap_short),
                    (distance_m + KIDNAP_PAST_TRUTH_M, &mut kidnap_reach),
                ];
                for (reach_m, tally) in searches {
                    let lost_s = MotionPrior::lost_s_for_radius(reach_m, &bench.config.reloc);
                    let prior = MotionPrior::new(&last, lost_s, &bench.config.reloc);
                    bench.draw_last_keyframe(&last);
                    let wrong_before = tally.wrong.len();
                    match bench.recover(&query, Some(prior), tally) {
                        None => tally.rejected += 1,
                        Some(outcome) => tally.record(&query, &outcome),
                    }
                    if let Some((err_m, err_deg, how)) = tally.wrong.get(wrong_before) {
                        tracing::info!(
                            query = done,
                            distance_m = format!("{distance_m:.2}"),
                            reach_m = format!("{:.2}", prior.radius_m),
                            lost_s = format!("{lost_s:.2}"),
                            "kidnapped prior: accepted {err_m:.2} m / {err_deg:.1} deg off ({how})"
                        );
                    }
                }
            }
        }
    }
    bench.print_queries(done);
    global.print("whole map", done);
    window.print(
        &format!(
            "2 m window (paper protocol; centre = truth + up to 0.5 m, heading = truth's; \
             as the service lost {near_lost_s:.2} s: reach {WINDOW_RADIUS_M} m, {near_turn_deg:.0} deg; \
             the renderer last drew the keyframe at the centre)"
        ),
        done,
    );
    if kidnaps && kidnapped == 0 {
        let (lo, hi) = KIDNAP_M;
        println!(
            "  kidnapped priors: none drawn (no frame of the flight lies {lo}-{hi} m from a query)"
        );
    } else if kidnaps {
        let (lo, hi) = KIDNAP_M;
        kidnap_short.print(
            &format!(
                "kidnapped, the truth beyond reach (last known pose: another frame of the flight {lo}-{hi} m away; \
                 reach half that distance; any pose taken within it is wrong)"
            ),
            kidnapped,
        );
        kidnap_reach.print(
            &format!(
                "kidnapped, the truth within reach (the same last pose; reach {KIDNAP_PAST_TRUTH_M} m past the truth)"
            ),
            kidnapped,
        );
    }
    tally::search_timing(&bench.db, bench.config.reloc.top_k as usize, seed);
    if let Some(path) = plan {
        draw_plan(path, &bench, seed, source, &cold)?;
    }
    if !scales.is_empty() {
        let lm = &bench.db.landmarks;
        let n = lm.len().max(1) as f32;
        let center_m = [
            lm.iter().map(|l| l.world_m[0]).sum::<f32>() / n,
            lm.iter().map(|l| l.world_m[1]).sum::<f32>() / n,
        ];
        let reach_m = (2.0 + crate::reloc::landmarks::LANDMARK_VIEW_RANGE_M) as f32;
        scale::landmark_scaling(lm, &frames, center_m, reach_m, &scales);
    }
    Ok(())
}

/// The bench over an existing dataset: its configuration (`config_path`,
/// else the dataset's `star.toml`, else the defaults), its map and the
/// database over the region it flies through.
fn dataset_bench(config_path: Option<&std::path::Path>, source: &DatasetSource) -> Result<Bench> {
    use anyhow::Context;
    let root = &source.dataset;
    let placed = root.join("star.toml");
    let config = match config_path {
        Some(p) => crate::config::Config::load(p)
            .with_context(|| format!("loading config {}", p.display()))?,
        None if placed.exists() => crate::config::Config::load(&placed)
            .with_context(|| format!("loading {}", placed.display()))?,
        None => crate::config::Config::default(),
    };
    let dataset = crate::dataset::Dataset::open(root)
        .with_context(|| format!("opening the dataset {}", root.display()))?;
    let truth = dataset
        .ground_truth
        .clone()
        .context("the dataset has no groundtruth.txt: the queries need the truth")?;
    let mesh = std::sync::Arc::new(crate::bench::integrity::map_of(root)?);
    let db = crate::bench::integrity::flown_region_database(
        &mesh,
        &dataset,
        &truth,
        &config,
        &crate::reloc::AlongTrajectory::default(),
        source.database.as_deref(),
    )?;
    Bench::from_dataset(config, dataset, mesh, db)
}

/// `--plan`: the map from above with the database's views and each
/// whole-map query marked by its outcome.
fn draw_plan(
    path: &std::path::Path,
    bench: &Bench,
    seed: u64,
    source: Option<&DatasetSource>,
    cold: &[Vec<[f64; 2]>; 3],
) -> Result<()> {
    use crate::output::plan::{plan_png, MarkKind, PlanInput};
    use anyhow::Context;
    let mesh = match source {
        Some(s) => crate::bench::integrity::map_of(&s.dataset)?,
        None => {
            let preset =
                crate::synth::preset::Preset::by_name("realistic").context("preset `realistic`")?;
            crate::synth::sequence::preset_scene(&preset, seed).map
        }
    };
    let floor_z_m = crate::map::floor::find_floor(&mesh)
        .map(|f| f.z_m)
        .context("the plan: no floor found in the map")?;
    let views_m = crate::output::plan::database_views_m(&bench.db);
    let marks = [
        MarkKind {
            label: "whole-map query: relocalized within 5 cm, 2 deg",
            color: [44, 160, 44],
            positions_m: &cold[0],
        },
        MarkKind {
            label: "whole-map query: refused",
            color: [148, 103, 189],
            positions_m: &cold[1],
        },
        MarkKind {
            label: "whole-map query: wrong pose accepted",
            color: [214, 39, 40],
            positions_m: &cold[2],
        },
    ];
    let summary = plan_png(
        &PlanInput {
            mesh: &mesh,
            floor_z_m,
            cell_m: 0.05,
            views_m: &views_m,
            landmarks_m: &[],
            trajectories: &[],
            marks: &marks,
        },
        path,
    )
    .with_context(|| format!("drawing the plan {}", path.display()))?;
    println!(
        "  plan: {} ({}x{} px): the database's views and the whole-map queries by outcome",
        path.display(),
        summary.width_px,
        summary.height_px
    );
    Ok(())
}
