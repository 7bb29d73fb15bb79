//! The Delta Lake transaction log: `_delta_log/<version, 20 digits>.json`, one action per
//! line. What chunkstore writes (a commit's actions) and what it reads back of a table
//! before appending to it (the replayed state: schema, partitions, files, segments).

use std::collections::{BTreeMap, BTreeSet};

use serde_json::{Value, json};

use super::DeltaError;

/// The log's directory, relative to the table.
pub(crate) const LOG_DIR: &str = "_delta_log";

/// The highest reader and writer protocol versions chunkstore writes and appends under:
/// a table that asks for more (column mapping, deletion vectors, invariants it would have
/// to enforce) is refused rather than corrupted.
const READER_VERSION: u64 = 1;
const WRITER_VERSION: u64 = 2;

/// The log entry of `version`: its name in the log's directory.
pub(crate) fn entry_name(version: u64) -> String {
    format!("{version:020}.json")
}

/// The version a log file's name holds, for a commit (`NNN….json`); `None` for anything
/// else (checkpoints, `_last_checkpoint`, temporary files).
pub(crate) fn entry_version(name: &str) -> Option<u64> {
    let stem = name.strip_suffix(".json")?;
    (stem.len() == 20 && stem.bytes().all(|b| b.is_ascii_digit()))
        .then(|| stem.parse().ok())
        .flatten()
}

/// Whether a log file's name is a checkpoint's (which chunkstore does not read).
pub(crate) fn is_checkpoint(name: &str) -> bool {
    name == "_last_checkpoint" || name.contains(".checkpoint.")
}

/// A data file a commit adds.
#[derive(Clone, Debug)]
pub(crate) struct AddFile {
    /// The file's path relative to the table, as stored (partition values escaped once).
    pub path: String,
    /// Its partition values, unescaped, in the table's partition order.
    pub partition_values: Vec<(String, String)>,
    /// Its size in bytes.
    pub size: u64,
    /// Its rows.
    pub rows: u64,
    /// Its statistics (`stats`), where read; else the row count alone.
    pub stats: Option<String>,
}

/// A table as its log says it is at `version`.
#[derive(Clone, Debug, Default)]
pub(crate) struct TableState {
    /// The last version read (`None`: no log yet).
    pub version: Option<u64>,
    /// The table's id (its first `metaData`'s).
    pub id: String,
    /// The schema's fields (Delta JSON).
    pub fields: Vec<Value>,
    /// The partition columns.
    pub partition_columns: Vec<String>,
    /// The live data files (relative URI path) and their `segment` partition value.
    pub files: BTreeMap<String, Option<String>>,
    /// Was a `metaData` action read (every table's first commit has one)?
    pub has_metadata: bool,
}

impl TableState {
    /// The segments the table holds.
    pub fn segments(&self) -> BTreeSet<&str> {
        self.files.values().flatten().map(String::as_str).collect()
    }

    /// Applies the log entry `name` of `version` (its text) to the state.
    ///
    /// # Errors
    /// [`DeltaError::BadLog`] for a line that is not an action, a protocol above what
    /// chunkstore writes ([`DeltaError::UnsupportedTable`]).
    pub fn apply(&mut self, version: u64, name: &str, text: &str) -> Result<(), DeltaError> {
        let bad = |reason: String| DeltaError::BadLog {
            file: name.to_owned(),
            reason,
        };
        for (number, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let action: Value =
                serde_json::from_str(line).map_err(|e| bad(format!("line {}: {e}", number + 1)))?;
            if let Some(protocol) = action.get("protocol") {
                let reader = protocol.get("minReaderVersion").and_then(Value::as_u64);
                let writer = protocol.get("minWriterVersion").and_then(Value::as_u64);
                if reader.is_none_or(|v| v > READER_VERSION)
                    || writer.is_none_or(|v| v > WRITER_VERSION)
                {
                    return Err(DeltaError::UnsupportedTable {
                        reason: format!(
                            "its protocol asks for reader version {} and writer version {} \
                             (chunkstore writes under {READER_VERSION} and {WRITER_VERSION})",
                            reader.map_or_else(|| "?".into(), |v| v.to_string()),
                            writer.map_or_else(|| "?".into(), |v| v.to_string()),
                        ),
                    });
                }
            }
            if let Some(metadata) = action.get("metaData") {
                self.apply_metadata(metadata).map_err(bad)?;
            }
            if let Some(add) = action.get("add") {
                let path = add
                    .get("path")
                    .and_then(Value::as_str)
                    .ok_or_else(|| bad("an add without a path".into()))?;
                let segment = add
                    .pointer(&format!("/partitionValues/{}", super::SEGMENT_COLUMN))
                    .and_then(Value::as_str)
                    .map(str::to_owned);
                self.files.insert(path.to_owned(), segment);
            }
            if let Some(path) = action.pointer("/remove/path").and_then(Value::as_str) {
                self.files.remove(path);
            }
        }
        self.version = Some(version);
        Ok(())
    }

