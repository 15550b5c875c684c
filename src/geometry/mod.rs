//! Geometry: rigid transforms on SE(3), the pinhole camera with
//! radial-tangential distortion, and the frame conventions every other module
//! relies on.
//!
//! Conventions (DESIGN.md "Conventions"):
//! - World frame `W` is the mesh file's own frame, in meters.
//! - Camera optical frame `C`: x right, y down, z forward.
//! - A pose is `world_from_camera` (`T_wc`), so `world_from_camera * p_camera`
//!   is a world point. This is the TUM trajectory convention.
//! - Pixel centers are at integer coordinates: pixel `(u, v)` covers
//!   `[u - 0.5, u + 0.5] x [v - 0.5, v + 0.5]`. The renderers sample at pixel
//!   centers, and the tracker's bilinear sampling uses the same convention.

pub mod camera;
pub mod look;
pub mod se3;
pub mod transform;

pub use camera::{
    CameraError, Distortion, PinholeCamera, UndistortMap, MAX_RADIAL_COEFFICIENT,
    MAX_TANGENTIAL_COEFFICIENT,
};
pub use se3::{adjoint, exp_se3, hat, log_se3, renormalized, Pose};
pub use transform::TransformConfig;
