//! A dataset's dataframe: each segment's own dataframe (SEMANTICS.md section 9, fill within
//! the segment), its segment id prepended, its columns placed in the dataset's table, the
//! segments one after another in id order.
//!
//! The table's columns are the union of the segments' (planned once, before the first
//! row: a stream's schema comes first), in the order a dataframe orders its columns: the
//! segment id, then the index and every other timeline by name, then the data columns by
//! entity (part by part, in natural order) and component. A column a segment lacks is
//! null in its rows. Planning loads each segment whose data is on the index (a segment
//! without it gives no rows, as a dataframe of it would be refused, and is never loaded),
//! but one of the shape of a segment planned before it (by their footers): that one's
//! schema is its. What planning read is kept for the rows' pass only for the segments
//! the rows start with.

use std::collections::{BTreeSet, HashMap, VecDeque};
use std::sync::Arc;
use std::sync::atomic::AtomicU64;
use std::sync::mpsc;

use arrow_array::{RecordBatch, RecordBatchReader};
use arrow_schema::{ArrowError, SchemaRef};
use parking_lot::Mutex;

use super::schema::{ColumnKey, Placed, SchemaUnion, project};
use super::{Dataset, DatasetError, ReadStats};
use crate::{DataframeQuery, DataframeStream};

impl Dataset {
    /// The dataframe of every segment on `query`'s index, as one table: see the module
    /// docs of `dataset/stream.rs`. The columns [`DataframeQuery::with_columns`] names are
    /// names of this table (the segment id column is always first).
    ///
    /// # Errors
    /// An index no segment has, a column two segments give different types, a column
    /// named that the table does not have, a segment that cannot be loaded (unless
    /// skipped, [`DatasetOptions::skip_bad`](super::DatasetOptions::skip_bad)).
    pub fn dataframe(&self, query: &DataframeQuery) -> Result<DatasetStream, DatasetError> {
        let (schema, segments) = self.plan_dataframe(query)?;
        Ok(self.stream_segments(schema, segments, self.read_threads()))
    }

    /// The table [`Dataset::dataframe`] streams for `query`, and the segments that give
    /// its rows (by number, in id order), each with its own query and what planning kept
    /// of it: for [`Dataset::stream_segments`].
    pub(crate) fn plan_dataframe(
        &self,
        query: &DataframeQuery,
    ) -> Result<PlannedRows, DatasetError> {
        let index = query.index();
        let with_index: Vec<usize> = (0..self.segments().len())
            .filter(|&n| self.segments()[n].time_type(index).is_some())
            .collect();
        if with_index.is_empty() {
            return Err(self.unknown_index_error(index));
        }
        let full = query.clone().without_columns();
        // Segments are planned on several threads. What planning read is kept for the
        // rows' pass only for the segments the stream starts with (as many as it loads at
        // once), while it fits the budget (`Dataset::segment_for`); the others' planning
        // reads only their columns' chunks and frees them at once. Holding every planned
        // segment that fits the budget until its rows are streamed was slower, not
        // faster: a hundred segments' chunks (60 MB) took fresh pages the kernel faulted
        // in and zeroed (19,000 page faults; 3,600 now), where reading the rows again
        // from the page cache into freed memory costs less (docs/PERFORMANCE.md,
        // "Datasets"). With the default budget, a quarter of the machine's memory, a
        // wide table of those hundred segments held 1.4 GB.
        let threads = self.read_threads();
        let room = AtomicU64::new(self.options().memory_budget);
        let no_room = AtomicU64::new(0);
        let positions: Vec<(usize, usize)> = with_index.iter().copied().enumerate().collect();
        let plan = |&(position, number): &(usize, usize)| {
            let segment_id = &self.segments()[number].id;
            let room = if position < threads { &room } else { &no_room };
            let super::SegmentRead { snapshot, keep, .. } =
                match self.segment_for(number, &full, Some(room)) {
                    Ok(read) => read,
                    Err(error) if self.options().skip_bad => {
                        self.warn(format!("skipped segment {segment_id:?}: {error}"));
                        return Ok(None);
                    }
                    Err(error) => return Err(error),
                };
            let schema =
                snapshot
                    .dataframe_schema(&full)
                    .map_err(|error| DatasetError::Dataframe {
                        segment: segment_id.clone(),
                        error,
                    })?;
            Ok(Some((schema, keep.then_some(snapshot))))
        };
        // A segment of the same shape as one planned before it (the same columns, by the
        // manifests, on the same timelines) has its schema: it is not read for planning
        // unless its read is kept for the rows. In a bucket, that read was a GET per
        // segment (half of a range's), for a chunk the rows seldom need; so there even the
        // first segments are not read to be kept: with 64 read at once, keeping theirs
        // fetched 6% more than the range needs.
        let keeps_first = if self.in_object_store() { 0 } else { threads };
        let same_as: Vec<Option<usize>> = self
            .shapes(&with_index)
            .into_iter()
            .enumerate()
            .map(|(position, first)| {
                first.filter(|&first| first != position && position >= keeps_first)
            })
            .collect();
        let read: Vec<(usize, usize)> = positions
            .iter()
            .copied()
            .filter(|&(position, _)| same_as[position].is_none())
            .collect();
        let mut plans: Vec<Option<PlannedSegment>> = vec![None; positions.len()];
        for (&(position, _), planned) in read
            .iter()
            .zip(super::threads::in_parallel(&read, threads, plan))
        {
            plans[position] = Some(planned?);
        }
        let mut union = SchemaUnion::default();
        let mut planned = Vec::with_capacity(positions.len());
        for &(position, number) in &positions {
            // Of the shape of an earlier segment: its schema, nothing kept.
            let first_schema = same_as[position]
                .and_then(|first| plans[first].as_ref()?.as_ref())
                .map(|(schema, _)| (Arc::clone(schema), None));
            let plan = match (&plans[position], first_schema) {
                (Some(plan), _) => plan.clone(),
                (None, Some(reused)) => Some(reused),
                // Its shape's first gave nothing (skipped: only `skip_bad` skips, and it
                // reads segments whole, which have no shape): read after all.
                (None, None) => plan(&(position, number))?,
            };
            if let Some((schema, kept)) = plan {
                union.add(&self.segments()[number].id, &schema)?;
                planned.push((number, schema, kept));
            }
        }
        let table = union.schema();
        let schema = match query.columns() {
            None => table,
            Some(names) => project(&table, names)?,
        };
        // Each segment's query asks for the output's columns it has (its rows stay its
        // whole view's).
        let segments = planned
            .into_iter()
            .map(|(number, own, kept)| {
                let columns: Vec<String> = schema
                    .fields()
                    .iter()
                    .skip(1)
                    .filter(|f| own.field_with_name(f.name()).is_ok())
                    .map(|f| f.name().clone())
                    .collect();
                (number, full.clone().with_columns(columns), kept)
            })
            .collect();
        Ok((schema, segments))
    }

