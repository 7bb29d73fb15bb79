//! Opening a dataset: listing a directory's `.rrd` files, opening each through its footer
//! (or reading it whole, or through the index cache, when it has none) on several threads,
//! and checking that the segments agree (one file per recording, one type per timeline).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use parking_lot::Mutex;

use super::cache::SegmentCache;
use super::threads::in_parallel;
use super::{
    Dataset, DatasetError, DatasetOptions, Inner, Opened, ReadStats, SegmentInfo, Warnings,
    index_cache,
};
use crate::TimeType;
use crate::recording::{LoadedRecording, OpenError, OpenOptions, RecordingReader};
use crate::rrd::LazyRecording;
use crate::storage::Input;

impl Dataset {
    /// Opens a dataset directory (its regular `*.rrd` files) or a single `.rrd` file,
    /// reading footers only.
    ///
    /// # Errors
    /// A directory without `.rrd` files, a file that cannot be opened (unless skipped),
    /// two files of one recording, a timeline of different types in two segments.
    pub fn open(path: &Path, options: &DatasetOptions) -> Result<Self, DatasetError> {
        if crate::storage::url_scheme(path).is_some() {
            return Self::open_url(path, options);
        }
        let path = crate::storage::local_path(path);
        let files = if std::fs::metadata(path)
            .map_err(|source| DatasetError::Io {
                path: path.to_owned(),
                source,
            })?
            .is_dir()
        {
            rrd_files(path, options.index_cache.as_deref())?
        } else {
            (vec![path.to_owned()], Vec::new())
        };
        let (files, notes) = files;
        if files.is_empty() {
            return Err(DatasetError::NoRrdFiles {
                dir: path.to_owned(),
            });
        }
        Self::open_files_noting(&files, options, notes)
    }

    /// Opens a dataset of these `.rrd` files.
    ///
    /// # Errors
    /// As [`Dataset::open`].
    pub fn open_files(files: &[PathBuf], options: &DatasetOptions) -> Result<Self, DatasetError> {
        Self::open_files_noting(files, options, Vec::new())
    }

    /// [`Dataset::open_files`], with warnings from listing the directory first.
    fn open_files_noting(
        files: &[PathBuf],
        options: &DatasetOptions,
        notes: Vec<String>,
    ) -> Result<Self, DatasetError> {
        if files.is_empty() {
            return Err(DatasetError::NoRrdFiles {
                dir: PathBuf::new(),
            });
        }
        let warnings = Mutex::new(notes);
        let results = in_parallel(files, options.threads, |path| {
            if crate::storage::url_scheme(path).is_some() {
                open_object(path, options, &warnings)
            } else {
                open_file(path, options, &warnings)
            }
        });
        Self::from_opened(files, results, options, warnings)
    }

    /// The dataset of the files `files` whose opening gave `results`.
    pub(super) fn from_opened(
        files: &[PathBuf],
        results: Vec<Result<Opened, DatasetError>>,
        options: &DatasetOptions,
        warnings: Mutex<Vec<String>>,
    ) -> Result<Self, DatasetError> {
        let mut opened = Vec::with_capacity(files.len());
        for (path, result) in files.iter().zip(results) {
            match result {
                Ok(file) => opened.push(file),
                Err(error) if options.skip_bad => {
                    warnings
                        .lock()
                        .push(format!("skipped {}: {error}", path.display()));
                }
                Err(error) => return Err(error),
            }
        }
        opened.sort_by(|a, b| a.info.id.cmp(&b.info.id));
        if let Some(pair) = opened.windows(2).find(|w| w[0].info.id == w[1].info.id) {
            if !options.skip_bad {
                return Err(DatasetError::DuplicateRecording {
                    id: pair[0].info.id.clone(),
                    first: pair[0].info.path.clone(),
                    second: pair[1].info.path.clone(),
                });
            }
            // With skip_bad, a second file of a recording is a bad file like any other:
            // the first (in path order) stays.
            let mut kept: Vec<Opened> = Vec::with_capacity(opened.len());
            for file in opened {
                match kept.last() {
                    Some(last) if last.info.id == file.info.id => warnings.lock().push(format!(
                        "skipped {}: recording {:?} is in {} already",
                        file.info.path.display(),
                        file.info.id,
                        last.info.path.display()
                    )),
                    _ => kept.push(file),
                }
            }
            opened = kept;
        }
        check_timeline_types(opened.iter().map(|o| &o.info))?;
        let mut cache = SegmentCache::new(options.memory_budget);
        for (number, file) in opened.iter_mut().enumerate() {
            if let Some(snapshot) = file.loaded.take() {
                cache.insert(number, snapshot);
            }
        }
        #[cfg(feature = "object-store")]
        let objects = opened.iter_mut().map(|o| o.object.take()).collect();
        Ok(Self {
            inner: Arc::new(Inner {
                #[cfg(feature = "object-store")]
                objects,
                segments: opened.into_iter().map(|o| o.info).collect(),
                options: options.clone(),
                cache: Mutex::new(cache),
                warnings,
                read: Mutex::new(ReadStats::default()),
                tables: Mutex::new(None),
            }),
        })
    }
}

