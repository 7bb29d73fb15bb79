//! The query context Flight SQL plans in: every recording's tables
//! ([`chunkstore::sql::register_segments`]) and the `recordings` table, made over the
//! recordings as they are, and kept while none of them changes (making one registers
//! every recording's tables).

use std::sync::atomic::{AtomicU64, Ordering};

use chunkstore::hub::StoreHub;
use chunkstore::rrd::StoreId;
use datafusion::error::DataFusionError;
use datafusion::prelude::{SessionConfig, SessionContext};
use parking_lot::Mutex;

use super::metrics::Metrics;
use super::recordings;

/// The query context last made, shared by the queries that follow while no recording
/// changes. Forgotten ([`QuerySessions::forget`]) when data is dropped, so that it does not
/// keep what a collection freed.
#[derive(Default)]
pub struct QuerySessions {
    /// Bumped by every [`QuerySessions::forget`]: a context made before is not kept.
    generation: AtomicU64,
    last: Mutex<Option<CachedSession>>,
}

struct CachedSession {
    generation: u64,
    /// Every recording's id and its snapshot's version when the context was made.
    key: Vec<(StoreId, u64)>,
    ctx: SessionContext,
}

impl QuerySessions {
    /// A context over `hub`'s recordings as they are now: the one kept if no recording
    /// changed since it was made, else a new one (counted in `metrics`).
    pub fn current(
        &self,
        hub: &StoreHub,
        metrics: &Metrics,
    ) -> Result<SessionContext, DataFusionError> {
        let recordings = hub.recordings();
        let key: Vec<(StoreId, u64)> = recordings
            .iter()
            .map(|r| (r.info.store_id.clone(), r.snapshot.version()))
            .collect();
        let generation = self.generation.load(Ordering::Acquire);
        if let Some(cached) = self.last.lock().as_ref()
            && cached.generation == generation
            && cached.key == key
        {
            return Ok(cached.ctx.clone());
        }
        metrics.session_built();
        let ctx =
            SessionContext::new_with_config(SessionConfig::new().with_information_schema(true));
        let segments: Vec<(String, chunkstore::Snapshot)> = recordings
            .iter()
            .map(|r| (r.info.store_id.recording_id.to_string(), r.snapshot.clone()))
            .collect();
        chunkstore::sql::register_segments(&ctx, &segments)?;
        // A timeline named `recordings` keeps its table.
        if !ctx.table_exist(recordings::TABLE)? {
            let table = recordings::table(&recordings)
                .map_err(|e| DataFusionError::ArrowError(Box::new(e), None))?;
            ctx.register_batch(recordings::TABLE, table)?;
        }
        self.keep(CachedSession {
            generation,
            key,
            ctx: ctx.clone(),
        });
        Ok(ctx)
    }

    /// Drops the context kept (and the snapshots it holds).
    pub fn forget(&self) {
        self.generation.fetch_add(1, Ordering::AcqRel);
        *self.last.lock() = None;
    }

    /// Keeps `made` unless a [`QuerySessions::forget`] came after it began: checked under
    /// the lock `forget` clears under, so a context of forgotten data is never kept.
    fn keep(&self, made: CachedSession) {
        let mut last = self.last.lock();
        if self.generation.load(Ordering::Acquire) == made.generation {
            *last = Some(made);
        }
    }
}
