//! Parsed schemas reused across the IPC messages of a stream of chunks.
//!
//! Every chunk of an `.rrd` stream carries its own IPC schema message, and for small chunks
//! verifying and parsing it was a third of decoding the chunk. The messages of one entity
//! and column set differ only in their schema-level metadata values (the chunk id), so each
//! thread keeps the last few schema messages it decoded (from a layout's second message on:
//! a message whose length no recent one had is not worth proving), each with its
//! [`SchemaLayout`](super::schema_layout::SchemaLayout) proof. A new message equal to a
//! kept one outside the proven value slots, its slots UTF-8, gets the kept schema's fields
//! and its own metadata, without verifying or parsing: by the proof, verification would
//! pass and parsing would give exactly that schema. Anything else is decoded in full.
//!
//! The cache is per thread because answers never depend on it (the proof makes a hit and a
//! full decode agree), so no caller has to own, pass or share one; it is small and bounded.

use std::cell::{Cell, RefCell};
use std::collections::HashMap;
use std::rc::Rc;
use std::sync::Arc;

use arrow_schema::{Schema, SchemaRef};
use smallvec::SmallVec;

use super::schema_layout::SchemaLayout;

/// How many schema messages a thread keeps.
const MAX_TEMPLATES: usize = 64;

/// The most message bytes a thread keeps in all; a message larger than a quarter of it is
/// never kept (a schema of thousands of columns is parsed once per chunk, but its chunk's
/// data dwarfs that).
const MAX_TEMPLATE_BYTES: usize = 1 << 20;

/// How many recent misses' lengths a thread remembers: a message is kept only when one of
/// them had its length. A layout that repeats (an entity's chunks) is kept from its second
/// message on; a stream whose schemas never repeat pays no proof for them.
const REMEMBERED_MISSES: usize = 16;

/// A decoded schema message and its proof.
struct Template {
    message: Box<[u8]>,
    layout: SchemaLayout,
    schema: SchemaRef,
    /// The keys of the layout's entries that have a key and a value, in message order:
    /// the entries `fb_to_schema` puts in the metadata map.
    keys: Rc<[String]>,
    /// The `bodyLength` the message declares (the stream's framing checks it).
    body_length: i64,
    last_used: u64,
}

/// One thread's kept schema messages.
#[derive(Default)]
struct SchemaCache {
    templates: Vec<Template>,
    bytes: usize,
    clock: u64,
    /// Messages answered from the cache (for tests and probes).
    hits: u64,
    /// The lengths of recent messages that missed and were not kept, a ring.
    missed_lengths: [usize; REMEMBERED_MISSES],
    next_miss: usize,
}

thread_local! {
    static CACHE: RefCell<SchemaCache> = RefCell::new(SchemaCache::default());
    /// Set while [`without`] runs.
    static OFF: Cell<bool> = const { Cell::new(false) };
}

/// Runs `decode` with this thread's cache off: nothing looked up, nothing kept.
pub(super) fn without<T>(decode: impl FnOnce() -> T) -> T {
    super::with_flag_set(&OFF, decode)
}

/// Empties this thread's cache.
pub(super) fn clear() {
    CACHE.with(|cache| {
        if let Ok(mut cache) = cache.try_borrow_mut() {
            *cache = SchemaCache::default();
        }
    });
}

/// A schema found for a message without decoding it: a kept schema's fields, and this
/// message's metadata values, not yet in a map (a chunk reads two of them and keeps the
/// rest only if they differ from the last chunk's).
#[derive(Clone)]
pub(super) struct CachedSchema<'a> {
    /// The kept schema: its fields are the message's, its metadata values are not.
    pub(super) template: SchemaRef,
    /// The metadata keys, in message order, with their values (as many).
    keys: Rc<[String]>,
    values: SmallVec<[&'a str; 4]>,
    pub(super) body_length: i64,
}

impl CachedSchema<'_> {
    /// The metadata entries, as `fb_to_schema`'s map holds them: of entries with equal
    /// keys, the last.
    pub(super) fn metadata(&self) -> impl Iterator<Item = (&str, &str)> + Clone {
        let keys = &*self.keys;
        keys.iter()
            .zip(&self.values)
            .enumerate()
            .filter(move |&(at, (key, _))| !keys[at + 1..].contains(key))
            .map(|(_, (key, value))| (key.as_str(), *value))
    }

    /// The schema, as `fb_to_schema` would build it from the message.
    pub(super) fn to_schema(&self) -> SchemaRef {
        let metadata: HashMap<String, String> = self
            .metadata()
            .map(|(key, value)| (key.to_owned(), value.to_owned()))
            .collect();
        Arc::new(Schema::new_with_metadata(
            self.template.fields().clone(),
            metadata,
        ))
    }
}

