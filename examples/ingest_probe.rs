//! The server's ingest without the network, for instruction counts: every message of an
//! `.rrd` file decoded and applied to a `StoreHub` one at a time, as `chunkstore serve`
//! does with a write stream's messages.
//!
//! ```text
//! cargo build --release --example ingest_probe
//! valgrind --tool=callgrind --toggle-collect='*probe_hub*' \
//!     target/release/examples/ingest_probe FILE.rrd
//! ```
#![allow(
    clippy::expect_used,
    reason = "a measurement program: a failure should stop it loudly"
)]

use chunkstore::StoreConfig;
use chunkstore::hub::StoreHub;
use chunkstore::rrd::{LogMsg, scan_log};

#[inline(never)]
fn probe_hub(hub: &StoreHub, messages: &[LogMsg]) {
    for msg in messages {
        hub.ingest(msg).expect("a valid message");
    }
}

fn main() {
    let path = std::env::args()
        .nth(1)
        .expect("usage: ingest_probe FILE.rrd");
    let bytes = std::fs::read(path).expect("a readable file");
    let scan = scan_log(&arrow_buffer::Buffer::from_vec(bytes));
    let hub = StoreHub::new(StoreConfig::DEFAULT).expect("the default configuration");
    let start = std::time::Instant::now();
    probe_hub(&hub, &scan.messages);
    eprintln!("{} messages in {:?}", scan.messages.len(), start.elapsed());
}
