//! The scanning run: a person walking around the room with a handheld
//! RGB-D camera, the way a room is scanned: one lap looking at the walls,
//! one lap looking back into the room and down at the floor and furniture.
//!
//! Each lap ([`ScanLap`]) follows an ellipse `wall_distance_m` in from the
//! walls at `speed_mps`, with a slow sideways wobble; the camera height
//! swings between `height_m.0` and `height_m.1`. The camera looks outward
//! (toward the wall the walk runs along) or inward (toward the room
//! center), at the lap's mean pitch, with yaw, pitch and roll wobble (sums
//! of two sinusoids). It never looks steeply up, and furniture hides what
//! is behind and under it, so the ceiling, the top of the walls in places
//! and the backs of the furniture stay unscanned: the map has holes where
//! the scan did not look. Positions are checked free of furniture and
//! occluders; a blocked lap is redrawn closer to or farther from the x
//! and y walls (up to 0.75 m each way). The laps follow each other (the walker steps
//! from one to the next between two frames).

use nalgebra::{Translation3, Vector3};
use serde::Serialize;

use super::depth_sensor::Gaussian;
use crate::geometry::look::camera_rotation;
use crate::geometry::Pose;

/// Where a lap's camera looks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LapLook {
    /// Away from the room center, at the wall the walk runs along.
    Outward,
    /// Toward the room center.
    Inward,
}

/// One lap of the scanning walk.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ScanLap {
    /// Where the camera looks.
    pub look: LapLook,
    /// Distance of the walk from the walls, meters.
    pub wall_distance_m: f64,
    /// Mean pitch, degrees (negative looks down).
    pub pitch_bias_deg: f64,
}

/// Exact parameters of the scanning walk.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScanPathSpec {
    /// Walking speed, m/s.
    pub speed_mps: f64,
    /// The laps, walked in order.
    pub laps: Vec<ScanLap>,
    /// Camera height range, meters.
    pub height_m: (f64, f64),
    /// Period of the height swing, seconds.
    pub height_period_s: f64,
    /// Sideways wobble amplitude, meters.
    pub position_wobble_m: f64,
    /// Yaw wobble amplitude around the lap's look direction, degrees.
    pub yaw_wobble_deg: f64,
    /// Pitch wobble amplitude, degrees.
    pub pitch_wobble_deg: f64,
    /// Roll wobble amplitude, degrees.
    pub roll_wobble_deg: f64,
    /// Frequency range of the wobbles, Hz.
    pub wobble_hz: (f64, f64),
    /// Required distance from furniture and occluders, meters.
    pub clearance_m: f64,
}

/// Why no walk could be placed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ScanPathError {
    /// The spec has no lap.
    #[error("the scanning walk has no lap")]
    NoLaps,
    /// Every candidate of a lap hit an obstacle.
    #[error(
        "no scanning lap stays {clearance_m} m from obstacles (last blocked at {blocked_at_m:?})"
    )]
    Blocked {
        /// Clearance required.
        clearance_m: f64,
        /// Where the last candidate was blocked.
        blocked_at_m: [f64; 3],
    },
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Wobble([(f64, f64, f64); 2]);

impl Wobble {
    fn draw(rng: &mut Gaussian, amplitude: f64, (lo, hi): (f64, f64)) -> Self {
        let w = 0.3 + 0.4 * rng.uniform();
        let mut one = |a: f64| {
            (
                a,
                lo + (hi - lo) * rng.uniform(),
                std::f64::consts::TAU * rng.uniform(),
            )
        };
        Self([one(amplitude * w), one(amplitude * (1.0 - w))])
    }

    fn at(&self, t_s: f64) -> f64 {
        self.0
            .iter()
            .map(|(a, f, p)| a * (std::f64::consts::TAU * f * t_s + p).sin())
            .sum()
    }
}

/// One drawn lap.
#[derive(Debug, Clone, PartialEq)]
struct Lap {
    lap: ScanLap,
    center_m: Vector3<f64>,
    radii_m: (f64, f64),
    theta0_rad: f64,
    direction: f64,
    duration_s: f64,
    height_phase_rad: f64,
    wobble: [Wobble; 4],
}

