//! `star check-config`: load and validate a configuration, then open every
//! file it names, and print the effective configuration.
//!
//! The files: the map mesh (loaded in full, with its warnings: undefined
//! materials, no colors), the relocalization database (read, and checked
//! against that map and the camera intrinsics), the iceoryx2 config (parsed
//! when the file exists; iceoryx2's defaults otherwise, as at run time) and
//! a `replay:` source's dataset. `--values-only` skips the files, for a
//! config written before the map exists (the install step checks the
//! shipped config that way).
//!
//! It warns (`# warning:`, exit status still 0) when the source is known
//! to deliver frames of another size than `[camera.intrinsics]`: a
//! `pattern:WxH` source, a replay dataset's `camera.toml` or first frame
//! ([`known_frame_sizes`]). The tracker refuses such frames.

use std::path::Path;

use anyhow::{Context, Result};

use crate::camera::{known_frame_sizes, SourceUri};
use crate::config::Config;
use crate::reloc::{map_fingerprint, RelocDatabase};

/// Loads `path`, validates it, opens the files it names unless
/// `values_only`, and prints the effective configuration.
pub fn run(path: &Path, values_only: bool) -> Result<()> {
    let config = Config::load(path)?;
    if !values_only {
        check_files(&config).with_context(|| format!("{} names a bad file", path.display()))?;
    }
    warn_frame_size(&config, !values_only)
        .with_context(|| format!("{}: camera.source", path.display()))?;
    let text = toml::to_string_pretty(&config)?;
    println!("# {} is valid; effective values:\n{text}", path.display());
    Ok(())
}

/// Prints a warning for each size the source is known to deliver that is
/// not the calibration's.
fn warn_frame_size(config: &Config, open_files: bool) -> Result<()> {
    let uri = SourceUri::parse(&config.camera.source)?;
    let c = &config.camera.intrinsics;
    if let SourceUri::V4l2(_) | SourceUri::Aravis(_) = uri {
        println!(
            "# camera.source {uri}: the camera is asked for {}x{} (the calibration's size); one that delivers another size is warned about by `star camera`, and its frames are refused by `star track`",
            c.width, c.height
        );
    }
    for known in known_frame_sizes(&uri, open_files)? {
        let (w, h) = (known.width, known.height);
        if (w, h) != (c.width, c.height) {
            println!(
                "# warning: {} is {w}x{h} but [camera.intrinsics] is {}x{}: star track refuses frames of another size than the calibration; calibrate at {w}x{h} (`star calib import`) or change the source",
                known.origin, c.width, c.height
            );
        }
    }
    Ok(())
}

/// Opens every file `config` names; prints one line per file.
fn check_files(config: &Config) -> Result<()> {
    let mesh_path = &config.map.mesh;
    let mesh = config
        .map
        .load_mesh()
        .with_context(|| format!("map.mesh: loading {}", mesh_path.display()))?;
    println!(
        "# map {}: {} triangles, {} vertices, {} textures",
        mesh_path.display(),
        mesh.triangle_count(),
        mesh.positions.len(),
        mesh.textures.len()
    );
    if let Some(db_path) = &config.reloc.database {
        let db = RelocDatabase::read(db_path)
            .with_context(|| format!("reloc.database: reading {}", db_path.display()))?;
        db.check_compatible(&config.camera.intrinsics, map_fingerprint(&mesh))
            .with_context(|| {
                format!(
                    "reloc.database {} against map {} and [camera.intrinsics]",
                    db_path.display(),
                    mesh_path.display()
                )
            })?;
        println!(
            "# relocalization database {}: {} views, built for this map and these intrinsics",
            db_path.display(),
            db.entries.len()
        );
    }
    let iox_path = &config.ipc.iceoryx2_config;
    if iox_path.exists() {
        crate::ipc::load_iceoryx_config(iox_path, None)
            .with_context(|| format!("ipc.iceoryx2_config: parsing {}", iox_path.display()))?;
        println!("# iceoryx2 config {}: parsed", iox_path.display());
    } else {
        println!(
            "# iceoryx2 config {} does not exist: iceoryx2's defaults apply",
            iox_path.display()
        );
    }
    let uri = SourceUri::parse(&config.camera.source).context("camera.source")?;
    if let SourceUri::Replay(dir) = &uri {
        let dataset = crate::dataset::Dataset::open(dir)
            .with_context(|| format!("camera.source: opening dataset {}", dir.display()))?;
        println!(
            "# replay dataset {}: {} frames",
            dir.display(),
            dataset.len()
        );
    }
    Ok(())
}
