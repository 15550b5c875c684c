//! Relocalization inside the STAR loop: what [`Localizer`] does with a
//! [`Relocalizer`] while lost.
//!
//! Each lost frame (after `reloc.resume_window_s`) with enough contrast is
//! searched: first within `search_radius_m + max_speed_m_s x (time lost)`
//! of the last tracked position, then over the whole map. The landmark pose
//! (the frame's corners matched to the map's landmarks, then RANSAC P3P)
//! comes first: matched to the landmarks within reach of the last position
//! (spatial cells), else, or when they give no pose, over the whole map
//! through the landmark vocabulary ([`crate::reloc::landmark_index`]); then the
//! `rank_candidates` nearest by whole-image descriptor are aligned against
//! their stored coarse points, and the top-k by that alignment follow,
//! placed where it moved them. Candidates are rendered on the render thread
//! (the lost frame waits for them; tracking never does) and aligned with the
//! tracker's aligner (the order and the prior: [`crate::reloc::prior`]).
//! The first that passes the strict gate within the motion prior's reach
//! (the radius above, and `search_yaw_deg + max_yaw_rate_deg_s x (time
//! lost)` of the last heading) becomes the keyframe and the prediction; one
//! the prior cannot vouch for (a cold start, a kidnap, a pose turned half
//! round in a symmetric room, on a scan one with little local contrast) is
//! held while its rivals at other places (on a scan the landmark poses at
//! the frame's other places first) are
//! verified ([`crate::reloc::rivals::RivalRule`], the rule `star bench
//! reloc` measures) and at the map's remembered symmetries, and refused
//! when one passes, unless one of the two places correlates decisively
//! better (`Judgment::HeldIsBetter`, `RivalIsBetter`); then at its
//! geometric twins, the places where its view's surfaces stand again
//! ([`crate::reloc::twins`]): refused when the view fits at many places or
//! the frame passes a looser gate at one. An accepted pose is not output
//! yet: the next
//! `verify_frames` frames must track through the same gate, and only then
//! is a pose output and `reset_counter` incremented. A wrong but confident
//! pose would need to fool the gate on consecutive frames. An attempt
//! allocates nothing (its candidates are held on the stack).

use crate::geometry::Pose;
use crate::reloc::prior::{landmark_regions, sources, Source};
use crate::reloc::rivals::{elsewhere, Judgment, RivalRule, LISTED_RIVALS};
use crate::reloc::twins::{plan, plan_needs_twins, twin_pose, TwinPlan, TwinRefusal};
use crate::reloc::{is_landmark_index, MAX_LANDMARK_ELSEWHERE};
use crate::reloc::{
    passes_gate, passes_resume_gate, passes_whole_gate, resume_local_floor, start_yaws_rad,
    through_lowered_first_level, Candidate, MAX_TOP_K,
};
use crate::reloc::{
    try_candidate, verify_candidate, MotionPrior, Query, RelocConfig, RelocDbError, Relocalizer,
    Verdict, Verified,
};
use crate::track::correlation::plain_and_local;
use crate::track::{Aligner, Keyframe, Pyramid};

use super::worker::RenderRequest;
use super::{Localizer, LossReason, TrackState};

impl Localizer {
    /// Enables relocalization with `relocalizer`; errors when its database
    /// was built for other intrinsics.
    pub fn set_relocalizer(&mut self, relocalizer: Relocalizer) -> Result<(), RelocDbError> {
        let db = relocalizer.database();
        db.check_compatible(&self.camera, db.map_fingerprint)?;
        tracing::info!(
            keyframes = db.entries.len(),
            top_k = relocalizer.config().top_k,
            "relocalization enabled"
        );
        self.attempt_budget_s = relocalizer.config().attempt_budget_s;
        self.reloc = Some(Box::new(relocalizer));
        Ok(())
    }

    /// Sets how long one relocalization attempt may go on trying new
    /// candidates, seconds (0: no limit); `[reloc] attempt_budget_s` by
    /// default.
    pub fn set_attempt_budget_s(&mut self, budget_s: f64) {
        self.attempt_budget_s = budget_s;
    }

    /// True when a relocalization database is set.
    pub fn has_relocalizer(&self) -> bool {
        self.reloc.is_some()
    }

    /// The frame in the pyramid aligned against the keyframe as a
    /// relocalization candidate is (coarse multi-start search, strict gate);
    /// `None` without a relocalizer, when not verifying, or when it fails.
    pub(super) fn verify_alignment(&mut self) -> Option<crate::track::Alignment> {
        if self.verify_left == 0 {
            return None;
        }
        // The relocalization's own gate, as the candidate it verifies had.
        let config = relocalization_gate_config(&self.reloc, &self.start_gate)?;
        let yaws = start_yaws_rad(config, 0.0);
        match verify_candidate(
            &mut self.reloc_aligners,
            &self.keyframe,
            &self.pyramid,
            &self.camera,
            config,
            &yaws,
        ) {
            // A prior alone does not vouch for a pose through the lowered
            // floor (see `RivalRule::for_held`).
            Verdict::Accepted(v) if !(self.verify_prior_only && v.lowered_first_level) => {
                Some(v.alignment)
            }
            _ => None,
        }
    }

    /// Whether `a`, a frame tracked from a verification frame that passed
    /// (`verify_passed`) after the search from the keyframe failed,
    /// confirms the relocalization: through the relocalization's own whole
    /// gate, correlations included, as the search's frames are, and as
    /// they are, not through its lowered first level where a prior alone
    /// vouches for the pose (a start pose or the last keyframe without a
    /// database: [`Self::verify_alignment`]).
    pub(super) fn verifies_by_tracking(&self, a: &crate::track::Alignment) -> bool {
        let Some(config) = relocalization_gate_config(&self.reloc, &self.start_gate) else {
            return false;
        };
        passes_whole_gate(&self.keyframe, &self.pyramid, &self.camera, a, config)
            .is_some_and(|c| !(self.verify_prior_only && through_lowered_first_level(&c, config)))
    }

