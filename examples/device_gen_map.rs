//! The map of `star synth --preset building --rooms N --frames 1
//! --no-depth OUT` (seed 1), without the camera back ends linked in: for
//! the GPU machine the render figures were taken on, which lacks
//! libaravis. Not part of the product; `star synth` is.
//! Usage: `device_gen_map ROOMS OUT`.

use anyhow::Context;
use star::synth::preset::Preset;
use star::synth::sequence::{write_sequence, SequenceOptions};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(rooms), Some(out)) = (args.get(1), args.get(2)) else {
        anyhow::bail!("usage: device_gen_map ROOMS OUT");
    };
    let mut preset = Preset::by_name("building").context("preset")?;
    if let Some(spec) = preset.scene.building.as_mut() {
        spec.rooms = rooms.parse().context("ROOMS")?;
    }
    let options = SequenceOptions {
        preset,
        seed: 1,
        frames: 1,
        write_depth: false,
    };
    write_sequence(std::path::Path::new(out), &options, &mut |_| {})?;
    Ok(())
}
