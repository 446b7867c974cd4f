//! The virtual camera: a pinhole looking at the arm, with radial (barrel) distortion, and
//! occlusion by the arm's own collision shapes.
//!
//! Model (docs/method.md, "Sensors"; the formula's units are ours): the end effector p is expressed in
//! the camera frame, divided by its depth and scaled back to metres at a reference depth
//! (perspective divide), then distorted about the optical centre c:
//! `p_d = c + (p - c)(1 + K1 r^2 + K2 r^4 + K3 r^6)`, r = |p - c| in metres (Brown-Conrady).
//! The default camera looks straight at the paper arm's x-z plane from -y, so its image
//! coordinates (u, v) are the world's (x, z), not mirrored.
//!
//! `model = "position"` turns it into a position tracker (motion capture): three outputs, the
//! end effector's world (x, y, z), with the same noise and occlusion and no distortion.

use nalgebra::Vector3;
use parry3d_f64::query::Ray;
use serde::{Deserialize, Serialize};

use crate::arm::EndEffector;
use crate::arm::kinematics::ArmPose;

/// What the camera reports.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum CameraModel {
    /// A pinhole image: two outputs (u, v) in metres at the reference depth, distorted.
    #[default]
    Pinhole,
    /// A position tracker: three outputs, the end effector's world (x, y, z).
    Position,
}

impl CameraModel {
    /// Number of outputs.
    pub fn outputs(self) -> usize {
        self.output_names().len()
    }

    /// Output names (channel names are `cam_<name>`).
    pub fn output_names(self) -> &'static [&'static str] {
        match self {
            Self::Pinhole => &["u", "v"],
            Self::Position => &["x", "y", "z"],
        }
    }
}

/// How the camera is set up. Defaults follow the paper: sigma 0.01 m, K1 = -1.5e-3, K2 = 5e-6,
/// K3 = 0, looking at the origin from 3 m along -y with z up.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// `pinhole` (two image outputs) or `position` (three world coordinates).
    pub model: CameraModel,
    /// Standard deviation of the Gaussian noise per image coordinate (m).
    pub sigma: f64,
    /// Radial distortion coefficients K1, K2, K3 (r in metres).
    pub k1: f64,
    pub k2: f64,
    pub k3: f64,
    /// Camera position in the world (m).
    pub position: [f64; 3],
    /// Point the optical axis passes through.
    pub look_at: [f64; 3],
    /// World direction that appears as +v in the image.
    pub up: [f64; 3],
    /// Distortion centre in image coordinates (m); (0, 0) is the principal point.
    pub optical_centre: [f64; 2],
    /// Depth at which image coordinates are metres; default: the distance to `look_at`.
    pub reference_depth: Option<f64>,
    /// Whether the arm's collision shapes can hide the end effector.
    pub occlusion: bool,
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            model: CameraModel::Pinhole,
            sigma: 0.01,
            k1: -1.5e-3,
            k2: 5e-6,
            k3: 0.0,
            position: [0.0, -3.0, 0.0],
            look_at: [0.0, 0.0, 0.0],
            up: [0.0, 0.0, 1.0],
            optical_centre: [0.0, 0.0],
            reference_depth: None,
            occlusion: true,
        }
    }
}

impl CameraConfig {
    /// Checks the geometry; returns the offending field and why.
    pub fn validate(&self) -> Result<(), crate::SettingError> {
        let finite = |name: &'static str, v: &[f64]| {
            if v.iter().all(|x| x.is_finite()) {
                Ok(())
            } else {
                Err(crate::SettingError::new(name, "must be finite".to_string()))
            }
        };
        finite("sigma", &[self.sigma])?;
        finite("k1", &[self.k1])?;
        finite("k2", &[self.k2])?;
        finite("k3", &[self.k3])?;
        finite("position", &self.position)?;
        finite("look_at", &self.look_at)?;
        finite("up", &self.up)?;
        finite("optical_centre", &self.optical_centre)?;
        if self.sigma < 0.0 || self.sigma > 1e3 {
            return Err(crate::SettingError::new("sigma", "must be in [0, 1e3] m"));
        }
        for (name, k) in [("k1", self.k1), ("k2", self.k2), ("k3", self.k3)] {
            if k.abs() > 1e3 {
                return Err(crate::SettingError::new(
                    name,
                    "must be at most 1e3 in size",
                ));
            }
        }
        let forward = Vector3::from(self.look_at) - Vector3::from(self.position);
        if forward.norm() < 1e-9 {
            return Err(crate::SettingError::new(
                "look_at",
                "must differ from position",
            ));
        }
        if forward.cross(&Vector3::from(self.up)).norm() < 1e-9 * forward.norm() {
            return Err(crate::SettingError::new(
                "up",
                "must not be parallel to the viewing direction",
            ));
        }
        if let Some(d) = self.reference_depth
            && !(d.is_finite() && d > 0.0)
        {
            return Err(crate::SettingError::new(
                "reference_depth",
                "must be finite and > 0",
            ));
        }
        Ok(())
    }
}