    /// Whether a frame that passed the ordinary lost test may be output:
    /// while tracking, yes; while verifying, when it passes the gate; while
    /// lost, only within `resume_window_s` of the loss and through the gate.
    pub(super) fn may_resume(&self, capture_ns: u64, a: &crate::track::Alignment) -> bool {
        let Some(config) = gate_config(&self.reloc, &self.start_gate) else {
            return true;
        };
        if self.verify_left > 0 {
            // Verifying a relocalization: through its own gate.
            let gate = relocalization_gate_config(&self.reloc, &self.start_gate).unwrap_or(config);
            return passes_gate(&a.quality, a.gain, gate);
        }
        if self.state == TrackState::Tracking {
            return true;
        }
        // Resuming on its own after a short loss: the frame must also pass
        // the whole relocalization gate, correlations included (the lost
        // test's thresholds are for noticing a loss, not for trusting a
        // pose again: an occluder dragging the alignment off can keep the
        // inlier ratio high), read from level 0 even with
        // `gate_at_map_detail` (`passes_resume_gate`). Its local contrast
        // floor follows the frames tracked before the loss where they read
        // lower (blurred frames: `resume_local_fraction`); the drop test's
        // reference survives a short loss (`continuity`).
        let (reference, frames) = self.continuity.local_reference();
        let settled = frames >= super::LOCAL_MEAN_MIN_FRAMES;
        let min_local = resume_local_floor(config, reference.filter(|_| settled));
        self.lost_s(capture_ns) <= config.resume_window_s
            && passes_resume_gate(
                &self.keyframe,
                &self.pyramid,
                &self.camera,
                a,
                config,
                min_local,
            )
            .is_some()
    }

    /// With a gate (a database, a verified start, or [`Self::use_gate`]),
    /// tracking also needs the keyframe points to correlate with the frame
    /// at the aligned pose, in intensity (`reloc.track_min_correlation`)
    /// and in local contrast (`reloc.track_min_local_correlation`): a frame
    /// from elsewhere (a teleport, a look-alike wall) can pass the inlier
    /// test with an affine photometric fit, but does not correlate; an
    /// alignment sliding along a one-way texture keeps the intensity
    /// correlation but loses the fine texture.
    pub(super) fn correlation_check(
        &mut self,
        camera_from_keyframe: &crate::geometry::Pose,
    ) -> Result<(), LossReason> {
        let Some(config) = gate_config(&self.reloc, &self.start_gate) else {
            return Ok(());
        };
        let pose = camera_from_keyframe;
        // The plain correlation at level 1 (what `track_min_correlation`
        // was measured at); local contrast at its lowest over levels 0-2:
        // a slide of a few pixels shows at the finest level first. Unlike
        // the relocalization gate with `gate_at_map_detail`, this check
        // keeps level 0 on a map coarser than the camera
        // (`Keyframe::gate_level`): reading from
        // level 1 let drifting poses through on `aggressive --scanned`
        // seed 1 (1 cm), although on a 2 cm scan level 0 costs true poses
        // (docs/building-scale.md). `f32::min` skips a `NaN` level (no
        // coarser level for the local mean); with none, it is not a
        // refusal and the plain correlation decides.
        let samples = &mut self.correlation_samples;
        let mut at = |level| {
            plain_and_local(
                &self.keyframe,
                &self.pyramid,
                &self.camera,
                pose,
                level,
                samples,
            )
        };
        let ncc = at(1);
        let (at0, at2) = (at(0), at(2));
        let local = [at0, at2]
            .iter()
            .flatten()
            .fold(ncc.map_or(f32::NAN, |(_, l)| l), |m, &(_, l)| m.min(l));
        tracing::trace!(
            ncc = ncc.map(|c| c.0),
            local,
            local0 = at0.map(|c| c.1),
            local1 = ncc.map(|c| c.1),
            local2 = at2.map(|c| c.1),
            local_mean = self.continuity.local_mean().0,
            local_reference = self.continuity.local_reference().0,
            "tracking correlation"
        );
        self.last_local = local;
        // A drop against its own running mean (off at 0), the highest of
        // the last few frames' (`continuity::LOCAL_REFERENCE_FRAMES`): a
        // drift against a stale keyframe, or a slide, loses local contrast
        // before anything else.
        let dropped = local_dropped(
            self.policy.lost_local_correlation_drop,
            self.continuity.local_reference(),
            local,
        );
        let check = if dropped {
            Err(LossReason::LocalContrastDrop)
        } else if !ncc.is_some_and(|(all, _)| all >= config.track_min_correlation) {
            Err(LossReason::GateCorrelation)
        } else if local
            < local_floor(
                config,
                self.continuity.local_mean(),
                self.policy.lost_local_correlation_drop,
            )
        {
            Err(LossReason::LocalContrast)
        } else {
            Ok(())
        };
        if check.is_err() && self.state == TrackState::Tracking {
            tracing::debug!(
                ncc = ncc.map(|c| c.0),
                local,
                "frame does not correlate with the keyframe"
            );
        }
        check
    }

