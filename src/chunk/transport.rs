//! Lossless conversion between a [`Chunk`] and an Arrow `RecordBatch` in the layout Rerun
//! uses on the wire (SEMANTICS.md section 2, "Transport").

use std::collections::HashMap;
use std::sync::Arc;

use arrow_array::{Array, ArrayRef, FixedSizeBinaryArray, RecordBatch};
use arrow_schema::{ArrowError, Field, FieldRef, Fields, Schema};

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

/// What a batch's fields say about its columns: everything decoding takes from a field
/// rather than from its array, worked out once per field list ([`layout_cache`]).
struct TransportLayout {
    /// The columns in order, up to the first field that is refused.
    columns: Vec<LaidOutColumn>,
}

/// One column of a [`TransportLayout`].
enum LaidOutColumn {
    RowId,
    Time {
        /// Named by `rerun:index_name` (else the field), typed by the field.
        timeline: Timeline,
        field_metadata: Metadata,
    },
    Component {
        descriptor: ComponentDescriptor,
        /// The field, if it says more than the descriptor.
        field: Option<FieldRef>,
    },
}

impl TransportLayout {
    /// The layout of `fields`, and the error of the first field refused (the layout then
    /// stops before it, so that a decoder meets the errors of earlier columns' arrays
    /// first, as it reads them in order).
    fn of(fields: &Fields) -> (Self, Option<ChunkError>) {
        let mut columns = Vec::with_capacity(fields.len());
        let mut has_row_ids = false;
        let mut failure = None;
        for field in fields {
            match Self::column(field, &mut has_row_ids) {
                Ok(column) => columns.push(column),
                Err(error) => {
                    failure = Some(error);
                    break;
                }
            }
        }
        (Self { columns }, failure)
    }

    fn column(field: &FieldRef, has_row_ids: &mut bool) -> Result<LaidOutColumn, ChunkError> {
        Ok(match column_kind(field)? {
            ColumnKind::RowId => {
                if std::mem::replace(has_row_ids, true) {
                    return Err(ChunkError::DuplicateRowIds {
                        column: field.name().clone(),
                    });
                }
                LaidOutColumn::RowId
            }
            ColumnKind::Time => {
                let name = field
                    .metadata()
                    .get(META_INDEX_NAME)
                    .unwrap_or_else(|| field.name());
                let time_type = TimeType::from_arrow(field.data_type()).ok_or_else(|| {
                    ChunkError::BadTimeType {
                        timeline: name.clone(),
                        data_type: field.data_type().clone(),
                    }
                })?;
                // What `to_record_batch` writes anyway is not kept: a decoded column then
                // has the layout of one built through the API, and a sorted one that of an
                // unsorted one (compaction merges them).
                let field_metadata = Metadata::kept(field.metadata(), |key, value| match key {
                    META_KIND => value != "index",
                    META_INDEX_NAME => value != name,
                    META_IS_SORTED => false,
                    _ => true,
                });
                LaidOutColumn::Time {
                    timeline: Timeline::new(name.as_str(), time_type),
                    field_metadata,
                }
            }
            ColumnKind::Component => {
                let meta = field.metadata();
                let name = meta.get(META_COMPONENT).unwrap_or_else(|| field.name());
                LaidOutColumn::Component {
                    descriptor: ComponentDescriptor {
                        name: ComponentName::new(name.as_str()),
                        archetype: meta.get(META_ARCHETYPE).map(|s| Arc::from(s.as_str())),
                        component_type: meta
                            .get(META_COMPONENT_TYPE)
                            .map(|s| Arc::from(s.as_str())),
                    },
                    // A field saying nothing the descriptor does not (what
                    // `to_record_batch` writes from it) is not kept: such a column has the
                    // same layout as one built through the API.
                    field: (field.name() != name || !says_only_the_descriptor(meta, name))
                        .then(|| Arc::clone(field)),
                }
            }
        })
    }
}

