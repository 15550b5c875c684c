//! The map's own look-alikes of a place: whether the map, rendered at a
//! pose that passed the gate, passes the same gate somewhere else.
//!
//! The rival rule ([`super::rivals`]) asks the frame: it verifies the
//! frame at the other places its own search ranked high, and refuses the
//! pose when one of them passes too. That holds only when the true place
//! verifies, or at least ranks among the candidates. On a scanned map it
//! often does neither: on the 22-room scanned floor the truth's local
//! contrast at level 0 was 0.53 (gate 0.7), no candidate within 2 m of it
//! was ranked, and the one place that passed, a stretch of corridor
//! exactly 40 m along, was accepted (docs/building-scale.md, "The map's
//! own look-alikes").
//!
//! So the map is asked as well. The render of the held pose is described
//! and searched over the whole database as a frame would be; the best
//! places elsewhere ([`RivalRule`]'s rivals of the held pose, without a
//! prior, up to [`MAP_TWIN_CHECKS`]) are rendered and the held render is
//! verified against them through the very gate. A place where it passes,
//! with a plain correlation no more than [`DECISIVE_MARGIN`] below the
//! frame's own at the held pose, is a twin: the map looks there as the
//! frame looks here, so the frame cannot tell the two apart, whichever of
//! them failed the frame's gate. Where the render passes with a
//! correlation decisively lower, the two places differ where the frame
//! can see it (a look-alike room whose furniture stands elsewhere), and
//! the frame's own verdict stands.
//!
//! Takes the relocalizer (descriptor search and coarse ranking), an
//! aligner, the held pose with its frame correlation and the keyframe
//! rendered there, and the render and recycle callbacks of the caller
//! (the service's render thread, the bench's renderer); gives the twin's
//! verified pose, or `None`. The service ([`crate::localizer`]) and
//! `star bench reloc` call the same function. Nothing here allocates.

use crate::geometry::{PinholeCamera, Pose};
use crate::track::{Aligner, Keyframe};

use super::rivals::{elsewhere, RivalRule, DECISIVE_MARGIN, LISTED_RIVALS, RIVAL_MIN_M};
use super::search::{Candidate, Relocalizer, MAX_TOP_K};
use super::verify::{try_candidate, Verified};
use super::SearchRegion;

/// Most places elsewhere at which the held render is verified.
pub const MAP_TWIN_CHECKS: usize = 3;

/// How many database views nearest the render by descriptor are aligned
/// (coarsely, against their stored points) to rank the places checked: all
/// a search holds ([`MAX_TOP_K`]), twice what a frame's search aligns.
pub const TWIN_RANKED: usize = MAX_TOP_K;

/// The pose the frame passed the gate at, and how well it correlated.
#[derive(Debug, Clone, Copy)]
pub struct Held<'a> {
    /// The verified pose.
    pub world_from_camera: &'a Pose,
    /// The frame's plain correlation there ([`Verified::correlation`]).
    pub correlation: f32,
    /// The keyframe rendered at (or within the gate's confirmation bound
    /// of) that pose: its gray pyramid and depth are what is searched.
    pub keyframe: &'a Keyframe,
}

/// A place, more than [`super::rivals::RIVAL_MIN_M`] from `held`, where the
/// map's render of `held` passes the gate with a plain correlation at least
/// the frame's own less [`DECISIVE_MARGIN`]; `None` when none of the first
/// `max_checks` (at most [`MAP_TWIN_CHECKS`]) places the render's search
/// ranks does, or when the render has too little contrast to describe.
pub fn map_twin(
    reloc: &mut Relocalizer,
    aligner: &mut Aligner,
    camera: &PinholeCamera,
    held: Held<'_>,
    max_checks: usize,
    render: &mut dyn FnMut(&Pose) -> Option<Box<Keyframe>>,
    recycle: &mut dyn FnMut(Box<Keyframe>),
) -> Option<Verified> {
    let max_checks = max_checks.min(MAP_TWIN_CHECKS);
    if max_checks == 0 {
        return None;
    }
    let view = held.keyframe;
    let (gray, depth) = (view.gray(), view.depth_m());
    let query = reloc.describe_render(gray.data(), depth.data(), gray.width(), gray.height())?;
    let mut candidates = [Candidate::default(); MAX_TOP_K];
    // Away from the held place: its own neighbouring views would fill the
    // list otherwise.
    let found = reloc.search_ranked_among(
        &query,
        SearchRegion::Beyond {
            center_m: held.world_from_camera.translation.vector,
            radius_m: RIVAL_MIN_M,
        },
        aligner,
        view.gray_pyramid(),
        (TWIN_RANKED, TWIN_RANKED),
    );
    let n = found.len().min(candidates.len());
    candidates[..n].copy_from_slice(&found[..n]);
    let mut places = [0usize; LISTED_RIVALS];
    let n_places =
        RivalRule::new(None).rivals(&candidates[..n], held.world_from_camera, &[], &mut places);
    // The render is an ideal pinhole image, whatever the camera's lens.
    let pinhole = camera.pinhole();
    let config = reloc.twin_gate();
    for &i in places[..n_places].iter().take(max_checks) {
        let Some(c) = candidates.get(i) else {
            continue;
        };
        tracing::debug!(
            held = ?held.world_from_camera.translation.vector,
            place = ?c.world_from_camera.translation.vector,
            coarse_score = c.score,
            "verifying the held pose's render at another place"
        );
        let Some((twin, kf)) = try_candidate(
            aligner,
            view.gray_pyramid(),
            &pinhole,
            config,
            &c.world_from_camera,
            c.yaw_rad,
            render,
            recycle,
        ) else {
            continue;
        };
        recycle(kf);
        tracing::debug!(
            held = ?held.world_from_camera.translation.vector,
            frame_correlation = held.correlation,
            place = ?twin.world_from_camera.translation.vector,
            render_correlation = twin.correlation,
            "the held pose's render passes the gate at another place"
        );
        if is_twin(
            held.world_from_camera,
            held.correlation,
            (&twin.world_from_camera, twin.correlation),
        ) {
            return Some(twin);
        }
    }
    None
}

/// Whether the held render, verified at `place` with the plain correlation
/// `render_correlation`, makes it a twin of the held pose: another place,
/// and a correlation no more than [`DECISIVE_MARGIN`] below the frame's at
/// the held pose.
pub fn is_twin(
    held: &Pose,
    frame_correlation: f32,
    (place, render_correlation): (&Pose, f32),
) -> bool {
    elsewhere(held, place)
        && render_correlation.is_finite()
        && render_correlation >= frame_correlation - DECISIVE_MARGIN
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Translation3;

    fn at(x: f64) -> Pose {
        Pose::from_parts(
            Translation3::new(x, 0.0, 1.4),
            nalgebra::UnitQuaternion::identity(),
        )
    }

    #[test]
    fn a_twin_is_elsewhere_and_correlates_nearly_as_the_frame_does() {
        let held = at(0.0);
        // The scanned floor's corridor, 40 m along: the render there
        // correlates as the frame does here.
        assert!(is_twin(&held, 0.82, (&at(40.0), 0.80)));
        assert!(is_twin(&held, 0.82, (&at(40.0), 0.95)));
        // A look-alike room whose furniture stands elsewhere: the render
        // passes the tolerant gate, but correlates decisively lower.
        assert!(!is_twin(&held, 0.82, (&at(40.0), 0.70)));
        // The render aligned back onto the held place: not another place.
        assert!(!is_twin(&held, 0.82, (&at(0.5), 0.99)));
        assert!(!is_twin(&held, 0.82, (&at(40.0), f32::NAN)));
    }
}
