//! The footer's chunk manifest: one row per chunk of a recording, saying where its message
//! is in the file and what it holds (entity, static or not, time range per timeline and per
//! component), so that a reader can pick chunks without decoding them.
//!
//! Rerun encodes it as an Arrow record batch (inside an `RrdManifest` protobuf, inside the
//! `RrdFooter` that the `End` message carries), with these columns:
//! - `chunk_entity_path`, `chunk_id` (16 bytes, big-endian), `chunk_is_static`,
//!   `chunk_num_rows`, `chunk_byte_offset` and `chunk_byte_size` (the `ArrowMsg` body, after
//!   its message header), `chunk_byte_size_uncompressed` (the IPC payload's size);
//! - `<component>:has_static_data` per component (metadata `rerun:index` = `rerun:static`);
//! - `<timeline>:start` / `<timeline>:end` per timeline (typed like the timeline);
//! - `<timeline>:<component>:start|end|num_rows` per timeline and component (metadata
//!   `rerun:index` names the timeline, `rerun:component` the component).
//!
//! Beside it, the footer carries the recording's *sorbet schema*: one field per index,
//! and per entity and component (`/entity:component`), with Rerun's column metadata.

use std::collections::BTreeMap;
use std::sync::Arc;

use arrow_array::types::{DurationNanosecondType, Int64Type, TimestampNanosecondType};
use arrow_array::{
    Array, ArrayRef, ArrowPrimitiveType, BooleanArray, FixedSizeBinaryArray, PrimitiveArray,
    RecordBatch, StringArray, UInt64Array,
};
use arrow_buffer::Buffer;
use arrow_schema::{DataType, Field, Schema};

use super::error::RrdErrorKind;
use super::messages::StoreId;
use super::protobuf::{FieldReader, FieldWriter, WireError};
use crate::{
    Chunk, ChunkId, ComponentDescriptor, ComponentName, EntityPath, TimeInt, TimeType, Timeline,
};

const INDEX_KEY: &str = "rerun:index";
const STATIC_INDEX: &str = "rerun:static";

/// One timeline's time range in a chunk (of the chunk, or of one component's cells).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ManifestTimeRange {
    /// The timeline.
    pub timeline: Timeline,
    /// Least time.
    pub min: TimeInt,
    /// Greatest time.
    pub max: TimeInt,
}

/// What the manifest says of one component of a chunk.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ManifestComponent {
    /// The component.
    pub name: ComponentName,
    /// Its cells' time range per timeline (empty for static data).
    pub ranges: Vec<ManifestTimeRange>,
}

/// One chunk as the manifest describes it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ManifestEntry {
    /// The chunk's id.
    pub chunk_id: ChunkId,
    /// Its entity.
    pub entity_path: EntityPath,
    /// Does it hold static data?
    pub is_static: bool,
    /// Its rows.
    pub num_rows: u64,
    /// Where its `ArrowMsg` body starts in the file (after the message header).
    pub byte_offset: u64,
    /// The `ArrowMsg` body's length.
    pub byte_size: u64,
    /// The decompressed IPC payload's length.
    pub uncompressed_size: u64,
    /// Time range of the chunk per timeline.
    pub ranges: Vec<ManifestTimeRange>,
    /// Its components.
    pub components: Vec<ManifestComponent>,
}

/// A recording's chunk manifest, from a file's footer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Manifest {
    /// The store it describes.
    pub store_id: StoreId,
    /// One entry per chunk, in file order.
    pub entries: Vec<ManifestEntry>,
}

/// What the manifest says of a chunk being written: where it went and a summary of it
/// (not the chunk itself, so that writing a large file keeps little in memory).
pub(crate) struct WrittenChunk {
    id: ChunkId,
    entity_path: EntityPath,
    is_static: bool,
    num_rows: u64,
    byte_offset: u64,
    byte_size: u64,
    uncompressed_size: u64,
    /// Per timeline: the timeline, its Arrow type, and the chunk's time range.
    timelines: Vec<(Timeline, DataType, i64, i64)>,
    components: Vec<WrittenComponent>,
}

struct WrittenComponent {
    descriptor: ComponentDescriptor,
    data_type: DataType,
    non_null_rows: u64,
    /// Per timeline of the chunk (same order): the non-null cells' time range.
    bounds: Vec<Option<(i64, i64)>>,
}

