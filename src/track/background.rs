//! One sensor's background for tracking: per beam, the horizontal range of what stays put.
//! It learns from the scans themselves, by the scans' own clock:
//! - seeing farther than the background (someone who stood there walked off, or the first
//!   scans caught people) makes the farther range the background at once;
//! - something short of the background at one range (within `hold_tol_m`) for `absorb_s`
//!   becomes background: a box put down fades in, while a person standing still (who stays
//!   well under `absorb_s`, default 90 s) stays foreground for at least a minute;
//! - a candidate not seen for `forget_s` is forgotten, so people passing at random ranges
//!   never add up to one.

/// Timings and tolerances of the background.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BackgroundParams {
    /// Something short of the background at one range for this long becomes background (s).
    pub absorb_s: f64,
    /// A return within this of the candidate's range is the same thing (m).
    pub hold_tol_m: f64,
    /// A candidate unseen this long is dropped (s).
    pub forget_s: f64,
    /// Farther than the background by this (plus 1 % of range) means it was not background (m).
    pub reveal_m: f64,
}

impl Default for BackgroundParams {
    fn default() -> Self {
        BackgroundParams {
            absorb_s: 90.0,
            hold_tol_m: 0.15,
            forget_s: 5.0,
            reveal_m: 0.1,
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Candidate {
    range_m: f32,
    since_ns: u64,
    last_ns: u64,
}

/// Per-beam background ranges of one sensor (horizontal, m; NaN where nothing stays).
#[derive(Debug, Clone)]
pub struct Background {
    ranges_m: Vec<f32>,
    candidates: Vec<Option<Candidate>>,
}

impl Background {
    /// A background seeded with a known static view (e.g. registration's persistent view), or
    /// with a sensor's first scan.
    pub fn seeded(ranges_m: Vec<f32>) -> Background {
        let candidates = vec![None; ranges_m.len()];
        Background {
            ranges_m,
            candidates,
        }
    }

    pub fn ranges_m(&self) -> &[f32] {
        &self.ranges_m
    }

    pub fn beams(&self) -> usize {
        self.ranges_m.len()
    }

    /// Learns from one scan's horizontal ranges (NaN: no return) taken at `t_ns`. Call it
    /// after detecting in the scan, so that what walks in is foreground for its first scan.
    pub fn update(&mut self, ranges_m: &[f32], t_ns: u64, p: &BackgroundParams) {
        if ranges_m.len() != self.ranges_m.len() {
            *self = Background::seeded(ranges_m.to_vec());
            return;
        }
        let absorb_ns = (p.absorb_s * 1e9) as u64;
        let forget_ns = (p.forget_s * 1e9) as u64;
        for ((b, cand), &r) in self
            .ranges_m
            .iter_mut()
            .zip(self.candidates.iter_mut())
            .zip(ranges_m)
        {
            if !r.is_finite() {
                continue;
            }
            if b.is_finite() && r > *b + p.reveal_m as f32 + 0.01 * r {
                *b = r;
                *cand = None;
                continue;
            }
            let short = b.is_nan() || r < *b - p.reveal_m as f32 - 0.01 * r;
            if !short {
                // The background seen again: nothing stands in front of it for good. Keep it
                // from drifting with the noise.
                *b += 0.05 * (r - *b);
                *cand = None;
                continue;
            }
            let tol = p.hold_tol_m as f32;
            match cand {
                Some(c)
                    if t_ns.saturating_sub(c.last_ns) <= forget_ns
                        && (r - c.range_m).abs() <= tol =>
                {
                    c.last_ns = t_ns;
                    c.range_m += 0.1 * (r - c.range_m);
                    if t_ns.saturating_sub(c.since_ns) >= absorb_ns {
                        *b = c.range_m;
                        *cand = None;
                    }
                }
                // Someone passing in front of the candidate hides it for a moment.
                Some(c) if t_ns.saturating_sub(c.last_ns) <= forget_ns && r < c.range_m - tol => {}
                _ => {
                    *cand = Some(Candidate {
                        range_m: r,
                        since_ns: t_ns,
                        last_ns: t_ns,
                    });
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: u64 = 1_000_000_000;

    #[test]
    fn a_box_put_down_fades_in_and_a_person_standing_a_minute_does_not() {
        let p = BackgroundParams::default();
        let mut bg = Background::seeded(vec![5.0; 4]);
        // A box at 3 m on beam 1 from t = 0; a person at 2 m ± 3 cm on beam 2 for 60 s.
        let mut t = 0;
        while t <= 100 * S {
            let sway = if (t / S).is_multiple_of(2) {
                0.03
            } else {
                -0.03
            };
            let person = if t <= 60 * S { 2.0 + sway } else { 5.0 };
            bg.update(&[5.0, 3.0, person, 5.0], t, &p);
            if t == 60 * S {
                assert!((bg.ranges_m()[2] - 5.0).abs() < 0.05, "{:?}", bg.ranges_m());
                assert!((bg.ranges_m()[1] - 5.0).abs() < 0.05, "{:?}", bg.ranges_m());
            }
            t += S / 40;
        }
        assert!((bg.ranges_m()[1] - 3.0).abs() < 0.05, "{:?}", bg.ranges_m());
        assert!((bg.ranges_m()[2] - 5.0).abs() < 0.05, "{:?}", bg.ranges_m());
    }

    #[test]
    fn people_in_the_first_scan_give_way_to_the_wall_behind_them() {
        let p = BackgroundParams::default();
        let mut bg = Background::seeded(vec![2.0, 5.0]);
        bg.update(&[5.0, 5.0], S, &p);
        assert_eq!(bg.ranges_m(), &[5.0, 5.0]);
        // A crowd passing at random ranges, the wall seen between them, never becomes
        // background.
        let mut t = 2 * S;
        let mut seed = 12345u64;
        while t < 200 * S {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = (seed >> 33) as f32 / (1u64 << 31) as f32;
            let r = if u < 0.3 { 5.0 } else { 1.0 + 3.5 * u };
            bg.update(&[r, 5.0], t, &p);
            t += S / 40;
        }
        assert!((bg.ranges_m()[0] - 5.0).abs() < 0.05, "{:?}", bg.ranges_m());
    }
}
