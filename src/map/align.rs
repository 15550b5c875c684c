//! Finding the floor of a mesh in any frame, and the `world_from_mesh` that
//! makes it z-up: what `star map align` writes and `star map info` reports.
//!
//! Takes a [`Mesh`] in its file's frame (a scanner's y-down camera frame,
//! glTF's y-up, CAD's z-up; meters), gives out a [`FloorPlane`] or an
//! [`AlignError`] saying why no floor was found.
//!
//! Method:
//! 1. Planes by RANSAC, largest first: a hypothesis is a triangle's plane
//!    (triangles drawn by area); its score is the area of the triangles
//!    within [`AlignParams::distance_tol_m`] of it whose normals are within
//!    [`AlignParams::normal_tol_deg`]; the best is refined by an
//!    area-weighted least-squares fit (three rounds, the inliers re-chosen
//!    each time), its triangles are removed, and the search goes on while a
//!    plane of [`AlignParams::min_plane_m2`] remains.
//! 2. Each plane's normal is turned towards the bulk of the mesh. A plane
//!    can be the floor when the mesh stands on it: little area below
//!    ([`MAX_BELOW_FRACTION`]), some above, and large planes perpendicular
//!    to it (walls, furniture sides: at least a tenth of its area).
//! 3. The floor is the largest such plane. A floor and a ceiling both
//!    qualify; of the two, the floor is the one with the furniture: the
//!    side with clearly more horizontal surface (table and box tops) in its
//!    near half of the room. An up hint ([`UpHint`]) settles it instead.
//!
//! The transform rotates the floor's normal onto +z by the smallest
//! rotation and puts the floor at z = 0. Yaw about the vertical is free:
//! the smallest rotation keeps the mesh's own heading as far as it can, and
//! the mesh origin's horizontal position stays at x = y = 0.

use nalgebra::{Matrix3, Translation3, UnitQuaternion, Vector3};

use super::Mesh;
use crate::geometry::Pose;
use crate::rng::SplitMix64;

/// Largest fraction of the off-plane area allowed below a floor.
pub const MAX_BELOW_FRACTION: f64 = 0.1;

/// Tuning of the plane search.
#[derive(Debug, Clone, PartialEq)]
pub struct AlignParams {
    /// Largest distance of a triangle's centroid from its plane, meters.
    pub distance_tol_m: f64,
    /// Largest angle between a triangle's normal and its plane's, degrees.
    pub normal_tol_deg: f64,
    /// Smallest plane reported, square meters.
    pub min_plane_m2: f64,
    /// Most planes extracted.
    pub max_planes: usize,
    /// RANSAC hypotheses per plane.
    pub iterations: usize,
    /// Triangles sampled (by area) to score hypotheses.
    pub score_samples: usize,
    /// Above this many triangles, every k-th is used.
    pub max_triangles: usize,
    /// Seed of the draws.
    pub seed: u64,
}

impl Default for AlignParams {
    fn default() -> Self {
        Self {
            distance_tol_m: 0.03,
            normal_tol_deg: 10.0,
            min_plane_m2: 1.0,
            max_planes: 10,
            iterations: 400,
            score_samples: 20_000,
            max_triangles: 1_000_000,
            seed: 1,
        }
    }
}

/// Which way is up, when known.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum UpHint {
    /// Decide from the mesh alone.
    Auto,
    /// Up is within 45 degrees of this direction (mesh frame).
    Near([f64; 3]),
}

/// A plane found in the mesh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal, mesh frame, towards the bulk of the mesh.
    pub normal: [f64; 3],
    /// Offset along the normal: the plane is `normal . p = offset_m`.
    pub offset_m: f64,
    /// Area of its triangles, square meters.
    pub area_m2: f64,
    /// Fraction of the mesh's off-plane area below it.
    pub below_fraction: f64,
    /// Area off the plane above it, square meters.
    pub above_m2: f64,
    /// Area of the other planes perpendicular to it, square meters.
    pub perpendicular_m2: f64,
    /// Horizontal area (parallel to it) in the near half of the room above
    /// it, apart from the plane itself, square meters.
    pub clutter_m2: f64,
}

impl Plane {
    /// Whether the mesh stands on this plane (see the module docs).
    pub fn can_be_floor(&self) -> bool {
        self.below_fraction <= MAX_BELOW_FRACTION
            && self.above_m2 >= (0.1 * self.area_m2).max(0.5)
            && self.perpendicular_m2 >= 0.1 * self.area_m2
    }

