//! Parameters of the synthetic scene: [`SceneParams`] with its defaults,
//! range checks ([`SceneParams::validate`]) and clamping.

/// Parameters of a synthetic scene. `Default` is an 8 x 6 x 3 m room with
/// 6 furniture boxes, 2 occluders and 5 % of the map's patches removed.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneParams {
    /// Seed of every random choice (layout, holes, textures).
    pub seed: u64,
    /// Seed of the textures when it differs from `seed`: a look-alike of
    /// another room, with that room's textures in this seed's layout.
    pub texture_seed: Option<u64>,
    /// Room size `[x, y, z]` in meters (x/y floor, z height).
    pub room_size_m: [f64; 3],
    /// Number of furniture boxes on the floor (fewer when they do not fit).
    pub boxes: usize,
    /// Texture resolution, texels per meter of surface.
    pub texture_px_per_m: f64,
    /// Fraction (0..=1) of the room-surface patches removed from the map.
    pub hole_fraction: f64,
    /// Number of objects present in the truth mesh but absent from the map.
    pub occluders: usize,
}

impl Default for SceneParams {
    fn default() -> Self {
        Self {
            seed: 1,
            texture_seed: None,
            room_size_m: [8.0, 6.0, 3.0],
            boxes: 6,
            texture_px_per_m: 128.0,
            hole_fraction: 0.05,
            occluders: 2,
        }
    }
}

/// Invalid [`SceneParams`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SceneParamsError {
    /// A field is out of its range.
    #[error("scene parameter {field} = {value} is invalid: expected {expected}")]
    OutOfRange {
        /// The field name.
        field: &'static str,
        /// The value found.
        value: f64,
        /// The accepted range.
        expected: &'static str,
    },
}

impl SceneParams {
    /// Checks ranges: room sides 2..=50 m (height 2..=10 m), resolution
    /// 8..=1024 texels/m, hole fraction 0..=0.9, at most 100 boxes and 100
    /// occluders. [`super::build_scene`] clamps out-of-range values instead.
    pub fn validate(&self) -> Result<(), SceneParamsError> {
        let check = |field, value: f64, lo: f64, hi: f64, expected| {
            if (lo..=hi).contains(&value) {
                Ok(())
            } else {
                Err(SceneParamsError::OutOfRange {
                    field,
                    value,
                    expected,
                })
            }
        };
        check("room_size_m[0]", self.room_size_m[0], 2.0, 50.0, "2..=50 m")?;
        check("room_size_m[1]", self.room_size_m[1], 2.0, 50.0, "2..=50 m")?;
        check("room_size_m[2]", self.room_size_m[2], 2.0, 10.0, "2..=10 m")?;
        check(
            "texture_px_per_m",
            self.texture_px_per_m,
            8.0,
            1024.0,
            "8..=1024",
        )?;
        check("hole_fraction", self.hole_fraction, 0.0, 0.9, "0..=0.9")?;
        check("boxes", self.boxes as f64, 0.0, 100.0, "0..=100")?;
        check("occluders", self.occluders as f64, 0.0, 100.0, "0..=100")
    }

    /// A copy with every field clamped into its valid range (NaN becomes
    /// the default).
    pub fn clamped(&self) -> Self {
        let d = Self::default();
        let clamp =
            |v: f64, lo: f64, hi: f64, def: f64| if v.is_nan() { def } else { v.clamp(lo, hi) };
        Self {
            seed: self.seed,
            texture_seed: self.texture_seed,
            room_size_m: [
                clamp(self.room_size_m[0], 2.0, 50.0, d.room_size_m[0]),
                clamp(self.room_size_m[1], 2.0, 50.0, d.room_size_m[1]),
                clamp(self.room_size_m[2], 2.0, 10.0, d.room_size_m[2]),
            ],
            boxes: self.boxes.min(100),
            texture_px_per_m: clamp(self.texture_px_per_m, 8.0, 1024.0, d.texture_px_per_m),
            hole_fraction: clamp(self.hole_fraction, 0.0, 0.9, d.hole_fraction),
            occluders: self.occluders.min(100),
        }
    }
}
