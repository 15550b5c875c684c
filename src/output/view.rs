//! What the tracker sees, as pictures: the camera frame warped into the
//! keyframe and the photometric residual between them, and the view strip
//! the flight log writes (`views/`, `--record-views`).
//!
//! Takes a camera frame (raw, distorted, 8-bit), a keyframe render (gray
//! and metric depth, ideal pinhole) and the pose and photometric model the
//! aligner found; gives out 8-bit images. Runs on the recorder (or
//! logging) thread, never on the tracker's: every buffer is the caller's
//! ([`ViewScratch`]), sized once.

use nalgebra::Vector3;

use crate::geometry::{PinholeCamera, Pose};
use crate::imgproc::{ImageF32, ImageU8};
use crate::localizer::{FrameOutput, TrackState};
use crate::render::NO_DEPTH;
use crate::track::Keyframe;

/// Gray levels of residual per gray level of the picture: the residual is
/// drawn as `128 + RESIDUAL_GAIN * (frame - (gain * keyframe + bias))`, so
/// mid-gray is no error and black or white is 64 gray levels or more.
pub const RESIDUAL_GAIN: f32 = 2.0;

/// Pixels between the panels of the strip (drawn black).
const GAP_PX: usize = 4;

/// The buffers of [`warp_into_keyframe`] and [`view_strip`].
#[derive(Debug, Clone)]
pub struct ViewScratch {
    /// The camera frame as floats, for bilinear sampling.
    frame: ImageF32,
    /// The camera frame sampled at each keyframe pixel's projection; 0
    /// where the keyframe has no depth or the projection leaves the frame.
    pub warped: ImageU8,
    /// The signed residual, `128 + RESIDUAL_GAIN * r`; 128 where undefined.
    pub residual: ImageU8,
    /// The four panels side by side.
    pub strip: ImageU8,
    /// Pixels with a residual, and their RMS, gray levels.
    pub residual_pixels: usize,
    /// RMS of the residual over those pixels, gray levels.
    pub residual_rms: f32,
}

impl ViewScratch {
    /// Buffers for frames of `width` x `height`.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            frame: ImageF32::new(width, height, 0.0),
            warped: ImageU8::new(width, height, 0),
            residual: ImageU8::new(width, height, 128),
            strip: ImageU8::new(4 * width + 3 * GAP_PX, height, 0),
            residual_pixels: 0,
            residual_rms: 0.0,
        }
    }
}

/// What the aligner found for a frame: the pose of the camera relative to
/// the keyframe and the photometric model `camera = gain * keyframe + bias`.
#[derive(Debug, Clone, Copy)]
pub struct Alignment {
    /// Pose of the camera relative to the keyframe.
    pub camera_from_keyframe: Pose,
    /// Photometric gain.
    pub gain: f32,
    /// Photometric bias, gray levels.
    pub bias: f32,
}

impl Alignment {
    /// The alignment of a tracked frame against `keyframe` (the keyframe
    /// it was tracked against); `None` for a frame without a pose.
    pub fn of(out: &FrameOutput, keyframe: &Keyframe) -> Option<Self> {
        let world_from_camera = out.world_from_camera?;
        (out.state == TrackState::Tracking).then(|| Self {
            camera_from_keyframe: world_from_camera.inverse() * keyframe.world_from_keyframe,
            gain: out.gain,
            bias: out.bias,
        })
    }
}

/// Warps `frame` into the keyframe: for each keyframe pixel with depth,
/// back-projects it through the keyframe's pinhole, moves it into the
/// camera with `alignment`, projects it through `camera` (distortion
/// included) and samples the frame there. Fills `scratch.warped` and
/// `scratch.residual`. Images of the wrong size leave them blank.
pub fn warp_into_keyframe(
    frame: &ImageU8,
    keyframe_gray: &ImageF32,
    keyframe_depth_m: &ImageF32,
    camera: &PinholeCamera,
    alignment: &Alignment,
    scratch: &mut ViewScratch,
) {
    let (w, h) = (frame.width(), frame.height());
    scratch.warped.fill(0);
    scratch.residual.fill(128);
    scratch.residual_pixels = 0;
    scratch.residual_rms = 0.0;
    let sizes_agree = [
        (keyframe_gray.width(), keyframe_gray.height()),
        (keyframe_depth_m.width(), keyframe_depth_m.height()),
        (scratch.frame.width(), scratch.frame.height()),
    ]
    .iter()
    .all(|&size| size == (w, h));
    if !sizes_agree {
        return;
    }
    for (f, &p) in scratch.frame.data_mut().iter_mut().zip(frame.data()) {
        *f = f32::from(p);
    }
    let pinhole = camera.pinhole();
    let m = alignment.camera_from_keyframe.to_homogeneous();
    let mut sum_sq = 0.0f64;
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let z = keyframe_depth_m.data()[i];
            if z == NO_DEPTH || !z.is_finite() {
                continue;
            }
            let z = f64::from(z);
            let p_keyframe = Vector3::new(
                (x as f64 - pinhole.cx) / pinhole.fx * z,
                (y as f64 - pinhole.cy) / pinhole.fy * z,
                z,
            );
            let p_camera = m.fixed_view::<3, 3>(0, 0) * p_keyframe + m.fixed_view::<3, 1>(0, 3);
            let Some(uv) = camera.project(&p_camera) else {
                continue;
            };
            let Some(sample) = scratch.frame.bilinear(uv.x as f32, uv.y as f32) else {
                continue;
            };
            let predicted = alignment.gain * keyframe_gray.data()[i] + alignment.bias;
            let r = sample - predicted;
            scratch.warped.data_mut()[i] = sample.round().clamp(0.0, 255.0) as u8;
            scratch.residual.data_mut()[i] =
                (128.0 + RESIDUAL_GAIN * r).round().clamp(0.0, 255.0) as u8;
            sum_sq += f64::from(r) * f64::from(r);
            scratch.residual_pixels += 1;
        }
    }
    if scratch.residual_pixels > 0 {
        scratch.residual_rms = (sum_sq / scratch.residual_pixels as f64).sqrt() as f32;
    }
}

