//! The one-character line checksum: the low six bits of the byte sum, plus `0x30`.

/// Checksum of `bytes`: `(Σ bytes & 0x3F) + 0x30`.
pub fn checksum(bytes: &[u8]) -> u8 {
    let sum = bytes
        .iter()
        .fold(0u32, |acc, &b| acc.wrapping_add(b as u32));
    (sum & 0x3F) as u8 + 0x30
}

/// Splits a data line `payload + sum` and checks it; `None` when empty or the sum is wrong.
pub fn verified_payload(line: &[u8]) -> Option<&[u8]> {
    let (&sum, payload) = line.split_last()?;
    (checksum(payload) == sum).then_some(payload)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spec_example_hokuyo_sums_to_o() {
        assert_eq!(checksum(b"Hokuyo"), b'o');
    }

    #[test]
    fn status_lines_of_real_units_verify() {
        assert_eq!(checksum(b"00"), b'P');
        assert_eq!(checksum(b"99"), b'b');
        assert_eq!(verified_payload(b"04T"), Some(&b"04"[..]));
        assert_eq!(verified_payload(b"04U"), None);
        assert_eq!(verified_payload(b""), None);
    }
}
