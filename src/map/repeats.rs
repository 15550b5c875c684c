//! The map's repeated geometry: where else in the map a view's surfaces
//! stand the same, moved by a horizontal translation.
//!
//! Owns [`MapOccupancy`], an occupancy grid of the map's surfaces built once
//! when the map is loaded, and [`MapOccupancy::twins`], which takes the 3D
//! points of one view (a rendered keyframe's) and gives the offsets, best
//! first, under which at least [`MIN_SCORE`] of them land on the map's
//! surfaces again at least [`MIN_OFFSET_M`] away. Relocalization checks a
//! pose it cannot vouch for at each such offset (`reloc::twins`): on a
//! scanned map the baked light differs from place to place, so a frame can
//! look more like the scan of a place's twin than like its own, and
//! appearance alone cannot rule the twin out. Geometry can find it.
//!
//! Method. Every steep triangle (normal within
//! [`MAX_NORMAL_ELEVATION_DEG`] of horizontal: walls and furniture sides;
//! floors and ceilings are alike everywhere) is sampled every half cell
//! into a grid of [`CELL_M`] cells, each cell a bit mask of [`SLICES`]
//! height slices of [`SLICE_M`] from the map's lowest point, then dilated by
//! one cell and one slice against the points' and the surfaces' noise. Of
//! the view's points, those on steep surfaces where they are count. Every
//! offset of a grid eight times coarser is scored (the fraction of the
//! points that fall in occupied coarse cells), and the best
//! [`MAX_COARSE_PEAKS`] coarse local maxima are refined at full resolution.
//! A refined offset is a twin when it scores at least [`MIN_SCORE`] and the
//! camera moved by it still sees its points through free space (the
//! midpoints of its rays, [`MIN_FREE_FRACTION`]): a view of one end wall
//! of a room also fits the opposite wall, from outside the room. A view of
//! a plain wall fits anywhere along it, and then has many twins.
//!
//! Cost, measured on the 22-room scanned floor (14.7 M triangles, a
//! 68 x 17 m grid): one pass over the triangles at load, 0.9-1.4 s, and
//! about 2 MB; a search, 2.5-17 ms. Nothing allocates after
//! [`MapOccupancy::build`] and [`MapOccupancy::scratch`].

use nalgebra::Vector3;

use super::Mesh;

/// Occupancy cell, meters.
pub const CELL_M: f64 = 0.05;
/// Height slice, meters.
pub const SLICE_M: f64 = 0.1;
/// Height slices (bits per cell); higher surfaces go in the last.
pub const SLICES: u32 = 32;
/// Most cells of the grid (64 MB; a 200 x 200 m floor). A larger map, or
/// one vertex far from the rest, is not searched.
pub const MAX_CELLS: usize = 16 << 20;
/// Coarse cells per side, in cells.
const COARSE: usize = 8;
/// Points of a view scored, at most (the rest are skipped evenly).
pub const MAX_POINTS: usize = 256;
/// Least points a view needs to be searched.
pub const MIN_POINTS: usize = 32;
/// Least fraction of the points that must land on surfaces at a coarse
/// offset for it to be refined ...
const COARSE_MIN_SCORE: f32 = 0.85;
/// ... and at the full-resolution offset, for it to be a twin. 0.9 until
/// 2026-12-07: on the scanned floor a cold start took a look-alike room
/// 16 m from the truth, and the true room, scanned with its own holes and
/// noise, fit the held view with 0.81 only, so it was never checked
/// (docs/building-scale.md, "Cold starts on the scanned floor that sent
/// wrong poses").
pub const MIN_SCORE: f32 = 0.8;
/// Shortest offset that is a twin, meters.
pub const MIN_OFFSET_M: f64 = 1.0;
/// Coarse local maxima refined per search, best first.
pub const MAX_COARSE_PEAKS: usize = 200;
/// Largest angle between a counted triangle's normal and the horizontal,
/// degrees: floors, ceilings and table tops repeat everywhere.
pub const MAX_NORMAL_ELEVATION_DEG: f64 = 60.0;
/// Rays shorter than this are not tested for free space, meters.
const MIN_RAY_M: f64 = 0.6;
/// A twin camera must see at least this fraction of its points through
/// free space (ray midpoints) ...
pub const MIN_FREE_FRACTION: f32 = 0.8;
/// ... or at least the held camera's fraction less this (a scan's noise).
const FREE_MARGIN: f32 = 0.1;
/// Two offsets closer than this are one, meters.
const SAME_OFFSET_M: f64 = 0.3;
/// [`MapOccupancy::score_at`] takes the best offset within this of the one
/// asked, meters (a relocalized pose is a few centimeters off).
pub const SCORE_SLACK_M: f64 = 0.1;

