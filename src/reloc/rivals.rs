//! Look-alike places: when a relocalized pose may be taken on the motion
//! prior alone, and otherwise which candidates at other places must fail
//! the gate before it is accepted. One rule, for the service
//! ([`crate::localizer`]) and `star bench reloc` alike ([`RivalRule`]).
//!
//! A map can repeat itself (the `building` preset has 6 room designs, each
//! built 3-4 times to the last vertex): from inside a room, its twin
//! renders the same image, so the gate passes there as well, and the
//! first candidate to pass would win whichever twin it stands in; a room
//! symmetric enough under a half turn passes at its mirror pose, a step
//! away and facing back. Takes the motion prior of the attempt (none on a
//! cold start, [`MotionPrior`]), the candidates of one attempt (the
//! landmark pose and the descriptor's, with their coarse-alignment
//! scores), the ones already tried, and the pose that passed; gives:
//!
//! - whether that pose may be held at all ([`RivalRule::may_hold`]): not
//!   one that passed only through its first level's lowered floor beyond
//!   the prior's reach (or on a cold start);
//! - whether it may be accepted without rivals
//!   ([`RivalRule::accepts_alone`]): only within the prior's reach in
//!   position and heading, never a pose that passed the gate only
//!   through its first level's lowered floor ([`RivalRule::for_held`]),
//!   and on a scan only with enough local contrast
//!   ([`RivalRule::with_alone_floor`]);
//! - how many rivals to verify and how near the best score they must be
//!   ([`RivalRule::budget`]): [`MAX_RIVALS`] within
//!   [`RIVAL_SCORE_MARGIN`] without a prior or outside its radius (look-
//!   alikes anywhere), [`NEAR_MAX_RIVALS`] within
//!   [`NEAR_RIVAL_SCORE_MARGIN`] inside the radius but turned beyond the
//!   heading bound (the twins are out of reach: only the place's own
//!   symmetry can fool the gate), and on top of it, within the prior's
//!   reach, the landmark poses at the frame's other places
//!   ([`RivalRule::with_landmark_rivals`]);
//! - which candidates are rivals ([`RivalRule::rivals`], built on
//!   [`RivalRule::is_rival`]; on a scan the caller puts the landmark poses
//!   at the other places the frame fits first for every pose held, one
//!   not accepted alone, within the prior's reach too,
//!   [`crate::reloc::Relocalizer::landmark_rivals`]): more than
//!   [`RIVAL_MIN_M`] from the pose,
//!   not tried yet in this attempt, scored within the margin of the best
//!   candidate near the pose (a landmark pose elsewhere always
//!   qualifies), in the candidates' order, best first, one per place
//!   ([`SAME_PLACE_DEG`]).
//!
//! The caller renders and verifies them as any candidate (the same gate,
//! refining renders included: a twin seen from a database view may need
//! them as the accepted pose did; rendered once, 10 of 100 cold starts on
//! the `building` got through), and [`RivalRule::judge`] says what a rival
//! that passes means: the same place (it aligned back onto the pose), the
//! prior's choice (the held pose was beyond the prior's reach, the rival
//! is within it: the order the candidates came in must not decide), a
//! decisive difference (one place correlates with the frame far better
//! than the other: a look-alike room whose furniture stands elsewhere,
//! see [`DECISIVE_MARGIN`]), or an ambiguous frame. Nothing here
//! allocates.

use crate::geometry::Pose;

use super::prior::MotionPrior;
use super::search::Candidate;

/// A candidate farther than this from the accepted pose stands at another
/// place, meters.
pub const RIVAL_MIN_M: f64 = 1.0;
/// A candidate at another place is a rival when its coarse-alignment score
/// is at least the best near the accepted pose less this: without a prior,
/// or outside its radius (look-alikes anywhere) ...
pub const RIVAL_SCORE_MARGIN: f32 = 0.3;
/// ... and inside the prior's radius (where only the place's own symmetry
/// can fool the gate: the twins are out of reach).
pub const NEAR_RIVAL_SCORE_MARGIN: f32 = 0.15;
/// Most rivals verified per accepted pose without a prior or outside its
/// radius ...
pub const MAX_RIVALS: usize = 4;
/// ... and inside its radius.
pub const NEAR_MAX_RIVALS: usize = 2;
/// Most rivals listed: once a rival has passed and one of the two places
/// correlated decisively better, up to twice the budget's places are
/// verified, so that the choice is made only when every rival was (see
/// [`RivalRule::judge`]).
pub const LISTED_RIVALS: usize = 2 * MAX_RIVALS;

/// Two places that both pass the gate are told apart when one's plain
/// correlation with the frame (the smallest over pyramid levels 0-2,
/// [`crate::reloc::Verified::correlation`]) exceeds the other's by at least
/// this, and reaches [`DECISIVE_MIN_CORRELATION`] ...
///
/// The gate tolerates what the map lacks (people, moved objects), so a
/// look-alike room whose furniture stands elsewhere passes it; the plain
/// correlation does not forgive the misplaced furniture. Measured on the
/// `building` floor (2026-11-25, 130 pairs of places that both passed, of
/// look-alike and of identical rooms, `docs/reloc-scale.md`): wherever the
/// difference was 0.075 or more, the better place was the true one; where
/// the better place was the wrong one, the difference was at most 0.050.
pub const DECISIVE_MARGIN: f32 = 0.08;
/// ... (the true places of those pairs correlated at 0.73-0.96, the wrong
/// ones at most 0.80 where the other place was the true one; true poses in
/// the `realistic` test room correlate at 0.72-0.79).
pub const DECISIVE_MIN_CORRELATION: f32 = 0.7;

/// A candidate turned more than this from the accepted pose stands at
/// another place too, whatever the distance, degrees. A room's own
/// symmetry can pass the gate there: in the one-room `building` (seed 3 of
/// `star bench reloc`, 2026-12-07) a landmark pose 0.86 m from the truth
/// and turned 89.8 degrees passed at correlation 0.52, while the true place,
/// among the candidates at 0.86 m, correlated at 0.96 and was never
/// verified against it. Three of the database's 15-degree yaw steps.
pub const RIVAL_MIN_TURN_DEG: f64 = 45.0;

