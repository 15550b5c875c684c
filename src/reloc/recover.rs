//! Online relocalization: the search and the acceptance test the STAR loop
//! runs while lost.
//!
//! Takes the current camera frame, the last tracked position and the time
//! since the failure; gives out the database keyframes to try (the top-k by
//! Hamming distance within a radius that grows with the time lost, or over
//! the whole map), and, once a candidate is rendered, the verdict of
//! [`verify_candidate`]: the aligned pose if it passes the strict gate.
//! After [`Relocalizer::new`] nothing here allocates.

use nalgebra::{Translation3, UnitQuaternion, Vector3};

use crate::geometry::{PinholeCamera, Pose};
use crate::track::TrackerConfig;
use crate::track::{AlignQuality, Aligner, Alignment, Keyframe, Pyramid, MAX_LEVELS};

use super::coarse::{coarse_camera, frame_level, to_keypoints};
use super::config::RelocConfig;
use super::database::{RelocDatabase, RelocDbError};
use super::descriptor::{Descriptor, Thumbnailer, QUERY_SHIFTS_PX, THUMB_W};
use super::landmarks::{LandmarkLocator, Located};

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

/// Most candidates one search returns.
pub const MAX_TOP_K: usize = 64;

/// [`Ranked::index`] of the candidate found from the landmarks (not a
/// database entry).
pub const LANDMARK_CANDIDATE: u32 = u32::MAX - 1;

/// Fewest stored coarse points a candidate needs to be aligned when
/// ranking (fewer score lowest).
const COARSE_MIN_POINTS: usize = 30;

/// Where to search.
#[derive(Debug, Clone, Copy)]
pub enum SearchRegion {
    /// Entries within `radius_m` of `center_m`.
    Near {
        /// Last tracked position, world, meters.
        center_m: Vector3<f64>,
        /// Search radius, meters.
        radius_m: f64,
    },
    /// The whole database.
    Everywhere,
}

impl SearchRegion {
    /// True when `position_m` (world, meters) lies in the region.
    pub fn contains(&self, position_m: &Vector3<f64>) -> bool {
        match self {
            Self::Near { center_m, radius_m } => (position_m - center_m).norm() <= *radius_m,
            Self::Everywhere => true,
        }
    }
}

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
    candidates: [Candidate; MAX_TOP_K],
    n_ranked: usize,
    landmarks: LandmarkLocator,
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
            landmarks: LandmarkLocator::new(camera, config, &db.landmarks),
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
            candidates: [Candidate::default(); MAX_TOP_K],
            n_ranked: 0,
        })
    }

    /// The database.
    pub fn database(&self) -> &RelocDatabase {
        &self.db
    }

    /// The `[reloc]` settings in use.
    pub fn config(&self) -> &RelocConfig {
        &self.config
    }

    /// The search radius after `lost_s` seconds lost.
    pub fn radius_m(&self, lost_s: f64) -> f64 {
        self.config.search_radius_m + self.config.max_speed_m_s * lost_s.max(0.0)
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
        self.thumbnailer
            .describe_u8(pixels, width, height, stride, self.config.min_contrast)?;
        let t = &self.thumbnailer;
        Some(QUERY_SHIFTS_PX.map(|dx| t.shifted(dx)))
    }

    /// The candidate the landmarks give for the camera frame `pixels` (8-bit,
    /// `width x height`, rows `stride` bytes apart): the pose RANSAC PnP
    /// finds from its features matched to the landmarks, inside `region`.
    /// `None` without landmarks or when PnP finds no pose.
    pub fn landmark_candidate(
        &mut self,
        pixels: &[u8],
        width: usize,
        height: usize,
        stride: usize,
        region: SearchRegion,
    ) -> Option<(Candidate, Located)> {
        let found = self
            .landmarks
            .locate(pixels, width, height, stride, region)?;
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
            for i in 0..n {
                let ranked = self.best[i];
                self.candidates[i] = Candidate {
                    ranked,
                    world_from_camera: self.db.entries[ranked.index as usize].world_from_camera,
                    yaw_rad: Some(self.shift_yaw_rad(ranked.shift)),
                    score: f32::NEG_INFINITY,
                };
            }
            self.n_ranked = n;
            return &self.candidates[..n];
        }
        let n = self.index.top_k(query, region, m, &mut self.best);
        let level = frame_level(&self.camera, frame.len() - 1);
        let coarse = coarse_camera(&self.camera);
        for i in 0..n {
            let ranked = self.best[i];
            let world_from_entry = self.db.entries[ranked.index as usize].world_from_camera;
            let yaws = start_yaws_rad(&self.config, self.shift_yaw_rad(ranked.shift));
            let points = self.db.coarse_points_of(ranked.index as usize);
            let kf = &mut self.coarse_keyframe;
            to_keypoints(points, &coarse, &mut kf.levels[level].points);
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
            self.candidates[i] = best;
        }
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
        self.n_ranked = n;
        &self.candidates[..kept]
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

