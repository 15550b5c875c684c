//! One query through the service's recovery order under one motion prior
//! (none: a cold start): the landmark pose first, then the database views
//! by descriptor (near the last position, then over the whole map), each
//! rendered and verified through the gate, then the rivals of a pose the
//! prior cannot vouch for, all as the service does it
//! ([`crate::reloc::prior`], [`crate::reloc::rivals`]) and timed as the
//! service would spend it. Unlike the service, an attempt here has no time
//! budget, and no look-alike places are remembered from one query to the
//! next.

use std::time::Instant;

use crate::geometry::{PinholeCamera, Pose};
use crate::map::repeats::Twin;
use crate::reloc::is_landmark_index;
use crate::reloc::prior::{landmark_regions, sources, Source};
use crate::reloc::rivals::{elsewhere, Judgment, LISTED_RIVALS};
use crate::reloc::twins::{plan, twin_pose, TwinCheck, TwinPlan, TwinRefusal, DEGENERATE_TWINS};
use crate::reloc::{
    try_candidate, Candidate, MotionPrior, Query, RelocConfig, SearchRegion, Verified,
    LANDMARK_CANDIDATE, MAX_LANDMARK_ELSEWHERE,
};
use crate::track::{Aligner, Keyframe, Pyramid};

use super::query::QueryFrame;
use super::setup::Bench;
use super::tally::{is_right, Tally};

/// Which gate [`Bench::try_at`] verifies through.
#[derive(Debug, Clone, Copy)]
enum Gate {
    /// `[reloc]`'s.
    Strict,
    /// The looser one of geometric twins ([`crate::reloc::twins::loose_gate`]).
    Loose,
}

/// What one search gave.
pub(super) struct Outcome {
    /// The frame's descriptor.
    pub(super) descriptor: Query,
    /// The landmark pose (when found) and the descriptor's candidates.
    pub(super) candidates: Vec<Candidate>,
    /// The accepted candidate.
    pub(super) verdict: Option<Verified>,
    /// A candidate within 0.5 m / 20 deg of the truth was among them.
    pub(super) near_truth: bool,
    /// Recovery time, ms.
    pub(super) ms: f64,
    /// The accepted candidate was the landmark pose.
    pub(super) verdict_from_landmarks: bool,
}

impl Bench {
    /// Runs the query in the frame buffers under `prior` (none: over the
    /// whole map); `None` when the frame has too little contrast to
    /// describe.
    /// Renders (untimed) the keyframe at `last`, the last known pose, as
    /// the service's render thread last drew the tracking keyframe there
    /// before the frame was lost: a renderer that reuses what its previous
    /// view saw (the CPU rasterizer's first batch, wgpu's first pass)
    /// starts a window search's candidate renders from that, as it does in
    /// the service, and not from whatever the previous query left.
    pub(super) fn draw_last_keyframe(&mut self, last: &Pose) {
        if let Err(e) = self
            .candidate_r
            .render(last, &self.pinhole, &mut self.kview)
        {
            tracing::debug!(error = %e, "the last keyframe could not be rendered");
        }
    }

