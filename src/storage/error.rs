//! [`StorageError`]: what went wrong with an object, naming its URL.

/// What went wrong reading or writing an object.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum StorageErrorKind {
    /// No such object (or bucket).
    NotFound,
    /// The credentials are missing, wrong, or not allowed to do this.
    AccessDenied,
    /// The object changed (another version was written) since it was opened: its reads
    /// would mix two versions.
    Changed,
    /// The object exists already (a write that must not replace one).
    AlreadyExists,
    /// The URL cannot name an object (a bad scheme, bucket or key), or an option is not
    /// one its store knows.
    BadUrl(String),
    /// The URL names an object store, and this build has no `object-store` feature.
    NeedsFeature,
    /// The request failed after its retries (a network error, a timeout, throttling).
    Request(String),
}

/// What went wrong with the object at `url`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StorageError {
    /// The object's (or prefix's) URL.
    pub url: String,
    /// What went wrong.
    pub kind: StorageErrorKind,
}

impl StorageError {
    /// An error of `kind` at `url`.
    pub fn new(url: impl Into<String>, kind: StorageErrorKind) -> Self {
        Self {
            url: url.into(),
            kind,
        }
    }

    #[cfg(not(feature = "object-store"))]
    pub(crate) fn needs_feature(path: &std::path::Path) -> Self {
        Self::new(path.display().to_string(), StorageErrorKind::NeedsFeature)
    }

    /// As an I/O error of the matching kind, with this error inside (for the readers that
    /// speak `std::io`; [`StorageError::from_io`] takes it back out).
    pub fn into_io(self) -> std::io::Error {
        use std::io::ErrorKind;
        let kind = match self.kind {
            StorageErrorKind::NotFound => ErrorKind::NotFound,
            StorageErrorKind::AccessDenied => ErrorKind::PermissionDenied,
            StorageErrorKind::AlreadyExists => ErrorKind::AlreadyExists,
            StorageErrorKind::BadUrl(_) | StorageErrorKind::NeedsFeature => ErrorKind::InvalidInput,
            StorageErrorKind::Changed | StorageErrorKind::Request(_) => ErrorKind::Other,
        };
        std::io::Error::new(kind, self)
    }

    /// The storage error inside an I/O error made by [`StorageError::into_io`], if any.
    pub fn from_io(error: &std::io::Error) -> Option<&Self> {
        error.get_ref()?.downcast_ref::<Self>()
    }
}

impl std::fmt::Display for StorageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let url = &self.url;
        match &self.kind {
            StorageErrorKind::NotFound => write!(f, "{url}: no such object"),
            StorageErrorKind::AccessDenied => write!(
                f,
                "{url}: access denied (check the credentials: AWS_ACCESS_KEY_ID, \
                 GOOGLE_APPLICATION_CREDENTIALS, AZURE_STORAGE_*, or --storage-option)"
            ),
            StorageErrorKind::Changed => write!(
                f,
                "{url}: the object changed while it was being read (its ETag is not the one \
                 it had when opened); open it again"
            ),
            StorageErrorKind::AlreadyExists => write!(f, "{url}: the object exists already"),
            StorageErrorKind::BadUrl(reason) | StorageErrorKind::Request(reason) => {
                write!(f, "{url}: {reason}")
            }
            StorageErrorKind::NeedsFeature => write!(
                f,
                "{url}: reading object storage needs chunkstore built with the \
                 `object-store` feature"
            ),
        }
    }
}

impl std::error::Error for StorageError {}
