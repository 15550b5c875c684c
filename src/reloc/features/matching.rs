//! Brute-force Hamming matching of binary descriptors: for each query, the
//! nearest and second-nearest training descriptors (for the ratio test of
//! [`crate::reloc::landmarks`]).
//!
//! Takes query and training [`Descriptor`] slices; gives `(best distance,
//! best index, second distance, second index)` per query, one at a time
//! ([`best_two`]) or [`BATCH`] queries per pass over the training set
//! ([`best_two_batch`]). Uses AVX2 / popcnt where the CPU has them;
//! allocates nothing.

use crate::reloc::descriptor::Descriptor;

/// For a query descriptor, the best and second-best training descriptors by
/// Hamming distance: `(best distance, best index, second distance, second
/// index)`; ties go to the lower index. Missing entries (fewer than two
/// training descriptors) are `u32::MAX`. Uses AVX2 / popcnt where the CPU
/// has them.
pub fn best_two(query: &Descriptor, train: &[Descriptor]) -> (u32, u32, u32, u32) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("popcnt")
        {
            // SAFETY: the CPU supports both features, checked just above.
            return unsafe { best_two_avx2(query, train) };
        }
        if std::arch::is_x86_feature_detected!("popcnt") {
            // SAFETY: the CPU supports popcnt, checked just above.
            return unsafe { best_two_popcnt(query, train) };
        }
    }
    best_two_scan(query, train)
}

/// [`best_two_scan`] compiled for AVX2 and popcnt.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
unsafe fn best_two_avx2(query: &Descriptor, train: &[Descriptor]) -> (u32, u32, u32, u32) {
    best_two_scan(query, train)
}

/// [`best_two_scan`] compiled with the popcnt instruction.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "popcnt")]
unsafe fn best_two_popcnt(query: &Descriptor, train: &[Descriptor]) -> (u32, u32, u32, u32) {
    best_two_scan(query, train)
}

/// The scan: one pass, the rare updates behind one well-predicted branch.
/// With AVX2 each distance is a handful of vector instructions (xor, nibble
/// table popcount, horizontal sum); with popcnt, four `popcnt`s.
#[inline(always)]
fn best_two_scan(query: &Descriptor, train: &[Descriptor]) -> (u32, u32, u32, u32) {
    let (mut best, mut best_i, mut second, mut second_i) = (u32::MAX, u32::MAX, u32::MAX, u32::MAX);
    for (i, t) in train.iter().enumerate() {
        let d = query.hamming(t);
        if d < second {
            if d < best {
                (second, second_i, best, best_i) = (best, best_i, d, i as u32);
            } else {
                (second, second_i) = (d, i as u32);
            }
        }
    }
    (best, best_i, second, second_i)
}

/// Queries matched per pass over the training set by [`best_two_batch`].
pub const BATCH: usize = 8;

/// [`best_two`] for every descriptor of `queries`, into `out` (one entry
/// per query; extra queries beyond `out.len()` are skipped). Matches
/// [`BATCH`] queries per pass over `train`, so the training set streams
/// through the cache once per batch rather than once per query.
pub fn best_two_batch(
    queries: &[Descriptor],
    train: &[Descriptor],
    out: &mut [(u32, u32, u32, u32)],
) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("popcnt")
        {
            // SAFETY: the CPU supports both features, checked just above.
            return unsafe { best_two_batch_avx2(queries, train, out) };
        }
        if std::arch::is_x86_feature_detected!("popcnt") {
            // SAFETY: the CPU supports popcnt, checked just above.
            return unsafe { best_two_batch_popcnt(queries, train, out) };
        }
    }
    best_two_batch_scan(queries, train, out)
}

/// [`best_two_batch_scan`] compiled for AVX2 and popcnt.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
unsafe fn best_two_batch_avx2(
    queries: &[Descriptor],
    train: &[Descriptor],
    out: &mut [(u32, u32, u32, u32)],
) {
    best_two_batch_scan(queries, train, out)
}

/// [`best_two_batch_scan`] compiled with the popcnt instruction.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "popcnt")]
unsafe fn best_two_batch_popcnt(
    queries: &[Descriptor],
    train: &[Descriptor],
    out: &mut [(u32, u32, u32, u32)],
) {
    best_two_batch_scan(queries, train, out)
}

#[inline(always)]
fn best_two_batch_scan(
    queries: &[Descriptor],
    train: &[Descriptor],
    out: &mut [(u32, u32, u32, u32)],
) {
    let n = queries.len().min(out.len());
    for (qs, os) in queries[..n].chunks(BATCH).zip(out[..n].chunks_mut(BATCH)) {
        let mut q = [Descriptor::default(); BATCH];
        q[..qs.len()].copy_from_slice(qs);
        let mut state = [(u32::MAX, u32::MAX, u32::MAX, u32::MAX); BATCH];
        for (i, t) in train.iter().enumerate() {
            let mut d = [0u32; BATCH];
            for j in 0..BATCH {
                d[j] = q[j].hamming(t);
            }
            for j in 0..BATCH {
                let s = &mut state[j];
                if d[j] < s.2 {
                    if d[j] < s.0 {
                        *s = (d[j], i as u32, s.0, s.1);
                    } else {
                        s.2 = d[j];
                        s.3 = i as u32;
                    }
                }
            }
        }
        os.copy_from_slice(&state[..os.len()]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    #[test]
    fn batch_matching_agrees_with_one_at_a_time() {
        let mut rng = crate::rng::SplitMix64::new(7);
        let mut draw = || Descriptor(std::array::from_fn(|_| rng.next_u64()));
        let train: Vec<Descriptor> = (0..1000).map(|_| draw()).collect();
        let queries: Vec<Descriptor> = (0..21).map(|_| draw()).collect();
        let mut out = vec![(0, 0, 0, 0); 21];
        best_two_batch(&queries, &train, &mut out);
        for (q, o) in queries.iter().zip(&out) {
            assert_eq!(*o, best_two(q, &train));
        }
    }

    #[test]
    fn best_two_finds_the_two_nearest() {
        let mut rng = SplitMix64::new(3);
        let train: Vec<Descriptor> = (0..1000)
            .map(|_| Descriptor([(); 4].map(|_| rng.next_u64())))
            .collect();
        let mut query = train[617];
        query.0[2] ^= 0b1011;
        let mut by_distance: Vec<(u32, u32)> = train
            .iter()
            .zip(0..)
            .map(|(t, i)| (query.hamming(t), i))
            .collect();
        by_distance.sort_unstable();
        let (d0, i0, d1, i1) = best_two(&query, &train);
        assert_eq!(((d0, i0), (d1, i1)), ((3, 617), by_distance[1]));
        let none = u32::MAX;
        assert_eq!(best_two(&query, &[]), (none, none, none, none));
        assert_eq!(best_two(&query, &train[617..618]), (3, 0, none, none));
        assert_eq!(best_two(&train[5], &[train[5]; 3]), (0, 0, 0, 1));
    }
}
