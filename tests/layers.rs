//! The module layers only point down: a module imports only modules of a
//! lower layer. Reads every `crate::MODULE` path in `src/` (comments
//! skipped) and fails naming the file, the line and the two modules when a
//! module reaches up or sideways, or when a module is missing from the table.
//!
//! The table is ARCHITECTURE.md's, from the leaves up; within a row no
//! module imports another.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

const LAYERS: &[&[&str]] = &[
    // Leaves.
    &["clock", "rng", "settings", "geometry", "imgproc"],
    // The map: a mesh placed in the world frame by a geometry transform.
    &["map"],
    // Drivers and data formats.
    &["render", "ipc", "mavlink_io", "dataset", "service"],
    // Built on one of those: the tracker core on the renderer, the camera
    // sources on the frame transport, the metrics on the trajectory format,
    // calibration import on the camera model and the frame capacity.
    &["track", "camera", "eval", "calib"],
    &["reloc"],
    // The STAR loop; the test-data generator (flight code never imports it).
    &["localizer", "synth"],
    // Outputs for people: the flight log, its pictures, the plots.
    &["output"],
    // Aggregates every module's config section.
    &["config"],
    // The processes.
    &["tracker", "offline"],
    // Benchmark runners (they drive the processes' code).
    &["bench"],
    // Arguments and printing only.
    &["cli"],
];

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|row| row.contains(&module))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("read src") {
        let path = entry.expect("dir entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// `src/a/b.rs` and `src/a.rs` belong to module `a`; `lib.rs` and `main.rs` to none.
fn module_of(src: &Path, file: &Path) -> Option<String> {
    let first = file.strip_prefix(src).ok()?.components().next()?;
    let name = first.as_os_str().to_str()?.trim_end_matches(".rs");
    (name != "lib" && name != "main").then(|| name.to_string())
}

/// Every `crate::NAME` on a line of code (not a comment).
fn imported_modules(line: &str) -> Vec<&str> {
    let code = line.trim_start();
    if code.starts_with("//") {
        return Vec::new();
    }
    let code = code.split(" //").next().unwrap_or(code);
    let mut found = Vec::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        let after = &rest[i + "crate::".len()..];
        let end = after
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .unwrap_or(after.len());
        found.push(&after[..end]);
        rest = &after[end..];
    }
    found
}

#[test]
fn layers_only_point_down() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let mut violations = Vec::new();
    let mut edges: BTreeMap<(String, String), usize> = BTreeMap::new();
    for file in &files {
        let Some(module) = module_of(&src, file) else {
            continue;
        };
        let Some(from) = layer_of(&module) else {
            violations.push(format!(
                "module `{module}` ({}) is not in the layer table",
                file.display()
            ));
            continue;
        };
        let text = std::fs::read_to_string(file).expect("read source");
        for (n, line) in text.lines().enumerate() {
            for target in imported_modules(line) {
                if target == module {
                    continue;
                }
                *edges
                    .entry((module.clone(), target.to_string()))
                    .or_default() += 1;
                match layer_of(target) {
                    Some(to) if to < from => {}
                    Some(to) => violations.push(format!(
                        "{}:{}: `{module}` (layer {from}) imports `{target}` (layer {to}): {}",
                        file.display(),
                        n + 1,
                        line.trim()
                    )),
                    None => violations.push(format!(
                        "{}:{}: `{target}` is not in the layer table",
                        file.display(),
                        n + 1
                    )),
                }
            }
        }
    }
    assert!(
        violations.is_empty(),
        "{} import(s) break the layers:\n{}",
        violations.len(),
        violations.join("\n")
    );
    // The scan itself must see the known edges, or it checks nothing.
    for (from, to) in [
        ("tracker", "localizer"),
        ("camera", "ipc"),
        ("reloc", "track"),
    ] {
        assert!(
            edges.contains_key(&(from.to_string(), to.to_string())),
            "expected `{from}` to import `{to}`; the scan is broken"
        );
    }
}

#[test]
fn the_scan_sees_imports_and_skips_comments() {
    assert_eq!(imported_modules("use crate::track::{A, B};"), ["track"]);
    assert_eq!(
        imported_modules("    let x = crate::map::load(crate::geometry::Pose::identity());"),
        ["map", "geometry"]
    );
    assert!(imported_modules("//! See [`crate::config::Config`].").is_empty());
    assert_eq!(imported_modules("f(crate::rng::X); // crate::cli"), ["rng"]);
}
