//! The relocalization database file: its versioned, checksummed binary
//! format, written through a temporary file and a rename, and read through
//! a memory map (`memmap2`) rather than into memory.
//!
//! Layout (little-endian): magic `STARRLDB`, format version (u32), then
//! the body, then a checksum of the body (u64, [`checksum`]). Body: camera
//! (width, height u32; fx, fy, cx, cy, k1, k2, p1, p2, k3 f64), the map
//! fingerprint (u64, [`map_fingerprint`](super::map_fingerprint)), then the
//! counts (u64 each) of entries, coarse points, landmarks, vocabulary words
//! and leaves, so the length is known up front; then per entry the pose
//! `world_from_camera` (tx, ty, tz, qx, qy, qz, qw f64), the descriptor
//! (4 x u64) and its number of coarse points (u32); the coarse points of
//! every entry in entry order ([`CoarsePoint::to_bytes`], 10 bytes each);
//! the landmarks leaf after leaf ([`Landmark::to_bytes`], 44 bytes each);
//! per word its descriptor and leaf count (u32); per leaf its descriptor
//! and landmark count (u32).
//!
//! Reading checks every part and names the file and the problem. The
//! checksum and the checks read every page once; the coarse points then
//! stay in the page cache, shared and evictable, and are decoded where a
//! candidate is ranked. A database is never modified in place (a rebuild
//! writes a new file and renames it over the old one), so the mapping
//! stays valid while it is in use.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Quaternion, Translation3, UnitQuaternion};

use crate::geometry::{Distortion, PinholeCamera, Pose};

use super::coarse::{CoarsePoint, COARSE_POINT_LEN, MAX_COARSE_POINTS};
use super::database::{CoarsePoints, RelocDatabase, RelocDbError, RelocEntry};
use super::descriptor::Descriptor;
use super::landmarks::{Landmark, LANDMARK_LEN};
use super::vocabulary::Vocabulary;

/// File magic.
pub const MAGIC: &[u8; 8] = b"STARRLDB";
/// Current format version. 2: the descriptor subtracts the thumbnail's
/// local mean (version-1 descriptors would not match the queries).
/// 3: coarse keyframe points per entry. 4: the descriptor's blur widened
/// (sigma 2.4 -> 3.5 thumbnail pixels). 5: landmarks. 6: the landmark
/// vocabulary, landmarks stored leaf after leaf, the checksum over 64-bit
/// words, read through a memory map.
pub const VERSION: u32 = 6;
/// Bytes before the body: magic and version.
pub const HEADER_LEN: usize = 8 + 4;
const CAMERA_LEN: usize = 8 + 9 * 8;
const COUNTS: usize = 5;
const BODY_FIXED_LEN: usize = CAMERA_LEN + 8 + COUNTS * 8;
const ENTRY_LEN: usize = 7 * 8 + 4 * 8 + 4;
const NODE_LEN: usize = 4 * 8 + 4;
/// Most entries a file may declare (guards the allocation).
pub const MAX_ENTRIES: u64 = 10_000_000;
/// Most landmarks a file may declare (guards the allocation).
pub const MAX_LANDMARKS: u64 = 50_000_000;
/// Most vocabulary leaves a file may declare.
const MAX_NODES: u64 = 1 << 20;

/// Checksum of the body: FNV-1a 64 over its 64-bit little-endian words,
/// then over the trailing bytes one at a time.
pub fn checksum(bytes: &[u8]) -> u64 {
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let mut hash = super::database::FNV_OFFSET;
    let mut words = bytes.chunks_exact(8);
    for w in &mut words {
        let mut b = [0u8; 8];
        b.copy_from_slice(w);
        hash ^= u64::from_le_bytes(b);
        hash = hash.wrapping_mul(PRIME);
    }
    for &b in words.remainder() {
        hash ^= b as u64;
        hash = hash.wrapping_mul(PRIME);
    }
    hash
}

