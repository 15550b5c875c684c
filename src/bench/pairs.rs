//! `star bench pairs` and `star bench track`: keyframe/frame pairs from the
//! synthetic scene (keyframe gray + 16-bit depth rendered from the map with
//! holes, camera frame rendered from the truth with occluders, gain/bias
//! drift, vignetting and noise; pinhole, so other trackers can use them
//! as-is) with the ground-truth relative pose, and the STAR tracker's time
//! and error on each pair, aligned on one thread from the identity.
//! `scripts/bench_vs_opencv.py` runs OpenCV's RGB odometry on the same
//! pairs.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use nalgebra::{Translation3, UnitQuaternion, Vector3, Vector6};

use crate::config::TrackerConfig;
use crate::dataset::{decode_gray_into, decode_u16, write_gray16, write_gray8};
use crate::geometry::look::camera_rotation;
use crate::geometry::{exp_se3, PinholeCamera, Pose};
use crate::imgproc::ImageU8;
use crate::render::cpu::CpuRenderer;
use crate::render::{RenderedView, Renderer};
use crate::synth::corrupt::photometric::{PhotometricSpec, SensorModel};
use crate::synth::{build_scene, SceneParams, SplitMix64};
use crate::track::{Aligner, Keyframe, Pyramid};

use crate::offline::median_p99;

/// The camera of the benchmark pairs (the synthetic presets' intrinsics).
pub fn bench_camera() -> PinholeCamera {
    PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5)
}

pub fn write_pairs(out: &Path, count: usize, seed: u64) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let scene = build_scene(&SceneParams {
        seed,
        hole_fraction: 0.1,
        occluders: 3,
        ..SceneParams::default()
    });
    let camera = bench_camera();
    let mut map_r = CpuRenderer::new(Arc::new(scene.map.clone()))?;
    let mut truth_r = CpuRenderer::new(Arc::new(scene.truth.clone()))?;
    let sensor = SensorModel::new(
        PhotometricSpec {
            gain_drift: 0.3,
            bias_drift: 10.0,
            drift_period_s: (8.0, 25.0),
            vignetting: 0.3,
            noise_sigma: 3.0,
        },
        &camera,
        seed,
    );
    let mut rng = SplitMix64::new(seed ^ 0x5eed);
    let mut kf_view = RenderedView::for_camera(&camera);
    let mut frame_view = RenderedView::for_camera(&camera);
    let mut frame = ImageU8::new(0, 0, 0);
    let mut gt = String::from("# index  keyframe_from_frame: tx ty tz qx qy qz qw\n");
    let bar = indicatif::ProgressBar::new(count as u64);
    let mut written = 0;
    let mut tries = 0;
    while written < count {
        tries += 1;
        if tries > count * 50 {
            bail!("could only place {written} of {count} pairs in the scene");
        }
        let p = Vector3::new(
            rng.range(scene.free_min_m[0], scene.free_max_m[0]),
            rng.range(scene.free_min_m[1], scene.free_max_m[1]),
            rng.range(0.8, 2.2),
        );
        if !scene.is_free([p.x, p.y, p.z], 0.4) {
            continue;
        }
        let yaw = rng.range(-std::f64::consts::PI, std::f64::consts::PI);
        let pitch = rng.range(-15f64, 15.0).to_radians();
        let world_from_keyframe =
            Pose::from_parts(Translation3::from(p), camera_rotation(yaw, pitch, 0.0));
        map_r.render(&world_from_keyframe, &camera, &mut kf_view)?;
        let hits = kf_view.depth_m.data().iter().filter(|&&d| d > 0.0).count();
        if hits < kf_view.depth_m.data().len() * 6 / 10 {
            continue;
        }
        // A frame-to-keyframe motion typical of tracking: a few cm, a few degrees.
        let twist = Vector6::new(
            rng.range(-0.04, 0.04),
            rng.range(-0.04, 0.04),
            rng.range(-0.04, 0.04),
            rng.range(-2f64, 2.0).to_radians(),
            rng.range(-2f64, 2.0).to_radians(),
            rng.range(-2f64, 2.0).to_radians(),
        );
        let keyframe_from_frame = exp_se3(&twist);
        truth_r.render(
            &(world_from_keyframe * keyframe_from_frame),
            &camera,
            &mut frame_view,
        )?;
        sensor.apply(
            &frame_view.gray,
            written as u64,
            written as f64 * 0.37,
            &mut frame,
        );
        let i = written;
        write_gray8(&out.join(format!("kf_{i:04}.png")), &kf_view.gray.to_u8())?;
        let depth_mm: Vec<u16> = kf_view
            .depth_m
            .data()
            .iter()
            .map(|&d| (d * 1000.0).round().clamp(0.0, 65535.0) as u16)
            .collect();
        write_gray16(
            &out.join(format!("kf_depth_{i:04}.png")),
            camera.width,
            camera.height,
            &depth_mm,
        )?;
        write_gray8(&out.join(format!("frame_{i:04}.png")), &frame)?;
        let t = keyframe_from_frame.translation.vector;
        let q = keyframe_from_frame.rotation;
        let _ = writeln!(
            gt,
            "{i} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
            t.x, t.y, t.z, q.i, q.j, q.k, q.w
        );
        written += 1;
        bar.inc(1);
    }
    bar.finish_and_clear();
    std::fs::write(out.join("pairs.txt"), gt)?;
    let c = camera;
    std::fs::write(
        out.join("camera.txt"),
        format!(
            "# width height fx fy cx cy depth_scale(per m)\n{} {} {} {} {} {} 1000\n",
            c.width, c.height, c.fx, c.fy, c.cx, c.cy
        ),
    )?;
    println!("bench pairs: wrote {written} pairs to {}", out.display());
    Ok(())
}

