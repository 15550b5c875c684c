//! The checkpoint of a database build: the finished work units, appended
//! to a file next to the output as they are done, so that a build
//! interrupted (Ctrl-C, a kill, a crash) resumes where it stopped and gives
//! the same database as an uninterrupted one.
//!
//! Takes the build's key (a hash of everything the result depends on) and
//! the results of each batch of work units; gives back, on reopening, the
//! results already done. Layout (little-endian): magic `STARRLCP`, version
//! (u32), key (u64), number of work units (u64); then records, each the
//! first unit (u64), the number of units (u64), the payload length (u64),
//! the payload (per unit: its entries, each pose as 7 f64, descriptor 4 x
//! u64 and coarse-point count u32, after their count u32; its coarse
//! points, after their count u32; its lifted landmarks, after their count
//! u32) and the payload's checksum (u64). A record cut short by the
//! interruption, or that does not check, ends what is read: the file is
//! truncated there and the build goes on from it.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use nalgebra::{Quaternion, Translation3, UnitQuaternion};

use crate::geometry::Pose;

use super::coarse::{CoarsePoint, COARSE_POINT_LEN};
use super::descriptor::Descriptor;
use super::file::checksum;
use super::grid::BuildError;
use super::landmarks::{Landmark, LANDMARK_LEN};

const MAGIC: &[u8; 8] = b"STARRLCP";
const VERSION: u32 = 1;
const HEADER_LEN: usize = 8 + 4 + 8 + 8;
const ENTRY_LEN: usize = 7 * 8 + 4 * 8 + 4;

/// What one work unit of the build gave.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct UnitOutput {
    /// Database entries: pose, descriptor, number of coarse points.
    pub entries: Vec<(Pose, Descriptor, u32)>,
    /// Their coarse points, entry after entry.
    pub points: Vec<CoarsePoint>,
    /// Features lifted to world points, not yet deduplicated.
    pub features: Vec<Landmark>,
}

/// The path of the checkpoint of a build writing `output`.
pub fn checkpoint_path(output: &Path) -> PathBuf {
    let mut name = output.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    output.with_file_name(name)
}

/// An open checkpoint, appended to.
pub struct Checkpoint {
    path: PathBuf,
    file: File,
}

