//! Rerun's `rerun.sdk_comms.v1alpha1.MessageProxyService` over tonic, written out by hand:
//! its two messages are the envelope `{ LogMsg log_msg = 1; }` that
//! [`LogMsg::decode_envelope`] reads, so the codec passes bytes and the library decodes
//! them (no generated code, no `protoc`).
//!
//! - `WriteMessages` (client streaming): each message is decoded and applied in turn; the
//!   first bad one ends the stream with `INVALID_ARGUMENT` naming it (the earlier ones
//!   stay); the response comes only once every message is in the store and, with
//!   `--persist`, synced to disk (the write path is [`super::write`]).
//! - `ReadMessages` (server streaming): the history ([`StoreHub::replay`]), then, in
//!   follow mode, every message accepted after it.
//! - `WriteTable` and `ReadTables` answer `UNIMPLEMENTED`.

use std::convert::Infallible;
use std::sync::Arc;
use std::task::{Context, Poll};

use arrow_buffer::Buffer;
use bytes::{Buf as _, BufMut as _};
use chunkstore::rrd::LogMsg;
use tokio::sync::broadcast::error::RecvError;
use tonic::codec::{Codec, DecodeBuf, Decoder, EncodeBuf, Encoder};
use tonic::codegen::{BoxFuture, Service, http};
use tonic::server::{Grpc, NamedService};
use tonic::{Request, Response, Status, Streaming};

use super::admission;
use super::write::blocking;
use super::{Live, ReadMode, ServerState};

/// The service's gRPC name.
pub const SERVICE: &str = "rerun.sdk_comms.v1alpha1.MessageProxyService";

/// Passes message bytes through: requests arrive as [`Buffer`]s (no copy past tonic's
/// own), responses leave as encoded bytes.
#[derive(Clone, Copy, Default)]
struct RawCodec;

struct RawEncoder;
struct RawDecoder;

impl Codec for RawCodec {
    type Encode = Vec<u8>;
    type Decode = Buffer;
    type Encoder = RawEncoder;
    type Decoder = RawDecoder;

    fn encoder(&mut self) -> Self::Encoder {
        RawEncoder
    }

    fn decoder(&mut self) -> Self::Decoder {
        RawDecoder
    }
}

impl Encoder for RawEncoder {
    type Item = Vec<u8>;
    type Error = Status;

    fn encode(&mut self, item: Vec<u8>, dst: &mut EncodeBuf<'_>) -> Result<(), Status> {
        dst.put_slice(&item);
        Ok(())
    }
}

impl Decoder for RawDecoder {
    type Item = Buffer;
    type Error = Status;

    fn decode(&mut self, src: &mut DecodeBuf<'_>) -> Result<Option<Buffer>, Status> {
        Ok(Some(Buffer::from(src.copy_to_bytes(src.remaining()))))
    }
}

/// The service: routes the proxy's four methods.
#[derive(Clone)]
pub struct ProxyService {
    state: Arc<ServerState>,
}

impl ProxyService {
    pub fn new(state: Arc<ServerState>) -> Self {
        Self { state }
    }
}

impl NamedService for ProxyService {
    const NAME: &'static str = SERVICE;
}

impl<B> Service<http::Request<B>> for ProxyService
where
    B: tonic::codegen::Body + Send + 'static,
    B::Error: Into<Box<dyn std::error::Error + Send + Sync>> + Send + 'static,
{
    type Response = http::Response<tonic::body::Body>;
    type Error = Infallible;
    type Future = BoxFuture<Self::Response, Self::Error>;

    fn poll_ready(&mut self, _cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        Poll::Ready(Ok(()))
    }

    fn call(&mut self, request: http::Request<B>) -> Self::Future {
        let state = Arc::clone(&self.state);
        let limit = state.max_message_bytes;
        match request.uri().path().strip_prefix(&format!("/{SERVICE}/")) {
            Some("WriteMessages") => Box::pin(async move {
                let mut grpc = grpc(limit);
                Ok(grpc
                    .client_streaming(WriteMessages { state }, request)
                    .await)
            }),
            Some("ReadMessages") => Box::pin(async move {
                let mut grpc = grpc(limit);
                Ok(grpc.server_streaming(ReadMessages { state }, request).await)
            }),
            Some(method) => {
                let status =
                    Status::unimplemented(format!("{SERVICE}/{method} is not served here"));
                Box::pin(async move { Ok(status.into_http()) })
            }
            None => {
                let status = Status::unimplemented("unknown service");
                Box::pin(async move { Ok(status.into_http()) })
            }
        }
    }
}

