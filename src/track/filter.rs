//! A constant-velocity Kalman filter in the plane: state (x, y, vx, vy), position measured.

use nalgebra::{Matrix2, Matrix2x4, Matrix4, Point2, Vector2, Vector4};

/// One person's motion estimate, site frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Kalman {
    /// x_m, y_m, vx_m_s, vy_m_s.
    pub x: Vector4<f64>,
    pub p: Matrix4<f64>,
}

const H: Matrix2x4<f64> = Matrix2x4::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0);

impl Kalman {
    /// A filter at `at`, standing still with velocity uncertainty `sigma_v_m_s` and position
    /// uncertainty `sigma_m`.
    pub fn new(at: Point2<f64>, sigma_m: f64, sigma_v_m_s: f64) -> Kalman {
        let (a, v) = (sigma_m * sigma_m, sigma_v_m_s * sigma_v_m_s);
        Kalman {
            x: Vector4::new(at.x, at.y, 0.0, 0.0),
            p: Matrix4::from_diagonal(&Vector4::new(a, a, v, v)),
        }
    }

    pub fn position(&self) -> Point2<f64> {
        Point2::new(self.x[0], self.x[1])
    }

    pub fn velocity(&self) -> Vector2<f64> {
        Vector2::new(self.x[2], self.x[3])
    }

    /// Root of the larger eigenvalue of the position covariance (m).
    pub fn sigma_m(&self) -> f64 {
        let c = self.p.fixed_view::<2, 2>(0, 0);
        let (a, b, d) = (c[(0, 0)], c[(0, 1)], c[(1, 1)]);
        let mean = 0.5 * (a + d);
        let diff = (0.25 * (a - d) * (a - d) + b * b).sqrt();
        (mean + diff).max(0.0).sqrt()
    }

    /// Caps the speed at `max_m_s` (people walk; a faster estimate is noise that would carry
    /// an unseen track away from its person).
    pub fn limit_speed(&mut self, max_m_s: f64) {
        let speed = self.velocity().norm();
        if speed > max_m_s {
            let k = max_m_s / speed;
            self.x[2] *= k;
            self.x[3] *= k;
        }
    }

    /// Moves the estimate `dt_s` ahead; `accel_psd` is the white acceleration's spectral
    /// density (m²/s³): how fast a walker changes speed and direction.
    pub fn predict(&mut self, dt_s: f64, accel_psd: f64) {
        if dt_s <= 0.0 {
            return;
        }
        let mut f = Matrix4::identity();
        f[(0, 2)] = dt_s;
        f[(1, 3)] = dt_s;
        let (t2, t3) = (dt_s * dt_s / 2.0, dt_s * dt_s * dt_s / 3.0);
        let q = Matrix4::new(
            t3, 0.0, t2, 0.0, //
            0.0, t3, 0.0, t2, //
            t2, 0.0, dt_s, 0.0, //
            0.0, t2, 0.0, dt_s,
        ) * accel_psd;
        self.x = f * self.x;
        self.p = f * self.p * f.transpose() + q;
    }

    /// The innovation of a measurement at `z` with noise `sigma_m`, and its covariance.
    pub fn innovation(&self, z: &Point2<f64>, sigma_m: f64) -> (Vector2<f64>, Matrix2<f64>) {
        let y = z.coords - H * self.x;
        let s = H * self.p * H.transpose() + Matrix2::identity() * (sigma_m * sigma_m);
        (y, s)
    }

    /// How unlikely a position measured at `z` with noise `sigma_m` is for this track: its
    /// negative log-likelihood up to a constant, the squared Mahalanobis distance plus
    /// ln(det S / σ⁴), 0 for a measurement right where a track known exactly expects it. The
    /// distance alone favours the least certain track (a wide covariance makes any
    /// detection near), so a track coasting unseen would take the person of one seen a
    /// moment ago.
    pub fn cost(&self, z: &Point2<f64>, sigma_m: f64) -> Option<f64> {
        let (y, s) = self.innovation(z, sigma_m);
        let inv = s.try_inverse()?;
        let spread = s.determinant() / sigma_m.powi(4);
        (spread > 0.0).then(|| (y.transpose() * inv * y)[(0, 0)] + spread.ln())
    }

    /// Takes a position measured at `z` with noise `sigma_m`.
    pub fn update(&mut self, z: &Point2<f64>, sigma_m: f64) {
        let (y, s) = self.innovation(z, sigma_m);
        let Some(inv) = s.try_inverse() else {
            return;
        };
        let k = self.p * H.transpose() * inv;
        self.x += k * y;
        // Joseph form keeps P symmetric and positive.
        let i_kh = Matrix4::identity() - k * H;
        let r = Matrix2::identity() * (sigma_m * sigma_m);
        self.p = i_kh * self.p * i_kh.transpose() + k * r * k.transpose();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_walker_at_constant_speed_is_followed_with_its_velocity() {
        let mut k = Kalman::new(Point2::new(0.0, 0.0), 0.1, 2.0);
        let dt = 0.025;
        for i in 1..=200 {
            k.predict(dt, 1.0);
            let t = i as f64 * dt;
            // 1.2 m/s along x with ±2 cm alternating noise.
            let noise = if i % 2 == 0 { 0.02 } else { -0.02 };
            k.update(&Point2::new(1.2 * t + noise, 0.5 * t), 0.05);
        }
        assert!(
            (k.velocity() - Vector2::new(1.2, 0.5)).norm() < 0.05,
            "{}",
            k.velocity()
        );
        assert!(
            (k.position() - Point2::new(6.0, 2.5)).norm() < 0.03,
            "{}",
            k.position()
        );
        assert!(k.sigma_m() < 0.05, "{}", k.sigma_m());
        // Coasting grows the uncertainty: where it expects its person costs more than it
        // did while seen, and a far measurement is far in σ.
        let seen = k.cost(&k.position(), 0.05).unwrap_or(f64::INFINITY);
        let before = k.sigma_m();
        k.predict(1.0, 1.0);
        assert!(k.sigma_m() > before);
        let near = k.cost(&k.position(), 0.05).unwrap_or(0.0);
        let far = k
            .cost(&(k.position() + Vector2::new(3.0, 0.0)), 0.05)
            .unwrap_or(0.0);
        assert!(
            seen < 1.0 && near > seen + 2.0 && far > near + 9.0,
            "{seen} {near} {far}"
        );
    }
}
