//! Reading a flight log back (`star eval --frames`): every part of
//! `frames.csv` in order, and what happened in it ([`FrameLogSummary`]):
//! frames, lost events, relocalizations, poses sent.

use std::path::{Path, PathBuf};

use super::files::part_path;
use super::row::{parse_frames_csv, FramesCsvError, LoggedFrame, RowState};

/// Reads `path`: a record folder (its `frames.csv`, `frames.1.csv`, ... in
/// order) or one CSV file.
pub fn read_frames_log(path: &Path) -> Result<Vec<LoggedFrame>, FramesCsvError> {
    let read = |file: PathBuf| -> Result<Vec<LoggedFrame>, FramesCsvError> {
        let text = std::fs::read_to_string(&file).map_err(|source| FramesCsvError::Read {
            path: file.clone(),
            source,
        })?;
        parse_frames_csv(&file, &text)
    };
    if !path.is_dir() {
        return read(path.to_owned());
    }
    let mut rows = read(part_path(path, "frames", "csv", 0))?;
    for part in 1.. {
        let file = part_path(path, "frames", "csv", part);
        if !file.is_file() {
            break;
        }
        rows.extend(read(file)?);
    }
    Ok(rows)
}

/// An event of the log, for the plots.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LogEvent {
    /// Tracking was lost at this stamp (the first frame without a pose
    /// after one with a pose).
    Lost {
        /// The trajectory's stamp, s.
        stamp_s: f64,
    },
    /// Tracking restarted through the relocalization gate (the reset
    /// counter changed).
    Relocalized {
        /// The trajectory's stamp, s.
        stamp_s: f64,
    },
    /// Poses resumed without a relocalization (a short loss, or the end of
    /// a gap in a trajectory without a log).
    Resumed {
        /// The trajectory's stamp, s.
        stamp_s: f64,
    },
}

impl LogEvent {
    /// When it happened, s.
    pub fn stamp_s(&self) -> f64 {
        match *self {
            Self::Lost { stamp_s } | Self::Relocalized { stamp_s } | Self::Resumed { stamp_s } => {
                stamp_s
            }
        }
    }
}

/// What a flight log says happened.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameLogSummary {
    /// Rows (frames processed).
    pub frames: usize,
    /// Frames with a pose.
    pub tracking: usize,
    /// Frames lost, not searching.
    pub lost: usize,
    /// Frames searching (relocalization, verification).
    pub searching: usize,
    /// Times tracking was lost.
    pub lost_events: usize,
    /// Relocalizations (reset counter changes after the first pose).
    pub relocalizations: usize,
    /// Poses that went out.
    pub poses_sent: usize,
    /// Poses whose MAVLink message went out.
    pub mavlink_sent: usize,
    /// Median capture-to-send latency of those, ms.
    pub median_send_latency_ms: Option<f64>,
    /// Median tracking time, ms.
    pub median_track_ms: Option<f64>,
    /// The events, in order.
    pub events: Vec<LogEvent>,
}

impl FrameLogSummary {
    /// Counts the rows.
    pub fn new(rows: &[LoggedFrame]) -> Self {
        let mut s = Self {
            frames: rows.len(),
            ..Self::default()
        };
        let mut previous: Option<&LoggedFrame> = None;
        let mut latencies_ms = Vec::new();
        let mut track_ms = Vec::with_capacity(rows.len());
        for row in rows {
            match row.state {
                RowState::Tracking => s.tracking += 1,
                RowState::Lost => s.lost += 1,
                RowState::Searching => s.searching += 1,
            }
            // The first pose of a run (a start verified through the gate,
            // which increments the reset counter too) is no event.
            let earlier_pose = s.poses_sent > 0;
            s.poses_sent += usize::from(row.pose_sent);
            if let Some(send_ns) = row.mavlink_send_ns {
                s.mavlink_sent += 1;
                latencies_ms.push(send_ns.saturating_sub(row.capture_ns) as f64 * 1e-6);
            }
            track_ms.push(f64::from(row.track_ms));
            if let Some(p) = previous {
                if p.pose_sent && !row.pose_sent {
                    s.lost_events += 1;
                    s.events.push(LogEvent::Lost {
                        stamp_s: row.stamp_s,
                    });
                }
                let resumed = row.pose_sent && earlier_pose;
                if resumed && row.reset_counter != p.reset_counter {
                    s.relocalizations += 1;
                    s.events.push(LogEvent::Relocalized {
                        stamp_s: row.stamp_s,
                    });
                } else if resumed && !p.pose_sent {
                    s.events.push(LogEvent::Resumed {
                        stamp_s: row.stamp_s,
                    });
                }
            }
            previous = Some(row);
        }
        s.median_send_latency_ms = median(&mut latencies_ms);
        s.median_track_ms = median(&mut track_ms);
        s
    }
}

impl std::fmt::Display for FrameLogSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "frames {}  tracking {}  lost {}  searching {}",
            self.frames, self.tracking, self.lost, self.searching
        )?;
        writeln!(
            f,
            "lost events {}  relocalizations {}  poses sent {}",
            self.lost_events, self.relocalizations, self.poses_sent
        )?;
        if let Some(ms) = self.median_track_ms {
            writeln!(f, "tracking time per frame: median {ms:.2} ms")?;
        }
        match self.median_send_latency_ms {
            Some(ms) => writeln!(
                f,
                "MAVLink poses sent {}  capture-to-send latency median {ms:.2} ms",
                self.mavlink_sent
            ),
            None => writeln!(f, "MAVLink: no pose message recorded"),
        }
    }
}

fn median(samples: &mut [f64]) -> Option<f64> {
    if samples.is_empty() {
        return None;
    }
    let mid = samples.len() / 2;
    Some(*samples.select_nth_unstable_by(mid, f64::total_cmp).1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(stamp_s: f64, state: RowState, reset_counter: u8) -> LoggedFrame {
        LoggedFrame {
            stamp_s,
            capture_ns: (stamp_s * 1e9) as u64,
            state,
            inlier_ratio: 0.9,
            correlation: 0.9,
            iterations: 5,
            track_ms: 2.0,
            keyframe_id: 1,
            keyframe_age_ms: 10.0,
            reset_counter,
            pose_sent: state == RowState::Tracking,
            mavlink_send_ns: (state == RowState::Tracking)
                .then_some((stamp_s * 1e9) as u64 + 3_000_000),
            timesync_offset_ns: None,
        }
    }

    #[test]
    fn counts_losses_relocalizations_and_sends() {
        use RowState::*;
        let rows = [
            frame(0.9, Searching, 0),
            frame(1.0, Tracking, 1),
            frame(1.1, Tracking, 1),
            frame(1.2, Lost, 1),
            frame(1.3, Searching, 1),
            frame(1.4, Searching, 1),
            frame(1.5, Tracking, 2),
            frame(1.6, Tracking, 2),
        ];
        let s = FrameLogSummary::new(&rows);
        assert_eq!((s.frames, s.tracking, s.lost, s.searching), (8, 4, 1, 3));
        assert_eq!((s.lost_events, s.relocalizations, s.poses_sent), (1, 1, 4));
        assert_eq!(s.mavlink_sent, 4);
        let latency = s.median_send_latency_ms.expect("latency");
        assert!((latency - 3.0).abs() < 1e-3, "{latency}");
        // The start (searching, then the first pose) is no event.
        assert_eq!(
            s.events,
            vec![
                LogEvent::Lost { stamp_s: 1.2 },
                LogEvent::Relocalized { stamp_s: 1.5 }
            ]
        );
    }
}
