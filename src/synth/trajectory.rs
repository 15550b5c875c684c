//! Synthetic camera trajectories at any rate, deterministic from a seed.
//!
//! Takes the room's free box, a free-space test (`Scene::is_free`), a
//! [`TrajectoryKind`] and a seed; gives a [`SynthTrajectory`], a smooth
//! (C-infinity: an ellipse plus sums of sinusoids) continuous function of
//! time that [`SynthTrajectory::sample`] turns into a TUM [`Trajectory`].
//!
//! The camera circles the room center on an ellipse, looking across the room
//! toward the center (so it sees the opposite walls and the furniture), with
//! wobble in position, yaw, pitch and roll. The `room_to_room` kind instead
//! follows a [`tour::Tour`] through the rooms and doors of a building floor,
//! looking along the direction of travel, with the same kinds of wobble. Pitch stays within
//! [`MAX_PITCH_DEG`] and every position within the first
//! `max(duration, 60 s)` is checked free with the kind's clearance; a
//! blocked candidate is redrawn with another ellipse size and phases.

use nalgebra::{Translation3, Vector3};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use serde::Serialize;

pub mod tour;

use std::sync::Arc;

use crate::dataset::Trajectory;
use crate::geometry::look::camera_rotation;
use crate::geometry::Pose;

/// Largest optical-axis elevation (up or down), degrees.
pub const MAX_PITCH_DEG: f64 = 30.0;
/// Horizon over which free space is checked and angular speed is capped, seconds.
pub const CHECK_HORIZON_S: f64 = 60.0;
const CHECK_STEP_S: f64 = 0.01;
const MAX_ATTEMPTS: u64 = 24;

/// Errors generating a trajectory.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TrajectoryError {
    /// The room box is empty, inverted or not finite.
    #[error("room box {min_m:?}..{max_m:?} m is too small for a trajectory with {clearance_m} m clearance")]
    RoomTooSmall {
        /// Lower corner.
        min_m: [f64; 3],
        /// Upper corner.
        max_m: [f64; 3],
        /// Clearance required around the camera.
        clearance_m: f64,
    },
    /// A room-to-room trajectory was asked of a scene without rooms.
    #[error("a room_to_room trajectory needs a building scene")]
    NoRooms,
    /// No candidate stayed in free space.
    #[error("no {kind:?} trajectory for seed {seed} stays {clearance_m} m from obstacles after {attempts} attempts; last blocked at {blocked_at_m:?}")]
    NoFreePath {
        /// The trajectory kind.
        kind: TrajectoryKind,
        /// The seed.
        seed: u64,
        /// Candidates tried.
        attempts: u64,
        /// Clearance required.
        clearance_m: f64,
        /// Where the last candidate hit an obstacle.
        blocked_at_m: [f64; 3],
    },
}

/// The kinds of trajectory.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TrajectoryKind {
    /// A smooth loop at about 0.5 m/s with gentle yaw and pitch.
    SlowLoop,
    /// A fast loop (about 1.5 m/s) with rotation rates up to 200 deg/s.
    Aggressive,
    /// Room to room through doors on a building floor at about 0.5 m/s,
    /// looking roughly along the direction of travel (`loop_speed_mps` is
    /// the speed along the tour, `loop_fill` is unused).
    RoomToRoom,
}

