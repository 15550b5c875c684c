//! Finding the floor of a map: the height of the lowest large horizontal
//! surface, in the world frame (z up).
//!
//! The relocalization grid's heights are measured from it: a scanned map
//! placed by `[map.world_from_mesh]` has its floor wherever the scanner's
//! registration put it, not at world z = 0.
//!
//! Method: every triangle whose normal is within [`MAX_TILT_DEG`] of
//! vertical adds its area to a histogram of heights ([`BIN_M`] bins). The
//! floor is the lowest bin holding at least [`MIN_FLOOR_AREA_M2`] and at
//! least a quarter of the largest bin (so a few square meters of scan noise
//! under the floor do not count, while a large table top or the ceiling
//! above it do not win); its height is the area-weighted mean of the
//! triangles within one bin of it. A map with no such surface (a single
//! wall, a scan that never looked down) has no floor: the caller must be
//! told to set the heights explicitly.

use super::Mesh;

/// Largest angle between a floor triangle's normal and the vertical, degrees.
pub const MAX_TILT_DEG: f64 = 10.0;
/// Height bin, meters.
pub const BIN_M: f64 = 0.02;
/// Least horizontal area at the floor's height, square meters.
pub const MIN_FLOOR_AREA_M2: f64 = 1.0;

/// The floor found in a map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Floor {
    /// Height of the floor, world meters.
    pub z_m: f64,
    /// Horizontal area found at that height, square meters.
    pub area_m2: f64,
    /// Horizontal area of the whole map, square meters.
    pub horizontal_area_m2: f64,
}

/// Why no floor was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FloorError {
    /// The map has no triangles.
    #[error("the map has no triangles")]
    Empty,
    /// No horizontal surface is large enough to be a floor.
    #[error(
        "no floor found in the map: the largest horizontal surface is {largest_m2:.2} m^2 \
         (at least {MIN_FLOOR_AREA_M2} m^2 within {BIN_M} m of one height, facing up within \
         {MAX_TILT_DEG} deg, is needed); is the map z-up (`[map.world_from_mesh]`)?"
    )]
    NotFound {
        /// Area of the largest horizontal bin, square meters.
        largest_m2: f64,
    },
}

/// Finds the floor of `mesh` (world frame, z up).
pub fn find_floor(mesh: &Mesh) -> Result<Floor, FloorError> {
    let (lo, hi) = mesh.bounds().ok_or(FloorError::Empty)?;
    if mesh.indices.len() < 3 {
        return Err(FloorError::Empty);
    }
    let z0 = lo[2] as f64;
    let bins = (((hi[2] - lo[2]) as f64 / BIN_M).floor() as usize + 1).min(1 << 20);
    let mut area = vec![0.0f64; bins];
    let cos_max = MAX_TILT_DEG.to_radians().cos();
    let horizontal = |t: &[u32]| -> Option<(f64, f64)> {
        let p = |i: u32| {
            let v = mesh.positions[i as usize];
            [v[0] as f64, v[1] as f64, v[2] as f64]
        };
        let (a, b, c) = (p(t[0]), p(t[1]), p(t[2]));
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        let norm = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        if !norm.is_finite() || norm <= 0.0 || n[2].abs() < cos_max * norm {
            return None;
        }
        Some(((a[2] + b[2] + c[2]) / 3.0, 0.5 * norm))
    };
    let mut total = 0.0;
    for t in mesh.indices.chunks_exact(3) {
        if let Some((z, a)) = horizontal(t) {
            let bin = (((z - z0) / BIN_M).floor().max(0.0) as usize).min(bins - 1);
            area[bin] += a;
            total += a;
        }
    }
    let largest = area.iter().copied().fold(0.0, f64::max);
    let needed = MIN_FLOOR_AREA_M2.max(0.25 * largest);
    let Some(bin) = area.iter().position(|&a| a >= needed) else {
        return Err(FloorError::NotFound {
            largest_m2: largest,
        });
    };
    // Refine: the area-weighted mean height within one bin of it.
    let center = z0 + (bin as f64 + 0.5) * BIN_M;
    let (mut sum_az, mut sum_a) = (0.0, 0.0);
    for t in mesh.indices.chunks_exact(3) {
        if let Some((z, a)) = horizontal(t) {
            if (z - center).abs() <= 1.5 * BIN_M {
                sum_az += a * z;
                sum_a += a;
            }
        }
    }
    Ok(Floor {
        z_m: sum_az / sum_a,
        area_m2: sum_a,
        horizontal_area_m2: total,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A horizontal square of side `s` at height `z`, plus optional extra
    /// triangles.
    fn square(mesh: &mut Mesh, x0: f32, y0: f32, s: f32, z: f32) {
        let base = mesh.positions.len() as u32;
        mesh.positions.extend_from_slice(&[
            [x0, y0, z],
            [x0 + s, y0, z],
            [x0 + s, y0 + s, z],
            [x0, y0 + s, z],
        ]);
        mesh.gray.extend_from_slice(&[0.5; 4]);
        mesh.indices
            .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }

    fn wall(mesh: &mut Mesh, x: f32, s: f32) {
        let base = mesh.positions.len() as u32;
        mesh.positions
            .extend_from_slice(&[[x, 0.0, 0.0], [x, s, 0.0], [x, s, s], [x, 0.0, s]]);
        mesh.gray.extend_from_slice(&[0.5; 4]);
        mesh.indices
            .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }

    #[test]
    fn the_floor_is_the_lowest_large_surface_not_the_largest() {
        let mut mesh = Mesh::default();
        // A 0.5 m^2 patch of scan noise 10 cm below, the 4 x 4 floor at
        // 0.37 m, a 2 x 2 table at 1.1 m and a 5 x 5 ceiling at 3 m.
        square(&mut mesh, 0.0, 0.0, 0.7, 0.27);
        square(&mut mesh, 0.0, 0.0, 4.0, 0.37);
        square(&mut mesh, 1.0, 1.0, 2.0, 1.1);
        square(&mut mesh, -0.5, -0.5, 5.0, 3.0);
        wall(&mut mesh, 0.0, 3.0);
        let floor = find_floor(&mesh).expect("floor");
        assert!((floor.z_m - 0.37).abs() < 1e-6, "{floor:?}");
        assert!((floor.area_m2 - 16.0).abs() < 1e-3, "{floor:?}");
    }

    #[test]
    fn a_map_without_horizontal_surfaces_has_no_floor() {
        let mut mesh = Mesh::default();
        wall(&mut mesh, 0.0, 3.0);
        wall(&mut mesh, 2.0, 3.0);
        let err = find_floor(&mesh).expect_err("no floor");
        assert!(matches!(err, FloorError::NotFound { .. }), "{err}");
        assert!(err.to_string().contains("no floor found"), "{err}");
        assert_eq!(find_floor(&Mesh::default()), Err(FloorError::Empty));
    }
}
