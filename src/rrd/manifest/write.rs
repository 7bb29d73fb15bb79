//! Writing a footer: a summary of each chunk as it is written ([`WrittenChunk`]), then the
//! manifest batch, the recording's schema and its SHA-256, in an `RrdFooter`.

use std::collections::BTreeMap;
use std::sync::Arc;

use arrow_array::types::Int64Type;
use arrow_array::{
    Array, ArrayRef, BooleanArray, FixedSizeBinaryArray, PrimitiveArray, RecordBatch, StringArray,
    UInt64Array,
};
use arrow_buffer::Buffer;
use arrow_schema::{DataType, Field, Schema};

use super::{INDEX_KEY, STATIC_INDEX};
use crate::rrd::messages::StoreId;
use crate::rrd::payload::ipc_stream;
use crate::rrd::protobuf::FieldWriter;
use crate::{Chunk, ChunkId, ComponentDescriptor, ComponentName, EntityPath, TimeType, Timeline};

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
    timelines: Vec<WrittenTimeline>,
    components: Vec<WrittenComponent>,
}

/// A timeline of a written chunk: its Arrow type, and the chunk's time range on it.
struct WrittenTimeline {
    timeline: Timeline,
    data_type: DataType,
    min: i64,
    max: i64,
}

/// A component's non-null cells on one timeline: their time range and how many there are.
#[derive(Clone, Copy)]
struct CellStats {
    start: i64,
    end: i64,
    num_rows: u64,
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
                .map(|c| WrittenTimeline {
                    timeline: c.timeline().clone(),
                    data_type: c.data_type().clone(),
                    min: c.time_range().min().as_i64(),
                    max: c.time_range().max().as_i64(),
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
        self.timelines
            .iter()
            .position(|t| t.timeline.name() == name)
    }
}

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
        for WrittenTimeline {
            timeline,
            data_type,
            ..
        } in &chunk.timelines
        {
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
        for WrittenTimeline { timeline, .. } in &chunk.timelines {
            timelines
                .entry(timeline.name().to_owned())
                .or_insert_with(|| timeline.time_type());
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
        Field::new("chunk_id", crate::ids::ID_DATA_TYPE, false),
        Arc::new(FixedSizeBinaryArray::new(
            crate::ids::ID_BYTES,
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
                .map(|i| (w.timelines[i].min, w.timelines[i].max))
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
            let stats: Vec<Option<CellStats>> = chunks
                .iter()
                .map(|w| {
                    let position = w.timeline_position(timeline)?;
                    let column = w.component(name)?;
                    let (start, end) = (*column.bounds.get(position)?)?;
                    Some(CellStats {
                        start,
                        end,
                        num_rows: column.non_null_rows,
                    })
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
                    "start" => time_array(
                        time_type,
                        stats.iter().map(|s| s.map(|s| s.start)).collect(),
                    ),
                    "end" => {
                        time_array(time_type, stats.iter().map(|s| s.map(|s| s.end)).collect())
                    }
                    _ => Arc::new(UInt64Array::from_iter_values(
                        stats.iter().map(|s| s.map_or(0, |s| s.num_rows)),
                    )),
                };
                push(field, column);
            }
        }
    }
    debug_assert!(columns.iter().all(|c| c.len() == n));
    RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)
}
