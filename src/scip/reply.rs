//! A framed reply split into echo, status and data lines, and the encoder the emulator uses to
//! write replies.

use thiserror::Error;

use super::checksum::checksum;
use super::framer::Frame;
use super::status::Status;

/// A reply whose structure is wrong.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum ReplyError {
    #[error("reply has no status line")]
    NoStatus,
    #[error("status line {0:?} is not two characters and a valid checksum")]
    BadStatus(String),
}

/// A reply borrowed from its frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reply<'a> {
    /// The echoed command line.
    pub echo: &'a [u8],
    pub status: Status,
    /// The bytes after the status line's LF, without the final empty line; `None` when the
    /// status line ends the reply. Kept whole so a scan decoder can walk its lines in one pass.
    data: Option<&'a [u8]>,
}

/// Splits at the first LF: the line, and what follows it (`None` without an LF).
pub(crate) fn split_line(bytes: &[u8]) -> (&[u8], Option<&[u8]>) {
    match memchr::memchr(b'\n', bytes) {
        Some(i) => (
            bytes.get(..i).unwrap_or_default(),
            Some(bytes.get(i + 1..).unwrap_or_default()),
        ),
        None => (bytes, None),
    }
}

impl<'a> Reply<'a> {
    pub fn parse(frame: &'a Frame) -> Result<Reply<'a>, ReplyError> {
        let body = frame.bytes.strip_suffix(b"\n\n").unwrap_or(&frame.bytes);
        let (echo, rest) = split_line(body);
        let (status_line, data) = split_line(rest.ok_or(ReplyError::NoStatus)?);
        let status = match status_line {
            [a, b, sum] if checksum(&[*a, *b]) == *sum => Status([*a, *b]),
            other => {
                return Err(ReplyError::BadStatus(
                    String::from_utf8_lossy(other).into_owned(),
                ));
            }
        };
        Ok(Reply { echo, status, data })
    }

    /// Lines after the status, each still ending in its checksum.
    pub fn lines(&self) -> impl Iterator<Item = &'a [u8]> + use<'a> {
        self.data
            .into_iter()
            .flat_map(|data| data.split(|&b| b == b'\n'))
    }

    /// The lines after the status as one block (LFs included), `None` when there are none.
    pub fn data(&self) -> Option<&'a [u8]> {
        self.data
    }

    /// The two command letters of the echo (`%S` for `%ST`).
    pub fn symbol(&self) -> [u8; 2] {
        match self.echo {
            [a, b, ..] => [*a, *b],
            _ => *b"??",
        }
    }
}

/// Appends `line + checksum + LF`.
pub fn push_line(out: &mut Vec<u8>, payload: &[u8]) {
    out.extend_from_slice(payload);
    out.push(checksum(payload));
    out.push(b'\n');
}

/// Echo and status, no data: `echo LF status sum LF LF`.
pub fn encode_status(echo: &[u8], status: [u8; 2]) -> Vec<u8> {
    let mut out = Vec::with_capacity(echo.len() + 6);
    out.extend_from_slice(echo);
    out.push(b'\n');
    push_line(&mut out, &status);
    out.push(b'\n');
    out
}

/// A `KEY:VALUE;sum` line, the sum covering `KEY:VALUE`.
pub fn push_field(out: &mut Vec<u8>, key: &str, value: &str) {
    let start = out.len();
    out.extend_from_slice(key.as_bytes());
    out.push(b':');
    out.extend_from_slice(value.as_bytes());
    let sum = checksum(out.get(start..).unwrap_or_default());
    out.push(b';');
    out.push(sum);
    out.push(b'\n');
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_and_field_lines_match_real_units() {
        assert_eq!(encode_status(b"CR00", *b"04"), b"CR00\n04T\n\n");
        let mut out = Vec::new();
        push_field(&mut out, "DMIN", "100");
        assert_eq!(out, b"DMIN:100;c\n");
        let frame = Frame {
            bytes: b"BM\n02R\n\n".to_vec(),
        };
        let reply = Reply::parse(&frame).unwrap();
        assert_eq!(
            (reply.echo, reply.status, reply.lines().count()),
            (&b"BM"[..], Status(*b"02"), 0)
        );
        let bad = Frame {
            bytes: b"BM\n02S\n\n".to_vec(),
        };
        assert!(matches!(Reply::parse(&bad), Err(ReplyError::BadStatus(_))));
    }
}
