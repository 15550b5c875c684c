//! Whether the occlusion cull pays on this device, timed in flight.
//!
//! Owns [`CullTiming`]: the choice, render by render, between drawing a
//! view with the occlusion cull (`super::occlusion`: two or three passes,
//! the depth read back between them) and with the frustum cull alone (one
//! pass). Both give the same image (the tests compare them bit for bit),
//! so the choice is only about time, and the time depends on the device:
//! on Mesa's lavapipe the cull halves a floor keyframe (16 against 37 ms),
//! on an NVIDIA H200 it makes it 3.7 times slower (5.5 against 1.5 ms: the
//! readback between passes costs more than drawing every triangle in the
//! frustum), and on the vehicle's Intel iGPU it is not known
//! (docs/building-scale.md). A hardware adapter's renderer therefore times
//! both, in short blocks, and keeps the faster.
//!
//! **The schedule.** A *trial* is a block of [`BLOCK`] renders with the
//! cull, then a block without; the first render of each block is not
//! counted (the cull's first pass draws what the previous render kept,
//! which a render without the cull did not record). The block whose median
//! is lower wins, the current choice keeping its place unless the other is
//! faster by [`SWITCH_MARGIN`]. The choice then holds for [`HOLD`] renders
//! (about 3 minutes at the tracker's 5 keyframes a second), and a new trial
//! follows, since the views change over a flight. The state is a few fixed
//! arrays: nothing is allocated per render.

/// Renders per block of a trial (the first of each not counted).
pub const BLOCK: usize = 5;
/// Renders between trials.
pub const HOLD: u32 = 1000;
/// The other mode must be faster by this share of the current one's median
/// to take its place.
pub const SWITCH_MARGIN: f64 = 0.1;

/// Where the schedule stands.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    /// Timing the block of `occlusion` (true: with the cull); `done`
    /// renders of it so far.
    Block { occlusion: bool, done: usize },
    /// The choice holds for `left` more renders.
    Hold { left: u32 },
}

/// The decision at the end of a trial.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CullDecision {
    /// Whether the occlusion cull is used from now on.
    pub occlusion: bool,
    /// Median render time with the cull, seconds.
    pub with_cull_s: f64,
    /// Median render time with the frustum cull alone, seconds.
    pub frustum_only_s: f64,
}

/// The timed choice; see the module docs.
#[derive(Debug, Clone)]
pub struct CullTiming {
    phase: Phase,
    /// The current choice.
    occlusion: bool,
    /// Counted times of this trial's blocks, seconds: with the cull, and
    /// without.
    with_cull_s: [f64; BLOCK - 1],
    frustum_only_s: [f64; BLOCK - 1],
    /// Trials finished since start.
    trials: u32,
    /// The last trial's decision.
    last: Option<CullDecision>,
}

impl Default for CullTiming {
    fn default() -> Self {
        Self::new()
    }
}

impl CullTiming {
    /// Starts with a trial, the cull on in the meantime.
    pub fn new() -> Self {
        Self {
            phase: Phase::Block {
                occlusion: true,
                done: 0,
            },
            occlusion: true,
            with_cull_s: [0.0; BLOCK - 1],
            frustum_only_s: [0.0; BLOCK - 1],
            trials: 0,
            last: None,
        }
    }

    /// Whether the next render uses the occlusion cull.
    pub fn next_uses_cull(&self) -> bool {
        match self.phase {
            Phase::Block { occlusion, .. } => occlusion,
            Phase::Hold { .. } => self.occlusion,
        }
    }

    /// Records the render just made (with the cull when `occlusion`, as
    /// [`CullTiming::next_uses_cull`] said) and how long it took; gives the
    /// decision when it ended a trial. A time that is not finite or not
    /// positive counts as the slowest possible.
    pub fn record(&mut self, occlusion: bool, elapsed_s: f64) -> Option<CullDecision> {
        let elapsed_s = if elapsed_s.is_finite() && elapsed_s > 0.0 {
            elapsed_s
        } else {
            f64::MAX
        };
        match self.phase {
            Phase::Hold { left } => {
                self.phase = if left > 1 {
                    Phase::Hold { left: left - 1 }
                } else {
                    // The trial starts with the mode in use, whose
                    // previous render is the one the cull's first pass
                    // follows.
                    Phase::Block {
                        occlusion: self.occlusion,
                        done: 0,
                    }
                };
                None
            }
            Phase::Block {
                occlusion: block,
                done,
            } => {
                if block != occlusion {
                    // Not the render the schedule asked for: start the
                    // block again.
                    self.phase = Phase::Block {
                        occlusion: block,
                        done: 0,
                    };
                    return None;
                }
                if done > 0 {
                    let times = if block {
                        &mut self.with_cull_s
                    } else {
                        &mut self.frustum_only_s
                    };
                    if let Some(t) = times.get_mut(done - 1) {
                        *t = elapsed_s;
                    }
                }
                let done = done + 1;
                if done < BLOCK {
                    self.phase = Phase::Block {
                        occlusion: block,
                        done,
                    };
                    return None;
                }
                // A trial opens with the mode in use.
                if block == self.occlusion {
                    // The other block next.
                    self.phase = Phase::Block {
                        occlusion: !block,
                        done: 0,
                    };
                    return None;
                }
                Some(self.decide())
            }
        }
    }