/// The motion design of a [`TrajectoryKind`]: exact parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MotionSpec {
    /// Speed along the ellipse, m/s.
    pub loop_speed_mps: f64,
    /// Ellipse radii as a fraction of the room half-size left after clearance and wobble.
    pub loop_fill: f64,
    /// Nominal camera height above the floor, m.
    pub height_m: f64,
    /// Horizontal position wobble amplitude per axis, m (two sinusoids).
    pub position_wobble_m: f64,
    /// Vertical position wobble amplitude, m.
    pub vertical_wobble_m: f64,
    /// Frequency range of position wobble, Hz.
    pub position_wobble_hz: (f64, f64),
    /// Yaw wobble amplitude around "look at the room center", degrees.
    pub yaw_wobble_deg: f64,
    /// Constant pitch, degrees (negative looks down).
    pub pitch_bias_deg: f64,
    /// Pitch wobble amplitude, degrees.
    pub pitch_wobble_deg: f64,
    /// Roll wobble amplitude, degrees.
    pub roll_wobble_deg: f64,
    /// Frequency range of rotation wobble, Hz.
    pub rotation_wobble_hz: (f64, f64),
    /// When set, rotation wobble amplitudes are scaled down so the peak
    /// angular speed over [`CHECK_HORIZON_S`] is at most this, deg/s.
    pub max_angular_speed_dps: Option<f64>,
    /// Required distance from every obstacle, m.
    pub clearance_m: f64,
}

impl TrajectoryKind {
    /// The exact motion parameters of this kind.
    pub fn spec(self) -> MotionSpec {
        match self {
            TrajectoryKind::SlowLoop => MotionSpec {
                loop_speed_mps: 0.5,
                loop_fill: 0.8,
                height_m: 1.4,
                position_wobble_m: 0.15,
                vertical_wobble_m: 0.15,
                position_wobble_hz: (0.03, 0.1),
                yaw_wobble_deg: 30.0,
                pitch_bias_deg: -5.0,
                pitch_wobble_deg: 10.0,
                roll_wobble_deg: 3.0,
                rotation_wobble_hz: (0.02, 0.08),
                max_angular_speed_dps: None,
                clearance_m: 0.35,
            },
            TrajectoryKind::Aggressive => MotionSpec {
                loop_speed_mps: 1.25,
                loop_fill: 0.8,
                height_m: 1.4,
                position_wobble_m: 0.3,
                vertical_wobble_m: 0.25,
                position_wobble_hz: (0.3, 0.8),
                yaw_wobble_deg: 50.0,
                pitch_bias_deg: -5.0,
                pitch_wobble_deg: 24.0,
                roll_wobble_deg: 15.0,
                rotation_wobble_hz: (0.3, 0.9),
                max_angular_speed_dps: Some(200.0),
                clearance_m: 0.3,
            },
            TrajectoryKind::RoomToRoom => MotionSpec {
                loop_speed_mps: 0.5,
                loop_fill: 0.0,
                height_m: 1.4,
                position_wobble_m: 0.05,
                vertical_wobble_m: 0.1,
                position_wobble_hz: (0.03, 0.1),
                yaw_wobble_deg: 15.0,
                pitch_bias_deg: -5.0,
                pitch_wobble_deg: 8.0,
                roll_wobble_deg: 3.0,
                rotation_wobble_hz: (0.02, 0.08),
                max_angular_speed_dps: None,
                clearance_m: 0.3,
            },
        }
    }
}

/// The axis-aligned box of the room's interior (floor to ceiling), world frame, m.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoomBox {
    /// Lower corner (floor level in z).
    pub min_m: Vector3<f64>,
    /// Upper corner (ceiling level in z).
    pub max_m: Vector3<f64>,
}

/// `a sin(2 pi f t + phase)`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Sine {
    amplitude: f64,
    freq_hz: f64,
    phase_rad: f64,
}

/// A sum of two sinusoids with total amplitude at most `amplitude`.
/// The wobbles of one trajectory: position x, y, z, then yaw, pitch, roll.
struct Wobbles {
    position: [[Sine; 2]; 3],
    yaw: [Sine; 2],
    pitch: [Sine; 2],
    roll: [Sine; 2],
}

