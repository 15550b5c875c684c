//! `star eval GT EST`: absolute (no alignment) and relative pose error of an
//! estimated TUM trajectory against ground truth, printed as a table.

use std::path::Path;

use anyhow::{Context, Result};

use crate::dataset::Trajectory;
use crate::eval::evaluate;

/// Reads both trajectories, evaluates them and prints the table.
pub fn run(gt_path: &Path, est_path: &Path, delta: Option<usize>, max_dt_s: f64) -> Result<()> {
    let gt = Trajectory::read(gt_path).context("reading the ground truth")?;
    let est = Trajectory::read(est_path).context("reading the estimate")?;
    let evaluation = evaluate(&gt, &est, max_dt_s, delta).with_context(|| {
        format!(
            "evaluating {} against {}",
            est_path.display(),
            gt_path.display()
        )
    })?;
    println!(
        "ground truth: {}\nestimate:     {}",
        gt_path.display(),
        est_path.display()
    );
    print!("{evaluation}");
    Ok(())
}
