//! The relocalization database: keyframe poses with their descriptors and
//! coarse points, the landmarks and their vocabulary, and the checks that a
//! database fits the map and camera in use.
//!
//! The file format, its checks and the memory map it is read through are
//! [`super::file`]. The coarse points, the bulk of a database, stay in the
//! mapped file ([`CoarsePoints`]); the keyframe poses and the landmarks are
//! decoded once at load (they are copied into the search structures anyway).

use std::path::PathBuf;

use std::sync::Arc;

use crate::geometry::{PinholeCamera, Pose};
use crate::map::Mesh;

use super::coarse::{CoarsePoint, COARSE_POINT_LEN};
use super::descriptor::Descriptor;
use super::file::VERSION;
use super::landmarks::Landmark;
use super::vocabulary::Vocabulary;

/// Errors reading, writing or using a relocalization database.
#[derive(Debug, thiserror::Error)]
pub enum RelocDbError {
    /// The file could not be read or written.
    #[error("relocalization database {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file does not start with the magic.
    #[error("{path} is not a relocalization database (bad magic; expected `STARRLDB`)")]
    BadMagic {
        /// The file.
        path: PathBuf,
    },
    /// The format version is not supported.
    #[error("relocalization database {path} has format version {found}; this build reads version {VERSION} (rebuild it with `star reloc build`)")]
    Version {
        /// The file.
        path: PathBuf,
        /// The version in the file.
        found: u32,
    },
    /// The file is shorter or longer than its header says.
    #[error("relocalization database {path} is truncated or has trailing bytes: expected {expected} bytes, found {found}")]
    Length {
        /// The file.
        path: PathBuf,
        /// Length implied by the header.
        expected: u64,
        /// Actual length.
        found: u64,
    },
    /// The checksum does not match the body.
    #[error("relocalization database {path} is corrupt: checksum {stored:#018x} stored, {computed:#018x} computed")]
    Checksum {
        /// The file.
        path: PathBuf,
        /// Checksum in the file.
        stored: u64,
        /// Checksum of the body read.
        computed: u64,
    },
    /// A field holds an impossible value.
    #[error("relocalization database {path}: {what}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// The database was built for another map.
    #[error("relocalization database {path} was built for another map (fingerprint {db:#018x}, this map {map:#018x}); rebuild it with `star reloc build`")]
    MapMismatch {
        /// The file.
        path: PathBuf,
        /// Fingerprint stored in the database.
        db: u64,
        /// Fingerprint of the map in use.
        map: u64,
    },
    /// The database was built for other intrinsics.
    #[error("relocalization database {path} was built for camera {db}, but the camera is {camera}; rebuild it with `star reloc build`")]
    CameraMismatch {
        /// The file.
        path: PathBuf,
        /// The database's camera.
        db: String,
        /// The camera in use.
        camera: String,
    },
}

/// One database keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelocEntry {
    /// Where the virtual camera was.
    pub world_from_camera: Pose,
    /// Descriptor of its rendered view.
    pub descriptor: Descriptor,
    /// First of its coarse points in [`RelocDatabase::coarse_points`].
    pub coarse_start: u32,
    /// Number of its coarse points (at most [`MAX_COARSE_POINTS`]).
    pub coarse_len: u32,
}

/// The relocalization database.
#[derive(Debug, Clone, PartialEq)]
pub struct RelocDatabase {
    /// The intrinsics the database was built for.
    pub camera: PinholeCamera,
    /// [`map_fingerprint`] of the map it was rendered from.
    pub map_fingerprint: u64,
    /// Keyframes.
    pub entries: Vec<RelocEntry>,
    /// The coarse keyframe points of all entries, in entry order.
    pub coarse_points: CoarsePoints,
    /// Map points with feature descriptors (empty when built without),
    /// stored leaf after leaf of `vocabulary`.
    pub landmarks: Vec<Landmark>,
    /// The vocabulary of the landmark descriptors.
    pub vocabulary: Vocabulary,
    /// Where it was read from (for error messages); empty when built in memory.
    pub path: PathBuf,
}

/// FNV-1a 64 of `bytes`, continuing from `hash` (start with [`FNV_OFFSET`]).
pub fn fnv1a64(mut hash: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        hash ^= b as u64;
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
    hash
}

/// FNV-1a 64 offset basis.
pub const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

/// Fingerprint of a map: FNV-1a 64 over vertex positions, vertex grays and
/// triangle indices.
pub fn map_fingerprint(mesh: &Mesh) -> u64 {
    let mut h = FNV_OFFSET;
    h = fnv1a64(h, &(mesh.positions.len() as u64).to_le_bytes());
    for p in &mesh.positions {
        for v in p {
            h = fnv1a64(h, &v.to_bits().to_le_bytes());
        }
    }
    for g in &mesh.gray {
        h = fnv1a64(h, &g.to_bits().to_le_bytes());
    }
    h = fnv1a64(h, &(mesh.indices.len() as u64).to_le_bytes());
    for i in &mesh.indices {
        h = fnv1a64(h, &i.to_le_bytes());
    }
    h
}

