//! Trajectory properties: determinism, speeds, pitch bounds, free space.

use super::*;

fn room() -> RoomBox {
    RoomBox {
        min_m: Vector3::new(0.0, 0.0, 0.0),
        max_m: Vector3::new(8.0, 6.0, 2.8),
    }
}

/// The room box minus a 1x1 m pillar in the middle.
fn free(p: &Vector3<f64>, margin: f64) -> bool {
    let r = room();
    let inside = (0..3).all(|k| p[k] >= r.min_m[k] + margin && p[k] <= r.max_m[k] - margin);
    let pillar = (p.x - 4.0).abs() < 0.5 + margin && (p.y - 3.0).abs() < 0.5 + margin;
    inside && !pillar
}

struct Motion {
    mean_speed_mps: f64,
    max_speed_mps: f64,
    max_angular_dps: f64,
    max_abs_pitch_deg: f64,
    max_accel_mps2: f64,
}

fn motion(traj: &Trajectory, rate_hz: f64) -> Motion {
    let dt = 1.0 / rate_hz;
    let p: Vec<_> = traj.poses.iter().map(|p| p.translation.vector).collect();
    let speeds: Vec<f64> = p.windows(2).map(|w| (w[1] - w[0]).norm() / dt).collect();
    let accels = p
        .windows(3)
        .map(|w| (w[2] - 2.0 * w[1] + w[0]).norm() / (dt * dt));
    let angular = traj.poses.windows(2).map(|w| {
        (w[0].rotation.inverse() * w[1].rotation)
            .angle()
            .to_degrees()
            / dt
    });
    let pitch = traj
        .poses
        .iter()
        .map(|p| (p.rotation * Vector3::z()).z.asin().to_degrees().abs());
    Motion {
        mean_speed_mps: speeds.iter().sum::<f64>() / speeds.len() as f64,
        max_speed_mps: speeds.iter().copied().fold(0.0, f64::max),
        max_angular_dps: angular.fold(0.0, f64::max),
        max_abs_pitch_deg: pitch.fold(0.0, f64::max),
        max_accel_mps2: accels.fold(0.0, f64::max),
    }
}

#[test]
fn slow_loop_is_slow_smooth_level_and_free() {
    for seed in [1, 2, 3] {
        let t = SynthTrajectory::generate(TrajectoryKind::SlowLoop, &room(), seed, 60.0, &free)
            .expect("free path");
        let traj = t.sample(3000, 50.0, 0.0);
        let m = motion(&traj, 50.0);
        assert!(
            (0.35..0.7).contains(&m.mean_speed_mps),
            "mean speed {}",
            m.mean_speed_mps
        );
        assert!(m.max_speed_mps < 1.0, "max speed {}", m.max_speed_mps);
        assert!(m.max_angular_dps < 45.0, "angular {}", m.max_angular_dps);
        assert!(
            m.max_abs_pitch_deg <= MAX_PITCH_DEG,
            "pitch {}",
            m.max_abs_pitch_deg
        );
        assert!(m.max_accel_mps2 < 2.0, "accel {}", m.max_accel_mps2);
        assert!(traj.poses.iter().all(|p| free(&p.translation.vector, 0.35)));
    }
}

#[test]
fn aggressive_reaches_but_respects_200_dps() {
    for seed in [1, 2, 3] {
        let t = SynthTrajectory::generate(TrajectoryKind::Aggressive, &room(), seed, 60.0, &free)
            .expect("free path");
        let traj = t.sample(3000, 50.0, 0.0);
        let m = motion(&traj, 50.0);
        assert!(
            (1.1..2.0).contains(&m.mean_speed_mps),
            "mean speed {}",
            m.mean_speed_mps
        );
        assert!(
            (150.0..=200.5).contains(&m.max_angular_dps),
            "angular {}",
            m.max_angular_dps
        );
        assert!(
            m.max_abs_pitch_deg <= MAX_PITCH_DEG,
            "pitch {}",
            m.max_abs_pitch_deg
        );
        assert!(m.max_accel_mps2 < 15.0, "accel {}", m.max_accel_mps2);
        assert!(traj.poses.iter().all(|p| free(&p.translation.vector, 0.3)));
    }
}

#[test]
fn same_seed_same_trajectory_and_prefix_property() {
    let a =
        SynthTrajectory::generate(TrajectoryKind::SlowLoop, &room(), 42, 2.0, &free).expect("ok");
    let b =
        SynthTrajectory::generate(TrajectoryKind::SlowLoop, &room(), 42, 30.0, &free).expect("ok");
    let c =
        SynthTrajectory::generate(TrajectoryKind::SlowLoop, &room(), 43, 2.0, &free).expect("ok");
    assert_eq!(
        a, b,
        "durations under the check horizon give the same trajectory"
    );
    assert_ne!(a, c);
    assert_eq!(a.sample(10, 50.0, 5.0).stamps_s[3], 5.0 + 3.0 / 50.0);
}

#[test]
fn camera_looks_into_the_room() {
    let t =
        SynthTrajectory::generate(TrajectoryKind::SlowLoop, &room(), 5, 20.0, &free).expect("ok");
    let center = Vector3::new(4.0, 3.0, 1.4);
    for i in 0..100 {
        let pose = t.pose_at(i as f64 * 0.2);
        let to_center = (center - pose.translation.vector).normalize();
        let forward = pose.rotation * Vector3::z();
        // Yaw wobble is at most 30 degrees and pitch small: center stays in front.
        assert!(forward.dot(&to_center) > 0.5, "frame {i} looks away");
    }
}

#[test]
fn blocked_rooms_are_errors() {
    let tiny = RoomBox {
        min_m: Vector3::zeros(),
        max_m: Vector3::new(1.0, 1.0, 2.0),
    };
    assert!(matches!(
        SynthTrajectory::generate(TrajectoryKind::SlowLoop, &tiny, 1, 10.0, &|_, _| true),
        Err(TrajectoryError::RoomTooSmall { .. })
    ));
    let err =
        SynthTrajectory::generate(TrajectoryKind::Aggressive, &room(), 1, 10.0, &|_, _| false)
            .unwrap_err();
    assert!(
        matches!(err, TrajectoryError::NoFreePath { attempts: 24, .. }),
        "{err}"
    );
}
