//! f*: the control law inside p(u | x) = N(f*(mu_x, mu_d), P_u^-1): a PID on the beliefs
//! (docs/method.md, "The control law"; the ECC paper: "converges to a PID").
//!
//! `f* = Kp (mu_d - mu) - Kd mu' + I`, with `I <- clamp(I + Ki dt (mu_d - mu), I_lo, I_hi)`
//! (anti-windup by clamping the integral torque; I_lo = -I_max, I_hi = I_max unless set one by
//! one). Kp and Kd are diagonal unless full matrices are given (a compatibility setting: the
//! authors' MATLAB benchmark damps joint 2 by joint 1's velocity belief). Gains are in SI units,
//! independent of dt.

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
    /// Full proportional-gain matrix (N m / rad), one row per joint, used in place of diag(kp);
    /// its diagonal must equal `kp`. Absent: diag(kp).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kp_matrix: Option<Vec<Vec<f64>>>,
    /// Full derivative-gain matrix (N m s / rad), one row per joint, used in place of diag(kd);
    /// its diagonal must equal `kd`. Absent: diag(kd). The authors' MATLAB benchmark:
    /// `[[100, 0], [20, 0]]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kd_matrix: Option<Vec<Vec<f64>>>,
    /// Lower clamp of the integral torque per joint (N m; `-inf` for none). Absent:
    /// -integral_limit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub integral_lower: Option<Vec<f64>>,
    /// Upper clamp of the integral torque per joint (N m; `inf` for none). Absent:
    /// +integral_limit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub integral_upper: Option<Vec<f64>>,
    /// The integral torque per joint at the first tick (N m), within the clamp. Absent: 0. The
    /// authors' benchmark script never resets its integral between tasks: chaining this
    /// reproduces it (tests/authors_reference.rs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub integral_initial: Option<Vec<f64>>,
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
            kp_matrix: None,
            kd_matrix: None,
            integral_lower: None,
            integral_upper: None,
            integral_initial: None,
        }
    }

    /// Diagonal gains (no matrix, a symmetric clamp).
    pub fn diagonal(kp: Vec<f64>, kd: Vec<f64>, ki: Vec<f64>, integral_limit: Vec<f64>) -> Self {
        Self {
            kp,
            kd,
            ki,
            integral_limit,
            kp_matrix: None,
            kd_matrix: None,
            integral_lower: None,
            integral_upper: None,
            integral_initial: None,
        }
    }

    /// The integral clamp [lower, upper] of joint `i`.
    pub fn integral_clamp(&self, i: usize) -> (f64, f64) {
        let lo = self
            .integral_lower
            .as_ref()
            .map_or(-self.integral_limit[i], |v| v[i]);
        let hi = self
            .integral_upper
            .as_ref()
            .map_or(self.integral_limit[i], |v| v[i]);
        (lo, hi)
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
        for (name, diagonal, matrix) in [
            ("kp_matrix", &self.kp, &self.kp_matrix),
            ("kd_matrix", &self.kd, &self.kd_matrix),
        ] {
            let Some(m) = matrix else { continue };
            if m.len() != n_joints || m.iter().any(|row| row.len() != n_joints) {
                return Err(crate::SettingError::new(
                    name,
                    format!(
                        "must be {n_joints} rows of {n_joints} entries (the arm has {n_joints} joints); \
                         got {} rows of {:?} entries",
                        m.len(),
                        m.iter().map(Vec::len).collect::<Vec<_>>()
                    ),
                ));
            }
            if !m.iter().flatten().all(|x| x.is_finite() && x.abs() <= 1e12) {
                return Err(crate::SettingError::new(
                    name,
                    "entries must be finite with |x| <= 1e12",
                ));
            }
            let base = &name[..2];
            if let Some(i) = (0..n_joints).find(|&i| m[i][i] != diagonal[i]) {
                return Err(crate::SettingError::new(
                    name,
                    format!(
                        "diagonal entry {i} is {}, but `{base}` says {} (the matrix's diagonal \
                         must equal `{base}`)",
                        m[i][i], diagonal[i]
                    ),
                ));
            }
        }
        for (name, side) in [
            ("integral_lower", &self.integral_lower),
            ("integral_upper", &self.integral_upper),
        ] {
            let Some(v) = side else { continue };
            if v.len() != n_joints {
                return Err(crate::SettingError::new(
                    name,
                    format!("has {} entries; the arm has {n_joints} joints", v.len()),
                ));
            }
            if v.iter()
                .any(|x| x.is_nan() || x.abs() > 1e12 && x.is_finite())
            {
                return Err(crate::SettingError::new(
                    name,
                    "entries must be numbers with |x| <= 1e12, or -inf / inf for no clamp",
                ));
            }
        }
        if let Some(v) = &self.integral_initial {
            if v.len() != n_joints {
                return Err(crate::SettingError::new(
                    "integral_initial",
                    format!("has {} entries; the arm has {n_joints} joints", v.len()),
                ));
            }
            for (i, x) in v.iter().enumerate() {
                let (lo, hi) = self.integral_clamp(i);
                if !(x.is_finite() && *x >= lo && *x <= hi) {
                    return Err(crate::SettingError::new(
                        "integral_initial",
                        format!("joint {i}: {x} must be finite and within the clamp [{lo}, {hi}]"),
                    ));
                }
            }
        }
        for i in 0..n_joints {
            let (lo, hi) = self.integral_clamp(i);
            if lo == f64::INFINITY {
                return Err(crate::SettingError::new(
                    "integral_lower",
                    format!("joint {i}: inf leaves no room below; -inf is no lower clamp"),
                ));
            }
            if hi == f64::NEG_INFINITY {
                return Err(crate::SettingError::new(
                    "integral_upper",
                    format!("joint {i}: -inf leaves no room above; inf is no upper clamp"),
                ));
            }
            if lo > hi {
                // Blame the side given explicitly (the other is +-integral_limit).
                let name = match (&self.integral_lower, &self.integral_upper) {
                    (Some(_), None) => "integral_lower",
                    (None, Some(_)) => "integral_upper",
                    _ => "integral_lower",
                };
                return Err(crate::SettingError::new(
                    name,
                    format!("joint {i}: the lower clamp {lo} is above the upper clamp {hi}"),
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
        let integral = gains
            .integral_initial
            .clone()
            .unwrap_or_else(|| vec![0.0; n]);
        Self { gains, integral }
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
            let (lo, hi) = g.integral_clamp(i);
            self.integral[i] = (self.integral[i] + g.ki[i] * dt * e).clamp(lo, hi);
            let p = match &g.kp_matrix {
                None => g.kp[i] * e,
                Some(m) => (0..out.len()).map(|c| m[i][c] * (target[c] - mu[c])).sum(),
            };
            let d = match &g.kd_matrix {
                None => g.kd[i] * mu_p[i],
                Some(m) => (0..out.len()).map(|c| m[i][c] * mu_p[c]).sum(),
            };
            out[i] = p - d + self.integral[i];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integral_winds_up_to_its_clamp_and_no_further() {
        let mut pid = Pid::new(PidGains::diagonal(
            vec![0.0],
            vec![0.0],
            vec![50.0],
            vec![5.0],
        ));
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
        let mut pid = Pid::new(PidGains::diagonal(
            vec![250.0],
            vec![100.0],
            vec![0.0],
            vec![0.0],
        ));
        let mut u = [0.0];
        pid.step(&[0.1], &[0.2], &[0.3], 1e-3, &mut u);
        assert!((u[0] - (250.0 * 0.2 - 100.0 * 0.2)).abs() < 1e-12);
    }

    #[test]
    fn a_full_derivative_matrix_damps_one_joint_by_anothers_velocity() {
        // The authors' MATLAB benchmark: [100, 0; 20, 0] * (0 - mu_p).
        let mut g =
            PidGains::diagonal(vec![250.0; 2], vec![100.0, 0.0], vec![0.0; 2], vec![0.0; 2]);
        g.kd_matrix = Some(vec![vec![100.0, 0.0], vec![20.0, 0.0]]);
        g.validate(2).unwrap();
        let mut pid = Pid::new(g);
        let mut u = [0.0; 2];
        pid.step(&[0.1, 0.2], &[0.3, -0.7], &[0.5, 0.2], 1e-3, &mut u);
        assert!((u[0] - (250.0 * 0.4 - 100.0 * 0.3)).abs() < 1e-12);
        // Joint 2: no error, damped only by joint 1's velocity belief.
        assert!((u[1] - (-20.0 * 0.3)).abs() < 1e-12);
        // A proportional matrix couples the errors the same way.
        let mut g = PidGains::diagonal(vec![2.0, 3.0], vec![0.0; 2], vec![0.0; 2], vec![0.0; 2]);
        g.kp_matrix = Some(vec![vec![2.0, 1.0], vec![0.0, 3.0]]);
        let mut pid = Pid::new(g);
        pid.step(&[0.0, 0.0], &[0.0, 0.0], &[1.0, 2.0], 1e-3, &mut u);
        assert_eq!(u, [4.0, 6.0]);
    }

    #[test]
    fn an_upper_only_clamp_lets_the_integral_fall_without_bound() {
        let mut g = PidGains::diagonal(vec![0.0], vec![0.0], vec![1000.0], vec![5.0]);
        g.integral_lower = Some(vec![f64::NEG_INFINITY]);
        g.integral_upper = Some(vec![4.5]);
        g.validate(1).unwrap();
        let mut pid = Pid::new(g);
        let mut u = [0.0];
        for _ in 0..100 {
            pid.step(&[0.0], &[0.0], &[1.0], 1e-3, &mut u);
        }
        assert_eq!(u[0], 4.5);
        for _ in 0..100 {
            pid.step(&[0.0], &[0.0], &[-1.0], 1e-3, &mut u);
        }
        // 4.5 - 100 x 1.0: far below the symmetric limit of 5.
        assert!((u[0] + 95.5).abs() < 1e-9, "{}", u[0]);
    }

    #[test]
    fn matrices_and_clamps_are_checked_with_the_key_that_is_wrong() {
        let base = PidGains::diagonal(vec![1.0; 2], vec![1.0; 2], vec![0.0; 2], vec![1.0; 2]);
        let mut g = base.clone();
        g.kd_matrix = Some(vec![vec![1.0, 0.0]]);
        assert_eq!(g.validate(2).unwrap_err().field, "kd_matrix");
        let mut g = base.clone();
        g.kd_matrix = Some(vec![vec![1.0, 0.0], vec![0.0, 2.0]]);
        let e = g.validate(2).unwrap_err();
        assert!(
            e.field == "kd_matrix" && e.message.contains("diagonal"),
            "{e:?}"
        );
        let mut g = base.clone();
        g.kp_matrix = Some(vec![vec![1.0, f64::NAN], vec![0.0, 1.0]]);
        assert_eq!(g.validate(2).unwrap_err().field, "kp_matrix");
        let mut g = base.clone();
        g.integral_lower = Some(vec![0.0, 2.0]);
        g.integral_upper = Some(vec![1.0, 1.0]);
        let e = g.validate(2).unwrap_err();
        assert!(e.message.contains("above"), "{e:?}");
        let mut g = base;
        g.integral_upper = Some(vec![1.0]);
        assert_eq!(g.validate(2).unwrap_err().field, "integral_upper");
    }
}
