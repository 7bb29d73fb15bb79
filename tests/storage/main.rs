//! Object storage (feature `object-store`) against a real S3 server: `SeaweedFS`, which
//! `.ci/run` starts (`scripts/s3_test_server.sh`) and names in `CHUNKSTORE_TEST_S3`
//! (`http://127.0.0.1:8333`, keys `key`/`secret`). Without it the tests say so and pass,
//! except under CI (`CI` set), where they fail: CI must run them.
//!
//! Each test writes under its own prefix of one bucket. The request counters are the
//! process's, so the tests take turns (`turn`).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::result_large_err,
    clippy::cast_possible_truncation,
    reason = "tests fail loudly on unexpected values; counts are small"
)]

#[path = "../common/mod.rs"]
mod common;

mod cli;
mod dataset;
mod delta;
mod faults;
mod recording;

// The judges of local files, Rerun 0.41's own answers, asked of the same files read from
// the bucket (`recording::rerun_answers_hold_for_the_recording_read_from_a_bucket`).
#[path = "../core/dataframe_oracle.rs"]
mod dataframe_oracle;
#[path = "../core/real_data.rs"]
mod real_data;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use chunkstore::storage::StorageOptions;
use chunkstore::storage::object::{StorageCounters, counters, upload_file};
use parking_lot::{Mutex, MutexGuard};

/// The bucket every test writes under (`SeaweedFS` makes it on the first PUT).
const BUCKET: &str = "chunkstore-test";

/// The S3 server's endpoint, or `None` (the test then passes without running, outside CI).
fn endpoint() -> Option<String> {
    match std::env::var("CHUNKSTORE_TEST_S3") {
        Ok(endpoint) if !endpoint.is_empty() => Some(endpoint),
        _ if std::env::var_os("CI").is_some() => {
            panic!("CI runs the object storage tests: CHUNKSTORE_TEST_S3 must name an S3 server")
        }
        _ => {
            eprintln!("skipped: CHUNKSTORE_TEST_S3 names no S3 server");
            None
        }
    }
}

/// The options that reach the test server, given explicitly (the CLI tests use the
/// environment instead).
fn options(endpoint: &str) -> StorageOptions {
    StorageOptions::default()
        .with("aws_endpoint", endpoint)
        .with("aws_allow_http", "true")
        .with("aws_access_key_id", "key")
        .with("aws_secret_access_key", "secret")
        .with("aws_region", "us-east-1")
}

/// A test's part of the S3 server: the endpoint, the options that reach it, a prefix of
/// its own (`name`), and its turn (held until the test ends), once the tests before it are
/// done; `None` without a server ([`endpoint`]).
fn bucket(name: &str) -> Option<(String, StorageOptions, String, MutexGuard<'static, ()>)> {
    let endpoint = endpoint()?;
    let turn = turn();
    let storage = options(&endpoint);
    Some((endpoint, storage, prefix(name), turn))
}

/// One test at a time: the request counters are the process's.
fn turn() -> MutexGuard<'static, ()> {
    static TURN: Mutex<()> = Mutex::new(());
    TURN.lock()
}

/// A prefix of the bucket no other test or run uses: `s3://BUCKET/<name>-<pid>-<n>/`.
fn prefix(name: &str) -> String {
    static RUN: std::sync::OnceLock<u128> = std::sync::OnceLock::new();
    let run = RUN.get_or_init(|| chunkstore::RowId::new().as_u128());
    format!("s3://{BUCKET}/{name}-{:x}/", run & 0xffff_ffff_ffff)
}

/// Uploads the local `file` to `url`.
fn upload(file: &Path, url: &str, options: &StorageOptions) {
    upload_file(file, url, options, Arc::new(AtomicBool::new(false)))
        .unwrap_or_else(|e| panic!("uploading {} to {url}: {e}", file.display()));
}

/// What the requests made by `f` were.
fn counted<T>(f: impl FnOnce() -> T) -> (T, StorageCounters) {
    let before = counters();
    let value = f();
    (value, counters().since(&before))
}

/// The URL of `name` under `prefix`, as a path (how the library takes sources).
fn url(prefix: &str, name: &str) -> PathBuf {
    PathBuf::from(format!("{prefix}{name}"))
}