/// The gRPC handler of either method: messages up to `--max-message-bytes` in, any size
/// out (a replayed image chunk).
fn grpc(max_message_bytes: usize) -> Grpc<RawCodec> {
    Grpc::new(RawCodec)
        .max_decoding_message_size(max_message_bytes)
        .max_encoding_message_size(usize::MAX)
}

struct WriteMessages {
    state: Arc<ServerState>,
}

impl tonic::server::ClientStreamingService<Buffer> for WriteMessages {
    type Response = Vec<u8>;
    type Future = BoxFuture<Response<Vec<u8>>, Status>;

    fn call(&mut self, request: Request<Streaming<Buffer>>) -> Self::Future {
        let state = Arc::clone(&self.state);
        let peer = request.remote_addr();
        Box::pin(async move {
            let result = write_messages(state, peer, request.into_inner()).await;
            if let Err(status) = &result {
                admission::log_refusal(peer, status);
            }
            result
        })
    }
}

async fn write_messages(
    state: Arc<ServerState>,
    peer: Option<std::net::SocketAddr>,
    mut stream: Streaming<Buffer>,
) -> Result<Response<Vec<u8>>, Status> {
    let admitted = state.admission.admit(peer).await?;
    let mut writer = if state.log_failed() {
        blocking(&state, ServerState::begin_stream).await??
    } else {
        state.begin_stream()?
    };
    let written = async {
        loop {
            let first = writer.index == 0;
            let next = tokio::select! {
                // A client gone mid-stream (reset, broken connection) is named as such.
                next = stream.message() => next.map_err(|status| Status::new(
                    status.code(),
                    format!(
                        "the client's stream broke after {} messages: {}",
                        writer.index,
                        status.message()
                    ),
                ))?,
                () = admitted.give_way.notified() => {
                    return Err(Status::unavailable(format!(
                        "ended to make room for a new log stream after {} s or more without \
                         a message (every slot was taken); reconnect to log more",
                        admission::IDLE_GRACE.as_secs()
                    )));
                }
                () = tokio::time::sleep(admission::FIRST_MESSAGE), if first => {
                    return Err(Status::deadline_exceeded(format!(
                        "no first message within {} s",
                        admission::FIRST_MESSAGE.as_secs()
                    )));
                }
            };
            let Some(bytes) = next else {
                break;
            };
            admitted.touch();
            let msg = LogMsg::decode_envelope(&bytes).map_err(|e| {
                state.metrics.refused("");
                Status::invalid_argument(format!("message {} of this stream: {e}", writer.index))
            })?;
            // What the stores grow by: a compressed body may decode to many times its size.
            let len = msg.decoded_len();
            // Decoding a chunk (LZ4, Arrow IPC, validation) and inserting it is CPU work
            // of well under a millisecond for the SDK's chunks: done on this worker
            // thread, as other streams are on the others (handing the thread over per
            // message, with `block_in_place`, cost more than the work).
            state.write(&mut writer, &msg, len)?;
            state.after_ingest(len);
        }
        Ok::<(), Status>(())
    }
    .await;
    if let Err(status) = written {
        if state.log_failed() {
            blocking(&state, ServerState::recover_log).await?;
        }
        return Err(status);
    }
    blocking(&state, move |state| state.finish(&writer)).await??;
    // `WriteMessagesResponse {}`: no fields.
    Ok(Response::new(Vec::new()))
}

