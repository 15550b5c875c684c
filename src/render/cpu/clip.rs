//! Sutherland-Hodgman clipping of one triangle against the near plane and
//! the guard band, in the camera frame.
//!
//! Takes the three camera-frame vertices with their attributes (gray, uv),
//! gives out a convex polygon of up to [`MAX_POLY`] vertices with linearly
//! interpolated attributes (linear in the camera frame, hence correct under
//! perspective). The intersection on an edge is always computed from its
//! inside end to its outside end, so two triangles sharing an edge cut it at
//! bit-identical points and the mesh stays watertight after clipping.

use super::view::{View, CLIP_PLANES, NEAR_M};

/// Most vertices a triangle can have after clipping against 5 planes.
pub(super) const MAX_POLY: usize = 3 + CLIP_PLANES;

/// A vertex being clipped: camera-frame position and attributes.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct ClipVertex {
    /// Camera-frame position, meters.
    pub p: [f32; 3],
    /// Vertex gray, 0..=255.
    pub gray: f32,
    /// Texture coordinates.
    pub uv: [f32; 2],
}

impl ClipVertex {
    #[inline]
    fn lerp(a: &Self, b: &Self, t: f32) -> Self {
        let l = |x: f32, y: f32| x + t * (y - x);
        Self {
            p: [l(a.p[0], b.p[0]), l(a.p[1], b.p[1]), l(a.p[2], b.p[2])],
            gray: l(a.gray, b.gray),
            uv: [l(a.uv[0], b.uv[0]), l(a.uv[1], b.uv[1])],
        }
    }
}

/// A clipped convex polygon.
#[derive(Debug, Clone, Copy)]
pub(super) struct Polygon {
    /// Vertices; the first `len` are valid.
    pub verts: [ClipVertex; MAX_POLY],
    /// Number of valid vertices.
    pub len: usize,
}

impl Polygon {
    /// A triangle.
    pub fn triangle(v: [ClipVertex; 3]) -> Self {
        let mut verts = [ClipVertex::default(); MAX_POLY];
        verts[..3].copy_from_slice(&v);
        Self { verts, len: 3 }
    }

    /// Clips against every plane `i < CLIP_PLANES` whose bit is set in
    /// `mask` (plane 0 is the near plane). The polygon may become empty.
    pub fn clip(&mut self, view: &View, mask: u32) {
        for plane in 0..CLIP_PLANES {
            if mask & (1 << plane) != 0 && self.len >= 3 {
                self.clip_plane(view, plane);
            }
        }
    }

    fn clip_plane(&mut self, view: &View, plane: usize) {
        let mut out = [ClipVertex::default(); MAX_POLY];
        let mut n = 0;
        for i in 0..self.len {
            let a = &self.verts[i];
            let b = &self.verts[(i + 1) % self.len];
            let da = view.plane_value(plane, a.p.into());
            let db = view.plane_value(plane, b.p.into());
            let a_in = da >= 0.0;
            if a_in && n < MAX_POLY {
                out[n] = *a;
                n += 1;
            }
            if a_in != (db >= 0.0) && n < MAX_POLY {
                let (inside, outside, d_in, d_out) =
                    if a_in { (a, b, da, db) } else { (b, a, db, da) };
                let t = d_in / (d_in - d_out);
                let mut v = ClipVertex::lerp(inside, outside, t);
                if plane == 0 {
                    v.p[2] = NEAR_M;
                }
                out[n] = v;
                n += 1;
            }
        }
        self.verts = out;
        self.len = n;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{PinholeCamera, Pose};

    fn v(p: [f32; 3]) -> ClipVertex {
        ClipVertex {
            p,
            gray: p[2] * 10.0,
            uv: [p[0], p[1]],
        }
    }

    #[test]
    fn near_clip_keeps_the_front_part() {
        let cam = PinholeCamera::new(64, 64, 50.0, 50.0, 31.5, 31.5);
        let view = View::new(&Pose::identity(), &cam);
        // One vertex behind the camera, two in front: a quad remains.
        let mut poly =
            Polygon::triangle([v([0.0, 0.0, -1.0]), v([1.0, 0.0, 1.0]), v([0.0, 1.0, 1.0])]);
        poly.clip(&view, 1);
        assert_eq!(poly.len, 4);
        for c in &poly.verts[..poly.len] {
            assert!(c.p[2] >= NEAR_M);
            // Attributes stay linear in the camera frame.
            assert!((c.gray - c.p[2] * 10.0).abs() < 1e-4);
        }
        // Two vertices behind: a triangle remains.
        let mut poly =
            Polygon::triangle([v([0.0, 0.0, -1.0]), v([1.0, 0.0, -1.0]), v([0.0, 1.0, 1.0])]);
        poly.clip(&view, 1);
        assert_eq!(poly.len, 3);
        // All behind: nothing remains.
        let mut poly = Polygon::triangle([
            v([0.0, 0.0, -1.0]),
            v([1.0, 0.0, -1.0]),
            v([0.0, 1.0, -1.0]),
        ]);
        poly.clip(&view, 1);
        assert_eq!(poly.len, 0);
    }

    #[test]
    fn shared_edge_is_cut_at_the_same_point() {
        let cam = PinholeCamera::new(64, 64, 50.0, 50.0, 31.5, 31.5);
        let view = View::new(&Pose::identity(), &cam);
        let a = v([0.3, -0.7, -2.0]);
        let b = v([-0.4, 0.9, 3.7]);
        let mut t1 = Polygon::triangle([a, b, v([5.0, 1.0, 2.0])]);
        let mut t2 = Polygon::triangle([b, a, v([-5.0, 1.0, 2.0])]);
        t1.clip(&view, 1);
        t2.clip(&view, 1);
        let on_near = |p: &Polygon| {
            let mut pts: Vec<[u32; 3]> = p.verts[..p.len]
                .iter()
                .filter(|c| c.p[2] == NEAR_M)
                .map(|c| c.p.map(f32::to_bits))
                .collect();
            pts.sort();
            pts
        };
        let shared: Vec<_> = on_near(&t1)
            .into_iter()
            .filter(|p| on_near(&t2).contains(p))
            .collect();
        assert_eq!(
            shared.len(),
            1,
            "the a-b edge crossing must be bit-identical"
        );
    }
}
