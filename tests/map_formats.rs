//! Map formats end to end: the same map written as OBJ, PLY (ASCII, binary
//! little and big endian) and GLB loads through `star::map::load_mesh` and
//! renders the same image with the CPU rasterizer; and every bad input
//! (truncated, no faces, an index out of range, a missing or unreadable
//! texture, NaN coordinates, content that is not what the extension says)
//! is an error that names the file and the problem.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use base64::Engine;
use nalgebra::Translation3;
use star::geometry::look::camera_rotation;
use star::geometry::{PinholeCamera, Pose};
use star::map::{load_mesh, write_glb, write_obj, write_ply, Mesh, PlyEncoding};
use star::render::cpu::CpuRenderer;
use star::render::{RenderedView, Renderer};

use common::room::{poses, room, textured_room};

fn camera() -> PinholeCamera {
    PinholeCamera::new(320, 256, 210.0, 210.0, 159.5, 127.5)
}

fn render_all(mesh: Mesh, poses: &[Pose]) -> Vec<RenderedView> {
    let mut renderer = CpuRenderer::new(Arc::new(mesh)).expect("renderer");
    poses
        .iter()
        .map(|pose| {
            let mut view = RenderedView::for_camera(&camera());
            renderer.render(pose, &camera(), &mut view).expect("render");
            view
        })
        .collect()
}

/// Fraction of pixels whose gray differs by at most one level (a pixel
/// that one render hits and the other misses counts as differing).
fn agreement(a: &[RenderedView], b: &[RenderedView]) -> f64 {
    let (mut same, mut total) = (0usize, 0usize);
    for (va, vb) in a.iter().zip(b) {
        let (ga, gb) = (va.gray.data(), vb.gray.data());
        let (da, db) = (va.depth_m.data(), vb.depth_m.data());
        for k in 0..ga.len() {
            let hit = (RenderedView::is_hit(da[k]), RenderedView::is_hit(db[k]));
            total += 1;
            if hit.0 == hit.1 && (!hit.0 || (ga[k] - gb[k]).abs() <= 1.0) {
                same += 1;
            }
        }
    }
    same as f64 / total as f64
}

/// `room()` with vertex gray only: the texture dropped, each vertex a
/// deterministic pseudo-random gray so that a wrong vertex shows.
fn vertex_colored_room() -> Mesh {
    let mut mesh = room(24, 4);
    for g in &mut mesh.groups {
        g.texture = None;
    }
    mesh.textures.clear();
    mesh.uvs.clear();
    let mut state = 0x2545_f491_u32;
    for g in &mut mesh.gray {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        *g = (*g * 0.5 + (state % 128) as f32).round();
    }
    mesh
}

#[test]
fn the_same_map_as_obj_ply_and_glb_renders_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = vertex_colored_room();
    let views = poses();
    let obj = write_obj(&mesh, dir.path(), "room").unwrap();
    let reference = render_all(load_mesh(&obj).unwrap(), &views);
    let hits: usize = reference
        .iter()
        .map(|v| {
            v.depth_m
                .data()
                .iter()
                .filter(|&&d| RenderedView::is_hit(d))
                .count()
        })
        .sum();
    assert!(
        hits > views.len() * 320 * 200,
        "the views see the room: {hits}"
    );
    for (name, encoding) in [
        ("ascii.ply", Some(PlyEncoding::Ascii)),
        ("le.ply", Some(PlyEncoding::BinaryLittleEndian)),
        ("be.ply", Some(PlyEncoding::BinaryBigEndian)),
        ("room.glb", None),
    ] {
        let path = dir.path().join(name);
        match encoding {
            Some(e) => write_ply(&mesh, &path, e).unwrap(),
            None => write_glb(&mesh, &path).unwrap(),
        }
        let loaded = load_mesh(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(loaded.triangle_count(), mesh.triangle_count(), "{name}");
        let same = agreement(&reference, &render_all(loaded, &views));
        eprintln!(
            "{name}: {:.5} of the pixels within one gray level of the OBJ's",
            same
        );
        assert!(same >= 0.99, "{name}: only {same:.4} of the pixels agree");
    }
}

