//! Normalized cross-correlation between a keyframe's points and a frame
//! aligned to it: the figure that tells a right pose from a wrong one on a
//! look-alike surface. The tracker's lost test and relocalization's
//! acceptance gate both use it.
//!
//! Takes a prepared [`Keyframe`], the frame's [`Pyramid`], the camera and
//! the aligned `camera_from_keyframe` pose; gives the zero-mean normalized
//! cross-correlation at one pyramid level ([`correlation`]), that figure
//! with its version trimmed of the points an occluder covers
//! ([`correlations`]), the correlation of local contrast (intensity over
//! the local mean, trimmed the same way), and the smallest of each over
//! levels 0, 1 and 2 ([`min_correlations`]), or over three levels from a
//! coarser one ([`min_correlations_from`]). Allocates nothing: the
//! per-frame check of tracking ([`plain_and_local`]) projects the points
//! once into a buffer its caller reserved, and refits from there.

use nalgebra::Vector3;

use crate::geometry::{PinholeCamera, Pose};

use super::{Keyframe, KeyframeLevel, Pyramid};

/// The smallest [`correlations`] over pyramid levels 0, 1 and 2 (each
/// figure on its own); `None` when level 0 or 1 cannot be evaluated.
pub fn min_correlations(
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    camera_from_keyframe: &Pose,
) -> Option<Correlations> {
    min_correlations_from(keyframe, frame, camera, camera_from_keyframe, 0)
}

/// [`min_correlations`] over the three levels from `first` (the keyframe's
/// [`Keyframe::gate_level`] to read only the levels the map holds); `None`
/// when the first two cannot be evaluated.
pub fn min_correlations_from(
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    camera_from_keyframe: &Pose,
    first: usize,
) -> Option<Correlations> {
    min_correlations_and_coarser_local(keyframe, frame, camera, camera_from_keyframe, first)
        .map(|(c, _)| c)
}

/// [`min_correlations_from`], and the smallest local-contrast correlation
/// over its levels after `first` alone (`NaN` where neither holds one: a
/// level too near the pyramid's top has no local contrast, and the
/// minimum skips it as `f32::min` does): for a gate that holds the first
/// level to a floor of its own.
pub fn min_correlations_and_coarser_local(
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    camera_from_keyframe: &Pose,
    first: usize,
) -> Option<(Correlations, f32)> {
    let mut out: Option<Correlations> = None;
    let mut coarser_local = f32::NAN;
    for level in first..first + 3 {
        match correlations(keyframe, frame, camera, camera_from_keyframe, level) {
            Some(c) => {
                if level > first {
                    coarser_local = coarser_local.min(c.local);
                }
                out = Some(out.map_or(c, |o| Correlations {
                    all: o.all.min(c.all),
                    trimmed: o.trimmed.min(c.trimmed),
                    kept: o.kept.min(c.kept),
                    local: o.local.min(c.local),
                    local_kept: o.local_kept.min(c.local_kept),
                }));
            }
            None if level < first + 2 => return None,
            None => {}
        }
    }
    out.map(|c| (c, coarser_local))
}

/// Zero-mean normalized cross-correlation between the keyframe points of
/// pyramid level `level` and the frame intensities where they project at
/// `camera_from_keyframe`; `None` with fewer than 50 visible points. A wrong
/// pose on a look-alike surface can fit an affine photometric model with
/// small residuals; it does not correlate.
pub fn correlation(
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    camera_from_keyframe: &Pose,
    level: usize,
) -> Option<f32> {
    let (kl, cam) = level_of(keyframe, frame, camera, level)?;
    let pairs = samples(kl, frame, &cam, level, camera_from_keyframe, None).map(|s| s.gray);
    fit(pairs, None).map(|f| f.ncc)
}

/// The keyframe's points of `level` and the camera scaled to it; `None`
/// when the keyframe or the frame lacks the level.
fn level_of<'k>(
    keyframe: &'k Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    level: usize,
) -> Option<(&'k KeyframeLevel, PinholeCamera)> {
    let kl = keyframe.levels.get(level)?;
    (level < frame.len()).then(|| (kl, camera.scaled_to_level(level as u32)))
}