    /// Uses the relocalization gate of `gate` (the `[reloc]` settings) for
    /// every later loss without a database, while trusting the start pose:
    /// the benchmarks' trusted start. After a loss, tracking then resumes
    /// only as it does in flight (correlation with the keyframe within
    /// `resume_window_s`, else re-verified against the last keyframe
    /// through the gate).
    pub fn use_gate(&mut self, gate: &RelocConfig) {
        self.start_gate = Some(gate.clone());
    }

    /// Makes the start pose a hint that must pass the relocalization gate
    /// (`gate`, the `[reloc]` settings) before any pose is output: the
    /// loop starts lost. With `hint`, the first frames are aligned against
    /// the keyframe rendered at the start pose through the same coarse
    /// multi-start search and gate as a relocalization candidate, then
    /// `verify_frames` more; without one (a cold start), the first frame is
    /// searched in the database at once. While lost, without a database,
    /// each frame past `resume_window_s` is verified against the last
    /// keyframe the same way, so a wrong hint or a loss costs time and never
    /// a wrong pose.
    pub fn verify_start(&mut self, gate: &RelocConfig, hint: bool) {
        self.start_gate = Some(gate.clone());
        self.state = TrackState::Lost;
        self.lost_since_ns = Some(0);
        self.verify_left = if hint { gate.verify_frames + 1 } else { 0 };
        self.verify_passed = false;
        self.verify_prior_only = hint;
        tracing::info!(
            hint,
            database = self.reloc.is_some(),
            "searching: no pose is output until one passes the relocalization gate"
        );
    }

    /// Without a database: a lost frame past the resume window starts a
    /// verification against the last keyframe (coarse multi-start search and
    /// the gate), as a relocalization candidate would be verified.
    pub(super) fn reverify_without_database(&mut self, capture_ns: u64) {
        if self.reloc.is_some() || self.verify_left > 0 {
            return;
        }
        if let Some(gate) = &self.start_gate {
            if self.lost_s(capture_ns) > gate.resume_window_s {
                self.verify_left = gate.verify_frames + 1;
                self.verify_passed = false;
                self.verify_prior_only = true;
            }
        }
    }

    /// True when a lost frame should be searched in the database.
    pub(super) fn reloc_due(&self, capture_ns: u64) -> bool {
        self.reloc
            .as_ref()
            .is_some_and(|r| self.lost_s(capture_ns) > r.config().resume_window_s)
    }

    pub(super) fn lost_s(&self, capture_ns: u64) -> f64 {
        self.lost_since_ns
            .map_or(0.0, |t| capture_ns.saturating_sub(t) as f64 * 1e-9)
    }

    /// A relocalization was confirmed: count it and mark the discontinuity.
    pub(super) fn confirm_relocalization(&mut self) {
        self.last_before_reloc = None;
        self.reset_counter = self.reset_counter.wrapping_add(1);
        self.stats.relocalizations += 1;
        tracing::info!(
            reset_counter = self.reset_counter,
            "relocalized: tracking restarted"
        );
    }