/// Whether a rival verified at `rival` stands at another place than
/// `accepted`: farther than [`RIVAL_MIN_M`] or turned by more than
/// [`RIVAL_MIN_TURN_DEG`] (a rival can align back to the accepted pose
/// itself: that is no ambiguity).
pub fn elsewhere(accepted: &Pose, rival: &Pose) -> bool {
    (rival.translation.vector - accepted.translation.vector).norm() > RIVAL_MIN_M
        || (accepted.rotation.inverse() * rival.rotation)
            .angle()
            .to_degrees()
            > RIVAL_MIN_TURN_DEG
}

/// What a rival that passed the gate means for the pose held.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Judgment {
    /// It aligned back onto the held pose: no other place.
    SamePlace,
    /// It stands at another place within the prior's reach, while the held
    /// pose is beyond it: the prior chooses the rival.
    PriorChooses,
    /// The held pose correlates decisively better than the rival's place
    /// ([`DECISIVE_MARGIN`]): it stays held, the other rivals are still
    /// verified.
    HeldIsBetter,
    /// The rival's place correlates decisively better than the held pose:
    /// it is held instead, the other rivals are still verified.
    RivalIsBetter,
    /// Another place passes as well and neither the prior nor the
    /// correlation can choose: the frame is refused.
    Ambiguous,
}

/// How many rivals to verify, and how near the best score near the
/// accepted pose they must have scored.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Budget {
    /// Most rivals verified (0: accepted on the prior alone) ...
    pub max: usize,
    /// Score margin below the best candidate near the accepted pose.
    pub margin: f32,
}

impl Budget {
    /// ... and, once a decisive correlation has chosen between two places
    /// ([`Judgment::HeldIsBetter`], [`Judgment::RivalIsBetter`]), twice
    /// that, so that the choice stands only when every rival place was
    /// verified.
    pub fn deciding_max(&self) -> usize {
        (2 * self.max).min(LISTED_RIVALS)
    }
}

/// The rival rule of one attempt.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RivalRule {
    /// Where the vehicle can be; `None` on a cold start.
    pub prior: Option<MotionPrior>,
    /// The pose held passed the gate only through its first level's lowered
    /// floor ([`crate::reloc::Verified::lowered_first_level`]): the prior
    /// does not vouch for it, and its rivals are verified as on a cold
    /// start ([`Self::for_held`]).
    pub lowered: bool,
    /// The least local contrast of a pose accepted on the prior alone
    /// ([`Self::with_alone_floor`]; -inf: any that passed the gate).
    pub alone_min_local: f32,
    /// The pose held read less local contrast than that
    /// ([`Self::for_held`]): its near rivals are verified first.
    pub weak: bool,
    /// A pose through the lowered floor may be held beyond the prior's
    /// reach (`[reloc] lowered_floor_without_prior`, [`Self::may_hold`]).
    pub lowered_without_prior: bool,
    /// The least plain correlation of the place a decisive correlation
    /// chooses ([`Self::with_decisive_floor`]; [`DECISIVE_MIN_CORRELATION`]
    /// by default).
    pub decisive_min_correlation: f32,
    /// How many landmark poses at the frame's other places the caller
    /// listed first among the rivals of a held pose within the prior's
    /// reach ([`Self::with_landmark_rivals`]): verified on top of the
    /// budget.
    pub landmark_rivals: usize,
    /// A decisive correlation may choose once the listed rivals are
    /// verified, though more places were eligible
    /// ([`Self::with_listed_rivals_deciding`], [`Self::may_decide`]).
    pub listed_rivals_decide: bool,
}

impl RivalRule {
    /// The rule under `prior` (none: a cold start).
    pub fn new(prior: Option<MotionPrior>) -> Self {
        Self {
            prior,
            lowered: false,
            alone_min_local: f32::NEG_INFINITY,
            weak: false,
            lowered_without_prior: false,
            decisive_min_correlation: DECISIVE_MIN_CORRELATION,
            landmark_rivals: 0,
            listed_rivals_decide: false,
        }
    }

    /// The rule where a decisive plain correlation ([`DECISIVE_MARGIN`])
    /// chooses between two places that both pass the gate only for a place
    /// that correlates at least `min_correlation` (never less than
    /// [`DECISIVE_MIN_CORRELATION`]); else the frame is refused as
    /// ambiguous ([`Self::judge`]). For a scanned map
    /// ([`crate::reloc::Relocalizer::rival_rule`], `[reloc]
    /// twin_checked_decisive_min_correlation`).
    ///
    /// Why: [`DECISIVE_MARGIN`] and its floor were measured on the textured
    /// floor, whose look-alike rooms differ in where their furniture
    /// stands. On a scan the baked light of one stretch of corridor can
    /// look like the frame as much as the frame's own place does. On the
    /// scanned floor a paced kidnap (`star bench integrity --kinds kidnap
    /// --seed 8`) held a place 12.7 m from the truth and turned 180 degrees
    /// from it because it read 0.749 against a second wrong place's 0.627;
    /// the truth was never aligned, and the pose was sent. Over 6 seeds of
    /// `star bench reloc` there, 48 choices took the right place at
    /// 0.77-0.93 and 3 a wrong one at 0.744-0.753 (docs/building-scale.md,
    /// "A decisive correlation between two wrong places").
    pub fn with_decisive_floor(self, min_correlation: f32) -> Self {
        Self {
            decisive_min_correlation: min_correlation,
            ..self
        }
    }

