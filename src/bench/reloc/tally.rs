//! The bench's figures: per search mode, successes, wrong accepts,
//! retrieval, landmark and recovery timings; and the search's own timing
//! over 10k keyframes.

use std::time::Instant;

use crate::geometry::Pose;
use crate::offline::median_p99;
use crate::reloc::{Query, Ranked, SearchIndex, SearchRegion, MAX_TOP_K};
use crate::rng::SplitMix64;

use super::query::QueryFrame;
use super::recover::Outcome;

/// Times the whole-map search over 10k keyframes (the database replicated
/// when smaller).
pub(super) fn search_timing(db: &crate::reloc::RelocDatabase, k: usize, seed: u64) {
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
pub(super) struct Tally {
    pub(super) success: usize,
    /// Successes among the queries with a near keyframe in the top k.
    pub(super) success_given_near: usize,
    /// Queries with a keyframe within 0.5 m / 20 deg of the truth in the top k.
    pub(super) retrieved_near: usize,
    pub(super) rejected: usize,
    /// Wrong accepts: error (m, deg) and the quality they passed with.
    pub(super) wrong: Vec<(f64, f64, String)>,
    /// Query to the first candidate (the landmark pose when there is one), m.
    pub(super) retrieved_m: Vec<f64>,
    /// Query to the descriptor search's best-ranked candidate, m.
    pub(super) descriptor_m: Vec<f64>,
    pub(super) recovery_ms: Vec<f64>,
    pub(super) success_ms: Vec<f64>,
    pub(super) renders: usize,
    /// Time spent rendering and preparing keyframes, ms.
    pub(super) render_ms: f64,
    /// Of which keyframe preparation (point selection), ms.
    pub(super) prepare_ms: f64,
    /// Whole-map rank (0 = first) of the best near keyframe, per query.
    pub(super) near_rank: Vec<usize>,
    /// Search and coarse ranking of the candidates, per query, ms.
    pub(super) rank_ms: Vec<f64>,
    /// Correlation and trimmed correlation of the successes.
    pub(super) success_ncc: Vec<(f32, f32)>,
    /// `reloc.rank_candidates`.
    pub(super) rank_candidates: u32,
    /// Landmark stage (features, matching, PnP) per query, ms.
    pub(super) landmark_ms: Vec<f64>,
    /// Queries the landmarks gave a pose for, and of those within 10 cm /
    /// 3 deg of the truth.
    pub(super) located: usize,
    pub(super) located_right: usize,
    /// Per located query: inliers, matches, right.
    pub(super) located_inliers: Vec<(usize, usize, bool)>,
    /// Accepted poses that came from the landmark candidate.
    pub(super) from_landmarks: usize,
    /// Of those, the ones from a landmark pose at another place than the
    /// first (`Source::LandmarkElsewhere`, or a rival that won).
    pub(super) from_elsewhere: usize,
    /// Poses refused because a place that passed the gate but could not be
    /// held (only through the lowered first level, beyond the prior's
    /// reach) passed too; counted in `ambiguous` as well.
    pub(super) unheld_refused: usize,
    /// Descriptor comparisons of the landmark matching, per query.
    pub(super) comparisons: Vec<f64>,
    /// Corners whose nearest landmark over the whole map is within the
    /// match bound, and of those the ones the search found too.
    pub(super) recall_of: usize,
    pub(super) recall_found: usize,
    /// Corners x landmarks of brute-force matching, per query.
    pub(super) brute_force: Vec<f64>,
    /// Rivals (candidates at another place, [`crate::reloc::rivals`])
    /// verified, the accepted poses they refused as ambiguous, and the
    /// rivals within the prior's reach taken instead of a pose beyond it.
    pub(super) rivals_tried: usize,
    /// Landmark poses at other places listed as rivals
    /// ([`crate::reloc::Relocalizer::landmark_rivals`]).
    pub(super) landmark_rivals: usize,
    /// Accepted poses that passed only through the first level's lowered
    /// floor ([`crate::reloc::Verified::lowered_first_level`]): right, and
    /// wrong.
    pub(super) lowered_right: usize,
    pub(super) lowered_wrong: usize,
    /// Poses that passed only through the lowered floor beyond the prior's
    /// reach, not held ([`crate::reloc::rivals::RivalRule::may_hold`]).
    pub(super) lowered_skipped: usize,
    pub(super) ambiguous: usize,
    /// Of those, the ones where the held pose or the rival was the truth
    /// ([`is_right`]): a right pose lost to a look-alike that passed too.
    pub(super) ambiguous_with_truth: usize,
    pub(super) prior_chose: usize,
    /// Rivals that passed at another place where one of the two correlated
    /// decisively better ([`crate::reloc::rivals::DECISIVE_MARGIN`]), and
    /// of those, the rival's place was the better.
    pub(super) decisive: usize,
    pub(super) decisive_rival: usize,
    /// Poses the prior could not vouch for whose view fits at many places
    /// in the map's geometry, refused ([`crate::reloc::twins`]); geometric
    /// twins checked, and poses refused because the frame passed at one.
    pub(super) geometric_degenerate: usize,
    pub(super) geometric_checked: usize,
    pub(super) geometric_refused: usize,
    /// Poses beyond the prior's reach refused because a geometric twin
    /// stands within it.
    pub(super) geometric_prior: usize,
}

/// A recovered pose within this of the truth is a success, meters...
pub(super) const SUCCESS_M: f64 = 0.05;
/// ...and degrees.
pub(super) const SUCCESS_DEG: f64 = 2.0;

/// What one search gave, against the truth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum QueryResult {
    /// A pose within [`SUCCESS_M`] and [`SUCCESS_DEG`] of the truth.
    Success,
    /// No pose.
    Refused,
    /// A pose farther off: a wrong accept.
    Wrong,
}

