//! Online relocalization, the acceptance gate: whether a rendered candidate
//! gives the pose.
//!
//! Takes the camera frame's pyramid, a keyframe rendered at a candidate's
//! pose (or a way to render one) and the `[reloc]` settings; aligns the
//! frame against it from several starts and gives the [`Verdict`]: the
//! aligned pose when it passes the strict gate ([`passes_gate`], the gain
//! range and the correlations of [`crate::track::correlation`]), a pose to
//! render again at and retry, or nothing. [`try_candidate`] runs that loop
//! for one candidate of [`super::search`].

use nalgebra::{Translation3, UnitQuaternion, Vector3};

use crate::geometry::{PinholeCamera, Pose};
use crate::track::correlation::{
    correlation, min_correlations_and_coarser_local, min_correlations_from, Correlations,
};
use crate::track::{AlignQuality, Aligner, Alignment, Keyframe, Pyramid};

use super::config::RelocConfig;

/// A candidate that passed the gate.
#[derive(Debug, Clone, Copy)]
pub struct Verified {
    /// The aligned camera pose.
    pub world_from_camera: Pose,
    /// The alignment.
    pub alignment: Alignment,
    /// Smallest correlation over pyramid levels 0, 1 and 2
    /// ([`crate::track::correlation::correlations`]).
    pub correlation: f32,
    /// Smallest trimmed correlation over the same levels.
    pub trimmed_correlation: f32,
    /// Smallest fraction of points the trimming kept.
    pub kept: f32,
    /// Smallest correlation of local contrast over the gated levels
    /// ([`crate::track::Correlations::local`]).
    pub local_correlation: f32,
    /// It passed only through the first level's lowered floor
    /// (`min_local_correlation_at_map_detail`): its local contrast there
    /// is below `min_local_correlation`. Such a pose is never accepted on
    /// the motion prior alone; its rivals are verified as on a cold start
    /// ([`crate::reloc::rivals::RivalRule::accepts_alone`]), and a prior
    /// alone (a start hint) is not confirmed by it. Always false where the
    /// gate starts at level 0 (a map as fine as the camera) or the floor
    /// is set to `min_local_correlation`.
    pub lowered_first_level: bool,
}

/// True when `q`, aligned at photometric gain `gain` (camera / map), passes
/// the relocalization gate of `config` ([`inlier_floor`]).
pub fn passes_gate(q: &AlignQuality, gain: f32, config: &RelocConfig) -> bool {
    q.inlier_ratio >= inlier_floor(config, gain)
        && q.visible_ratio >= config.min_visible_ratio
        && q.residual_rms <= config.max_residual_gray
        && q.residual_rms.is_finite()
}

/// The largest gain the inlier floor follows ([`inlier_floor`]): the true
/// poses it was measured on aligned at gains up to 2.5; beyond, the floor
/// stays at its value there.
pub const INLIER_FLOOR_MAX_GAIN: f32 = 2.5;

/// The gate's inlier floor at photometric gain `gain`: `min_inlier_ratio`,
/// divided by the gain (at most [`INLIER_FLOOR_MAX_GAIN`]) where it is
/// above 1 and `inlier_floor_follows_gain` is set (a gain that is not
/// finite keeps the floor).
pub fn inlier_floor(config: &RelocConfig, gain: f32) -> f32 {
    if config.inlier_floor_follows_gain && gain > 1.0 && gain.is_finite() {
        config.min_inlier_ratio / gain.min(INLIER_FLOOR_MAX_GAIN)
    } else {
        config.min_inlier_ratio
    }
}

/// The whole gate for an alignment `a` of `frame` against `keyframe`: the
/// cheap figures ([`passes_gate`]), the gain range, and both correlations
/// over levels 0 to 2. Gives the correlations when it passes. The
/// correlations (five passes over the finest points) run only where the
/// cheaper tests pass.
pub fn passes_whole_gate(
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    a: &Alignment,
    config: &RelocConfig,
) -> Option<Correlations> {
    whole_gate_from(
        keyframe,
        frame,
        camera,
        a,
        config,
        (
            first_gate_level(keyframe, config),
            config.min_local_correlation,
        ),
    )
}

