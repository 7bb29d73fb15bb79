//! One write of a Delta table: its files staged, placed, then committed as the next
//! version of the log (the steps in the module docs of `parquet/delta`).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use arrow_schema::SchemaRef;
use parking_lot::Mutex;
use serde_json::{Value, json};

use super::log::{
    AddFile, TableState, commit_text, entry_name, entry_version, is_checkpoint, log_path, now_ms,
    random_uuid,
};
use super::{DeltaError, SEGMENT_COLUMN, TableStore};
use crate::parquet::delta_types::DeltaSchema;
use crate::parquet::{HiveSummary, ParquetSummary};

/// What a write asks of a table.
pub(crate) struct DeltaWrite<'a> {
    /// Where the table is.
    pub table: &'a dyn TableStore,
    /// Add to an existing table (else make a new one).
    pub append: bool,
    /// The partition columns after `segment`, with their Delta types.
    pub partitions: Vec<(String, &'static str)>,
    /// The segments the write may add: checked against the table before anything is
    /// written.
    pub segments: Vec<String>,
    /// The Arrow schema of every file the write makes (before the Delta types): checked
    /// before anything is written.
    pub schema: SchemaRef,
}

/// What a write committed.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct DeltaCommit {
    /// The log version the commit is.
    pub version: u64,
    /// Each file added (its path in the table, `/`-separated) and what it holds.
    pub files: Vec<(String, ParquetSummary)>,
    /// The segments added, in order.
    pub segments: Vec<String>,
    /// Commits other writers made first, each of which this write then read and committed
    /// after.
    pub retries: usize,
}

impl DeltaCommit {
    /// Rows added, over every file.
    pub fn rows(&self) -> u64 {
        self.files.iter().map(|(_, s)| s.rows).sum()
    }
}

/// A file staged for the commit: where it is, where it goes, and its `add`.
#[derive(Clone)]
struct Staged {
    file: PathBuf,
    relative: String,
    add: AddFile,
    summary: ParquetSummary,
}

/// How a write's files are placed as they are written: told of the files just written
/// (under the staging directory), it places them.
pub(crate) type Place<'a> = dyn Fn(&HiveSummary) -> Result<(), DeltaError> + Sync + 'a;

