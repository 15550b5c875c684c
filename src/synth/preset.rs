//! Named presets of synthetic sequences, with every parameter exact and
//! printable (`star synth --list-presets`).
//!
//! - `ideal`: the slow loop, images drawn from the map mesh itself (no
//!   holes, no occluders), no lens distortion, no photometric corruption,
//!   no blur: what the tracker sees matches its rendered keyframes exactly
//!   up to quantization;
//! - `realistic`: the slow loop rendered from the truth mesh (3 occluders
//!   absent from the map), map with 10 % of its room-surface patches
//!   removed, gain drift +-30 %, bias drift +-10 levels, vignetting 30 %,
//!   noise sigma 3, lens distortion, 5 ms exposure motion blur;
//! - `aggressive`: the aggressive trajectory (about 1.5 m/s, up to
//!   200 deg/s) with the realistic corruptions;
//! - `scanned`: `realistic` with a map rebuilt by TSDF fusion of a noisy
//!   scanning run (Open3D, 1 cm voxels: blurred vertex colors, the scan's
//!   light baked in, holes where the scan did not look, a small
//!   registration error, stored in the scanner's frame), and flight images
//!   under a different, moving light with auto-exposure steps (see
//!   [`super::scanned`]). Any preset gets the same treatment with
//!   [`Preset::scanned`] (`star synth --scanned`).
//!
//! - `building`: a floor of 22 rooms of varied size on both sides of a
//!   corridor, joined to it by doorways, with look-alike rooms on purpose
//!   (6 room designs, 4 texture sets; about 900 m² and 5.5 M map
//!   triangles, see [`super::scene::building`]), flown room to room
//!   through the doors (`room_to_room`, 0.5 m/s, looking along the
//!   direction of travel) with the realistic corruptions; occluders in
//!   every other room design, no map holes. `star synth --rooms N` builds
//!   a floor of N rooms instead.
//!
//! All: 640x512, fx = fy = 420 px (74.6 x 62.7 degrees field of view),
//! principal point at the image center, 50 Hz; all but `building` an
//! 8 x 6 x 3 m room with 6 furniture boxes.

use serde::Serialize;

use super::corrupt::{BlurSpec, PhotometricSpec};
use super::scanned::ScannedSpec;
use super::scene::building::BuildingSpec;
use super::trajectory::{MotionSpec, TrajectoryKind};
use crate::geometry::{Distortion, PinholeCamera};

/// Which of the scene's meshes draws the camera images.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ImageSource {
    /// The map mesh (the one written to `map/`).
    Map,
    /// The truth mesh: no holes, with occluders.
    Truth,
}

/// The scene part of a preset (the seed comes from the command line).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ScenePreset {
    /// Room size `[x, y, z]`, m (the one room; unused with `building`).
    pub room_size_m: [f64; 3],
    /// Furniture boxes (in map and truth).
    pub furniture_boxes: usize,
    /// Occluder boxes (truth only).
    pub occluders: usize,
    /// Fraction of room-surface patches removed from the map.
    pub map_hole_fraction: f64,
    /// Texture resolution, texels per meter.
    pub texture_px_per_m: f64,
    /// Seed of the textures, when not the sequence's: a look-alike room
    /// (`star synth --texture-seed`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub texture_seed: Option<u64>,
    /// A building floor instead of the one room: its own rooms, furniture
    /// and occluders replace the fields above (but the texture seed).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub building: Option<BuildingSpec>,
}

/// A complete, exact description of a synthetic sequence.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Preset {
    /// Name on the command line.
    pub name: &'static str,
    /// One-line description.
    pub description: &'static str,
    /// Frame rate, Hz.
    pub rate_hz: f64,
    /// Camera of the stored images (with distortion), as in `camera.toml`.
    pub camera: PinholeCamera,
    /// 16-bit depth PNG units per meter.
    pub depth_scale: f64,
    /// Which mesh draws the images.
    pub images_from: ImageSource,
    /// The scene.
    pub scene: ScenePreset,
    /// Trajectory kind.
    pub trajectory: TrajectoryKind,
    /// The trajectory kind's exact motion parameters.
    pub motion: MotionSpec,
    /// Photometric corruption.
    pub photometric: PhotometricSpec,
    /// Motion blur; `None` renders one instant per frame.
    pub blur: Option<BlurSpec>,
    /// The scanned variant: the map comes from TSDF fusion of a scanning
    /// run and the flight has its own light and auto-exposure; `None` for
    /// the closed-world presets.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scanned: Option<ScannedSpec>,
}

/// TSDF voxel of a scanned building, meters: coarser than one room's 1 cm,
/// since a whole floor is fused into one map (at 3 cm the vertex colors are
/// too blurred for the tracker's correlation gates: docs/building-scale.md).
pub const BUILDING_SCAN_VOXEL_M: f64 = 0.02;

