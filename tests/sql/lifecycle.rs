//! Issue 72: what a long-running server keeps. `--retention` drops what is older than its
//! span behind each recording's newest time, and nothing else; a restart on the same log
//! keeps to it.

use std::time::{Duration, Instant};

use chunkstore::rrd::StoreId;

use super::server::{Server, chunk_msg, counts, info_msg, runtime, temp_dir, write, write_as};

/// Waits until `counts(table)` is `expected`, or fails after 10 s with what it was.
async fn wait_for_counts(server: &Server, table: &str, expected: &[(&str, i64)]) {
    let expected: Vec<(String, i64)> = expected
        .iter()
        .map(|(s, n)| ((*s).to_owned(), *n))
        .collect();
    let start = Instant::now();
    loop {
        let got = counts(server, table).await;
        if got == expected {
            return;
        }
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "{got:?} != {expected:?}: {}",
            server.stderr()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

#[test]
fn retention_keeps_the_last_span_of_each_recording_across_a_restart() {
    let dir = temp_dir("retention");
    let rt = runtime();
    let log = dir.join("live.rrd");
    let args = [
        "--retention",
        "frame=10",
        "--persist",
        log.to_str().unwrap(),
    ];
    let server = Server::start(&dir, &args);
    let (r1, r2) = (
        StoreId::recording("app", "r1"),
        StoreId::recording("app", "r2"),
    );
    rt.block_on(async {
        // r1 up to frame 99, r2 up to frame 40: each keeps frames from its own newest − 10.
        let mut messages = vec![info_msg(&r1), info_msg(&r2)];
        for frame in 0..100 {
            messages.push(chunk_msg(&r1, "/a", frame, 1.0));
            if frame <= 40 {
                messages.push(chunk_msg(&r2, "/b", frame, 2.0));
            }
        }
        write(&server, messages).await.unwrap();
        wait_for_counts(&server, "frame", &[("r1", 11), ("r2", 11)]).await;
        // A late row older than the span goes too; a newer one moves r2's window.
        write(
            &server,
            vec![chunk_msg(&r2, "/b", 5, 3.0), chunk_msg(&r2, "/b", 45, 3.0)],
        )
        .await
        .unwrap();
        wait_for_counts(&server, "frame", &[("r1", 11), ("r2", 7)]).await;
    });
    drop(server);
    // The log holds everything acknowledged; the restarted server applies the same rule.
    let again = Server::start(&dir, &args);
    rt.block_on(wait_for_counts(&again, "frame", &[("r1", 11), ("r2", 7)]));
    drop(again);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `DoAction` of `chunkstore.drop_recording` with `token`: the result's text, or the error.
async fn drop_recording(
    server: &Server,
    id: &str,
    token: Option<&str>,
) -> Result<String, tonic::Status> {
    let mut client =
        arrow_flight::flight_service_client::FlightServiceClient::new(server.channel().await);
    let mut request = tonic::Request::new(arrow_flight::Action {
        r#type: "chunkstore.drop_recording".to_owned(),
        body: id.as_bytes().to_vec().into(),
    });
    if let Some(token) = token {
        request
            .metadata_mut()
            .insert("authorization", format!("Bearer {token}").parse().unwrap());
    }
    let mut results = client.do_action(request).await?.into_inner();
    let result = results.message().await?.expect("one result");
    Ok(String::from_utf8(result.body.to_vec()).unwrap())
}

#[test]
fn the_recordings_table_lists_them_and_a_dropped_one_stays_dropped() {
    let dir = temp_dir("recordings");
    let rt = runtime();
    let log = dir.join("live.rrd");
    let args = ["--persist", log.to_str().unwrap(), "--token", "s3cret"];
    let server = Server::start(&dir, &args);
    let (r1, r2) = (
        StoreId::recording("app", "r1"),
        StoreId::recording("other", "r2"),
    );
    rt.block_on(async {
        let mut messages = vec![info_msg(&r1), info_msg(&r2)];
        for frame in 0..5 {
            messages.push(chunk_msg(&r1, "/a", frame, 1.0));
        }
        messages.push(chunk_msg(&r2, "/b", 42, 2.0));
        write_as(&server, messages, Some("s3cret")).await.unwrap();
        let table = super::server::query(
            &server,
            "SELECT rerun_segment_id, application_id, rows, frame_first, frame_last, heap_bytes > 0 AS held \
             FROM recordings ORDER BY 1",
            Some("s3cret"),
        )
        .await
        .unwrap();
        let text = datafusion::arrow::util::pretty::pretty_format_batches(&table).unwrap().to_string();
        let expected = "\
+------------------+----------------+------+-------------+------------+------+
| rerun_segment_id | application_id | rows | frame_first | frame_last | held |
+------------------+----------------+------+-------------+------------+------+
| r1               | app            | 5    | 0           | 4          | true |
| r2               | other          | 1    | 42          | 42         | true |
+------------------+----------------+------+-------------+------------+------+";
        assert_eq!(text, expected);
        // Queries only: contexts are shared, so nothing may create, insert or set.
        for sql in [
            "CREATE TABLE t AS SELECT 1",
            "INSERT INTO recordings SELECT * FROM recordings",
            "SET datafusion.execution.batch_size = 1",
        ] {
            let refused = super::server::query(&server, sql, Some("s3cret")).await;
            assert!(refused.is_err(), "{sql} was run");
        }
        // Without the token, nothing is dropped; an unknown id is NOT_FOUND.
        let refused = drop_recording(&server, "r1", None).await.unwrap_err();
        assert_eq!(refused.code(), tonic::Code::Unauthenticated);
        let unknown = drop_recording(&server, "r9", Some("s3cret")).await.unwrap_err();
        assert_eq!(unknown.code(), tonic::Code::NotFound, "{unknown}");
        let said = drop_recording(&server, "r1", Some("s3cret")).await.unwrap();
        assert!(said.contains("dropped recording \"r1\""), "{said}");
        let ids = super::server::query(&server, "SELECT rerun_segment_id FROM recordings", Some("s3cret"))
            .await
            .unwrap();
        assert_eq!(ids.iter().map(arrow_array::RecordBatch::num_rows).sum::<usize>(), 1);
    });
    drop(server);
    // The log was rewritten without it: a restart does not bring it back.
    let again = Server::start(&dir, &args);
    rt.block_on(async {
        let table = super::server::query(
            &again,
            "SELECT rerun_segment_id, rows FROM recordings",
            Some("s3cret"),
        )
        .await
        .unwrap();
        let text = datafusion::arrow::util::pretty::pretty_format_batches(&table)
            .unwrap()
            .to_string();
        assert!(text.contains("| r2 ") && !text.contains("r1"), "{text}");
    });
    drop(again);
    std::fs::remove_dir_all(&dir).unwrap();
}
