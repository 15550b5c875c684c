//! The pinhole camera with radial-tangential (Brown-Conrady, OpenCV
//! `k1 k2 p1 p2 k3`) distortion: projection, unprojection, pyramid scaling and
//! the undistortion map that turns a raw camera frame into the ideal pinhole
//! image the tracker aligns against the rendered keyframe.
//!
//! Pixel centers are at integer coordinates (see [`crate::geometry`]).

use nalgebra::{Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// Errors in camera parameters.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CameraError {
    /// A parameter is not finite or out of its valid range.
    #[error("camera parameter `{name}` = {value} is invalid: {reason}")]
    InvalidParameter {
        /// Parameter name as in `camera.toml`.
        name: &'static str,
        /// The value found.
        value: f64,
        /// What was expected.
        reason: &'static str,
    },
}

/// Largest magnitude accepted for a radial coefficient (`k1`, `k2`, `k3`).
/// Calibrations of real lenses in the OpenCV 5-coefficient model stay
/// within a few units; beyond 100 the value is a typo or a unit mix-up.
pub const MAX_RADIAL_COEFFICIENT: f64 = 100.0;
/// Largest magnitude accepted for a tangential coefficient (`p1`, `p2`):
/// real lenses stay below 0.01; 1 would be a lens tilted beyond use.
pub const MAX_TANGENTIAL_COEFFICIENT: f64 = 1.0;
const RADIAL_REASON: &str = "expected a finite radial coefficient within -100..=100";
const TANGENTIAL_REASON: &str = "expected a finite tangential coefficient within -1..=1";

/// Radial-tangential distortion coefficients in OpenCV order.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Distortion {
    /// Radial r^2 coefficient.
    #[serde(default)]
    pub k1: f64,
    /// Radial r^4 coefficient.
    #[serde(default)]
    pub k2: f64,
    /// Tangential coefficient 1.
    #[serde(default)]
    pub p1: f64,
    /// Tangential coefficient 2.
    #[serde(default)]
    pub p2: f64,
    /// Radial r^6 coefficient.
    #[serde(default)]
    pub k3: f64,
}

impl Distortion {
    /// True when all coefficients are zero.
    pub fn is_zero(&self) -> bool {
        self.k1 == 0.0 && self.k2 == 0.0 && self.p1 == 0.0 && self.p2 == 0.0 && self.k3 == 0.0
    }

    /// Distorts normalized image coordinates `(x, y) = (X/Z, Y/Z)`.
    pub fn distort(&self, xn: Vector2<f64>) -> Vector2<f64> {
        let (x, y) = (xn.x, xn.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let dx = 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let dy = self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        Vector2::new(x * radial + dx, y * radial + dy)
    }

    /// Inverts [`Distortion::distort`] by Gauss-Newton on the 2x2 system.
    /// Returns `None` when it does not converge (far outside the valid
    /// field of view of the model).
    pub fn undistort(&self, xd: Vector2<f64>) -> Option<Vector2<f64>> {
        if self.is_zero() {
            return Some(xd);
        }
        let mut x = xd;
        for _ in 0..20 {
            let f = self.distort(x) - xd;
            if f.norm_squared() < 1e-24 {
                return Some(x);
            }
            // Numerical Jacobian is enough here: this runs at start-up
            // (undistortion map) and on a few points, never per pixel per frame.
            let h = 1e-7;
            let jx = (self.distort(x + Vector2::new(h, 0.0)) - self.distort(x)) / h;
            let jy = (self.distort(x + Vector2::new(0.0, h)) - self.distort(x)) / h;
            let det = jx.x * jy.y - jy.x * jx.y;
            if det.abs() < 1e-12 || !det.is_finite() {
                return None;
            }
            let step = Vector2::new(
                (jy.y * f.x - jy.x * f.y) / det,
                (-jx.y * f.x + jx.x * f.y) / det,
            );
            x -= step;
        }
        let residual = (self.distort(x) - xd).norm();
        (residual < 1e-9).then_some(x)
    }
}

/// A pinhole camera, optionally with lens distortion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PinholeCamera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels (pixel centers at integers).
    pub cx: f64,
    /// Principal point y, pixels (pixel centers at integers).
    pub cy: f64,
    /// Lens distortion; zero for an ideal pinhole.
    #[serde(default)]
    pub distortion: Distortion,
}

impl PinholeCamera {
    /// An ideal pinhole camera (no distortion).
    pub fn new(width: u32, height: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Self {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion: Distortion::default(),
        }
    }