/// The whole gate as [`passes_whole_gate`], but always from level 0,
/// whatever `gate_at_map_detail` says: for tracking that resumes on its
/// own after a short loss. There the pose comes from the tracker's own
/// prediction, not from a search, and at close range a drifted pose
/// passed the gate read from level 1 (`aggressive --scanned` seed 1:
/// docs/building-scale.md), so the map's detail only widens the
/// relocalization's gate. Its local contrast floor is `min_local`
/// ([`resume_local_floor`]).
pub fn passes_resume_gate(
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    a: &Alignment,
    config: &RelocConfig,
    min_local: f32,
) -> Option<Correlations> {
    whole_gate_from(keyframe, frame, camera, a, config, (0, min_local))
}

/// The local contrast floor of a frame resuming on its own after a short
/// loss: `min_local_correlation`, or `resume_local_fraction` times
/// `reference` (the drop test's reference from the frames tracked before
/// the loss; `None` while it is not settled) where that is lower. A `NaN`
/// reference keeps the fixed floor.
pub fn resume_local_floor(config: &RelocConfig, reference: Option<f32>) -> f32 {
    let fixed = config.min_local_correlation;
    match reference {
        Some(r) if config.resume_local_fraction > 0.0 && r.is_finite() => {
            fixed.min(config.resume_local_fraction * r)
        }
        _ => fixed,
    }
}

/// The whole gate from `first_level`, with `min_local` in place of
/// `min_local_correlation`.
fn whole_gate_from(
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    a: &Alignment,
    config: &RelocConfig,
    (first_level, min_local): (usize, f32),
) -> Option<Correlations> {
    let gain_ok = (config.min_gain..=config.max_gain).contains(&a.gain);
    let both = (passes_gate(&a.quality, a.gain, config) && gain_ok)
        .then(|| {
            min_correlations_and_coarser_local(
                keyframe,
                frame,
                camera,
                &a.camera_from_keyframe,
                first_level,
            )
        })
        .flatten();
    let c = both.map(|(c, _)| c);
    let passes = both.is_some_and(|(c, coarser_local)| {
        c.all >= config.min_correlation
            && local_contrast_passes(&c, coarser_local, first_level, config, min_local)
    });
    if tracing::enabled!(target: "star::reloc::gate", tracing::Level::TRACE) {
        let world_from_camera = keyframe.world_from_keyframe * a.camera_from_keyframe.inverse();
        let t = world_from_camera.translation.vector;
        let c = c.unwrap_or(Correlations {
            all: f32::NAN,
            trimmed: f32::NAN,
            kept: f32::NAN,
            local: f32::NAN,
            local_kept: f32::NAN,
        });
        tracing::trace!(
            target: "star::reloc::gate",
            x_m = t.x,
            y_m = t.y,
            z_m = t.z,
            inliers = a.quality.inlier_ratio,
            visible = a.quality.visible_ratio,
            residual = a.quality.residual_rms,
            gain = a.gain,
            all = c.all,
            trimmed = c.trimmed,
            local = c.local,
            passes,
            "gate"
        );
    }
    c.filter(|_| passes)
}

/// The gate's local-contrast test: the smallest over its three levels
/// (`c.local`) at least `min_local_correlation`; where the gate starts at
/// the map's detail (`first_level` above 0), the first level at least
/// `min_local_correlation_at_map_detail` (when lower) and the two coarser
/// levels (`coarser_local`) at least `min_local_correlation`; where those
/// hold no local contrast (`NaN`: a pyramid too short for it), the first
/// level the whole floor.
fn local_contrast_passes(
    c: &Correlations,
    coarser_local: f32,
    first_level: usize,
    config: &RelocConfig,
    min_local: f32,
) -> bool {
    // From level 0, or with no local contrast above the first level (too
    // few levels), the smallest over the levels holds the whole floor.
    if first_level == 0 || coarser_local.is_nan() {
        return c.local >= min_local;
    }
    let first_floor = config.min_local_correlation_at_map_detail.min(min_local);
    c.local >= first_floor && coarser_local >= min_local
}

/// True when the whole gate passed `c` only through its lowered first
/// level (`gate_at_map_detail`): its local contrast is short of
/// `min_local_correlation` ([`Verified::lowered_first_level`]).
pub fn through_lowered_first_level(c: &Correlations, config: &RelocConfig) -> bool {
    c.local < config.min_local_correlation
}

/// The first pyramid level the gate reads: the keyframe's
/// [`Keyframe::gate_level`] with `gate_at_map_detail`, else 0.
fn first_gate_level(keyframe: &Keyframe, config: &RelocConfig) -> usize {
    if config.gate_at_map_detail {
        keyframe.gate_level
    } else {
        0
    }
}

