//! Relocalization's landmark pose (`star::reloc::pnp::RansacPnp`): RANSAC
//! P3P over 300 correspondences, as a frame's features matched to the
//! landmarks hand it, at three inlier ratios:
//!
//! - 50 %: a room the ratio test locates; RANSAC stops early;
//! - 15 %: a look-alike room matched without the ratio test, where one
//!   match in five or fewer is at the right place;
//! - 0 %: no pose to find, so every one of the 5 000 hypotheses is drawn
//!   and scored (what a frame that finds no pose pays, per pass).
//!
//! Each case prints, before its timings, whether the pose was found and
//! how many inliers it has.
//!
//! Run: `cargo bench --bench reloc_pnp`.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Point3, UnitQuaternion, Vector2, Vector3};
use star::geometry::Pose;
use star::reloc::pnp::{PnpParams, RansacPnp};
use star::rng::SplitMix64;

/// Correspondences per call: about the features of a frame that have a
/// landmark within the Hamming bound.
const N: usize = 300;
/// The focal length the threshold is given at, pixels.
const F_PX: f64 = 500.0;

/// `N` points 1-6 m in front of a random camera; the first `(1 - inlier)
/// * N` observations are random, the rest exact plus 0.5 px of noise.
fn scene(seed: u64, inlier: f64) -> (Vec<Vector3<f64>>, Vec<Vector2<f64>>) {
    let mut rng = SplitMix64::new(seed);
    let mut r = |s: f64| rng.range(-s, s);
    let axis = Vector3::new(r(3.0), r(3.0), r(3.0));
    let t = Vector3::new(r(5.0), r(5.0), r(5.0));
    let world_from_camera = Pose::from_parts(t.into(), UnitQuaternion::from_scaled_axis(axis));
    let (mut world, mut obs) = (Vec::with_capacity(N), Vec::with_capacity(N));
    for i in 0..N {
        let x = Vector2::new(r(0.6), r(0.45));
        let p_camera = Point3::from(x.push(1.0) * (3.5 + r(2.5)));
        world.push((world_from_camera * p_camera).coords);
        let outlier = (i as f64) < (1.0 - inlier) * N as f64;
        obs.push(if outlier {
            Vector2::new(r(0.6), r(0.45))
        } else {
            x + Vector2::new(r(0.5), r(0.5)) / F_PX
        });
    }
    (world, obs)
}

fn bench(c: &mut Criterion) {
    // The landmark locator's settings: 5 000 hypotheses, 3 px.
    let params = PnpParams {
        max_iterations: 5000,
        threshold: 3.0 / F_PX,
        min_inliers: 12,
        confidence: 0.999,
    };
    let mut group = c.benchmark_group("ransac_pnp_300");
    group.sample_size(20);
    for (name, inlier) in [
        ("inliers_50pct", 0.5),
        ("inliers_15pct", 0.15),
        ("no_pose", 0.0),
    ] {
        let (world, obs) = scene(7, inlier);
        let mut pnp = RansacPnp::new(N);
        let found = pnp.solve(&world, &obs, &params, 1);
        println!(
            "{name}: {}",
            found.map_or("no pose".to_string(), |f| format!(
                "pose with {} inliers of {N}",
                f.inliers
            ))
        );
        group.bench_function(name, |b| {
            b.iter(|| black_box(pnp.solve(black_box(&world), black_box(&obs), &params, 1)))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
