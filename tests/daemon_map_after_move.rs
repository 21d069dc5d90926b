//! The fused map after a move, on the `moved` fixture through the daemon's fuser (each half of
//! the fixture looped, as the emulator loops it): `bench` is fused under its old pose until
//! the move, under that stale pose for a while after it (until it is found moved and
//! re-registered), then under its new pose. No occupied cell may remain
//! that only the old pose explained: cells bench's scans under its old pose (before the move,
//! and displaced during the stale spell) made occupied that neither the other sensors nor
//! bench at its new pose see occupied.

use nalgebra::Point2;
use scanfuse::daemon::config::PublishConfig;
use scanfuse::daemon::pipeline::PosedScan;
use scanfuse::daemon::pipeline_fuse::Fuser;
use scanfuse::fuse::{Cell, OccupancyGrid};
use scanfuse::geometry::{Mount, Pose2, Pose3, pose2};
use scanfuse::record::{self, Recording};
use scanfuse::scan::Scan;

const ANCHOR: &str = "entrance";
/// Times each phase (before, stale, after) of the fixture is played.
const PASSES: usize = 3;

struct Stream {
    /// (sensor index, scan) in stamp order.
    scans: Vec<(usize, Scan)>,
    ids: Vec<String>,
    mounts: Vec<Mount>,
    poses: Vec<Pose2>,
    bench: usize,
    bench_after: Pose2,
    /// Where the stale spell (moved, old pose) and the new pose begin in the stream.
    stale_from_ns: u64,
    new_from_ns: u64,
}

fn stream(rec: &Recording) -> Stream {
    let truth = |x: f64, y: f64, yaw_deg: f64| pose2(x, y, yaw_deg.to_radians());
    let t = rec.sensor(ANCHOR).and_then(|s| s.truth).unwrap();
    let anchor_from_world = truth(t.x_m, t.y_m, t.yaw_deg).inverse();
    let mut scans = Vec::new();
    let (mut ids, mut mounts, mut poses) = (Vec::new(), Vec::new(), Vec::new());
    for (i, info) in rec.sensors.iter().enumerate() {
        let t = info.truth.unwrap();
        ids.push(info.id.clone());
        mounts.push(info.mount());
        poses.push(anchor_from_world * truth(t.x_m, t.y_m, t.yaw_deg));
        scans.extend(rec.scans_of(&info.id).iter().map(|s| (i, s.clone())));
    }
    scans.sort_by_key(|(_, s)| s.stamp_ns);
    let the_move = rec.moves.iter().find(|m| m.sensor_id == "bench").unwrap();
    let p = the_move.pose;
    // The fixture's second before the move and its second after, each played PASSES times
    // (as the looping emulator would): before, stale (after, bench still at its old pose),
    // then after under the new pose. Stamps shifted so they keep rising.
    let (before, after): (Vec<_>, Vec<_>) = scans
        .into_iter()
        .partition(|(_, s)| s.stamp_ns < the_move.at_ns);
    let mut looped = Vec::new();
    let mut offset_ns = 0u64;
    let mut phase_starts = Vec::new();
    for part in [&before, &after, &after] {
        phase_starts.push(part.first().unwrap().1.stamp_ns + offset_ns);
        let span = part.last().unwrap().1.stamp_ns - part.first().unwrap().1.stamp_ns + 25_000_000;
        for _ in 0..PASSES {
            for (i, scan) in part {
                let mut scan = scan.clone();
                scan.stamp_ns += offset_ns;
                looped.push((*i, scan));
            }
            offset_ns += span;
        }
    }
    looped.sort_by_key(|(_, s)| s.stamp_ns);
    let scans = looped;
    Stream {
        stale_from_ns: phase_starts[1],
        new_from_ns: phase_starts[2],
        scans,
        bench: ids.iter().position(|id| id == "bench").unwrap(),
        ids,
        mounts,
        poses,
        bench_after: anchor_from_world * truth(p.x_m, p.y_m, p.yaw_deg),
    }
}

