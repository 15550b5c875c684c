//! Online relocalization, the search: which database keyframes to try
//! while lost, and in what order.
//!
//! Takes the current camera frame (its whole-image descriptors at every
//! query shift, or its pyramid), the region to search ([`SearchRegion`])
//! and the database; gives out the candidates to render and verify (the
//! top-k by Hamming distance within the region, re-ranked by aligning the
//! frame against each entry's stored coarse points, or the landmark pose).
//! The acceptance gate they then go through is [`super::verify`].
//! After [`Relocalizer::new`] nothing here allocates.

use nalgebra::{Translation3, UnitQuaternion, Vector3};

use crate::geometry::{PinholeCamera, Pose};
use crate::track::TrackerConfig;
use crate::track::{Aligner, Keyframe, Pyramid, MAX_LEVELS};

use super::coarse::{coarse_camera, frame_level, to_keypoints};
use super::config::RelocConfig;
use super::database::{RelocDatabase, RelocDbError};
use super::descriptor::{Descriptor, Thumbnailer, QUERY_SHIFTS_PX, THUMB_W};
use super::landmarks::{LandmarkLocator, Located};
use super::region::SearchRegion;
use super::verify::start_yaws_rad;

/// One search result.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ranked {
    /// Hamming distance (the smallest over the query shifts).
    pub distance: u32,
    /// Database entry index.
    pub index: u32,
    /// Index into [`QUERY_SHIFTS_PX`] of the shift that matched best.
    pub shift: u8,
}

impl Default for Ranked {
    fn default() -> Self {
        Self {
            distance: u32::MAX,
            index: 0,
            shift: 0,
        }
    }
}

/// A candidate to render and verify.
#[derive(Debug, Clone, Copy)]
pub struct Candidate {
    /// The database entry and its Hamming distance.
    pub ranked: Ranked,
    /// Where to render it: the entry's pose, or where the coarse alignment
    /// against its stored points moved it.
    pub world_from_camera: Pose,
    /// Yaw of the query relative to that pose to start the alignment from,
    /// radians (0 after a coarse alignment).
    /// `None`: the pose is precise (from the landmarks), verified from a
    /// single start.
    pub yaw_rad: Option<f64>,
    /// Correlation reached by the coarse alignment; -inf when not aligned.
    pub score: f32,
}

impl Default for Candidate {
    fn default() -> Self {
        Self {
            ranked: Ranked::default(),
            world_from_camera: Pose::identity(),
            yaw_rad: Some(0.0),
            score: f32::NEG_INFINITY,
        }
    }
}

/// The query descriptors at every shift of [`QUERY_SHIFTS_PX`].
pub type Query = [Descriptor; QUERY_SHIFTS_PX.len()];

/// Most candidates one search returns: the largest `top_k` and
/// `rank_candidates` [`RelocConfig::validate`] accepts, and the capacity of
/// the candidate lists.
pub const MAX_TOP_K: usize = 64;

/// [`Ranked::index`] of the candidate found from the landmarks (not a
/// database entry).
pub const LANDMARK_CANDIDATE: u32 = u32::MAX - 1;

/// [`Ranked::index`] of the first landmark pose at another place
/// ([`Relocalizer::landmark_rivals`]); the k-th is this less k.
pub const LANDMARK_ELSEWHERE: u32 = u32::MAX - 2;
/// Most landmark poses at other places one attempt verifies as rivals.
pub const MAX_LANDMARK_ELSEWHERE: usize = 3;

/// Whether a candidate's index is a landmark pose's: the one found
/// ([`LANDMARK_CANDIDATE`]) or one at another place.
pub fn is_landmark_index(index: u32) -> bool {
    index <= LANDMARK_CANDIDATE && index > LANDMARK_ELSEWHERE - MAX_LANDMARK_ELSEWHERE as u32
}

/// Fewest stored coarse points a candidate needs to be aligned when
/// ranking (fewer score lowest).
const COARSE_MIN_POINTS: usize = 30;

/// The search side of relocalization: database, descriptor scratch and the
/// candidate list.
#[derive(Debug, Clone)]
pub struct Relocalizer {
    db: RelocDatabase,
    index: SearchIndex,
    config: RelocConfig,
    thumbnailer: Thumbnailer,
    best: [Ranked; MAX_TOP_K],
    n_best: usize,
    camera: PinholeCamera,
    /// Holds one candidate's stored coarse points at a time (only the
    /// level the frame is aligned on is filled).
    coarse_keyframe: Box<Keyframe>,
    /// The last [`Self::search_ranked`]'s candidates.
    candidates: heapless::Vec<Candidate, MAX_TOP_K>,
    landmarks: LandmarkLocator,
    /// The map's geometry, for the twins of a held pose
    /// ([`Self::with_map`]; none until then).
    twins: super::twins::GeometricTwins,
    /// Relocalization's gate: `config`, with the lower floors of a map
    /// checked for twins ([`super::twins::relocalization_gate`]).
    gate: RelocConfig,
}

