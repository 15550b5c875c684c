//! Tests of the OBJ loader and writer.

use super::*;
use crate::map::error::MeshProblem;
use crate::map::{write_obj, MeshGroup};

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).unwrap();
    }
    std::fs::write(&path, text).unwrap();
    path
}

const QUAD_COLORED: &str = "\
v 0 0 0 1 0 0
v 1 0 0 0 1 0
v 1 1 0 0 0 1
v 0 1 0 1 1 1
f 1 2 3 4
";

#[test]
fn vertex_colors_become_rec601_gray() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = load_obj(&write(dir.path(), "q.obj", QUAD_COLORED)).unwrap();
    assert_eq!(mesh.triangle_count(), 2);
    assert_eq!(mesh.groups.len(), 1);
    assert_eq!(mesh.groups[0].texture, None);
    let expect = [0.299 * 255.0, 0.587 * 255.0, 0.114 * 255.0, 255.0];
    for (g, e) in mesh.gray.iter().zip(expect) {
        assert!((g - e).abs() < 1e-3, "{g} vs {e}");
    }
}

#[test]
fn colors_above_one_are_read_as_0_255() {
    let dir = tempfile::tempdir().unwrap();
    let text = "v 0 0 0 255 255 255\nv 1 0 0 0 0 0\nv 0 1 0 100 100 100\nf 1 2 3\n";
    let mesh = load_obj(&write(dir.path(), "q.obj", text)).unwrap();
    assert!((mesh.gray[0] - 255.0).abs() < 1e-3);
    assert!((mesh.gray[2] - 100.0).abs() < 1e-3);
}

fn write_rgb_png(path: &Path, w: u32, h: u32, f: impl Fn(u32, u32) -> [u8; 3]) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    image::RgbImage::from_fn(w, h, |x, y| image::Rgb(f(x, y)))
        .save(path)
        .unwrap();
}

/// A scene with a textured quad (material in a subfolder, texture relative
/// to it) and an untextured Kd triangle.
fn textured_scene(dir: &Path, kd_line: &str) -> PathBuf {
    write_rgb_png(&dir.join("mat/tex/wall.png"), 4, 2, |x, y| {
        if y == 0 {
            [200, 100, 50]
        } else {
            [x as u8 * 10, x as u8 * 10, x as u8 * 10]
        }
    });
    write(
        dir,
        "mat/scene.mtl",
        &format!("newmtl wall\n{kd_line}\nmap_Kd tex/wall.png\nnewmtl gray\nKd 0.5 0.5 0.5\n"),
    );
    write(
        dir,
        "scene.obj",
        "mtllib mat/scene.mtl\n\
         v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\n\
         vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
         usemtl gray\nf 2 5 3\n\
         usemtl wall\nf 1/1 2/2 3/3 4/4\n",
    )
}

#[test]
fn mtl_diffuse_and_texture_relative_to_mtl_folder() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = load_obj(&textured_scene(dir.path(), "Kd 1 0 0")).unwrap();
    assert_eq!(mesh.triangle_count(), 3);
    assert_eq!(mesh.textures.len(), 1);
    let tex = &mesh.textures[0];
    assert_eq!((tex.width, tex.height), (4, 2));
    let top = 0.299 * 200.0 + 0.587 * 100.0 + 0.114 * 50.0;
    assert!((tex.texels[0] - top).abs() < 0.5, "{}", tex.texels[0]);
    assert!((tex.texels[4 + 3] - 30.0).abs() < 0.5);

    let textured = mesh.groups.iter().find(|g| g.texture == Some(0)).unwrap();
    let plain = mesh.groups.iter().find(|g| g.texture.is_none()).unwrap();
    assert_eq!(textured.index_count, 6);
    assert_eq!(plain.index_count, 3);
    let i = mesh.indices[plain.first_index as usize] as usize;
    assert!((mesh.gray[i] - 127.5).abs() < 1e-3);
    // Textured vertices carry the Kd luma and the v-flipped uvs.
    let first = textured.first_index as usize;
    for &i in &mesh.indices[first..first + 6] {
        let i = i as usize;
        assert!((mesh.gray[i] - 0.299 * 255.0).abs() < 1e-3);
        let p = mesh.positions[i];
        assert_eq!(mesh.uvs[i], [p[0], 1.0 - p[1]]);
    }
}

