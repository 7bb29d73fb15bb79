//! A data file's statistics as Delta's `add` action carries them (`numRecords`,
//! `minValues`, `maxValues`, `nullCount`), read from the file's own Parquet footer: what
//! lets a reader skip the files a filter rules out (a range of the index, say) without
//! opening them.

use std::path::Path;

use parquet::file::metadata::ParquetMetaDataReader;
use parquet::file::statistics::Statistics;
use serde_json::{Map, Value, json};

use super::DeltaError;

/// The stats JSON of the Parquet file `path` holding `rows` rows: the row count, and for
/// every top-level column of integers, floats or booleans whose row groups all have
/// statistics, its least and greatest values and its nulls. Exact: they are the values
/// the writer saw.
///
/// # Errors
/// The file cannot be read, or its footer parsed ([`DeltaError::Io`]).
pub(crate) fn file_stats(path: &Path, rows: u64) -> Result<String, DeltaError> {
    let io = |e: std::io::Error| DeltaError::io(path.display().to_string(), e);
    let file = std::fs::File::open(path).map_err(io)?;
    let metadata = ParquetMetaDataReader::new()
        .parse_and_finish(&file)
        .map_err(|e| io(std::io::Error::other(e)))?;
    let schema = metadata.file_metadata().schema_descr();
    let (mut min, mut max, mut nulls) = (Map::new(), Map::new(), Map::new());
    for (index, column) in schema.columns().iter().enumerate() {
        // A top-level primitive column (a list's leaves are deeper) holding plain numbers
        // (Delta writes a date's stats as text: not taken).
        let plain = matches!(
            column.logical_type_ref(),
            None | Some(parquet::basic::LogicalType::Integer { .. })
        );
        if column.path().parts().len() != 1 || !plain {
            continue;
        }
        let mut range: Option<(Value, Value, u64)> = None;
        let mut complete = true;
        for group in metadata.row_groups() {
            let Some((low, high, null_count)) = group.column(index).statistics().and_then(bounds)
            else {
                complete = false;
                break;
            };
            range = Some(match range {
                None => (low, high, null_count),
                Some((a, b, n)) => {
                    let least = if before(&low, &a) { low } else { a };
                    let greatest = if before(&b, &high) { high } else { b };
                    (least, greatest, n + null_count)
                }
            });
        }
        if let (true, Some((low, high, null_count))) = (complete, range) {
            let name = column.path().parts()[0].clone();
            if !low.is_null() {
                min.insert(name.clone(), low);
                max.insert(name.clone(), high);
            }
            nulls.insert(name, json!(null_count));
        }
    }
    Ok(json!({
        "numRecords": rows,
        "minValues": min,
        "maxValues": max,
        "nullCount": nulls,
    })
    .to_string())
}

/// A row group's least and greatest values of a column (null when it holds only nulls),
/// and its nulls; `None` for a type Delta's stats do not take as a number (or a NaN).
fn bounds(statistics: &Statistics) -> Option<(Value, Value, u64)> {
    let nulls = statistics.null_count_opt()?;
    let pair = |low: Option<Value>, high: Option<Value>| match (low, high) {
        (Some(low), Some(high)) => Some((low, high, nulls)),
        (None, None) => Some((Value::Null, Value::Null, nulls)),
        _ => None,
    };
    let float = |v: f64| (!v.is_nan()).then(|| json!(v));
    match statistics {
        Statistics::Boolean(s) => {
            pair(s.min_opt().map(|v| json!(v)), s.max_opt().map(|v| json!(v)))
        }
        Statistics::Int32(s) => pair(s.min_opt().map(|v| json!(v)), s.max_opt().map(|v| json!(v))),
        Statistics::Int64(s) => pair(s.min_opt().map(|v| json!(v)), s.max_opt().map(|v| json!(v))),
        Statistics::Float(s) => pair(
            s.min_opt().and_then(|&v| float(f64::from(v))),
            s.max_opt().and_then(|&v| float(f64::from(v))),
        ),
        Statistics::Double(s) => pair(
            s.min_opt().and_then(|&v| float(v)),
            s.max_opt().and_then(|&v| float(v)),
        ),
        _ => None,
    }
}

/// Whether `a` comes before `b` (a null, a group of nulls only, comes before nothing and
/// after everything: it never bounds). Integers compare as integers: nanosecond times
/// do not fit a float exactly.
fn before(a: &Value, b: &Value) -> bool {
    if b.is_null() {
        return !a.is_null();
    }
    if let (Some(x), Some(y)) = (a.as_i64(), b.as_i64()) {
        return x < y;
    }
    if let (Some(x), Some(y)) = (a.as_bool(), b.as_bool()) {
        return !x & y;
    }
    matches!((a.as_f64(), b.as_f64()), (Some(x), Some(y)) if x < y)
}