    /// Searches, renders and verifies candidates for the frame already in
    /// `self.pyramid`; on success the candidate becomes the keyframe and the
    /// prediction, and verification starts.
    pub(super) fn relocalize(&mut self, pixels: &[u8], stride: usize, capture_ns: u64) {
        let Some(mut reloc) = self.reloc.take() else {
            return;
        };
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let Some(query) = reloc.describe(pixels, w, h, stride) else {
            tracing::debug!("lost frame without contrast; not searched");
            self.reloc = Some(reloc);
            return;
        };
        self.stats.reloc_attempts += 1;
        self.last_attempt.capture_ns = capture_ns;
        self.last_attempt.tried = 0;
        let started = std::time::Instant::now();
        // The render thread must be idle: take (and drop) a pending keyframe.
        if self.pending {
            match self.worker.wait_result() {
                Ok(kf) => self.worker.recycle(kf),
                Err(_) => self.stats.render_failures += 1,
            }
            self.pending = false;
        }
        let lost_s = self.lost_s(capture_ns);
        let prior_from = |last: Option<(u64, Pose)>| {
            last.map(|(_, pose)| MotionPrior::new(&pose, lost_s, reloc.config()))
        };
        let prior = prior_from(self.last);
        // Only a confirmed pose vouches for a place: after a relocalization
        // its next frame did not confirm, the rule's prior is the last
        // verified pose (on the `building` floor, a look-alike 26 m away
        // was accepted alone through the prior of its own unconfirmed
        // acceptance: docs/benchmarks.md, "Kidnaps on the building floor").
        let rule = reloc.rival_rule(match self.last_before_reloc {
            Some(verified) => prior_from(verified),
            None => prior,
        });
        // The landmark pose (features matched to the map's landmarks, then
        // PnP) is tried first, wherever it is (one candidate, a few renders;
        // on a scanned map it is the candidate that passes, and trying the
        // nearby views first cost seconds of renders per attempt): matched
        // to the landmarks within reach of the last position when there is
        // one, else (or when they give no pose) over the whole map through
        // the vocabulary. Then the database views ranked by the whole-image
        // descriptor, nearby first; on a cold start, before the whole map's
        // views, the landmark poses at the other places the frame's corners
        // fit, where the first was refused (on a scan:
        // `reloc::prior::sources`). Every candidate passes the same gate.
        let (regions, n_regions) = landmark_regions(prior.as_ref());
        let landmark = reloc
            .landmark_candidate(
                pixels,
                w,
                h,
                stride,
                regions.get(..n_regions).unwrap_or(&[]),
            )
            .map(|(c, found)| {
                tracing::debug!(
                    capture_ns,
                    inliers = found.inliers,
                    matches = found.matches,
                    "landmark pose found"
                );
                c
            });
        if landmark.is_none() {
            tracing::debug!(capture_ns, "no landmark pose");
        }
        // Every candidate of the attempt in the order the steps give them
        // (the rivals are chosen among all of them), and the entries tried.
        let mut candidates = [Candidate::default(); MAX_ATTEMPT_CANDIDATES];
        let mut n = 0usize;
        let mut tried = [u32::MAX; MAX_ATTEMPT_CANDIDATES];
        let mut n_tried = 0usize;
        let mut steps = sources(prior.as_ref()).into_iter().flatten();
        let mut passed: Option<(Verified, Box<Keyframe>)> = None;
        // The poses that passed the gate but could not be held: the frame
        // fits there as well, and any pose held later is judged against
        // them as against a rival that passed (they are among `tried`, so
        // the rival list leaves them out).
        let mut passed_unheld = heapless::Vec::<(Pose, f32), MAX_PASSED_UNHELD>::new();
        let mut unheld_overflow = false;
        let mut elsewhere_gathered = false;
        'steps: for source in steps.by_ref() {
            elsewhere_gathered |= matches!(source, Source::LandmarkElsewhere);
            let first = n;
            n += gather(
                &mut reloc,
                (&mut self.reloc_aligners[0], &self.pyramid),
                source,
                landmark,
                &query,
                candidates.get_mut(n..).unwrap_or(&mut []),
            );
            for &candidate in candidates.get(first..n).unwrap_or(&[]) {
                let c = candidate.ranked.index;
                if tried[..n_tried].contains(&c) {
                    continue;
                }
                let spent_s = started.elapsed().as_secs_f64();
                if n_tried > 0 && self.attempt_budget_s > 0.0 && spent_s > self.attempt_budget_s {
                    tracing::debug!(
                        candidates = n_tried,
                        spent_s,
                        "relocalization attempt out of time; the next frame starts a new one"
                    );
                    self.reloc = Some(reloc);
                    return;
                }
                let Some(slot) = tried.get_mut(n_tried) else {
                    break 'steps;
                };
                *slot = c;
                n_tried += 1;
                let (found, refused) = self.try_and_record(reloc.gate(), &candidate, capture_ns);
                let Some((v, kf)) = found else {
                    if refused {
                        break 'steps;
                    }
                    continue;
                };
                if !rule
                    .for_held(v.lowered_first_level, v.local_correlation)
                    .may_hold(&v.world_from_camera)
                {
                    tracing::debug!(
                        candidate = c,
                        local = v.local_correlation,
                        "passed only through the lowered first level, beyond the prior's reach: not held"
                    );
                    unheld_overflow |= passed_unheld
                        .push((v.world_from_camera, v.correlation))
                        .is_err();
                    self.worker.recycle(kf);
                    continue;
                }
                tracing::info!(
                    candidate = c,
                    coarse_score = candidate.score,
                    inliers = v.alignment.quality.inlier_ratio,
                    visible = v.alignment.quality.visible_ratio,
                    residual = v.alignment.quality.residual_rms,
                    "relocalization candidate passed the gate"
                );
                if rule
                    .for_held(v.lowered_first_level, v.local_correlation)
                    .accepts_alone(&v.world_from_camera)
                {
                    self.accept_relocalization(v, kf, capture_ns, reloc.config().verify_frames);
                    self.reloc = Some(reloc);
                    return;
                }
                passed = Some((v, kf));
                break 'steps;
            }
        }
        let Some((mut v, mut kf)) = passed else {
            tracing::debug!(candidates = n_tried, "relocalization failed for this frame");
            self.reloc = Some(reloc);
            return;
        };
        let rule = rule.for_held(v.lowered_first_level, v.local_correlation);
        // Away from where the prior can vouch for it (no prior, outside the
        // reach of the last position, or turned beyond the heading bound):
        // held while its rivals among the candidates of every step are
        // verified (`reloc::rivals`).
        for source in steps.filter(|s| !matches!(s, Source::LandmarkElsewhere)) {
            n += gather(
                &mut reloc,
                (&mut self.reloc_aligners[0], &self.pyramid),
                source,
                landmark,
                &query,
                candidates.get_mut(n..).unwrap_or(&mut []),
            );
        }
        // The landmark poses at the other places the frame's corners fit
        // come first among the rivals (already among the candidates when a
        // cold start's search reached them): beyond the prior's reach, and
        // within it for a pose the prior does not vouch for alone, where
        // they are verified on top of the near rivals
        // (`RivalRule::with_landmark_rivals`).
        let mut landmark_rivals = 0;
        if !elsewhere_gathered {
            let m = MAX_LANDMARK_ELSEWHERE.min(candidates.len() - n);
            candidates.copy_within(0..n, m);
            let added = reloc.landmark_rivals(&v.world_from_camera, &mut candidates[..m]);
            if added < m {
                candidates.copy_within(m..m + n, added);
            }
            n += added;
            landmark_rivals = added;
        }
        let rule = rule.with_landmark_rivals(landmark_rivals);
        let mut rivals = [0usize; LISTED_RIVALS];
        let n_rivals = rule.rivals(
            candidates.get(..n).unwrap_or(&[]),
            &v.world_from_camera,
            tried.get(..n_tried).unwrap_or(&[]),
            &mut rivals,
        );
        let all_checked = rule.may_decide(
            n_rivals,
            rule.count_rivals(
                candidates.get(..n).unwrap_or(&[]),
                &v.world_from_camera,
                tried.get(..n_tried).unwrap_or(&[]),
            ),
        );
        // The budget's rivals, and the rest of the list only once a
        // decisive correlation has chosen between two places.
        let first_rivals = rule.budget(&v.world_from_camera).max;
        let mut decided = false;
        for (k, &i) in rivals[..n_rivals].iter().enumerate() {
            if k >= first_rivals && !decided {
                break;
            }
            let Some(rival) = candidates.get(i).copied() else {
                continue;
            };
            let (found, refused) = self.try_and_record(reloc.gate(), &rival, capture_ns);
            let Some((r, r_kf)) = found else {
                if refused {
                    // A rival that could not be rendered was not ruled out.
                    tracing::debug!(capture_ns, "render thread busy during the rival check");
                    self.worker.recycle(kf);
                    self.reloc = Some(reloc);
                    return;
                }
                continue;
            };
            let judgment = rule.judge(
                (&v.world_from_camera, v.correlation),
                (&r.world_from_camera, r.correlation),
                all_checked,
            );
            if judgment != Judgment::SamePlace {
                self.remember_symmetry(&v.world_from_camera, &r.world_from_camera);
            }
            match judgment {
                Judgment::SamePlace => self.worker.recycle(r_kf),
                Judgment::HeldIsBetter | Judgment::RivalIsBetter => {
                    decided = true;
                    self.stats.reloc_decided += 1;
                    let rival_better = judgment == Judgment::RivalIsBetter;
                    tracing::info!(
                        capture_ns,
                        held = ?v.world_from_camera.translation.vector,
                        held_correlation = v.correlation,
                        rival = ?r.world_from_camera.translation.vector,
                        rival_correlation = r.correlation,
                        rival_better,
                        "two places pass the gate; one correlates decisively better"
                    );
                    if rival_better {
                        self.worker.recycle(std::mem::replace(&mut kf, r_kf));
                        v = r;
                    } else {
                        self.worker.recycle(r_kf);
                    }
                }
                Judgment::PriorChooses => {
                    tracing::info!(
                        capture_ns,
                        held = ?v.world_from_camera.translation.vector,
                        taken = ?r.world_from_camera.translation.vector,
                        "two places pass the gate; the one within the motion prior's reach is taken"
                    );
                    self.worker.recycle(kf);
                    self.accept_relocalization(r, r_kf, capture_ns, reloc.config().verify_frames);
                    self.reloc = Some(reloc);
                    return;
                }
                Judgment::Ambiguous => {
                    tracing::info!(
                        capture_ns,
                        first = ?v.world_from_camera.translation.vector,
                        first_correlation = v.correlation,
                        second = ?r.world_from_camera.translation.vector,
                        second_correlation = r.correlation,
                        all_checked,
                        "relocalization refused: two places pass the gate"
                    );
                    self.worker.recycle(r_kf);
                    self.worker.recycle(kf);
                    self.stats.reloc_ambiguous += 1;
                    self.reloc = Some(reloc);
                    return;
                }
            }
        }
        // The places that passed but could not be held are rivals that
        // passed: only a held pose that correlates decisively better than
        // each stands (`RivalRule::unheld_rival`).
        let unheld_rival = rule.unheld_rival(
            (&v.world_from_camera, v.correlation),
            &passed_unheld,
            all_checked,
        );
        if unheld_rival.is_some() || unheld_overflow {
            tracing::info!(
                capture_ns,
                held = ?v.world_from_camera.translation.vector,
                held_correlation = v.correlation,
                other = ?unheld_rival.map(|(p, _)| p.translation.vector),
                other_correlation = ?unheld_rival.map(|(_, c)| *c),
                "relocalization refused: the frame passed the gate at another place too (there only through the lowered first level)"
            );
            self.worker.recycle(kf);
            self.stats.reloc_ambiguous += 1;
            self.reloc = Some(reloc);
            return;
        }
        match self.twin_passes(&reloc, (&v, &rule), capture_ns) {
            Some(twin) => {
                tracing::info!(
                    capture_ns,
                    first = ?v.world_from_camera.translation.vector,
                    second = ?twin.translation.vector,
                    "relocalization refused: a known look-alike place passes the gate too"
                );
                self.worker.recycle(kf);
                self.stats.reloc_ambiguous += 1;
            }
            None if self.geometric_twins_refuse(&mut reloc, (&v, &rule), &kf, capture_ns) => {
                self.worker.recycle(kf);
                self.stats.reloc_ambiguous += 1;
            }
            None => {
                tracing::debug!(
                    rivals = n_rivals,
                    "no other place passes the gate; verifying"
                );
                self.accept_relocalization(v, kf, capture_ns, reloc.config().verify_frames);
            }
        }
        self.reloc = Some(reloc);
    }

    /// [`Self::try_reloc_candidate`] for `candidate` (a rival is verified
    /// as any candidate, refining renders included), recorded in the last
    /// attempt.
    fn try_and_record(
        &mut self,
        config: &RelocConfig,
        candidate: &Candidate,
        capture_ns: u64,
    ) -> (Option<(Verified, Box<Keyframe>)>, bool) {
        let (found, refused) = self.try_reloc_candidate(
            config,
            &candidate.world_from_camera,
            candidate.yaw_rad,
            capture_ns,
        );
        let attempt = &mut self.last_attempt;
        if let Some(slot) = attempt.candidates.get_mut(attempt.tried) {
            *slot = super::RelocCandidate {
                world_from_camera: found
                    .as_ref()
                    .map_or(candidate.world_from_camera, |(v, _)| v.world_from_camera),
                from_landmarks: is_landmark_index(candidate.ranked.index),
                accepted: found.is_some(),
            };
        }
        attempt.tried += 1;
        (found, refused)
    }

    /// Renders and aligns one relocalization candidate through the gate
    /// ([`try_candidate`]); also whether the render thread refused the
    /// request (busy).
    fn try_reloc_candidate(
        &mut self,
        config: &RelocConfig,
        world_from_candidate: &Pose,
        yaw_rad: Option<f64>,
        capture_ns: u64,
    ) -> (Option<(Verified, Box<Keyframe>)>, bool) {
        let mut refused = false;
        let worker = &self.worker;
        let stats = &mut self.stats;
        let next_id = &mut self.next_keyframe_id;
        let mut render = |world_from_keyframe: &Pose| {
            let requested = worker.try_request(RenderRequest {
                world_from_keyframe: *world_from_keyframe,
                id: *next_id,
                requested_at_ns: capture_ns,
                // A candidate: not verified (see `RenderRequest`).
                candidate: true,
            });
            if !requested {
                refused = true;
                return None;
            }
            *next_id += 1;
            stats.reloc_candidates += 1;
            match worker.wait_result() {
                Ok(kf) => Some(kf),
                Err(e) => {
                    stats.render_failures += 1;
                    tracing::warn!(error = %e, "relocalization render failed");
                    None
                }
            }
        };
        let found = try_candidate(
            &mut self.reloc_aligners,
            &self.pyramid,
            &self.camera,
            config,
            world_from_candidate,
            yaw_rad,
            &mut render,
            &mut |kf| worker.recycle(kf),
        );
        (found, refused)
    }

    /// Remembers that the map looks the same at `second` as at `first`:
    /// the rigid motion between them (`second = symmetry * first`), which
    /// later acceptances are checked against ([`Self::twin_passes`]). The
    /// twin rooms of a building stay twins; kept for the localizer's life,
    /// up to [`MAX_SYMMETRIES`].
    fn remember_symmetry(&mut self, first: &Pose, second: &Pose) {
        let symmetry = second * first.inverse();
        let known = self.map_symmetries.iter().any(|s| {
            [*s, s.inverse()].iter().any(|k| {
                (k.translation.vector - symmetry.translation.vector).norm() < AMBIGUITY_RADIUS_M
                    && k.rotation.angle_to(&symmetry.rotation) < 0.2
            })
        });
        if !known && self.map_symmetries.push(symmetry).is_ok() {
            tracing::info!(
                translation_m = ?symmetry.translation.vector,
                rotation_deg = symmetry.rotation.angle().to_degrees(),
                "look-alike places in the map: relocalizations are checked against both"
            );
        }
    }

    /// A pose where the frame also passes the gate through one of the map's
    /// known symmetries of the held pose (each way), at another place than
    /// the held pose, and that the held pose does not beat by a decisive
    /// correlation ([`twin_refuses`]); `None` when none does.
    fn twin_passes(
        &mut self,
        reloc: &Relocalizer,
        (held, rule): (&Verified, &RivalRule),
        capture_ns: u64,
    ) -> Option<Pose> {
        let config = reloc.gate();
        let world_from_camera = &held.world_from_camera;
        for i in 0..self.map_symmetries.len() {
            let symmetry = self.map_symmetries[i];
            for twin in [
                symmetry * world_from_camera,
                symmetry.inverse() * world_from_camera,
            ] {
                let (found, _) = self.try_reloc_candidate(config, &twin, None, capture_ns);
                let Some((v, kf)) = found else {
                    continue;
                };
                self.worker.recycle(kf);
                if twin_refuses(
                    rule,
                    (world_from_camera, held.correlation),
                    (&v.world_from_camera, v.correlation),
                ) {
                    return Some(v.world_from_camera);
                }
            }
        }
        None
    }

    /// Whether the map's geometry refuses `held` (aligned against `kf`; a
    /// pose whose place the prior of `rule` cannot vouch for) by the plan
    /// of [`crate::reloc::twins::plan`]: its view fits at many places, a
    /// twin stands within the prior's reach while the held pose does not,
    /// or the frame passes the looser gate at one of the twins the plan
    /// lists, moved or turned. A twin the render thread could not render
    /// was not ruled out, and refuses too. On a map without twin checks,
    /// never.
    fn geometric_twins_refuse(
        &mut self,
        reloc: &mut Relocalizer,
        (held, rule): (&Verified, &RivalRule),
        kf: &Keyframe,
        capture_ns: u64,
    ) -> bool {
        let prior_only = reloc.twins_mut().prior_only();
        if !reloc.twins_mut().has_occupancy()
            || !plan_needs_twins(rule, &held.world_from_camera, prior_only)
        {
            return false;
        }
        let check = match rule.prior.as_ref() {
            Some(prior) if prior_only => reloc.twins_mut().check_near(kf, prior),
            _ => reloc.twins_mut().check(kf),
        };
        let twins = reloc.twins_mut();
        tracing::debug!(
            capture_ns,
            ?check,
            found = ?twins.found(),
            turned = ?twins.turned(),
            "geometric twins of the held pose"
        );
        let planned = match plan(
            rule,
            &held.world_from_camera,
            (check, prior_only),
            (twins.found(), twins.turned()),
        ) {
            TwinPlan::Refuse(TwinRefusal::PriorPrefersATwin) => {
                tracing::info!(
                    capture_ns,
                    held = ?held.world_from_camera.translation.vector,
                    "relocalization refused: the view's geometry stands again where the motion prior expects the vehicle"
                );
                return true;
            }
            TwinPlan::Refuse(TwinRefusal::Degenerate) => {
                tracing::info!(
                    capture_ns,
                    held = ?held.world_from_camera.translation.vector,
                    "relocalization refused: the view's geometry fits at many places in the map"
                );
                return true;
            }
            TwinPlan::Check(planned) => planned,
        };
        for twin in planned {
            let pose = twin_pose(&held.world_from_camera, &twin);
            let (found, refused) =
                self.try_reloc_candidate(reloc.twins_mut().loose(), &pose, None, capture_ns);
            if refused {
                tracing::debug!(
                    capture_ns,
                    "render thread busy during the geometric twin check"
                );
                return true;
            }
            let Some((r, r_kf)) = found else {
                continue;
            };
            self.worker.recycle(r_kf);
            if elsewhere(&held.world_from_camera, &r.world_from_camera) {
                tracing::info!(
                    capture_ns,
                    held = ?held.world_from_camera.translation.vector,
                    twin = ?r.world_from_camera.translation.vector,
                    twin_score = twin.score,
                    twin_yaw_deg = twin.yaw_rad.to_degrees(),
                    "relocalization refused: the frame passes at a place where the map's geometry repeats"
                );
                return true;
            }
        }
        false
    }

    /// Takes a candidate that passed the gate: its keyframe becomes the
    /// current one, and `verify_frames` more frames must track before any
    /// pose goes out (none: at once).
    fn accept_relocalization(
        &mut self,
        v: Verified,
        kf: Box<Keyframe>,
        capture_ns: u64,
        verify_frames: u32,
    ) {
        let old = std::mem::replace(&mut self.keyframe, kf);
        self.worker.recycle(old);
        self.stats.keyframes += 1;
        if verify_frames > 0 {
            // Until confirmed, the pose vouches for no later attempt.
            let before = self.last;
            self.last_before_reloc.get_or_insert(before);
        }
        self.last = Some((capture_ns, v.world_from_camera));
        self.velocity = nalgebra::Vector6::zeros();
        self.tracked_run = 0;
        self.continuity.reset();
        self.verify_left = verify_frames;
        self.verify_passed = false;
        self.verify_prior_only = false;
        if self.verify_left == 0 {
            self.confirm_relocalization();
            self.state = TrackState::Tracking;
            self.lost_since_ns = None;
        }
    }
}

