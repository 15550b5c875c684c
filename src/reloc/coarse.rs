//! Coarse keyframes stored in the relocalization database: the selected
//! points of each entry's view at 40x32 (for the presets' 640x512 camera),
//! so that many more candidates than are rendered can be aligned, at the
//! coarsest pyramid level, before any render.
//!
//! Takes the database views (rendered at twice the thumbnail size, gray and
//! depth) at build time and gives out at most [`MAX_COARSE_POINTS`]
//! [`CoarsePoint`]s per view, 10 bytes each; at query time turns them back
//! into the tracker's [`KeyPoint`]s (3D point, intensity, inverse
//! compositional Jacobian) for the camera level the frame is aligned on.
//! The gradient is stored per coarse pixel and the Jacobian rebuilt from
//! gradient times focal length, which does not depend on the level, so the
//! stored points align against any frame level of about that size.

use crate::geometry::{PinholeCamera, Pose};
use crate::render::RenderedView;
use crate::track::TrackerConfig;
use crate::track::{KeyPoint, Keyframe};

use super::grid::thumb_render_camera;

/// Pyramid level, above the database render, of the stored points (the
/// render is 160x128 for the presets; level 2 is 40x32).
pub const COARSE_LEVEL: u32 = 2;
/// Most points stored per entry (the tracker's floor of points per level).
pub const MAX_COARSE_POINTS: usize = 256;
/// Selection threshold above the block median gradient, gray levels per
/// pixel (the tracker's is 4): a 40x32 view has few pixels, and
/// the ranking needs as many as it can get.
const COARSE_GRADIENT_THRESHOLD: f32 = 1.0;
/// Stored gradient units per gray level per pixel.
const GRAD_SCALE: f32 = 128.0;

/// One stored coarse keyframe point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CoarsePoint {
    /// Pixel column in [`coarse_camera`].
    pub x: u8,
    /// Pixel row in [`coarse_camera`].
    pub y: u8,
    /// Rendered intensity, 0..=255.
    pub gray: u8,
    /// Depth along the optical axis, millimeters (> 0).
    pub depth_mm: u16,
    /// Horizontal intensity gradient, 1/128 gray level per coarse pixel.
    pub grad_x: i16,
    /// Vertical intensity gradient, same units.
    pub grad_y: i16,
}

/// Bytes per point in the database file.
pub const COARSE_POINT_LEN: usize = 1 + 1 + 1 + 1 + 2 + 2 + 2;

impl CoarsePoint {
    /// The file bytes: x, y, gray, a zero byte, depth, gradient (little-endian).
    pub fn to_bytes(self) -> [u8; COARSE_POINT_LEN] {
        let mut b = [0u8; COARSE_POINT_LEN];
        b[0] = self.x;
        b[1] = self.y;
        b[2] = self.gray;
        b[4..6].copy_from_slice(&self.depth_mm.to_le_bytes());
        b[6..8].copy_from_slice(&self.grad_x.to_le_bytes());
        b[8..10].copy_from_slice(&self.grad_y.to_le_bytes());
        b
    }

    /// Parses [`Self::to_bytes`]; `None` when the reserved byte is not zero
    /// or the depth is zero.
    pub fn from_bytes(b: [u8; COARSE_POINT_LEN]) -> Option<Self> {
        let p = Self {
            x: b[0],
            y: b[1],
            gray: b[2],
            depth_mm: u16::from_le_bytes([b[4], b[5]]),
            grad_x: i16::from_le_bytes([b[6], b[7]]),
            grad_y: i16::from_le_bytes([b[8], b[9]]),
        };
        (b[3] == 0 && p.depth_mm > 0).then_some(p)
    }
}

/// The pinhole camera the stored points' pixels refer to: the database
/// render camera of `camera` at [`COARSE_LEVEL`].
pub fn coarse_camera(camera: &PinholeCamera) -> PinholeCamera {
    thumb_render_camera(camera).scaled_to_level(COARSE_LEVEL)
}