/// A translation under which a view's surfaces stand in the map again
/// (after a turn of the view about its camera's vertical axis, when the
/// caller turned the points it searched).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Twin {
    /// World offset `[x, y]`, meters: the view's points at `p` stand at
    /// `p + offset` too.
    pub offset_m: [f64; 2],
    /// The turn about the camera's vertical axis, radians, applied before
    /// the offset (0 from [`MapOccupancy::twins`]; `reloc::twins` turns the
    /// view's points by a quarter, a half and three quarters).
    pub yaw_rad: f64,
    /// Fraction of the view's points that land on the map's surfaces there.
    pub score: f32,
}

/// An occupancy grid: a bit mask of height slices per cell, row-major.
#[derive(Debug, Clone, Default, PartialEq)]
struct Grid {
    nx: usize,
    ny: usize,
    cells: Vec<u32>,
}

impl Grid {
    fn at(&self, x: isize, y: isize) -> u32 {
        if x < 0 || y < 0 || x as usize >= self.nx || y as usize >= self.ny {
            return 0;
        }
        self.cells[y as usize * self.nx + x as usize]
    }

    /// OR of each `f x f` block.
    fn coarsened(&self, f: usize) -> Grid {
        let (nx, ny) = (self.nx.div_ceil(f), self.ny.div_ceil(f));
        let mut cells = vec![0u32; nx * ny];
        for y in 0..self.ny {
            for x in 0..self.nx {
                cells[(y / f) * nx + x / f] |= self.cells[y * self.nx + x];
            }
        }
        Grid { nx, ny, cells }
    }

    /// Each cell OR its 8 neighbours, each bit OR the slices above and below.
    fn dilated(&self) -> Grid {
        let mut cells = vec![0u32; self.cells.len()];
        for y in 0..self.ny as isize {
            for x in 0..self.nx as isize {
                let mut m = 0u32;
                for yy in y - 1..=y + 1 {
                    for xx in x - 1..=x + 1 {
                        m |= self.at(xx, yy);
                    }
                }
                cells[y as usize * self.nx + x as usize] = m | (m << 1) | (m >> 1);
            }
        }
        Grid {
            nx: self.nx,
            ny: self.ny,
            cells,
        }
    }
}

/// A view's point in grid units: fine cell (x, y) and slice bit, and its
/// position from the grid's corner, meters.
#[derive(Debug, Clone, Copy, Default)]
struct GridPoint {
    x: isize,
    y: isize,
    bit: u32,
    m: [f64; 3],
}

/// The map's surfaces on a grid, and the buffers of one twin search.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MapOccupancy {
    /// World `[x, y]` of the grid's first cell corner, meters.
    origin_m: [f64; 2],
    /// World height of the first slice, meters.
    z0_m: f64,
    /// Dilated, full resolution.
    fine: Grid,
    /// Coarsened, then dilated.
    coarse: Grid,
}

/// Buffers of [`MapOccupancy::twins`], allocated once per map.
#[derive(Debug, Clone, Default)]
pub struct TwinScratch {
    points: Vec<GridPoint>,
    coarse_points: Vec<GridPoint>,
    scores: Vec<f32>,
    peaks: Vec<(f32, isize, isize)>,
}

impl MapOccupancy {
    /// An empty grid: [`Self::twins`] finds nothing.
    pub fn none() -> Self {
        Self::default()
    }

