//! Issue 72: a browser on the server's port. Rerun's web viewer speaks grpc-web from
//! another origin: a CORS preflight first, then each call as one HTTP/1.1 request whose
//! body holds the call's messages as length-prefixed frames and whose answer ends with a
//! trailers frame. Spoken here byte by byte, as a browser does, beside plain gRPC.

use std::io::{Read as _, Write as _};

use chunkstore::rrd::{LogMsg, StoreId};

use super::server::{READ, Server, WRITE, chunk_msg, info_msg, read_all, runtime, temp_dir};

/// An HTTP/1.1 answer: status, headers (names in lower case) and body (de-chunked).
pub(super) struct Answer {
    pub(super) status: u16,
    headers: Vec<(String, String)>,
    pub(super) body: Vec<u8>,
}

impl Answer {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_str())
    }
}

/// One request to the server on a connection of its own (`Connection: close`).
fn http1(
    server: &Server,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &[u8],
) -> Answer {
    http1_to(
        server.url.trim_start_matches("http://"),
        method,
        path,
        headers,
        body,
    )
}

/// One request to `host` (`HOST:PORT`) on a connection of its own.
pub(super) fn http1_to(
    host: &str,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &[u8],
) -> Answer {
    let mut stream = std::net::TcpStream::connect(host).unwrap();
    let mut request = format!("{method} {path} HTTP/1.1\r\nhost: {host}\r\nconnection: close\r\n");
    for (name, value) in headers {
        request += &[*name, ": ", *value, "\r\n"].concat();
    }
    request += &["content-length: ", &body.len().to_string(), "\r\n\r\n"].concat();
    stream.write_all(request.as_bytes()).unwrap();
    stream.write_all(body).unwrap();
    let mut raw = Vec::new();
    stream.read_to_end(&mut raw).unwrap();
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a header block");
    let head = String::from_utf8(raw[..split].to_vec()).unwrap();
    let mut lines = head.split("\r\n");
    let status = lines
        .next()
        .unwrap()
        .split(' ')
        .nth(1)
        .unwrap()
        .parse()
        .unwrap();
    let headers: Vec<(String, String)> = lines
        .filter_map(|line| line.split_once(':'))
        .map(|(n, v)| (n.trim().to_ascii_lowercase(), v.trim().to_owned()))
        .collect();
    let mut body = raw[split + 4..].to_vec();
    if headers
        .iter()
        .any(|(n, v)| n == "transfer-encoding" && v.contains("chunked"))
    {
        body = dechunk(&body);
    }
    Answer {
        status,
        headers,
        body,
    }
}

/// A chunked transfer's payload.
fn dechunk(mut raw: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let line_end = raw
            .windows(2)
            .position(|w| w == b"\r\n")
            .expect("a chunk size");
        let size_text = std::str::from_utf8(&raw[..line_end]).unwrap();
        let size = usize::from_str_radix(size_text.split(';').next().unwrap().trim(), 16).unwrap();
        raw = &raw[line_end + 2..];
        if size == 0 {
            return out;
        }
        out.extend_from_slice(&raw[..size]);
        raw = &raw[size + 2..];
    }
}

/// grpc-web's body of `messages`: each a data frame (flag 0, a big-endian length, bytes).
fn frames(messages: &[Vec<u8>]) -> Vec<u8> {
    let mut out = Vec::new();
    for message in messages {
        out.push(0);
        out.extend_from_slice(&u32::try_from(message.len()).unwrap().to_be_bytes());
        out.extend_from_slice(message);
    }
    out
}

/// An answer's data frames, and its trailers frame (flag 0x80) as text.
fn unframe(mut body: &[u8]) -> (Vec<Vec<u8>>, String) {
    let (mut messages, mut trailers) = (Vec::new(), String::new());
    while body.len() >= 5 {
        let len = u32::from_be_bytes(body[1..5].try_into().unwrap()) as usize;
        let payload = body[5..5 + len].to_vec();
        if body[0] & 0x80 == 0 {
            messages.push(payload);
        } else {
            trailers.push_str(&String::from_utf8(payload).unwrap());
        }
        body = &body[5 + len..];
    }
    assert!(body.is_empty(), "a frame cut short");
    (messages, trailers.to_ascii_lowercase())
}

/// A call's status: in the headers of an answer without a body, else in its trailers.
fn grpc_status(answer: &Answer) -> Option<String> {
    answer.header("grpc-status").map(str::to_owned).or_else(|| {
        let (_, trailers) = unframe(&answer.body);
        trailers
            .lines()
            .find_map(|l| l.strip_prefix("grpc-status:").map(|s| s.trim().to_owned()))
    })
}

