//! Issue 72: a server for deployments. What it is doing (Prometheus metrics and HTTP
//! health on `--metrics-addr`, the gRPC health service on its port, log lines), its stop
//! on SIGTERM, and TLS with a certificate clients are told to trust (`tls/`: a test CA and
//! a server certificate for `localhost`, `127.0.0.1` and `::1`, valid until 2126).

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use arrow_array::Array as _;
use arrow_array::Int64Array;
use chunkstore::rrd::StoreId;
use tonic::transport::{Certificate, Channel, ClientTlsConfig};

use super::server::{
    Raw, Server, chunk_msg, info_msg, open_idle_stream, query, runtime, temp_dir, write_as,
};
use super::web::http1_to;

const HEALTH_CHECK: &str = "/grpc.health.v1.Health/Check";

/// The `--metrics-addr` the server announced.
fn metrics_host(server: &Server) -> String {
    let stderr = server.stderr();
    let line = stderr
        .lines()
        .find(|l| l.starts_with("metrics on http://"))
        .unwrap_or_else(|| panic!("no metrics line: {stderr}"));
    line["metrics on http://".len()..]
        .split('/')
        .next()
        .unwrap()
        .to_owned()
}

/// A scrape, as `(series, value)` lines.
fn scrape(host: &str) -> Vec<(String, f64)> {
    let answer = http1_to(host, "GET", "/metrics", &[], b"");
    assert_eq!(answer.status, 200);
    String::from_utf8(answer.body)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let (series, value) = l.rsplit_once(' ').unwrap();
            (series.to_owned(), value.parse().unwrap())
        })
        .collect()
}

fn value(samples: &[(String, f64)], series: &str) -> Option<f64> {
    samples.iter().find(|(s, _)| s == series).map(|(_, v)| *v)
}

/// `grpc.health.v1.Health/Check` of `service` over `channel`: the status number
/// (1 `SERVING`, 2 `NOT_SERVING`) or the call's error.
async fn health(
    channel: Channel,
    service: &str,
    token: Option<&str>,
) -> Result<u64, tonic::Status> {
    let mut grpc = tonic::client::Grpc::new(channel);
    grpc.ready().await.unwrap();
    // HealthCheckRequest { string service = 1; }
    let mut body = vec![0x0a, u8::try_from(service.len()).unwrap()];
    body.extend_from_slice(service.as_bytes());
    let mut request = tonic::Request::new(body);
    if let Some(token) = token {
        request
            .metadata_mut()
            .insert("authorization", format!("Bearer {token}").parse().unwrap());
    }
    let answer = grpc
        .unary::<Vec<u8>, Vec<u8>, _>(
            request,
            tonic::codegen::http::uri::PathAndQuery::from_static(HEALTH_CHECK),
            Raw,
        )
        .await?
        .into_inner();
    // HealthCheckResponse { ServingStatus status = 1; }: a varint under tag 0x08.
    assert_eq!(answer.first(), Some(&0x08), "{answer:?}");
    Ok(u64::from(answer[1]))
}

