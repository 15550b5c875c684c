//! Auto-exposure steps of the flight camera: a global gain that jumps by
//! 15-25 % every 1-2 s, as an auto-exposure loop does when the view's
//! brightness changes.
//!
//! The gain is piecewise constant: it starts at 1, and at each step time
//! (intervals drawn from `step_interval_s`) it is multiplied by `1 + f` or
//! `1 - f` (`f` drawn from `step_fraction`), the sign drawn at random
//! except that a step never leaves `gain_range`. Seeded, so the schedule is
//! the same for the same seed; steps are computed up front for the
//! sequence's duration.

use serde::Serialize;

use super::depth_sensor::Gaussian;

/// Exact auto-exposure parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ExposureSpec {
    /// Range of the time between steps, seconds.
    pub step_interval_s: (f64, f64),
    /// Range of the relative size of a step.
    pub step_fraction: (f64, f64),
    /// The gain stays within this range.
    pub gain_range: (f64, f64),
}

/// A drawn exposure schedule: `(time, gain from then on)`.
#[derive(Debug, Clone, PartialEq)]
pub struct ExposureSchedule {
    steps: Vec<(f64, f64)>,
}

impl ExposureSchedule {
    /// Draws the steps of `spec` over `0..duration_s` from `seed`.
    pub fn new(spec: &ExposureSpec, seed: u64, duration_s: f64) -> Self {
        let mut rng = Gaussian::new(seed);
        let mut draw = |(lo, hi): (f64, f64)| lo + (hi - lo) * rng.uniform();
        let mut steps = vec![(0.0, 1.0)];
        let mut t = 0.0;
        let mut gain: f64 = 1.0;
        let (lo, hi) = spec.gain_range;
        // At least one step per second keeps the count bounded.
        let max_steps = duration_s.max(0.0) as usize + 1;
        while steps.len() <= max_steps {
            t += draw(spec.step_interval_s).max(1e-3);
            if t >= duration_s {
                break;
            }
            let f = draw(spec.step_fraction);
            let up = draw((0.0, 1.0)) < 0.5;
            let up = if up {
                gain * (1.0 + f) <= hi
            } else {
                gain * (1.0 - f) < lo
            };
            gain = if up {
                gain * (1.0 + f)
            } else {
                gain * (1.0 - f)
            };
            steps.push((t, gain));
        }
        Self { steps }
    }

    /// The gain at time `t_s`.
    pub fn gain_at(&self, t_s: f64) -> f64 {
        let i = self.steps.partition_point(|&(t, _)| t <= t_s);
        self.steps[i.saturating_sub(1)].1
    }

    /// The steps, `(time s, gain from then on)`, the first at time 0.
    pub fn steps(&self) -> &[(f64, f64)] {
        &self.steps
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_have_the_requested_size_and_rhythm() {
        let spec = ExposureSpec {
            step_interval_s: (1.0, 2.0),
            step_fraction: (0.15, 0.25),
            gain_range: (0.6, 1.6),
        };
        let s = ExposureSchedule::new(&spec, 4, 60.0);
        assert_eq!(s, ExposureSchedule::new(&spec, 4, 60.0));
        let steps = s.steps();
        assert!((30..=61).contains(&steps.len()), "{}", steps.len());
        for w in steps.windows(2) {
            let dt = w[1].0 - w[0].0;
            assert!((1.0..=2.0).contains(&dt), "interval {dt}");
            let r = w[1].1 / w[0].1;
            let f = (r - 1.0).abs();
            assert!((0.15 - 1e-9..=0.25 + 1e-9).contains(&f), "step {r}");
            assert!((0.6..=1.6).contains(&w[1].1), "gain {}", w[1].1);
        }
        assert_eq!(s.gain_at(0.0), 1.0);
        assert_eq!(s.gain_at(steps[1].0), steps[1].1);
        assert_eq!(s.gain_at(steps[1].0 - 1e-6), 1.0);
        assert_eq!(s.gain_at(1e9), steps[steps.len() - 1].1);
    }
}