impl Wobbles {
    /// Draws them from `rng` in the order above.
    fn draw(rng: &mut StdRng, spec: &MotionSpec) -> Self {
        let position = [
            draw_wobble(rng, spec.position_wobble_m, spec.position_wobble_hz),
            draw_wobble(rng, spec.position_wobble_m, spec.position_wobble_hz),
            draw_wobble(rng, spec.vertical_wobble_m, spec.position_wobble_hz),
        ];
        let rotation = |rng: &mut StdRng, deg: f64| {
            draw_wobble(rng, deg.to_radians(), spec.rotation_wobble_hz)
        };
        let yaw = rotation(rng, spec.yaw_wobble_deg);
        let pitch = rotation(rng, spec.pitch_wobble_deg);
        let roll = rotation(rng, spec.roll_wobble_deg);
        Self {
            position,
            yaw,
            pitch,
            roll,
        }
    }
}

fn draw_wobble(rng: &mut StdRng, amplitude: f64, (lo_hz, hi_hz): (f64, f64)) -> [Sine; 2] {
    let w: f64 = rng.random_range(0.3..0.7);
    let mut sine = |a: f64| Sine {
        amplitude: a,
        freq_hz: rng.random_range(lo_hz..hi_hz),
        phase_rad: rng.random_range(0.0..std::f64::consts::TAU),
    };
    [sine(amplitude * w), sine(amplitude * (1.0 - w))]
}

fn eval(sines: &[Sine; 2], t_s: f64, scale: f64) -> f64 {
    sines
        .iter()
        .map(|s| {
            scale * s.amplitude * (std::f64::consts::TAU * s.freq_hz * t_s + s.phase_rad).sin()
        })
        .sum()
}

/// A continuous camera trajectory, `world_from_camera` as a function of time.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthTrajectory {
    kind: TrajectoryKind,
    center_m: Vector3<f64>,
    radii_m: (f64, f64),
    loop_rate_rad_s: f64,
    theta0_rad: f64,
    position: [[Sine; 2]; 3],
    yaw: [Sine; 2],
    pitch: [Sine; 2],
    roll: [Sine; 2],
    pitch_bias_rad: f64,
    rotation_scale: f64,
    /// The room-to-room path; `None` for the loops.
    tour: Option<Arc<tour::Tour>>,
}

impl SynthTrajectory {
    /// Generates a trajectory of `kind` inside `room`, free for at least
    /// `max(duration_s, 60 s)` according to `is_free(point, clearance_m)`.
    pub fn generate(
        kind: TrajectoryKind,
        room: &RoomBox,
        seed: u64,
        duration_s: f64,
        is_free: &dyn Fn(&Vector3<f64>, f64) -> bool,
    ) -> Result<Self, TrajectoryError> {
        let spec = kind.spec();
        let half = (room.max_m - room.min_m) / 2.0;
        let avail = (
            half.x - spec.clearance_m - spec.position_wobble_m,
            half.y - spec.clearance_m - spec.position_wobble_m,
        );
        let z_lo = room.min_m.z + spec.clearance_m + spec.vertical_wobble_m;
        let z_hi = room.max_m.z - spec.clearance_m - spec.vertical_wobble_m;
        if !(avail.0 > 0.2 && avail.1 > 0.2 && z_hi >= z_lo) {
            return Err(TrajectoryError::RoomTooSmall {
                min_m: room.min_m.into(),
                max_m: room.max_m.into(),
                clearance_m: spec.clearance_m,
            });
        }
        let horizon_s = duration_s.max(CHECK_HORIZON_S);
        let mut blocked_at_m = [f64::NAN; 3];
        for attempt in 0..MAX_ATTEMPTS {
            let mut rng = StdRng::seed_from_u64(seed ^ attempt.wrapping_mul(0x9E37_79B9_7F4A_7C15));
            // Alternate bigger and smaller loops around the nominal size.
            let step = attempt.div_ceil(2) as f64 * if attempt % 2 == 1 { -0.12 } else { 0.12 };
            let fill = (spec.loop_fill * (1.0 + step)).clamp(0.15, 1.0);
            let radii_m = (fill * avail.0, fill * avail.1);
            let direction = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let mut center_m = (room.min_m + room.max_m) / 2.0;
            center_m.z = (room.min_m.z + spec.height_m).clamp(z_lo, z_hi);
            // Drawn in this order: it fixes what a seed gives.
            let theta0_rad = rng.random_range(0.0..std::f64::consts::TAU);
            let wobble = Wobbles::draw(&mut rng, &spec);
            let mut candidate = Self {
                kind,
                center_m,
                radii_m,
                loop_rate_rad_s: direction * spec.loop_speed_mps / (0.5 * (radii_m.0 + radii_m.1)),
                theta0_rad,
                position: wobble.position,
                yaw: wobble.yaw,
                pitch: wobble.pitch,
                roll: wobble.roll,
                pitch_bias_rad: spec.pitch_bias_deg.to_radians(),
                rotation_scale: 1.0,
                tour: None,
            };
            if let Some(max_dps) = spec.max_angular_speed_dps {
                candidate.cap_angular_speed(max_dps);
            }
            match candidate.first_blocked(horizon_s, spec.clearance_m, is_free) {
                None => {
                    tracing::debug!(?kind, seed, attempt, fill, "trajectory generated");
                    return Ok(candidate);
                }
                Some(p) => blocked_at_m = p.into(),
            }
        }
        Err(TrajectoryError::NoFreePath {
            kind,
            seed,
            attempts: MAX_ATTEMPTS,
            clearance_m: spec.clearance_m,
            blocked_at_m,
        })
    }