impl WrittenChunk {
    pub(crate) fn new(
        chunk: &Chunk,
        byte_offset: u64,
        byte_size: u64,
        uncompressed_size: u64,
    ) -> Self {
        Self {
            id: chunk.id(),
            entity_path: chunk.entity_path().clone(),
            is_static: chunk.is_static(),
            num_rows: chunk.num_rows() as u64,
            byte_offset,
            byte_size,
            uncompressed_size,
            timelines: chunk
                .time_columns()
                .iter()
                .map(|c| {
                    let (min, max) = c.time_range();
                    (
                        c.timeline().clone(),
                        c.data_type().clone(),
                        min.as_i64(),
                        max.as_i64(),
                    )
                })
                .collect(),
            components: chunk
                .components()
                .iter()
                .map(|c| WrittenComponent {
                    descriptor: c.descriptor().clone(),
                    data_type: c.list_array().data_type().clone(),
                    non_null_rows: (c.list_array().len() - c.list_array().null_count()) as u64,
                    bounds: (0..chunk.time_columns().len())
                        .map(|i| {
                            c.bounds(i)
                                .map(|b| (b.min_time.as_i64(), b.max_time.as_i64()))
                        })
                        .collect(),
                })
                .collect(),
        }
    }

    fn component(&self, name: &ComponentName) -> Option<&WrittenComponent> {
        self.components.iter().find(|c| &c.descriptor.name == name)
    }

    fn timeline_position(&self, name: &str) -> Option<usize> {
        self.timelines.iter().position(|t| t.0.name() == name)
    }
}

// ---------------------------------------------------------------------------------------
// Reading

/// Decodes an `RrdFooter` message body into its manifests.
pub(crate) fn decode_footer(bytes: &[u8]) -> Result<Vec<Manifest>, WireError> {
    let mut manifests = Vec::new();
    let mut fields = FieldReader::new(bytes);
    while let Some(field) = fields.next_field()? {
        if field.number == 1 {
            let base = field.value_start;
            let manifest =
                decode_manifest(field.bytes("RrdFooter")?).map_err(|(at, e)| (at + base, e))?;
            manifests.push(manifest);
        }
    }
    Ok(manifests)
}

fn decode_manifest(bytes: &[u8]) -> Result<Manifest, WireError> {
    let mut store_id = None;
    let mut batch = None;
    let mut fields = FieldReader::new(bytes);
    while let Some(field) = fields.next_field()? {
        let base = field.value_start;
        match field.number {
            1 => {
                store_id = Some(
                    StoreId::decode(field.bytes("RrdManifest")?)
                        .map_err(|(at, e)| (at + base, e))?,
                );
            }
            4 => {
                batch = Some(
                    decode_dataframe_part(field.bytes("RrdManifest")?)
                        .map_err(|(at, e)| (at + base, e))?,
                );
            }
            _ => {}
        }
    }
    let missing = |field| {
        (
            0,
            RrdErrorKind::MissingField {
                message: "RrdManifest",
                field,
            },
        )
    };
    let store_id = store_id.ok_or_else(|| missing("store_id"))?;
    let batch = batch.ok_or_else(|| missing("data"))?;
    let entries =
        entries_from_batch(&batch).map_err(|reason| (0, RrdErrorKind::Footer { reason }))?;
    Ok(Manifest { store_id, entries })
}

/// A `DataframePart`: one Arrow IPC stream holding one batch, maybe LZ4-compressed.
fn decode_dataframe_part(bytes: &[u8]) -> Result<RecordBatch, WireError> {
    let mut payload = None;
    let mut compressed = false;
    let mut uncompressed_size = 0;
    let mut fields = FieldReader::new(bytes);
    while let Some(field) = fields.next_field()? {
        match field.number {
            2 => payload = Some(field.bytes("DataframePart")?),
            3 => compressed = field.varint("DataframePart")? == 2,
            4 => uncompressed_size = field.varint("DataframePart")?,
            _ => {}
        }
    }
    let payload = payload.ok_or((
        0,
        RrdErrorKind::MissingField {
            message: "DataframePart",
            field: "payload",
        },
    ))?;
    let ipc = if compressed {
        super::payload::decompress(payload, uncompressed_size).map_err(|e| (0, e))?
    } else {
        payload.to_vec()
    };
    let mut batches = crate::io::read_stream_batches_zero_copy(Buffer::from_vec(ipc))
        .map_err(|e| (0, RrdErrorKind::Ipc(e)))?;
    match (batches.pop(), batches.is_empty()) {
        (Some(batch), true) => Ok(batch),
        _ => Err((
            0,
            RrdErrorKind::Footer {
                reason: "the manifest is not exactly one record batch".to_owned(),
            },
        )),
    }
}