impl Relocalizer {
    /// Takes `db` for use with `camera`; errors when the database was built
    /// for other intrinsics (check the map with
    /// [`RelocDatabase::check_compatible`] where the map is at hand).
    pub fn new(
        db: RelocDatabase,
        config: &RelocConfig,
        camera: &PinholeCamera,
    ) -> Result<Self, RelocDbError> {
        db.check_compatible(camera, db.map_fingerprint)?;
        Ok(Self {
            landmarks: LandmarkLocator::new(camera, config, &db.landmarks, &db.vocabulary),
            index: SearchIndex::new(&db),
            db,
            config: config.clone(),
            thumbnailer: Thumbnailer::for_camera(camera),
            best: [Ranked::default(); MAX_TOP_K],
            n_best: 0,
            camera: *camera,
            coarse_keyframe: Box::new(Keyframe::new(
                camera,
                &TrackerConfig {
                    pyramid_levels: MAX_LEVELS as u32,
                    ..TrackerConfig::default()
                },
            )),
            candidates: heapless::Vec::new(),
            twins: super::twins::GeometricTwins::none(config),
            gate: config.clone(),
        })
    }

    /// Takes the map's geometry (`mesh`, the map the database was built
    /// from), so that a pose the prior cannot vouch for is checked at its
    /// geometric twins ([`super::twins`]). About a second for a
    /// 15 M-triangle floor; nothing where `[reloc] geometric_twins` leaves
    /// the map out.
    pub fn with_map(mut self, mesh: &crate::map::Mesh) -> Self {
        let started = std::time::Instant::now();
        self.twins = super::twins::GeometricTwins::new(mesh, &self.config);
        self.gate = super::twins::relocalization_gate(&self.config, self.twins.has_map());
        if self.twins.has_map() {
            tracing::info!(
                ms = started.elapsed().as_secs_f64() * 1e3,
                "map occupancy built for the geometric twin checks"
            );
        }
        self
    }

    /// Takes geometric twins already built for this map and config
    /// ([`super::twins::GeometricTwins::new`]), as [`Self::with_map`] would.
    pub fn with_twins(mut self, twins: super::twins::GeometricTwins) -> Self {
        self.twins = twins;
        self.gate = super::twins::relocalization_gate(&self.config, self.twins.has_map());
        self
    }

    /// The rival rule of an attempt under `prior` (none: a cold start) on
    /// this map: on a scan (held poses checked for geometric twins), a pose
    /// is accepted on the prior alone only with `[reloc]
    /// prior_alone_min_local_correlation` of local contrast
    /// ([`super::rivals::RivalRule::with_alone_floor`]); a pose through the
    /// lowered first level is held beyond the prior's reach only with
    /// `[reloc] lowered_floor_without_prior`, and a decisive correlation
    /// chooses between two places only for one that correlates `[reloc]
    /// twin_checked_decisive_min_correlation`.
    pub fn rival_rule(&self, prior: Option<super::prior::MotionPrior>) -> super::rivals::RivalRule {
        let rule = super::rivals::RivalRule::new(prior)
            .with_lowered_without_prior(self.config.lowered_floor_without_prior);
        if self.twins.has_map() {
            rule.with_alone_floor(self.config.prior_alone_min_local_correlation)
                .with_decisive_floor(self.config.twin_checked_decisive_min_correlation)
                .with_listed_rivals_deciding(self.config.twin_checked_decisive_with_listed_rivals)
        } else {
            rule
        }
    }

    /// The geometric twins of held poses ([`Self::with_map`]).
    pub fn twins_mut(&mut self) -> &mut super::twins::GeometricTwins {
        &mut self.twins
    }

    /// The landmark side (its probes, its comparison counts).
    pub fn landmarks_mut(&mut self) -> &mut LandmarkLocator {
        &mut self.landmarks
    }

    /// The database.
    pub fn database(&self) -> &RelocDatabase {
        &self.db
    }

    /// The `[reloc]` settings in use.
    pub fn config(&self) -> &RelocConfig {
        &self.config
    }