    /// The shapes of these segments (by number), in their order, each given as the
    /// position in `numbers` of the first segment of that shape (so that only the
    /// distinct shapes are held);
    /// `None` for a segment read whole or whose footer cannot be read
    /// ([`Dataset::column_keys`]).
    fn shapes(&self, numbers: &[usize]) -> Vec<Option<usize>> {
        // Each distinct shape: its id, and the least position of a segment of it.
        let distinct: Mutex<HashMap<Shape, (usize, usize)>> = Mutex::default();
        let positions: Vec<usize> = (0..numbers.len()).collect();
        let ids = super::threads::in_parallel(&positions, self.options().threads, |&at| {
            let number = numbers[at];
            let timelines = self.segments()[number]
                .timelines
                .iter()
                .map(|(t, _)| (t.name().to_owned(), t.time_type()))
                .collect();
            let shape: Shape = (self.columns_of(number)?.into_iter().collect(), timelines);
            let mut distinct = distinct.lock();
            let next_id = distinct.len();
            let (id, least) = distinct.entry(shape).or_insert((next_id, at));
            *least = (*least).min(at);
            Some(*id)
        });
        let mut least_of = vec![0; distinct.lock().len()];
        for (id, least) in distinct.into_inner().into_values() {
            least_of[id] = least;
        }
        ids.into_iter()
            .map(|id| id.map(|id| least_of[id]))
            .collect()
    }

    /// The rows of these segments (by number, each with its own query, and what planning
    /// kept of it) in `schema` (the segment id first, then columns of the dataset's
    /// table), loading up to `threads` segments at once.
    pub(crate) fn stream_segments(
        &self,
        schema: SchemaRef,
        segments: Vec<(usize, DataframeQuery, Option<crate::Snapshot>)>,
        threads: usize,
    ) -> DatasetStream {
        DatasetStream {
            dataset: self.clone(),
            schema,
            segments,
            threads: threads.max(1),
            next: 0,
            current: None,
            current_bytes: 0,
            ahead: VecDeque::new(),
            loaders: None,
            read: ReadStats::default(),
        }
    }

    pub(super) fn warn(&self, warning: String) {
        self.inner.warnings.lock().push(warning);
    }
}

