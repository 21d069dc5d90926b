//! Decode of one UTM-30LX ME scan (1,081 range+intensity pairs) from the real capture in
//! `fixtures/scip/`: framing, reply split, checksums and values. Target ≤ 5 µs.
//!
//! `cargo bench --bench scip_decode`

use criterion::{Criterion, criterion_group, criterion_main};
use scanfuse::scip::capture::unpack;
use scanfuse::scip::{Frame, Framer, Reply, ScipScan};
use std::hint::black_box;

const UTM_30LX: &[u8] = include_bytes!("../fixtures/scip/example_utm_30lx.logr");

fn me_scan_frame() -> Frame {
    let stream = unpack(UTM_30LX).expect("fixture is a complete log");
    let mut framer = Framer::new();
    framer.push(&stream);
    std::iter::from_fn(|| framer.next_frame())
        .find(|f| f.echo().starts_with(b"ME") && f.bytes.len() > 1000)
        .expect("the capture holds one ME scan")
}

fn bench(c: &mut Criterion) {
    let frame = me_scan_frame();
    let mut scratch = Vec::new();
    let check =
        ScipScan::decode(&Reply::parse(&frame).expect("reply"), &mut scratch).expect("scan");
    assert_eq!(check.ranges_mm.len(), 1081);
    c.bench_function(
        "decode ME scan, 1081 pairs (reply + checksums + values)",
        |b| {
            b.iter(|| {
                let reply = Reply::parse(black_box(&frame)).expect("reply");
                black_box(ScipScan::decode(&reply, &mut scratch).expect("scan"))
            })
        },
    );
    let mut framer = Framer::new();
    c.bench_function("frame + decode ME scan from bytes", |b| {
        b.iter(|| {
            framer.push(black_box(&frame.bytes));
            let f = framer.next_frame().expect("frame");
            let reply = Reply::parse(&f).expect("reply");
            black_box(ScipScan::decode(&reply, &mut scratch).expect("scan"))
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
