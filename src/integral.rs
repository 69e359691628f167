//! Whole numbers in request bodies, written as JSON integers or as floats
//! with no fractional part (`1` or `1.0`).
//!
//! Why: JSON Schema calls `1.0` an integer, so a client generated from the
//! OpenAPI document may send it; refusing it would be refusing a value the
//! document allows. A fraction (`1.5`), a string or a value beyond the
//! target type is still refused, naming what was expected.

use serde::de::{self, Deserializer, SeqAccess, Visitor};

/// Largest float that is still an exact integer (2^53).
const EXACT: f64 = 9_007_199_254_740_992.0;

struct Whole;

impl<'de> Visitor<'de> for Whole {
    type Value = i64;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a whole number")
    }

    fn visit_i64<E: de::Error>(self, v: i64) -> Result<i64, E> {
        Ok(v)
    }

    fn visit_u64<E: de::Error>(self, v: u64) -> Result<i64, E> {
        i64::try_from(v).map_err(|_| E::custom(format!("{v} is too large")))
    }

    fn visit_f64<E: de::Error>(self, v: f64) -> Result<i64, E> {
        if v.fract() == 0.0 && v.abs() <= EXACT {
            Ok(v as i64)
        } else {
            Err(E::invalid_value(de::Unexpected::Float(v), &self))
        }
    }
}

/// A whole number as `i64`.
pub(crate) fn int<'de, D: Deserializer<'de>>(d: D) -> Result<i64, D::Error> {
    d.deserialize_any(Whole)
}

/// A whole number `>= 0` as `usize`.
pub fn count<'de, D: Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    let v = int(d)?;
    usize::try_from(v).map_err(|_| de::Error::custom(format!("{v} is negative; give a count >= 0")))
}

/// An optional whole number (absent or null: `None`).
pub(crate) fn opt_int<'de, D: Deserializer<'de>>(d: D) -> Result<Option<i64>, D::Error> {
    struct Opt;
    impl<'de> Visitor<'de> for Opt {
        type Value = Option<i64>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a whole number or null")
        }
        fn visit_none<E: de::Error>(self) -> Result<Self::Value, E> {
            Ok(None)
        }
        fn visit_unit<E: de::Error>(self) -> Result<Self::Value, E> {
            Ok(None)
        }
        fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
            int(d).map(Some)
        }
    }
    d.deserialize_option(Opt)
}

/// An optional count `>= 0`.
pub(crate) fn opt_count<'de, D: Deserializer<'de>>(d: D) -> Result<Option<usize>, D::Error> {
    opt_int(d)?
        .map(|v| {
            usize::try_from(v)
                .map_err(|_| de::Error::custom(format!("{v} is negative; give a count >= 0")))
        })
        .transpose()
}

/// A list of whole numbers.
pub(crate) fn ints<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<i64>, D::Error> {
    struct List;
    struct One(i64);
    impl<'de> de::Deserialize<'de> for One {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            int(d).map(One)
        }
    }
    impl<'de> Visitor<'de> for List {
        type Value = Vec<i64>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a list of whole numbers")
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
            let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(1024));
            while let Some(One(v)) = seq.next_element()? {
                out.push(v);
            }
            Ok(out)
        }
    }
    d.deserialize_seq(List)
}

#[cfg(test)]
mod tests {
    #[derive(serde::Deserialize, Debug)]
    struct Body {
        #[serde(deserialize_with = "super::int")]
        id: i64,
        #[serde(default, deserialize_with = "super::ints")]
        ids: Vec<i64>,
        #[serde(default, deserialize_with = "super::opt_count")]
        n: Option<usize>,
    }

    fn parse(s: &str) -> Result<Body, String> {
        serde_json::from_str(s).map_err(|e| e.to_string())
    }

    #[test]
    fn integral_floats_are_whole_numbers_and_fractions_are_not() {
        let b = parse(r#"{"id": 1.0, "ids": [2, 3.0], "n": 4.0}"#).unwrap();
        assert_eq!((b.id, b.ids, b.n), (1, vec![2, 3], Some(4)));
        let b = parse(r#"{"id": -7, "n": null}"#).unwrap();
        assert_eq!((b.id, b.ids.len(), b.n), (-7, 0, None));
        assert!(parse(r#"{"id": 1.5}"#)
            .unwrap_err()
            .contains("expected a whole number"));
        assert!(parse(r#"{"id": "1"}"#)
            .unwrap_err()
            .contains("expected a whole number"));
        assert!(parse(r#"{"id": 1e300}"#).is_err());
        assert!(parse(r#"{"id": 18446744073709551615}"#)
            .unwrap_err()
            .contains("too large"));
        assert!(parse(r#"{"id": 1, "n": -2}"#)
            .unwrap_err()
            .contains("negative"));
        assert!(parse(r#"{"id": 1, "ids": [1, 2.5]}"#).is_err());
    }
}
