//! Tracker tests on an analytic scene: a tilted, textured plane rendered by
//! ray casting, so ground truth is exact and independent of the rasterizers.

use nalgebra::{Translation3, UnitQuaternion, Vector2, Vector3};

use crate::geometry::{Distortion, PinholeCamera, Pose};
use crate::render::RenderedView;
use crate::track::{IlluminationModel, TrackerConfig};

use super::*;

fn texture(x: f64, y: f64) -> f64 {
    128.0
        + 50.0 * (20.0 * x + 3.0 * (7.0 * y).sin()).sin() * (17.0 * y).cos()
        + 30.0 * (31.0 * x - 23.0 * y).sin()
}

/// Plane `Z = 2 + 0.2 X` in the world frame; returns (gray, depth) at a pixel.
fn cast(world_from_camera: &Pose, camera: &PinholeCamera, u: f64, v: f64) -> Option<(f64, f64)> {
    let ray_c = camera.unproject(Vector2::new(u, v), 1.0)?;
    let o = world_from_camera.translation.vector;
    let d = world_from_camera.rotation * ray_c;
    let s = (2.0 - o.z + 0.2 * o.x) / (d.z - 0.2 * d.x);
    if !(s > 0.0) {
        return None;
    }
    let p = o + d * s;
    Some((texture(p.x, p.y), s))
}

fn camera() -> PinholeCamera {
    PinholeCamera::new(320, 256, 210.0, 210.0, 159.5, 127.5)
}

fn config() -> TrackerConfig {
    TrackerConfig {
        pyramid_levels: 3,
        max_points: 3000,
        ..TrackerConfig::default()
    }
}

fn render_view(world_from_camera: &Pose, camera: &PinholeCamera) -> RenderedView {
    let mut view = RenderedView::for_camera(camera);
    for v in 0..camera.height as usize {
        for u in 0..camera.width as usize {
            if let Some((g, d)) = cast(world_from_camera, camera, u as f64, v as f64) {
                view.gray.row_mut(v)[u] = g as f32;
                view.depth_m.row_mut(v)[u] = d as f32;
            }
        }
    }
    view
}