    /// Checks that every parameter is finite and in range.
    pub fn validate(&self) -> Result<(), CameraError> {
        let bad = |name, value: f64, reason| {
            Err(CameraError::InvalidParameter {
                name,
                value,
                reason,
            })
        };
        if self.width == 0 || self.width > 8192 {
            return bad("width", self.width as f64, "expected 1..=8192 pixels");
        }
        if self.height == 0 || self.height > 8192 {
            return bad("height", self.height as f64, "expected 1..=8192 pixels");
        }
        for (name, v) in [("fx", self.fx), ("fy", self.fy)] {
            if !v.is_finite() || v <= 0.0 {
                return bad(name, v, "expected a finite focal length > 0");
            }
        }
        for (name, v, max) in [
            ("cx", self.cx, self.width as f64),
            ("cy", self.cy, self.height as f64),
        ] {
            if !v.is_finite() || v < -0.5 || v > max - 0.5 {
                return bad(name, v, "principal point must lie inside the image");
            }
        }
        let d = &self.distortion;
        for (name, v, bound, reason) in [
            ("distortion.k1", d.k1, MAX_RADIAL_COEFFICIENT, RADIAL_REASON),
            ("distortion.k2", d.k2, MAX_RADIAL_COEFFICIENT, RADIAL_REASON),
            (
                "distortion.p1",
                d.p1,
                MAX_TANGENTIAL_COEFFICIENT,
                TANGENTIAL_REASON,
            ),
            (
                "distortion.p2",
                d.p2,
                MAX_TANGENTIAL_COEFFICIENT,
                TANGENTIAL_REASON,
            ),
            ("distortion.k3", d.k3, MAX_RADIAL_COEFFICIENT, RADIAL_REASON),
        ] {
            if !(v.is_finite() && v.abs() <= bound) {
                return bad(name, v, reason);
            }
        }
        Ok(())
    }

    /// The same camera without distortion: the model of the undistorted
    /// image and of rendered keyframes.
    pub fn pinhole(&self) -> Self {
        Self {
            distortion: Distortion::default(),
            ..*self
        }
    }

    /// The camera for pyramid level `level` (each level halves the size).
    /// With pixel centers at integers, `c' = (c + 0.5) / 2 - 0.5`.
    pub fn scaled_to_level(&self, level: u32) -> Self {
        let s = 0.5f64.powi(level as i32);
        Self {
            width: (self.width >> level).max(1),
            height: (self.height >> level).max(1),
            fx: self.fx * s,
            fy: self.fy * s,
            cx: (self.cx + 0.5) * s - 0.5,
            cy: (self.cy + 0.5) * s - 0.5,
            distortion: self.distortion,
        }
    }

    /// True when the pixel coordinate lies inside the image
    /// (within `margin` pixels of the outermost pixel centers).
    pub fn contains(&self, uv: Vector2<f64>, margin: f64) -> bool {
        uv.x >= margin
            && uv.y >= margin
            && uv.x <= self.width as f64 - 1.0 - margin
            && uv.y <= self.height as f64 - 1.0 - margin
    }

    /// Projects a point in the camera optical frame to a pixel, applying
    /// distortion. `None` for points at or behind the camera.
    pub fn project(&self, p_camera: &Vector3<f64>) -> Option<Vector2<f64>> {
        if !(p_camera.z > 1e-9) {
            return None;
        }
        let xn = Vector2::new(p_camera.x / p_camera.z, p_camera.y / p_camera.z);
        let xd = self.distortion.distort(xn);
        Some(Vector2::new(
            self.fx * xd.x + self.cx,
            self.fy * xd.y + self.cy,
        ))
    }

    /// Back-projects pixel `uv` at depth `depth_m` (the z coordinate, not the
    /// ray length) into the camera optical frame, removing distortion.
    pub fn unproject(&self, uv: Vector2<f64>, depth_m: f64) -> Option<Vector3<f64>> {
        let xd = Vector2::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy);
        let xn = self.distortion.undistort(xd)?;
        Some(Vector3::new(xn.x * depth_m, xn.y * depth_m, depth_m))
    }

    /// Builds the map from each pixel of the undistorted (pinhole) image to
    /// its source position in the distorted camera image.
    pub fn undistort_map(&self) -> UndistortMap {
        let n = self.width as usize * self.height as usize;
        let mut src_xy = Vec::with_capacity(n);
        for v in 0..self.height {
            for u in 0..self.width {
                let xn = Vector2::new(
                    (u as f64 - self.cx) / self.fx,
                    (v as f64 - self.cy) / self.fy,
                );
                let xd = self.distortion.distort(xn);
                src_xy.push([
                    (self.fx * xd.x + self.cx) as f32,
                    (self.fy * xd.y + self.cy) as f32,
                ]);
            }
        }
        UndistortMap {
            width: self.width as usize,
            height: self.height as usize,
            src_xy,
            identity: self.distortion.is_zero(),
        }
    }
}