/// Most poses of one attempt that passed the gate without being held that
/// are remembered; past it, a pose held later in the attempt is refused.
const MAX_PASSED_UNHELD: usize = 8;

/// Candidates one attempt can hold: the landmark pose, the views of the
/// two view steps (near the last position, the whole map) and the
/// landmark poses at other places.
const MAX_ATTEMPT_CANDIDATES: usize = 2 * MAX_TOP_K + 1 + MAX_LANDMARK_ELSEWHERE;
/// How far apart the translations of two remembered symmetries must be for
/// them to be two symmetries, m (`reloc::rivals::RIVAL_MIN_M`).
const AMBIGUITY_RADIUS_M: f64 = crate::reloc::rivals::RIVAL_MIN_M;

/// Whether a pose `twin` (with its plain correlation), where the frame
/// passed the gate through one of the map's remembered symmetries of the
/// `held` pose, refuses it: judged as a rival that passed, every rival
/// checked (`RivalRule::judge`), anything but the same place
/// (`reloc::rivals::elsewhere`: within `RIVAL_MIN_M` and turned by at most
/// `RIVAL_MIN_TURN_DEG`) or a held pose decisively better. A symmetry of a
/// room turned about its middle can put the twin beside the held pose,
/// facing another wall: another place too.
fn twin_refuses(rule: &RivalRule, held: (&Pose, f32), twin: (&Pose, f32)) -> bool {
    !matches!(
        rule.judge(held, twin, true),
        Judgment::SamePlace | Judgment::HeldIsBetter
    )
}

