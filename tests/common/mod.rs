//! Helpers shared by integration tests: the Python tools (evo) of the
//! project's virtual environment, per-test iceoryx2 resource prefixes, the
//! counting allocator of the allocation tests and the room meshes (which
//! the renderer benchmarks include too).
//!
//! [`open3d_python`]: the venv's Python when it has open3d (the TSDF
//! fusion of `star synth --preset scanned` and `scripts/map_from_rgbd.py`).
//!
//! The venv is `$STAR_VENV`, or `<repo>/.venv` by default. When it is
//! missing, a test fails if `CI` or `STAR_REQUIRE_VENV` is set, and otherwise
//! prints a loud SKIP message and returns early.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic
#![allow(dead_code)]

pub mod counting_alloc;
pub mod reloc_fixture;
pub mod room;
pub mod star_cli;
pub mod wall;

use std::path::PathBuf;
use std::process::Command;

/// The venv's `bin/NAME`, or `None` (after printing SKIP) when the venv is
/// missing and not required. Panics when it is required and missing.
pub fn venv_tool(name: &str) -> Option<PathBuf> {
    let venv = std::env::var_os("STAR_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(".venv"));
    let tool = venv.join("bin").join(name);
    if tool.exists() {
        return Some(tool);
    }
    let required =
        std::env::var_os("CI").is_some() || std::env::var_os("STAR_REQUIRE_VENV").is_some();
    assert!(
        !required,
        "{} not found and CI/STAR_REQUIRE_VENV is set; create the venv or set STAR_VENV",
        tool.display()
    );
    eprintln!(
        "\n**********\nSKIP: {} not found (set STAR_VENV to the Python venv with evo); \
         this test did not run\n**********\n",
        tool.display()
    );
    None
}

/// Runs `tool args...` with a private HOME (evo writes its settings there)
/// and returns stdout; panics with stderr on failure.
pub fn run_tool(tool: &PathBuf, args: &[&str], home: &std::path::Path) -> String {
    let out = Command::new(tool)
        .args(args)
        .env("HOME", home)
        .env("MPLBACKEND", "Agg")
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", tool.display()));
    assert!(
        out.status.success(),
        "{} {:?} failed: {}\n{}",
        tool.display(),
        args,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

// Helpers shared by the transport tests: an iceoryx2 config whose resource
// prefix is unique to one test, so tests running in parallel never share
// services.
use std::path::Path;

/// The resource prefix for `tag` in this test process.
pub fn prefix(tag: &str) -> String {
    format!("st{}_{}_", std::process::id(), tag)
}

/// Removes the shared-memory and descriptor files with this test's prefix
/// when dropped (iceoryx2 keeps a small global management segment per
/// prefix). Declare it first so it drops after the nodes.
pub struct Cleanup(pub String);

impl Drop for Cleanup {
    fn drop(&mut self) {
        for dir in ["/dev/shm", "/tmp/iceoryx2/nodes", "/tmp/iceoryx2/services"] {
            let Ok(entries) = std::fs::read_dir(dir) else {
                continue;
            };
            for entry in entries.flatten() {
                if entry.file_name().to_string_lossy().starts_with(&self.0) {
                    let _ = std::fs::remove_file(entry.path());
                }
            }
        }
    }
}

/// An iceoryx2 config with a prefix unique to this process and `tag`.
pub fn isolated_config(tag: &str) -> iceoryx2::config::Config {
    let prefix = prefix(tag);
    star::ipc::load_iceoryx_config(Path::new("/nonexistent/iceoryx2.toml"), Some(&prefix))
        .expect("isolated iceoryx2 config")
}

/// Writes an iceoryx2 config file with that prefix (for child processes)
/// and a star config that points at it; returns the star config path.
pub fn write_isolated_configs(dir: &Path, tag: &str, extra_star_toml: &str) -> std::path::PathBuf {
    let prefix = prefix(tag);
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/iceoryx2.toml");
    let text = std::fs::read_to_string(shipped).expect("shipped iceoryx2.toml");
    let text = text.replace("prefix = \"iox2_\"", &format!("prefix = \"{prefix}\""));
    assert!(
        text.contains(&prefix),
        "config/iceoryx2.toml must set prefix = \"iox2_\""
    );
    let iox = dir.join("iceoryx2.toml");
    std::fs::write(&iox, text).expect("write iceoryx2.toml");
    let star = dir.join("star.toml");
    std::fs::write(
        &star,
        format!(
            "[ipc]\niceoryx2_config = \"{}\"\nsilence_timeout_ms = 200\n{extra_star_toml}",
            iox.display()
        ),
    )
    .expect("write star.toml");
    star
}

/// The venv's python when it has open3d; `None` (after a SKIP message)
/// when it does not and the venv is not required.
pub fn open3d_python() -> Option<PathBuf> {
    let python = venv_tool("python")?;
    let ok = Command::new(&python)
        .args(["-c", "import open3d"])
        .output()
        .is_ok_and(|o| o.status.success());
    if ok {
        return Some(python);
    }
    let required =
        std::env::var_os("CI").is_some() || std::env::var_os("STAR_REQUIRE_VENV").is_some();
    assert!(
        !required,
        "{} cannot import open3d and CI/STAR_REQUIRE_VENV is set; pip install -r hil_tests/requirements.txt",
        python.display()
    );
    eprintln!(
        "\n**********\nSKIP: {} has no open3d (pip install -r hil_tests/requirements.txt); \
         this test did not run\n**********\n",
        python.display()
    );
    None
}
