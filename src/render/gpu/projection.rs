//! The projection the wgpu renderer uses: the paper's eqs. 7-9 (pinhole
//! intrinsics as an OpenGL projection) adapted to wgpu's conventions.
//!
//! Takes pinhole intrinsics and a pose; gives out `clip_from_world`, the
//! 4x4 matrix the vertex shader applies. Conventions handled here:
//! - `star` puts pixel centers at integer coordinates; wgpu puts fragment
//!   centers at `+0.5` in framebuffer coordinates. Image coordinate `u`
//!   therefore lies at framebuffer `x = u + 0.5`, so the principal point
//!   shifts by half a pixel.
//! - wgpu NDC has y up and framebuffer y down, while the camera optical
//!   frame has y down: the y row is negated.
//! - Depth is reversed: without a far limit `z_ndc = near / z_camera`, in
//!   `[0, 1]` for `z_camera >= near`, compared with `Greater` and cleared to
//!   0. Depth32Float keeps nearly constant relative precision this way.
//!   With a far limit `z_ndc = (near / z - near / far) / (1 - near / far)`:
//!   1 at the near plane, 0 at the far plane, and the hardware clips what
//!   lies beyond it.
//! - `w_clip = z_camera`, so the shader takes the metric depth it writes to
//!   the R32Float target straight from `clip.w`.
//!
//! The matrix is composed in `f64` (nalgebra, as the pose is) and converted
//! once to the `f32` [`glam::Mat4`] of [`ViewUniform`], the bytes the vertex
//! shader reads.

use bytemuck::{Pod, Zeroable};
use glam::Mat4;
use nalgebra::Matrix4;

use crate::geometry::{PinholeCamera, Pose};

/// Near clipping plane, meters: surfaces closer than this are not drawn.
pub const NEAR_M: f64 = 0.05;

/// `clip_from_camera` for `camera` (distortion ignored) and near plane
/// `near_m`. Columns act on `[x, y, z, 1]` in the camera optical frame.
pub fn clip_from_camera(camera: &PinholeCamera, near_m: f64) -> Matrix4<f64> {
    clip_from_camera_far(camera, near_m, None)
}

/// [`clip_from_camera`] with the far plane at `far_m` (`None`: none).
pub fn clip_from_camera_far(
    camera: &PinholeCamera,
    near_m: f64,
    far_m: Option<f64>,
) -> Matrix4<f64> {
    // z_ndc = a + b / z: a + b / near = 1 and a + b / far = 0.
    let (a, b) = match far_m {
        Some(far_m) if far_m > near_m => {
            let span = far_m - near_m;
            (-near_m / span, near_m * far_m / span)
        }
        _ => (0.0, near_m),
    };
    let w = f64::from(camera.width);
    let h = f64::from(camera.height);
    #[rustfmt::skip]
    let m = Matrix4::new(
        2.0 * camera.fx / w, 0.0,                  2.0 * (camera.cx + 0.5) / w - 1.0, 0.0,
        0.0,                 -2.0 * camera.fy / h, 1.0 - 2.0 * (camera.cy + 0.5) / h, 0.0,
        0.0,                 0.0,                  a,                                 b,
        0.0,                 0.0,                  1.0,                               0.0,
    );
    m
}

/// The `View` uniform of `shaders/mesh.wgsl` (group 0, binding 0), byte
/// for byte: one `mat4x4<f32>`, column-major, 64 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct ViewUniform {
    /// `clip_from_world`: world point `[x, y, z, 1]` to clip space.
    pub clip_from_world: Mat4,
}

/// Size of [`ViewUniform`] in bytes, as the bind group layout declares it.
pub const VIEW_UNIFORM_BYTES: u64 = std::mem::size_of::<ViewUniform>() as u64;
const _: () = assert!(VIEW_UNIFORM_BYTES == 64, "WGSL `View` is one mat4x4<f32>");

impl ViewUniform {
    /// The uniform for a camera at `world_from_camera`, with the far
    /// plane at `far_m` (`None`: none).
    pub fn new(
        world_from_camera: &Pose,
        camera: &PinholeCamera,
        near_m: f64,
        far_m: Option<f64>,
    ) -> Self {
        let camera_from_world = world_from_camera.inverse().to_homogeneous();
        let m = clip_from_camera_far(camera, near_m, far_m) * camera_from_world;
        Self {
            clip_from_world: Mat4::from_cols_array_2d(&m.cast::<f32>().into()),
        }
    }
}