#[test]
fn texture_without_kd_has_white_vertices() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = load_obj(&textured_scene(dir.path(), "")).unwrap();
    let g = mesh.groups.iter().find(|g| g.texture.is_some()).unwrap();
    let i = mesh.indices[g.first_index as usize] as usize;
    assert_eq!(mesh.gray[i], 255.0);
}

#[test]
fn missing_file_is_a_read_error() {
    let err = load_obj(Path::new("/nonexistent/dir/x.obj")).unwrap_err();
    assert!(matches!(err, MapError::Read { .. }), "{err}");
    assert!(err.to_string().contains("/nonexistent/dir/x.obj"));
}

#[test]
fn parse_errors_name_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "bad.obj", "v 0 0 0\nv 1 0\nf 1 2 1\n");
    let err = load_obj(&path).unwrap_err();
    assert!(matches!(err, MapError::Parse { line: 2, .. }), "{err}");
    let path = write(
        dir.path(),
        "bad2.obj",
        "v 0 0 0\nv 1 0 x\nv 0 1 0\nf 1 2 3\n",
    );
    assert!(matches!(load_obj(&path), Err(MapError::Parse { .. })));
    let path = write(
        dir.path(),
        "bad3.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 a 3\n",
    );
    assert!(matches!(
        load_obj(&path),
        Err(MapError::Parse { line: 4, .. })
    ));
    let path = write(
        dir.path(),
        "mixed.obj",
        "v 0 0 0 1 1 1\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    );
    assert!(matches!(
        load_obj(&path),
        Err(MapError::Parse { line: 2, .. })
    ));
}

#[test]
fn no_faces_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "empty.obj", "v 0 0 0\nv 1 0 0\n");
    let err = load_obj(&path).unwrap_err();
    assert_eq!(err.problem(), Some(&MeshProblem::NoFaces), "{err}");
}

#[test]
fn non_finite_vertices_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    for bad in ["NaN", "inf", "-inf"] {
        let path = write(
            dir.path(),
            "nan.obj",
            &format!("v 0 0 0\nv 1 {bad} 0\nv 0 1 0\nf 1 2 3\n"),
        );
        let err = load_obj(&path).unwrap_err();
        assert!(
            matches!(
                err.problem(),
                Some(MeshProblem::NotFinite {
                    what: "position",
                    ..
                })
            ),
            "{err}"
        );
    }
}

#[test]
fn out_of_range_indices_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    for face in [
        "f 1 2 4",
        "f 0 1 2",
        "f 1 2 -4",
        "f 1/5 2/1 3/1",
        "f 1/0 2 3",
    ] {
        let text = format!("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n{face}\n");
        let path = write(dir.path(), "range.obj", &text);
        let err = load_obj(&path).unwrap_err();
        assert!(
            matches!(err, MapError::FaceIndex { line: 5, .. }),
            "{face}: {err}"
        );
    }
    // Negative (relative) indices in range are fine.
    let path = write(
        dir.path(),
        "rel.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n",
    );
    assert_eq!(load_obj(&path).unwrap().triangle_count(), 1);
}

#[test]
fn missing_texture_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let obj = textured_scene(dir.path(), "Kd 1 1 1");
    std::fs::remove_file(dir.path().join("mat/tex/wall.png")).unwrap();
    let err = load_obj(&obj).unwrap_err();
    match &err {
        MapError::MissingTexture { path, material } => {
            assert!(path.ends_with("mat/tex/wall.png"));
            assert_eq!(material, "wall");
        }
        other => panic!("unexpected {other}"),
    }
}

