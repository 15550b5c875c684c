//! One row of the flight log's `frames.csv`: what the tracker hands the
//! recorder per frame ([`FrameRow`], a small `Copy` value), how it is
//! written, and how `star eval` reads it back ([`LoggedFrame`]).
//!
//! Columns, in order ([`CSV_HEADER`]): the trajectory's stamp (dataset time
//! for replayed data, else the capture time), the capture time, the state
//! (`tracking`, `lost`, `searching`), the alignment's inlier ratio,
//! correlation and LM iterations, the tracking time, the keyframe's id and
//! age, the reset counter, whether a pose went out, and, where the run has a
//! MAVLink link, when the pose message went out and the TIMESYNC offset its
//! `usec` carried (empty otherwise).

use std::io::Write;
use std::path::Path;

use crate::geometry::Pose;
use crate::localizer::{FrameOutput, TrackState};

/// The header line of `frames.csv`.
pub const CSV_HEADER: &str = "stamp_s,capture_ns,state,inlier_ratio,correlation,iterations,track_ms,keyframe_id,keyframe_age_ms,reset_counter,pose_sent,mavlink_send_ns,timesync_offset_ns";

/// The tracking state of a frame in the log.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RowState {
    /// A pose went out.
    Tracking,
    /// No pose, no search.
    Lost,
    /// No pose; the frame was searched in the relocalization database, or a
    /// start pose or candidate is being verified.
    Searching,
}

impl RowState {
    /// The CSV word.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Tracking => "tracking",
            Self::Lost => "lost",
            Self::Searching => "searching",
        }
    }

    fn parse(word: &str) -> Option<Self> {
        match word {
            "tracking" => Some(Self::Tracking),
            "lost" => Some(Self::Lost),
            "searching" => Some(Self::Searching),
            _ => None,
        }
    }
}

/// What the tracker hands the recorder for one frame. `Copy`, no heap.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameRow {
    /// The trajectory's stamp: dataset time for replayed data, else the
    /// capture time, seconds.
    pub stamp_s: f64,
    /// Capture time, CLOCK_MONOTONIC ns.
    pub capture_ns: u64,
    /// Tracking, lost or searching.
    pub state: RowState,
    /// Alignment inlier ratio (0..=1).
    pub inlier_ratio: f32,
    /// Zero-mean normalized cross-correlation with the keyframe (-1..=1).
    pub correlation: f32,
    /// LM iterations over all levels.
    pub iterations: u32,
    /// Time `process_frame` took, ms.
    pub track_ms: f32,
    /// The keyframe tracked against.
    pub keyframe_id: u64,
    /// Its age, ms since the frame that requested it.
    pub keyframe_age_ms: f32,
    /// The reset counter the frame carried.
    pub reset_counter: u8,
    /// The pose that went out (to the trajectory, the pose service and the
    /// MAVLink mailbox); `None` while lost or searching.
    pub world_from_camera: Option<Pose>,
}

impl FrameRow {
    /// The row of a localizer output, tracked in `track_ms`.
    pub fn new(out: &FrameOutput, stamp_s: f64, track_ms: f64) -> Self {
        let pose = match out.state {
            TrackState::Tracking => out.world_from_camera,
            TrackState::Lost => None,
        };
        let state = match (pose, out.searching) {
            (Some(_), _) => RowState::Tracking,
            (None, true) => RowState::Searching,
            (None, false) => RowState::Lost,
        };
        Self {
            stamp_s,
            capture_ns: out.capture_ns,
            state,
            inlier_ratio: out.quality.inlier_ratio,
            correlation: out.quality.correlation,
            iterations: out.quality.iterations,
            track_ms: track_ms as f32,
            keyframe_id: out.keyframe_id,
            keyframe_age_ms: (out.keyframe_age_s * 1e3) as f32,
            reset_counter: out.reset_counter,
            world_from_camera: pose,
        }
    }

