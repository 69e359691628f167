//! Colour calibrations: each scene's measured colour balance, newest wins.
//!
//! Why in the catalogue: a balance is measured once on the bench (a white
//! card, a flat field) and must outlive the daemon's restarts and the
//! capture it was measured from, which the user may delete.

use rusqlite::{params, OptionalExtension, Row};

use super::records::json_column;
use super::{now, Store, StoreError};
use crate::calibrate::colour::ColourBalance;

/// One stored colour calibration.
#[derive(Debug, Clone)]
pub struct ColourCalibrationRow {
    /// Its id.
    pub id: i64,
    /// The scene it is of.
    pub scene: String,
    /// The capture it was measured from (which may since be deleted).
    pub capture: i64,
    /// The colours' responses.
    pub balance: ColourBalance,
    /// When it was measured.
    pub created_at: String,
}

impl ColourCalibrationRow {
    /// How a reconstruction's report names it: `colour calibration 2 (capture 5)`.
    pub(crate) fn label(&self) -> String {
        format!("colour calibration {} (capture {})", self.id, self.capture)
    }
}

impl Store {
    /// Records scene `scene`'s colour balance measured from `capture`; returns its row.
    pub fn insert_colour_calibration(
        &self,
        scene: &str,
        capture: i64,
        balance: &ColourBalance,
    ) -> Result<ColourCalibrationRow, StoreError> {
        // A balance is plain numbers and names: it always serializes.
        let text = serde_json::to_string(balance).unwrap_or_default();
        let created_at = now();
        let id = self.with(|c| {
            c.execute(
                "INSERT INTO colour_calibrations (scene, capture, balance, created_at) VALUES (?1, ?2, ?3, ?4)",
                params![scene, capture, text, created_at],
            )?;
            Ok(c.last_insert_rowid())
        })?;
        Ok(ColourCalibrationRow {
            id,
            scene: scene.to_string(),
            capture,
            balance: balance.clone(),
            created_at,
        })
    }

    /// Scene `scene`'s newest colour calibration, if it has one.
    pub fn colour_calibration(
        &self,
        scene: &str,
    ) -> Result<Option<ColourCalibrationRow>, StoreError> {
        self.with(|c| {
            c.query_row(
                "SELECT id, scene, capture, balance, created_at FROM colour_calibrations WHERE scene = ?1 ORDER BY id DESC LIMIT 1",
                [scene],
                calibration_row,
            )
            .optional()
        })
    }

    /// Every scene's newest colour calibration, by scene name.
    pub fn colour_calibrations(&self) -> Result<Vec<ColourCalibrationRow>, StoreError> {
        self.with(|c| {
            let mut st = c.prepare(
                "SELECT id, scene, capture, balance, created_at FROM colour_calibrations WHERE id IN (SELECT MAX(id) FROM colour_calibrations GROUP BY scene) ORDER BY scene",
            )?;
            let rows = st.query_map([], calibration_row)?.collect();
            rows
        })
    }
}

/// A `colour_calibrations` row (an unreadable balance makes the row an error, never a default).
fn calibration_row(r: &Row<'_>) -> rusqlite::Result<ColourCalibrationRow> {
    Ok(ColourCalibrationRow {
        id: r.get("id")?,
        scene: r.get("scene")?,
        capture: r.get("capture")?,
        balance: json_column(r, "balance")?.ok_or(rusqlite::Error::InvalidColumnType(
            3,
            "balance".into(),
            rusqlite::types::Type::Null,
        ))?,
        created_at: r.get("created_at")?,
    })
}
