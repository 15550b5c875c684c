//! Image-space lighting of rendered views: a point light shading a gray
//! render by the surface normals estimated from its own depth.
//!
//! Takes a rendered view (gray 0..=255 and metric depth of an ideal pinhole
//! camera), the camera pose and a [`PointLight`]; multiplies every hit pixel
//! by `ambient + diffuse * max(0, n . l) / (1 + (d / falloff)^2)`, where `n`
//! is the unit surface normal (facing the camera), `l` the unit direction to
//! the light and `d` the distance to it. Normals come from the depth image
//! by finite differences, each axis taking the one-sided difference with
//! the smaller depth step so that depth edges do not bend the normals of
//! the surface in front.
//!
//! The scan's frames are lit by one fixed light (the light baked into the
//! map's vertex colors); the flight's frames by another that moves
//! ([`MovingLightSpec`]).

use nalgebra::{Point3, Vector3};
use serde::Serialize;

use crate::geometry::{PinholeCamera, Pose};
use crate::imgproc::ImageF32;

/// How strongly a point light shades a surface.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LightSpec {
    /// Gain of a surface the light does not reach.
    pub ambient: f64,
    /// Added gain of a surface facing the light at zero distance.
    pub diffuse: f64,
    /// Distance at which the diffuse term has fallen to half, meters.
    pub falloff_m: f64,
}

/// A point light at a world position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointLight {
    /// Position, world frame, meters.
    pub position_m: Vector3<f64>,
    /// Shading strength.
    pub spec: LightSpec,
}

/// A light circling the room near the ceiling: the flight's light.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MovingLightSpec {
    /// Shading strength.
    pub light: LightSpec,
    /// Distance below the ceiling, meters.
    pub below_ceiling_m: f64,
    /// Radii of its ellipse around the room center, as a fraction of the
    /// room's half length and half width.
    pub radius_fraction: f64,
    /// Time of one turn, seconds.
    pub period_s: f64,
}

impl MovingLightSpec {
    /// The light at time `t_s` in a room of `room_size_m` (spanning
    /// `0..size`), starting at angle `phase_rad`.
    pub fn at(&self, room_size_m: [f64; 3], phase_rad: f64, t_s: f64) -> PointLight {
        let a = phase_rad + std::f64::consts::TAU * t_s / self.period_s.max(1e-3);
        let [lx, ly, lz] = room_size_m;
        PointLight {
            position_m: Vector3::new(
                0.5 * lx * (1.0 + self.radius_fraction * a.cos()),
                0.5 * ly * (1.0 + self.radius_fraction * a.sin()),
                lz - self.below_ceiling_m,
            ),
            spec: self.light,
        }
    }
}

/// Unit normals (camera frame, facing the camera) of every pixel with depth,
/// `[0, 0, 0]` where there is none. `out` is resized to the image.
pub fn depth_normals(depth_m: &ImageF32, camera: &PinholeCamera, out: &mut Vec<[f32; 3]>) {
    let (w, h) = (depth_m.width(), depth_m.height());
    out.clear();
    out.resize(w * h, [0.0; 3]);
    let (fx, fy, cx, cy) = (
        camera.fx as f32,
        camera.fy as f32,
        camera.cx as f32,
        camera.cy as f32,
    );
    let d = depth_m.data();
    let point = |x: usize, y: usize| -> Option<Vector3<f32>> {
        let z = d[y * w + x];
        (z > 0.0).then(|| Vector3::new((x as f32 - cx) / fx * z, (y as f32 - cy) / fy * z, z))
    };
    // The one-sided difference (toward `a` or from `b`) with the smaller
    // depth step.
    let pick = |p: &Vector3<f32>, a: Option<Vector3<f32>>, b: Option<Vector3<f32>>| match (a, b) {
        (Some(a), Some(b)) => Some(if (a.z - p.z).abs() <= (p.z - b.z).abs() {
            a - p
        } else {
            p - b
        }),
        (Some(a), None) => Some(a - p),
        (None, Some(b)) => Some(p - b),
        (None, None) => None,
    };
    for y in 0..h {
        for x in 0..w {
            let Some(p) = point(x, y) else { continue };
            let right = (x + 1 < w).then(|| point(x + 1, y)).flatten();
            let left = (x > 0).then(|| point(x - 1, y)).flatten();
            let down = (y + 1 < h).then(|| point(x, y + 1)).flatten();
            let up = (y > 0).then(|| point(x, y - 1)).flatten();
            let n = match (pick(&p, right, left), pick(&p, down, up)) {
                (Some(dx), Some(dy)) => dy.cross(&dx),
                _ => -p,
            };
            let n = n.try_normalize(1e-12).unwrap_or_else(|| -p.normalize());
            // Face the camera.
            let n = if n.dot(&p) > 0.0 { -n } else { n };
            out[y * w + x] = [n.x, n.y, n.z];
        }
    }
}

