//! The relocalization database: keyframe poses with their descriptors, and
//! its versioned binary file.
//!
//! File layout (little-endian): magic `STARRLDB`, format version (u32), then
//! the body, then an FNV-1a 64 checksum of the body (u64). Body: camera
//! (width, height u32; fx, fy, cx, cy, k1, k2, p1, p2, k3 f64), the map
//! fingerprint (u64, [`map_fingerprint`]), the entry count (u64), and per
//! entry the pose `world_from_camera` (tx, ty, tz, qx, qy, qz, qw f64), the
//! descriptor (4 x u64) and its number of coarse points (u32); then the
//! coarse points of every entry in entry order ([`CoarsePoint::to_bytes`],
//! 10 bytes each); then the landmarks ([`Landmark::to_bytes`], 44 bytes
//! each). The header before the entries also holds the total number of
//! coarse points and of landmarks (u64 each), so the length is known up
//! front. Reading checks every part and names the file and
//! the problem; [`RelocDatabase::check_compatible`] rejects a database made
//! for another map or other intrinsics.

use std::path::{Path, PathBuf};

use nalgebra::{Quaternion, Translation3, UnitQuaternion};

use crate::geometry::{Distortion, PinholeCamera, Pose};
use crate::map::Mesh;

use super::coarse::{CoarsePoint, COARSE_POINT_LEN, MAX_COARSE_POINTS};
use super::descriptor::Descriptor;
use super::landmarks::{Landmark, LANDMARK_LEN};