fn column<'a, T: 'static>(batch: &'a RecordBatch, name: &str) -> Result<&'a T, String> {
    batch
        .column_by_name(name)
        .ok_or_else(|| format!("manifest has no column {name:?}"))?
        .as_any()
        .downcast_ref::<T>()
        .ok_or_else(|| format!("manifest column {name:?} has the wrong type"))
}

/// The values of a time column (`Int64`, `Timestamp(ns)` or `Duration(ns)`), nulls as `None`.
fn times(array: &ArrayRef) -> Option<Vec<Option<i64>>> {
    fn values<T: ArrowPrimitiveType<Native = i64>>(array: &ArrayRef) -> Option<Vec<Option<i64>>> {
        let array = array.as_any().downcast_ref::<PrimitiveArray<T>>()?;
        Some(array.iter().collect())
    }
    match array.data_type() {
        DataType::Int64 => values::<Int64Type>(array),
        DataType::Timestamp(arrow_schema::TimeUnit::Nanosecond, _) => {
            values::<TimestampNanosecondType>(array)
        }
        DataType::Duration(arrow_schema::TimeUnit::Nanosecond) => {
            values::<DurationNanosecondType>(array)
        }
        _ => None,
    }
}

/// The time columns of a manifest batch, by timeline and (for per-component ones)
/// component: `(start, end, num_rows)`.
type RangeColumns =
    BTreeMap<(String, Option<String>), (Option<usize>, Option<usize>, Option<usize>)>;

/// A decoded family of range columns: the timeline, starts, ends and row counts.
type DecodedRanges<'a> = (
    Timeline,
    Vec<Option<i64>>,
    Vec<Option<i64>>,
    Option<&'a UInt64Array>,
);