    fn apply_metadata(&mut self, metadata: &Value) -> Result<(), String> {
        let schema = metadata
            .get("schemaString")
            .and_then(Value::as_str)
            .ok_or("a metaData without a schemaString")?;
        let schema: Value =
            serde_json::from_str(schema).map_err(|e| format!("its schemaString: {e}"))?;
        let fields = schema
            .get("fields")
            .and_then(Value::as_array)
            .ok_or("a schemaString without fields")?;
        let partitions = metadata
            .get("partitionColumns")
            .and_then(Value::as_array)
            .ok_or("a metaData without partitionColumns")?;
        self.fields.clone_from(fields);
        self.partition_columns = partitions
            .iter()
            .map(|p| {
                p.as_str()
                    .map(str::to_owned)
                    .ok_or("a partition column not text")
            })
            .collect::<Result<_, _>>()?;
        if let Some(id) = metadata.get("id").and_then(Value::as_str) {
            id.clone_into(&mut self.id);
        }
        self.has_metadata = true;
        Ok(())
    }
}

/// A commit's text: its `commitInfo`, the table's `protocol` (first commit only), its
/// `metaData` when the schema is new or wider, and an `add` per file.
pub(crate) fn commit_text(
    first: bool,
    metadata: Option<(&str, &[Value], &[String])>,
    adds: &[AddFile],
    now_ms: u64,
) -> String {
    let mut lines = vec![json!({
        "commitInfo": {
            "timestamp": now_ms,
            "operation": "WRITE",
            "operationParameters": { "mode": if first { "ErrorIfExists" } else { "Append" } },
            "isBlindAppend": !first,
            "engineInfo": concat!("chunkstore/", env!("CARGO_PKG_VERSION")),
        }
    })];
    if first {
        lines.push(json!({
            "protocol": { "minReaderVersion": READER_VERSION, "minWriterVersion": WRITER_VERSION }
        }));
    }
    if let Some((id, fields, partitions)) = metadata {
        let schema = json!({ "type": "struct", "fields": fields }).to_string();
        lines.push(json!({
            "metaData": {
                "id": id,
                "format": { "provider": "parquet", "options": {} },
                "schemaString": schema,
                "partitionColumns": partitions,
                "configuration": {},
                "createdTime": now_ms,
            }
        }));
    }
    for add in adds {
        let values: serde_json::Map<String, Value> = add
            .partition_values
            .iter()
            .map(|(k, v)| (k.clone(), Value::String(v.clone())))
            .collect();
        lines.push(json!({
            "add": {
                "path": add.path,
                "partitionValues": values,
                "size": add.size,
                "modificationTime": now_ms,
                "dataChange": true,
                "stats": add.stats.clone()
                    .unwrap_or_else(|| json!({ "numRecords": add.rows }).to_string()),
            }
        }));
    }
    let mut text = String::new();
    for line in lines {
        text.push_str(&line.to_string());
        text.push('\n');
    }
    text
}

/// A file's path relative to the table as the log stores it: a URI path, so the `%` of
/// an escaped partition value is escaped again (`entity=%2Fworld` -> `entity=%252Fworld`).
pub(crate) fn log_path(relative: &str) -> String {
    relative.replace('%', "%25")
}