    /// The settings a relocalization candidate is verified with: `config`,
    /// with the plain correlation's and the inlier ratio's floors lowered
    /// on a map checked for geometric twins
    /// ([`super::twins::relocalization_gate`]).
    pub fn gate(&self) -> &RelocConfig {
        &self.gate
    }

    /// Descriptors of a camera frame at every query shift; `None` when it
    /// has too little contrast.
    pub fn describe(
        &mut self,
        pixels: &[u8],
        width: usize,
        height: usize,
        stride: usize,
    ) -> Option<Query> {
        self.thumbnailer.describe_u8(
            pixels,
            width,
            height,
            stride,
            self.config.min_contrast_gray,
        )?;
        let t = &self.thumbnailer;
        Some(QUERY_SHIFTS_PX.map(|dx| t.shifted(dx)))
    }

    /// The candidate the landmarks give for the camera frame `pixels` (8-bit,
    /// `width x height`, rows `stride` bytes apart): the pose RANSAC PnP
    /// finds from its features matched to the landmarks of each of
    /// `regions` in turn (near the last position, then the whole map), the
    /// first inside its region. `None` without landmarks or when PnP finds
    /// no pose.
    pub fn landmark_candidate(
        &mut self,
        pixels: &[u8],
        width: usize,
        height: usize,
        stride: usize,
        regions: &[SearchRegion],
    ) -> Option<(Candidate, Located)> {
        let found = self
            .landmarks
            .locate_in(pixels, width, height, stride, regions)?;
        let candidate = Candidate {
            ranked: Ranked {
                distance: 0,
                index: LANDMARK_CANDIDATE,
                shift: 0,
            },
            world_from_camera: found.world_from_camera,
            yaw_rad: None,
            score: f32::INFINITY,
        };
        Some((candidate, found))
    }

    /// The landmark poses of the last [`Self::landmark_candidate`] at the
    /// other places where the frame's corners fit over the whole map
    /// ([`LandmarkLocator::poses_elsewhere`]), as candidates to verify as
    /// rivals of `held` (precise poses, scored as the landmark pose is),
    /// written to `out`; returns how many (at most
    /// [`MAX_LANDMARK_ELSEWHERE`]). On a cold start, with `held` the
    /// landmark pose the gate refused, they are also the attempt's next
    /// candidates ([`super::prior::Source::LandmarkElsewhere`]): on the
    /// scanned floor the landmark pose fell more than 10 cm from the truth
    /// in 29 of 50 cold starts (seed 1), most often on a look-alike room,
    /// and with this step 29 of those 50 cold starts succeed instead of
    /// 19, none wrong (docs/building-scale.md, "The landmarks' other places
    /// as candidates"). Only on a map checked for geometric twins (a
    /// scan): on the textured `building` floor the rivals the search
    /// already lists tell its look-alikes apart (0 wrong in 100 cold starts
    /// either way), and these cost its cold start 183 -> 260 ms median
    /// (docs/building-scale.md, "The landmarks' other places").
    pub fn landmark_rivals(&mut self, held: &Pose, out: &mut [Candidate]) -> usize {
        if !self.twins.has_map() {
            return 0;
        }
        let mut found = heapless::Vec::<Located, MAX_LANDMARK_ELSEWHERE>::new();
        self.landmarks.poses_elsewhere(held, &mut found);
        let mut n = 0;
        for (k, (f, slot)) in found.iter().zip(out.iter_mut()).enumerate() {
            *slot = Candidate {
                ranked: Ranked {
                    distance: 0,
                    index: LANDMARK_ELSEWHERE - k as u32,
                    shift: 0,
                },
                world_from_camera: f.world_from_camera,
                yaw_rad: None,
                score: f32::INFINITY,
            };
            n += 1;
        }
        n
    }

    /// The `top_k` entries in `region` nearest to `query` by Hamming
    /// distance, best first (fewer when the region holds fewer).
    pub fn search(&mut self, query: &Query, region: SearchRegion) -> &[Ranked] {
        let k = (self.config.top_k as usize).clamp(1, MAX_TOP_K);
        let n = self.index.top_k(query, region, k, &mut self.best);
        self.n_best = n;
        &self.best[..n]
    }

