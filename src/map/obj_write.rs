//! Wavefront OBJ writing of a gray [`Mesh`], the inverse of
//! [`crate::map::load_obj`].
//!
//! Takes a valid mesh, a folder and a file stem; writes `stem.obj` (vertex
//! gray as `v x y z g g g` with `g = gray/255`, uvs as `vt` with v flipped
//! back to OBJ's upward convention), `stem.mtl` (one material per texture,
//! `Kd 1 1 1`, `map_Kd stem_texN.png`, plus an untextured one) and one 8-bit
//! gray PNG per texture. Gray values are clamped to 0..=255 and textures
//! rounded to whole levels, so a round trip is exact to within one level.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use super::error::MapError;
use super::Mesh;

/// Writes `mesh` as `dir/stem.obj` + `dir/stem.mtl` + `dir/stem_texN.png`,
/// creating `dir` if needed. Returns the path of the `.obj`.
pub fn write_obj(mesh: &Mesh, dir: &Path, stem: &str) -> Result<PathBuf, MapError> {
    mesh.validate()?;
    std::fs::create_dir_all(dir).map_err(|source| MapError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    let obj_path = dir.join(format!("{stem}.obj"));
    let mtl_path = dir.join(format!("{stem}.mtl"));
    let texture_name = |i: usize| format!("{stem}_tex{i}.png");

    for (i, texture) in mesh.textures.iter().enumerate() {
        let path = dir.join(texture_name(i));
        let bytes: Vec<u8> = texture
            .texels
            .iter()
            .map(|&t| t.round().clamp(0.0, 255.0) as u8)
            .collect();
        let image =
            image::GrayImage::from_raw(texture.width, texture.height, bytes).ok_or_else(|| {
                MapError::TextureEncode {
                    path: path.clone(),
                    source: image::ImageError::Parameter(image::error::ParameterError::from_kind(
                        image::error::ParameterErrorKind::DimensionMismatch,
                    )),
                }
            })?;
        image
            .save_with_format(&path, image::ImageFormat::Png)
            .map_err(|source| MapError::TextureEncode { path, source })?;
    }

    let mut mtl = String::from("# written by star\nnewmtl untextured\nKd 1 1 1\n");
    for i in 0..mesh.textures.len() {
        mtl.push_str(&format!(
            "newmtl tex{i}\nKd 1 1 1\nmap_Kd {}\n",
            texture_name(i)
        ));
    }
    std::fs::write(&mtl_path, mtl).map_err(|source| MapError::Write {
        path: mtl_path.clone(),
        source,
    })?;

    let write_err = |source| MapError::Write {
        path: obj_path.clone(),
        source,
    };
    let file = File::create(&obj_path).map_err(write_err)?;
    let mut out = BufWriter::new(file);
    write_obj_body(mesh, stem, &mut out).map_err(write_err)?;
    out.flush().map_err(write_err)?;
    tracing::info!(
        path = %obj_path.display(),
        triangles = mesh.triangle_count(),
        textures = mesh.textures.len(),
        "mesh written"
    );
    Ok(obj_path)
}

fn write_obj_body(mesh: &Mesh, stem: &str, out: &mut impl Write) -> std::io::Result<()> {
    writeln!(out, "# written by star: gray mesh, vertex color = gray/255")?;
    writeln!(out, "mtllib {stem}.mtl")?;
    for (p, &gray) in mesh.positions.iter().zip(&mesh.gray) {
        let g = gray.clamp(0.0, 255.0) / 255.0;
        writeln!(out, "v {} {} {} {g} {g} {g}", p[0], p[1], p[2])?;
    }
    for uv in &mesh.uvs {
        writeln!(out, "vt {} {}", uv[0], 1.0 - uv[1])?;
    }
    for group in &mesh.groups {
        match group.texture {
            Some(t) => writeln!(out, "usemtl tex{t}")?,
            None => writeln!(out, "usemtl untextured")?,
        }
        let first = group.first_index as usize;
        let end = first + group.index_count as usize;
        for tri in mesh.indices[first..end].chunks_exact(3) {
            let (a, b, c) = (tri[0] + 1, tri[1] + 1, tri[2] + 1);
            if mesh.uvs.is_empty() {
                // Vertex colors only: no texture coordinates to refer to.
                writeln!(out, "f {a} {b} {c}")?;
            } else {
                writeln!(out, "f {a}/{a} {b}/{b} {c}/{c}")?;
            }
        }
    }
    Ok(())
}
