//! `chunkstore serve` (feature `server`), driven as a user drives it: the built binary on a
//! free loopback port, Rerun's proxy protocol written by a raw gRPC client (the bytes an
//! SDK sends), Arrow Flight SQL read by arrow-flight's client. What the real Rerun SDK and
//! ADBC do against it is `tests/clients/server_sdk.py`'s part (run by `.ci/run`).

use std::io::{BufRead as _, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use arrow_array::{Array, Int64Array, RecordBatch, StringArray};
use arrow_flight::sql::client::FlightSqlServiceClient;
use bytes::{Buf as _, BufMut as _};
use chunkstore::rrd::{LogMsg, StoreId, StoreInfo, StoreKind};
use futures::{StreamExt as _, TryStreamExt as _};
use tonic::codec::{Codec, DecodeBuf, Decoder, EncodeBuf, Encoder};
use tonic::transport::Channel;

use super::common;

pub(super) const WRITE: &str = "/rerun.sdk_comms.v1alpha1.MessageProxyService/WriteMessages";
pub(super) const READ: &str = "/rerun.sdk_comms.v1alpha1.MessageProxyService/ReadMessages";

/// The server, killed (SIGKILL) when dropped.
pub(super) struct Server {
    pub(super) child: Child,
    /// `http://HOST:PORT`, or `https://…` when it speaks TLS.
    pub(super) url: String,
    stderr: PathBuf,
}

impl Server {
    pub(super) fn start(dir: &Path, args: &[&str]) -> Self {
        let stderr = dir.join(format!("stderr-{}.txt", chunkstore::RowId::new().as_u128()));
        let mut child = Command::new(env!("CARGO_BIN_EXE_chunkstore"))
            .arg("serve")
            .args(["--addr", "127.0.0.1:0"])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&stderr).unwrap())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let line = line.trim();
        let (scheme, rest) = match line.strip_prefix("listening on rerun+https://") {
            Some(rest) => ("https", Some(rest)),
            None => ("http", line.strip_prefix("listening on rerun+http://")),
        };
        let host = rest
            .and_then(|rest| rest.strip_suffix("/proxy"))
            .unwrap_or_else(|| {
                panic!(
                    "first line {line:?}; stderr: {}",
                    std::fs::read_to_string(&stderr).unwrap_or_default()
                )
            })
            .to_owned();
        Self {
            child,
            url: format!("{scheme}://{host}"),
            stderr,
        }
    }

    pub(super) fn stderr(&self) -> String {
        std::fs::read_to_string(&self.stderr).unwrap_or_default()
    }

    pub(super) async fn channel(&self) -> Channel {
        Channel::from_shared(self.url.clone())
            .unwrap()
            .connect()
            .await
            .unwrap()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[derive(Clone, Copy, Default)]
pub(super) struct Raw;
pub(super) struct RawEncoder;
pub(super) struct RawDecoder;

impl Codec for Raw {
    type Encode = Vec<u8>;
    type Decode = Vec<u8>;
    type Encoder = RawEncoder;
    type Decoder = RawDecoder;
    fn encoder(&mut self) -> RawEncoder {
        RawEncoder
    }
    fn decoder(&mut self) -> RawDecoder {
        RawDecoder
    }
}

impl Encoder for RawEncoder {
    type Item = Vec<u8>;
    type Error = tonic::Status;
    fn encode(&mut self, item: Vec<u8>, dst: &mut EncodeBuf<'_>) -> Result<(), tonic::Status> {
        dst.put_slice(&item);
        Ok(())
    }
}

impl Decoder for RawDecoder {
    type Item = Vec<u8>;
    type Error = tonic::Status;
    fn decode(&mut self, src: &mut DecodeBuf<'_>) -> Result<Option<Vec<u8>>, tonic::Status> {
        Ok(Some(src.copy_to_bytes(src.remaining()).to_vec()))
    }
}

/// One `WriteMessages` stream of `requests` (encoded envelopes).
pub(super) async fn write(server: &Server, requests: Vec<Vec<u8>>) -> Result<(), tonic::Status> {
    write_as(server, requests, None).await
}

/// One `WriteMessages` stream of `requests`, with `token` as a bearer token if given.
pub(super) async fn write_as(
    server: &Server,
    requests: Vec<Vec<u8>>,
    token: Option<&str>,
) -> Result<(), tonic::Status> {
    let mut grpc = tonic::client::Grpc::new(server.channel().await);
    grpc.ready().await.unwrap();
    let mut request = tonic::Request::new(futures::stream::iter(requests));
    if let Some(token) = token {
        request
            .metadata_mut()
            .insert("authorization", format!("Bearer {token}").parse().unwrap());
    }
    grpc.client_streaming::<_, Vec<u8>, Vec<u8>, _>(
        request,
        tonic::codegen::http::uri::PathAndQuery::from_static(WRITE),
        Raw,
    )
    .await
    .map(drop)
}

/// Every message `ReadMessages` sends (the server must end the stream: snapshot mode).
pub(super) async fn read_all(server: &Server) -> Vec<LogMsg> {
    let mut grpc = tonic::client::Grpc::new(server.channel().await);
    grpc.ready().await.unwrap();
    let response = grpc
        .server_streaming::<Vec<u8>, Vec<u8>, _>(
            tonic::Request::new(Vec::new()),
            tonic::codegen::http::uri::PathAndQuery::from_static(READ),
            Raw,
        )
        .await
        .unwrap();
    let items: Vec<Vec<u8>> = response.into_inner().try_collect().await.unwrap();
    items
        .into_iter()
        .map(|bytes| LogMsg::decode_envelope(&arrow_buffer::Buffer::from(bytes)).unwrap())
        .collect()
}

/// A query's batches through Flight SQL, with `token` as a bearer token if given.
pub(super) async fn query(
    server: &Server,
    sql: &str,
    token: Option<&str>,
) -> Result<Vec<RecordBatch>, arrow_flight::error::FlightError> {
    let mut client = FlightSqlServiceClient::new(server.channel().await);
    if let Some(token) = token {
        client.set_token(token.to_owned());
    }
    let info = client.execute(sql.to_owned(), None).await?;
    let mut batches = Vec::new();
    for endpoint in info.endpoint {
        let ticket = endpoint.ticket.unwrap();
        let stream = client.do_get(ticket).await?;
        batches.extend(stream.try_collect::<Vec<_>>().await?);
    }
    Ok(batches)
}

/// `(segment, rows)` of `SELECT rerun_segment_id, count(*) ... GROUP BY 1 ORDER BY 1`.
pub(super) async fn counts(server: &Server, table: &str) -> Vec<(String, i64)> {
    let sql = format!("SELECT rerun_segment_id, count(*) AS n FROM {table} GROUP BY 1 ORDER BY 1");
    let batches = query(server, &sql, None).await.unwrap();
    let mut out = Vec::new();
    for batch in batches {
        let segments = batch
            .column(0)
            .as_any()
            .downcast_ref::<StringArray>()
            .unwrap();
        let n = batch
            .column(1)
            .as_any()
            .downcast_ref::<Int64Array>()
            .unwrap();
        for i in 0..batch.num_rows() {
            out.push((segments.value(i).to_owned(), n.value(i)));
        }
    }
    out
}

fn envelope(msg: &LogMsg) -> Vec<u8> {
    msg.encode_envelope()
}

pub(super) fn info_msg(id: &StoreId) -> Vec<u8> {
    envelope(&LogMsg::from_store_info(&StoreInfo::new(id.clone())))
}

pub(super) fn chunk_msg(id: &StoreId, entity: &str, frame: i64, value: f64) -> Vec<u8> {
    let chunk = common::scalar(
        entity,
        "x",
        frame,
        chunkstore::RowId::new().as_u128(),
        value,
    );
    envelope(&LogMsg::from_chunk(id, &chunk, true).unwrap())
}

pub(super) fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

pub(super) fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("chunkstore-server-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn logged_data_is_queryable_replayable_and_survives_a_kill() {
    let dir = temp_dir("persist");
    let log = dir.join("live.rrd");
    let log_arg = log.to_str().unwrap();
    let rt = runtime();
    let r1 = StoreId::recording("app", "r1");
    let r2 = StoreId::recording("app", "r2");
    let mut blueprint = StoreId::recording("app", "layout");
    blueprint.kind = StoreKind::Blueprint;
    {
        let server = Server::start(&dir, &["--persist", log_arg, "--read-mode", "snapshot"]);
        rt.block_on(async {
            // As the SDK: the store info twice, then chunks; a second recording and a
            // blueprint on other streams.
            let mut first = vec![info_msg(&r1), info_msg(&r1)];
            first.extend((0..10).map(|f| chunk_msg(&r1, "/arm", f, f as f64)));
            write(&server, first).await.unwrap();
            let second = vec![
                info_msg(&r2),
                chunk_msg(&r2, "/leg", 0, 1.0),
                chunk_msg(&r2, "/leg", 1, 2.0),
                info_msg(&blueprint),
                chunk_msg(&blueprint, "/view", 0, 0.0),
            ];
            write(&server, second).await.unwrap();

            assert_eq!(
                counts(&server, "frame").await,
                [("r1".to_owned(), 10), ("r2".to_owned(), 2)]
            );
            // The blueprint is no data: not in `chunks`.
            assert_eq!(
                counts(&server, "chunks").await,
                [("r1".to_owned(), 10), ("r2".to_owned(), 2)]
            );
            let sum = query(
                &server,
                r#"SELECT sum("/arm:x"[1]) AS s FROM frame WHERE rerun_segment_id = 'r1' AND frame >= 5"#,
                None,
            )
            .await
            .unwrap();
            let s = sum[0]
                .column(0)
                .as_any()
                .downcast_ref::<arrow_array::Float64Array>()
                .unwrap()
                .value(0);
            assert!((s - 35.0).abs() < 1e-9, "{s}");

            // The history as messages: 2 recordings' store infos, the blueprint's store
            // info and chunk as they came, then the 12 chunks.
            let history = read_all(&server).await;
            let chunks: usize = history
                .iter()
                .filter(|m| matches!(m.decode().unwrap(), chunkstore::rrd::DecodedLogMsg::Chunk { .. }))
                .count();
            assert_eq!(chunks, 12);
            assert_eq!(history.len(), 2 + 2 + 12);
        });
        // Dropped: SIGKILL, no clean shutdown.
    }
    // Restarted on the same log: everything acknowledged is back.
    let server = Server::start(&dir, &["--persist", log_arg]);
    rt.block_on(async {
        assert_eq!(
            counts(&server, "frame").await,
            [("r1".to_owned(), 10), ("r2".to_owned(), 2)]
        );
    });
    drop(server);

    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_torn_tail_is_dropped_and_a_damaged_byte_refuses_to_start() {
    let dir = temp_dir("damage");
    let log = dir.join("live.rrd");
    let log_arg = log.to_str().unwrap();
    let rt = runtime();
    let r1 = StoreId::recording("app", "r1");
    let r2 = StoreId::recording("app", "r2");
    {
        let server = Server::start(&dir, &["--persist", log_arg]);
        rt.block_on(async {
            let mut first = vec![info_msg(&r1)];
            first.extend((0..10).map(|f| chunk_msg(&r1, "/arm", f, f as f64)));
            write(&server, first).await.unwrap();
            let second = vec![
                info_msg(&r2),
                chunk_msg(&r2, "/leg", 0, 1.0),
                chunk_msg(&r2, "/leg", 1, 2.0),
            ];
            write(&server, second).await.unwrap();
        });
    }
    // A torn tail (a write cut short by a crash: the first half of a chunk's frame) is
    // dropped with one warning.
    let mut bytes = std::fs::read(&log).unwrap();
    let whole = bytes.len();
    let torn = LogMsg::from_chunk(&r1, &common::scalar("/arm", "x", 99, 1, 9.0), true).unwrap();
    bytes.extend_from_slice(&torn.frame_header());
    bytes.extend_from_slice(&torn.body().as_slice()[..torn.body().len() / 2]);
    std::fs::write(&log, &bytes).unwrap();
    let server = Server::start(&dir, &["--persist", log_arg]);
    rt.block_on(async {
        assert_eq!(
            counts(&server, "frame").await,
            [("r1".to_owned(), 10), ("r2".to_owned(), 2)]
        );
    });
    assert!(
        server.stderr().contains("torn last message"),
        "{}",
        server.stderr()
    );
    assert_eq!(std::fs::metadata(&log).unwrap().len(), whole as u64);
    drop(server);

    // One damaged byte in the middle, the high byte of message 5's length, is no torn
    // tail: the server refuses to start, names where, and leaves every byte in place.
    let mut bytes = std::fs::read(&log).unwrap();
    let scan = chunkstore::rrd::scan_log(&arrow_buffer::Buffer::from(bytes.clone()));
    let mut at = 12;
    for msg in &scan.messages[..5] {
        at += 16 + msg.body().len();
    }
    bytes[at + 15] = 0x01;
    std::fs::write(&log, &bytes).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_chunkstore"))
        .args(["serve", "--addr", "127.0.0.1:0", "--persist", log_arg])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains(&format!("damaged after byte {at}")),
        "{stderr}"
    );
    assert_eq!(std::fs::read(&log).unwrap(), bytes);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_empty_server_has_chunks_and_a_statement_gets_the_schema_it_was_planned_with() {
    let dir = temp_dir("schema");
    let rt = runtime();
    let server = Server::start(&dir, &[]);
    let r1 = StoreId::recording("app", "r1");
    rt.block_on(async {
        // Before the first recording: `chunks` is there, empty; an unknown table is an
        // error naming the tables there are.
        assert_eq!(counts(&server, "chunks").await, []);
        let err = query(&server, "SELECT * FROM frame", None)
            .await
            .unwrap_err();
        assert!(err.to_string().contains("the tables are: chunks"), "{err}");

        write(&server, vec![info_msg(&r1), chunk_msg(&r1, "/a", 0, 1.0)])
            .await
            .unwrap();
        // Planned with one entity's column, run after a second entity arrived: the batches
        // have the columns that were advertised.
        let mut client = FlightSqlServiceClient::new(server.channel().await);
        let info = client
            .execute("SELECT * FROM frame".to_owned(), None)
            .await
            .unwrap();
        let advertised = info.clone().try_decode_schema().unwrap();
        write(&server, vec![chunk_msg(&r1, "/b", 1, 2.0)])
            .await
            .unwrap();
        let ticket = info.endpoint[0].ticket.clone().unwrap();
        let batches: Vec<RecordBatch> = client
            .do_get(ticket)
            .await
            .unwrap()
            .try_collect()
            .await
            .unwrap();
        let rows: usize = batches.iter().map(RecordBatch::num_rows).sum();
        assert_eq!(rows, 2);
        for batch in &batches {
            assert_eq!(batch.schema().fields(), advertised.fields());
        }
        // A statement planned now sees both entities.
        let now = query(&server, "SELECT * FROM frame", None).await.unwrap();
        assert_eq!(now[0].num_columns(), advertised.fields().len() + 1);
    });
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn sigterm_stops_the_server_while_a_follow_reader_is_connected() {
    let dir = temp_dir("sigterm");
    let rt = runtime();
    let mut server = Server::start(&dir, &[]);
    let r1 = StoreId::recording("app", "r1");
    rt.block_on(async {
        write(&server, vec![info_msg(&r1), chunk_msg(&r1, "/a", 0, 1.0)])
            .await
            .unwrap();
        // A follow reader (the default read mode), reading the history and then waiting.
        let mut grpc = tonic::client::Grpc::new(server.channel().await);
        grpc.ready().await.unwrap();
        let mut stream = grpc
            .server_streaming::<Vec<u8>, Vec<u8>, _>(
                tonic::Request::new(Vec::new()),
                tonic::codegen::http::uri::PathAndQuery::from_static(READ),
                Raw,
            )
            .await
            .unwrap()
            .into_inner();
        for _ in 0..2 {
            stream.message().await.unwrap().unwrap();
        }
        let pid = server.child.id().to_string();
        let killed = Command::new("kill").args(["-TERM", &pid]).status().unwrap();
        assert!(killed.success());
        // The reader's stream ends and the process exits, well within the grace period.
        let start = std::time::Instant::now();
        loop {
            if let Some(status) = server.child.try_wait().unwrap() {
                assert!(status.success(), "{status}: {}", server.stderr());
                break;
            }
            assert!(
                start.elapsed() < std::time::Duration::from_secs(4),
                "still running 4 s after SIGTERM: {}",
                server.stderr()
            );
            tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        }
        assert!(matches!(stream.message().await, Ok(None) | Err(_)));
    });
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A `WriteMessages` stream that sends nothing until `release` is dropped, then `then`.
pub(super) fn open_idle_stream(
    channel: Channel,
    then: Vec<Vec<u8>>,
) -> (
    tokio::sync::oneshot::Sender<()>,
    tokio::task::JoinHandle<Result<(), tonic::Status>>,
) {
    let (release, released) = tokio::sync::oneshot::channel::<()>();
    let requests = futures::stream::once(async move {
        let _ = released.await;
        futures::stream::iter(then)
    })
    .flatten();
    let task = tokio::spawn(async move {
        let mut grpc = tonic::client::Grpc::new(channel);
        grpc.ready().await.unwrap();
        grpc.client_streaming::<_, Vec<u8>, Vec<u8>, _>(
            tonic::Request::new(requests),
            tonic::codegen::http::uri::PathAndQuery::from_static(WRITE),
            Raw,
        )
        .await
        .map(drop)
    });
    (release, task)
}

/// Idle streams cannot lock loggers out: one connection holds at most 16, a stream must
/// send its first message within 10 s, and when every slot is taken the stream idle
/// longest gives way to a new one; each refusal is one line on stderr.
#[test]
fn idle_log_streams_give_way_and_are_capped_per_connection() {
    let dir = temp_dir("idle");
    let rt = runtime();
    let server = Server::start(&dir, &["--max-write-streams", "20"]);
    let r1 = StoreId::recording("app", "r1");
    rt.block_on(async {
        // One connection, 17 streams sending nothing: the 17th is refused at once.
        let channel = server.channel().await;
        let mut idle = Vec::new();
        for _ in 0..16 {
            idle.push(open_idle_stream(channel.clone(), Vec::new()));
        }
        tokio::time::sleep(std::time::Duration::from_millis(300)).await;
        let (_release, refused) = open_idle_stream(channel.clone(), Vec::new());
        let status = refused.await.unwrap().unwrap_err();
        assert_eq!(status.code(), tonic::Code::ResourceExhausted, "{status}");
        assert!(status.message().contains("this connection"), "{status}");
        // None sent a first message: after 10 s each is ended.
        for (_release, task) in idle {
            let status = task.await.unwrap().unwrap_err();
            assert_eq!(status.code(), tonic::Code::DeadlineExceeded, "{status}");
        }
    });
    let stderr = server.stderr();
    assert_eq!(stderr.matches("no first message").count(), 16, "{stderr}");
    assert!(
        stderr.contains("this connection already has 16"),
        "{stderr}"
    );
    drop(server);

    // Two slots, both held by streams that logged once and went quiet: a third stream
    // is taken (after the idle grace), and the idlest gives way.
    let server = Server::start(&dir, &["--max-write-streams", "2"]);
    rt.block_on(async {
        let mut quiet = Vec::new();
        for frame in 0..2 {
            let channel = server.channel().await;
            let first = vec![info_msg(&r1), chunk_msg(&r1, "/quiet", frame, 1.0)];
            let (release, released) = tokio::sync::oneshot::channel::<()>();
            let requests = futures::stream::iter(first).chain(
                futures::stream::once(async move {
                    let _ = released.await;
                    futures::stream::iter(Vec::<Vec<u8>>::new())
                })
                .flatten(),
            );
            let task = tokio::spawn(async move {
                let mut grpc = tonic::client::Grpc::new(channel);
                grpc.ready().await.unwrap();
                grpc.client_streaming::<_, Vec<u8>, Vec<u8>, _>(
                    tonic::Request::new(requests),
                    tonic::codegen::http::uri::PathAndQuery::from_static(WRITE),
                    Raw,
                )
                .await
                .map(drop)
            });
            quiet.push((release, task));
        }
        tokio::time::sleep(std::time::Duration::from_secs(11)).await;
        write(&server, vec![info_msg(&r1), chunk_msg(&r1, "/new", 5, 2.0)])
            .await
            .unwrap();
        let mut gave_way = 0;
        for (release, task) in quiet {
            drop(release);
            if let Err(status) = task.await.unwrap() {
                assert_eq!(status.code(), tonic::Code::Unavailable, "{status}");
                gave_way += 1;
            }
        }
        assert_eq!(gave_way, 1);
        assert_eq!(counts(&server, "frame").await, [("r1".to_owned(), 3)]);
    });
    assert!(
        server.stderr().contains("to make room"),
        "{}",
        server.stderr()
    );
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A query whose client goes away is stopped (the server says so), and the server goes on
/// serving its connections meanwhile.
#[test]
fn an_abandoned_query_stops() {
    let dir = temp_dir("abandoned");
    let rt = runtime();
    let server = Server::start(&dir, &[]);
    let r1 = StoreId::recording("app", "r1");
    rt.block_on(async {
        let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..300)
            .map(|i| (i, chunkstore::RowId::new().as_u128(), Some(vec![1.0])))
            .collect();
        let chunk = common::scalars("/a", "x", &rows);
        let msg = envelope(&LogMsg::from_chunk(&r1, &chunk, true).unwrap());
        write(&server, vec![info_msg(&r1), msg]).await.unwrap();
        // 300^4 rows to count: far longer than the test waits.
        let mut client = FlightSqlServiceClient::new(server.channel().await);
        let info = client
            .execute(
                "SELECT count(*) FROM frame a, frame b, frame c, frame d".to_owned(),
                None,
            )
            .await
            .unwrap();
        let ticket = info.endpoint[0].ticket.clone().unwrap();
        let started = tokio::time::timeout(std::time::Duration::from_secs(1), async {
            let mut stream = client.do_get(ticket).await.unwrap();
            stream.try_next().await
        })
        .await;
        assert!(started.is_err(), "the query finished: {started:?}");
        drop(client);
        let start = std::time::Instant::now();
        while !server.stderr().contains("query stopped: its client left") {
            assert!(
                start.elapsed() < std::time::Duration::from_secs(10),
                "{}",
                server.stderr()
            );
            tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        }
        // The connections are served while the abandoned query's operators finish the
        // work they are in (DataFusion's cannot be interrupted inside a poll).
        let start = std::time::Instant::now();
        write(&server, vec![chunk_msg(&r1, "/b", 0, 1.0)])
            .await
            .unwrap();
        assert!(start.elapsed() < std::time::Duration::from_secs(2));
    });
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--addr` takes a host name; on every interface the start line shows an address a
/// client here can use; follow mode says how `rerun --save --connect` behaves; Flight SQL
/// answers `GetTableTypes`.
#[test]
fn addresses_start_lines_and_table_types() {
    let dir = temp_dir("addr");
    let rt = runtime();
    for (addr, shown) in [("localhost:0", "127.0.0.1:"), ("0.0.0.0:0", "127.0.0.1:")] {
        let stderr = dir.join(format!("stderr-{}.txt", chunkstore::RowId::new().as_u128()));
        let mut child = Command::new(env!("CARGO_BIN_EXE_chunkstore"))
            .args(["serve", "--addr", addr])
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&stderr).unwrap())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        assert!(
            line.starts_with(&format!("listening on rerun+http://{shown}")),
            "{addr}: {line}"
        );
        let _ = child.kill();
        let _ = child.wait();
        let said = std::fs::read_to_string(&stderr).unwrap();
        assert!(said.contains("--read-mode snapshot"), "{said}");
        if addr.starts_with("0.0.0.0") {
            assert!(said.contains("every interface"), "{said}");
        }
    }
    let server = Server::start(&dir, &[]);
    rt.block_on(async {
        let mut client = FlightSqlServiceClient::new(server.channel().await);
        let info = client.get_table_types().await.unwrap();
        let ticket = info.endpoint[0].ticket.clone().unwrap();
        let batches: Vec<RecordBatch> = client
            .do_get(ticket)
            .await
            .unwrap()
            .try_collect()
            .await
            .unwrap();
        let types = batches[0]
            .column(0)
            .as_any()
            .downcast_ref::<StringArray>()
            .unwrap();
        assert_eq!(types.value(0), "TABLE");
        // The stacked tables are tables to information_schema too, as in the CLI.
        let r1 = StoreId::recording("app", "r1");
        write(&server, vec![info_msg(&r1), chunk_msg(&r1, "/a", 0, 1.0)])
            .await
            .unwrap();
        let shown = query(
            &server,
            "SELECT DISTINCT table_type FROM information_schema.tables \
             WHERE table_schema = 'public'",
            None,
        )
        .await
        .unwrap();
        let kinds = shown[0]
            .column(0)
            .as_any()
            .downcast_ref::<StringArray>()
            .unwrap();
        assert_eq!((kinds.len(), kinds.value(0)), (1, "BASE TABLE"));
    });
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The memory limit counts what the stores grow by: chunks that compress to almost
/// nothing on the wire (800 KB of zeros each) are collected as their decoded size
/// requires.
#[test]
fn the_memory_limit_counts_decoded_bytes() {
    let dir = temp_dir("decoded");
    let rt = runtime();
    let server = Server::start(&dir, &["--memory-limit", "16MiB"]);
    let r1 = StoreId::recording("app", "r1");
    rt.block_on(async {
        let mut messages = vec![info_msg(&r1)];
        for frame in 0..100 {
            let rows = [(
                frame,
                chunkstore::RowId::new().as_u128(),
                Some(vec![0.0; 100_000]),
            )];
            let chunk = common::scalars("/depth", "x", &rows);
            messages.push(envelope(&LogMsg::from_chunk(&r1, &chunk, true).unwrap()));
        }
        let wire: usize = messages.iter().map(Vec::len).sum();
        assert!(wire < 4 << 20, "{wire} bytes on the wire");
        write(&server, messages).await.unwrap();
        // 80 MB decoded under a 16 MiB limit (8 MiB for the stores): at most 10 chunks
        // of 800 KB stay.
        let kept = counts(&server, "chunks").await;
        assert!(kept[0].1 <= 10, "{kept:?} chunks kept");
    });
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_second_server_on_the_same_log_exits_2_naming_the_first() {
    let dir = temp_dir("lock");
    let log = dir.join("live.rrd");
    let log_arg = log.to_str().unwrap();
    let first = Server::start(&dir, &["--persist", log_arg]);
    let out = Command::new(env!("CARGO_BIN_EXE_chunkstore"))
        .args(["serve", "--addr", "127.0.0.1:0", "--persist", log_arg])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("in use by another server"), "{stderr}");
    assert!(
        stderr.contains(&format!("pid {}", first.child.id())),
        "{stderr}"
    );
    drop(first);
    let again = Server::start(&dir, &["--persist", log_arg]);
    drop(again);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_messages_end_their_stream_and_change_nothing_else() {
    let dir = temp_dir("bad");
    let rt = runtime();
    let server = Server::start(&dir, &[]);
    let r1 = StoreId::recording("app", "r1");
    rt.block_on(async {
        write(&server, vec![info_msg(&r1), chunk_msg(&r1, "/a", 0, 1.0)])
            .await
            .unwrap();

        let unknown_oneof = vec![0x0a, 0x03, 0x22, 0x01, 0x00];
        let mut corrupt = chunk_msg(&r1, "/a", 1, 2.0);
        let n = corrupt.len();
        corrupt[n - 40..n - 30].fill(0xee);
        let mut wrong_type = LogMsg::from_chunk(
            &r1,
            &chunkstore::ChunkBuilder::new(
                chunkstore::ChunkId::new(),
                chunkstore::EntityPath::parse("/a").unwrap(),
            )
            .with_row(
                chunkstore::RowId::new(),
                [(chunkstore::Timeline::sequence("frame"), 2)],
                [(
                    "x",
                    std::sync::Arc::new(StringArray::from(vec!["text"])) as arrow_array::ArrayRef,
                )],
            )
            .build()
            .unwrap(),
            true,
        )
        .unwrap()
        .encode_envelope();
        wrong_type.shrink_to_fit();
        let cases: [(&str, Vec<u8>, &str); 4] = [
            ("garbage", vec![0xff, 0xff, 0xff], "protobuf"),
            ("unknown oneof member", unknown_oneof, "kind 4"),
            ("corrupt payload", corrupt, "message 1"),
            ("component type conflict", wrong_type, "refused"),
        ];
        for (what, bad, says) in cases {
            // A good message first: it stays.
            let status = write(&server, vec![chunk_msg(&r1, "/b", 7, 7.0), bad])
                .await
                .unwrap_err();
            assert_eq!(
                status.code(),
                tonic::Code::InvalidArgument,
                "{what}: {status:?}"
            );
            assert!(
                status.message().to_lowercase().contains(says),
                "{what}: {}",
                status.message()
            );
        }
        // The good message before each bad one is in (1 + 4 rows), nothing of the bad
        // ones is, and the server still serves.
        assert_eq!(counts(&server, "chunks").await, [("r1".to_owned(), 5)]);
        let good = vec![chunk_msg(&r1, "/a", 9, 9.0)];
        write(&server, good).await.unwrap();
        assert_eq!(counts(&server, "chunks").await, [("r1".to_owned(), 6)]);

        // Bad SQL is the client's error, not the server's.
        let err = query(&server, "SELECT nope FROM frame", None)
            .await
            .unwrap_err();
        assert!(err.to_string().contains("nope"), "{err}");
    });
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_token_guards_every_call() {
    let dir = temp_dir("token");
    let rt = runtime();
    let server = Server::start(&dir, &["--token", "s3cret"]);
    rt.block_on(async {
        let err = query(&server, "SELECT 1", None).await.unwrap_err();
        assert!(err.to_string().contains("Bearer"), "{err}");
        let err = query(&server, "SELECT 1", Some("wrong")).await.unwrap_err();
        assert!(err.to_string().contains("Bearer"), "{err}");
        let batches = query(&server, "SELECT 1 AS one", Some("s3cret"))
            .await
            .unwrap();
        assert_eq!(batches[0].num_rows(), 1);
        let status = write(&server, vec![info_msg(&StoreId::recording("a", "r"))])
            .await
            .unwrap_err();
        assert_eq!(status.code(), tonic::Code::Unauthenticated);
    });
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_arguments_exit_2_with_one_line() {
    let run = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_chunkstore"))
            .arg("serve")
            .args(args)
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    for args in [
        &["--addr", "not-an-address"][..],
        &["--memory-limit", "lots"],
        &["--addr", "127.0.0.1:0", "/no/such/recording.rrd"],
        &["--addr", "127.0.0.1:0", "--token", ""],
        &["--addr", "127.0.0.1:0", "--memory-limit", "1KiB"],
        &[
            "--addr",
            "127.0.0.1:0",
            "--memory-limit",
            "64MiB",
            "--max-message-bytes",
            "40MiB",
        ],
    ] {
        let (code, stderr) = run(args);
        assert_eq!(code, Some(2), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
    }
    let file = std::env::temp_dir().join(format!("chunkstore-not-a-log-{}", std::process::id()));
    std::fs::write(&file, b"this is no log").unwrap();
    let (code, stderr) = run(&["--addr", "127.0.0.1:0", "--persist", file.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains("not an .rrd log"), "{stderr}");
    assert_eq!(std::fs::read(&file).unwrap(), b"this is no log");
    std::fs::remove_file(&file).unwrap();
}

#[test]
fn preloaded_sources_are_served_beside_live_recordings() {
    let dir = temp_dir("preload");
    let rrd = Path::new(env!("CARGO_MANIFEST_DIR")).join("testdata/rerun-0.41/a_robot/a_robot.rrd");
    let expected = chunkstore::recording::LoadedRecording::load(
        &rrd,
        &chunkstore::recording::OpenOptions::default(),
        &mut (),
    )
    .unwrap();
    let rows = i64::try_from(expected.store.stats().num_rows()).unwrap();
    let recording_id = expected
        .store_info
        .unwrap()
        .store_id
        .recording_id
        .to_string();
    let rt = runtime();
    let server = Server::start(&dir, &[rrd.to_str().unwrap()]);
    rt.block_on(async {
        assert_eq!(
            counts(&server, "chunks").await,
            [(recording_id.clone(), rows)]
        );
        // A live recording beside it.
        let live = StoreId::recording("app", "zz-live");
        write(
            &server,
            vec![info_msg(&live), chunk_msg(&live, "/a", 0, 1.0)],
        )
        .await
        .unwrap();
        assert_eq!(
            counts(&server, "chunks").await,
            [(recording_id, rows), ("zz-live".to_owned(), 1)]
        );
    });
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The HTTP/2 settings a server sends first, read with a bare client: the connection
/// preface and an empty SETTINGS frame, then the server's SETTINGS frame, by identifier.
fn http2_settings(url: &str) -> Vec<(u16, u32)> {
    use std::io::{Read as _, Write as _};
    let host = url.strip_prefix("http://").unwrap();
    let mut tcp = std::net::TcpStream::connect(host).unwrap();
    tcp.set_read_timeout(Some(std::time::Duration::from_secs(10)))
        .unwrap();
    tcp.write_all(b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n").unwrap();
    // Length 0, type 4 (SETTINGS), no flags, stream 0.
    tcp.write_all(&[0, 0, 0, 4, 0, 0, 0, 0, 0]).unwrap();
    let mut header = [0u8; 9];
    tcp.read_exact(&mut header).unwrap();
    assert_eq!(
        header[3], 4,
        "the server's first frame is SETTINGS: {header:?}"
    );
    assert_eq!(header[4] & 1, 0, "not an acknowledgement");
    let len = usize::from(header[0]) << 16 | usize::from(header[1]) << 8 | usize::from(header[2]);
    let mut payload = vec![0u8; len];
    tcp.read_exact(&mut payload).unwrap();
    payload
        .chunks_exact(6)
        .map(|s| {
            (
                u16::from_be_bytes([s[0], s[1]]),
                u32::from_be_bytes([s[2], s[3], s[4], s[5]]),
            )
        })
        .collect()
}

#[test]
fn clients_may_send_frames_of_a_mebibyte_or_of_the_window_under_a_memory_limit() {
    const MAX_FRAME_SIZE: u16 = 5;
    let dir = temp_dir("frames");
    let frame = |args: &[&str]| {
        let server = Server::start(&dir, args);
        let settings = http2_settings(&server.url);
        settings
            .iter()
            .find(|(id, _)| *id == MAX_FRAME_SIZE)
            .map(|(_, value)| *value)
    };
    assert_eq!(frame(&[]), Some(1 << 20));
    // A 16 MiB limit gives streams a 256 KiB window.
    assert_eq!(frame(&["--memory-limit", "16MiB"]), Some(256 << 10));
    std::fs::remove_dir_all(&dir).unwrap();
}
