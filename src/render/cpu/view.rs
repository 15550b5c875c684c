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
//!
//! The pose (`f64`, nalgebra) becomes an `f32` [`Affine3A`] once per render;
//! vertices are transformed as [`Vec3A`] (SIMD lanes). Projection to pixels
//! stays scalar `f64`, as the fixed-point snapping needs.

use glam::{Affine3A, Mat4, Vec3A, Vec4};

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
pub(super) const OUT_NEAR: u32 = 1;
/// Outcode bits of the guard-band planes (planes 1..5).
pub(super) const OUT_GUARD: u32 = 0b1_1110;
/// Outcode bits of the view planes (planes 5..9).
pub(super) const OUT_VIEW: u32 = 0b1_1110_0000;
/// Outcode bit: the vertex is not finite in the camera frame.
pub(super) const OUT_INVALID: u32 = 1 << 9;
/// A triangle needs clipping when any vertex has one of these bits.
pub(super) const CLIP_MASK: u32 = OUT_NEAR | OUT_GUARD;
/// A triangle is culled when all its vertices share one of these bits.
pub(super) const CULL_MASK: u32 = OUT_NEAR | OUT_VIEW;
/// Number of planes the polygon clipper uses (near + guard band).
pub(super) const CLIP_PLANES: usize = 5;

/// A mesh vertex's outcode and, when it lies in front of the near plane and
/// inside the guard band, its projection. (16 bytes: the setup stage reads
/// three per triangle; the rare clipped triangle recomputes the camera-frame
/// positions with [`View::camera_point`].)
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct CamVertex {
    /// Fixed-point screen x (`SUBPIXEL_BITS` fraction bits).
    pub sx: i32,
    /// Fixed-point screen y.
    pub sy: i32,
    /// `1 / z`, 1/meters.
    pub inv_z: f32,
    /// Outcode: bit `i` set when the vertex is outside plane `i`.
    pub code: u32,
}

/// The world-to-camera transform and projection of one render.
#[derive(Debug, Clone, Copy)]
pub(super) struct View {
    /// `camera_from_world`, rounded to `f32` once per render.
    camera_from_world: Affine3A,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Smallest `1/z` a pixel may have (`1/far`, as `f32`): deeper pixels
    /// are not drawn. 0 without a far limit.
    pub min_inv_z: f32,
    /// Whether triangles clockwise on the image (back faces, with
    /// counter-clockwise fronts) are dropped at setup.
    pub cull_back_faces: bool,
    /// The camera's position, world frame, meters.
    pub eye_m: [f64; 3],
    /// Clip planes `(a, b, c, d)` as `x y z w`: near, guard
    /// left/right/top/bottom, view left/right/top/bottom.
    pub planes: [Vec4; 9],
    /// The planes 1..9 as pixel bounds for points in front of the near
    /// plane: guard `u_min u_max v_min v_max`, then view likewise.
    bounds: [f64; 8],
}

impl View {
    /// The view of `camera` (distortion ignored) at `world_from_camera`.
    pub fn new(world_from_camera: &Pose, camera: &PinholeCamera) -> Self {
        let camera_from_world = world_from_camera.inverse().to_homogeneous();
        let camera_from_world = Affine3A::from_mat4(Mat4::from_cols_array_2d(
            &camera_from_world.cast::<f32>().into(),
        ));
        let (fx, fy, cx, cy) = (camera.fx, camera.fy, camera.cx, camera.cy);
        let (w, h) = (camera.width as f64, camera.height as f64);
        let g = GUARD_PX;
        // u = fx x / z + cx >= lo  <=>  fx x + (cx - lo) z >= 0 (for z > 0),
        // u <= hi  <=>  -fx x + (hi - cx) z >= 0; likewise for v.
        let side = |lo_u: f64, hi_u: f64, lo_v: f64, hi_v: f64| {
            [
                Vec4::new(fx as f32, 0.0, (cx - lo_u) as f32, 0.0),
                Vec4::new(-fx as f32, 0.0, (hi_u - cx) as f32, 0.0),
                Vec4::new(0.0, fy as f32, (cy - lo_v) as f32, 0.0),
                Vec4::new(0.0, -fy as f32, (hi_v - cy) as f32, 0.0),
            ]
        };
        let guard = side(-g, w - 1.0 + g, -g, h - 1.0 + g);
        // One pixel of margin beyond the outermost pixel centers.
        let view = side(-1.0, w, -1.0, h);
        let near = Vec4::new(0.0, 0.0, 1.0, -NEAR_M);
        Self {
            camera_from_world,
            fx,
            fy,
            cx,
            cy,
            width: camera.width as usize,
            height: camera.height as usize,
            min_inv_z: 0.0,
            cull_back_faces: false,
            eye_m: world_from_camera.translation.vector.into(),
            planes: [
                near, guard[0], guard[1], guard[2], guard[3], view[0], view[1], view[2], view[3],
            ],
            bounds: [-g, w - 1.0 + g, -g, h - 1.0 + g, -1.0, w, -1.0, h],
        }
    }

    /// This view with pixels deeper than `far_m` left undrawn (`None`: no
    /// limit).
    pub fn with_far(mut self, far_m: Option<f64>) -> Self {
        self.min_inv_z = far_m.map_or(0.0, |f| (1.0 / f) as f32);
        self
    }