    /// The occupancy of `mesh`'s triangles.
    pub fn build(mesh: &Mesh) -> Self {
        let Some((lo, hi)) = mesh.bounds() else {
            return Self::none();
        };
        let origin_m = [f64::from(lo[0]), f64::from(lo[1])];
        let z0_m = f64::from(lo[2]);
        let cells = |extent: f32| (f64::from(extent) / CELL_M).ceil() + 1.0;
        let (fx, fy) = (cells(hi[0] - lo[0]), cells(hi[1] - lo[1]));
        // Not `>`: a NaN or infinite extent fails this too.
        if !(fx * fy <= MAX_CELLS as f64) {
            tracing::warn!(
                extent_m = ?[hi[0] - lo[0], hi[1] - lo[1]],
                max_cells = MAX_CELLS,
                "map too large for the geometric twin grid (a stray vertex far away?); twins are not checked"
            );
            return Self::none();
        }
        let (nx, ny) = (
            (fx as usize).next_multiple_of(COARSE),
            (fy as usize).next_multiple_of(COARSE),
        );
        let grid = occupancy(mesh, origin_m, z0_m, nx, ny);
        Self {
            origin_m,
            z0_m,
            fine: grid.dilated(),
            coarse: grid.coarsened(COARSE).dilated(),
        }
    }

    /// Whether a map was searched into the grid.
    pub fn is_empty(&self) -> bool {
        self.fine.cells.is_empty()
    }

    /// Buffers for [`Self::twins`] on this grid.
    pub fn scratch(&self) -> TwinScratch {
        TwinScratch {
            points: Vec::with_capacity(MAX_POINTS),
            coarse_points: Vec::with_capacity(MAX_POINTS),
            scores: vec![0.0; (2 * self.coarse.nx + 1) * (2 * self.coarse.ny + 1)],
            peaks: Vec::with_capacity(MAX_COARSE_PEAKS + 1),
        }
    }

    /// The offsets under which `points_world` (a view's surface points,
    /// world meters; at most [`MAX_POINTS`] of them are used, evenly
    /// skipped) land on the map's surfaces again, at least [`MIN_OFFSET_M`]
    /// away: best first, one per place, at most `out`'s capacity. Empty
    /// when the view has fewer than [`MIN_POINTS`] points on the grid.
    pub fn twins<const N: usize>(
        &self,
        camera_world: &Vector3<f64>,
        points_world: &[Vector3<f64>],
        scratch: &mut TwinScratch,
        out: &mut heapless::Vec<Twin, N>,
    ) {
        self.twins_turned(camera_world, points_world, (0.0, None), scratch, out);
    }