/// The rows of a [`Dataset::dataframe`]: record batches of one segment each, in segment
/// order. A segment that fails to load while streaming (its file changed or vanished
/// since the dataset opened) is an error naming it, or with `skip_bad` skipped with a
/// warning.
pub struct DatasetStream {
    dataset: Dataset,
    schema: SchemaRef,
    /// The segments that give rows (by number), with each one's own query, and what
    /// planning read of it if that was kept.
    segments: Vec<(usize, DataframeQuery, Option<crate::Snapshot>)>,
    /// Segments loaded at once: the one streamed and those loaded ahead.
    threads: usize,
    next: usize,
    /// The segment being streamed: its id as a column value, and its stream.
    current: Option<Placed<DataframeStream<'static>>>,
    /// The heap bytes of the store `current` streams from.
    current_bytes: u64,
    /// The next segments' loads, on threads of their own while this one streams (one fewer
    /// than `threads`), by position.
    ahead: VecDeque<(usize, mpsc::Receiver<LoadResult>)>,
    /// The threads that load ahead, started with the first load ahead.
    loaders: Option<Loaders>,
    /// What its loads read from the files.
    read: ReadStats,
}

/// What planning learnt of a segment: its schema, and its read if kept for the rows.
type PlannedSegment = Option<(SchemaRef, Option<crate::Snapshot>)>;

/// A segment's shape: the columns its manifest names and its timelines. Two segments of
/// one shape have one dataframe schema for any query (when their columns' types agree).
type Shape = (BTreeSet<ColumnKey>, Vec<(String, crate::TimeType)>);

/// A dataframe's table and the segments that give its rows: [`Dataset::plan_dataframe`].
pub(crate) type PlannedRows = (
    SchemaRef,
    Vec<(usize, DataframeQuery, Option<crate::Snapshot>)>,
);

/// A segment's store for the rows, and what reading it read.
type Loaded = Result<(crate::Snapshot, ReadStats), DatasetError>;

/// The stream of `query`'s rows in what was read of segment `segment`: of the columns
/// `query` names, those the store holds (what was read for the rows alone may lack a
/// column, which holds no cell in the rows); `None` if it holds nothing on the index.
fn rows_of(
    snapshot: crate::Snapshot,
    query: &DataframeQuery,
    segment: &str,
) -> Result<Option<DataframeStream<'static>>, DatasetError> {
    let failed = |error| DatasetError::Dataframe {
        segment: segment.to_owned(),
        error,
    };
    let every_column = query.clone().without_columns();
    let own = match snapshot.dataframe_schema(&every_column) {
        Ok(own) => own,
        Err(crate::DataframeError::UnknownIndex(_)) => return Ok(None),
        Err(error) => return Err(failed(error)),
    };
    let present: Vec<String> = query
        .columns()
        .unwrap_or_default()
        .iter()
        .filter(|name| own.field_with_name(name).is_ok())
        .cloned()
        .collect();
    snapshot
        .into_dataframe(&every_column.with_columns(present))
        .map(Some)
        .map_err(failed)
}

/// What segment `number` holds for `query`'s rows, read here (in this thread).
fn load_rows(dataset: &Dataset, number: usize, query: &DataframeQuery) -> Loaded {
    dataset
        .segment_for(number, query, None)
        .map(|read| (read.snapshot, read.read))
}

/// The largest segment (heap bytes) kept while the next one loads (see
/// [`DatasetStream`]'s `next`).
const KEEP_DONE_SEGMENT_BYTES: u64 = 8 << 20;

/// A load ahead's segment, or the panic that ended it.
type LoadResult = std::thread::Result<Loaded>;

/// A segment to load ahead: its number, its query, and where its load goes.
type LoadJob = (usize, DataframeQuery, mpsc::Sender<LoadResult>);

/// The threads a stream loads segments ahead on, for as long as it lives: a thread per
/// segment cost more than its load (100 threads made and ended in a 0.06 s query: 4% of
/// its time in `clone`, and each new thread's memory was fresh pages again).
struct Loaders {
    jobs: mpsc::Sender<LoadJob>,
}

impl Loaders {
    /// `threads` threads loading segments of `dataset`; they end when the stream drops.
    fn start(dataset: &Dataset, threads: usize) -> Self {
        let (jobs, queue) = mpsc::channel::<LoadJob>();
        let queue = Arc::new(parking_lot::Mutex::new(queue));
        for _ in 0..threads {
            let (dataset, queue) = (dataset.clone(), Arc::clone(&queue));
            std::thread::spawn(move || {
                loop {
                    let job = queue.lock().recv();
                    let Ok((number, query, done)) = job else {
                        return; // the stream dropped
                    };
                    let loaded = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        load_rows(&dataset, number, &query)
                    }));
                    // A stream dropped before it took this load no longer wants it.
                    let _ = done.send(loaded);
                }
            });
        }
        Self { jobs }
    }

    /// Starts loading segment `number` for `query`; its load comes through the receiver.
    fn load(&self, number: usize, query: DataframeQuery) -> mpsc::Receiver<LoadResult> {
        let (done, loaded) = mpsc::channel();
        // The threads end only when `jobs` drops (were they gone, the receiver says so,
        // and the segment is loaded where it is wanted).
        let _ = self.jobs.send((number, query, done));
        loaded
    }
}

