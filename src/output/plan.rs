//! `star map plan`: a map seen from above, as a floor plan, with what the
//! relocalization database holds and where flights went.
//!
//! Takes the map (world frame, z up), its floor height, a cell size, and
//! optionally the database's view positions and landmarks and one or more
//! trajectories; gives out one PNG, one pixel per cell, +x to the right and
//! +y up: the floor (horizontal surfaces within [`FLOOR_BAND_M`] of its
//! height) light gray, walls and furniture (any surface from
//! [`FLOOR_BAND_M`] to [`OBSTACLE_TOP_M`] above the floor: what a vehicle
//! flying there would meet) dark, landmarks tinting their cells orange, the
//! database's views as blue dots, trajectories as lines, places of given
//! kinds as rings (`star bench reloc --plan`: each query by its outcome), a
//! legend and a scale bar below. Every triangle is sampled at half a cell, so a large
//! wall and a 2 cm scan draw alike. What it shows at a glance, and a table
//! does not: where the database has no views (no relocalization there),
//! which walls carry landmarks, and where a flight went against the
//! rooms.

use std::path::Path;

use nalgebra::Vector3;
use plotters::prelude::*;

use super::plot::{register_font, write_png, FONT};
use crate::dataset::Trajectory;
use crate::map::Mesh;

/// Horizontal surfaces within this of the floor's height are floor, m.
pub const FLOOR_BAND_M: f64 = 0.1;
/// Surfaces up to this above the floor are walls and furniture, m (above:
/// ceilings and lamps, left out).
pub const OBSTACLE_TOP_M: f64 = 2.0;
/// Accepted cell sizes, m.
pub const CELL_M_RANGE: std::ops::RangeInclusive<f64> = 0.005..=1.0;
/// The plan's longer side at most, cells: a larger map gets larger cells.
pub const MAX_SIDE_CELLS: usize = 4000;
/// Pixels around the plan and below it for the legend.
const MARGIN_PX: u32 = 12;
/// The legend: the scale bar's band, then rows of two items.
const LEGEND_TOP_PX: u32 = 34;
const LEGEND_ROW_PX: u32 = 18;
/// Narrowest picture, so the legend fits.
const MIN_WIDTH_PX: u32 = 640;
/// Most samples along a triangle's edge (a 100 m edge at 5 cm cells is
/// 4 000).
const MAX_EDGE_SAMPLES: usize = 8192;

/// Errors drawing the plan.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// The cell size is outside [`CELL_M_RANGE`].
    #[error("cell size {0} m is outside 0.005..=1 m")]
    Cell(f64),
    /// Nothing of the map lies on the floor or up to 2 m above it.
    #[error(
        "nothing of the map lies within 0.1 m of the floor (z = {floor_z_m:.2} m) or up to 2 m \
         above it: is the map z-up in meters (`[map.world_from_mesh]`)?"
    )]
    Empty {
        /// The floor height used, m.
        floor_z_m: f64,
    },
    /// The embedded font could not be loaded.
    #[error("the embedded plot font is invalid")]
    Font,
    /// plotters failed.
    #[error("drawing the plan: {0}")]
    Draw(String),
    /// The PNG could not be written.
    #[error(transparent)]
    Write(#[from] crate::dataset::DatasetError),
}

/// What a plan shows.
#[derive(Debug, Clone, Copy)]
pub struct PlanInput<'a> {
    /// The map, world frame, z up, meters.
    pub mesh: &'a Mesh,
    /// Height of its floor, m.
    pub floor_z_m: f64,
    /// Cell size asked for, m (grown for a map larger than
    /// [`MAX_SIDE_CELLS`] cells).
    pub cell_m: f64,
    /// Positions of the database's views, world meters.
    pub views_m: &'a [[f64; 3]],
    /// Positions of the database's landmarks, world meters.
    pub landmarks_m: &'a [[f32; 3]],
    /// Trajectories to draw, with their labels.
    pub trajectories: &'a [(&'a str, &'a Trajectory)],
    /// Places to mark, by kind (`star bench reloc --plan`: each query's
    /// outcome), drawn last.
    pub marks: &'a [MarkKind<'a>],
}

