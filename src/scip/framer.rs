//! Splits a byte stream into replies, whatever the read boundaries.
//!
//! A reply is `echo LF status sum LF … LF LF`. Like gpsd's packet lexer, the framer expects
//! junk: stray LFs, bytes left from a half-read reply after a reconnect, echoes of commands it
//! does not know. A reply starts only where a known echo is followed by a status line with a
//! valid checksum; everything else is skipped and counted. Every decision is made on complete
//! lines, so the same bytes give the same frames however they are split.

use super::checksum::checksum;

/// Longest reply accepted: a 3-echo NE scan of 1,081 steps is ≈ 24 KB.
pub const MAX_FRAME_BYTES: usize = 64 * 1024;
/// Longest echo line: symbol, 13 parameter digits, `;` and a 16-character tag.
const MAX_ECHO_BYTES: usize = 2 + 13 + 1 + 16;

/// Command symbols a reply may echo.
const KNOWN_SYMBOLS: [&[u8; 2]; 23] = [
    b"VV", b"PP", b"II", b"BM", b"QT", b"RS", b"RT", b"RB", b"TM", b"SS", b"CR", b"HS", b"DB",
    b"MD", b"MS", b"ME", b"ND", b"NE", b"GD", b"GS", b"GE", b"HD", b"HE",
];

/// One complete reply, including its final empty line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    pub bytes: Vec<u8>,
}

impl Frame {
    /// The echo line (the command as the sensor received it).
    pub fn echo(&self) -> &[u8] {
        self.lines().next().unwrap_or_default()
    }

    /// The lines of the reply without their LFs and without the final empty line.
    pub fn lines(&self) -> impl Iterator<Item = &[u8]> {
        let body = self.bytes.strip_suffix(b"\n\n").unwrap_or(&self.bytes);
        let mut start = 0;
        let mut ends = memchr::memchr_iter(b'\n', body).chain([body.len()]);
        std::iter::from_fn(move || {
            let end = ends.next()?;
            let line = body.get(start..end).unwrap_or_default();
            start = end + 1;
            Some(line)
        })
    }
}

/// What the framer has seen, for the driver's counters. Never reset.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FramerStats {
    pub frames: u64,
    /// Bytes dropped: garbage, unknown echoes, oversized replies.
    pub skipped_bytes: u64,
    /// Empty lines between replies.
    pub blank_lines: u64,
    /// Lines skipped because they did not start a known reply.
    pub skipped_lines: u64,
    /// Replies dropped for being longer than [`MAX_FRAME_BYTES`].
    pub oversized: u64,
}

/// Incremental reply framer: [`push`](Framer::push) bytes, then take frames with
/// [`next_frame`](Framer::next_frame) until it returns `None`.
#[derive(Debug, Default)]
pub struct Framer {
    buf: Vec<u8>,
    /// Start of the unconsumed bytes in `buf`.
    pos: usize,
    /// Where to resume looking for the `LF LF` of the reply starting at `pos`.
    search_from: usize,
    stats: FramerStats,
}

fn is_echo(line: &[u8]) -> bool {
    if line.len() < 2 || line.len() > MAX_ECHO_BYTES {
        return false;
    }
    let known = line.starts_with(b"%ST") || KNOWN_SYMBOLS.iter().any(|s| line.starts_with(&s[..]));
    known && line.iter().all(|&c| (0x20..0x7f).contains(&c))
}

fn is_status(line: &[u8]) -> bool {
    match line {
        [a, b, sum] => {
            a.is_ascii_alphanumeric() && b.is_ascii_alphanumeric() && checksum(&[*a, *b]) == *sum
        }
        _ => false,
    }
}

/// Offset of the first `LF LF` in `bytes`, looking only at LFs.
fn find_blank_line(bytes: &[u8]) -> Option<usize> {
    memchr::memmem::find(bytes, b"\n\n")
}

impl Framer {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn stats(&self) -> FramerStats {
        self.stats
    }

    /// Bytes received but not yet part of a frame.
    pub fn pending(&self) -> usize {
        self.buf.len() - self.pos
    }