/// A drawn scanning walk: `world_from_camera` as a function of time.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanPath {
    spec: ScanPathSpec,
    laps: Vec<Lap>,
}

/// Changes of the wall distance tried, meters, per axis: every pair, the
/// smallest total change first.
const WALL_DISTANCE_SHIFTS_M: [f64; 7] = [0.0, 0.25, -0.25, 0.5, -0.5, 0.75, -0.75];

/// The `(x, y)` wall-distance changes in the order they are tried.
fn shift_pairs() -> Vec<(f64, f64)> {
    let mut pairs: Vec<(f64, f64)> = WALL_DISTANCE_SHIFTS_M
        .iter()
        .flat_map(|&x| WALL_DISTANCE_SHIFTS_M.iter().map(move |&y| (x, y)))
        .collect();
    // Stable: ties keep the list's order.
    pairs.sort_by(|a, b| (a.0.abs() + a.1.abs()).total_cmp(&(b.0.abs() + b.1.abs())));
    pairs
}

impl ScanPath {
    /// Draws a walk in a room spanning `0..room_size_m` that is free
    /// according to `is_free(point, clearance)` at every 2 cm of its length.
    pub fn generate(
        spec: &ScanPathSpec,
        room_size_m: [f64; 3],
        seed: u64,
        is_free: &dyn Fn([f64; 3], f64) -> bool,
    ) -> Result<Self, ScanPathError> {
        Self::generate_in(spec, [0.0, 0.0], room_size_m, seed, is_free)
    }

    /// [`ScanPath::generate`] for a room whose floor spans `origin_m ..
    /// origin_m + size` in `x` and `y` (world frame; `0..size[2]` in `z`).
    pub fn generate_in(
        spec: &ScanPathSpec,
        origin_m: [f64; 2],
        room_size_m: [f64; 3],
        seed: u64,
        is_free: &dyn Fn([f64; 3], f64) -> bool,
    ) -> Result<Self, ScanPathError> {
        if spec.laps.is_empty() {
            return Err(ScanPathError::NoLaps);
        }
        let mut laps = Vec::with_capacity(spec.laps.len());
        for (k, lap) in spec.laps.iter().enumerate() {
            laps.push(Self::generate_lap(
                spec,
                lap,
                (origin_m, room_size_m),
                super::super::corrupt::derive_seed(seed, 0x1a9 + k as u64),
                is_free,
            )?);
        }
        Ok(Self {
            spec: spec.clone(),
            laps,
        })
    }

    fn generate_lap(
        spec: &ScanPathSpec,
        lap: &ScanLap,
        (origin_m, room_size_m): ([f64; 2], [f64; 3]),
        seed: u64,
        is_free: &dyn Fn([f64; 3], f64) -> bool,
    ) -> Result<Lap, ScanPathError> {
        let mut blocked_at_m = [f64::NAN; 3];
        // A closed lap passes every angle, so new phases rarely help: each
        // attempt moves the walk closer to or farther from the x and y walls.
        for (attempt, (sx, sy)) in shift_pairs().into_iter().enumerate() {
            let mut rng = Gaussian::new(super::super::corrupt::derive_seed(seed, attempt as u64));
            let least = spec.clearance_m + spec.position_wobble_m;
            let radii_m = (
                (0.5 * room_size_m[0] - (lap.wall_distance_m + sx).max(least)).max(0.1),
                (0.5 * room_size_m[1] - (lap.wall_distance_m + sy).max(least)).max(0.1),
            );
            let mean_r = ((radii_m.0 * radii_m.0 + radii_m.1 * radii_m.1) / 2.0).sqrt();
            let deg = |x: f64| x.to_radians();
            let candidate = Lap {
                lap: *lap,
                center_m: Vector3::new(
                    origin_m[0] + 0.5 * room_size_m[0],
                    origin_m[1] + 0.5 * room_size_m[1],
                    0.0,
                ),
                radii_m,
                theta0_rad: std::f64::consts::TAU * rng.uniform(),
                direction: if rng.uniform() < 0.5 { 1.0 } else { -1.0 },
                duration_s: std::f64::consts::TAU * mean_r / spec.speed_mps.max(1e-3),
                height_phase_rad: std::f64::consts::TAU * rng.uniform(),
                wobble: [
                    Wobble::draw(&mut rng, spec.position_wobble_m, spec.wobble_hz),
                    Wobble::draw(&mut rng, deg(spec.yaw_wobble_deg), spec.wobble_hz),
                    Wobble::draw(&mut rng, deg(spec.pitch_wobble_deg), spec.wobble_hz),
                    Wobble::draw(&mut rng, deg(spec.roll_wobble_deg), spec.wobble_hz),
                ],
            };
            let steps = (candidate.duration_s * spec.speed_mps / 0.02).ceil() as usize;
            let blocked = (0..=steps)
                .map(|i| {
                    candidate
                        .position_at(spec, candidate.duration_s * i as f64 / steps.max(1) as f64)
                })
                .find(|p| !is_free([p.x, p.y, p.z], spec.clearance_m));
            match blocked {
                None => return Ok(candidate),
                Some(p) => blocked_at_m = p.into(),
            }
        }
        Err(ScanPathError::Blocked {
            clearance_m: spec.clearance_m,
            blocked_at_m,
        })
    }