/// Look-alike pairs of places the localizer remembers (the map's
/// symmetries, see [`Localizer::remember_symmetry`]).
pub(super) const MAX_SYMMETRIES: usize = 8;

/// Writes the candidates of one attempt step from `source` to `out` (the
/// landmark pose, or the views `reloc` finds and ranks in a region) and
/// returns how many.
fn gather(
    reloc: &mut Relocalizer,
    (aligner, pyramid): (&mut Aligner, &Pyramid),
    source: Source,
    landmark: Option<Candidate>,
    query: &Query,
    out: &mut [Candidate],
) -> usize {
    match source {
        Source::Landmark => match (landmark, out.first_mut()) {
            (Some(c), Some(slot)) => {
                *slot = c;
                1
            }
            _ => 0,
        },
        Source::LandmarkElsewhere => match landmark {
            Some(c) => reloc.landmark_rivals(&c.world_from_camera, out),
            None => 0,
        },
        Source::Views(region) => {
            let found = reloc.search_ranked(query, region, aligner, pyramid);
            let n = found.len().min(out.len());
            out[..n].copy_from_slice(&found[..n]);
            n
        }
    }
}

/// Whether a frame's local contrast correlation `local` fell below `drop`
/// times its running mean (`mean` over `frames` tracked frames):
/// `[keyframe] lost_local_correlation_drop`, off at 0, and silent until the
/// mean covers [`super::LOCAL_MEAN_MIN_FRAMES`]. A `NaN` local correlation
/// (no level measured) is no drop.
fn local_dropped(drop: f32, (mean, frames): (Option<f32>, u32), local: f32) -> bool {
    drop > 0.0
        && frames >= super::LOCAL_MEAN_MIN_FRAMES
        && mean.is_some_and(|mean| local < drop * mean)
}

