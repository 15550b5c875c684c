//! Milliseconds to prepare one 640x512 keyframe (fx = 420) from a rendered
//! view: the pyramid, the selection of semi-dense points on every level
//! and their Jacobians ([`star::track::Keyframe::prepare`]), as the render
//! thread does for every keyframe and relocalization for every candidate.
//! The views are the `realistic` preset's room
//! (its map mesh) from 8 poses of its trajectory, one second apart,
//! rendered once by the CPU rasterizer before the timing.
//!
//! Run: `cargo bench --bench keyframe_prepare`.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::hint::black_box;
use std::sync::Arc;

use criterion::{criterion_group, criterion_main, Criterion};
use star::geometry::PinholeCamera;
use star::render::cpu::CpuRenderer;
use star::render::{RenderedView, Renderer};
use star::track::{build_config, Keyframe, TrackerConfig};

fn prepare(c: &mut Criterion) {
    let preset = star::synth::preset::Preset::by_name("realistic").expect("preset");
    let (scene, trajectory, _) =
        star::synth::sequence::scene_with_trajectory(&preset, 1, 8.0).expect("scene");
    let camera = PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
    let mut renderer = CpuRenderer::new(Arc::new(scene.map)).expect("valid mesh");
    let views: Vec<(star::geometry::Pose, RenderedView)> = (0..8)
        .map(|k| {
            let pose = trajectory.pose_at(k as f64);
            let mut view = RenderedView::for_camera(&camera);
            renderer.render(&pose, &camera, &mut view).expect("render");
            (pose, view)
        })
        .collect();
    // The configuration the service prepares keyframes with (one pyramid
    // level more than tracking aligns on).
    let config = build_config(&TrackerConfig::default());
    let mut keyframe = Keyframe::new(&camera, &config);
    let points: usize = views
        .iter()
        .map(|(pose, view)| {
            keyframe.prepare(view, *pose, 0, &config);
            keyframe.point_count(0)
        })
        .sum();
    println!(
        "keyframe_prepare: {} views, {:.0} level-0 points each on average",
        views.len(),
        points as f64 / views.len() as f64
    );
    let mut k = 0;
    c.bench_function("keyframe_prepare_640x512", |b| {
        b.iter(|| {
            k = (k + 1) % views.len();
            let (pose, view) = &views[k];
            keyframe.prepare(black_box(view), *pose, 0, &config);
            black_box(keyframe.point_count(0))
        })
    });
}

criterion_group!(benches, prepare);
criterion_main!(benches);
