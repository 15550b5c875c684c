//! A room-to-room tour: the ground path of the `room_to_room` trajectory
//! kind, through the rooms and doors of a building floor.
//!
//! Takes each room's [`RoomRoute`] (world-frame points in the horizontal
//! plane: the corridor point in front of its door, the door, a point just
//! inside, and a small loop in the room), a seed and a length; gives out a
//! [`Tour`]: the polyline that starts in one room, goes round its loop,
//! out through its door, along the corridor and into the next room by the
//! door x order, round that room's loop and out again, room after room
//! (turning back at either end of the corridor), smoothed.
//!
//! Smoothing: the polyline `P(s)` (arc length `s`) is averaged by a
//! triangular kernel of half-width `2w` (two box filters of half-width
//! `w`), in closed form from its first and second integrals (piecewise
//! quadratic and cubic): the curve is C2 and its tangent C1, so a camera
//! looking along it turns without jumps in angular speed. A corner is cut
//! by at most about `w`; straight legs longer than `4w` keep a straight
//! middle (the passage through a door).

/// Half-width of each of the two box filters, meters.
pub const SMOOTH_HALF_WIDTH_M: f64 = 0.35;

/// Where a tour goes in one room, world frame, meters (horizontal plane).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoomRoute {
    /// On the corridor's center line, in front of the door.
    pub corridor_m: [f64; 2],
    /// The middle of the doorway.
    pub door_m: [f64; 2],
    /// Just inside the room, in front of the door.
    pub inside_m: [f64; 2],
    /// The loop in the room after `inside_m`: left, back, right (the tour
    /// returns to `inside_m` after it).
    pub loop_m: [[f64; 2]; 3],
}

/// A smoothed polyline, parametrized by the arc length of the polyline.
#[derive(Debug, Clone, PartialEq)]
pub struct Tour {
    /// Polyline vertices.
    points: Vec<[f64; 2]>,
    /// Arc length at each vertex.
    s: Vec<f64>,
    /// `I(s_i)`: integral of `P` from 0 to `s_i`.
    first: Vec<[f64; 2]>,
    /// `K(s_i)`: integral of `I` from 0 to `s_i`.
    second: Vec<[f64; 2]>,
    /// The rooms visited, in order.
    rooms: Vec<usize>,
}

impl Tour {
    /// The tour through `routes` (one per room, in corridor order) for
    /// `seed`, at least `length_m` long: the start room and direction come
    /// from the seed. `None` when there is no room.
    pub fn through(routes: &[RoomRoute], seed: u64, length_m: f64) -> Option<Self> {
        if routes.is_empty() {
            return None;
        }
        let n = routes.len();
        let mut rng = crate::rng::SplitMix64::new(seed ^ 0x70_u64.wrapping_mul(0x9E37_79B9));
        let mut room = rng.below(n);
        let mut step: isize = if rng.chance(0.5) { 1 } else { -1 };
        let first = routes.get(room)?;
        let mut points = vec![first.loop_m[1], first.loop_m[2], first.inside_m];
        points.extend([first.door_m, first.corridor_m]);
        let mut rooms = vec![room];
        let mut length = polyline_length(&points);
        // A generous cap: every room a hundred times over.
        for _ in 0..100 * n.max(1) {
            if length >= length_m {
                break;
            }
            if n > 1 {
                let next = room as isize + step;
                if next < 0 || next >= n as isize {
                    step = -step;
                }
                room = (room as isize + step) as usize;
            }
            let r = routes.get(room)?;
            let [l, b, rr] = r.loop_m;
            points.extend([
                r.corridor_m,
                r.door_m,
                r.inside_m,
                l,
                b,
                rr,
                r.inside_m,
                r.door_m,
                r.corridor_m,
            ]);
            rooms.push(room);
            length = polyline_length(&points);
        }
        Some(Self::new(points, rooms))
    }

    fn new(raw: Vec<[f64; 2]>, rooms: Vec<usize>) -> Self {
        let mut points: Vec<[f64; 2]> = Vec::with_capacity(raw.len());
        for p in raw {
            if points.last().is_none_or(|q| dist(*q, p) > 1e-9) {
                points.push(p);
            }
        }
        let mut s = vec![0.0];
        let mut first = vec![[0.0; 2]];
        let mut second = vec![[0.0; 2]];
        for i in 1..points.len() {
            let (a, b) = (points[i - 1], points[i]);
            let len = dist(a, b);
            let d = [(b[0] - a[0]) / len, (b[1] - a[1]) / len];
            let (ip, kp) = (first[i - 1], second[i - 1]);
            s.push(s[i - 1] + len);
            first.push([0, 1].map(|k| ip[k] + a[k] * len + d[k] * len * len / 2.0));
            second.push([0, 1].map(|k| {
                kp[k] + ip[k] * len + a[k] * len * len / 2.0 + d[k] * len * len * len / 6.0
            }));
        }
        Self {
            points,
            s,
            first,
            second,
            rooms,
        }
    }

    /// Length of the polyline, meters.
    pub fn length_m(&self) -> f64 {
        self.s.last().copied().unwrap_or(0.0)
    }

    /// The rooms visited, in order (indices into the routes given).
    pub fn rooms(&self) -> &[usize] {
        &self.rooms
    }

