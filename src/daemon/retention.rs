//! Deleting captures and reconstructions: on a client's request, and by the
//! retention policy of the config, applied every `check_every_s` seconds.
//! Each deletion is announced on the event stream, so every open page drops
//! the row it shows.

use std::sync::Arc;
use std::time::Duration;

use super::{Daemon, Event};
use crate::store::StoreError;

impl Daemon {
    /// Deletes capture `id` (and, with `with_reconstructions`, the
    /// reconstructions that use it); returns those reconstructions.
    pub fn delete_capture(
        &self,
        id: i64,
        with_reconstructions: bool,
        reason: &'static str,
    ) -> Result<Vec<i64>, StoreError> {
        let reconstructions = self.store.delete_capture(id, with_reconstructions)?;
        for &r in &reconstructions {
            self.emit(Event::Deleted {
                kind: "reconstruction",
                id: r,
                reason,
            });
        }
        self.emit(Event::Deleted {
            kind: "capture",
            id,
            reason,
        });
        Ok(reconstructions)
    }

    /// Deletes reconstruction `id`.
    pub fn delete_reconstruction(&self, id: i64) -> Result<(), StoreError> {
        self.store.delete_reconstruction(id)?;
        self.emit(Event::Deleted {
            kind: "reconstruction",
            id,
            reason: "request",
        });
        Ok(())
    }

    /// Applies the retention policy once: deletes what
    /// [`crate::store::Store::retention_plan`] names; returns the captures
    /// deleted. A capture a job took meanwhile is skipped, not an error.
    pub fn apply_retention(&self) -> Result<Vec<i64>, StoreError> {
        let plan = self.store.retention_plan(&self.config.retention.policy())?;
        let mut deleted = Vec::with_capacity(plan.len());
        for id in plan {
            match self.delete_capture(id, true, "retention") {
                Ok(with) => {
                    tracing::info!(
                        "retention: deleted capture {id} and {} reconstruction(s) using it",
                        with.len()
                    );
                    deleted.push(id);
                }
                Err(e @ StoreError::InUse { .. }) => tracing::debug!("retention: {e}"),
                Err(e) => return Err(e),
            }
        }
        Ok(deleted)
    }
}

/// Applies the retention policy now and then every `check_every_s`, while
/// the daemon runs; does nothing when no limit is set.
pub(super) async fn retention_task(d: Arc<Daemon>) {
    let policy = d.config.retention.policy();
    if policy.max_age.is_none() && policy.max_bytes.is_none() {
        return;
    }
    let every = Duration::from_secs_f64(d.config.retention.check_every_s);
    loop {
        let d2 = d.clone();
        match tokio::task::spawn_blocking(move || d2.apply_retention()).await {
            Ok(Ok(_)) => {}
            Ok(Err(e)) => tracing::error!("retention: {}", d.store.describe(&e)),
            Err(e) => tracing::error!("retention: {e}"),
        }
        tokio::time::sleep(every).await;
    }
}
