//! `aift init`: a healthy scenario that runs out of the box on any serial URDF arm, every choice
//! derived from the arm itself and commented in the file.
//!
//! - Start: each joint at 0, or mid-range when 0 is within 10 % of a limit; two targets inside the
//!   limits (+-0.3 rad, alternating per joint, moved inward where the range is narrow).
//! - PID gains from the arm's own inertia: the mass matrix M and gravity torque G of the arm's
//!   model at the start and the targets ([`crate::arm::Dynamics`]);
//!   with the largest row sum m_i = sum_j |M_ij| seen (the torque joint i meets when every joint
//!   accelerates at 1 rad/s^2: its own inertia plus the reaction of the others' motion, which on
//!   a light wrist under a heavy shoulder is many times the diagonal), the largest gravity torque
//!   G_i and the joint's damping D_i, kp_i = max(m_i w^2, D_i w / 2, G_i / 0.05 rad) (the second
//!   where the joint's own damping would make the loop slower than w / 2, the third so that
//!   gravity alone bends the joint at most 0.05 rad before the integral acts),
//!   kd_i = max(0, 2 zeta sqrt(kp_i m_i) - D_i) (damping ratio zeta with the plant's damping
//!   counted), ki_i = kp_i w / 8 (integral time 8 / w), w = 8 rad/s and zeta = 0.9; w lowered,
//!   and kp capped, where a 0.5 rad error would ask for more than the joint's effort limit. A
//!   joint whose row sum or gravity floor sets kp answers faster than w on its own inertia (by
//!   about sqrt(m_i / M_ii)): the Jaco2's fastest mode of M^-1 Kp is 139 rad/s, 0.14 per tick at
//!   the scenario's dt = 1 ms, far from the discrete loop's limit; a much longer dt may not be.
//!   (Until 2026-12-02 m_i was the diagonal M_ii and gravity was left to the integral: a Kinova
//!   Jaco2's wrist got kp 0.05-2 N m/rad and ended 0.42 rad off its target, no-FT, articulated
//!   engine, 15 s; `panda_healthy.toml` was written by that rule.)
//! - Discrete-time limits (since 2026-12-04): with m_eff_i = 1 / (M^-1)_ii, the smallest seen (the
//!   inertia joint i's torque moves when the other joints are free: on a joint coaxial with
//!   another, far below M_ii), kp_i <= max((0.3 / dt)^2 m_eff_i, 0.3 D_i / dt) (the second where
//!   the joint's damping D_i makes its loop first order) and kd_i <= 0.5 m_eff_i / dt; then
//!   the coupled modes: dt lambda_max(M^-1 Kd) <= 0.5 at every pose. An explicit velocity loop
//!   flips sign every tick above kd dt / m = 1: a 7-DOF arm's coaxial roll joints chattered at
//!   500 Hz under the gains the rules above give alone. Where the per-joint kd exceed it (two
//!   nearly coaxial joints: their relative motion moves almost no inertia, their common motion
//!   much), no per-joint kd can damp the slow mode and keep the fast one within the tick:
//!   since 2026-12-07 the derivative gain then goes per mode (`kd_matrix`): with M = L L^T at
//!   the start and L^-1 Kp L^-T = V diag(w_k^2) V^T, Kd = L V diag(c_k) V^T L^T - D,
//!   c_k = min(2 zeta w_k, 0.5 / dt), projected on the positive semidefinite matrices and
//!   scaled down where another pose's fastest mode exceeds the limit; then each joint's
//!   diagonal gets back what its per-joint kd exceeds that, as far as the limit allows (the
//!   per-joint rule's margin: without it a generated arm's healthy `ekf-gate` run ran away).
//!   (Until then the kd of the
//!   joints in the fastest mode were lowered by their share of its eigenvector: generated arms
//!   57080 and 640003 were refused, 0.22 and 0.26 rad off, 57080's slow mode swinging (4 s) on
//!   kd 0.07 N m s/rad. A first version scaled every gain together, kp too: on generated arms it
//!   left heavy joints 1.5 rad off under gravity.)
//! - Coulomb friction F_i (since 2026-12-04): kp_i >= F_i / 0.01 rad, above the effort cap (the
//!   proportional torque alone breaks the friction from 0.01 rad on), and the integral limit
//!   covers it. (Gains that ignored it left generated arms and a Panda with 4 N m of friction on
//!   its wrist stuck off their targets: 6 of 40 generated arms, seeds 50001..50040, refused by
//!   the check run; none since, with the camera seeing an end effector inside a hull.)
//! - Integral time (since 2026-12-07): at most a quarter of a target's hold (7.5 s / 4), within
//!   a quarter of the Routh-Hurwitz bound ki < kp (kd + D) / m_i; never below kp w / 8. Where the
//!   effort limit lowers w to 2-3 rad/s, 8 / w is 3-4 s: the loop, overdamped on an inertia far
//!   below the row sum m_i, overshoots and the integral's tail had not decayed when the target
//!   switched (4 of 60 generated arms, seeds 652001..652060, refused by the check run at
//!   0.010-0.022 rad; none with the shorter integral time).
//! - Integral limit: 1.5 x (the largest gravity torque seen + F_i), at least 1 N m, capped at the
//!   effort.
//! - Camera: a pinhole looking along the axis in which the end effector moves least over the
//!   training box (the smallest principal axis of 200 sampled positions), from 3 x the extent of
//!   the workspace, so its image spans the motion; the opposite side when more of the samples are
//!   hidden from the first; the next principal axes when more than a tenth are hidden from both
//!   (a generated arm whose first joint turns about that axis hid all 200 behind its first link).
//! - GP: 100 points per joint plus 100, at most 600, over the box of start and targets widened by
//!   0.3 rad (the default margin).
//! - The state prior's acceleration bound: the default 200 rad/s^2, whatever the gains (its
//!   position prior must stay above the encoders' precision; docs/method.md, "Prior scale").

use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use rand::SeedableRng;

use super::config::{InitialState, Target};
use super::{GpConfig, PrecisionConfig, RobotConfig, Scenario, ScenarioError};
use crate::control::{ControlConfig, PidGains};
use crate::estimation::uaic::UaicConfig;
use crate::gp;
use std::sync::Arc;

use crate::arm::{ArmModel, Dynamics, EndEffector, JointKind, Kinematics, UrdfOptions};
use crate::sensors::{Camera, CameraConfig};

/// What `aift init` needs.
#[derive(Clone, Debug)]
pub struct InitOptions {
    /// End-effector link; default `ee` if the arm has one, else the last link of the chain.
    pub ee_link: Option<String>,
    pub balance_inertia: bool,
    /// The URDF path as the scenario should name it (relative to the scenario file).
    pub urdf_in_scenario: String,
    /// Scenario name.
    pub name: String,
}