    /// Time of the whole walk (all laps), seconds.
    pub fn duration_s(&self) -> f64 {
        self.laps.iter().map(|l| l.duration_s).sum()
    }

    /// Walks `next` after this walk's last lap (the walker steps from one
    /// room to the next between two frames). Both must be of one spec.
    pub fn then(mut self, next: ScanPath) -> Self {
        self.laps.extend(next.laps);
        self
    }

    /// Number of laps.
    pub fn lap_count(&self) -> usize {
        self.laps.len()
    }

    /// The number of the lap walked at `t_s`.
    pub fn lap_index_at(&self, t_s: f64) -> usize {
        self.lap_at(t_s).0
    }

    /// The lap walked at `t_s`, its number and the time into it.
    fn lap_at(&self, t_s: f64) -> (usize, &Lap, f64) {
        let mut t = t_s;
        for (k, lap) in self.laps.iter().enumerate() {
            if t < lap.duration_s || k + 1 == self.laps.len() {
                return (k, lap, t);
            }
            t -= lap.duration_s;
        }
        // Unreachable: `generate` refuses a walk without laps.
        let last = self.laps.len() - 1;
        (last, &self.laps[last], t)
    }

    /// Camera position at `t_s`, world frame.
    pub fn position_at(&self, t_s: f64) -> Vector3<f64> {
        let (_, lap, t) = self.lap_at(t_s);
        lap.position_at(&self.spec, t)
    }

    /// `world_from_camera` at `t_s`.
    pub fn pose_at(&self, t_s: f64) -> Pose {
        let (_, lap, t) = self.lap_at(t_s);
        lap.pose_at(&self.spec, t)
    }
}

impl Lap {
    fn theta(&self, spec: &ScanPathSpec, t_s: f64) -> f64 {
        let mean_r = ((self.radii_m.0.powi(2) + self.radii_m.1.powi(2)) / 2.0).sqrt();
        self.theta0_rad + self.direction * spec.speed_mps * t_s / mean_r
    }

    fn position_at(&self, spec: &ScanPathSpec, t_s: f64) -> Vector3<f64> {
        let theta = self.theta(spec, t_s);
        let (s, c) = theta.sin_cos();
        // Outward unit normal of the ellipse, for the sideways wobble.
        let normal = Vector3::new(c / self.radii_m.0, s / self.radii_m.1, 0.0)
            .try_normalize(1e-12)
            .unwrap_or_else(Vector3::x);
        let (lo, hi) = spec.height_m;
        let swing = (std::f64::consts::TAU * t_s / spec.height_period_s.max(1e-3)
            + self.height_phase_rad)
            .sin();
        self.center_m
            + Vector3::new(self.radii_m.0 * c, self.radii_m.1 * s, 0.0)
            + normal * self.wobble[0].at(t_s)
            + Vector3::new(0.0, 0.0, 0.5 * (lo + hi) + 0.5 * (hi - lo) * swing)
    }