/// The local contrast floor of a tracked frame: `track_min_local_correlation`,
/// lowered in proportion to the settled running mean `mean` (over `frames`
/// tracked frames) where that is below `track_local_reference`, to no lower
/// than `track_min_local_correlation_lowest`; a map with less fine detail
/// than the camera reads lower at true poses. Only with the drop test on
/// (`drop` > 0), which then still refuses a frame that falls below `drop`
/// times the mean.
fn local_floor(config: &RelocConfig, (mean, frames): (Option<f32>, u32), drop: f32) -> f32 {
    let floor = config.track_min_local_correlation;
    let reference = config.track_local_reference;
    match mean {
        Some(mean) if drop > 0.0 && reference > 0.0 && frames >= super::LOCAL_MEAN_MIN_FRAMES => {
            let scaled = floor * (mean / reference).min(1.0);
            if scaled.is_nan() {
                floor
            } else {
                scaled.max(config.track_min_local_correlation_lowest.min(floor))
            }
        }
        _ => floor,
    }
}

/// The gate settings: the database's, else those given to
/// [`Localizer::verify_start`]; `None` when neither was set.
fn gate_config<'a>(
    reloc: &'a Option<Box<Relocalizer>>,
    start_gate: &'a Option<RelocConfig>,
) -> Option<&'a RelocConfig> {
    reloc
        .as_deref()
        .map(Relocalizer::config)
        .or(start_gate.as_ref())
}

