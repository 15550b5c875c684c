//! Tests of the synthetic scene.

use super::*;

fn small(seed: u64) -> SceneParams {
    SceneParams {
        seed,
        texture_px_per_m: 24.0,
        ..SceneParams::default()
    }
}

/// Per view, the pixels (gray or depth) that differ between `mesh`
/// rendered with back faces culled and with both sides drawn, camera at
/// each of `positions_m` looking round in 6 directions, 10 degrees down:
/// 0 where every surface seen is wound counter-clockwise toward the camera
/// (a pixel or two where a back face shows through a crack between two
/// surfaces that meet without sharing vertices).
pub(crate) fn pixels_changed_by_back_face_cull(
    mesh: &Mesh,
    positions_m: &[[f64; 3]],
) -> Vec<usize> {
    use crate::render::cpu::CpuRenderer;
    use crate::render::{RenderedView, Renderer};
    use nalgebra::{Translation3, Vector3};
    let camera = crate::geometry::PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
    let mesh = std::sync::Arc::new(mesh.clone());
    let mut both = CpuRenderer::new(mesh.clone()).unwrap();
    let mut front = CpuRenderer::new(mesh).unwrap();
    front.set_cull_back_faces(true);
    let (mut a, mut b) = (
        RenderedView::for_camera(&camera),
        RenderedView::for_camera(&camera),
    );
    let mut changed = Vec::new();
    for p in positions_m {
        for k in 0..6 {
            let yaw = k as f64 * std::f64::consts::FRAC_PI_3;
            let forward = Vector3::new(yaw.cos(), yaw.sin(), -0.17);
            let rotation = crate::geometry::look::look_rotation(&forward, &Vector3::z()).unwrap();
            let pose =
                crate::geometry::Pose::from_parts(Translation3::new(p[0], p[1], p[2]), rotation);
            both.render(&pose, &camera, &mut a).unwrap();
            front.render(&pose, &camera, &mut b).unwrap();
            let seen = a
                .depth_m
                .data()
                .iter()
                .filter(|d| RenderedView::is_hit(**d))
                .count();
            assert!(
                seen > camera.width as usize * camera.height as usize / 2,
                "{p:?} sees little"
            );
            let gray = a
                .gray
                .data()
                .iter()
                .zip(b.gray.data())
                .filter(|(x, y)| x != y);
            let depth = a
                .depth_m
                .data()
                .iter()
                .zip(b.depth_m.data())
                .filter(|(x, y)| x.to_bits() != y.to_bits());
            changed.push(gray.count().max(depth.count()));
        }
    }
    changed
}

/// Most pixels of a 640x512 view that culling back faces may change on a
/// synthetic map: cracks a pixel wide where two surfaces meet (1-4 seen on
/// the `building` floor's views); a surface wound the wrong way changes
/// thousands.
pub(crate) const MOST_CRACK_PIXELS: usize = 8;

fn texture_bytes(mesh: &Mesh) -> usize {
    mesh.textures.iter().map(|t| t.texels.len() * 4).sum()
}

#[test]
fn default_scene_is_valid_and_sized() {
    let scene = default_scene();
    scene.map.validate().unwrap();
    scene.truth.validate().unwrap();
    let tris = scene.truth.triangle_count();
    assert!((10_000..=60_000).contains(&tris), "{tris} triangles");
    assert!(scene.map.triangle_count() < tris);
    assert!(texture_bytes(&scene.truth) < 100 << 20);
    assert_eq!(scene.furniture.len(), 6);
    assert_eq!(scene.occluders.len(), 2);
    let (lo, hi) = scene.truth.bounds().unwrap();
    assert_eq!(lo, [0.0, 0.0, 0.0]);
    assert_eq!(hi, [8.0, 6.0, 3.0]);
}

#[test]
fn same_seed_same_meshes_other_seed_differs() {
    let a = build_scene(&small(42));
    let b = build_scene(&small(42));
    // (assert! rather than assert_eq!: a failure would print whole meshes)
    assert!(a.map == b.map);
    assert!(a.truth == b.truth);
    assert_eq!(a.furniture, b.furniture);
    let c = build_scene(&small(43));
    assert!(a.truth.positions != c.truth.positions);
    assert!(a.truth.textures[0] != c.truth.textures[0]);
}

