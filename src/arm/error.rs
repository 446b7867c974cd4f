//! Errors of the arm model: reading a URDF, validating it, naming links.

use std::path::PathBuf;

/// Everything that can go wrong while reading a URDF into an [`crate::arm::ArmModel`].
///
/// Every variant names the file and the offending element, so a message can say exactly what is
/// wrong where.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ArmError {
    #[error("{path}: cannot read the file")]
    Unreadable {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    File(crate::fsio::FsError),
    #[error("{path}: the file is empty")]
    Empty { path: PathBuf },
    #[error("{path}: the file is not UTF-8 text (binary file?)")]
    NotText { path: PathBuf },
    #[error("{path}: XML nested {depth} levels deep near line {line} (limit {limit}); not a URDF")]
    TooDeep {
        path: PathBuf,
        depth: usize,
        limit: usize,
        line: usize,
    },
    #[error("{path}: XML error: {message}")]
    Xml { path: PathBuf, message: String },
    #[error("{path}: {element}: attribute `{attribute}` = {value:?} is not {expected}")]
    BadNumber {
        path: PathBuf,
        element: String,
        attribute: String,
        value: String,
        expected: String,
    },
    #[error("{path}: duplicate {kind} name '{name}'")]
    DuplicateName {
        path: PathBuf,
        kind: &'static str,
        name: String,
    },
    #[error("{path}: joint '{joint}' names {role} link '{link}', which does not exist")]
    UnknownLink {
        path: PathBuf,
        joint: String,
        role: &'static str,
        link: String,
    },
    #[error("{path}: link '{link}' is the child of more than one joint ('{first}' and '{second}')")]
    MultipleParents {
        path: PathBuf,
        link: String,
        first: String,
        second: String,
    },
    #[error("{path}: the links do not form one tree: {roots_found} root links found ({roots})")]
    NoSingleRoot {
        path: PathBuf,
        roots_found: usize,
        roots: String,
    },
    #[error("{path}: joint '{joint}' closes a kinematic cycle")]
    Cycle { path: PathBuf, joint: String },
    #[error("{path}: link '{link}' is not connected to the root link '{root}'")]
    Disconnected {
        path: PathBuf,
        link: String,
        root: String,
    },
    #[error("{path}: link '{link}': <inertial><mass value> = {mass} must be finite and >= 0")]
    BadMass {
        path: PathBuf,
        link: String,
        mass: f64,
    },
    #[error("{path}: link '{link}': <inertial><inertia> {reason}")]
    BadInertia {
        path: PathBuf,
        link: String,
        reason: String,
    },
    #[error("{path}: joint '{joint}': {element} {attribute} = {value} must be >= 0")]
    Negative {
        path: PathBuf,
        joint: String,
        element: &'static str,
        attribute: &'static str,
        value: f64,
    },
    #[error("{path}: joint '{joint}': <axis xyz> is the zero vector")]
    ZeroAxis { path: PathBuf, joint: String },
    #[error("{path}: joint '{joint}': <limit> lower {lower} > upper {upper}")]
    BadLimit {
        path: PathBuf,
        joint: String,
        lower: f64,
        upper: f64,
    },
    #[error(
        "{path}: joint '{joint}' has type '{kind}', which aift does not support (revolute, continuous, prismatic, fixed)"
    )]
    UnsupportedJoint {
        path: PathBuf,
        joint: String,
        kind: String,
    },
    #[error(
        "{path}: the moving body of link '{link}' has no mass (give it or a link fixed to it an <inertial>)"
    )]
    MasslessBody { path: PathBuf, link: String },
    #[error(
        "{path}: line {line}: `{found}` is xacro, not URDF: expand the file first (`xacro {} > arm.urdf`, with ROS's xacro or `pip install xacro`)",
        path.display()
    )]
    Xacro {
        path: PathBuf,
        line: usize,
        found: String,
    },
    #[error("{path}: no movable joint (revolute, continuous or prismatic): nothing to control")]
    NoMovableJoint { path: PathBuf },
    #[error(
        "{path}: {count} movable joints; more than {limit} is refused (every estimator's state, the camera model's inputs and the controller grow with it)"
    )]
    TooManyJoints {
        path: PathBuf,
        count: usize,
        limit: usize,
    },
    #[error("gen-arm: {message}")]
    Generate { message: String },
    #[error("{path}: end-effector link '{link}' does not exist (links: {available})")]
    UnknownEndEffector {
        path: PathBuf,
        link: String,
        available: String,
    },
}

impl ArmError {
    /// The file the error is about.
    pub fn path(&self) -> &std::path::Path {
        match self {
            Self::Generate { .. } => std::path::Path::new("<generated>"),
            Self::File(e) => e.path(),
            Self::Unreadable { path, .. }
            | Self::Empty { path }
            | Self::NotText { path }
            | Self::TooDeep { path, .. }
            | Self::Xml { path, .. }
            | Self::BadNumber { path, .. }
            | Self::DuplicateName { path, .. }
            | Self::UnknownLink { path, .. }
            | Self::MultipleParents { path, .. }
            | Self::NoSingleRoot { path, .. }
            | Self::Cycle { path, .. }
            | Self::Disconnected { path, .. }
            | Self::BadMass { path, .. }
            | Self::BadInertia { path, .. }
            | Self::Negative { path, .. }
            | Self::ZeroAxis { path, .. }
            | Self::BadLimit { path, .. }
            | Self::UnsupportedJoint { path, .. }
            | Self::MasslessBody { path, .. }
            | Self::Xacro { path, .. }
            | Self::NoMovableJoint { path }
            | Self::TooManyJoints { path, .. }
            | Self::UnknownEndEffector { path, .. } => path,
        }
    }
}