/// A candidate that passed the gate.
#[derive(Debug, Clone, Copy)]
pub struct Verified {
    /// The aligned camera pose.
    pub world_from_camera: Pose,
    /// The alignment.
    pub alignment: Alignment,
    /// Smallest correlation over pyramid levels 0, 1 and 2 ([`correlations`]).
    pub correlation: f32,
    /// Smallest trimmed correlation over the same levels.
    pub trimmed_correlation: f32,
    /// Smallest fraction of points the trimming kept.
    pub kept: f32,
}

/// The smallest [`correlations`] over pyramid levels 0, 1 and 2 (each
/// figure on its own); `None` when level 0 or 1 cannot be evaluated.
pub fn min_correlations(
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    camera_from_keyframe: &Pose,
) -> Option<Correlations> {
    let mut out: Option<Correlations> = None;
    for level in 0..3 {
        match correlations(keyframe, frame, camera, camera_from_keyframe, level) {
            Some(c) => {
                out = Some(out.map_or(c, |o| Correlations {
                    all: o.all.min(c.all),
                    trimmed: o.trimmed.min(c.trimmed),
                    kept: o.kept.min(c.kept),
                }));
            }
            None if level < 2 => return None,
            None => {}
        }
    }
    out
}

/// Zero-mean normalized cross-correlation between the keyframe points of
/// pyramid level `level` and the frame intensities where they project at
/// `camera_from_keyframe`; `None` with fewer than 50 visible points. A wrong
/// pose on a look-alike surface can fit an affine photometric model with
/// small residuals; it does not correlate.
pub fn correlation(
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    camera_from_keyframe: &Pose,
    level: usize,
) -> Option<f32> {
    let (kl, cam) = level_of(keyframe, frame, camera, level)?;
    let fit = ncc_pass(kl, frame, &cam, level, camera_from_keyframe, None)?;
    Some(fit.ncc)
}

/// The keyframe's points of `level` and the camera scaled to it; `None`
/// when the keyframe or the frame lacks the level.
fn level_of<'k>(
    keyframe: &'k Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    level: usize,
) -> Option<(&'k crate::track::KeyframeLevel, PinholeCamera)> {
    let kl = keyframe.levels.get(level)?;
    (level < frame.len()).then(|| (kl, camera.scaled_to_level(level as u32)))
}

/// What [`correlations`] measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correlations {
    /// Over every visible point ([`correlation`]).
    pub all: f32,
    /// Over the points that fit the affine intensity relation (trimmed
    /// four times at 2.5 standard deviations of the refitted relation; an
    /// object over a third of the view needs three or four): what is left when an
    /// object that is not in the map covers part of the view. A wrong pose
    /// on a low-contrast look-alike fits every point loosely and stays low.
    pub trimmed: f32,
    /// Fraction of the visible points the trimming kept.
    pub kept: f32,
}

/// [`correlation`] together with its trimmed version.
pub fn correlations(
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    camera_from_keyframe: &Pose,
    level: usize,
) -> Option<Correlations> {
    let (kl, cam) = level_of(keyframe, frame, camera, level)?;
    let all = ncc_pass(kl, frame, &cam, level, camera_from_keyframe, None)?;
    let mut trimmed = all;
    for _ in 0..4 {
        let limit = (trimmed.slope, trimmed.offset, 2.5 * trimmed.sigma);
        match ncc_pass(kl, frame, &cam, level, camera_from_keyframe, Some(limit)) {
            Some(t) => trimmed = t,
            None => break,
        }
    }
    Some(Correlations {
        all: all.ncc,
        trimmed: trimmed.ncc,
        kept: trimmed.n as f32 / all.n.max(1) as f32,
    })
}

/// One correlation pass and the affine fit `frame = slope * keyframe + offset`.
#[derive(Debug, Clone, Copy)]
struct NccFit {
    n: usize,
    ncc: f32,
    slope: f64,
    offset: f64,
    /// Standard deviation of the fit's residual, gray levels.
    sigma: f64,
}

