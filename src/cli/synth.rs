//! `star synth --preset NAME OUT`: write a synthetic TUM-layout dataset
//! (images, depth, ground truth, calibration, map mesh) from a named preset
//! and a seed, with a progress bar; `--list-presets` prints every preset's
//! exact parameters. `--scanned` (or `--preset scanned`) rebuilds the map
//! from a scanning run by TSDF fusion (Open3D, through Python) and writes
//! `OUT/star.toml`, the config that places that map in the world.
//! `--preset building` synthesizes a floor of rooms flown room to room;
//! `--rooms N` sets how many rooms; with `--scanned` the floor is scanned
//! room by room and along the corridor and fused at 2 cm voxels
//! (`docs/building-scale.md`).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};

use crate::synth::preset::{Preset, PRESET_NAMES};
use crate::synth::scanned::ScanTools;
use crate::synth::sequence::{write_sequence_with, SequenceOptions};

/// Arguments of `star synth`.
#[derive(Debug, clap::Args)]
pub struct SynthArgs {
    /// Preset name (see `--list-presets`).
    #[arg(long, default_value = "realistic")]
    pub preset: String,
    /// Output dataset folder (created; files in it are overwritten).
    #[arg(required_unless_present = "list_presets")]
    pub out: Option<PathBuf>,
    /// Seed of the scene, the trajectory and the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Number of frames (at the preset's 50 Hz).
    #[arg(long, default_value_t = 500)]
    pub frames: usize,
    /// Do not write depth images.
    #[arg(long)]
    pub no_depth: bool,
    /// Print every preset's exact parameters and exit.
    #[arg(long)]
    pub list_presets: bool,
    /// The scanned variant of the preset: the map is rebuilt by TSDF fusion
    /// of a noisy scanning run (in the scanner's frame, placed by
    /// OUT/star.toml), the flight gets a moving light and auto-exposure
    /// steps. `--preset scanned` is `realistic` with this.
    #[arg(long)]
    pub scanned: bool,
    /// A look-alike room: the textures of this seed's room in the layout of
    /// `--seed` (the integrity tests fly it to check that a place that
    /// looks the same is not taken for the mapped one).
    #[arg(long)]
    pub texture_seed: Option<u64>,
    /// Rooms of the `building` preset (1..=64; default 22): `--rooms 1` and
    /// `--rooms 4` make the smaller floors of the size table.
    #[arg(long)]
    pub rooms: Option<usize>,
    /// Rooms of one design of the `building` preset get the same furniture
    /// too, so they are the same to the last vertex (by default each room
    /// is furnished on its own: look-alikes that a careful gate can tell
    /// apart). From inside such a twin only the view through the door, or
    /// a motion prior, says which room it is.
    #[arg(long)]
    pub identical_rooms: bool,
    /// TSDF voxel edge of the scanned map, meters (default: the preset's,
    /// 0.01); a coarser voxel is faster (for tests).
    #[arg(long)]
    pub scan_voxel_m: Option<f64>,
    /// Python with open3d for the fusion (default: $STAR_PYTHON, else
    /// $STAR_VENV/bin/python, else ./.venv/bin/python, else python3).
    #[arg(long)]
    pub python: Option<PathBuf>,
}

