//! `chunkstore serve`'s command line: [`ServeArgs`], apart from the server so that the
//! `cli_args` fuzz target compiles it with clap alone (it lives beside `retention.rs`,
//! whose rules it parses, and takes `parse_bytes` from its parent).

use std::net::SocketAddr;
use std::path::PathBuf;

use clap::{Parser, ValueEnum};

use super::parse_bytes;
use super::retention;

const SERVE_EXAMPLES: &str = "\
Examples:
  chunkstore serve
  chunkstore serve robot.rrd --persist live.rrd --memory-limit 2GiB
  chunkstore serve --addr 0.0.0.0:9876 --token s3cret --tls-cert cert.pem --tls-key key.pem
  chunkstore serve --metrics-addr 127.0.0.1:9100

Log into it from Rerun's SDK (Python):
  rr.init(\"robot\"); rr.connect_grpc(\"rerun+http://127.0.0.1:9876/proxy\")
Query it with Flight SQL (ADBC, Python):
  adbc_driver_flightsql.dbapi.connect(\"grpc://127.0.0.1:9876\")
Save what it holds with Rerun's CLI (with --read-mode snapshot, which ends the read):
  rerun --save out.rrd --connect rerun+http://127.0.0.1:9876/proxy

A token (--token) protects every call: Flight SQL clients send it as
`authorization: Bearer TOKEN`. Rerun's SDK cannot send one, so a token-protected server
takes no logging from it: use a token for a server that only answers queries (of
preloaded SOURCEs or a --persist log), or keep the default loopback address.

Log lines go to stderr; RUST_LOG sets their level (`warn`, `info` the default, `debug`).";

/// Serve recordings live: Rerun SDKs log into it (Rerun's gRPC proxy protocol) and SQL
/// clients query it (Arrow Flight SQL), on one port.
#[derive(Parser, Debug)]
#[command(name = "chunkstore serve", version, after_help = SERVE_EXAMPLES)]
pub struct ServeArgs {
    /// Recordings to load before listening: `.rrd` files or directories of Arrow IPC
    /// chunk files, local or named by URL (`s3://…`, as any SOURCE). They are served, not
    /// written to the --persist log.
    pub sources: Vec<PathBuf>,
    /// Address to listen on, `HOST:PORT` (`localhost:9876`, `0.0.0.0:9876`; `:0` picks a
    /// free port, and the line printed on start says which).
    #[arg(long, default_value = "127.0.0.1:9876", value_parser = parse_addr)]
    pub addr: SocketAddr,
    /// Append every accepted message to this `.rrd` file before acknowledging it, and
    /// read it back on start (a file Rerun wrote works too).
    #[arg(long, value_name = "FILE.rrd")]
    pub persist: Option<PathBuf>,
    /// Keep the process near this size (e.g. 512MiB, 2GB): the stores get what is left
    /// after the server's working memory (a quarter, at least 128MiB, at most half), and
    /// garbage collection drops their oldest rows first, keeping the latest of each column
    /// and all static data.
    #[arg(long, value_name = "BYTES", value_parser = parse_bytes)]
    pub memory_limit: Option<u64>,
    /// What a reader (`ReadMessages`: viewers, `rerun --connect`) gets: the history, then
    /// live messages (follow), or the history alone (snapshot).
    #[arg(long, value_enum, default_value_t = ReadMode::Follow)]
    pub read_mode: ReadMode,
    /// Require `authorization: Bearer TOKEN` on every call (see below).
    #[arg(long, value_name = "TOKEN")]
    pub token: Option<String>,
    /// Most log streams open at once; more are refused (`RESOURCE_EXHAUSTED`).
    #[arg(long, value_name = "N", default_value_t = 256)]
    pub max_write_streams: usize,
    /// Largest message accepted (an image chunk can be many megabytes). Default: 1GiB, or
    /// an eighth of --memory-limit; at most half of it.
    #[arg(long, value_name = "BYTES", value_parser = parse_bytes)]
    pub max_message_bytes: Option<u64>,
    /// A web page origin (`https://viewer.example.com`) allowed to call the server from a
    /// browser (grpc-web, as Rerun's web viewer speaks), besides pages served from this
    /// machine (`localhost`, `127.0.0.1`, `[::1]`, any port); `*` allows any; repeatable.
    #[arg(long = "cors-allow-origin", value_name = "ORIGIN")]
    pub cors_allow_origins: Vec<String>,
    /// Speak TLS with this certificate chain (PEM); clients then connect to
    /// `rerun+https://` and `grpc+tls://`. Needs --tls-key.
    #[arg(long, value_name = "FILE.pem", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// The private key of --tls-cert (PEM: PKCS#8, PKCS#1 or SEC1).
    #[arg(long, value_name = "FILE.pem", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Keep only the last SPAN of data behind the newest time: `1h` on every time
    /// timeline (timestamps, durations), `frame=100000` or `log_time=30m` on one
    /// timeline; repeatable, a named timeline's rule wins. Applied once a second.
    #[arg(long, value_name = "[TIMELINE=]SPAN", value_parser = retention::parse_rule)]
    pub retention: Vec<retention::Rule>,
    /// Answer Prometheus (`GET /metrics`) and HTTP probes (`GET /health`) on this
    /// address, plain HTTP without the token (keep it on a private network).
    #[arg(long, value_name = "HOST:PORT", value_parser = parse_addr)]
    pub metrics_addr: Option<SocketAddr>,
    /// An option of the object store a URL SOURCE is in, as for any command
    /// (`aws_endpoint=URL`, …); repeatable.
    #[arg(long = "storage-option", value_name = "KEY=VALUE", value_parser = chunkstore::storage::StorageOptions::parse_pair)]
    pub storage_options: Vec<(String, String)>,
}

/// What `ReadMessages` sends.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ReadMode {
    /// The history, then live messages until the client goes.
    Follow,
    /// The history, then the end of the stream.
    Snapshot,
}

/// `HOST:PORT`, a name resolved to its first address (`localhost:9876`).
pub fn parse_addr(text: &str) -> Result<SocketAddr, String> {
    text.parse().or_else(|_| resolve(text))
}

#[cfg(not(any(fuzzing, test)))]
fn resolve(text: &str) -> Result<SocketAddr, String> {
    use std::net::ToSocketAddrs as _;
    text.to_socket_addrs()
        .map_err(|e| format!("{text:?} is not HOST:PORT ({e})"))?
        .next()
        .ok_or_else(|| format!("{text:?} names no address"))
}

/// A fuzzer's arbitrary names would each be a DNS query (when fuzzing, and when `cargo
/// test` replays the fuzzer's corpus).
#[cfg(any(fuzzing, test))]
fn resolve(text: &str) -> Result<SocketAddr, String> {
    Err(format!(
        "{text:?} is not an address (names are not resolved when fuzzing)"
    ))
}
