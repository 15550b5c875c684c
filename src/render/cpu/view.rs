//! The per-render view: the world-to-camera transform, the pinhole
//! projection to fixed-point screen coordinates, and the clip planes with
//! their vertex outcodes.
//!
//! Takes a pose and a camera, gives out [`View`], which turns world vertices
//! into [`CamVertex`] (camera-frame position, outcode, projected position).
//! Every clip plane is a half-space `a x + b y + c z + d >= 0` in the camera
//! optical frame: the near plane, four guard-band planes (clipped against, so
//! that fixed-point coordinates stay bounded) and four view planes (used only
//! to cull triangles that cannot cover a pixel center).

use crate::geometry::{PinholeCamera, Pose};

/// Near clip plane, meters along the optical axis.
pub(super) const NEAR_M: f32 = 0.05;
/// Guard band beyond the image border, pixels. Triangles reaching further
/// out are clipped in the camera frame; the rest are rasterized unclipped.
pub(super) const GUARD_PX: f64 = 8192.0;
/// Fractional bits of the fixed-point screen coordinates.
pub(super) const SUBPIXEL_BITS: u32 = 8;
/// `1 << SUBPIXEL_BITS`.
pub(super) const SUBPIXEL: i64 = 1 << SUBPIXEL_BITS;
/// Projected coordinates are clamped to this many pixels (only reached
/// through float rounding at the guard band; keeps fixed point in range).
const COORD_LIMIT_PX: f64 = 3.0 * GUARD_PX + 8192.0;

/// Outcode bit: behind the near plane (plane 0).
pub(super) const OUT_NEAR: u16 = 1;
/// Outcode bits of the guard-band planes (planes 1..5).
pub(super) const OUT_GUARD: u16 = 0b1_1110;
/// Outcode bits of the view planes (planes 5..9).
pub(super) const OUT_VIEW: u16 = 0b1_1110_0000;
/// Outcode bit: the vertex is not finite in the camera frame.
pub(super) const OUT_INVALID: u16 = 1 << 9;
/// A triangle needs clipping when any vertex has one of these bits.
pub(super) const CLIP_MASK: u16 = OUT_NEAR | OUT_GUARD;
/// A triangle is culled when all its vertices share one of these bits.
pub(super) const CULL_MASK: u16 = OUT_NEAR | OUT_VIEW;
/// Number of planes the polygon clipper uses (near + guard band).
pub(super) const CLIP_PLANES: usize = 5;

/// A mesh vertex in the camera frame, with its outcode and, when it lies in
/// front of the near plane and inside the guard band, its projection.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct CamVertex {
    /// Position in the camera optical frame, meters.
    pub p: [f32; 3],
    /// Fixed-point screen x (`SUBPIXEL_BITS` fraction bits).
    pub sx: i32,
    /// Fixed-point screen y.
    pub sy: i32,
    /// `1 / z`, 1/meters.
    pub inv_z: f32,
    /// Outcode: bit `i` set when the vertex is outside plane `i`.
    pub code: u16,
}

/// The world-to-camera transform and projection of one render.
#[derive(Debug, Clone, Copy)]
pub(super) struct View {
    /// Rotation of `camera_from_world`, row-major.
    rot: [[f32; 3]; 3],
    /// Translation of `camera_from_world`.
    trans: [f32; 3],
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Clip planes `[a, b, c, d]`: near, guard left/right/top/bottom, view
    /// left/right/top/bottom.
    pub planes: [[f32; 4]; 9],
}

impl View {
    /// The view of `camera` (distortion ignored) at `world_from_camera`.
    pub fn new(world_from_camera: &Pose, camera: &PinholeCamera) -> Self {
        let camera_from_world = world_from_camera.inverse();
        let r = camera_from_world.rotation.to_rotation_matrix();
        let m = r.matrix();
        let t = camera_from_world.translation.vector;
        let rot = [
            [m[(0, 0)] as f32, m[(0, 1)] as f32, m[(0, 2)] as f32],
            [m[(1, 0)] as f32, m[(1, 1)] as f32, m[(1, 2)] as f32],
            [m[(2, 0)] as f32, m[(2, 1)] as f32, m[(2, 2)] as f32],
        ];
        let (fx, fy, cx, cy) = (camera.fx, camera.fy, camera.cx, camera.cy);
        let (w, h) = (camera.width as f64, camera.height as f64);
        let g = GUARD_PX;
        // u = fx x / z + cx >= lo  <=>  fx x + (cx - lo) z >= 0 (for z > 0),
        // u <= hi  <=>  -fx x + (hi - cx) z >= 0; likewise for v.
        let side = |lo_u: f64, hi_u: f64, lo_v: f64, hi_v: f64| {
            [
                [fx as f32, 0.0, (cx - lo_u) as f32, 0.0],
                [-fx as f32, 0.0, (hi_u - cx) as f32, 0.0],
                [0.0, fy as f32, (cy - lo_v) as f32, 0.0],
                [0.0, -fy as f32, (hi_v - cy) as f32, 0.0],
            ]
        };
        let guard = side(-g, w - 1.0 + g, -g, h - 1.0 + g);
        // One pixel of margin beyond the outermost pixel centers.
        let view = side(-1.0, w, -1.0, h);
        let near = [0.0, 0.0, 1.0, -NEAR_M];
        Self {
            rot,
            trans: [t.x as f32, t.y as f32, t.z as f32],
            fx,
            fy,
            cx,
            cy,
            width: camera.width as usize,
            height: camera.height as usize,
            planes: [
                near, guard[0], guard[1], guard[2], guard[3], view[0], view[1], view[2], view[3],
            ],
        }
    }