/// For every pixel of the undistorted image, where to sample the raw image.
/// Built once at start-up; applying it allocates nothing.
#[derive(Debug, Clone)]
pub struct UndistortMap {
    /// Width of both images.
    pub width: usize,
    /// Height of both images.
    pub height: usize,
    /// Source coordinates `[x, y]` in the distorted image, row-major.
    pub src_xy: Vec<[f32; 2]>,
    /// True when the camera has no distortion and the map is the identity.
    pub identity: bool,
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn camera_with_distortion() -> PinholeCamera {
        PinholeCamera {
            distortion: Distortion {
                k1: -0.28,
                k2: 0.07,
                p1: 0.0008,
                p2: -0.0005,
                k3: 0.0,
            },
            ..PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5)
        }
    }

    proptest! {
        #[test]
        fn project_unproject_roundtrip(u in 0.0..639.0f64, v in 0.0..511.0f64, d in 0.2..30.0f64) {
            for cam in [camera_with_distortion(), camera_with_distortion().pinhole()] {
                let p = cam.unproject(Vector2::new(u, v), d).expect("inside the image the model inverts");
                prop_assert!((p.z - d).abs() < 1e-12);
                let back = cam.project(&p).expect("in front of the camera");
                prop_assert!((back - Vector2::new(u, v)).norm() < 1e-6, "{u} {v} -> {back:?}");
            }
        }
    }

    #[test]
    fn principal_point_projects_optical_axis() {
        let cam = camera_with_distortion();
        let uv = cam.project(&Vector3::new(0.0, 0.0, 3.0)).expect("in front");
        assert!((uv - Vector2::new(cam.cx, cam.cy)).norm() < 1e-12);
        // x right, y down: a point to the right and below lands right and below.
        let uv = cam
            .pinhole()
            .project(&Vector3::new(1.0, 0.5, 2.0))
            .expect("in front");
        assert!((uv.x - (319.5 + 210.0)).abs() < 1e-12);
        assert!((uv.y - (255.5 + 105.0)).abs() < 1e-12);
    }

    #[test]
    fn behind_camera_is_rejected() {
        let cam = camera_with_distortion();
        assert!(cam.project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
        assert!(cam.project(&Vector3::new(1.0, 0.0, 0.0)).is_none());
        assert!(cam
            .project(&Vector3::new(f64::NAN, 0.0, 1.0))
            .is_some_and(|uv| uv.x.is_nan()));
        assert!(cam.project(&Vector3::new(0.0, 0.0, f64::NAN)).is_none());
    }

    #[test]
    fn pyramid_scaling_keeps_pixel_centers() {
        let cam = PinholeCamera::new(640, 512, 400.0, 400.0, 319.5, 255.5);
        let l1 = cam.scaled_to_level(1);
        assert_eq!((l1.width, l1.height), (320, 256));
        assert!((l1.cx - 159.5).abs() < 1e-12 && (l1.cy - 127.5).abs() < 1e-12);
        let p = Vector3::new(0.3, -0.2, 2.0);
        let uv0 = cam.project(&p).expect("in front");
        let uv1 = l1.project(&p).expect("in front");
        // level-1 pixel x covers level-0 pixels 2x and 2x+1, centered at 2x + 0.5.
        assert!(((uv1.x * 2.0 + 0.5) - uv0.x).abs() < 1e-9);
        assert!(((uv1.y * 2.0 + 0.5) - uv0.y).abs() < 1e-9);
    }

    #[test]
    fn undistort_map_inverts_distortion() {
        let cam = camera_with_distortion();
        let map = cam.undistort_map();
        assert!(!map.identity);
        // A point projected with the pinhole model at (u, v) appears in the raw
        // image at map[v][u].
        let p = Vector3::new(-0.4, 0.25, 1.7);
        let uv_ideal = cam.pinhole().project(&p).expect("in front");
        let uv_raw = cam.project(&p).expect("in front");
        let (u, v) = (uv_ideal.x.round() as usize, uv_ideal.y.round() as usize);
        let src = map.src_xy[v * map.width + u];
        let expect = cam
            .project(
                &cam.pinhole()
                    .unproject(Vector2::new(u as f64, v as f64), 1.0)
                    .expect("ok"),
            )
            .expect("in front");
        assert!((src[0] as f64 - expect.x).abs() < 1e-3 && (src[1] as f64 - expect.y).abs() < 1e-3);
        assert!((uv_raw - expect).norm() < 2.0);
    }

    #[test]
    fn validate_rejects_bad_parameters() {
        let mut cam = camera_with_distortion();
        assert!(cam.validate().is_ok());
        cam.fx = -1.0;
        assert!(matches!(
            cam.validate(),
            Err(CameraError::InvalidParameter { name: "fx", .. })
        ));
        let mut cam = camera_with_distortion();
        cam.cx = 10_000.0;
        assert!(matches!(
            cam.validate(),
            Err(CameraError::InvalidParameter { name: "cx", .. })
        ));
        let mut cam = camera_with_distortion();
        cam.distortion.k2 = f64::NAN;
        assert!(cam.validate().is_err());
        let mut cam = camera_with_distortion();
        cam.width = 0;
        assert!(cam.validate().is_err());
    }
}