/// The level of a pyramid of `camera`'s frames nearest in size to
/// [`coarse_camera`], at most `max_level`.
pub fn frame_level(camera: &PinholeCamera, max_level: usize) -> usize {
    let coarse_w = coarse_camera(camera).width.max(1) as f64;
    let ratio = camera.width.max(1) as f64 / coarse_w;
    (ratio.log2().round().max(0.0) as usize).min(max_level)
}

/// Build side: selects the coarse points of database views. Owns a
/// keyframe sized for the render camera; nothing allocates per view.
#[derive(Debug, Clone)]
pub struct CoarseExtractor {
    keyframe: Keyframe,
    config: TrackerConfig,
    camera: PinholeCamera,
}

impl CoarseExtractor {
    /// For views rendered with `render_camera` (see
    /// [`thumb_render_camera`]).
    pub fn new(render_camera: &PinholeCamera) -> Self {
        let config = TrackerConfig {
            pyramid_levels: COARSE_LEVEL + 1,
            // The tracker keeps max_points >> level, at least 200.
            max_points: (MAX_COARSE_POINTS as u32) << COARSE_LEVEL,
            gradient_threshold_gray: COARSE_GRADIENT_THRESHOLD,
            ..TrackerConfig::default()
        };
        Self {
            keyframe: Keyframe::new(render_camera, &config),
            camera: render_camera.scaled_to_level(COARSE_LEVEL),
            config,
        }
    }

    /// Appends the coarse points of `view` (rendered with the render camera
    /// given to [`Self::new`]) to `out`; returns how many.
    pub fn extract(&mut self, view: &RenderedView, out: &mut Vec<CoarsePoint>) -> usize {
        self.keyframe
            .prepare(view, Pose::identity(), 0, &self.config);
        let (fx, fy, cx, cy) = (
            self.camera.fx as f32,
            self.camera.fy as f32,
            self.camera.cx as f32,
            self.camera.cy as f32,
        );
        let (w, h) = (self.camera.width as f32, self.camera.height as f32);
        let before = out.len();
        for kp in self
            .keyframe
            .levels
            .get(COARSE_LEVEL as usize)
            .map_or(&[][..], |l| &l.points[..])
            .iter()
            .take(MAX_COARSE_POINTS)
        {
            let [px, py, z] = kp.p_keyframe;
            if !(z > 0.0 && z < 65.0) {
                continue;
            }
            let x = (fx * px / z + cx).round();
            let y = (fy * py / z + cy).round();
            if !(0.0..w.min(256.0)).contains(&x) || !(0.0..h.min(256.0)).contains(&y) {
                continue;
            }
            // Jacobian row 0 is gx * fx / z (see the keyframe preparation).
            let gx = kp.jacobian[0] * z / fx;
            let gy = kp.jacobian[1] * z / fy;
            let q = |g: f32| {
                (g * GRAD_SCALE)
                    .round()
                    .clamp(i16::MIN as f32, i16::MAX as f32) as i16
            };
            out.push(CoarsePoint {
                x: x as u8,
                y: y as u8,
                gray: kp.gray.round().clamp(0.0, 255.0) as u8,
                depth_mm: (z * 1000.0).round().clamp(1.0, u16::MAX as f32) as u16,
                grad_x: q(gx),
                grad_y: q(gy),
            });
        }
        out.len() - before
    }
}