    /// The rule where a decisive correlation may (`allowed`) choose between
    /// two places once every listed rival ([`Self::rivals`], up to
    /// [`Budget::deciding_max`]) is verified, though more places were
    /// eligible ([`Self::may_decide`]); else only when every eligible place
    /// is listed. For a scanned map (`[reloc]
    /// twin_checked_decisive_with_listed_rivals`), with its higher floor
    /// ([`Self::with_decisive_floor`]).
    ///
    /// Why: on the scanned floor (`star bench reloc --kidnaps`, seeds 1-5,
    /// 7 and 8; docs/building-scale.md, "Deciding on the listed rivals"),
    /// of 254 pairs of places that both passed the gate with the truth one
    /// of the two, the place that read a plain correlation of 0.8 or more
    /// and 0.08 above the other was the truth in 142, and never the wrong
    /// one (wrong places read at most 0.742, and 0.75 where both were
    /// wrong); 42 frames were refused only because more places were
    /// eligible than listed. What the guard is for, a twin room that reads
    /// as well as the place chosen, is what the geometric twin check after
    /// the rivals finds on a scan (beyond the prior's reach).
    pub fn with_listed_rivals_deciding(self, allowed: bool) -> Self {
        Self {
            listed_rivals_decide: allowed,
            ..self
        }
    }

    /// Whether a decisive correlation may choose between two places that
    /// both pass the gate ([`Self::judge`]'s `all_checked`), where `listed`
    /// rivals were listed of `eligible` places ([`Self::count_rivals`]):
    /// when every eligible place is listed (an unlisted one could read as
    /// well as the place chosen), or with [`Self::listed_rivals_decide`].
    pub fn may_decide(&self, listed: usize, eligible: usize) -> bool {
        eligible <= listed || self.listed_rivals_decide
    }

    /// The rule for a held pose among whose rivals the caller listed `added`
    /// landmark poses at the frame's other places first
    /// ([`crate::reloc::Relocalizer::landmark_rivals`]). Within the prior's
    /// reach they are verified on top of [`Self::budget`]'s rivals, so that
    /// the place's own symmetry (the near rivals) is still checked; beyond
    /// it they are among the budget's, as they always were.
    ///
    /// Why: on a scanned map the prior does not vouch alone for a pose
    /// with little local contrast ([`Self::weak`]), and its near rivals
    /// (the database's views, ranked by the whole-image descriptor) do not
    /// hold the true place where it is a look-alike room within reach. On
    /// the scanned floor a kidnapped prior's search (`star bench reloc
    /// --kidnaps`, seed 7, query 9) took a landmark pose 7.98 m from the
    /// truth and turned 90 degrees (local contrast 0.75): its two near
    /// rivals failed the gate, and the truth, which the same frame's cold
    /// search found at plain correlation 0.92 with this very place as its
    /// rival, was never verified (docs/building-scale.md, "The landmarks'
    /// other places as rivals within reach").
    pub fn with_landmark_rivals(self, added: usize) -> Self {
        Self {
            landmark_rivals: added,
            ..self
        }
    }

    /// The rule where a pose through the lowered floor may (`allowed`) or
    /// may not be held beyond the prior's reach ([`Self::may_hold`]).
    pub fn with_lowered_without_prior(self, allowed: bool) -> Self {
        Self {
            lowered_without_prior: allowed,
            ..self
        }
    }

    /// The rule where a pose is accepted on the prior alone only with at
    /// least `min_local` local contrast (`[reloc]
    /// prior_alone_min_local_correlation` on a scanned map,
    /// [`crate::reloc::Relocalizer::rival_rule`]).
    ///
    /// Why: on a scanned map a look-alike passes the gate with figures
    /// right poses also read. On the scanned floor a window search took a
    /// turned look-alike 1.4 m and 90 degrees from the truth on the prior
    /// alone (local contrast 0.714 over every level), and the truth was no
    /// geometric twin of it (its view fit there at 0.66; a twin needs
    /// 0.9). Verified as its rival, the truth correlates decisively better.
    pub fn with_alone_floor(self, min_local: f32) -> Self {
        Self {
            alone_min_local: min_local,
            ..self
        }
    }

    /// The rule for a pose held: `lowered_first_level` or not
    /// ([`Self::lowered`]), with `local_correlation` of local contrast
    /// ([`Self::weak`] below the rule's floor).
    ///
    /// Why the lowered floor: it lets true poses on a scanned map through
    /// where the map's colors are blurred, and a look-alike with them. On
    /// the scanned floor of look-alike rooms a window search took a turned
    /// look-alike 1.4 m and 90 degrees from the truth on the prior alone
    /// (0.53-0.57 at the first level; the true place, 0.88, was never
    /// tried). Verified against its rivals, the true place correlates
    /// decisively better.
    pub fn for_held(&self, lowered_first_level: bool, local_correlation: f32) -> Self {
        Self {
            lowered: lowered_first_level,
            weak: !(local_correlation >= self.alone_min_local),
            ..*self
        }
    }

    /// Whether the rule has a motion prior (not on a cold start).
    pub fn has_prior(&self) -> bool {
        self.prior.is_some()
    }

    /// Whether `pose` lies within the prior's reach, in position and in
    /// heading ([`MotionPrior::reaches`]); never on a cold start.
    pub fn prior_reaches(&self, pose: &Pose) -> bool {
        self.prior.is_some_and(|p| p.reaches(pose))
    }

    /// Whether the prior vouches for the place of a pose that passed the
    /// gate: it lies within the prior's reach ([`Self::prior_reaches`]) and
    /// did not pass through the lowered floor ([`Self::lowered`]). Its
    /// geometric twins are then not checked.
    pub fn vouches_for_place(&self, accepted: &Pose) -> bool {
        !self.lowered && self.prior_reaches(accepted)
    }

