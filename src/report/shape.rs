//! The one shape every bench report has: it is run by a
//! [`super::BenchSelection`], and gives its rows (for `bench.json`), its charts
//! and its Markdown section. Each report's file implements it; only
//! `selection.rs` names them all.

use serde_json::{Map, Value};

use super::charts::{Chart, ChartError};

/// A report of the bench.
pub trait Report {
    /// Its fields in `bench.json` (rows, and what they were measured with).
    fn json(&self) -> Map<String, Value>;
    /// Its charts, as (file stem, chart); the Markdown names them `STEM.png`.
    fn charts(&self) -> Result<Vec<(String, Chart)>, ChartError>;
    /// Its section of `bench.md`, from the `## ` heading on.
    fn markdown(&self) -> String;
}

/// A report's fields as a JSON object under `key`.
pub(crate) fn fields(pairs: Vec<(&str, Result<Value, serde_json::Error>)>) -> Map<String, Value> {
    pairs
        .into_iter()
        .map(|(k, v)| (k.to_string(), v.unwrap_or(Value::Null)))
        .collect()
}