/// The schema of `message` (one IPC message's metadata bytes, unverified) if this thread
/// kept a message it provably decodes like.
pub(super) fn lookup(message: &[u8]) -> Option<CachedSchema<'_>> {
    if OFF.with(Cell::get) {
        return None;
    }
    CACHE.with(|cache| cache.try_borrow_mut().ok()?.lookup(message))
}

/// Keeps `message`, which flatbuffers verified and arrow-ipc decoded into `schema`, if
/// its layout is proven; `body_length` is its declared body length.
pub(super) fn learn(message: &[u8], schema: &SchemaRef, body_length: i64) {
    if message.len() > MAX_TEMPLATE_BYTES / 4 || OFF.with(Cell::get) {
        return;
    }
    CACHE.with(|cache| {
        let Ok(mut cache) = cache.try_borrow_mut() else {
            return;
        };
        if !cache.seen_length(message.len()) {
            return;
        }
        let Some(layout) = SchemaLayout::prove(message) else {
            return;
        };
        let keys = layout
            .entries
            .iter()
            .filter(|entry| entry.value.is_some())
            .filter_map(|entry| entry.key.clone())
            .collect();
        cache.insert(Template {
            message: message.into(),
            layout,
            schema: Arc::clone(schema),
            keys,
            body_length,
            last_used: 0,
        });
    });
}

impl SchemaCache {
    fn lookup<'a>(&mut self, message: &'a [u8]) -> Option<CachedSchema<'a>> {
        self.clock += 1;
        let clock = self.clock;
        let template = self
            .templates
            .iter_mut()
            .find(|t| t.message.len() == message.len() && t.matches(message))?;
        template.last_used = clock;
        let values = template.values_in(message)?;
        self.hits += 1;
        Some(CachedSchema {
            template: Arc::clone(&template.schema),
            keys: Rc::clone(&template.keys),
            values,
            body_length: template.body_length,
        })
    }

    /// Did a recent miss have this length? If not, remembers it.
    fn seen_length(&mut self, len: usize) -> bool {
        if self.missed_lengths.contains(&len) {
            return true;
        }
        self.missed_lengths[self.next_miss] = len;
        self.next_miss = (self.next_miss + 1) % REMEMBERED_MISSES;
        false
    }

    fn insert(&mut self, mut template: Template) {
        while !self.templates.is_empty()
            && (self.templates.len() >= MAX_TEMPLATES
                || self.bytes + template.message.len() > MAX_TEMPLATE_BYTES)
        {
            let oldest = self
                .templates
                .iter()
                .enumerate()
                .min_by_key(|(_, t)| t.last_used)
                .map_or(0, |(i, _)| i);
            let evicted = self.templates.swap_remove(oldest);
            self.bytes -= evicted.message.len();
        }
        self.clock += 1;
        template.last_used = self.clock;
        self.bytes += template.message.len();
        self.templates.push(template);
    }
}

impl Template {
    /// Is `message` (of the same length) equal to this one outside the slots?
    fn matches(&self, message: &[u8]) -> bool {
        let mut at = 0;
        for slot in &self.layout.slots {
            if self.message[at..slot.start] != message[at..slot.start] {
                return false;
            }
            at = slot.end;
        }
        self.message[at..] == message[at..]
    }

    /// `message`'s values of the entries with a key, in message order; `None` if a value
    /// is not UTF-8 (the verifier refuses that message, even for a value whose entry has
    /// no key and so no place in the schema).
    fn values_in<'a>(&self, message: &'a [u8]) -> Option<SmallVec<[&'a str; 4]>> {
        let mut values = SmallVec::new();
        for entry in &self.layout.entries {
            let Some(value) = &entry.value else {
                continue;
            };
            let value = std::str::from_utf8(message.get(value.clone())?).ok()?;
            if entry.key.is_some() {
                values.push(value);
            }
        }
        Some(values)
    }
}

/// How many messages this thread answered from its cache, and how many it keeps.
#[cfg(test)]
pub(super) fn counts() -> (u64, usize) {
    CACHE.with(|cache| {
        let cache = cache.borrow();
        (cache.hits, cache.templates.len())
    })
}
