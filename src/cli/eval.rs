//! `star eval GT EST`: absolute (no alignment) and relative pose error of an
//! estimated TUM trajectory against ground truth, printed as a table; with
//! `--frames` the counts of a flight log (`--record`), with `--plot` a PNG
//! of the trajectory and its errors over time.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use crate::dataset::Trajectory;
use crate::eval::evaluate;
use crate::output::plot::{gap_events, plot_png, PlotInput};
use crate::output::{read_frames_log, FrameLogSummary};

/// Arguments of `star eval`.
#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Ground-truth trajectory (TUM format, world_from_camera).
    pub gt: PathBuf,
    /// Estimated trajectory (TUM format, world_from_camera).
    pub est: PathBuf,
    /// Also compute the RPE over this many matched frames.
    #[arg(long)]
    pub delta: Option<usize>,
    /// Association tolerance in seconds (5 ms suits 50 Hz; use 0.02 for 30 Hz TUM).
    #[arg(long, default_value_t = crate::eval::DEFAULT_MAX_DT_S)]
    pub max_dt: f64,
    /// A flight log (`--record DIR`: the folder or its frames.csv): print
    /// its counts (frames, lost events, relocalizations, poses sent) and
    /// mark its events on the plot.
    #[arg(long, value_name = "CSV_OR_DIR")]
    pub frames: Option<PathBuf>,
    /// Draw the trajectory against the truth (top-down), and the
    /// translation and rotation error over time, into this PNG. Lost and
    /// relocalization events come from --frames, else from gaps in EST.
    #[arg(long, value_name = "OUT.png")]
    pub plot: Option<PathBuf>,
    /// Size of the plot, pixels.
    #[arg(long, value_name = "WxH", default_value = "1600x900", value_parser = parse_size)]
    pub plot_size: (u32, u32),
}

/// `WxH`, e.g. `1600x900`.
fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT (e.g. 1600x900), found `{text}`"))?;
    let parse = |s: &str, what: &str| {
        s.trim()
            .parse::<u32>()
            .map_err(|_| format!("{what} `{s}` in `{text}` is not a whole number of pixels"))
    };
    Ok((parse(w, "width")?, parse(h, "height")?))
}

/// Reads both trajectories, evaluates them and prints the table; reads the
/// flight log and draws the plot when asked.
pub fn run(args: &EvalArgs) -> Result<()> {
    let gt = Trajectory::read(&args.gt).context("reading the ground truth")?;
    let est = Trajectory::read(&args.est).context("reading the estimate")?;
    let evaluation = evaluate(&gt, &est, args.max_dt, args.delta).with_context(|| {
        format!(
            "evaluating {} against {}",
            args.est.display(),
            args.gt.display()
        )
    })?;
    println!(
        "ground truth: {}\nestimate:     {}",
        args.gt.display(),
        args.est.display()
    );
    print!("{evaluation}");
    let log = match &args.frames {
        Some(path) => {
            let rows =
                read_frames_log(path).with_context(|| format!("--frames {}", path.display()))?;
            let summary = FrameLogSummary::new(&rows);
            println!("flight log:   {}", path.display());
            print!("{summary}");
            Some(summary)
        }
        None => None,
    };
    if let Some(out) = &args.plot {
        plot(args, &gt, &est, log.as_ref(), out)?;
    }
    Ok(())
}

fn plot(
    args: &EvalArgs,
    gt: &Trajectory,
    est: &Trajectory,
    log: Option<&FrameLogSummary>,
    out: &Path,
) -> Result<()> {
    let inferred;
    let (events, events_from) = match log {
        Some(s) => (s.events.as_slice(), "flight log"),
        None => {
            inferred = gap_events(est);
            (inferred.as_slice(), "gap in EST")
        }
    };
    let input = PlotInput {
        ground_truth: gt,
        estimate: est,
        max_dt_s: args.max_dt,
        events,
        events_from,
    };
    if out
        .extension()
        .is_none_or(|e| !e.eq_ignore_ascii_case("png"))
    {
        bail!("--plot {}: the plot is a PNG; name it *.png", out.display());
    }
    plot_png(&input, out, args.plot_size).with_context(|| format!("--plot {}", out.display()))?;
    println!(
        "plot:         {} ({}x{}, {} events marked from the {events_from})",
        out.display(),
        args.plot_size.0,
        args.plot_size.1,
        events.len()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_size_parses_and_names_bad_parts() {
        assert_eq!(parse_size("640x480"), Ok((640, 480)));
        assert_eq!(parse_size("800X600"), Ok((800, 600)));
        assert!(parse_size("640").unwrap_err().contains("WIDTHxHEIGHT"));
        assert!(parse_size("ax480").unwrap_err().contains("width `a`"));
    }
}