    /// Why it cannot be the floor, or `None` when it can.
    pub fn why_not_floor(&self) -> Option<String> {
        if self.above_m2 < 0.5 && self.below_fraction <= 0.0 {
            return Some("nothing stands off it (the mesh is flat)".into());
        }
        if self.below_fraction > MAX_BELOW_FRACTION {
            return Some(format!(
                "{:.0} % of the mesh lies on its other side",
                100.0 * self.below_fraction
            ));
        }
        if self.above_m2 < (0.1 * self.area_m2).max(0.5) {
            return Some(format!(
                "only {:.2} m^2 of the mesh stands off it",
                self.above_m2
            ));
        }
        if self.perpendicular_m2 < 0.1 * self.area_m2 {
            return Some(format!(
                "no large plane is perpendicular to it (walls: {:.2} m^2)",
                self.perpendicular_m2
            ));
        }
        None
    }
}

/// The floor found in a mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct FloorPlane {
    /// The floor.
    pub floor: Plane,
    /// Every plane found, largest first (the floor among them).
    pub planes: Vec<Plane>,
}

impl FloorPlane {
    /// The floor's unit normal (up), mesh frame.
    pub fn up(&self) -> Vector3<f64> {
        Vector3::from(self.floor.normal)
    }

    /// The rigid transform that puts the floor at z = 0 with +z up, by the
    /// smallest rotation (yaw is left as the mesh has it).
    pub fn world_from_mesh(&self) -> Pose {
        let up = self.up();
        let rotation = UnitQuaternion::rotation_between(&up, &Vector3::z()).unwrap_or_else(|| {
            // Up is -z: half a turn about x.
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
        });
        Pose::from_parts(Translation3::new(0.0, 0.0, -self.floor.offset_m), rotation)
    }

    /// Angle between the floor's normal and the frame's +z, degrees.
    pub fn tilt_from_z_deg(&self) -> f64 {
        self.up().z.clamp(-1.0, 1.0).acos().to_degrees()
    }
}

/// Why no floor was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AlignError {
    /// The mesh has no triangles with area.
    #[error("the mesh has no triangles")]
    Empty,
    /// No plane is large enough.
    #[error(
        "no dominant horizontal plane: the mesh has no plane of {min_m2} m^2 or more (the largest \
         flat patch is {largest_m2:.2} m^2 within {tol_m} m); a floor needs a large flat area"
    )]
    NoPlane {
        /// Largest plane's area, square meters.
        largest_m2: f64,
        /// The least area of a plane, square meters.
        min_m2: f64,
        /// The plane's thickness, meters.
        tol_m: f64,
    },
    /// Planes, but none the mesh stands on.
    #[error("no dominant horizontal plane: {reason}")]
    NoFloor {
        /// What the planes lacked.
        reason: String,
    },
}

#[derive(Debug, Clone, Copy)]
struct Tri {
    c: Vector3<f64>,
    n: Vector3<f64>,
    a: f64,
}

fn triangles(mesh: &Mesh, max: usize) -> Vec<Tri> {
    let count = mesh.indices.len() / 3;
    let stride = count.div_ceil(max.max(1)).max(1);
    let p = |i: u32| {
        mesh.positions
            .get(i as usize)
            .map(|v| Vector3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2])))
    };
    mesh.indices
        .chunks_exact(3)
        .step_by(stride)
        .filter_map(|t| {
            let (a, b, c) = (p(t[0])?, p(t[1])?, p(t[2])?);
            let cross = (b - a).cross(&(c - a));
            let norm = cross.norm();
            (norm.is_finite() && norm > 1e-12).then(|| Tri {
                c: (a + b + c) / 3.0,
                n: cross / norm,
                a: 0.5 * norm * stride as f64,
            })
        })
        .collect()
}

/// Indices drawn with probability proportional to area.
fn draw_by_area(tris: &[Tri], count: usize, rng: &mut SplitMix64) -> Vec<usize> {
    let mut cumulative = Vec::with_capacity(tris.len());
    let mut total = 0.0;
    for t in tris {
        total += t.a;
        cumulative.push(total);
    }
    (0..count)
        .map(|_| {
            let u = rng.next_f64() * total;
            cumulative
                .partition_point(|&c| c < u)
                .min(tris.len().saturating_sub(1))
        })
        .collect()
}

