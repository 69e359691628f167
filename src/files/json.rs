//! JSON conventions: non-finite numbers (an infinite kappa, a perfect PSNR)
//! are written as the strings `"inf"`, `"-inf"`, `"nan"`, since JSON has no such numbers.

use serde::Serializer;

/// Serializes a finite `f64` as a number and a non-finite one as a string.
pub fn finite_or_inf<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    if v.is_finite() {
        s.serialize_f64(*v)
    } else if v.is_nan() {
        s.serialize_str("nan")
    } else if *v > 0.0 {
        s.serialize_str("inf")
    } else {
        s.serialize_str("-inf")
    }
}

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
