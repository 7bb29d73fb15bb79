//! Browsers on the server's port: grpc-web (tonic's own translation, `tonic_web`) for Rerun's
//! web viewer, which is served from another origin, and the CORS answers a browser needs
//! before it sends a call from that origin. Flight SQL and the SDK keep plain gRPC on the
//! same port.

use std::time::Duration;

use tonic::codegen::http::{HeaderName, HeaderValue, Method};
use tower_http::cors::{AllowOrigin, CorsLayer};

/// How long a browser may keep a preflight's answer.
const PREFLIGHT_MAX_AGE: Duration = Duration::from_hours(24);

/// Request headers a grpc-web call carries (and `authorization`, for `--token`).
const ALLOWED_HEADERS: [&str; 6] = [
    "content-type",
    "x-grpc-web",
    "x-user-agent",
    "grpc-timeout",
    "authorization",
    "grpc-accept-encoding",
];

/// Response headers a grpc-web client reads (a call's status, when it has no body).
const EXPOSED_HEADERS: [&str; 3] = ["grpc-status", "grpc-message", "grpc-status-details-bin"];

/// The origins whose pages may call the server: any page served from this machine
/// (`localhost`, `127.0.0.1` or `[::1]` on any port, over HTTP or HTTPS), and each of
/// `extra` (`--cors-allow-origin`; `*` allows every origin).
#[derive(Clone, Debug)]
pub struct AllowedOrigins {
    extra: Vec<String>,
}

impl AllowedOrigins {
    /// The local origins and `extra` (each as a browser writes an origin:
    /// `scheme://host[:port]`, a trailing `/` ignored).
    pub fn new(extra: &[String]) -> Self {
        Self {
            extra: extra
                .iter()
                .map(|origin| origin.trim_end_matches('/').to_ascii_lowercase())
                .collect(),
        }
    }

    /// Whether a page of `origin` may call the server.
    pub fn allows(&self, origin: &str) -> bool {
        let origin = origin.to_ascii_lowercase();
        if self.extra.iter().any(|o| o == "*" || *o == origin) {
            return true;
        }
        let Some(rest) = origin
            .strip_prefix("http://")
            .or_else(|| origin.strip_prefix("https://"))
        else {
            return false;
        };
        let host = match rest.strip_prefix('[') {
            // An IPv6 literal: `[::1]` or `[::1]:port`.
            Some(v6) => v6.split_once(']'),
            None => Some(rest.split_once(':').unwrap_or((rest, ""))),
        };
        let Some((host, port)) = host else {
            return false;
        };
        let port = port.strip_prefix(':').unwrap_or(port);
        let port_ok = port.is_empty() || port.parse::<u16>().is_ok();
        port_ok && matches!(host, "localhost" | "127.0.0.1" | "::1")
    }

    /// The CORS layer that answers preflights for these origins and marks their calls'
    /// answers readable.
    pub fn layer(&self) -> CorsLayer {
        let origins = self.clone();
        CorsLayer::new()
            .allow_origin(AllowOrigin::predicate(move |origin: &HeaderValue, _| {
                origin.to_str().is_ok_and(|o| origins.allows(o))
            }))
            .allow_methods([Method::POST, Method::OPTIONS])
            .allow_headers(ALLOWED_HEADERS.map(HeaderName::from_static))
            .expose_headers(EXPOSED_HEADERS.map(HeaderName::from_static))
            .max_age(PREFLIGHT_MAX_AGE)
    }
}

#[cfg(test)]
mod tests {
    use super::AllowedOrigins;

    #[test]
    fn local_pages_and_named_origins_are_allowed() {
        let origins = AllowedOrigins::new(&["https://viewer.example.com/".to_owned()]);
        for allowed in [
            "http://localhost:9090",
            "http://127.0.0.1:9090",
            "https://localhost",
            "http://[::1]:8080",
            "HTTP://LOCALHOST:1",
            "https://viewer.example.com",
        ] {
            assert!(origins.allows(allowed), "{allowed}");
        }
        for refused in [
            "http://evil.example.com",
            "http://localhost.evil.example.com",
            "http://127.0.0.1.evil.example.com:80",
            "file://localhost",
            "http://localhost:notaport",
            "http://[::1",
            "null",
            "",
            "https://viewer.example.com:8443",
        ] {
            assert!(!origins.allows(refused), "{refused}");
        }
        assert!(AllowedOrigins::new(&["*".to_owned()]).allows("http://anything.example"));
    }
}