/// Correlation over the visible points of `kl`, only those within
/// `limit.2` of the fit `(slope, offset) = (limit.0, limit.1)` when given;
/// `None` with fewer than 50 points or no variance.
fn ncc_pass(
    kl: &crate::track::KeyframeLevel,
    frame: &Pyramid,
    cam: &PinholeCamera,
    level: usize,
    camera_from_keyframe: &Pose,
    limit: Option<(f64, f64, f64)>,
) -> Option<NccFit> {
    let image = frame.level(level);
    let (mut n, mut sa, mut sb, mut saa, mut sbb, mut sab) = (0usize, 0f64, 0f64, 0f64, 0f64, 0f64);
    for kp in &kl.points {
        let p = Vector3::new(
            kp.p_keyframe[0] as f64,
            kp.p_keyframe[1] as f64,
            kp.p_keyframe[2] as f64,
        );
        let Some(uv) = cam.project(&(camera_from_keyframe * nalgebra::Point3::from(p)).coords)
        else {
            continue;
        };
        let Some(v) = image.bilinear(uv.x as f32, uv.y as f32) else {
            continue;
        };
        let (a, b) = (kp.gray as f64, v as f64);
        if let Some((slope, offset, max)) = limit {
            if (b - (slope * a + offset)).abs() > max {
                continue;
            }
        }
        n += 1;
        sa += a;
        sb += b;
        saa += a * a;
        sbb += b * b;
        sab += a * b;
    }
    if n < 50 {
        return None;
    }
    let nf = n as f64;
    let cov = sab - sa * sb / nf;
    let va = saa - sa * sa / nf;
    let vb = sbb - sb * sb / nf;
    if !(va > 0.0 && vb > 0.0) {
        return None;
    }
    let slope = cov / va;
    Some(NccFit {
        n,
        ncc: (cov / (va * vb).sqrt()) as f32,
        slope,
        offset: (sb - slope * sa) / nf,
        sigma: ((vb - slope * cov) / nf).max(1e-6).sqrt(),
    })
}