/// A fresh random id, formatted as a UUID (version 4): for a table's id and its files'
/// names. Random from the standard library's per-process hash keys, the time and a
/// counter.
pub(crate) fn random_uuid() -> String {
    use std::hash::{BuildHasher, Hasher};
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    let count = COUNTER.fetch_add(1, Ordering::Relaxed);
    let half = |salt: u64| {
        let mut hasher = std::collections::hash_map::RandomState::new().build_hasher();
        hasher.write_u128(nanos);
        hasher.write_u64(count);
        hasher.write_u32(std::process::id());
        hasher.write_u64(salt);
        hasher.finish()
    };
    let bits = (u128::from(half(1)) << 64) | u128::from(half(2));
    // Version 4, variant 1.
    let bits = (bits & !(0xF << 76) & !(0x3 << 62)) | (0x4 << 76) | (0x2 << 62);
    let hex = format!("{bits:032x}");
    format!(
        "{}-{}-{}-{}-{}",
        &hex[..8],
        &hex[8..12],
        &hex[12..16],
        &hex[16..20],
        &hex[20..]
    )
}

/// Milliseconds since the Unix epoch, now.
pub(crate) fn now_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_millis()).unwrap_or(u64::MAX))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_names_and_ids_are_what_delta_readers_expect() {
        assert_eq!(entry_name(12), "00000000000000000012.json");
        assert_eq!(entry_version("00000000000000000012.json"), Some(12));
        assert_eq!(
            entry_version("00000000000000000012.checkpoint.parquet"),
            None
        );
        assert_eq!(entry_version("12.json"), None);
        assert_eq!(entry_version(".00000000000000000012.json.x.tmp"), None);
        assert!(is_checkpoint("_last_checkpoint"));
        assert!(is_checkpoint("00000000000000000010.checkpoint.parquet"));
        assert_eq!(
            log_path("segment=a/entity=%2Fworld/p.parquet"),
            "segment=a/entity=%252Fworld/p.parquet"
        );
        let ids: std::collections::HashSet<String> = (0..1000).map(|_| random_uuid()).collect();
        assert_eq!(ids.len(), 1000);
        for id in ids.iter().take(10) {
            let parts: Vec<&str> = id.split('-').collect();
            assert_eq!(
                parts.iter().map(|p| p.len()).collect::<Vec<_>>(),
                [8, 4, 4, 4, 12]
            );
            assert!(parts[2].starts_with('4'), "{id}: version 4");
            assert!(
                matches!(&parts[3][..1], "8" | "9" | "a" | "b"),
                "{id}: variant 1"
            );
        }
    }

    /// A commit's text replays to the state it describes; a remove takes a file out.
    #[test]
    fn a_commit_replays_to_its_state() {
        let fields =
            vec![json!({"name": "segment", "type": "string", "nullable": true, "metadata": {}})];
        let partitions = vec!["segment".to_owned()];
        let adds = vec![AddFile {
            path: "segment=a%252Fb/part-1.parquet".into(),
            partition_values: vec![("segment".into(), "a/b".into())],
            size: 10,
            rows: 2,
            stats: None,
        }];
        let text = commit_text(true, Some(("id-1", &fields, &partitions)), &adds, 5);
        let mut state = TableState::default();
        state.apply(0, "0.json", &text).unwrap();
        assert_eq!(state.version, Some(0));
        assert_eq!(state.id, "id-1");
        assert_eq!(state.fields, fields);
        assert_eq!(state.partition_columns, partitions);
        assert_eq!(state.segments().into_iter().collect::<Vec<_>>(), ["a/b"]);
        let remove = "{\"remove\":{\"path\":\"segment=a%252Fb/part-1.parquet\"}}\n";
        state.apply(1, "1.json", remove).unwrap();
        assert!(state.segments().is_empty());
        let error = state.apply(2, "2.json", "not json").unwrap_err();
        assert!(matches!(error, DeltaError::BadLog { .. }), "{error}");
    }
}
