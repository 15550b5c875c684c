//! The view frustum of one render as world-frame half-spaces, and the
//! conservative test of a box against it that decides which mesh chunks
//! ([`super::chunks`]) the renderers draw.
//!
//! Takes a pose and pinhole intrinsics; gives out [`Frustum`]: the near
//! plane, the four image-side planes two pixels beyond the outermost
//! pixel centers (one more than the CPU rasterizer's own triangle cull),
//! and, with a far limit ([`Frustum::with_far`]), the far plane. A box is
//! outside only when, padded by a millimeter, it lies wholly outside one
//! plane: then every vertex in it lies outside that plane, and no triangle
//! of it can cover a pixel center in either renderer (beyond the far plane
//! every pixel a triangle covers is deeper than the limit, since depth
//! over a triangle lies between its vertices' depths, and both renderers
//! drop such pixels).

use nalgebra::Vector3;

use super::chunks::Aabb;
use crate::geometry::{PinholeCamera, Pose};

/// Padding of the chunk boxes in the frustum test, meters, on top of a
/// relative 1e-6 of the largest coordinate: far above the `f32` rounding of
/// the renderers' vertex transforms.
const BOX_PAD_M: f64 = 1e-3;

/// Margin of the side planes beyond the outermost pixel centers, pixels.
/// The CPU rasterizer culls at one pixel; the test adds one more.
const SIDE_MARGIN_PX: f64 = 2.0;

/// The view volume of one render as six world-frame half-spaces
/// `n . p + d >= 0`: near, left, right, top, bottom, then far (a plane
/// every point passes when there is no far limit).
#[derive(Debug, Clone, Copy)]
pub struct Frustum {
    planes: [[f64; 4]; 6],
}

/// The far half-space when there is no far limit: `0 . p + 1 >= 0`.
const NO_FAR: [f64; 4] = [0.0, 0.0, 0.0, 1.0];

/// A camera-frame half-space `[a, b, c, d]` in the world frame:
/// `p_camera = R^T (p_world - t)`, so `n_c . p_camera = (R n_c) . (p_world - t)`.
fn to_world(world_from_camera: &Pose, [a, b, c, d]: [f64; 4]) -> [f64; 4] {
    let n = world_from_camera.rotation * Vector3::new(a, b, c);
    let t = world_from_camera.translation.vector;
    [n.x, n.y, n.z, d - n.dot(&t)]
}

impl Frustum {
    /// The volume seen by `camera` (distortion ignored) at
    /// `world_from_camera`, from `near_m` along the optical axis.
    pub fn new(world_from_camera: &Pose, camera: &PinholeCamera, near_m: f64) -> Self {
        let (fx, fy, cx, cy) = (camera.fx, camera.fy, camera.cx, camera.cy);
        let m = SIDE_MARGIN_PX;
        let (lo_u, hi_u) = (-m, f64::from(camera.width) - 1.0 + m);
        let (lo_v, hi_v) = (-m, f64::from(camera.height) - 1.0 + m);
        // Camera frame: u >= lo  <=>  fx x + (cx - lo) z >= 0 for z > 0, etc.
        let camera_planes = [
            [0.0, 0.0, 1.0, -near_m],
            [fx, 0.0, cx - lo_u, 0.0],
            [-fx, 0.0, hi_u - cx, 0.0],
            [0.0, fy, cy - lo_v, 0.0],
            [0.0, -fy, hi_v - cy, 0.0],
        ];
        let planes = camera_planes.map(|p| to_world(world_from_camera, p));
        Self {
            planes: [
                planes[0], planes[1], planes[2], planes[3], planes[4], NO_FAR,
            ],
        }
    }

    /// This frustum cut at `far_m` along the optical axis (`None`: no
    /// limit).
    pub fn with_far(mut self, world_from_camera: &Pose, far_m: Option<f64>) -> Self {
        self.planes[5] = match far_m {
            // z <= far  <=>  -z + far >= 0.
            Some(far_m) => to_world(world_from_camera, [0.0, 0.0, -1.0, far_m]),
            None => NO_FAR,
        };
        self
    }

    /// False only when `bounds` (padded) lies wholly outside one plane.
    pub fn intersects(&self, bounds: &Aabb) -> bool {
        let lo = bounds.min_m.map(f64::from);
        let hi = bounds.max_m.map(f64::from);
        let largest = lo.iter().chain(&hi).fold(0.0f64, |m, v| m.max(v.abs()));
        let pad = BOX_PAD_M + 1e-6 * largest;
        let center = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
        let half = [0, 1, 2].map(|k| 0.5 * (hi[k] - lo[k]) + pad);
        self.planes.iter().all(|[a, b, c, d]| {
            let reach = a.abs() * half[0] + b.abs() * half[1] + c.abs() * half[2];
            a * center[0] + b * center[1] + c * center[2] + d + reach >= 0.0
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frustum_keeps_boxes_in_view_and_drops_boxes_behind() {
        let cam = PinholeCamera::new(64, 48, 50.0, 50.0, 31.5, 23.5);
        let pose = Pose::identity();
        let f = Frustum::new(&pose, &cam, 0.05);
        let cube = |c: [f32; 3], h: f32| Aabb {
            min_m: c.map(|v| v - h),
            max_m: c.map(|v| v + h),
        };
        assert!(f.intersects(&cube([0.0, 0.0, 3.0], 0.1)));
        // Straddling the near plane, or containing the camera.
        assert!(f.intersects(&cube([0.0, 0.0, 0.0], 0.1)));
        assert!(!f.intersects(&cube([0.0, 0.0, -3.0], 0.1)), "behind");
        assert!(!f.intersects(&cube([10.0, 0.0, 3.0], 0.1)), "right");
        assert!(!f.intersects(&cube([0.0, -10.0, 3.0], 0.1)), "above");
        // A flat box at z = 3 m starting just right of the right plane
        // (u = 63 + 2 px: x = (65 - 31.5) * 3 / 50 = 2.01 m) is kept
        // within the padding, and culled beyond it.
        let right_of = |x: f32| Aabb {
            min_m: [x, -0.1, 3.0],
            max_m: [x + 0.2, 0.1, 3.0],
        };
        assert!(f.intersects(&right_of(2.01 + 0.0005)));
        assert!(!f.intersects(&right_of(2.01 + 0.01)));
        // The same boxes seen from a moved, turned camera.
        let moved = Pose::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.0, 0.0, 3.0));
        let fm = Frustum::new(&moved, &cam, 0.05);
        let at = |p: [f32; 3]| {
            let q =
                moved * nalgebra::Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
            [q.x as f32, q.y as f32, q.z as f32]
        };
        assert!(fm.intersects(&cube(at([0.0, 0.0, 3.0]), 0.1)));
        assert!(!fm.intersects(&cube(at([0.0, 0.0, -3.0]), 0.1)));
        // The far limit: boxes wholly beyond it go, boxes reaching it stay.
        let far = fm.with_far(&moved, Some(10.0));
        assert!(far.intersects(&cube(at([0.0, 0.0, 3.0]), 0.1)));
        assert!(far.intersects(&cube(at([0.0, 0.0, 10.05]), 0.1)));
        assert!(!far.intersects(&cube(at([0.0, 0.0, 10.2]), 0.1)));
        assert!(fm.intersects(&cube(at([0.0, 0.0, 10.2]), 0.1)));
        assert!(far
            .with_far(&moved, None)
            .intersects(&cube(at([0.0, 0.0, 10.2]), 0.1)));
    }
}
