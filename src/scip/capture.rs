//! The hokuyoaist log format of the captures in `fixtures/scip/`: records of
//! `u32 BE seconds, u32 BE microseconds, u32 BE length, bytes`.

use thiserror::Error;

#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error("log record at byte {offset} is cut short")]
pub struct CaptureError {
    pub offset: usize,
}

/// One record: when it was logged (µs since the log started) and its bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Record<'a> {
    pub at_us: u64,
    pub bytes: &'a [u8],
}

/// Splits a log into its records.
pub fn records(log: &[u8]) -> Result<Vec<Record<'_>>, CaptureError> {
    let mut out = Vec::new();
    let mut offset = 0;
    while offset < log.len() {
        let word = |at: usize| -> Result<u32, CaptureError> {
            let bytes = log
                .get(offset + at..offset + at + 4)
                .ok_or(CaptureError { offset })?;
            let bytes = <[u8; 4]>::try_from(bytes).map_err(|_| CaptureError { offset })?;
            Ok(u32::from_be_bytes(bytes))
        };
        let (seconds, micros, len) = (word(0)?, word(4)?, word(8)?);
        let bytes = log
            .get(offset + 12..offset + 12 + len as usize)
            .ok_or(CaptureError { offset })?;
        out.push(Record {
            at_us: seconds as u64 * 1_000_000 + micros as u64,
            bytes,
        });
        offset += 12 + len as usize;
    }
    Ok(out)
}

/// The stream a log holds: all record payloads concatenated.
pub fn unpack(log: &[u8]) -> Result<Vec<u8>, CaptureError> {
    Ok(records(log)?
        .iter()
        .flat_map(|r| r.bytes.iter().copied())
        .collect())
}
