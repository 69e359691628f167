//! How the numbers of reports, conditioning and metrics appear in JSON:
//! JSON has no infinite or NaN numbers, and these can hold them.

/// Serializes a finite `f64` as a number and a non-finite one as the string
/// `"inf"`, `"-inf"` or `"nan"`: JSON has no such numbers, and a report can
/// hold them (an infinite kappa, a perfect PSNR).
pub fn finite_or_inf<S: serde::Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
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