#[test]
fn metrics_and_health_answer_and_follow_the_data() {
    let dir = temp_dir("metrics");
    let rt = runtime();
    let persist = dir.join("live.rrd");
    let server = Server::start(
        &dir,
        &[
            "--metrics-addr",
            "127.0.0.1:0",
            "--token",
            "s3cret",
            "--persist",
            persist.to_str().unwrap(),
        ],
    );
    let host = metrics_host(&server);
    let before = scrape(&host);
    assert_eq!(value(&before, "chunkstore_recordings"), Some(0.0));
    let syncs_before = value(&before, "chunkstore_log_sync_seconds_count").unwrap();
    assert!(value(&before, "process_resident_memory_bytes").unwrap() > 0.0);
    let r1 = StoreId::recording("app", "r1");
    rt.block_on(async {
        // Health needs no token: probes have none.
        assert_eq!(health(server.channel().await, "", None).await.unwrap(), 1);
        let proxy = "rerun.sdk_comms.v1alpha1.MessageProxyService";
        assert_eq!(
            health(server.channel().await, proxy, None).await.unwrap(),
            1
        );
        let unknown = health(server.channel().await, "no.such.Service", None).await;
        assert_eq!(unknown.unwrap_err().code(), tonic::Code::NotFound);
        let messages = vec![
            info_msg(&r1),
            chunk_msg(&r1, "/a", 0, 1.0),
            chunk_msg(&r1, "/a", 1, 2.0),
            chunk_msg(&r1, "/b", 2, 3.0),
        ];
        write_as(&server, messages, Some("s3cret")).await.unwrap();
        // A message that does not decode is refused, and counted without a recording.
        let garbage = vec![vec![0x0a, 0x03, 1, 2, 3]];
        let refused = write_as(&server, garbage, Some("s3cret"))
            .await
            .unwrap_err();
        assert_eq!(refused.code(), tonic::Code::InvalidArgument, "{refused}");
        let batches = query(&server, "SELECT count(*) FROM chunks", Some("s3cret"))
            .await
            .unwrap();
        assert_eq!(batches[0].column(0).len(), 1);
        assert!(
            query(&server, "SELECT nonsense(", Some("s3cret"))
                .await
                .is_err()
        );
    });
    let after = scrape(&host);
    let rows = r#"chunkstore_ingested_rows_total{recording="r1"}"#;
    assert_eq!(value(&after, rows), Some(3.0), "{after:?}");
    let messages = r#"chunkstore_ingested_messages_total{recording="r1"}"#;
    assert_eq!(value(&after, messages), Some(4.0));
    let bytes = r#"chunkstore_ingested_bytes_total{recording="r1"}"#;
    assert!(value(&after, bytes).unwrap() > 0.0);
    let refused = r#"chunkstore_refused_messages_total{recording=""}"#;
    assert_eq!(value(&after, refused), Some(1.0), "{after:?}");
    assert_eq!(value(&after, "chunkstore_recordings"), Some(1.0));
    assert!(value(&after, "chunkstore_store_bytes").unwrap() > 0.0);
    assert!(value(&after, "chunkstore_log_bytes").unwrap() > 0.0);
    // The acknowledged stream synced the log.
    assert!(value(&after, "chunkstore_log_sync_seconds_count").unwrap() > syncs_before);
    assert_eq!(value(&after, "chunkstore_query_seconds_count"), Some(1.0));
    assert_eq!(
        value(&after, r#"chunkstore_query_seconds_bucket{le="+Inf"}"#),
        Some(1.0)
    );
    assert_eq!(value(&after, "chunkstore_query_errors_total"), Some(1.0));
    assert_eq!(value(&after, "chunkstore_write_streams"), Some(0.0));
    // HTTP probes, and what is not served there.
    let ok = http1_to(&host, "GET", "/health", &[], b"");
    assert_eq!((ok.status, ok.body.as_slice()), (200, &b"serving\n"[..]));
    assert_eq!(http1_to(&host, "GET", "/nothing", &[], b"").status, 404);
    assert_eq!(http1_to(&host, "POST", "/metrics", &[], b"").status, 405);
    // The refusal left one line naming it.
    let stderr = server.stderr();
    let refusals = stderr
        .lines()
        .filter(|l| l.contains(" WARN log stream from 127.0.0.1:"));
    assert_eq!(refusals.count(), 1, "{stderr}");
    assert!(
        stderr.contains("ended: message 0 of this stream: "),
        "{stderr}"
    );
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `SELECT count(*) FROM {table}`.
async fn count(server: &Server, table: &str) -> i64 {
    let sql = format!("SELECT count(*) AS n FROM {table}");
    let batches = query(server, &sql, None).await.unwrap();
    let n = batches[0]
        .column(0)
        .as_any()
        .downcast_ref::<Int64Array>()
        .unwrap();
    n.value(0)
}

#[test]
fn queries_share_a_context_until_the_data_changes() {
    let dir = temp_dir("sessions");
    let rt = runtime();
    let server = Server::start(&dir, &["--metrics-addr", "127.0.0.1:0"]);
    let host = metrics_host(&server);
    let built = || {
        let samples = scrape(&host);
        let built = value(&samples, "chunkstore_query_sessions_built_total").unwrap();
        // A count, exact in an f64.
        #[expect(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            reason = "a count"
        )]
        let built = built as u64;
        built
    };
    let r1 = StoreId::recording("app", "r1");
    rt.block_on(async {
        write_as(
            &server,
            vec![info_msg(&r1), chunk_msg(&r1, "/a", 0, 1.0)],
            None,
        )
        .await
        .unwrap();
        assert_eq!(count(&server, "frame").await, 1);
        let first = built();
        for _ in 0..3 {
            assert_eq!(count(&server, "frame").await, 1);
        }
        assert_eq!(built(), first, "queries on unchanged data built contexts");
        write_as(&server, vec![chunk_msg(&r1, "/a", 9, 9.0)], None)
            .await
            .unwrap();
        assert_eq!(count(&server, "frame").await, 2, "the new row is seen");
        assert_eq!(built(), first + 1);
    });
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// SIGTERM with a log stream open: health turns to 503, the open stream may still finish
/// within the grace period, the log is synced and the process exits 0.
#[test]
fn sigterm_lets_an_open_stream_finish_then_exits_0() {
    let dir = temp_dir("graceful");
    let rt = runtime();
    let persist = dir.join("live.rrd");
    let mut server = Server::start(
        &dir,
        &[
            "--metrics-addr",
            "127.0.0.1:0",
            "--persist",
            persist.to_str().unwrap(),
        ],
    );
    let host = metrics_host(&server);
    let r1 = StoreId::recording("app", "r1");
    rt.block_on(async {
        let then = vec![info_msg(&r1), chunk_msg(&r1, "/a", 7, 7.0)];
        let (release, stream) = open_idle_stream(server.channel().await, then);
        // The stream is open (admitted) before the signal.
        let start = Instant::now();
        while !scrape(&host).contains(&("chunkstore_write_streams".to_owned(), 1.0)) {
            assert!(
                start.elapsed() < Duration::from_secs(5),
                "{}",
                server.stderr()
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        let pid = server.child.id().to_string();
        assert!(
            Command::new("kill")
                .args(["-TERM", &pid])
                .status()
                .unwrap()
                .success()
        );
        let start = Instant::now();
        loop {
            let answer = http1_to(&host, "GET", "/health", &[], b"");
            if answer.status == 503 {
                break;
            }
            assert!(
                start.elapsed() < Duration::from_secs(2),
                "{}",
                server.stderr()
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        // The stream, still open, sends its messages and is acknowledged.
        drop(release);
        stream.await.unwrap().unwrap();
        let start = Instant::now();
        let status = loop {
            if let Some(status) = server.child.try_wait().unwrap() {
                break status;
            }
            assert!(
                start.elapsed() < Duration::from_secs(8),
                "{}",
                server.stderr()
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        };
        assert!(status.success(), "{status}: {}", server.stderr());
    });
    assert!(server.stderr().contains("stopping: no new connections"));
    // What was acknowledged is in the log: a new server reads it back.
    drop(server);
    let again = Server::start(&dir, &["--persist", persist.to_str().unwrap()]);
    rt.block_on(async {
        assert_eq!(count(&again, "chunks").await, 1);
    });
    drop(again);
    std::fs::remove_dir_all(&dir).unwrap();
}

fn tls_file(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/sql/tls")
        .join(name)
        .to_string_lossy()
        .into_owned()
}

/// A channel to a TLS server that trusts the test CA (or not).
async fn tls_channel(
    server: &Server,
    trust_the_ca: bool,
) -> Result<Channel, tonic::transport::Error> {
    let mut tls = ClientTlsConfig::new().domain_name("localhost");
    if trust_the_ca {
        let ca = std::fs::read(tls_file("ca.pem")).unwrap();
        tls = tls.ca_certificate(Certificate::from_pem(ca));
    }
    Channel::from_shared(server.url.clone())
        .unwrap()
        .tls_config(tls)?
        .connect()
        .await
}

#[test]
fn tls_serves_clients_that_trust_its_certificate_and_only_over_tls() {
    let dir = temp_dir("tls");
    let rt = runtime();
    let (cert, key) = (tls_file("server.pem"), tls_file("server-key.pem"));
    let server = Server::start(&dir, &["--tls-cert", &cert, "--tls-key", &key]);
    assert!(
        server.url.starts_with("https://127.0.0.1:"),
        "{}",
        server.url
    );
    let stderr = server.stderr();
    assert!(
        stderr.contains("Flight SQL on grpc+tls://127.0.0.1:"),
        "{stderr}"
    );
    let r1 = StoreId::recording("app", "r1");
    rt.block_on(async {
        let channel = tls_channel(&server, true).await.unwrap();
        let mut grpc = tonic::client::Grpc::new(channel.clone());
        grpc.ready().await.unwrap();
        let messages = vec![info_msg(&r1), chunk_msg(&r1, "/a", 0, 1.0)];
        grpc.client_streaming::<_, Vec<u8>, Vec<u8>, _>(
            tonic::Request::new(futures::stream::iter(messages)),
            tonic::codegen::http::uri::PathAndQuery::from_static(super::server::WRITE),
            Raw,
        )
        .await
        .unwrap();
        let mut sql = arrow_flight::sql::client::FlightSqlServiceClient::new(channel.clone());
        let info = sql
            .execute("SELECT count(*) FROM chunks".to_owned(), None)
            .await
            .unwrap();
        let ticket = info.endpoint[0].ticket.clone().unwrap();
        let batches: Vec<_> = futures::TryStreamExt::try_collect(sql.do_get(ticket).await.unwrap())
            .await
            .unwrap();
        assert_eq!(batches[0].num_rows(), 1);
        assert_eq!(health(channel, "", None).await.unwrap(), 1);
        // A client that does not trust the certificate gets no connection.
        let untrusting = tls_channel(&server, false).await;
        assert!(untrusting.is_err(), "connected without trusting the CA");
        // Nor does one speaking plain HTTP/2.
        let plain = server.url.replace("https://", "http://");
        let plain = Channel::from_shared(plain).unwrap().connect().await;
        if let Ok(plain) = plain {
            assert!(health(plain, "", None).await.is_err());
        }
    });
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_tls_files_exit_2_with_one_line() {
    let dir = temp_dir("tls-bad");
    let garbage = dir.join("garbage.pem");
    std::fs::write(&garbage, "not a key").unwrap();
    let run = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_chunkstore"))
            .args(["serve", "--addr", "127.0.0.1:0"])
            .args(args)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{args:?}: {stderr}");
        assert!(out.stdout.is_empty(), "{args:?} started");
        stderr
    };
    let cert = tls_file("server.pem");
    let key = tls_file("server-key.pem");
    let missing = dir.join("missing.pem");
    let said = run(&["--tls-cert", &cert, "--tls-key", missing.to_str().unwrap()]);
    assert!(said.contains("missing.pem"), "{said}");
    let said = run(&["--tls-cert", &cert, "--tls-key", garbage.to_str().unwrap()]);
    assert!(said.contains("--tls-cert/--tls-key"), "{said}");
    // The key of another certificate: the CA's certificate as the server's.
    let said = run(&["--tls-cert", &tls_file("ca.pem"), "--tls-key", &key]);
    assert!(said.contains("--tls-cert/--tls-key"), "{said}");
    let said = run(&["--tls-cert", &cert]);
    assert!(said.contains("--tls-key"), "{said}");
    let said = Command::new(env!("CARGO_BIN_EXE_chunkstore"))
        .args(["serve", "--addr", "127.0.0.1:0"])
        .env("RUST_LOG", "chunkstore=[")
        .output()
        .unwrap();
    assert_eq!(said.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&said.stderr).contains("RUST_LOG"));
    std::fs::remove_dir_all(&dir).unwrap();
}