/// Natural frequency (rad/s) and damping ratio of the generated PID loops.
const OMEGA: f64 = 8.0;
const ZETA: f64 = 0.9;
/// Position error the gains must be able to answer within the effort limit (rad).
const ERROR_SPAN: f64 = 0.5;
/// Target offsets from the start (rad).
const STEP: f64 = 0.3;
/// The most gravity alone may bend a joint from its set point under the proportional gain
/// (rad); the integral removes the rest.
const GRAVITY_SAG: f64 = 0.05;
/// The error (rad) at which the proportional torque alone equals the joint's Coulomb friction:
/// a joint at rest closer to its target than this waits for the integral to break it free. The
/// check run's tolerance: a joint the proportional torque leaves stuck is still within it.
const FRICTION_BAND: f64 = CHECK_TOLERANCE;
/// The tick `init` writes (`dt`).
const DT: f64 = 1e-3;
/// When the second target replaces the first (s), and the run's length: each target holds for
/// this long.
const SWITCH_TIME: f64 = 7.5;
const DURATION: f64 = 2.0 * SWITCH_TIME;
/// The longest integral time (s) init writes, as a fraction of a target's hold: the integral's
/// slow tail decays as exp(-t / T_i), so T_i <= SWITCH_TIME / 4 leaves at most e^-4 (2 %) of it
/// when the target switches. The integral time 8 / w is longer only where the effort limit
/// lowered w below 4.3 rad/s.
const INTEGRAL_TIME_MAX: f64 = SWITCH_TIME / 4.0;
/// The Routh-Hurwitz margin of the integral: on the joint's largest inertia m the loop
/// m s^3 + (kd + D) s^2 + kp s + ki is stable for ki < kp (kd + D) / m; init stays this factor
/// below that.
const INTEGRAL_MARGIN: f64 = 4.0;
/// The most a derivative gain may take per tick from the velocity of the inertia it acts on:
/// kd_i dt / m_eff_i, and dt lambda_max(M^-1 Kd) over the coupled modes. An explicit velocity
/// loop flips sign every tick above 1 and is unstable above 2 (the velocity belief's lag
/// narrows that further).
const DAMPING_PER_TICK: f64 = 0.5;
/// The most a proportional gain may turn per tick on the joint's effective inertia:
/// sqrt(kp_i / m_eff_i) dt (300 rad/s at dt = 1 ms, far below the tick's Nyquist rate).
const STIFFNESS_PER_TICK: f64 = 0.3;

fn fmt_list(v: &[f64]) -> String {
    let items: Vec<String> = v.iter().map(|x| format_number(*x)).collect();
    format!("[{}]", items.join(", "))
}

/// A number with about 4 significant digits, always with a decimal point (TOML float).
fn format_number(x: f64) -> String {
    if x == 0.0 {
        return "0.0".into();
    }
    if x.abs() < 1e-3 {
        return format!("{x:.3e}");
    }
    let digits = (4 - 1 - x.abs().log10().floor() as i32).max(0) as usize;
    let s = format!("{x:.digits$}");
    if s.contains('.') || s.contains('e') {
        s
    } else {
        format!("{s}.0")
    }
}

/// The link the end effector goes on by default: `ee`, else, on the body of the last movable
/// joint, the first link (in file order) whose name says it is the tool point (`end_effector`,
/// `tcp`, `tool`, `flange`, in that order of preference), else the last link there in file order
/// (a gripper's fingers come after the flange in many URDFs).
pub fn default_ee(model: &ArmModel) -> String {
    if model.link("ee").is_some() {
        return "ee".into();
    }
    let last = model.joints.last().map_or(0, |j| j.child_body);
    let on_last: Vec<&str> = model
        .links
        .iter()
        .filter(|l| l.body == last)
        .map(|l| l.name.as_str())
        .collect();
    for hint in ["end_effector", "tcp", "tool", "flange"] {
        if let Some(name) = on_last
            .iter()
            .find(|name| name.to_ascii_lowercase().contains(hint))
        {
            return name.to_string();
        }
    }
    on_last
        .last()
        .map_or_else(|| model.bodies[last].link.clone(), |name| name.to_string())
}

/// Writes a healthy scenario for the arm in `urdf` (as TOML text with comments).
///
/// ```
/// use std::path::Path;
/// use aift::scenario::init::{InitOptions, init_scenario};
///
/// let options = InitOptions {
///     ee_link: None,
///     balance_inertia: false,
///     urdf_in_scenario: "urdf/planar_3dof.urdf".into(),
///     name: "planar3".into(),
/// };
/// let text = init_scenario(Path::new("urdf/planar_3dof.urdf"), &options)?;
/// let scenario = aift::scenario::parse_scenario(&text, Path::new("planar3.toml"), &[])?;
/// assert_eq!(scenario.initial.q.len(), 3);
/// # Ok::<(), aift::scenario::ScenarioError>(())
/// ```
pub fn init_scenario(urdf: &Path, options: &InitOptions) -> Result<String, ScenarioError> {
    init_scenario_noted(urdf, options).map(|init| init.text)
}

/// What [`init_scenario_noted`] writes and what it found worth telling the user.
#[derive(Clone, Debug)]
pub struct Initialised {
    /// The scenario (TOML text with comments).
    pub text: String,
    /// The joints the camera cannot see, at the start nor at any target (below
    /// [`CAMERA_BLIND`] encoder readings per frame at every one), by name: an encoder drift
    /// there looks like a tachometer bias to every method but the oracle.
    pub camera_blind: Vec<String>,
}

/// [`init_scenario`], with the notes the scenario's comments carry as values.
pub fn init_scenario_noted(
    urdf: &Path,
    options: &InitOptions,
) -> Result<Initialised, ScenarioError> {
    let model = crate::arm::load_urdf_with(
        urdf,
        &UrdfOptions {
            balance_inertia: options.balance_inertia,
        },
    )?;
    let ee = options
        .ee_link
        .clone()
        .unwrap_or_else(|| default_ee(&model));
    let end_effector = EndEffector::new(&model, &ee, [0.0; 3])?;
    check_serial(&model, &end_effector, &ee, options.ee_link.is_some(), urdf)?;
    let model = Arc::new(model);
    let n = model.joints.len();
    let poses = start_and_targets(&model);
    // A joint that cannot move far enough for a target the sensors can tell from the start.
    for j in &model.joints {
        if let (JointKind::Revolute | JointKind::Prismatic, Some((lo, hi))) = (j.kind, j.limits)
            && hi - lo < MIN_RANGE
        {
            return Err(ScenarioError::Invalid {
                path: urdf.to_path_buf(),
                field: format!("joint '{}' <limit>", j.name),
                message: format!(
                    "its range [{lo}, {hi}] is narrower than {MIN_RANGE}: no target init could \
                     set would stand out from the encoders' noise (make the joint fixed, or \
                     give its real limits)"
                ),
            });
        }
    }
    let gains = gains_from_dynamics(&model, &poses);
    // What no gain can fix: a motor weaker than the gravity torque it must hold.
    for (j, g) in model.joints.iter().zip(&gains.g_max) {
        if let Some(e) = j.effort.filter(|e| g > e) {
            return Err(ScenarioError::Invalid {
                path: urdf.to_path_buf(),
                field: format!("joint '{}' <limit effort>", j.name),
                message: format!(
                    "{e} N m is below the gravity torque of {g:.4} N m the joint must hold at \
                     the start or a target; init cannot write a scenario that reaches them \
                     (raise the effort limit, or lighten the links it carries)"
                ),
            });
        }
    }
    let view = place_camera(&model, &end_effector, &poses);
    let scenario = scenario_value(options, &model, &ee, &poses, &gains, view.config);
    // What init writes must load: checked against the arm before it is written.
    let layout = crate::sensors::ChannelLayout::new(n, scenario.camera.model);
    scenario.validate(&layout, urdf)?;
    let (sensitivity, greatest) = camera_sensitivity(&model, &end_effector, &poses, &scenario);
    let notes = Notes {
        urdf,
        n,
        start: if poses.notes.is_empty() {
            String::new()
        } else {
            format!(" ({})", poses.notes.join("; "))
        },
        distance: view.distance,
        hidden: view.hidden,
        axis_rank: view.axis_rank,
        m_max: &gains.m_max,
        g_max: &gains.g_max,
        per_mode: gains.kd_matrix.is_some(),
        camera_blind: model
            .joints
            .iter()
            .zip(&greatest)
            .filter(|(_, s)| **s < CAMERA_BLIND)
            .map(|(j, _)| j.name.clone())
            .collect(),
        camera_sensitivity: sensitivity,
    };
    Ok(Initialised {
        text: render(&scenario, &notes),
        camera_blind: notes.camera_blind,
    })
}