/// Places of one kind, marked with rings of one color.
#[derive(Debug, Clone, Copy)]
pub struct MarkKind<'a> {
    /// Legend label (the count is added).
    pub label: &'a str,
    /// Ring color.
    pub color: [u8; 3],
    /// World x, y of each place, m.
    pub positions_m: &'a [[f64; 2]],
}

/// The positions of `db`'s views, world meters, as [`PlanInput::views_m`]
/// takes them.
pub fn database_views_m(db: &crate::reloc::RelocDatabase) -> Vec<[f64; 3]> {
    db.entries
        .iter()
        .map(|e| {
            let t = e.world_from_camera.translation.vector;
            [t.x, t.y, t.z]
        })
        .collect()
}

/// What a drawn plan holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanSummary {
    /// Picture size, pixels.
    pub width_px: u32,
    /// See `width_px`.
    pub height_px: u32,
    /// The cell size used, m.
    pub cell_m: f64,
    /// Floor area seen, m².
    pub floor_m2: f64,
    /// Area of cells with walls or furniture, m².
    pub obstacle_m2: f64,
    /// Views and landmarks inside the plan.
    pub views: usize,
    /// See `views`.
    pub landmarks: usize,
    /// Views above cells with nothing of the map (neither floor nor
    /// walls): outside the building, where no flight goes.
    pub views_off_map: usize,
}

/// A cell's content.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cell {
    /// Nothing of the map.
    Unmapped,
    /// Floor.
    Floor,
    /// Walls or furniture (wins over floor).
    Obstacle,
}

impl Cell {
    /// Its color in the picture.
    fn color(self) -> [u8; 3] {
        match self {
            Cell::Unmapped => UNMAPPED,
            Cell::Floor => FLOOR,
            Cell::Obstacle => OBSTACLE,
        }
    }
}

/// The map's cells seen from above.
#[derive(Debug, Clone)]
pub struct PlanGrid {
    /// World x, y of the corner of cell (0, 0), m.
    pub origin_m: [f64; 2],
    /// Cell size, m.
    pub cell_m: f64,
    /// Cells across (x) and up (y).
    pub size: (usize, usize),
    /// Row-major from the lowest y.
    pub cells: Vec<Cell>,
}