/// The regular `.rrd` files directly in `dir`, sorted by name, each file once (a link to
/// a file beside it is the same file); and what to warn of: the links left out, the
/// subdirectories holding `.rrd` files but `index_cache` (a dataset is the files directly
/// in `dir`).
fn rrd_files(
    dir: &Path,
    index_cache: Option<&Path>,
) -> Result<(Vec<PathBuf>, Vec<String>), DatasetError> {
    let cache = index_cache.and_then(|c| std::fs::canonicalize(c).ok());
    let io = |source| DatasetError::Io {
        path: dir.to_owned(),
        source,
    };
    // Each `.rrd` file with whether its entry is a link (the entry says so: no call).
    let mut files: Vec<(PathBuf, bool)> = Vec::new();
    let mut subdirectories = 0usize;
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let entry = entry.map_err(io)?;
        let is_link = entry.file_type().is_ok_and(|kind| kind.is_symlink());
        let path = entry.path();
        if is_rrd_name(&path) && path.is_file() {
            files.push((path, is_link));
        } else if path.is_dir()
            && cache.as_deref() != std::fs::canonicalize(&path).ok().as_deref()
            && std::fs::read_dir(&path).is_ok_and(|mut inner| {
                inner.any(|e| e.is_ok_and(|e| is_rrd_name(&e.path()) && e.path().is_file()))
            })
        {
            subdirectories += 1;
        }
    }
    let mut notes = Vec::new();
    if subdirectories > 0 {
        notes.push(format!(
            "{}: {subdirectories} subdirectories hold .rrd files, which are not read (a \
             dataset is the .rrd files directly in the directory)",
            dir.display()
        ));
    }
    // A link to a file of the dataset: the file is read once, under its own name. A
    // regular file's real path is the real directory's and its name; only links need
    // resolving.
    let real_dir = std::fs::canonicalize(dir).unwrap_or_else(|_| dir.to_owned());
    // Real files first, so that a link gives way to the file it names.
    files.sort_by(|a, b| (a.1, &a.0).cmp(&(b.1, &b.0)));
    let mut by_real: ahash::HashMap<PathBuf, PathBuf> = ahash::HashMap::default();
    let mut unique = Vec::with_capacity(files.len());
    for (path, is_link) in files {
        let real = if is_link {
            std::fs::canonicalize(&path).unwrap_or_else(|_| path.clone())
        } else {
            path.file_name()
                .map_or_else(|| path.clone(), |name| real_dir.join(name))
        };
        match by_real.entry(real) {
            std::collections::hash_map::Entry::Occupied(first) => notes.push(format!(
                "{}: the same file as {}, read once",
                path.display(),
                first.get().display()
            )),
            std::collections::hash_map::Entry::Vacant(slot) => {
                slot.insert(path.clone());
                unique.push(path);
            }
        }
    }
    unique.sort();
    Ok((unique, notes))
}

fn is_rrd_name(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("rrd"))
}

/// Does `dir` hold a regular `.rrd` file (is it a dataset directory)? `false` if it
/// cannot be listed.
pub fn is_dataset_dir(dir: &Path) -> bool {
    rrd_files(dir, None).is_ok_and(|(files, _)| !files.is_empty())
}

/// One file's segment: from its footer, or read whole if it has none.
fn open_file(
    path: &Path,
    options: &DatasetOptions,
    warnings: &Mutex<Vec<String>>,
) -> Result<Opened, DatasetError> {
    let metadata = std::fs::metadata(path).map_err(|source| OpenError::Io {
        path: path.to_owned(),
        source,
    })?;
    let file_bytes = metadata.len();
    if crate::recording::SourceKind::detect(path)? != crate::recording::SourceKind::Rrd {
        return Err(DatasetError::NotRrd {
            path: path.to_owned(),
        });
    }
    match LazyRecording::open(path) {
        Ok(Some(lazy)) => {
            let info = lazy
                .store_info()
                .cloned()
                .ok_or_else(|| DatasetError::NoRecordingId {
                    path: path.to_owned(),
                })?;
            let mut lazy = lazy.map_input(Input::File);
            let reader = RecordingReader::lazy(&mut lazy);
            Ok(Opened::new(
                SegmentInfo::read(path, &info.store_id, &reader, file_bytes, true),
                None,
            ))
        }
        Ok(None) => match &options.index_cache {
            Some(dir) if !options.skip_bad => {
                index_cache::open_indexed(path, dir, options, &metadata)
            }
            _ => load_whole(path, options, warnings, file_bytes),
        },
        Err(error) => footer_failed(path, error, options, warnings, file_bytes),
    }
}

