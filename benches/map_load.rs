//! Loading a large binary PLY map: seconds and the process's peak resident
//! memory (VmHWM), against the file size and the size of the mesh's own
//! arrays, to show that loading streams (a fixed buffer plus the mesh, no
//! copy of the file, no per-element map).
//!
//! Two steps, each its own process so the peak of one is not the other's:
//!
//! ```sh
//! cargo bench --bench map_load -- write /tmp/big.ply 5000000   # a room subdivided to >= 5M triangles
//! cargo bench --bench map_load -- load /tmp/big.ply            # prints the figures
//! ```
//!
//! The room is the renderer benchmarks' (`tests/common/room.rs`) with its
//! texture dropped and a gray per vertex.

#![allow(clippy::expect_used, clippy::unwrap_used)]

#[path = "../tests/common/room.rs"]
mod room;

use std::path::Path;
use std::time::Instant;

use star::map::{load_mesh, subdivide, write_ply, PlyEncoding};

/// A field of /proc/self/status in kB.
fn status_kb(key: &str) -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with(key))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    match args
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>()
        .as_slice()
    {
        ["write", path, triangles] => {
            let mut base = room::room(8, 2);
            for g in &mut base.groups {
                g.texture = None;
            }
            base.textures.clear();
            base.uvs.clear();
            let mesh = subdivide(&base, triangles.parse().expect("a triangle count"));
            write_ply(&mesh, Path::new(path), PlyEncoding::BinaryLittleEndian).expect("write");
            println!(
                "wrote {path}: {} triangles, {} vertices, {} bytes",
                mesh.triangle_count(),
                mesh.positions.len(),
                std::fs::metadata(path).map(|m| m.len()).unwrap_or(0)
            );
        }
        ["load", path] => {
            let rss_before_kb = status_kb("VmRSS:");
            let start = Instant::now();
            let mesh = load_mesh(Path::new(path)).expect("load");
            let load_s = start.elapsed().as_secs_f64();
            let peak_kb = status_kb("VmHWM:");
            let file_bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
            let mesh_bytes = mesh.positions.len() * 16 + mesh.indices.len() * 4;
            println!(
                "load {path}: {} triangles, {} vertices, file {:.1} MB; {load_s:.2} s; \
                 peak RSS {:.1} MB (before loading {:.1} MB); the mesh's arrays {:.1} MB",
                mesh.triangle_count(),
                mesh.positions.len(),
                file_bytes as f64 / 1e6,
                peak_kb as f64 / 1e3,
                rss_before_kb as f64 / 1e3,
                mesh_bytes as f64 / 1e6
            );
        }
        _ => eprintln!("usage: map_load write PATH TRIANGLES | map_load load PATH"),
    }
}