#[test]
fn holes_remove_whole_patches_from_the_map_only() {
    let params = SceneParams {
        hole_fraction: 0.2,
        occluders: 0,
        ..small(5)
    };
    let scene = build_scene(&params);
    // Room: floor/ceiling 16x12 patches, walls 16x6 and 12x6; 32 triangles each.
    let patches = 2 * 16 * 12 + 2 * 16 * 6 + 2 * 12 * 6;
    let holes = (0.2 * patches as f64).round() as usize;
    assert_eq!(
        scene.truth.triangle_count() - scene.map.triangle_count(),
        holes * 32
    );
    let none = build_scene(&SceneParams {
        hole_fraction: 0.0,
        ..params
    });
    assert!(none.map.positions == none.truth.positions);
    assert!(none.map.indices == none.truth.indices);
    assert!(none.map.gray == none.truth.gray);
    assert!(none.map.textures[..] == none.truth.textures[..none.map.textures.len()]);
}

#[test]
fn occluders_are_in_truth_only() {
    let scene = build_scene(&small(9));
    let occluder_texture = scene.truth.textures.len() as u32 - 1;
    assert!(scene
        .truth
        .groups
        .iter()
        .any(|g| g.texture == Some(occluder_texture)));
    assert!(scene
        .map
        .groups
        .iter()
        .all(|g| g.texture.is_some_and(|t| t < occluder_texture)));
    assert_eq!(scene.map.textures.len() + 1, scene.truth.textures.len());
}

#[test]
fn is_free_respects_room_furniture_and_occluders() {
    let scene = build_scene(&small(3));
    let [lx, ly, lz] = scene.room_size_m;
    assert!(!scene.is_free([-0.1, 1.0, 1.0], 0.0));
    assert!(!scene.is_free([1.0, 1.0, lz + 0.1], 0.0));
    assert!(!scene.is_free([0.2, 3.0, 1.5], 0.3));
    for b in scene.furniture.iter().chain(&scene.occluders) {
        let [x, y] = b.center_xy_m;
        assert!(!scene.is_free([x, y, b.height_m * 0.5], 0.0));
        assert!(!scene.is_free([x, y, b.height_m + 0.1], 0.2));
    }
    // High above everything (furniture <= 1.2 m, occluders <= 1.85 m).
    assert!(scene.is_free([lx * 0.5, ly * 0.5, 2.4], 0.3));
    // The free box is inside the room.
    for k in 0..3 {
        assert!(scene.free_min_m[k] > 0.0 && scene.free_max_m[k] < scene.room_size_m[k]);
    }
}

#[test]
fn boxes_do_not_overlap_and_stay_inside() {
    for seed in 0..5 {
        let scene = build_scene(&small(seed));
        let all: Vec<_> = scene.furniture.iter().chain(&scene.occluders).collect();
        for (i, a) in all.iter().enumerate() {
            for b in &all[i + 1..] {
                let d = ((a.center_xy_m[0] - b.center_xy_m[0]).powi(2)
                    + (a.center_xy_m[1] - b.center_xy_m[1]).powi(2))
                .sqrt();
                assert!(d > a.radius_m() + b.radius_m(), "seed {seed}");
            }
        }
        let (lo, hi) = scene.truth.bounds().unwrap();
        for k in 0..3 {
            assert!(lo[k] >= -1e-4 && hi[k] <= scene.room_size_m[k] as f32 + 1e-4);
        }
    }
}

#[test]
fn params_validate_and_clamp() {
    assert!(SceneParams::default().validate().is_ok());
    let bad = SceneParams {
        room_size_m: [8.0, f64::NAN, 3.0],
        hole_fraction: 2.0,
        ..SceneParams::default()
    };
    let err = bad.validate().unwrap_err();
    assert!(err.to_string().contains("room_size_m[1]"), "{err}");
    let fixed = bad.clamped();
    assert!(fixed.validate().is_ok());
    assert_eq!(fixed.room_size_m[1], 6.0);
    assert_eq!(fixed.hole_fraction, 0.9);
}