/// Why a camera reading is missing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NotSeen {
    /// The point is behind (or on) the image plane.
    Behind,
    /// A collision shape blocks the line of sight.
    Occluded,
}

/// The camera, ready to project.
#[derive(Clone, Debug)]
pub struct Camera {
    config: CameraConfig,
    position: Vector3<f64>,
    /// Image right, image up, viewing direction (unit, world coordinates).
    right: Vector3<f64>,
    image_up: Vector3<f64>,
    forward: Vector3<f64>,
    reference_depth: f64,
}

/// Occlusion ignores hits this close to the end effector (m): the surface the point sits on.
const OCCLUSION_MARGIN: f64 = 1e-6;

impl Camera {
    /// Builds the camera; the configuration must have passed [`CameraConfig::validate`].
    pub fn new(config: CameraConfig) -> Self {
        let position = Vector3::from(config.position);
        let to_target = Vector3::from(config.look_at) - position;
        let forward = to_target.normalize();
        let right = forward.cross(&Vector3::from(config.up)).normalize();
        let image_up = right.cross(&forward);
        let reference_depth = config.reference_depth.unwrap_or(to_target.norm());
        Self {
            config,
            position,
            right,
            image_up,
            forward,
            reference_depth,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &CameraConfig {
        &self.config
    }

    /// Pinhole projection of a world point to undistorted image metres, or `None` if it is behind.
    pub fn project_undistorted(&self, p: &Vector3<f64>) -> Option<[f64; 2]> {
        let d = p - self.position;
        let depth = d.dot(&self.forward);
        if depth <= 1e-9 {
            return None;
        }
        let scale = self.reference_depth / depth;
        Some([d.dot(&self.right) * scale, d.dot(&self.image_up) * scale])
    }

    /// Radial distortion about the optical centre: `c + (p - c)(1 + K1 r^2 + K2 r^4 + K3 r^6)`.
    pub fn distort(&self, p: [f64; 2]) -> [f64; 2] {
        let [cx, cy] = self.config.optical_centre;
        let (dx, dy) = (p[0] - cx, p[1] - cy);
        let r2 = dx * dx + dy * dy;
        let f = 1.0 + r2 * (self.config.k1 + r2 * (self.config.k2 + r2 * self.config.k3));
        [cx + dx * f, cy + dy * f]
    }

    /// The noise-free, distorted image of a world point (no occlusion test).
    pub fn project(&self, p: &Vector3<f64>) -> Option<[f64; 2]> {
        self.project_undistorted(p).map(|u| self.distort(u))
    }

    /// Whether one of the arm's collision shapes, other than those on the end effector's own
    /// body and those that contain `p`, lies on the line of sight from the camera to `p`. A
    /// collision shape is a coarse hull: an end effector inside one (a tool frame inside a
    /// wrist's cylinder, a generated link folded back into its parent's) is taken to be on its
    /// surface, not hidden by it for ever.
    pub fn occluded(&self, arm: &dyn ArmPose, ee: &EndEffector, p: &Vector3<f64>) -> bool {
        let d = p - self.position;
        let distance = d.norm();
        if distance <= OCCLUSION_MARGIN {
            return false;
        }
        let dir = d / distance;
        let vector = |v: &Vector3<f64>| parry3d_f64::math::Vector::new(v.x, v.y, v.z);
        let ray = Ray::new(vector(&self.position), vector(&dir));
        arm.model()
            .colliders
            .iter()
            .filter(|c| c.body != ee.body)
            .any(|c| {
                let pose = arm.collision_pose(c.body) * c.parry_pose;
                c.parry_shape
                    .cast_ray(&pose, &ray, distance - OCCLUSION_MARGIN, true)
                    .is_some()
                    && !c
                        .parry_shape
                        .contains_point(&pose, parry3d_f64::math::Vector::new(p.x, p.y, p.z))
            })
    }

    /// Number of outputs.
    pub fn outputs(&self) -> usize {
        self.config.model.outputs()
    }

    /// The noise-free outputs for an end effector at world point `p` (no occlusion test).
    pub fn measure(&self, p: &Vector3<f64>, out: &mut [f64]) -> Result<(), NotSeen> {
        match self.config.model {
            CameraModel::Pinhole => {
                let image = self.project(p).ok_or(NotSeen::Behind)?;
                out.copy_from_slice(&image);
            }
            CameraModel::Position => out.copy_from_slice(p.as_slice()),
        }
        Ok(())
    }

    /// The Jacobian of [`Camera::measure`] with respect to the world point (outputs x 3, row-major
    /// rows), in closed form: the perspective divide's derivative
    /// `d u / d p = (R / z)(right - (u / R) forward)` (likewise v with the image's up), then the
    /// distortion's `f I + 2 f'(r^2) (u - c)(u - c)^T`, f' = K1 + 2 K2 r^2 + 3 K3 r^4 (module doc).
    pub fn measure_jacobian(&self, p: &Vector3<f64>) -> Result<Vec<[f64; 3]>, NotSeen> {
        match self.config.model {
            CameraModel::Position => Ok(vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
            CameraModel::Pinhole => {
                let u = self.project_undistorted(p).ok_or(NotSeen::Behind)?;
                let depth = (p - self.position).dot(&self.forward);
                let scale = self.reference_depth / depth;
                let row = |axis: &Vector3<f64>, value: f64| -> Vector3<f64> {
                    (axis - self.forward * (value / self.reference_depth)) * scale
                };
                let undistorted = [row(&self.right, u[0]), row(&self.image_up, u[1])];
                let [cx, cy] = self.config.optical_centre;
                let d = [u[0] - cx, u[1] - cy];
                let r2 = d[0] * d[0] + d[1] * d[1];
                let (k1, k2, k3) = (self.config.k1, self.config.k2, self.config.k3);
                let f = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                let df = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
                Ok((0..2)
                    .map(|a| {
                        let mut out = Vector3::zeros();
                        for (b, du) in undistorted.iter().enumerate() {
                            let identity = if a == b { f } else { 0.0 };
                            out += du * (identity + 2.0 * df * d[a] * d[b]);
                        }
                        [out.x, out.y, out.z]
                    })
                    .collect())
            }
        }
    }

    /// What one camera frame says about each joint: |d measure / d q_j| / sigma, in inverse
    /// radians (metres for a prismatic joint), at the pose `poses` (the bodies' world poses) with
    /// end effector `ee`. Multiplied by an encoder's sigma, it is one frame's information about
    /// the joint against one encoder reading's; zero for a joint the camera cannot see at this
    /// pose (an end effector on the joint's axis, or a joint moving it along the line of sight):
    /// only the joint's own sensors and the dynamics can check such a joint (docs/method.md,
    /// "Sensors nobody else can check").
    pub fn joint_sensitivity(
        &self,
        model: &crate::arm::ArmModel,
        ee: &EndEffector,
        poses: &[nalgebra::Isometry3<f64>],
    ) -> Result<Vec<f64>, NotSeen> {
        let p = ee.position(poses);
        let camera = self.measure_jacobian(&p)?;
        let arm = crate::arm::kinematics::ee_jacobian(model, ee, poses);
        Ok((0..arm.ncols())
            .map(|j| {
                let column = arm.column(j);
                camera
                    .iter()
                    .map(|row| (0..3).map(|k| row[k] * column[k]).sum::<f64>().powi(2))
                    .sum::<f64>()
                    .sqrt()
                    / self.config.sigma
            })
            .collect())
    }

    /// [`Camera::joint_sensitivity`] per joint, the least and the greatest over the joint
    /// positions `qs` (a scenario's start and targets): a pose at which the end effector is
    /// behind the camera counts as 0 for every joint.
    pub fn joint_sensitivity_range<'a>(
        &self,
        model: &crate::arm::ArmModel,
        ee: &EndEffector,
        qs: impl IntoIterator<Item = &'a [f64]>,
    ) -> (Vec<f64>, Vec<f64>) {
        let n = model.joints.len();
        let mut poses = vec![nalgebra::Isometry3::identity(); model.bodies.len()];
        let (mut least, mut greatest) = (vec![f64::INFINITY; n], vec![0.0_f64; n]);
        for q in qs {
            crate::arm::kinematics::forward(model, q, &mut poses);
            let seen = self
                .joint_sensitivity(model, ee, &poses)
                .unwrap_or_else(|_| vec![0.0; n]);
            for (j, s) in seen.into_iter().enumerate() {
                least[j] = least[j].min(s);
                greatest[j] = greatest[j].max(s);
            }
        }
        (least, greatest)
    }

    /// What the camera sees of the arm's end effector this tick, before noise, written into
    /// `out` (one value per output).
    pub fn observe(
        &self,
        arm: &dyn ArmPose,
        ee: &EndEffector,
        out: &mut [f64],
    ) -> Result<(), NotSeen> {
        let p = arm.ee_position(ee);
        self.measure(&p, out)?;
        if self.config.occlusion && self.occluded(arm, ee, &p) {
            return Err(NotSeen::Occluded);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A distorted, tilted pinhole (off-centre optical centre, all three K) and the position
    /// tracker: the closed-form Jacobian against central differences of `measure`.
    #[test]
    fn measure_jacobian_matches_central_differences() {
        let tilted = CameraConfig {
            k1: -0.08,
            k2: 0.02,
            k3: -0.004,
            position: [0.4, -1.7, 0.9],
            look_at: [0.1, 0.2, -0.3],
            up: [0.2, 0.1, 1.0],
            optical_centre: [0.05, -0.03],
            reference_depth: Some(1.3),
            ..CameraConfig::default()
        };
        let position = CameraConfig {
            model: CameraModel::Position,
            ..CameraConfig::default()
        };
        for config in [tilted, position] {
            let cam = Camera::new(config);
            for p in [
                Vector3::new(0.3, 0.1, -0.2),
                Vector3::new(-0.9, 0.4, 0.7),
                Vector3::new(1.2, -0.5, -1.1),
            ] {
                let jac = cam.measure_jacobian(&p).unwrap();
                let m = cam.outputs();
                assert_eq!(jac.len(), m);
                let h = 1e-6;
                for k in 0..3 {
                    let mut step = Vector3::zeros();
                    step[k] = h;
                    let (mut plus, mut minus) = (vec![0.0; m], vec![0.0; m]);
                    cam.measure(&(p + step), &mut plus).unwrap();
                    cam.measure(&(p - step), &mut minus).unwrap();
                    for o in 0..m {
                        let fd = (plus[o] - minus[o]) / (2.0 * h);
                        assert!(
                            (jac[o][k] - fd).abs() < 1e-7 * (1.0 + fd.abs()),
                            "output {o}, axis {k}, at {p:?}: {} against {fd}",
                            jac[o][k]
                        );
                    }
                }
            }
        }
        let behind = Camera::new(CameraConfig::default());
        assert_eq!(
            behind.measure_jacobian(&Vector3::new(0.0, -4.0, 0.0)),
            Err(NotSeen::Behind)
        );
    }

    /// Two links, the end effector 0.3 m out on the second: each joint's sensitivity against
    /// central differences of forward kinematics and `measure` (an independent path), and zero
    /// for the second joint once the end effector sits on its axis.
    #[test]
    fn joint_sensitivity_matches_differences_and_vanishes_on_the_axis() {
        use crate::arm::kinematics::forward;
        const ARM: &str = r#"<robot name="t">
          <link name="world"/>
          <joint name="j1" type="continuous"><parent link="world"/><child link="l1"/>
            <axis xyz="0 -1 0"/></joint>
          <link name="l1"><inertial><origin xyz="0.5 0 0"/><mass value="2"/>
            <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.3" iyz="0" izz="0.3"/></inertial></link>
          <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
            <origin xyz="1 0 0" rpy="0.3 0 0"/><axis xyz="0.6 -0.8 0"/>
            <limit lower="-3" upper="3" effort="100" velocity="10"/></joint>
          <link name="l2"><inertial><origin xyz="0.4 0 0"/><mass value="1.5"/>
            <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.2" iyz="0" izz="0.2"/></inertial></link>
        </robot>"#;
        let model = crate::arm::parse_urdf(ARM, std::path::Path::new("t.urdf")).unwrap();
        let cam = Camera::new(CameraConfig::default());
        let q = [0.4, -0.7];
        let mut poses = vec![nalgebra::Isometry3::identity(); model.bodies.len()];
        let image = |ee: &EndEffector, q: &[f64]| {
            let mut poses = vec![nalgebra::Isometry3::identity(); model.bodies.len()];
            forward(&model, q, &mut poses);
            let mut out = [0.0; 2];
            cam.measure(&ee.position(&poses), &mut out).unwrap();
            out
        };
        let ee = EndEffector::new(&model, "l2", [0.3, 0.0, 0.0]).unwrap();
        forward(&model, &q, &mut poses);
        let sensitivity = cam.joint_sensitivity(&model, &ee, &poses).unwrap();
        let h = 1e-6;
        for j in 0..2 {
            let (mut plus, mut minus) = (q, q);
            plus[j] += h;
            minus[j] -= h;
            let (a, b) = (image(&ee, &plus), image(&ee, &minus));
            let fd = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
                / (2.0 * h)
                / cam.config().sigma;
            assert!(
                (sensitivity[j] - fd).abs() < 1e-6 * fd,
                "joint {j}: {} against {fd}",
                sensitivity[j]
            );
            assert!(fd > 1.0, "joint {j} is visible here: {fd}");
        }
        // On the second joint's axis (through l2's origin along (0.6, -0.8, 0)).
        let on_axis = EndEffector::new(&model, "l2", [0.3, -0.4, 0.0]).unwrap();
        let sensitivity = cam.joint_sensitivity(&model, &on_axis, &poses).unwrap();
        assert!(sensitivity[1] < 1e-9, "{}", sensitivity[1]);
        assert!(sensitivity[0] > 1.0, "{}", sensitivity[0]);
    }

    #[test]
    fn default_camera_sees_world_x_and_z_unmirrored() {
        let cam = Camera::new(CameraConfig {
            k1: 0.0,
            k2: 0.0,
            ..CameraConfig::default()
        });
        let [u, v] = cam.project(&Vector3::new(0.7, 0.0, -1.3)).unwrap();
        assert!(
            (u - 0.7).abs() < 1e-15 && (v + 1.3).abs() < 1e-15,
            "{u} {v}"
        );
    }

    #[test]
    fn distortion_matches_hand_computed_points() {
        let cam = Camera::new(CameraConfig::default());
        // r = 2 m on the u axis: factor 1 - 1.5e-3 * 4 + 5e-6 * 16 = 0.99408.
        let [u, v] = cam.distort([2.0, 0.0]);
        assert!((u - 1.98816).abs() < 1e-14 && v == 0.0, "{u}");
        // (1, 1): r^2 = 2, factor 1 - 3e-3 + 2e-5 = 0.99702.
        let [u, v] = cam.distort([1.0, 1.0]);
        assert!((u - 0.99702).abs() < 1e-14 && (v - 0.99702).abs() < 1e-14);
        // About an optical centre at (0.5, 0): the centre is fixed, distances shrink about it.
        let cam = Camera::new(CameraConfig {
            optical_centre: [0.5, 0.0],
            ..CameraConfig::default()
        });
        assert_eq!(cam.distort([0.5, 0.0]), [0.5, 0.0]);
        let [u, _] = cam.distort([2.5, 0.0]);
        assert!((u - (0.5 + 2.0 * 0.99408)).abs() < 1e-14);
    }

    #[test]
    fn off_axis_pose_projects_with_the_perspective_divide() {
        // Camera at (1, -2, 0.5) looking at the origin; reference depth 2 m.
        let cam = Camera::new(CameraConfig {
            k1: 0.0,
            k2: 0.0,
            position: [1.0, -2.0, 0.5],
            reference_depth: Some(2.0),
            ..CameraConfig::default()
        });
        let p = Vector3::new(0.3, 0.4, -0.2);
        // By hand: viewing direction f = (-1, 2, -0.5)/sqrt(5.25), image right r = f x z / |.| =
        // (2, 1, 0)/sqrt(5), image up r x f = (-0.5, 1, 5)/sqrt(26.25). From the camera the point
        // is d = (-0.7, 2.4, -0.7): depth d.f = 5.85/sqrt(5.25), d.r = 1/sqrt(5),
        // d.up = -0.75/sqrt(26.25); scaled by reference depth / depth.
        let depth = 5.85 / 5.25f64.sqrt();
        let expected = [
            (1.0 / 5f64.sqrt()) * 2.0 / depth,
            (-0.75 / 26.25f64.sqrt()) * 2.0 / depth,
        ];
        let got = cam.project(&p).unwrap();
        assert!((got[0] - 0.350_323_103).abs() < 1e-9, "{got:?}");
        assert!((got[1] + 0.114_670_153).abs() < 1e-9, "{got:?}");
        assert!((got[0] - expected[0]).abs() < 1e-14 && (got[1] - expected[1]).abs() < 1e-14);
        // A point behind the camera is not seen.
        assert!(cam.project(&Vector3::new(3.0, -6.0, 1.5)).is_none());
    }

    #[test]
    fn validation_names_the_field() {
        let bad = CameraConfig {
            up: [0.0, 1.0, 0.0],
            ..CameraConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().field, "up");
        let bad = CameraConfig {
            sigma: f64::NAN,
            ..CameraConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().field, "sigma");
    }
}
