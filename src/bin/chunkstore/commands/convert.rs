//! `convert`: the source written as an `.rrd` file or a directory of chunk files,
//! atomically, never over the source.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use chunkstore::rrd::{StoreId, StoreInfo};
use chunkstore::{Chunk, StoreConfig};

use crate::Failure;
use crate::load::{self, Options};
use crate::source::Source;

/// `convert OUT` of `source` (a recording: a dataset is many).
pub fn run(
    source: &Source,
    out: &Path,
    application_id: &str,
    recording_id: Option<&str>,
) -> Result<(), Failure> {
    match source {
        Source::Recording(recording) => {
            recording.refuse_to_overwrite(out)?;
            convert(
                &recording.path,
                out,
                &recording.options,
                application_id,
                recording_id,
            )
        }
        Source::Dataset(dataset) => Err(dataset.unanswered()),
    }
}

fn convert(
    source: &Path,
    out: &Path,
    options: &Options,
    application_id: &str,
    recording_id: Option<&str>,
) -> Result<(), Failure> {
    // Without `--compact`, the chunks go out as they came in: no compaction on insert.
    let load_options = options.clone().with_config(if options.compact {
        options.config
    } else {
        StoreConfig::COMPACTION_OFF
    });
    let loaded = load::load_in_order(source, &load_options)?;
    let chunks: Vec<Arc<Chunk>> = if options.compact {
        // What the store holds and the Clears it still applies (`export_chunks`), entity
        // by entity, each in time order: what a reader scans best.
        let mut chunks = loaded.store.export_chunks();
        chunks.sort_by_cached_key(|c| {
            let start = c.time_columns().first().map(|t| t.time_range().min());
            (c.entity_path().clone(), start, c.id())
        });
        chunks
    } else {
        loaded.in_source_order
    };
    if loaded.skipped_blueprint_messages > 0 {
        eprintln!(
            "warning: {}: left out its blueprint ({} messages): chunkstore keeps recordings only",
            source.display(),
            loaded.skipped_blueprint_messages
        );
    }
    let is_rrd = out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("rrd"));
    // The recording keeps its own identity (its store info, not a blueprint's); a source
    // without one (chunk files) is named by the options or the file name.
    let info = loaded.store_info.unwrap_or_else(|| {
        let recording = recording_id.map_or_else(
            || {
                source.file_stem().map_or_else(
                    || "recording".to_owned(),
                    |s| s.to_string_lossy().into_owned(),
                )
            },
            str::to_owned,
        );
        StoreInfo::new(StoreId::recording(application_id, recording))
    });
    if is_rrd {
        let bar = load::progress(chunks.len() as u64, "writing", false);
        crate::output::write_output(out, |out| {
            let result = chunkstore::rrd::write_rrd_file(out, &info, chunks, |_| bar.inc(1));
            bar.finish_and_clear();
            result
                .map(drop)
                .map_err(|e| crate::about_path(out, e).into())
        })?;
    } else if chunkstore::storage::url_scheme(out).is_some() {
        return Err(format!(
            "{}: a directory of chunk files is written locally; to object storage, convert \
             to an .rrd (a name ending in .rrd)",
            out.display()
        )
        .into());
    } else {
        write_directory(out, &info, &chunks)?;
    }
    Ok(())
}

/// Writes one IPC file per chunk, and the recording's store info, into a temporary
/// directory beside `out`, then renames it to `out` (which must not exist, or be an empty
/// directory).
fn write_directory(out: &Path, info: &StoreInfo, chunks: &[Arc<Chunk>]) -> Result<(), String> {
    let name = out.display();
    // A link to an empty directory is written through: the directory it names is
    // replaced, the link kept.
    let resolved;
    let out = if std::fs::symlink_metadata(out).is_ok_and(|m| m.file_type().is_symlink()) {
        resolved = out.canonicalize().map_err(|e| format!("{name}: {e}"))?;
        resolved.as_path()
    } else {
        out
    };
    if let Ok(mut entries) = std::fs::read_dir(out)
        && entries.next().is_some()
    {
        return Err(format!("{name}: the directory exists and is not empty"));
    }
    if out.exists() && !out.is_dir() {
        return Err(format!(
            "{name}: a file exists there (an .rrd output needs a name ending .rrd)"
        ));
    }
    let file_name = out
        .file_name()
        .map_or_else(|| "out".to_owned(), |n| n.to_string_lossy().into_owned());
    let temp: PathBuf = out.with_file_name(format!(".{file_name}.{}.tmp", std::process::id()));
    // Registered, so that an interrupt (SIGINT, SIGTERM) removes it.
    let (_unfinished, ()) =
        chunkstore::output::UnfinishedOutput::create(&temp, |p| std::fs::create_dir(p))
            .map_err(|e| format!("{name}: {e}"))?;
    let result = (|| -> Result<(), String> {
        let width = chunks.len().to_string().len().max(4);
        let bar = load::progress(chunks.len() as u64, "writing", false);
        for (i, chunk) in chunks.iter().enumerate() {
            let path = temp.join(format!("{i:0width$}.arrow"));
            let file =
                std::fs::File::create(&path).map_err(|e| format!("{}: {e}", path.display()))?;
            let mut writer = std::io::BufWriter::new(file);
            chunkstore::ipc::write_chunk_ipc_file(chunk, &mut writer)
                .map_err(|e| format!("{}: {e}", path.display()))?;
            let file = writer
                .into_inner()
                .map_err(|e| format!("{}: {}", path.display(), e.error()))?;
            file.sync_all()
                .map_err(|e| format!("{}: {e}", path.display()))?;
            bar.inc(1);
        }
        bar.finish_and_clear();
        chunkstore::rrd::write_directory_store_info(&temp, info)
            .map_err(|e| format!("{}: {e}", temp.display()))?;
        if out.is_dir() {
            std::fs::remove_dir(out).map_err(|e| format!("{name}: {e}"))?;
        }
        std::fs::rename(&temp, out).map_err(|e| format!("{name}: {e}"))
    })();
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&temp);
    }
    result
}