impl PlanGrid {
    /// The cells of `mesh` at `cell_m` (grown so that neither side exceeds
    /// [`MAX_SIDE_CELLS`]) around the floor at `floor_z_m`.
    pub fn from_mesh(mesh: &Mesh, floor_z_m: f64, cell_m: f64) -> Result<Self, PlanError> {
        if !CELL_M_RANGE.contains(&cell_m) {
            return Err(PlanError::Cell(cell_m));
        }
        let (lo, hi) = mesh.bounds().ok_or(PlanError::Empty { floor_z_m })?;
        let (lo, hi) = (lo.map(f64::from), hi.map(f64::from));
        let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]);
        let cell_m = cell_m.max(extent / MAX_SIDE_CELLS as f64);
        let size = (
            ((hi[0] - lo[0]) / cell_m).floor() as usize + 1,
            ((hi[1] - lo[1]) / cell_m).floor() as usize + 1,
        );
        let mut grid = Self {
            origin_m: [lo[0], lo[1]],
            cell_m,
            size,
            cells: vec![Cell::Unmapped; size.0 * size.1],
        };
        let (z_lo, z_hi) = (floor_z_m - FLOOR_BAND_M, floor_z_m + OBSTACLE_TOP_M);
        let step_m = 0.5 * cell_m;
        let mut any = false;
        for tri in mesh.indices.chunks_exact(3) {
            let p = |i: u32| {
                mesh.positions
                    .get(i as usize)
                    .map_or(Vector3::repeat(f64::NAN), |v| {
                        Vector3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))
                    })
            };
            let (a, b, c) = (p(tri[0]), p(tri[1]), p(tri[2]));
            let (tz_lo, tz_hi) = (a.z.min(b.z).min(c.z), a.z.max(b.z).max(c.z));
            if !(tz_hi >= z_lo && tz_lo <= z_hi) {
                continue;
            }
            let (ab, ac) = (b - a, c - a);
            let n = ab.cross(&ac);
            let horizontal = n.norm() > 0.0 && (n.z / n.norm()).abs() >= 0.7;
            let edge = ab.norm().max(ac.norm()).max((c - b).norm());
            let k = ((edge / step_m).ceil() as usize).clamp(1, MAX_EDGE_SAMPLES);
            for i in 0..=k {
                for j in 0..=k - i {
                    let (s, t) = (i as f64 / k as f64, j as f64 / k as f64);
                    let q = a + s * ab + t * ac;
                    let dz = q.z - floor_z_m;
                    let class = if horizontal && dz.abs() <= FLOOR_BAND_M {
                        Cell::Floor
                    } else if dz > FLOOR_BAND_M && dz <= OBSTACLE_TOP_M {
                        Cell::Obstacle
                    } else {
                        continue;
                    };
                    if let Some(cell) = grid.cell_mut(q.x, q.y) {
                        any = true;
                        if *cell != Cell::Obstacle {
                            *cell = class;
                        }
                    }
                }
            }
        }
        if any {
            Ok(grid)
        } else {
            Err(PlanError::Empty { floor_z_m })
        }
    }

    /// The cell at world `(x, y)`, if inside; a point less than a cell
    /// outside the map's bounds (a landmark placed from rendered depth
    /// lies a few millimeters off its wall) is in the border cell.
    fn index(&self, x_m: f64, y_m: f64) -> Option<usize> {
        let cx = ((x_m - self.origin_m[0]) / self.cell_m).floor();
        let cy = ((y_m - self.origin_m[1]) / self.cell_m).floor();
        let (w, h) = (self.size.0 as f64, self.size.1 as f64);
        if !(cx >= -1.0 && cy >= -1.0 && cx <= w && cy <= h) {
            return None;
        }
        let cx = cx.clamp(0.0, w - 1.0) as usize;
        let cy = cy.clamp(0.0, h - 1.0) as usize;
        Some(cy * self.size.0 + cx)
    }

    fn cell_mut(&mut self, x_m: f64, y_m: f64) -> Option<&mut Cell> {
        let i = self.index(x_m, y_m)?;
        self.cells.get_mut(i)
    }

    /// The cell at world `(x, y)`, if inside.
    pub fn at(&self, x_m: f64, y_m: f64) -> Option<Cell> {
        self.cells.get(self.index(x_m, y_m)?).copied()
    }

    /// The picture pixel of world `(x, y)` (+y up), if inside the plan.
    fn pixel(&self, x_m: f64, y_m: f64) -> Option<(u32, u32)> {
        let i = self.index(x_m, y_m)?;
        let (cx, cy) = (i % self.size.0, i / self.size.0);
        Some((
            MARGIN_PX + cx as u32,
            MARGIN_PX + (self.size.1 - 1 - cy) as u32,
        ))
    }
}

const UNMAPPED: [u8; 3] = [250, 250, 250];
const FLOOR: [u8; 3] = [215, 215, 215];
const OBSTACLE: [u8; 3] = [45, 45, 45];
const LANDMARK: [u8; 3] = [255, 127, 14];
const VIEW: [u8; 3] = [31, 119, 180];
const TRACKS: [[u8; 3]; 3] = [[44, 160, 44], [214, 39, 40], [148, 103, 189]];

