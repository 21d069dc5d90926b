//! What a Hokuyo reports for one beam, given what the beam's footprint covers.
//!
//! Each beam is cast as three sub-rays across its footprint (one step wide). From those hits
//! this module draws the reported range and intensity:
//!
//! - **Noise.** Gaussian, σ = a third of the spec bound (METHOD.md §7): the UTM's ±30 mm to
//!   10 m and ±50 mm to 30 m give σ = 10 mm up to 10 m rising linearly to 16.7 mm at 30 m
//!   (and on beyond); the UXM's ±50/±100 mm give 16.7 → 33.3 mm. Weak returns (dark, far,
//!   grazing) are noisier: σ grows with 1/√signal below a reference signal, up to 3×.
//!   Ranges are whole millimetres, as SCIP sends them.
//! - **Dropouts.** Probability `floor + 1 / (1 + (s / s50)²)` on the received signal
//!   `s = reflectivity · cos(incidence) · (10 m / range)²`: a white wall square on at 10 m
//!   drops ~0.3 %, at 30 m ~10 %; a dark surface at 20 m most of the time.
//! - **Mixed pixels.** When the sub-rays land on different surfaces more than a few cm apart
//!   in depth, the beam straddles an edge: with probability [`MIXED_PROBABILITY`] it reports the
//!   energy-weighted mean of the two depths (a point in mid-air), otherwise the stronger one.
//! - **Intensity.** UTM-like magnitudes (≈2,500 for a light wall at 3 m, tens of thousands for
//!   retro-reflectors): a baseline plus reflectivity · cos(incidence)^0.8 falling with range.
//! - **Spurious returns.** Rarely (dust, sunlight) a beam reports a random range short of its target.

use rand::Rng;

use super::plan::Model;
use super::scene::Hit;

/// How often a beam that straddles a depth edge reports a depth between the two surfaces.
pub(crate) const MIXED_PROBABILITY: f64 = 0.6;
/// Sub-ray depth difference above which a footprint straddles an edge, m.
const EDGE_GAP_M: f64 = 0.05;
/// Signal at which half the beams drop out.
const HALF_DROP_SIGNAL: f64 = 0.03;
/// Dropout rate even on a perfect target.
const DROPOUT_FLOOR: f64 = 0.002;
/// Signal at and above which noise is the spec figure.
const FULL_SIGNAL: f64 = 0.2;
/// Chance a beam reports a spurious short range.
const SPURIOUS_RATE: f64 = 2e-4;

/// The per-model constants of the beam model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BeamModel {
    pub dmin_m: f64,
    pub dmax_m: f64,
    /// σ at and below 10 m, m.
    pub sigma_near_m: f64,
    /// σ at 30 m, m.
    pub sigma_far_m: f64,
    /// Intensity of a white target square on at 0 m, before the baseline.
    pub intensity_gain: f64,
    /// Sensitivity relative to the UTM (scales the signal).
    pub sensitivity: f64,
}

impl BeamModel {
    pub fn of(model: Model, dmin_m: f64, dmax_m: f64) -> BeamModel {
        match model {
            Model::Utm30lxEw => BeamModel {
                dmin_m,
                dmax_m,
                sigma_near_m: 0.030 / 3.0,
                sigma_far_m: 0.050 / 3.0,
                intensity_gain: 4000.0,
                sensitivity: 1.0,
            },
            Model::Uxm30lxE => BeamModel {
                dmin_m,
                dmax_m,
                sigma_near_m: 0.050 / 3.0,
                sigma_far_m: 0.100 / 3.0,
                intensity_gain: 3000.0,
                sensitivity: 1.2,
            },
        }
    }

    /// Received signal strength of a hit, relative (1 ≈ white wall square on at 10 m).
    pub fn signal(&self, hit: &Hit) -> f64 {
        let r = hit.range_m.max(1.0);
        self.sensitivity * hit.reflectivity * hit.cos_incidence * (10.0 / r).powi(2)
    }

    /// σ of the range noise for a hit of this signal at this range.
    pub fn sigma_m(&self, range_m: f64, signal: f64) -> f64 {
        let slope = (self.sigma_far_m - self.sigma_near_m) / 20.0;
        let base = self.sigma_near_m + slope * (range_m - 10.0).max(0.0);
        let weak = (FULL_SIGNAL / signal.max(1e-9)).sqrt().clamp(1.0, 3.0);
        base * weak
    }