    /// [`Self::twins`] of the view turned by `yaw_rad` about the camera's
    /// vertical axis: the points that lie on the map's steep surfaces
    /// where they are, turned, then searched for the offsets under which
    /// they land on surfaces again (each [`Twin`] carries `yaw_rad`).
    ///
    /// With `within` (an offset `[x, y]` and a radius, meters), only the
    /// offsets within that radius of it are twins: where the camera moved
    /// by them stands in a region (the motion prior's, for
    /// `reloc::twins`), whatever scores better elsewhere.
    pub fn twins_turned<const N: usize>(
        &self,
        camera_world: &Vector3<f64>,
        points_world: &[Vector3<f64>],
        (yaw_rad, within): (f64, Option<([f64; 2], f64)>),
        scratch: &mut TwinScratch,
        out: &mut heapless::Vec<Twin, N>,
    ) {
        out.clear();
        if self.is_empty()
            || scratch.scores.len() < (2 * self.coarse.nx + 1) * (2 * self.coarse.ny + 1)
        {
            return;
        }
        let n = self.prepare_points(camera_world, points_world, yaw_rad, scratch);
        if n < MIN_POINTS {
            return;
        }
        // Every coarse offset (dx, dy) in [-n, n].
        let (cnx, cny) = (self.coarse.nx as isize, self.coarse.ny as isize);
        let width = 2 * cnx + 1;
        let need = (COARSE_MIN_SCORE * n as f32).ceil() as usize;
        for dy in -cny..=cny {
            for dx in -cnx..=cnx {
                let mut hits = 0usize;
                for (k, p) in scratch.coarse_points.iter().enumerate() {
                    if self.coarse.at(p.x + dx, p.y + dy) & p.bit != 0 {
                        hits += 1;
                    } else if hits + (n - k - 1) < need {
                        break;
                    }
                }
                scratch.scores[((dy + cny) * width + dx + cnx) as usize] = hits as f32 / n as f32;
            }
        }
        // Coarse local maxima, best first.
        scratch.peaks.clear();
        let score = |dx: isize, dy: isize| {
            if dx.abs() > cnx || dy.abs() > cny {
                return f32::NEG_INFINITY;
            }
            scratch.scores[((dy + cny) * width + dx + cnx) as usize]
        };
        let min_coarse = MIN_OFFSET_M / (CELL_M * COARSE as f64) - 1.0;
        for dy in -cny..=cny {
            for dx in -cnx..=cnx {
                let s = score(dx, dy);
                if s < COARSE_MIN_SCORE || (dx as f64).hypot(dy as f64) < min_coarse {
                    continue;
                }
                if let Some((center_m, radius_m)) = within {
                    // A coarse cell's refinement reaches a coarse cell
                    // around it: that much slack.
                    let coarse_m = CELL_M * COARSE as f64;
                    let off_m = [dx as f64 * coarse_m, dy as f64 * coarse_m];
                    let d_m = (off_m[0] - center_m[0]).hypot(off_m[1] - center_m[1]);
                    if !(d_m <= radius_m + 1.5 * coarse_m) {
                        continue;
                    }
                }
                let is_max = (dy - 1..=dy + 1).all(|yy| {
                    (dx - 1..=dx + 1).all(|xx| (xx, yy) == (dx, dy) || score(xx, yy) <= s)
                });
                if !is_max {
                    continue;
                }
                let at = scratch.peaks.partition_point(|q| q.0 >= s);
                if at < MAX_COARSE_PEAKS {
                    if scratch.peaks.len() == MAX_COARSE_PEAKS {
                        scratch.peaks.pop();
                    }
                    scratch.peaks.insert(at, (s, dx, dy));
                }
            }
        }
        // Refine each at full resolution; the twin camera must see its
        // points through free space, as the held one does.
        let Some(camera) = self.grid_point(camera_world) else {
            return;
        };
        let own_free = self
            .free_fraction(&camera, &scratch.points, (0, 0))
            .unwrap_or(0.0);
        let reach = COARSE as isize;
        for &(_, cdx, cdy) in &scratch.peaks {
            let mut best: Option<(usize, isize, isize)> = None;
            for fy in cdy * COARSE as isize - reach..=cdy * COARSE as isize + reach {
                for fx in cdx * COARSE as isize - reach..=cdx * COARSE as isize + reach {
                    let hits = scratch
                        .points
                        .iter()
                        .filter(|p| self.fine.at(p.x + fx, p.y + fy) & p.bit != 0)
                        .count();
                    if best.is_none_or(|(b, _, _)| hits > b) {
                        best = Some((hits, fx, fy));
                    }
                }
            }
            let Some((hits, fx, fy)) = best else {
                continue;
            };
            let free = self.free_fraction(&camera, &scratch.points, (fx, fy));
            if free.is_none_or(|f| f < MIN_FREE_FRACTION.min(own_free - FREE_MARGIN)) {
                continue;
            }
            let twin = Twin {
                offset_m: [fx as f64 * CELL_M, fy as f64 * CELL_M],
                yaw_rad,
                score: hits as f32 / n as f32,
            };
            if twin.score >= MIN_SCORE && twin.offset_m[0].hypot(twin.offset_m[1]) >= MIN_OFFSET_M {
                insert(out, twin);
            }
        }
    }

    /// Fills `scratch`'s points with those of `points_world` (evenly
    /// skipped to [`MAX_POINTS`]) that lie on the map's steep surfaces
    /// where they are, turned by `yaw_rad` about `camera_world`'s vertical;
    /// returns how many.
    fn prepare_points(
        &self,
        camera_world: &Vector3<f64>,
        points_world: &[Vector3<f64>],
        yaw_rad: f64,
        scratch: &mut TwinScratch,
    ) -> usize {
        let (sin, cos) = yaw_rad.sin_cos();
        let stride = points_world.len().div_ceil(MAX_POINTS).max(1);
        scratch.points.clear();
        scratch.coarse_points.clear();
        for p in points_world.iter().step_by(stride) {
            // Only points on the map's steep surfaces where they are.
            let Some(g) = self
                .grid_point(p)
                .filter(|g| self.fine.at(g.x, g.y) & g.bit != 0)
            else {
                continue;
            };
            // Turned about the camera: possibly off the grid, which the
            // offsets bring back.
            let g = if yaw_rad == 0.0 {
                g
            } else {
                let d = p - camera_world;
                let q =
                    camera_world + Vector3::new(cos * d.x - sin * d.y, sin * d.x + cos * d.y, d.z);
                let m = [
                    q.x - self.origin_m[0],
                    q.y - self.origin_m[1],
                    q.z - self.z0_m,
                ];
                GridPoint {
                    x: (m[0] / CELL_M).floor() as isize,
                    y: (m[1] / CELL_M).floor() as isize,
                    bit: g.bit,
                    m,
                }
            };
            if scratch.points.len() < MAX_POINTS {
                scratch.points.push(g);
                scratch.coarse_points.push(GridPoint {
                    x: g.x.div_euclid(COARSE as isize),
                    y: g.y.div_euclid(COARSE as isize),
                    ..g
                });
            }
        }
        scratch.points.len()
    }