/// File magic.
pub const MAGIC: &[u8; 8] = b"STARRLDB";
/// Current format version. 2: the descriptor subtracts the thumbnail's
/// local mean (version-1 descriptors would not match the queries).
/// 3: coarse keyframe points per entry. 4: the descriptor's blur widened
/// (sigma 2.4 -> 3.5 thumbnail pixels). 5: landmarks.
pub const VERSION: u32 = 5;
const HEADER_LEN: usize = 8 + 4;
const CAMERA_LEN: usize = 8 + 9 * 8;
const BODY_FIXED_LEN: usize = CAMERA_LEN + 8 + 8 + 8 + 8;
const ENTRY_LEN: usize = 7 * 8 + 4 * 8 + 4;
/// Most entries a file may declare (guards the allocation).
pub const MAX_ENTRIES: u64 = 10_000_000;
/// Most landmarks a file may declare (guards the allocation).
pub const MAX_LANDMARKS: u64 = 50_000_000;

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
    pub coarse_points: Vec<CoarsePoint>,
    /// Map points with feature descriptors (empty when built without).
    pub landmarks: Vec<Landmark>,
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
    pub fn coarse_points_of(&self, index: usize) -> &[CoarsePoint] {
        self.entries
            .get(index)
            .and_then(|e| {
                let start = e.coarse_start as usize;
                self.coarse_points.get(start..start + e.coarse_len as usize)
            })
            .unwrap_or(&[])
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

    /// The file's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut body = Vec::with_capacity(
            BODY_FIXED_LEN
                + self.entries.len() * ENTRY_LEN
                + self.coarse_points.len() * COARSE_POINT_LEN
                + self.landmarks.len() * LANDMARK_LEN,
        );
        let c = &self.camera;
        body.extend_from_slice(&c.width.to_le_bytes());
        body.extend_from_slice(&c.height.to_le_bytes());
        let d = &c.distortion;
        for v in [c.fx, c.fy, c.cx, c.cy, d.k1, d.k2, d.p1, d.p2, d.k3] {
            body.extend_from_slice(&v.to_le_bytes());
        }
        body.extend_from_slice(&self.map_fingerprint.to_le_bytes());
        body.extend_from_slice(&(self.entries.len() as u64).to_le_bytes());
        let n_coarse: usize = (0..self.entries.len())
            .map(|i| self.coarse_points_of(i).len())
            .sum();
        body.extend_from_slice(&(n_coarse as u64).to_le_bytes());
        body.extend_from_slice(&(self.landmarks.len() as u64).to_le_bytes());
        for (i, e) in self.entries.iter().enumerate() {
            let t = e.world_from_camera.translation.vector;
            let q = e.world_from_camera.rotation.coords; // [x, y, z, w]
            for v in [t.x, t.y, t.z, q[0], q[1], q[2], q[3]] {
                body.extend_from_slice(&v.to_le_bytes());
            }
            for w in e.descriptor.0 {
                body.extend_from_slice(&w.to_le_bytes());
            }
            body.extend_from_slice(&(self.coarse_points_of(i).len() as u32).to_le_bytes());
        }
        for i in 0..self.entries.len() {
            for p in self.coarse_points_of(i) {
                body.extend_from_slice(&p.to_bytes());
            }
        }
        for l in &self.landmarks {
            body.extend_from_slice(&l.to_bytes());
        }
        let mut out = Vec::with_capacity(HEADER_LEN + body.len() + 8);
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&VERSION.to_le_bytes());
        out.extend_from_slice(&body);
        out.extend_from_slice(&fnv1a64(FNV_OFFSET, &body).to_le_bytes());
        out
    }

    /// Writes the database to `path` (through a temporary file and a rename,
    /// so a crash never leaves a half-written database).
    pub fn write(&self, path: &Path) -> Result<(), RelocDbError> {
        let io = |source| RelocDbError::Io {
            path: path.to_owned(),
            source,
        };
        let tmp = path.with_extension("tmp");
        std::fs::write(&tmp, self.to_bytes()).map_err(io)?;
        std::fs::rename(&tmp, path).map_err(io)
    }

    /// Reads and checks the database at `path`.
    pub fn read(path: &Path) -> Result<Self, RelocDbError> {
        let bytes = std::fs::read(path).map_err(|source| RelocDbError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_bytes(&bytes, path)
    }

    /// Parses and checks file bytes; `path` names the file in errors.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, RelocDbError> {
        let p = || path.to_owned();
        let min_len = (HEADER_LEN + BODY_FIXED_LEN + 8) as u64;
        if bytes.len() < 8 || &bytes[..8] != MAGIC {
            return Err(RelocDbError::BadMagic { path: p() });
        }
        if bytes.len() < HEADER_LEN {
            return Err(RelocDbError::Length {
                path: p(),
                expected: min_len,
                found: bytes.len() as u64,
            });
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
            return Err(RelocDbError::Length {
                path: p(),
                expected: min_len,
                found: bytes.len() as u64,
            });
        }
        let count_at = HEADER_LEN + CAMERA_LEN + 8;
        let count = Reader {
            bytes,
            at: count_at,
        }
        .u64();
        if count > MAX_ENTRIES {
            return Err(RelocDbError::Invalid {
                path: p(),
                what: format!("entry count {count} exceeds the limit {MAX_ENTRIES}"),
            });
        }
        let n_coarse = Reader {
            bytes,
            at: count_at + 8,
        }
        .u64();
        if n_coarse > count * MAX_COARSE_POINTS as u64 {
            return Err(RelocDbError::Invalid {
                path: p(),
                what: format!(
                    "{n_coarse} coarse points for {count} entries (at most {MAX_COARSE_POINTS} each)"
                ),
            });
        }
        let n_landmarks = Reader {
            bytes,
            at: count_at + 16,
        }
        .u64();
        if n_landmarks > MAX_LANDMARKS {
            return Err(RelocDbError::Invalid {
                path: p(),
                what: format!("landmark count {n_landmarks} exceeds the limit {MAX_LANDMARKS}"),
            });
        }
        let expected = min_len
            + count * ENTRY_LEN as u64
            + n_coarse * COARSE_POINT_LEN as u64
            + n_landmarks * LANDMARK_LEN as u64;
        if bytes.len() as u64 != expected {
            return Err(RelocDbError::Length {
                path: p(),
                expected,
                found: bytes.len() as u64,
            });
        }
        let body_end = bytes.len() - 8;
        let computed = fnv1a64(FNV_OFFSET, &bytes[HEADER_LEN..body_end]);
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
            return Err(RelocDbError::Invalid {
                path: p(),
                what: format!("camera: {e}"),
            });
        }
        let map_fingerprint = r.u64();
        let _count = r.u64();
        let _n_coarse = r.u64();
        let _n_landmarks = r.u64();
        let mut entries = Vec::with_capacity(count as usize);
        let mut coarse_start = 0u64;
        for index in 0..count {
            let f: [f64; 7] = std::array::from_fn(|_| r.f64());
            let descriptor = Descriptor(std::array::from_fn(|_| r.u64()));
            let coarse_len = r.u32();
            if coarse_len as usize > MAX_COARSE_POINTS
                || coarse_start + coarse_len as u64 > n_coarse
            {
                return Err(RelocDbError::Invalid {
                    path: p(),
                    what: format!(
                        "entry {index}: {coarse_len} coarse points (at most {MAX_COARSE_POINTS}, {} left of {n_coarse})",
                        n_coarse - coarse_start
                    ),
                });
            }
            let q = Quaternion::new(f[6], f[3], f[4], f[5]);
            let norm = q.norm();
            if !f.iter().all(|v| v.is_finite()) || (norm - 1.0).abs() > 1e-3 {
                return Err(RelocDbError::Invalid {
                    path: p(),
                    what: format!("entry {index}: pose is not finite or not a unit rotation"),
                });
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
            return Err(RelocDbError::Invalid {
                path: p(),
                what: format!(
                    "the entries hold {coarse_start} coarse points, the header says {n_coarse}"
                ),
            });
        }
        let mut coarse_points = Vec::with_capacity(n_coarse as usize);
        for index in 0..n_coarse {
            let Some(point) = CoarsePoint::from_bytes(r.take()) else {
                return Err(RelocDbError::Invalid {
                    path: p(),
                    what: format!("coarse point {index}: zero depth or a reserved byte set"),
                });
            };
            coarse_points.push(point);
        }
        let mut landmarks = Vec::with_capacity(n_landmarks as usize);
        for index in 0..n_landmarks {
            let Some(landmark) = Landmark::from_bytes(r.take()) else {
                return Err(RelocDbError::Invalid {
                    path: p(),
                    what: format!("landmark {index}: position is not finite"),
                });
            };
            landmarks.push(landmark);
        }
        Ok(Self {
            camera,
            map_fingerprint,
            entries,
            coarse_points,
            landmarks,
            path: path.to_owned(),
        })
    }
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