/// Judges `outcome` against `query`'s truth.
pub(super) fn judge(query: &QueryFrame, outcome: &Outcome) -> QueryResult {
    match &outcome.verdict {
        None => QueryResult::Refused,
        Some(v) if is_right(query, &v.world_from_camera) => QueryResult::Success,
        Some(_) => QueryResult::Wrong,
    }
}

/// Whether `world_from_camera` is within [`SUCCESS_M`] and
/// [`SUCCESS_DEG`] of `query`'s truth.
pub(super) fn is_right(query: &QueryFrame, world_from_camera: &Pose) -> bool {
    let err = query.truth.inverse() * world_from_camera;
    err.translation.vector.norm() <= SUCCESS_M && err.rotation.angle().to_degrees() <= SUCCESS_DEG
}

impl Tally {
    /// An empty tally for `rank_candidates` (`reloc.rank_candidates`).
    pub(super) fn new(rank_candidates: u32) -> Self {
        Self {
            rank_candidates,
            ..Self::default()
        }
    }

    /// Counts one search's verdict against the truth.
    pub(super) fn record(&mut self, query: &QueryFrame, outcome: &Outcome) {
        match &outcome.verdict {
            None => self.rejected += 1,
            Some(v) => {
                let err = query.truth.inverse() * v.world_from_camera;
                let err_m = err.translation.vector.norm();
                let err_deg = err.rotation.angle().to_degrees();
                let right = judge(query, outcome) == QueryResult::Success;
                if v.lowered_first_level {
                    self.lowered_right += usize::from(right);
                    self.lowered_wrong += usize::from(!right);
                }
                if right {
                    self.success += 1;
                    self.success_ncc
                        .push((v.correlation, v.trimmed_correlation));
                    self.success_given_near += usize::from(outcome.near_truth);
                    self.success_ms.push(outcome.ms);
                } else {
                    let q = v.alignment.quality;
                    let (t, a) = (
                        query.truth.translation.vector,
                        v.world_from_camera.translation.vector,
                    );
                    self.wrong.push((
                            err_m,
                            err_deg,
                            format!(
                                "truth at ({:.2}, {:.2}, {:.2}) m, accepted at ({:.2}, {:.2}, {:.2}) m{}; inliers {:.2}, visible {:.2}, residual {:.1}, correlation {:.2}, trimmed {:.2} keeping {:.2}, local contrast {:.2}{}, gain {:.2}",
                                t.x,
                                t.y,
                                t.z,
                                a.x,
                                a.y,
                                a.z,
                                if outcome.verdict_from_landmarks { ", from the landmark pose" } else { ", from a database view" },
                                q.inlier_ratio,
                                q.visible_ratio,
                                q.residual_rms,
                                v.correlation,
                                v.trimmed_correlation,
                                v.kept,
                                v.local_correlation,
                                if v.lowered_first_level { " (through the lowered first level)" } else { "" },
                                v.alignment.gain
                            ),
                        ));
                }
            }
        }
    }

