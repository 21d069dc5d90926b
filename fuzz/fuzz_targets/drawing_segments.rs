//! DXF / SVG bytes → wall segments: any input gives segments or an error, never a panic or a
//! hang. The first byte picks the format. `cargo fuzz run drawing_segments` (nightly).
#![no_main]

use libfuzzer_sys::fuzz_target;
use scanfuse::drawing::{Format, ReadOptions, parse};

fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    let format = match pick % 3 {
        0 => Format::Dxf,
        1 => Format::Svg,
        _ => Format::Pgm,
    };
    let opts = ReadOptions {
        scale_m_per_unit: Some(0.01),
        max_bytes: 1 << 20,
        ..ReadOptions::default()
    };
    let _ = parse("fuzz", rest, format, &opts);
});
