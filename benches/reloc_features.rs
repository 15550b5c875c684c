//! Relocalization's local features (`star::reloc::features`): FAST + BRIEF
//! extraction on a 640x512 frame of smooth value noise (default settings,
//! 500 features over 4 levels), and brute-force Hamming matching
//! (`best_two`) of 50 of its descriptors against 100k random ones, whose
//! throughput criterion reports in descriptors per second. The keypoint
//! count is printed before the timings.
//!
//! Run: `cargo bench --bench reloc_features`.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use star::reloc::features::{best_two, FeatureExtractor, FeatureParams};
use star::reloc::Descriptor;
use star::rng::SplitMix64;

/// Value noise (octaves of 16, 8 and 4 px, smoothstep), contrast stretched
/// with saturation, at `(x, y)` pixels (the features' unit tests use the
/// same image).
fn noise(x: f32, y: f32) -> f32 {
    let mut v = 0.0;
    for (o, cell) in [16.0f32, 8.0, 4.0].into_iter().enumerate() {
        let (fx, fy) = (x / cell, y / cell);
        let (ix, iy) = (fx.floor() as i64, fy.floor() as i64);
        let smooth = |t: f32| t * t * (3.0 - 2.0 * t);
        let (tx, ty) = (smooth(fx - fx.floor()), smooth(fy - fy.floor()));
        let at = |dx: i64, dy: i64| {
            let h = ((ix + dx) as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
                ^ ((iy + dy) as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
            SplitMix64::new(h ^ o as u64).next_f64() as f32
        };
        let top = at(0, 0) * (1.0 - tx) + at(1, 0) * tx;
        let bottom = at(0, 1) * (1.0 - tx) + at(1, 1) * tx;
        v += (top * (1.0 - ty) + bottom * ty) / (1 << o) as f32;
    }
    (128.0 + 400.0 * (v / 1.75 - 0.5)).clamp(0.0, 255.0)
}

/// A `w x h` image of `noise`, each pixel the mean of 3x3 samples.
fn render(w: usize, h: usize) -> Vec<u8> {
    let at = |x: f32, y: f32| {
        let sub = |i: usize| (i as f32 - 1.0) / 3.0;
        let sum: f32 = (0..9).map(|i| noise(x + sub(i % 3), y + sub(i / 3))).sum();
        (sum / 9.0).round() as u8
    };
    (0..w * h)
        .map(|i| at((i % w) as f32 + 0.5, (i / w) as f32 + 0.5))
        .collect()
}

fn benches(c: &mut Criterion) {
    let (w, h) = (640, 512);
    let img = render(w, h);
    let mut fx = FeatureExtractor::new(w, h, &FeatureParams::default());
    let n = fx.extract(&img, w, h, w).len();
    println!("features/extract_640x512: {n} keypoints");
    c.bench_function("features/extract_640x512", |b| {
        b.iter(|| black_box(fx.extract(black_box(&img), w, h, w).len()))
    });

    let mut rng = SplitMix64::new(11);
    let train: Vec<Descriptor> = (0..100_000)
        .map(|_| Descriptor([(); 4].map(|_| rng.next_u64())))
        .collect();
    let queries: Vec<Descriptor> = fx.extract(&img, w, h, w)[..50.min(n)]
        .iter()
        .map(|k| k.descriptor)
        .collect();
    let mut group = c.benchmark_group("features");
    group.throughput(Throughput::Elements((queries.len() * train.len()) as u64));
    group.bench_function(format!("best_two_{}x{}", queries.len(), train.len()), |b| {
        b.iter(|| {
            queries
                .iter()
                .map(|q| best_two(black_box(q), &train).0 as u64)
                .sum::<u64>()
        })
    });
    group.finish();
}

criterion_group! {
    name = reloc_features;
    config = Criterion::default().sample_size(20).warm_up_time(std::time::Duration::from_secs(1));
    targets = benches
}
criterion_main!(reloc_features);