impl RelocDatabase {
    /// The file's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let coarse = self.coarse_points.as_bytes();
        let v = &self.vocabulary;
        let mut out = Vec::with_capacity(
            HEADER_LEN
                + BODY_FIXED_LEN
                + self.entries.len() * ENTRY_LEN
                + coarse.len()
                + self.landmarks.len() * LANDMARK_LEN
                + (v.words.len() + v.leaves.len()) * NODE_LEN
                + 8,
        );
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&VERSION.to_le_bytes());
        let c = &self.camera;
        out.extend_from_slice(&c.width.to_le_bytes());
        out.extend_from_slice(&c.height.to_le_bytes());
        let d = &c.distortion;
        for x in [c.fx, c.fy, c.cx, c.cy, d.k1, d.k2, d.p1, d.p2, d.k3] {
            out.extend_from_slice(&x.to_le_bytes());
        }
        out.extend_from_slice(&self.map_fingerprint.to_le_bytes());
        let n_coarse: usize = (0..self.entries.len())
            .map(|i| self.coarse_points_of(i).len())
            .sum();
        for n in [
            self.entries.len(),
            n_coarse,
            self.landmarks.len(),
            v.words.len(),
            v.leaves.len(),
        ] {
            out.extend_from_slice(&(n as u64).to_le_bytes());
        }
        for (i, e) in self.entries.iter().enumerate() {
            let t = e.world_from_camera.translation.vector;
            let q = e.world_from_camera.rotation.coords; // [x, y, z, w]
            for x in [t.x, t.y, t.z, q[0], q[1], q[2], q[3]] {
                out.extend_from_slice(&x.to_le_bytes());
            }
            for w in e.descriptor.0 {
                out.extend_from_slice(&w.to_le_bytes());
            }
            out.extend_from_slice(&(self.coarse_points_of(i).len() as u32).to_le_bytes());
        }
        for i in 0..self.entries.len() {
            for p in self.coarse_points_of(i).iter() {
                out.extend_from_slice(&p.to_bytes());
            }
        }
        for l in &self.landmarks {
            out.extend_from_slice(&l.to_bytes());
        }
        let nodes = v
            .words
            .iter()
            .zip(&v.word_leaves)
            .chain(v.leaves.iter().zip(&v.leaf_sizes));
        for (d, n) in nodes {
            for w in d.0 {
                out.extend_from_slice(&w.to_le_bytes());
            }
            out.extend_from_slice(&n.to_le_bytes());
        }
        let sum = checksum(&out[HEADER_LEN..]);
        out.extend_from_slice(&sum.to_le_bytes());
        out
    }

    /// Writes the database to `path` (through a temporary file and a rename,
    /// so a crash never leaves a half-written database, and a database in
    /// use, mapped, is never modified); gives the file's size in bytes.
    pub fn write(&self, path: &Path) -> Result<u64, RelocDbError> {
        let io = |source| RelocDbError::Io {
            path: path.to_owned(),
            source,
        };
        let tmp = path.with_extension("tmp");
        let bytes = self.to_bytes();
        std::fs::write(&tmp, &bytes).map_err(io)?;
        std::fs::rename(&tmp, path).map_err(io)?;
        Ok(bytes.len() as u64)
    }

    /// Maps and checks the database at `path`; logs its size.
    pub fn read(path: &Path) -> Result<Self, RelocDbError> {
        let t0 = Instant::now();
        let io = |source| RelocDbError::Io {
            path: path.to_owned(),
            source,
        };
        let file = std::fs::File::open(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        if len == 0 {
            return Self::from_bytes(&[], path);
        }
        // SAFETY: the map is read-only, and a database file is never
        // modified in place: `write` (and `star reloc build`) write a new
        // file and rename it over the old one, which leaves this mapping on
        // the old contents. Another program truncating the file while it
        // is mapped would fault the reads; the file is ours.
        let map = Arc::new(unsafe { memmap2::Mmap::map(&file) }.map_err(io)?);
        let (mut db, coarse) = parse(&map, path)?;
        db.coarse_points = CoarsePoints::mapped(map.clone(), coarse.start, coarse.len());
        tracing::info!(
            path = %path.display(),
            size_mb = len as f64 / 1e6,
            keyframes = db.entries.len(),
            coarse_points = db.coarse_points.len(),
            landmarks = db.landmarks.len(),
            vocabulary_leaves = db.vocabulary.leaves.len(),
            load_ms = t0.elapsed().as_secs_f64() * 1e3,
            "relocalization database mapped"
        );
        Ok(db)
    }

    /// Parses and checks file bytes; `path` names the file in errors. The
    /// coarse points are copied (use [`Self::read`] to map a file).
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, RelocDbError> {
        let (mut db, coarse) = parse(bytes, path)?;
        db.coarse_points = bytes
            .get(coarse)
            .unwrap_or(&[])
            .chunks_exact(COARSE_POINT_LEN)
            .filter_map(|c| {
                let mut b = [0u8; COARSE_POINT_LEN];
                b.copy_from_slice(c);
                CoarsePoint::from_bytes(b)
            })
            .collect();
        Ok(db)
    }
}