/// Below this many encoder readings of information per camera frame, the camera cannot see a
/// joint at all (the end effector on its axis: zero up to rounding).
pub const CAMERA_BLIND: f64 = 1e-6;

/// Per joint, the least and the greatest over the start and the targets of
/// [`Camera::joint_sensitivity`] times the encoder's sigma: one camera frame's information about
/// the joint in encoder readings (docs/method.md, "Sensors nobody else can check"). A pose the
/// camera cannot see counts as 0.
fn camera_sensitivity(
    model: &ArmModel,
    end_effector: &EndEffector,
    poses: &Poses,
    scenario: &Scenario,
) -> (Vec<f64>, Vec<f64>) {
    let qs = [&poses.q0, &poses.t1, &poses.t2].map(|q| q.as_slice());
    let (least, greatest) =
        Camera::new(scenario.camera.clone()).joint_sensitivity_range(model, end_effector, qs);
    let readings = |v: Vec<f64>| -> Vec<f64> {
        v.into_iter()
            .map(|s| s * scenario.sensors.encoder_sigma)
            .collect()
    };
    (readings(least), readings(greatest))
}

/// Largest final joint error (rad or m) the check run of [`check_scenario`] may end with.
pub const CHECK_TOLERANCE: f64 = 0.01;

/// Runs the scenario `text` (as [`init_scenario`] wrote it, to be saved at `path`) once, healthy,
/// with fixed precisions (`no-ft`) on the articulated engine, and refuses it when the run does
/// not complete or ends more than [`CHECK_TOLERANCE`] off its last target on some joint: init's
/// gains come from the arm's dynamics, but whether the loop they close settles (with the
/// u-AIC's belief and the camera model in it) is only known by running it. Costs one run and
/// the camera GP's training.
pub fn check_scenario(text: &str, path: &Path) -> Result<(), ScenarioError> {
    let overrides = [
        "plant.engine=\"articulated\"".to_string(),
        "precision.method=\"no-ft\"".to_string(),
    ];
    let scenario = super::parse_scenario(text, path, &overrides)?;
    let base_dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .to_path_buf();
    let loaded = super::LoadedScenario {
        scenario,
        path: path.to_path_buf(),
        base_dir: Some(base_dir),
    };
    let setup = super::RunSetup::prepare(loaded)?;
    let result = super::runner::Run::new(&setup, super::Method::NoFt).execute()?;
    let worst = result
        .final_error_per_joint
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))
        .map(|(j, e)| (setup.model.joints[j].name.clone(), *e));
    let completed = result.outcome.name() == "completed";
    if completed && result.max_final_error <= CHECK_TOLERANCE {
        return Ok(());
    }
    let (joint, error) = worst.unwrap_or_default();
    Err(ScenarioError::Invalid {
        path: path.to_path_buf(),
        field: "controller.gains".into(),
        message: format!(
            "a check run of the scenario init derived (healthy, no-ft, articulated engine, {} s) \
             ends {} with joint '{joint}' {error:.4} off its last target (at most \
             {CHECK_TOLERANCE}): init writes only scenarios that reach their targets (--no-check \
             writes it anyway, to tune by hand)",
            setup.scenario().duration,
            result.outcome.name(),
        ),
    })
}

/// Narrowest joint range (rad or m) init writes targets for: 20 standard deviations of the
/// default encoder noise.
const MIN_RANGE: f64 = 0.02;

/// aift controls serial arms: every joint must move the end effector (the camera sees nothing
/// else, and the u-AIC's camera model is a function of every joint). Refuses an end effector on
/// the root (no joint moves it) and joints on another branch of a tree.
fn check_serial(
    model: &ArmModel,
    ee: &EndEffector,
    ee_name: &str,
    given: bool,
    urdf: &Path,
) -> Result<(), ScenarioError> {
    let field = if given {
        "--ee".to_string()
    } else {
        format!("the end effector '{ee_name}' (chosen by init; --ee picks another)")
    };
    match ee.not_serial(model, ee_name) {
        Some(message) => Err(ScenarioError::Invalid {
            path: urdf.to_path_buf(),
            field,
            message,
        }),
        None => Ok(()),
    }
}

/// The start and the two targets, and which joints start mid-range.
struct Poses {
    q0: Vec<f64>,
    t1: Vec<f64>,
    t2: Vec<f64>,
    notes: Vec<String>,
}

/// Start: each joint at 0, or mid-range when 0 is within 10 % of a limit; two targets inside the
/// limits (+-0.3 rad, alternating per joint, moved inward where the range is narrow).
fn start_and_targets(model: &ArmModel) -> Poses {
    let n = model.joints.len();
    let mut q0 = vec![0.0; n];
    let mut t1 = vec![0.0; n];
    let mut t2 = vec![0.0; n];
    let mut notes = Vec::new();
    for (i, j) in model.joints.iter().enumerate() {
        let (lo, hi) = match (j.kind, j.limits) {
            (JointKind::Continuous, _) | (_, None) => (-std::f64::consts::PI, std::f64::consts::PI),
            (_, Some((lo, hi))) => (lo, hi),
        };
        let range = hi - lo;
        let inner = (lo + 0.1 * range, hi - 0.1 * range);
        q0[i] = if (inner.0..=inner.1).contains(&0.0) {
            0.0
        } else {
            0.5 * (lo + hi)
        };
        let step = STEP.min(0.3 * range);
        let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
        t1[i] = (q0[i] + sign * step).clamp(inner.0, inner.1);
        t2[i] = (q0[i] - sign * step * 0.5).clamp(inner.0, inner.1);
        if q0[i] != 0.0 {
            notes.push(format!("joint {} starts mid-range", j.name));
        }
    }
    Poses { q0, t1, t2, notes }
}

/// The PID gains and integral limits, with the largest row sum of |M| and gravity torque per
/// joint they were derived from.
struct Gains {
    kp: Vec<f64>,
    kd: Vec<f64>,
    /// Where the per-joint kd could not damp the slow coupled modes without exceeding the
    /// per-tick limit in a fast one: the derivative gain per mode (its diagonal is `kd`).
    kd_matrix: Option<nalgebra::DMatrix<f64>>,
    ki: Vec<f64>,
    ilim: Vec<f64>,
    m_max: Vec<f64>,
    g_max: Vec<f64>,
}