    /// Probability that a return of this signal is lost.
    pub fn dropout_probability(&self, signal: f64) -> f64 {
        let x = signal / HALF_DROP_SIGNAL;
        (DROPOUT_FLOOR + 1.0 / (1.0 + x * x)).min(1.0)
    }

    /// Intensity of a return, before noise.
    pub fn intensity(&self, hit: &Hit) -> f64 {
        let falloff = 1.0 + (hit.range_m / 8.0).powf(1.2);
        500.0 + self.intensity_gain * hit.reflectivity * hit.cos_incidence.powf(0.8) / falloff
    }
}

/// One reported beam: range in m (0 = no return) and intensity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Reading {
    pub range_m: f32,
    pub intensity: f32,
    /// The beam straddled an edge and reported a depth between two surfaces.
    pub mixed: bool,
}

const NO_RETURN: Reading = Reading {
    range_m: 0.0,
    intensity: 0.0,
    mixed: false,
};

/// A standard normal draw (Box–Muller).
pub(crate) fn normal(rng: &mut impl Rng) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// What the sensor reports for a beam whose three footprint sub-rays hit `subs`
/// (centre in the middle).
pub(crate) fn read_beam(model: &BeamModel, subs: &[Option<Hit>; 3], rng: &mut impl Rng) -> Reading {
    let [_, centre, _] = subs;
    let near = subs
        .iter()
        .flatten()
        .min_by(|a, b| a.range_m.total_cmp(&b.range_m));
    let Some(near) = near.copied() else {
        return NO_RETURN;
    };
    let on_near = |h: &Option<Hit>| {
        h.is_some_and(|h| h.surface == near.surface || h.range_m - near.range_m < EDGE_GAP_M)
    };
    let near_count = subs.iter().filter(|h| on_near(h)).count();
    let far = subs
        .iter()
        .flatten()
        .filter(|h| !on_near(&Some(**h)))
        .max_by(|a, b| a.range_m.total_cmp(&b.range_m))
        .copied();
    // Share of the footprint on the near surface, blurred: the spot is not a top hat.
    let jitter = (rng.random::<f64>() - 0.5) / 3.0;
    let near_share = ((near_count as f64) / 3.0 + jitter).clamp(0.05, 0.95);

    let (hit, signal, mixed) = match (near_count, far) {
        (3, _) => {
            let hit = centre.unwrap_or(near);
            (hit, model.signal(&hit), false)
        }
        // Part of the footprint sees nothing: the near surface returns with less energy.
        (_, None) => (near, model.signal(&near) * near_share, false),
        (_, Some(far)) => {
            let e_near = model.signal(&near) * near_share;
            let e_far = model.signal(&far) * (1.0 - near_share);
            if rng.random::<f64>() < MIXED_PROBABILITY {
                let range_m = (e_near * near.range_m + e_far * far.range_m) / (e_near + e_far);
                let hit = Hit {
                    range_m,
                    cos_incidence: (near.cos_incidence * e_near + far.cos_incidence * e_far)
                        / (e_near + e_far),
                    reflectivity: near.reflectivity.max(far.reflectivity),
                    ..near
                };
                (hit, e_near + e_far, true)
            } else if e_near >= e_far {
                (near, e_near, false)
            } else {
                (far, e_far, false)
            }
        }
    };

    if rng.random::<f64>() < SPURIOUS_RATE {
        let range_m = model.dmin_m + rng.random::<f64>() * (hit.range_m - model.dmin_m).max(0.0);
        return finish(model, range_m, 300.0 + 500.0 * rng.random::<f64>(), false);
    }
    let intensity = model.intensity(&hit) * (1.0 + 0.03 * normal(rng)) + 20.0 * normal(rng);
    if rng.random::<f64>() < model.dropout_probability(signal) {
        return NO_RETURN;
    }
    let range_m = hit.range_m + model.sigma_m(hit.range_m, signal) * normal(rng);
    finish(model, range_m, intensity, mixed)
}

