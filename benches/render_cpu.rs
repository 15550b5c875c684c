//! Milliseconds per 640x512 frame (fx = 420) of the CPU rasterizer, on a
//! procedural textured room with furniture, subdivided to 200k and 1M
//! triangles (`star::map::subdivide`). Each iteration renders the next of 8
//! poses inside the room, so the figure averages views of walls, corners
//! and furniture at 0.3..6 m.
//!
//! The first figure is the synthetic default scene of `star synth` (the
//! `realistic` map mesh, about 24k triangles) along its trajectory.
//!
//! Run: `cargo bench --bench render_cpu`.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::hint::black_box;
use std::sync::Arc;

use criterion::{criterion_group, criterion_main, Criterion};
use star::geometry::PinholeCamera;
use star::map::{subdivide, Mesh};
use star::render::cpu::CpuRenderer;
use star::render::{RenderedView, Renderer};

#[path = "../tests/common/room.rs"]
mod room;
use room::{poses, room};

fn bench_mesh(c: &mut Criterion, name: &str, mesh: Mesh, threads: Option<usize>) {
    bench_mesh_at(c, name, mesh, threads, poses());
}

/// The synthetic default scene (`star synth`'s room, map mesh) seen from 8
/// poses of the `realistic` preset's trajectory, one second apart.
fn bench_synth_default(c: &mut Criterion) {
    let preset = star::synth::preset::Preset::by_name("realistic").expect("preset");
    let (scene, trajectory, _) =
        star::synth::sequence::scene_with_trajectory(&preset, 1, 8.0).expect("scene");
    let poses = (0..8).map(|k| trajectory.pose_at(k as f64)).collect();
    bench_mesh_at(c, "cpu_640x512/synth_default", scene.map, None, poses);
}

fn bench_mesh_at(
    c: &mut Criterion,
    name: &str,
    mesh: Mesh,
    threads: Option<usize>,
    poses: Vec<star::geometry::Pose>,
) {
    let camera = PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
    let triangles = mesh.triangle_count();
    let mesh = Arc::new(mesh);
    let mut renderer = match threads {
        Some(n) => CpuRenderer::with_threads(mesh, n),
        None => CpuRenderer::new(mesh),
    }
    .expect("valid mesh");
    let mut out = RenderedView::for_camera(&camera);
    let mut hits = 0usize;
    for p in &poses {
        renderer.render(p, &camera, &mut out).expect("render");
        hits += out.depth_m.data().iter().filter(|&&d| d > 0.0).count();
    }
    println!(
        "{name}: {triangles} triangles, {} threads, {:.1}% of pixels hit",
        renderer.threads(),
        100.0 * hits as f64 / (poses.len() * 640 * 512) as f64
    );
    let mut k = 0;
    c.bench_function(name, |b| {
        b.iter(|| {
            k = (k + 1) % poses.len();
            renderer
                .render(black_box(&poses[k]), &camera, &mut out)
                .expect("render");
            black_box(out.gray.data()[0])
        })
    });
}

fn benches(c: &mut Criterion) {
    bench_synth_default(c);
    // Base meshes sized so that 1-to-4 subdivision lands just above the
    // target counts: 816 * 4^4 = 209k, 1152 * 4^5 = 1.18M.
    bench_mesh(c, "cpu_640x512/room_1k", room(8, 2), None);
    let m200k = subdivide(&room(6, 2), 200_000);
    bench_mesh(c, "cpu_640x512/room_200k", m200k.clone(), None);
    bench_mesh(c, "cpu_640x512/room_200k_1thread", m200k, Some(1));
    bench_mesh(
        c,
        "cpu_640x512/room_1m",
        subdivide(&room(8, 2), 1_000_000),
        None,
    );
}

criterion_group! {
    name = render_cpu;
    config = Criterion::default().sample_size(20).warm_up_time(std::time::Duration::from_secs(1));
    targets = benches
}
criterion_main!(render_cpu);