/// Multiplies every pixel of `gray` that has depth by the light's shading
/// (see the module docs). `normals` come from [`depth_normals`] of `depth_m`.
pub fn shade(
    gray: &mut ImageF32,
    depth_m: &ImageF32,
    normals: &[[f32; 3]],
    camera: &PinholeCamera,
    world_from_camera: &Pose,
    light: &PointLight,
) {
    let w = gray.width();
    let light_c = world_from_camera.inverse_transform_point(&Point3::from(light.position_m));
    let light_c = Vector3::new(light_c.x as f32, light_c.y as f32, light_c.z as f32);
    let (fx, fy, cx, cy) = (
        camera.fx as f32,
        camera.fy as f32,
        camera.cx as f32,
        camera.cy as f32,
    );
    let ambient = light.spec.ambient as f32;
    let diffuse = light.spec.diffuse as f32;
    let inv_falloff2 = 1.0 / (light.spec.falloff_m.max(1e-6) as f32).powi(2);
    let pixels = gray
        .data_mut()
        .iter_mut()
        .zip(depth_m.data())
        .zip(normals)
        .enumerate();
    for (i, ((g, &z), n)) in pixels {
        if z <= 0.0 {
            continue;
        }
        let (x, y) = ((i % w) as f32, (i / w) as f32);
        let p = Vector3::new((x - cx) / fx * z, (y - cy) / fy * z, z);
        let to_light = light_c - p;
        let d2 = to_light.norm_squared().max(1e-12);
        let cos = Vector3::from(*n).dot(&to_light) / d2.sqrt();
        *g *= ambient + diffuse * cos.max(0.0) / (1.0 + d2 * inv_falloff2);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn camera() -> PinholeCamera {
        PinholeCamera::new(64, 48, 40.0, 40.0, 31.5, 23.5)
    }

    #[test]
    fn a_fronto_parallel_wall_faces_the_camera() {
        let depth = ImageF32::new(64, 48, 2.0);
        let mut normals = Vec::new();
        depth_normals(&depth, &camera(), &mut normals);
        for n in &normals {
            assert!((n[2] + 1.0).abs() < 1e-5 && n[0].abs() < 1e-5, "{n:?}");
        }
    }

    #[test]
    fn a_tilted_plane_gives_its_normal_even_at_a_depth_edge() {
        // Plane z = 2 + 0.5 x (camera frame) on the left half, far wall at
        // 6 m on the right: the normals left of the edge stay the plane's.
        let cam = camera();
        let mut depth = ImageF32::new(64, 48, 0.0);
        for y in 0..48 {
            for x in 0..64 {
                let xn = (x as f32 - 31.5) / 40.0;
                let z = if x < 40 { 2.0 / (1.0 - 0.5 * xn) } else { 6.0 };
                depth.row_mut(y)[x] = z;
            }
        }
        let mut normals = Vec::new();
        depth_normals(&depth, &cam, &mut normals);
        let want = Vector3::new(0.5f32, 0.0, -1.0).normalize();
        for y in 1..47 {
            for x in [1, 20, 39] {
                let n = Vector3::from(normals[y * 64 + x]);
                assert!((n - want).norm() < 1e-3, "({x},{y}): {n:?}");
            }
        }
    }

    #[test]
    fn shading_follows_the_light() {
        let cam = camera();
        let depth = ImageF32::new(64, 48, 2.0);
        let mut normals = Vec::new();
        depth_normals(&depth, &cam, &mut normals);
        let pose = Pose::from_parts(Translation3::identity(), UnitQuaternion::identity());
        let spec = LightSpec {
            ambient: 0.5,
            diffuse: 1.0,
            falloff_m: 1e9,
        };
        // Light at the camera: the center pixel faces it fully.
        let light = PointLight {
            position_m: Vector3::zeros(),
            spec,
        };
        let mut gray = ImageF32::new(64, 48, 100.0);
        shade(&mut gray, &depth, &normals, &cam, &pose, &light);
        let center = gray.get(31, 23).expect("inside");
        assert!((center - 150.0).abs() < 0.5, "{center}");
        assert!(gray.get(0, 0).expect("inside") < center);
        // Light behind the wall: ambient only.
        let behind = PointLight {
            position_m: Vector3::new(0.0, 0.0, 5.0),
            spec,
        };
        let mut gray = ImageF32::new(64, 48, 100.0);
        shade(&mut gray, &depth, &normals, &cam, &pose, &behind);
        assert!(gray.data().iter().all(|&g| (g - 50.0).abs() < 1e-4));
    }

    #[test]
    fn the_moving_light_stays_under_the_ceiling_and_moves() {
        let spec = MovingLightSpec {
            light: LightSpec {
                ambient: 0.5,
                diffuse: 1.0,
                falloff_m: 3.0,
            },
            below_ceiling_m: 0.3,
            radius_fraction: 0.5,
            period_s: 20.0,
        };
        let a = spec.at([8.0, 6.0, 3.0], 0.0, 0.0).position_m;
        let b = spec.at([8.0, 6.0, 3.0], 0.0, 5.0).position_m;
        assert!((a - Vector3::new(6.0, 3.0, 2.7)).norm() < 1e-9, "{a:?}");
        assert!((b - Vector3::new(4.0, 4.5, 2.7)).norm() < 1e-9, "{b:?}");
    }
}