/// Writes one commit to `write.table`: `files` writes the data files, in the Delta types,
/// into the staging directory it is given, each named by the name it is given inside its
/// partition directories, calls the [`Place`] it is given with each batch of files it
/// finished (a segment's, say: the staging directory then holds only what is not placed
/// yet), and says what it wrote.
///
/// # Errors
/// [`DeltaError`] (through `E`): the table's state, its store's errors, a lost race on a
/// segment; `files`' own.
pub(crate) fn write_table<E: From<DeltaError>>(
    write: &DeltaWrite<'_>,
    files: impl FnOnce(&Path, &str, &Place<'_>) -> Result<HiveSummary, E>,
) -> Result<DeltaCommit, E> {
    let table = write.table;
    let schema = DeltaSchema::of(&write.schema).map_err(DeltaError::from)?;
    let partition_names: Vec<String> = std::iter::once(SEGMENT_COLUMN.to_owned())
        .chain(write.partitions.iter().map(|(name, _)| name.clone()))
        .collect();
    let state = if write.append {
        let state = read_state(table)?;
        if state.version.is_none() {
            return Err(DeltaError::NotATable {
                table: table.name(),
            }
            .into());
        }
        if !state.has_metadata {
            return Err(DeltaError::BadLog {
                file: entry_name(0),
                reason: "no metaData action in the whole log: it describes no table".into(),
            }
            .into());
        }
        if state.partition_columns != partition_names {
            return Err(DeltaError::Partitions {
                table: state.partition_columns,
                write: partition_names,
            }
            .into());
        }
        check_segments(&state, write.segments.iter().map(String::as_str))?;
        state
    } else {
        table.check_new()?;
        TableState::default()
    };
    let staging = table.staging_dir()?;
    let name = format!("part-{}.parquet", random_uuid());
    let partition_fields = std::iter::once((SEGMENT_COLUMN, "string"))
        .chain(write.partitions.iter().map(|(n, t)| (n.as_str(), *t)))
        .map(|(name, delta_type)| {
            json!({ "name": name, "type": delta_type, "nullable": true, "metadata": {} })
        });
    let fields: Vec<Value> = partition_fields.chain(schema.fields).collect();
    let placed: Mutex<Vec<Staged>> = Mutex::new(Vec::new());
    let place = |written: &HiveSummary| -> Result<(), DeltaError> {
        let files = staged_files(staging.path(), written)?;
        // Recorded first: a file that fails half-placed is removed with the rest.
        placed.lock().extend(files.iter().cloned());
        place_all(table, &files)
    };
    let result = files(staging.path(), &name, &place).and_then(|_| {
        let mut staged = placed.lock();
        // In the table's order, whichever thread placed them.
        staged.sort_by(|a, b| a.relative.cmp(&b.relative));
        Ok(commit(write, state, &fields, &partition_names, &staged)?)
    });
    if result.is_err() {
        for file in placed.lock().iter() {
            table.remove_placed(&file.relative);
        }
    }
    drop(staging);
    result
}

/// The commit loop: the next version, written if absent; after a lost race, the winners
/// read and the commit tried again at the version after theirs.
fn commit(
    write: &DeltaWrite<'_>,
    mut state: TableState,
    fields: &[Value],
    partition_names: &[String],
    staged: &[Staged],
) -> Result<DeltaCommit, DeltaError> {
    let adds: Vec<AddFile> = staged.iter().map(|s| s.add.clone()).collect();
    let segments: BTreeSet<&str> = adds.iter().filter_map(segment_of).collect();
    let mut retries = 0;
    loop {
        let version = state.version.map_or(0, |v| v + 1);
        let (merged, changed) = merged_fields(&state.fields, fields)?;
        let id = if state.id.is_empty() {
            random_uuid()
        } else {
            state.id.clone()
        };
        let metadata = changed.then_some((id.as_str(), &merged[..], partition_names));
        let text = commit_text(version == 0, metadata, &adds, now_ms());
        if write
            .table
            .put_log_if_absent(&entry_name(version), text.into_bytes())?
        {
            return Ok(DeltaCommit {
                version,
                files: staged
                    .iter()
                    .map(|s| (s.relative.clone(), s.summary))
                    .collect(),
                segments: segments.iter().map(|s| (*s).to_owned()).collect(),
                retries,
            });
        }
        if !write.append {
            return Err(DeltaError::Exists {
                table: write.table.name(),
            });
        }
        retries += 1;
        catch_up(write.table, &mut state)?;
        check_segments(&state, segments.iter().copied())?;
    }
}

fn segment_of(add: &AddFile) -> Option<&str> {
    add.partition_values
        .iter()
        .find(|(k, _)| k == SEGMENT_COLUMN)
        .map(|(_, v)| v.as_str())
}

/// The staged files as the commit adds them: their paths in the table, their partition
/// values read back from their directories' names.
fn staged_files(staging: &Path, summary: &HiveSummary) -> Result<Vec<Staged>, DeltaError> {
    let mut staged = Vec::with_capacity(summary.files.len());
    for (file, written) in summary.files.iter().cloned() {
        let relative = file.strip_prefix(staging).map_err(|_| {
            DeltaError::io(
                file.display().to_string(),
                std::io::Error::other("a staged file outside the staging directory"),
            )
        })?;
        let parts: Vec<String> = relative
            .components()
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect();
        let partition_values = parts[..parts.len().saturating_sub(1)]
            .iter()
            .filter_map(|dir| dir.split_once('='))
            .map(|(key, value)| {
                (
                    key.to_owned(),
                    crate::parquet::unescape_partition_value(value),
                )
            })
            .collect();
        let relative = parts.join("/");
        staged.push(Staged {
            add: AddFile {
                path: log_path(&relative),
                partition_values,
                size: written.bytes,
                rows: written.rows,
                stats: Some(super::stats::file_stats(&file, written.rows)?),
            },
            file,
            relative,
            summary: written,
        });
    }
    Ok(staged)
}

/// Places every staged file, [`TableStore::parallel_places`] at once; the first error
/// stops the rest.
fn place_all(table: &dyn TableStore, staged: &[Staged]) -> Result<(), DeltaError> {
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let error = Mutex::new(None);
    let workers = table.parallel_places().clamp(1, staged.len().max(1));
    std::thread::scope(|scope| {
        for _ in 0..workers {
            scope.spawn(|| {
                while !failed.load(Ordering::Relaxed) {
                    let Some(file) = staged.get(next.fetch_add(1, Ordering::Relaxed)) else {
                        break;
                    };
                    let placed = table.place(&file.file, &file.relative);
                    // An upload leaves its staged copy (a move takes it): not kept.
                    let _ = std::fs::remove_file(&file.file);
                    if let Err(e) = placed {
                        failed.store(true, Ordering::Relaxed);
                        error.lock().get_or_insert(e);
                    }
                }
            });
        }
    });
    error.into_inner().map_or(Ok(()), Err)
}

/// The table's schema with the write's columns: a new column is added (nullable: the
/// table's files so far lack it), a column the write lacks becomes nullable, and a column
/// of another type is an error. `true` when the schema changed (a `metaData` is due).
fn merged_fields(table: &[Value], write: &[Value]) -> Result<(Vec<Value>, bool), DeltaError> {
    if table.is_empty() {
        return Ok((write.to_vec(), true));
    }
    let name = |f: &Value| f.get("name").and_then(Value::as_str).map(str::to_owned);
    let mut merged = table.to_vec();
    let mut changed = false;
    for field in write {
        let field_name = name(field);
        if let Some(existing) = merged.iter_mut().find(|t| name(t) == field_name) {
            if existing.get("type") != field.get("type") {
                return Err(DeltaError::ColumnType {
                    column: field_name.unwrap_or_default(),
                    table: type_text(existing.get("type")),
                    write: type_text(field.get("type")),
                });
            }
            if existing.get("nullable") == Some(&Value::Bool(false))
                && field.get("nullable") != Some(&Value::Bool(false))
            {
                existing["nullable"] = Value::Bool(true);
                changed = true;
            }
        } else {
            let mut added = field.clone();
            added["nullable"] = Value::Bool(true);
            merged.push(added);
            changed = true;
        }
    }
    let written: BTreeSet<Option<String>> = write.iter().map(name).collect();
    for existing in &mut merged {
        if !written.contains(&name(existing))
            && existing.get("nullable") != Some(&Value::Bool(true))
        {
            existing["nullable"] = Value::Bool(true);
            changed = true;
        }
    }
    Ok((merged, changed))
}

/// A Delta type as a person reads it: `long`, `array<double>`, `struct<x: float>`,
/// `map<string, long>` (the log's JSON where it is none of these).
fn type_text(delta_type: Option<&Value>) -> String {
    let Some(delta_type) = delta_type else {
        return "untyped".into();
    };
    if let Value::String(text) = delta_type {
        return text.clone();
    }
    let part = |key: &str| type_text(delta_type.get(key));
    match delta_type.get("type").and_then(Value::as_str) {
        Some("array") => format!("array<{}>", part("elementType")),
        Some("map") => format!("map<{}, {}>", part("keyType"), part("valueType")),
        Some("struct") => {
            let fields: Vec<String> = delta_type
                .get("fields")
                .and_then(Value::as_array)
                .into_iter()
                .flatten()
                .map(|f| {
                    let name = f.get("name").and_then(Value::as_str).unwrap_or("?");
                    format!("{name}: {}", type_text(f.get("type")))
                })
                .collect();
            format!("struct<{}>", fields.join(", "))
        }
        _ => delta_type.to_string(),
    }
}

/// The segments a write adds must not be in the table.
fn check_segments<'a>(
    state: &TableState,
    segments: impl IntoIterator<Item = &'a str>,
) -> Result<(), DeltaError> {
    let present = state.segments();
    match segments.into_iter().find(|s| present.contains(s)) {
        Some(segment) => Err(DeltaError::SegmentExists {
            segment: segment.to_owned(),
        }),
        None => Ok(()),
    }
}