    /// Signed distance-like value of `p` to plane `i` (negative: outside).
    #[inline]
    pub fn plane_value(&self, i: usize, p: [f32; 3]) -> f32 {
        let q = self.planes[i];
        q[0] * p[0] + q[1] * p[1] + q[2] * p[2] + q[3]
    }

    /// Transforms a world point into the camera frame and classifies it.
    #[inline]
    pub fn vertex(&self, p_world: [f32; 3]) -> CamVertex {
        let r = &self.rot;
        let p = [
            r[0][0] * p_world[0] + r[0][1] * p_world[1] + r[0][2] * p_world[2] + self.trans[0],
            r[1][0] * p_world[0] + r[1][1] * p_world[1] + r[1][2] * p_world[2] + self.trans[1],
            r[2][0] * p_world[0] + r[2][1] * p_world[1] + r[2][2] * p_world[2] + self.trans[2],
        ];
        if !(p[0].is_finite() && p[1].is_finite() && p[2].is_finite()) {
            return CamVertex {
                code: OUT_INVALID,
                ..CamVertex::default()
            };
        }
        let mut code = 0u16;
        for i in 0..self.planes.len() {
            code |= u16::from(self.plane_value(i, p) < 0.0) << i;
        }
        let (sx, sy, inv_z) = if code & CLIP_MASK == 0 {
            self.project(p)
        } else {
            (0, 0, 0.0)
        };
        CamVertex {
            p,
            sx,
            sy,
            inv_z,
            code,
        }
    }

    /// Projects a camera-frame point in front of the near plane to
    /// fixed-point screen coordinates and `1/z`. The single projection used
    /// for every vertex, so shared vertices snap identically.
    #[inline]
    pub fn project(&self, p: [f32; 3]) -> (i32, i32, f32) {
        let inv_z = 1.0 / f64::from(p[2]);
        let u =
            (self.fx * f64::from(p[0]) * inv_z + self.cx).clamp(-COORD_LIMIT_PX, COORD_LIMIT_PX);
        let v =
            (self.fy * f64::from(p[1]) * inv_z + self.cy).clamp(-COORD_LIMIT_PX, COORD_LIMIT_PX);
        let s = SUBPIXEL as f64;
        (
            floor_i64(u * s + 0.5) as i32,
            floor_i64(v * s + 0.5) as i32,
            inv_z as f32,
        )
    }
}

/// `floor(x)` as an integer, without a libm call (saturating for huge `x`).
#[inline]
pub(super) fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    i - i64::from((i as f64) > x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_matches_std() {
        for x in [-2.5, -2.0, -0.1, 0.0, 0.3, 1.0, 7.9, 1e10, -1e10] {
            assert_eq!(floor_i64(x), x.floor() as i64, "x = {x}");
        }
    }

    #[test]
    fn outcodes_follow_the_planes() {
        let cam = PinholeCamera::new(640, 480, 400.0, 400.0, 319.5, 239.5);
        let view = View::new(&Pose::identity(), &cam);
        let center = view.vertex([0.0, 0.0, 2.0]);
        assert_eq!(center.code, 0);
        assert_eq!(center.sx, (319.5 * 256.0) as i32);
        assert_eq!(view.vertex([0.0, 0.0, 0.01]).code & OUT_NEAR, OUT_NEAR);
        // Far to the left: outside the left view plane, inside the guard band.
        let left = view.vertex([-2.0, 0.0, 1.0]);
        assert_eq!(left.code, 1 << 5);
        // Very far to the left: outside the guard band too.
        let far_left = view.vertex([-100.0, 0.0, 1.0]);
        assert_eq!(far_left.code, (1 << 5) | (1 << 1));
        // Behind the camera: outside near, and left of center flips sides.
        let behind = view.vertex([0.0, 0.0, -1.0]);
        assert_ne!(behind.code & OUT_NEAR, 0);
    }
}
