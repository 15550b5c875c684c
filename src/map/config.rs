//! `[map]`: where the mesh of the building is, and how its frame maps into
//! the z-up world frame (`[map.world_from_mesh]`).
//!
//! A mesh file may be in any frame and unit: a scanner writes its first
//! camera's frame (y down), CAD tools often millimeters. Everything
//! downstream (renders, relocalization, MAVLink) works in the world frame,
//! so the transform is applied once, when the mesh is loaded
//! ([`MapConfig::load_mesh`]).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{MapError, Mesh};
use crate::geometry::{Pose, TransformConfig};
use crate::settings::SettingError;

/// Smallest and largest accepted mesh scale (a typo, not a unit, outside).
pub const MESH_SCALE_RANGE: (f64, f64) = (1e-6, 1e6);

/// `[map]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapConfig {
    /// Mesh of the building: `.obj` (+ MTL, textures), `.ply` (vertex
    /// colors, ASCII or binary), `.gltf` or `.glb` (vertex colors or
    /// base-color textures); the extension names the format.
    pub mesh: PathBuf,
    /// The mesh file's frame in the world: `p_world = world_from_mesh *
    /// (scale * p_mesh)`. Identity by default (the mesh is z-up, meters).
    pub world_from_mesh: MeshTransformConfig,
}

impl Default for MapConfig {
    fn default() -> Self {
        Self {
            mesh: PathBuf::from("/var/lib/star/map/map.obj"),
            world_from_mesh: MeshTransformConfig::default(),
        }
    }
}

/// `[map.world_from_mesh]`: a rigid transform (as every transform in the
/// config) plus a uniform scale applied first, for meshes in other units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MeshTransformConfig {
    /// Translation `[x, y, z]` of the mesh origin in the world, meters.
    pub translation_m: [f64; 3],
    /// Rotation as `[roll, pitch, yaw]` in degrees, `Rz(yaw) Ry(pitch) Rx(roll)`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rpy_deg: Option<[f64; 3]>,
    /// Rotation as a unit quaternion `[w, x, y, z]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub quaternion_wxyz: Option<[f64; 4]>,
    /// Rotation as a 3x3 matrix, row by row (orthonormal, determinant +1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rotation_rows: Option<[[f64; 3]; 3]>,
    /// Meters per mesh unit: 1 for meters, 0.001 for millimeters.
    pub scale: f64,
}

impl Default for MeshTransformConfig {
    fn default() -> Self {
        Self {
            translation_m: [0.0; 3],
            rpy_deg: None,
            quaternion_wxyz: None,
            rotation_rows: None,
            scale: 1.0,
        }
    }
}

impl MeshTransformConfig {
    /// The rigid part.
    pub fn rigid(&self) -> TransformConfig {
        TransformConfig {
            translation_m: self.translation_m,
            rpy_deg: self.rpy_deg,
            quaternion_wxyz: self.quaternion_wxyz,
            rotation_rows: self.rotation_rows,
        }
    }

    /// True for the identity (nothing to apply).
    pub fn is_identity(&self) -> bool {
        *self == Self::default()
    }
}

impl MapConfig {
    /// Checks the transform; keys are relative to `[map]`.
    pub fn validate(&self) -> Result<(), SettingError> {
        let t = &self.world_from_mesh;
        let (lo, hi) = MESH_SCALE_RANGE;
        if !(t.scale >= lo && t.scale <= hi) {
            return Err(SettingError::new(
                "world_from_mesh.scale",
                format!(
                    "expected meters per mesh unit within {lo:e}..={hi:e} (1 for meters, 0.001 for millimeters), found {}",
                    t.scale
                ),
            ));
        }
        t.rigid()
            .validate()
            .map_err(|reason| SettingError::new("world_from_mesh", reason))
    }

    /// Loads `self.mesh` into the world frame.
    pub fn load_mesh(&self) -> Result<Mesh, MapError> {
        self.load_mesh_from(&self.mesh)
    }

    /// Loads the mesh at `path` (a `--map` override) into the world frame.
    pub fn load_mesh_from(&self, path: &Path) -> Result<Mesh, MapError> {
        let mut mesh = super::load_mesh(path)?;
        if !self.world_from_mesh.is_identity() {
            mesh.transform(
                self.world_from_mesh.scale,
                &self.world_from_mesh.rigid().to_pose(),
            );
            tracing::info!(
                mesh = %path.display(),
                scale = self.world_from_mesh.scale,
                "map placed in the world frame by [map.world_from_mesh]"
            );
        }
        Ok(mesh)
    }
}

impl Mesh {
    /// Maps every vertex `p` to `world_from_mesh * (scale * p)`.
    pub fn transform(&mut self, scale: f64, world_from_mesh: &Pose) {
        for p in &mut self.positions {
            let v = nalgebra::Point3::new(p[0] as f64, p[1] as f64, p[2] as f64) * scale;
            let w = world_from_mesh * v;
            *p = [w.x as f32, w.y as f32, w.z as f32];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> MapConfig {
        toml::from_str(text).expect("parses")
    }

    #[test]
    fn a_wrong_transform_names_its_key() {
        let c = parse("[world_from_mesh]\nscale = 0.0\n");
        let e = c.validate().expect_err("zero scale");
        assert_eq!(e.key, "world_from_mesh.scale");
        assert!(e.reason.contains("found 0"), "{e}");
        let c = parse("[world_from_mesh]\nrotation_rows = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 1.0]]\n");
        let e = c.validate().expect_err("not orthonormal");
        assert_eq!(e.key, "world_from_mesh");
        assert!(
            e.reason.contains("rotation_rows") && e.reason.contains("orthonormal"),
            "{e}"
        );
        MapConfig::default().validate().expect("identity is valid");
    }

    #[test]
    fn transform_applies_scale_then_rotation_then_translation() {
        let mut mesh = Mesh {
            positions: vec![[1000.0, 0.0, 0.0], [0.0, 1000.0, 0.0]],
            ..Mesh::default()
        };
        // Millimeters, a scanner frame (y down, z forward) to z-up, 1 m up.
        let c = parse(
            "[world_from_mesh]\nscale = 0.001\ntranslation_m = [0.0, 0.0, 1.0]\nrotation_rows = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]\n",
        );
        c.validate().expect("valid");
        let t = &c.world_from_mesh;
        mesh.transform(t.scale, &t.rigid().to_pose());
        let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
        assert!(
            close(mesh.positions[0], [1.0, 0.0, 1.0]),
            "{:?}",
            mesh.positions[0]
        );
        // Mesh +y (down) is world -z.
        assert!(
            close(mesh.positions[1], [0.0, 0.0, 0.0]),
            "{:?}",
            mesh.positions[1]
        );
    }
}
