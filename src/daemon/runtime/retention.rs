//! Deleting captures and reconstructions: on a client's request, and by the
//! retention policy of the config, applied every `check_every_s` seconds.
//! Each deletion is announced on the event stream, so every open page drops
//! the row it shows.

use std::sync::Arc;
use std::time::Duration;

use super::config::RetentionConfig;
use super::events::Events;
use crate::daemon::Event;
use crate::store::{Store, StoreError};

/// Deletes capture `id` (with the reconstructions using it when asked) and
/// announces each row deleted, with `reason` (`request` or `retention`).
pub(in crate::daemon) fn delete_capture(
    store: &Store,
    events: &Events,
    id: i64,
    with_reconstructions: bool,
    reason: &'static str,
) -> Result<Vec<i64>, StoreError> {
    let reconstructions = store.delete_capture(id, with_reconstructions)?;
    for &r in &reconstructions {
        events.emit(Event::Deleted {
            kind: "reconstruction",
            id: r,
            reason,
        });
    }
    events.emit(Event::Deleted {
        kind: "capture",
        id,
        reason,
    });
    Ok(reconstructions)
}

/// Applies the retention policy once: deletes what
/// [`crate::store::Store::retention_plan`] names; returns the captures
/// deleted. A capture a job took meanwhile is skipped, not an error.
fn apply(
    store: &Store,
    events: &Events,
    retention: &RetentionConfig,
) -> Result<Vec<i64>, StoreError> {
    let plan = store.retention_plan(&retention.policy())?;
    let mut deleted = Vec::with_capacity(plan.len());
    for id in plan {
        match delete_capture(store, events, id, true, "retention") {
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

/// Applies the retention policy now and then every `check_every_s`, while
/// the daemon runs; does nothing when no limit is set.
pub(in crate::daemon) async fn retention_task(
    store: Arc<Store>,
    events: Events,
    retention: RetentionConfig,
) {
    let policy = retention.policy();
    if policy.max_age.is_none() && policy.max_bytes.is_none() {
        return;
    }
    let every = Duration::from_secs_f64(retention.check_every_s);
    let retention = Arc::new(retention);
    loop {
        let (s, e, r) = (store.clone(), events.clone(), retention.clone());
        match tokio::task::spawn_blocking(move || apply(&s, &e, &r)).await {
            Ok(Ok(_)) => {}
            Ok(Err(e)) => tracing::error!("retention: {}", store.describe(&e)),
            Err(e) => tracing::error!("retention: {e}"),
        }
        tokio::time::sleep(every).await;
    }
}