/// The layouts this thread worked out last, by field list.
///
/// Every chunk of an `.rrd` stream carries its own schema, and the IPC schema cache gives
/// each message of a layout the field list it parsed once (only the schema's metadata,
/// the chunk id and entity path, differs). Working out a layout read every field's
/// metadata through a hash map, and interned its names: for a one-row chunk, a tenth of
/// decoding it. Keyed by the field list's allocation, which the cache holds so that no
/// other list can take its address; answers never depend on it, a miss works the layout
/// out again.
mod layout_cache {
    use std::cell::RefCell;
    use std::rc::Rc;

    use arrow_schema::Fields;

    use super::{ChunkError, TransportLayout};

    /// How many layouts a thread keeps.
    const MAX_LAYOUTS: usize = 16;
    /// A wider field list is worked out every time: its chunk's data dwarfs that.
    const MAX_FIELDS: usize = 256;

    thread_local! {
        static LAYOUTS: RefCell<Vec<(Fields, Rc<TransportLayout>)>> = const { RefCell::new(Vec::new()) };
    }

    fn same_list(a: &Fields, b: &Fields) -> bool {
        std::ptr::eq::<[_]>(std::ptr::from_ref(&**a), std::ptr::from_ref(&**b))
    }

    /// The layout of `fields`, and the error of its first refused field.
    pub(super) fn layout_of(fields: &Fields) -> (Rc<TransportLayout>, Option<ChunkError>) {
        let kept = LAYOUTS.with(|layouts| {
            let layouts = layouts.try_borrow().ok()?;
            let (_, layout) = layouts.iter().find(|(kept, _)| same_list(kept, fields))?;
            Some(Rc::clone(layout))
        });
        if let Some(layout) = kept {
            return (layout, None);
        }
        let (layout, failure) = TransportLayout::of(fields);
        let layout = Rc::new(layout);
        if failure.is_none() && fields.len() <= MAX_FIELDS {
            LAYOUTS.with(|layouts| {
                if let Ok(mut layouts) = layouts.try_borrow_mut() {
                    if layouts.len() == MAX_LAYOUTS {
                        layouts.remove(0);
                    }
                    layouts.push((fields.clone(), Rc::clone(&layout)));
                }
            });
        }
        (layout, failure)
    }

