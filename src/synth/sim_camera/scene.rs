//! The scene of a `sim:` camera: a `star synth` dataset's room, rebuilt.
//!
//! Owns [`SimScene`]. Takes a dataset folder; reads its `synth.toml`
//! (preset, seed, scene seed), rebuilds the scene exactly as `star synth`
//! built it, checks the rebuilt map against the dataset's `map/map.obj`,
//! and gives out the mesh the camera sees (the preset's image mesh: the
//! truth, with occluders and without map holes) and the preset's sensor
//! model. A scanned dataset is refused.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::SimError;
use crate::map::Mesh;
use crate::synth::corrupt::{BlurSpec, PhotometricSpec};
use crate::synth::preset::{ImageSource, Preset};
use crate::synth::sequence::preset_scene;

/// A scene rebuilt from a `star synth` dataset.
#[derive(Clone)]
pub struct SimScene {
    /// The dataset folder.
    pub dir: PathBuf,
    /// The mesh the camera sees (the preset's image mesh: truth or map).
    pub image_mesh: Arc<Mesh>,
    /// The preset's sensor model.
    pub photometric: PhotometricSpec,
    /// The preset's exposure (motion blur).
    pub blur: Option<BlurSpec>,
    /// The dataset's seed (noise).
    pub seed: u64,
    /// The preset's name.
    pub preset: &'static str,
}

impl std::fmt::Debug for SimScene {
    /// The mesh by its size only (it has hundreds of thousands of values).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimScene")
            .field("dir", &self.dir)
            .field("preset", &self.preset)
            .field("seed", &self.seed)
            .field("image_triangles", &self.image_mesh.triangle_count())
            .finish_non_exhaustive()
    }
}

impl SimScene {
    /// Rebuilds the scene of the dataset at `dir` from its `synth.toml`.
    pub fn load(dir: &Path) -> Result<Self, SimError> {
        let path = dir.join("synth.toml");
        let bad = |reason: String| SimError::Scene {
            path: path.clone(),
            reason,
        };
        let text = std::fs::read_to_string(&path).map_err(|e| {
            bad(format!(
                "{e} (is {} a `star synth` dataset?)",
                dir.display()
            ))
        })?;
        let table: toml::Table = text.parse().map_err(|e| bad(format!("not TOML: {e}")))?;
        let int = |key: &str| -> Result<u64, SimError> {
            table
                .get(key)
                .and_then(toml::Value::as_integer)
                .and_then(|v| u64::try_from(v).ok())
                .ok_or_else(|| bad(format!("`{key}` missing or not a non-negative integer")))
        };
        let (seed, scene_seed) = (int("seed")?, int("scene_seed")?);
        let name = table
            .get("name")
            .and_then(toml::Value::as_str)
            .ok_or_else(|| bad("`name` (the preset) missing".into()))?;
        let mut preset =
            Preset::by_name(name).ok_or_else(|| bad(format!("unknown preset `{name}`")))?;
        if table.contains_key("scanned") {
            return Err(bad(
                "a scanned dataset (map in the scanner's frame, moving light) is not supported \
                 by the sim camera; synthesize one without --scanned"
                    .into(),
            ));
        }
        preset.scene.texture_seed = table
            .get("scene")
            .and_then(|s| s.get("texture_seed"))
            .and_then(toml::Value::as_integer)
            .and_then(|v| u64::try_from(v).ok());
        // A building of another size (`star synth --rooms N`), or of
        // identical rooms (`--identical-rooms`).
        if let Some(spec) = preset.scene.building.as_mut() {
            let building = table.get("scene").and_then(|s| s.get("building"));
            if let Some(rooms) = building
                .and_then(|b| b.get("rooms"))
                .and_then(toml::Value::as_integer)
                .and_then(|v| usize::try_from(v).ok())
            {
                spec.rooms = rooms;
            }
            if let Some(identical) = building
                .and_then(|b| b.get("identical_rooms"))
                .and_then(toml::Value::as_bool)
            {
                spec.identical_rooms = identical;
            }
            spec.validate().map_err(|e| bad(e.to_string()))?;
        }
        // Every parameter must be this star's: the scene is rebuilt, not read.
        if !text.contains(&preset.to_toml()) {
            return Err(bad(format!(
                "its parameters differ from this star's preset `{name}`: \
                 synthesize the dataset again with this star"
            )));
        }
        let scene = preset_scene(&preset, scene_seed);
        let map_path = dir.join("map").join("map.obj");
        let map = crate::map::load_obj(&map_path).map_err(|e| SimError::Scene {
            path: map_path.clone(),
            reason: e.to_string(),
        })?;
        let (file_mean, rebuilt_mean) = (triangle_mean_m(&map), triangle_mean_m(&scene.map));
        let same = map.triangle_count() == scene.map.triangle_count()
            && (0..3).all(|k| (file_mean[k] - rebuilt_mean[k]).abs() < 1e-6);
        if !same {
            return Err(SimError::Scene {
                path: map_path,
                reason: format!(
                    "{} triangles around {file_mean:.3?} m, the rebuilt scene's map {} around \
                     {rebuilt_mean:.3?} m: not this dataset's scene",
                    map.triangle_count(),
                    scene.map.triangle_count()
                ),
            });
        }
        let image_mesh = match preset.images_from {
            ImageSource::Truth => scene.truth,
            ImageSource::Map => scene.map,
        };
        Ok(Self {
            dir: dir.to_path_buf(),
            image_mesh: Arc::new(image_mesh),
            photometric: preset.photometric,
            blur: preset.blur,
            seed,
            preset: preset.name,
        })
    }

    /// The dataset folder of a `star synth` map at `DIR/map/map.obj`.
    pub fn dir_of_map(mesh: &Path) -> Option<PathBuf> {
        let map_dir = mesh.parent()?;
        (map_dir.file_name()? == "map").then(|| map_dir.parent().map(Path::to_path_buf))?
    }
}

/// The mean of the triangles' vertices, meters: a fingerprint of the
/// layout that survives the OBJ round trip (vertex order and rounding).
fn triangle_mean_m(mesh: &Mesh) -> [f64; 3] {
    let mut sum = [0.0f64; 3];
    for &i in &mesh.indices {
        if let Some(p) = mesh.positions.get(i as usize) {
            (0..3).for_each(|k| sum[k] += f64::from(p[k]));
        }
    }
    let n = mesh.indices.len().max(1) as f64;
    sum.map(|v| v / n)
}