/// Initial yaw offsets tried per candidate, radians: the yaw the search
/// matched at (`shift_yaw_rad`), the candidate's own yaw, then half a grid
/// yaw step either way (the true yaw is at most that far from the nearest
/// database yaw).
pub fn start_yaws_rad(config: &RelocConfig, shift_yaw_rad: f64) -> [f64; 4] {
    let half = std::f64::consts::PI / config.yaw_steps.max(1) as f64;
    [shift_yaw_rad, 0.0, half, -half]
}

/// What aligning a frame against one rendered keyframe gave.
// Returned by value and dropped at once; boxing the large variant would
// allocate on a path that must not.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy)]
pub enum Verdict {
    /// Passed the gate.
    Accepted(Verified),
    /// Short of the gate but plausible (inliers at least
    /// `refine_min_inlier_ratio`): the aligned pose, world_from_camera, to
    /// render a new keyframe at and verify again.
    Refine(Pose),
    /// Nothing usable.
    Rejected,
}

/// Translation offsets of the coarse starts, camera frame (x right, z
/// forward), in units of half the grid spacing: the truth is at most
/// 0.71 grid spacings from the nearest database position horizontally.
const START_OFFSETS: [(f64, f64); 9] = [
    (0.0, 0.0),
    (1.0, 0.0),
    (-1.0, 0.0),
    (0.0, 1.0),
    (0.0, -1.0),
    (1.0, 1.0),
    (-1.0, 1.0),
    (1.0, -1.0),
    (-1.0, -1.0),
];

/// Coarse starts finished at full resolution.
const FINISHED_STARTS: usize = 2;

/// Pyramid levels a precise start (one start, no yaw search: the landmark
/// pose, a render at an aligned pose) is aligned without, coarsest first.
/// Relocalization's pyramids have one level more than tracking's
/// ([`crate::track::build_config`]) for the database views' basin. On 4
/// scanned rooms (`star bench reloc`, `STAR_BENCH_VERBOSE=1`), 15 of 50
/// frames aligned from a keyframe rendered at their true pose ended
/// 0.11-1.07 m off with that level, where an unmapped pillar filled a
/// fifth of the view; without it 49 of 50 stayed within 3 cm
/// (docs/building-scale.md).
pub const PRECISE_START_SKIPPED_LEVELS: usize = 1;