    /// How well the view of [`Self::twins_turned`] fits at one given turn
    /// and offset (the best within [`SCORE_SLACK_M`] of it): the fraction of
    /// its points on the map's surfaces there (as [`Twin::score`]) and the
    /// fraction of its rays through free space; `None` when the view has
    /// fewer than [`MIN_POINTS`] points or the moved camera leaves the
    /// grid. For diagnosis: why a place was, or was not, a twin.
    pub fn score_at(
        &self,
        camera_world: &Vector3<f64>,
        points_world: &[Vector3<f64>],
        (yaw_rad, offset_m): (f64, [f64; 2]),
        scratch: &mut TwinScratch,
    ) -> Option<(f32, f32)> {
        if self.is_empty() {
            return None;
        }
        let n = self.prepare_points(camera_world, points_world, yaw_rad, scratch);
        if n < MIN_POINTS {
            return None;
        }
        let camera = self.grid_point(camera_world)?;
        let (cx, cy) = (
            (offset_m[0] / CELL_M).round() as isize,
            (offset_m[1] / CELL_M).round() as isize,
        );
        let slack = (SCORE_SLACK_M / CELL_M).round() as isize;
        let mut best = (0usize, cx, cy);
        for fy in cy - slack..=cy + slack {
            for fx in cx - slack..=cx + slack {
                let hits = scratch
                    .points
                    .iter()
                    .filter(|p| self.fine.at(p.x + fx, p.y + fy) & p.bit != 0)
                    .count();
                if hits > best.0 {
                    best = (hits, fx, fy);
                }
            }
        }
        let free = self.free_fraction(&camera, &scratch.points, (best.1, best.2))?;
        Some((best.0 as f32 / n as f32, free))
    }