    /// Whether a pose that passed the gate may be held at all: not one that
    /// passed only through the first level's lowered floor
    /// ([`Self::lowered`]) beyond the prior's reach (or on a cold start).
    /// The search goes on to the next candidate instead.
    ///
    /// Why: on the scanned floor's 3 000-frame flight, of 200 searches
    /// (cold and near the last position, `star bench reloc` seeds 1 and
    /// 2), no right pose was accepted through the lowered floor, and every
    /// wrong cold accept left by the rival and twin checks was: rooms 8,
    /// 11, 24 and 40 m from the truth, whose view's geometry fit there at
    /// only 0.64-0.85 (a twin needs 0.9), the true room never verified as a
    /// rival. Their figures (local contrast 0.57, plain correlation 0.46,
    /// inliers 0.79-0.83) lie among those of the right cold starts the
    /// floor gives on 4 scanned rooms without look-alikes (0.57-0.70,
    /// 0.40-0.58, 0.50-0.77), and the frame's corners fit nowhere else in
    /// either: nothing tells them apart without a prior, so a cold start
    /// waits for a frame that passes the whole gate (docs/building-scale.md,
    /// "The lowered first level on a cold start"). A map whose places do
    /// not repeat may allow it ([`Self::with_lowered_without_prior`]).
    pub fn may_hold(&self, held: &Pose) -> bool {
        !self.lowered || self.prior_reaches(held) || self.lowered_without_prior
    }

    /// Whether a pose that passed the gate may be accepted without any
    /// rival check: the prior vouches for its place
    /// ([`Self::vouches_for_place`]) and it is not [`Self::weak`].
    pub fn accepts_alone(&self, accepted: &Pose) -> bool {
        !self.weak && self.vouches_for_place(accepted)
    }

    /// How many rivals `accepted` must beat, and within what score margin.
    pub fn budget(&self, accepted: &Pose) -> Budget {
        let budget = match self.prior {
            _ if self.lowered => Budget {
                max: MAX_RIVALS,
                margin: RIVAL_SCORE_MARGIN,
            },
            Some(p) if p.reaches(accepted) && !self.weak => Budget {
                max: 0,
                margin: 0.0,
            },
            Some(p) if p.region().contains(&accepted.translation.vector) => Budget {
                max: NEAR_MAX_RIVALS,
                margin: NEAR_RIVAL_SCORE_MARGIN,
            },
            _ => Budget {
                max: MAX_RIVALS,
                margin: RIVAL_SCORE_MARGIN,
            },
        };
        // Within reach, the landmark poses at the frame's other places come
        // on top ([`Self::with_landmark_rivals`]).
        if budget.max > 0 && self.prior_reaches(accepted) {
            Budget {
                max: budget.max + self.landmark_rivals,
                ..budget
            }
        } else {
            budget
        }
    }

    /// Whether `candidate` may be a rival of `accepted`: at another place
    /// ([`elsewhere`]) and not tried yet in this attempt (`tried`: the
    /// `ranked.index` of each candidate tried; one that failed the gate
    /// fails it again).
    pub fn is_rival(accepted: &Pose, candidate: &Candidate, tried: &[u32]) -> bool {
        elsewhere(accepted, &candidate.world_from_camera)
            && !tried.contains(&candidate.ranked.index)
    }

    /// What `rival`, which passed the gate, means for the held pose
    /// `accepted` (one that [`Self::accepts_alone`] refused); each comes
    /// with its plain correlation. `all_checked`: every rival of the held
    /// pose fits in the budget ([`Self::count_rivals`]); only then may the
    /// correlation choose, since an unchecked candidate could be the place
    /// that correlates as well as the winner.
    pub fn judge(
        &self,
        (accepted, accepted_correlation): (&Pose, f32),
        (rival, rival_correlation): (&Pose, f32),
        all_checked: bool,
    ) -> Judgment {
        let min_correlation = DECISIVE_MIN_CORRELATION.max(self.decisive_min_correlation);
        let decisive =
            |a: f32, b: f32| a >= min_correlation && a - b >= DECISIVE_MARGIN && b.is_finite();
        if !elsewhere(accepted, rival) {
            Judgment::SamePlace
        } else if self.prior_reaches(rival) && !self.prior_reaches(accepted) {
            Judgment::PriorChooses
        } else if all_checked && decisive(accepted_correlation, rival_correlation) {
            Judgment::HeldIsBetter
        } else if all_checked && decisive(rival_correlation, accepted_correlation) {
            Judgment::RivalIsBetter
        } else {
            Judgment::Ambiguous
        }
    }

    /// The first of `passed_unheld` (poses of this attempt that passed the
    /// gate but could not be held, each with its plain correlation) that
    /// stands against the held pose `accepted`: each is judged as a rival
    /// that passed ([`Self::judge`]), and only the same place or a held pose
    /// decisively better lets it go. They are not among the rivals
    /// [`Self::rivals`] lists (tried already), yet the frame fits there
    /// too: on the scanned floor a place that passed only through the
    /// lowered first level was left out, and a look-alike's pose held
    /// after it (docs/building-scale.md, "The landmarks' other places as
    /// candidates").
    pub fn unheld_rival<'a>(
        &self,
        (accepted, accepted_correlation): (&Pose, f32),
        passed_unheld: &'a [(Pose, f32)],
        all_checked: bool,
    ) -> Option<&'a (Pose, f32)> {
        passed_unheld.iter().find(|(pose, correlation)| {
            !matches!(
                self.judge(
                    (accepted, accepted_correlation),
                    (pose, *correlation),
                    all_checked
                ),
                Judgment::SamePlace | Judgment::HeldIsBetter
            )
        })
    }

    /// Writes to `out` the indices into `candidates` of the rivals of
    /// `accepted` (in the candidates' order, best first; one per place)
    /// under [`Self::budget`], up to [`Budget::deciding_max`], and returns
    /// how many. The caller verifies the first [`Budget::max`], and the
    /// rest only once a decisive correlation has chosen.
    pub fn rivals(
        &self,
        candidates: &[Candidate],
        accepted: &Pose,
        tried: &[u32],
        out: &mut [usize; LISTED_RIVALS],
    ) -> usize {
        let max = self.budget(accepted).deciding_max();
        let (written, _) = self.eligible(candidates, accepted, tried, &mut out[..max]);
        written
    }

    /// How many places are rivals of `accepted` under [`Self::budget`]'s
    /// margin, without its cap: more than the cap means some go unchecked.
    pub fn count_rivals(&self, candidates: &[Candidate], accepted: &Pose, tried: &[u32]) -> usize {
        self.eligible(candidates, accepted, tried, &mut []).1
    }

    /// Writes to `out` (as many as fit) the indices into `candidates` of the
    /// rivals of `accepted` within [`Self::budget`]'s score margin, in
    /// order, one per place: a candidate within [`RIVAL_MIN_M`] and
    /// [`SAME_PLACE_DEG`] of an earlier rival stands at the same place, and
    /// so does a repeated entry. Returns how many were written and how many
    /// places there are in all.
    fn eligible(
        &self,
        candidates: &[Candidate],
        accepted: &Pose,
        tried: &[u32],
        out: &mut [usize],
    ) -> (usize, usize) {
        let budget = self.budget(accepted);
        let near_best = candidates
            .iter()
            .filter(|c| !elsewhere(accepted, &c.world_from_camera) && c.score.is_finite())
            .map(|c| c.score)
            .fold(f32::NEG_INFINITY, f32::max);
        let bar = near_best - budget.margin;
        // The places found so far (beyond the first 32, each counts).
        let mut places = [0usize; 32];
        let (mut n_places, mut written) = (0usize, 0usize);
        for (i, c) in candidates.iter().enumerate() {
            // -inf scores (not aligned) pass only when nothing near was scored.
            let qualifies =
                Self::is_rival(accepted, c, tried) && (c.score >= bar || c.score == f32::INFINITY);
            let seen = places[..n_places.min(places.len())].iter().any(|&j| {
                candidates.get(j).is_some_and(|b| {
                    b.ranked.index == c.ranked.index
                        || same_place(&b.world_from_camera, &c.world_from_camera)
                })
            });
            if !qualifies || seen {
                continue;
            }
            if let Some(slot) = places.get_mut(n_places) {
                *slot = i;
            }
            n_places += 1;
            if let Some(slot) = out.get_mut(written) {
                *slot = i;
                written += 1;
            }
        }
        (written, n_places)
    }
}