    /// A `room_to_room` trajectory through the rooms of `routes` (in
    /// corridor order), free for at least `max(duration_s, 60 s)`
    /// according to `is_free(point, clearance_m)`. Each attempt draws
    /// another start room, direction and wobble.
    pub fn generate_tour(
        routes: &[tour::RoomRoute],
        seed: u64,
        duration_s: f64,
        is_free: &dyn Fn(&Vector3<f64>, f64) -> bool,
    ) -> Result<Self, TrajectoryError> {
        let kind = TrajectoryKind::RoomToRoom;
        let spec = kind.spec();
        let horizon_s = duration_s.max(CHECK_HORIZON_S);
        // The wobble and the smoothing never reach this far past the end.
        let length_m = spec.loop_speed_mps * horizon_s + 4.0;
        let mut blocked_at_m = [f64::NAN; 3];
        for attempt in 0..MAX_ATTEMPTS {
            let attempt_seed = seed ^ attempt.wrapping_mul(0x9E37_79B9_7F4A_7C15);
            let Some(path) = tour::Tour::through(routes, attempt_seed, length_m) else {
                break;
            };
            let mut rng = StdRng::seed_from_u64(attempt_seed);
            let wobble = Wobbles::draw(&mut rng, &spec);
            let candidate = Self {
                kind,
                center_m: Vector3::new(0.0, 0.0, spec.height_m),
                radii_m: (0.0, 0.0),
                loop_rate_rad_s: spec.loop_speed_mps,
                theta0_rad: 0.0,
                position: wobble.position,
                yaw: wobble.yaw,
                pitch: wobble.pitch,
                roll: wobble.roll,
                pitch_bias_rad: spec.pitch_bias_deg.to_radians(),
                rotation_scale: 1.0,
                tour: Some(Arc::new(path)),
            };
            match candidate.first_blocked(horizon_s, spec.clearance_m, is_free) {
                None => {
                    tracing::debug!(?kind, seed, attempt, "tour generated");
                    return Ok(candidate);
                }
                Some(p) => blocked_at_m = p.into(),
            }
        }
        Err(TrajectoryError::NoFreePath {
            kind,
            seed,
            attempts: MAX_ATTEMPTS,
            clearance_m: spec.clearance_m,
            blocked_at_m,
        })
    }

    /// The rooms a `room_to_room` trajectory visits, in order (empty for
    /// a loop).
    pub fn rooms_visited(&self) -> &[usize] {
        self.tour.as_ref().map_or(&[], |t| t.rooms())
    }

    /// The kind this trajectory was generated as.
    pub fn kind(&self) -> TrajectoryKind {
        self.kind
    }