/// `clip_from_world` for a camera at `world_from_camera`: composed in `f64`,
/// then rounded once to `f32`.
pub fn clip_from_world(world_from_camera: &Pose, camera: &PinholeCamera, near_m: f64) -> Mat4 {
    let camera_from_world = world_from_camera.inverse().to_homogeneous();
    let m = clip_from_camera(camera, near_m) * camera_from_world;
    Mat4::from_cols_array_2d(&m.cast::<f32>().into())
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3, Vector4};

    /// Framebuffer position (wgpu: origin top-left, y down, fragment centers
    /// at +0.5) and NDC depth of a clip-space point.
    fn to_framebuffer(clip: Vector4<f64>, camera: &PinholeCamera) -> (f64, f64, f64) {
        let ndc = clip.xyz() / clip.w;
        let x = (ndc.x + 1.0) * 0.5 * f64::from(camera.width);
        let y = (1.0 - ndc.y) * 0.5 * f64::from(camera.height);
        (x, y, ndc.z)
    }

    #[test]
    fn matches_pinhole_projection_with_half_pixel_shift() {
        let camera = PinholeCamera::new(640, 512, 420.0, 410.0, 319.5, 255.5);
        let m = clip_from_camera(&camera, NEAR_M);
        for p in [
            Vector3::new(0.0, 0.0, 2.0),
            Vector3::new(0.7, -0.3, 1.5),
            Vector3::new(-1.2, 0.9, 3.0),
        ] {
            let (x, y, z) = to_framebuffer(m * p.push(1.0), &camera);
            let uv = camera.project(&p).expect("in front");
            // Fragment (x, y) has its center at +0.5: image coordinate = x - 0.5.
            assert!((x - 0.5 - uv.x).abs() < 1e-9, "{x} vs {}", uv.x);
            assert!((y - 0.5 - uv.y).abs() < 1e-9, "{y} vs {}", uv.y);
            assert!((z - NEAR_M / p.z).abs() < 1e-12);
            assert!((m * p.push(1.0)).w == p.z, "w_clip is metric depth");
        }
    }

    #[test]
    fn principal_point_lands_on_its_pixel_center() {
        // cx = 319.5 is the geometric image center; cx = 100 must be the
        // center of fragment column 100 (framebuffer x = 100.5).
        let camera = PinholeCamera::new(640, 512, 400.0, 400.0, 100.0, 50.0);
        let m = clip_from_camera(&camera, NEAR_M);
        let (x, y, _) = to_framebuffer(m * Vector4::new(0.0, 0.0, 1.0, 1.0), &camera);
        assert!((x - 100.5).abs() < 1e-12 && (y - 50.5).abs() < 1e-12);
    }

    #[test]
    fn depth_is_reversed_and_clips_at_near() {
        let camera = PinholeCamera::new(64, 64, 50.0, 50.0, 31.5, 31.5);
        let m = clip_from_camera(&camera, NEAR_M);
        let near = m * Vector4::new(0.0, 0.0, NEAR_M, 1.0);
        let far = m * Vector4::new(0.0, 0.0, 1e6, 1.0);
        assert!(
            (near.z / near.w - 1.0).abs() < 1e-12,
            "near plane at depth 1"
        );
        assert!(
            far.z / far.w > 0.0 && far.z / far.w < 1e-6,
            "far tends to 0"
        );
        let behind = m * Vector4::new(0.0, 0.0, NEAR_M * 0.5, 1.0);
        assert!(
            behind.z > behind.w,
            "closer than near is clipped (z_clip > w_clip)"
        );
    }

    #[test]
    fn far_limit_maps_near_to_one_far_to_zero_and_clips_beyond() {
        let camera = PinholeCamera::new(64, 64, 50.0, 50.0, 31.5, 31.5);
        let m = clip_from_camera_far(&camera, NEAR_M, Some(30.0));
        let ndc_z = |z: f64| {
            let c = m * Vector4::new(0.0, 0.0, z, 1.0);
            c.z / c.w
        };
        assert!((ndc_z(NEAR_M) - 1.0).abs() < 1e-12);
        assert!(ndc_z(30.0).abs() < 1e-12);
        assert!(ndc_z(30.1) < 0.0, "beyond far is clipped (z_ndc < 0)");
        assert!(ndc_z(2.0) > ndc_z(3.0), "still reversed");
        assert_eq!(
            clip_from_camera_far(&camera, NEAR_M, None),
            clip_from_camera(&camera, NEAR_M)
        );
    }

    #[test]
    fn world_matrix_composes_inverse_pose() {
        let camera = PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
        let world_from_camera = Pose::from_parts(
            Translation3::new(1.0, -2.0, 0.5),
            UnitQuaternion::from_euler_angles(0.1, -0.4, 0.3),
        );
        let p_camera = Vector3::new(0.2, 0.1, 2.5);
        let p_world = world_from_camera * nalgebra::Point3::from(p_camera);
        let m = clip_from_world(&world_from_camera, &camera, NEAR_M);
        let m = Matrix4::from_column_slice(&m.to_cols_array().map(f64::from));
        let clip = m * p_world.to_homogeneous();
        assert!((clip.w - p_camera.z).abs() < 1e-5);
        let (x, _, _) = to_framebuffer(clip, &camera);
        let uv = camera.project(&p_camera).expect("in front");
        assert!((x - 0.5 - uv.x).abs() < 1e-3);
    }
}
