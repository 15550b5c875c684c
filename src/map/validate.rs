//! Structural validation of an in-memory [`Mesh`]: finite attributes,
//! indices in range, groups covering the indices, textures consistent.
//!
//! Takes a mesh, gives out `Ok(())` or the first [`MeshProblem`] found. The
//! OBJ loader runs the same checks, and renderers call [`Mesh::validate`]
//! before uploading a mesh built in code.

use std::path::PathBuf;

use super::error::{MapError, MeshProblem, IN_MEMORY};
use super::Mesh;

impl Mesh {
    /// Checks the mesh is renderable: at least one triangle, attribute
    /// arrays sized like `positions` (`uvs` may be empty when no group is
    /// textured), finite positions/gray/uvs, indices in range, groups
    /// covering `indices` exactly once in order (or no groups at all: every
    /// triangle untextured), textures existing and of consistent size with
    /// finite texels.
    ///
    /// The error names [`IN_MEMORY`] as the file; the loader replaces it.
    pub fn validate(&self) -> Result<(), MapError> {
        self.find_problem().map_err(|problem| MapError::Invalid {
            path: PathBuf::from(IN_MEMORY),
            problem,
        })
    }

    /// The first structural problem, if any.
    pub fn find_problem(&self) -> Result<(), MeshProblem> {
        let n = self.positions.len();
        if self.indices.is_empty() {
            return Err(MeshProblem::NoFaces);
        }
        if self.indices.len() % 3 != 0 {
            return Err(MeshProblem::IndexCount {
                count: self.indices.len(),
            });
        }
        let textured = self.groups.iter().any(|g| g.texture.is_some());
        let uvs_optional = !textured && self.uvs.is_empty();
        for (what, found) in [("gray", self.gray.len()), ("uvs", self.uvs.len())] {
            if found != n && !(what == "uvs" && uvs_optional) {
                return Err(MeshProblem::AttributeCount {
                    what,
                    expected: n,
                    found,
                });
            }
        }
        for (vertex, p) in self.positions.iter().enumerate() {
            if let Some(&value) = p.iter().find(|c| !c.is_finite()) {
                return Err(MeshProblem::NotFinite {
                    vertex,
                    what: "position",
                    value,
                });
            }
        }
        for (vertex, &value) in self.gray.iter().enumerate() {
            if !value.is_finite() {
                return Err(MeshProblem::NotFinite {
                    vertex,
                    what: "gray",
                    value,
                });
            }
        }
        for (vertex, uv) in self.uvs.iter().enumerate() {
            if let Some(&value) = uv.iter().find(|c| !c.is_finite()) {
                return Err(MeshProblem::NotFinite {
                    vertex,
                    what: "uv",
                    value,
                });
            }
        }
        for (i, &index) in self.indices.iter().enumerate() {
            if index as usize >= n {
                return Err(MeshProblem::IndexOutOfRange {
                    triangle: i / 3,
                    index,
                    vertex_count: n,
                });
            }
        }
        self.check_groups()?;
        self.check_textures()
    }

    fn check_groups(&self) -> Result<(), MeshProblem> {
        if self.groups.is_empty() {
            return Ok(()); // no groups: every triangle untextured
        }
        let mut next: u64 = 0;
        for (group, g) in self.groups.iter().enumerate() {
            let end = u64::from(g.first_index) + u64::from(g.index_count);
            if u64::from(g.first_index) != next
                || g.index_count % 3 != 0
                || end > self.indices.len() as u64
            {
                return Err(MeshProblem::GroupCoverage {
                    group,
                    first: g.first_index,
                    end,
                    expected_first: next,
                    index_count: self.indices.len(),
                });
            }
            if let Some(texture) = g.texture {
                if texture as usize >= self.textures.len() {
                    return Err(MeshProblem::TextureOutOfRange {
                        group,
                        texture,
                        texture_count: self.textures.len(),
                    });
                }
            }
            next = end;
        }
        if next != self.indices.len() as u64 {
            return Err(MeshProblem::GroupCoverage {
                group: self.groups.len(),
                first: next as u32,
                end: self.indices.len() as u64,
                expected_first: next,
                index_count: self.indices.len(),
            });
        }
        Ok(())
    }

    fn check_textures(&self) -> Result<(), MeshProblem> {
        for (texture, t) in self.textures.iter().enumerate() {
            let expected = t.width as usize * t.height as usize;
            if expected == 0 || t.texels.len() != expected {
                return Err(MeshProblem::TextureSize {
                    texture,
                    width: t.width,
                    height: t.height,
                    found: t.texels.len(),
                });
            }
            if let Some((texel, &value)) = t.texels.iter().enumerate().find(|(_, v)| !v.is_finite())
            {
                return Err(MeshProblem::TextureNotFinite {
                    texture,
                    texel,
                    value,
                });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::{GrayTexture, MeshGroup};

    fn quad() -> Mesh {
        Mesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ],
            gray: vec![255.0; 4],
            uvs: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
            indices: vec![0, 1, 2, 0, 2, 3],
            groups: vec![
                MeshGroup {
                    first_index: 0,
                    index_count: 3,
                    texture: None,
                },
                MeshGroup {
                    first_index: 3,
                    index_count: 3,
                    texture: Some(0),
                },
            ],
            textures: vec![GrayTexture {
                width: 2,
                height: 1,
                texels: vec![10.0, 20.0],
            }],
        }
    }

    #[test]
    fn valid_mesh_passes() {
        assert!(quad().validate().is_ok());
    }

    #[test]
    fn each_defect_is_reported() {
        let mut m = quad();
        m.indices.clear();
        m.groups.clear();
        assert_eq!(m.find_problem(), Err(MeshProblem::NoFaces));

        let mut m = quad();
        m.positions[2][1] = f32::NAN;
        assert!(matches!(
            m.find_problem(),
            Err(MeshProblem::NotFinite {
                vertex: 2,
                what: "position",
                ..
            })
        ));

        let mut m = quad();
        m.gray[1] = f32::INFINITY;
        assert!(matches!(
            m.find_problem(),
            Err(MeshProblem::NotFinite {
                vertex: 1,
                what: "gray",
                ..
            })
        ));

        let mut m = quad();
        m.indices[4] = 9;
        assert_eq!(
            m.find_problem(),
            Err(MeshProblem::IndexOutOfRange {
                triangle: 1,
                index: 9,
                vertex_count: 4
            })
        );

        let mut m = quad();
        m.groups.pop();
        assert!(matches!(
            m.find_problem(),
            Err(MeshProblem::GroupCoverage { .. })
        ));

        let mut m = quad();
        m.groups[1].texture = Some(3);
        assert!(matches!(
            m.find_problem(),
            Err(MeshProblem::TextureOutOfRange { .. })
        ));

        let mut m = quad();
        m.textures[0].texels.pop();
        assert!(matches!(
            m.find_problem(),
            Err(MeshProblem::TextureSize { .. })
        ));

        // No groups and no uvs: a plain untextured mesh is fine.
        let mut m = quad();
        m.groups.clear();
        m.uvs.clear();
        assert_eq!(m.find_problem(), Ok(()));

        let mut m = quad();
        m.uvs.pop();
        assert!(matches!(
            m.find_problem(),
            Err(MeshProblem::AttributeCount { what: "uvs", .. })
        ));
    }

    #[test]
    fn validate_names_in_memory_source() {
        let mut m = quad();
        m.indices.clear();
        let err = m.validate().unwrap_err();
        assert!(err.to_string().contains(IN_MEMORY), "{err}");
    }
}
