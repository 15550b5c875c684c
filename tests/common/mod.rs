//! Helpers shared by integration tests that call the Python tools (evo) of
//! the project's virtual environment.
//!
//! The venv is `$STAR_VENV`, or `<repo>/.venv` by default. When it is
//! missing, a test fails if `CI` or `STAR_REQUIRE_VENV` is set, and otherwise
//! prints a loud SKIP message and returns early.

#![allow(dead_code)]

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
