//! Lossless conversion between a [`Chunk`] and an Arrow `RecordBatch` in the layout Rerun
//! uses on the wire (SEMANTICS.md section 2, "Transport").

use std::collections::HashMap;
use std::sync::Arc;

use arrow_array::{Array, ArrayRef, FixedSizeBinaryArray, RecordBatch};
use arrow_schema::{ArrowError, Field, FieldRef, Schema};

use super::{Chunk, Metadata, RawComponentColumn, RawTimeColumn, RawTimes};
use crate::ChunkError;
use crate::{ChunkId, ComponentDescriptor, ComponentName, EntityPath, RowId, TimeType, Timeline};

pub(super) const META_ID: &str = "rerun:id";
pub(super) const META_ENTITY_PATH: &str = "rerun:entity_path";
const META_KIND: &str = "rerun:kind";
const META_INDEX_NAME: &str = "rerun:index_name";
const META_IS_SORTED: &str = "rerun:is_sorted";
const META_COMPONENT: &str = "rerun:component";
const META_ARCHETYPE: &str = "rerun:archetype";
const META_COMPONENT_TYPE: &str = "rerun:component_type";
const ROW_ID_COLUMN: &str = "rerun.controls.RowId";

/// The row-id column's field as Rerun writes it: a control column holding the
/// `rerun.datatypes.TUID` extension type.
pub(crate) fn row_id_field() -> Field {
    let meta = HashMap::from([
        (META_KIND.to_owned(), "control".to_owned()),
        (
            "ARROW:extension:name".to_owned(),
            "rerun.datatypes.TUID".to_owned(),
        ),
        (
            "ARROW:extension:metadata".to_owned(),
            r#"{"namespace":"row"}"#.to_owned(),
        ),
    ]);
    Field::new(ROW_ID_COLUMN, crate::ids::ID_DATA_TYPE, false).with_metadata(meta)
}

/// What a transport column holds.
enum ColumnKind {
    RowId,
    Time,
    Component,
}

/// Reads `rerun:kind`; without it, guesses from the name and type so that hand-made batches
/// work too: the `RowId` column by name, time types as timelines, lists as components.
fn column_kind(field: &Field) -> Result<ColumnKind, ChunkError> {
    match field.metadata().get(META_KIND).map(String::as_str) {
        Some("control") => Ok(ColumnKind::RowId),
        Some("index" | "time") => Ok(ColumnKind::Time),
        Some("data" | "component") => Ok(ColumnKind::Component),
        Some(other) => Err(ChunkError::UnknownColumnKind {
            column: field.name().clone(),
            kind: other.to_owned(),
        }),
        None if field.name() == ROW_ID_COLUMN => Ok(ColumnKind::RowId),
        None if TimeType::from_arrow(field.data_type()).is_some() => Ok(ColumnKind::Time),
        None => Ok(ColumnKind::Component),
    }
}

/// Does a component field's metadata hold only what [`Chunk::to_record_batch`] writes from
/// the descriptor of component `name`?
fn says_only_the_descriptor(meta: &HashMap<String, String>, name: &str) -> bool {
    meta.iter().all(|(key, value)| match key.as_str() {
        META_KIND => value == "data",
        META_COMPONENT => value == name,
        META_ARCHETYPE | META_COMPONENT_TYPE => true,
        _ => false,
    })
}

fn row_ids_from_arrow(array: &ArrayRef) -> Result<Vec<RowId>, ChunkError> {
    let bad_type = || ChunkError::BadRowIdType {
        data_type: array.data_type().clone(),
    };
    let array = array
        .as_any()
        .downcast_ref::<FixedSizeBinaryArray>()
        .ok_or_else(bad_type)?;
    if array.value_length() != 16 {
        return Err(bad_type());
    }
    if array.null_count() > 0 {
        return Err(ChunkError::NullRowIds {
            null_count: array.null_count(),
        });
    }
    Ok(array
        .iter()
        .flatten()
        .map(|bytes| {
            let mut be = [0u8; 16];
            be.copy_from_slice(bytes);
            RowId::from_be_bytes(be)
        })
        .collect())
}