    /// Of the points at least [`MIN_RAY_M`] from `camera`, the fraction
    /// whose ray's midpoint lies in free space, all moved by `(fx, fy)`
    /// cells; `None` when the moved camera leaves the grid (a twin pose
    /// outside the map). 1 when no ray is long enough.
    fn free_fraction(
        &self,
        camera: &GridPoint,
        points: &[GridPoint],
        (fx, fy): (isize, isize),
    ) -> Option<f32> {
        let (cx, cy) = (camera.x + fx, camera.y + fy);
        if cx < 0 || cy < 0 || cx as usize >= self.fine.nx || cy as usize >= self.fine.ny {
            return None;
        }
        let (mut rays, mut free) = (0usize, 0usize);
        for p in points {
            let d = [
                p.m[0] - camera.m[0],
                p.m[1] - camera.m[1],
                p.m[2] - camera.m[2],
            ];
            if (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() < MIN_RAY_M {
                continue;
            }
            let mid = [
                camera.m[0] + 0.5 * d[0],
                camera.m[1] + 0.5 * d[1],
                camera.m[2] + 0.5 * d[2],
            ];
            let x = (mid[0] / CELL_M).floor() as isize + fx;
            let y = (mid[1] / CELL_M).floor() as isize + fy;
            let s = (mid[2] / SLICE_M).floor().clamp(0.0, f64::from(SLICES - 1)) as u32;
            rays += 1;
            free += usize::from(self.fine.at(x, y) & (1 << s) == 0);
        }
        Some(if rays == 0 {
            1.0
        } else {
            free as f32 / rays as f32
        })
    }

    /// `p` on the grid; `None` outside it or not finite.
    fn grid_point(&self, p: &Vector3<f64>) -> Option<GridPoint> {
        let x = ((p.x - self.origin_m[0]) / CELL_M).floor();
        let y = ((p.y - self.origin_m[1]) / CELL_M).floor();
        let s = ((p.z - self.z0_m) / SLICE_M).floor();
        let inside = x >= 0.0
            && y >= 0.0
            && s >= 0.0
            && (x as usize) < self.fine.nx
            && (y as usize) < self.fine.ny;
        inside.then(|| GridPoint {
            x: x as isize,
            y: y as isize,
            bit: 1 << (s.min(f64::from(SLICES - 1)) as u32),
            m: [
                p.x - self.origin_m[0],
                p.y - self.origin_m[1],
                p.z - self.z0_m,
            ],
        })
    }
}

/// The occupancy of `mesh`'s triangles on an `nx x ny` grid from
/// `origin_m`, slices from `z0`.
fn occupancy(mesh: &Mesh, origin_m: [f64; 2], z0: f64, nx: usize, ny: usize) -> Grid {
    let mut cells = vec![0u32; nx * ny];
    let half_cell = 0.5 * CELL_M;
    let mut mark = |p: Vector3<f64>| {
        let x = ((p.x - origin_m[0]) / CELL_M).floor();
        let y = ((p.y - origin_m[1]) / CELL_M).floor();
        let s = ((p.z - z0) / SLICE_M)
            .floor()
            .clamp(0.0, f64::from(SLICES - 1));
        if x >= 0.0 && y >= 0.0 && (x as usize) < nx && (y as usize) < ny && s.is_finite() {
            cells[y as usize * nx + x as usize] |= 1 << (s as u32);
        }
    };
    let vertex = |i: u32| {
        mesh.positions
            .get(i as usize)
            .map(|p| Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])))
    };
    let max_up = MAX_NORMAL_ELEVATION_DEG.to_radians().sin();
    for t in mesh.indices.chunks_exact(3) {
        let (Some(a), Some(b), Some(c)) = (vertex(t[0]), vertex(t[1]), vertex(t[2])) else {
            continue;
        };
        let n = (b - a).cross(&(c - a));
        let area2 = n.norm();
        if !(area2 > 0.0) || (n.z / area2).abs() > max_up {
            continue;
        }
        let longest = (b - a).norm().max((c - b).norm()).max((a - c).norm());
        if !longest.is_finite() {
            continue;
        }
        let steps = ((longest / half_cell).ceil() as usize).clamp(1, 512);
        for i in 0..=steps {
            for j in 0..=steps - i {
                let (u, v) = (i as f64 / steps as f64, j as f64 / steps as f64);
                mark(a + (b - a) * u + (c - a) * v);
            }
        }
    }
    Grid { nx, ny, cells }
}