    /// How many layouts this thread keeps.
    #[cfg(test)]
    pub(super) fn len() -> usize {
        LAYOUTS.with(|layouts| layouts.borrow().len())
    }
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
    // By index, so that the vector is allocated once at its length.
    Ok((0..array.len())
        .map(|row| {
            let mut be = [0u8; 16];
            be.copy_from_slice(array.value(row));
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
        let schema = batch.schema_ref();
        Self::from_transport_parts(
            schema.fields(),
            &super::metadata::str_entries(schema.metadata()),
            batch.columns().iter().cloned(),
        )
    }

    /// [`Chunk::from_record_batch`] of a batch given in parts, so that a decoder need not
    /// build a `Schema` (with a metadata map of its own) and a `RecordBatch` only for this
    /// to read them and drop them: the schema's `fields` and `metadata` entries (their
    /// keys unique), and the `columns`, each of its field's type (as a `RecordBatch`
    /// checks).
    pub(crate) fn from_transport_parts<'m>(
        fields: &Fields,
        metadata: &(impl Iterator<Item = (&'m str, &'m str)> + Clone),
        columns: impl IntoIterator<Item = ArrayRef>,
    ) -> Result<Self, ChunkError> {
        let get = |wanted: &'static str| {
            metadata
                .clone()
                .find(|&(key, _)| key == wanted)
                .map(|(_, value)| value)
                .ok_or(ChunkError::MissingMetadata { key: wanted })
        };
        let id: ChunkId = get(META_ID)?.parse().map_err(ChunkError::BadChunkId)?;
        let entity_path = EntityPath::parse_recent(get(META_ENTITY_PATH)?)?;
        let metadata =
            Metadata::kept_of(metadata, |key, _| key != META_ID && key != META_ENTITY_PATH);

        let (layout, failure) = layout_cache::layout_of(fields);
        let mut row_ids = None;
        let mut times = super::RawTimeColumns::new();
        let mut components = super::RawComponentColumns::new();
        for (column, array) in layout.columns.iter().zip(columns) {
            match column {
                LaidOutColumn::RowId => row_ids = Some(row_ids_from_arrow(&array)?),
                LaidOutColumn::Time {
                    timeline,
                    field_metadata,
                } => {
                    // The layout took the type from the field, and a batch's column has
                    // its field's type (`RecordBatch` checks it).
                    times.push(RawTimeColumn {
                        timeline: timeline.clone(),
                        times: RawTimes::Array(array),
                        field_metadata: field_metadata.clone(),
                    });
                }
                LaidOutColumn::Component { descriptor, field } => {
                    components.push(RawComponentColumn {
                        descriptor: descriptor.clone(),
                        array,
                        field: field.clone(),
                        from_accepted_cells: false,
                    });
                }
            }
        }
        if let Some(failure) = failure {
            return Err(failure);
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

#[cfg(test)]
mod tests {
    use arrow_schema::DataType;

    use super::*;
    use crate::ChunkBuilder;

    /// A chunk of entity `path` whose time field and component field say more than the
    /// API writes, so that its layout keeps field metadata both ways.
    fn batch_of(path: &str, time: i64, value: f64) -> RecordBatch {
        let values = Arc::new(arrow_array::Float64Array::from(vec![value])) as ArrayRef;
        let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse(path).unwrap())
            .with_row(
                RowId::new(),
                [(Timeline::sequence("frame"), time)],
                [(
                    ComponentDescriptor {
                        name: ComponentName::new("Scalars:scalars"),
                        archetype: Some(Arc::from("rerun.archetypes.Scalars")),
                        component_type: Some(Arc::from("rerun.components.Scalar")),
                    },
                    values,
                )],
            )
            .build()
            .unwrap();
        let batch = chunk.to_record_batch().unwrap();
        let schema = batch.schema();
        let fields: Vec<FieldRef> = schema
            .fields()
            .iter()
            .map(|field| {
                let mut meta = field.metadata().clone();
                meta.insert("user:note".to_owned(), field.name().clone());
                Arc::new(field.as_ref().clone().with_metadata(meta))
            })
            .collect();
        RecordBatch::try_new(
            Arc::new(Schema::new_with_metadata(fields, schema.metadata().clone())),
            batch.columns().to_vec(),
        )
        .unwrap()
    }

    /// `batch` with `fields` (another batch's allocation) in place of its own.
    fn with_fields(batch: &RecordBatch, fields: &Fields) -> RecordBatch {
        let schema = Schema::new_with_metadata(fields.clone(), batch.schema().metadata().clone());
        RecordBatch::try_new(Arc::new(schema), batch.columns().to_vec()).unwrap()
    }

    /// Batches sharing one field list (what the IPC schema cache hands out) decode through
    /// one kept layout, into the chunks their own field lists give.
    #[test]
    fn batches_sharing_a_field_list_decode_like_fresh_ones() {
        let first = batch_of("/robot/a", 1, 0.5);
        let fields = first.schema().fields().clone();
        let kept_before = layout_cache::len();
        let decoded_first = Chunk::from_record_batch(&first).unwrap();
        assert!(layout_cache::len() > kept_before || kept_before == 16);
        for (i, path) in [(0_i32, "/robot/b"), (1, "/robot/a"), (2, "/c/d/e")] {
            let own = batch_of(path, 10 + i64::from(i), f64::from(i));
            let shared = with_fields(&own, &fields);
            let fresh = Chunk::from_record_batch(&own).unwrap();
            let reused = Chunk::from_record_batch(&shared).unwrap();
            assert!(reused.has_same_contents(&fresh), "{path}");
            assert!(reused.has_same_layout(&decoded_first) == (path == "/robot/a"));
            assert_eq!(reused.entity_path().to_string(), path);
            assert_eq!(
                reused.to_record_batch().unwrap(),
                fresh.to_record_batch().unwrap()
            );
            reused.sanity_check().unwrap();
            // What the time and component fields say that the API does not write is kept
            // (the row-id column is always written afresh).
            let back = reused.to_record_batch().unwrap();
            let notes = |batch: &RecordBatch| -> Vec<Option<String>> {
                let schema = batch.schema();
                let data_fields = schema.fields().iter().filter(|f| f.name() != ROW_ID_COLUMN);
                data_fields
                    .map(|f| f.metadata().get("user:note").cloned())
                    .collect()
            };
            assert_eq!(notes(&back), notes(&own));
            assert!(notes(&back).iter().all(Option::is_some));
        }
    }

    /// A refused field list is never kept, and its errors come in column order: an
    /// earlier column's bad array before a later field's refusal.
    #[test]
    fn refused_field_lists_are_not_kept_and_fail_in_column_order() {
        let good = batch_of("/e", 1, 1.0);
        let schema = good.schema();
        let row_ids_at = schema
            .fields()
            .iter()
            .position(|f| f.name() == ROW_ID_COLUMN)
            .unwrap();
        // A second row-id column after the first.
        let mut fields: Vec<FieldRef> = schema.fields().iter().cloned().collect();
        let mut columns = good.columns().to_vec();
        fields.push(Arc::clone(&fields[row_ids_at]));
        columns.push(Arc::clone(&columns[row_ids_at]));
        let twice = RecordBatch::try_new(
            Arc::new(Schema::new_with_metadata(fields, schema.metadata().clone())),
            columns,
        )
        .unwrap();
        let kept = layout_cache::len();
        for _ in 0..2 {
            assert!(matches!(
                Chunk::from_record_batch(&twice),
                Err(ChunkError::DuplicateRowIds { .. })
            ));
        }
        assert_eq!(layout_cache::len(), kept);

        // A time column of another type (so its field's kind says time but the type does
        // not) after row ids holding a null: the nulls are met first.
        let mut fields: Vec<FieldRef> = schema.fields().iter().cloned().collect();
        let mut columns = good.columns().to_vec();
        let null_ids = arrow_array::FixedSizeBinaryArray::try_from_sparse_iter_with_size(
            std::iter::once(None::<Vec<u8>>),
            16,
        )
        .unwrap();
        let null_ids_field = Field::new(ROW_ID_COLUMN, DataType::FixedSizeBinary(16), true)
            .with_metadata(fields[row_ids_at].metadata().clone());
        fields[row_ids_at] = Arc::new(null_ids_field);
        columns[row_ids_at] = Arc::new(null_ids);
        let mut bad_time_meta = HashMap::new();
        bad_time_meta.insert(META_KIND.to_owned(), "index".to_owned());
        fields.push(Arc::new(
            Field::new("t", DataType::Float64, false).with_metadata(bad_time_meta),
        ));
        columns.push(Arc::new(arrow_array::Float64Array::from(vec![1.0])));
        let batch = RecordBatch::try_new(
            Arc::new(Schema::new_with_metadata(fields, schema.metadata().clone())),
            columns,
        )
        .unwrap();
        assert!(matches!(
            Chunk::from_record_batch(&batch),
            Err(ChunkError::NullRowIds { null_count: 1 })
        ));
        // With valid row ids, the time column's type is what is refused.
        let mut columns = batch.columns().to_vec();
        columns[row_ids_at] = Arc::clone(good.column(row_ids_at));
        let batch = RecordBatch::try_new(batch.schema(), columns).unwrap();
        assert!(matches!(
            Chunk::from_record_batch(&batch),
            Err(ChunkError::BadTimeType { .. })
        ));
    }
}