/// Rotation of a scanned building's registration error, degrees: a map
/// registered to the floor plan is off by about the one room's centimeters
/// everywhere (0.03 degrees is 1.8 cm at 34 m, the 68 m floor's half
/// length), not by 0.3 degrees, which would put its far end 18 cm off.
pub const BUILDING_REGISTRATION_ERROR_DEG: f64 = 0.03;

/// Names of all presets, in `--list-presets` order.
pub const PRESET_NAMES: [&str; 5] = ["ideal", "realistic", "aggressive", "scanned", "building"];

fn camera(distortion: Distortion) -> PinholeCamera {
    PinholeCamera {
        distortion,
        ..PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5)
    }
}

const REALISTIC_DISTORTION: Distortion = Distortion {
    k1: -0.10,
    k2: 0.02,
    p1: 3e-4,
    p2: -2e-4,
    k3: 0.0,
};

const REALISTIC_PHOTOMETRIC: PhotometricSpec = PhotometricSpec {
    gain_drift: 0.3,
    bias_drift: 10.0,
    drift_period_s: (8.0, 25.0),
    vignetting: 0.3,
    noise_sigma: 3.0,
};

const REALISTIC_BLUR: BlurSpec = BlurSpec {
    exposure_s: 0.005,
    px_per_subframe: 1.5,
    max_subframes: 8,
    typical_depth_m: 2.5,
};

const SCENE: ScenePreset = ScenePreset {
    room_size_m: [8.0, 6.0, 3.0],
    furniture_boxes: 6,
    occluders: 0,
    map_hole_fraction: 0.0,
    texture_px_per_m: 128.0,
    texture_seed: None,
    building: None,
};

impl Preset {
    /// The preset called `name`, or `None`.
    pub fn by_name(name: &str) -> Option<Preset> {
        let realistic_scene = ScenePreset {
            occluders: 3,
            map_hole_fraction: 0.1,
            ..SCENE
        };
        match name {
            "ideal" => Some(Preset {
                name: "ideal",
                description: "slow loop, images rendered from the map mesh, no corruption",
                rate_hz: 50.0,
                camera: camera(Distortion::default()),
                depth_scale: crate::dataset::TUM_DEPTH_SCALE,
                images_from: ImageSource::Map,
                scene: SCENE,
                trajectory: TrajectoryKind::SlowLoop,
                motion: TrajectoryKind::SlowLoop.spec(),
                photometric: PhotometricSpec::NONE,
                blur: None,
                scanned: None,
            }),
            "realistic" => Some(Preset {
                name: "realistic",
                description: "slow loop; drift, vignetting, noise, distortion, blur, occluders, 10 % map holes",
                rate_hz: 50.0,
                camera: camera(REALISTIC_DISTORTION),
                depth_scale: crate::dataset::TUM_DEPTH_SCALE,
                images_from: ImageSource::Truth,
                scene: realistic_scene,
                trajectory: TrajectoryKind::SlowLoop,
                motion: TrajectoryKind::SlowLoop.spec(),
                photometric: REALISTIC_PHOTOMETRIC,
                blur: Some(REALISTIC_BLUR),
                scanned: None,
            }),
            "aggressive" => Some(Preset {
                name: "aggressive",
                description: "aggressive trajectory (~1.5 m/s, up to 200 deg/s) with the realistic corruptions",
                trajectory: TrajectoryKind::Aggressive,
                motion: TrajectoryKind::Aggressive.spec(),
                ..Preset::by_name("realistic")?
            }),
            "scanned" => Some(Preset {
                name: "scanned",
                description: "realistic, with a TSDF-fused map of a noisy scan (1 cm voxels, baked light, holes, scanner frame) and a moving light with auto-exposure steps in flight",
                ..Preset::by_name("realistic")?.scanned()
            }),
            "building" => Some(Preset {
                name: "building",
                description: "a floor of 22 rooms (look-alikes on purpose) and a corridor, flown room to room through the doors, with the realistic corruptions",
                scene: ScenePreset {
                    occluders: 0,
                    map_hole_fraction: 0.0,
                    building: Some(BuildingSpec::default()),
                    ..SCENE
                },
                trajectory: TrajectoryKind::RoomToRoom,
                motion: TrajectoryKind::RoomToRoom.spec(),
                ..Preset::by_name("realistic")?
            }),
            _ => None,
        }
    }