#[test]
fn a_textured_map_as_obj_and_glb_renders_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = textured_room();
    let views: Vec<Pose> = [(3.0, 2.5, 1.4), (1.5, 1.2, 1.0), (4.5, 3.5, 2.0)]
        .iter()
        .flat_map(|&(x, y, z)| {
            (0..4).map(move |k| {
                Pose::from_parts(
                    Translation3::new(x, y, z),
                    camera_rotation(0.4 + k as f64 * std::f64::consts::FRAC_PI_2, -0.2, 0.0),
                )
            })
        })
        .collect();
    let obj = write_obj(&mesh, dir.path(), "textured").unwrap();
    let glb = dir.path().join("textured.glb");
    write_glb(&mesh, &glb).unwrap();
    let from_glb = load_mesh(&glb).unwrap();
    assert_eq!(from_glb.textures.len(), mesh.textures.len());
    let same = agreement(
        &render_all(load_mesh(&obj).unwrap(), &views),
        &render_all(from_glb, &views),
    );
    eprintln!("textured GLB: {same:.5} of the pixels within one gray level of the OBJ's");
    assert!(same >= 0.99, "only {same:.4} of the pixels agree");
}

/// A small ASCII PLY: 4 vertices (with float colors), then `faces`.
fn ascii_ply(vertices: &[&str], faces: &[&str]) -> String {
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float red\nproperty float green\nproperty float blue\n",
        vertices.len()
    );
    if !faces.is_empty() {
        s.push_str(&format!(
            "element face {}\nproperty list uchar int vertex_indices\n",
            faces.len()
        ));
    }
    s.push_str("end_header\n");
    for v in vertices.iter().chain(faces) {
        s.push_str(v);
        s.push('\n');
    }
    s
}

const QUAD: [&str; 4] = [
    "0 0 0 1 0 0",
    "1 0 0 0 1 0",
    "1 1 0 0 0 1",
    "0 1 0 0.5 0.5 0.5",
];

/// Loading `path` fails with a message naming the file and containing
/// every one of `needles`.
fn assert_refused(path: &Path, needles: &[&str]) {
    let e = load_mesh(path).expect_err(&format!("{} loads", path.display()));
    let message = format!("{e:#}");
    let name = path.file_name().unwrap().to_str().unwrap();
    assert!(message.contains(name), "the error names no file: {message}");
    for needle in needles {
        assert!(message.contains(needle), "'{needle}' not in: {message}");
    }
    eprintln!("{name}: {message}");
}

#[test]
fn ply_colors_and_polygons_are_read() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("quad.ply");
    std::fs::write(&path, ascii_ply(&QUAD, &["4 0 1 2 3"])).unwrap();
    let mesh = load_mesh(&path).unwrap();
    assert_eq!(mesh.indices, vec![0, 1, 2, 0, 2, 3]);
    let expected = [0.299 * 255.0, 0.587 * 255.0, 0.114 * 255.0, 127.5];
    for (g, e) in mesh.gray.iter().zip(expected) {
        assert!((g - e).abs() < 1e-3, "{:?}", mesh.gray);
    }
}

