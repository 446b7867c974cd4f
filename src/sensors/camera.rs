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
