//! Lens distortion of synthetic frames.
//!
//! Renderers draw ideal pinhole views. To store frames that carry the
//! distortion of `camera.toml`, each stored (distorted) pixel `(u, v)` is
//! traced back: `x_d = ((u - cx) / fx, (v - cy) / fy)`, `x_n =
//! undistort(x_d)`, and sampled bilinearly from a pinhole render at
//! `(fx x_n + cx', fy x_n + cy')`. That render uses the same focal lengths but
//! is enlarged (`cx' = cx + pad_left`, ...) so every traced pixel lands
//! inside it: barrel distortion shows more of the scene than the pinhole
//! image of the same size. The map is built once; applying it allocates
//! nothing.

use nalgebra::Vector2;

use crate::geometry::PinholeCamera;
use crate::imgproc::ImageF32;

/// Errors building a distortion warp.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DistortionError {
    /// A pixel's distortion cannot be inverted (coefficients too strong for
    /// the field of view).
    #[error("distortion of pixel ({u}, {v}) cannot be inverted; coefficients too strong for the image size")]
    NotInvertible {
        /// Pixel column.
        u: u32,
        /// Pixel row.
        v: u32,
    },
    /// The pinhole render needed to cover the distorted image is too large.
    #[error("distortion needs a {width}x{height} pinhole render (more than twice the image size)")]
    RenderTooLarge {
        /// Needed width.
        width: u32,
        /// Needed height.
        height: u32,
    },
}

/// The resampling from an enlarged pinhole render to the distorted image.
#[derive(Debug, Clone)]
pub struct DistortionWarp {
    camera: PinholeCamera,
    render_camera: PinholeCamera,
    /// Per stored pixel, the source position in the render, row-major.
    src_xy: Vec<[f32; 2]>,
}

impl DistortionWarp {
    /// Builds the warp for `camera` (with its distortion). Without
    /// distortion the render camera is `camera` itself and the warp is a copy.
    pub fn new(camera: &PinholeCamera) -> Result<Self, DistortionError> {
        let (w, h) = (camera.width, camera.height);
        let mut src = Vec::with_capacity(w as usize * h as usize);
        let (mut min, mut max) = (
            Vector2::new(0.0f64, 0.0),
            Vector2::new(w as f64 - 1.0, h as f64 - 1.0),
        );
        for v in 0..h {
            for u in 0..w {
                let xd = Vector2::new(
                    (u as f64 - camera.cx) / camera.fx,
                    (v as f64 - camera.cy) / camera.fy,
                );
                let xn = camera
                    .distortion
                    .undistort(xd)
                    .ok_or(DistortionError::NotInvertible { u, v })?;
                let p = Vector2::new(camera.fx * xn.x + camera.cx, camera.fy * xn.y + camera.cy);
                min = min.inf(&p);
                max = max.sup(&p);
                src.push(p);
            }
        }
        // One pixel of margin keeps all four bilinear neighbours inside.
        let pad_left = (-min.x).max(0.0).ceil() + if min.x < 0.0 { 1.0 } else { 0.0 };
        let pad_top = (-min.y).max(0.0).ceil() + if min.y < 0.0 { 1.0 } else { 0.0 };
        let pad_right = (max.x - (w as f64 - 1.0)).max(0.0).ceil()
            + if max.x > w as f64 - 1.0 { 1.0 } else { 0.0 };
        let pad_bottom = (max.y - (h as f64 - 1.0)).max(0.0).ceil()
            + if max.y > h as f64 - 1.0 { 1.0 } else { 0.0 };
        let render_w = w as f64 + pad_left + pad_right;
        let render_h = h as f64 + pad_top + pad_bottom;
        if render_w > 2.0 * w as f64 || render_h > 2.0 * h as f64 {
            return Err(DistortionError::RenderTooLarge {
                width: render_w as u32,
                height: render_h as u32,
            });
        }
        let render_camera = PinholeCamera {
            width: render_w as u32,
            height: render_h as u32,
            cx: camera.cx + pad_left,
            cy: camera.cy + pad_top,
            ..camera.pinhole()
        };
        let src_xy = src
            .iter()
            .map(|p| [(p.x + pad_left) as f32, (p.y + pad_top) as f32])
            .collect();
        Ok(Self {
            camera: *camera,
            render_camera,
            src_xy,
        })
    }

    /// The pinhole camera to render with (enlarged when there is distortion).
    pub fn render_camera(&self) -> &PinholeCamera {
        &self.render_camera
    }

