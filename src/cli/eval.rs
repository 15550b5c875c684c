//! `star eval GT EST`: absolute (no alignment) and relative pose error of an
//! estimated TUM trajectory against ground truth, printed as a table; with
//! `--frames` the counts of a flight log (`--record`).

use std::path::PathBuf;

use anyhow::{Context, Result};

use crate::dataset::Trajectory;
use crate::eval::evaluate;
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
    /// its counts (frames, lost events, relocalizations, poses sent).
    #[arg(long, value_name = "CSV_OR_DIR")]
    pub frames: Option<PathBuf>,
}

/// Reads both trajectories, evaluates them and prints the table; reads the
/// flight log when asked.
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
    if let Some(path) = &args.frames {
        let rows = read_frames_log(path).with_context(|| format!("--frames {}", path.display()))?;
        let summary = FrameLogSummary::new(&rows);
        println!("flight log:   {}", path.display());
        print!("{summary}");
    }
    Ok(())
}