#[test]
fn undecodable_texture_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let obj = textured_scene(dir.path(), "Kd 1 1 1");
    std::fs::write(dir.path().join("mat/tex/wall.png"), b"not a png at all").unwrap();
    let err = load_obj(&obj).unwrap_err();
    assert!(matches!(err, MapError::TextureDecode { .. }), "{err}");
}

#[test]
fn missing_or_bad_material_library_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let obj = textured_scene(dir.path(), "Kd 1 1 1");
    std::fs::remove_file(dir.path().join("mat/scene.mtl")).unwrap();
    let err = load_obj(&obj).unwrap_err();
    assert!(matches!(err, MapError::Material { .. }), "{err}");
    assert!(err.to_string().contains("scene.mtl"));

    let obj = textured_scene(dir.path(), "Kd 1 1");
    let err = load_obj(&obj).unwrap_err();
    assert!(matches!(err, MapError::Material { .. }), "{err}");
}

/// A mesh with two textures and an untextured group, vertices unshared
/// across groups.
fn sample_mesh() -> Mesh {
    let mut mesh = Mesh::default();
    let tex = |w: u32, h: u32, k: f32| GrayTexture {
        width: w,
        height: h,
        texels: (0..w * h).map(|i| (i as f32 * k) % 256.0).collect(),
    };
    mesh.textures = vec![tex(5, 3, 17.3), tex(2, 7, 33.1)];
    for (g, texture) in [(0, Some(1)), (1, None), (2, Some(0))] {
        let first_index = mesh.indices.len() as u32;
        for t in 0..3 {
            let base = mesh.positions.len() as u32;
            for k in 0..3 {
                let x = (g * 10 + t * 3 + k) as f32 * 0.37;
                mesh.positions.push([x, x * x * 0.1, -x + 0.25]);
                mesh.gray.push((x * 31.7) % 255.0);
                mesh.uvs.push([(x * 0.3) % 1.0, (x * 0.7) % 1.0]);
            }
            mesh.indices.extend([base, base + 1, base + 2]);
        }
        mesh.groups.push(MeshGroup {
            first_index,
            index_count: 9,
            texture,
        });
    }
    mesh
}

#[test]
fn write_then_load_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = sample_mesh();
    let path = write_obj(&mesh, &dir.path().join("out"), "room").unwrap();
    assert!(path.ends_with("out/room.obj"));
    let back = load_obj(&path).unwrap();
    assert_eq!(back.triangle_count(), mesh.triangle_count());
    assert_eq!(back.textures.len(), mesh.textures.len());
    // Compare corner by corner, group by group (texture numbering may differ).
    let mut texture_map = std::collections::HashMap::new();
    for (g, h) in mesh.groups.iter().zip(&back.groups) {
        assert_eq!(g.index_count, h.index_count);
        assert_eq!(g.texture.is_some(), h.texture.is_some());
        if let (Some(a), Some(b)) = (g.texture, h.texture) {
            texture_map.insert(a, b);
        }
        let src = &mesh.indices[g.first_index as usize..][..g.index_count as usize];
        let dst = &back.indices[h.first_index as usize..][..h.index_count as usize];
        for (&i, &j) in src.iter().zip(dst) {
            let (i, j) = (i as usize, j as usize);
            assert_eq!(mesh.positions[i], back.positions[j]);
            assert!((mesh.gray[i] - back.gray[j]).abs() <= 1.0);
            for k in 0..2 {
                assert!((mesh.uvs[i][k] - back.uvs[j][k]).abs() < 1e-5);
            }
        }
    }
    for (a, b) in texture_map {
        let (ta, tb) = (&mesh.textures[a as usize], &back.textures[b as usize]);
        assert_eq!((ta.width, ta.height), (tb.width, tb.height));
        for (x, y) in ta.texels.iter().zip(&tb.texels) {
            assert!((x - y).abs() <= 1.0, "{x} vs {y}");
        }
    }
}