/// A file whose footer could not be read: an error, or (`skip_bad`, a corrupt footer) the
/// file read whole, message by message.
fn footer_failed(
    path: &Path,
    error: crate::rrd::RrdError,
    options: &DatasetOptions,
    warnings: &Mutex<Vec<String>>,
    file_bytes: u64,
) -> Result<Opened, DatasetError> {
    if error.is_recording_choice() {
        return Err(OpenError::rrd(path, error).into());
    }
    if options.skip_bad {
        return load_whole(path, options, warnings, file_bytes);
    }
    Err(OpenError::Footer {
        path: path.to_owned(),
        error,
    }
    .into())
}

fn load_whole(
    path: &Path,
    options: &DatasetOptions,
    warnings: &Mutex<Vec<String>>,
    file_bytes: u64,
) -> Result<Opened, DatasetError> {
    let open = OpenOptions {
        config: options.config,
        skip_bad: options.skip_bad,
        lazy: false,
        storage: options.storage.clone(),
        ..OpenOptions::default()
    };
    let loaded = LoadedRecording::load(path, &open, &mut Warnings(warnings))?;
    let info = loaded
        .store_info
        .as_ref()
        .ok_or_else(|| DatasetError::NoRecordingId {
            path: path.to_owned(),
        })?;
    let store = &loaded.store;
    Ok(Opened::new(
        SegmentInfo::read(
            path,
            &info.store_id,
            &RecordingReader::view(store),
            file_bytes,
            false,
        ),
        Some(store.snapshot()),
    ))
}

/// A timeline has one type across the segments.
fn check_timeline_types<'a>(
    segments: impl Iterator<Item = &'a SegmentInfo>,
) -> Result<(), DatasetError> {
    let mut seen: ahash::HashMap<&str, (&str, TimeType)> = ahash::HashMap::default();
    for segment in segments {
        for (timeline, _) in &segment.timelines {
            let here = (segment.id.as_str(), timeline.time_type());
            match seen.get(timeline.name()) {
                Some(&(first, time_type)) if time_type != here.1 => {
                    return Err(DatasetError::TimelineTypeConflict {
                        timeline: timeline.name().to_owned(),
                        first: (first.to_owned(), time_type),
                        second: (here.0.to_owned(), here.1),
                    });
                }
                Some(_) => {}
                None => {
                    seen.insert(timeline.name(), here);
                }
            }
        }
    }
    Ok(())
}

/// A dataset file named by URL and not opened yet (outside [`Dataset::open_url`]'s
/// listing): opened through its footer, or read whole if it has none.
fn open_object(
    path: &Path,
    options: &DatasetOptions,
    warnings: &Mutex<Vec<String>>,
) -> Result<Opened, DatasetError> {
    let input =
        crate::storage::open_input(path, &options.storage).map_err(|source| OpenError::Io {
            path: path.to_owned(),
            source,
        })?;
    opened_object(path, input, options, warnings)
}

/// A dataset file in an object store, its end fetched already (in `input`): opened from
/// its footer alone (its manifest names the recording), or read whole if it has none.
pub(super) fn opened_object(
    path: &Path,
    input: Input,
    options: &DatasetOptions,
    warnings: &Mutex<Vec<String>>,
) -> Result<Opened, DatasetError> {
    let file_bytes = input.size().unwrap_or(0);
    #[cfg(feature = "object-store")]
    let object = match &input {
        Input::Object(object) => Some(object.clone()),
        Input::File(_) => None,
    };
    match LazyRecording::from_reader_footer(input, None) {
        Ok(Some(mut lazy)) => {
            let store = lazy.manifest().store_id.clone();
            let reader = RecordingReader::lazy(&mut lazy);
            let info = SegmentInfo::read(path, &store, &reader, file_bytes, true);
            #[cfg(feature = "object-store")]
            let object = object.map(|mut object| {
                object.keep_from(lazy.footers_start());
                object
            });
            Ok(Opened {
                info,
                loaded: None,
                #[cfg(feature = "object-store")]
                object,
            })
        }
        Ok(None) => {
            #[cfg(feature = "object-store")]
            if let (Some(dir), Some(object), false) =
                (&options.index_cache, object, options.skip_bad)
                && let Some(opened) = index_cache::open_indexed_object(path, object, dir, options)
            {
                return opened;
            }
            load_whole(path, options, warnings, file_bytes)
        }
        Err(error) => footer_failed(path, error, options, warnings, file_bytes),
    }
}
