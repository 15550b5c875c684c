//! The landmark vocabulary: a two-level tree of binary words over the
//! landmarks' BRIEF descriptors, trained on the map's own landmarks when
//! the database is built (k-majority clustering, DBoW-style), and stored in
//! the database with the landmarks sorted by leaf (the inverted file).
//!
//! Takes the landmark descriptors at build time; gives out the
//! [`Vocabulary`] (the words, the leaves under each word, and how many
//! landmarks each leaf holds) and the order to store the landmarks in.
//! Online, [`super::landmark_index`] descends it to the few leaves nearest
//! to a frame's corner and compares the corner only with the landmarks
//! there, instead of with every landmark of the map.

use rayon::prelude::*;

use crate::rng::SplitMix64;

use super::descriptor::Descriptor;

/// Most top-level words.
pub const MAX_WORDS: usize = 64;
/// Most leaves under one word.
pub const MAX_LEAVES_PER_WORD: usize = 64;
/// Landmarks per leaf the training aims at (the leaf count follows the
/// landmark count up to `MAX_WORDS x MAX_LEAVES_PER_WORD` leaves).
const LEAF_TARGET: usize = 24;
/// k-majority iterations (fewer when the assignment stops changing).
const ITERATIONS: usize = 10;
/// Most descriptors one clustering is trained on (a strided sample beyond).
const MAX_TRAIN: usize = 100_000;
/// Seed of the k-means++ seeding: the vocabulary depends only on the map.
const SEED: u64 = 0x5354_4152_564f_4342;

/// The vocabulary. Leaf `l` holds landmarks `sum(leaf_sizes[..l])..` of
/// the database, the leaves of word `w` follow those of word `w - 1`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Vocabulary {
    /// Top-level words.
    pub words: Vec<Descriptor>,
    /// Number of leaves under each word.
    pub word_leaves: Vec<u32>,
    /// Leaf words, word after word.
    pub leaves: Vec<Descriptor>,
    /// Number of landmarks in each leaf.
    pub leaf_sizes: Vec<u32>,
}

impl Vocabulary {
    /// True when there is no word (a database without landmarks).
    pub fn is_empty(&self) -> bool {
        self.words.is_empty()
    }

    /// Trains a vocabulary on `descriptors`; gives it and, per descriptor,
    /// its leaf (which [`Self::leaf_of`] also gives). The vocabulary's
    /// `leaf_sizes` count the descriptors per leaf.
    pub fn train(descriptors: &[Descriptor]) -> (Self, Vec<u32>) {
        if descriptors.is_empty() {
            return (Self::default(), Vec::new());
        }
        let mut rng = SplitMix64::new(SEED);
        let n_leaves = descriptors.len().div_ceil(LEAF_TARGET);
        let k_words = ((n_leaves as f64).sqrt().ceil() as usize).clamp(1, MAX_WORDS);
        let words = k_majority(&sample(descriptors), k_words, &mut rng);
        let word_of: Vec<u32> = descriptors
            .par_iter()
            .map(|d| nearest(&words, d).0)
            .collect();
        let mut vocabulary = Self {
            words,
            ..Self::default()
        };
        let mut members = Vec::new();
        for w in 0..vocabulary.words.len() {
            members.clear();
            members.extend(
                descriptors
                    .iter()
                    .zip(&word_of)
                    .filter(|&(_, &o)| o as usize == w)
                    .map(|(d, _)| *d),
            );
            let k = members
                .len()
                .div_ceil(LEAF_TARGET)
                .clamp(1, MAX_LEAVES_PER_WORD);
            let leaves = if members.is_empty() {
                vec![vocabulary.words[w]]
            } else {
                k_majority(&sample(&members), k, &mut rng)
            };
            vocabulary.word_leaves.push(leaves.len() as u32);
            vocabulary.leaves.extend(leaves);
        }
        let leaf_of: Vec<u32> = descriptors
            .par_iter()
            .map(|d| vocabulary.leaf_of(d).unwrap_or(0))
            .collect();
        vocabulary.leaf_sizes = vec![0; vocabulary.leaves.len()];
        for &l in &leaf_of {
            vocabulary.leaf_sizes[l as usize] += 1;
        }
        (vocabulary, leaf_of)
    }

    /// The leaf of `descriptor`: the nearest leaf under the nearest word
    /// (ties to the lower index); `None` for an empty vocabulary.
    pub fn leaf_of(&self, descriptor: &Descriptor) -> Option<u32> {
        if self.words.is_empty() {
            return None;
        }
        let (w, _) = nearest(&self.words, descriptor);
        let first = self.first_leaf(w as usize);
        let n = *self.word_leaves.get(w as usize)? as usize;
        let (l, _) = nearest(self.leaves.get(first..first + n)?, descriptor);
        Some((first + l as usize) as u32)
    }

    /// Index of the first leaf of word `w`.
    pub fn first_leaf(&self, w: usize) -> usize {
        self.word_leaves[..w.min(self.word_leaves.len())]
            .iter()
            .map(|&n| n as usize)
            .sum()
    }