/// [`Chunk::from_record_batch`], for code generic over conversions.
///
/// ```
/// # use std::sync::Arc;
/// # use arrow_array::{ArrayRef, Float64Array, RecordBatch};
/// # use chunkstore::*;
/// let value = Arc::new(Float64Array::from(vec![1.0])) as ArrayRef;
/// let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/e").unwrap())
///     .with_row(RowId::new(), [(Timeline::sequence("frame"), 1)], [("x", value)])
///     .build()?;
/// let batch: RecordBatch = chunk.to_record_batch()?;
/// let back = Chunk::try_from(&batch)?;
/// assert_eq!(back.id(), chunk.id());
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
impl TryFrom<&RecordBatch> for Chunk {
    type Error = ChunkError;

    fn try_from(batch: &RecordBatch) -> Result<Self, Self::Error> {
        Self::from_record_batch(batch)
    }
}

impl Chunk {
    /// Decodes a chunk from a `RecordBatch` in the transport layout.
    ///
    /// # Errors
    /// Missing `rerun:id` / `rerun:entity_path` metadata or row-id column, and everything
    /// [`Chunk::try_new`] rejects.
    pub fn from_record_batch(batch: &RecordBatch) -> Result<Self, ChunkError> {
        let schema = batch.schema();
        let schema_metadata = schema.metadata();
        let id_text = schema_metadata
            .get(META_ID)
            .ok_or(ChunkError::MissingMetadata { key: META_ID })?;
        let id: ChunkId = id_text.parse().map_err(ChunkError::BadChunkId)?;
        let path_text =
            schema_metadata
                .get(META_ENTITY_PATH)
                .ok_or(ChunkError::MissingMetadata {
                    key: META_ENTITY_PATH,
                })?;
        let entity_path = EntityPath::parse(path_text)?;
        let metadata = Metadata::kept(schema_metadata, |key, _| {
            key != META_ID && key != META_ENTITY_PATH
        });

        let mut row_ids = None;
        let mut times = Vec::new();
        let mut components = Vec::new();
        for (field, array) in schema.fields().iter().zip(batch.columns()) {
            match column_kind(field)? {
                ColumnKind::RowId => {
                    if row_ids.is_some() {
                        return Err(ChunkError::DuplicateRowIds {
                            column: field.name().clone(),
                        });
                    }
                    row_ids = Some(row_ids_from_arrow(array)?);
                }
                ColumnKind::Time => {
                    let name = field
                        .metadata()
                        .get(META_INDEX_NAME)
                        .unwrap_or_else(|| field.name());
                    let time_type = TimeType::from_arrow(array.data_type()).ok_or_else(|| {
                        ChunkError::BadTimeType {
                            timeline: name.clone(),
                            data_type: array.data_type().clone(),
                        }
                    })?;
                    // What `to_record_batch` writes anyway is not kept: a decoded column
                    // then has the layout of one built through the API, and a sorted one
                    // that of an unsorted one (compaction merges them).
                    let field_metadata = Metadata::kept(field.metadata(), |key, value| match key {
                        META_KIND => value != "index",
                        META_INDEX_NAME => value != name,
                        META_IS_SORTED => false,
                        _ => true,
                    });
                    times.push(RawTimeColumn {
                        timeline: Timeline::new(name.as_str(), time_type),
                        times: RawTimes::Array(Arc::clone(array)),
                        field_metadata,
                    });
                }
                ColumnKind::Component => {
                    let meta = field.metadata();
                    let name = meta.get(META_COMPONENT).unwrap_or_else(|| field.name());
                    let descriptor = ComponentDescriptor {
                        name: ComponentName::new(name.as_str()),
                        archetype: meta.get(META_ARCHETYPE).map(|s| Arc::from(s.as_str())),
                        component_type: meta
                            .get(META_COMPONENT_TYPE)
                            .map(|s| Arc::from(s.as_str())),
                    };
                    components.push(RawComponentColumn {
                        descriptor,
                        array: Arc::clone(array),
                        // A field saying nothing the descriptor does not (what
                        // `to_record_batch` writes from it) is not kept: such a column has
                        // the same layout as one built through the API.
                        field: (field.name() != name || !says_only_the_descriptor(meta, name))
                            .then(|| Arc::clone(field)),
                        from_accepted_cells: false,
                    });
                }
            }
        }
        let row_ids = row_ids.ok_or(ChunkError::MissingRowIds)?;
        Self::from_raw(
            id,
            entity_path,
            row_ids,
            times,
            components,
            metadata,
            super::Buffers::Unknown,
        )
    }

