//! Helpers shared by the transport tests: an iceoryx2 config whose resource
//! prefix is unique to one test, so tests running in parallel never share
//! services.

#![allow(dead_code)]

use std::path::Path;

/// An iceoryx2 config with a prefix unique to this process and `tag`.
pub fn isolated_config(tag: &str) -> iceoryx2::config::Config {
    let prefix = format!("st{}_{}_", std::process::id(), tag);
    star::ipc::load_iceoryx_config(Path::new("/nonexistent/iceoryx2.toml"), Some(&prefix))
        .expect("isolated iceoryx2 config")
}

/// Writes an iceoryx2 config file with that prefix (for child processes)
/// and a star config that points at it; returns the star config path.
pub fn write_isolated_configs(dir: &Path, tag: &str, extra_star_toml: &str) -> std::path::PathBuf {
    let prefix = format!("st{}_{}_", std::process::id(), tag);
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/iceoryx2.toml");
    let text = std::fs::read_to_string(shipped).expect("shipped iceoryx2.toml");
    let text = text.replace("prefix = \"iox2_\"", &format!("prefix = \"{prefix}\""));
    assert!(text.contains(&prefix), "config/iceoryx2.toml must set prefix = \"iox2_\"");
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