/// Aligns `frame` against `keyframe`. Coarse to fine: first every start
/// (the keyframe pose turned by each of `start_yaws_rad` about the camera's
/// vertical axis, moved by each of [`START_OFFSETS`] and, with several
/// database heights, up and down by half their spacing) is aligned on the
/// coarsest pyramid level only and scored by the correlation of the
/// keyframe points with the frame one level finer; the best
/// [`FINISHED_STARTS`] are then aligned down to full resolution. Returns
/// the best alignment that passes the gate and stays within two grid
/// spacings of the keyframe; else the most plausible one to refine from;
/// else `Rejected`. A single start (`&[0.0]`, a keyframe rendered at the
/// estimate) skips the coarse search.
///
/// The starts are independent: the coarse ones are shared between the two
/// `aligners` (every other start each), and so are the finished ones, on
/// two threads of the rayon pool ([`rayon::join`]). The result is the
/// sequential one: ties go to the earlier start either way. A single start
/// runs on the first aligner alone.
pub fn verify_candidate(
    aligners: &mut [Aligner; 2],
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    config: &RelocConfig,
    start_yaws_rad: &[f64],
) -> Verdict {
    // The coarsest level with enough points to align and score on.
    let n_levels = keyframe.levels.len().min(frame.len());
    let coarsest = (0..n_levels)
        .rev()
        .find(|&l| keyframe.levels[l].points.len() >= 100)
        .unwrap_or(0);
    let search = start_yaws_rad.len() > 1;
    let top = if search {
        let starts = CoarseStarts::new(start_yaws_rad, config);
        let [first, second] = &mut *aligners;
        let (even, odd) = rayon::join(
            || starts.best(first, keyframe, frame, camera, coarsest, 0),
            || starts.best(second, keyframe, frame, camera, coarsest, 1),
        );
        merge_best(&even, &odd)
    } else {
        let mut top = [Scored::none(); FINISHED_STARTS];
        if let Some(&yaw) = start_yaws_rad.first() {
            top[0] = Scored {
                score: 0.0,
                start: 0,
                camera_from_keyframe: Pose::from_parts(
                    Translation3::identity(),
                    UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw),
                )
                .inverse(),
            };
        }
        top
    };
    // Finish the best starts at full resolution: each aligned and gated on
    // its own aligner, then judged in order.
    let [first, second] = &mut *aligners;
    let skip_coarsest = if search {
        0
    } else {
        PRECISE_START_SKIPPED_LEVELS
    };
    let finish = |aligner: &mut Aligner, s: &Scored| {
        (s.score != f32::NEG_INFINITY).then(|| {
            let a = aligner.align_without_coarsest(
                keyframe,
                frame,
                camera,
                s.camera_from_keyframe,
                skip_coarsest,
            );
            let world_from_camera = keyframe.world_from_keyframe * a.camera_from_keyframe.inverse();
            let finite = world_from_camera
                .translation
                .vector
                .iter()
                .chain(world_from_camera.rotation.coords.iter())
                .all(|v| v.is_finite());
            let moved_m = a.camera_from_keyframe.translation.vector.norm();
            let usable = a.valid && finite && moved_m <= 2.0 * config.grid_spacing_m;
            // Full-resolution detail (the alignment's own level-0 figure),
            // level 1 and coarse structure (level 2) must all correlate: a
            // look-alike place elsewhere in the map matched the texture at
            // 0.73 but the layout only at 0.52, another 0.9 m off reached
            // 0.6 only at level 0's 0.59, where correct poses measured at
            // least 0.58.
            let accepted = usable
                .then(|| passes_whole_gate(keyframe, frame, camera, &a, config))
                .flatten();
            (a, world_from_camera, usable, accepted)
        })
    };
    let finished = if top[1].score == f32::NEG_INFINITY {
        [finish(first, &top[0]), None]
    } else {
        let (a, b) = rayon::join(|| finish(first, &top[0]), || finish(second, &top[1]));
        [a, b]
    };
    let mut best: Option<Verified> = None;
    let mut refine: Option<(f32, Pose)> = None;
    for (a, world_from_camera, usable, accepted) in finished.into_iter().flatten() {
        if !usable {
            continue;
        }
        let q = &a.quality;
        tracing::debug!(
            inliers = q.inlier_ratio,
            visible = q.visible_ratio,
            residual_gray = q.residual_rms,
            gain = a.gain,
            correlations = ?min_correlations_from(
                keyframe,
                frame,
                camera,
                &a.camera_from_keyframe,
                first_gate_level(keyframe, config)
            )
                .map(|c| (c.all, c.trimmed, c.local, c.kept, c.local_kept)),
            accepted = accepted.is_some(),
            position_m = ?world_from_camera.translation.vector.as_slice(),
            "candidate start aligned"
        );
        if let Some(ncc) = accepted {
            let better = best
                .as_ref()
                .is_none_or(|b| q.inlier_ratio > b.alignment.quality.inlier_ratio);
            if better {
                best = Some(Verified {
                    world_from_camera,
                    alignment: a,
                    correlation: ncc.all,
                    trimmed_correlation: ncc.trimmed,
                    kept: ncc.kept,
                    local_correlation: ncc.local,
                    lowered_first_level: through_lowered_first_level(&ncc, config),
                });
            }
        } else if q.inlier_ratio >= config.refine_min_inlier_ratio
            && q.visible_ratio >= config.min_visible_ratio
            && refine.is_none_or(|(r, _)| q.inlier_ratio > r)
        {
            refine = Some((q.inlier_ratio, world_from_camera));
        }
    }
    match (best, refine) {
        (Some(v), _) => Verdict::Accepted(v),
        (None, Some((_, pose))) => Verdict::Refine(pose),
        (None, None) => Verdict::Rejected,
    }
}

/// A coarse start and its score: the correlation one level finer than
/// the coarse alignment (`NEG_INFINITY`: none).
#[derive(Debug, Clone, Copy)]
struct Scored {
    score: f32,
    /// Its place in the order of [`CoarseStarts`], which breaks ties.
    start: usize,
    /// The coarse alignment, the finished alignment's start.
    camera_from_keyframe: Pose,
}

impl Scored {
    fn none() -> Self {
        Self {
            score: f32::NEG_INFINITY,
            start: usize::MAX,
            camera_from_keyframe: Pose::identity(),
        }
    }

    /// Whether `self` ranks before `other`: the higher score, and on a tie
    /// the earlier start (as inserting in order, strictly better first).
    fn before(&self, other: &Self) -> bool {
        self.score > other.score || (self.score == other.score && self.start < other.start)
    }
}

