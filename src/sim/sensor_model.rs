//! What a Hokuyo reports for one beam, given what the beam's footprint covers.
//!
//! Each beam is cast as three sub-rays across its footprint (centre and ±0.4 step, so a depth
//! edge is straddled by about one beam). From those hits this module draws the reported range
//! and intensity:
//!
//! - **Noise.** Gaussian, σ = a third of the spec bound (METHOD.md §7): the UTM's ±30 mm to
//!   10 m and ±50 mm to 30 m give σ = 10 mm up to 10 m rising linearly to 16.7 mm at 30 m
//!   (and on beyond); the UXM's ±50/±100 mm give 16.7 → 33.3 mm; the URG-04LX's ±10 mm to 1 m
//!   and ±1 % of the distance beyond give 3.3 mm up to 1 m, then 0.33 % of the range
//!   ([`NoiseLaw`]). Weak returns (dark, far,
//!   grazing) are noisier: σ grows with 1/√signal below a reference signal, up to 3×.
//!   Weak returns also read long, by up to [`WEAK_BIAS_M`] (the range walk of a time-of-flight
//!   receiver on a small pulse), so dark and grazing surfaces sit a little behind where they are.
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
/// How much further than the truth the weakest returns read, m.
pub(crate) const WEAK_BIAS_M: f64 = 0.015;
/// Chance a beam reports a spurious short range.
const SPURIOUS_RATE: f64 = 2e-4;

/// How the spec-level σ of the range noise grows with range, as each model's data sheet
/// states its accuracy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum NoiseLaw {
    /// A fixed bound to 10 m and another to 30 m (UTM, UXM): σ `near_m` at and below 10 m,
    /// rising linearly to `far_m` at 30 m and on beyond.
    NearFar { near_m: f64, far_m: f64 },
    /// A fixed bound close in, a share of the distance further out (URG-04LX): σ is the larger
    /// of `floor_m` and `fraction` × range.
    Proportional { floor_m: f64, fraction: f64 },
}

impl NoiseLaw {
    /// σ at full signal for a return at this range, m.
    fn sigma_m(self, range_m: f64) -> f64 {
        match self {
            NoiseLaw::NearFar { near_m, far_m } => {
                let slope = (far_m - near_m) / 20.0;
                near_m + slope * (range_m - 10.0).max(0.0)
            }
            NoiseLaw::Proportional { floor_m, fraction } => floor_m.max(fraction * range_m),
        }
    }
}