    /// The candidates to render for `query` in `region`, best first, at
    /// most `top_k`. The `rank_candidates` nearest entries by Hamming
    /// distance are each aligned, at the level of `frame` (the query
    /// frame's pyramid) nearest 40x32, against the entry's stored coarse
    /// keyframe from the yaws of [`start_yaws_rad`]; they are re-ranked by
    /// the correlation reached, and each is to be rendered where its
    /// alignment moved it (nearer the truth: the STAR idea, before any
    /// render). A descriptor ranks views by how alike they look; the
    /// alignment by whether the frame fits the candidate's geometry, which
    /// also sees through the offsets a whole-image descriptor does not
    /// tolerate (close range, a few tenths of a meter off the grid).
    /// Candidates whose alignments end within 5 cm and 2 degrees of a
    /// better one's are dropped (they would render the same view). Without
    /// coarse points, or with `rank_candidates <= top_k`, the top-k by
    /// Hamming distance at their database poses.
    pub fn search_ranked(
        &mut self,
        query: &Query,
        region: SearchRegion,
        aligner: &mut Aligner,
        frame: &Pyramid,
    ) -> &[Candidate] {
        let top_k = (self.config.top_k as usize).clamp(1, MAX_TOP_K);
        let m = (self.config.rank_candidates as usize).min(MAX_TOP_K);
        if m <= top_k || self.db.coarse_points.is_empty() || frame.is_empty() {
            let n = self.search(query, region).len();
            self.candidates.clear();
            for i in 0..n {
                let ranked = self.best[i];
                let candidate = Candidate {
                    ranked,
                    world_from_camera: self.db.entries[ranked.index as usize].world_from_camera,
                    yaw_rad: Some(self.shift_yaw_rad(ranked.shift)),
                    score: f32::NEG_INFINITY,
                };
                // Never full: a search returns at most MAX_TOP_K.
                if self.candidates.push(candidate).is_err() {
                    break;
                }
            }
            return &self.candidates;
        }
        let n = self.index.top_k(query, region, m, &mut self.best);
        let level = frame_level(&self.camera, frame.len() - 1);
        let coarse = coarse_camera(&self.camera);
        self.candidates.clear();
        for i in 0..n {
            let ranked = self.best[i];
            let world_from_entry = self.db.entries[ranked.index as usize].world_from_camera;
            let yaws = start_yaws_rad(&self.config, self.shift_yaw_rad(ranked.shift));
            let points = self.db.coarse_points_of(ranked.index as usize);
            let kf = &mut self.coarse_keyframe;
            to_keypoints(points.iter(), &coarse, &mut kf.levels[level].points);
            let mut best = Candidate {
                ranked,
                world_from_camera: world_from_entry,
                yaw_rad: Some(yaws[0]),
                score: f32::NEG_INFINITY,
            };
            if kf.levels[level].points.len() >= COARSE_MIN_POINTS {
                for (k, &yaw) in yaws.iter().enumerate() {
                    if yaws[..k].contains(&yaw) {
                        continue;
                    }
                    let start = Pose::from_parts(
                        Translation3::identity(),
                        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw),
                    )
                    .inverse();
                    let a = aligner.align_to_level(kf, frame, &self.camera, start, level);
                    let q = &a.quality;
                    let moved_m = a.camera_from_keyframe.translation.vector.norm();
                    if a.valid
                        && q.visible_ratio >= self.config.min_visible_ratio
                        && moved_m <= 2.0 * self.config.grid_spacing_m
                        && q.correlation > best.score
                    {
                        best.score = q.correlation;
                        best.world_from_camera =
                            world_from_entry * a.camera_from_keyframe.inverse();
                        best.yaw_rad = Some(0.0);
                    }
                }
            }
            // Never full: a search returns at most MAX_TOP_K.
            if self.candidates.push(best).is_err() {
                break;
            }
        }
        let n = self.candidates.len();
        // Insertion sort (no allocation), best first; ties keep the
        // Hamming order.
        for i in 1..n {
            let c = self.candidates[i];
            let mut j = i;
            while j > 0 && self.candidates[j - 1].score < c.score {
                self.candidates[j] = self.candidates[j - 1];
                j -= 1;
            }
            self.candidates[j] = c;
        }
        // Keep the first `top_k` that do not duplicate a better one.
        let mut kept = 0usize;
        for i in 0..n {
            let c = self.candidates[i];
            let duplicate = c.score.is_finite()
                && self.candidates[..kept].iter().any(|k| {
                    let d = k.world_from_camera.inverse() * c.world_from_camera;
                    d.translation.vector.norm() < 0.05 && d.rotation.angle() < 2f64.to_radians()
                });
            if duplicate {
                continue;
            }
            self.candidates.swap(kept, i);
            kept += 1;
            if kept == top_k {
                break;
            }
        }
        self.candidates.truncate(kept);
        &self.candidates
    }

    /// Hamming distance of the `rank`-th candidate of the last search.
    pub fn distance_of_rank(&self, rank: usize) -> Option<u32> {
        self.best[..self.n_best].get(rank).map(|b| b.distance)
    }

    /// Yaw of the query relative to a candidate that matched at `shift`
    /// (an index into [`QUERY_SHIFTS_PX`]), radians, about the camera's
    /// vertical axis (positive: the query looks further right).
    pub fn shift_yaw_rad(&self, shift: u8) -> f64 {
        let dx = QUERY_SHIFTS_PX.get(shift as usize).copied().unwrap_or(0) as f64;
        let fx_thumb = self.camera.fx * THUMB_W as f64 / self.camera.width.max(1) as f64;
        // Sampling the query dx pixels to the right matches the entry: the
        // scene moved right in the query, so the query looks further left.
        -(dx / fx_thumb).atan()
    }
}