/// One pair's ground truth: index and keyframe_from_frame.
fn read_pairs(dir: &Path) -> Result<Vec<(usize, Pose)>> {
    let path = dir.join("pairs.txt");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Vec<f64> = line
            .split_whitespace()
            .map(str::parse)
            .collect::<Result<_, _>>()
            .with_context(|| format!("{}:{}: not numbers", path.display(), n + 1))?;
        let [i, tx, ty, tz, qx, qy, qz, qw] = v[..] else {
            bail!(
                "{}:{}: expected 8 values, found {}",
                path.display(),
                n + 1,
                v.len()
            );
        };
        let q = nalgebra::Quaternion::new(qw, qx, qy, qz);
        out.push((
            i as usize,
            Pose::from_parts(
                Translation3::new(tx, ty, tz),
                UnitQuaternion::from_quaternion(q),
            ),
        ));
    }
    Ok(out)
}

pub fn track_pairs(dir: &Path, csv: Option<&Path>, repeat: usize) -> Result<()> {
    let pairs = read_pairs(dir)?;
    if pairs.is_empty() {
        bail!("{}: no pairs", dir.join("pairs.txt").display());
    }
    let camera = bench_camera();
    let config = TrackerConfig::default();
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut keyframe = Keyframe::new(&camera, &config);
    let mut view = RenderedView::for_camera(&camera);
    let mut aligner = Aligner::new(&config);
    let mut pyramid = Pyramid::new(w, h, config.pyramid_levels as usize);
    let mut gray = ImageU8::new(w, h, 0);
    let mut frame = ImageU8::new(w, h, 0);
    let mut depth = Vec::new();
    let mut scratch = Vec::new();
    let mut times_ms = Vec::with_capacity(pairs.len());
    let mut prep_ms = Vec::with_capacity(pairs.len());
    let (mut t_err, mut r_err) = (Vec::new(), Vec::new());
    let mut points = vec![Vec::new(); config.pyramid_levels as usize];
    let mut rows = String::from("index,time_ms,t_err_m,r_err_deg\n");
    for &(i, keyframe_from_frame) in &pairs {
        let size = Some((camera.width, camera.height));
        decode_gray_into(
            &dir.join(format!("kf_{i:04}.png")),
            size,
            &mut gray,
            &mut scratch,
        )?;
        decode_u16(&dir.join(format!("kf_depth_{i:04}.png")), size, &mut depth)?;
        decode_gray_into(
            &dir.join(format!("frame_{i:04}.png")),
            size,
            &mut frame,
            &mut scratch,
        )?;
        for (d, &s) in view.gray.data_mut().iter_mut().zip(gray.data()) {
            *d = s as f32;
        }
        for (d, &s) in view.depth_m.data_mut().iter_mut().zip(&depth) {
            *d = s as f32 * 1e-3;
        }
        let t0 = Instant::now();
        keyframe.prepare(&view, Pose::identity(), i as u64, &config);
        prep_ms.push(t0.elapsed().as_secs_f64() * 1e3);
        // The per-frame work: pyramid of the camera frame + alignment.
        let mut reps_ms = [0.0f64; 1000];
        let mut result = None;
        for rep_ms in reps_ms.iter_mut().take(repeat) {
            let t0 = Instant::now();
            pyramid.fill_from_u8(frame.data(), w);
            let aligned = aligner.align(&keyframe, &pyramid, &camera, Pose::identity());
            *rep_ms = t0.elapsed().as_secs_f64() * 1e3;
            result = Some(aligned);
        }
        let Some(result) = result else {
            bail!("--repeat must be at least 1");
        };
        let (ms, _) = median_p99(&reps_ms[..repeat]);
        let err = keyframe_from_frame.inverse() * result.camera_from_keyframe.inverse();
        let (te, re) = (
            err.translation.vector.norm(),
            err.rotation.angle().to_degrees(),
        );
        times_ms.push(ms);
        t_err.push(te);
        r_err.push(re);
        for (l, p) in points.iter_mut().enumerate() {
            p.push(result.quality.points_used[l] as f64);
        }
        let _ = writeln!(rows, "{i},{ms:.4},{te:.6},{re:.5}");
    }
    if let Some(csv) = csv {
        std::fs::write(csv, rows).with_context(|| format!("writing {}", csv.display()))?;
    }
    let (med, p99) = median_p99(&times_ms);
    let (prep_med, _) = median_p99(&prep_ms);
    let (t_med, _) = median_p99(&t_err);
    let (r_med, _) = median_p99(&r_err);
    let ok = t_err
        .iter()
        .zip(&r_err)
        .filter(|(t, r)| **t < 0.01 && **r < 0.5)
        .count();
    let pts: Vec<u32> = points.iter().map(|p| median_p99(p).0 as u32).collect();
    println!(
        "star tracker on {} pairs, 640x512, one thread{}:",
        pairs.len(),
        if repeat > 1 {
            format!(", each pair's time the median of {repeat} alignments")
        } else {
            String::new()
        }
    );
    println!("  per-frame time (pyramid + alignment): median {med:.2} ms, p99 {p99:.2} ms");
    println!("  keyframe preparation (render thread): median {prep_med:.2} ms");
    println!("  points used per level (median, finest first): {pts:?}");
    println!(
        "  error: median {:.2} mm, {:.3} deg; converged (< 1 cm and < 0.5 deg): {ok}/{}",
        t_med * 1e3,
        r_med,
        pairs.len()
    );
    Ok(())
}