    pub fn push(&mut self, bytes: &[u8]) {
        if self.pos > 0 && self.pos * 2 >= self.buf.len() {
            self.buf.drain(..self.pos);
            self.search_from -= self.pos;
            self.pos = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    fn skip(&mut self, n: usize) {
        self.pos += n;
        self.search_from = self.pos;
        self.stats.skipped_bytes += n as u64;
    }

    /// The next complete reply, or `None` until more bytes arrive.
    pub fn next_frame(&mut self) -> Option<Frame> {
        loop {
            let rest = self.buf.get(self.pos..).unwrap_or_default();
            if rest.first() == Some(&b'\n') {
                self.stats.blank_lines += 1;
                self.skip(1);
                continue;
            }
            // The reply must start with an echo and a status line; both must be complete.
            let first_end = memchr::memchr(b'\n', rest)?;
            let first = rest.get(..first_end).unwrap_or_default();
            let after = rest.get(first_end + 1..).unwrap_or_default();
            let second_end = memchr::memchr(b'\n', after)?;
            let second = after.get(..second_end).unwrap_or_default();
            if !is_status(second) {
                self.stats.skipped_lines += 1;
                self.skip(first_end + 1);
                continue;
            }
            if !is_echo(first) {
                // Garbage glued to the front of a real echo: keep the echo.
                match (1..first.len()).find(|&k| first.get(k..).is_some_and(is_echo)) {
                    Some(k) => self.skip(k),
                    None => {
                        self.stats.skipped_lines += 1;
                        self.skip(first_end + 1);
                    }
                }
                continue;
            }
            // A status line followed directly by LF ends the reply at once.
            let from = self.search_from.max(self.pos + first_end);
            let window = self.buf.get(from..).unwrap_or_default();
            match find_blank_line(window) {
                Some(i) => {
                    let end = from + i + 2;
                    if end - self.pos > MAX_FRAME_BYTES {
                        self.stats.oversized += 1;
                        self.skip(first_end + 1);
                        continue;
                    }
                    let bytes = self.buf.get(self.pos..end).unwrap_or_default().to_vec();
                    self.pos = end;
                    self.search_from = end;
                    self.stats.frames += 1;
                    return Some(Frame { bytes });
                }
                None => {
                    // Resume the search where it stopped (one byte back for a split LF LF).
                    self.search_from = self.buf.len().saturating_sub(1).max(from);
                    if self.buf.len() - self.pos > MAX_FRAME_BYTES {
                        self.stats.oversized += 1;
                        self.skip(first_end + 1);
                        continue;
                    }
                    return None;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const TWO_REPLIES: &[u8] = b"BM\n00P\n\nTM1\n00P\n<SfkP\n\n";

    fn frames_of(framer: &mut Framer) -> Vec<Frame> {
        std::iter::from_fn(|| framer.next_frame()).collect()
    }

    #[test]
    fn garbage_blank_lines_and_unknown_echoes_are_skipped_and_counted() {
        let mut framer = Framer::new();
        framer.push(b"\n\n\x00\xffjunk\nXX\n00P\n\nzzBM\n00P\n\n");
        framer.push(TWO_REPLIES);
        let frames = frames_of(&mut framer);
        let echoes: Vec<&[u8]> = frames.iter().map(Frame::echo).collect();
        assert_eq!(echoes, vec![&b"BM"[..], b"BM", b"TM1"]);
        let stats = framer.stats();
        assert_eq!(stats.frames, 3);
        assert_eq!(stats.blank_lines, 3);
        // Three LFs, "\0\xffjunk\n", "XX\n", "00P\n" and the "zz" glued to BM.
        assert_eq!(stats.skipped_bytes, 3 + 7 + 3 + 4 + 2);
        assert_eq!(framer.pending(), 0);
    }

    #[test]
    fn a_reply_without_end_is_dropped_once_it_exceeds_the_limit() {
        let mut framer = Framer::new();
        framer.push(b"MD0000108001000\n99b\n");
        framer.push(&vec![b'0'; MAX_FRAME_BYTES]);
        assert_eq!(framer.next_frame(), None);
        assert_eq!(framer.stats().oversized, 1);
        framer.push(b"\n\nBM\n00P\n\n");
        assert_eq!(frames_of(&mut framer).len(), 1);
    }

    proptest! {
        /// urg_stamped's test: one stream cut anywhere gives the same replies.
        #[test]
        fn any_split_gives_the_same_frames(
            noise in proptest::collection::vec(any::<u8>(), 0..40),
            cuts in proptest::collection::vec(0usize..200, 0..12),
        ) {
            let mut stream = noise.clone();
            stream.extend_from_slice(b"\n");
            stream.extend_from_slice(TWO_REPLIES);
            stream.extend_from_slice(&noise);
            stream.extend_from_slice(b"\nVV\n00P\nVEND:Hokuyo;x\n\n");
            let mut whole = Framer::new();
            whole.push(&stream);
            let expected = frames_of(&mut whole);
            let mut framer = Framer::new();
            let mut got = Vec::new();
            let mut cuts: Vec<usize> = cuts.into_iter().map(|c| c.min(stream.len())).collect();
            cuts.sort_unstable();
            let mut last = 0;
            for cut in cuts.into_iter().chain([stream.len()]) {
                framer.push(&stream[last..cut]);
                got.extend(frames_of(&mut framer));
                last = cut;
            }
            prop_assert_eq!(&got, &expected);
            prop_assert_eq!(framer.stats(), whole.stats());
            prop_assert!(got.iter().any(|f| f.echo() == b"TM1"));
        }
    }
}