#[expect(
    clippy::too_many_lines,
    reason = "the manifest's column families, read in one place as they are documented"
)]
fn entries_from_batch(batch: &RecordBatch) -> Result<Vec<ManifestEntry>, String> {
    let paths = column::<StringArray>(batch, "chunk_entity_path")?;
    let ids = column::<FixedSizeBinaryArray>(batch, "chunk_id")?;
    if ids.value_length() != 16 {
        return Err("manifest chunk ids are not 16 bytes".to_owned());
    }
    let statics = column::<BooleanArray>(batch, "chunk_is_static")?;
    let num_rows = column::<UInt64Array>(batch, "chunk_num_rows")?;
    let offsets = column::<UInt64Array>(batch, "chunk_byte_offset")?;
    let sizes = column::<UInt64Array>(batch, "chunk_byte_size")?;
    let uncompressed = column::<UInt64Array>(batch, "chunk_byte_size_uncompressed")?;

    let schema = batch.schema();
    let mut static_columns: Vec<(ComponentName, usize)> = Vec::new();
    let mut range_columns: RangeColumns = BTreeMap::new();
    for (i, field) in schema.fields().iter().enumerate() {
        let Some(index) = field.metadata().get(INDEX_KEY) else {
            continue;
        };
        let component = field.metadata().get("rerun:component").cloned();
        if index == STATIC_INDEX {
            if let Some(name) = field.name().strip_suffix(":has_static_data") {
                let name = component.unwrap_or_else(|| name.to_owned());
                static_columns.push((ComponentName::new(name.as_str()), i));
            }
            continue;
        }
        let slot = range_columns.entry((index.clone(), component)).or_default();
        let name = field.name();
        if name.ends_with(":start") {
            slot.0 = Some(i);
        } else if name.ends_with(":end") {
            slot.1 = Some(i);
        } else if name.ends_with(":num_rows") {
            slot.2 = Some(i);
        }
    }

    // Decode every range column once.
    let mut decoded: BTreeMap<(String, Option<String>), DecodedRanges<'_>> = BTreeMap::new();
    for (key, (start, end, rows)) in range_columns {
        let (Some(start), Some(end)) = (start, end) else {
            continue;
        };
        let start_array = batch.column(start);
        let time_type = TimeType::from_arrow(start_array.data_type()).ok_or_else(|| {
            format!(
                "manifest column {:?} is not a time",
                schema.field(start).name()
            )
        })?;
        let starts = times(start_array).ok_or("manifest start column has a bad type")?;
        let ends = times(batch.column(end)).ok_or("manifest end column has a bad type")?;
        let rows = rows.and_then(|i| batch.column(i).as_any().downcast_ref::<UInt64Array>());
        decoded.insert(
            key.clone(),
            (Timeline::new(key.0.as_str(), time_type), starts, ends, rows),
        );
    }

    let mut entries = Vec::with_capacity(batch.num_rows());
    for row in 0..batch.num_rows() {
        let mut id = [0u8; 16];
        id.copy_from_slice(ids.value(row));
        let entity_path =
            EntityPath::parse(paths.value(row)).map_err(|e| format!("manifest row {row}: {e}"))?;
        let mut ranges = Vec::new();
        let mut components: BTreeMap<ComponentName, Vec<ManifestTimeRange>> = BTreeMap::new();
        for ((_, component), (timeline, starts, ends, rows)) in &decoded {
            let (Some(Some(min)), Some(Some(max))) = (starts.get(row), ends.get(row)) else {
                continue;
            };
            if rows.is_some_and(|r| r.is_valid(row) && r.value(row) == 0) {
                continue;
            }
            let (Some(min), Some(max)) = (TimeInt::new(*min), TimeInt::new(*max)) else {
                return Err(format!("manifest row {row}: time i64::MIN is reserved"));
            };
            let range = ManifestTimeRange {
                timeline: timeline.clone(),
                min,
                max,
            };
            match component {
                None => ranges.push(range),
                Some(name) => components
                    .entry(ComponentName::new(name.as_str()))
                    .or_default()
                    .push(range),
            }
        }
        let is_static = statics.value(row);
        if is_static {
            for (name, i) in &static_columns {
                let has = batch.column(*i).as_any().downcast_ref::<BooleanArray>();
                if has.is_some_and(|has| has.is_valid(row) && has.value(row)) {
                    components.entry(name.clone()).or_default();
                }
            }
        }
        entries.push(ManifestEntry {
            chunk_id: ChunkId::from_be_bytes(id),
            entity_path,
            is_static,
            num_rows: num_rows.value(row),
            byte_offset: offsets.value(row),
            byte_size: sizes.value(row),
            uncompressed_size: uncompressed.value(row),
            ranges,
            components: components
                .into_iter()
                .map(|(name, ranges)| ManifestComponent { name, ranges })
                .collect(),
        });
    }
    Ok(entries)
}

// ---------------------------------------------------------------------------------------
// Writing

/// Encodes the `RrdFooter` for one recording written as `chunks`.
pub(crate) fn encode_footer(
    store_id: &StoreId,
    chunks: &[WrittenChunk],
) -> Result<Vec<u8>, arrow_schema::ArrowError> {
    let batch = manifest_batch(chunks)?;
    let ipc = ipc_stream(&batch.schema(), Some(&batch))?;
    let schema = sorbet_schema(chunks);
    let schema_ipc = ipc_stream(&schema, None)?;
    let schema_sha256 = schema_sha256(&schema)?;
    let compressed = lz4_flex::block::compress(&ipc);
    let mut footer = FieldWriter::default();
    footer.message(1, |manifest| {
        manifest
            .message(1, |id| store_id.encode(id))
            .message(2, |schema| {
                schema.bytes(1, &schema_ipc);
            })
            .bytes(3, &schema_sha256)
            .message(4, |part| {
                part.varint(1, 1)
                    .bytes(2, &compressed)
                    .varint(3, 2)
                    .varint(4, ipc.len() as u64);
            });
    });
    Ok(footer.bytes)
}

fn ipc_stream(
    schema: &Schema,
    batch: Option<&RecordBatch>,
) -> Result<Vec<u8>, arrow_schema::ArrowError> {
    let mut out = Vec::new();
    let mut writer = arrow_ipc::writer::StreamWriter::try_new(&mut out, schema)?;
    if let Some(batch) = batch {
        writer.write(batch)?;
    }
    writer.finish()?;
    drop(writer);
    Ok(out)
}

/// The schema's fingerprint as Rerun computes it (and checks it): SHA-256 of the IPC schema
/// message of its fields, sorted, without schema metadata or end-of-stream marker.
fn schema_sha256(schema: &Schema) -> Result<[u8; 32], arrow_schema::ArrowError> {
    use sha2::Digest as _;
    let mut fields = schema.fields().to_vec();
    fields.sort();
    let stream = ipc_stream(&Schema::new(fields), None)?;
    let message = &stream[..stream.len().saturating_sub(8)];
    Ok(sha2::Sha256::digest(message).into())
}

