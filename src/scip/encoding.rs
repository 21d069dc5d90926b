//! SCIP's character encodings: a value is split into 6-bit groups, most significant first, and
//! each group is sent as `group + 0x30` (so every character lies in `'0'..='o'`).
//!
//! 2 characters carry 12 bits (MS/GS ranges), 3 carry 18 bits (ranges and intensities), 4 carry
//! 24 bits (timestamps, which therefore wrap every 2^24 ms ≈ 4 h 40 min).

use thiserror::Error;

/// A character outside `'0'..='o'` where an encoded value was expected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
#[error("byte 0x{byte:02x} at offset {offset} is not a SCIP-encoded character")]
pub struct EncodingError {
    pub byte: u8,
    pub offset: usize,
}

/// Decodes `chars` (1 to 4 characters) into a value.
pub fn decode(chars: &[u8]) -> Result<u32, EncodingError> {
    let mut value = 0u32;
    for (offset, &byte) in chars.iter().enumerate() {
        let group = byte.wrapping_sub(0x30);
        if group > 0x3F {
            return Err(EncodingError { byte, offset });
        }
        value = (value << 6) | group as u32;
    }
    Ok(value)
}

/// Checks that every byte is an encoded character.
pub fn validate(chars: &[u8]) -> Result<(), EncodingError> {
    // A branch-free OR over all bytes (vectorises); find the culprit only when there is one.
    let bad = chars
        .iter()
        .fold(0u8, |acc, &b| acc | (b.wrapping_sub(0x30) & 0xC0));
    if bad == 0 {
        return Ok(());
    }
    let offset = chars
        .iter()
        .position(|&b| b.wrapping_sub(0x30) > 0x3F)
        .unwrap_or(0);
    Err(EncodingError {
        byte: chars.get(offset).copied().unwrap_or(0),
        offset,
    })
}

/// Decodes characters already checked by [`validate`] (others give a wrong value, not a panic).
#[inline]
pub fn decode_valid(chars: &[u8]) -> u32 {
    let group = |b: u8| (b.wrapping_sub(0x30) & 0x3F) as u32;
    match *chars {
        [a, b, c] => (group(a) << 12) | (group(b) << 6) | group(c),
        [a, b] => (group(a) << 6) | group(b),
        _ => chars.iter().fold(0u32, |value, &b| (value << 6) | group(b)),
    }
}

/// Encodes the low `6 * width` bits of `value` into `width` characters, appended to `out`.
pub fn encode_into(value: u32, width: usize, out: &mut Vec<u8>) {
    for i in (0..width).rev() {
        out.push(((value >> (6 * i)) & 0x3F) as u8 + 0x30);
    }
}

/// Encodes `value` into `width` characters.
pub fn encode(value: u32, width: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity(width);
    encode_into(value, width, &mut out);
    out
}

/// Largest value `width` characters can carry.
pub fn max_value(width: usize) -> u32 {
    if width >= 5 {
        u32::MAX
    } else {
        (1u32 << (6 * width)) - 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn spec_examples_decode() {
        assert_eq!(decode(b"CB"), Ok(1234));
        assert_eq!(decode(b"1Dh"), Ok(5432));
        assert_eq!(decode(b"m2@0"), Ok(16_000_000));
    }

    #[test]
    fn characters_outside_the_alphabet_are_errors() {
        assert_eq!(
            decode(b"0p"),
            Err(EncodingError {
                byte: b'p',
                offset: 1
            })
        );
        assert_eq!(
            decode(b"/"),
            Err(EncodingError {
                byte: b'/',
                offset: 0
            })
        );
    }

    proptest! {
        #[test]
        fn encode_then_decode_is_identity(width in 1usize..=4, raw in any::<u32>()) {
            let value = raw & max_value(width);
            prop_assert_eq!(decode(&encode(value, width)), Ok(value));
        }
    }
}