/// Adds `t` to `out` (best first, one per place and turn; the worst drops
/// out).
pub(crate) fn insert<const N: usize>(out: &mut heapless::Vec<Twin, N>, t: Twin) {
    let same = |q: &Twin| {
        q.yaw_rad == t.yaw_rad
            && (q.offset_m[0] - t.offset_m[0]).hypot(q.offset_m[1] - t.offset_m[1]) < SAME_OFFSET_M
    };
    if let Some(q) = out.iter_mut().find(|q| same(q)) {
        if q.score < t.score {
            *q = t;
        }
    } else if out.is_full() {
        if let Some(last) = out.last_mut().filter(|l| l.score < t.score) {
            *last = t;
        }
    } else {
        let _ = out.push(t);
    }
    out.sort_unstable_by(|a, b| b.score.total_cmp(&a.score));
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An axis-aligned box's four vertical sides, `(x0, y0)`-`(x1, y1)`, 0 to
    /// `h` m high, appended to `mesh` as two triangles each.
    fn walls(mesh: &mut Mesh, (x0, y0, x1, y1): (f32, f32, f32, f32), h: f32) {
        let corners = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]];
        for k in 0..4 {
            let (p, q) = (corners[k], corners[(k + 1) % 4]);
            let base = mesh.positions.len() as u32;
            mesh.positions.extend_from_slice(&[
                [p[0], p[1], 0.0],
                [q[0], q[1], 0.0],
                [q[0], q[1], h],
                [p[0], p[1], h],
            ]);
            mesh.gray.extend_from_slice(&[128.0; 4]);
            mesh.indices
                .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
        }
    }

    /// Two cabinets of different sizes: a layout with no symmetry of its own.
    fn furniture(mesh: &mut Mesh, x: f32, y: f32) {
        walls(mesh, (x, y, x + 1.2, y + 0.6), 1.8);
        walls(mesh, (x + 2.1, y + 1.5, x + 2.5, y + 2.4), 0.9);
    }

    /// Points every 0.1 m on the sides of the cabinets of [`furniture`] at
    /// `(x, y)`, as a camera circling them would see them.
    fn view(x: f64, y: f64) -> Vec<Vector3<f64>> {
        let mut points = Vec::new();
        for (x0, y0, w, d, h) in [(x, y, 1.2, 0.6, 1.8), (x + 2.1, y + 1.5, 0.4, 0.9, 0.9)] {
            let corners = [(x0, y0), (x0 + w, y0), (x0 + w, y0 + d), (x0, y0 + d)];
            for k in 0..4 {
                let ((ax, ay), (bx, by)) = (corners[k], corners[(k + 1) % 4]);
                let steps = (bx - ax).hypot(by - ay) / 0.1;
                for i in 0..steps.round() as usize {
                    let u = i as f64 / steps;
                    for j in 0..(h / 0.2) as usize {
                        let z = 0.1 + 0.2 * j as f64;
                        points.push(Vector3::new(ax + (bx - ax) * u, ay + (by - ay) * u, z));
                    }
                }
            }
        }
        points
    }

    /// Where the camera of [`view`] stands: south-west of the cabinets, in
    /// the room.
    fn camera(x: f64, y: f64) -> Vector3<f64> {
        Vector3::new(x - 0.5, y - 0.8, 1.4)
    }

    #[test]
    fn a_layout_built_twice_is_found_at_its_offset_and_nowhere_else() {
        let mut mesh = Mesh::default();
        furniture(&mut mesh, 0.3, 0.4);
        furniture(&mut mesh, 12.3, 0.4);
        walls(&mut mesh, (-1.0, -1.0, 20.0, 5.0), 3.0);
        let map = MapOccupancy::build(&mesh);
        let mut scratch = map.scratch();
        let mut out: heapless::Vec<Twin, 4> = heapless::Vec::new();
        map.twins(&camera(0.3, 0.4), &view(0.3, 0.4), &mut scratch, &mut out);
        assert_eq!(out.len(), 1, "{out:?}");
        let t = out[0];
        assert!(
            (t.offset_m[0] - 12.0).abs() <= CELL_M + 1e-9 && t.offset_m[1].abs() <= CELL_M + 1e-9,
            "{t:?}"
        );
        assert!(t.score >= MIN_SCORE);
        // From the copy, the twin is back the other way.
        map.twins(&camera(12.3, 0.4), &view(12.3, 0.4), &mut scratch, &mut out);
        assert_eq!(out.len(), 1, "{out:?}");
        assert!(
            (out[0].offset_m[0] + 12.0).abs() <= CELL_M + 1e-9,
            "{out:?}"
        );
    }

    /// A copy that differs a little, as a room's scan differs from its
    /// look-alike's (holes, noise): the small cabinet is 0.2 m high there
    /// instead of 0.9, so about an eighth of the view's points miss. It is
    /// still a twin: the scanned floor's true room fit a wrong cold start's
    /// view with 0.81, and was never checked while a twin needed 0.9.
    #[test]
    fn a_copy_that_differs_a_little_is_still_a_twin() {
        let mut mesh = Mesh::default();
        furniture(&mut mesh, 0.3, 0.4);
        walls(&mut mesh, (12.3, 0.4, 13.5, 1.0), 1.8);
        walls(&mut mesh, (14.4, 1.9, 14.8, 2.8), 0.2);
        walls(&mut mesh, (-1.0, -1.0, 20.0, 5.0), 3.0);
        let out = twins_of_the_first_layout(&mesh);
        assert_eq!(out.len(), 1, "{out:?}");
        let t = out[0];
        assert!(
            (t.offset_m[0] - 12.0).abs() <= CELL_M + 1e-9 && t.offset_m[1].abs() <= CELL_M + 1e-9,
            "{t:?}"
        );
        assert!((MIN_SCORE..0.9).contains(&t.score), "{t:?}");
    }

    /// The twins of the view of the cabinets at (0.3, 0.4) in `mesh`.
    fn twins_of_the_first_layout(mesh: &Mesh) -> heapless::Vec<Twin, 4> {
        let map = MapOccupancy::build(mesh);
        let mut scratch = map.scratch();
        let mut out = heapless::Vec::new();
        map.twins(&camera(0.3, 0.4), &view(0.3, 0.4), &mut scratch, &mut out);
        out
    }

    #[test]
    fn the_fit_at_a_given_offset_is_the_twins_there_and_low_elsewhere() {
        let mut mesh = Mesh::default();
        furniture(&mut mesh, 0.3, 0.4);
        furniture(&mut mesh, 12.3, 0.4);
        // The same cabinets 6 m away, moved apart: a look-alike, not a twin.
        walls(&mut mesh, (6.3, 0.4, 7.5, 1.0), 1.8);
        walls(&mut mesh, (9.9, 2.9, 10.3, 3.8), 0.9);
        walls(&mut mesh, (-1.0, -1.0, 20.0, 5.0), 3.0);
        let map = MapOccupancy::build(&mesh);
        let mut scratch = map.scratch();
        let (c, v) = (camera(0.3, 0.4), view(0.3, 0.4));
        // A few centimeters off the copy's offset: within the slack.
        let (copy, copy_free) = map
            .score_at(&c, &v, (0.0, [12.04, -0.03]), &mut scratch)
            .expect("the copy is on the grid");
        assert!(copy >= MIN_SCORE, "{copy}");
        assert!(copy_free >= MIN_FREE_FRACTION, "{copy_free}");
        let (alike, _) = map
            .score_at(&c, &v, (0.0, [6.0, 0.0]), &mut scratch)
            .expect("the look-alike is on the grid");
        assert!(alike < MIN_SCORE && alike < copy, "{alike}");
        // Off the grid, or too few points: nothing.
        assert!(map
            .score_at(&c, &v, (0.0, [500.0, 0.0]), &mut scratch)
            .is_none());
        assert!(map
            .score_at(&c, &v[..MIN_POINTS - 1], (0.0, [12.0, 0.0]), &mut scratch)
            .is_none());
    }

    #[test]
    fn a_layout_built_once_has_no_twin() {
        let mut mesh = Mesh::default();
        furniture(&mut mesh, 0.3, 0.4);
        // The same cabinets 12 m away, moved apart.
        walls(&mut mesh, (12.3, 0.4, 13.5, 1.0), 1.8);
        walls(&mut mesh, (15.9, 2.9, 16.3, 3.8), 0.9);
        walls(&mut mesh, (-1.0, -1.0, 20.0, 5.0), 3.0);
        let out = twins_of_the_first_layout(&mesh);
        assert!(out.is_empty(), "{out:?}");
    }

    #[test]
    fn bad_input_finds_nothing() {
        let mut mesh = Mesh::default();
        furniture(&mut mesh, 0.3, 0.4);
        let map = MapOccupancy::build(&mesh);
        let mut scratch = map.scratch();
        let mut out: heapless::Vec<Twin, 4> = heapless::Vec::new();
        // Too few points, points off the map, points not finite.
        map.twins(
            &camera(0.3, 0.4),
            &view(0.3, 0.4)[..MIN_POINTS - 1],
            &mut scratch,
            &mut out,
        );
        assert!(out.is_empty());
        let off: Vec<_> = view(-50.0, 0.4);
        map.twins(&camera(-50.0, 0.4), &off, &mut scratch, &mut out);
        assert!(out.is_empty());
        let nan = vec![Vector3::new(f64::NAN, 0.0, 1.0); 100];
        map.twins(&camera(0.3, 0.4), &nan, &mut scratch, &mut out);
        assert!(out.is_empty());
        // A vertex 10 km away would need a grid of 800 M cells: none.
        let mut stray = mesh.clone();
        stray.positions.push([10_000.0, 10_000.0, 1.0]);
        stray.gray.push(128.0);
        let base = stray.positions.len() as u32 - 1;
        stray.indices.extend_from_slice(&[0, 1, base]);
        assert!(MapOccupancy::build(&stray).is_empty());
        // An empty map, and scratch from another map.
        let empty = MapOccupancy::build(&Mesh::default());
        assert!(empty.is_empty());
        empty.twins(&camera(0.3, 0.4), &view(0.3, 0.4), &mut scratch, &mut out);
        assert!(out.is_empty());
        map.twins(
            &camera(0.3, 0.4),
            &view(0.3, 0.4),
            &mut TwinScratch::default(),
            &mut out,
        );
        assert!(out.is_empty());
    }
}