#[test]
fn write_rejects_invalid_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let err = write_obj(&Mesh::default(), dir.path(), "x").unwrap_err();
    assert_eq!(err.problem(), Some(&MeshProblem::NoFaces));
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
    /// Arbitrary OBJ-like text never panics the loader.
    #[test]
    fn garbage_never_panics(lines in proptest::collection::vec(
        "(v|vt|vn|f|usemtl|mtllib|o|g|l|#)( -?[0-9]{0,2}(/-?[0-9]{0,2}){0,3}| nan| x){0,7}", 0..12)) {
        let dir = tempfile::tempdir().unwrap();
        let path = write(dir.path(), "g.obj", &lines.join("\n"));
        let _ = load_obj(&path);
    }
}

/// Each triangle's corners as (position, gray, uv) bits, in triangle order.
fn corners(mesh: &Mesh) -> Vec<[u32; 6]> {
    mesh.indices
        .iter()
        .map(|&i| {
            let (p, g, t) = (
                mesh.positions[i as usize],
                mesh.gray[i as usize],
                mesh.uvs.get(i as usize).copied().unwrap_or([0.0; 2]),
            );
            [p[0], p[1], p[2], g, t[0], t[1]].map(f32::to_bits)
        })
        .collect()
}

#[test]
fn an_object_read_in_parts_is_the_same_surface() {
    let dir = tempfile::tempdir().unwrap();
    // A 9 x 9 grid of vertices (colors in 0..255 only in the last rows, so
    // that a part decides nothing alone), quads and triangles, two
    // materials switching mid-object, then a named object of its own.
    let mut text = String::from("mtllib m.mtl\no first\n");
    for y in 0..9 {
        for x in 0..9 {
            let c = if y >= 7 { 200.0 } else { 0.1 * x as f64 };
            text += &format!("v {x} {y} 0 {c} {c} {c}\n");
        }
    }
    let at = |x: usize, y: usize| 9 * y + x + 1;
    for y in 0..8 {
        if y == 4 {
            text += "usemtl red\n";
        }
        for x in 0..8 {
            if x % 2 == 0 {
                text += &format!(
                    "f {} {} {} {}\n",
                    at(x, y),
                    at(x + 1, y),
                    at(x + 1, y + 1),
                    at(x, y + 1)
                );
            } else {
                text += &format!(
                    "f {} {} {}\nf {} {} {}\n",
                    at(x, y),
                    at(x + 1, y),
                    at(x + 1, y + 1),
                    at(x, y),
                    at(x + 1, y + 1),
                    at(x, y + 1)
                );
            }
        }
    }
    text += "g second\nf 1 2 10\nf 2 11 10\n";
    write(dir.path(), "m.mtl", "newmtl red\nKd 1 0 0\n");
    let path = write(dir.path(), "grid.obj", &text);
    let whole = load_obj_in_parts(&path, usize::MAX).unwrap();
    assert_eq!(whole.triangle_count(), 2 * 64 + 2);
    for part_faces in [1, 3, 7, 40] {
        let parts = load_obj_in_parts(&path, part_faces).unwrap();
        assert_eq!(corners(&parts), corners(&whole), "parts of {part_faces}");
        assert_eq!(parts.groups, whole.groups);
        // Shared vertices are repeated per part, never lost.
        assert!(parts.positions.len() >= whole.positions.len());
    }
    // The file's colors are 0..255 (some exceed 1), in every part.
    let small = load_obj_in_parts(&path, 1).unwrap();
    let at_5_0 = small
        .positions
        .iter()
        .position(|p| *p == [5.0, 0.0, 0.0])
        .unwrap();
    // 0.5 of 255, not 0.5 of 1.
    assert!(
        (small.gray[at_5_0] - 0.5).abs() < 1e-3,
        "{}",
        small.gray[at_5_0]
    );
    assert!(load_obj(&path).unwrap() == whole);
}
