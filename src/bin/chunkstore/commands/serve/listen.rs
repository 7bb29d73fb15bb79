//! The network side of `chunkstore serve`: the listener (TLS if asked), the services on
//! its port (Rerun's proxy and Flight SQL behind the token, grpc-web and CORS in front,
//! the gRPC health service open to probes), the `--metrics-addr` listener, the lines a
//! started server prints, and the stop: on SIGTERM or Ctrl-C, health turns to
//! `NOT_SERVING`, no connection is accepted, open calls get [`SHUTDOWN_GRACE`] to finish,
//! and the log is synced.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use super::{ReadMode, SHUTDOWN_GRACE, ServerState, flight, http, proxy, web};

/// How long a TLS client may take to finish its handshake.
const TLS_HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// How long a connection may be silent before the kernel asks whether its peer is still
/// there: a robot that loses power mid-stream leaves no FIN, and without asking, its write
/// stream would stay open for as long as the server runs.
const TCP_KEEPALIVE: Duration = Duration::from_mins(1);

/// The connections `listener` accepts, set up as tonic's own listener sets them up (its
/// builder's `tcp_nodelay` is ignored for connections handed to it): without
/// `TCP_NODELAY`, a response's last small write waited for the client's delayed
/// acknowledgement, and every Flight SQL query took 40 ms more than its work.
fn connections(listener: tokio::net::TcpListener) -> tonic::transport::server::TcpIncoming {
    tonic::transport::server::TcpIncoming::from(listener)
        .with_nodelay(Some(true))
        .with_keepalive(Some(TCP_KEEPALIVE))
}

/// How the server listens: [`serve`]'s settings from the command line.
pub struct Listen {
    pub addr: SocketAddr,
    pub token: Option<String>,
    /// The certificate chain and key (PEM) to speak TLS with.
    pub tls: Option<tonic::transport::Identity>,
    /// The HTTP/2 flow-control windows, per stream and per connection.
    pub windows: (u32, u32),
    pub origins: web::AllowedOrigins,
    /// Where Prometheus and HTTP probes are answered.
    pub metrics_addr: Option<SocketAddr>,
}

/// Waits for SIGTERM or Ctrl-C on a thread of its own, so that a runtime whose threads
/// are all busy (a query's CPU work) still hears it; then notifies the returned handle, and
/// if the process has not ended [`SHUTDOWN_GRACE`] and two seconds later, ends it.
pub fn stop_signal() -> Result<Arc<tokio::sync::Notify>, String> {
    let stop = Arc::new(tokio::sync::Notify::new());
    let notify = Arc::clone(&stop);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| format!("starting the signal thread: {e}"))?;
    // Registered before this returns: a signal from now on is heard.
    let mut terminate = runtime
        .block_on(async {
            tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        })
        .map_err(|e| format!("listening for SIGTERM: {e}"))?;
    std::thread::Builder::new()
        .name("stop-signal".to_owned())
        .spawn(move || {
            runtime.block_on(async {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = terminate.recv() => {}
                }
            });
            notify.notify_one();
            std::thread::sleep(SHUTDOWN_GRACE + Duration::from_secs(2));
            tracing::warn!("the server did not stop in time after the stop signal; exiting");
            std::process::exit(1);
        })
        .map_err(|e| format!("starting the signal thread: {e}"))?;
    Ok(stop)
}

/// The lines a started server prints: on stderr, notes and the Flight SQL URL; then on
/// stdout the URL loggers connect to, which is how a script learns the port.
fn announce(local: SocketAddr, read_mode: ReadMode, tls: bool, metrics: Option<SocketAddr>) {
    // On every interface (0.0.0.0, ::), clients connect to one of the machine's own
    // addresses: the line shows loopback, which works here.
    let shown = if local.ip().is_unspecified() {
        let loopback: std::net::IpAddr = if local.is_ipv4() {
            std::net::Ipv4Addr::LOCALHOST.into()
        } else {
            std::net::Ipv6Addr::LOCALHOST.into()
        };
        SocketAddr::new(loopback, local.port())
    } else {
        local
    };
    // Notes first: a script that reads the line below may stop the server at once.
    if local.ip().is_unspecified() {
        eprintln!(
            "listening on every interface ({local}): from other machines, use this one's \
             address with port {}",
            local.port()
        );
    }
    if read_mode == ReadMode::Follow {
        eprintln!(
            "readers follow live data until they leave: `rerun --save FILE --connect` keeps \
             running (stop it with Ctrl-C), or start the server with --read-mode snapshot"
        );
    }
    if let Some(metrics) = metrics {
        eprintln!("metrics on http://{metrics}/metrics, health on http://{metrics}/health");
    }
    let (grpc, rerun) = if tls {
        ("grpc+tls", "rerun+https")
    } else {
        ("grpc", "rerun+http")
    };
    eprintln!("Flight SQL on {grpc}://{shown}");
    println!("listening on {rerun}://{shown}/proxy");
    // The line above is how a script learns the port: make sure it is out.
    {
        use std::io::Write as _;
        let _ = std::io::stdout().flush();
    }
}

