//! A map larger than the GPU budget streams its chunks and renders the
//! same image: a 4-room floor of the `building` preset (built in memory
//! from seed 1) rendered by wgpu (lavapipe where installed) from 36 poses
//! through its rooms, doorways and corridor, with the whole mesh resident
//! and with `gpu_budget_mb` at a quarter of the mesh's vertex and index
//! bytes (chunks uploaded into a slot pool, least recently used evicted),
//! and from every third pose with a pool of 8 slots (views drawn in
//! several passes): gray and depth must be identical bit for bit. Also: a
//! budget below one chunk is refused with the key and the minimum, through
//! the configured renderer chain too.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::sync::Arc;

use nalgebra::Translation3;
use star::geometry::look::camera_rotation;
use star::geometry::{PinholeCamera, Pose};
use star::map::Mesh;
use star::render::gpu::{self, AdapterPreference, GpuError, GpuRenderer};
use star::render::select::{FallbackRenderer, DEFAULT_FAR_M};
use star::render::{RenderConfig, RenderError, RenderedView, Renderer, RendererKind};
use star::synth::preset::Preset;
use star::synth::sequence::preset_scene;
use star::synth::SplitMix64;

/// Poses rendered.
const POSES: usize = 36;

/// `POSES` poses through the floor: each room's corridor point, door,
/// inside point and loop in turn, looking every way (up to 20 degrees up
/// or down), every seventh along the corridor.
fn poses(scene: &star::synth::Scene) -> Vec<Pose> {
    let plan = scene.plan.as_ref().expect("a building");
    let routes = plan.routes();
    let mut rng = SplitMix64::new(22);
    let middle_x = 0.5 * (plan.corridor_min_m[0] + plan.corridor_max_m[0]);
    (0..POSES)
        .map(|i| {
            let r = &routes[i % routes.len()];
            let points = [
                r.corridor_m,
                r.door_m,
                r.inside_m,
                r.loop_m[0],
                r.loop_m[1],
                r.loop_m[2],
            ];
            let along_corridor = i % 7 == 0;
            let p = if along_corridor {
                r.corridor_m
            } else {
                points[(i / routes.len() + i) % points.len()]
            };
            let yaw = match (along_corridor, p[0] < middle_x) {
                (true, true) => 0.0,
                (true, false) => std::f64::consts::PI,
                _ => rng.range(-std::f64::consts::PI, std::f64::consts::PI),
            };
            let pitch = rng.range(-20f64, 20.0).to_radians();
            let z = rng.range(0.8, 2.0);
            Pose::from_parts(
                Translation3::new(p[0], p[1], z),
                camera_rotation(yaw, pitch, 0.0),
            )
        })
        .collect()
}

/// The adapter class to test on: the software one where it works, else a
/// hardware one; `None` (test skipped) only when wgpu sees no adapter.
fn adapter_class(mesh: &Arc<Mesh>) -> Option<AdapterPreference> {
    for which in [AdapterPreference::Software, AdapterPreference::Hardware] {
        if GpuRenderer::new(Arc::clone(mesh), which).is_ok() {
            return Some(which);
        }
    }
    let adapters = gpu::list_adapters();
    assert!(
        adapters.is_empty() && !gpu::lavapipe_installed(),
        "wgpu sees adapters ({adapters:?}) but none renders this map"
    );
    None
}

fn same(a: &RenderedView, b: &RenderedView) -> bool {
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    bits(a.gray.data()) == bits(b.gray.data()) && bits(a.depth_m.data()) == bits(b.depth_m.data())
}

