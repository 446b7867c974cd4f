//! The fault-tolerance methods, by the names used everywhere (CLI, files, tables).

use std::fmt;

use serde::{Deserialize, Serialize};

/// A fault-tolerance method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, PartialOrd, Ord)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Fixed nominal precisions: no fault tolerance.
    NoFt,
    /// The paper's gradient precision learning at all times.
    PlAlways,
    /// Gradient precision learning once the detector fires (the paper's "PL + FD").
    PlDetect,
    /// The detector fires and the isolated channel's precision goes to 0 (ECC).
    Deterministic,
    /// Gamma posterior precision with forgetting (the paper's future work).
    Bayes,
    /// Precision from the last k residuals (the paper's future work).
    Window,
    /// Told the faulty channel and the fault time: the reference, not a usable method.
    Oracle,
}

impl Method {
    /// Every method, in table order.
    pub const ALL: [Method; 7] = [
        Method::NoFt,
        Method::PlAlways,
        Method::PlDetect,
        Method::Deterministic,
        Method::Bayes,
        Method::Window,
        Method::Oracle,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::NoFt => "no-ft",
            Self::PlAlways => "pl-always",
            Self::PlDetect => "pl-detect",
            Self::Deterministic => "deterministic",
            Self::Bayes => "bayes",
            Self::Window => "window",
            Self::Oracle => "oracle",
        }
    }

    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Whether the method needs the calibrated detector.
    pub fn needs_detector(self) -> bool {
        matches!(self, Self::PlDetect | Self::Deterministic)
    }

    /// The seed paper's Table 1 row for this method (faulty joint, healthy joint MSE), if any.
    pub fn paper_table1(self) -> Option<(f64, f64)> {
        match self {
            Self::NoFt => Some((0.0036, 0.0020)),
            Self::PlAlways => Some((5.422e-5, 4.527e-5)),
            Self::PlDetect => Some((6.097e-5, 4.134e-5)),
            Self::Deterministic => Some((0.5946e-5, 0.3579e-5)),
            _ => None,
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::parse(s).ok_or_else(|| {
            format!(
                "unknown method {s:?} (methods: {})",
                Self::ALL.map(Method::name).join(", ")
            )
        })
    }
}
