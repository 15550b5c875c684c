//! Milliseconds per 640x512 keyframe of the wgpu renderer, render plus
//! readback (gray + metric depth in host memory), on the procedural
//! textured room subdivided to 200k and 1M triangles, for every adapter
//! class present: the hardware adapter (an iGPU or discrete GPU through
//! Vulkan, then GL) and the software adapter (Mesa lavapipe/llvmpipe).
//! An absent adapter class is reported and skipped; the adapter name is
//! printed with the figures.
//!
//! Run: `cargo bench --bench render_gpu`.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::hint::black_box;
use std::sync::Arc;

use criterion::{criterion_group, criterion_main, Criterion};
use star::geometry::PinholeCamera;
use star::map::{subdivide, Mesh};
use star::render::gpu::{AdapterPreference, GpuRenderer};
use star::render::{RenderedView, Renderer};

#[path = "../tests/common/room.rs"]
mod room;
use room::{poses, room};

fn bench_mesh(c: &mut Criterion, class: &str, which: AdapterPreference, name: &str, mesh: &Mesh) {
    let camera = PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
    let triangles = mesh.triangle_count();
    let mut renderer = match GpuRenderer::new(Arc::new(mesh.clone()), which) {
        Ok(r) => r,
        Err(e) => {
            println!("{class}: no adapter of this class, skipped ({e})");
            return;
        }
    };
    let mut out = RenderedView::for_camera(&camera);
    let poses = poses();
    for p in &poses {
        renderer.render(p, &camera, &mut out).expect("render");
    }
    println!(
        "{class}/{name}: {triangles} triangles on {}",
        renderer.name()
    );
    let mut k = 0;
    c.bench_function(&format!("wgpu_{class}_640x512/{name}"), |b| {
        b.iter(|| {
            k = (k + 1) % poses.len();
            renderer
                .render(black_box(&poses[k]), &camera, &mut out)
                .expect("render");
            black_box(out.depth_m.data()[0])
        })
    });
}

fn benches(c: &mut Criterion) {
    let m200k = subdivide(&room(6, 2), 200_000);
    let m1m = subdivide(&room(8, 2), 1_000_000);
    for (class, which) in [
        ("hardware", AdapterPreference::Hardware),
        ("software", AdapterPreference::Software),
    ] {
        bench_mesh(c, class, which, "room_200k", &m200k);
        bench_mesh(c, class, which, "room_1m", &m1m);
    }
}

criterion_group! {
    name = render_gpu;
    config = Criterion::default().sample_size(20).warm_up_time(std::time::Duration::from_secs(1));
    targets = benches
}
criterion_main!(render_gpu);