    /// The segment holding `s` (clamped), its start arc length, start
    /// point, unit direction, and the integrals at its start.
    fn segment(&self, s: f64) -> (f64, [f64; 2], [f64; 2], [f64; 2], [f64; 2]) {
        let last = self.points.len().saturating_sub(1);
        let i = self
            .s
            .partition_point(|&v| v <= s)
            .saturating_sub(1)
            .min(last);
        let p = self.points.get(i).copied().unwrap_or([0.0; 2]);
        let d = match self.points.get(i + 1) {
            Some(&q) if i < last => {
                let len = dist(p, q);
                [(q[0] - p[0]) / len, (q[1] - p[1]) / len]
            }
            // Beyond the end: the path stands still.
            _ => [0.0, 0.0],
        };
        let s0 = self.s.get(i).copied().unwrap_or(0.0);
        let ip = self.first.get(i).copied().unwrap_or([0.0; 2]);
        let kp = self.second.get(i).copied().unwrap_or([0.0; 2]);
        (s0, p, d, ip, kp)
    }

    /// `I(s)` and `K(s)`, the path held at its first point before 0 and at
    /// its last after the end.
    fn integrals(&self, s: f64) -> ([f64; 2], [f64; 2]) {
        let p0 = self.points.first().copied().unwrap_or([0.0; 2]);
        if s < 0.0 {
            return (
                [p0[0] * s, p0[1] * s],
                [p0[0] * s * s / 2.0, p0[1] * s * s / 2.0],
            );
        }
        let (s0, p, d, ip, kp) = self.segment(s);
        let u = s - s0;
        (
            [0, 1].map(|k| ip[k] + p[k] * u + d[k] * u * u / 2.0),
            [0, 1].map(|k| kp[k] + ip[k] * u + p[k] * u * u / 2.0 + d[k] * u * u * u / 6.0),
        )
    }

    /// The smoothed point at arc length `s`, meters.
    pub fn position(&self, s: f64) -> [f64; 2] {
        let w = SMOOTH_HALF_WIDTH_M;
        let (_, k_plus) = self.integrals(s + 2.0 * w);
        let (_, k_mid) = self.integrals(s);
        let (_, k_minus) = self.integrals(s - 2.0 * w);
        [0, 1].map(|k| (k_plus[k] - 2.0 * k_mid[k] + k_minus[k]) / (4.0 * w * w))
    }

    /// The smoothed tangent at `s` (length at most 1; shorter where the
    /// path starts, ends or turns sharply).
    pub fn tangent(&self, s: f64) -> [f64; 2] {
        let w = SMOOTH_HALF_WIDTH_M;
        let (i_plus, _) = self.integrals(s + 2.0 * w);
        let (i_mid, _) = self.integrals(s);
        let (i_minus, _) = self.integrals(s - 2.0 * w);
        [0, 1].map(|k| (i_plus[k] - 2.0 * i_mid[k] + i_minus[k]) / (4.0 * w * w))
    }

    /// Heading of the tangent at `s`, radians (0 along +x); where the
    /// tangent vanishes (a standing start), that of the first segment.
    pub fn heading_rad(&self, s: f64) -> f64 {
        let t = self.tangent(s.max(1e-3));
        if t[0].hypot(t[1]) > 1e-9 {
            t[1].atan2(t[0])
        } else {
            let d = self.segment(0.0).2;
            d[1].atan2(d[0])
        }
    }
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

fn polyline_length(points: &[[f64; 2]]) -> f64 {
    points.windows(2).map(|w| dist(w[0], w[1])).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn route(x: f64, north: bool) -> RoomRoute {
        let sign = if north { 1.0 } else { -1.0 };
        let y = |v: f64| 5.0 + sign * v;
        RoomRoute {
            corridor_m: [x, 5.0],
            door_m: [x, y(1.3)],
            inside_m: [x, y(2.6)],
            loop_m: [[x - 1.0, y(4.0)], [x, y(5.5)], [x + 1.0, y(4.0)]],
        }
    }

    #[test]
    fn smoothing_keeps_straight_legs_and_is_continuous() {
        let routes = [route(2.0, false), route(8.0, true), route(14.0, false)];
        let tour = Tour::through(&routes, 3, 60.0).expect("tour");
        assert!(tour.length_m() >= 60.0);
        assert!(tour.rooms().len() >= 3);
        // Straight legs far from corners are reproduced exactly.
        let p = tour.position(20.0);
        assert!(p.iter().all(|v| v.is_finite()));
        // Continuity of position and heading at a fine step.
        let mut prev = tour.position(0.0);
        let mut prev_heading = tour.heading_rad(0.0);
        for i in 1..6000 {
            let s = i as f64 * 0.01;
            let q = tour.position(s);
            assert!(dist(prev, q) <= 0.0101, "jump at {s}");
            let h = tour.heading_rad(s);
            let dh = (h - prev_heading + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            assert!(dh.abs() < 0.05, "heading jump {dh} at {s}");
            prev = q;
            prev_heading = h;
        }
    }

    #[test]
    fn door_passages_are_straight() {
        // A corridor point, a door 1.3 m on, the inside point 1.3 m further:
        // the middle of the passage is exactly on the line.
        let tour = Tour::new(
            vec![[0.0, 0.0], [5.0, 0.0], [5.0, 1.3], [5.0, 2.6], [8.0, 2.6]],
            vec![0],
        );
        let s_door = 5.0 + 1.3;
        for ds in [-0.5, 0.0, 0.5] {
            let p = tour.position(s_door + ds);
            assert!((p[0] - 5.0).abs() < 1e-9, "{p:?}");
            assert!((p[1] - (1.3 + ds)).abs() < 1e-9, "{p:?}");
        }
    }
}