/// Area-weighted least-squares plane through the centroids of `inliers`.
fn fit(tris: &[Tri], inliers: &[usize], guess: Vector3<f64>) -> Option<(Vector3<f64>, f64)> {
    let weight: f64 = inliers.iter().map(|&i| tris[i].a).sum();
    if weight <= 0.0 {
        return None;
    }
    let mean = inliers
        .iter()
        .map(|&i| tris[i].c * tris[i].a)
        .sum::<Vector3<f64>>()
        / weight;
    let mut cov = Matrix3::zeros();
    for &i in inliers {
        let d = tris[i].c - mean;
        cov += d * d.transpose() * tris[i].a;
    }
    let eigen = cov.symmetric_eigen();
    let k = eigen.eigenvalues.imin();
    let mut n: Vector3<f64> = eigen.eigenvectors.column(k).into_owned();
    if n.dot(&guess) < 0.0 {
        n = -n;
    }
    Some((n, n.dot(&mean)))
}

fn is_inlier(t: &Tri, n: &Vector3<f64>, d: f64, tol_m: f64, cos_tol: f64) -> bool {
    (n.dot(&t.c) - d).abs() < tol_m && n.dot(&t.n).abs() > cos_tol
}

/// Finds the floor of `mesh` in its own frame (see the module docs).
pub fn find_floor_plane(
    mesh: &Mesh,
    params: &AlignParams,
    hint: UpHint,
) -> Result<FloorPlane, AlignError> {
    let tris = triangles(mesh, params.max_triangles);
    if tris.is_empty() {
        return Err(AlignError::Empty);
    }
    let cos_tol = params.normal_tol_deg.to_radians().cos();
    let tol = params.distance_tol_m;
    let total_area: f64 = tris.iter().map(|t| t.a).sum();
    let mut rng = SplitMix64::new(params.seed);
    let mut active = vec![true; tris.len()];
    let mut found: Vec<(Vector3<f64>, f64, f64)> = Vec::new();
    let mut largest = 0.0f64;
    for _ in 0..params.max_planes {
        let remaining: f64 = tris
            .iter()
            .zip(&active)
            .filter(|(_, &on)| on)
            .map(|(t, _)| t.a)
            .sum();
        if remaining < params.min_plane_m2 {
            break;
        }
        let live: Vec<Tri> = tris
            .iter()
            .zip(&active)
            .filter(|(_, &on)| on)
            .map(|(t, _)| *t)
            .collect();
        let sample = draw_by_area(&live, params.score_samples, &mut rng);
        let per_sample = remaining / sample.len().max(1) as f64;
        let mut best: Option<(usize, f64)> = None;
        for _ in 0..params.iterations {
            let Some(&seed) = sample.get(rng.below(sample.len())) else {
                break;
            };
            let (n, d) = (live[seed].n, live[seed].n.dot(&live[seed].c));
            let score = sample
                .iter()
                .filter(|&&i| is_inlier(&live[i], &n, d, tol, cos_tol))
                .count() as f64
                * per_sample;
            if best.is_none_or(|(_, s)| score > s) {
                best = Some((seed, score));
            }
        }
        let Some((seed, _)) = best else { break };
        let (mut n, mut d) = (live[seed].n, live[seed].n.dot(&live[seed].c));
        let mut inliers: Vec<usize> = Vec::new();
        for round in 0..3 {
            let round_tol = tol * [1.0, 0.75, 0.5][round];
            inliers = (0..tris.len())
                .filter(|&i| active[i] && is_inlier(&tris[i], &n, d, round_tol, cos_tol))
                .collect();
            match fit(&tris, &inliers, n) {
                Some((fitted_n, fitted_d)) => (n, d) = (fitted_n, fitted_d),
                None => break,
            }
        }
        let area: f64 = inliers.iter().map(|&i| tris[i].a).sum();
        largest = largest.max(area);
        // Remove the plane's slab at the full tolerance.
        for (i, t) in tris.iter().enumerate() {
            if active[i] && is_inlier(t, &n, d, tol, cos_tol) {
                active[i] = false;
            }
        }
        if area < params.min_plane_m2 {
            break;
        }
        found.push((n, d, area));
    }
    if found.is_empty() {
        return Err(AlignError::NoPlane {
            largest_m2: largest,
            min_m2: params.min_plane_m2,
            tol_m: tol,
        });
    }
    let perpendicular_sin = params.normal_tol_deg.to_radians().sin();
    let planes: Vec<Plane> = found
        .iter()
        .enumerate()
        .map(|(k, &(n, d, area))| {
            let (mut above, mut below) = (0.0, 0.0);
            for t in &tris {
                let h = n.dot(&t.c) - d;
                if h > tol {
                    above += t.a;
                } else if h < -tol {
                    below += t.a;
                }
            }
            let (n, d, above, below) = if below > above {
                (-n, -d, below, above)
            } else {
                (n, d, above, below)
            };
            let perpendicular_m2 = found
                .iter()
                .enumerate()
                .filter(|&(j, &(m, _, _))| j != k && n.dot(&m).abs() < perpendicular_sin)
                .map(|(_, &(_, _, a))| a)
                .sum();
            let top = tris.iter().map(|t| n.dot(&t.c) - d).fold(0.0f64, f64::max);
            let clutter_m2 = tris
                .iter()
                .filter(|t| {
                    let h = n.dot(&t.c) - d;
                    h > 3.0 * tol && h < 0.5 * top && n.dot(&t.n).abs() > cos_tol
                })
                .map(|t| t.a)
                .sum();
            let off = above + below;
            Plane {
                normal: [n.x, n.y, n.z],
                offset_m: d,
                area_m2: area,
                below_fraction: if off > 0.0 { below / off } else { 0.0 },
                above_m2: above,
                perpendicular_m2,
                clutter_m2,
            }
        })
        .collect();
    tracing::debug!(
        planes = planes.len(),
        total_area_m2 = total_area,
        "planes found"
    );

    let near_hint = |p: &Plane| match hint {
        UpHint::Auto => true,
        UpHint::Near(h) => {
            let h = Vector3::from(h);
            h.try_normalize(1e-12)
                .is_some_and(|h| Vector3::from(p.normal).dot(&h) >= std::f64::consts::FRAC_1_SQRT_2)
        }
    };
    let candidates: Vec<&Plane> = planes
        .iter()
        .filter(|p| p.can_be_floor() && near_hint(p))
        .collect();
    let Some(&best) = candidates
        .iter()
        .max_by(|a, b| a.area_m2.total_cmp(&b.area_m2))
    else {
        let reason = match planes.first() {
            Some(p) if matches!(hint, UpHint::Near(_)) && !planes.iter().any(near_hint) => format!(
                "no plane faces within 45 deg of the up hint; the largest ({:.2} m^2) faces [{:.2}, {:.2}, {:.2}]",
                p.area_m2, p.normal[0], p.normal[1], p.normal[2]
            ),
            Some(p) => format!(
                "no plane of the {} found has the mesh standing on it; the largest ({:.2} m^2): {}",
                planes.len(),
                p.area_m2,
                p.why_not_floor().unwrap_or_else(|| "does not face the up hint".into())
            ),
            None => "no plane found".into(),
        };
        return Err(AlignError::NoFloor { reason });
    };
    // Floor or ceiling: the side the furniture stands on.
    let mut floor = *best;
    if hint == UpHint::Auto {
        let n = Vector3::from(best.normal);
        if let Some(other) = candidates
            .iter()
            .find(|p| Vector3::from(p.normal).dot(&n) < -params.normal_tol_deg.to_radians().cos())
        {
            if other.clutter_m2 >= 2.0 * best.clutter_m2 && other.clutter_m2 >= 0.5 {
                floor = **other;
            }
        }
    }
    Ok(FloorPlane { floor, planes })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Appends the quad `a, b, c, d` split into `cells x cells`.
    fn quad(mesh: &mut Mesh, a: [f32; 3], b: [f32; 3], d: [f32; 3], cells: usize) {
        let base = mesh.positions.len() as u32;
        for j in 0..=cells {
            for i in 0..=cells {
                let (s, t) = (i as f32 / cells as f32, j as f32 / cells as f32);
                mesh.positions.push(std::array::from_fn(|k| {
                    a[k] + s * (b[k] - a[k]) + t * (d[k] - a[k])
                }));
                mesh.gray.push(128.0);
            }
        }
        let at = |i: usize, j: usize| base + (j * (cells + 1) + i) as u32;
        for j in 0..cells {
            for i in 0..cells {
                mesh.indices
                    .extend([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                mesh.indices
                    .extend([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
    }

    /// An axis-aligned box `lo..hi` (z up), with or without its bottom.
    fn boxed(mesh: &mut Mesh, lo: [f32; 3], hi: [f32; 3], cells: usize, bottom: bool) {
        let [x0, y0, z0] = lo;
        let [x1, y1, z1] = hi;
        if bottom {
            quad(mesh, [x0, y0, z0], [x1, y0, z0], [x0, y1, z0], cells);
        }
        quad(mesh, [x0, y0, z1], [x1, y0, z1], [x0, y1, z1], cells);
        quad(mesh, [x0, y0, z0], [x1, y0, z0], [x0, y0, z1], cells);
        quad(mesh, [x0, y1, z0], [x1, y1, z0], [x0, y1, z1], cells);
        quad(mesh, [x0, y0, z0], [x0, y1, z0], [x0, y0, z1], cells);
        quad(mesh, [x1, y0, z0], [x1, y1, z0], [x1, y0, z1], cells);
    }

    /// A 6 x 4 x 3 m room (floor at z = 0.2) with two tables, then moved
    /// into a scanner-like frame by `mesh_from_world`.
    fn room(mesh_from_world: &Pose) -> Mesh {
        let mut mesh = Mesh::default();
        boxed(&mut mesh, [0.0, 0.0, 0.2], [6.0, 4.0, 3.2], 8, true);
        boxed(&mut mesh, [1.0, 1.0, 0.2], [2.5, 2.0, 1.0], 4, false);
        boxed(&mut mesh, [3.5, 2.0, 0.2], [5.0, 3.2, 0.9], 4, false);
        mesh.transform(1.0, mesh_from_world);
        mesh
    }

    #[test]
    fn the_floor_of_a_room_in_a_scanner_frame_is_found() {
        // A camera 1.4 m above the floor, looking along world +x, tilted.
        let world_from_camera = Pose::from_parts(
            Translation3::new(2.0, 1.5, 1.6),
            UnitQuaternion::from_euler_angles(-1.7, 0.1, -1.5),
        );
        let mesh = room(&world_from_camera.inverse());
        let found = find_floor_plane(&mesh, &AlignParams::default(), UpHint::Auto).expect("floor");
        let up_true = world_from_camera.inverse().rotation * Vector3::z();
        let angle = found.up().angle(&up_true).to_degrees();
        assert!(angle < 0.05, "normal off by {angle} deg: {found:?}");
        // The camera (mesh origin) is 1.4 m above the floor.
        let level = found.world_from_mesh();
        assert!((level.translation.z - 1.4).abs() < 1e-3, "{level:?}");
        // Every vertex ends up at or above the floor.
        let mut leveled = mesh.clone();
        leveled.transform(1.0, &level);
        let lowest = leveled
            .positions
            .iter()
            .map(|p| p[2])
            .fold(f32::MAX, f32::min);
        assert!(lowest.abs() < 1e-3, "lowest vertex at {lowest}");
    }

    #[test]
    fn the_ceiling_is_not_taken_for_the_floor() {
        // Upside down. The floor and the ceiling have the same area (the
        // tables have no bottoms): the tables' tops decide.
        let flip = Pose::from_parts(
            Translation3::new(0.0, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
        );
        let mesh = room(&flip);
        let found = find_floor_plane(&mesh, &AlignParams::default(), UpHint::Auto).expect("floor");
        assert!(found.up().z < -0.999, "{:?}", found.floor);
        assert!(
            (found.floor.offset_m - 0.2).abs() < 1e-3,
            "{:?}",
            found.floor
        );
        // A hint says otherwise: the ceiling then.
        let hinted = find_floor_plane(
            &mesh,
            &AlignParams::default(),
            UpHint::Near([0.0, 0.0, 1.0]),
        )
        .expect("ceiling");
        assert!(hinted.up().z > 0.999, "{:?}", hinted.floor);
    }

    #[test]
    fn a_lone_wall_or_a_sphere_has_no_floor() {
        let mut wall = Mesh::default();
        quad(
            &mut wall,
            [0.0, 0.0, 0.0],
            [4.0, 0.0, 0.0],
            [0.0, 0.0, 3.0],
            10,
        );
        let e = find_floor_plane(&wall, &AlignParams::default(), UpHint::Auto).expect_err("wall");
        assert!(
            matches!(e, AlignError::NoFloor { .. }) && e.to_string().contains("flat"),
            "{e}"
        );
        let mut sphere = Mesh::default();
        let (rings, segments) = (24, 48);
        for r in 0..=rings {
            let theta = std::f32::consts::PI * r as f32 / rings as f32;
            for s in 0..segments {
                let phi = std::f32::consts::TAU * s as f32 / segments as f32;
                sphere.positions.push([
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                ]);
                sphere.gray.push(100.0);
            }
        }
        for r in 0..rings as u32 {
            for s in 0..segments as u32 {
                let at = |r: u32, s: u32| r * segments as u32 + s % segments as u32;
                sphere
                    .indices
                    .extend([at(r, s), at(r + 1, s), at(r + 1, s + 1)]);
                sphere
                    .indices
                    .extend([at(r, s), at(r + 1, s + 1), at(r, s + 1)]);
            }
        }
        let e =
            find_floor_plane(&sphere, &AlignParams::default(), UpHint::Auto).expect_err("sphere");
        assert!(matches!(e, AlignError::NoPlane { .. }), "{e}");
        assert!(
            e.to_string().contains("no dominant horizontal plane"),
            "{e}"
        );
    }
}