    /// True when the camera has no distortion (the warp is a plain copy).
    pub fn is_identity(&self) -> bool {
        self.camera.distortion.is_zero()
    }

    /// Resamples a render (`render_camera`-sized) into the distorted image
    /// `out` (camera-sized, resized in place), bilinearly.
    pub fn warp_gray(&self, render: &ImageF32, out: &mut ImageF32) {
        out.resize(self.camera.width as usize, self.camera.height as usize, 0.0);
        if self.is_identity() {
            out.data_mut().copy_from_slice(render.data());
            return;
        }
        for (o, s) in out.data_mut().iter_mut().zip(&self.src_xy) {
            *o = render.bilinear(s[0], s[1]).unwrap_or(0.0);
        }
    }

    /// Resamples a depth render into `out` with the nearest pixel (depth is
    /// never blended across edges).
    pub fn warp_depth(&self, render_depth_m: &ImageF32, out: &mut ImageF32) {
        out.resize(self.camera.width as usize, self.camera.height as usize, 0.0);
        if self.is_identity() {
            out.data_mut().copy_from_slice(render_depth_m.data());
            return;
        }
        for (o, s) in out.data_mut().iter_mut().zip(&self.src_xy) {
            *o = render_depth_m
                .get(s[0].round() as usize, s[1].round() as usize)
                .unwrap_or(0.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Distortion;
    use nalgebra::Vector3;

    fn camera() -> PinholeCamera {
        PinholeCamera {
            distortion: Distortion {
                k1: -0.12,
                k2: 0.03,
                p1: 0.0005,
                p2: -0.0003,
                k3: 0.0,
            },
            ..PinholeCamera::new(160, 128, 105.0, 105.0, 79.5, 63.5)
        }
    }

    /// A "render" whose gray value encodes the ray direction: the pinhole
    /// render of a world where intensity = 100 + 50 x_n + 30 y_n.
    fn ray_render(cam: &PinholeCamera) -> ImageF32 {
        let mut img = ImageF32::new(cam.width as usize, cam.height as usize, 0.0);
        for y in 0..cam.height as usize {
            for (x, v) in img.row_mut(y).iter_mut().enumerate() {
                let xn = (x as f64 - cam.cx) / cam.fx;
                let yn = (y as f64 - cam.cy) / cam.fy;
                *v = (100.0 + 50.0 * xn + 30.0 * yn) as f32;
            }
        }
        img
    }

    #[test]
    fn warped_pixels_see_the_ray_the_distorted_camera_projects() {
        let cam = camera();
        let warp = DistortionWarp::new(&cam).expect("invertible");
        let rc = *warp.render_camera();
        assert!(
            rc.width > cam.width && rc.height > cam.height,
            "barrel distortion needs a larger render"
        );
        let mut out = ImageF32::new(1, 1, 0.0);
        warp.warp_gray(&ray_render(&rc), &mut out);
        // A 3D point projects with the distorted model to (u, v); the stored
        // pixel there must show that point's ray.
        for p in [
            Vector3::new(0.5, -0.4, 1.0),
            Vector3::new(-0.7, 0.55, 1.0),
            Vector3::new(0.0, 0.0, 1.0),
        ] {
            let uv = cam.project(&p).expect("in front");
            let (u, v) = (uv.x.round(), uv.y.round());
            let xn = cam.unproject(Vector2::new(u, v), 1.0).expect("inverts");
            let expect = 100.0 + 50.0 * xn.x + 30.0 * xn.y;
            let got = out.get(u as usize, v as usize).expect("inside") as f64;
            assert!((got - expect).abs() < 0.05, "{p:?}: {got} vs {expect}");
        }
        assert!(
            out.data().iter().all(|&v| v > 0.0),
            "no pixel falls outside the render"
        );
    }

    #[test]
    fn no_distortion_is_a_copy() {
        let cam = camera().pinhole();
        let warp = DistortionWarp::new(&cam).expect("ok");
        assert_eq!(*warp.render_camera(), cam);
        let img = ray_render(&cam);
        let mut out = ImageF32::new(1, 1, 0.0);
        warp.warp_gray(&img, &mut out);
        assert_eq!(out, img);
        warp.warp_depth(&img, &mut out);
        assert_eq!(out, img);
    }

    #[test]
    fn absurd_distortion_is_an_error() {
        let mut cam = camera();
        cam.distortion.k1 = -2.0;
        assert!(DistortionWarp::new(&cam).is_err());
    }
}
