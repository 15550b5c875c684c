//! Landmark matching as the map grows (`STAR_BENCH_LANDMARK_SCALES=4,16,40`):
//! the scene's landmarks replicated into look-alike rooms, and the
//! frames' corners of the queries matched against them, near the last
//! position (spatial cells) and over the whole map (vocabulary), timed and
//! compared with brute force.
//!
//! Copy `k` of the landmarks lies `k x 30 m` along x (outside the room and
//! its reach), each descriptor with 20 of its 256 bits flipped: a room that
//! looks almost the same, the hard case for a ratio test. The vocabulary is
//! trained on the replicated set as `star reloc build` would.

use std::time::Instant;

use crate::offline::median_p99;
use crate::reloc::build::organize;
use crate::reloc::landmark_index::{BestTwo, LandmarkIndex};
use crate::reloc::landmarks::Landmark;
use crate::reloc::Descriptor;
use crate::rng::SplitMix64;

use super::setup::probes_from_env;

/// Spacing of the copies along x, meters.
const COPY_SPACING_M: f32 = 30.0;
/// Bits flipped in a copy's descriptor.
const FLIPPED_BITS: usize = 20;
/// Query frames whose recall is measured against brute force.
const RECALL_FRAMES: usize = 8;

/// The scales asked for by `STAR_BENCH_LANDMARK_SCALES` (none when unset).
pub(super) fn scales_from_env() -> Vec<usize> {
    std::env::var("STAR_BENCH_LANDMARK_SCALES")
        .ok()
        .map(|v| {
            v.split(',')
                .filter_map(|s| s.trim().parse().ok())
                .filter(|&s| s >= 1)
                .collect()
        })
        .unwrap_or_default()
}

/// Prints the figures for each of `scales` over `frames` (the queries'
/// corner descriptors) against `landmarks` replicated; `center_m` is a
/// position in the original room (the near search's center), `reach_m`
/// its reach.
pub(super) fn landmark_scaling(
    landmarks: &[Landmark],
    frames: &[Vec<Descriptor>],
    center_m: [f32; 2],
    reach_m: f32,
    scales: &[usize],
) {
    if landmarks.is_empty() || frames.is_empty() {
        return;
    }
    let max_bits = 50;
    for &scale in scales {
        let mut rng = SplitMix64::new(0x5ca1e ^ scale as u64);
        let mut all = Vec::with_capacity(landmarks.len() * scale);
        for k in 0..scale {
            for l in landmarks {
                let mut c = *l;
                c.world_m[0] += k as f32 * COPY_SPACING_M;
                if k > 0 {
                    for _ in 0..FLIPPED_BITS {
                        let b = rng.below(256);
                        c.descriptor.0[b / 64] ^= 1 << (b % 64);
                    }
                }
                all.push(c);
            }
        }
        let t_train = Instant::now();
        let (sorted, vocabulary) = organize(all);
        let train_s = t_train.elapsed().as_secs_f64();
        let mut index = LandmarkIndex::new(&sorted, &vocabulary);
        if let Some(p) = probes_from_env() {
            index.set_probes(p);
        }
        let mut out: Vec<BestTwo> = vec![(0, 0, 0, 0); 1024];
        let mut brute: Vec<BestTwo> = vec![(0, 0, 0, 0); 1024];
        let (mut cold_ms, mut cold_cmp, mut near_ms, mut near_cmp) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut found, mut of) = (0usize, 0usize);
        for (i, q) in frames.iter().enumerate() {
            let q = &q[..q.len().min(out.len())];
            let t = Instant::now();
            index.best_two_everywhere(q, &mut out);
            cold_ms.push(t.elapsed().as_secs_f64() * 1e3);
            cold_cmp.push(index.comparisons() as f64);
            if i < RECALL_FRAMES {
                index.best_two_all(q, &mut brute);
                for (o, b) in out[..q.len()].iter().zip(&brute) {
                    if b.0 <= max_bits {
                        of += 1;
                        found += usize::from(o.0 == b.0);
                    }
                }
            }
            let t = Instant::now();
            index.best_two_near(q, center_m, reach_m, &mut out);
            near_ms.push(t.elapsed().as_secs_f64() * 1e3);
            near_cmp.push(index.comparisons() as f64);
        }
        let (cm, cp) = median_p99(&cold_ms);
        let (cc, _) = median_p99(&cold_cmp);
        let (nm, np) = median_p99(&near_ms);
        let (nc, _) = median_p99(&near_cmp);
        println!(
            "  landmarks x{scale} = {} ({} leaves, vocabulary trained in {train_s:.1} s): whole map {cm:.2} / {cp:.2} ms median / p99, {cc:.0} comparisons, nearest found for {found}/{of} corners ({:.1} %); near the last position {nm:.2} / {np:.2} ms, {nc:.0} comparisons ({} frames)",
            sorted.len(),
            vocabulary.leaves.len(),
            100.0 * found as f64 / of.max(1) as f64,
            frames.len()
        );
    }
}
