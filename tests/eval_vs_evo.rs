//! `star::eval` against evo: ATE without alignment (translation part and
//! rotation angle) and RPE over a frame delta must give the same statistics
//! as `evo_ape` / `evo_rpe` on the same files.

mod common;

use std::collections::HashMap;

use nalgebra::Vector6;
use rand::{RngExt, SeedableRng};
use star::dataset::Trajectory;
use star::eval::{ate, rpe, ErrorStats};
use star::geometry::exp_se3;

/// Parses evo's printed statistics (`   rmse\t0.123456`).
fn parse_evo_stats(stdout: &str) -> HashMap<String, f64> {
    stdout
        .lines()
        .filter_map(|l| {
            let mut it = l.split_whitespace();
            let (k, v) = (it.next()?, it.next()?);
            Some((k.to_string(), v.parse().ok()?))
        })
        .collect()
}

fn assert_same(ours: &ErrorStats, evo: &HashMap<String, f64>, what: &str) {
    for (key, value) in [
        ("rmse", ours.rmse),
        ("mean", ours.mean),
        ("median", ours.median),
        ("max", ours.max),
        ("std", ours.std),
    ] {
        let theirs = *evo
            .get(key)
            .unwrap_or_else(|| panic!("{what}: evo printed no {key}: {evo:?}"));
        assert!(
            (value - theirs).abs() < 1e-4,
            "{what} {key}: star {value} vs evo {theirs}"
        );
    }
}

#[test]
fn ate_and_rpe_match_evo() {
    let Some(evo_ape) = common::venv_tool("evo_ape") else {
        return;
    };
    let Some(evo_rpe) = common::venv_tool("evo_rpe") else {
        return;
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    let (mut gt, mut est) = (Trajectory::default(), Trajectory::default());
    for i in 0..400 {
        let t = i as f64 * 0.02;
        let pose = exp_se3(&Vector6::new(
            2.0 * (0.3 * t).sin(),
            1.5 * (0.2 * t).cos(),
            1.4 + 0.2 * t.sin(),
            0.3 * (0.5 * t).sin(),
            0.2 * (0.7 * t).cos(),
            0.4 * t,
        ));
        gt.push(t, pose);
        // The estimate drops every 7th frame, jitters its stamps by up to 2 ms,
        // and is off by a few cm and a degree or two.
        if i % 7 == 3 {
            continue;
        }
        let mut noise = Vector6::zeros();
        for k in 0..3 {
            noise[k] = rng.random_range(-0.05..0.05);
            noise[k + 3] = rng.random_range(-0.03..0.03);
        }
        est.push(t + rng.random_range(-0.002..0.002), pose * exp_se3(&noise));
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let gt_path = dir.path().join("gt.txt");
    let est_path = dir.path().join("est.txt");
    gt.write(&gt_path).expect("write gt");
    est.write(&est_path).expect("write est");
    let (g, e) = (
        gt_path.to_str().expect("utf-8"),
        est_path.to_str().expect("utf-8"),
    );
    let max_dt = "0.005";

    let ours = ate(&gt, &est, 0.005).expect("ate");
    assert_eq!(ours.translation_m.count, 400 - 57);
    let out = common::run_tool(
        &evo_ape,
        &["tum", g, e, "-r", "trans_part", "--t_max_diff", max_dt],
        dir.path(),
    );
    assert!(out.contains("not aligned"), "{out}");
    assert_same(
        &ours.translation_m,
        &parse_evo_stats(&out),
        "ATE translation",
    );
    let out = common::run_tool(
        &evo_ape,
        &["tum", g, e, "-r", "angle_deg", "--t_max_diff", max_dt],
        dir.path(),
    );
    assert_same(&ours.rotation_deg, &parse_evo_stats(&out), "ATE rotation");

    let ours = rpe(&gt, &est, 0.005, 10).expect("rpe");
    let rpe_args = |r: &'static str| {
        [
            "tum",
            g,
            e,
            "-r",
            r,
            "--t_max_diff",
            max_dt,
            "--delta",
            "10",
            "--delta_unit",
            "f",
        ]
    };
    let out = common::run_tool(&evo_rpe, &rpe_args("trans_part"), dir.path());
    assert_same(
        &ours.translation_m,
        &parse_evo_stats(&out),
        "RPE translation",
    );
    let out = common::run_tool(&evo_rpe, &rpe_args("angle_deg"), dir.path());
    assert_same(&ours.rotation_deg, &parse_evo_stats(&out), "RPE rotation");
}

#[test]
fn star_eval_prints_the_table() {
    let mut gt = Trajectory::default();
    for i in 0..20 {
        gt.push(
            i as f64 * 0.02,
            exp_se3(&Vector6::new(i as f64 * 0.1, 0.0, 0.0, 0.0, 0.0, 0.0)),
        );
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("gt.txt");
    gt.write(&path).expect("write");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_star"))
        .args([
            "eval",
            path.to_str().expect("utf-8"),
            path.to_str().expect("utf-8"),
            "--delta",
            "2",
        ])
        .output()
        .expect("run star");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("ATE translation [m]") && text.contains("RPE/2f"),
        "{text}"
    );
    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_star"))
        .args(["eval", "/nonexistent/gt.txt", path.to_str().expect("utf-8")])
        .output()
        .expect("run star");
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("/nonexistent/gt.txt"));
}