/// Inserts `s` into the ranked `top` when it beats one of them (a score of
/// `NEG_INFINITY` or NaN never does).
fn insert(top: &mut [Scored; FINISHED_STARTS], s: Scored) {
    if !(s.score > f32::NEG_INFINITY) {
        return;
    }
    if let Some(slot) = top.iter().position(|t| s.before(t)) {
        top.copy_within(slot..FINISHED_STARTS - 1, slot + 1);
        top[slot] = s;
    }
}

/// The best of two rankings of disjoint starts, as one ranking of all.
fn merge_best(
    a: &[Scored; FINISHED_STARTS],
    b: &[Scored; FINISHED_STARTS],
) -> [Scored; FINISHED_STARTS] {
    let mut top = *a;
    for &s in b {
        insert(&mut top, s);
    }
    top
}

/// The coarse starts of one verification, in order: for each distinct
/// yaw, each offset of [`START_OFFSETS`], each vertical step.
struct CoarseStarts<'a> {
    yaws_rad: &'a [f64],
    vertical: &'static [f64],
    half_m: f64,
    half_height_m: f64,
}

impl<'a> CoarseStarts<'a> {
    fn new(yaws_rad: &'a [f64], config: &RelocConfig) -> Self {
        let half_height_m = 0.5 * config.height_spacing_m();
        Self {
            yaws_rad,
            vertical: if half_height_m > 0.0 {
                &[0.0, 1.0, -1.0]
            } else {
                &[0.0]
            },
            half_m: 0.5 * config.grid_spacing_m,
            half_height_m,
        }
    }

    /// Every start as keyframe_from_camera, in order (a repeated yaw is
    /// left out).
    fn iter(&self) -> impl Iterator<Item = Pose> + '_ {
        self.yaws_rad
            .iter()
            .enumerate()
            .filter(|&(i, yaw)| !self.yaws_rad[..i].contains(yaw))
            .flat_map(move |(_, &yaw)| {
                START_OFFSETS.iter().flat_map(move |&(dx, dz)| {
                    self.vertical.iter().map(move |&dy| {
                        // Camera y points down: turning right (z toward +x)
                        // is a positive rotation about y.
                        Pose::from_parts(
                            Translation3::new(
                                dx * self.half_m,
                                dy * self.half_height_m,
                                dz * self.half_m,
                            ),
                            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw),
                        )
                    })
                })
            })
    }

    /// The best [`FINISHED_STARTS`] of every other start from `parity` (0 or
    /// 1): each aligned on `coarsest` and scored one level finer.
    fn best(
        &self,
        aligner: &mut Aligner,
        keyframe: &Keyframe,
        frame: &Pyramid,
        camera: &PinholeCamera,
        coarsest: usize,
        parity: usize,
    ) -> [Scored; FINISHED_STARTS] {
        let score_level = coarsest.saturating_sub(1);
        let mut top = [Scored::none(); FINISHED_STARTS];
        for (i, keyframe_from_camera) in self.iter().enumerate() {
            if i % 2 != parity {
                continue;
            }
            let a = aligner.align_to_level(
                keyframe,
                frame,
                camera,
                keyframe_from_camera.inverse(),
                coarsest,
            );
            if !a.valid {
                continue;
            }
            let score = correlation(
                keyframe,
                frame,
                camera,
                &a.camera_from_keyframe,
                score_level,
            )
            .unwrap_or(f32::NEG_INFINITY);
            insert(
                &mut top,
                Scored {
                    score,
                    start: i,
                    camera_from_keyframe: a.camera_from_keyframe,
                },
            );
        }
        top
    }
}

