//! Trajectories in the TUM format: one `timestamp tx ty tz qx qy qz qw` line
//! per pose, `world_from_camera` (camera to world), `#` comments allowed.
//!
//! Takes TUM text (ground truth, estimates) and gives a [`Trajectory`];
//! writes one back with full precision (Rust's shortest round-trip float
//! formatting, so a written file reads back to the same values).

use std::path::Path;

use nalgebra::{Quaternion, Translation3, UnitQuaternion};

use super::list::{check_monotonic, data_lines, parse_f64};
use super::DatasetError;
use crate::geometry::Pose;

/// Timestamped poses, `world_from_camera`, in increasing time order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    /// Timestamps in seconds, strictly increasing.
    pub stamps_s: Vec<f64>,
    /// `world_from_camera` at each timestamp.
    pub poses: Vec<Pose>,
}

impl Trajectory {
    /// Number of poses.
    pub fn len(&self) -> usize {
        self.stamps_s.len()
    }

    /// True when there are no poses.
    pub fn is_empty(&self) -> bool {
        self.stamps_s.is_empty()
    }

    /// Appends a pose; the caller keeps timestamps increasing.
    pub fn push(&mut self, stamp_s: f64, world_from_camera: Pose) {
        self.stamps_s.push(stamp_s);
        self.poses.push(world_from_camera);
    }

    /// Parses TUM trajectory text read from `file` (used in error messages).
    pub fn parse(file: &Path, text: &str) -> Result<Self, DatasetError> {
        const FIELDS: [&str; 8] = [
            "a finite timestamp in seconds",
            "a finite tx",
            "a finite ty",
            "a finite tz",
            "a finite qx",
            "a finite qy",
            "a finite qz",
            "a finite qw",
        ];
        let mut trajectory = Trajectory::default();
        for (line, content) in data_lines(text) {
            let tokens: Vec<&str> = content.split_whitespace().collect();
            if tokens.len() != 8 {
                return Err(DatasetError::Malformed {
                    path: file.to_path_buf(),
                    line,
                    expected: "8 fields `timestamp tx ty tz qx qy qz qw`",
                    found: content.to_string(),
                });
            }
            let mut v = [0.0f64; 8];
            for ((slot, token), what) in v.iter_mut().zip(&tokens).zip(FIELDS) {
                *slot = parse_f64(file, line, token, what)?;
            }
            check_monotonic(file, line, trajectory.stamps_s.last().copied(), v[0])?;
            let q = Quaternion::new(v[7], v[4], v[5], v[6]);
            if !(q.norm() > 1e-6) {
                return Err(DatasetError::Malformed {
                    path: file.to_path_buf(),
                    line,
                    expected: "a non-zero quaternion `qx qy qz qw`",
                    found: content.to_string(),
                });
            }
            let pose = Pose::from_parts(
                Translation3::new(v[1], v[2], v[3]),
                UnitQuaternion::new_normalize(q),
            );
            trajectory.push(v[0], pose);
        }
        Ok(trajectory)
    }

    /// Reads a TUM trajectory file.
    pub fn read(path: &Path) -> Result<Self, DatasetError> {
        let text = super::read_text(path)?;
        Self::parse(path, &text)
    }

    /// Formats as TUM text with a header comment and full precision.
    pub fn to_tum_string(&self) -> String {
        let mut text = String::from("# timestamp tx ty tz qx qy qz qw (world_from_camera)\n");
        for (stamp, pose) in self.stamps_s.iter().zip(&self.poses) {
            let t = pose.translation.vector;
            let q = pose.rotation.coords; // [x, y, z, w]
            text.push_str(&format!(
                "{} {} {} {} {} {} {} {}\n",
                stamp, t.x, t.y, t.z, q[0], q[1], q[2], q[3]
            ));
        }
        text
    }

    /// Writes a TUM trajectory file.
    pub fn write(&self, path: &Path) -> Result<(), DatasetError> {
        super::write_text(path, &self.to_tum_string())
    }
}

/// Writes a TUM trajectory as poses are produced, so a process killed
/// mid-flight loses at most the last second: lines go into a fixed buffer
/// and reach the file when it fills and at least once a second.
///
/// Formatting a pose into the buffer allocates nothing; the file is created
/// (and the path checked) when the writer is.
pub struct TrajectoryWriter {
    path: std::path::PathBuf,
    out: std::io::BufWriter<std::fs::File>,
    poses: u64,
    last_flush: std::time::Instant,
}

impl TrajectoryWriter {
    /// Longest time a written pose stays in the buffer.
    pub const FLUSH_INTERVAL: std::time::Duration = std::time::Duration::from_secs(1);

    /// Creates (truncates) `path` and writes the header line.
    pub fn create(path: &Path) -> Result<Self, DatasetError> {
        use std::io::Write;
        let io = |source| DatasetError::Io {
            path: path.to_owned(),
            source,
        };
        let file = std::fs::File::create(path).map_err(io)?;
        // 64 KiB: about 10 s of poses at 50 Hz, so the buffer never grows.
        let mut out = std::io::BufWriter::with_capacity(64 * 1024, file);
        out.write_all(b"# timestamp tx ty tz qx qy qz qw (world_from_camera)\n")
            .and_then(|()| out.flush())
            .map_err(io)?;
        Ok(Self {
            path: path.to_owned(),
            out,
            poses: 0,
            last_flush: std::time::Instant::now(),
        })
    }