impl Checkpoint {
    /// Opens the checkpoint at `path` for a build of `total` units with
    /// `key`: gives it and the units already done, in order. A missing
    /// file, or one for another build (key or unit count), starts empty.
    pub fn open(
        path: &Path,
        key: u64,
        total: usize,
    ) -> Result<(Self, Vec<UnitOutput>), BuildError> {
        let err = |source| BuildError::Checkpoint {
            path: path.to_owned(),
            source,
        };
        let mut header = Vec::with_capacity(HEADER_LEN);
        header.extend_from_slice(MAGIC);
        header.extend_from_slice(&VERSION.to_le_bytes());
        header.extend_from_slice(&key.to_le_bytes());
        header.extend_from_slice(&(total as u64).to_le_bytes());
        let (done, good_len) = match std::fs::read(path) {
            Ok(bytes) if bytes.len() >= HEADER_LEN && bytes[..HEADER_LEN] == header[..] => {
                let (done, len) = read_records(&bytes);
                tracing::info!(
                    path = %path.display(),
                    units = done.len(),
                    total,
                    "resuming the database build from its checkpoint"
                );
                (done, len)
            }
            Ok(_) => {
                tracing::warn!(
                    path = %path.display(),
                    "the checkpoint is for another build (map, camera, settings or version); starting over"
                );
                (Vec::new(), 0)
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => (Vec::new(), 0),
            Err(e) => return Err(err(e)),
        };
        let mut file = OpenOptions::new()
            .create(true)
            .write(true)
            .truncate(false)
            .open(path)
            .map_err(err)?;
        if good_len == 0 {
            file.set_len(0).map_err(err)?;
            file.write_all(&header).map_err(err)?;
        } else {
            file.set_len(good_len as u64).map_err(err)?;
        }
        use std::io::Seek;
        file.seek(std::io::SeekFrom::End(0)).map_err(err)?;
        file.sync_data().map_err(err)?;
        Ok((
            Self {
                path: path.to_owned(),
                file,
            },
            done,
        ))
    }

    /// Appends the outputs of units `first..first + outputs.len()` and
    /// syncs them to disk.
    pub fn append(&mut self, first: usize, outputs: &[UnitOutput]) -> Result<(), BuildError> {
        let mut payload = Vec::new();
        for o in outputs {
            encode(o, &mut payload);
        }
        let mut record = Vec::with_capacity(payload.len() + 32);
        for v in [first as u64, outputs.len() as u64, payload.len() as u64] {
            record.extend_from_slice(&v.to_le_bytes());
        }
        record.extend_from_slice(&payload);
        record.extend_from_slice(&checksum(&payload).to_le_bytes());
        let err = |source| BuildError::Checkpoint {
            path: self.path.clone(),
            source,
        };
        self.file.write_all(&record).map_err(err)?;
        self.file.sync_data().map_err(err)
    }

    /// Removes the checkpoint (the database is written).
    pub fn remove(self) -> Result<(), BuildError> {
        drop(self.file);
        std::fs::remove_file(&self.path).map_err(|source| BuildError::Checkpoint {
            path: self.path,
            source,
        })
    }
}

/// The units of the records after the header, up to the first that is
/// cut short, does not check or does not follow; and the length read.
fn read_records(bytes: &[u8]) -> (Vec<UnitOutput>, usize) {
    let mut done = Vec::new();
    let mut at = HEADER_LEN;
    loop {
        let mut r = Reader { bytes, at };
        let (Some(first), Some(n), Some(len)) = (r.u64(), r.u64(), r.u64()) else {
            break;
        };
        let Some(payload) = r.take(len as usize) else {
            break;
        };
        let Some(sum) = r.u64() else {
            break;
        };
        if first != done.len() as u64 || sum != checksum(payload) {
            break;
        }
        let mut p = Reader {
            bytes: payload,
            at: 0,
        };
        let Some(units) = (0..n).map(|_| decode(&mut p)).collect::<Option<Vec<_>>>() else {
            break;
        };
        done.extend(units);
        at = r.at;
    }
    (done, at)
}

fn encode(o: &UnitOutput, out: &mut Vec<u8>) {
    out.extend_from_slice(&(o.entries.len() as u32).to_le_bytes());
    for (pose, descriptor, n) in &o.entries {
        let t = pose.translation.vector;
        let q = pose.rotation.coords;
        for v in [t.x, t.y, t.z, q[0], q[1], q[2], q[3]] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for w in descriptor.0 {
            out.extend_from_slice(&w.to_le_bytes());
        }
        out.extend_from_slice(&n.to_le_bytes());
    }
    out.extend_from_slice(&(o.points.len() as u32).to_le_bytes());
    for p in &o.points {
        out.extend_from_slice(&p.to_bytes());
    }
    out.extend_from_slice(&(o.features.len() as u32).to_le_bytes());
    for f in &o.features {
        out.extend_from_slice(&f.to_bytes());
    }
}

fn decode(r: &mut Reader) -> Option<UnitOutput> {
    let mut o = UnitOutput::default();
    let n = r.u32()?;
    for _ in 0..n {
        let e = r.take(ENTRY_LEN)?;
        let f = |i: usize| {
            let mut b = [0u8; 8];
            b.copy_from_slice(&e[8 * i..8 * i + 8]);
            b
        };
        let t = |i: usize| f64::from_le_bytes(f(i));
        let descriptor = Descriptor(std::array::from_fn(|i| u64::from_le_bytes(f(7 + i))));
        let mut c = [0u8; 4];
        c.copy_from_slice(&e[88..92]);
        // The stored quaternion is a unit one, written by `encode`: no
        // renormalization (it would change the bits).
        let pose = Pose::from_parts(
            Translation3::new(t(0), t(1), t(2)),
            UnitQuaternion::new_unchecked(Quaternion::new(t(6), t(3), t(4), t(5))),
        );
        o.entries.push((pose, descriptor, u32::from_le_bytes(c)));
    }
    let n = r.u32()?;
    for _ in 0..n {
        let mut b = [0u8; COARSE_POINT_LEN];
        b.copy_from_slice(r.take(COARSE_POINT_LEN)?);
        o.points.push(CoarsePoint::from_bytes(b)?);
    }
    let n = r.u32()?;
    for _ in 0..n {
        let mut b = [0u8; LANDMARK_LEN];
        b.copy_from_slice(r.take(LANDMARK_LEN)?);
        o.features.push(Landmark::from_bytes(b)?);
    }
    Some(o)
}

/// Checked little-endian reads.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let s = self.bytes.get(self.at..self.at.checked_add(n)?)?;
        self.at += n;
        Some(s)
    }
    fn u32(&mut self) -> Option<u32> {
        let mut b = [0u8; 4];
        b.copy_from_slice(self.take(4)?);
        Some(u32::from_le_bytes(b))
    }
    fn u64(&mut self) -> Option<u64> {
        let mut b = [0u8; 8];
        b.copy_from_slice(self.take(8)?);
        Some(u64::from_le_bytes(b))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(i: usize) -> UnitOutput {
        UnitOutput {
            entries: vec![(
                Pose::from_parts(
                    Translation3::new(i as f64, 0.5, 1.4),
                    UnitQuaternion::from_euler_angles(0.1, 0.2, i as f64),
                ),
                Descriptor([i as u64, 1, 2, 3]),
                1,
            )],
            points: vec![CoarsePoint {
                x: 3,
                y: 4,
                gray: 5,
                depth_mm: 900,
                grad_x: -7,
                grad_y: 8,
            }],
            features: vec![Landmark {
                world_m: [i as f32, 1.0, 2.0],
                descriptor: Descriptor([9, 8, 7, i as u64]),
            }],
        }
    }

    #[test]
    fn units_survive_a_reopen_and_a_cut_record_is_dropped() {
        let tmp = tempfile::tempdir().expect("tmp");
        let path = checkpoint_path(&tmp.path().join("map.reloc"));
        assert!(path.ends_with("map.reloc.partial"));
        let (mut c, done) = Checkpoint::open(&path, 7, 10).expect("open");
        assert!(done.is_empty());
        let units: Vec<UnitOutput> = (0..5).map(unit).collect();
        c.append(0, &units[..2]).expect("append");
        c.append(2, &units[2..]).expect("append");
        drop(c);
        let (c, done) = Checkpoint::open(&path, 7, 10).expect("reopen");
        assert_eq!(done, units);
        drop(c);
        // A record cut short (the kill came mid-write) ends what is read.
        let len = std::fs::metadata(&path).expect("meta").len();
        let f = OpenOptions::new().write(true).open(&path).expect("f");
        f.set_len(len - 5).expect("cut");
        drop(f);
        let (mut c, done) = Checkpoint::open(&path, 7, 10).expect("reopen cut");
        assert_eq!(done, units[..2].to_vec());
        c.append(2, &units[2..3]).expect("append after cut");
        drop(c);
        let (c, done) = Checkpoint::open(&path, 7, 10).expect("reopen");
        assert_eq!(done, units[..3].to_vec());
        drop(c);
        // Another build's key starts over.
        let (c, done) = Checkpoint::open(&path, 8, 10).expect("other key");
        assert!(done.is_empty());
        c.remove().expect("remove");
        assert!(!path.exists());
    }
}
