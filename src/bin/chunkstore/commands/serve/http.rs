//! `--metrics-addr`: a plain HTTP/1.1 listener apart from the gRPC port, for Prometheus
//! (`GET /metrics`) and for probes that speak HTTP (`GET /health`: 200 while serving, 503
//! once stopping). One request per connection; anything else is 404 or 405. Kept this
//! small on purpose: it reads one request head of at most 8 KiB, within 5 seconds.

use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
use tokio::net::{TcpListener, TcpStream};

/// The longest request head read.
const MAX_HEAD: usize = 8 << 10;
/// How long a client may take to send it.
const READ_TIMEOUT: Duration = Duration::from_secs(5);

/// What the endpoints answer with, asked at each request.
pub struct Endpoints {
    /// The metrics text.
    pub metrics: Box<dyn Fn() -> String + Send + Sync>,
    /// Whether the server is serving (not stopping).
    pub serving: Box<dyn Fn() -> bool + Send + Sync>,
}

/// Answers requests on `listener` until `stop` resolves.
pub async fn serve(
    listener: TcpListener,
    endpoints: Arc<Endpoints>,
    stop: impl std::future::Future<Output = ()>,
) {
    tokio::pin!(stop);
    loop {
        let accepted = tokio::select! {
            accepted = listener.accept() => accepted,
            () = &mut stop => return,
        };
        match accepted {
            Ok((connection, _)) => {
                let endpoints = Arc::clone(&endpoints);
                tokio::spawn(async move {
                    let _ =
                        tokio::time::timeout(READ_TIMEOUT, answer(connection, &endpoints)).await;
                });
            }
            // Out of file descriptors, say: wait a moment rather than spin.
            Err(e) => {
                tracing::warn!("metrics listener: accepting a connection: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    }
}

/// Reads one request head and writes the response.
async fn answer(mut connection: TcpStream, endpoints: &Endpoints) -> std::io::Result<()> {
    let mut head = Vec::with_capacity(1024);
    let mut buf = [0u8; 1024];
    while !head.windows(4).any(|w| w == b"\r\n\r\n") {
        if head.len() >= MAX_HEAD {
            return respond(&mut connection, 431, "request head too large\n").await;
        }
        let n = connection.read(&mut buf).await?;
        if n == 0 {
            return Ok(());
        }
        head.extend_from_slice(&buf[..n]);
    }
    let line = head.split(|&b| b == b'\r').next().unwrap_or_default();
    let line = String::from_utf8_lossy(line);
    let mut parts = line.split(' ');
    let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
    let path = target.split('?').next().unwrap_or("");
    match (method, path) {
        ("GET", "/metrics") => respond(&mut connection, 200, &(endpoints.metrics)()).await,
        ("GET", "/health") if (endpoints.serving)() => {
            respond(&mut connection, 200, "serving\n").await
        }
        ("GET", "/health") => respond(&mut connection, 503, "stopping\n").await,
        (_, "/metrics" | "/health") => respond(&mut connection, 405, "only GET\n").await,
        _ => respond(&mut connection, 404, "not found: try /metrics or /health\n").await,
    }
}

async fn respond(connection: &mut TcpStream, status: u16, body: &str) -> std::io::Result<()> {
    let reason = match status {
        200 => "OK",
        404 => "Not Found",
        405 => "Method Not Allowed",
        431 => "Request Header Fields Too Large",
        _ => "Service Unavailable",
    };
    let head = format!(
        "HTTP/1.1 {status} {reason}\r\ncontent-type: text/plain; version=0.0.4; \
         charset=utf-8\r\ncontent-length: {}\r\nconnection: close\r\n\r\n",
        body.len()
    );
    connection.write_all(head.as_bytes()).await?;
    connection.write_all(body.as_bytes()).await?;
    connection.shutdown().await
}
