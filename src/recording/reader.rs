//! [`RecordingReader`]: every read of a recording, answered from a store's view or lazily
//! from an `.rrd`'s footer, the same answers either way.

use crate::UnknownTimeline;
use crate::query::{LatestAtQuery, QueryCell, RangeQuery, RangeResult};
use crate::rrd::{LazyRecording, RrdError};
use crate::storage::Input;
use crate::{ComponentName, EntityPath, StoreView, TimeRange, TimeType, Timeline};

/// The reads of a recording: discovery (entities, components, timelines and their spans,
/// counts) and queries (latest-at, range). From [`Recording::reader`](super::Recording::reader),
/// or over any store's view ([`RecordingReader::view`]: a store, a snapshot).
///
/// A lazy recording decodes the chunks a query needs as it answers, so queries take
/// `&mut self` and can fail with the file's fault; over a view they never fail.
pub struct RecordingReader<'a> {
    source: Source<'a>,
}

enum Source<'a> {
    View(&'a StoreView),
    Lazy(&'a mut LazyRecording<Input>),
}

impl<'a> RecordingReader<'a> {
    /// Reads over a store's view (a [`ChunkStore`](crate::ChunkStore) or a
    /// [`Snapshot`](crate::Snapshot) dereferences to one).
    pub fn view(view: &'a StoreView) -> Self {
        Self {
            source: Source::View(view),
        }
    }

    /// Reads over a lazy recording.
    pub fn lazy(recording: &'a mut LazyRecording<Input>) -> Self {
        Self {
            source: Source::Lazy(recording),
        }
    }

    /// Is it reading lazily?
    pub fn is_lazy(&self) -> bool {
        matches!(self.source, Source::Lazy(_))
    }

    /// Every entity with data, sorted.
    pub fn entity_paths(&self) -> Vec<EntityPath> {
        match &self.source {
            Source::View(view) => view.entity_paths(),
            Source::Lazy(lazy) => lazy.entity_paths(),
        }
    }

    /// The components `entity` has data for, sorted.
    pub fn component_names(&self, entity: &EntityPath) -> Vec<ComponentName> {
        match &self.source {
            Source::View(view) => view.component_names(entity),
            Source::Lazy(lazy) => lazy.component_names(entity),
        }
    }

    /// Every timeline, sorted by name.
    pub fn timelines(&self) -> Vec<Timeline> {
        match &self.source {
            Source::View(view) => view.timelines(),
            Source::Lazy(lazy) => lazy.timelines(),
        }
    }

    /// The least and greatest time of the data on `timeline`, if any is there.
    pub fn time_range(&self, timeline: &str) -> Option<TimeRange> {
        match &self.source {
            Source::View(view) => view.time_range(timeline),
            Source::Lazy(lazy) => lazy.time_range(timeline),
        }
    }

    /// The type of `timeline`.
    ///
    /// # Errors
    /// [`UnknownTimeline`], naming the recording's timelines, if it has no data on it: a
    /// misspelt name must not pass for an answer of static data only.
    pub fn time_type(&self, timeline: &str) -> Result<TimeType, UnknownTimeline> {
        let timelines = self.timelines();
        timelines
            .iter()
            .find(|t| t.name() == timeline)
            .map(Timeline::time_type)
            .ok_or_else(|| UnknownTimeline::new(timeline, &timelines))
    }

    /// Rows and chunks: for a lazy recording, as its footer lists them.
    pub fn num_rows_and_chunks(&self) -> (u64, u64) {
        match &self.source {
            Source::View(view) => {
                let stats = view.stats();
                (stats.num_rows(), stats.num_chunks())
            }
            Source::Lazy(lazy) => {
                let entries = &lazy.manifest().entries;
                (
                    entries.iter().map(|e| e.num_rows).sum(),
                    entries.len() as u64,
                )
            }
        }
    }

    /// Static chunks: for a lazy recording, as its footer lists them.
    pub fn num_static_chunks(&self) -> u64 {
        match &self.source {
            Source::View(view) => view.stats().num_static_chunks,
            Source::Lazy(lazy) => {
                let entries = &lazy.manifest().entries;
                entries.iter().filter(|e| e.is_static).count() as u64
            }
        }
    }

    /// The latest-at answer ([`StoreView::latest_at`]).
    ///
    /// # Errors
    /// Lazily, if a chunk the query needs cannot be read or decoded.
    pub fn latest_at(
        &mut self,
        query: &LatestAtQuery,
        entity: &EntityPath,
        component: &str,
    ) -> Result<Option<QueryCell>, RrdError> {
        match &mut self.source {
            Source::View(view) => Ok(view.latest_at(query, entity, component)),
            Source::Lazy(lazy) => lazy.latest_at(query, entity, component),
        }
    }

    /// The range answer ([`StoreView::range`]).
    ///
    /// # Errors
    /// As [`RecordingReader::latest_at`].
    pub fn range(
        &mut self,
        query: &RangeQuery,
        entity: &EntityPath,
        component: &str,
    ) -> Result<RangeResult, RrdError> {
        match &mut self.source {
            Source::View(view) => Ok(view.range(query, entity, component)),
            Source::Lazy(lazy) => lazy.range(query, entity, component),
        }
    }
}
