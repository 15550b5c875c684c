//! `[map]`: where the mesh of the building is.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// `[map]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapConfig {
    /// OBJ mesh of the building, world frame, meters.
    pub mesh: PathBuf,
}

impl Default for MapConfig {
    fn default() -> Self {
        Self {
            mesh: PathBuf::from("/var/lib/star/map/map.obj"),
        }
    }
}