    /// The scanned variant of this preset: the map is rebuilt from a
    /// scanning run of the scene (holes come from where the scan did not
    /// look, so the scene's patch holes are off) and the flight gets a
    /// moving light and auto-exposure steps. Keeps the name. A building's
    /// scan is fused at [`BUILDING_SCAN_VOXEL_M`].
    pub fn scanned(self) -> Preset {
        let fresh = self.scanned.is_none();
        let mut spec = self.scanned.unwrap_or_default();
        if self.scene.building.is_some() && fresh {
            // A whole floor at 1 cm would be about 70 M triangles
            // (docs/building-scale.md).
            spec.voxel_m = BUILDING_SCAN_VOXEL_M;
            spec.registration_error_deg = BUILDING_REGISTRATION_ERROR_DEG;
        }
        Preset {
            scene: ScenePreset {
                map_hole_fraction: 0.0,
                ..self.scene
            },
            scanned: Some(spec),
            ..self
        }
    }

    /// All presets.
    pub fn all() -> Vec<Preset> {
        PRESET_NAMES
            .iter()
            .filter_map(|n| Preset::by_name(n))
            .collect()
    }

    /// The preset as TOML, for `--list-presets` and the dataset's `synth.toml`.
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# cannot format preset: {e}\n"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_named() {
        for name in PRESET_NAMES {
            let p = Preset::by_name(name).expect("exists");
            assert_eq!(p.name, name);
            p.camera.validate().expect("valid camera");
            assert_eq!((p.camera.width, p.camera.height), (640, 512));
            assert_eq!(p.rate_hz, 50.0);
            assert_eq!(p.motion, p.trajectory.spec());
            let text = p.to_toml();
            assert!(
                text.contains("noise_sigma") && text.contains("[camera.distortion]"),
                "{text}"
            );
        }
        assert!(Preset::by_name("nope").is_none());
    }

    #[test]
    fn ideal_is_clean_and_realistic_is_not() {
        let ideal = Preset::by_name("ideal").expect("exists");
        assert_eq!(ideal.photometric, PhotometricSpec::NONE);
        assert!(ideal.camera.distortion.is_zero() && ideal.blur.is_none());
        assert_eq!(ideal.images_from, ImageSource::Map);
        assert_eq!(
            (ideal.scene.occluders, ideal.scene.map_hole_fraction),
            (0, 0.0)
        );
        let real = Preset::by_name("realistic").expect("exists");
        assert_eq!(real.photometric.gain_drift, 0.3);
        assert_eq!(real.photometric.noise_sigma, 3.0);
        assert_eq!(real.scene.map_hole_fraction, 0.1);
        assert!(real.scene.occluders > 0 && !real.camera.distortion.is_zero());
        let aggr = Preset::by_name("aggressive").expect("exists");
        assert_eq!(aggr.trajectory, TrajectoryKind::Aggressive);
        assert_eq!(aggr.photometric, real.photometric);
        assert_eq!(aggr.motion.max_angular_speed_dps, Some(200.0));
        assert!(ideal.scanned.is_none() && real.scanned.is_none() && aggr.scanned.is_none());
        assert!(ideal.scene.building.is_none() && real.scene.building.is_none());
    }

    #[test]
    fn building_is_realistic_room_to_room() {
        let b = Preset::by_name("building").expect("exists");
        let real = Preset::by_name("realistic").expect("exists");
        assert_eq!(b.trajectory, TrajectoryKind::RoomToRoom);
        assert_eq!(b.photometric, real.photometric);
        assert_eq!(b.camera, real.camera);
        assert_eq!(b.blur, real.blur);
        assert_eq!(b.images_from, ImageSource::Truth);
        let spec = b.scene.building.expect("building");
        spec.validate().expect("valid");
        assert!(spec.rooms >= 20);
        let text = b.to_toml();
        assert!(
            text.contains("[scene.building]") && text.contains("rooms = 22"),
            "{text}"
        );
    }

    #[test]
    fn scanned_is_realistic_with_a_fused_map() {
        let scanned = Preset::by_name("scanned").expect("exists");
        let real = Preset::by_name("realistic").expect("exists");
        let spec = scanned.scanned.as_ref().expect("scanned");
        assert_eq!(spec.voxel_m, 0.01);
        assert_eq!(scanned.photometric, real.photometric);
        assert_eq!(scanned.images_from, ImageSource::Truth);
        assert_eq!(scanned.scene.map_hole_fraction, 0.0);
        assert_eq!(scanned.scene.occluders, real.scene.occluders);
        let text = scanned.to_toml();
        assert!(
            text.contains("[scanned.depth_sensor]") && text.contains("voxel_m"),
            "{text}"
        );
        let aggr = Preset::by_name("aggressive").expect("exists").scanned();
        assert_eq!(aggr.name, "aggressive");
        assert_eq!(aggr.scanned.as_ref(), Some(spec));
    }
}
