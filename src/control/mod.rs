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
    /// Which belief f* reads: `updated` (this tick's, after the readings; default) or
    /// `previous` (the one before this tick's update, as the authors' MATLAB benchmark does).
    pub belief: BeliefTiming,
    /// Ticks between the law's output and the torque reaching the joints (0..=1000): the torque
    /// applied at tick k is the output of tick k - d, zero before. Default 0; the authors' MATLAB
    /// benchmark: 1 (with `belief = "previous"`, two ticks behind the readings).
    pub delay_ticks: u32,
}

/// Which belief the control law reads each tick.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum BeliefTiming {
    /// The belief updated with this tick's readings.
    #[default]
    Updated,
    /// The belief before this tick's update (at the first tick: its initialisation from the
    /// first readings). A compatibility setting: the authors' `u(:,i+1) = ... mu(:,i)`.
    Previous,
}

/// Most ticks of actuation delay.
pub const MAX_DELAY_TICKS: u32 = 1000;

impl Default for ControlConfig {
    fn default() -> Self {
        Self {
            gains: PidGains::paper(),
            kappa_u: None,
            control_precision: 1.0,
            belief: BeliefTiming::Updated,
            delay_ticks: 0,
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
        if self.delay_ticks > MAX_DELAY_TICKS {
            return Err(crate::SettingError::new(
                "delay_ticks",
                format!("{} must be <= {MAX_DELAY_TICKS}", self.delay_ticks),
            ));
        }
        if let Some(k) = self.kappa_u {
            positive("kappa_u", k)?;
        }
        if n_joints != 2 && self.gains == PidGains::paper() {
            // Without `[controller.gains]` the paper arm's gains apply, which fit 2 joints only.
            return Err(crate::SettingError::new(
                "gains",
                format!(
                    "are the paper's 2-joint arm's (the defaults when `[controller.gains]` is \
                     absent); this arm has {n_joints} joints: give kp, kd, ki and integral_limit \
                     with {n_joints} entries each (`aift init <urdf>` writes them for an arm)"
                ),
            ));
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
    /// The law's outputs waiting to be applied (`delay_ticks` of them, oldest first).
    pending: std::collections::VecDeque<Vec<f64>>,
    belief_timing: BeliefTiming,
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
            pending: (0..config.delay_ticks).map(|_| vec![0.0; n]).collect(),
            belief_timing: config.belief,
        }
    }

    /// Which belief the law reads (the runner hands it over).
    pub fn belief_timing(&self) -> BeliefTiming {
        self.belief_timing
    }

    /// One tick: f* on the belief (mu, mu') toward `target`, then u = f* or mu_u descending F,
    /// delayed by `delay_ticks`. Returns the torques to apply this tick.
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
        if let Some(mut oldest) = self.pending.pop_front() {
            std::mem::swap(&mut oldest, &mut self.torques);
            self.pending.push_back(oldest);
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

    /// Drops the output of this tick's step (after a refused belief update: it came from a
    /// belief that failed): without a delay the torques applied now are zero; with one, the
    /// output queued this tick is, and what is applied now (computed d ticks ago) stands.
    pub fn hold(&mut self) {
        match self.pending.back_mut() {
            Some(newest) => newest.fill(0.0),
            None => self.torques.fill(0.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_delayed_law_applies_each_output_d_ticks_later_and_zero_before() {
        let config = ControlConfig {
            gains: PidGains::diagonal(vec![1.0], vec![0.0], vec![0.0], vec![0.0]),
            delay_ticks: 2,
            ..ControlConfig::default()
        };
        config.validate(1).unwrap();
        let mut c = Control::new(&config);
        let applied: Vec<f64> = (0..5)
            .map(|k| c.step(&[0.0], &[0.0], &[k as f64 + 1.0], 1e-3)[0])
            .collect();
        assert_eq!(applied, [0.0, 0.0, 1.0, 2.0, 3.0]);
        // A hold drops this tick's output only: it is applied as zero two ticks later, the
        // outputs queued before it as they were.
        c.hold();
        assert_eq!(c.torques()[0], 3.0);
        assert_eq!(c.step(&[0.0], &[0.0], &[9.0], 1e-3)[0], 4.0);
        assert_eq!(c.step(&[0.0], &[0.0], &[9.0], 1e-3)[0], 0.0);
        assert_eq!(c.step(&[0.0], &[0.0], &[9.0], 1e-3)[0], 9.0);
        // Without a delay, the torques of the tick are zero.
        let mut c = Control::new(&ControlConfig {
            delay_ticks: 0,
            ..config.clone()
        });
        c.step(&[0.0], &[0.0], &[5.0], 1e-3);
        c.hold();
        assert_eq!(c.torques()[0], 0.0);
        let too_long = ControlConfig {
            delay_ticks: MAX_DELAY_TICKS + 1,
            ..config
        };
        assert_eq!(too_long.validate(1).unwrap_err().field, "delay_ticks");
    }
}