/// An RGB picture being drawn.
struct Canvas {
    width: u32,
    height: u32,
    rgb: Vec<u8>,
}

impl Canvas {
    fn put(&mut self, x: i64, y: i64, color: [u8; 3]) {
        if x < 0 || y < 0 || x >= i64::from(self.width) || y >= i64::from(self.height) {
            return;
        }
        let i = 3 * (y as usize * self.width as usize + x as usize);
        if let Some(px) = self.rgb.get_mut(i..i + 3) {
            px.copy_from_slice(&color);
        }
    }

    /// A square dot of side `2 r + 1`.
    fn dot(&mut self, (x, y): (u32, u32), r: i64, color: [u8; 3]) {
        for dy in -r..=r {
            for dx in -r..=r {
                self.put(i64::from(x) + dx, i64::from(y) + dy, color);
            }
        }
    }

    /// A square ring of half-side `r`, two pixels thick.
    fn ring(&mut self, (x, y): (u32, u32), r: i64, color: [u8; 3]) {
        for dy in -r..=r {
            for dx in -r..=r {
                if dx.abs() >= r - 1 || dy.abs() >= r - 1 {
                    self.put(i64::from(x) + dx, i64::from(y) + dy, color);
                }
            }
        }
    }

    /// A line two pixels wide.
    fn line(&mut self, a: (u32, u32), b: (u32, u32), color: [u8; 3]) {
        let (x0, y0, x1, y1) = (
            i64::from(a.0),
            i64::from(a.1),
            i64::from(b.0),
            i64::from(b.1),
        );
        let steps = (x1 - x0).abs().max((y1 - y0).abs()).max(1);
        for s in 0..=steps {
            let x = x0 + (x1 - x0) * s / steps;
            let y = y0 + (y1 - y0) * s / steps;
            self.put(x, y, color);
            self.put(x + 1, y, color);
            self.put(x, y + 1, color);
        }
    }
}

/// Draws the plan of `input` into `path`.
pub fn plan_png(input: &PlanInput<'_>, path: &Path) -> Result<PlanSummary, PlanError> {
    register_font().map_err(|_| PlanError::Font)?;
    let grid = PlanGrid::from_mesh(input.mesh, input.floor_z_m, input.cell_m)?;
    let width = (grid.size.0 as u32 + 2 * MARGIN_PX).max(MIN_WIDTH_PX);
    let items = 2
        + usize::from(!input.landmarks_m.is_empty())
        + usize::from(!input.views_m.is_empty())
        + input.trajectories.len()
        + input.marks.len();
    let legend_px = LEGEND_TOP_PX + LEGEND_ROW_PX * items.div_ceil(2) as u32;
    let height = grid.size.1 as u32 + 2 * MARGIN_PX + legend_px;
    let mut canvas = Canvas {
        width,
        height,
        rgb: vec![255; width as usize * height as usize * 3],
    };
    let mut summary = PlanSummary {
        width_px: width,
        height_px: height,
        cell_m: grid.cell_m,
        floor_m2: 0.0,
        obstacle_m2: 0.0,
        views: 0,
        landmarks: 0,
        views_off_map: 0,
    };
    let cell_m2 = grid.cell_m * grid.cell_m;
    for (i, cell) in grid.cells.iter().enumerate() {
        let (cx, cy) = (i % grid.size.0, i / grid.size.0);
        match cell {
            Cell::Unmapped => {}
            Cell::Floor => summary.floor_m2 += cell_m2,
            Cell::Obstacle => summary.obstacle_m2 += cell_m2,
        }
        let color = cell.color();
        canvas.put(
            i64::from(MARGIN_PX) + cx as i64,
            i64::from(MARGIN_PX) + (grid.size.1 - 1 - cy) as i64,
            color,
        );
    }
    // Landmarks tint their cell (half orange), so the walls under them
    // still show.
    for l in input.landmarks_m {
        let (x, y) = (f64::from(l[0]), f64::from(l[1]));
        if let (Some(px), Some(cell)) = (grid.pixel(x, y), grid.at(x, y)) {
            let base = cell.color();
            let tint = [0, 1, 2].map(|k| ((u16::from(base[k]) + u16::from(LANDMARK[k])) / 2) as u8);
            canvas.dot(px, 0, tint);
            summary.landmarks += 1;
        }
    }
    for v in input.views_m {
        if let Some(px) = grid.pixel(v[0], v[1]) {
            canvas.dot(px, 1, VIEW);
            summary.views += 1;
            if grid.at(v[0], v[1]) == Some(Cell::Unmapped) {
                summary.views_off_map += 1;
            }
        }
    }
    for (k, (_, trajectory)) in input.trajectories.iter().enumerate() {
        let color = TRACKS[k % TRACKS.len()];
        let mut last = None;
        for pose in &trajectory.poses {
            let t = pose.translation.vector;
            let here = grid.pixel(t.x, t.y);
            if let (Some(a), Some(b)) = (last, here) {
                canvas.line(a, b, color);
            }
            last = here;
        }
    }
    for kind in input.marks {
        for p in kind.positions_m {
            if let Some(px) = grid.pixel(p[0], p[1]) {
                canvas.ring(px, 4, kind.color);
            }
        }
    }
    draw_legend(&mut canvas, input, &grid, (&summary, legend_px))
        .map_err(|e| PlanError::Draw(e.to_string()))?;
    let image = image::RgbImage::from_raw(width, height, canvas.rgb)
        .ok_or_else(|| PlanError::Draw("the picture buffer has the wrong size".into()))?;
    write_png(path, &image)?;
    Ok(summary)
}

