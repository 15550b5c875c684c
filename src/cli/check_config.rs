//! `star check-config`: load, validate and print a configuration.

use std::path::Path;

use anyhow::Result;

use crate::config::Config;

/// Loads `path`, validates it, and prints the effective configuration.
pub fn run(path: &Path) -> Result<()> {
    let config = Config::load(path)?;
    let text = toml::to_string_pretty(&config)?;
    println!("# {} is valid; effective values:\n{text}", path.display());
    Ok(())
}