    fn pose_at(&self, spec: &ScanPathSpec, t_s: f64) -> Pose {
        let theta = self.theta(spec, t_s);
        let (s, c) = theta.sin_cos();
        // The ellipse's outward normal: toward the wall the walk runs along.
        let outward = (s / self.radii_m.1).atan2(c / self.radii_m.0);
        let look = match self.lap.look {
            LapLook::Outward => outward,
            LapLook::Inward => outward + std::f64::consts::PI,
        };
        let yaw = look + self.wobble[1].at(t_s);
        let pitch = self.lap.pitch_bias_deg.to_radians() + self.wobble[2].at(t_s);
        let roll = self.wobble[3].at(t_s);
        Pose::from_parts(
            Translation3::from(self.position_at(spec, t_s)),
            camera_rotation(yaw, pitch, roll),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn spec() -> ScanPathSpec {
        super::super::ScannedSpec::default().scan_path
    }

    #[test]
    fn the_laps_stay_in_their_band_and_look_where_they_should() {
        let room = [8.0, 6.0, 3.0];
        let spec = spec();
        let path = ScanPath::generate(&spec, room, 3, &|_, _| true).expect("free");
        assert_eq!(
            path,
            ScanPath::generate(&spec, room, 3, &|_, _| true).expect("free")
        );
        assert!(path.duration_s() > 30.0 && path.duration_s() < 200.0);
        let mut t0 = 0.0;
        for (lap, drawn) in spec.laps.iter().zip(&path.laps) {
            let n = 200;
            for i in 0..n {
                let t = t0 + drawn.duration_s * i as f64 / n as f64;
                let p = path.position_at(t);
                assert!((1.2 - 1e-9..=1.6 + 1e-9).contains(&p.z), "height {}", p.z);
                let to_wall = p.x.min(room[0] - p.x).min(p.y).min(room[1] - p.y);
                let band = lap.wall_distance_m - 0.15..=lap.wall_distance_m + 1.0;
                assert!(band.contains(&to_wall), "{to_wall} m from a wall");
                let forward = path.pose_at(t).rotation * Vector3::z();
                let mut outward = Vector3::new(p.x - 4.0, p.y - 3.0, 0.0).normalize();
                if lap.look == LapLook::Inward {
                    outward = -outward;
                }
                let angle = forward.dot(&outward).clamp(-1.0, 1.0).acos().to_degrees();
                assert!(angle < 95.0, "looks {angle} deg off its direction");
                let pitch = forward.z.asin().to_degrees();
                assert!(pitch < 20.0, "pitch {pitch}");
            }
            t0 += drawn.duration_s;
        }
    }

    #[test]
    fn a_blocked_lap_is_redrawn_or_refused() {
        let room = [8.0, 6.0, 3.0];
        let spec = ScanPathSpec {
            laps: vec![spec().laps[0]],
            ..spec()
        };
        // A pillar where the nominal lap crosses the x axis: a lap farther
        // from or closer to the walls avoids it.
        let x = room[0] - spec.laps[0].wall_distance_m;
        let pillar = move |p: [f64; 3], c: f64| (p[0] - x).hypot(p[1] - 3.0) > 0.05 + c;
        let path = ScanPath::generate(&spec, room, 1, &pillar).expect("redrawn");
        for i in 0..400 {
            let p = path.position_at(path.duration_s() * i as f64 / 400.0);
            assert!(pillar([p.x, p.y, p.z], spec.clearance_m));
        }
        let err = ScanPath::generate(&spec, room, 1, &|_, _| false).expect_err("all blocked");
        assert!(
            matches!(err, ScanPathError::Blocked { clearance_m, .. } if clearance_m == spec.clearance_m)
        );
        let none = ScanPathSpec {
            laps: vec![],
            ..spec
        };
        assert_eq!(
            ScanPath::generate(&none, room, 1, &|_, _| true),
            Err(ScanPathError::NoLaps)
        );
    }
}