    /// Encodes the chunk as a `RecordBatch` in the transport layout. Decoding the result
    /// with [`Chunk::from_record_batch`] gives back an identical chunk.
    ///
    /// # Errors
    /// Only if Arrow rejects the batch, which would be a bug in this crate.
    pub fn to_record_batch(&self) -> Result<RecordBatch, ArrowError> {
        let mut fields: Vec<FieldRef> =
            Vec::with_capacity(1 + self.time_columns.len() + self.components.len());
        let mut columns: Vec<ArrayRef> = Vec::with_capacity(fields.capacity());

        let row_id = row_id_field();
        let mut row_id_meta = row_id.metadata().clone();
        row_id_meta.insert(
            META_IS_SORTED.to_owned(),
            self.is_sorted_by_row_id.to_string(),
        );
        fields.push(Arc::new(row_id.with_metadata(row_id_meta)));
        columns.push(RowId::array(self.row_ids.iter().copied()));

        for column in &self.time_columns {
            let mut meta = column.field_metadata.to_map();
            let name = column.timeline.name();
            meta.insert(META_KIND.to_owned(), "index".to_owned());
            meta.insert(META_INDEX_NAME.to_owned(), name.to_owned());
            if column.is_sorted {
                meta.insert(META_IS_SORTED.to_owned(), "true".to_owned());
            } else {
                meta.remove(META_IS_SORTED);
            }
            fields.push(Arc::new(
                Field::new(name, column.data_type.clone(), true).with_metadata(meta),
            ));
            let data = arrow_data::ArrayData::builder(column.data_type.clone())
                .len(column.times.len())
                .add_buffer(column.times.inner().clone())
                .build()?;
            columns.push(arrow_array::make_array(data));
        }

        for column in &self.components {
            let mut meta = column
                .field
                .as_ref()
                .map(|field| field.metadata().clone())
                .unwrap_or_default();
            let descriptor = &column.descriptor;
            meta.insert(META_KIND.to_owned(), "data".to_owned());
            meta.insert(
                META_COMPONENT.to_owned(),
                descriptor.name.as_str().to_owned(),
            );
            for (key, value) in [
                (META_ARCHETYPE, &descriptor.archetype),
                (META_COMPONENT_TYPE, &descriptor.component_type),
            ] {
                match value {
                    Some(value) => meta.insert(key.to_owned(), value.to_string()),
                    None => meta.remove(key),
                };
            }
            let name = column
                .field
                .as_ref()
                .map_or(descriptor.name.as_str(), |field| field.name().as_str());
            let field = Field::new(name, column.list.data_type().clone(), true).with_metadata(meta);
            fields.push(Arc::new(field));
            columns.push(Arc::new(column.list.clone()));
        }

        let mut metadata = self.extra_metadata.to_map();
        metadata.insert(META_ID.to_owned(), self.id.to_string());
        metadata.insert(META_ENTITY_PATH.to_owned(), self.entity_path.to_string());
        let schema = Arc::new(Schema::new_with_metadata(fields, metadata));
        RecordBatch::try_new(schema, columns)
    }
}