    /// Writes the CSV line (with its newline); `mavlink` is the send time
    /// and offset columns, `None` for a run without a link.
    pub fn write_csv(
        &self,
        out: &mut impl Write,
        mavlink: Option<(Option<u64>, Option<i64>)>,
    ) -> std::io::Result<()> {
        write!(
            out,
            "{:.6},{},{},{:.4},{:.4},{},{:.3},{},{:.1},{},{},",
            self.stamp_s,
            self.capture_ns,
            self.state.as_str(),
            self.inlier_ratio,
            self.correlation,
            self.iterations,
            self.track_ms,
            self.keyframe_id,
            self.keyframe_age_ms,
            self.reset_counter,
            u8::from(self.world_from_camera.is_some()),
        )?;
        if let Some((send_ns, offset_ns)) = mavlink {
            if let Some(t) = send_ns {
                write!(out, "{t}")?;
            }
            out.write_all(b",")?;
            if let Some(o) = offset_ns {
                write!(out, "{o}")?;
            }
        } else {
            out.write_all(b",")?;
        }
        out.write_all(b"\n")
    }
}

/// A row read back from `frames.csv`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoggedFrame {
    /// The trajectory's stamp, seconds.
    pub stamp_s: f64,
    /// Capture time, CLOCK_MONOTONIC ns.
    pub capture_ns: u64,
    /// Tracking, lost or searching.
    pub state: RowState,
    /// Alignment inlier ratio.
    pub inlier_ratio: f32,
    /// Correlation with the keyframe.
    pub correlation: f32,
    /// LM iterations.
    pub iterations: u32,
    /// Tracking time, ms.
    pub track_ms: f32,
    /// Keyframe id.
    pub keyframe_id: u64,
    /// Keyframe age, ms.
    pub keyframe_age_ms: f32,
    /// Reset counter.
    pub reset_counter: u8,
    /// Whether a pose went out (with `[keyframe] hold_for_next_frame`: was
    /// output by the tracker, and went out if the next frame tracked too).
    pub pose_sent: bool,
    /// When the MAVLink pose message went out, CLOCK_MONOTONIC ns.
    pub mavlink_send_ns: Option<u64>,
    /// The TIMESYNC offset, ns.
    pub timesync_offset_ns: Option<i64>,
}

/// Errors reading `frames.csv`.
#[derive(Debug, thiserror::Error)]
pub enum FramesCsvError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: std::path::PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The first line is not the header this version writes.
    #[error(
        "{path}: line 1 is not the frames.csv header; expected `{CSV_HEADER}`, found `{found}`"
    )]
    Header {
        /// The file.
        path: std::path::PathBuf,
        /// The line found.
        found: String,
    },
    /// A field could not be parsed.
    #[error("{path}:{line}: column `{column}`: expected {expected}, found `{found}`")]
    Field {
        /// The file.
        path: std::path::PathBuf,
        /// 1-based line number.
        line: usize,
        /// The column's name.
        column: &'static str,
        /// What was expected.
        expected: &'static str,
        /// The text found.
        found: String,
    },
}

const COLUMNS: [&str; 13] = [
    "stamp_s",
    "capture_ns",
    "state",
    "inlier_ratio",
    "correlation",
    "iterations",
    "track_ms",
    "keyframe_id",
    "keyframe_age_ms",
    "reset_counter",
    "pose_sent",
    "mavlink_send_ns",
    "timesync_offset_ns",
];

/// Parses the text of one `frames.csv` (`path` for the messages).
pub fn parse_frames_csv(path: &Path, text: &str) -> Result<Vec<LoggedFrame>, FramesCsvError> {
    let mut lines = text.lines();
    let header = lines.next().unwrap_or("");
    if header.trim_end() != CSV_HEADER {
        return Err(FramesCsvError::Header {
            path: path.to_owned(),
            found: header.chars().take(200).collect(),
        });
    }
    let mut rows = Vec::new();
    for (i, line) in lines.enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        rows.push(parse_line(path, i + 2, line)?);
    }
    Ok(rows)
}

