//! The job queues: bounded channels of job ids, refused at once when full
//! (HTTP 429), and for captures the disk each queued capture reserved and
//! the progressive reconstruction it asked for; and why a job was not
//! queued ([`SubmitError`]), which admission answers with.

use std::collections::BTreeMap;
use std::sync::Mutex;

use tokio::sync::mpsc;

use crate::daemon::requests::validate::{ProgressiveSpec, RequestError};

/// Why a request was not queued.
#[derive(Debug, thiserror::Error)]
pub enum SubmitError {
    /// The request itself is wrong (404, 422) or needs the camera (503).
    #[error(transparent)]
    Request(#[from] RequestError),
    /// Its files would not fit on the disk (HTTP 507).
    #[error("this capture needs {} MiB of disk, but the data directory has {} MiB free, of which queued captures reserve {} MiB and {} MiB are kept free ([queue] reserve_free_mib); take fewer frames or a smaller region, or free disk space", mib(*.need), mib(*.free), mib(*.held), mib(*.keep))]
    Disk {
        /// Bytes its files take at most.
        need: u64,
        /// Bytes free now.
        free: u64,
        /// Bytes reserved by queued captures.
        held: u64,
        /// Bytes kept free.
        keep: u64,
    },
    /// The queue is full (HTTP 429).
    #[error("the {queue} queue is full; retry after {retry_after} s")]
    QueueFull {
        /// `capture` or `reconstruction`.
        queue: &'static str,
        /// Seconds to wait.
        retry_after: u64,
    },
    /// The catalogue could not record it, or validation did not finish.
    #[error("{0}")]
    Internal(String),
}

fn mib(bytes: u64) -> String {
    format!("{:.1}", bytes as f64 / (1u64 << 20) as f64)
}

/// A bounded queue of job ids for one kind of worker; a clone pushes to
/// the same queue.
#[derive(Debug, Clone)]
pub(crate) struct Queue {
    /// `capture` or `reconstruction`, for the 429's text.
    name: &'static str,
    tx: mpsc::Sender<i64>,
}

impl Queue {
    /// A queue of at most `capacity` jobs, and the receiving end for its workers.
    pub(crate) fn new(name: &'static str, capacity: usize) -> (Self, mpsc::Receiver<i64>) {
        let (tx, rx) = mpsc::channel(capacity);
        (Self { name, tx }, rx)
    }

    /// Jobs waiting.
    pub(crate) fn depth(&self) -> usize {
        self.tx.max_capacity() - self.tx.capacity()
    }

    /// Queues the job `insert` records, if there is room: the room is taken
    /// first, so a full queue records nothing.
    pub(crate) fn push(
        &self,
        retry_after: u64,
        insert: impl FnOnce() -> Result<i64, SubmitError>,
    ) -> Result<i64, SubmitError> {
        let permit = self.tx.try_reserve().map_err(|_| SubmitError::QueueFull {
            queue: self.name,
            retry_after,
        })?;
        let id = insert()?;
        permit.send(id);
        Ok(id)
    }
}

/// The capture queue, with the disk bytes each queued or running capture
/// reserved and the progressive reconstructions asked for with them.
#[derive(Debug)]
pub(crate) struct CaptureQueue {
    queue: Queue,
    /// Disk bytes reserved by queued and running captures, by capture id.
    reserved: Mutex<BTreeMap<i64, u64>>,
    /// Progressive reconstructions asked for with queued captures, by capture id.
    progressive: Mutex<BTreeMap<i64, ProgressiveSpec>>,
}

/// The disk a capture asks for, against what there is.
#[derive(Debug, Clone, Copy)]
pub(crate) struct DiskNeed {
    /// Bytes its files take at most.
    pub need: u64,
    /// Bytes free on the data directory's disk now.
    pub free: u64,
    /// Bytes kept free whatever is queued.
    pub keep: u64,
}

impl CaptureQueue {
    /// A queue of at most `capacity` captures, and its receiving end.
    pub(crate) fn new(capacity: usize) -> (Self, mpsc::Receiver<i64>) {
        let (queue, rx) = Queue::new("capture", capacity);
        let q = Self {
            queue,
            reserved: Mutex::new(BTreeMap::new()),
            progressive: Mutex::new(BTreeMap::new()),
        };
        (q, rx)
    }

    /// Captures waiting.
    pub(crate) fn depth(&self) -> usize {
        self.queue.depth()
    }