/// Runs `star synth`.
pub fn run(args: &SynthArgs) -> Result<()> {
    if args.list_presets {
        for preset in Preset::all() {
            println!(
                "# preset `{}`: {}\n{}",
                preset.name,
                preset.description,
                preset.to_toml()
            );
        }
        return Ok(());
    }
    let Some(out) = args.out.as_ref() else {
        bail!("an output folder is required");
    };
    let Some(preset) = Preset::by_name(&args.preset) else {
        bail!(
            "unknown preset `{}`: expected one of {}",
            args.preset,
            PRESET_NAMES.join(", ")
        );
    };
    let mut preset = if args.scanned {
        preset.scanned()
    } else {
        preset
    };
    preset.scene.texture_seed = args.texture_seed;
    if let Some(rooms) = args.rooms {
        let Some(spec) = preset.scene.building.as_mut() else {
            bail!("--rooms applies to the building preset (--preset building)");
        };
        spec.rooms = rooms;
    }
    if args.identical_rooms {
        let Some(spec) = preset.scene.building.as_mut() else {
            bail!("--identical-rooms applies to the building preset (--preset building)");
        };
        spec.identical_rooms = true;
    }
    if let Some(spec) = &preset.scene.building {
        spec.validate().context("--rooms")?;
    }
    if let Some(voxel_m) = args.scan_voxel_m {
        let Some(spec) = preset.scanned.as_mut() else {
            bail!("--scan-voxel-m applies to a scanned preset (--preset scanned or --scanned)");
        };
        if !(0.002..=0.1).contains(&voxel_m) {
            bail!("--scan-voxel-m {voxel_m}: expected 0.002..=0.1 m");
        }
        spec.voxel_m = voxel_m;
    }
    let tools = match &args.python {
        Some(python) => ScanTools {
            python: python.clone(),
        },
        None => ScanTools::from_env(),
    };
    let options = SequenceOptions {
        preset,
        seed: args.seed,
        frames: args.frames,
        write_depth: !args.no_depth,
    };
    let bar = indicatif::ProgressBar::new(args.frames as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "synth {msg} [{bar:40}] {pos}/{len} frames, {per_sec}, eta {eta}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_message(args.preset.clone());
    let start = Instant::now();
    if options.preset.scanned.is_some() {
        bar.set_message(format!("{}: scanning run", args.preset));
    }
    let scan_bar = bar.clone();
    let scan_name = args.preset.clone();
    let mut scan_started = false;
    let summary = write_sequence_with(
        out,
        &options,
        &tools,
        &mut |done, total| {
            if !scan_started {
                scan_bar.set_length(total as u64);
                scan_started = true;
            }
            scan_bar.set_position(done as u64);
            if done == total {
                scan_bar.set_message(format!(
                    "{scan_name}: TSDF fusion (Open3D), then flight frames"
                ));
                scan_bar.set_position(0);
                scan_bar.set_length(options.frames as u64);
            }
        },
        &mut |n| {
            bar.set_message(args.preset.clone());
            bar.set_position(n as u64)
        },
    )
    .with_context(|| {
        format!(
            "synthesizing preset `{}` into {}",
            args.preset,
            out.display()
        )
    })?;
    bar.finish_and_clear();
    println!(
        "wrote {} frames of preset `{}` (seed {}) to {} in {:.1} s: {} renders, map {} ({} triangles)",
        summary.frames,
        args.preset,
        args.seed,
        summary.root.display(),
        start.elapsed().as_secs_f64(),
        summary.renders,
        summary.map_path.display(),
        summary.map_triangles
    );
    if let Some((rooms, area_m2, [x_m, y_m])) = summary.building {
        println!(
            "building: {rooms} room{} and a corridor, {area_m2:.0} m² of floor on a {x_m:.1} m x {y_m:.1} m footprint",
            if rooms == 1 { "" } else { "s" }
        );
    }
    if let Some(scanned) = &summary.scanned {
        let f = &scanned.fusion;
        println!(
            "scanned map: {} scan frames rendered in {:.1} s, fused by Open3D {} into {} vertices / {} triangles: {} tiles of {} m ({} voxels a side), {} integrations, {:.1} s (integrate {:.1} s, extract {:.1} s), peak memory {:.0} MB",
            scanned.scan_frames,
            scanned.scan_render_s,
            f.open3d,
            scanned.map_vertices,
            summary.map_triangles,
            f.tiles,
            f.tile_m,
            f.tile_voxels,
            f.integrations,
            f.total_s,
            f.integrate_s,
            f.extract_s,
            f.max_rss_mb
        );
        println!(
            "the map is in the scanner's frame; {} places it in the world: star localize {} --config {}",
            scanned.config_path.display(),
            summary.root.display(),
            scanned.config_path.display()
        );
    }
    Ok(())
}
