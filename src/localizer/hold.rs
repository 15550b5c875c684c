//! Holding each pose until the next frame tracks too
//! (`[keyframe] hold_for_next_frame`).
//!
//! Owns [`NextFrameHold`], the one-frame delay line between
//! [`super::Localizer::process_frame`] and what sends poses (the MAVLink
//! link, the pose topic, the trajectory file, `star localize`'s estimate).
//! A tracked frame's pose goes out only once the next frame the tracker
//! processes has tracked as well; when that next frame is lost, the held
//! pose is released as a lost frame and never sent.
//!
//! Why. On `aggressive --scanned` the wrong poses left were the last frame
//! of a slide or a step: a frame 10-13 cm off, tracked with every test
//! passing, and the frame after it lost by the jump test when a fresh
//! keyframe pulled the alignment back (docs/benchmarks.md, "A pose held
//! for the next frame"). The next frame is the evidence the frame itself
//! cannot give. The cost is one frame of latency on every pose (20 ms at
//! 50 Hz; the pose keeps its capture time, so the autopilot's fusion
//! places it where it belongs) and the poses of frames just before a loss.
//!
//! Nothing here allocates: the held output is a fixed-size value.

use super::{FrameOutput, TrackState};

/// The one-frame delay line. `M` is what the caller needs to send a frame
/// besides its output (its stamp, its sequence number).
#[derive(Debug)]
pub struct NextFrameHold<M> {
    enabled: bool,
    held: Option<(FrameOutput, M)>,
    withheld: u64,
}

impl<M> NextFrameHold<M> {
    /// A delay line that holds each frame when `enabled`, else hands every
    /// frame straight back.
    pub fn new(enabled: bool) -> Self {
        Self {
            enabled,
            held: None,
            withheld: 0,
        }
    }

    /// Whether frames are held.
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// Takes the output of the frame just processed and returns the frame
    /// to send now: the same one when the hold is off, else the frame before
    /// it (`None` for the first), whose pose is kept only if `out` tracked.
    pub fn push(&mut self, out: FrameOutput, meta: M) -> Option<(FrameOutput, M)> {
        if !self.enabled {
            return Some((out, meta));
        }
        let confirms = sends_pose(&out);
        let released = self.held.replace((out, meta));
        released.map(|(mut previous, meta)| {
            if !confirms {
                self.withhold(&mut previous);
            }
            (previous, meta)
        })
    }

    /// Releases the frame still held at the end of the stream: no frame
    /// follows to confirm it, so its pose is withheld.
    pub fn finish(&mut self) -> Option<(FrameOutput, M)> {
        let (mut last, meta) = self.held.take()?;
        self.withhold(&mut last);
        Some((last, meta))
    }

    /// Tracked frames whose pose was not sent because the next frame was
    /// lost (or none came).
    pub fn withheld(&self) -> u64 {
        self.withheld
    }

    fn withhold(&mut self, out: &mut FrameOutput) {
        if sends_pose(out) {
            self.withheld += 1;
            tracing::debug!(
                capture_ns = out.capture_ns,
                "pose withheld: the next frame did not track"
            );
        }
        out.state = TrackState::Lost;
        out.world_from_camera = None;
    }
}

/// Whether `out` carries a pose to send.
fn sends_pose(out: &FrameOutput) -> bool {
    out.state == TrackState::Tracking && out.world_from_camera.is_some()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose;
    use crate::track::AlignQuality;
    use nalgebra::Matrix6;

    fn frame(capture_ns: u64, tracked: bool) -> FrameOutput {
        FrameOutput {
            capture_ns,
            state: if tracked {
                TrackState::Tracking
            } else {
                TrackState::Lost
            },
            world_from_camera: tracked.then(Pose::identity),
            covariance: Matrix6::identity(),
            quality: AlignQuality::default(),
            gain: 1.0,
            bias: 0.0,
            keyframe_id: 1,
            keyframe_age_s: 0.0,
            stale_keyframe: false,
            reset_counter: 0,
            searching: false,
        }
    }

    /// Feeds frames tracked (`true`) or lost, and returns what was sent:
    /// (capture_ns, pose sent) for each frame released, `finish` included.
    fn run(enabled: bool, tracked: &[bool]) -> (Vec<(u64, bool)>, u64) {
        let mut hold = NextFrameHold::new(enabled);
        let mut sent = Vec::new();
        for (i, &t) in tracked.iter().enumerate() {
            if let Some((out, meta)) = hold.push(frame(i as u64 * 20, t), i) {
                assert_eq!(
                    out.capture_ns,
                    meta as u64 * 20,
                    "the meta travels with its frame"
                );
                sent.push((out.capture_ns, sends_pose(&out)));
            }
        }
        sent.extend(
            hold.finish()
                .map(|(out, _)| (out.capture_ns, sends_pose(&out))),
        );
        (sent, hold.withheld())
    }

    #[test]
    fn off_every_frame_goes_out_as_it_came() {
        let (sent, withheld) = run(false, &[true, false, true, true]);
        assert_eq!(sent, [(0, true), (20, false), (40, true), (60, true)]);
        assert_eq!(withheld, 0);
    }

    #[test]
    fn a_pose_goes_out_once_the_next_frame_tracks() {
        // Frame 1 is followed by a loss: not sent. Frame 4 has no frame
        // after it: not sent either. Every frame is released exactly once,
        // in order.
        let (sent, withheld) = run(true, &[true, true, false, true, true]);
        assert_eq!(
            sent,
            [(0, true), (20, false), (40, false), (60, true), (80, false)]
        );
        assert_eq!(withheld, 2);
    }

    #[test]
    fn lost_frames_are_released_lost_and_not_counted() {
        let (sent, withheld) = run(true, &[false, false, true]);
        assert_eq!(sent, [(0, false), (20, false), (40, false)]);
        assert_eq!(withheld, 1, "only the last, tracked one was withheld");
    }
}
