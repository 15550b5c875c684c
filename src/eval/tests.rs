//! ATE/RPE on trajectories with known errors.

use super::*;
use crate::geometry::exp_se3;
use nalgebra::{Translation3, UnitQuaternion, Vector3, Vector6};

fn gt(n: usize) -> Trajectory {
    let mut t = Trajectory::default();
    for i in 0..n {
        let s = i as f64 * 0.02;
        t.push(
            s,
            exp_se3(&Vector6::new(s.sin(), s, 1.5, 0.2 * s, 0.3 * s.cos(), s)),
        );
    }
    t
}

#[test]
fn association_picks_nearest_within_tolerance() {
    let g = gt(10);
    let mut e = Trajectory::default();
    for (stamp, pose) in [(0.001, 0), (0.029, 1), (0.068, 2), (0.5, 3)] {
        e.push(stamp, g.poses[pose]);
    }
    // 0.001 -> gt 0 (0.000); 0.029 -> gt 1 (0.02) is 9 ms, gt 2 (0.04) 11 ms: out of 5 ms.
    assert_eq!(associate(&g, &e, 0.005), vec![(0, 0)]);
    assert_eq!(associate(&g, &e, 0.01), vec![(0, 0), (1, 1), (2, 3)]);
    // 0.068 is nearest to gt 3 (0.06), 8 ms away.
    assert!(associate(&g, &e, 0.0).is_empty());
}

#[test]
fn perfect_estimate_has_zero_error() {
    let g = gt(50);
    let eval = evaluate(&g, &g, DEFAULT_MAX_DT_S, Some(5)).expect("overlap");
    assert_eq!(eval.matched, 50);
    assert!(eval.ate.translation_m.max < 1e-12);
    assert!(eval.ate.rotation_deg.max < 1e-5);
    let (delta, rpe) = eval.rpe.expect("rpe");
    assert_eq!(delta, 5);
    assert_eq!(rpe.translation_m.count, 9);
    assert!(rpe.translation_m.max < 1e-12);
}

#[test]
fn constant_offset_is_not_aligned_away() {
    let g = gt(40);
    let mut e = g.clone();
    let offset = Translation3::new(0.3, -0.4, 0.0); // 0.5 m in the world frame
    let tilt = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 2f64.to_radians());
    for p in &mut e.poses {
        // world offset in translation, 2 degrees in the camera frame.
        *p = Pose::from_parts(offset * p.translation, p.rotation * tilt);
    }
    let ate = ate(&g, &e, DEFAULT_MAX_DT_S).expect("overlap");
    assert!((ate.translation_m.rmse - 0.5).abs() < 1e-12);
    assert!((ate.translation_m.std).abs() < 1e-9);
    assert!((ate.rotation_deg.mean - 2.0).abs() < 1e-9);
    // A constant world offset is invisible to the RPE translation.
    let rpe = rpe(&g, &e, DEFAULT_MAX_DT_S, 1).expect("rpe");
    assert!(
        rpe.translation_m.max > 1e-4,
        "the camera-frame tilt changes relative motion"
    );
    let mut shifted = g.clone();
    shifted
        .poses
        .iter_mut()
        .for_each(|p| p.translation = offset * p.translation);
    let rpe = super::rpe(&g, &shifted, DEFAULT_MAX_DT_S, 1).expect("rpe");
    assert!(rpe.translation_m.max < 1e-12);
}

#[test]
fn errors_are_reported() {
    let g = gt(10);
    let mut late = g.clone();
    late.stamps_s.iter_mut().for_each(|s| *s += 100.0);
    assert!(matches!(
        ate(&g, &late, 0.005),
        Err(EvalError::NoOverlap { .. })
    ));
    assert!(matches!(
        ate(&g, &Trajectory::default(), 0.005),
        Err(EvalError::NoOverlap { .. })
    ));
    assert!(matches!(
        rpe(&g, &g, 0.005, 0),
        Err(EvalError::BadDelta { delta: 0, .. })
    ));
    assert!(matches!(
        rpe(&g, &g, 0.005, 10),
        Err(EvalError::BadDelta {
            delta: 10,
            matched: 10
        })
    ));
    assert!(matches!(
        ate(&g, &g, f64::NAN),
        Err(EvalError::BadTolerance(_))
    ));
    let text = evaluate(&g, &g, 0.005, Some(2)).expect("ok").to_string();
    assert!(
        text.contains("ATE translation [m]") && text.contains("RPE/2f rotation [deg]"),
        "{text}"
    );
}
