//! Renderer selection and runtime fallback with real renderers: `auto`
//! starts on wgpu (lavapipe here), and a forced failure of the GPU renderer
//! switches to the CPU rasterizer while rendering continues.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::sync::Arc;

use nalgebra::{Translation3, UnitQuaternion};
use star::config::RendererKind;
use star::geometry::{PinholeCamera, Pose};
use star::map::{Mesh, MeshGroup};
use star::render::cpu::CpuRenderer;
use star::render::gpu::{self, AdapterClass};
use star::render::select::{make_renderer, FallbackRenderer, Stage};
use star::render::{RenderedView, Renderer};

/// A floor and a box-like wall: enough geometry for depth and gray to vary.
fn scene() -> Arc<Mesh> {
    let mut mesh = Mesh::default();
    let mut quad = |c: [[f32; 3]; 4], gray: f32| {
        let base = mesh.positions.len() as u32;
        mesh.positions.extend(c);
        mesh.gray.extend([gray, gray * 0.5, gray, gray * 0.8]);
        mesh.uvs.extend([[0.0, 0.0]; 4]);
        mesh.indices
            .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
    };
    quad(
        [
            [-5.0, -5.0, 0.0],
            [5.0, -5.0, 0.0],
            [5.0, 5.0, 0.0],
            [-5.0, 5.0, 0.0],
        ],
        200.0,
    );
    quad(
        [
            [1.0, -1.0, 0.0],
            [1.0, 1.0, 0.0],
            [1.0, 1.0, 1.5],
            [1.0, -1.0, 1.5],
        ],
        120.0,
    );
    mesh.groups = vec![MeshGroup {
        first_index: 0,
        index_count: 12,
        texture: None,
    }];
    Arc::new(mesh)
}

/// Cameras at 1.2 m height looking along +x, stepping sideways.
fn pose(step: usize) -> Pose {
    // Optical frame: x right = -y_world, y down = -z_world, z forward = +x_world.
    let rotation = UnitQuaternion::from_matrix(&nalgebra::Matrix3::new(
        0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0,
    ));
    Pose::from_parts(Translation3::new(-2.0, 0.1 * step as f64, 1.2), rotation)
}

fn camera() -> PinholeCamera {
    PinholeCamera::new(160, 128, 105.0, 105.0, 79.5, 63.5)
}

#[test]
fn auto_takes_a_hardware_adapter_else_the_cpu_rasterizer() {
    let r = make_renderer(RendererKind::Auto, scene()).expect("auto always starts");
    let hardware = gpu::list_adapters()
        .iter()
        .any(|a| a.class == AdapterClass::Hardware);
    if hardware {
        assert!(r.name().starts_with("wgpu"), "auto chose {}", r.name());
    } else {
        // A software adapter (lavapipe) is slower than the CPU rasterizer:
        // auto never takes it.
        assert_eq!(r.name(), "cpu", "auto chose {}", r.name());
    }
    let software = make_renderer(RendererKind::Software, scene());
    if gpu::lavapipe_installed() {
        assert!(software
            .expect("software adapter")
            .name()
            .starts_with("wgpu"));
    }
    if !hardware {
        let Err(err) = make_renderer(RendererKind::Gpu, scene()) else {
            panic!("gpu is strict: no hardware adapter must be an error");
        };
        assert!(err.to_string().contains("hardware"), "{err}");
    }
}

#[test]
fn forced_gpu_failure_falls_back_and_rendering_continues() {
    // The software adapter (lavapipe here) fails over to the CPU rasterizer,
    // as a hardware adapter under `auto` does.
    let map = scene();
    let Ok(mut r) = FallbackRenderer::new(RendererKind::Software, Arc::clone(&map)) else {
        assert!(
            !gpu::lavapipe_installed(),
            "lavapipe installed but the software adapter did not start"
        );
        eprintln!("SKIPPED: no wgpu software adapter (lavapipe) on this machine");
        return;
    };
    assert_eq!(
        Arc::strong_count(&map),
        2,
        "the map is kept while the CPU rasterizer may still have to start"
    );
    assert!(r.inject_failure_after(2));
    let camera = camera();
    let mut reference = CpuRenderer::new(scene()).expect("cpu");
    let mut out = RenderedView::for_camera(&camera);
    let mut expected = RenderedView::for_camera(&camera);
    let mut names = Vec::new();
    for step in 0..5 {
        r.render(&pose(step), &camera, &mut out)
            .expect("rendering continues through the failure");
        names.push(r.name());
        let hits = out.depth_m.data().iter().filter(|&&d| d > 0.0).count();
        assert!(hits > 1000, "step {step}: only {hits} pixels hit");
        if r.active_stage() == Stage::Cpu {
            reference
                .render(&pose(step), &camera, &mut expected)
                .expect("cpu");
            assert_eq!(
                out.depth_m, expected.depth_m,
                "step {step} is the CPU's render"
            );
        }
    }
    assert!(
        names[0].starts_with("wgpu") && names[1] == names[0],
        "{names:?}"
    );
    assert_ne!(
        names[2], names[1],
        "the third render switched renderer: {names:?}"
    );
    assert!(names[2..].iter().all(|n| n == &names[2]), "{names:?}");
    assert_eq!(
        r.active_stage(),
        Stage::Cpu,
        "software falls back to the CPU"
    );
    assert_eq!(
        Arc::strong_count(&map),
        1,
        "once on the last stage the renderer lets the map go"
    );
}

#[test]
fn request_errors_do_not_trigger_fallback() {
    // On the software adapter where there is one: a wgpu stage has a
    // fallback that a bad request must not trigger.
    let mut r = FallbackRenderer::new(RendererKind::Software, scene())
        .or_else(|_| FallbackRenderer::new(RendererKind::Auto, scene()))
        .expect("auto");
    let before = r.active_stage();
    let camera = camera();
    let mut wrong = RenderedView::new(10, 10);
    assert!(r.render(&pose(0), &camera, &mut wrong).is_err());
    assert_eq!(
        r.active_stage(),
        before,
        "a bad request is not a backend failure"
    );
}
