//! Reading a footer: the `RrdFooter` protobuf, each manifest's `DataframePart`, and the
//! manifest batch's columns into [`ManifestEntry`]s.

use std::collections::BTreeMap;

use arrow_array::types::{DurationNanosecondType, Int64Type, TimestampNanosecondType};
use arrow_array::{
    Array, ArrayRef, ArrowPrimitiveType, BooleanArray, FixedSizeBinaryArray, PrimitiveArray,
    RecordBatch, StringArray, UInt64Array,
};
use arrow_buffer::Buffer;
use arrow_schema::DataType;
use smallvec::SmallVec;

use super::{
    INDEX_KEY, Manifest, ManifestComponent, ManifestEntry, ManifestTimeRange, STATIC_INDEX,
};
use crate::rrd::error::RrdErrorKind;
use crate::rrd::messages::StoreId;
use crate::rrd::protobuf::{FieldReader, WireError};
use crate::{ChunkId, ComponentName, EntityPath, TimeInt, TimeType, Timeline};

/// Decodes an `RrdFooter` message body into its manifests.
pub(crate) fn decode_footer(bytes: &[u8]) -> Result<Vec<Manifest>, WireError> {
    let mut manifests = Vec::new();
    let mut fields = FieldReader::new(bytes);
    while let Some(field) = fields.next_field()? {
        if field.number == 1 {
            manifests.push(field.nested("RrdFooter", decode_manifest)?);
        }
    }
    Ok(manifests)
}

fn decode_manifest(bytes: &[u8]) -> Result<Manifest, WireError> {
    let mut store_id = None;
    let mut batch = None;
    let mut fields = FieldReader::new(bytes);
    while let Some(field) = fields.next_field()? {
        match field.number {
            1 => {
                store_id = Some(field.nested("RrdManifest", StoreId::decode)?);
            }
            4 => {
                batch = Some(field.nested("RrdManifest", decode_dataframe_part)?);
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
        crate::rrd::payload::decompress(payload, uncompressed_size).map_err(|e| (0, e))?
    } else {
        payload.to_vec()
    };
    let mut batches = crate::ipc::read_stream_batches_zero_copy(Buffer::from_vec(ipc))
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

/// A timeline's (and, for per-component ones, a component's) range columns of a manifest
/// batch, by position.
#[derive(Default)]
struct RangeColumns {
    start: Option<usize>,
    end: Option<usize>,
    num_rows: Option<usize>,
}

/// A decoded family of range columns.
struct DecodedRanges<'a> {
    timeline: Timeline,
    /// The component of a per-component family.
    component: Option<ComponentName>,
    starts: Vec<Option<i64>>,
    ends: Vec<Option<i64>>,
    num_rows: Option<&'a UInt64Array>,
}

#[expect(
    clippy::too_many_lines,
    reason = "the manifest's column families, read in one place as they are documented"
)]
fn entries_from_batch(batch: &RecordBatch) -> Result<Vec<ManifestEntry>, String> {
    let paths = column::<StringArray>(batch, "chunk_entity_path")?;
    let ids = column::<FixedSizeBinaryArray>(batch, "chunk_id")?;
    if ids.value_length() != crate::ids::ID_BYTES {
        return Err("manifest chunk ids are not 16 bytes".to_owned());
    }
    let statics = column::<BooleanArray>(batch, "chunk_is_static")?;
    let num_rows = column::<UInt64Array>(batch, "chunk_num_rows")?;
    let offsets = column::<UInt64Array>(batch, "chunk_byte_offset")?;
    let sizes = column::<UInt64Array>(batch, "chunk_byte_size")?;
    let uncompressed = column::<UInt64Array>(batch, "chunk_byte_size_uncompressed")?;

    let schema = batch.schema();
    let mut static_columns: Vec<(ComponentName, usize)> = Vec::new();
    let mut range_columns: BTreeMap<(String, Option<String>), RangeColumns> = BTreeMap::new();
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
            slot.start = Some(i);
        } else if name.ends_with(":end") {
            slot.end = Some(i);
        } else if name.ends_with(":num_rows") {
            slot.num_rows = Some(i);
        }
    }

    // Decode every range column once, in the families' order (by timeline, then
    // component), and name each family's component once.
    let mut decoded: Vec<DecodedRanges<'_>> = Vec::with_capacity(range_columns.len());
    for (key, columns) in range_columns {
        let (Some(start), Some(end)) = (columns.start, columns.end) else {
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
        let num_rows = columns
            .num_rows
            .and_then(|i| batch.column(i).as_any().downcast_ref::<UInt64Array>());
        decoded.push(DecodedRanges {
            timeline: Timeline::new(key.0.as_str(), time_type),
            component: key.1.as_deref().map(ComponentName::new),
            starts,
            ends,
            num_rows,
        });
    }

    let mut entries = Vec::with_capacity(batch.num_rows());
    // An entity's path repeats on every row of its chunks: parsed once, then shared.
    let mut parsed_paths: ahash::HashMap<&str, EntityPath> = ahash::HashMap::default();
    for row in 0..batch.num_rows() {
        let mut id = [0u8; 16];
        id.copy_from_slice(ids.value(row));
        let text = paths.value(row);
        let entity_path = if let Some(path) = parsed_paths.get(text) {
            path.clone()
        } else {
            let path = EntityPath::parse(text).map_err(|e| format!("manifest row {row}: {e}"))?;
            parsed_paths.insert(text, path.clone());
            path
        };
        let mut ranges = Vec::new();
        let mut component_ranges: SmallVec<[(&ComponentName, ManifestTimeRange); 8]> =
            SmallVec::new();
        for ranges_of in &decoded {
            let (Some(Some(min)), Some(Some(max))) =
                (ranges_of.starts.get(row), ranges_of.ends.get(row))
            else {
                continue;
            };
            if ranges_of
                .num_rows
                .is_some_and(|r| r.is_valid(row) && r.value(row) == 0)
            {
                continue;
            }
            let (Some(min), Some(max)) = (TimeInt::new(*min), TimeInt::new(*max)) else {
                return Err(format!("manifest row {row}: time i64::MIN is reserved"));
            };
            let range = ManifestTimeRange {
                timeline: ranges_of.timeline.clone(),
                min,
                max,
            };
            match &ranges_of.component {
                None => ranges.push(range),
                Some(name) => component_ranges.push((name, range)),
            }
        }
        // By name; a stable sort keeps each component's ranges in timeline order.
        component_ranges.sort_by(|a, b| a.0.cmp(b.0));
        let mut components: Vec<ManifestComponent> = Vec::new();
        for (name, range) in component_ranges {
            match components.last_mut() {
                Some(last) if last.name == *name => last.ranges.push(range),
                _ => components.push(ManifestComponent {
                    name: name.clone(),
                    ranges: vec![range],
                }),
            }
        }
        let is_static = statics.value(row);
        if is_static {
            for (name, i) in &static_columns {
                let has = batch.column(*i).as_any().downcast_ref::<BooleanArray>();
                if has.is_some_and(|has| has.is_valid(row) && has.value(row))
                    && let Err(at) = components.binary_search_by(|c| c.name.cmp(name))
                {
                    components.insert(
                        at,
                        ManifestComponent {
                            name: name.clone(),
                            ranges: Vec::new(),
                        },
                    );
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
            components,
        });
    }
    Ok(entries)
}
