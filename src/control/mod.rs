//! Control: the law f* the belief is driven toward, and the action that follows it.
//!
//! The u-AIC's control comes from the same free energy as its belief: the action belief mu_u
//! descends F through its term 1/2 (P_u e_u^2 - ln P_u), e_u = mu_u - f*(mu, mu', mu_d)
//! (docs/method.md, "Action"). With kappa_u -> infinity (the authors' code, our default) that is
//! u = f*; a finite kappa_u makes mu_u follow f* with time constant 1 / (kappa_u P_u). Every
//! estimator drives the same f*, so methods differ only in their beliefs.

mod pid;

use serde::{Deserialize, Serialize};

pub use pid::{Pid, PidGains};

/// Settings of the control stage (the scenario's `[controller]` section).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ControlConfig {
    pub gains: PidGains,
    /// Finite action gain kappa_u (1/s); absent: u = f* (the authors' kappa_u -> infinity).
    pub kappa_u: Option<f64>,
    /// Control precision P_u, used with a finite kappa_u.
    pub control_precision: f64,
}

impl Default for ControlConfig {
    fn default() -> Self {
        Self {
            gains: PidGains::paper(),
            kappa_u: None,
            control_precision: 1.0,
        }
    }
}

impl ControlConfig {
    /// Checks the settings for an arm of `n_joints`; returns the offending field and why.
    pub fn validate(&self, n_joints: usize) -> Result<(), crate::SettingError> {
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 && v <= 1e300 {
                Ok(())
            } else {
                Err(crate::SettingError::new(
                    name.to_string(),
                    format!("{v} must be finite and > 0"),
                ))
            }
        };
        positive("control_precision", self.control_precision)?;
        if let Some(k) = self.kappa_u {
            positive("kappa_u", k)?;
        }
        self.gains.validate(n_joints).map_err(|e| e.within("gains"))
    }
}

/// f* and the action: torques from a belief and a target.
#[derive(Clone, Debug)]
pub struct Control {
    pid: Pid,
    kappa_u: Option<f64>,
    control_precision: f64,
    f_star: Vec<f64>,
    /// mu_u, the action belief (used with a finite kappa_u).
    mu_u: Vec<f64>,
    torques: Vec<f64>,
    free_energy: f64,
}

impl Control {
    pub fn new(config: &ControlConfig) -> Self {
        let n = config.gains.kp.len();
        Self {
            pid: Pid::new(config.gains.clone()),
            kappa_u: config.kappa_u,
            control_precision: config.control_precision,
            f_star: vec![0.0; n],
            mu_u: vec![0.0; n],
            torques: vec![0.0; n],
            free_energy: 0.0,
        }
    }

    /// One tick: f* on the belief (mu, mu') toward `target`, then u = f* or mu_u descending F.
    /// Returns the torques.
    pub fn step(&mut self, mu: &[f64], mu_p: &[f64], target: &[f64], dt: f64) -> &[f64] {
        self.pid.step(mu, mu_p, target, dt, &mut self.f_star);
        self.free_energy = 0.0;
        match self.kappa_u {
            None => self.torques.copy_from_slice(&self.f_star),
            Some(kappa_u) => {
                let pu = self.control_precision;
                // mu_u <- mu_u - dt kappa_u P_u (mu_u - f*), taken implicitly: stable for any
                // kappa_u.
                let a = dt * kappa_u * pu;
                for i in 0..self.mu_u.len() {
                    self.mu_u[i] = (self.mu_u[i] + a * self.f_star[i]) / (1.0 + a);
                    let e_u = self.mu_u[i] - self.f_star[i];
                    self.free_energy += 0.5 * (pu * e_u * e_u - pu.ln());
                }
                self.torques.copy_from_slice(&self.mu_u);
            }
        }
        &self.torques
    }

    /// The torques of the last step.
    pub fn torques(&self) -> &[f64] {
        &self.torques
    }

    /// f* of the last step.
    pub fn f_star(&self) -> &[f64] {
        &self.f_star
    }

    /// The action's term of the free energy at the last step (0 with u = f*).
    pub fn free_energy(&self) -> f64 {
        self.free_energy
    }

    /// The PID's integral torque per joint.
    pub fn integral(&self) -> &[f64] {
        self.pid.integral()
    }

    /// Zero torques (after a refused belief update).
    pub fn hold(&mut self) {
        self.torques.fill(0.0);
    }
}
