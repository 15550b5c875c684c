//! Where a frame's landmark matches gather on the floor plan: a vote of
//! the matched landmarks' positions in square cells, and the few places
//! (peaks of that vote) worth matching the frame against on their own.
//!
//! Owns the vote grid and its peak search; [`super::landmarks`] uses it
//! when the ratio test over the whole map (or the whole prior region)
//! gives no pose. On a floor of look-alike rooms a corner's best match and
//! its runner-up are the same corner in two twin rooms, so the ratio test
//! refuses it; matched again against the landmarks of one place only, its
//! twin is out of reach and the test keeps it. The places are the peaks
//! of the votes of both matches, so a twin that took the best match of
//! most corners does not hide the place that took the runner-ups.
//!
//! After [`PlaceVote::new`] nothing here allocates.

use nalgebra::Vector2;

/// Edge of a vote cell, meters (at least: a large map gets larger cells,
/// so that the grid stays within [`MAX_CELLS`]).
pub const VOTE_CELL_M: f32 = 2.0;
/// Most cells in the vote grid.
const MAX_CELLS: usize = 1 << 18;
/// Places given at most.
pub const MAX_PLACES: usize = 4;
/// A place's score is the votes in the 3 x 3 cells around it; a second
/// place is at least this many cells (Chebyshev) from every place before
/// it.
const PLACE_SEPARATION_CELLS: i64 = 2;

/// A peak of the vote.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Place {
    /// Mean position of the votes around the peak, world x and y, meters.
    pub center_m: Vector2<f32>,
    /// Votes in the 3 x 3 cells around it.
    pub votes: u32,
}

/// The vote grid over a map's landmarks.
#[derive(Debug, Clone)]
pub struct PlaceVote {
    origin_m: [f32; 2],
    cell_m: f32,
    nx: usize,
    ny: usize,
    /// Votes and the sums of the voting positions, per cell.
    count: Vec<u32>,
    sum_m: Vec<[f32; 2]>,
    /// Cells voted for since the last [`Self::clear`], each once.
    touched: Vec<(u32, u32)>,
    max_touched: usize,
    places: Vec<Place>,
    picked: Vec<(i64, i64)>,
}

impl PlaceVote {
    /// A grid over the horizontal extent of `positions_m` (world, meters),
    /// for at most `max_votes` votes between clears.
    pub fn new(positions_m: &[[f32; 3]], max_votes: usize) -> Self {
        let mut lo = [f32::INFINITY; 2];
        let mut hi = [f32::NEG_INFINITY; 2];
        for p in positions_m {
            for i in 0..2 {
                if p[i].is_finite() {
                    lo[i] = lo[i].min(p[i]);
                    hi[i] = hi[i].max(p[i]);
                }
            }
        }
        if lo[0] > hi[0] || lo[1] > hi[1] {
            lo = [0.0; 2];
            hi = [0.0; 2];
        }
        let area = (hi[0] - lo[0] + VOTE_CELL_M) * (hi[1] - lo[1] + VOTE_CELL_M);
        let cell_m = VOTE_CELL_M.max((area / MAX_CELLS as f32).sqrt());
        let nx = ((hi[0] - lo[0]) / cell_m) as usize + 1;
        let ny = ((hi[1] - lo[1]) / cell_m) as usize + 1;
        Self {
            origin_m: lo,
            cell_m,
            nx,
            ny,
            count: vec![0; nx * ny],
            sum_m: vec![[0.0; 2]; nx * ny],
            touched: Vec::with_capacity(max_votes),
            max_touched: max_votes,
            places: Vec::with_capacity(MAX_PLACES),
            picked: Vec::with_capacity(MAX_PLACES),
        }
    }

    /// Edge of a cell, meters.
    pub fn cell_m(&self) -> f32 {
        self.cell_m
    }

    fn cell_of(&self, x_m: f32, y_m: f32) -> Option<(i64, i64)> {
        let fx = ((x_m - self.origin_m[0]) / self.cell_m).floor();
        let fy = ((y_m - self.origin_m[1]) / self.cell_m).floor();
        if !(fx >= 0.0 && fy >= 0.0) {
            return None;
        }
        let (cx, cy) = (fx as i64, fy as i64);
        (cx < self.nx as i64 && cy < self.ny as i64).then_some((cx, cy))
    }

    /// A vote for a landmark at `position_m` (world, meters); outside the
    /// grid, none. Beyond the votes [`Self::new`] was given room for, the
    /// vote is dropped.
    pub fn vote(&mut self, position_m: &[f32; 3]) {
        let Some((cx, cy)) = self.cell_of(position_m[0], position_m[1]) else {
            return;
        };
        let c = cy as usize * self.nx + cx as usize;
        if self.count[c] == 0 {
            if self.touched.len() >= self.max_touched {
                return;
            }
            self.touched.push((cx as u32, cy as u32));
        }
        self.count[c] += 1;
        self.sum_m[c][0] += position_m[0];
        self.sum_m[c][1] += position_m[1];
    }