/// The database laid out for search: descriptors and positions in two
/// contiguous arrays (a scan touches 44 bytes per entry, not the whole entry).
#[derive(Debug, Clone, Default)]
pub struct SearchIndex {
    descriptors: Vec<Descriptor>,
    positions_m: Vec<[f32; 3]>,
}

impl SearchIndex {
    /// Copies the descriptors and positions of `db`.
    pub fn new(db: &RelocDatabase) -> Self {
        Self {
            descriptors: db.entries.iter().map(|e| e.descriptor).collect(),
            positions_m: db
                .entries
                .iter()
                .map(|e| {
                    let t = e.world_from_camera.translation.vector;
                    [t.x as f32, t.y as f32, t.z as f32]
                })
                .collect(),
        }
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.descriptors.len()
    }

    /// True when there are no entries.
    pub fn is_empty(&self) -> bool {
        self.descriptors.is_empty()
    }

    /// The `k` entries in `region` nearest to `query` (the smallest distance
    /// over its shifts), written to `best[..returned]`, best first; ties by
    /// index. Uses the CPU's popcount instruction where there is one.
    pub fn top_k(
        &self,
        query: &[Descriptor],
        region: SearchRegion,
        k: usize,
        best: &mut [Ranked; MAX_TOP_K],
    ) -> usize {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("popcnt") {
                // SAFETY: the CPU supports popcnt, checked just above.
                return unsafe { self.top_k_popcnt(query, region, k, best) };
            }
        }
        self.scan(query, region, k, best)
    }

    /// [`Self::scan`] compiled with the popcnt instruction.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "popcnt")]
    unsafe fn top_k_popcnt(
        &self,
        query: &[Descriptor],
        region: SearchRegion,
        k: usize,
        best: &mut [Ranked; MAX_TOP_K],
    ) -> usize {
        self.scan(query, region, k, best)
    }

    #[inline(always)]
    fn scan(
        &self,
        query: &[Descriptor],
        region: SearchRegion,
        k: usize,
        best: &mut [Ranked; MAX_TOP_K],
    ) -> usize {
        let k = k.clamp(1, MAX_TOP_K);
        let mut n = 0usize;
        let (center, r2, near) = match region {
            SearchRegion::Near { center_m, radius_m } => (
                [center_m.x as f32, center_m.y as f32, center_m.z as f32],
                (radius_m * radius_m) as f32,
                true,
            ),
            SearchRegion::Everywhere => ([0.0; 3], 0.0, false),
        };
        for (i, (desc, pos)) in self.descriptors.iter().zip(&self.positions_m).enumerate() {
            if near {
                let d2 = (pos[0] - center[0]).powi(2)
                    + (pos[1] - center[1]).powi(2)
                    + (pos[2] - center[2]).powi(2);
                if d2 > r2 {
                    continue;
                }
            }
            let (mut d, mut shift) = (u32::MAX, 0u8);
            for (s, q) in query.iter().enumerate() {
                let ds = q.hamming(desc);
                if ds < d {
                    (d, shift) = (ds, s as u8);
                }
            }
            if n == k && d >= best[k - 1].distance {
                continue;
            }
            // Insertion into the sorted list.
            let mut j = if n < k { n } else { k - 1 };
            while j > 0 && best[j - 1].distance > d {
                best[j] = best[j - 1];
                j -= 1;
            }
            best[j] = Ranked {
                distance: d,
                index: i as u32,
                shift,
            };
            n = (n + 1).min(k);
        }
        n
    }
}