const GRPC_WEB: [(&str, &str); 3] = [
    ("content-type", "application/grpc-web+proto"),
    ("x-grpc-web", "1"),
    ("origin", "http://localhost:9090"),
];

#[test]
fn grpc_web_calls_from_a_browser_get_what_grpc_gets() {
    let dir = temp_dir("grpc-web");
    let server = Server::start(
        &dir,
        &[
            "--read-mode",
            "snapshot",
            "--cors-allow-origin",
            "https://viewer.example.com",
        ],
    );
    let id = StoreId::recording("web", "rec-web");

    // WriteMessages: the stream's messages in one body; its answer, status 0 in trailers.
    let written = [
        info_msg(&id),
        chunk_msg(&id, "/arm", 1, 1.5),
        chunk_msg(&id, "/arm", 2, 2.5),
    ];
    let answer = http1(&server, "POST", WRITE, &GRPC_WEB, &frames(&written));
    assert_eq!(answer.status, 200);
    assert_eq!(
        answer.header("access-control-allow-origin"),
        Some("http://localhost:9090")
    );
    assert!(
        answer
            .header("content-type")
            .is_some_and(|t| t.starts_with("application/grpc-web"))
    );
    let (_, trailers) = unframe(&answer.body);
    assert!(trailers.contains("grpc-status:0"), "{trailers:?}");

    // ReadMessages: the messages a gRPC reader gets, in its order.
    let answer = http1(&server, "POST", READ, &GRPC_WEB, &frames(&[Vec::new()]));
    assert_eq!(answer.status, 200);
    let (messages, trailers) = unframe(&answer.body);
    assert!(trailers.contains("grpc-status:0"), "{trailers:?}");
    let over_web: Vec<LogMsg> = messages
        .iter()
        .map(|bytes| LogMsg::decode_envelope(&arrow_buffer::Buffer::from(bytes.clone())).unwrap())
        .collect();
    let over_grpc = runtime().block_on(read_all(&server));
    assert!(over_grpc.len() >= written.len(), "{}", over_grpc.len());
    assert_eq!(over_web, over_grpc);

    // A bad call is a grpc-web error, not a broken connection: an unknown method.
    let answer = http1(
        &server,
        "POST",
        "/no.such.Service/Call",
        &GRPC_WEB,
        &frames(&[Vec::new()]),
    );
    assert_eq!(grpc_status(&answer).as_deref(), Some("12"), "UNIMPLEMENTED");

    // The preflight: pages of this machine and named origins may call; others may not.
    for (origin, allowed) in [
        ("http://localhost:9090", true),
        ("http://127.0.0.1:3000", true),
        ("https://viewer.example.com", true),
        ("http://evil.example.com", false),
    ] {
        let answer = http1(
            &server,
            "OPTIONS",
            READ,
            &[
                ("origin", origin),
                ("access-control-request-method", "POST"),
                ("access-control-request-headers", "content-type,x-grpc-web"),
            ],
            b"",
        );
        assert!(answer.status < 300, "{origin}: {}", answer.status);
        assert_eq!(
            answer.header("access-control-allow-origin"),
            allowed.then_some(origin),
            "{origin}"
        );
        if allowed {
            let headers = answer
                .header("access-control-allow-headers")
                .unwrap_or_default();
            assert!(headers.contains("x-grpc-web"), "{headers}");
        }
    }
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Behind `--token`, a browser's preflight needs none (a browser sends none), its calls do.
#[test]
fn a_token_guards_grpc_web_calls_but_not_preflights() {
    let dir = temp_dir("grpc-web-token");
    let server = Server::start(&dir, &["--read-mode", "snapshot", "--token", "s3cret"]);
    let preflight = http1(
        &server,
        "OPTIONS",
        READ,
        &[
            ("origin", "http://localhost:9090"),
            ("access-control-request-method", "POST"),
            (
                "access-control-request-headers",
                "authorization,content-type,x-grpc-web",
            ),
        ],
        b"",
    );
    assert!(preflight.status < 300, "{}", preflight.status);
    assert!(
        preflight
            .header("access-control-allow-headers")
            .is_some_and(|h| h.contains("authorization"))
    );
    let refused = http1(&server, "POST", READ, &GRPC_WEB, &frames(&[Vec::new()]));
    assert_eq!(
        grpc_status(&refused).as_deref(),
        Some("16"),
        "UNAUTHENTICATED"
    );
    let mut with_token = GRPC_WEB.to_vec();
    with_token.push(("authorization", "Bearer s3cret"));
    let allowed = http1(&server, "POST", READ, &with_token, &frames(&[Vec::new()]));
    assert_eq!(grpc_status(&allowed).as_deref(), Some("0"));
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}