/// Lays out the strip in `scratch.strip`: the camera frame, the keyframe
/// render, the frame warped into the keyframe, the residual (left to
/// right, 4 black pixels apart). Call [`warp_into_keyframe`] first.
pub fn view_strip(frame: &ImageU8, keyframe_gray: &ImageF32, scratch: &mut ViewScratch) {
    let (w, h) = (frame.width(), frame.height());
    scratch.strip.fill(0);
    if scratch.strip.width() != 4 * w + 3 * GAP_PX
        || scratch.strip.height() != h
        || keyframe_gray.width() != w
        || keyframe_gray.height() != h
    {
        return;
    }
    for y in 0..h {
        let row = scratch.strip.row_mut(y);
        let (frame_px, rest) = row.split_at_mut(w);
        frame_px.copy_from_slice(frame.row(y));
        let keyframe_px = &mut rest[GAP_PX..GAP_PX + w];
        for (out, &g) in keyframe_px.iter_mut().zip(keyframe_gray.row(y)) {
            *out = g.round().clamp(0.0, 255.0) as u8;
        }
        let at = 2 * (w + GAP_PX);
        row[at..at + w].copy_from_slice(scratch.warped.row(y));
        let at = 3 * (w + GAP_PX);
        row[at..at + w].copy_from_slice(scratch.residual.row(y));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured plane 2 m in front of the keyframe.
    fn scene(camera: &PinholeCamera) -> (ImageF32, ImageF32) {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let mut gray = ImageF32::new(w, h, 0.0);
        for y in 0..h {
            for x in 0..w {
                gray.row_mut(y)[x] =
                    128.0 + 60.0 * ((x as f32 * 0.3).sin() * (y as f32 * 0.2).cos());
            }
        }
        (gray, ImageF32::new(w, h, 2.0))
    }

    #[test]
    fn the_keyframe_itself_warps_onto_itself_with_zero_residual() {
        let camera = PinholeCamera::new(64, 48, 50.0, 50.0, 31.5, 23.5);
        let (gray, depth) = scene(&camera);
        let frame = gray.to_u8();
        let mut scratch = ViewScratch::new(64, 48);
        let alignment = Alignment {
            camera_from_keyframe: Pose::identity(),
            gain: 1.0,
            bias: 0.0,
        };
        warp_into_keyframe(&frame, &gray, &depth, &camera, &alignment, &mut scratch);
        // Every pixel but the last row and column (bilinear needs a neighbour).
        assert_eq!(scratch.residual_pixels, 63 * 47);
        assert!(scratch.residual_rms < 0.6, "rms {}", scratch.residual_rms);
        view_strip(&frame, &gray, &mut scratch);
        assert_eq!(scratch.strip.width(), 4 * 64 + 12);
        assert_eq!(scratch.strip.row(10)[..64], *frame.row(10));
    }

    #[test]
    fn a_wrong_pose_shows_in_the_residual() {
        let camera = PinholeCamera::new(64, 48, 50.0, 50.0, 31.5, 23.5);
        let (gray, depth) = scene(&camera);
        let frame = gray.to_u8();
        let mut scratch = ViewScratch::new(64, 48);
        let shifted = Alignment {
            camera_from_keyframe: Pose::translation(0.1, 0.0, 0.0),
            gain: 1.0,
            bias: 0.0,
        };
        warp_into_keyframe(&frame, &gray, &depth, &camera, &shifted, &mut scratch);
        assert!(scratch.residual_rms > 10.0, "rms {}", scratch.residual_rms);
    }

    #[test]
    fn mismatched_sizes_leave_the_pictures_blank() {
        let camera = PinholeCamera::new(64, 48, 50.0, 50.0, 31.5, 23.5);
        let (gray, depth) = scene(&camera);
        let frame = ImageU8::new(32, 24, 7);
        let mut scratch = ViewScratch::new(64, 48);
        let alignment = Alignment {
            camera_from_keyframe: Pose::identity(),
            gain: 1.0,
            bias: 0.0,
        };
        warp_into_keyframe(&frame, &gray, &depth, &camera, &alignment, &mut scratch);
        assert_eq!(scratch.residual_pixels, 0);
    }
}