fn camera_image(world_from_camera: &Pose, camera: &PinholeCamera, gain: f64, bias: f64) -> Vec<u8> {
    let mut img = vec![0u8; (camera.width * camera.height) as usize];
    for v in 0..camera.height as usize {
        for u in 0..camera.width as usize {
            if let Some((g, _)) = cast(world_from_camera, camera, u as f64, v as f64) {
                img[v * camera.width as usize + u] =
                    (gain * g + bias).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    img
}

fn pose(t: [f64; 3], rpy_deg: [f64; 3]) -> Pose {
    Pose::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_euler_angles(
            rpy_deg[0].to_radians(),
            rpy_deg[1].to_radians(),
            rpy_deg[2].to_radians(),
        ),
    )
}

struct Setup {
    keyframe: Keyframe,
    config: TrackerConfig,
}

fn setup(config: TrackerConfig) -> Setup {
    let cam = camera();
    let view = render_view(&Pose::identity(), &cam);
    let mut keyframe = Keyframe::new(&cam, &config);
    keyframe.prepare(&view, Pose::identity(), 1, &config);
    Setup { keyframe, config }
}

fn run(
    s: &Setup,
    cam: &PinholeCamera,
    truth: &Pose,
    gain: f64,
    bias: f64,
) -> (Alignment, f64, f64) {
    let img = camera_image(truth, cam, gain, bias);
    let mut pyr = Pyramid::new(
        cam.width as usize,
        cam.height as usize,
        s.config.pyramid_levels as usize,
    );
    pyr.fill_from_u8(&img, cam.width as usize);
    let mut aligner = Aligner::new(&s.config);
    let result = aligner.align(&s.keyframe, &pyr, cam, Pose::identity());
    // keyframe = world, so world_from_camera = inverse(camera_from_keyframe).
    let est = result.camera_from_keyframe.inverse();
    let err = truth.inverse() * est;
    (
        result,
        err.translation.vector.norm(),
        err.rotation.angle().to_degrees(),
    )
}

#[test]
fn keyframe_selects_points_on_every_level() {
    let s = setup(config());
    for l in 0..3 {
        let n = s.keyframe.point_count(l);
        assert!(n >= 200, "level {l}: {n} points");
        assert!(n <= s.config.max_points_per_level(l));
    }
    // Back-projected points lie on the plane Z = 2 + 0.2 X.
    for p in &s.keyframe.levels[0].points {
        let [x, _, z] = p.p_keyframe;
        assert!((z - (2.0 + 0.2 * x)).abs() < 2e-3, "{:?}", p.p_keyframe);
    }
    assert!((s.keyframe.median_depth_m - 2.0).abs() < 0.2);
}

#[test]
fn aligns_small_motion_to_sub_millimeter() {
    let s = setup(config());
    let truth = pose([0.05, -0.03, 0.04], [1.5, -2.0, 1.0]);
    let (r, t_err, r_err) = run(&s, &camera(), &truth, 1.0, 0.0);
    assert!(r.valid);
    assert!(
        t_err < 2e-3 && r_err < 0.05,
        "t {t_err} m, r {r_err} deg, {r:?}"
    );
    assert!(r.quality.inlier_ratio > 0.95, "{:?}", r.quality);
    assert!(r.quality.visible_ratio > 0.8);
}

#[test]
fn affine_model_absorbs_gain_and_bias() {
    let s = setup(config());
    let truth = pose([0.03, 0.02, -0.05], [-1.0, 1.0, 2.0]);
    let (r, t_err, r_err) = run(&s, &camera(), &truth, 0.75, 18.0);
    assert!(t_err < 2e-3 && r_err < 0.05, "t {t_err} m, r {r_err} deg");
    assert!(
        (r.gain - 0.75).abs() < 0.02 && (r.bias - 18.0).abs() < 3.0,
        "{} {}",
        r.gain,
        r.bias
    );
}

#[test]
fn median_model_absorbs_offset() {
    let s = setup(TrackerConfig {
        illumination: IlluminationModel::Median,
        ..config()
    });
    let truth = pose([0.03, 0.02, -0.05], [-1.0, 1.0, 2.0]);
    let (r, t_err, r_err) = run(&s, &camera(), &truth, 1.0, -15.0);
    assert!(t_err < 3e-3 && r_err < 0.1, "t {t_err} m, r {r_err} deg");
    assert!((r.bias + 15.0).abs() < 2.0, "beta {}", r.bias);
}

#[test]
fn distortion_is_handled_in_the_warp() {
    let s = setup(config());
    let cam = PinholeCamera {
        distortion: Distortion {
            k1: -0.25,
            k2: 0.06,
            p1: 0.001,
            p2: -0.0007,
            k3: 0.0,
        },
        ..camera()
    };
    let truth = pose([-0.04, 0.02, 0.03], [1.0, 1.5, -1.0]);
    let (r, t_err, r_err) = run(&s, &cam, &truth, 1.0, 0.0);
    assert!(
        r.valid && t_err < 3e-3 && r_err < 0.08,
        "t {t_err} m, r {r_err} deg"
    );
}

#[test]
fn covariance_is_finite_and_positive() {
    let s = setup(config());
    let truth = pose([0.01, 0.0, 0.0], [0.0, 0.5, 0.0]);
    let (r, _, _) = run(&s, &camera(), &truth, 1.0, 0.0);
    for i in 0..6 {
        assert!(r.covariance_delta[i][i] > 0.0 && r.covariance_delta[i][i].is_finite());
    }
}

#[test]
fn covariance_scale_multiplies_the_variance() {
    // The residual-variance estimate times the benches' factor: the same
    // alignment with `covariance_scale` 1 and 9 differs by exactly 9.
    let truth = pose([0.01, 0.0, 0.0], [0.0, 0.5, 0.0]);
    let one = setup(TrackerConfig {
        covariance_scale: 1.0,
        ..config()
    });
    let nine = setup(TrackerConfig {
        covariance_scale: 9.0,
        ..config()
    });
    let (a, _, _) = run(&one, &camera(), &truth, 1.0, 0.0);
    let (b, _, _) = run(&nine, &camera(), &truth, 1.0, 0.0);
    for i in 0..6 {
        for j in 0..6 {
            let (x, y) = (a.covariance_delta[i][j], b.covariance_delta[i][j]);
            assert!(
                (y - 9.0 * x).abs() <= 1e-9 * y.abs().max(1e-30),
                "({i}, {j}): {x} {y}"
            );
        }
    }
}

#[test]
fn all_black_frame_is_not_a_confident_pose() {
    let s = setup(config());
    let cam = camera();
    let img = vec![0u8; (cam.width * cam.height) as usize];
    let mut pyr = Pyramid::new(cam.width as usize, cam.height as usize, 3);
    pyr.fill_from_u8(&img, cam.width as usize);
    let r = Aligner::new(&s.config).align(&s.keyframe, &pyr, &cam, Pose::identity());
    assert!(!r.valid || r.quality.inlier_ratio < 0.3, "{r:?}");
    let t = r.camera_from_keyframe.translation.vector;
    assert!(t.iter().all(|v| v.is_finite()));
    let _ = Vector3::<f64>::zeros();
}

#[test]
fn a_precise_start_aligns_without_the_coarsest_levels() {
    let s = setup(config());
    let cam = camera();
    let truth = pose([0.01, -0.008, 0.01], [0.3, -0.2, 0.25]);
    let img = camera_image(&truth, &cam, 1.1, 4.0);
    let mut pyr = Pyramid::new(cam.width as usize, cam.height as usize, 3);
    pyr.fill_from_u8(&img, cam.width as usize);
    let mut aligner = Aligner::new(&s.config);
    let full = aligner.align(&s.keyframe, &pyr, &cam, Pose::identity());
    assert!(full.quality.points_used[2] > 0, "{:?}", full.quality);
    for skip in [1, 2, 5] {
        let a = aligner.align_without_coarsest(&s.keyframe, &pyr, &cam, Pose::identity(), skip);
        // The skipped levels saw no points; level 0 is always aligned.
        let kept = 3usize.saturating_sub(skip).max(1);
        for level in kept..3 {
            assert_eq!(
                a.quality.points_used[level], 0,
                "skip {skip}: {:?}",
                a.quality
            );
        }
        assert!(a.quality.points_used[0] > 0, "skip {skip}: {:?}", a.quality);
        assert!(a.valid, "skip {skip}");
        let err = truth.inverse() * a.camera_from_keyframe.inverse();
        assert!(
            err.translation.vector.norm() < 2e-3 && err.rotation.angle().to_degrees() < 0.1,
            "skip {skip}: {:.4} m {:.3} deg",
            err.translation.vector.norm(),
            err.rotation.angle().to_degrees()
        );
    }
}