#[test]
fn bad_ply_files_are_refused_naming_the_file_and_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, bytes: &[u8]| -> PathBuf {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    };
    // No faces: a point cloud.
    let p = write("points.ply", ascii_ply(&QUAD, &[]).as_bytes());
    assert_refused(&p, &["no faces", "point cloud"]);
    let p = write(
        "empty_faces.ply",
        ascii_ply(&QUAD, &[])
            .replace(
                "end_header",
                "element face 0\nproperty list uchar int vertex_indices\nend_header",
            )
            .as_bytes(),
    );
    assert_refused(&p, &["no faces", "empty"]);
    // An index out of range.
    let p = write(
        "index.ply",
        ascii_ply(&QUAD, &["3 0 1 2", "3 0 2 9"]).as_bytes(),
    );
    assert_refused(&p, &["face 1", "vertex 9", "4 vertices"]);
    let p = write("negative.ply", ascii_ply(&QUAD, &["3 0 -1 2"]).as_bytes());
    assert_refused(&p, &["vertex -1"]);
    // Truncated, ASCII and binary.
    let text = ascii_ply(&QUAD, &["3 0 1 2", "3 0 2 3"]);
    let cut = &text[..text.len() - 8];
    let p = write("cut_ascii.ply", cut.as_bytes());
    assert_refused(&p, &["truncated"]);
    let mesh = vertex_colored_room();
    let full = dir.path().join("full.ply");
    write_ply(&mesh, &full, PlyEncoding::BinaryLittleEndian).unwrap();
    let bytes = std::fs::read(&full).unwrap();
    let p = write("cut_binary.ply", &bytes[..bytes.len() - 100]);
    assert_refused(&p, &["truncated"]);
    // A header that declares far more than the file holds.
    let header_end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = String::from_utf8(bytes[..header_end].to_vec()).unwrap();
    let huge = header.replace(
        &format!("element face {}", mesh.triangle_count()),
        "element face 4000000000",
    );
    let mut lying = huge.into_bytes();
    lying.extend_from_slice(&bytes[header_end..]);
    let p = write("lying.ply", &lying);
    assert_refused(&p, &["truncated", "4000000000 faces"]);
    // NaN coordinates: the first vertex's x set to NaN in the binary file.
    let mut nan = bytes.clone();
    nan[header_end..header_end + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let p = write("nan.ply", &nan);
    assert_refused(&p, &["vertex 0", "non-finite position", "NaN"]);
    // A coordinate far beyond a building.
    let p = write(
        "far.ply",
        ascii_ply(
            &["0 0 0 1 1 1", "1e9 0 0 1 1 1", "0 1 0 1 1 1"],
            &["3 0 1 2"],
        )
        .as_bytes(),
    );
    assert_refused(&p, &["vertex 1", "sane range"]);
    // A header that is not PLY's.
    let p = write(
        "header.ply",
        b"ply\nformat ascii 1.0\nelement vertex two\nend_header\n",
    );
    assert_refused(&p, &["bad PLY file", "header"]);
    // No coordinates.
    let p = write("no_z.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0\n3 0 0 0\n");
    assert_refused(&p, &["`z`"]);
}

/// A `.gltf` with one triangle primitive, its buffer as a data URI.
fn gltf_json(
    positions: &[[f32; 3]],
    indices: &[u32],
    material: serde_json::Value,
    images: serde_json::Value,
) -> String {
    let mut bin: Vec<u8> = bytemuck::cast_slice(positions).to_vec();
    let index_offset = bin.len();
    bin.extend_from_slice(bytemuck::cast_slice(indices));
    let uv_offset = bin.len();
    let uvs: Vec<[f32; 2]> = positions.iter().map(|p| [p[0], p[1]]).collect();
    bin.extend_from_slice(bytemuck::cast_slice(&uvs));
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    );
    serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 2}, "indices": 1, "material": 0}]}],
        "materials": [material],
        "textures": [{"source": 0}],
        "images": images,
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": positions.len(), "type": "VEC3", "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]},
            {"bufferView": 1, "componentType": 5125, "count": indices.len(), "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5126, "count": positions.len(), "type": "VEC2"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": index_offset},
            {"buffer": 0, "byteOffset": index_offset, "byteLength": uv_offset - index_offset},
            {"buffer": 0, "byteOffset": uv_offset, "byteLength": bin.len() - uv_offset}
        ],
        "buffers": [{"byteLength": bin.len(), "uri": uri}]
    })
    .to_string()
}

const TRIANGLE: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