    /// Prints the figures over `done` queries.
    pub(super) fn print(&self, what: &str, done: usize) {
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
        println!(
            "    look-alike places: {} rivals at another place verified ({} landmark poses at other places listed), {} poses refused because one passed too ({} of them with the truth as one of the two, {} a place that passed only through the lowered first level; counted in no pose), {} beyond the prior's reach replaced by a rival within it, {} passing rivals told apart by a decisive correlation ({} of them the better place)",
            self.rivals_tried,
            self.landmark_rivals,
            self.ambiguous,
            self.ambiguous_with_truth,
            self.unheld_refused,
            self.prior_chose,
            self.decisive,
            self.decisive_rival
        );
        println!(
            "    geometric twins: {} poses refused because their view fits at {} or more places; {} because a twin stands within the prior's reach; {} twins checked, {} poses refused because the frame passed the looser gate at one (all counted in no pose)",
            self.geometric_degenerate,
            crate::reloc::twins::DEGENERATE_TWINS,
            self.geometric_prior,
            self.geometric_checked,
            self.geometric_refused
        );
        println!(
            "    accepted through the first level's lowered floor: {} right, {} off; {} passed only through it beyond the prior's reach, not held",
            self.lowered_right, self.lowered_wrong, self.lowered_skipped
        );
        let elsewhere = self.wrong.iter().filter(|w| w.0 > 1.0).count();
        if !self.wrong.is_empty() {
            println!(
                "    of the accepted but off: {elsewhere} more than 1 m off (another place: a look-alike room), {} within 1 m",
                self.wrong.len() - elsewhere
            );
        }
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
            "    landmarks: a pose for {}/{done}, within 10 cm / 3 deg for {}; accepted from it {} ({} from a landmark pose at another place than the first); features + matching + PnP median {lmed:.1} ms, p99 {lp99:.1} ms",
            self.located, self.located_right, self.from_landmarks, self.from_elsewhere
        );
        let (cmed, cp99) = median_p99(&self.comparisons);
        let (bmed, _) = median_p99(&self.brute_force);
        let recall = if self.recall_of == 0 {
            "the recall against brute force not measured".to_string()
        } else {
            format!(
                "the nearest landmark found for {}/{} corners whose nearest over the whole map is within the match bound ({:.1} %)",
                self.recall_found,
                self.recall_of,
                100.0 * self.recall_found as f64 / self.recall_of as f64
            )
        };
        println!(
            "    landmark matching: {cmed:.0} descriptor comparisons per query median, p99 {cp99:.0} (brute force: {bmed:.0}); {recall}"
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

#[cfg(test)]
mod tests {
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    use super::*;

    #[test]
    fn a_pose_is_right_within_5_cm_and_2_degrees_of_the_truth() {
        let truth = Pose::from_parts(
            Translation3::new(3.0, -2.0, 1.4),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
        );
        let query = QueryFrame {
            truth,
            position_m: truth.translation.vector,
        };
        let moved = |x_m: f64, yaw_deg: f64| {
            truth
                * Pose::from_parts(
                    Translation3::new(x_m, 0.0, 0.0),
                    UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw_deg.to_radians()),
                )
        };
        assert!(is_right(&query, &truth));
        assert!(is_right(&query, &moved(0.049, 1.9)));
        assert!(!is_right(&query, &moved(0.051, 0.0)));
        assert!(!is_right(&query, &moved(0.0, 2.1)));
        // A look-alike place: right in its own room, 12 m away.
        assert!(!is_right(&query, &moved(12.0, 0.0)));
    }
}
