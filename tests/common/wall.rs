//! The textured wall both tracker allocation tests fly past.

use star::map::{GrayTexture, Mesh, MeshGroup};

/// A 6 x 6 m textured wall at z = 3 m, facing the camera.
pub fn wall() -> Mesh {
    let n = 512u32;
    let mut texels = Vec::with_capacity((n * n) as usize);
    for y in 0..n {
        for x in 0..n {
            let (u, v) = (x as f32 / n as f32, y as f32 / n as f32);
            let g = 128.0
                + 60.0 * (40.0 * u + 4.0 * (9.0 * v).sin()).sin() * (31.0 * v).cos()
                + 40.0 * (((u * 17.0).floor() + (v * 13.0).floor()) % 2.0 - 0.5);
            texels.push(g.clamp(0.0, 255.0));
        }
    }
    Mesh {
        positions: vec![
            [-3.0, -3.0, 3.0],
            [3.0, -3.0, 3.0],
            [3.0, 3.0, 3.0],
            [-3.0, 3.0, 3.0],
        ],
        gray: vec![255.0; 4],
        uvs: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
        indices: vec![0, 1, 2, 0, 2, 3],
        groups: vec![MeshGroup {
            first_index: 0,
            index_count: 6,
            texture: Some(0),
        }],
        textures: vec![GrayTexture {
            width: n,
            height: n,
            texels,
        }],
    }
}