struct ReadMessages {
    state: Arc<ServerState>,
}

type MessageStream = tokio_stream::wrappers::ReceiverStream<Result<Vec<u8>, Status>>;

impl tonic::server::ServerStreamingService<Buffer> for ReadMessages {
    type Response = Vec<u8>;
    type ResponseStream = MessageStream;
    type Future = BoxFuture<Response<MessageStream>, Status>;

    fn call(&mut self, _request: Request<Buffer>) -> Self::Future {
        let state = Arc::clone(&self.state);
        Box::pin(async move { Ok(Response::new(read_messages(&state))) })
    }
}

/// The history, then (follow mode) the live messages, through a channel a task fills.
fn read_messages(state: &Arc<ServerState>) -> MessageStream {
    let (tx, rx) = tokio::sync::mpsc::channel(16);
    // Subscribe before taking the history: a message accepted in between arrives both
    // ways and is sent once (by sequence number).
    let mut live = state.live.subscribe();
    let mut stopping = state.stopping.subscribe();
    let replay = state.hub.replay();
    let follow = state.read_mode == ReadMode::Follow;
    let counted = Arc::clone(state);
    tokio::spawn(async move {
        let _open = counted.metrics.read_stream();
        let history_seq = replay.seq;
        let history_tx = tx.clone();
        let sent = tokio::task::spawn_blocking(move || {
            for msg in replay.into_messages() {
                let item = msg
                    .map(|m| m.encode_envelope())
                    .map_err(|e| Status::internal(format!("encoding the history: {e}")));
                if history_tx.blocking_send(item).is_err() {
                    return false;
                }
            }
            true
        })
        .await
        .unwrap_or(false);
        if !sent || !follow {
            return;
        }
        loop {
            let received = tokio::select! {
                received = live.recv() => received,
                // The server is stopping: the stream ends (the reader may reconnect).
                _ = stopping.wait_for(|stopping| *stopping) => return,
            };
            match received {
                Ok(Live::Message(seq, msg)) if seq > history_seq => {
                    if tx.send(Ok(msg.encode_envelope())).await.is_err() {
                        return;
                    }
                }
                Ok(Live::Message(..)) => {}
                Ok(Live::RolledBack) => {
                    let _ = tx
                        .send(Err(Status::unavailable(
                            "the server dropped messages it had sent this reader, which its \
                             log failed to keep; reconnect to read the history again",
                        )))
                        .await;
                    return;
                }
                Err(RecvError::Lagged(n)) => {
                    let _ = tx
                        .send(Err(Status::data_loss(format!(
                            "this reader fell {n} messages behind the writers and was \
                             dropped; reconnect to read the history again"
                        ))))
                        .await;
                    return;
                }
                Err(RecvError::Closed) => return,
            }
        }
    });
    MessageStream::new(rx)
}

/// `--token`: every call must carry `authorization: Bearer TOKEN`.
#[derive(Clone)]
pub struct BearerCheck {
    expected: Option<Arc<str>>,
}

impl BearerCheck {
    pub fn new(token: Option<String>) -> Self {
        Self {
            expected: token.map(|t| Arc::from(format!("Bearer {t}"))),
        }
    }
}

impl tonic::service::Interceptor for BearerCheck {
    fn call(&mut self, request: Request<()>) -> Result<Request<()>, Status> {
        let Some(expected) = &self.expected else {
            return Ok(request);
        };
        let given = request
            .metadata()
            .get("authorization")
            .and_then(|v| v.to_str().ok());
        // Compared in constant time: the token is a secret.
        let matches = given.is_some_and(|given| {
            given.len() == expected.len()
                && given
                    .bytes()
                    .zip(expected.bytes())
                    .fold(0u8, |acc, (a, b)| acc | (a ^ b))
                    == 0
        });
        if matches {
            Ok(request)
        } else {
            Err(Status::unauthenticated(
                "this server needs `authorization: Bearer TOKEN` (its --token)",
            ))
        }
    }
}
