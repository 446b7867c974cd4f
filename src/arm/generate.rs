//! Random serial arms, by the thousand, to test the methods on arms nobody tuned them for
//! (`aift gen-arm`). A generated arm is a URDF text, a pure function of its seed and the joint
//! range; every draw comes from one ChaCha8 stream seeded by it.
//!
//! The distributions (docs/arms.md, "Generated arms"), per arm:
//! - joints: n uniform in the range (2 to 7 by default); each revolute (3 in 4) or continuous;
//! - reach: log-uniform in [0.15, 2] m, shared out among the links in proportions drawn uniform
//!   in [0.3, 1]; each link's length clamped to [0.03, 1] m; one link in 6 (never the first) has
//!   length 0, so its joint's origin coincides with the last one's (a wrist);
//! - axes: the joint frame is the last one turned by a random multiple of a quarter turn about a
//!   random principal axis (1 in 2), a random rotation (1 in 8), or not at all; the axis in it is
//!   +-x, +-y or +-z (5 in 6) or a random unit vector;
//! - links point along the joint frame's z (the arm is straight at q = 0, a singular pose: the
//!   generated arms start near one), with a lateral offset of up to 20 % of the length (1 in 4);
//! - masses: the first link log-uniform in [0.3, 20] kg, each next one times a factor uniform in
//!   [0.3, 1], at least 0.05 kg; inertias of a solid cylinder of radius 5-20 % of the length
//!   (at least 1 cm) about the centre of mass, which sits mid-link moved by up to 10 % of the
//!   length; the inertial frame turned by a random rotation (1 in 3);
//! - viscous damping: 0 (3 in 10) or log-uniform in [0.01, 100] N m s/rad; Coulomb friction: 0
//!   (1 in 2) or uniform in [0, 5] % of the joint's effort limit;
//! - effort limits: the largest gravity torque over 200 random configurations times a margin
//!   uniform in [1.5, 4], plus the torque that accelerates the joint's largest inertia seen at
//!   5 rad/s^2, plus the damping torque at 1 rad/s, at least 0.1 N m (without the damping term
//!   a joint of damping 90 N m s/rad under a 0.1 N m motor moved at 1 mrad/s);
//! - position limits of a revolute joint: lower uniform in [-pi, -0.5], upper in [0.5, pi];
//! - an `ee` link fixed at the tip of the last link; a cylinder collider per link.

use std::f64::consts::PI;
use std::fmt::Write as _;
use std::sync::Arc;

use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{ArmError, Dynamics};

/// The most joints a generated arm may have.
pub const MAX_GENERATED_JOINTS: usize = 12;

/// What `gen-arm` generates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GenerateOptions {
    pub seed: u64,
    /// Fewest and most joints (inclusive).
    pub joints: (usize, usize),
}

impl Default for GenerateOptions {
    fn default() -> Self {
        Self {
            seed: 1,
            joints: (2, 7),
        }
    }
}

struct Joint {
    kind: &'static str,
    xyz: Vector3<f64>,
    rotation: UnitQuaternion<f64>,
    axis: Vector3<f64>,
    limits: Option<(f64, f64)>,
    damping: f64,
    friction_share: f64,
}

struct Link {
    length: f64,
    offset: Vector3<f64>,
    mass: f64,
    com: Vector3<f64>,
    inertial_rpy: [f64; 3],
    inertia: Matrix3<f64>,
    radius: f64,
}

fn log_uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    (lo.ln() + rng.random::<f64>() * (hi.ln() - lo.ln())).exp()
}

fn random_rotation(rng: &mut ChaCha8Rng) -> UnitQuaternion<f64> {
    // A uniform random rotation (Shoemake).
    let (u1, u2, u3): (f64, f64, f64) = (rng.random(), rng.random(), rng.random());
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        b * (2.0 * PI * u3).cos(),
        a * (2.0 * PI * u2).sin(),
        a * (2.0 * PI * u2).cos(),
        b * (2.0 * PI * u3).sin(),
    ))
}

fn unit_vector(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    loop {
        let v = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let n = v.norm();
        if n > 0.1 && n <= 1.0 {
            return v / n;
        }
    }
}