/// Gains from the arm's dynamics at the start and the targets (gravity along -z, the scenario's
/// default), as the module documentation derives them.
fn gains_from_dynamics(model: &Arc<ArmModel>, poses: &Poses) -> Gains {
    let n = model.joints.len();
    let mut dynamics = Dynamics::new(model.clone(), [0.0, 0.0, -9.81]);
    // Per joint: the largest diagonal inertia, the largest row sum of |M| and the largest
    // gravity torque seen.
    let mut m_diag = vec![0.0f64; n];
    let mut m_max = vec![0.0f64; n];
    let mut g_max = vec![0.0f64; n];
    // The smallest effective inertia 1 / (M^-1)_ii seen: what joint i's torque moves when the
    // other joints are free (on coaxial or nearly coaxial joints far below M_ii).
    let mut m_eff = vec![f64::INFINITY; n];
    let mut inverses = Vec::new();
    let mut m_start = None;
    for q in [&poses.q0, &poses.t1, &poses.t2] {
        let (m, g) = dynamics.mass_matrix_and_gravity(q);
        m_start.get_or_insert_with(|| m.clone());
        for i in 0..n {
            m_diag[i] = m_diag[i].max(m[(i, i)]);
            m_max[i] = m_max[i].max((0..n).map(|j| m[(i, j)].abs()).sum::<f64>());
            g_max[i] = g_max[i].max(g[i].abs());
        }
        if let Some(inv) = m.clone().cholesky().map(|c| c.inverse()) {
            for i in 0..n {
                m_eff[i] = m_eff[i].min(1.0 / inv[(i, i)].max(1e-300));
            }
            inverses.push(inv);
        }
    }
    for i in 0..n {
        if !m_eff[i].is_finite() {
            m_eff[i] = m_diag[i];
        }
    }
    let (mut kp, mut kd, mut ki, mut ilim) =
        (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    for (i, j) in model.joints.iter().enumerate() {
        let m = m_max[i].max(1e-6);
        let d = j.damping;
        let mut w = OMEGA;
        if let Some(e) = j.effort {
            w = w.min((e / (ERROR_SPAN * m)).sqrt());
        }
        // Where the joint's own damping dominates (kd + D >> 2 zeta m w), the slow pole sits at
        // kp / (kd + D): kp is raised so that it is no slower than w / 2.
        kp[i] = (m * w * w).max(0.5 * d * w).max(g_max[i] / GRAVITY_SAG);
        if let Some(e) = j.effort {
            kp[i] = kp[i].min(e / ERROR_SPAN);
        }
        // Coulomb friction holds a joint at rest wherever kp e + I stays within it: the
        // proportional torque alone overcomes it from FRICTION_BAND on, even if a 0.5 rad error
        // then asks for more than the effort limit (the torque saturates there).
        kp[i] = kp[i].max(j.friction / FRICTION_BAND);
        // Discrete-time limits on the inertia the joint's torque actually moves.
        let m_eff_i = m_eff[i].max(1e-9);
        // On a joint whose own damping dominates, the proportional loop's pole is kp / D (first
        // order): its per-tick turn kp dt / D is the limit there, not the inertia's.
        let stiffness_cap =
            ((STIFFNESS_PER_TICK / DT).powi(2) * m_eff_i).max(STIFFNESS_PER_TICK * d / DT);
        kp[i] = kp[i].min(stiffness_cap);
        kd[i] = (2.0 * ZETA * (kp[i] * m).sqrt() - d)
            .max(0.0)
            .min(DAMPING_PER_TICK * m_eff_i / DT);
        // Integral time 8 / w (shortened below, after the coupled modes' kd, where it exceeds
        // INTEGRAL_TIME_MAX).
        ki[i] = kp[i] * w / 8.0;
        // Enough to hold gravity and to break the joint's Coulomb friction with a margin: at rest
        // the joint moves only once |kp e + I - G| exceeds the friction, so an integral that
        // cannot reach G + F leaves it stuck up to (G + F - I_max) / kp off its target.
        let limit = (1.5 * (g_max[i] + j.friction)).max(1.0);
        ilim[i] = j.effort.map_or(limit, |e| limit.min(e));
    }
    // The coupled modes: lambda_max(M^-1 Kd) at every pose. A diagonal Kd that fits the fastest
    // mode's per-tick limit leaves the gains per joint. One that does not (two joints nearly
    // coaxial: their relative motion moves almost no inertia, their common motion much) cannot
    // both damp the slow mode and keep the fast one within the limit: the derivative gain then
    // goes per mode of the start's M^-1 Kp, each at zeta (capped at the per-tick limit).
    let mut kd_matrix = None;
    let diagonal = nalgebra::DMatrix::from_diagonal(&nalgebra::DVector::from_column_slice(&kd));
    if fastest_mode(&inverses, &diagonal) * DT > DAMPING_PER_TICK
        && let Some(modal) = m_start
            .as_ref()
            .and_then(|m| modal_damping(m, &kp, model, &inverses))
    {
        let modal = with_joint_damping(modal, &kd, &inverses);
        kd = (0..n).map(|i| modal[(i, i)]).collect();
        kd_matrix = Some(modal);
    }
    if kd_matrix.is_none() {
        // Bounded passes: the joints in the fastest mode give up damping in proportion to
        // their share of its eigenvector (each pass at least halves the excess on the mode's
        // joints), then a uniform scaling as a backstop.
        for _ in 0..50 {
            let (value, shares) = fastest_diagonal_mode(&inverses, &kd);
            if value * DT <= DAMPING_PER_TICK {
                break;
            }
            let f = DAMPING_PER_TICK / (value * DT);
            for (k, share) in kd.iter_mut().zip(&shares) {
                *k *= f.powf(share.min(1.0));
            }
        }
        let (value, _) = fastest_diagonal_mode(&inverses, &kd);
        if value * DT > DAMPING_PER_TICK {
            let f = DAMPING_PER_TICK / (value * DT);
            kd.iter_mut().for_each(|k| *k *= f);
        }
    }
    // Where the effort limit made the integral slower than INTEGRAL_TIME_MAX, it is raised
    // towards kp / INTEGRAL_TIME_MAX as far as its Routh-Hurwitz margin on the joint's largest
    // inertia allows (with the final kd); never lowered.
    for (i, j) in model.joints.iter().enumerate() {
        let routh = kp[i] * (kd[i] + j.damping) / m_max[i].max(1e-6);
        let wanted = (kp[i] / INTEGRAL_TIME_MAX).min(routh / INTEGRAL_MARGIN);
        ki[i] = ki[i].max(wanted);
    }
    Gains {
        kp,
        kd,
        kd_matrix,
        ki,
        ilim,
        m_max,
        g_max,
    }
}

/// The fastest coupled mode of a derivative gain: the largest lambda(M^-1 Kd) over the poses'
/// inverse mass matrices (with Kd symmetric positive semidefinite, the eigenvalues of
/// R^T Kd R, M^-1 = R R^T, symmetric).
fn fastest_mode(inverses: &[nalgebra::DMatrix<f64>], kd: &nalgebra::DMatrix<f64>) -> f64 {
    fastest_mode_vector(inverses, kd).0
}

/// The largest eigenvalue of a symmetric matrix and its eigenvector.
fn top_eigen(s: nalgebra::DMatrix<f64>) -> (f64, nalgebra::DVector<f64>) {
    let eig = s.symmetric_eigen();
    let (idx, &value) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))
        .expect("n >= 1");
    (value, eig.eigenvectors.column(idx).into_owned())
}

/// [`fastest_mode`] of a diagonal gain, with each joint's share of the mode (its eigenvector of
/// Kd^1/2 M^-1 Kd^1/2, squared).
fn fastest_diagonal_mode(inverses: &[nalgebra::DMatrix<f64>], k: &[f64]) -> (f64, Vec<f64>) {
    let n = k.len();
    let mut best = (0.0, vec![0.0; n]);
    for inv in inverses {
        let s = nalgebra::DMatrix::from_fn(n, n, |a, b| (k[a] * k[b]).sqrt() * inv[(a, b)]);
        let (value, mode) = top_eigen(s);
        if value > best.0 {
            best = (value, mode.iter().map(|v| v * v).collect());
        }
    }
    best
}