fn draw_legend(
    canvas: &mut Canvas,
    input: &PlanInput<'_>,
    grid: &PlanGrid,
    (summary, legend_px): (&PlanSummary, u32),
) -> Result<(), Box<dyn std::error::Error>> {
    let (width, height) = (canvas.width, canvas.height);
    let root = BitMapBackend::with_buffer(&mut canvas.rgb, (width, height)).into_drawing_area();
    let text = |size: u32| (FONT, size).into_font().color(&BLACK);
    let rgb = |c: [u8; 3]| RGBColor(c[0], c[1], c[2]);
    let top = (height - legend_px) as i32;
    let x0 = MARGIN_PX as i32;
    // Scale bar: the round length nearest a fifth of the plan's width.
    let plan_w_m = grid.size.0 as f64 * grid.cell_m;
    let bar_m = [0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0]
        .into_iter()
        .min_by(|a, b| {
            (a - plan_w_m / 5.0)
                .abs()
                .total_cmp(&(b - plan_w_m / 5.0).abs())
        })
        .unwrap_or(1.0);
    let bar_px = (bar_m / grid.cell_m).round() as i32;
    root.draw(&Rectangle::new(
        [(x0, top + 4), (x0 + bar_px, top + 9)],
        BLACK.filled(),
    ))?;
    root.draw(&Text::new(
        format!("{bar_m} m"),
        (x0 + bar_px + 8, top),
        text(14),
    ))?;
    let mut items: Vec<(RGBColor, String)> = vec![
        (rgb(FLOOR), "floor".to_string()),
        (
            rgb(OBSTACLE),
            format!("walls, furniture (0.1-{OBSTACLE_TOP_M} m above the floor)"),
        ),
    ];
    if !input.landmarks_m.is_empty() {
        items.push((
            rgb(LANDMARK),
            format!("relocalization landmarks ({})", summary.landmarks),
        ));
    }
    if !input.views_m.is_empty() {
        items.push((
            rgb(VIEW),
            format!("relocalization views ({})", summary.views),
        ));
    }
    for (k, (label, _)) in input.trajectories.iter().enumerate() {
        items.push((rgb(TRACKS[k % TRACKS.len()]), (*label).to_string()));
    }
    for kind in input.marks {
        items.push((
            rgb(kind.color),
            format!("{} ({})", kind.label, kind.positions_m.len()),
        ));
    }
    let columns = 2;
    let column_px = ((width - 2 * MARGIN_PX) / columns) as i32;
    for (k, (color, label)) in items.iter().enumerate() {
        let (col, row) = ((k % columns as usize) as i32, (k / columns as usize) as i32);
        let (x, y) = (x0 + col * column_px, top + 22 + row * LEGEND_ROW_PX as i32);
        root.draw(&Rectangle::new(
            [(x, y + 2), (x + 12, y + 12)],
            color.filled(),
        ))?;
        root.draw(&Text::new(label.clone(), (x + 18, y), text(13)))?;
    }
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A 4 x 3 m room, walls 2.5 m high, as four wall quads and a floor
    /// quad of two triangles each, and a 1 m cube table in the middle, on
    /// a floor at `z0`.
    fn room(z0: f32) -> Mesh {
        let mut mesh = Mesh::default();
        let mut quad = |p: [[f32; 3]; 4]| {
            let base = mesh.positions.len() as u32;
            mesh.positions.extend_from_slice(&p);
            mesh.gray.extend_from_slice(&[128.0; 4]);
            mesh.indices
                .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
        };
        let h = z0 + 2.5;
        quad([
            [0.0, 0.0, z0],
            [4.0, 0.0, z0],
            [4.0, 3.0, z0],
            [0.0, 3.0, z0],
        ]);
        quad([[0.0, 0.0, z0], [4.0, 0.0, z0], [4.0, 0.0, h], [0.0, 0.0, h]]);
        quad([[4.0, 0.0, z0], [4.0, 3.0, z0], [4.0, 3.0, h], [4.0, 0.0, h]]);
        quad([[4.0, 3.0, z0], [0.0, 3.0, z0], [0.0, 3.0, h], [4.0, 3.0, h]]);
        quad([[0.0, 3.0, z0], [0.0, 0.0, z0], [0.0, 0.0, h], [0.0, 3.0, h]]);
        // The table's top, 0.75 m up.
        let t = z0 + 0.75;
        quad([[1.5, 1.0, t], [2.5, 1.0, t], [2.5, 2.0, t], [1.5, 2.0, t]]);
        // A ceiling, left out.
        quad([[0.0, 0.0, h], [4.0, 0.0, h], [4.0, 3.0, h], [0.0, 3.0, h]]);
        mesh
    }

    #[test]
    fn walls_and_furniture_are_dark_the_floor_light_the_ceiling_left_out() {
        let grid = PlanGrid::from_mesh(&room(1.0), 1.0, 0.05).expect("a plan");
        assert_eq!(grid.size, (81, 61));
        assert_eq!(grid.at(1.0, 0.5), Some(Cell::Floor));
        assert_eq!(grid.at(3.5, 2.5), Some(Cell::Floor));
        assert_eq!(grid.at(2.0, 1.5), Some(Cell::Obstacle), "the table");
        for wall in [(2.0, 0.0), (4.0, 1.5), (2.0, 3.0), (0.0, 1.5)] {
            assert_eq!(grid.at(wall.0, wall.1), Some(Cell::Obstacle), "{wall:?}");
        }
        assert_eq!(grid.at(-1.0, 1.0), None);
        // With the floor taken 1 m too low, the floor is not floor.
        let low = PlanGrid::from_mesh(&room(1.0), 0.0, 0.05).expect("walls still");
        assert_eq!(low.at(1.0, 0.5), Some(Cell::Obstacle));
    }

    #[test]
    fn a_map_away_from_the_floor_or_a_bad_cell_is_an_error() {
        assert!(matches!(
            PlanGrid::from_mesh(&room(0.0), 10.0, 0.05),
            Err(PlanError::Empty { .. })
        ));
        assert!(matches!(
            PlanGrid::from_mesh(&Mesh::default(), 0.0, 0.05),
            Err(PlanError::Empty { .. })
        ));
        for bad in [0.0, -0.1, 2.0, f64::NAN] {
            assert!(matches!(
                PlanGrid::from_mesh(&room(0.0), 0.0, bad),
                Err(PlanError::Cell(_))
            ));
        }
    }

    #[test]
    fn a_large_map_gets_larger_cells() {
        let mut mesh = room(0.0);
        for p in &mut mesh.positions {
            p[0] *= 2000.0;
        }
        let grid = PlanGrid::from_mesh(&mesh, 0.0, 0.05).expect("a plan");
        assert!(grid.size.0 <= MAX_SIDE_CELLS + 1, "{:?}", grid.size);
        assert!((grid.cell_m - 2.0).abs() < 1e-9, "{}", grid.cell_m);
    }

    #[test]
    fn the_picture_has_the_views_landmarks_and_trajectory_where_they_are() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("plan.png");
        let mut mesh = room(0.0);
        // A pillar 4 m east of the room: unmapped cells between.
        let base = mesh.positions.len() as u32;
        mesh.positions.extend_from_slice(&[
            [8.0, 1.0, 0.0],
            [8.0, 1.2, 0.0],
            [8.0, 1.2, 1.5],
            [8.0, 1.0, 1.5],
        ]);
        mesh.gray.extend_from_slice(&[128.0; 4]);
        mesh.indices
            .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
        let mut track = Trajectory::default();
        for k in 0..5 {
            track.push(
                f64::from(k),
                Pose::from_parts(
                    Translation3::new(0.5 + 0.5 * f64::from(k), 2.5, 1.2),
                    UnitQuaternion::identity(),
                ),
            );
        }
        let input = PlanInput {
            mesh: &mesh,
            floor_z_m: 0.0,
            cell_m: 0.05,
            views_m: &[[0.5, 0.5, 1.2], [99.0, 0.5, 1.2], [6.0, 1.5, 1.2]],
            landmarks_m: &[[2.0, 0.02, 1.0]],
            trajectories: &[("truth", &track)],
            marks: &[MarkKind {
                label: "refused",
                color: [200, 0, 200],
                positions_m: &[[3.0, 1.5]],
            }],
        };
        let summary = plan_png(&input, &path).expect("drawn");
        assert_eq!(
            (summary.views, summary.views_off_map, summary.landmarks),
            (2, 1, 1),
            "one view outside the plan, one between the room and the pillar"
        );
        // 81 x 61 cells of 5 cm, less the walls' 280 and the table's 441.
        let floor_m2 = (81.0 * 61.0 - 280.0 - 441.0) * 0.0025;
        assert!(
            (summary.floor_m2 - floor_m2).abs() < 1e-6,
            "{summary:?}, {floor_m2}"
        );
        let image = image::open(&path).expect("a PNG").to_rgb8();
        assert_eq!(
            (image.width(), image.height()),
            (summary.width_px, summary.height_px)
        );
        let at = |x: f64, y: f64| {
            let grid = PlanGrid::from_mesh(&mesh, 0.0, 0.05).expect("a plan");
            let (px, py) = grid.pixel(x, y).expect("inside");
            image.get_pixel(px, py).0
        };
        assert_eq!(at(0.5, 0.5), VIEW);
        // Half orange over the wall.
        assert_eq!(at(2.0, 0.02), [150, 86, 29]);
        assert_eq!(at(1.25, 2.5), TRACKS[0]);
        // The mark's ring, 4 cells right of its place; its center is left.
        assert_eq!(at(3.2, 1.5), [200, 0, 200]);
        assert_eq!(at(3.0, 1.5), FLOOR);
        assert_eq!(at(3.5, 1.0), FLOOR);
        assert_eq!(at(4.0, 1.0), OBSTACLE);
    }
}
