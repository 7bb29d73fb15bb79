//! The tables `latest_at` and `range` return, built from the store's answers without
//! copying a cell: every component column is a slice (or a `take`) of its chunk's list
//! array.

use std::collections::HashMap;
use std::sync::Arc;

use arrow_array::{Array, ArrayRef, RecordBatch, new_null_array};
use arrow_schema::{ArrowError, DataType, Field, Schema, SchemaRef};
use chunkstore::{ComponentName, EntityPath, QueryCell, RangeResult, RowId, TimeType};

/// The name of the row id column in every table this package builds.
pub const ROW_ID: &str = "row_id";

fn component_field(entity: &EntityPath, name: &str, data_type: DataType) -> Field {
    Field::new(name, data_type, true).with_metadata(HashMap::from([
        ("rerun:entity_path".to_owned(), entity.to_string()),
        ("rerun:component".to_owned(), name.to_owned()),
    ]))
}

/// One component's latest-at answer, or the list type its column would have.
pub enum Answer {
    Found(QueryCell),
    /// The entity has the component, but no cell at or before the time.
    Missing(DataType),
}

/// The latest-at table: one row holding, per component, its answer (null where it has
/// none), its time column the greatest time among the answers and its row id the greatest
/// row id (the compound index of the answers, as Rerun's latest-at results report it);
/// no row at all when no component has an answer.
pub fn latest_at_batch(
    timeline: &str,
    time_type: TimeType,
    entity: &EntityPath,
    answers: Vec<(ComponentName, Answer)>,
) -> Result<RecordBatch, ArrowError> {
    let any = answers.iter().any(|(_, a)| matches!(a, Answer::Found(_)));
    let rows = usize::from(any);
    let time = answers
        .iter()
        .filter_map(|(_, a)| match a {
            Answer::Found(cell) => cell.time().map(chunkstore::TimeInt::as_i64),
            Answer::Missing(_) => None,
        })
        .max();
    let row_id = answers
        .iter()
        .filter_map(|(_, a)| match a {
            Answer::Found(cell) => Some(cell.row_id()),
            Answer::Missing(_) => None,
        })
        .max();
    let mut fields = vec![
        Field::new(timeline, time_type.to_arrow(), true),
        Field::new(ROW_ID, DataType::FixedSizeBinary(16), false),
    ];
    let mut columns: Vec<ArrayRef> = vec![
        time_type.array(vec![time; rows]),
        RowId::array(row_id.into_iter().take(rows)),
    ];
    for (name, answer) in answers {
        let column = match answer {
            Answer::Found(cell) => cell
                .column()
                .list_array()
                .slice(cell.row(), rows)
                .into_data(),
            Answer::Missing(data_type) => new_null_array(&data_type, rows).into_data(),
        };
        let column = arrow_array::make_array(column);
        fields.push(component_field(
            entity,
            name.as_str(),
            column.data_type().clone(),
        ));
        columns.push(column);
    }
    RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)
}

/// The range table: its rows in `(time, row id)` order, as record batches, one per run of
/// rows from one chunk (each a slice of the chunk's columns when the run is contiguous).
pub fn range_batches(
    timeline: &str,
    time_type: TimeType,
    entity: &EntityPath,
    component: &str,
    list_type: DataType,
    result: &RangeResult,
) -> Result<(Vec<RecordBatch>, SchemaRef), ArrowError> {
    let schema = Arc::new(Schema::new(vec![
        Field::new(timeline, time_type.to_arrow(), true),
        Field::new(ROW_ID, DataType::FixedSizeBinary(16), false),
        component_field(entity, component, list_type.clone()),
    ]));
    let mut batches = Vec::new();
    for run in result.runs() {
        // Null cells are no data (as `RangeResult::iter` skips them).
        let column = run.column();
        let rows: Vec<usize> = run.rows().filter(|&row| column.is_valid(row)).collect();
        if rows.is_empty() {
            continue;
        }
        let times_column = run
            .chunk()
            .time_columns()
            .iter()
            .find(|t| t.timeline().name() == timeline);
        let times: Vec<Option<i64>> = rows
            .iter()
            .map(|&row| times_column.map(|t| t.times()[row]))
            .collect();
        let list = column.list_array();
        let cells: ArrayRef = match run.contiguous_rows() {
            Some(span) if span.len() == rows.len() => Arc::new(list.slice(span.start, span.len())),
            _ => {
                let indices = arrow_array::UInt32Array::from_iter_values(
                    rows.iter()
                        .map(|&row| u32::try_from(row).unwrap_or(u32::MAX)),
                );
                arrow_select::take::take(list, &indices, None)?
            }
        };
        if cells.data_type() != &list_type {
            return Err(ArrowError::SchemaError(format!(
                "{entity}:{component} has cells of two types ({list_type} and {}); read it \
                 with dataframe(), which unifies them",
                cells.data_type()
            )));
        }
        let row_ids = run.chunk().row_ids();
        let row_id_column = RowId::array(rows.iter().map(|&row| row_ids[row]));
        batches.push(RecordBatch::try_new(
            Arc::clone(&schema),
            vec![time_type.array(times), row_id_column, cells],
        )?);
    }
    Ok((batches, schema))
}
