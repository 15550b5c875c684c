//! `star doctor`: checks what this machine offers the flight binary and
//! prints a report, one section per subsystem.
//!
//! The renderer section lists every wgpu adapter (Vulkan and GL), says which
//! one `renderer = "auto"` would choose, and renders a small test view with
//! the configured renderer kind. Later sections (camera, IPC, MAVLink) get
//! their own functions here.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result};

use crate::config::{Config, RendererKind};
use crate::geometry::{PinholeCamera, Pose};
use crate::map::{Mesh, MeshGroup};
use crate::render::gpu::{self, AdapterClass};
use crate::render::select::make_renderer;
use crate::render::RenderedView;

/// Runs every check; `config` (optional) supplies the configured renderer kind.
pub fn run(config: Option<&Path>) -> Result<()> {
    let kind = match config {
        Some(path) => Config::load(path)?.render.renderer,
        None => RendererKind::Auto,
    };
    check_renderer(kind)
}

/// The renderer section: adapters, auto's choice, and a test render.
pub fn check_renderer(kind: RendererKind) -> Result<()> {
    println!("renderer");
    let adapters = gpu::list_adapters();
    if adapters.is_empty() {
        println!("  wgpu adapters: none (Vulkan and GL)");
    }
    for a in &adapters {
        let class = match a.class {
            AdapterClass::Hardware => "hardware",
            AdapterClass::Software => "software",
        };
        println!("  wgpu adapter [{class} #{}]: {a}", a.rank);
    }
    println!(
        "  lavapipe (Mesa Vulkan software driver): {}",
        if gpu::lavapipe_installed() {
            "installed"
        } else {
            "not installed (apt install mesa-vulkan-drivers)"
        }
    );
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        // Mesa's complaint, printed (on stderr) while the adapters above were
        // listed: harmless, and alarming in a journal.
        println!(
            "  XDG_RUNTIME_DIR: not set; Mesa prints \"error: XDG_RUNTIME_DIR is invalid or not \
             set\" when wgpu starts (harmless: no display is used). star-track.service sets it; \
             elsewhere export XDG_RUNTIME_DIR=/run/user/$(id -u) or any folder this user owns"
        );
    }
    match gpu::auto_choice(&adapters) {
        Some(a) => println!("  auto would choose: wgpu on {} ({:?})", a.name, a.backend),
        None => println!(
            "  auto would choose: the CPU rasterizer (no hardware wgpu adapter; \
             auto prefers it to a software adapter, which is slower)"
        ),
    }

    // A quad in front of the camera, rendered by the configured kind.
    let mesh = Arc::new(test_quad());
    let mut renderer =
        make_renderer(kind, mesh).with_context(|| format!("starting the `{kind:?}` renderer"))?;
    let camera = PinholeCamera::new(64, 48, 40.0, 40.0, 31.5, 23.5);
    let mut view = RenderedView::for_camera(&camera);
    renderer
        .render(&Pose::identity(), &camera, &mut view)
        .with_context(|| format!("test render on {}", renderer.name()))?;
    let center = view.depth_m.get(32, 24).unwrap_or(0.0);
    anyhow::ensure!(
        (center - 2.0).abs() < 1e-3,
        "test render on {} gave depth {center} m at the center, expected 2 m",
        renderer.name()
    );
    println!("  test render ({kind:?}): ok on {}", renderer.name());
    Ok(())
}

/// A 2 m x 2 m gray quad 2 m in front of the identity pose.
fn test_quad() -> Mesh {
    Mesh {
        positions: vec![
            [-1.0, -1.0, 2.0],
            [1.0, -1.0, 2.0],
            [1.0, 1.0, 2.0],
            [-1.0, 1.0, 2.0],
        ],
        gray: vec![128.0; 4],
        uvs: vec![[0.0, 0.0]; 4],
        indices: vec![0, 1, 2, 0, 2, 3],
        groups: vec![MeshGroup {
            first_index: 0,
            index_count: 6,
            texture: None,
        }],
        textures: Vec::new(),
    }
}