/// Fuses the stream up to `until_ns` the way the daemon's map pass does (latest scan of each
/// sensor, every scan); `pose_of` gives each sensor's pose at a stamp, `None` to leave the
/// sensor out (and its cells: an unposed sensor leaves the map).
fn fuse(s: &Stream, until_ns: u64, pose_of: impl Fn(usize, u64) -> Option<Pose2>) -> OccupancyGrid {
    let mut fuser = Fuser::new(&PublishConfig::default());
    let mut latest: Vec<Option<Scan>> = vec![None; s.ids.len()];
    for (i, scan) in s
        .scans
        .iter()
        .take_while(|(_, scan)| scan.stamp_ns < until_ns)
    {
        latest[*i] = Some(scan.clone());
        let now = scan.stamp_ns;
        let posed: Vec<PosedScan> = latest
            .iter()
            .enumerate()
            .filter_map(|(j, scan)| {
                let pose = pose_of(j, now)?;
                Some(PosedScan {
                    index: j as u16,
                    id: s.ids[j].clone(),
                    scan: scan.clone()?,
                    geometry: None,
                    mount: s.mounts[j],
                    site_from_sensor: Pose3::from_planar(
                        &pose,
                        s.mounts[j].height_m.unwrap_or(0.0),
                        s.mounts[j].pitch_rad,
                    ),
                })
            })
            .collect();
        fuser.integrate(&posed);
    }
    fuser.grid()
}

fn occupied_cells(grid: &OccupancyGrid) -> Vec<Point2<f64>> {
    let (w, h) = grid.size();
    let c = grid.params().cell_m;
    let o = grid.origin();
    let mut out = Vec::new();
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            if grid.cell(x, y) == Cell::Occupied {
                out.push(Point2::new(
                    o.x + (x as f64 + 0.5) * c,
                    o.y + (y as f64 + 0.5) * c,
                ));
            }
        }
    }
    out
}

#[test]
fn no_cell_only_the_old_pose_explained_survives_the_move() {
    let rec =
        record::read(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/moved.mcap"))
            .unwrap();
    let s = stream(&rec);
    let bench = s.bench;
    assert!(
        s.stale_from_ns + 2_000_000_000 < s.new_from_ns,
        "bench is fused under its stale pose for seconds"
    );

    // What the daemon's map ends as: bench under its old pose, stale after the move, then new.
    let fused = fuse(&s, u64::MAX, |j, t| {
        Some(if j == bench && t >= s.new_from_ns {
            s.bench_after
        } else {
            s.poses[j]
        })
    });
    // Everything bench drew under its old pose: before the move, and its new view during the
    // stale spell (drawn displaced: those cells nobody else explains).
    let old_only = fuse(&s, s.new_from_ns, |j, _| (j == bench).then_some(s.poses[j]));
    // The site as if bench had never stood at its old pose: the others, and bench from its
    // re-registration on, at its new pose.
    let truth_now = fuse(&s, u64::MAX, |j, t| {
        if j != bench {
            Some(s.poses[j])
        } else {
            (t >= s.new_from_ns).then_some(s.bench_after)
        }
    });
    let only_old: Vec<Point2<f64>> = occupied_cells(&old_only)
        .into_iter()
        .filter(|p| truth_now.cell_at(*p) != Cell::Occupied)
        .collect();
    assert!(
        only_old.len() > 20,
        "bench's old view has cells nobody else explains: {}",
        only_old.len()
    );
    let survivors: Vec<&Point2<f64>> = only_old
        .iter()
        .filter(|p| fused.cell_at(**p) == Cell::Occupied)
        .collect();
    assert!(
        survivors.is_empty(),
        "{} of {} cells only bench's old pose explained are still occupied, e.g. {:?}",
        survivors.len(),
        only_old.len(),
        survivors.first()
    );
    // And the map still has the site: what bench sees now is in it.
    let now_cells = occupied_cells(&truth_now);
    let kept = now_cells
        .iter()
        .filter(|p| fused.cell_at(**p) == Cell::Occupied)
        .count();
    assert!(
        kept as f64 > 0.8 * now_cells.len() as f64,
        "{kept} of {} cells of the site as it is now are in the map",
        now_cells.len()
    );
}