fn descriptor_metadata(descriptor: &ComponentDescriptor) -> Vec<(String, String)> {
    let mut meta = vec![(
        "rerun:component".to_owned(),
        descriptor.name.as_str().to_owned(),
    )];
    if let Some(archetype) = &descriptor.archetype {
        meta.push(("rerun:archetype".to_owned(), archetype.to_string()));
    }
    if let Some(component_type) = &descriptor.component_type {
        meta.push((
            "rerun:component_type".to_owned(),
            component_type.to_string(),
        ));
    }
    meta
}

/// The recording's columns: row id, one per timeline, one per entity and component.
fn sorbet_schema(chunks: &[WrittenChunk]) -> Schema {
    let mut timelines: BTreeMap<String, DataType> = BTreeMap::new();
    let mut columns: BTreeMap<(EntityPath, ComponentName), (Field, bool)> = BTreeMap::new();
    for chunk in chunks {
        for (timeline, data_type, _, _) in &chunk.timelines {
            timelines
                .entry(timeline.name().to_owned())
                .or_insert_with(|| data_type.clone());
        }
        for component in &chunk.components {
            let key = (chunk.entity_path.clone(), component.descriptor.name.clone());
            let entry = columns.entry(key).or_insert_with(|| {
                let mut meta: std::collections::HashMap<String, String> =
                    descriptor_metadata(&component.descriptor)
                        .into_iter()
                        .collect();
                meta.insert(
                    "rerun:entity_path".to_owned(),
                    chunk.entity_path.to_string(),
                );
                meta.insert("rerun:kind".to_owned(), "data".to_owned());
                let name = format!(
                    "{}:{}",
                    chunk.entity_path,
                    component.descriptor.name.as_str()
                );
                (
                    Field::new(name, component.data_type.clone(), true).with_metadata(meta),
                    true,
                )
            });
            entry.1 &= chunk.is_static;
        }
    }
    let mut fields = vec![crate::chunk::row_id_field()];
    for (name, data_type) in timelines {
        fields.push(
            Field::new(name.as_str(), data_type, true).with_metadata(
                [
                    ("rerun:index_name".to_owned(), name.clone()),
                    ("rerun:kind".to_owned(), "index".to_owned()),
                ]
                .into(),
            ),
        );
    }
    for (_, (field, is_static)) in columns {
        let field = if is_static {
            let mut meta = field.metadata().clone();
            meta.insert("rerun:is_static".to_owned(), "true".to_owned());
            field.with_metadata(meta)
        } else {
            field
        };
        fields.push(field);
    }
    Schema::new(fields)
}

