//! Framer + decoders on arbitrary bytes: nothing panics, the framer gives the same frames
//! however the bytes are split, and every scan that decodes re-encodes to a scan that decodes
//! to the same values.
//!
//! `cargo +nightly fuzz run scip_framer_decoder` (from the repository root). Input: one byte
//! choosing the chunk size, then the stream. Seeds worth giving it: the three captures in
//! `fixtures/scip/`, unpacked (`scip::capture::unpack`) and prefixed with any byte.

#![no_main]

use libfuzzer_sys::fuzz_target;
use scanfuse::scip::command::Request;
use scanfuse::scip::info::{Parameters, StateInfo, VersionInfo, parse_tm1};
use scanfuse::scip::{Frame, Framer, Reply, ScipScan};

fn frames(chunks: impl Iterator<Item = Vec<u8>>) -> Vec<Frame> {
    let mut framer = Framer::new();
    let mut out = Vec::new();
    for chunk in chunks {
        framer.push(&chunk);
        out.extend(std::iter::from_fn(|| framer.next_frame()));
    }
    out
}

fuzz_target!(|data: &[u8]| {
    let Some((&split, bytes)) = data.split_first() else {
        return;
    };
    let whole = frames(std::iter::once(bytes.to_vec()));
    let step = split as usize % 17 + 1;
    let pieces = frames(bytes.chunks(step).map(<[u8]>::to_vec));
    assert_eq!(whole, pieces, "framing depends on read boundaries");
    let mut scratch = Vec::new();
    for frame in &whole {
        let Ok(reply) = Reply::parse(frame) else {
            continue;
        };
        let _ = VersionInfo::parse(&reply);
        let _ = Parameters::parse(&reply);
        let _ = StateInfo::parse(&reply);
        let _ = parse_tm1(&reply);
        let _ = Request::parse(reply.echo);
        if let Ok(scan) = ScipScan::decode(&reply, &mut scratch) {
            let again = scan.encode(reply.echo, reply.status.0);
            let mut framer = Framer::new();
            framer.push(&again);
            let frame = framer.next_frame().expect("re-encoded scan frames");
            let reply = Reply::parse(&frame).expect("re-encoded reply parses");
            let decoded = ScipScan::decode(&reply, &mut scratch).expect("re-encoded scan decodes");
            assert_eq!(decoded, scan);
        }
    }
    for line in bytes.split(|&b| b == b'\n') {
        if let Ok(request) = Request::parse(line) {
            assert_eq!(Request::parse(&request.line()), Ok(request));
        }
    }
});