/// The largest HTTP/2 frame a client may send us, for a stream window: 1 MiB (HTTP/2's
/// default is 16 KiB), at most the window (a frame cannot be larger than what the client
/// may send ahead). Fewer, larger frames are fewer reads and wake-ups per message: with
/// one SDK client sending 82.6 MB, half the context switches (1,003 and 533 against 2,045
/// and 1,081 over two runs), 3% fewer instructions (callgrind: 1.97 G against 2.03 G), and
/// `benches/server_ingest.py --only ingest` server CPU over a file load's 1.40–1.69×
/// against 1.76–1.87× (one client), 1.00–1.09× against 1.09–1.25× (eight), four runs each.
fn max_frame_size(stream_window: u32) -> u32 {
    // HTTP/2 allows 16 KiB to 16 MiB - 1.
    (1 << 20).min(stream_window).max(16 << 10)
}

/// Serves `state` until `stop` is notified, then stops as the module says.
pub async fn serve(
    state: Arc<ServerState>,
    listen: Listen,
    stop: Arc<tokio::sync::Notify>,
    queries: tokio::runtime::Handle,
) -> Result<(), String> {
    let Listen {
        addr,
        token,
        tls,
        windows: (stream_window, connection_window),
        origins,
        metrics_addr,
    } = listen;
    // Set up before listening, so that a bad certificate or key is an error before the
    // start lines.
    let mut builder = tonic::transport::Server::builder();
    let tls_on = tls.is_some();
    if let Some(identity) = tls {
        builder = builder
            // A client that opens a connection and never finishes its handshake is
            // dropped rather than held.
            .tls_config(
                tonic::transport::ServerTlsConfig::new()
                    .identity(identity)
                    .timeout(TLS_HANDSHAKE_TIMEOUT),
            )
            .map_err(|e| format!("--tls-cert/--tls-key: {}", error_chain(&e)))?;
    }
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|e| format!("listening on {addr}: {e}"))?;
    let local = listener
        .local_addr()
        .map_err(|e| format!("listening on {addr}: {e}"))?;
    let metrics_local = match metrics_addr {
        Some(metrics_addr) => Some(listen_for_metrics(&state, metrics_addr).await?),
        None => None,
    };
    announce(local, state.read_mode, tls_on, metrics_local);
    spawn_every_second(&state);
    let auth = proxy::BearerCheck::new(token);
    let proxy_service = tonic::service::interceptor::InterceptedService::new(
        proxy::ProxyService::new(Arc::clone(&state)),
        auth.clone(),
    );
    let flight_service = tonic::service::interceptor::InterceptedService::new(
        arrow_flight::flight_service_server::FlightServiceServer::new(flight::SqlService::new(
            Arc::clone(&state),
            queries,
        ))
        .max_decoding_message_size(state.max_message_bytes)
        .max_encoding_message_size(usize::MAX),
        auth,
    );
    // Probes ask without a token: health says nothing about the data.
    let (health, health_service) = tonic_health::server::health_reporter();
    set_health(&health, tonic_health::ServingStatus::Serving).await;
    let incoming = connections(listener);
    let stopping = Arc::clone(&state);
    let shutdown = async move {
        stop.notified().await;
        tracing::info!(
            "stopping: no new connections; open calls have {} s",
            SHUTDOWN_GRACE.as_secs()
        );
        set_health(&health, tonic_health::ServingStatus::NotServing).await;
        // Live readers end their streams, so that the graceful stop does not wait for
        // them (a follow reader never ends by itself).
        stopping.stopping.send_replace(true);
    };
    // HTTP/2's default flow-control windows (64 KiB) let a client send one window, then
    // wait a round trip for more: an SDK streaming 60 kB chunks ran at a third of its
    // speed. Large windows let it stream; a write stream still holds one message at a time.
    // A browser speaks grpc-web over HTTP/1.1 (or HTTP/2) on the same port: CORS answers
    // its preflights first, then grpc-web calls are translated to gRPC.
    let server = builder
        .initial_stream_window_size(Some(stream_window))
        .initial_connection_window_size(Some(connection_window))
        .max_frame_size(Some(max_frame_size(stream_window)))
        .accept_http1(true)
        .layer(origins.layer())
        .layer(tonic_web::GrpcWebLayer::new())
        .add_service(health_service)
        .add_service(proxy_service)
        .add_service(flight_service)
        .serve_with_incoming_shutdown(incoming, shutdown);
    let mut stopped = state.stopping.subscribe();
    let outcome = tokio::select! {
        result = server => result,
        () = async {
            let _ = stopped.wait_for(|stopping| *stopping).await;
            tokio::time::sleep(SHUTDOWN_GRACE).await;
        } => {
            tracing::warn!(
                "calls still open {} s after the stop signal were cut off",
                SHUTDOWN_GRACE.as_secs()
            );
            Ok(())
        }
    };
    if let Some(log) = &state.persist {
        log.sync()
            .map_err(|e| format!("{}: {e}", log.path().display()))?;
    }
    outcome.map_err(|e| format!("serving on {local}: {e}"))
}