fn principal(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    let mut v = Vector3::zeros();
    v[rng.random_range(0..3)] = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    v
}

fn draw(options: &GenerateOptions) -> (Vec<Joint>, Vec<Link>) {
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let (lo, hi) = options.joints;
    let n = rng.random_range(lo..=hi);
    let reach = log_uniform(&mut rng, 0.15, 2.0);
    let shares: Vec<f64> = (0..n).map(|_| rng.random_range(0.3..1.0)).collect();
    let total: f64 = shares.iter().sum();
    let mut joints = Vec::with_capacity(n);
    let mut links = Vec::with_capacity(n);
    let mut mass = log_uniform(&mut rng, 0.3, 20.0);
    let mut previous_length = 0.0;
    for (i, share) in shares.iter().enumerate() {
        let wrist = i > 0 && rng.random_bool(1.0 / 6.0);
        let length = if wrist {
            0.0
        } else {
            (reach * share / total).clamp(0.03, 1.0)
        };
        let rotation = match rng.random_range(0..8) {
            0 => random_rotation(&mut rng),
            1..=4 => {
                let quarter = f64::from(rng.random_range(1..4u8)) * PI / 2.0;
                UnitQuaternion::from_axis_angle(
                    &nalgebra::Unit::new_normalize(principal(&mut rng)),
                    quarter,
                )
            }
            _ => UnitQuaternion::identity(),
        };
        let axis = if rng.random_range(0..6) == 0 {
            unit_vector(&mut rng)
        } else {
            principal(&mut rng)
        };
        let kind = if rng.random_range(0..4) == 0 {
            "continuous"
        } else {
            "revolute"
        };
        let limits =
            (kind == "revolute").then(|| (rng.random_range(-PI..-0.5), rng.random_range(0.5..PI)));
        let damping = if rng.random_range(0..10) < 3 {
            0.0
        } else {
            log_uniform(&mut rng, 0.01, 100.0)
        };
        let friction_share = if rng.random_bool(0.5) {
            0.0
        } else {
            rng.random_range(0.0..0.05)
        };
        joints.push(Joint {
            kind,
            xyz: Vector3::new(0.0, 0.0, previous_length),
            rotation,
            axis,
            limits,
            damping,
            friction_share,
        });
        let offset = if rng.random_range(0..4) == 0 {
            Vector3::new(
                rng.random_range(-0.2..0.2) * length,
                rng.random_range(-0.2..0.2) * length,
                0.0,
            )
        } else {
            Vector3::zeros()
        };
        if i > 0 {
            mass = (mass * rng.random_range(0.3..1.0)).max(0.05);
        }
        let extent = length.max(0.03);
        let radius = (extent * rng.random_range(0.05..0.2)).max(0.01);
        let com = Vector3::new(
            offset.x + rng.random_range(-0.1..0.1) * extent,
            offset.y + rng.random_range(-0.1..0.1) * extent,
            0.5 * length + rng.random_range(-0.1..0.1) * extent,
        );
        let (ixx, izz) = (
            mass * (3.0 * radius * radius + extent * extent) / 12.0,
            0.5 * mass * radius * radius,
        );
        let inertial_rpy = if rng.random_range(0..3) == 0 {
            let (r, p, y) = random_rotation(&mut rng).euler_angles();
            [r, p, y]
        } else {
            [0.0; 3]
        };
        links.push(Link {
            length,
            offset,
            mass,
            com,
            inertial_rpy,
            inertia: Matrix3::from_diagonal(&Vector3::new(ixx, ixx, izz)),
            radius,
        });
        previous_length = length;
    }
    (joints, links)
}

fn rpy_of(q: &UnitQuaternion<f64>) -> [f64; 3] {
    let (r, p, y) = q.euler_angles();
    [r, p, y]
}