/// The per-model constants of the beam model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BeamModel {
    pub dmin_m: f64,
    pub dmax_m: f64,
    /// σ of the range noise at full signal, by range.
    pub noise: NoiseLaw,
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
                noise: NoiseLaw::NearFar {
                    near_m: 0.030 / 3.0,
                    far_m: 0.050 / 3.0,
                },
                intensity_gain: 4000.0,
                sensitivity: 1.0,
            },
            Model::Uxm30lxE => BeamModel {
                dmin_m,
                dmax_m,
                noise: NoiseLaw::NearFar {
                    near_m: 0.050 / 3.0,
                    far_m: 0.100 / 3.0,
                },
                intensity_gain: 3000.0,
                sensitivity: 1.2,
            },
            Model::Urg04lx => BeamModel {
                dmin_m,
                dmax_m,
                // ±10 mm from 60 mm to 1 m, ±1 % of the distance from 1 m to 4 m; the two
                // meet at 1 m, and the share carries on to DMAX.
                noise: NoiseLaw::Proportional {
                    floor_m: 0.010 / 3.0,
                    fraction: 0.01 / 3.0,
                },
                // Never used: the URG-04LX sends no intensities (plans may not ask for them).
                intensity_gain: 0.0,
                // A small class 1 unit built for 4 m on white paper, not 30 m: its receiver
                // gathers far less light than the UTM's, so dark and grazing surfaces drop
                // out and read noisier well before its 5.6 m DMAX cuts the range.
                sensitivity: 0.5,
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
        let base = self.noise.sigma_m(range_m);
        let weak = (FULL_SIGNAL / signal.max(1e-9)).sqrt().clamp(1.0, 3.0);
        base * weak
    }

    /// Systematic range error of a return of this signal: none at full signal, growing to
    /// [`WEAK_BIAS_M`] as the signal vanishes.
    pub fn bias_m(&self, signal: f64) -> f64 {
        WEAK_BIAS_M * (1.0 - (signal / FULL_SIGNAL).min(1.0))
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

/// Two independent standard normal draws (Box–Muller).
pub(crate) fn normal_pair(rng: &mut impl Rng) -> (f64, f64) {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random();
    let radius = (-2.0 * u1.ln()).sqrt();
    let (sin, cos) = (std::f64::consts::TAU * u2).sin_cos();
    (radius * cos, radius * sin)
}

/// What the sensor reports for a beam whose three footprint sub-rays hit `subs`
/// (centre in the middle).
pub(crate) fn read_beam(
    model: &BeamModel,
    subs: &[Option<Hit>; 3],
    with_intensity: bool,
    rng: &mut impl Rng,
) -> Reading {
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
    let mut near_share = || {
        let jitter = (rng.random::<f64>() - 0.5) / 3.0;
        ((near_count as f64) / 3.0 + jitter).clamp(0.05, 0.95)
    };

    let (hit, signal, mixed) = match (near_count, far) {
        (3, _) => {
            let hit = centre.unwrap_or(near);
            (hit, model.signal(&hit), false)
        }
        // Part of the footprint sees nothing: the near surface returns with less energy.
        (_, None) => (near, model.signal(&near) * near_share(), false),
        (_, Some(far)) => {
            let near_share = near_share();
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
    if rng.random::<f64>() < model.dropout_probability(signal) {
        return NO_RETURN;
    }
    let (range_noise, intensity_noise) = normal_pair(rng);
    let range_m =
        hit.range_m + model.bias_m(signal) + model.sigma_m(hit.range_m, signal) * range_noise;
    let intensity = if with_intensity {
        model.intensity(&hit) * (1.0 + 0.03 * intensity_noise)
    } else {
        0.0
    };
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
            .map(|_| {
                read_beam(
                    &model,
                    &[hit(5.0, 0), hit(5.0, 0), hit(5.0, 0)],
                    true,
                    &mut rng,
                )
            })
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
    fn each_model_states_its_noise_law() {
        let full = 1.0;
        let utm = utm();
        // The UTM keeps its near/far law: 10 mm to 10 m, 16.7 mm at 30 m, on beyond.
        assert_eq!(utm.sigma_m(5.0, full), 0.010);
        assert!((utm.sigma_m(30.0, full) - 0.050 / 3.0).abs() < 1e-15);
        assert!(utm.sigma_m(40.0, full) > utm.sigma_m(30.0, full));
        let urg = BeamModel::of(Model::Urg04lx, 0.020, 5.6);
        // The URG: 3.3 mm to 1 m, then a third of 1 % of the range.
        assert!((urg.sigma_m(0.3, full) - 0.010 / 3.0).abs() < 1e-15);
        assert!((urg.sigma_m(1.0, full) - 0.010 / 3.0).abs() < 1e-15);
        assert!((urg.sigma_m(2.0, full) - 0.020 / 3.0).abs() < 1e-15);
        assert!((urg.sigma_m(4.0, full) - 0.040 / 3.0).abs() < 1e-15);
        // A weaker receiver: the same dark target is weaker, so it drops out more often.
        let dark = Hit {
            range_m: 5.0,
            cos_incidence: 1.0,
            reflectivity: 0.05,
            surface: Surface::Shape(0),
        };
        assert!(urg.signal(&dark) < utm.signal(&dark));
        assert!(
            urg.dropout_probability(urg.signal(&dark)) > utm.dropout_probability(utm.signal(&dark))
        );
    }

    #[test]
    fn dark_surfaces_read_noisier_and_a_little_long() {
        let model = utm();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        // Albedo 0.05 at 10 m: signal 0.05, a quarter of full.
        let dark = Some(Hit {
            range_m: 10.0,
            cos_incidence: 1.0,
            reflectivity: 0.05,
            surface: Surface::Shape(0),
        });
        let errors: Vec<f64> = (0..40_000)
            .map(|_| read_beam(&model, &[dark, dark, dark], false, &mut rng))
            .filter(|r| r.range_m > 0.0)
            .map(|r| r.range_m as f64 - 10.0)
            .filter(|e| e.abs() < 0.2)
            .collect();
        assert!(errors.len() > 20_000, "{} returns", errors.len());
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let sd =
            (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt();
        let expected_bias = WEAK_BIAS_M * 0.75;
        assert!(
            (mean - expected_bias).abs() < 0.001,
            "mean {mean}, expected {expected_bias}"
        );
        assert!(
            (sd - 0.020).abs() < 0.002,
            "sd {sd}: twice the spec σ at a quarter of full signal"
        );
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
            let r = read_beam(
                &model,
                &[hit(3.0, 0), hit(3.0, 0), hit(6.0, 1)],
                true,
                &mut rng,
            );
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