/// The segment a load ahead read, or its error (a panic there, a bug, goes on in this
/// thread); `None` if its loader ended without sending it.
fn taken(loaded: &mpsc::Receiver<LoadResult>) -> Option<Loaded> {
    match loaded.recv() {
        Ok(Ok(loaded)) => Some(loaded),
        Ok(Err(panic)) => std::panic::resume_unwind(panic),
        Err(mpsc::RecvError) => None,
    }
}

impl std::fmt::Debug for DatasetStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DatasetStream")
            .field("segments", &self.segments.len())
            .field("next", &self.next)
            .finish_non_exhaustive()
    }
}

impl DatasetStream {
    /// The table's schema.
    pub fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }

    /// Segments that give rows (those whose data is on the index).
    pub fn num_segments(&self) -> usize {
        self.segments.len()
    }

    /// What the stream has read from the dataset's files so far.
    pub fn read_stats(&self) -> ReadStats {
        self.read
    }

    /// Starts loading, on the stream's loader threads, the segments after `position` that
    /// planning did not keep, up to one fewer than the dataset's threads.
    fn load_ahead(&mut self, position: usize) {
        let end = (position + self.threads).min(self.segments.len());
        for ahead in position + 1..end {
            let (number, query, kept) = &self.segments[ahead];
            if kept.is_some() || self.ahead.iter().any(|(p, _)| *p == ahead) {
                continue;
            }
            let (number, query) = (*number, query.clone());
            let loaders = self
                .loaders
                .get_or_insert_with(|| Loaders::start(&self.dataset, self.threads - 1));
            self.ahead.push_back((ahead, loaders.load(number, query)));
        }
    }

    /// Starts the next segment's stream; `Ok(false)` when there is none.
    fn start_next(&mut self) -> Result<bool, DatasetError> {
        loop {
            let position = self.next;
            if position >= self.segments.len() {
                return Ok(false);
            }
            self.next += 1;
            self.load_ahead(position);
            let loaded_ahead = match self.ahead.front() {
                Some((p, _)) if *p == position => self.ahead.pop_front().map(|(_, h)| h),
                _ => None,
            };
            let (number, query, kept) = &mut self.segments[position];
            let number = *number;
            let id = self.dataset.segments()[number].id.clone();
            let loaded = match (kept.take(), loaded_ahead.as_ref().and_then(taken)) {
                (Some(snapshot), _) => Ok((snapshot, ReadStats::default())),
                (None, Some(loaded)) => loaded,
                (None, None) => load_rows(&self.dataset, number, query),
            };
            let snapshot = loaded.map(|(snapshot, read)| {
                self.read.add(read);
                self.current_bytes = snapshot.stats().heap_bytes;
                snapshot
            });
            let query = &self.segments[position].1;
            let started = snapshot.and_then(|snapshot| rows_of(snapshot, query, &id));
            match started {
                Ok(Some(stream)) => {
                    self.current = Some(Placed::new(stream, Arc::clone(&self.schema), id.into()));
                    return Ok(true);
                }
                Ok(None) => {} // nothing on the index: no rows
                Err(error) if self.dataset.options().skip_bad => {
                    self.dataset
                        .warn(format!("skipped segment {id:?}: {error}"));
                }
                Err(error) => return Err(error),
            }
        }
    }
}

impl Iterator for DatasetStream {
    type Item = Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            // A segment's stream, once done, is dropped only when the next segment is
            // loaded: freed first, its memory at the heap's top went back to the kernel
            // (glibc trims a free top past its threshold) and the next load faulted it in
            // again (a scan of 1,000 segments: 80,000 page faults, 6,000 this way).
            if let Some(batch) = self.current.as_mut().and_then(Iterator::next) {
                return Some(batch);
            }
            // A large segment is freed before the next loads: held, two of them were in
            // memory at once (image recordings of 37 MB doubled a scan's peak), and memory
            // that large is mapped and unmapped whole, never at the heap's top.
            if self.current_bytes > KEEP_DONE_SEGMENT_BYTES {
                self.current = None;
            }
            match self.start_next() {
                Ok(true) => {}
                Ok(false) => {
                    self.current = None; // the last segment's memory, not kept past the end
                    return None;
                }
                Err(error) => return Some(Err(ArrowError::ExternalError(Box::new(error)))),
            }
        }
    }
}

impl RecordBatchReader for DatasetStream {
    fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }
}