/// Verifies one database candidate: renders it (`render` gives a prepared
/// keyframe at a world_from_keyframe pose, `None` on failure) and aligns the
/// frame against it. A pose is accepted only from a keyframe rendered at
/// (nearly) that pose: when the alignment passes the gate but moved more
/// than `confirm_max_m` / `confirm_max_deg` from its keyframe, or is
/// plausible but short of the gate, a keyframe is rendered at the aligned
/// pose and the frame aligned again, up to `refine_renders` times. A view
/// rendered nearer the truth widens the basin of direct alignment (the STAR
/// idea), and a wrong pose that fitted a look-alike part of the view rarely
/// survives a render of the whole view from where it claims to be. Every
/// keyframe not returned goes back through `recycle`. `shift_yaw_rad` is
/// the yaw the search matched at (the first render is verified with the
/// coarse search of [`verify_candidate`]); `None` for a precise pose (from
/// the landmarks): a single start. Returns the accepted pose and the
/// keyframe it was aligned against; never a pose more than two grid
/// spacings from the candidate.
#[allow(clippy::too_many_arguments)]
pub fn try_candidate(
    aligners: &mut [Aligner; 2],
    frame: &Pyramid,
    camera: &PinholeCamera,
    config: &RelocConfig,
    world_from_candidate: &Pose,
    shift_yaw_rad: Option<f64>,
    render: &mut dyn FnMut(&Pose) -> Option<Box<Keyframe>>,
    recycle: &mut dyn FnMut(Box<Keyframe>),
) -> Option<(Verified, Box<Keyframe>)> {
    let far = |pose: &Pose| {
        (pose.translation.vector - world_from_candidate.translation.vector).norm()
            > 2.0 * config.grid_spacing_m
    };
    let confirmed = |v: &Verified| {
        let d = &v.alignment.camera_from_keyframe;
        d.translation.vector.norm() <= config.confirm_max_m
            && d.rotation.angle().to_degrees() <= config.confirm_max_deg
    };
    let mut keyframe = render(world_from_candidate)?;
    let searched;
    let yaws: &[f64] = match shift_yaw_rad {
        Some(shift) => {
            searched = start_yaws_rad(config, shift);
            &searched
        }
        None => &[0.0],
    };
    let mut verdict = verify_candidate(aligners, &keyframe, frame, camera, config, yaws);
    let mut renders = 0;
    loop {
        let next = match verdict {
            Verdict::Accepted(v) if far(&v.world_from_camera) => None,
            Verdict::Accepted(v) if confirmed(&v) => return Some((v, keyframe)),
            Verdict::Accepted(v) => Some(v.world_from_camera),
            Verdict::Refine(pose) if !far(&pose) => Some(pose),
            _ => None,
        };
        recycle(keyframe);
        let pose = next.filter(|_| renders < config.refine_renders)?;
        keyframe = render(&pose)?;
        renders += 1;
        verdict = verify_candidate(aligners, &keyframe, frame, camera, config, &[0.0]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::TrackerConfig;

    /// [`local_contrast_passes`] with the config's own floor,
    /// `min_local_correlation`.
    fn passes_local(c: &Correlations, coarser: f32, level: usize, config: &RelocConfig) -> bool {
        local_contrast_passes(c, coarser, level, config, config.min_local_correlation)
    }

    #[test]
    fn the_inlier_floor_follows_a_gain_above_1_only_when_set() {
        let on = RelocConfig {
            min_inlier_ratio: 0.5,
            inlier_floor_follows_gain: true,
            ..RelocConfig::default()
        };
        let off = RelocConfig {
            inlier_floor_follows_gain: false,
            ..on.clone()
        };
        assert_eq!(inlier_floor(&on, 2.0), 0.25);
        assert_eq!(inlier_floor(&on, 1.0), 0.5);
        // A camera that sees the map darker keeps the floor.
        assert_eq!(inlier_floor(&on, 0.5), 0.5);
        for gain in [f32::NAN, f32::INFINITY] {
            assert_eq!(inlier_floor(&on, gain), 0.5);
        }
        assert_eq!(inlier_floor(&off, 2.0), 0.5);
        // Beyond the gains it was measured at, the floor stops falling.
        assert_eq!(inlier_floor(&on, 4.0), 0.5 / INLIER_FLOOR_MAX_GAIN);
        // The scanned floor's true pose under a brighter camera: 0.40 of its
        // points within the inlier threshold at a gain of 2.1.
        let q = AlignQuality {
            inlier_ratio: 0.40,
            visible_ratio: 1.0,
            residual_rms: 11.4,
            correlation: 0.77,
            ..AlignQuality::default()
        };
        assert!(passes_gate(&q, 2.1, &on));
        assert!(!passes_gate(&q, 2.1, &off));
        assert!(!passes_gate(&q, 1.1, &on));
    }

    #[test]
    fn a_resume_floor_follows_the_frames_before_the_loss_only_downwards() {
        let mut config = RelocConfig {
            min_local_correlation: 0.7,
            resume_local_fraction: 0.9,
            ..RelocConfig::default()
        };
        // Blurred frames tracked at 0.66: a resume needs 0.9 of that.
        let floor = resume_local_floor(&config, Some(0.66));
        assert!((floor - 0.594).abs() < 1e-6, "{floor}");
        // Sharp frames never raise it past the fixed floor.
        assert_eq!(resume_local_floor(&config, Some(0.95)), 0.7);
        // Nothing settled, not measured, or turned off: the fixed floor.
        assert_eq!(resume_local_floor(&config, None), 0.7);
        assert_eq!(resume_local_floor(&config, Some(f32::NAN)), 0.7);
        config.resume_local_fraction = 0.0;
        assert_eq!(resume_local_floor(&config, Some(0.66)), 0.7);
    }

    /// A start scored `score` at place `start` of the order.
    fn scored(score: f32, start: usize) -> Scored {
        Scored {
            score,
            start,
            camera_from_keyframe: Pose::identity(),
        }
    }

    #[test]
    fn ranking_two_halves_of_the_starts_is_ranking_them_all_in_order() {
        // Scores from a few values, so that ties are common; some starts
        // failed (NEG_INFINITY) or scored NaN.
        let values = [0.3, 0.5, 0.5, 0.7, f32::NEG_INFINITY, f32::NAN, 0.7, 0.1];
        for n in 0..40usize {
            for seed in 0..5usize {
                let scores: Vec<f32> = (0..n)
                    .map(|i| values[(i * 7 + seed * 3 + i * i) % values.len()])
                    .collect();
                // The reference: a stable sort by score, best first, of the
                // starts that scored.
                let mut by_score: Vec<usize> =
                    (0..n).filter(|&i| scores[i] > f32::NEG_INFINITY).collect();
                by_score.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]));
                let expected: Vec<usize> = by_score.into_iter().take(FINISHED_STARTS).collect();
                // In order, on one aligner.
                let mut sequential = [Scored::none(); FINISHED_STARTS];
                for (i, &sc) in scores.iter().enumerate() {
                    insert(&mut sequential, scored(sc, i));
                }
                // Every other start on each of two, then merged.
                let mut halves = [[Scored::none(); FINISHED_STARTS]; 2];
                for (i, &sc) in scores.iter().enumerate() {
                    insert(&mut halves[i % 2], scored(sc, i));
                }
                let merged = merge_best(&halves[0], &halves[1]);
                for top in [&sequential, &merged] {
                    let got: Vec<usize> = top
                        .iter()
                        .filter(|s| s.score > f32::NEG_INFINITY)
                        .map(|s| s.start)
                        .collect();
                    assert_eq!(got, expected, "n {n}, seed {seed}, scores {scores:?}");
                }
            }
        }
    }

    #[test]
    fn the_coarse_starts_are_every_yaw_offset_and_height_once() {
        let config = RelocConfig {
            grid_spacing_m: 0.5,
            heights_m: vec![1.2, 1.6],
            ..RelocConfig::default()
        };
        let yaws = start_yaws_rad(&config, 0.0);
        // The search's shift repeats the first of the fixed yaws (0).
        assert_eq!(yaws[0], yaws[1]);
        let starts: Vec<Pose> = CoarseStarts::new(&yaws, &config).iter().collect();
        assert_eq!(starts.len(), 3 * START_OFFSETS.len() * 3);
        assert_eq!(starts[0], Pose::identity());
        for (i, a) in starts.iter().enumerate() {
            for b in &starts[..i] {
                let apart_m = (a.translation.vector - b.translation.vector).norm();
                let apart_rad = a.rotation.angle_to(&b.rotation);
                assert!(
                    apart_m > 0.05 || apart_rad > 0.05,
                    "start {i} repeats another"
                );
            }
        }
        // Half the grid spacing across, half the height spacing up.
        let max_x = starts.iter().map(|p| p.translation.x).fold(0.0, f64::max);
        let max_y = starts.iter().map(|p| p.translation.y).fold(0.0, f64::max);
        assert!((max_x - 0.25).abs() < 1e-12 && (max_y - 0.2).abs() < 1e-12);
        // One height: no vertical steps.
        let flat = RelocConfig {
            heights_m: vec![1.4],
            ..config
        };
        assert_eq!(
            CoarseStarts::new(&yaws, &flat).iter().count(),
            3 * START_OFFSETS.len()
        );
    }

    #[test]
    fn the_gate_reads_from_the_maps_detail_unless_told_not_to() {
        let camera = PinholeCamera::new(160, 128, 120.0, 120.0, 79.5, 63.5);
        let mut keyframe = Keyframe::new(&camera, &TrackerConfig::default());
        keyframe.gate_level = 1; // a map coarser than the camera
        let mut config = RelocConfig::default();
        assert!(config.gate_at_map_detail, "on by default");
        assert_eq!(first_gate_level(&keyframe, &config), 1);
        config.gate_at_map_detail = false;
        assert_eq!(first_gate_level(&keyframe, &config), 0);
    }

    /// Correlations with this local contrast, the rest passing.
    fn with_local_of(local: f32) -> Correlations {
        Correlations {
            all: 0.6,
            trimmed: 0.6,
            kept: 0.9,
            local,
            local_kept: 0.9,
        }
    }

    #[test]
    fn the_first_level_at_the_maps_detail_has_a_floor_of_its_own() {
        // Set to min_local_correlation, the split is off.
        let off = RelocConfig {
            min_local_correlation_at_map_detail: 0.7,
            ..RelocConfig::default()
        };
        assert!(!passes_local(&with_local_of(0.55), 0.75, 1, &off));
        assert!(!passes_local(&with_local_of(0.69), 0.8, 1, &off));
        assert!(passes_local(&with_local_of(0.71), 0.8, 1, &off));
        // The default lowers the first level (a pose through it is then
        // verified against its rivals: `RivalRule::for_held`).
        let config = RelocConfig::default();
        assert!(config.min_local_correlation_at_map_detail < config.min_local_correlation);
        let with_local = with_local_of;
        // From level 0 (a map as fine as the camera) the smallest of the
        // three levels holds min_local_correlation, as before.
        assert!(!passes_local(&with_local(0.6), 0.8, 0, &config));
        assert!(passes_local(&with_local(0.75), 0.8, 0, &config));
        // A resume's lowered floor (`resume_local_floor`) holds in its place.
        assert!(local_contrast_passes(
            &with_local(0.6),
            0.8,
            0,
            &config,
            0.59
        ));
        assert!(!local_contrast_passes(
            &with_local(0.58),
            0.8,
            0,
            &config,
            0.59
        ));
        // At the map's detail: a true pose on 4 scanned rooms (0.57 at
        // level 1, 0.75 and 0.77 above) passes ...
        assert!(passes_local(&with_local(0.57), 0.75, 1, &config));
        // ... the place 2.4 m away (0.59, then 0.66 and 0.70) and the
        // 13 cm slide (0.24, 0.48, 0.63) do not.
        assert!(!passes_local(&with_local(0.59), 0.66, 1, &config));
        assert!(!passes_local(&with_local(0.24), 0.48, 1, &config));
        // The first level's own floor still holds; where the coarser
        // levels hold no local contrast (NaN), the first holds the whole.
        assert!(!passes_local(&with_local(0.45), 0.9, 1, &config));
        assert!(!passes_local(&with_local(0.6), f32::NAN, 1, &config));
        assert!(passes_local(&with_local(0.75), f32::NAN, 1, &config));
        // A floor set above min_local_correlation does not raise the gate.
        let strict = RelocConfig {
            min_local_correlation_at_map_detail: 0.95,
            ..config.clone()
        };
        assert!(passes_local(&with_local(0.72), 0.8, 1, &strict));
        assert!(!passes_local(&with_local(0.69), 0.8, 1, &strict));
    }

    #[test]
    fn resuming_reads_from_level_0_even_on_a_coarse_map() {
        // The map holds only the coarse pattern (sampled every 5 cm); the
        // camera also sees a fine grain: the true view, as a 2 cm scan
        // looks to a sharp camera.
        let coarse = |x: usize, y: usize| {
            let (x, y) = (x as f32, y as f32);
            128.0 + 50.0 * (x * 0.3).sin() * (y * 0.23).cos()
        };
        let grain = |x: usize, y: usize| 40.0 * ((x as f32) * 2.5).sin() * ((y as f32) * 2.3).sin();
        let (keyframe, frame, camera) =
            crate::track::correlation::tests::setup_detail(coarse, |x, y, v| v + grain(x, y), 0.05);
        assert_eq!(keyframe.gate_level, 1);
        let a = Alignment {
            camera_from_keyframe: Pose::identity(),
            gain: 1.0,
            bias: 0.0,
            covariance_delta: [[0.0; 6]; 6],
            quality: AlignQuality {
                inlier_ratio: 0.95,
                visible_ratio: 1.0,
                residual_rms: 5.0,
                correlation: 0.9,
                ..AlignQuality::default()
            },
            valid: true,
        };
        let mut config = RelocConfig::default();
        assert!(
            passes_whole_gate(&keyframe, &frame, &camera, &a, &config).is_some(),
            "relocalization reads the levels the map holds"
        );
        assert!(
            passes_resume_gate(
                &keyframe,
                &frame,
                &camera,
                &a,
                &config,
                config.min_local_correlation
            )
            .is_none(),
            "resuming reads level 0"
        );
        config.gate_at_map_detail = false;
        assert!(passes_whole_gate(&keyframe, &frame, &camera, &a, &config).is_none());
    }
}
