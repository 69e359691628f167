//! JSON files: written pretty and atomically. Non-finite numbers in reports
//! follow [`crate::solve::json::finite_or_inf`].

/// Writes a value as pretty JSON atomically.
pub fn write<T: serde::Serialize>(
    path: &std::path::Path,
    value: &T,
) -> Result<(), super::FileError> {
    let mut text = serde_json::to_string_pretty(value)
        .map_err(|e| super::FileError::format(path, e.to_string()))?;
    text.push('\n');
    super::write_atomic(path, text.as_bytes())
}