fn finish(model: &BeamModel, range_m: f64, intensity: f64, mixed: bool) -> Reading {
    if !(model.dmin_m..=model.dmax_m).contains(&range_m) {
        return NO_RETURN;
    }
    Reading {
        range_m: ((range_m * 1000.0).round() / 1000.0) as f32,
        intensity: intensity.clamp(0.0, 60_000.0).round() as f32,
        mixed,
    }
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::sim::scene::Surface;

    fn hit(range_m: f64, surface: u32) -> Option<Hit> {
        Some(Hit {
            range_m,
            cos_incidence: 1.0,
            reflectivity: 0.7,
            surface: Surface::Shape(surface),
        })
    }

    fn utm() -> BeamModel {
        BeamModel::of(Model::Utm30lxEw, 0.023, 60.0)
    }

    #[test]
    fn noise_matches_the_spec_bound_as_three_sigma() {
        let model = utm();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let n = 20_000;
        let errors: Vec<f64> = (0..n)
            .map(|_| read_beam(&model, &[hit(5.0, 0), hit(5.0, 0), hit(5.0, 0)], &mut rng))
            .filter(|r| r.range_m > 0.0)
            .map(|r| r.range_m as f64 - 5.0)
            .collect();
        // Spurious returns (dust) are rare and far off; leave them out of the noise figures.
        let spurious = errors.iter().filter(|e| e.abs() > 0.2).count();
        assert!(spurious < 20, "{spurious} spurious returns in {n}");
        let errors: Vec<f64> = errors.into_iter().filter(|e| e.abs() <= 0.2).collect();
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let sd =
            (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt();
        assert!(mean.abs() < 0.0005, "mean {mean}");
        assert!((sd - 0.010).abs() < 0.001, "sd {sd}");
        let beyond = errors.iter().filter(|e| e.abs() > 0.030).count() as f64 / errors.len() as f64;
        assert!(beyond < 0.01, "{beyond} beyond the spec bound");
    }

    #[test]
    fn dropouts_grow_with_range_and_darkness() {
        let model = utm();
        let white = |r: f64| Hit {
            range_m: r,
            cos_incidence: 1.0,
            reflectivity: 0.8,
            surface: Surface::Shape(0),
        };
        let p10 = model.dropout_probability(model.signal(&white(10.0)));
        let p30 = model.dropout_probability(model.signal(&white(30.0)));
        let dark20 = Hit {
            reflectivity: 0.08,
            ..white(20.0)
        };
        let pdark = model.dropout_probability(model.signal(&dark20));
        let grazing = Hit {
            cos_incidence: 0.1,
            ..white(10.0)
        };
        let pgraze = model.dropout_probability(model.signal(&grazing));
        assert!(p10 < 0.005, "{p10}");
        assert!((0.05..0.2).contains(&p30), "{p30}");
        assert!(pdark > 0.5, "{pdark}");
        assert!(pgraze > p10 * 5.0, "{pgraze}");
    }

    #[test]
    fn beam_across_an_edge_sometimes_reports_a_depth_in_between() {
        let model = utm();
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let n = 10_000;
        let mut between = 0;
        let mut near = 0;
        let mut far = 0;
        for _ in 0..n {
            let r = read_beam(&model, &[hit(3.0, 0), hit(3.0, 0), hit(6.0, 1)], &mut rng);
            let d = r.range_m as f64;
            if r.range_m == 0.0 {
                continue;
            } else if (d - 3.0).abs() < 0.05 {
                near += 1;
            } else if (d - 6.0).abs() < 0.05 {
                far += 1;
            } else if d > 3.05 && d < 5.95 {
                between += 1;
                assert!(r.mixed);
            }
        }
        let between = between as f64 / n as f64;
        assert!((0.4..0.8).contains(&between), "mixed share {between}");
        assert!(near > far, "near {near} far {far}");
    }

    #[test]
    fn intensity_has_utm_magnitudes_and_falls_with_range_and_incidence() {
        let model = utm();
        let at = |r: f64, c: f64| {
            model.intensity(&Hit {
                range_m: r,
                cos_incidence: c,
                reflectivity: 0.7,
                surface: Surface::Floor,
            })
        };
        assert!((1500.0..4000.0).contains(&at(3.3, 1.0)), "{}", at(3.3, 1.0));
        assert!(at(20.0, 1.0) < at(3.3, 1.0));
        assert!(at(3.3, 0.2) < at(3.3, 1.0));
    }
}