/// The per-mode gain with the per-joint rule's damping added back on its diagonal as far as
/// the per-tick limit allows: the per-joint kd_i (from the row sum m_i, more than a mode of M
/// alone asks for: the margin the per-joint gains have always had against the belief's lag)
/// less what the per-mode gain already gives, lowered on the joints of the fastest mode by
/// their share of its added damping until dt lambda_max(M^-1 Kd) fits (bounded passes, then a
/// uniform scaling by bisection as a backstop; the per-mode gain alone fits).
fn with_joint_damping(
    modal: nalgebra::DMatrix<f64>,
    per_joint: &[f64],
    inverses: &[nalgebra::DMatrix<f64>],
) -> nalgebra::DMatrix<f64> {
    let n = per_joint.len();
    let mut added: Vec<f64> = (0..n)
        .map(|i| (per_joint[i] - modal[(i, i)]).max(0.0))
        .collect();
    let with = |added: &[f64]| {
        let mut k = modal.clone();
        for (i, a) in added.iter().enumerate() {
            k[(i, i)] += a;
        }
        k
    };
    for _ in 0..50 {
        let (value, mode) = fastest_mode_vector(inverses, &with(&added));
        if value * DT <= DAMPING_PER_TICK {
            return with(&added);
        }
        let weights: Vec<f64> = (0..n).map(|i| added[i] * mode[i] * mode[i]).collect();
        let total: f64 = weights.iter().sum();
        if total <= 0.0 {
            break;
        }
        let f = DAMPING_PER_TICK / (value * DT);
        for (a, w) in added.iter_mut().zip(&weights) {
            *a *= f.powf((w / total).min(1.0));
        }
    }
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..30 {
        let mid = 0.5 * (lo + hi);
        let scaled: Vec<f64> = added.iter().map(|a| a * mid).collect();
        if fastest_mode(inverses, &with(&scaled)) * DT <= DAMPING_PER_TICK {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let scaled: Vec<f64> = added.iter().map(|a| a * lo).collect();
    with(&scaled)
}

/// [`fastest_mode`] with its mode shape in joint space: x = R u for the top eigenvector u of
/// R^T Kd R (M^-1 Kd x = lambda x).
fn fastest_mode_vector(
    inverses: &[nalgebra::DMatrix<f64>],
    kd: &nalgebra::DMatrix<f64>,
) -> (f64, Vec<f64>) {
    let mut best = (0.0, vec![0.0; kd.nrows()]);
    for c in inverses.iter().filter_map(|inv| inv.clone().cholesky()) {
        let r = c.l();
        let s = r.transpose() * kd * &r;
        let (value, u) = top_eigen((&s + s.transpose()) * 0.5);
        if value > best.0 {
            best = (value, (&r * u).iter().copied().collect());
        }
    }
    best
}

/// Modal damping (docs/method.md, "Bring your own arm"): with M = L L^T the start's mass matrix and
/// L^-1 Kp L^-T = V diag(w_k^2) V^T, the total damping L V diag(c_k) V^T L^T gives mode k of
/// M q'' + (Kd + D) q' + Kp q = 0 the rate c_k = min(2 zeta w_k, limit / dt) exactly at the
/// start; the joints' own damping D is taken off and what is left projected on the positive
/// semidefinite matrices. Scaled down as a whole where another pose's fastest mode exceeds the
/// per-tick limit. None where M is not positive definite.
fn modal_damping(
    m: &nalgebra::DMatrix<f64>,
    kp: &[f64],
    model: &ArmModel,
    inverses: &[nalgebra::DMatrix<f64>],
) -> Option<nalgebra::DMatrix<f64>> {
    let n = kp.len();
    let l = m.clone().cholesky()?.l();
    let l_inv = l.clone().try_inverse()?;
    let stiffness = nalgebra::DMatrix::from_diagonal(&nalgebra::DVector::from_column_slice(kp));
    let a = &l_inv * stiffness * l_inv.transpose();
    let eig = ((&a + a.transpose()) * 0.5).symmetric_eigen();
    let rates = eig
        .eigenvalues
        .map(|w2| (2.0 * ZETA * w2.max(0.0).sqrt()).min(DAMPING_PER_TICK / DT));
    let v = &eig.eigenvectors;
    let total = &l * v * nalgebra::DMatrix::from_diagonal(&rates) * v.transpose() * l.transpose();
    let mut kd = (&total + total.transpose()) * 0.5;
    for (i, j) in model.joints.iter().enumerate() {
        kd[(i, i)] -= j.damping;
    }
    let eig = kd.symmetric_eigen();
    let clipped = eig.eigenvalues.map(|x| x.max(0.0));
    let kd = &eig.eigenvectors
        * nalgebra::DMatrix::from_diagonal(&clipped)
        * eig.eigenvectors.transpose();
    let mut kd = (&kd + kd.transpose()) * 0.5;
    let value = fastest_mode(inverses, &kd);
    if value * DT > DAMPING_PER_TICK {
        kd *= DAMPING_PER_TICK / (value * DT);
    }
    (0..n).all(|i| kd[(i, i)].is_finite()).then_some(kd)
}

/// The camera: its settings, its distance from the centroid of the sampled end-effector
/// positions, and how many of those samples it cannot see.
struct CameraPlacement {
    config: CameraConfig,
    distance: f64,
    hidden: usize,
    /// 0: the axis of least motion; 1, 2: the next, tried when the first hid the end effector.
    axis_rank: usize,
}

/// A pinhole looking along the axis in which the end effector moves least over the training box,
/// from 3 x the workspace's extent; the side that sees more of the samples.
fn place_camera(
    model: &Arc<ArmModel>,
    end_effector: &EndEffector,
    poses: &Poses,
) -> CameraPlacement {
    // The GP box and the camera.
    let box_ = gp::derive_box(&[poses.q0.clone(), poses.t1.clone(), poses.t2.clone()], 0.3);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let samples = gp::latin_hypercube(&box_, 200, &mut rng);
    let mut arm = Kinematics::new(model.clone());
    let points: Vec<Vector3<f64>> = samples
        .iter()
        .map(|q| end_effector.position(arm.set(q)))
        .collect();
    let centroid = points.iter().fold(Vector3::zeros(), |a, p| a + p) / points.len() as f64;
    let mut cov = Matrix3::zeros();
    let mut extent = 0.0f64;
    for p in &points {
        let d = p - centroid;
        cov += d * d.transpose();
        extent = extent.max(d.norm());
    }
    let eig = cov.symmetric_eigen();
    let mut axes = [0usize, 1, 2];
    axes.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let distance = 3.0 * extent.max(0.2);
    let up_for = |view: &Vector3<f64>| {
        if view.cross(&Vector3::z()).norm() > 0.2 {
            [0.0, 0.0, 1.0]
        } else {
            [1.0, 0.0, 0.0]
        }
    };
    let mut best: Option<(usize, CameraConfig, usize)> = None;
    let mut image = vec![0.0; 2];
    // The axis of least motion first; the next axes only while more than a tenth of the samples
    // are hidden from both sides (a link's collider between the camera and the end effector:
    // on an arm whose first joint turns about that axis, from both sides).
    let sides = axes
        .iter()
        .enumerate()
        .flat_map(|(rank, &a)| [(rank, a, 1.0), (rank, a, -1.0)]);
    for (rank, a, side) in sides {
        if side > 0.0
            && best
                .as_ref()
                .is_some_and(|(h, ..)| *h * 10 <= samples.len())
        {
            break;
        }
        let axis: Vector3<f64> = eig.eigenvectors.column(a).into();
        let position = centroid + axis * (side * distance);
        let view = centroid - position;
        let config = CameraConfig {
            position: position.into(),
            look_at: centroid.into(),
            up: up_for(&view),
            ..CameraConfig::default()
        };
        let camera = Camera::new(config.clone());
        let hidden = samples
            .iter()
            .filter(|q| {
                arm.set(q);
                camera.observe(&arm, end_effector, &mut image).is_err()
            })
            .count();
        if best.as_ref().is_none_or(|(h, ..)| hidden < *h) {
            best = Some((hidden, config, rank));
        }
    }
    let (hidden, camera, axis_rank) = best.expect("two sides tried");
    CameraPlacement {
        config: camera,
        distance,
        hidden,
        axis_rank,
    }
}

/// The scenario value: the derived start, targets, gains, camera and GP size; every other
/// section at its default.
fn scenario_value(
    options: &InitOptions,
    model: &ArmModel,
    ee: &str,
    poses: &Poses,
    gains: &Gains,
    camera: CameraConfig,
) -> Scenario {
    let n = model.joints.len();
    let gp_points = (100 * n + 100).min(600);

    let targets = vec![
        Target {
            time: 0.0,
            q: rounded(&poses.t1),
        },
        Target {
            time: SWITCH_TIME,
            q: rounded(&poses.t2),
        },
    ];
    Scenario {
        name: options.name.clone(),
        description: format!(
            "Healthy reaching on {} (generated by aift init)",
            model.name
        ),
        duration: DURATION,
        dt: DT,
        seed: 1,
        record_every: 1,
        robot: RobotConfig {
            urdf: options.urdf_in_scenario.clone().into(),
            ee_link: ee.to_string(),
            ee_offset: [0.0; 3],
            gravity: [0.0, 0.0, -9.81],
            balance_inertia: options.balance_inertia,
        },
        plant: Default::default(),
        model: Default::default(),
        initial: InitialState {
            q: rounded(&poses.q0),
            qd: None,
        },
        targets,
        sensors: Default::default(),
        camera: CameraConfig {
            position: rounded3(&camera.position),
            look_at: rounded3(&camera.look_at),
            up: camera.up,
            ..camera
        },
        gp: GpConfig {
            points: gp_points,
            ..GpConfig::default()
        },
        // The prior's bound does not grow with the gains: it sets the position prior P_mu = 1 /
        // (a dt^2 / 2)^2, which must stay well above the encoders' precision (docs/method.md,
        // "Prior scale"); the tachometers, not the prior, carry a fast joint's velocity.
        belief: UaicConfig::default(),
        controller: ControlConfig {
            gains: PidGains {
                kd_matrix: gains.kd_matrix.as_ref().map(|k| {
                    k.row_iter()
                        .map(|row| row.iter().map(|x| round4(*x)).collect())
                        .collect()
                }),
                ..PidGains::diagonal(
                    rounded(&gains.kp),
                    rounded(&gains.kd),
                    rounded(&gains.ki),
                    rounded(&gains.ilim),
                )
            },
            ..ControlConfig::default()
        },
        precision: PrecisionConfig::default(),
        detector: Default::default(),
        kalman: Default::default(),
        hybrid: Default::default(),
        momentum: Default::default(),
        faults: Vec::new(),
        actuator_faults: Vec::new(),
        disturbances: Vec::new(),
    }
}

/// Numbers to about 4 significant digits, as the file shows them.
fn round4(x: f64) -> f64 {
    format_number(x).parse().unwrap_or(x)
}

fn rounded(v: &[f64]) -> Vec<f64> {
    v.iter().map(|x| round4(*x)).collect()
}

fn rounded3(v: &[f64; 3]) -> [f64; 3] {
    [round4(v[0]), round4(v[1]), round4(v[2])]
}

/// What the comments of the written file say.
struct Notes<'a> {
    urdf: &'a Path,
    n: usize,
    start: String,
    distance: f64,
    hidden: usize,
    axis_rank: usize,
    m_max: &'a [f64],
    g_max: &'a [f64],
    /// Whether the derivative gain goes per mode (`kd_matrix`).
    per_mode: bool,
    /// Per joint, the least over the start and targets of what one camera frame tells about it,
    /// in encoder readings.
    camera_sensitivity: Vec<f64>,
    /// The joints the camera cannot see at the start nor at any target (below
    /// [`CAMERA_BLIND`] at every one), by name.
    camera_blind: Vec<String>,
}

/// The comment naming the joints the camera cannot see, or nothing.
fn camera_blind_note(blind: &[String]) -> String {
    if blind.is_empty() {
        return String::new();
    }
    format!(
        "# The camera cannot see joint {}: nothing but the joint's own encoder and tachometer\n\
         # and the dynamics can check it, and an encoder drift there looks like a tachometer bias.\n",
        blind
            .iter()
            .map(|name| format!("'{name}'"))
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// Keys written even where they equal the default: the values `init` derived.
const DERIVED: &[&str] = &[
    "gp.points",
    "belief.acceleration_bound",
    "controller.gains",
    "precision.method",
];

/// The scenario as TOML: every section the scenario's own serialisation gives, with the keys
/// that equal their defaults left out (but the derived ones), and comments saying where each
/// value came from.
fn render(scenario: &Scenario, notes: &Notes<'_>) -> String {
    let mut doc = toml_edit::ser::to_document(scenario).expect("a scenario serialises");
    expand_tables(doc.as_table_mut());
    let defaults = default_sections();
    prune(doc.as_table_mut(), &defaults, "");
    // A healthy task has no faults; an empty `faults = []` would make the `[[faults]]` table a
    // user appends a duplicate key, so the key is left out and an example closes the file.
    let no_faults = doc
        .get("faults")
        .and_then(toml_edit::Item::as_array)
        .is_some_and(toml_edit::Array::is_empty);
    if no_faults {
        doc.remove("faults");
    }
    let comment = |doc: &mut toml_edit::DocumentMut, section: &str, text: String| {
        if let Some(t) = doc.get_mut(section).and_then(toml_edit::Item::as_table_mut) {
            t.decor_mut().set_prefix(format!("\n{text}"));
        }
    };
    doc.as_table_mut()
        .decor_mut()
        .set_prefix(format!(
            "# Written by `aift init` for {} ({} joints): a healthy reaching task, every value derived\n\
             # from the arm itself (docs/arms.md, \"Bring your own arm\"). Edit freely; `aift run` it.\n",
            notes.urdf.display(),
            notes.n
        ));
    comment(
        &mut doc,
        "initial",
        format!(
            "# Each joint at 0, or mid-range where 0 lies within 10 % of a limit{}.\n",
            notes.start
        ),
    );
    if let Some(t) = doc
        .get_mut("targets")
        .and_then(toml_edit::Item::as_array_of_tables_mut)
        .and_then(|a| a.get_mut(0))
    {
        t.decor_mut().set_prefix(format!(
            "\n# Two set points {STEP} rad and {} rad from the start, alternating in sign per joint, kept\n\
             # 10 % inside the limits; the switch at 7.5 s leaves time to settle.\n",
            STEP * 0.5
        ));
    }
    comment(
        &mut doc,
        "camera",
        format!(
            "# A pinhole camera looking along the axis in which the end effector moves {} over the GP's\n\
             # box (so the image spans the motion), {:.2} m from the workspace centre; {} of 200 sampled\n\
             # configurations are hidden from it. Distortion and noise are the paper's defaults.\n\
             # One frame tells about each joint as much as this many encoder readings (the least\n\
             # over the start and targets; docs/method.md, \"Sensors nobody else can check\"):\n\
             # {}.\n{}",
            [
                "least",
                "second least (the first hid it)",
                "most (the others hid it)"
            ][notes.axis_rank.min(2)],
            notes.distance,
            notes.hidden,
            fmt_list(&notes.camera_sensitivity),
            camera_blind_note(&notes.camera_blind)
        ),
    );
    comment(
        &mut doc,
        "gp",
        "# 100 training points per joint plus 100 (at most 600), over the start and targets widened by\n\
         # 0.3 rad.\n"
            .to_string(),
    );
    comment(
        &mut doc,
        "belief",
        format!(
            "# The state prior treats {:.0} rad/s^2 as one standard deviation of acceleration (the\n\
             # default): its position prior 1 / (a dt^2 / 2)^2 = 1e8 stays 100 x the encoders' precision,\n\
             # so that an encoder the belief stops trusting leaves its joint to the integrated\n\
             # tachometer, not free (docs/method.md, \"Prior scale\").\n",
            scenario.belief.acceleration_bound
        ),
    );
    comment(
        &mut doc,
        "controller",
        format!(
            "# PID from the largest row sum of |M| m_i = sum_j |M_ij| of the arm's model at the start and\n\
             # targets (the joint's inertia with the reaction of the others' motion: {}), the largest\n\
             # gravity torque G_i ({}) and the joint damping D_i: kp = max(m w^2, D w / 2, G / {GRAVITY_SAG} rad),\n\
             # kd = max(0, 2 zeta sqrt(kp m) - D), ki = kp w / 8, w = {OMEGA} rad/s (lower where a {ERROR_SPAN} rad error\n\
             # would exceed the effort limit), zeta = {ZETA}; kp >= F / {FRICTION_BAND} rad for Coulomb friction F;\n\
             # ki raised to kp / {INTEGRAL_TIME_MAX} s where slower (integral time a quarter of a target's hold),\n\
             # within a quarter of the Routh-Hurwitz bound kp (kd + D) / m;\n\
             # the integral is clamped at 1.5 x (G + F), at least 1 N m, at most the effort limit.\n{}",
            fmt_list(notes.m_max),
            fmt_list(notes.g_max),
            if notes.per_mode {
                format!(
                    "# kd_matrix: no per-joint kd could damp this arm's slow coupled modes while keeping its\n\
                     # fastest within the tick (dt lambda_max(M^-1 Kd) <= {DAMPING_PER_TICK}), so the derivative gain goes\n\
                     # per mode of the start's M^-1 Kp: each damped at 2 zeta w_k (at most {DAMPING_PER_TICK} / dt), less the\n\
                     # joints' own damping, plus what the per-joint kd above asks for more on the diagonal as far\n\
                     # as the tick allows; kd is its diagonal.\n"
                )
            } else {
                String::new()
            }
        ),
    );
    let mut text = doc.to_string();
    if no_faults {
        text.push_str(FAULT_EXAMPLE);
    }
    text
}

/// The closing comment of a written file: how to add a fault (docs/method.md, "Sensors").
const FAULT_EXAMPLE: &str = "\n# Faults: append one table per fault, for example a frozen encoder from 4 s to 6 s\n\
# (a channel such as enc1 or tach2, a group enc, tach or cam, or a list; kinds freeze, bias,\n\
# drift, gain, noise, dropout, stuck, spikes, with their parameters; `end` optional).\n\
# [[faults]]\n\
# channel = \"enc1\"\n\
# kind = \"freeze\"\n\
# start = 4.0\n\
# end = 6.0\n";

/// Each defaulted section of a scenario as TOML (the tables a written file may leave out).
fn default_sections() -> toml_edit::Table {
    #[derive(serde::Serialize)]
    struct Sections {
        plant: crate::plant::PlantSettings,
        model: crate::arm::ModelConfig,
        sensors: crate::sensors::SensorConfig,
        camera: CameraConfig,
        gp: GpConfig,
        belief: UaicConfig,
        controller: ControlConfig,
        precision: PrecisionConfig,
        detector: crate::precision::DetectorConfig,
        kalman: crate::estimation::kalman::KalmanConfig,
        hybrid: crate::estimation::hybrid::HybridConfig,
    }
    let sections = Sections {
        plant: Default::default(),
        model: Default::default(),
        sensors: Default::default(),
        camera: Default::default(),
        gp: Default::default(),
        belief: Default::default(),
        controller: Default::default(),
        precision: Default::default(),
        detector: Default::default(),
        kalman: Default::default(),
        hybrid: Default::default(),
    };
    let mut doc = toml_edit::ser::to_document(&sections).expect("defaults serialise");
    expand_tables(doc.as_table_mut());
    doc.as_table().clone()
}

/// Inline tables as standard tables (`[plant.rapier]`), arrays of inline tables as arrays of
/// tables (`[[targets]]`), as scenario files are written by hand.
fn expand_tables(table: &mut toml_edit::Table) {
    let keys: Vec<String> = table.iter().map(|(k, _)| k.to_string()).collect();
    for key in keys {
        let item = table.get_mut(&key).expect("listed");
        let new = match std::mem::take(item) {
            toml_edit::Item::Value(toml_edit::Value::InlineTable(t)) => {
                let mut t = t.into_table();
                expand_tables(&mut t);
                toml_edit::Item::Table(t)
            }
            toml_edit::Item::Value(toml_edit::Value::Array(a))
                if !a.is_empty() && a.iter().all(toml_edit::Value::is_inline_table) =>
            {
                let mut tables = toml_edit::ArrayOfTables::new();
                for v in a {
                    if let toml_edit::Value::InlineTable(t) = v {
                        let mut t = t.into_table();
                        expand_tables(&mut t);
                        tables.push(t);
                    }
                }
                toml_edit::Item::ArrayOfTables(tables)
            }
            toml_edit::Item::Table(mut t) => {
                expand_tables(&mut t);
                toml_edit::Item::Table(t)
            }
            other => other,
        };
        *item = new;
    }
}

/// Removes from `table` every key equal to its value in `defaults` (tables key by key), but the
/// [`DERIVED`] ones; a table left empty goes too.
fn prune(table: &mut toml_edit::Table, defaults: &toml_edit::Table, prefix: &str) {
    let keys: Vec<String> = table.iter().map(|(k, _)| k.to_string()).collect();
    for key in keys {
        let path = if prefix.is_empty() {
            key.clone()
        } else {
            format!("{prefix}.{key}")
        };
        if DERIVED.contains(&path.as_str()) {
            continue;
        }
        let Some(default) = defaults.get(&key) else {
            continue;
        };
        let item = table.get_mut(&key).expect("listed");
        if let (Some(t), Some(d)) = (item.as_table_mut(), default.as_table()) {
            prune(t, d, &path);
            if t.is_empty() {
                table.remove(&key);
            }
        } else if item.to_string().trim() == default.to_string().trim() {
            table.remove(&key);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The arm `aift gen-arm --seed seed` writes (2-7 joints).
    fn generated_model(seed: u64) -> Arc<ArmModel> {
        use crate::arm::generate::{GenerateOptions, generate_arm};
        let text = generate_arm(&GenerateOptions {
            seed,
            joints: (2, 7),
        })
        .unwrap();
        Arc::new(crate::arm::parse_urdf(&text, Path::new("generated.urdf")).unwrap())
    }

    /// On arms nobody tuned for (generated, 2-7 joints), the gains keep every joint's and every
    /// coupled mode's per-tick turn within the limits, at every pose the gains were taken from.
    #[test]
    fn gains_respect_the_discrete_time_limits_on_generated_arms() {
        for seed in 100..120 {
            let model = generated_model(seed);
            let n = model.joints.len();
            let poses = start_and_targets(&model);
            let g = gains_from_dynamics(&model, &poses);
            let mut dynamics = Dynamics::new(model.clone(), [0.0, 0.0, -9.81]);
            for q in [&poses.q0, &poses.t1, &poses.t2] {
                let (m, _) = dynamics.mass_matrix_and_gravity(q);
                let inv = m.clone().cholesky().unwrap().inverse();
                for i in 0..n {
                    let m_eff = 1.0 / inv[(i, i)];
                    // Per joint where the gain is per joint; a per-mode gain is bounded by its
                    // modes below.
                    assert!(
                        g.kd_matrix.is_some()
                            || g.kd[i] * DT / m_eff <= DAMPING_PER_TICK * (1.0 + 1e-9)
                    );
                    let d = model.joints[i].damping;
                    let inertial = (g.kp[i] / m_eff).sqrt() * DT;
                    let viscous = g.kp[i] * DT / d.max(1e-300);
                    assert!(inertial.min(viscous) <= STIFFNESS_PER_TICK * (1.0 + 1e-9));
                }
                // The coupled modes, by the eigenvalues of M^-1 K directly (not symmetrised).
                let gains = g.kd_matrix.clone().unwrap_or_else(|| {
                    nalgebra::DMatrix::from_diagonal(&nalgebra::DVector::from_column_slice(&g.kd))
                });
                let damping = (&inv * gains)
                    .complex_eigenvalues()
                    .iter()
                    .map(|c| c.re)
                    .fold(0.0, f64::max)
                    * DT;
                assert!(
                    damping <= DAMPING_PER_TICK * (1.0 + 1e-6),
                    "seed {seed}: {damping}"
                );
            }
            assert!(g.kp.iter().chain(&g.kd).all(|v| v.is_finite() && *v >= 0.0));
        }
    }

    /// Where the gains go per mode: the gain is symmetric positive semidefinite with `kd` its
    /// diagonal; and without the joints' own damping, every mode of the start's
    /// M q'' + Kd q' + Kp q = 0 is damped at 2 zeta w_k (at the per-tick limit where that is
    /// less) and the modes stay uncoupled: Phi^T Kd Phi = diag(c_k) on the modes Phi computed
    /// here with M's symmetric square root (the construction uses its Cholesky factor).
    #[test]
    fn per_mode_damping_damps_each_mode_of_the_start_at_zeta() {
        let mut per_mode = 0;
        for seed in 100..140 {
            let model = generated_model(seed);
            let n = model.joints.len();
            let poses = start_and_targets(&model);
            let g = gains_from_dynamics(&model, &poses);
            let Some(kd) = &g.kd_matrix else { continue };
            per_mode += 1;
            assert!((kd - kd.transpose()).abs().max() == 0.0, "seed {seed}");
            let least = kd.clone().symmetric_eigen().eigenvalues.min();
            assert!(least >= -1e-9 * kd.abs().max(), "seed {seed}: {least}");
            assert!((0..n).all(|i| kd[(i, i)] == g.kd[i]));

            let mut undamped = (*model).clone();
            undamped.joints.iter_mut().for_each(|j| j.damping = 0.0);
            let (m, _) =
                Dynamics::new(model.clone(), [0.0, 0.0, -9.81]).mass_matrix_and_gravity(&poses.q0);
            let inv = m.clone().try_inverse().unwrap();
            let kd = modal_damping(&m, &g.kp, &undamped, std::slice::from_ref(&inv)).unwrap();
            let e = m.clone().symmetric_eigen();
            let root_inv = &e.eigenvectors
                * nalgebra::DMatrix::from_diagonal(&e.eigenvalues.map(|x| 1.0 / x.sqrt()))
                * e.eigenvectors.transpose();
            let kp = nalgebra::DMatrix::from_diagonal(&nalgebra::DVector::from_column_slice(&g.kp));
            let b = &root_inv * kp * &root_inv;
            let modes = ((&b + b.transpose()) * 0.5).symmetric_eigen();
            let phi = &root_inv * &modes.eigenvectors;
            let modal = phi.transpose() * &kd * &phi;
            for k in 0..n {
                let wanted =
                    (2.0 * ZETA * modes.eigenvalues[k].max(0.0).sqrt()).min(DAMPING_PER_TICK / DT);
                for l in 0..n {
                    let expected = if k == l { wanted } else { 0.0 };
                    assert!(
                        (modal[(k, l)] - expected).abs() <= 1e-6 * (1.0 + wanted),
                        "seed {seed}: modes {k}, {l}: {} against {expected}",
                        modal[(k, l)]
                    );
                }
            }
        }
        assert!(
            per_mode > 0,
            "no generated arm among 100..140 needed per-mode damping"
        );
    }

    /// On generated arms every joint's integral time kp / ki is at most a quarter of a target's
    /// hold, except where the Routh-Hurwitz margin stops it, and the third-order loop on the
    /// joint's largest inertia, m s^3 + (kd + D) s^2 + kp s + ki, is stable (Routh: its roots'
    /// real parts, computed here, are negative).
    #[test]
    fn the_integral_fits_a_target_hold_within_its_stability_margin() {
        let mut raised_to_the_margin = 0;
        for seed in 100..140 {
            let model = generated_model(seed);
            let poses = start_and_targets(&model);
            let g = gains_from_dynamics(&model, &poses);
            for (i, j) in model.joints.iter().enumerate() {
                let (kp, kd, ki, m) = (g.kp[i], g.kd[i] + j.damping, g.ki[i], g.m_max[i]);
                let routh = kp * kd / m;
                let within_hold = kp / ki <= INTEGRAL_TIME_MAX * (1.0 + 1e-12);
                let at_margin = ki >= routh / INTEGRAL_MARGIN * (1.0 - 1e-12);
                assert!(
                    within_hold || at_margin,
                    "seed {seed} joint {i}: {kp} {kd} {ki}"
                );
                if !within_hold {
                    raised_to_the_margin += 1;
                }
                // The cubic's roots, independently of Routh's criterion.
                let p =
                    nalgebra::Matrix3::new(-kd / m, -kp / m, -ki / m, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0);
                let worst = p
                    .complex_eigenvalues()
                    .iter()
                    .map(|c| c.re)
                    .fold(f64::NEG_INFINITY, f64::max);
                assert!(
                    worst < 0.0 || kd == 0.0,
                    "seed {seed} joint {i}: a root at {worst}"
                );
            }
        }
        eprintln!(
            "joints whose integral time the margin kept above the bound: {raised_to_the_margin}"
        );
    }

    #[test]
    fn numbers_are_toml_floats_with_four_digits() {
        assert_eq!(format_number(250.0), "250.0");
        assert_eq!(format_number(0.012345), "0.01235");
        assert_eq!(format_number(-1.234567), "-1.235");
        assert_eq!(format_number(0.0), "0.0");
        assert_eq!(format_number(12345.0), "12345.0");
    }
}
