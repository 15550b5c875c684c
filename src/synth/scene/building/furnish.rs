//! Furniture and occluders of one room design, in the room's frame, kept
//! off the path the tour takes through the room.
//!
//! Takes the room size, a [`KeepOut`] (the tour's loop and its way in from
//! the door) and a seeded generator; gives out non-overlapping
//! [`SceneBox`]es: furniture against the side and back walls, occluders
//! (person- or plant-sized) standing in the open.

use super::super::objects::SceneBox;
use crate::rng::SplitMix64;

/// Where boxes may not stand: inside `polygon`, or within `distance_m`
/// (plus the box's footprint radius) of any of `segments`.
#[derive(Debug, Clone)]
pub(super) struct KeepOut {
    /// A closed polygon, room frame.
    pub polygon: Vec<[f64; 2]>,
    /// Segments, room frame.
    pub segments: Vec<[[f64; 2]; 2]>,
    /// Clearance from the segments, meters.
    pub distance_m: f64,
}

impl KeepOut {
    fn allows(&self, b: &SceneBox) -> bool {
        let c = b.center_xy_m;
        !inside(&self.polygon, c)
            && self
                .segments
                .iter()
                .all(|&[p, q]| segment_distance(c, p, q) > self.distance_m + b.radius_m())
    }
}

/// Even-odd test of `p` against the closed polygon `poly`.
fn inside(poly: &[[f64; 2]], p: [f64; 2]) -> bool {
    let mut odd = false;
    for (i, a) in poly.iter().enumerate() {
        let b = poly[(i + 1) % poly.len()];
        if (a[1] > p[1]) != (b[1] > p[1]) {
            let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
            if p[0] < x {
                odd = !odd;
            }
        }
    }
    odd
}

fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
}

/// Places up to `count` boxes in a `[w, d]` room (room frame: the door
/// wall is `y = 0`), clear of `keep_out`, of `existing` and of each other.
pub(super) fn place(
    rng: &mut SplitMix64,
    [w, d]: [f64; 2],
    keep_out: &KeepOut,
    existing: &[SceneBox],
    count: usize,
    occluder: bool,
) -> Vec<SceneBox> {
    let mut placed: Vec<SceneBox> = Vec::new();
    for _ in 0..count {
        for _attempt in 0..200 {
            let candidate = if occluder {
                let half = [rng.range(0.15, 0.3), rng.range(0.12, 0.25)];
                let height = rng.range(1.0, 1.85);
                SceneBox {
                    center_xy_m: [rng.range(0.6, w - 0.6), rng.range(0.6, d - 0.6)],
                    half_size_m: half,
                    height_m: height,
                    yaw_cos_sin: [1.0, 0.0],
                }
            } else {
                let half = [rng.range(0.3, 0.9), rng.range(0.2, 0.45)];
                let height = rng.range(0.45, 1.9);
                let off = half[1] + 0.02;
                // Right, back or left wall; never the door wall.
                let (center, yaw) = match rng.below(3) {
                    0 => (
                        [w - off, rng.range(half[0] + 0.05, d - half[0] - 0.05)],
                        [0.0, 1.0],
                    ),
                    1 => (
                        [rng.range(half[0] + 0.05, w - half[0] - 0.05), d - off],
                        [1.0, 0.0],
                    ),
                    _ => (
                        [off, rng.range(half[0] + 0.05, d - half[0] - 0.05)],
                        [0.0, 1.0],
                    ),
                };
                SceneBox {
                    center_xy_m: center,
                    half_size_m: half,
                    height_m: height,
                    yaw_cos_sin: yaw,
                }
            };
            let c = candidate.center_xy_m;
            let clear = existing.iter().chain(&placed).all(|o| {
                let (dx, dy) = (o.center_xy_m[0] - c[0], o.center_xy_m[1] - c[1]);
                dx.hypot(dy) > o.radius_m() + candidate.radius_m() + 0.2
            });
            let fits = c[0] > 0.0 && c[0] < w && c[1] > 0.0 && c[1] < d;
            if clear && fits && keep_out.allows(&candidate) {
                placed.push(candidate);
                break;
            }
        }
    }
    placed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn boxes_keep_off_the_path_and_each_other() {
        let keep_out = KeepOut {
            polygon: vec![[2.5, 1.2], [1.5, 3.0], [2.5, 4.5], [3.5, 3.0]],
            segments: vec![[[2.5, -1.0], [2.5, 1.2]]],
            distance_m: 0.9,
        };
        let mut rng = SplitMix64::new(4);
        let boxes = place(&mut rng, [5.0, 6.0], &keep_out, &[], 8, false);
        assert!(!boxes.is_empty());
        for b in &boxes {
            assert!(keep_out.allows(b));
            assert!(!b.contains([2.5, 3.0, 1.0], 0.3), "{b:?}");
        }
        let occluders = place(&mut rng, [5.0, 6.0], &keep_out, &boxes, 3, true);
        for o in &occluders {
            for b in &boxes {
                let d = (o.center_xy_m[0] - b.center_xy_m[0])
                    .hypot(o.center_xy_m[1] - b.center_xy_m[1]);
                assert!(d > o.radius_m() + b.radius_m());
            }
        }
    }
}