/// Says `status` for the whole server (`""`) and each of its services.
async fn set_health(
    health: &tonic_health::server::HealthReporter,
    status: tonic_health::ServingStatus,
) {
    for service in ["", proxy::SERVICE, flight::SERVICE] {
        health.set_service_status(service, status).await;
    }
}

/// Starts the `--metrics-addr` listener; it stops with the server. Returns its address.
async fn listen_for_metrics(
    state: &Arc<ServerState>,
    addr: SocketAddr,
) -> Result<SocketAddr, String> {
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|e| format!("--metrics-addr {addr}: {e}"))?;
    let local = listener
        .local_addr()
        .map_err(|e| format!("--metrics-addr {addr}: {e}"))?;
    let metrics_state = Arc::clone(state);
    let serving_state = Arc::clone(state);
    let endpoints = Arc::new(http::Endpoints {
        metrics: Box::new(move || metrics_state.metrics_text()),
        serving: Box::new(move || !*serving_state.stopping.borrow()),
    });
    let mut stopped = state.stopping.subscribe();
    tokio::spawn(http::serve(listener, endpoints, async move {
        let _ = stopped.wait_for(|stopping| *stopping).await;
        // Still answering (503 on /health) while calls finish.
        tokio::time::sleep(SHUTDOWN_GRACE).await;
    }));
    Ok(local)
}

/// An error with its causes, on one line (rustls' reasons are in the causes).
fn error_chain(error: &dyn std::error::Error) -> String {
    let mut text = error.to_string();
    let mut source = error.source();
    while let Some(cause) = source {
        text.push_str(": ");
        text.push_str(&cause.to_string());
        source = cause.source();
    }
    text
}

/// The work done once a second, off the async threads: syncing the log (a stream that
/// ends syncs it too; this bounds what a crash loses of streams still open) and applying
/// `--retention`.
fn spawn_every_second(state: &Arc<ServerState>) {
    if state.persist.is_none() && !state.has_retention() && state.memory_limit.is_none() {
        return;
    }
    let state = Arc::clone(state);
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        loop {
            tick.tick().await;
            let state = Arc::clone(&state);
            let _ = tokio::task::spawn_blocking(move || {
                if let Some(log) = &state.persist
                    && let Err(e) = log.sync_if_dirty()
                {
                    tracing::warn!("syncing {}: {e}", log.path().display());
                    state.recover_log();
                }
                if state.has_retention() {
                    state.apply_retention();
                    state.rewrite_log_if_large();
                }
                if state.memory_limit.is_some() {
                    super::allocator::release_free_memory();
                }
            })
            .await;
        }
    });
}

#[cfg(test)]
mod tests {
    use futures::StreamExt as _;

    use super::{connections, max_frame_size};

    #[test]
    fn frames_are_a_mebibyte_or_the_window_within_what_http2_allows() {
        assert_eq!(max_frame_size(2 << 20), 1 << 20);
        assert_eq!(max_frame_size(256 << 10), 256 << 10);
        assert_eq!(max_frame_size(1024), 16 << 10);
    }

    #[tokio::test]
    async fn accepted_connections_send_small_writes_at_once() {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let mut incoming = connections(listener);
        let _client = tokio::net::TcpStream::connect(addr).await.unwrap();
        let accepted = incoming.next().await.unwrap().unwrap();
        assert!(accepted.nodelay().unwrap());
        let socket = socket2::SockRef::from(&accepted);
        assert!(socket.keepalive().unwrap());
        assert_eq!(socket.tcp_keepalive_time().unwrap(), super::TCP_KEEPALIVE);
    }
}
