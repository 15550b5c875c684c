//! The seeded pseudo-random generator behind every deterministic random
//! choice: synthetic scenes, BRIEF sampling patterns, RANSAC draws and bench
//! queries. A leaf: it imports nothing of the crate.
//!
//! Fixed algorithm, no platform dependence: the same seed gives the same
//! sequence everywhere, so databases and datasets built from seeds are
//! reproducible bit for bit.

/// SplitMix64 (Steele, Lea, Flood 2014): a tiny, fast, seedable PRNG with a
/// fixed algorithm, so sequences are identical on every platform.
#[derive(Debug, Clone)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// A generator seeded with `seed`.
    pub fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix64(self.state)
    }

    /// Uniform in `[0, 1)` with 53 bits of precision.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next_f64()
    }

    /// Uniform integer in `0..n` (`0` when `n == 0`).
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            return 0;
        }
        (self.next_f64() * n as f64) as usize % n
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.next_f64() < p
    }

    /// An independent generator for a named sub-task, derived from this one's
    /// seed and `salt` without advancing this one.
    pub fn fork(&self, salt: u64) -> SplitMix64 {
        SplitMix64::new(mix64(
            self.state ^ mix64(salt.wrapping_add(0x5851_F42D_4C95_7F2D)),
        ))
    }
}

/// The SplitMix64 output mix (a bijective 64-bit hash).
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}
