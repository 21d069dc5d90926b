//! Registration on real laser data: single 180° SICK scans from public CARMEN logs, with the
//! logs' SLAM-corrected poses (good to ~5 cm) as the truth, so success means ≤ 15 cm / 1.5°.
//!
//! The logs live in `../shared/datasets/radish-carmen-corrected/`, beside the repository and
//! not in it (their licence keeps them out). Where they are absent each test says so on stderr
//! and passes without checking anything; CI has them. `SCANFUSE_CARMEN_DIR` points elsewhere.
//!
//! The draws are fixed (seeded), so the figures are too; the bounds sit a little below what
//! was measured, to catch a regression (a broken beam-angle convention, a free-space check
//! that no longer bites) rather than noise. They are not the targets (85 % right, ≤ 2 %
//! confidently wrong), which single 180° scans do not reach yet; `scanfuse eval --only real`
//! gives the full tables.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use scanfuse::geometry::{Mount, Pose2, pose_error};
use scanfuse::record::carmen::{self, LogScan};
use scanfuse::register::model::shared_view;
use scanfuse::register::{RegisterParams, ScanModel, register_pair};
use std::path::PathBuf;

const TOL_M: f64 = 0.15;
const TOL_DEG: f64 = 1.5;

/// The scans of one log, or `None` (said on stderr) when the datasets are absent.
fn log(name: &str) -> Option<Vec<LogScan>> {
    let dir = std::env::var_os("SCANFUSE_CARMEN_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("../shared/datasets/radish-carmen-corrected")
        });
    let path = dir.join(format!("{name}-corrected.log.gz"));
    if !path.is_file() {
        eprintln!(
            "skipping: {} is absent (the CARMEN logs ship beside the repository, not in it)",
            path.display()
        );
        return None;
    }
    Some(carmen::load(&path).unwrap_or_else(|e| panic!("{e}")))
}

fn model(s: &LogScan, p: &RegisterParams) -> ScanModel {
    ScanModel::from_scan(&s.scan, None, &Mount::default(), p)
}

fn within(estimate: &Pose2, truth: &Pose2) -> bool {
    let (dt, dyaw) = pose_error(estimate, truth);
    dt <= TOL_M && dyaw.to_degrees() <= TOL_DEG
}

/// `count` pairs of scans 1–10 m apart sharing at least 30 % of their view under the truth.
fn draw_pairs(
    scans: &[LogScan],
    count: usize,
    rng: &mut ChaCha8Rng,
    p: &RegisterParams,
) -> Vec<(ScanModel, ScanModel, Pose2)> {
    let mut out = Vec::new();
    for _ in 0..count * 400 {
        if out.len() == count {
            break;
        }
        let (i, j) = (
            rng.random_range(0..scans.len()),
            rng.random_range(0..scans.len()),
        );
        let truth = scans[i].site_from_laser.inverse() * scans[j].site_from_laser;
        if !(1.0..=10.0).contains(&truth.translation.vector.norm()) {
            continue;
        }
        let (a, b) = (model(&scans[i], p), model(&scans[j], p));
        if shared_view(&a, &b, &truth) >= 0.3 {
            out.push((a, b, truth));
        }
    }
    assert_eq!(out.len(), count, "could not draw {count} overlapping pairs");
    out
}

#[test]
fn real_scan_pairs_register_mostly_right_and_rarely_confidently_wrong() {
    let p = RegisterParams::default();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let (mut pairs, mut right, mut wrong) = (0, 0, 0);
    for name in ["intel", "aces", "csail"] {
        let Some(scans) = log(name) else { return };
        for (a, b, truth) in draw_pairs(&scans, 12, &mut rng, &p) {
            let r = register_pair(&a, &b, &p);
            pairs += 1;
            if r.registered() {
                if within(&r.a_from_b, &truth) {
                    right += 1;
                } else {
                    wrong += 1;
                    let (dt, dyaw) = pose_error(&r.a_from_b, &truth);
                    eprintln!(
                        "{name}: confidently wrong by {dt:.2} m / {:.1}°",
                        dyaw.to_degrees()
                    );
                }
            }
        }
    }
    eprintln!("{pairs} real pairs at ≥ 30 % overlap: {right} right, {wrong} confidently wrong");
    // Measured: 18 right, 3 confidently wrong (two near-misses at 1.9° and 2.6°, one 90° turn).
    assert!(right >= 15, "only {right} of {pairs} registered right");
    assert!(wrong <= 4, "{wrong} of {pairs} confidently wrong");
}
