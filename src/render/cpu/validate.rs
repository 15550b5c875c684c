//! Mesh validation for the CPU renderer.
//!
//! Takes a [`Mesh`] and either rejects it with a [`RenderError::InvalidMesh`]
//! naming the field, the element and the problem, or gives out the texture
//! index of every triangle (resolved from the groups), so the hot path never
//! meets an out-of-range index or a non-finite value.

use super::setup::NO_TEXTURE;
use crate::map::Mesh;
use crate::render::RenderError;

fn invalid(field: &'static str, index: usize, reason: String) -> RenderError {
    RenderError::InvalidMesh {
        field,
        index,
        reason,
    }
}

/// Checks `mesh` and returns the texture index (or [`NO_TEXTURE`]) of each
/// triangle. Triangles outside every group are untextured; `uvs` may be
/// empty when no group is textured.
pub(super) fn validate_mesh(mesh: &Mesh) -> Result<Vec<u32>, RenderError> {
    let n = mesh.positions.len();
    if n > u32::MAX as usize {
        return Err(invalid("positions", n, "more than 2^32 vertices".into()));
    }
    if let Some((i, p)) = mesh
        .positions
        .iter()
        .enumerate()
        .find(|(_, p)| !p.iter().all(|c| c.is_finite()))
    {
        return Err(invalid(
            "positions",
            i,
            format!("expected finite coordinates, found {p:?}"),
        ));
    }
    if mesh.gray.len() != n {
        return Err(invalid(
            "gray",
            mesh.gray.len(),
            format!(
                "expected one gray value per vertex ({n}), found {}",
                mesh.gray.len()
            ),
        ));
    }
    if let Some((i, g)) = mesh.gray.iter().enumerate().find(|(_, g)| !g.is_finite()) {
        return Err(invalid(
            "gray",
            i,
            format!("expected a finite value, found {g}"),
        ));
    }
    let textured = mesh.groups.iter().any(|g| g.texture.is_some());
    if mesh.uvs.len() != n && (textured || !mesh.uvs.is_empty()) {
        return Err(invalid(
            "uvs",
            mesh.uvs.len(),
            format!("expected one uv per vertex ({n}), found {}", mesh.uvs.len()),
        ));
    }
    if let Some((i, uv)) = mesh
        .uvs
        .iter()
        .enumerate()
        .find(|(_, uv)| !(uv[0].is_finite() && uv[1].is_finite()))
    {
        return Err(invalid(
            "uvs",
            i,
            format!("expected finite coordinates, found {uv:?}"),
        ));
    }
    if mesh.indices.len() % 3 != 0 {
        return Err(invalid(
            "indices",
            mesh.indices.len(),
            format!(
                "expected a multiple of 3 indices, found {}",
                mesh.indices.len()
            ),
        ));
    }
    if let Some((i, &v)) = mesh
        .indices
        .iter()
        .enumerate()
        .find(|(_, &v)| v as usize >= n)
    {
        return Err(invalid(
            "indices",
            i,
            format!("vertex index {v} out of range (the mesh has {n} vertices)"),
        ));
    }
    for (i, t) in mesh.textures.iter().enumerate() {
        let want = t.width as usize * t.height as usize;
        if t.width == 0 || t.height == 0 || t.texels.len() != want {
            return Err(invalid(
                "textures",
                i,
                format!(
                    "expected {}x{} = {want} texels (non-empty), found {}",
                    t.width,
                    t.height,
                    t.texels.len()
                ),
            ));
        }
        if t.texels.iter().any(|v| !v.is_finite()) {
            return Err(invalid("textures", i, "texels must be finite".into()));
        }
    }
    let tris = mesh.indices.len() / 3;
    let mut tri_texture = vec![NO_TEXTURE; tris];
    let mut covered = vec![false; tris];
    for (gi, g) in mesh.groups.iter().enumerate() {
        let (first, count) = (g.first_index as usize, g.index_count as usize);
        if first % 3 != 0 || count % 3 != 0 || first + count > mesh.indices.len() {
            return Err(invalid(
                "groups",
                gi,
                format!(
                    "indices {first}..{} must be whole triangles within the {} indices",
                    first + count,
                    mesh.indices.len()
                ),
            ));
        }
        let texture = match g.texture {
            Some(t) if t as usize >= mesh.textures.len() => {
                return Err(invalid(
                    "groups",
                    gi,
                    format!(
                        "texture {t} out of range (the mesh has {} textures)",
                        mesh.textures.len()
                    ),
                ))
            }
            Some(t) => t,
            None => NO_TEXTURE,
        };
        for t in first / 3..(first + count) / 3 {
            if std::mem::replace(&mut covered[t], true) {
                return Err(invalid(
                    "groups",
                    gi,
                    format!("triangle {t} is already in another group"),
                ));
            }
            tri_texture[t] = texture;
        }
    }
    Ok(tri_texture)
}
