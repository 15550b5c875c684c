//! Boxes standing on the floor: furniture (in map and truth) and occluders
//! (truth only). Takes the room size and a seeded generator; gives out
//! non-overlapping [`SceneBox`]es and their textured faces.

use super::build::{Face, MeshBuilder, UvMap};
use super::lambert;
use super::params::SceneParams;
use crate::rng::SplitMix64;

/// A box standing on the floor, rotated about `z`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneBox {
    /// Footprint center `[x, y]`, meters.
    pub center_xy_m: [f64; 2],
    /// Half extents along the box's own x and y axes, meters.
    pub half_size_m: [f64; 2],
    /// Height above the floor, meters.
    pub height_m: f64,
    /// `[cos(yaw), sin(yaw)]` of the box's x axis in the world.
    pub yaw_cos_sin: [f64; 2],
}

impl SceneBox {
    /// True when `p_world` is inside the box grown by `margin_m`.
    pub fn contains(&self, p_world: [f64; 3], margin_m: f64) -> bool {
        let dx = p_world[0] - self.center_xy_m[0];
        let dy = p_world[1] - self.center_xy_m[1];
        let [c, s] = self.yaw_cos_sin;
        let (lx, ly) = (c * dx + s * dy, -s * dx + c * dy);
        lx.abs() < self.half_size_m[0] + margin_m
            && ly.abs() < self.half_size_m[1] + margin_m
            && p_world[2] < self.height_m + margin_m
    }

    /// Radius of the footprint's circumscribed circle.
    pub fn radius_m(&self) -> f64 {
        (self.half_size_m[0] * self.half_size_m[0] + self.half_size_m[1] * self.half_size_m[1])
            .sqrt()
    }
}

/// Places up to `count` boxes without overlapping `existing` or each other.
/// Furniture stands against a wall half of the time; occluders are
/// person- or plant-sized and stand in the open.
pub(super) fn place_boxes(
    rng: &mut SplitMix64,
    params: &SceneParams,
    existing: &[SceneBox],
    count: usize,
    occluder: bool,
) -> Vec<SceneBox> {
    let [lx, ly, _] = params.room_size_m;
    let mut placed: Vec<SceneBox> = Vec::new();
    for _ in 0..count {
        for _attempt in 0..200 {
            let (half, height) = if occluder {
                (
                    [rng.range(0.15, 0.3), rng.range(0.12, 0.25)],
                    rng.range(1.0, 1.85),
                )
            } else {
                (
                    [rng.range(0.25, 0.8), rng.range(0.2, 0.45)],
                    rng.range(0.4, 1.2),
                )
            };
            let against_wall = !occluder && rng.chance(0.5);
            let (center, yaw) = if against_wall {
                let wall = rng.below(4);
                let along = if wall % 2 == 0 { lx } else { ly };
                let t = rng.range(half[0] + 0.05, along - half[0] - 0.05);
                let off = half[1] + 0.02;
                match wall {
                    0 => ([t, off], [1.0, 0.0]),
                    1 => ([lx - off, t], [0.0, 1.0]),
                    2 => ([t, ly - off], [1.0, 0.0]),
                    _ => ([off, t], [0.0, 1.0]),
                }
            } else {
                let r = (half[0] * half[0] + half[1] * half[1]).sqrt() + 0.3;
                let yaw = random_unit(rng);
                ([rng.range(r, lx - r), rng.range(r, ly - r)], yaw)
            };
            let candidate = SceneBox {
                center_xy_m: center,
                half_size_m: half,
                height_m: height,
                yaw_cos_sin: yaw,
            };
            let clear = existing.iter().chain(&placed).all(|o| {
                let dx = o.center_xy_m[0] - center[0];
                let dy = o.center_xy_m[1] - center[1];
                (dx * dx + dy * dy).sqrt() > o.radius_m() + candidate.radius_m() + 0.35
            });
            let inside = center[0] > 0.0 && center[0] < lx && center[1] > 0.0 && center[1] < ly;
            if clear && inside {
                placed.push(candidate);
                break;
            }
        }
    }
    placed
}

/// A random unit vector in the plane, without trigonometry.
fn random_unit(rng: &mut SplitMix64) -> [f64; 2] {
    for _ in 0..32 {
        let (a, b) = (rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
        let n = (a * a + b * b).sqrt();
        if n > 0.1 && n <= 1.0 {
            return [a / n, b / n];
        }
    }
    [1.0, 0.0]
}

/// Adds the top and four sides of `b`, each face on a random part of an
/// atlas of `atlas_m` meters.
pub(super) fn add_box(
    builder: &mut MeshBuilder,
    b: &SceneBox,
    texture: usize,
    atlas_m: [f64; 2],
    rng: &mut SplitMix64,
) {
    let [c, s] = b.yaw_cos_sin;
    let (ex, ey) = ([c, s, 0.0], [-s, c, 0.0]);
    let [hx, hy] = b.half_size_m;
    let h = b.height_m;
    let at = |a: f64, bb: f64, z: f64| {
        [
            b.center_xy_m[0] + a * ex[0] + bb * ey[0],
            b.center_xy_m[1] + a * ex[1] + bb * ey[1],
            z,
        ]
    };
    let neg = |v: [f64; 3]| [-v[0], -v[1], -v[2]];
    let down = [0.0, 0.0, -1.0];
    let faces = [
        Face {
            origin: at(-hx, -hy, h),
            u_axis: ex,
            v_axis: ey,
            u_len_m: 2.0 * hx,
            v_len_m: 2.0 * hy,
            normal: [0.0, 0.0, 1.0],
        },
        Face {
            origin: at(hx, -hy, h),
            u_axis: ey,
            v_axis: down,
            u_len_m: 2.0 * hy,
            v_len_m: h,
            normal: ex,
        },
        Face {
            origin: at(hx, hy, h),
            u_axis: neg(ex),
            v_axis: down,
            u_len_m: 2.0 * hx,
            v_len_m: h,
            normal: ey,
        },
        Face {
            origin: at(-hx, hy, h),
            u_axis: neg(ey),
            v_axis: down,
            u_len_m: 2.0 * hy,
            v_len_m: h,
            normal: neg(ex),
        },
        Face {
            origin: at(-hx, -hy, h),
            u_axis: ex,
            v_axis: down,
            u_len_m: 2.0 * hx,
            v_len_m: h,
            normal: neg(ey),
        },
    ];
    for face in &faces {
        let span = [
            (face.u_len_m / atlas_m[0]).min(1.0),
            (face.v_len_m / atlas_m[1]).min(1.0),
        ];
        let uv = UvMap {
            offset: [rng.range(0.0, 1.0 - span[0]), rng.range(0.0, 1.0 - span[1])],
            scale: [span[0] / face.u_len_m, span[1] / face.v_len_m],
        };
        let top = face.normal[2] > 0.5;
        let shade = |p: [f64; 3]| {
            let floor_dark = if top {
                1.0
            } else {
                1.0 - 0.2 * (1.0 - (p[2] / 0.3).min(1.0))
            };
            lambert(face.normal) * floor_dark
        };
        builder.face(face, texture, uv, &shade);
    }
}
