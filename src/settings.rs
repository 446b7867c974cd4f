//! What every settings type's `validate` returns: the offending field (a dotted key relative to
//! the settings' own table) and why. The scenario puts its section in front (`plant.articulated.`
//! + `substeps`) and the file name around it ([`crate::scenario::ScenarioError::Invalid`]).

/// A setting that fails validation: its key and why.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("`{field}` {message}")]
pub struct SettingError {
    /// The key, relative to the settings' table (`substeps`, `gains.kp`).
    pub field: String,
    pub message: String,
}

impl SettingError {
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            message: message.into(),
        }
    }

    /// The same error with its key under `section` (`section.field`).
    pub fn within(mut self, section: &str) -> Self {
        if !section.is_empty() {
            self.field = format!("{section}.{}", self.field);
        }
        self
    }
}

/// The first tick at or after time `t` (robust to rounding of `t / dt`): where a fault, a target
/// or any timed event starts.
pub fn tick_at(t: f64, dt: f64) -> u64 {
    (t / dt - 1e-6).ceil().max(0.0) as u64
}

/// Checks a timed event's window: `start` finite and >= 0, `end` (if any) finite and after it.
/// On error returns the offending field (`start` or `end`) and why.
pub fn check_window(start: f64, end: Option<f64>) -> Result<(), SettingError> {
    if !start.is_finite() || start < 0.0 {
        return Err(SettingError::new("start", "must be finite and >= 0"));
    }
    if let Some(end) = end
        && (!end.is_finite() || end <= start)
    {
        return Err(SettingError::new("end", "must be finite and after start"));
    }
    Ok(())
}
