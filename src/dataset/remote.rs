//! Opening a dataset named by URL: a prefix (`s3://bucket/episodes/`) is listed with one
//! paginated LIST, the end of each `.rrd` object fetched with one GET, many at once, and
//! each segment opened from its footer alone; an object's URL is a dataset of one.

use std::path::Path;

use super::{Dataset, DatasetError, DatasetOptions};
use crate::recording::OpenError;

impl Dataset {
    /// Opens the dataset a URL names ([`Dataset::open`]).
    pub(super) fn open_url(path: &Path, options: &DatasetOptions) -> Result<Self, DatasetError> {
        if !crate::storage::is_prefix_url(path) {
            return Self::open_files(&[path.to_owned()], options);
        }
        #[cfg(feature = "object-store")]
        return open_prefix(path, options);
        #[cfg(not(feature = "object-store"))]
        Err(OpenError::Io {
            path: path.to_owned(),
            source: crate::storage::StorageError::needs_feature(path).into_io(),
        }
        .into())
    }
}

#[cfg(feature = "object-store")]
fn open_prefix(path: &Path, options: &DatasetOptions) -> Result<Dataset, DatasetError> {
    let url = path.to_string_lossy();
    let listed =
        crate::storage::object::list_rrd_objects(&url, &options.storage).map_err(|error| {
            DatasetError::Io {
                path: path.to_owned(),
                source: error.into_io(),
            }
        })?;
    Dataset::open_listed(path, &listed, options)
}

#[cfg(feature = "object-store")]
impl Dataset {
    /// Opens the dataset over the prefix `path` from its listing (`listed`, by
    /// [`list_rrd_objects`](crate::storage::object::list_rrd_objects)): for a caller that
    /// listed it to learn what it holds, so that opening does not list it again.
    ///
    /// # Errors
    /// As [`Dataset::open`].
    pub fn open_listed(
        path: &Path,
        listed: &crate::storage::object::ListedObjects,
        options: &DatasetOptions,
    ) -> Result<Self, DatasetError> {
        use std::path::PathBuf;

        use parking_lot::Mutex;

        use crate::storage::Input;
        use crate::storage::object::open_all;

        let url = path.to_string_lossy();
        if listed.objects.is_empty() {
            return Err(DatasetError::NoRrdFiles {
                dir: path.to_owned(),
            });
        }
        let mut notes = Vec::new();
        if listed.subdirectories > 0 {
            notes.push(format!(
                "{url}: {} prefixes under it are not read (a dataset is the .rrd objects directly \
             under its prefix)",
                listed.subdirectories
            ));
        }
        let files: Vec<PathBuf> = listed
            .objects
            .iter()
            .map(|(location, _)| PathBuf::from(&location.url))
            .collect();
        let work: Vec<_> = files.iter().zip(open_all(listed)).collect();
        let warnings = Mutex::new(notes);
        let results =
            super::threads::in_parallel(&work, options.threads, |(path, object)| match object {
                Ok(object) => super::open::opened_object(
                    path,
                    Input::Object(object.clone()),
                    options,
                    &warnings,
                ),
                Err(error) => Err(OpenError::Io {
                    path: (*path).clone(),
                    source: error.clone().into_io(),
                }
                .into()),
            });
        Dataset::from_opened(&files, results, options, warnings)
    }
}