    fn decide(&mut self) -> CullDecision {
        let with_cull_s = median(&mut self.with_cull_s);
        let frustum_only_s = median(&mut self.frustum_only_s);
        let (current_s, other_s) = if self.occlusion {
            (with_cull_s, frustum_only_s)
        } else {
            (frustum_only_s, with_cull_s)
        };
        if other_s < current_s * (1.0 - SWITCH_MARGIN) {
            self.occlusion = !self.occlusion;
        }
        let decision = CullDecision {
            occlusion: self.occlusion,
            with_cull_s,
            frustum_only_s,
        };
        self.phase = Phase::Hold { left: HOLD };
        self.trials += 1;
        self.last = Some(decision);
        decision
    }

    /// Trials finished since start.
    pub fn trials(&self) -> u32 {
        self.trials
    }

    /// The last trial's decision, if one has finished.
    pub fn last_decision(&self) -> Option<CullDecision> {
        self.last
    }
}

/// Median of `values` (sorted in place; the mean of the middle two for an
/// even count).
fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    match n {
        0 => f64::MAX,
        _ if n % 2 == 1 => values[n / 2],
        _ => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs `timing` for `renders` renders, each taking `with_s` with the
    /// cull and `without_s` without; gives the decisions made.
    fn run(timing: &mut CullTiming, renders: usize, with_s: f64, without_s: f64) -> Vec<bool> {
        let mut decisions = Vec::new();
        for _ in 0..renders {
            let cull = timing.next_uses_cull();
            let t = if cull { with_s } else { without_s };
            if let Some(d) = timing.record(cull, t) {
                decisions.push(d.occlusion);
            }
        }
        decisions
    }

    #[test]
    fn a_device_where_the_readback_costs_more_drops_the_cull() {
        let mut timing = CullTiming::new();
        // An H200's floor keyframe: 5.5 ms with the cull, 1.5 ms without.
        assert_eq!(run(&mut timing, 2 * BLOCK, 5.5e-3, 1.5e-3), vec![false]);
        let d = timing.last_decision().expect("a trial finished");
        assert_eq!((d.with_cull_s, d.frustum_only_s), (5.5e-3, 1.5e-3));
        // It holds: every render of the next HOLD is without the cull.
        for _ in 0..HOLD {
            assert!(!timing.next_uses_cull());
            assert_eq!(timing.record(false, 1.5e-3), None);
        }
        // Then a trial again, opening with the mode in use.
        assert!(!timing.next_uses_cull());
        assert_eq!(timing.trials(), 1);
    }

    #[test]
    fn a_device_where_the_cull_pays_keeps_it() {
        let mut timing = CullTiming::new();
        // lavapipe's floor keyframe: 16 ms with the cull, 37 ms without.
        assert_eq!(run(&mut timing, 2 * BLOCK, 16e-3, 37e-3), vec![true]);
        assert!(timing.next_uses_cull());
    }

    #[test]
    fn the_first_render_of_a_block_is_not_counted_and_a_close_call_keeps_the_mode() {
        let mut timing = CullTiming::new();
        let mut times_with = [1.0, 0.010, 0.010, 0.010, 0.010].into_iter();
        // Without the cull: 5 % faster, under the switch margin.
        let mut times_without = [1.0, 0.0095, 0.0095, 0.0095, 0.0095].into_iter();
        let mut decision = None;
        for _ in 0..2 * BLOCK {
            let cull = timing.next_uses_cull();
            let t = if cull {
                times_with.next()
            } else {
                times_without.next()
            };
            decision = timing.record(cull, t.expect("one time per render"));
        }
        let d = decision.expect("the trial ended on its last render");
        assert!(d.occlusion);
        assert_eq!((d.with_cull_s, d.frustum_only_s), (0.010, 0.0095));
    }

    #[test]
    fn a_render_out_of_schedule_restarts_its_block_and_bad_times_count_as_slow() {
        let mut timing = CullTiming::new();
        assert!(timing.record(true, 0.01).is_none());
        // A render without the cull inside the cull's block (a caller that
        // overrode the mode): the block starts over.
        assert!(timing.record(false, 0.01).is_none());
        for _ in 0..BLOCK {
            assert!(timing.next_uses_cull());
            assert!(timing.record(true, f64::NAN).is_none());
        }
        let mut decision = None;
        for _ in 0..BLOCK {
            assert!(!timing.next_uses_cull());
            decision = timing.record(false, 0.02);
        }
        // NaN times with the cull count as the slowest: the cull is dropped.
        assert_eq!(decision.map(|d| d.occlusion), Some(false));
    }
}