/// What [`correlations`] measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correlations {
    /// Over every visible point ([`correlation`]).
    pub all: f32,
    /// Over the points that fit the affine intensity relation (trimmed
    /// four times at 2.5 standard deviations of the refitted relation; an
    /// object over a third of the view needs three or four): what is left when an
    /// object that is not in the map covers part of the view. A wrong pose
    /// on a low-contrast look-alike fits every point loosely and stays low.
    pub trimmed: f32,
    /// Fraction of the visible points the trimming kept.
    pub kept: f32,
    /// The trimmed correlation of local contrast (each intensity divided by
    /// the mean around it, two pyramid levels up): blind to shading that
    /// varies smoothly across the view, such as a lamp's falloff on a map
    /// whose colors were baked under other light. `NaN` where the pyramid
    /// has no coarser level to take the mean from.
    pub local: f32,
    /// Fraction of the visible points the local-contrast trimming kept.
    pub local_kept: f32,
}

/// [`correlation`] together with its trimmed version.
pub fn correlations(
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    camera_from_keyframe: &Pose,
    level: usize,
) -> Option<Correlations> {
    let (kl, cam) = level_of(keyframe, frame, camera, level)?;
    let contrast = contrast_of(keyframe, frame, level);
    let source = || samples(kl, frame, &cam, level, camera_from_keyframe, contrast);
    fit_all(source, true)
}

/// [`Correlations::all`] and [`Correlations::local`] alone (`local` is
/// `NaN` where the pyramid has no coarser level for the local mean), from
/// one projection of the keyframe points into `scratch` (its capacity
/// reserved up front: no allocation once it holds a level's points): the
/// per-frame check of tracking, which skips the trimming of the intensity
/// correlation.
pub fn plain_and_local(
    keyframe: &Keyframe,
    frame: &Pyramid,
    camera: &PinholeCamera,
    camera_from_keyframe: &Pose,
    level: usize,
    scratch: &mut Vec<Sample>,
) -> Option<(f32, f32)> {
    let (kl, cam) = level_of(keyframe, frame, camera, level)?;
    let contrast = contrast_of(keyframe, frame, level);
    scratch.clear();
    scratch.extend(samples(
        kl,
        frame,
        &cam,
        level,
        camera_from_keyframe,
        contrast,
    ));
    fit_all(|| scratch.iter().copied(), false).map(|c| (c.all, c.local))
}

/// One keyframe point where the frame sees it: the rendered and the
/// observed intensity, and their local contrast (`NaN` where it cannot be
/// read). The per-frame check keeps a level's worth of them.
#[derive(Debug, Clone, Copy)]
pub struct Sample {
    gray: [f32; 2],
    local: [f32; 2],
}

/// The local-contrast settings of `level`: the mean two levels up, or the
/// coarsest level both pyramids have; `None` when there is none coarser.
fn contrast_of<'k>(keyframe: &'k Keyframe, frame: &Pyramid, level: usize) -> Option<Contrast<'k>> {
    let coarse = (level + 2).min(
        frame
            .len()
            .min(keyframe.gray_pyramid().len())
            .saturating_sub(1),
    );
    (coarse > level).then(|| Contrast {
        keyframe: keyframe.gray_pyramid(),
        coarse,
    })
}

/// The [`Correlations`] of the samples `source` yields (called once per
/// pass); without `intensity_trim`, `trimmed` and `kept` are those of the
/// untrimmed pass. `None` when the intensities cannot be fitted (fewer
/// than 50 points, or no variance); `local` is `NaN` where local contrast
/// cannot.
fn fit_all<I: Iterator<Item = Sample>>(
    source: impl Fn() -> I,
    intensity_trim: bool,
) -> Option<Correlations> {
    let gray = || source().map(|s| s.gray);
    let local = || source().map(|s| s.local).filter(|l| !l[0].is_nan());
    let all = fit(gray(), None)?;
    let trimmed = if intensity_trim { trim(gray, all) } else { all };
    let (local, local_kept) = fit(local(), None)
        .map(|first| {
            let t = trim(local, first);
            (t.ncc, t.n as f32 / all.n.max(1) as f32)
        })
        .unwrap_or((f32::NAN, f32::NAN));
    Some(Correlations {
        all: all.ncc,
        trimmed: trimmed.ncc,
        kept: trimmed.n as f32 / all.n.max(1) as f32,
        local,
        local_kept,
    })
}