fn parse_line(path: &Path, line_no: usize, line: &str) -> Result<LoggedFrame, FramesCsvError> {
    let mut fields = [""; 13];
    let mut n = 0;
    for (slot, field) in fields.iter_mut().zip(line.split(',')) {
        *slot = field.trim();
        n += 1;
    }
    let count = line.split(',').count();
    let err = |column: usize, expected: &'static str, found: &str| FramesCsvError::Field {
        path: path.to_owned(),
        line: line_no,
        column: COLUMNS[column.min(COLUMNS.len() - 1)],
        expected,
        found: found.chars().take(80).collect(),
    };
    if n != COLUMNS.len() || count != COLUMNS.len() {
        return Err(err(
            count.min(COLUMNS.len() - 1),
            "13 comma-separated fields",
            line,
        ));
    }
    fn num<T: std::str::FromStr>(s: &str) -> Option<T> {
        s.parse().ok()
    }
    let finite = |c: usize| -> Result<f64, FramesCsvError> {
        num::<f64>(fields[c])
            .filter(|v| v.is_finite())
            .ok_or_else(|| err(c, "a finite number", fields[c]))
    };
    let optional = |c: usize| -> Result<Option<&str>, FramesCsvError> {
        Ok(Some(fields[c]).filter(|s| !s.is_empty()))
    };
    Ok(LoggedFrame {
        stamp_s: finite(0)?,
        capture_ns: num(fields[1]).ok_or_else(|| err(1, "an integer (ns)", fields[1]))?,
        state: RowState::parse(fields[2])
            .ok_or_else(|| err(2, "tracking, lost or searching", fields[2]))?,
        inlier_ratio: finite(3)? as f32,
        correlation: finite(4)? as f32,
        iterations: num(fields[5]).ok_or_else(|| err(5, "an integer", fields[5]))?,
        track_ms: finite(6)? as f32,
        keyframe_id: num(fields[7]).ok_or_else(|| err(7, "an integer", fields[7]))?,
        keyframe_age_ms: finite(8)? as f32,
        reset_counter: num(fields[9]).ok_or_else(|| err(9, "0..=255", fields[9]))?,
        pose_sent: match fields[10] {
            "1" => true,
            "0" => false,
            other => return Err(err(10, "0 or 1", other)),
        },
        mavlink_send_ns: optional(11)?
            .map(|s| num(s).ok_or_else(|| err(11, "an integer (ns) or nothing", s)))
            .transpose()?,
        timesync_offset_ns: optional(12)?
            .map(|s| num(s).ok_or_else(|| err(12, "an integer (ns) or nothing", s)))
            .transpose()?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(state: RowState) -> FrameRow {
        FrameRow {
            stamp_s: 1000.02,
            capture_ns: 1_020_000_000,
            state,
            inlier_ratio: 0.875,
            correlation: 0.95,
            iterations: 12,
            track_ms: 3.25,
            keyframe_id: 4,
            keyframe_age_ms: 120.0,
            reset_counter: 1,
            world_from_camera: (state == RowState::Tracking).then(Pose::identity),
        }
    }

    #[test]
    fn written_rows_read_back() {
        let mut text = format!("{CSV_HEADER}\n").into_bytes();
        row(RowState::Tracking)
            .write_csv(&mut text, Some((Some(1_023_000_000), Some(-42))))
            .expect("write");
        row(RowState::Searching)
            .write_csv(&mut text, Some((None, None)))
            .expect("write");
        row(RowState::Lost)
            .write_csv(&mut text, None)
            .expect("write");
        let text = String::from_utf8(text).expect("utf-8");
        let rows = parse_frames_csv(Path::new("f.csv"), &text).expect("parse");
        assert_eq!(rows.len(), 3);
        assert_eq!(rows[0].state, RowState::Tracking);
        assert!(rows[0].pose_sent);
        assert_eq!(rows[0].mavlink_send_ns, Some(1_023_000_000));
        assert_eq!(rows[0].timesync_offset_ns, Some(-42));
        assert_eq!(rows[0].iterations, 12);
        assert_eq!(rows[1].state, RowState::Searching);
        assert!(!rows[1].pose_sent);
        assert_eq!(rows[2].mavlink_send_ns, None);
        assert_eq!(rows[2].timesync_offset_ns, None);
    }

    #[test]
    fn bad_fields_are_named_with_file_line_and_column() {
        let text = format!("{CSV_HEADER}\n1.0,5,flying,0.9,0.9,3,1.0,1,2.0,0,1,,\n");
        let e = parse_frames_csv(Path::new("f.csv"), &text).expect_err("bad state");
        let msg = e.to_string();
        assert!(
            msg.contains("f.csv:2") && msg.contains("state") && msg.contains("flying"),
            "{msg}"
        );
        let text = format!("{CSV_HEADER}\n1.0,5,lost\n");
        let e = parse_frames_csv(Path::new("f.csv"), &text).expect_err("short line");
        assert!(e.to_string().contains("13 comma-separated"), "{e}");
        let e = parse_frames_csv(Path::new("f.csv"), "a,b\n").expect_err("header");
        assert!(e.to_string().contains("line 1"), "{e}");
    }
}