#[expect(
    clippy::too_many_lines,
    reason = "the manifest's column families, written in one place as they are documented"
)]
fn manifest_batch(chunks: &[WrittenChunk]) -> Result<RecordBatch, arrow_schema::ArrowError> {
    let n = chunks.len();
    // Every component (by name, with the descriptor first seen) and timeline in the file.
    let mut components: BTreeMap<ComponentName, ComponentDescriptor> = BTreeMap::new();
    let mut timelines: BTreeMap<String, TimeType> = BTreeMap::new();
    for chunk in chunks {
        for component in &chunk.components {
            components
                .entry(component.descriptor.name.clone())
                .or_insert_with(|| component.descriptor.clone());
        }
        for (timeline, _, _, _) in &chunk.timelines {
            timelines
                .entry(timeline.name().to_owned())
                .or_insert(timeline.time_type());
        }
    }

    let mut fields: Vec<Field> = Vec::new();
    let mut columns: Vec<ArrayRef> = Vec::new();
    let mut push = |field: Field, column: ArrayRef| {
        fields.push(field);
        columns.push(column);
    };
    let u64s = |f: &dyn Fn(&WrittenChunk) -> u64| -> ArrayRef {
        Arc::new(UInt64Array::from_iter_values(chunks.iter().map(f)))
    };
    push(
        Field::new("chunk_entity_path", DataType::Utf8, false),
        Arc::new(StringArray::from_iter_values(
            chunks.iter().map(|w| w.entity_path.to_string()),
        )),
    );
    let id_bytes: Vec<u8> = chunks.iter().flat_map(|w| w.id.to_be_bytes()).collect();
    push(
        Field::new("chunk_id", DataType::FixedSizeBinary(16), false),
        Arc::new(FixedSizeBinaryArray::new(
            16,
            Buffer::from_vec(id_bytes),
            None,
        )),
    );
    push(
        Field::new("chunk_is_static", DataType::Boolean, false),
        Arc::new(
            chunks
                .iter()
                .map(|w| Some(w.is_static))
                .collect::<BooleanArray>(),
        ),
    );
    push(
        Field::new("chunk_num_rows", DataType::UInt64, false),
        u64s(&|w| w.num_rows),
    );
    push(
        Field::new("chunk_byte_offset", DataType::UInt64, false),
        u64s(&|w| w.byte_offset),
    );
    push(
        Field::new("chunk_byte_size", DataType::UInt64, false),
        u64s(&|w| w.byte_size),
    );
    push(
        Field::new("chunk_byte_size_uncompressed", DataType::UInt64, false),
        u64s(&|w| w.uncompressed_size),
    );

    let with_meta = |field: Field, index: &str, descriptor: Option<&ComponentDescriptor>| {
        let mut meta: std::collections::HashMap<String, String> = descriptor
            .map(descriptor_metadata)
            .unwrap_or_default()
            .into_iter()
            .collect();
        meta.insert(INDEX_KEY.to_owned(), index.to_owned());
        field.with_metadata(meta)
    };
    for (name, descriptor) in &components {
        let values = chunks
            .iter()
            .map(|w| Some(w.is_static && w.component(name).is_some()));
        push(
            with_meta(
                Field::new(
                    format!("{}:has_static_data", name.as_str()),
                    DataType::Boolean,
                    false,
                ),
                STATIC_INDEX,
                Some(descriptor),
            ),
            Arc::new(values.collect::<BooleanArray>()),
        );
    }
    let time_array = |time_type: TimeType, values: Vec<Option<i64>>| -> ArrayRef {
        let array = PrimitiveArray::<Int64Type>::from(values);
        let data = array
            .into_data()
            .into_builder()
            .data_type(time_type.to_arrow());
        match data.build() {
            Ok(data) => arrow_array::make_array(data),
            Err(_) => Arc::new(PrimitiveArray::<Int64Type>::from(Vec::<Option<i64>>::new())),
        }
    };
    for (timeline, &time_type) in &timelines {
        let range = |w: &WrittenChunk| {
            w.timeline_position(timeline)
                .map(|i| (w.timelines[i].2, w.timelines[i].3))
        };
        for (suffix, pick) in [("start", true), ("end", false)] {
            let values = chunks
                .iter()
                .map(|w| range(w).map(|(min, max)| if pick { min } else { max }))
                .collect();
            push(
                with_meta(
                    Field::new(format!("{timeline}:{suffix}"), time_type.to_arrow(), true),
                    timeline,
                    None,
                ),
                time_array(time_type, values),
            );
        }
    }
    for (timeline, &time_type) in &timelines {
        for (name, descriptor) in &components {
            // Per chunk: (start, end, num_rows) of the component's non-null cells.
            let stats: Vec<Option<(i64, i64, u64)>> = chunks
                .iter()
                .map(|w| {
                    let position = w.timeline_position(timeline)?;
                    let column = w.component(name)?;
                    let (min, max) = (*column.bounds.get(position)?)?;
                    Some((min, max, column.non_null_rows))
                })
                .collect();
            for (suffix, data_type) in [
                ("start", time_type.to_arrow()),
                ("end", time_type.to_arrow()),
                ("num_rows", DataType::UInt64),
            ] {
                let field = with_meta(
                    Field::new(
                        format!("{timeline}:{}:{suffix}", name.as_str()),
                        data_type,
                        true,
                    ),
                    timeline,
                    Some(descriptor),
                );
                let column: ArrayRef = match suffix {
                    "start" => {
                        time_array(time_type, stats.iter().map(|s| s.map(|s| s.0)).collect())
                    }
                    "end" => time_array(time_type, stats.iter().map(|s| s.map(|s| s.1)).collect()),
                    _ => Arc::new(UInt64Array::from_iter_values(
                        stats.iter().map(|s| s.map_or(0, |s| s.2)),
                    )),
                };
                push(field, column);
            }
        }
    }
    debug_assert!(columns.iter().all(|c| c.len() == n));
    RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)
}