fn plain() -> serde_json::Value {
    serde_json::json!({"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1.0]}})
}

#[test]
fn bad_gltf_files_are_refused_naming_the_file_and_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, bytes: &[u8]| -> PathBuf {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    };
    let images = serde_json::json!([{"uri": "white.png"}]);
    image::GrayImage::from_pixel(4, 4, image::Luma([200u8]))
        .save(dir.path().join("white.png"))
        .unwrap();
    // The good file first: it loads, gray = luma of the factor.
    let good = write(
        "good.gltf",
        gltf_json(&TRIANGLE, &[0, 1, 2], plain(), images.clone()).as_bytes(),
    );
    let mesh = load_mesh(&good).unwrap();
    assert_eq!(mesh.triangle_count(), 1);
    assert!((mesh.gray[0] - 127.5).abs() < 1e-3, "{:?}", mesh.gray);
    // A texture that is missing, or not an image.
    let textured = serde_json::json!({"name": "wall", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}});
    let p = write(
        "textured.gltf",
        gltf_json(&TRIANGLE, &[0, 1, 2], textured.clone(), images).as_bytes(),
    );
    assert_eq!(load_mesh(&p).unwrap().textures.len(), 1);
    let p = write(
        "missing_texture.gltf",
        gltf_json(
            &TRIANGLE,
            &[0, 1, 2],
            textured.clone(),
            serde_json::json!([{"uri": "nowhere.png"}]),
        )
        .as_bytes(),
    );
    assert_refused(&p, &["nowhere.png", "does not exist", "wall"]);
    write("garbage.png", b"not an image at all");
    let p = write(
        "bad_texture.gltf",
        gltf_json(
            &TRIANGLE,
            &[0, 1, 2],
            textured,
            serde_json::json!([{"uri": "garbage.png"}]),
        )
        .as_bytes(),
    );
    let e = load_mesh(&p).expect_err("garbage texture");
    assert!(
        e.to_string().contains("garbage.png") && e.to_string().contains("cannot decode"),
        "{e}"
    );
    // An index out of range.
    let p = write(
        "index.gltf",
        gltf_json(
            &TRIANGLE,
            &[0, 1, 7],
            plain(),
            serde_json::json!([{"uri": "white.png"}]),
        )
        .as_bytes(),
    );
    assert_refused(&p, &["index 7 is out of range", "3 vertices"]);
    // NaN coordinates.
    let nan = [[0.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let p = write(
        "nan.gltf",
        gltf_json(
            &nan,
            &[0, 1, 2],
            plain(),
            serde_json::json!([{"uri": "white.png"}]),
        )
        .as_bytes(),
    );
    assert_refused(&p, &["vertex 1", "non-finite position"]);
    // No faces: a document without meshes.
    let p = write(
        "no_mesh.gltf",
        br#"{"asset": {"version": "2.0"}, "scenes": [{"nodes": []}], "scene": 0}"#,
    );
    assert_refused(&p, &["no faces"]);
    // Truncated GLB, and truncated JSON.
    let glb = dir.path().join("room.glb");
    write_glb(&vertex_colored_room(), &glb).unwrap();
    let bytes = std::fs::read(&glb).unwrap();
    let p = write("cut.glb", &bytes[..bytes.len() / 2]);
    assert_refused(&p, &["bad GLB file", "truncated"]);
    let p = write("tiny.glb", b"glTF\x02\0\0\0\x04\0\0\0");
    assert_refused(&p, &["bad GLB file"]);
    let text = std::fs::read(&good).unwrap();
    let p = write("cut.gltf", &text[..text.len() / 2]);
    assert_refused(&p, &["bad glTF file", "JSON"]);
    // A buffer file that is not there.
    let p = write(
        "lost_buffer.gltf",
        br#"{"asset": {"version": "2.0"}, "buffers": [{"byteLength": 12, "uri": "lost.bin"}]}"#,
    );
    assert_refused(&p, &["buffer 0", "lost.bin"]);
}

#[test]
fn content_that_is_not_what_the_extension_says_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = vertex_colored_room();
    let glb = dir.path().join("room.glb");
    write_glb(&mesh, &glb).unwrap();
    let renamed = dir.path().join("room.ply");
    std::fs::copy(&glb, &renamed).unwrap();
    assert_refused(&renamed, &["extension says PLY", "GLB"]);
    let ply = dir.path().join("scan.ply");
    write_ply(&mesh, &ply, PlyEncoding::Ascii).unwrap();
    let as_obj = dir.path().join("scan.obj");
    std::fs::copy(&ply, &as_obj).unwrap();
    assert_refused(&as_obj, &["extension says OBJ", "PLY header"]);
    let stl = dir.path().join("scan.stl");
    std::fs::write(&stl, b"solid").unwrap();
    assert_refused(&stl, &["unknown map format", "'stl'"]);
    // An OBJ cut in the middle of a face line.
    let obj = write_obj(&mesh, dir.path(), "cut").unwrap();
    let text = std::fs::read_to_string(&obj).unwrap();
    let last_face = text.trim_end().rfind("\nf ").unwrap();
    let cut = &text[..last_face + 1];
    let line = text[last_face + 1..].lines().next().unwrap();
    let two = line.rsplit_once(' ').unwrap().0;
    std::fs::write(&obj, format!("{cut}{two}")).unwrap();
    assert_refused(&obj, &["face has 2 corners", "truncated"]);
}
