//! A directory of Arrow IPC chunk files keeps its recording's identity in one small file
//! beside the chunks, [`STORE_INFO_FILE`]: the recording's `SetStoreInfo` message body,
//! as an `.rrd` stream carries it (store id, application id, and the store source and
//! version kept verbatim). Chunk files carry no store id, so without it an `.rrd` turned
//! into a directory and back would come out under a made-up recording id.

use std::path::Path;

use super::error::{RrdError, RrdErrorKind};
use super::messages::StoreInfo;

/// The file in a directory of chunk files that names its recording.
pub const STORE_INFO_FILE: &str = "store_info.pb";

/// The recording's store info of a directory of chunk files, if it has one.
///
/// # Errors
/// If the file exists but cannot be read or decoded ([`RrdError::offset`] is within it).
pub fn read_directory_store_info(dir: &Path) -> Result<Option<StoreInfo>, RrdError> {
    match std::fs::read(dir.join(STORE_INFO_FILE)) {
        Ok(bytes) => decode_directory_store_info(&bytes).map(Some),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(RrdError::new(0, RrdErrorKind::Io(e))),
    }
}

/// The store info a [`STORE_INFO_FILE`] holds (`bytes`, read from wherever it is kept).
///
/// # Errors
/// If it does not decode ([`RrdError::offset`] is within it).
pub fn decode_directory_store_info(bytes: &[u8]) -> Result<StoreInfo, RrdError> {
    StoreInfo::decode_set_store_info(bytes).map_err(|(at, kind)| RrdError::new(at as u64, kind))
}

/// The recording of a directory of chunk files ([`read_directory_store_info`]), checked
/// against the one asked for: a directory holds one recording, so asking for another is
/// an error naming the one it holds (a directory without a store info names none).
///
/// # Errors
/// As [`read_directory_store_info`], and [`RrdErrorKind::NoSuchRecording`].
pub fn read_directory_recording(
    dir: &Path,
    recording_id: Option<&str>,
) -> Result<Option<StoreInfo>, RrdError> {
    choose_directory_recording(read_directory_store_info(dir)?.as_ref(), recording_id)
}

/// A directory's recording (its store info, if it has one: `info`), checked against the
/// one asked for, as [`read_directory_recording`] checks it.
///
/// # Errors
/// [`RrdErrorKind::NoSuchRecording`].
pub fn choose_directory_recording(
    info: Option<&StoreInfo>,
    recording_id: Option<&str>,
) -> Result<Option<StoreInfo>, RrdError> {
    let mut selector = super::RecordingSelector::new(recording_id);
    if let Some(info) = info {
        selector.observe(info);
    }
    selector.finish().map_err(|kind| RrdError::new(0, kind))
}

/// Writes `info` into a directory of chunk files (see the module docs).
///
/// # Errors
/// If the file cannot be written.
pub fn write_directory_store_info(dir: &Path, info: &StoreInfo) -> Result<(), RrdError> {
    let bytes = info.encode_set_store_info(crate::RowId::new().as_u128());
    std::fs::write(dir.join(STORE_INFO_FILE), bytes)
        .map_err(|e| RrdError::new(0, RrdErrorKind::Io(e)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rrd::StoreId;

    #[test]
    fn a_store_info_round_trips_through_a_directory() {
        let dir = std::env::temp_dir().join(format!("chunkstore-dirinfo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert!(read_directory_store_info(&dir).unwrap().is_none());
        let info = StoreInfo::new(StoreId::recording("app", "rec-1"));
        write_directory_store_info(&dir, &info).unwrap();
        assert_eq!(read_directory_store_info(&dir).unwrap(), Some(info));
        std::fs::write(dir.join(STORE_INFO_FILE), b"\x0f\xff").unwrap();
        assert!(read_directory_store_info(&dir).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