/// The URDF text of the drawn arm, with effort limits `effort` (None: none written yet).
fn urdf_text(name: &str, joints: &[Joint], links: &[Link], effort: Option<&[f64]>) -> String {
    let mut out = String::new();
    let f = |v: f64| format!("{v:.6}");
    let _ = writeln!(out, "<?xml version=\"1.0\"?>");
    let _ = writeln!(
        out,
        "<!-- Generated by `aift gen-arm` ({name}); docs/arms.md, \"Generated arms\". -->"
    );
    let _ = writeln!(out, "<robot name=\"{name}\">\n  <link name=\"base\"/>");
    let mut parent = "base".to_string();
    for (i, (j, l)) in joints.iter().zip(links).enumerate() {
        let child = format!("link{}", i + 1);
        let rpy = rpy_of(&j.rotation);
        let _ = writeln!(
            out,
            "  <joint name=\"joint{}\" type=\"{}\">\n    <parent link=\"{parent}\"/>\n    <child link=\"{child}\"/>\n    <origin xyz=\"{} {} {}\" rpy=\"{} {} {}\"/>\n    <axis xyz=\"{} {} {}\"/>",
            i + 1,
            j.kind,
            f(j.xyz.x + links.get(i.wrapping_sub(1)).map_or(0.0, |p| p.offset.x)),
            f(j.xyz.y + links.get(i.wrapping_sub(1)).map_or(0.0, |p| p.offset.y)),
            f(j.xyz.z),
            f(rpy[0]),
            f(rpy[1]),
            f(rpy[2]),
            f(j.axis.x),
            f(j.axis.y),
            f(j.axis.z)
        );
        let e = effort.map_or(1e3, |e| e[i]);
        let friction = effort.map_or(0.0, |e| j.friction_share * e[i]);
        let (lo, hi) = j.limits.unwrap_or((0.0, 0.0));
        let _ = writeln!(
            out,
            "    <limit lower=\"{}\" upper=\"{}\" effort=\"{}\" velocity=\"5\"/>\n    <dynamics damping=\"{}\" friction=\"{}\"/>\n  </joint>",
            f(lo),
            f(hi),
            f(e),
            f(j.damping),
            f(friction)
        );
        let i3 = &l.inertia;
        let _ = writeln!(
            out,
            "  <link name=\"{child}\">\n    <inertial>\n      <origin xyz=\"{} {} {}\" rpy=\"{} {} {}\"/>\n      <mass value=\"{}\"/>\n      <inertia ixx=\"{:.9}\" ixy=\"0\" ixz=\"0\" iyy=\"{:.9}\" iyz=\"0\" izz=\"{:.9}\"/>\n    </inertial>",
            f(l.com.x),
            f(l.com.y),
            f(l.com.z),
            f(l.inertial_rpy[0]),
            f(l.inertial_rpy[1]),
            f(l.inertial_rpy[2]),
            f(l.mass),
            i3[(0, 0)],
            i3[(1, 1)],
            i3[(2, 2)]
        );
        if l.length > 0.0 {
            let _ = writeln!(
                out,
                "    <collision>\n      <origin xyz=\"{} {} {}\"/>\n      <geometry><cylinder radius=\"{}\" length=\"{}\"/></geometry>\n    </collision>",
                f(l.offset.x),
                f(l.offset.y),
                f(0.5 * l.length),
                f(l.radius),
                f(l.length)
            );
        }
        let _ = writeln!(out, "  </link>");
        parent = child;
    }
    let last = links.last().map_or(0.0, |l| l.length);
    let off = links.last().map_or(Vector3::zeros(), |l| l.offset);
    let _ = writeln!(
        out,
        "  <joint name=\"ee_joint\" type=\"fixed\">\n    <parent link=\"{parent}\"/>\n    <child link=\"ee\"/>\n    <origin xyz=\"{} {} {}\"/>\n  </joint>\n  <link name=\"ee\"/>\n</robot>",
        f(off.x),
        f(off.y),
        f(last)
    );
    out
}

/// The speed (rad/s) every generated joint's effort can hold against its own viscous damping: a
/// motor that cannot turn its joint faster than a few mrad/s is no arm anyone builds.
const DRIVEN_SPEED: f64 = 1.0;

