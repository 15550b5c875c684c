//! Drawing a query: a random free pose at the database's heights and
//! pitch, rendered from the truth mesh (occluders, no map holes) through
//! the lens distortion and the realistic sensor model; or a random frame
//! of a dataset, with its ground truth.

use anyhow::{Context, Result};
use nalgebra::{Translation3, Vector3};

use crate::geometry::look::camera_rotation;
use crate::geometry::Pose;
use crate::render::Renderer;
use crate::rng::SplitMix64;

use super::setup::{Bench, Queries};

/// A drawn query; its frame is in [`Bench::frame`] and [`Bench::pyramid`].
pub(super) struct QueryFrame {
    /// Where the camera truly was.
    pub(super) truth: Pose,
    /// Its position, m.
    pub(super) position_m: Vector3<f64>,
}

impl Bench {
    /// Draws the next query (`index` numbers it for the sensor model), or
    /// `None` when the draw is not free or sees too little of the map.
    pub(super) fn draw_query(
        &mut self,
        rng: &mut SplitMix64,
        index: usize,
    ) -> Result<Option<QueryFrame>> {
        let synthetic = match &mut self.queries {
            Queries::Synthetic(s) => s,
            Queries::Dataset {
                dataset,
                truth,
                scratch,
            } => {
                let i = rng.below(dataset.len());
                dataset
                    .load_frame_into(i, &mut self.frame, scratch)
                    .with_context(|| format!("reading frame {i} of {}", dataset.root.display()))?;
                fill_pyramids(&self.frame, &mut self.pyramid, &mut self.contrast);
                let truth = truth.poses[i];
                return Ok(Some(QueryFrame {
                    truth,
                    position_m: truth.translation.vector,
                }));
            }
        };
        let s = synthetic.as_mut();
        let (z_lo, z_hi) = s.z_range_m;
        let scene = &s.scene;
        let p = Vector3::new(
            rng.range(scene.free_min_m[0], scene.free_max_m[0]),
            rng.range(scene.free_min_m[1], scene.free_max_m[1]),
            rng.range(z_lo, z_hi),
        );
        if !scene.is_free([p.x, p.y, p.z], 0.4) {
            return Ok(None);
        }
        let yaw = rng.range(-std::f64::consts::PI, std::f64::consts::PI);
        let pitch = (s.pitch_mid_deg + rng.range(-5.0, 5.0)).to_radians();
        // STAR_BENCH_ROLL_DEG=R: queries rolled uniformly within +-R deg
        // (the database views have none; no draw without it, so the default
        // queries stay the same).
        let roll = s
            .max_roll_deg
            .map_or(0.0, |r| rng.range(-r, r).to_radians());
        let truth = Pose::from_parts(Translation3::from(p), camera_rotation(yaw, pitch, roll));
        s.truth_r.render(&truth, &s.render_camera, &mut s.qview)?;
        let hits = s.qview.depth_m.data().iter().filter(|&&d| d > 0.0).count();
        if hits < s.qview.depth_m.data().len() * 6 / 10 {
            return Ok(None);
        }
        s.warp.warp_gray(&s.qview.gray, &mut s.warped);
        s.sensor.apply(
            &s.warped,
            index as u64,
            rng.range(0.0, 60.0),
            &mut self.frame,
        );
        fill_pyramids(&self.frame, &mut self.pyramid, &mut self.contrast);
        Ok(Some(QueryFrame {
            truth,
            position_m: p,
        }))
    }

    /// The last known pose of a kidnap to `query`: the true pose of a
    /// random frame of the dataset's flight whose horizontal distance from
    /// the query lies in `range_m`; `None` on synthetic queries, or when 64
    /// draws find none.
    pub(super) fn kidnapped_from(
        &self,
        rng: &mut SplitMix64,
        query: &QueryFrame,
        (min_m, max_m): (f64, f64),
    ) -> Option<Pose> {
        let Queries::Dataset { truth, .. } = &self.queries else {
            return None;
        };
        if truth.poses.is_empty() {
            return None;
        }
        (0..64).find_map(|_| {
            let pose = *truth.poses.get(rng.below(truth.poses.len()))?;
            let d = pose.translation.vector - query.position_m;
            (min_m..=max_m).contains(&d.x.hypot(d.y)).then_some(pose)
        })
    }
}

/// Builds the frame's pyramid, and its locally normalized one when
/// candidates are aligned on local contrast.
fn fill_pyramids(
    frame: &crate::imgproc::ImageU8,
    pyramid: &mut crate::track::Pyramid,
    contrast: &mut Option<(
        crate::reloc::local_contrast::LocalContrast,
        crate::track::Pyramid,
    )>,
) {
    pyramid.fill_from_u8(frame.data(), frame.width());
    if let Some((c, normalized_pyramid)) = contrast {
        if let Some(normalized) = c.frame(frame.data()) {
            normalized_pyramid.fill_from_u8(normalized, frame.width());
        }
    }
}