/// No texture has a large flat region: in every 0.5 m block, a fair share
/// of texels has a gradient of a few gray levels per texel.
#[test]
fn textures_have_gradients_everywhere() {
    let scene = build_scene(&SceneParams {
        texture_px_per_m: 64.0,
        ..small(11)
    });
    let block = 32usize;
    for (n, t) in scene.truth.textures.iter().enumerate() {
        let (w, h) = (t.width as usize, t.height as usize);
        let mut worst: f64 = 1.0;
        for by in (0..h - 1).step_by(block) {
            for bx in (0..w - 1).step_by(block) {
                let (mut strong, mut total) = (0usize, 0usize);
                for y in by..(by + block).min(h - 1) {
                    for x in bx..(bx + block).min(w - 1) {
                        let v = t.texels[y * w + x];
                        let gx = t.texels[y * w + x + 1] - v;
                        let gy = t.texels[(y + 1) * w + x] - v;
                        total += 1;
                        if gx.abs() + gy.abs() > 3.0 {
                            strong += 1;
                        }
                    }
                }
                worst = worst.min(strong as f64 / total as f64);
            }
        }
        assert!(
            worst > 0.03,
            "texture {n}: worst block has {worst:.3} strong texels"
        );
    }
}

/// The map written as OBJ + MTL + PNGs loads back equal within a gray level.
#[test]
fn map_round_trips_through_obj() {
    let scene = build_scene(&SceneParams {
        texture_px_per_m: 16.0,
        ..small(21)
    });
    let dir = tempfile::tempdir().unwrap();
    let path = crate::map::write_obj(&scene.map, dir.path(), "map").unwrap();
    let back = crate::map::load_obj(&path).unwrap();
    assert_eq!(back.triangle_count(), scene.map.triangle_count());
    assert_eq!(back.textures.len(), scene.map.textures.len());
    assert_eq!(back.bounds(), scene.map.bounds());
    for (a, b) in scene.map.textures.iter().zip(&back.textures) {
        assert_eq!((a.width, a.height), (b.width, b.height));
        assert!(a
            .texels
            .iter()
            .zip(&b.texels)
            .all(|(x, y)| (x - y).abs() <= 0.5 + 1e-3));
    }
    let corners = |m: &Mesh| -> Vec<[f32; 3]> {
        m.indices.iter().map(|&i| m.positions[i as usize]).collect()
    };
    assert!(corners(&back) == corners(&scene.map));
}

#[test]
fn a_texture_seed_makes_a_look_alike_room() {
    let mapped = build_scene(&small(3));
    let look_alike = build_scene(&SceneParams {
        texture_seed: Some(3),
        ..small(11)
    });
    let other = build_scene(&small(11));
    assert_eq!(look_alike.map.textures, mapped.map.textures);
    assert_ne!(other.map.textures, mapped.map.textures);
    // The layout is seed 11's, not the mapped room's.
    assert_eq!(look_alike.map.positions, other.map.positions);
    assert_ne!(look_alike.map.positions, mapped.map.positions);
}

#[test]
fn the_rooms_surfaces_face_where_they_are_seen_from() {
    let scene = default_scene();
    let (lo, hi) = (scene.free_min_m, scene.free_max_m);
    let positions: Vec<[f64; 3]> = [[0.2, 0.3], [0.5, 0.5], [0.8, 0.7], [0.3, 0.8]]
        .iter()
        .map(|f| {
            [
                lo[0] + f[0] * (hi[0] - lo[0]),
                lo[1] + f[1] * (hi[1] - lo[1]),
                1.4,
            ]
        })
        .filter(|p| scene.is_free(*p, 0.3))
        .collect();
    assert!(positions.len() >= 3, "{positions:?}");
    for (mesh, what) in [(&scene.map, "map"), (&scene.truth, "truth")] {
        let changed = pixels_changed_by_back_face_cull(mesh, &positions);
        assert!(
            changed.iter().all(|&n| n <= MOST_CRACK_PIXELS),
            "{what}: pixels changed per view {changed:?}"
        );
    }
}
