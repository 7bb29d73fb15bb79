//! A store that throttles: a fake S3 endpoint on loopback answering `503 SlowDown` to
//! its first requests (or to all of them), and serving one object's ranges after. The
//! client retries with backoff and answers as if nothing happened; a store that never
//! recovers is one line naming the URL after the retries (exit 2 in the tool). Needs no
//! S3 server: these run everywhere.

use std::io::{BufRead, BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use chunkstore::recording::{OpenOptions, Recording};
use chunkstore::storage::StorageErrorKind;

use super::{options, turn};
use crate::common;

/// A fake S3 endpoint serving `object` (under any key) whose first `throttled` requests
/// are answered `503 SlowDown`; it counts the requests it got.
struct Throttling {
    endpoint: String,
    requests: Arc<AtomicUsize>,
}

impl Throttling {
    fn start(object: Vec<u8>, throttled: usize) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let endpoint = format!("http://{}", listener.local_addr().unwrap());
        let requests = Arc::new(AtomicUsize::new(0));
        let counted = Arc::clone(&requests);
        let object = Arc::new(object);
        std::thread::spawn(move || {
            for stream in listener.incoming().flatten() {
                let n = counted.fetch_add(1, Ordering::SeqCst);
                answer(stream, &object, n < throttled);
            }
        });
        Self { endpoint, requests }
    }

    fn requests(&self) -> usize {
        self.requests.load(Ordering::SeqCst)
    }
}

/// Answers one request (and closes the connection): S3's throttling error, or the range
/// of `object` it asks for.
fn answer(stream: TcpStream, object: &[u8], throttle: bool) {
    let mut reader = BufReader::new(stream.try_clone().unwrap());
    let mut range = None;
    loop {
        let mut line = String::new();
        if reader.read_line(&mut line).unwrap_or(0) == 0 || line == "\r\n" {
            break;
        }
        if let Some(value) = line.to_ascii_lowercase().strip_prefix("range: bytes=") {
            range = Some(value.trim().to_owned());
        }
    }
    let mut stream = stream;
    if throttle {
        let body = "<Error><Code>SlowDown</Code><Message>Please reduce your request rate.</Message></Error>";
        let _ = write!(
            stream,
            "HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/xml\r\n\
             Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
            body.len()
        );
        return;
    }
    let total = object.len();
    let (start, end) = match range.as_deref().and_then(|r| r.split_once('-')) {
        Some(("", suffix)) => (total.saturating_sub(suffix.parse().unwrap()), total),
        Some((from, "")) => (from.parse().unwrap(), total),
        Some((from, to)) => (
            from.parse().unwrap(),
            (to.parse::<usize>().unwrap() + 1).min(total),
        ),
        None => (0, total),
    };
    let status = if range.is_some() {
        "206 Partial Content"
    } else {
        "200 OK"
    };
    let _ = write!(
        stream,
        "HTTP/1.1 {status}\r\nContent-Length: {}\r\nContent-Range: bytes {start}-{}/{total}\r\n\
         ETag: \"v1\"\r\nLast-Modified: Mon, 07 Dec 2026 06:00:00 GMT\r\n\
         Connection: close\r\n\r\n",
        end - start,
        end - 1,
    );
    let _ = stream.write_all(&object[start..end]);
}

fn robot_bytes() -> Vec<u8> {
    std::fs::read(common::robot_recording().join("a_robot.rrd")).unwrap()
}

/// Two `SlowDown`s, then the object: the recording opens and answers as its file does,
/// the throttled requests tried again.
#[test]
fn throttled_requests_are_retried_and_the_answer_is_the_files() {
    let _turn = turn();
    let server = Throttling::start(robot_bytes(), 2);
    let storage = options(&server.endpoint);
    let url = std::path::PathBuf::from("s3://throttled/a_robot.rrd");
    let mut ours =
        Recording::open(&url, &OpenOptions::default().with_storage(storage), &mut ()).unwrap();
    let local = common::robot_recording().join("a_robot.rrd");
    let mut theirs = Recording::open(&local, &OpenOptions::default(), &mut ()).unwrap();
    assert_eq!(
        ours.store_info().map(|i| i.store_id.clone()),
        theirs.store_info().map(|i| i.store_id.clone())
    );
    let (a, b) = (ours.load_all().unwrap(), theirs.load_all().unwrap());
    assert_eq!(a.stats().num_rows(), b.stats().num_rows());
    // The two answered 503, then the opening's two GETs and the chunks'.
    assert!(server.requests() >= 4, "{}", server.requests());
}

/// A store that never stops throttling: after 5 retries with backoff (6 requests), one
/// line naming the URL and what the store said; the tool exits 2 with it.
#[test]
fn a_store_that_keeps_throttling_is_one_line_naming_the_url() {
    let _turn = turn();
    let server = Throttling::start(Vec::new(), usize::MAX);
    let storage = options(&server.endpoint);
    let url = "s3://throttled/run.rrd";
    let started = std::time::Instant::now();
    let error = Recording::open(
        std::path::Path::new(url),
        &OpenOptions::default().with_storage(storage),
        &mut (),
    )
    .unwrap_err();
    let text = error.to_string();
    assert_eq!(server.requests(), 6, "one request and five retries");
    // Each wait of the backoff is at least its first, 100 ms.
    let waited = started.elapsed();
    assert!(
        waited >= std::time::Duration::from_millis(500),
        "backoff: {waited:?}"
    );
    assert!(text.starts_with(url), "{text}");
    assert!(text.contains("SlowDown") || text.contains("503"), "{text}");
    assert_eq!(text.lines().count(), 1, "{text}");
    let source = std::error::Error::source(&error)
        .and_then(|e| e.downcast_ref::<std::io::Error>())
        .and_then(chunkstore::storage::StorageError::from_io);
    assert!(
        matches!(source.map(|e| &e.kind), Some(StorageErrorKind::Request(_))),
        "{error:?}"
    );

    let output = Command::new(env!("CARGO_BIN_EXE_chunkstore"))
        .args([url, "stats"])
        .env("AWS_ENDPOINT_URL", &server.endpoint)
        .env("AWS_ALLOW_HTTP", "true")
        .env("AWS_ACCESS_KEY_ID", "key")
        .env("AWS_SECRET_ACCESS_KEY", "secret")
        .env("AWS_REGION", "us-east-1")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains(url) && stderr.contains("SlowDown"),
        "{stderr}"
    );
    assert_eq!(server.requests(), 12, "the tool's open: six more");
}
