//! The synthetic camera: renders of a mesh turned into the 8-bit frames a
//! real camera delivers.
//!
//! Owns the CPU renderer of the image mesh and the corruption chain, in
//! this order: sub-frame renders averaged across the exposure (motion
//! blur, [`super::corrupt::blur`]), an optional per-sub-frame shading hook
//! (the scanned variant's moving light), the enlarged pinhole render
//! resampled through the lens distortion ([`DistortionWarp`]), an optional
//! exposure gain, then the photometric sensor model (drift, vignetting,
//! noise, quantization: [`SensorModel`]). Takes a pose as a function of
//! time; gives out an [`ImageU8`] of the camera's size. Shared by
//! `star synth` ([`super::sequence`]) and the simulated vehicle's camera
//! ([`super::sim_camera`]). Buffers are sized once: a frame allocates
//! nothing after the first.

use std::sync::Arc;

use super::corrupt::{
    subframe_offsets_s, BlurSpec, DistortionError, DistortionWarp, PhotometricSpec, SensorModel,
};
use crate::geometry::{PinholeCamera, Pose};
use crate::imgproc::{ImageF32, ImageU8};
use crate::map::Mesh;
use crate::render::cpu::CpuRenderer;
use crate::render::{RenderError, RenderedView, Renderer};

/// Why a synthetic camera cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum SyntheticCameraError {
    /// The lens distortion cannot be resampled.
    #[error("cannot build the distortion warp")]
    Distortion(#[from] DistortionError),
    /// The renderer cannot take the mesh.
    #[error("cannot build the renderer")]
    Render(#[from] RenderError),
}

/// A camera that renders a mesh and corrupts it like a real sensor.
pub struct SyntheticCamera {
    renderer: CpuRenderer,
    warp: DistortionWarp,
    render_camera: PinholeCamera,
    sensor: SensorModel,
    blur: Option<BlurSpec>,
    focal_px: f64,
    view: RenderedView,
    accum: ImageF32,
    warped: ImageF32,
    offsets_s: Vec<f64>,
}

impl SyntheticCamera {
    /// A camera with `camera`'s intrinsics and distortion looking at
    /// `mesh`, with the `photometric` sensor model (noise seeded by `seed`)
    /// and the `blur` exposure (`None`: one instant per frame).
    pub fn new(
        mesh: Arc<Mesh>,
        camera: &PinholeCamera,
        photometric: PhotometricSpec,
        blur: Option<BlurSpec>,
        seed: u64,
    ) -> Result<Self, SyntheticCameraError> {
        let warp = DistortionWarp::new(camera)?;
        let render_camera = *warp.render_camera();
        let view = RenderedView::for_camera(&render_camera);
        let accum = ImageF32::new(view.gray.width(), view.gray.height(), 0.0);
        Ok(Self {
            renderer: CpuRenderer::new(mesh)?,
            warp,
            render_camera,
            sensor: SensorModel::new(photometric, camera, seed),
            blur,
            focal_px: camera.fx,
            view,
            accum,
            warped: ImageF32::new(0, 0, 0.0),
            offsets_s: Vec::with_capacity(blur.map_or(1, |b| b.max_subframes.max(1) as usize)),
        })
    }

    /// The pinhole camera the mesh is rendered with (enlarged for the
    /// distortion).
    pub fn render_camera(&self) -> &PinholeCamera {
        &self.render_camera
    }

    /// Renders the exposure of the frame at `t_s`: the sub-frames the
    /// motion of `world_from_camera_at` needs, each passed to `shade` with
    /// its pose and time, averaged. Returns the number of renders.
    pub fn expose(
        &mut self,
        world_from_camera_at: impl Fn(f64) -> Pose,
        t_s: f64,
        mut shade: impl FnMut(&mut RenderedView, &Pose, f64),
    ) -> Result<usize, RenderError> {
        match &self.blur {
            Some(spec) => subframe_offsets_s(
                spec,
                self.focal_px,
                &world_from_camera_at,
                t_s,
                &mut self.offsets_s,
            ),
            None => {
                self.offsets_s.clear();
                self.offsets_s.push(0.0);
            }
        }
        self.accum.fill(0.0);
        let weight = 1.0 / self.offsets_s.len() as f32;
        for &dt in &self.offsets_s {
            let pose = world_from_camera_at(t_s + dt);
            self.renderer
                .render(&pose, &self.render_camera, &mut self.view)?;
            shade(&mut self.view, &pose, t_s + dt);
            for (a, &g) in self.accum.data_mut().iter_mut().zip(self.view.gray.data()) {
                *a += weight * g;
            }
        }
        Ok(self.offsets_s.len())
    }

    /// Turns the last exposure into frame `frame_index` at `t_s`: lens
    /// distortion, then `gain` (auto-exposure; `None` leaves it out), then
    /// the sensor model. `out` is resized in place.
    pub fn develop(&mut self, gain: Option<f32>, frame_index: u64, t_s: f64, out: &mut ImageU8) {
        self.warp.warp_gray(&self.accum, &mut self.warped);
        if let Some(gain) = gain {
            self.warped.data_mut().iter_mut().for_each(|g| *g *= gain);
        }
        self.sensor.apply(&self.warped, frame_index, t_s, out);
    }

    /// The ideal depth of the mesh at `world_from_camera`, through the lens
    /// distortion (nearest pixel). Reuses the last exposure's render when
    /// it was a single instant at that pose (`reuse_last`); returns the
    /// number of renders made (0 or 1).
    pub fn depth(
        &mut self,
        world_from_camera: &Pose,
        reuse_last: bool,
        out: &mut ImageF32,
    ) -> Result<usize, RenderError> {
        let single_instant = self.offsets_s.len() == 1 && self.offsets_s[0] == 0.0;
        let renders = if reuse_last && single_instant {
            0
        } else {
            self.renderer
                .render(world_from_camera, &self.render_camera, &mut self.view)?;
            1
        };
        self.warp.warp_depth(&self.view.depth_m, out);
        Ok(renders)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::preset::Preset;
    use crate::synth::sequence::preset_scene;

    #[test]
    fn a_realistic_frame_has_texture_and_is_seeded() {
        let preset = Preset::by_name("realistic").expect("preset");
        let scene = preset_scene(&preset, 1);
        let camera = PinholeCamera {
            distortion: preset.camera.distortion,
            ..PinholeCamera::new(160, 128, 105.0, 105.0, 79.5, 63.5)
        };
        let mesh = Arc::new(scene.truth);
        let make = |seed| {
            SyntheticCamera::new(mesh.clone(), &camera, preset.photometric, preset.blur, seed)
                .expect("camera")
        };
        let pose = Pose::from_parts(
            nalgebra::Translation3::new(4.0, 3.0, 1.2),
            crate::geometry::look::camera_rotation(0.3, 0.0, 0.0),
        );
        let mut frames = Vec::new();
        for seed in [1, 1, 2] {
            let mut cam = make(seed);
            let renders = cam.expose(|_| pose, 0.0, |_, _, _| {}).expect("render");
            assert_eq!(renders, 1, "a still camera needs one render");
            let mut out = ImageU8::new(0, 0, 0);
            cam.develop(None, 7, 0.0, &mut out);
            assert_eq!((out.width(), out.height()), (160, 128));
            frames.push(out);
        }
        assert_eq!(frames[0], frames[1], "same seed, same frame");
        assert_ne!(frames[0], frames[2], "the noise follows the seed");
        let mut seen = [false; 256];
        frames[0]
            .data()
            .iter()
            .for_each(|&v| seen[v as usize] = true);
        assert!(seen.iter().filter(|&&s| s).count() > 64);
    }
}
