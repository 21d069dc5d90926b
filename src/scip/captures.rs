//! Golden tests: the three real captures in `fixtures/scip/` decode to the values the dataset's
//! README lists, and every reply in them frames and verifies.

use super::capture::unpack;
use super::info::{Parameters, StateInfo, VersionInfo, parse_tm1};
use super::{Framer, Reply, ScipScan};
use crate::scan::ScanGeometry;

const URG_04LX: &[u8] = include_bytes!("../../fixtures/scip/example_urg_04lx.logr");
const UTM_30LX: &[u8] = include_bytes!("../../fixtures/scip/example_utm_30lx.logr");
const UXM_30LX_E: &[u8] = include_bytes!("../../fixtures/scip/example_uxm_30lx_e.logr");
const UXM_30LX_E_SENT: &[u8] = include_bytes!("../../fixtures/scip/example_uxm_30lx_e.logw");

fn frames(log: &[u8]) -> (Vec<super::Frame>, super::FramerStats) {
    let stream = unpack(log).expect("fixture is a complete log");
    let mut framer = Framer::new();
    let mut frames = Vec::new();
    // Byte by byte, as the records arrived.
    for byte in stream {
        framer.push(&[byte]);
        frames.extend(std::iter::from_fn(|| framer.next_frame()));
    }
    assert_eq!(framer.pending(), 0);
    (frames, framer.stats())
}

fn only_scan(frames: &[super::Frame]) -> ScipScan {
    let scans: Vec<ScipScan> = frames
        .iter()
        .filter_map(|f| ScipScan::decode(&Reply::parse(f).ok()?, &mut Vec::new()).ok())
        .collect();
    assert_eq!(scans.len(), 1);
    scans.into_iter().next().expect("one scan")
}

#[test]
fn uxm_30lx_e_capture_decodes_to_the_readme_values() {
    let (frames, stats) = frames(UXM_30LX_E);
    assert_eq!(stats.skipped_bytes, 0);
    let echoes: Vec<&[u8]> = frames.iter().map(|f| f.echo()).collect();
    let sent = unpack(UXM_30LX_E_SENT).expect("complete log");
    let sent_lines: Vec<&[u8]> = sent
        .split(|&b| b == b'\n')
        .filter(|l| !l.is_empty())
        .collect();
    assert_eq!(echoes, sent_lines, "every command is echoed byte for byte");

    let pp = frames.iter().find(|f| f.echo() == b"PP").expect("PP reply");
    let params = Parameters::parse(&Reply::parse(pp).expect("reply")).expect("PP");
    assert_eq!(params.model, "UXM-30LX-E(Hokuyo Automatic Co.,Ltd.)");
    assert_eq!(params.geometry, ScanGeometry::UXM_30LX_E);
    let vv = frames.iter().find(|f| f.echo() == b"VV").expect("VV reply");
    let version = VersionInfo::parse(&Reply::parse(vv).expect("reply")).expect("VV");
    assert_eq!(version.firmware, "0.3.01(11/Mar./2010)");
    assert_eq!(version.serial, "H0909106");
    let ii = frames.iter().find(|f| f.echo() == b"II").expect("II reply");
    let state = StateInfo::parse(&Reply::parse(ii).expect("reply")).expect("II");
    assert_eq!(state.time_ms, 0x323D56);
    assert!(state.laser_on);

    let tm1: Vec<u32> = frames
        .iter()
        .filter(|f| f.echo() == b"TM1")
        .filter_map(|f| parse_tm1(&Reply::parse(f).ok()?))
        .collect();
    assert_eq!(tm1.len(), 10);
    assert!(tm1.windows(2).all(|w| w[0] <= w[1]));

    let scan = only_scan(&frames);
    assert_eq!(scan.timestamp_ms, 3_293_169);
    assert_eq!(scan.ranges_mm.len(), 761);
    assert_eq!(scan.ranges_mm[..4], [353, 353, 588, 1311]);
    assert_eq!(scan.ranges_mm[380], 2243);
    assert_eq!(scan.ranges_mm[757..], [453, 453, 418, 403]);
}

#[test]
fn utm_30lx_capture_decodes_the_me_scan_with_intensities() {
    let (frames, stats) = frames(UTM_30LX);
    assert_eq!(stats.skipped_bytes, 0);
    let scan = only_scan(&frames);
    assert_eq!(scan.timestamp_ms, 4_821_609);
    assert_eq!(scan.ranges_mm.len(), 1081);
    assert_eq!(scan.intensities.len(), 1081);
    assert_eq!((scan.ranges_mm[0], scan.intensities[0]), (45, 1809));
    // The dataset README puts (3295 mm, 2389) at step 540; the stream has it at step 541 (an
    // independent Python decode agrees), and step 540 is (3298 mm, 2369).
    assert_eq!((scan.ranges_mm[541], scan.intensities[541]), (3295, 2389));
    assert_eq!((scan.ranges_mm[540], scan.intensities[540]), (3298, 2369));
    // The stream's own acknowledgement (status 00, no data) comes first.
    let me: Vec<&super::Frame> = frames
        .iter()
        .filter(|f| f.echo().starts_with(b"ME"))
        .collect();
    assert_eq!(me.len(), 2);
    let pp = frames.iter().find(|f| f.echo() == b"PP").expect("PP reply");
    let params = Parameters::parse(&Reply::parse(pp).expect("reply")).expect("PP");
    assert_eq!(
        params.geometry,
        ScanGeometry {
            scan_rpm: 2400,
            ..ScanGeometry::UTM_30LX_EW
        }
    );
    let ii = frames.iter().find(|f| f.echo() == b"II").expect("II reply");
    assert_eq!(
        StateInfo::parse(&Reply::parse(ii).expect("reply"))
            .expect("II")
            .time_ms,
        0x4991D0
    );
    let scan_m = scan.to_scan(&params.geometry, 0, None);
    assert_eq!(scan_m.ranges_m[541], 3.295);
    assert_eq!(scan_m.ranges_m[0], 0.045);
    assert!((scan_m.start_angle_rad.to_degrees() + 135.0).abs() < 1e-9);
}

#[test]
fn urg_04lx_capture_decodes_the_gd_scan() {
    let (frames, stats) = frames(URG_04LX);
    assert_eq!(stats.skipped_bytes, 0);
    let scan = only_scan(&frames);
    assert_eq!(scan.timestamp_ms, 6_968_830);
    assert_eq!(scan.ranges_mm.len(), 682);
    assert_eq!(scan.ranges_mm[..3], [392, 392, 391]);
    assert_eq!((scan.request.start_step, scan.request.end_step), (44, 725));
}

#[test]
fn captures_cut_into_random_chunks_give_the_same_frames() {
    use proptest::prelude::*;
    let stream = unpack(UTM_30LX).expect("complete log");
    let (expected, _) = frames(UTM_30LX);
    proptest!(|(cuts in proptest::collection::vec(0usize..stream.len(), 0..40))| {
        let mut cuts = cuts;
        cuts.sort_unstable();
        let mut framer = Framer::new();
        let mut got = Vec::new();
        let mut last = 0;
        for cut in cuts.into_iter().chain([stream.len()]) {
            framer.push(&stream[last..cut]);
            got.extend(std::iter::from_fn(|| framer.next_frame()));
            last = cut;
        }
        prop_assert_eq!(&got, &expected);
    });
}