    /// Appends one pose (the caller keeps timestamps increasing), and
    /// flushes when the last flush is [`Self::FLUSH_INTERVAL`] old.
    pub fn push(&mut self, stamp_s: f64, world_from_camera: &Pose) -> Result<(), DatasetError> {
        use std::io::Write;
        let t = world_from_camera.translation.vector;
        let q = world_from_camera.rotation.coords; // [x, y, z, w]
        let written = writeln!(
            self.out,
            "{} {} {} {} {} {} {} {}",
            stamp_s, t.x, t.y, t.z, q[0], q[1], q[2], q[3]
        );
        written.map_err(|source| DatasetError::Io {
            path: self.path.clone(),
            source,
        })?;
        self.poses += 1;
        if self.last_flush.elapsed() >= Self::FLUSH_INTERVAL {
            self.flush()?;
        }
        Ok(())
    }

    /// Writes the buffered lines to the file.
    pub fn flush(&mut self) -> Result<(), DatasetError> {
        use std::io::Write;
        self.last_flush = std::time::Instant::now();
        self.out.flush().map_err(|source| DatasetError::Io {
            path: self.path.clone(),
            source,
        })
    }

    /// Poses written so far.
    pub fn poses(&self) -> u64 {
        self.poses
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::exp_se3;
    use nalgebra::Vector6;

    fn sample() -> Trajectory {
        let mut t = Trajectory::default();
        for i in 0..20 {
            let s = i as f64;
            let xi = Vector6::new(0.1 * s, -0.3, 1.0 / 3.0, 0.01 * s, 0.7, -2.9 + 0.05 * s);
            t.push(1305031102.175304 + 0.02 * s, exp_se3(&xi));
        }
        t
    }

    #[test]
    fn write_read_roundtrip_is_full_precision() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("traj.txt");
        let t = sample();
        t.write(&path).expect("write");
        let back = Trajectory::read(&path).expect("read");
        assert_eq!(back.stamps_s, t.stamps_s, "timestamps are bit-exact");
        for (a, b) in t.poses.iter().zip(&back.poses) {
            assert_eq!(a.translation, b.translation, "translations are bit-exact");
            assert!((a.rotation.coords - b.rotation.coords).norm() < 1e-15);
        }
    }

    #[test]
    fn parses_tum_groundtruth_lines() {
        let text = "# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n\
                    1305031098.6659 1.3563 0.6305 1.6380 0.6132 0.5962 -0.3311 -0.3986\n";
        let t = Trajectory::parse(Path::new("groundtruth.txt"), text).expect("valid");
        assert_eq!(t.len(), 1);
        assert!((t.poses[0].translation.vector.x - 1.3563).abs() < 1e-12);
        // The stored quaternion was not exactly unit; it is normalized.
        assert!((t.poses[0].rotation.coords.norm() - 1.0).abs() < 1e-12);
        assert!((t.poses[0].rotation.w + 0.3986 / 0.99997f64.sqrt()).abs() < 1e-3);
    }

    #[test]
    fn errors_name_file_line_and_field() {
        let p = Path::new("gt.txt");
        let err = Trajectory::parse(p, "1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n").unwrap_err();
        assert!(
            matches!(err, DatasetError::Malformed { line: 2, .. }),
            "{err}"
        );
        let err = Trajectory::parse(p, "1 0 0 0 0 0 0 1\n2 0 x 0 0 0 0 1\n").unwrap_err();
        assert!(
            matches!(
                err,
                DatasetError::Malformed {
                    line: 2,
                    expected: "a finite ty",
                    ..
                }
            ),
            "{err}"
        );
        assert!(err.to_string().contains("gt.txt:2"), "{err}");
        let err = Trajectory::parse(p, "1 0 0 0 0 0 0 0\n").unwrap_err();
        assert!(matches!(err, DatasetError::Malformed { line: 1, .. }));
        let err = Trajectory::parse(p, "2 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n").unwrap_err();
        assert!(matches!(err, DatasetError::NonMonotonic { line: 2, .. }));
        let err = Trajectory::read(Path::new("/nonexistent/gt.txt")).unwrap_err();
        assert!(matches!(err, DatasetError::MissingFile { .. }));
    }

    #[test]
    fn streamed_trajectory_reads_back_equal() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("streamed.txt");
        let t = sample();
        let mut w = TrajectoryWriter::create(&path).expect("create");
        for (stamp, pose) in t.stamps_s.iter().zip(&t.poses) {
            w.push(*stamp, pose).expect("push");
        }
        w.flush().expect("flush");
        assert_eq!(w.poses(), t.len() as u64);
        let back = Trajectory::read(&path).expect("read back");
        assert_eq!(back.stamps_s, t.stamps_s);
        assert_eq!(back.poses.len(), t.poses.len());
        let missing = dir.path().join("no/such/dir/t.txt");
        let err = TrajectoryWriter::create(&missing)
            .err()
            .expect("missing dir");
        assert!(err.to_string().contains("no/such/dir"), "{err}");
    }
}