    /// Errors unless the vocabulary is consistent with `n_landmarks`
    /// landmarks stored leaf after leaf: says what is wrong.
    pub fn check(&self, n_landmarks: u64) -> Result<(), String> {
        if self.word_leaves.len() != self.words.len() {
            return Err(format!(
                "{} words but {} leaf counts",
                self.words.len(),
                self.word_leaves.len()
            ));
        }
        if let Some(w) = self
            .word_leaves
            .iter()
            .position(|&n| n == 0 || n as usize > MAX_LEAVES_PER_WORD)
        {
            return Err(format!(
                "word {w} has {} leaves (1..={MAX_LEAVES_PER_WORD})",
                self.word_leaves[w]
            ));
        }
        let leaves: u64 = self.word_leaves.iter().map(|&n| n as u64).sum();
        if leaves != self.leaves.len() as u64 || leaves != self.leaf_sizes.len() as u64 {
            return Err(format!(
                "the words have {leaves} leaves, the file {} (sizes for {})",
                self.leaves.len(),
                self.leaf_sizes.len()
            ));
        }
        let held: u64 = self.leaf_sizes.iter().map(|&n| n as u64).sum();
        if held != n_landmarks || (self.words.is_empty() && n_landmarks > 0) {
            return Err(format!(
                "the leaves hold {held} landmarks, the file has {n_landmarks}"
            ));
        }
        Ok(())
    }
}

/// The nearest of `centers` to `d`: (index, distance); ties to the lower
/// index. `(0, u32::MAX)` when `centers` is empty.
pub fn nearest(centers: &[Descriptor], d: &Descriptor) -> (u32, u32) {
    let mut best = (0u32, u32::MAX);
    for (i, c) in centers.iter().enumerate() {
        let h = c.hamming(d);
        if h < best.1 {
            best = (i as u32, h);
        }
    }
    best
}

/// At most [`MAX_TRAIN`] of `data`, evenly strided.
fn sample(data: &[Descriptor]) -> Vec<Descriptor> {
    if data.len() <= MAX_TRAIN {
        return data.to_vec();
    }
    (0..MAX_TRAIN)
        .map(|i| data[i * data.len() / MAX_TRAIN])
        .collect()
}

/// k-majority clustering (k-means with Hamming distance and the bitwise
/// majority as the center), seeded by k-means++; at most `k` centers,
/// fewer when `data` has fewer distinct descriptors.
fn k_majority(data: &[Descriptor], k: usize, rng: &mut SplitMix64) -> Vec<Descriptor> {
    let k = k.min(data.len());
    if k == 0 {
        return Vec::new();
    }
    let mut centers = Vec::with_capacity(k);
    centers.push(data[rng.below(data.len())]);
    let mut to_nearest: Vec<u32> = data.iter().map(|d| d.hamming(&centers[0])).collect();
    while centers.len() < k {
        let total: u64 = to_nearest.iter().map(|&d| (d as u64) * (d as u64)).sum();
        if total == 0 {
            break;
        }
        let mut pick = rng.next_u64() % total;
        let mut chosen = data.len() - 1;
        for (i, &d) in to_nearest.iter().enumerate() {
            let w = (d as u64) * (d as u64);
            if pick < w {
                chosen = i;
                break;
            }
            pick -= w;
        }
        let c = data[chosen];
        centers.push(c);
        for (n, d) in to_nearest.iter_mut().zip(data) {
            *n = (*n).min(d.hamming(&c));
        }
    }
    let mut assignment = vec![u32::MAX; data.len()];
    for _ in 0..ITERATIONS {
        let next: Vec<u32> = data.par_iter().map(|d| nearest(&centers, d).0).collect();
        if next == assignment {
            break;
        }
        assignment = next;
        let mut counts = vec![[0u32; 256]; centers.len()];
        let mut sizes = vec![0u32; centers.len()];
        for (d, &a) in data.iter().zip(&assignment) {
            let a = a as usize;
            sizes[a] += 1;
            for (bit, c) in counts[a].iter_mut().enumerate() {
                *c += ((d.0[bit / 64] >> (bit % 64)) & 1) as u32;
            }
        }
        for ((center, count), &size) in centers.iter_mut().zip(&counts).zip(&sizes) {
            if size == 0 {
                continue;
            }
            let mut words = [0u64; 4];
            for (bit, &c) in count.iter().enumerate() {
                if 2 * c > size {
                    words[bit / 64] |= 1 << (bit % 64);
                }
            }
            *center = Descriptor(words);
        }
    }
    centers
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random(n: usize, seed: u64) -> Vec<Descriptor> {
        let mut rng = SplitMix64::new(seed);
        (0..n)
            .map(|_| Descriptor(std::array::from_fn(|_| rng.next_u64())))
            .collect()
    }

    #[test]
    fn training_is_consistent_and_deterministic() {
        let data = random(5000, 1);
        let (v, leaf_of) = Vocabulary::train(&data);
        assert!(v.words.len() > 1 && v.leaves.len() > v.words.len());
        v.check(data.len() as u64).expect("consistent");
        for (d, &l) in data.iter().zip(&leaf_of) {
            assert_eq!(v.leaf_of(d), Some(l));
        }
        let (again, _) = Vocabulary::train(&data);
        assert_eq!(again, v);
        assert_eq!(
            v.check(data.len() as u64 + 1)
                .map_err(|e| e.contains("hold")),
            Err(true)
        );
    }

    #[test]
    fn empty_vocabulary_has_no_leaf() {
        let (v, leaf_of) = Vocabulary::train(&[]);
        assert!(v.is_empty() && leaf_of.is_empty());
        assert_eq!(v.leaf_of(&Descriptor::default()), None);
        v.check(0).expect("empty is consistent");
        assert!(v.check(3).is_err());
    }
}