    pub(super) fn recover(
        &mut self,
        query: &QueryFrame,
        prior: Option<MotionPrior>,
        tally: &mut Tally,
    ) -> Option<Outcome> {
        let rule = self.reloc.rival_rule(prior);
        // The region of the retrieval figures: the first views step's.
        let region = prior.map_or(SearchRegion::Everywhere, |p| p.region());
        let t_query = Instant::now();
        let (renders_before, rivals_before) = (tally.renders, tally.rivals_tried);
        let descriptor = self.reloc.describe(
            self.frame.data(),
            self.frame.width(),
            self.frame.height(),
            self.frame.width(),
        )?;
        let t_landmarks = Instant::now();
        let (regions, n_regions) = landmark_regions(prior.as_ref());
        let landmark = self.reloc.landmark_candidate(
            self.frame.data(),
            self.frame.width(),
            self.frame.height(),
            self.frame.width(),
            regions.get(..n_regions).unwrap_or(&[]),
        );
        tally
            .landmark_ms
            .push(t_landmarks.elapsed().as_secs_f64() * 1e3);
        // Outside the timing: how much the search compared. Whether it
        // found what comparing with every landmark finds is measured after
        // the query: a scan of every landmark here would evict from the
        // cache what the renders after it use, a cost the service never
        // pays.
        let t_untimed = Instant::now();
        let locator = self.reloc.landmarks_mut();
        tally.comparisons.push(locator.comparisons() as f64);
        tally
            .brute_force
            .push(locator.brute_force_comparisons() as f64);
        let mut untimed_ms = t_untimed.elapsed().as_secs_f64() * 1e3;
        let mut landmark_off = (f64::NAN, f64::NAN);
        let landmark = landmark.map(|(c, found)| {
            let e = query.truth.inverse() * c.world_from_camera;
            landmark_off = (e.translation.vector.norm(), e.rotation.angle().to_degrees());
            let right =
                e.translation.vector.norm() <= 0.1 && e.rotation.angle().to_degrees() <= 3.0;
            tally.located += 1;
            tally.located_right += usize::from(right);
            tally
                .located_inliers
                .push((found.inliers, found.matches, right));
            c
        });
        let mut candidates: Vec<Candidate> = Vec::new();
        let mut tried: Vec<u32> = Vec::new();
        let mut verdict = None;
        let mut verdict_index = None;
        let mut region_searched = false;
        let mut steps = sources(prior.as_ref()).into_iter().flatten();
        let mut elsewhere_gathered = false;
        // Poses that passed the gate but could not be held (as the service).
        let mut passed_unheld: Vec<(Pose, f32)> = Vec::new();
        'steps: for source in steps.by_ref() {
            elsewhere_gathered |= matches!(source, Source::LandmarkElsewhere);
            let first = candidates.len();
            let rank_ms = self.gather(source, landmark, &descriptor, &mut candidates);
            if !region_searched && matches!(source, Source::Views(_)) {
                tally.rank_ms.push(rank_ms);
                region_searched = true;
            }
            for i in first..candidates.len() {
                let c = candidates[i];
                if tried.contains(&c.ranked.index) {
                    continue;
                }
                tried.push(c.ranked.index);
                let found = self.try_one(&c, tally);
                verdict = found.filter(|v| {
                    let holds = rule
                        .for_held(v.lowered_first_level, v.local_correlation)
                        .may_hold(&v.world_from_camera);
                    tally.lowered_skipped += usize::from(!holds);
                    holds
                });
                if let Some(f) = found.filter(|_| verdict.is_none()) {
                    passed_unheld.push((f.world_from_camera, f.correlation));
                }
                if verdict.is_some() {
                    verdict_index = Some(c.ranked.index);
                    break 'steps;
                }
            }
        }
        // A pose the prior cannot vouch for: another place that passes the
        // gate as well makes the frame ambiguous, and no pose is given.
        match verdict {
            Some(v)
                if self.check_rivals
                    && !rule
                        .for_held(v.lowered_first_level, v.local_correlation)
                        .accepts_alone(&v.world_from_camera) =>
            {
                let rule = rule.for_held(v.lowered_first_level, v.local_correlation);
                // The held keyframe is the last spare one until the next
                // render: its view's geometric twins now.
                let mut held_twins = self.twin_check(&query.truth, &rule);
                for source in steps.filter(|s| !matches!(s, Source::LandmarkElsewhere)) {
                    let rank_ms = self.gather(source, landmark, &descriptor, &mut candidates);
                    if !region_searched && matches!(source, Source::Views(_)) {
                        tally.rank_ms.push(rank_ms);
                        region_searched = true;
                    }
                }
                // The landmark poses at the other places the frame's corners
                // fit come first among the rivals (as the service).
                let mut landmark_rivals = 0;
                if !elsewhere_gathered {
                    let mut elsewhere_found = [Candidate::default(); MAX_LANDMARK_ELSEWHERE];
                    let m = self
                        .reloc
                        .landmark_rivals(&v.world_from_camera, &mut elsewhere_found);
                    tally.landmark_rivals += m;
                    // After the landmark pose, which the figures read first.
                    let at = candidates
                        .iter()
                        .position(|c| c.ranked.index != LANDMARK_CANDIDATE)
                        .unwrap_or(candidates.len());
                    candidates.splice(at..at, elsewhere_found[..m].iter().copied());
                    landmark_rivals = m;
                }
                let rule = rule.with_landmark_rivals(landmark_rivals);
                let mut rivals = [0usize; LISTED_RIVALS];
                let n = rule.rivals(&candidates, &v.world_from_camera, &tried, &mut rivals);
                let all_checked = rule.may_decide(
                    n,
                    rule.count_rivals(&candidates, &v.world_from_camera, &tried),
                );
                let mut held = v;
                let first_rivals = rule.budget(&v.world_from_camera).max;
                let mut decided = false;
                for (k, &i) in rivals[..n].iter().enumerate() {
                    if k >= first_rivals && !decided {
                        break;
                    }
                    let c = candidates[i];
                    tally.rivals_tried += 1;
                    let Some(r) = self.try_one(&c, tally) else {
                        continue;
                    };
                    let judgment = rule.judge(
                        (&held.world_from_camera, held.correlation),
                        (&r.world_from_camera, r.correlation),
                        all_checked,
                    );
                    if matches!(
                        judgment,
                        Judgment::HeldIsBetter | Judgment::RivalIsBetter | Judgment::Ambiguous
                    ) {
                        // Both places, and which the rule chose (none where
                        // ambiguous): the margin's evidence on this map.
                        let off_m = |p: &Pose| {
                            (p.translation.vector - query.truth.translation.vector).norm()
                        };
                        tracing::info!(
                            ?judgment,
                            held_correlation = held.correlation,
                            held_local = held.local_correlation,
                            held_off_m = off_m(&held.world_from_camera),
                            held_right = is_right(query, &held.world_from_camera),
                            rival_correlation = r.correlation,
                            rival_local = r.local_correlation,
                            rival_off_m = off_m(&r.world_from_camera),
                            rival_right = is_right(query, &r.world_from_camera),
                            rival_landmark = is_landmark_index(c.ranked.index),
                            all_checked,
                            prior = rule.has_prior(),
                            "two places passed"
                        );
                    }
                    match judgment {
                        Judgment::SamePlace => {}
                        Judgment::HeldIsBetter => {
                            tally.decisive += 1;
                            decided = true;
                        }
                        Judgment::RivalIsBetter => {
                            tally.decisive += 1;
                            decided = true;
                            tally.decisive_rival += 1;
                            held = r;
                            verdict = Some(r);
                            verdict_index = Some(c.ranked.index);
                            held_twins = self.twin_check(&query.truth, &rule);
                        }
                        Judgment::PriorChooses => {
                            tally.prior_chose += 1;
                            verdict = Some(r);
                            verdict_index = Some(c.ranked.index);
                            break;
                        }
                        Judgment::Ambiguous => {
                            tally.ambiguous += 1;
                            tally.ambiguous_with_truth += usize::from(
                                is_right(query, &held.world_from_camera)
                                    || is_right(query, &r.world_from_camera),
                            );
                            verdict = None;
                            break;
                        }
                    }
                }
                // The places that passed but could not be held are rivals
                // that passed (as the service).
                if let Some(held) = verdict {
                    let unheld_rival = rule.unheld_rival(
                        (&held.world_from_camera, held.correlation),
                        &passed_unheld,
                        all_checked,
                    );
                    if let Some((pose, _)) = unheld_rival {
                        tally.ambiguous += 1;
                        tally.unheld_refused += 1;
                        tally.ambiguous_with_truth += usize::from(
                            is_right(query, &held.world_from_camera) || is_right(query, pose),
                        );
                        verdict = None;
                    }
                }
                // Still held beyond the prior's reach: its geometric twins.
                if let Some(held) = verdict.filter(|v| !rule.accepts_alone(&v.world_from_camera)) {
                    if !self.twins_pass(&held, held_twins, (&rule, &query.truth), tally) {
                        verdict = None;
                    }
                }
            }
            _ if !region_searched => {
                // The descriptor search runs for the retrieval figures even
                // when the landmark pose was accepted; it counts in the
                // recovery time only when it was needed.
                let t_rank = Instant::now();
                let rank_ms = self.gather(
                    Source::Views(region),
                    landmark,
                    &descriptor,
                    &mut candidates,
                );
                tally.rank_ms.push(rank_ms);
                untimed_ms += t_rank.elapsed().as_secs_f64() * 1e3;
            }
            _ => {}
        }
        let verdict_from_landmarks = verdict_index.is_some_and(is_landmark_index);
        if verdict.is_some() {
            tally.from_landmarks += usize::from(verdict_from_landmarks);
            tally.from_elsewhere +=
                usize::from(verdict_from_landmarks && verdict_index != Some(LANDMARK_CANDIDATE));
        }
        let ms = t_query.elapsed().as_secs_f64() * 1e3 - untimed_ms;
        tally.recovery_ms.push(ms);
        // The landmark search's recall against brute force (the last frame
        // the locator saw is still this query's), unless told not to.
        if self.landmark_recall {
            let (found, of) = self.reloc.landmarks_mut().recall_of_last();
            tally.recall_found += found;
            tally.recall_of += of;
        }
        tracing::debug!(
            recovery_ms = ms,
            renders = tally.renders - renders_before,
            rivals = tally.rivals_tried - rivals_before,
            landmark_pose = landmark.is_some(),
            landmark_off_m = landmark_off.0,
            landmark_off_deg = landmark_off.1,
            accepted = verdict.is_some(),
            from_landmarks = verdict_from_landmarks,
            off_m =
                verdict.map(|v| (v.world_from_camera.translation.vector - query.position_m).norm()),
            lowered = verdict.map(|v| v.lowered_first_level),
            local = verdict.map(|v| v.local_correlation),
            plain = verdict.map(|v| v.correlation),
            inliers = verdict.map(|v| v.alignment.quality.inlier_ratio),
            gain = verdict.map(|v| v.alignment.gain),
            truth_x_m = query.position_m.x,
            truth_y_m = query.position_m.y,
            truth_z_m = query.position_m.z,
            "query"
        );
        if let Some(first) = candidates.first() {
            tally
                .retrieved_m
                .push((first.world_from_camera.translation.vector - query.position_m).norm());
        }
        if let Some(first) = candidates
            .iter()
            .find(|c| !is_landmark_index(c.ranked.index))
        {
            tally
                .descriptor_m
                .push((first.world_from_camera.translation.vector - query.position_m).norm());
        }
        // Retrieval alone: is a candidate near the truth among the
        // landmark pose and the top k?
        let is_near = |world_from_camera: &Pose| {
            let e = query.truth.inverse() * world_from_camera;
            e.translation.vector.norm() <= 0.5 && e.rotation.angle().to_degrees() <= 20.0
        };
        let near_truth = candidates.iter().any(|c| is_near(&c.world_from_camera));
        tally.retrieved_near += usize::from(near_truth);
        Some(Outcome {
            descriptor,
            candidates,
            verdict,
            near_truth,
            ms,
            verdict_from_landmarks,
        })
    }

    /// Appends the candidates of one attempt step to `candidates`: the
    /// landmark pose, or the views ranked in a region; returns the time the
    /// views' search took, ms (0 for the landmark pose).
    fn gather(
        &mut self,
        source: Source,
        landmark: Option<Candidate>,
        descriptor: &Query,
        candidates: &mut Vec<Candidate>,
    ) -> f64 {
        match source {
            Source::Landmark => {
                candidates.extend(landmark);
                0.0
            }
            Source::LandmarkElsewhere => {
                if let Some(c) = landmark {
                    let mut found = [Candidate::default(); MAX_LANDMARK_ELSEWHERE];
                    let m = self.reloc.landmark_rivals(&c.world_from_camera, &mut found);
                    candidates.extend_from_slice(&found[..m]);
                }
                0.0
            }
            Source::Views(region) => {
                let t_rank = Instant::now();
                let ranked = self.reloc.search_ranked(
                    descriptor,
                    region,
                    &mut self.aligners[0],
                    &self.pyramid,
                );
                candidates.extend_from_slice(ranked);
                t_rank.elapsed().as_secs_f64() * 1e3
            }
        }
    }

    /// Renders and verifies one candidate (or rival) through the gate.
    fn try_one(&mut self, c: &Candidate, tally: &mut Tally) -> Option<Verified> {
        self.try_at(
            Gate::Strict,
            (&c.world_from_camera, c.yaw_rad),
            c.ranked.index,
            tally,
        )
    }

    /// Renders and verifies `world_from_candidate` (with the yaw the search
    /// matched at; `None`: a precise pose) through `gate`; `index` names its
    /// keyframes.
    ///
    /// On local contrast (`STAR_BENCH_NORMALIZE_PX`) the candidate is
    /// aligned and judged on the normalized images. With
    /// `STAR_BENCH_NORMALIZE_GATE=plain` the pose it converges to is judged
    /// on the images as they are instead: aligned again from there (one
    /// start) against a plain render, through the same gate, so that the
    /// gate, the rivals and the twins keep the brightness that tells
    /// textured look-alike places apart (on scanned maps it refuses half
    /// the true poses again: docs/building-scale.md).
    fn try_at(
        &mut self,
        gate: Gate,
        start: (&Pose, Option<f64>),
        index: u32,
        tally: &mut Tally,
    ) -> Option<Verified> {
        if self.contrast.is_none() {
            return self.try_on(gate, start, index, tally, false);
        }
        let v = self.try_on(gate, start, index, tally, true)?;
        if !self.judge_plain {
            return Some(v);
        }
        self.try_on(gate, (&v.world_from_camera, None), index, tally, false)
    }

    /// [`Self::try_at`] on one kind of image: the normalized ones when
    /// `normalized` (and candidates are aligned on local contrast).
    fn try_on(
        &mut self,
        gate: Gate,
        start: (&Pose, Option<f64>),
        index: u32,
        tally: &mut Tally,
        normalized: bool,
    ) -> Option<Verified> {
        let gate = match gate {
            Gate::Strict => self.reloc.gate(),
            Gate::Loose => self.reloc.twins_mut().loose(),
        };
        let (candidate_r, pinhole, kview, tracker) = (
            &mut self.candidate_r,
            &self.pinhole,
            &mut self.kview,
            &self.tracker,
        );
        // On local contrast: the frame's normalized pyramid, and each
        // candidate's view normalized before its keyframe is prepared.
        let (mut contrast, pyramid) = match &mut self.contrast {
            Some((c, p)) if normalized => (Some(c), &*p),
            _ => (None, &self.pyramid),
        };
        let mut render = |world_from_keyframe: &Pose, kf: &mut Keyframe| {
            let t_render = Instant::now();
            candidate_r
                .render(world_from_keyframe, pinhole, kview)
                .ok()?;
            if let Some(c) = contrast.as_mut() {
                c.view(kview);
            }
            tally.renders += 1;
            let t_prepare = Instant::now();
            kf.prepare(kview, *world_from_keyframe, u64::from(index), tracker);
            tally.prepare_ms += t_prepare.elapsed().as_secs_f64() * 1e3;
            tally.render_ms += t_render.elapsed().as_secs_f64() * 1e3;
            Some(())
        };
        attempt(
            &mut self.aligners,
            pyramid,
            &self.camera,
            gate,
            start,
            (&mut self.spare, &mut self.returned),
            &mut render,
        )
    }

    /// The geometric twins of the keyframe just accepted (the last spare
    /// one), up to [`crate::reloc::twins::TWIN_CHECKS`] to check.
    fn twin_check(&mut self, truth: &Pose, rule: &crate::reloc::rivals::RivalRule) -> HeldTwins {
        let none = || {
            (
                TwinCheck::Unique,
                heapless::Vec::new(),
                heapless::Vec::new(),
            )
        };
        let Some(kf) = self.spare.last() else {
            return none();
        };
        let twins = self.reloc.twins_mut();
        if !crate::reloc::twins::plan_needs_twins(rule, &kf.world_from_keyframe, twins.prior_only())
        {
            // As the service: no search where the plan cannot use it.
            return none();
        }
        let check = match rule.prior.as_ref() {
            Some(prior) if twins.prior_only() => twins.check_near(kf, prior),
            _ => twins.check(kf),
        };
        // Where the held pose is another place, how well its view fits at
        // the truth (why the truth was, or was not, a twin); only when
        // logged, since it runs inside the timed search.
        let held = kf.world_from_keyframe;
        if tracing::enabled!(tracing::Level::DEBUG) && twins.has_map() && elsewhere(&held, truth) {
            let to_truth = crate::reloc::twins::twin_between(&held, truth);
            let fit = twins.score_of(&held.translation.vector, &to_truth);
            tracing::debug!(
                yaw_deg = to_truth.yaw_rad.to_degrees(),
                offset_m = ?to_truth.offset_m,
                score = fit.map(|f| f.0),
                free = fit.map(|f| f.1),
                check = ?check,
                found = twins.found().len(),
                turned = twins.turned().len(),
                "held at another place: the truth as its geometric twin"
            );
        }
        (
            check,
            twins.found().iter().copied().collect(),
            twins.turned().iter().copied().collect(),
        )
    }

    /// Whether `held` survives its geometric twins (`check`, from
    /// [`Self::twin_check`] when it was accepted), by the plan of
    /// [`crate::reloc::twins::plan`] under `rule`: false when it refuses
    /// outright, or when the frame passes the looser gate at a twin it
    /// lists, at another place.
    fn twins_pass(
        &mut self,
        held: &Verified,
        (check, found, turned): HeldTwins,
        (rule, truth): (&crate::reloc::rivals::RivalRule, &Pose),
        tally: &mut Tally,
    ) -> bool {
        let prior_only = self.reloc.twins_mut().prior_only();
        let planned = match plan(
            rule,
            &held.world_from_camera,
            (check, prior_only),
            (&found, &turned),
        ) {
            TwinPlan::Refuse(TwinRefusal::PriorPrefersATwin) => {
                tally.geometric_prior += 1;
                return false;
            }
            TwinPlan::Refuse(TwinRefusal::Degenerate) => {
                tally.geometric_degenerate += 1;
                return false;
            }
            TwinPlan::Check(planned) => planned,
        };
        let held_off_m = (truth.inverse() * held.world_from_camera)
            .translation
            .vector
            .norm();
        for twin in &planned {
            tally.geometric_checked += 1;
            let pose = twin_pose(&held.world_from_camera, twin);
            let off = truth.inverse() * pose;
            let passed = self.try_at(Gate::Loose, (&pose, None), u32::MAX, tally);
            let refused =
                passed.is_some_and(|r| elsewhere(&held.world_from_camera, &r.world_from_camera));
            tracing::debug!(
                yaw_deg = twin.yaw_rad.to_degrees(),
                score = twin.score,
                refused,
                held_off_m,
                off_truth_m = off.translation.vector.norm(),
                off_truth_deg = off.rotation.angle().to_degrees(),
                "geometric twin checked"
            );
            if refused {
                tally.geometric_refused += 1;
                return false;
            }
        }
        true
    }

    /// Where the nearest good keyframe sits in the full ranking: what a
    /// re-ranking stage over the top N could recover (`usize::MAX`: none
    /// near).
    pub(super) fn near_rank(&self, query: &QueryFrame, outcome: &Outcome) -> usize {
        let is_near = |world_from_camera: &Pose| {
            let e = query.truth.inverse() * world_from_camera;
            e.translation.vector.norm() <= 0.5 && e.rotation.angle().to_degrees() <= 20.0
        };
        let distance = |e: &crate::reloc::RelocEntry| {
            outcome
                .descriptor
                .iter()
                .map(|q| q.hamming(&e.descriptor))
                .min()
                .unwrap_or(u32::MAX)
        };
        let entries = &self.db.entries;
        let near_best = entries
            .iter()
            .filter(|e| is_near(&e.world_from_camera))
            .map(distance)
            .min();
        near_best.map_or(usize::MAX, |best| {
            entries.iter().filter(|e| distance(e) < best).count()
        })
    }
}

/// One candidate through [`try_candidate`] from `world_from_candidate`
/// (with the yaw the search matched at), keyframes drawn from `spare` and
/// filled by `render`; every keyframe is back in `spare` afterwards
/// (`returned` holds the recycled ones meanwhile).
#[allow(clippy::vec_box)] // `try_candidate` hands keyframes over boxed
pub(super) fn attempt(
    aligners: &mut [Aligner; 2],
    pyramid: &Pyramid,
    camera: &PinholeCamera,
    rc: &RelocConfig,
    (world_from_candidate, shift_yaw_rad): (&Pose, Option<f64>),
    (spare, returned): (&mut Vec<Box<Keyframe>>, &mut Vec<Box<Keyframe>>),
    render: &mut dyn FnMut(&Pose, &mut Keyframe) -> Option<()>,
) -> Option<Verified> {
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
        aligners,
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

/// A held pose's geometric twins: the check, the moved twins and the
/// turned ones ([`crate::reloc::twins::GeometricTwins::turned`]).
type HeldTwins = (
    TwinCheck,
    heapless::Vec<Twin, DEGENERATE_TWINS>,
    heapless::Vec<Twin, DEGENERATE_TWINS>,
);
