//! [`ReadAhead`]: batches built on a thread of their own, ahead of the reader, in a queue
//! bounded in bytes. A timeline table's scan builds the later parts of its index range
//! this way while the reader's own thread builds the first, and reads the parts in order:
//! the rows stay in index order (the table's promise), and the parts are built side by
//! side.

use std::collections::VecDeque;
use std::sync::Arc;

use arrow_array::RecordBatch;
use arrow_schema::ArrowError;
use parking_lot::{Condvar, Mutex};

/// How many bytes of built batches one part may hold ahead of the reader before its
/// thread waits. A part's first batch is always taken, however large.
pub(crate) const READ_AHEAD_BYTES: usize = 64 << 20;

type Item = Result<RecordBatch, ArrowError>;

#[derive(Default)]
struct Queue {
    /// Built and not yet read, with their sizes.
    batches: VecDeque<(Item, usize)>,
    bytes: usize,
    /// The builder is done (or stopped: see `failed`).
    finished: bool,
    /// The builder's thread panicked: the part is incomplete.
    failed: bool,
    /// The reader is gone: the builder stops at its next batch.
    abandoned: bool,
}

#[derive(Default)]
struct Shared {
    queue: Mutex<Queue>,
    changed: Condvar,
}

/// The reading end of a part built on its own thread: the part's batches, in order.
/// Dropping it stops the builder at its next batch.
pub(crate) struct ReadAhead {
    shared: Arc<Shared>,
}

impl ReadAhead {
    /// Starts a new thread that makes the batches (`make`, so that their setup is done
    /// there too) and builds them, at most `limit_bytes` ahead of the reader.
    ///
    /// # Errors
    /// The thread could not be started.
    pub(crate) fn spawn<I: Iterator<Item = Item>>(
        make: impl FnOnce() -> I + Send + 'static,
        limit_bytes: usize,
    ) -> std::io::Result<Self> {
        let shared = Arc::new(Shared::default());
        let builder = Arc::clone(&shared);
        std::thread::Builder::new()
            .name("chunkstore-scan".to_owned())
            .spawn(move || build(&builder, make, limit_bytes))?;
        Ok(Self { shared })
    }
}

fn build<I: Iterator<Item = Item>>(shared: &Shared, make: impl FnOnce() -> I, limit_bytes: usize) {
    /// Marks the part finished however the builder leaves, as failed if by a panic, so
    /// that the reader never waits forever nor takes a cut part for a whole one.
    struct Finish<'a>(&'a Shared);
    impl Drop for Finish<'_> {
        fn drop(&mut self) {
            let mut queue = self.0.queue.lock();
            queue.finished = true;
            queue.failed = std::thread::panicking();
            self.0.changed.notify_all();
        }
    }
    let _finish = Finish(shared);
    for item in make() {
        let size = item.as_ref().map_or(0, RecordBatch::get_array_memory_size);
        let mut queue = shared.queue.lock();
        while !queue.abandoned && queue.bytes > 0 && queue.bytes + size > limit_bytes {
            shared.changed.wait(&mut queue);
        }
        if queue.abandoned {
            return;
        }
        queue.bytes += size;
        queue.batches.push_back((item, size));
        shared.changed.notify_all();
    }
}

impl Iterator for ReadAhead {
    type Item = Item;

    fn next(&mut self) -> Option<Item> {
        let mut queue = self.shared.queue.lock();
        loop {
            if let Some((item, size)) = queue.batches.pop_front() {
                queue.bytes -= size;
                self.shared.changed.notify_all();
                return Some(item);
            }
            if queue.finished {
                if queue.failed {
                    queue.failed = false; // reported once
                    return Some(Err(ArrowError::ComputeError(
                        "a scan's builder thread panicked".to_owned(),
                    )));
                }
                return None;
            }
            self.shared.changed.wait(&mut queue);
        }
    }
}

impl Drop for ReadAhead {
    fn drop(&mut self) {
        let mut queue = self.shared.queue.lock();
        queue.abandoned = true;
        queue.batches.clear();
        queue.bytes = 0;
        self.shared.changed.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};

    use arrow_array::{Int64Array, RecordBatch};
    use arrow_schema::ArrowError;

    use super::ReadAhead;

    fn batch(value: i64) -> RecordBatch {
        RecordBatch::try_from_iter([(
            "x",
            Arc::new(Int64Array::from(vec![value; 100])) as arrow_array::ArrayRef,
        )])
        .unwrap()
    }

    fn values(batches: impl Iterator<Item = Result<RecordBatch, ArrowError>>) -> Vec<i64> {
        batches
            .map(|b| {
                b.unwrap()
                    .column(0)
                    .as_any()
                    .downcast_ref::<Int64Array>()
                    .unwrap()
                    .value(0)
            })
            .collect()
    }

    #[test]
    fn batches_arrive_in_order_whatever_the_bound() {
        for limit in [0, 1, 1 << 30] {
            let ahead = ReadAhead::spawn(|| (0..50).map(|i| Ok(batch(i))), limit).unwrap();
            assert_eq!(values(ahead), (0..50).collect::<Vec<_>>(), "limit {limit}");
        }
    }

    #[test]
    fn the_builder_waits_at_the_bound_and_stops_when_the_reader_goes() {
        let built = Arc::new(AtomicUsize::new(0));
        let counter = Arc::clone(&built);
        let size = batch(0).get_array_memory_size();
        let source = (0..1_000).map(move |i| {
            counter.fetch_add(1, Ordering::SeqCst);
            Ok(batch(i))
        });
        let mut ahead = ReadAhead::spawn(|| source, 3 * size).unwrap();
        assert_eq!(ahead.next().unwrap().unwrap().num_rows(), 100);
        std::thread::sleep(std::time::Duration::from_millis(50));
        // Three held, one read, one built and waiting for room.
        assert!(built.load(Ordering::SeqCst) <= 5, "{built:?}");
        drop(ahead);
        std::thread::sleep(std::time::Duration::from_millis(50));
        assert!(built.load(Ordering::SeqCst) <= 6, "{built:?}");
    }

    #[test]
    fn a_panicking_builder_is_an_error_not_a_short_answer() {
        let source = (0..3).map(|i| {
            assert!(i < 2, "a bug in the builder");
            Ok(batch(i))
        });
        let results: Vec<_> = ReadAhead::spawn(|| source, 1 << 20).unwrap().collect();
        assert_eq!(results.len(), 3);
        assert!(results[0].is_ok() && results[1].is_ok());
        assert!(results[2].is_err());
    }
}