    /// This view with back faces culled when `on`.
    pub fn with_back_faces_culled(mut self, on: bool) -> Self {
        self.cull_back_faces = on;
        self
    }

    /// Pixel coordinates of a camera-frame point in front of the camera,
    /// `f32` (for conservative screen rectangles, not for rasterization).
    pub fn pixel_f32(&self, p: Vec3A) -> (f32, f32) {
        let (x, y, z) = (f64::from(p.x), f64::from(p.y), f64::from(p.z));
        (
            (self.fx * x / z + self.cx) as f32,
            (self.fy * y / z + self.cy) as f32,
        )
    }

    /// Signed distance-like value of `p` to plane `i` (negative: outside).
    #[inline]
    pub fn plane_value(&self, i: usize, p: Vec3A) -> f32 {
        let q = self.planes[i];
        Vec3A::from_vec4(q).dot(p) + q.w
    }

    /// A world point in the camera frame (f32, bit-identical on every call).
    #[inline]
    pub fn camera_point(&self, p_world: [f32; 3]) -> Vec3A {
        self.camera_from_world
            .transform_point3a(Vec3A::from_array(p_world))
    }

    /// Transforms a world point into the camera frame and classifies it.
    #[inline]
    pub fn vertex(&self, p_world: [f32; 3]) -> CamVertex {
        let p = self.camera_point(p_world);
        if !p.is_finite() {
            return CamVertex {
                code: OUT_INVALID,
                ..CamVertex::default()
            };
        }
        if p.z < NEAR_M {
            // Behind the near plane: the plane tests, in homogeneous form,
            // are valid for any z (also behind the camera).
            let mut code = 0u32;
            for i in 0..self.planes.len() {
                code |= u32::from(self.plane_value(i, p) < 0.0) << i;
            }
            return CamVertex {
                code,
                ..CamVertex::default()
            };
        }
        // In front: the same tests on the projected pixel, which is needed
        // anyway (cheaper than eight plane evaluations).
        let inv_z = 1.0 / f64::from(p.z);
        let u = self.fx * f64::from(p.x) * inv_z + self.cx;
        let v = self.fy * f64::from(p.y) * inv_z + self.cy;
        let b = &self.bounds;
        let code = u32::from(u < b[0]) << 1
            | u32::from(u > b[1]) << 2
            | u32::from(v < b[2]) << 3
            | u32::from(v > b[3]) << 4
            | u32::from(u < b[4]) << 5
            | u32::from(u > b[5]) << 6
            | u32::from(v < b[6]) << 7
            | u32::from(v > b[7]) << 8;
        let (sx, sy) = if code & CLIP_MASK == 0 {
            (to_fixed(u), to_fixed(v))
        } else {
            (0, 0)
        };
        CamVertex {
            sx,
            sy,
            inv_z: inv_z as f32,
            code,
        }
    }

    /// Projects a camera-frame point in front of the near plane to
    /// fixed-point screen coordinates and `1/z`. The single projection used
    /// for every vertex, so shared vertices snap identically.
    #[inline]
    pub fn project(&self, p: Vec3A) -> (i32, i32, f32) {
        let inv_z = 1.0 / f64::from(p.z);
        let u = self.fx * f64::from(p.x) * inv_z + self.cx;
        let v = self.fy * f64::from(p.y) * inv_z + self.cy;
        (to_fixed(u), to_fixed(v), inv_z as f32)
    }
}

impl crate::render::tiles::BoxProjection for View {
    fn camera_point(&self, p_world: [f32; 3]) -> Vec3A {
        View::camera_point(self, p_world)
    }

    fn pixel_f32(&self, p: Vec3A) -> (f32, f32) {
        View::pixel_f32(self, p)
    }

    fn size_px(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn near_m(&self) -> f32 {
        NEAR_M
    }
}

/// A pixel coordinate in fixed point, rounded to nearest, clamped to
/// `±COORD_LIMIT_PX` (only reached through float rounding at the guard band).
#[inline]
fn to_fixed(coord_px: f64) -> i32 {
    let c = coord_px.clamp(-COORD_LIMIT_PX, COORD_LIMIT_PX) * SUBPIXEL as f64;
    // Shifted positive, truncation is floor: floor(c + 0.5) rounds.
    ((c + (0.5 + FIXED_OFFSET)) as i64 - FIXED_OFFSET as i64) as i32
}

/// Offset making every clamped fixed-point coordinate positive.
const FIXED_OFFSET: f64 = (1u64 << 32) as f64;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_point_rounds_to_nearest_and_clamps() {
        let s = SUBPIXEL as f64;
        for px in [-2.5, -2.0, -0.1, 0.0, 0.3, 1.0, 7.9, 1000.123] {
            assert_eq!(to_fixed(px) as f64, (px * s).round(), "px = {px}");
        }
        assert_eq!(to_fixed(-1.0 / s * 0.5), 0, "ties round up");
        assert_eq!(to_fixed(1e12) as f64, COORD_LIMIT_PX * s);
        assert_eq!(to_fixed(-1e12) as f64, -COORD_LIMIT_PX * s);
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
