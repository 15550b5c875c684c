//! Look-alike places: before a relocalization is accepted, the candidates
//! that stand somewhere else and look as good are verified too, and a pose
//! that another place also passes is refused as ambiguous.
//!
//! A map can repeat itself (the `building` preset has 6 room designs, each
//! built 3-4 times to the last vertex): from inside a room, its twin
//! renders the same image, so the gate passes there as well, and the
//! first candidate to pass would win whichever twin it stands in. Takes
//! the candidates of one attempt (the landmark pose and the descriptor's,
//! with their coarse-alignment scores) and the pose that passed; gives the
//! rivals to verify: at most [`MAX_RIVALS`] over the whole map (fewer
//! near the last position), each more than [`RIVAL_MIN_M`] from that
//! pose, scored by the coarse alignment within [`RIVAL_SCORE_MARGIN`]
//! (less near the last position) of the best candidate near it (a landmark pose
//! elsewhere always qualifies). The caller renders and verifies them
//! through the same gate; if one passes at another place ([`elsewhere`]:
//! a rival may align back onto the accepted pose), the frame is ambiguous.
//! Nothing here allocates.

use crate::geometry::Pose;

use super::region::SearchRegion;
use super::search::Candidate;

/// A candidate farther than this from the accepted pose stands at another
/// place, meters.
pub const RIVAL_MIN_M: f64 = 1.0;
/// A candidate at another place is a rival when its coarse-alignment score
/// is at least the best near the accepted pose less this: over the whole
/// map (look-alikes anywhere) ...
pub const RIVAL_SCORE_MARGIN: f32 = 0.3;
/// ... and near the last position (where only the place's own symmetry
/// can fool the gate: the twins are out of reach).
pub const NEAR_RIVAL_SCORE_MARGIN: f32 = 0.15;
/// Most rivals verified per accepted pose, over the whole map ...
pub const MAX_RIVALS: usize = 4;
/// ... and near the last position.
pub const NEAR_MAX_RIVALS: usize = 2;

/// Whether a rival verified at `rival` stands at another place than
/// `accepted` (a rival can align back to the accepted pose itself: that is
/// no ambiguity).
pub fn elsewhere(accepted: &Pose, rival: &Pose) -> bool {
    (rival.translation.vector - accepted.translation.vector).norm() > RIVAL_MIN_M
}

/// Writes to `out` the indices into `candidates` of the rivals of
/// `accepted`, found in `region` (in the candidates' order, best first),
/// and returns how many.
pub fn rivals(
    candidates: &[Candidate],
    accepted: &Pose,
    region: SearchRegion,
    out: &mut [usize; MAX_RIVALS],
) -> usize {
    let (max, margin) = match region {
        SearchRegion::Everywhere => (MAX_RIVALS, RIVAL_SCORE_MARGIN),
        SearchRegion::Near { .. } => (NEAR_MAX_RIVALS, NEAR_RIVAL_SCORE_MARGIN),
    };
    let far = |c: &Candidate| elsewhere(accepted, &c.world_from_camera);
    let near_best = candidates
        .iter()
        .filter(|c| !far(c) && c.score.is_finite())
        .map(|c| c.score)
        .fold(f32::NEG_INFINITY, f32::max);
    let bar = near_best - margin;
    let mut n = 0;
    for (i, c) in candidates.iter().enumerate() {
        if n == max {
            break;
        }
        // -inf scores (not aligned) pass only when nothing near was scored.
        if far(c) && (c.score >= bar || c.score == f32::INFINITY) {
            if let Some(slot) = out.get_mut(n) {
                *slot = i;
                n += 1;
            }
        }
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn at(x: f64, score: f32) -> Candidate {
        Candidate {
            world_from_camera: Pose::from_parts(
                Translation3::new(x, 0.0, 1.4),
                UnitQuaternion::identity(),
            ),
            score,
            ..Candidate::default()
        }
    }

    #[test]
    fn rivals_are_far_and_score_near_the_best_near_the_pose() {
        let accepted = at(0.0, 0.0).world_from_camera;
        let candidates = [
            at(0.2, 0.9),             // near
            at(5.2, 0.88),            // a twin room: a rival
            at(0.5, 0.95),            // near, the best: the bar is 0.65 (0.8 near)
            at(12.0, 0.55),           // far but scored too low
            at(-20.0, f32::INFINITY), // a landmark pose elsewhere: a rival
            at(30.0, 0.7),            // a rival over the whole map only
            at(31.0, 0.8),            // a rival
            at(32.0, 0.8),            // beyond MAX_RIVALS
        ];
        let mut out = [usize::MAX; MAX_RIVALS];
        let n = rivals(&candidates, &accepted, SearchRegion::Everywhere, &mut out);
        assert_eq!(&out[..n], &[1, 4, 5, 6]);
        let near = SearchRegion::Near {
            center_m: accepted.translation.vector,
            radius_m: 2.0,
        };
        let n = rivals(&candidates, &accepted, near, &mut out);
        assert_eq!(&out[..n], &[1, 4]);
    }

    #[test]
    fn without_a_scored_candidate_near_every_far_one_is_a_rival() {
        let accepted = at(0.0, 0.0).world_from_camera;
        let candidates = [at(0.1, f32::NEG_INFINITY), at(3.0, f32::NEG_INFINITY)];
        let mut out = [usize::MAX; MAX_RIVALS];
        let n = rivals(&candidates, &accepted, SearchRegion::Everywhere, &mut out);
        assert_eq!(&out[..n], &[1]);
    }

    #[test]
    fn nothing_far_is_no_rival() {
        let accepted = at(0.0, 0.0).world_from_camera;
        let candidates = [at(0.3, 0.9), at(-0.8, 0.99)];
        let mut out = [usize::MAX; MAX_RIVALS];
        assert_eq!(
            rivals(&candidates, &accepted, SearchRegion::Everywhere, &mut out),
            0
        );
    }
}
