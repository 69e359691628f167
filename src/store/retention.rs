//! Which captures a retention policy removes: the oldest finished captures
//! (with the reconstructions that use them) beyond an age or beyond a total
//! size of the data directory, never one a queued or running job needs.
//!
//! Why in the store: only the catalogue knows which rows are finished and
//! who uses whom; the daemon's retention task only asks and deletes.

use std::path::Path;
use std::time::{Duration, SystemTime};

use super::{timestamp, Store, StoreError};

/// What may be kept: captures no older than `max_age`, and captures and
/// reconstructions together no larger than `max_bytes` on disk.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Retention {
    /// Captures created longer ago than this are removed.
    pub max_age: Option<Duration>,
    /// The oldest captures are removed until the data's files fit in this.
    pub max_bytes: Option<u64>,
}

/// Bytes of the regular files under `dir` (0 when it does not exist).
pub(crate) fn dir_bytes(dir: &Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    entries
        .flatten()
        .map(|e| match e.file_type() {
            Ok(t) if t.is_dir() => dir_bytes(&e.path()),
            Ok(t) if t.is_file() => e.metadata().map(|m| m.len()).unwrap_or(0),
            _ => 0,
        })
        .sum()
}

impl Store {
    /// Bytes the captures' and reconstructions' files take.
    pub fn data_bytes(&self) -> u64 {
        dir_bytes(&self.dir.join("captures")) + dir_bytes(&self.dir.join("reconstructions"))
    }

    /// The captures `policy` removes now (oldest first), each deletable with
    /// its reconstructions: too old, or among the oldest while the data is
    /// larger than allowed. Captures a queued or running job needs are
    /// skipped, and their bytes still count; the newest finished capture is
    /// always kept (the one a user is looking at, even when it alone is
    /// larger than the limit).
    pub fn retention_plan(&self, policy: &Retention) -> Result<Vec<i64>, StoreError> {
        if policy.max_age.is_none() && policy.max_bytes.is_none() {
            return Ok(Vec::new());
        }
        let mut finished: Vec<(i64, String)> = self.with(|c| {
            c.prepare("SELECT id, created_at FROM captures WHERE state NOT IN ('queued', 'running') ORDER BY id")?
                .query_map([], |r| Ok((r.get(0)?, r.get(1)?)))?
                .collect()
        })?;
        finished.pop();
        let cutoff = policy
            .max_age
            .and_then(|a| SystemTime::now().checked_sub(a))
            .map(timestamp);
        let mut excess = policy
            .max_bytes
            .map_or(0, |max| self.data_bytes().saturating_sub(max));
        let mut plan = Vec::new();
        for (id, created_at) in finished {
            let too_old = cutoff.as_ref().is_some_and(|c| created_at < *c);
            if !too_old && excess == 0 {
                continue;
            }
            let Ok(users) = self.deletable_capture(id, true) else {
                continue;
            };
            let bytes = dir_bytes(&self.capture_dir(id))
                + users
                    .iter()
                    .map(|r| dir_bytes(&self.reconstruction_dir(*r)))
                    .sum::<u64>();
            excess = excess.saturating_sub(bytes);
            plan.push(id);
        }
        Ok(plan)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::{CaptureRequest, ReconstructionRequest};

    fn request(dark_capture: Option<i64>) -> CaptureRequest {
        CaptureRequest {
            dark_capture,
            ..CaptureRequest::example()
        }
    }

    /// A finished capture with `bytes` of files.
    fn done(store: &Store, bytes: usize, dark: Option<i64>) -> i64 {
        let id = store.insert_capture(&request(dark)).unwrap();
        let dir = store.capture_dir(id);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("mean.tiff"), vec![0u8; bytes]).unwrap();
        assert!(store.capture_running(id).unwrap());
        store
            .capture_done(
                id,
                "cam",
                "{}",
                crate::camera::FrameCounts::default(),
                crate::measure::Clipping::default(),
            )
            .unwrap();
        id
    }

    #[test]
    fn the_oldest_finished_captures_go_until_the_data_fits() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let ids: Vec<i64> = (0..4).map(|_| done(&store, 1000, None)).collect();
        assert_eq!(store.data_bytes(), 4000);
        // The newest is kept even when it alone is too large.
        assert_eq!(
            store
                .retention_plan(&Retention {
                    max_age: None,
                    max_bytes: Some(10)
                })
                .unwrap(),
            ids[..3]
        );
        // No policy: nothing.
        assert!(store
            .retention_plan(&Retention::default())
            .unwrap()
            .is_empty());
        let fit = |max| Retention {
            max_age: None,
            max_bytes: Some(max),
        };
        assert!(store.retention_plan(&fit(4000)).unwrap().is_empty());
        assert_eq!(store.retention_plan(&fit(3999)).unwrap(), vec![ids[0]]);
        assert_eq!(
            store.retention_plan(&fit(1500)).unwrap(),
            vec![ids[0], ids[1], ids[2]]
        );
        // Capture 1 feeds a queued reconstruction: it stays, the next goes.
        let r = store
            .insert_reconstruction(&ReconstructionRequest {
                scene: "brewster-crossed".into(),
                captures: vec![ids[0]],
                params: crate::store::ReconstructionParams::default(),
            })
            .unwrap();
        assert_eq!(store.retention_plan(&fit(3999)).unwrap(), vec![ids[1]]);
        // A queued capture that subtracts capture 2 as its dark keeps it too.
        store.insert_capture(&request(Some(ids[1]))).unwrap();
        assert_eq!(store.retention_plan(&fit(3999)).unwrap(), vec![ids[2]]);
        // Once the reconstruction is finished, capture 1 goes with it.
        store.reconstruction_failed(r, "test").unwrap();
        assert_eq!(store.retention_plan(&fit(3999)).unwrap(), vec![ids[0]]);
    }

    #[test]
    fn captures_older_than_the_age_go_younger_ones_stay() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let old = done(&store, 10, None);
        let young = done(&store, 10, None);
        let newest = done(&store, 10, None);
        let back = timestamp(SystemTime::now() - Duration::from_secs(3 * 86_400));
        let age = |id: i64| {
            store
                .with(|c| {
                    c.execute(
                        "UPDATE captures SET created_at = ?1 WHERE id = ?2",
                        rusqlite::params![back, id],
                    )
                })
                .unwrap()
        };
        age(old);
        let two_days = Retention {
            max_age: Some(Duration::from_secs(2 * 86_400)),
            max_bytes: None,
        };
        assert_eq!(store.retention_plan(&two_days).unwrap(), vec![old]);
        // Even too old, the newest finished capture stays; a young one stays.
        age(newest);
        assert_eq!(store.retention_plan(&two_days).unwrap(), vec![old]);
        assert!(young > old);
    }
}