/// True when `q` passes the relocalization gate of `config`.
pub fn passes_gate(q: &AlignQuality, config: &RelocConfig) -> bool {
    q.inlier_ratio >= config.min_inlier_ratio
        && q.visible_ratio >= config.min_visible_ratio
        && q.residual_rms <= config.max_residual
        && q.residual_rms.is_finite()
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
pub fn verify_candidate(
    aligner: &mut Aligner,
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
    let score_level = coarsest.saturating_sub(1);
    let half_m = 0.5 * config.grid_spacing_m;
    let half_height_m = 0.5 * config.height_spacing_m();
    let vertical: &[f64] = if half_height_m > 0.0 && start_yaws_rad.len() > 1 {
        &[0.0, 1.0, -1.0]
    } else {
        &[0.0]
    };
    // Best coarse starts, by correlation: (score, camera_from_keyframe).
    let mut top = [(f32::NEG_INFINITY, Pose::identity()); FINISHED_STARTS];
    let search = start_yaws_rad.len() > 1;
    for (i, &yaw) in start_yaws_rad.iter().enumerate() {
        if i > 0 && start_yaws_rad[..i].contains(&yaw) {
            continue;
        }
        let offsets: &[(f64, f64)] = if search {
            &START_OFFSETS
        } else {
            &START_OFFSETS[..1]
        };
        for (&(dx, dz), dy) in offsets
            .iter()
            .flat_map(|o| vertical.iter().map(move |&dy| (o, dy)))
        {
            // Camera y points down: turning right (z toward +x) is a
            // positive rotation about y.
            let keyframe_from_camera = Pose::from_parts(
                Translation3::new(dx * half_m, dy * half_height_m, dz * half_m),
                UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw),
            );
            let start = keyframe_from_camera.inverse();
            if !search {
                top[0] = (0.0, start);
                continue;
            }
            let a = aligner.align_to_level(keyframe, frame, camera, start, coarsest);
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
            if let Some(slot) = top.iter().position(|(s, _)| score > *s) {
                top.copy_within(slot..FINISHED_STARTS - 1, slot + 1);
                top[slot] = (score, a.camera_from_keyframe);
            }
        }
    }
    let mut best: Option<Verified> = None;
    let mut refine: Option<(f32, Pose)> = None;
    for &(score, start) in &top {
        if score == f32::NEG_INFINITY {
            continue;
        }
        let a = aligner.align(keyframe, frame, camera, start);
        let world_from_camera = keyframe.world_from_keyframe * a.camera_from_keyframe.inverse();
        let finite = world_from_camera
            .translation
            .vector
            .iter()
            .chain(world_from_camera.rotation.coords.iter())
            .all(|v| v.is_finite());
        let moved_m = a.camera_from_keyframe.translation.vector.norm();
        let q = &a.quality;
        if !(a.valid && finite) || moved_m > 2.0 * config.grid_spacing_m {
            continue;
        }
        // Full-resolution detail (the alignment's own level-0 figure),
        // level 1 and coarse structure (level 2) must all correlate: a
        // look-alike place elsewhere in the map matched the texture at 0.73
        // but the layout only at 0.52, another 0.9 m off reached 0.6 only
        // at level 0's 0.59, where correct poses measured at least 0.58.
        let gain_ok = (config.min_gain..=config.max_gain).contains(&a.gain);
        // The correlations (five passes over the finest points) only where
        // the cheaper tests pass.
        let accepted = (passes_gate(q, config) && gain_ok)
            .then(|| min_correlations(keyframe, frame, camera, &a.camera_from_keyframe))
            .flatten()
            .filter(|c| {
                c.all >= config.min_correlation && c.trimmed >= config.min_trimmed_correlation
            });
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
    aligner: &mut Aligner,
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
    let mut verdict = verify_candidate(aligner, &keyframe, frame, camera, config, yaws);
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
        verdict = verify_candidate(aligner, &keyframe, frame, camera, config, &[0.0]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imgproc::ImageF32;
    use crate::render::RenderedView;

    fn texture(x: usize, y: usize, phase: f32) -> f32 {
        128.0 + 50.0 * ((x as f32 * 0.31 + phase).sin() + (y as f32 * 0.23 - phase).cos())
    }

    /// A keyframe of a textured fronto-parallel plane, and a frame of the
    /// same view with `edit` applied to its pixels.
    fn setup(edit: impl Fn(usize, usize, f32) -> f32) -> (Keyframe, Pyramid, PinholeCamera) {
        let camera = PinholeCamera::new(160, 128, 120.0, 120.0, 79.5, 63.5);
        let config = TrackerConfig {
            pyramid_levels: 3,
            ..TrackerConfig::default()
        };
        let mut view = RenderedView::for_camera(&camera);
        let mut frame = ImageF32::new(160, 128, 0.0);
        for y in 0..128 {
            for x in 0..160 {
                let v = texture(x, y, 0.0);
                view.gray.row_mut(y)[x] = v;
                frame.row_mut(y)[x] = edit(x, y, v);
            }
        }
        view.depth_m = ImageF32::new(160, 128, 2.0);
        let mut keyframe = Keyframe::new(&camera, &config);
        keyframe.prepare(&view, Pose::identity(), 1, &config);
        let mut pyramid = Pyramid::new(160, 128, 3);
        pyramid.fill_from_f32(&frame);
        (keyframe, pyramid, camera)
    }

    #[test]
    fn trimming_sees_through_an_occluder_but_not_a_wrong_view() {
        // A gain change and an object with its own texture over the left
        // third.
        let (kf, frame, camera) = setup(|x, y, v| {
            if x < 53 {
                texture(y, x, 2.9)
            } else {
                0.8 * v + 10.0
            }
        });
        let c = correlations(&kf, &frame, &camera, &Pose::identity(), 0).expect("occluded");
        assert!(c.all < 0.8, "{c:?}");
        assert!(c.trimmed > 0.95, "{c:?}");
        assert!((0.5..0.8).contains(&c.kept), "{c:?}");
        assert_eq!(
            correlation(&kf, &frame, &camera, &Pose::identity(), 0),
            Some(c.all)
        );
        // Another texture altogether: trimming does not make it correlate.
        let (kf, frame, camera) = setup(|x, y, _| texture(x, y, 1.7));
        let c = correlations(&kf, &frame, &camera, &Pose::identity(), 0).expect("other");
        assert!(c.trimmed < 0.6, "{c:?}");
        // The same view: both near 1, nothing trimmed away to speak of.
        let (kf, frame, camera) = setup(|_, _, v| v);
        let c = min_correlations(&kf, &frame, &camera, &Pose::identity()).expect("same");
        assert!(c.all > 0.99 && c.trimmed > 0.99 && c.kept > 0.95, "{c:?}");
    }
}