/// As [`gate_config`], but the database's relocalization gate
/// ([`Relocalizer::gate`]: lower floors on a map checked for twins) in place
/// of its `[reloc]` settings: for the candidates of a relocalization and
/// the frames that verify one.
fn relocalization_gate_config<'a>(
    reloc: &'a Option<Box<Relocalizer>>,
    start_gate: &'a Option<RelocConfig>,
) -> Option<&'a RelocConfig> {
    reloc
        .as_deref()
        .map(Relocalizer::gate)
        .or(start_gate.as_ref())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn facing(x_m: f64, yaw_deg: f64) -> Pose {
        Pose::from_parts(
            nalgebra::Translation3::new(x_m, 0.0, 1.4),
            nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_deg.to_radians()),
        )
    }

    #[test]
    fn a_twin_turned_at_the_held_spot_refuses_it() {
        let cold = RivalRule::new(None);
        let held = facing(1.0, 10.0);
        // Both places read alike: no decisive correlation.
        let refuses = |twin: &Pose| twin_refuses(&cold, (&held, 0.8), (twin, 0.78));
        // The seed-3 case of the one-room building, remembered: 0.86 m and
        // 89.8 degrees from the held pose. Under the old rule (distance
        // alone, 1 m) it refused nothing.
        let turned = facing(1.86, 99.8);
        assert!(refuses(&turned));
        // Turned half round at the same spot.
        assert!(refuses(&facing(1.0, 190.0)));
        // Two metres away, not turned.
        assert!(refuses(&facing(3.0, 10.0)));
        // The held pose correlates decisively better: it stands.
        assert!(!twin_refuses(&cold, (&held, 0.9), (&turned, 0.6)));
        // Aligned back onto the held pose (near, barely turned): no other
        // place.
        assert!(!refuses(&facing(1.3, 25.0)));
        assert!(!refuses(&held));
    }

    #[test]
    fn local_contrast_drops_only_against_a_settled_mean() {
        let settled = super::super::LOCAL_MEAN_MIN_FRAMES;
        // The drift of `aggressive --scanned` seed 1: 0.37 against a mean
        // of 0.73.
        assert!(local_dropped(0.7, (Some(0.73), settled), 0.37));
        // A right frame at 0.74 of its mean stays.
        assert!(!local_dropped(0.7, (Some(0.73), settled), 0.74 * 0.73));
        // Off at 0; no mean yet; a mean over too few frames (the first
        // frames after a start sit on their keyframe's pose).
        assert!(!local_dropped(0.0, (Some(0.73), settled), 0.1));
        assert!(!local_dropped(0.7, (None, settled), 0.1));
        assert!(!local_dropped(0.7, (Some(0.78), settled - 1), 0.5));
        // No level measured: no drop.
        assert!(!local_dropped(0.7, (Some(0.73), settled), f32::NAN));
    }

    #[test]
    fn local_floor_follows_a_settled_mean_below_the_reference_only() {
        let settled = super::super::LOCAL_MEAN_MIN_FRAMES;
        let config = RelocConfig::default();
        let floor = config.track_min_local_correlation;
        let near = |a: f32, b: f32| (a - b).abs() < 1e-6;
        // A map as fine as the camera (true poses 0.5 and up): the floor.
        assert!(near(
            local_floor(&config, (Some(0.73), settled), 0.7),
            floor
        ));
        // The 2 cm scan (mean 0.36): lowered in proportion, 0.216, under
        // its lowest true pose (0.283).
        let scan = local_floor(&config, (Some(0.36), settled), 0.7);
        assert!(near(scan, floor * 0.36 / 0.5), "{scan}");
        assert!(scan < 0.283);
        // Never under the lowest, whatever the mean.
        assert!(near(
            local_floor(&config, (Some(0.05), settled), 0.7),
            config.track_min_local_correlation_lowest
        ));
        // Not before the mean settles, nor with the drop test off, nor with
        // the reference at 0, nor on a NaN mean.
        assert!(near(
            local_floor(&config, (Some(0.36), settled - 1), 0.7),
            floor
        ));
        assert!(near(local_floor(&config, (None, settled), 0.7), floor));
        assert!(near(
            local_floor(&config, (Some(0.36), settled), 0.0),
            floor
        ));
        let off = RelocConfig {
            track_local_reference: 0.0,
            ..RelocConfig::default()
        };
        assert!(near(local_floor(&off, (Some(0.36), settled), 0.7), floor));
        assert!(near(
            local_floor(&config, (Some(f32::NAN), settled), 0.7),
            floor
        ));
    }
}