    /// Camera position at time `t_s`, world frame.
    pub fn position_at(&self, t_s: f64) -> Vector3<f64> {
        let wobble = Vector3::new(
            eval(&self.position[0], t_s, 1.0),
            eval(&self.position[1], t_s, 1.0),
            eval(&self.position[2], t_s, 1.0),
        );
        if let Some(tour) = &self.tour {
            // loop_rate_rad_s holds the speed along the tour, m/s.
            let [x, y] = tour.position(self.loop_rate_rad_s * t_s);
            return Vector3::new(x, y, self.center_m.z) + wobble;
        }
        let theta = self.theta0_rad + self.loop_rate_rad_s * t_s;
        self.center_m
            + Vector3::new(
                self.radii_m.0 * theta.cos(),
                self.radii_m.1 * theta.sin(),
                0.0,
            )
            + wobble
    }

    /// Yaw, pitch and roll at time `t_s`, radians (see [`super::look`]).
    pub fn yaw_pitch_roll_at(&self, t_s: f64) -> (f64, f64, f64) {
        let k = self.rotation_scale;
        let heading = match &self.tour {
            Some(tour) => tour.heading_rad(self.loop_rate_rad_s * t_s),
            None => self.theta0_rad + self.loop_rate_rad_s * t_s + std::f64::consts::PI,
        };
        (
            heading + eval(&self.yaw, t_s, k),
            self.pitch_bias_rad + eval(&self.pitch, t_s, k),
            eval(&self.roll, t_s, k),
        )
    }

    /// `world_from_camera` at time `t_s` (seconds from the start).
    pub fn pose_at(&self, t_s: f64) -> Pose {
        let (yaw, pitch, roll) = self.yaw_pitch_roll_at(t_s);
        Pose::from_parts(
            Translation3::from(self.position_at(t_s)),
            camera_rotation(yaw, pitch, roll),
        )
    }

    /// `n_frames` poses at `rate_hz`, the first at time 0; TUM stamps are
    /// `start_s + i / rate_hz`.
    pub fn sample(&self, n_frames: usize, rate_hz: f64, start_s: f64) -> Trajectory {
        let mut out = Trajectory::default();
        for i in 0..n_frames {
            let t = i as f64 / rate_hz;
            out.push(start_s + t, self.pose_at(t));
        }
        out
    }

    fn angular_speed_dps(&self, t_s: f64) -> f64 {
        let dt = 1e-3;
        let a = self.pose_at(t_s).rotation;
        let b = self.pose_at(t_s + dt).rotation;
        (a.inverse() * b).angle().to_degrees() / dt
    }

    fn max_angular_speed_dps(&self) -> f64 {
        let steps = (CHECK_HORIZON_S / CHECK_STEP_S) as usize;
        (0..steps)
            .map(|i| self.angular_speed_dps(i as f64 * CHECK_STEP_S))
            .fold(0.0, f64::max)
    }

    /// Scales rotation wobble so the peak angular speed is at most `max_dps`.
    fn cap_angular_speed(&mut self, max_dps: f64) {
        self.rotation_scale = 1.0;
        if self.max_angular_speed_dps() <= max_dps {
            return;
        }
        let (mut lo, mut hi) = (0.0, 1.0);
        for _ in 0..16 {
            self.rotation_scale = 0.5 * (lo + hi);
            if self.max_angular_speed_dps() <= max_dps {
                lo = self.rotation_scale;
            } else {
                hi = self.rotation_scale;
            }
        }
        self.rotation_scale = lo;
    }

    fn first_blocked(
        &self,
        horizon_s: f64,
        clearance_m: f64,
        is_free: &dyn Fn(&Vector3<f64>, f64) -> bool,
    ) -> Option<Vector3<f64>> {
        let steps = (horizon_s / CHECK_STEP_S).ceil() as usize;
        (0..=steps)
            .map(|i| self.position_at(i as f64 * CHECK_STEP_S))
            .find(|p| !is_free(p, clearance_m))
    }
}

#[cfg(test)]
mod tests;