/// The table as its whole log says (no log: an empty state).
fn read_state(table: &dyn TableStore) -> Result<TableState, DeltaError> {
    let mut state = TableState::default();
    catch_up(table, &mut state)?;
    Ok(state)
}

/// Applies the log entries after `state.version`, in order.
fn catch_up(table: &dyn TableStore, state: &mut TableState) -> Result<(), DeltaError> {
    let names = table.log_files()?;
    if names.iter().any(|n| is_checkpoint(n)) {
        return Err(DeltaError::UnsupportedTable {
            reason: "its log has a checkpoint (chunkstore reads JSON commits only)".into(),
        });
    }
    let mut versions: Vec<(u64, String)> = names
        .into_iter()
        .filter_map(|n| entry_version(&n).map(|v| (v, n)))
        .filter(|(v, _)| state.version.is_none_or(|read| *v > read))
        .collect();
    versions.sort();
    for (version, name) in versions {
        let expected = state.version.map_or(0, |v| v + 1);
        if version != expected {
            return Err(DeltaError::UnsupportedTable {
                reason: format!("its log has version {version} where {expected} was expected"),
            });
        }
        let bytes = table.read_log(&name)?;
        let text = String::from_utf8(bytes).map_err(|_| DeltaError::BadLog {
            file: name.clone(),
            reason: "not UTF-8".into(),
        })?;
        state.apply(version, &name, &text)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::type_text;

    #[test]
    fn nested_types_read_as_a_person_writes_them() {
        let list = json!({"type": "array", "elementType": "double", "containsNull": true});
        assert_eq!(type_text(Some(&list)), "array<double>");
        let nested = json!({
            "type": "struct",
            "fields": [
                {"name": "x", "type": list, "nullable": true, "metadata": {}},
                {"name": "m", "type": {"type": "map", "keyType": "string", "valueType": "long"}},
            ]
        });
        assert_eq!(
            type_text(Some(&nested)),
            "struct<x: array<double>, m: map<string, long>>"
        );
        assert_eq!(type_text(Some(&json!("long"))), "long");
        assert_eq!(type_text(Some(&json!({"type": 7}))), "{\"type\":7}");
        assert_eq!(type_text(None), "untyped");
    }
}