/// Two candidates closer than this in heading (and [`RIVAL_MIN_M`] in
/// position) stand at the same place, degrees.
pub const SAME_PLACE_DEG: f64 = 30.0;

/// Whether two candidate poses stand at the same place (one rival check
/// covers both).
fn same_place(a: &Pose, b: &Pose) -> bool {
    !elsewhere(a, b) && (a.rotation.inverse() * b.rotation).angle().to_degrees() < SAME_PLACE_DEG
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::look::camera_rotation;
    use crate::reloc::{Ranked, RelocConfig, LANDMARK_ELSEWHERE};
    use nalgebra::Translation3;

    /// A camera at `x` on the x axis looking along `yaw_deg`.
    fn pose(x: f64, yaw_deg: f64) -> Pose {
        Pose::from_parts(
            Translation3::new(x, 0.0, 1.4),
            camera_rotation(yaw_deg.to_radians(), -5f64.to_radians(), 0.0),
        )
    }

    /// `c` looking along `yaw_deg` (a held pose's own candidate faces as it does).
    fn facing(c: Candidate, yaw_deg: f64) -> Candidate {
        let x = c.world_from_camera.translation.vector.x;
        Candidate {
            world_from_camera: pose(x, yaw_deg),
            ..c
        }
    }

    /// Database entry `index` at `x` with the coarse `score`.
    fn at(index: u32, x: f64, score: f32) -> Candidate {
        Candidate {
            ranked: Ranked {
                index,
                ..Ranked::default()
            },
            world_from_camera: pose(x, 0.0),
            score,
            ..Candidate::default()
        }
    }

    /// Lost for 0.75 s at the origin facing +x: 2 m and 120 degrees of
    /// reach under the default `[reloc]`.
    fn near_origin() -> RivalRule {
        let config = RelocConfig::default();
        RivalRule::new(Some(MotionPrior::new(&pose(0.0, 0.0), 0.75, &config)))
    }

    #[test]
    fn a_place_that_passed_unheld_stands_unless_the_held_pose_is_decisively_better() {
        let cold = RivalRule::new(None);
        let held = pose(20.0, 0.0);
        // The true room passed only through the lowered first level, 9 m
        // away; the held look-alike correlates no better.
        let unheld = [(pose(11.0, 0.0), 0.66)];
        assert_eq!(
            cold.unheld_rival((&held, 0.72), &unheld, true),
            Some(&unheld[0])
        );
        // Decisively better, with every rival checked: held.
        assert_eq!(cold.unheld_rival((&held, 0.9), &unheld, true), None);
        // Decisively better, but not every rival checked: still refused.
        assert!(cold.unheld_rival((&held, 0.9), &unheld, false).is_some());
        // The same place (within a meter): no rival.
        let same = [(pose(20.5, 0.0), 0.66)];
        assert_eq!(cold.unheld_rival((&held, 0.72), &same, true), None);
        // The first that stands is given, past one at the same place.
        let both = [same[0], unheld[0]];
        assert_eq!(
            cold.unheld_rival((&held, 0.72), &both, true),
            Some(&unheld[0])
        );
        assert_eq!(cold.unheld_rival((&held, 0.72), &[], true), None);
    }

    #[test]
    fn inside_the_radius_and_the_heading_is_accepted_directly() {
        let rule = near_origin();
        let accepted = pose(1.5, 100.0);
        assert!(rule.accepts_alone(&accepted));
        assert_eq!(rule.budget(&accepted).max, 0);
        let candidates = [at(1, 0.2, 0.9), at(2, -1.0, 0.95)];
        let mut out = [usize::MAX; LISTED_RIVALS];
        assert_eq!(rule.rivals(&candidates, &accepted, &[], &mut out), 0);
    }

    #[test]
    fn a_pose_through_the_lowered_floor_is_checked_as_on_a_cold_start() {
        let rule = near_origin();
        // The scanned floor's turned look-alike: 1.4 m off, turned 90
        // degrees, within the prior's reach.
        let accepted = pose(1.4, 90.0);
        assert!(rule.accepts_alone(&accepted));
        let lowered = rule.for_held(true, 0.75);
        assert!(!lowered.accepts_alone(&accepted));
        assert!(lowered.prior_reaches(&accepted));
        assert_eq!(
            lowered.budget(&accepted),
            Budget {
                max: MAX_RIVALS,
                margin: RIVAL_SCORE_MARGIN
            }
        );
        // The truth at the origin, scored below the look-alike but within
        // the cold margin (not the near one), is its rival ...
        let candidates = [facing(at(1, 1.4, 0.9), 90.0), at(2, 0.0, 0.7)];
        let mut out = [usize::MAX; LISTED_RIVALS];
        let n = lowered.rivals(&candidates, &accepted, &[], &mut out);
        assert_eq!(&out[..n], &[1]);
        // ... and where both pass, the place that correlates decisively
        // better is held; where neither does, the frame is refused.
        let truth = pose(0.0, 0.0);
        assert_eq!(
            lowered.judge((&accepted, 0.68), (&truth, 0.89), true),
            Judgment::RivalIsBetter
        );
        assert_eq!(
            lowered.judge((&accepted, 0.68), (&truth, 0.72), true),
            Judgment::Ambiguous
        );
        // A pose not through the lowered floor keeps the rule as it was.
        assert_eq!(rule.for_held(false, 0.75), rule);
        // Within the prior's reach it is held; beyond it, or on a cold
        // start, only where the map's places do not repeat (the setting).
        assert!(lowered.may_hold(&accepted));
        let far = pose(30.0, 0.0);
        assert!(!lowered.may_hold(&far));
        let cold = RivalRule::new(None).for_held(true, 0.6);
        assert!(!cold.may_hold(&accepted));
        assert!(cold.with_lowered_without_prior(true).may_hold(&accepted));
        assert!(RivalRule::new(None).for_held(false, 0.6).may_hold(&far));
    }

    #[test]
    fn on_a_scanned_map_a_weak_pose_within_reach_has_its_near_rivals_checked() {
        // The scanned floor's window wrong accept: 1.4 m off, turned 90
        // degrees, within the prior's reach, local contrast 0.714.
        let accepted = pose(1.4, 90.0);
        let scanned = near_origin().with_alone_floor(0.8);
        let weak = scanned.for_held(false, 0.714);
        assert!(weak.vouches_for_place(&accepted));
        assert!(!weak.accepts_alone(&accepted));
        assert_eq!(
            weak.budget(&accepted),
            Budget {
                max: NEAR_MAX_RIVALS,
                margin: NEAR_RIVAL_SCORE_MARGIN
            }
        );
        // The truth at the origin, scored near the look-alike: its rival.
        let candidates = [facing(at(1, 1.4, 0.9), 90.0), at(2, 0.0, 0.8)];
        let mut out = [usize::MAX; LISTED_RIVALS];
        let n = weak.rivals(&candidates, &accepted, &[], &mut out);
        assert_eq!(&out[..n], &[1]);
        // At the floor or above, the prior alone as on any map; and a map
        // that is no scan has no floor.
        assert!(scanned.for_held(false, 0.8).accepts_alone(&accepted));
        assert!(near_origin()
            .for_held(false, 0.714)
            .accepts_alone(&accepted));
        // A figure that is not a number is no confidence.
        assert!(!scanned.for_held(false, f32::NAN).accepts_alone(&accepted));
    }

    #[test]
    fn a_weak_pose_within_reach_has_the_landmark_places_verified_on_top_of_its_near_rivals() {
        // The scanned floor's kidnapped search (seed 7, query 9): a landmark
        // pose within the prior's reach, 8 m from the truth and turned 90
        // degrees, local contrast 0.75; the truth (here 2 m away, where the
        // frame's corners fit too) was never verified.
        let held = pose(1.8, 90.0);
        let truth = pose(-0.2, 0.0);
        let weak = near_origin().with_alone_floor(0.8).for_held(false, 0.75);
        assert!(weak.prior_reaches(&held) && !weak.accepts_alone(&held));
        // The landmark poses elsewhere first (unscored, as the locator gives
        // them), then two near views that are the place's own symmetry.
        let candidates = [
            Candidate {
                score: f32::INFINITY,
                world_from_camera: truth,
                ..at(LANDMARK_ELSEWHERE, 0.0, 0.0)
            },
            Candidate {
                score: f32::INFINITY,
                world_from_camera: pose(6.0, 0.0),
                ..at(LANDMARK_ELSEWHERE - 1, 0.0, 0.0)
            },
            facing(at(1, 1.8, 0.9), 90.0),
            Candidate {
                world_from_camera: pose(0.3, 270.0),
                ..at(2, 0.0, 0.85)
            },
            at(3, 3.5, 0.8),
        ];
        let rule = weak.with_landmark_rivals(2);
        assert_eq!(
            rule.budget(&held),
            Budget {
                max: NEAR_MAX_RIVALS + 2,
                margin: NEAR_RIVAL_SCORE_MARGIN
            }
        );
        let mut out = [usize::MAX; LISTED_RIVALS];
        let n = rule.rivals(&candidates, &held, &[], &mut out);
        // Both landmark places and both near views are verified.
        assert_eq!(&out[..n], &[0, 1, 3, 4]);
        assert!(n <= rule.budget(&held).max);
        // The truth correlates decisively better: held instead (0.8 on a
        // scan), else the frame is refused.
        let scanned = rule.with_decisive_floor(0.8);
        assert_eq!(
            scanned.judge((&held, 0.73), (&truth, 0.92), true),
            Judgment::RivalIsBetter
        );
        assert_eq!(
            scanned.judge((&held, 0.73), (&truth, 0.78), true),
            Judgment::Ambiguous
        );
        // Without landmark rivals the budget is the near one, and beyond
        // the prior's reach they are among the budget's, as before.
        assert_eq!(weak.budget(&held).max, NEAR_MAX_RIVALS);
        let far = pose(9.0, 0.0);
        let beyond = near_origin().with_landmark_rivals(3);
        assert!(!beyond.accepts_alone(&far));
        assert_eq!(beyond.budget(&far).max, MAX_RIVALS);
        // A pose the prior vouches for alone lists none and has no budget.
        let strong = near_origin().with_alone_floor(0.8).for_held(false, 0.85);
        assert!(strong.accepts_alone(&held));
        assert_eq!(strong.with_landmark_rivals(3).budget(&held).max, 0);
    }

    #[test]
    fn on_a_scan_the_listed_rivals_suffice_for_a_decisive_choice() {
        // The scanned floor's refused cold start: the truth held at plain
        // correlation 0.94, a look-alike 16 m away passing at 0.41, and
        // more places eligible than listed.
        let cold = RivalRule::new(None).with_decisive_floor(0.8);
        let (truth, far) = (pose(0.0, 0.0), pose(16.0, 0.0));
        assert!(!cold.may_decide(8, 11));
        assert!(cold.may_decide(8, 8));
        let decides =
            |rule: &RivalRule| rule.judge((&truth, 0.94), (&far, 0.41), rule.may_decide(8, 11));
        assert_eq!(decides(&cold), Judgment::Ambiguous);
        let scan = cold.with_listed_rivals_deciding(true);
        assert!(scan.may_decide(8, 11));
        assert_eq!(decides(&scan), Judgment::HeldIsBetter);
        // The floor and the margin still hold: a place under 0.8, or one
        // less than 0.08 better, is no choice.
        assert_eq!(
            scan.judge((&truth, 0.78), (&far, 0.41), scan.may_decide(8, 11)),
            Judgment::Ambiguous
        );
        assert_eq!(
            scan.judge((&truth, 0.86), (&far, 0.8), scan.may_decide(8, 11)),
            Judgment::Ambiguous
        );
        // The setting survives the rule for a held pose.
        assert!(
            scan.for_held(false, 0.7)
                .with_landmark_rivals(2)
                .listed_rivals_decide
        );
    }

    #[test]
    fn inside_the_radius_but_turned_half_round_needs_the_near_checks() {
        let rule = near_origin();
        // The half-turn look-alike of the building: 1.44 m off, facing back.
        let accepted = pose(1.44, 180.0);
        assert!(!rule.accepts_alone(&accepted));
        assert_eq!(
            rule.budget(&accepted),
            Budget {
                max: NEAR_MAX_RIVALS,
                margin: NEAR_RIVAL_SCORE_MARGIN
            }
        );
        // The truth (the origin) scored near the best: it is the rival.
        let candidates = [
            facing(at(1, 1.4, 0.9), 180.0),
            at(2, 0.0, 0.8),
            at(3, 0.3, 0.6),
        ];
        let mut out = [usize::MAX; LISTED_RIVALS];
        let n = rule.rivals(&candidates, &accepted, &[], &mut out);
        assert_eq!(&out[..n], &[1]);
    }

    #[test]
    fn outside_the_radius_needs_the_whole_map_checks() {
        let rule = near_origin();
        let accepted = pose(5.2, 0.0);
        assert!(!rule.accepts_alone(&accepted));
        assert_eq!(rule.budget(&accepted).max, MAX_RIVALS);
        let cold = RivalRule::new(None);
        assert!(!cold.accepts_alone(&pose(0.0, 0.0)));
        assert_eq!(
            cold.budget(&pose(0.0, 0.0)),
            Budget {
                max: MAX_RIVALS,
                margin: RIVAL_SCORE_MARGIN
            }
        );
    }

    #[test]
    fn rivals_are_far_untried_and_score_near_the_best_near_the_pose() {
        let accepted = pose(0.0, 0.0);
        let candidates = [
            at(1, 0.2, 0.9),             // near
            at(2, 5.2, 0.88),            // a twin room: a rival
            at(3, 0.5, 0.95),            // near, the best: the bar is 0.65
            at(4, 12.0, 0.55),           // far but scored too low
            at(5, -20.0, f32::INFINITY), // a landmark pose elsewhere: a rival
            at(6, 30.0, 0.7),            // tried already
            at(2, 5.2, 0.88),            // entry 2 again (another search)
            at(10, 5.5, 0.9),            // the twin room of entry 2 again
            at(7, 31.0, 0.8),            // a rival
            at(8, 32.5, 0.8),            // a rival
            at(9, 34.0, 0.8),            // beyond the budget
        ];
        let mut out = [usize::MAX; LISTED_RIVALS];
        let cold = RivalRule::new(None);
        let n = cold.rivals(&candidates, &accepted, &[6], &mut out);
        // The first 4 (the budget) are verified; entry 9, a fifth place,
        // only once a decisive correlation has chosen.
        assert_eq!(&out[..n], &[1, 4, 8, 9, 10]);
        assert_eq!(cold.budget(&accepted).deciding_max(), 2 * MAX_RIVALS);
        assert_eq!(cold.count_rivals(&candidates, &accepted, &[6]), 5);
        assert!(RivalRule::is_rival(&accepted, &candidates[5], &[]));
        assert!(!RivalRule::is_rival(&accepted, &candidates[5], &[6]));
        assert!(!RivalRule::is_rival(&accepted, &candidates[0], &[]));
    }

    #[test]
    fn a_place_turned_beyond_the_limit_is_another_place_at_any_distance() {
        // The one-room `building`'s wrong accept: held 0.86 m from the
        // true place and turned 90 degrees.
        let held = pose(0.0, 90.0);
        let truth = pose(0.86, 0.0);
        assert!(elsewhere(&held, &truth) && elsewhere(&truth, &held));
        assert!(elsewhere(
            &held,
            &pose(0.0, 90.0 + RIVAL_MIN_TURN_DEG + 1.0)
        ));
        assert!(!elsewhere(
            &held,
            &pose(0.3, 90.0 + RIVAL_MIN_TURN_DEG - 1.0)
        ));
        assert!(!elsewhere(&held, &held));
        // So the true place is verified as a rival (entry 2 stands at the
        // same place and is listed once), and a pass there is judged:
        // decisively better, it is chosen.
        let candidates = [at(1, 0.86, 0.96), at(2, 0.1, 0.5)];
        let mut out = [usize::MAX; LISTED_RIVALS];
        let cold = RivalRule::new(None);
        assert_eq!(cold.rivals(&candidates, &held, &[], &mut out), 1);
        assert_eq!(out[0], 0);
        assert_eq!(
            cold.judge((&held, 0.52), (&truth, 0.96), true),
            Judgment::RivalIsBetter
        );
    }

    #[test]
    fn without_a_scored_candidate_near_every_far_one_is_a_rival() {
        let accepted = pose(0.0, 0.0);
        let candidates = [at(1, 0.1, f32::NEG_INFINITY), at(2, 3.0, f32::NEG_INFINITY)];
        let mut out = [usize::MAX; LISTED_RIVALS];
        let n = RivalRule::new(None).rivals(&candidates, &accepted, &[], &mut out);
        assert_eq!(&out[..n], &[1]);
    }

    #[test]
    fn nothing_far_is_no_rival() {
        let accepted = pose(0.0, 0.0);
        let candidates = [at(1, 0.3, 0.9), at(2, -0.8, 0.99)];
        let mut out = [usize::MAX; LISTED_RIVALS];
        assert_eq!(
            RivalRule::new(None).rivals(&candidates, &accepted, &[], &mut out),
            0
        );
    }

    #[test]
    fn a_passing_rival_is_the_same_place_the_prior_s_choice_or_ambiguous() {
        let rule = near_origin();
        // Held: the twin room 5.2 m away, beyond the 2 m reach; both
        // correlate alike.
        let twin = (&pose(5.2, 0.0), 0.9);
        let judge = |rule: &RivalRule, rival: &Pose| rule.judge(twin, (rival, 0.9), true);
        assert_eq!(judge(&rule, &pose(5.5, 0.0)), Judgment::SamePlace);
        assert_eq!(judge(&rule, &pose(0.1, 10.0)), Judgment::PriorChooses);
        // A rival within the radius but facing back is no choice of the prior.
        assert_eq!(judge(&rule, &pose(0.1, 180.0)), Judgment::Ambiguous);
        // Without a prior two places that correlate alike are ambiguous.
        let cold = RivalRule::new(None);
        assert_eq!(judge(&cold, &pose(0.1, 10.0)), Judgment::Ambiguous);
    }

    #[test]
    fn a_decisively_better_correlation_chooses_only_when_every_rival_was_checked() {
        let cold = RivalRule::new(None);
        let (here, there) = (pose(0.0, 0.0), pose(8.0, 0.0));
        let m = DECISIVE_MARGIN;
        assert_eq!(
            cold.judge((&here, 0.9), (&there, 0.9 - 1.25 * m), true),
            Judgment::HeldIsBetter
        );
        assert_eq!(
            cold.judge((&here, 0.9 - 1.25 * m), (&there, 0.9), true),
            Judgment::RivalIsBetter
        );
        // Not by enough, or not well enough, or some rivals unchecked.
        assert_eq!(
            cold.judge((&here, 0.9), (&there, 0.9 - 0.5 * m), true),
            Judgment::Ambiguous
        );
        let low = DECISIVE_MIN_CORRELATION - 0.01;
        assert_eq!(
            cold.judge((&here, low), (&there, low - 2.0 * m), true),
            Judgment::Ambiguous
        );
        assert_eq!(
            cold.judge((&here, 0.9), (&there, 0.9 - 2.0 * m), false),
            Judgment::Ambiguous
        );
        assert_eq!(
            cold.judge((&here, 0.9), (&there, f32::NAN), true),
            Judgment::Ambiguous
        );
        // The same place is never a choice, however the two correlate.
        assert_eq!(
            cold.judge((&here, 0.9), (&pose(0.5, 0.0), 0.5), true),
            Judgment::SamePlace
        );
    }

    #[test]
    fn on_a_scan_a_decisive_correlation_needs_a_higher_floor() {
        // The paced kidnap on the scanned floor: two places beyond the
        // prior's reach, 0.749 against 0.627; the truth was neither.
        let (far, farther) = (pose(12.0, 180.0), pose(21.0, 180.0));
        let scan = |rule: RivalRule| rule.with_decisive_floor(0.8);
        for rule in [scan(near_origin()), scan(RivalRule::new(None))] {
            assert_eq!(
                rule.judge((&far, 0.749), (&farther, 0.627), true),
                Judgment::Ambiguous
            );
            assert_eq!(
                rule.judge((&farther, 0.627), (&far, 0.749), true),
                Judgment::Ambiguous
            );
            // A place that correlates as right ones do is still chosen.
            assert_eq!(
                rule.judge((&far, 0.85), (&farther, 0.627), true),
                Judgment::HeldIsBetter
            );
            assert_eq!(
                rule.judge((&farther, 0.627), (&far, 0.85), true),
                Judgment::RivalIsBetter
            );
        }
        // Within the prior's reach too: two wrong places 1.3 and 1.5 m
        // from the truth, 0.753 against 0.618 (`star bench reloc`, seed 1).
        let scan_near = scan(near_origin());
        let (here, there) = (pose(0.5, 0.0), pose(1.6, 0.0));
        assert!(scan_near.prior_reaches(&here) && scan_near.prior_reaches(&there));
        assert_eq!(
            scan_near.judge((&here, 0.753), (&there, 0.618), true),
            Judgment::Ambiguous
        );
        // A textured map's rule keeps the floor of 0.7.
        assert_eq!(
            near_origin().judge((&far, 0.749), (&farther, 0.627), true),
            Judgment::HeldIsBetter
        );
        // A floor under 0.7 does not lower it.
        let low = RivalRule::new(None).with_decisive_floor(0.5);
        assert_eq!(
            low.judge((&far, 0.69), (&farther, 0.5), true),
            Judgment::Ambiguous
        );
    }
}