    /// Votes and summed positions in the 3 x 3 cells around `(cx, cy)`.
    fn around(&self, cx: i64, cy: i64) -> (u32, [f32; 2]) {
        let mut n = 0;
        let mut s = [0.0f32; 2];
        for y in (cy - 1).max(0)..=(cy + 1).min(self.ny as i64 - 1) {
            for x in (cx - 1).max(0)..=(cx + 1).min(self.nx as i64 - 1) {
                let c = y as usize * self.nx + x as usize;
                n += self.count[c];
                s[0] += self.sum_m[c][0];
                s[1] += self.sum_m[c][1];
            }
        }
        (n, s)
    }

    /// What the last [`Self::places`] gave.
    pub fn places_found(&self) -> &[Place] {
        &self.places
    }

    /// The peaks of the votes, most votes first: at most [`MAX_PLACES`],
    /// each with at least `min_votes` in the 3 x 3 cells around it, and
    /// [`PLACE_SEPARATION_CELLS`] apart. Then the grid is cleared.
    pub fn places(&mut self, min_votes: u32) -> &[Place] {
        self.places.clear();
        self.picked.clear();
        // The touched cells by their score, best first.
        let mut scored = std::mem::take(&mut self.touched);
        scored.sort_unstable_by_key(|&(x, y)| {
            let (n, _) = self.around(x as i64, y as i64);
            (std::cmp::Reverse(n), y, x)
        });
        for &(x, y) in &scored {
            if self.places.len() == MAX_PLACES {
                break;
            }
            let (cx, cy) = (x as i64, y as i64);
            if self
                .picked
                .iter()
                .any(|&(px, py)| (px - cx).abs().max((py - cy).abs()) <= PLACE_SEPARATION_CELLS)
            {
                continue;
            }
            let (n, s) = self.around(cx, cy);
            if n < min_votes.max(1) {
                break;
            }
            self.picked.push((cx, cy));
            self.places.push(Place {
                center_m: Vector2::new(s[0] / n as f32, s[1] / n as f32),
                votes: n,
            });
        }
        for &(x, y) in &scored {
            let c = y as usize * self.nx + x as usize;
            self.count[c] = 0;
            self.sum_m[c] = [0.0; 2];
        }
        scored.clear();
        self.touched = scored;
        &self.places
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> PlaceVote {
        PlaceVote::new(&[[0.0, 0.0, 0.0], [40.0, 20.0, 3.0]], 1000)
    }

    #[test]
    fn two_look_alike_rooms_give_two_places_the_larger_first() {
        let mut v = grid();
        for i in 0..30 {
            v.vote(&[5.0 + (i % 5) as f32 * 0.5, 5.0 + (i / 10) as f32, 1.0]);
        }
        for i in 0..20 {
            v.vote(&[25.0 + (i % 5) as f32 * 0.5, 5.0 + (i / 10) as f32, 1.0]);
        }
        // Scattered single votes are not places.
        v.vote(&[38.0, 18.0, 1.0]);
        let places = v.places(5).to_vec();
        assert_eq!(places.len(), 2, "{places:?}");
        assert_eq!(places[0].votes, 30);
        assert_eq!(places[1].votes, 20);
        assert!((places[0].center_m.x - 6.0).abs() < 0.01, "{places:?}");
        assert!((places[1].center_m.x - 26.0).abs() < 0.01, "{places:?}");
        assert!((places[0].center_m.y - 6.0).abs() < 1.01, "{places:?}");
    }

    #[test]
    fn the_grid_is_cleared_after_the_places_are_read() {
        let mut v = grid();
        for _ in 0..10 {
            v.vote(&[10.0, 10.0, 1.0]);
        }
        assert_eq!(v.places(5).len(), 1);
        assert!(v.places(1).is_empty());
        for _ in 0..10 {
            v.vote(&[30.0, 10.0, 1.0]);
        }
        let p = v.places(5).to_vec();
        assert_eq!(p.len(), 1);
        assert!((p[0].center_m.x - 30.0).abs() < 1e-4);
    }

    #[test]
    fn votes_around_one_peak_make_one_place() {
        let mut v = grid();
        // A room's corners spread over 6 m: neighbouring cells, one place.
        for i in 0..60 {
            v.vote(&[10.0 + (i % 6) as f32, 8.0 + (i / 20) as f32, 1.0]);
        }
        let p = v.places(5).to_vec();
        assert_eq!(p.len(), 1, "{p:?}");
        assert!(p[0].votes >= 40, "{p:?}");
    }

    #[test]
    fn votes_outside_the_grid_or_beyond_its_room_are_dropped() {
        let mut v = PlaceVote::new(&[[0.0, 0.0, 0.0], [10.0, 10.0, 0.0]], 2);
        v.vote(&[-50.0, 0.0, 0.0]);
        v.vote(&[f32::NAN, 0.0, 0.0]);
        v.vote(&[1.0, 1.0, 0.0]);
        v.vote(&[9.0, 9.0, 0.0]);
        // A third cell: no room left for it.
        v.vote(&[5.0, 5.0, 0.0]);
        let p = v.places(1).to_vec();
        assert_eq!(p.len(), 2, "{p:?}");
        assert!(p.iter().all(|p| p.votes == 1));
    }

    #[test]
    fn an_empty_map_has_a_grid_and_no_places() {
        let mut v = PlaceVote::new(&[], 10);
        v.vote(&[0.0, 0.0, 0.0]);
        assert_eq!(v.places(1).len(), 1);
        assert!(v.cell_m() >= VOTE_CELL_M);
    }
}
