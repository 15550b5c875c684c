//! Diagnostics of a whole-map query (`STAR_BENCH_VERBOSE=1`): would the
//! database entry nearest the truth have been accepted, had retrieval found
//! it; how the frame aligns against a keyframe rendered at the truth itself
//! (from the truth, as a precise start is aligned), and how it correlates
//! there unaligned;
//! where each candidate was. `STAR_BENCH_DUMP=DIR` also writes the frame.

use crate::geometry::Pose;
use crate::track::Keyframe;

use super::query::QueryFrame;
use super::recover::{attempt, Outcome};
use super::setup::Bench;
use super::tally::Tally;

impl Bench {
    /// Prints the diagnostics of query number `done`.
    pub(super) fn diagnose(
        &mut self,
        query: &QueryFrame,
        outcome: &Outcome,
        done: usize,
        tally: &Tally,
    ) {
        // Diagnostics: would the nearest database entry (by pose)
        // have been accepted, had retrieval found it?
        let nearest = self
            .db
            .entries
            .iter()
            .enumerate()
            .min_by(|a, b| {
                let score = |e: &crate::reloc::RelocEntry| {
                    let d = query.truth.inverse() * e.world_from_camera;
                    d.translation.vector.norm() + 0.01 * d.rotation.angle().to_degrees()
                };
                score(a.1).total_cmp(&score(b.1))
            })
            .map(|(i, _)| i);
        let mut oracle = "none".to_string();
        if let Some(i) = nearest {
            let e = &self.db.entries[i];
            let (candidate_r, pinhole, kview, tracker) = (
                &mut self.candidate_r,
                &self.pinhole,
                &mut self.kview,
                &self.tracker,
            );
            let mut render = |world_from_keyframe: &Pose, kf: &mut Keyframe| {
                candidate_r
                    .render(world_from_keyframe, pinhole, kview)
                    .ok()?;
                kf.prepare(kview, *world_from_keyframe, i as u64, tracker);
                Some(())
            };
            let found = attempt(
                &mut self.aligners,
                &self.pyramid,
                &self.camera,
                self.reloc.gate(),
                (&e.world_from_camera, Some(0.0)),
                (&mut self.spare, &mut self.returned),
                &mut render,
            );
            let d = query.truth.inverse() * e.world_from_camera;
            let dist = outcome
                .descriptor
                .iter()
                .map(|q| q.hamming(&e.descriptor))
                .min()
                .unwrap_or(0);
            oracle = match found {
                Some(v) => {
                    let err = query.truth.inverse() * v.world_from_camera;
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
        if let Some(mut kf) = self.spare.pop() {
            if self
                .candidate_r
                .render(&query.truth, &self.pinhole, &mut self.kview)
                .is_ok()
            {
                kf.prepare(&self.kview, query.truth, 0, &self.tracker);
                // As a precise start is aligned ([`crate::reloc::verify_candidate`]).
                let a = self.aligners[0].align_without_coarsest(
                    &kf,
                    &self.pyramid,
                    &self.camera,
                    Pose::identity(),
                    crate::reloc::PRECISE_START_SKIPPED_LEVELS,
                );
                let q = a.quality;
                let corr = |camera_from_keyframe: &Pose, level| {
                    crate::track::correlations(
                        &kf,
                        &self.pyramid,
                        &self.camera,
                        camera_from_keyframe,
                        level,
                    )
                };
                let aligned = &a.camera_from_keyframe;
                let (c0, c1, c2) = (corr(aligned, 0), corr(aligned, 1), corr(aligned, 2));
                let trimmed =
                    |c: Option<crate::track::Correlations>| c.map_or(f32::NAN, |c| c.trimmed);
                let local = |c: Option<crate::track::Correlations>| c.map_or(f32::NAN, |c| c.local);
                let off = a.camera_from_keyframe.translation.vector.norm();
                let still = Pose::identity();
                let (s0, s1, s2) = (corr(&still, 0), corr(&still, 1), corr(&still, 2));
                let unaligned = format!(
                    "unaligned ncc {:.2}/{:.2}/{:.2} local {:.2}/{:.2}/{:.2}",
                    s0.map_or(f32::NAN, |c| c.all),
                    s1.map_or(f32::NAN, |c| c.all),
                    s2.map_or(f32::NAN, |c| c.all),
                    local(s0),
                    local(s1),
                    local(s2)
                );
                at_truth = format!(
                        "at truth: inliers {:.2} visible {:.2} residual {:.1} ncc {:.2}/{:.2}/{:.2} trimmed {:.2}/{:.2}/{:.2} local {:.2}/{:.2}/{:.2} gain {:.2} off {off:.3} m; {unaligned}",
                        q.inlier_ratio,
                        q.visible_ratio,
                        q.residual_rms,
                        q.correlation,
                        c1.map_or(f32::NAN, |c| c.all),
                        c2.map_or(f32::NAN, |c| c.all),
                        trimmed(c0),
                        trimmed(c1),
                        trimmed(c2),
                        local(c0),
                        local(c1),
                        local(c2),
                        a.gain
                    );
            }
            self.spare.push(kf);
        }
        let top1 = outcome.candidates.first().map_or(0, |c| c.ranked.distance);
        let cands: Vec<String> = outcome
            .candidates
            .iter()
            .map(|c| {
                let d = query.truth.inverse() * c.world_from_camera;
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
            if let Err(e) = crate::dataset::write_gray8(&path, &self.frame) {
                eprintln!("STAR_BENCH_DUMP: {e}");
            }
        }
        println!(
            "    query {done}: {} near rank {:?}, top-1 hamming {top1}; {oracle}; {at_truth}",
            if outcome.verdict.is_some() {
                "accepted"
            } else {
                "REFUSED"
            },
            tally.near_rank.last()
        );
    }
}