/// `first` refitted four times over the pairs within 2.5 standard
/// deviations of the previous fit (fewer when a fit runs short of points).
fn trim<I: Iterator<Item = [f32; 2]>>(pairs: impl Fn() -> I, first: NccFit) -> NccFit {
    let mut trimmed = first;
    for _ in 0..4 {
        let limit = (trimmed.slope, trimmed.offset, 2.5 * trimmed.sigma);
        match fit(pairs(), Some(limit)) {
            Some(t) => trimmed = t,
            None => break,
        }
    }
    trimmed
}

/// Local contrast instead of intensity: each intensity divided by the
/// mean around it, read from pyramid level `coarse` of the keyframe's
/// render and of the frame.
#[derive(Clone, Copy)]
struct Contrast<'a> {
    keyframe: &'a Pyramid,
    coarse: usize,
}

/// The pixel of level `coarse` under pixel `(x, y)` of level `level`
/// (pixel centers at integers).
fn to_coarse(x: f64, y: f64, level: usize, coarse: usize) -> (f32, f32) {
    let s = 0.5f64.powi((coarse - level) as i32);
    (((x + 0.5) * s - 0.5) as f32, ((y + 0.5) * s - 0.5) as f32)
}

/// One correlation pass and the affine fit `frame = slope * keyframe + offset`.
#[derive(Debug, Clone, Copy)]
struct NccFit {
    n: usize,
    ncc: f32,
    slope: f64,
    offset: f64,
    /// Standard deviation of the fit's residual, gray levels.
    sigma: f64,
}

/// The visible points of `kl` at `camera_from_keyframe`, with their local
/// contrast when `contrast` is given.
fn samples<'a>(
    kl: &'a KeyframeLevel,
    frame: &'a Pyramid,
    cam: &'a PinholeCamera,
    level: usize,
    camera_from_keyframe: &'a Pose,
    contrast: Option<Contrast<'a>>,
) -> impl Iterator<Item = Sample> + 'a {
    let image = frame.level(level);
    kl.points.iter().filter_map(move |kp| {
        let p = Vector3::new(
            kp.p_keyframe[0] as f64,
            kp.p_keyframe[1] as f64,
            kp.p_keyframe[2] as f64,
        );
        let uv = cam.project(&(camera_from_keyframe * nalgebra::Point3::from(p)).coords)?;
        let v = image.bilinear(uv.x as f32, uv.y as f32)?;
        let local = contrast
            .and_then(|c| {
                let (fx, fy) = to_coarse(uv.x, uv.y, level, c.coarse);
                let uv_k = kl.camera.project(&p)?;
                let (kx, ky) = to_coarse(uv_k.x, uv_k.y, level, c.coarse);
                let mf = frame.level(c.coarse).bilinear(fx, fy)?;
                let mk = c.keyframe.level(c.coarse).bilinear(kx, ky)?;
                (mf >= 4.0 && mk >= 4.0).then(|| {
                    [
                        (kp.gray as f64 / mk as f64 - 1.0) as f32,
                        (v as f64 / mf as f64 - 1.0) as f32,
                    ]
                })
            })
            .unwrap_or([f32::NAN; 2]);
        Some(Sample {
            gray: [kp.gray, v],
            local,
        })
    })
}