/// The effort limits of a drawn arm (docs at the top): from its model's gravity torques and
/// inertias over 200 random configurations within its limits.
fn efforts(model: &super::ArmModel, seed: u64, margins: &[f64]) -> Vec<f64> {
    let n = model.joints.len();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(1);
    let mut dynamics = Dynamics::new(Arc::new(model.clone()), [0.0, 0.0, -9.81]);
    let (mut g_max, mut m_max) = (vec![0.0f64; n], vec![0.0f64; n]);
    for _ in 0..200 {
        let q: Vec<f64> = model
            .joints
            .iter()
            .map(|j| {
                let (lo, hi) = j.limits.unwrap_or((-PI, PI));
                rng.random_range(lo..hi)
            })
            .collect();
        let (m, g) = dynamics.mass_matrix_and_gravity(&q);
        for i in 0..n {
            g_max[i] = g_max[i].max(g[i].abs());
            m_max[i] = m_max[i].max(m[(i, i)]);
        }
    }
    (0..n)
        .map(|i| {
            (margins[i] * g_max[i] + 5.0 * m_max[i] + model.joints[i].damping * DRIVEN_SPEED)
                .max(0.1)
        })
        .collect()
}

/// A random serial arm as URDF text (docs at the top of this module).
///
/// ```
/// use aift::arm::{GenerateOptions, generate_arm, parse_urdf};
///
/// let urdf = generate_arm(&GenerateOptions { seed: 7, joints: (3, 5) })?;
/// let arm = parse_urdf(&urdf, std::path::Path::new("generated.urdf"))?;
/// assert!((3..=5).contains(&arm.joints.len()));
/// # Ok::<(), aift::arm::ArmError>(())
/// ```
pub fn generate_arm(options: &GenerateOptions) -> Result<String, ArmError> {
    let (lo, hi) = options.joints;
    if lo < 1 || lo > hi || hi > MAX_GENERATED_JOINTS {
        return Err(ArmError::Generate {
            message: format!(
                "joints {lo}..{hi}: need 1 <= fewest <= most <= {MAX_GENERATED_JOINTS}"
            ),
        });
    }
    let name = format!("gen_{}", options.seed);
    let (joints, links) = draw(options);
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    rng.set_stream(2);
    let margins: Vec<f64> = joints.iter().map(|_| rng.random_range(1.5..4.0)).collect();
    let path = std::path::PathBuf::from(format!("<generated>/{name}.urdf"));
    let draft = super::parse_urdf(&urdf_text(&name, &joints, &links, None), &path)?;
    let effort = efforts(&draft, options.seed, &margins);
    let text = urdf_text(&name, &joints, &links, Some(&effort));
    // What is written must load.
    super::parse_urdf(&text, &path)?;
    Ok(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generated_arms_load_are_reproducible_and_span_the_ranges() {
        let mut joints = std::collections::BTreeSet::new();
        let (mut min_mass, mut max_mass) = (f64::INFINITY, 0.0f64);
        let (mut zero_damping, mut coincident) = (0, 0);
        for seed in 0..200 {
            let options = GenerateOptions {
                seed,
                ..GenerateOptions::default()
            };
            let text = generate_arm(&options).unwrap();
            assert_eq!(text, generate_arm(&options).unwrap(), "seed {seed}");
            let model = crate::arm::parse_urdf(&text, std::path::Path::new("g.urdf")).unwrap();
            joints.insert(model.joints.len());
            for b in model.bodies.iter().skip(1) {
                min_mass = min_mass.min(b.mass);
                max_mass = max_mass.max(b.mass);
            }
            zero_damping += model.joints.iter().filter(|j| j.damping == 0.0).count();
            coincident += model
                .joints
                .iter()
                .skip(1)
                .filter(|j| j.origin.translation.vector.norm() < 1e-12)
                .count();
            assert!(model.link("ee").is_some());
            assert!(model.joints.iter().all(|j| j.effort.is_some()));
        }
        assert_eq!(joints, (2..=7).collect());
        assert!((0.05 - 1e-9..0.2).contains(&min_mass), "{min_mass}");
        assert!(max_mass > 10.0 && max_mass <= 20.0 + 1e-9, "{max_mass}");
        assert!(
            zero_damping > 50 && coincident > 20,
            "{zero_damping} {coincident}"
        );
    }
}