fn camera_string(c: &PinholeCamera) -> String {
    let d = &c.distortion;
    format!(
        "{}x{} fx {} fy {} cx {} cy {} k1 {} k2 {} p1 {} p2 {} k3 {}",
        c.width, c.height, c.fx, c.fy, c.cx, c.cy, d.k1, d.k2, d.p1, d.p2, d.k3
    )
}

fn cameras_match(a: &PinholeCamera, b: &PinholeCamera) -> bool {
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-6 * (1.0 + x.abs().max(y.abs()));
    let (da, db) = (&a.distortion, &b.distortion);
    a.width == b.width
        && a.height == b.height
        && [
            (a.fx, b.fx),
            (a.fy, b.fy),
            (a.cx, b.cx),
            (a.cy, b.cy),
            (da.k1, db.k1),
            (da.k2, db.k2),
            (da.p1, db.p1),
            (da.p2, db.p2),
            (da.k3, db.k3),
        ]
        .iter()
        .all(|&(x, y)| close(x, y))
}

impl RelocDatabase {
    /// The coarse keyframe points of entry `index` (empty when out of range).
    pub fn coarse_points_of(&self, index: usize) -> CoarseSlice<'_> {
        self.entries
            .get(index)
            .and_then(|e| {
                let start = e.coarse_start as usize;
                self.coarse_points.get(start..start + e.coarse_len as usize)
            })
            .unwrap_or_default()
    }

    /// Errors unless the database was built for `camera` and the map with
    /// fingerprint `map_fingerprint`.
    pub fn check_compatible(
        &self,
        camera: &PinholeCamera,
        map_fingerprint: u64,
    ) -> Result<(), RelocDbError> {
        if self.map_fingerprint != map_fingerprint {
            return Err(RelocDbError::MapMismatch {
                path: self.path.clone(),
                db: self.map_fingerprint,
                map: map_fingerprint,
            });
        }
        if !cameras_match(&self.camera, camera) {
            return Err(RelocDbError::CameraMismatch {
                path: self.path.clone(),
                db: camera_string(&self.camera),
                camera: camera_string(camera),
            });
        }
        Ok(())
    }
}

/// The coarse points of a database, in their file encoding
/// ([`CoarsePoint::to_bytes`]): in memory while building, in the mapped
/// file once read. Decoded point by point where they are used.
#[derive(Clone, Default)]
pub struct CoarsePoints {
    storage: Storage,
}

#[derive(Clone)]
enum Storage {
    Owned(Vec<u8>),
    Mapped {
        map: Arc<memmap2::Mmap>,
        start: usize,
        len: usize,
    },
}

impl Default for Storage {
    fn default() -> Self {
        Self::Owned(Vec::new())
    }
}

impl std::fmt::Debug for CoarsePoints {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mapped = matches!(self.storage, Storage::Mapped { .. });
        f.debug_struct("CoarsePoints")
            .field("len", &self.len())
            .field("mapped", &mapped)
            .finish()
    }
}

impl PartialEq for CoarsePoints {
    fn eq(&self, other: &Self) -> bool {
        self.as_bytes() == other.as_bytes()
    }
}

impl FromIterator<CoarsePoint> for CoarsePoints {
    fn from_iter<I: IntoIterator<Item = CoarsePoint>>(iter: I) -> Self {
        let mut bytes = Vec::new();
        for p in iter {
            bytes.extend_from_slice(&p.to_bytes());
        }
        Self {
            storage: Storage::Owned(bytes),
        }
    }
}

impl CoarsePoints {
    /// Points in the file bytes `start..start + len` of `map` (whole
    /// points, checked by the reader).
    pub(super) fn mapped(map: Arc<memmap2::Mmap>, start: usize, len: usize) -> Self {
        Self {
            storage: Storage::Mapped { map, start, len },
        }
    }

    /// Their file bytes.
    pub fn as_bytes(&self) -> &[u8] {
        match &self.storage {
            Storage::Owned(b) => b,
            Storage::Mapped { map, start, len } => map.get(*start..*start + *len).unwrap_or(&[]),
        }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.as_bytes().len() / COARSE_POINT_LEN
    }

    /// True when there is none.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Points `range`; `None` when out of bounds.
    pub fn get(&self, range: std::ops::Range<usize>) -> Option<CoarseSlice<'_>> {
        let bytes = self
            .as_bytes()
            .get(range.start * COARSE_POINT_LEN..range.end * COARSE_POINT_LEN)?;
        Some(CoarseSlice(bytes))
    }

    /// Point `index`; `None` when out of bounds or invalid.
    pub fn point(&self, index: usize) -> Option<CoarsePoint> {
        self.get(index..index + 1)?.iter().next()
    }
}

/// Some coarse points in their file encoding.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CoarseSlice<'a>(&'a [u8]);

impl<'a> CoarseSlice<'a> {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.0.len() / COARSE_POINT_LEN
    }

    /// True when there is none.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The points, decoded (an invalid one, which the reader refuses, is
    /// skipped).
    pub fn iter(&self) -> impl Iterator<Item = CoarsePoint> + 'a {
        self.0.chunks_exact(COARSE_POINT_LEN).filter_map(|c| {
            let mut b = [0u8; COARSE_POINT_LEN];
            b.copy_from_slice(c);
            CoarsePoint::from_bytes(b)
        })
    }
}