#[test]
fn streamed_chunks_render_the_same_image_as_the_resident_mesh() {
    let mut preset = Preset::by_name("building").unwrap();
    if let Some(spec) = preset.scene.building.as_mut() {
        spec.rooms = 4;
    }
    let scene = preset_scene(&preset, 1);
    let poses = poses(&scene);
    let mesh = Arc::new(scene.map.clone());
    let camera: PinholeCamera = preset.camera.pinhole();
    let Some(which) = adapter_class(&mesh) else {
        eprintln!("SKIPPED: wgpu sees no adapter at all (no GPU, no lavapipe)");
        return;
    };
    let far = Some(DEFAULT_FAR_M);

    let mut resident = GpuRenderer::new(Arc::clone(&mesh), which).unwrap();
    resident.set_far_m(far);
    // A streamed mesh is drawn with the frustum cull only; so is the
    // resident one here. (The occlusion cull leaves out walls seen exactly
    // edge-on, which lavapipe may still rasterize into a pixel: these poses
    // stand in wall planes. tests/render_gpu_occlusion.rs tests that cull.)
    resident.set_occlusion_cull(false);
    let whole_bytes = resident.memory().mesh_buffer_bytes;
    assert_eq!(resident.stream_stats().slots, 0, "no budget: resident");
    // A budget above the mesh: resident as well.
    let roomy = GpuRenderer::new_with_budget(Arc::clone(&mesh), which, whole_bytes).unwrap();
    assert_eq!(roomy.stream_stats().slots, 0);
    drop(roomy);

    let budget_bytes = whole_bytes / 4;
    let mut streamed =
        GpuRenderer::new_with_budget(Arc::clone(&mesh), which, budget_bytes).unwrap();
    streamed.set_far_m(far);
    let pool = streamed.stream_stats();
    assert!(pool.slots > 0, "a quarter of the mesh must stream");
    let pool_bytes = streamed.memory().mesh_buffer_bytes;
    assert!(pool_bytes <= budget_bytes && pool_bytes > budget_bytes - pool.slot_bytes);
    assert_eq!(
        resident.memory().texture_bytes,
        streamed.memory().texture_bytes
    );

    // 8 slots: most views need several passes.
    let mut narrow =
        GpuRenderer::new_with_budget(Arc::clone(&mesh), which, 8 * pool.slot_bytes).unwrap();
    narrow.set_far_m(far);
    assert_eq!(narrow.stream_stats().slots, 8);

    let (mut a, mut b) = (
        RenderedView::for_camera(&camera),
        RenderedView::for_camera(&camera),
    );
    for (k, pose) in poses.iter().enumerate() {
        resident.render(pose, &camera, &mut a).unwrap();
        let hits = a.depth_m.data().iter().filter(|&&d| d > 0.0).count();
        assert!(
            hits > a.depth_m.data().len() / 2,
            "pose {k} sees mostly nothing"
        );
        streamed.render(pose, &camera, &mut b).unwrap();
        assert!(
            same(&a, &b),
            "pose {k} ({pose:?}): streaming changed the image"
        );
        if k % 3 == 0 {
            narrow.render(pose, &camera, &mut b).unwrap();
            assert!(
                same(&a, &b),
                "pose {k} ({pose:?}): multi-pass changed the image"
            );
        }
    }
    let s = streamed.stream_stats();
    let n = narrow.stream_stats();
    eprintln!(
        "whole mesh {:.1} MB in {} chunks; budget {:.1} MB: {} slots of {:.0} kB, {s:?}; 8 slots: {n:?}",
        whole_bytes as f64 / 1e6,
        streamed.cull_stats().chunks,
        budget_bytes as f64 / 1e6,
        pool.slots,
        pool.slot_bytes as f64 / 1e3,
    );
    assert_eq!(s.renders, POSES as u64);
    assert!(
        s.evictions > 0,
        "the budget never forced an eviction: {s:?}"
    );
    assert!(s.uploads >= s.evictions + s.slots as u64 / 2, "{s:?}");
    assert!(
        n.passes > n.renders,
        "8 slots never needed a second pass: {n:?}"
    );

    // A budget below one chunk: refused with the key and the minimum.
    let err = GpuRenderer::new_with_budget(Arc::clone(&mesh), which, 1000).unwrap_err();
    let GpuError::BudgetTooSmall { min_mb, .. } = err else {
        panic!("expected BudgetTooSmall, got {err}");
    };
    assert!(
        (min_mb * 1e6 - pool.slot_bytes as f64).abs() < 1000.0,
        "{min_mb}"
    );
    let text = err_text(&mesh, which);
    assert!(
        text.contains("render.gpu_budget_mb") && text.contains("minimum"),
        "{text}"
    );
}

/// The error of the configured renderer chain with a 1 kB budget.
fn err_text(mesh: &Arc<Mesh>, which: AdapterPreference) -> String {
    let config = RenderConfig {
        renderer: match which {
            AdapterPreference::Software => RendererKind::Software,
            AdapterPreference::Hardware => RendererKind::Gpu,
        },
        gpu_budget_mb: 0.001,
        ..RenderConfig::default()
    };
    match FallbackRenderer::configured(&config, Arc::clone(mesh)) {
        Err(e @ RenderError::Setting(_)) => e.to_string(),
        Err(e) => panic!("expected a setting error, got {e}"),
        Ok(_) => panic!("a 1 kB budget was accepted"),
    }
}