/// Query side: replaces `out` with the keyframe points of `points`, stored
/// for `coarse` ([`coarse_camera`]).
pub fn to_keypoints(
    points: impl IntoIterator<Item = CoarsePoint>,
    coarse: &PinholeCamera,
    out: &mut Vec<KeyPoint>,
) {
    out.clear();
    let (fx, fy, cx, cy) = (
        coarse.fx as f32,
        coarse.fy as f32,
        coarse.cx as f32,
        coarse.cy as f32,
    );
    let room = out.capacity();
    for p in points.into_iter().take(room) {
        let z = p.depth_mm as f32 * 1e-3;
        let gx = p.grad_x as f32 / GRAD_SCALE;
        let gy = p.grad_y as f32 / GRAD_SCALE;
        out.push(KeyPoint::from_pixel(
            p.x as f32,
            p.y as f32,
            z,
            p.gray as f32,
            gx,
            gy,
            [fx, fy, cx, cy],
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imgproc::ImageF32;

    #[test]
    fn bytes_round_trip_and_reject_a_zero_depth() {
        let p = CoarsePoint {
            x: 39,
            y: 31,
            gray: 200,
            depth_mm: 2345,
            grad_x: -1234,
            grad_y: 32000,
        };
        assert_eq!(CoarsePoint::from_bytes(p.to_bytes()), Some(p));
        let mut b = p.to_bytes();
        b[4] = 0;
        b[5] = 0;
        assert_eq!(CoarsePoint::from_bytes(b), None);
        let mut b = p.to_bytes();
        b[3] = 1;
        assert_eq!(CoarsePoint::from_bytes(b), None);
    }

    /// A fronto-parallel plane with a horizontal ramp: the stored points
    /// give back the keyframe's own points and Jacobians.
    #[test]
    fn extracted_points_rebuild_the_keyframe_points() {
        let camera = PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
        let render = thumb_render_camera(&camera);
        let (w, h) = (render.width as usize, render.height as usize);
        let mut view = RenderedView::for_camera(&render);
        let mut gray = ImageF32::new(w, h, 0.0);
        for y in 0..h {
            for x in 0..w {
                // Texture in both directions so every block has gradient.
                let v = 128.0 + 60.0 * ((x as f32) * 0.35).sin() * ((y as f32) * 0.27).cos();
                gray.row_mut(y)[x] = v;
            }
        }
        view.gray = gray;
        view.depth_m = ImageF32::new(w, h, 2.5);
        let mut ex = CoarseExtractor::new(&render);
        let mut stored = Vec::new();
        let n = ex.extract(&view, &mut stored);
        assert!(n >= 100, "only {n} points");
        assert!(n <= MAX_COARSE_POINTS);
        let coarse = coarse_camera(&camera);
        assert_eq!((coarse.width, coarse.height), (40, 32));
        let mut kps = Vec::with_capacity(MAX_COARSE_POINTS);
        to_keypoints(stored.iter().copied(), &coarse, &mut kps);
        let original = &ex.keyframe.levels[COARSE_LEVEL as usize].points;
        assert_eq!(kps.len(), n);
        for (a, b) in kps.iter().zip(original) {
            for k in 0..3 {
                assert!(
                    (a.p_keyframe[k] - b.p_keyframe[k]).abs() < 2e-3,
                    "{a:?} {b:?}"
                );
            }
            assert!((a.gray - b.gray).abs() <= 0.5);
            for k in 0..6 {
                // 2 % plus the gradient's quantization (1/256 gray level
                // per pixel), which shows in the rotation terms as a
                // difference of large products: relative to the row's size.
                let size = b.jacobian.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                let tol = 0.02 * b.jacobian[k].abs() + 2e-3 * size;
                assert!((a.jacobian[k] - b.jacobian[k]).abs() < tol, "{a:?} {b:?}");
            }
        }
    }

    #[test]
    fn frame_level_matches_the_coarse_size() {
        let c = PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
        assert_eq!(frame_level(&c, 4), 4);
        assert_eq!(frame_level(&c, 3), 3);
        // The database renders at a fixed 160x128: a frame twice as large
        // meets the coarse points one level further up.
        let c = PinholeCamera::new(1280, 1024, 840.0, 840.0, 639.5, 511.5);
        assert_eq!(frame_level(&c, 5), 5);
    }
}