/// Correlation of the pairs `(keyframe, frame)`, only those within
/// `limit.2` of the fit `(slope, offset) = (limit.0, limit.1)` when given;
/// `None` with fewer than 50 pairs or no variance.
fn fit(pairs: impl Iterator<Item = [f32; 2]>, limit: Option<(f64, f64, f64)>) -> Option<NccFit> {
    let (mut n, mut sa, mut sb, mut saa, mut sbb, mut sab) = (0usize, 0f64, 0f64, 0f64, 0f64, 0f64);
    for [a, b] in pairs {
        let (a, b) = (a as f64, b as f64);
        if let Some((slope, offset, max)) = limit {
            if (b - (slope * a + offset)).abs() > max {
                continue;
            }
        }
        n += 1;
        sa += a;
        sb += b;
        saa += a * a;
        sbb += b * b;
        sab += a * b;
    }
    if n < 50 {
        return None;
    }
    let nf = n as f64;
    let cov = sab - sa * sb / nf;
    let va = saa - sa * sa / nf;
    let vb = sbb - sb * sb / nf;
    if !(va > 0.0 && vb > 0.0) {
        return None;
    }
    let slope = cov / va;
    Some(NccFit {
        n,
        ncc: (cov / (va * vb).sqrt()) as f32,
        slope,
        offset: (sb - slope * sa) / nf,
        sigma: ((vb - slope * cov) / nf).max(1e-6).sqrt(),
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::imgproc::ImageF32;
    use crate::render::RenderedView;
    use crate::track::TrackerConfig;

    fn texture(x: usize, y: usize, phase: f32) -> f32 {
        128.0 + 50.0 * ((x as f32 * 0.31 + phase).sin() + (y as f32 * 0.23 - phase).cos())
    }

    /// A keyframe of a textured fronto-parallel plane, and a frame of the
    /// same view with `edit` applied to its pixels.
    fn setup(edit: impl Fn(usize, usize, f32) -> f32) -> (Keyframe, Pyramid, PinholeCamera) {
        setup_textured(|x, y| texture(x, y, 0.0), edit)
    }

    /// [`setup`] with the plane's texture `tex`.
    fn setup_textured(
        tex: impl Fn(usize, usize) -> f32,
        edit: impl Fn(usize, usize, f32) -> f32,
    ) -> (Keyframe, Pyramid, PinholeCamera) {
        setup_detail(tex, edit, 0.0)
    }

    /// [`setup_textured`] from a map whose appearance is sampled every
    /// `detail_m` meters (the plane is 2 m away, 120 px focal length:
    /// 16.7 mm pixels at level 0).
    pub(crate) fn setup_detail(
        tex: impl Fn(usize, usize) -> f32,
        edit: impl Fn(usize, usize, f32) -> f32,
        detail_m: f32,
    ) -> (Keyframe, Pyramid, PinholeCamera) {
        let camera = PinholeCamera::new(160, 128, 120.0, 120.0, 79.5, 63.5);
        let config = TrackerConfig {
            pyramid_levels: 3,
            ..TrackerConfig::default()
        };
        let mut view = RenderedView::for_camera(&camera);
        let mut frame = ImageF32::new(160, 128, 0.0);
        for y in 0..128 {
            for x in 0..160 {
                let v = tex(x, y);
                view.gray.row_mut(y)[x] = v;
                frame.row_mut(y)[x] = edit(x, y, v);
            }
        }
        view.depth_m = ImageF32::new(160, 128, 2.0);
        view.detail_m = detail_m;
        let mut keyframe = Keyframe::new(&camera, &config);
        keyframe.prepare(&view, Pose::identity(), 1, &config);
        let mut pyramid = Pyramid::new(160, 128, 3);
        pyramid.fill_from_f32(&frame);
        (keyframe, pyramid, camera)
    }

    #[test]
    fn local_contrast_sees_through_shading_but_not_a_wrong_view() {
        // A lamp's falloff across the view: the frame is three times as
        // bright on the right as on the left, plus an exposure offset.
        let shade = |x: usize, y: usize| 0.5 + 1.0 * (x as f32 / 160.0) + 0.3 * (y as f32 / 128.0);
        let (kf, frame, camera) = setup(|x, y, v| shade(x, y) * v + 5.0);
        let c = min_correlations(&kf, &frame, &camera, &Pose::identity()).expect("shaded");
        assert!(c.local > 0.95, "{c:?}");
        assert!(c.trimmed < c.local, "{c:?}");
        // The same shading over another texture does not correlate.
        let (kf, frame, camera) = setup(|x, y, _| shade(x, y) * texture(x, y, 1.7));
        let c = min_correlations(&kf, &frame, &camera, &Pose::identity()).expect("other");
        assert!(c.local < 0.6, "{c:?}");
        // An object over the left fifth is trimmed away as before.
        let (kf, frame, camera) = setup(|x, y, v| {
            if x < 32 {
                texture(y, x, 2.9)
            } else {
                0.8 * v + 10.0
            }
        });
        let c = min_correlations(&kf, &frame, &camera, &Pose::identity()).expect("occluded");
        assert!(c.local > 0.9, "{c:?}");
    }

    #[test]
    fn trimming_sees_through_an_occluder_but_not_a_wrong_view() {
        // A gain change and an object with its own texture over the left
        // third.
        let (kf, frame, camera) = setup(|x, y, v| {
            if x < 53 {
                texture(y, x, 2.9)
            } else {
                0.8 * v + 10.0
            }
        });
        let c = correlations(&kf, &frame, &camera, &Pose::identity(), 0).expect("occluded");
        assert!(c.all < 0.8, "{c:?}");
        assert!(c.trimmed > 0.95, "{c:?}");
        assert!((0.5..0.8).contains(&c.kept), "{c:?}");
        assert_eq!(
            correlation(&kf, &frame, &camera, &Pose::identity(), 0),
            Some(c.all)
        );
        // Another texture altogether: trimming does not make it correlate.
        let (kf, frame, camera) = setup(|x, y, _| texture(x, y, 1.7));
        let c = correlations(&kf, &frame, &camera, &Pose::identity(), 0).expect("other");
        assert!(c.trimmed < 0.6, "{c:?}");
        // The same view: both near 1, nothing trimmed away to speak of.
        let (kf, frame, camera) = setup(|_, _, v| v);
        let c = min_correlations(&kf, &frame, &camera, &Pose::identity()).expect("same");
        assert!(c.all > 0.99 && c.trimmed > 0.99 && c.kept > 0.95, "{c:?}");
    }

    #[test]
    fn local_contrast_sees_a_slide_that_intensity_does_not() {
        // Strong coarse shading (period ~40 px) over a fine grain (~4.5 px),
        // as a floor's planks over the wood's grain; the frame is the same
        // view slid 2 pixels. The coarse part dominates the intensity
        // variance and barely moves; the grain is out of phase.
        let tex = |x: usize, y: usize| {
            let (x, y) = (x as f32, y as f32);
            128.0
                + 60.0 * (x * 0.157).sin() * (y * 0.05).cos()
                + 15.0 * (x * 1.4).sin() * (y * 1.3).sin()
        };
        let (kf, frame, camera) = setup_textured(tex, |x, y, _| tex(x + 2, y));
        let plain = correlations(&kf, &frame, &camera, &Pose::identity(), 1).expect("level 1");
        let local = min_correlations(&kf, &frame, &camera, &Pose::identity()).expect("slid");
        assert!(plain.all > 0.6, "{plain:?}");
        assert!(local.local < 0.3, "{local:?}");
        // In place, both agree that it fits.
        let (kf, frame, camera) = setup_textured(tex, |_, _, v| v);
        let c = min_correlations(&kf, &frame, &camera, &Pose::identity()).expect("in place");
        assert!(c.local > 0.95 && c.all > 0.95, "{c:?}");
    }

    #[test]
    fn a_coarse_map_is_checked_at_the_levels_it_holds() {
        // The camera sees a fine grain (period 2.5 px) over the coarse
        // pattern; the map kept only the coarse pattern, as a scan fused at
        // voxels coarser than the camera's pixels does.
        let coarse = |x: usize, y: usize| {
            let (x, y) = (x as f32, y as f32);
            128.0 + 50.0 * (x * 0.3).sin() * (y * 0.23).cos()
        };
        let grain = |x: usize, y: usize| 30.0 * ((x as f32) * 2.5).sin() * ((y as f32) * 2.3).sin();
        let seen = |x: usize, y: usize, v: f32| v + grain(x, y);
        // Told nothing of the map's detail, the gate reads level 0, where
        // the grain the map lacks decides.
        let (kf, frame, camera) = setup_detail(coarse, seen, 0.0);
        assert_eq!(kf.gate_level, 0);
        let fine = min_correlations_from(&kf, &frame, &camera, &Pose::identity(), kf.gate_level)
            .expect("level 0");
        // A map sampled every 5 cm: level 0's 16.7 mm pixels are finer than
        // half of that, level 1's 33 mm are not.
        let (kf, frame, camera) = setup_detail(coarse, seen, 0.05);
        assert_eq!(kf.gate_level, 1);
        let held = min_correlations_from(&kf, &frame, &camera, &Pose::identity(), kf.gate_level)
            .expect("level 1");
        assert!(held.local > 0.9, "{held:?}");
        assert!(fine.local < held.local - 0.2, "{fine:?} {held:?}");
        // A wrong view of the same coarse map still fails there.
        let (kf, frame, camera) =
            setup_detail(coarse, |x, y, _| coarse(x + 9, y + 7) + grain(x, y), 0.05);
        let wrong = min_correlations_from(&kf, &frame, &camera, &Pose::identity(), kf.gate_level)
            .expect("wrong");
        assert!(wrong.local < 0.5, "{wrong:?}");
    }
}
