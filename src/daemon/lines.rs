//! Splits a byte stream into newline-terminated lines with a length cap, so one client sending
//! an endless line cannot make the daemon buffer without bound. Pure: bytes in, lines out.

/// One thing the framer found in the bytes fed so far.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Frame {
    /// A complete line, without its `\n` (and without a trailing `\r`).
    Line(Vec<u8>),
    /// A line longer than the cap; its bytes were discarded up to and including its `\n`.
    /// `bytes` counts what was discarded, so far, when this was reported.
    TooLong { bytes: usize },
}

/// Incremental line splitter with a cap on line length.
#[derive(Debug)]
pub struct LineFramer {
    max_line_bytes: usize,
    buf: Vec<u8>,
    /// Set while skipping the rest of an over-long line (already reported).
    discarding: bool,
}

impl LineFramer {
    /// A framer that rejects lines longer than `max_line_bytes` (the `\n` not counted).
    pub fn new(max_line_bytes: usize) -> Self {
        LineFramer {
            max_line_bytes,
            buf: Vec::new(),
            discarding: false,
        }
    }

    /// Feeds bytes as they arrive, in any chunking, and returns the frames they complete.
    /// An over-long line is reported once, as soon as it passes the cap, not when it ends.
    pub fn push(&mut self, mut bytes: &[u8]) -> Vec<Frame> {
        let mut frames = Vec::new();
        while !bytes.is_empty() {
            let newline = bytes.iter().position(|&b| b == b'\n');
            let (chunk, rest, ends_line) = match newline {
                Some(i) => (&bytes[..i], &bytes[i + 1..], true),
                None => (bytes, &[][..], false),
            };
            bytes = rest;
            if self.discarding {
                if ends_line {
                    self.discarding = false;
                }
                continue;
            }
            if self.buf.len() + chunk.len() > self.max_line_bytes {
                frames.push(Frame::TooLong {
                    bytes: self.buf.len() + chunk.len(),
                });
                self.buf.clear();
                self.discarding = !ends_line;
                continue;
            }
            self.buf.extend_from_slice(chunk);
            if ends_line {
                let mut line = std::mem::take(&mut self.buf);
                if line.last() == Some(&b'\r') {
                    line.pop();
                }
                frames.push(Frame::Line(line));
            }
        }
        frames
    }

    /// Bytes of an unfinished line held so far.
    pub fn pending_bytes(&self) -> usize {
        self.buf.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn splits_lines_and_strips_carriage_returns() {
        let mut f = LineFramer::new(16);
        assert_eq!(f.push(b"ab"), vec![]);
        assert_eq!(
            f.push(b"c\r\nd\n\ne"),
            vec![
                Frame::Line(b"abc".to_vec()),
                Frame::Line(b"d".to_vec()),
                Frame::Line(vec![])
            ]
        );
        assert_eq!(f.pending_bytes(), 1);
    }

    #[test]
    fn an_over_long_line_is_reported_once_and_the_next_line_survives() {
        let mut f = LineFramer::new(4);
        assert_eq!(f.push(b"abc"), vec![]);
        assert_eq!(f.push(b"de"), vec![Frame::TooLong { bytes: 5 }]);
        assert_eq!(f.push(b"fghij"), vec![]);
        assert_eq!(f.push(b"k\nok\n"), vec![Frame::Line(b"ok".to_vec())]);
        // Exactly at the cap is fine.
        assert_eq!(f.push(b"abcd\n"), vec![Frame::Line(b"abcd".to_vec())]);
        // Over the cap within one chunk that also ends the line.
        assert_eq!(
            f.push(b"abcde\nx\n"),
            vec![Frame::TooLong { bytes: 5 }, Frame::Line(b"x".to_vec())]
        );
    }

    proptest! {
        /// Any chunking of the same stream gives the same lines.
        #[test]
        fn chunking_does_not_matter(
            lines in proptest::collection::vec("[a-z{}\":,]{0,12}", 0..8),
            cuts in proptest::collection::vec(0usize..200, 0..10),
        ) {
            let stream: Vec<u8> = lines.iter().flat_map(|l| format!("{l}\n").into_bytes()).collect();
            let mut cuts: Vec<usize> = cuts.into_iter().map(|c| c % (stream.len() + 1)).collect();
            cuts.push(0);
            cuts.push(stream.len());
            cuts.sort_unstable();
            let mut f = LineFramer::new(8);
            let mut got = Vec::new();
            for w in cuts.windows(2) {
                got.extend(f.push(&stream[w[0]..w[1]]));
            }
            let want: Vec<Frame> = lines
                .iter()
                .map(|l| if l.len() > 8 {
                    Frame::TooLong { bytes: 0 }
                } else {
                    Frame::Line(l.clone().into_bytes())
                })
                .collect();
            // Compare with the discarded counts blanked: they depend on where the cut fell.
            let blank = |fr: Frame| match fr {
                Frame::TooLong { .. } => Frame::TooLong { bytes: 0 },
                other => other,
            };
            let got: Vec<Frame> = got.into_iter().map(blank).collect();
            prop_assert_eq!(got, want);
            prop_assert_eq!(f.pending_bytes(), 0);
        }
    }
}