/// Parses and checks `bytes`: the database without its coarse points, and
/// where they lie in `bytes` (all checked).
fn parse(
    bytes: &[u8],
    path: &Path,
) -> Result<(RelocDatabase, std::ops::Range<usize>), RelocDbError> {
    let p = || path.to_owned();
    let invalid = |what: String| RelocDbError::Invalid { path: p(), what };
    let min_len = (HEADER_LEN + BODY_FIXED_LEN + 8) as u64;
    if bytes.len() < 8 || &bytes[..8] != MAGIC {
        return Err(RelocDbError::BadMagic { path: p() });
    }
    let length = |expected: u64| RelocDbError::Length {
        path: p(),
        expected,
        found: bytes.len() as u64,
    };
    if bytes.len() < HEADER_LEN {
        return Err(length(min_len));
    }
    let mut r = Reader { bytes, at: 8 };
    let version = r.u32();
    if version != VERSION {
        return Err(RelocDbError::Version {
            path: p(),
            found: version,
        });
    }
    if (bytes.len() as u64) < min_len {
        return Err(length(min_len));
    }
    let mut counts = Reader {
        bytes,
        at: HEADER_LEN + CAMERA_LEN + 8,
    };
    let [count, n_coarse, n_landmarks, n_words, n_leaves] = [(); COUNTS].map(|_| counts.u64());
    if count > MAX_ENTRIES {
        return Err(invalid(format!(
            "entry count {count} exceeds the limit {MAX_ENTRIES}"
        )));
    }
    if n_coarse > count * MAX_COARSE_POINTS as u64 {
        return Err(invalid(format!(
            "{n_coarse} coarse points for {count} entries (at most {MAX_COARSE_POINTS} each)"
        )));
    }
    if n_landmarks > MAX_LANDMARKS {
        return Err(invalid(format!(
            "landmark count {n_landmarks} exceeds the limit {MAX_LANDMARKS}"
        )));
    }
    if n_words > MAX_NODES || n_leaves > MAX_NODES {
        return Err(invalid(format!(
            "{n_words} vocabulary words and {n_leaves} leaves (at most {MAX_NODES} each)"
        )));
    }
    let expected = min_len
        + count * ENTRY_LEN as u64
        + n_coarse * COARSE_POINT_LEN as u64
        + n_landmarks * LANDMARK_LEN as u64
        + (n_words + n_leaves) * NODE_LEN as u64;
    if bytes.len() as u64 != expected {
        return Err(length(expected));
    }
    let body_end = bytes.len() - 8;
    let computed = checksum(&bytes[HEADER_LEN..body_end]);
    let stored = Reader {
        bytes,
        at: body_end,
    }
    .u64();
    if stored != computed {
        return Err(RelocDbError::Checksum {
            path: p(),
            stored,
            computed,
        });
    }
    let (width, height) = (r.u32(), r.u32());
    let v: [f64; 9] = std::array::from_fn(|_| r.f64());
    let camera = PinholeCamera {
        distortion: Distortion {
            k1: v[4],
            k2: v[5],
            p1: v[6],
            p2: v[7],
            k3: v[8],
        },
        ..PinholeCamera::new(width, height, v[0], v[1], v[2], v[3])
    };
    if let Err(e) = camera.validate() {
        return Err(invalid(format!("camera: {e}")));
    }
    let map_fingerprint = r.u64();
    r.at += COUNTS * 8;
    let mut entries = Vec::with_capacity(count as usize);
    let mut coarse_start = 0u64;
    for index in 0..count {
        let f: [f64; 7] = std::array::from_fn(|_| r.f64());
        let descriptor = Descriptor(std::array::from_fn(|_| r.u64()));
        let coarse_len = r.u32();
        if coarse_len as usize > MAX_COARSE_POINTS || coarse_start + coarse_len as u64 > n_coarse {
            return Err(invalid(format!(
                "entry {index}: {coarse_len} coarse points (at most {MAX_COARSE_POINTS}, {} left of {n_coarse})",
                n_coarse - coarse_start
            )));
        }
        let q = Quaternion::new(f[6], f[3], f[4], f[5]);
        let norm = q.norm();
        if !f.iter().all(|v| v.is_finite()) || (norm - 1.0).abs() > 1e-3 {
            return Err(invalid(format!(
                "entry {index}: pose is not finite or not a unit rotation"
            )));
        }
        entries.push(RelocEntry {
            world_from_camera: Pose::from_parts(
                Translation3::new(f[0], f[1], f[2]),
                UnitQuaternion::new_normalize(q),
            ),
            descriptor,
            coarse_start: coarse_start as u32,
            coarse_len,
        });
        coarse_start += coarse_len as u64;
    }
    if coarse_start != n_coarse {
        return Err(invalid(format!(
            "the entries hold {coarse_start} coarse points, the header says {n_coarse}"
        )));
    }
    let coarse = r.at..r.at + n_coarse as usize * COARSE_POINT_LEN;
    for index in 0..n_coarse {
        if CoarsePoint::from_bytes(r.take()).is_none() {
            return Err(invalid(format!(
                "coarse point {index}: zero depth or a reserved byte set"
            )));
        }
    }
    let mut landmarks = Vec::with_capacity(n_landmarks as usize);
    for index in 0..n_landmarks {
        let Some(landmark) = Landmark::from_bytes(r.take()) else {
            return Err(invalid(format!("landmark {index}: position is not finite")));
        };
        landmarks.push(landmark);
    }
    let mut vocabulary = Vocabulary::default();
    for _ in 0..n_words {
        vocabulary
            .words
            .push(Descriptor(std::array::from_fn(|_| r.u64())));
        vocabulary.word_leaves.push(r.u32());
    }
    for _ in 0..n_leaves {
        vocabulary
            .leaves
            .push(Descriptor(std::array::from_fn(|_| r.u64())));
        vocabulary.leaf_sizes.push(r.u32());
    }
    vocabulary
        .check(n_landmarks)
        .map_err(|e| invalid(format!("landmark vocabulary: {e}")))?;
    let db = RelocDatabase {
        camera,
        map_fingerprint,
        entries,
        coarse_points: CoarsePoints::default(),
        landmarks,
        vocabulary,
        path: path.to_owned(),
    };
    Ok((db, coarse))
}

/// Little-endian reads at known-good offsets (lengths are checked first).
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        if let Some(src) = self.bytes.get(self.at..self.at + N) {
            out.copy_from_slice(src);
        }
        self.at += N;
        out
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take())
    }
}
