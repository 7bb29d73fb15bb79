//! The body of the `log_msg` fuzz target: arbitrary bytes as what a client sends
//! `chunkstore serve`'s `WriteMessages`: a run of messages, each a little-endian `u16`
//! length and that many bytes of a `WriteMessagesRequest` envelope. Each message is decoded
//! and ingested by one [`StoreHub`], as the server does. Nothing may panic; a refused
//! message changes nothing (the sequence number and every recording's rows stay); the hub
//! stays sane; a decoded message's envelope round-trips, and its decoded length lies
//! between its body's and what LZ4 can expand that to; and replaying the hub's history
//! into a fresh hub gives the same recordings with the same rows. Then what the server's
//! `--retention` and its drop action do: retention keeps the hub sane, never adds rows and
//! keeps every recording's newest time on every timeline; a dropped recording is gone and
//! the rest stay. The same bytes are also scanned as an `.rrd` log (what `--persist` reads
//! back at start).

use arrow_buffer::Buffer;
use chunkstore::StoreConfig;
use chunkstore::TimeInt;
use chunkstore::hub::StoreHub;
use chunkstore::rrd::{LogMsg, scan_log};

fn rows(hub: &StoreHub) -> Vec<(String, u64)> {
    hub.recordings()
        .iter()
        .map(|r| {
            (
                r.info.store_id.recording_id.to_string(),
                r.snapshot.stats().num_rows(),
            )
        })
        .collect()
}

pub fn log_msg(bytes: &[u8]) {
    let scan = scan_log(&Buffer::from(bytes.to_vec()));
    assert!(scan.valid_len <= bytes.len() as u64);
    assert!(scan.fault.is_some() || scan.valid_len == bytes.len() as u64);

    let hub = StoreHub::new(StoreConfig::DEFAULT.with_max_rows(4)).expect("a valid config");
    let mut rest = bytes;
    while rest.len() >= 2 {
        let len = usize::from(u16::from_le_bytes([rest[0], rest[1]])).min(rest.len() - 2);
        let message = Buffer::from(rest[2..2 + len].to_vec());
        rest = &rest[2 + len..];
        let Ok(msg) = LogMsg::decode_envelope(&message) else {
            continue;
        };
        let again = LogMsg::decode_envelope(&Buffer::from(msg.encode_envelope()))
            .expect("an envelope this crate wrote decodes");
        assert_eq!(again, msg);
        // What the server counts a message as (it drives the memory checks): never less
        // than the body, never more than LZ4 can expand it to.
        let body = msg.body().len() as u64;
        let decoded = msg.decoded_len();
        assert!(decoded >= body && decoded <= body.saturating_mul(255).max(body));
        let (seq, before) = (hub.last_seq(), rows(&hub));
        if let Ok(new_seq) = hub.ingest(&msg) {
            assert_eq!(new_seq, seq + 1);
        } else {
            assert_eq!(hub.last_seq(), seq, "a refused message took a number");
            assert_eq!(rows(&hub), before, "a refused message changed the rows");
        }
    }
    hub.sanity_check().expect("the hub stays sane");

    let copy = StoreHub::new(StoreConfig::DEFAULT).expect("a valid config");
    for msg in hub.replay().into_messages() {
        copy.ingest(&msg.expect("a held chunk encodes"))
            .expect("a replayed message is accepted");
    }
    assert_eq!(
        rows(&copy),
        rows(&hub),
        "the replay holds what the hub held"
    );

    // Retention on every timeline at once (every newest time measured before anything
    // goes): what is left on a timeline lies within the span behind its newest time before.
    let before = (rows(&hub), newest(&hub));
    let retained = bytes.len() as u64 % 8;
    hub.retain_recent(|_| Some(retained));
    hub.sanity_check()
        .expect("the hub stays sane after retention");
    for ((id, after), (_, was)) in rows(&hub).iter().zip(&before.0) {
        assert!(after <= was, "retention added rows to {id}");
    }
    for (recording, was) in hub.recordings().iter().zip(&before.1) {
        for (timeline, newest) in was {
            let (Some(left), Some(newest)) =
                (recording.snapshot.view().time_range(timeline), newest)
            else {
                continue;
            };
            let oldest_kept = i128::from(newest.as_i64()) - i128::from(retained);
            assert!(
                i128::from(left.min().as_i64()) >= oldest_kept,
                "retention left {timeline} data older than its span"
            );
        }
    }
    if let Some(first) = hub.recordings().first() {
        let id = first.info.store_id.recording_id.clone();
        let held = hub.recording_count();
        let dropped = hub.drop_recording(&id);
        assert!(!dropped.is_empty(), "a held recording was not dropped");
        assert_eq!(hub.recording_count(), held - dropped.len());
        assert!(rows(&hub).iter().all(|(other, _)| other.as_str() != &*id));
        hub.sanity_check().expect("the hub stays sane after a drop");
    }
}

/// Every recording's newest time on each of its timelines.
fn newest(hub: &StoreHub) -> Vec<Vec<(String, Option<TimeInt>)>> {
    hub.recordings()
        .iter()
        .map(|r| {
            r.snapshot
                .view()
                .timelines()
                .iter()
                .map(|t| {
                    let newest = r
                        .snapshot
                        .view()
                        .time_range(t.name())
                        .map(chunkstore::TimeRange::max);
                    (t.name().to_owned(), newest)
                })
                .collect()
        })
        .collect()
}
