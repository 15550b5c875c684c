//! `star bench reloc --dataset`: relocalization queried with a dataset's
//! own frames against the database over the region it flies through, the
//! way the `scanned` figure is taken; its `--plan` picture; and the bench
//! options' bad input.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::process::Output;

use common::star_cli::{dataset, star};

fn text(o: &Output) -> String {
    format!(
        "status {}\nstdout:\n{}\nstderr:\n{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// The count before `needle` in `line`, e.g. `accepted but off: 0`.
fn count_after(out: &str, needle: &str) -> usize {
    let rest = out
        .split(needle)
        .nth(1)
        .unwrap_or_else(|| panic!("no {needle:?} in:\n{out}"));
    rest.trim_start()
        .split(|c: char| !c.is_ascii_digit())
        .next()
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no count after {needle:?} in:\n{out}"))
}

#[test]
fn a_dataset_s_own_frames_relocalize_and_none_is_accepted_off() {
    let tmp = tempfile::tempdir().unwrap();
    let db = tmp.path().join("flown.db");
    let ds = dataset().to_str().unwrap();
    let args = [
        "--log",
        "warn",
        "bench",
        "reloc",
        "--dataset",
        ds,
        "--database",
        db.to_str().unwrap(),
        "--queries",
        "6",
    ];
    let first = star(&args);
    assert!(first.status.success(), "{}", text(&first));
    assert!(
        db.exists(),
        "the database was not written: {}",
        text(&first)
    );
    let out = String::from_utf8_lossy(&first.stdout).to_string();
    assert!(out.contains("random frames of the dataset's 60"), "{out}");
    // Whole map, then the 2 m window: never a pose off the truth, and the
    // frames of a mapped room are found.
    let whole = out.split("search whole map").nth(1).expect("whole map");
    assert_eq!(count_after(whole, "accepted but off:"), 0, "{out}");
    let success = count_after(whole, "success (accepted, within 5 cm / 2 deg):");
    assert!(success >= 4, "{success} of 6 relocalized:\n{out}");
    // The second run reads the database written by the first, draws the
    // plan of its queries (`--plan`) and searches each from kidnapped
    // priors too (`--kidnaps`, its own stream), which changes no verdict
    // of the first two searches.
    let png = tmp.path().join("queries.png");
    let mut with_plan = args.to_vec();
    with_plan.extend_from_slice(&["--plan", png.to_str().unwrap(), "--kidnaps"]);
    let second = star(&with_plan);
    assert!(second.status.success(), "{}", text(&second));
    let out2 = String::from_utf8_lossy(&second.stdout).to_string();
    let verdicts = |out: &str| -> Vec<String> {
        out.lines()
            .filter(|l| l.contains("success (accepted"))
            .take(2)
            .map(str::to_owned)
            .collect()
    };
    assert_eq!(
        verdicts(&out),
        verdicts(&out2),
        "the same database and seed gave other verdicts"
    );
    assert!(out2.contains("  plan: "), "{out2}");
    // Kidnapped priors need frames 1.5-5 m apart; this flight is shorter,
    // and the bench says so instead of printing empty searches.
    assert!(
        out2.contains("kidnapped priors: none drawn") && !out2.contains("search kidnapped"),
        "{out2}"
    );
    let image = image::open(&png).expect("the plan is a PNG").to_rgb8();
    // Every relocalized query is ringed in green.
    assert!(
        image.pixels().any(|p| p.0 == [44, 160, 44]),
        "no relocalized query drawn"
    );
}

#[test]
fn bench_options_refuse_bad_input_with_a_message() {
    let o = star(&["bench", "integrity", "--kinds", "cold,sideways"]);
    assert!(!o.status.success(), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("unknown trial kind \"sideways\""),
        "{}",
        text(&o)
    );
    // A database without a dataset to fly over.
    let o = star(&["bench", "reloc", "--database", "/tmp/none.db"]);
    assert!(!o.status.success(), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("--dataset"),
        "{}",
        text(&o)
    );
    let o = star(&["bench", "reloc", "--dataset", "/nonexistent/star-ds"]);
    assert!(!o.status.success(), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("opening the dataset /nonexistent/star-ds"),
        "{}",
        text(&o)
    );
    assert!(!err.contains("panicked"), "{}", text(&o));
}
