//! f*: the control law inside p(u | x) = N(f*(mu_x, mu_d), P_u^-1): a PID on the beliefs
//! (docs/method.md, "The control law"; the ECC paper: "converges to a PID").
//!
//! `f* = Kp (mu_d - mu) - Kd mu' + I`, with `I <- clamp(I + Ki dt (mu_d - mu), -I_max, I_max)`
//! (anti-windup by clamping the integral torque). Gains are in SI units, independent of dt.

use serde::{Deserialize, Serialize};

/// PID gains, one entry per joint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PidGains {
    /// Proportional gain (N m / rad).
    pub kp: Vec<f64>,
    /// Derivative gain on the velocity belief (N m s / rad).
    pub kd: Vec<f64>,
    /// Integral gain on the time integral of the error (N m / (rad s)).
    pub ki: Vec<f64>,
    /// Largest integral torque magnitude (N m).
    pub integral_limit: Vec<f64>,
}

impl PidGains {
    /// Gains for the paper arm: Kp = 250, Kd = diag(100, 20) and integral clamp +-50 N m
    /// (docs/method.md, "The control law"), with Ki = 150 N m/(rad s): with 50, joint 1 was still
    /// 0.012 rad short of the first target at 7.5 s (results/studies.md).
    pub fn paper() -> Self {
        Self {
            kp: vec![250.0, 250.0],
            kd: vec![100.0, 20.0],
            ki: vec![150.0, 150.0],
            integral_limit: vec![50.0, 50.0],
        }
    }

    /// Checks the lengths and values; returns the offending field and why.
    pub fn validate(&self, n_joints: usize) -> Result<(), crate::SettingError> {
        for (name, v) in [
            ("kp", &self.kp),
            ("kd", &self.kd),
            ("ki", &self.ki),
            ("integral_limit", &self.integral_limit),
        ] {
            if v.len() != n_joints {
                return Err(crate::SettingError::new(
                    name,
                    format!("has {} entries; the arm has {n_joints} joints", v.len()),
                ));
            }
            if !v.iter().all(|x| x.is_finite() && *x >= 0.0 && *x <= 1e12) {
                return Err(crate::SettingError::new(
                    name,
                    "entries must be finite, >= 0 and <= 1e12",
                ));
            }
        }
        Ok(())
    }
}

/// The PID's state: the integral torque.
#[derive(Clone, Debug)]
pub struct Pid {
    gains: PidGains,
    integral: Vec<f64>,
}

impl Pid {
    pub fn new(gains: PidGains) -> Self {
        let n = gains.kp.len();
        Self {
            gains,
            integral: vec![0.0; n],
        }
    }

    pub fn gains(&self) -> &PidGains {
        &self.gains
    }

    /// The integral torque per joint.
    pub fn integral(&self) -> &[f64] {
        &self.integral
    }

    /// Advances the integral by one tick and writes f*(mu, mu', mu_d) into `out`.
    pub fn step(&mut self, mu: &[f64], mu_p: &[f64], target: &[f64], dt: f64, out: &mut [f64]) {
        let g = &self.gains;
        for i in 0..out.len() {
            let e = target[i] - mu[i];
            let lim = g.integral_limit[i];
            self.integral[i] = (self.integral[i] + g.ki[i] * dt * e).clamp(-lim, lim);
            out[i] = g.kp[i] * e - g.kd[i] * mu_p[i] + self.integral[i];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integral_winds_up_to_its_clamp_and_no_further() {
        let mut pid = Pid::new(PidGains {
            kp: vec![0.0],
            kd: vec![0.0],
            ki: vec![50.0],
            integral_limit: vec![5.0],
        });
        let mut u = [0.0];
        for _ in 0..1000 {
            pid.step(&[0.0], &[0.0], &[1.0], 1e-3, &mut u);
        }
        assert_eq!(u[0], 5.0);
        // Unwinds at once when the error changes sign.
        pid.step(&[0.0], &[0.0], &[-1.0], 1e-3, &mut u);
        assert!((u[0] - 4.95).abs() < 1e-12);
    }

    #[test]
    fn proportional_and_derivative_terms() {
        let mut pid = Pid::new(PidGains {
            kp: vec![250.0],
            kd: vec![100.0],
            ki: vec![0.0],
            integral_limit: vec![0.0],
        });
        let mut u = [0.0];
        pid.step(&[0.1], &[0.2], &[0.3], 1e-3, &mut u);
        assert!((u[0] - (250.0 * 0.2 - 100.0 * 0.2)).abs() < 1e-12);
    }
}
