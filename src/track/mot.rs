//! CLEAR-MOT (Bernardin & Stiefelhagen, 2008): how tracks compare with the true people, frame
//! by frame. A truth and a track match within `radius_m`; a correspondence of the previous
//! frame is kept while it stays within the radius, the rest are matched by the Hungarian
//! method on distance. Misses, false tracks and identity switches add up to MOTA's errors;
//! MOTP is the mean distance of the matches.

use std::collections::BTreeMap;

use super::assign::assign;

/// The running tallies.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ClearMot {
    pub radius_m: f64,
    /// Truth objects over all frames.
    pub truths: usize,
    pub matches: usize,
    pub misses: usize,
    pub false_tracks: usize,
    pub id_switches: usize,
    pub frames: usize,
    /// Summed distance of the matches (m).
    pub distance_m: f64,
    /// Truth id → the track it was last matched to.
    last: BTreeMap<String, u64>,
}

impl ClearMot {
    pub fn new(radius_m: f64) -> ClearMot {
        ClearMot {
            radius_m,
            ..ClearMot::default()
        }
    }

    /// One frame: the true people (id, x, y) and the tracks (id, x, y) at the same instant.
    /// Returns the identity switches of this frame: (truth index, track it had, track it has).
    pub fn frame(
        &mut self,
        truth: &[(String, f64, f64)],
        tracks: &[(u64, f64, f64)],
    ) -> Vec<(usize, u64, u64)> {
        let mut switches = Vec::new();
        self.frames += 1;
        self.truths += truth.len();
        let dist = |i: usize, j: usize| {
            let (_, tx, ty) = &truth[i];
            let (_, x, y) = tracks[j];
            ((tx - x).powi(2) + (ty - y).powi(2)).sqrt()
        };
        let mut truth_to: Vec<Option<usize>> = vec![None; truth.len()];
        let mut used = vec![false; tracks.len()];
        // Correspondences kept from the previous frame.
        for (i, (id, _, _)) in truth.iter().enumerate() {
            let Some(prev) = self.last.get(id) else {
                continue;
            };
            if let Some(j) = tracks.iter().position(|(tid, _, _)| tid == prev)
                && !used[j]
                && dist(i, j) <= self.radius_m
            {
                truth_to[i] = Some(j);
                used[j] = true;
            }
        }
        let rows: Vec<usize> = (0..truth.len())
            .filter(|&i| truth_to[i].is_none())
            .collect();
        let cols: Vec<usize> = (0..tracks.len()).filter(|&j| !used[j]).collect();
        let chosen = assign(rows.len(), cols.len(), self.radius_m, |r, c| {
            Some(dist(rows[r], cols[c]))
        });
        for (r, c) in chosen.iter().enumerate() {
            if let Some(c) = c {
                truth_to[rows[r]] = Some(cols[*c]);
                used[cols[*c]] = true;
            }
        }
        for (i, m) in truth_to.iter().enumerate() {
            let Some(j) = *m else {
                self.misses += 1;
                continue;
            };
            self.matches += 1;
            self.distance_m += dist(i, j);
            let id = &truth[i].0;
            let track = tracks[j].0;
            if let Some(prev) = self.last.insert(id.clone(), track)
                && prev != track
            {
                self.id_switches += 1;
                switches.push((i, prev, track));
            }
        }
        self.false_tracks += used.iter().filter(|u| !**u).count();
        switches
    }

    /// 1 − (misses + false tracks + id switches) / truths.
    pub fn mota(&self) -> f64 {
        if self.truths == 0 {
            return f64::NAN;
        }
        1.0 - (self.misses + self.false_tracks + self.id_switches) as f64 / self.truths as f64
    }

    /// Mean distance of the matches (m).
    pub fn motp_m(&self) -> f64 {
        if self.matches == 0 {
            return f64::NAN;
        }
        self.distance_m / self.matches as f64
    }

    /// Adds another run's tallies (different truth ids).
    pub fn add(&mut self, other: &ClearMot) {
        self.truths += other.truths;
        self.matches += other.matches;
        self.misses += other.misses;
        self.false_tracks += other.false_tracks;
        self.id_switches += other.id_switches;
        self.frames += other.frames;
        self.distance_m += other.distance_m;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn misses_false_tracks_and_switches_are_counted() {
        let mut m = ClearMot::new(0.5);
        let truth = |x: f64| vec![("a".to_string(), x, 0.0), ("b".to_string(), x, 3.0)];
        m.frame(&truth(0.0), &[(1, 0.1, 0.0), (2, 0.0, 3.0)]);
        // Tracks swap ids: two switches; a far track: one false track.
        m.frame(&truth(0.1), &[(2, 0.1, 0.0), (1, 0.1, 3.0), (3, 9.0, 9.0)]);
        // b lost: one miss.
        m.frame(&truth(0.2), &[(2, 0.2, 0.0)]);
        assert_eq!((m.truths, m.matches, m.misses), (6, 5, 1));
        assert_eq!((m.false_tracks, m.id_switches), (1, 2));
        assert!((m.mota() - (1.0 - 4.0 / 6.0)).abs() < 1e-9);
        assert!((m.motp_m() - 0.1 / 5.0).abs() < 1e-9);
    }
}
