//! The wgpu renderer's chunk cull: drawing only the chunks that meet the
//! view frustum gives the same image, bit for bit, as drawing them all
//! (from poses inside the textured test room and random poses around it),
//! and chunks behind the camera are not drawn.
//!
//! Runs for real on Mesa's lavapipe where it is installed; finding no
//! adapter there is a failure, never a skip.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::sync::Arc;

use nalgebra::{Translation3, UnitQuaternion, Vector3};
use star::geometry::{PinholeCamera, Pose};
use star::map::subdivide;
use star::render::gpu::{self, AdapterPreference, GpuRenderer};
use star::render::{RenderedView, Renderer};

#[path = "common/room.rs"]
mod room;

/// The software renderer (lavapipe), else a hardware one; `None` (said out
/// loud) only where there is no adapter and lavapipe is not installed.
fn gpu_renderer(mesh: &Arc<star::map::Mesh>) -> Option<GpuRenderer> {
    let software = GpuRenderer::new(Arc::clone(mesh), AdapterPreference::Software);
    match software.or_else(|e| {
        GpuRenderer::new(Arc::clone(mesh), AdapterPreference::Hardware)
            .map_err(|h| format!("{e}; {h}"))
    }) {
        Ok(r) => Some(r),
        Err(e) if gpu::lavapipe_installed() => {
            panic!("lavapipe is installed but no wgpu adapter works: {e}")
        }
        Err(e) => {
            eprintln!("SKIPPED: no wgpu adapter and no lavapipe on this machine: {e}");
            None
        }
    }
}

#[test]
fn cull_never_changes_the_image_and_skips_chunks() {
    // The 8 x 3 x 6 m room (y down), about 100k triangles: ~25 chunks.
    let mesh = Arc::new(subdivide(&room::room(8, 2), 100_000));
    let Some(mut culled) = gpu_renderer(&mesh) else {
        return;
    };
    let mut full = gpu_renderer(&mesh).unwrap();
    full.set_frustum_cull(false);
    let camera = PinholeCamera::new(160, 128, 105.0, 105.0, 79.5, 63.5);
    let mut poses = room::poses();
    let mut state = 5u64;
    let mut rnd = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..24 {
        let t = Translation3::new(rnd() * 10.0 - 5.0, rnd() * 4.0 - 2.0, rnd() * 8.0 - 4.0);
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(
            rnd() * 6.0 - 3.0,
            rnd() * 6.0 - 3.0,
            rnd() * 6.0 - 3.0,
        ));
        poses.push(Pose::from_parts(t, r));
    }
    let mut a = RenderedView::for_camera(&camera);
    let mut b = RenderedView::for_camera(&camera);
    let (mut skipped, mut hits) = (0usize, 0usize);
    for (k, pose) in poses.iter().enumerate() {
        culled.render(pose, &camera, &mut a).unwrap();
        full.render(pose, &camera, &mut b).unwrap();
        assert!(a.gray.data() == b.gray.data(), "gray differs at pose {k}");
        assert!(
            a.depth_m.data() == b.depth_m.data(),
            "depth differs at pose {k}"
        );
        let stats = culled.cull_stats();
        assert_eq!(stats.triangles, mesh.triangle_count());
        assert_eq!(full.cull_stats().visible_chunks, stats.chunks);
        skipped += stats.chunks - stats.visible_chunks;
        hits += a.depth_m.data().iter().filter(|&&z| z > 0.0).count();
    }
    assert!(
        hits > poses.len() * 160 * 128 / 4,
        "{hits} pixels hit: the views should see the room"
    );
    assert!(
        skipped > poses.len(),
        "{skipped} chunks skipped in {} renders",
        poses.len()
    );
    // At the room center looking at the +x wall (+90 deg about y turns the
    // optical axis from +z to +x): the -x half of the room is behind.
    let at_wall = Pose::from_parts(
        Translation3::new(0.0, 0.0, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::FRAC_PI_2),
    );
    culled.render(&at_wall, &camera, &mut a).unwrap();
    let stats = culled.cull_stats();
    assert!(stats.visible_chunks < stats.chunks, "{stats:?}");
    assert!(stats.visible_fraction() < 0.75, "{stats:?}");
    assert!(
        a.depth_m.data().iter().all(|&z| z > 0.0),
        "the wall fills the view"
    );
}
