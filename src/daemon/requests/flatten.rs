//! A struct's fields embedded in a request body (`#[serde(flatten)]`) with
//! errors that still name the field.
//!
//! Why: serde hands a flattened struct its keys through a buffer that
//! `serde_path_to_error` cannot see into, so `"region": [0, 0, -1, 1]` would
//! be refused as "invalid value: integer `-1`" with no field named. Used as
//! `#[serde(flatten, deserialize_with = "super::flatten::named")]` in a body
//! that refuses unknown fields: this takes only the struct's own keys, so
//! the body still refuses any other.

use std::cell::Cell;

use serde::de::{self, DeserializeOwned, Deserializer, MapAccess, Visitor};

/// Reads the flattened struct `T` from the body's keys that are its fields;
/// an error names the field (`region[2]: invalid value ...`).
pub fn named<'de, D: Deserializer<'de>, T: DeserializeOwned>(d: D) -> Result<T, D::Error> {
    let map = d.deserialize_struct("flattened", fields_of::<T>(), Collect)?;
    serde_path_to_error::deserialize(serde_json::Value::Object(map))
        .map_err(|e| de::Error::custom(format!("{}: {}", e.path(), e.inner())))
}

/// Gathers the entries a flattened struct is given.
struct Collect;

impl<'de> Visitor<'de> for Collect {
    type Value = serde_json::Map<String, serde_json::Value>;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("an object")
    }

    fn visit_map<A: MapAccess<'de>>(self, mut m: A) -> Result<Self::Value, A::Error> {
        let mut out = serde_json::Map::new();
        while let Some((k, v)) = m.next_entry::<String, serde_json::Value>()? {
            out.insert(k, v);
        }
        Ok(out)
    }
}

/// The field names serde's derive gives `T`: what its `Deserialize` passes to
/// `deserialize_struct`, caught by a deserializer that reads nothing.
pub fn fields_of<'de, T: serde::Deserialize<'de>>() -> &'static [&'static str] {
    let spy = Spy(Cell::new(&[]));
    // The spy refuses to read anything: the error is the expected outcome.
    let _ = T::deserialize(&spy);
    spy.0.get()
}

/// A deserializer that only records the field list it is asked for.
struct Spy(Cell<&'static [&'static str]>);

/// The spy's refusal.
#[derive(Debug)]
struct Refused;

impl std::fmt::Display for Refused {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("only the field names are read")
    }
}

impl std::error::Error for Refused {}

impl de::Error for Refused {
    fn custom<M: std::fmt::Display>(_: M) -> Self {
        Refused
    }
}

impl<'de> Deserializer<'de> for &Spy {
    type Error = Refused;

    fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Refused> {
        Err(Refused)
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _: &'static str,
        fields: &'static [&'static str],
        _: V,
    ) -> Result<V::Value, Refused> {
        self.0.set(fields);
        Err(Refused)
    }

    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string
        bytes byte_buf option unit unit_struct newtype_struct seq tuple
        tuple_struct map enum identifier ignored_any
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraSettings;

    #[derive(Debug, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Body {
        scene: String,
        #[serde(flatten, deserialize_with = "named")]
        settings: CameraSettings,
    }

    fn read(json: &str) -> Result<Body, String> {
        let v: serde_json::Value = serde_json::from_str(json).map_err(|e| e.to_string())?;
        serde_path_to_error::deserialize(v).map_err(|e| format!("{} at {}", e.inner(), e.path()))
    }

    #[test]
    fn the_settings_fields_are_found() {
        assert_eq!(
            fields_of::<CameraSettings>(),
            [
                "exposure_us",
                "gain",
                "pixel_format",
                "region",
                "binning",
                "trigger"
            ]
        );
    }

    #[test]
    fn a_flattened_field_is_read_and_named_in_errors_and_others_are_refused() {
        let b = read(r#"{"scene": "s", "gain": 2, "region": [0, 0, 8, 8]}"#).unwrap();
        assert_eq!((b.scene.as_str(), b.settings.gain), ("s", Some(2.0)));
        assert_eq!(b.settings.region, Some([0, 0, 8, 8]));
        assert_eq!(b.settings.exposure_us, None);
        let cases = [
            (
                r#"{"scene": "s", "region": [0, 0, -1, 8]}"#,
                "region[2]: invalid value",
            ),
            (r#"{"scene": "s", "gain": "high"}"#, "gain: invalid type"),
            (
                r#"{"scene": "s", "trigger": "often"}"#,
                "trigger: unknown variant",
            ),
            (
                r#"{"scene": "s", "colour": true}"#,
                "unknown field `colour`",
            ),
            (r#"{"gain": 1}"#, "missing field `scene`"),
        ];
        for (json, says) in cases {
            let e = read(json).unwrap_err();
            assert!(e.contains(says), "{json}: {e}");
        }
    }
}
