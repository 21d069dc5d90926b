//! Global assignment of detections to tracks: the Hungarian method (`pathfinding`'s
//! Kuhn–Munkres) on a gated cost, solved per group of tracks and detections the gate links
//! (a crowd splits into small independent problems).

use pathfinding::kuhn_munkres::kuhn_munkres_min;
use pathfinding::matrix::Matrix;

/// Costs are rounded to this many units per cost unit for the integer solver.
const SCALE: f64 = 1000.0;

/// Assigns rows (tracks) to columns (detections) minimising the summed cost, where
/// `cost(row, col)` is `Some(c)` for a pair inside the gate and `None` outside; a row may
/// stay unassigned at cost `gate`, so no pair costing more than `gate` is taken. Returns, per
/// row, its column.
pub fn assign(
    rows: usize,
    cols: usize,
    gate: f64,
    mut cost: impl FnMut(usize, usize) -> Option<f64>,
) -> Vec<Option<usize>> {
    let mut out = vec![None; rows];
    if rows == 0 || cols == 0 {
        return out;
    }
    // Gated pairs, and the groups they link (union-find over rows and columns).
    let mut pairs: Vec<(usize, usize, f64)> = Vec::new();
    for r in 0..rows {
        for c in 0..cols {
            if let Some(v) = cost(r, c).filter(|v| v.is_finite() && *v <= gate) {
                pairs.push((r, c, v));
            }
        }
    }
    let mut parent: Vec<usize> = (0..rows + cols).collect();
    fn find(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for &(r, c, _) in &pairs {
        let (a, b) = (find(&mut parent, r), find(&mut parent, rows + c));
        if a != b {
            parent[a] = b;
        }
    }
    let mut groups: std::collections::BTreeMap<usize, (Vec<usize>, Vec<usize>)> =
        Default::default();
    for &(r, c, _) in &pairs {
        let g = find(&mut parent, r);
        let entry = groups.entry(g).or_default();
        if !entry.0.contains(&r) {
            entry.0.push(r);
        }
        if !entry.1.contains(&c) {
            entry.1.push(c);
        }
    }
    let gated: std::collections::HashMap<(usize, usize), f64> =
        pairs.iter().map(|&(r, c, v)| ((r, c), v)).collect();
    let never = (gate * SCALE).round() as i64 * 4 + 1;
    for (_, (gr, gc)) in groups {
        // Rows: the group's tracks; columns: its detections, then one "unassigned" per row.
        let (nr, nc) = (gr.len(), gc.len());
        let lookup = |r: usize, c: usize| gated.get(&(r, c)).copied();
        let mut local = vec![never; nr * nc];
        for (i, &r) in gr.iter().enumerate() {
            for (j, &c) in gc.iter().enumerate() {
                if let Some(v) = lookup(r, c) {
                    local[i * nc + j] = (v * SCALE).round() as i64;
                }
            }
        }
        let unassigned = (gate * SCALE).round() as i64;
        let m = Matrix::from_fn(nr, nc + nr, |(i, j)| {
            if j < nc {
                local[i * nc + j]
            } else {
                unassigned
            }
        });
        let (_, chosen) = kuhn_munkres_min(&m);
        for (i, &j) in chosen.iter().enumerate() {
            if j < nc && local[i * nc + j] < never {
                out[gr[i]] = Some(gc[j]);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_global_optimum_beats_greedy_and_the_gate_holds() {
        // Greedy would give row 0 column 0 (cost 1) and leave row 1 with 10; the optimum
        // is 0→1, 1→0 (2 + 2).
        let costs = [[1.0, 2.0], [2.0, 10.0]];
        let got = assign(2, 2, 9.0, |r, c| Some(costs[r][c]));
        assert_eq!(got, vec![Some(1), Some(0)]);
        // Outside the gate: unassigned.
        let got = assign(
            2,
            1,
            9.0,
            |r, _| if r == 0 { Some(20.0) } else { Some(3.0) },
        );
        assert_eq!(got, vec![None, Some(0)]);
        // More tracks than detections, and the other way round.
        let got = assign(3, 1, 9.0, |r, _| Some(r as f64 + 1.0));
        assert_eq!(got, vec![Some(0), None, None]);
        let got = assign(1, 3, 9.0, |_, c| Some(3.0 - c as f64));
        assert_eq!(got, vec![Some(2)]);
    }
}