    /// Queues the capture `insert` records when its files fit beside what
    /// queued captures reserved and the kept reserve, and the queue has
    /// room; reserves its disk until [`CaptureQueue::release`].
    pub(crate) fn push(
        &self,
        disk: DiskNeed,
        retry_after: u64,
        progressive: Option<ProgressiveSpec>,
        insert: impl FnOnce() -> Result<i64, SubmitError>,
    ) -> Result<i64, SubmitError> {
        // Held across the check and the insert: two requests cannot both
        // count the same free bytes.
        let mut reserved = self.reserved.lock().unwrap_or_else(|e| e.into_inner());
        fits(&reserved, disk)?;
        // The reservation and the progressive spec are recorded before the
        // id is sent: the worker may take the job at once, and it reads the
        // spec when it starts and releases the reservation when it ends
        // (recorded after the send, a capture that started first ran
        // without the progressive steps it asked for, and a reservation
        // could outlive its capture).
        let specs = &self.progressive;
        self.queue.push(retry_after, || {
            let id = insert()?;
            reserved.insert(id, disk.need);
            if let Some(p) = progressive {
                specs
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .insert(id, p);
            }
            Ok(id)
        })
    }

    /// Records the capture `insert` records without queueing it (a live
    /// session's recording, which the live view writes), when its files fit
    /// as [`CaptureQueue::push`]'s do; reserves its disk until
    /// [`CaptureQueue::release`].
    pub(crate) fn reserve(
        &self,
        disk: DiskNeed,
        insert: impl FnOnce() -> Result<i64, SubmitError>,
    ) -> Result<i64, SubmitError> {
        let mut reserved = self.reserved.lock().unwrap_or_else(|e| e.into_inner());
        fits(&reserved, disk)?;
        let id = insert()?;
        reserved.insert(id, disk.need);
        Ok(id)
    }

    /// The progressive reconstruction capture `id` asked for, taken once.
    pub(crate) fn take_progressive(&self, id: i64) -> Option<ProgressiveSpec> {
        let mut specs = self.progressive.lock().unwrap_or_else(|e| e.into_inner());
        specs.remove(&id)
    }

    /// Frees the disk reservation of a capture that ended (or never started).
    pub(crate) fn release(&self, id: i64) {
        let mut reserved = self.reserved.lock().unwrap_or_else(|e| e.into_inner());
        reserved.remove(&id);
        let mut specs = self.progressive.lock().unwrap_or_else(|e| e.into_inner());
        specs.remove(&id);
    }
}

/// Whether `disk.need` fits beside what `reserved` holds and the kept reserve.
fn fits(reserved: &BTreeMap<i64, u64>, disk: DiskNeed) -> Result<(), SubmitError> {
    let held: u64 = reserved.values().sum();
    if disk.need.saturating_add(held).saturating_add(disk.keep) > disk.free {
        return Err(SubmitError::Disk {
            need: disk.need,
            free: disk.free,
            held,
            keep: disk.keep,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_queue_records_nothing_and_reservations_count_against_the_disk() {
        let (q, mut rx) = CaptureQueue::new(2);
        let disk = DiskNeed {
            need: 40,
            free: 100,
            keep: 10,
        };
        let next = std::cell::Cell::new(0);
        let insert = || {
            next.set(next.get() + 1);
            Ok(next.get())
        };
        assert_eq!(q.push(disk, 1, None, insert).unwrap(), 1);
        // 40 held + 40 + 10 kept = 90 <= 100.
        assert_eq!(q.push(disk, 1, None, insert).unwrap(), 2);
        assert_eq!(q.depth(), 2);
        // 80 held + 40 + 10 > 100: refused for disk before the queue is asked.
        match q.push(disk, 1, None, insert) {
            Err(SubmitError::Disk { held: 80, .. }) => {}
            other => panic!("{other:?}"),
        }
        q.release(1);
        // Room on the disk again, but the queue holds two: refused, nothing recorded.
        match q.push(disk, 7, None, insert) {
            Err(SubmitError::QueueFull {
                queue: "capture",
                retry_after: 7,
            }) => {}
            other => panic!("{other:?}"),
        }
        assert_eq!(next.get(), 2);
        assert_eq!(rx.try_recv().unwrap(), 1);
        assert_eq!(q.push(disk, 1, None, insert).unwrap(), 3);
        // A recording reserves beside them without a place in the queue:
        // 80 held + 40 + 10 > 100 refused, then one fits once one is released.
        assert!(matches!(
            q.reserve(disk, insert),
            Err(SubmitError::Disk { held: 80, .. })
        ));
        q.release(2);
        assert_eq!(q.reserve(disk, insert).unwrap(), 4);
        assert_eq!(q.depth(), 2, "not queued");
        assert!(matches!(
            q.push(disk, 1, None, insert),
            Err(SubmitError::Disk { held: 80, .. })
        ));
    }
}
