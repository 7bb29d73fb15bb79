//! The tool with URLs: sources and outputs in a bucket, credentials from the environment
//! (as the clouds' own tools read them) or `--storage-option`, one line for each error.

use std::path::Path;
use std::process::{Command, Output};

use chunkstore::storage::StorageOptions;

use super::{bucket, upload};
use crate::common;

/// The tool, with the test server's credentials in its environment.
fn chunkstore(endpoint: &str, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_chunkstore"))
        .args(args)
        .env("AWS_ENDPOINT_URL", endpoint)
        .env("AWS_ALLOW_HTTP", "true")
        .env("AWS_ACCESS_KEY_ID", "key")
        .env("AWS_SECRET_ACCESS_KEY", "secret")
        .env("AWS_REGION", "us-east-1")
        .output()
        .unwrap()
}

fn stdout(output: &Output) -> String {
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout.clone()).unwrap()
}

/// Reads the whole object `url` into memory.
fn download(url: &str, storage: &StorageOptions) -> Vec<u8> {
    use std::io::Read as _;
    let (mut input, _) = chunkstore::storage::open_stream(Path::new(url), storage).unwrap();
    let mut bytes = Vec::new();
    input.read_to_end(&mut bytes).unwrap();
    bytes
}

#[test]
fn every_output_goes_to_a_bucket_and_reads_back_as_the_local_one() {
    let Some((endpoint, storage, prefix, _turn)) = bucket("cli") else {
        return;
    };
    let robot = common::robot_recording().join("a_robot.rrd");
    let robot = robot.to_str().unwrap();
    let dir = common::ScratchDir::new("storage-cli");

    // convert: a local recording to an `.rrd` in the bucket, which reads back the same.
    let converted = format!("{prefix}converted.rrd");
    stdout(&chunkstore(&endpoint, &[robot, "convert", &converted]));
    let at = ["latest-at", "frame_id", "30"];
    assert_eq!(
        stdout(&chunkstore(
            &endpoint,
            &[&[converted.as_str()], &at[..]].concat()
        )),
        stdout(&chunkstore(&endpoint, &[&[robot], &at[..]].concat())),
    );
    // Refused: writing over the source.
    let refused = chunkstore(&endpoint, &[&converted, "convert", &converted]);
    assert_eq!(refused.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("would overwrite the source"));

    // dataframe --out: the same Parquet file as written locally.
    let local = dir.join("table.parquet");
    let remote = format!("{prefix}table.parquet");
    stdout(&chunkstore(
        &endpoint,
        &[
            robot,
            "dataframe",
            "frame_id",
            "--out",
            local.to_str().unwrap(),
        ],
    ));
    stdout(&chunkstore(
        &endpoint,
        &[&converted, "dataframe", "frame_id", "--out", &remote],
    ));
    assert_eq!(download(&remote, &storage), std::fs::read(&local).unwrap());

    // A dataset over a prefix: stats name the objects; --storage-option instead of the
    // environment gives the same.
    let episodes = dir.join("episodes");
    std::fs::create_dir(&episodes).unwrap();
    common::episodes(&episodes);
    let dataset = format!("{prefix}episodes/");
    for entry in std::fs::read_dir(&episodes).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_str().unwrap().to_owned();
        upload(&path, &format!("{dataset}{name}"), &storage);
    }
    let stats = stdout(&chunkstore(&endpoint, &[&dataset, "stats"]));
    assert!(
        stats.contains(&format!("\"path\":\"{dataset}first.rrd\"")),
        "{stats}"
    );
    let explicit = Command::new(env!("CARGO_BIN_EXE_chunkstore"))
        .args([&dataset, "stats", "--verbose"])
        .args(["--storage-option", &format!("aws_endpoint={endpoint}")])
        .args(["--storage-option", "aws_allow_http=true"])
        .args(["--storage-option", "aws_access_key_id=key"])
        .args(["--storage-option", "aws_secret_access_key=secret"])
        .args(["--storage-option", "aws_region=us-east-1"])
        .env_remove("AWS_ENDPOINT_URL")
        .output()
        .unwrap();
    assert_eq!(stdout(&explicit), stats);
    let said = String::from_utf8_lossy(&explicit.stderr);
    assert!(said.contains("object storage: 3 GET"), "{said}");
    assert!(said.contains("1 LIST"), "{said}");

    // EXPLAIN ANALYZE shows a dataset scan's requests: one coalesced GET per segment
    // with rows on `frame` (two of the three), and what they brought.
    #[cfg(feature = "datafusion")]
    {
        let plan = stdout(&chunkstore(
            &endpoint,
            &[
                &dataset,
                "sql",
                "EXPLAIN ANALYZE SELECT count(*) FROM frame",
            ],
        ));
        assert!(plan.contains("requests=2"), "{plan}");
        assert!(plan.contains("bytes_fetched="), "{plan}");
        assert!(!plan.contains("bytes_fetched=0"), "{plan}");
    }
}

#[test]
fn bad_urls_and_options_exit_2_with_one_line() {
    let Some((endpoint, _, prefix, _turn)) = bucket("cli-errors") else {
        return;
    };
    let missing = format!("{prefix}missing.rrd");
    for (args, expected) in [
        (
            vec![missing.as_str(), "stats"],
            format!("error: {missing}: no such object"),
        ),
        (
            vec![
                missing.as_str(),
                "stats",
                "--storage-option",
                "aws_endpoint_urll=x",
            ],
            "is not a storage option".to_owned(),
        ),
        (
            vec![missing.as_str(), "stats", "--storage-option", "novalue"],
            "\"novalue\" is not KEY=VALUE".to_owned(),
        ),
    ] {
        let output = chunkstore(&endpoint, &args);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.contains(&expected), "{args:?}: {stderr}");
    }
}

/// `hive --delta` to a bucket: a table, then an append of the same segments refused in
/// one line, a plain Hive copy to a bucket refused in one line (it could not appear at
/// once), and `-v` counting one conditional PUT per commit beside the files'.
#[test]
fn hive_delta_writes_a_table_to_a_bucket_and_refuses_a_segment_twice() {
    let Some((endpoint, _, prefix, _turn)) = bucket("cli-delta") else {
        return;
    };
    let scratch = common::ScratchDir::new("storage-cli-delta");
    let episodes = scratch.join("episodes");
    std::fs::create_dir(&episodes).unwrap();
    common::episodes(&episodes);
    let episodes = episodes.to_str().unwrap();
    let table = format!("{prefix}episodes/");
    let made = chunkstore(&endpoint, &["-v", episodes, "hive", &table, "--delta"]);
    let stderr = String::from_utf8_lossy(&made.stderr);
    assert!(made.status.success(), "{stderr}");
    assert!(stderr.contains("committed version 0 of"), "{stderr}");
    assert!(stderr.contains("of 3 segments"), "{stderr}");
    for (args, expected) in [
        (
            vec![episodes, "hive", table.as_str(), "--delta", "--append"],
            "is in the table already",
        ),
        (
            vec![episodes, "hive", table.as_str(), "--delta"],
            "already exists",
        ),
        (vec![episodes, "hive", table.as_str()], "--delta"),
    ] {
        let output = chunkstore(&endpoint, &args);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.contains(expected), "{args:?}: {stderr}");
    }
}

/// `print` streams an `.rrd` object (one GET), and an object named like an Arrow IPC file
/// (`.arrow`) is read as one: both say what the same local files say.
#[test]
fn print_and_ipc_files_read_objects_as_local_files() {
    let Some((endpoint, storage, prefix, _turn)) = bucket("cli-print") else {
        return;
    };
    let robot = common::robot_recording().join("a_robot.rrd");
    let robot_url = format!("{prefix}a_robot.rrd");
    upload(&robot, &robot_url, &storage);
    let robot = robot.to_str().unwrap();
    let printed = stdout(&chunkstore(&endpoint, &[robot, "print", "--json"]));
    assert!(printed.lines().count() > 10, "{printed}");
    let counted = chunkstore(&endpoint, &[&robot_url, "print", "--json", "--verbose"]);
    assert_eq!(stdout(&counted), printed);
    let said = String::from_utf8_lossy(&counted.stderr);
    assert!(said.contains("object storage: 1 GET"), "{said}");

    let chunk = common::robot_chunk_files()[3].clone();
    let chunk_url = format!("{prefix}chunk.arrow");
    upload(&chunk, &chunk_url, &storage);
    let chunk = chunk.to_str().unwrap();
    for args in [&["print", "--json"][..], &["stats"][..]] {
        assert_eq!(
            stdout(&chunkstore(
                &endpoint,
                &[&[chunk_url.as_str()], args].concat()
            )),
            stdout(&chunkstore(&endpoint, &[&[chunk], args].concat())),
            "{args:?}"
        );
    }
    // Not there: one line naming it.
    let missing = chunkstore(&endpoint, &[&format!("{prefix}missing.arrow"), "stats"]);
    assert_eq!(missing.status.code(), Some(2));
    let said = String::from_utf8_lossy(&missing.stderr);
    assert_eq!(said.lines().count(), 1, "{said}");
    assert!(said.contains("missing.arrow"), "{said}");
}

/// A prefix holding Arrow IPC chunk files and no `.rrd` is one recording's chunk
/// directory, as a local directory of them is; holding both kinds is refused as locally.
#[test]
fn a_prefix_of_chunk_files_is_a_chunk_directory() {
    let Some((endpoint, storage, prefix, _turn)) = bucket("cli-chunks") else {
        return;
    };
    let local = common::robot_recording().join("chunks");
    let chunks = format!("{prefix}chunks/");
    for file in common::robot_chunk_files() {
        let name = file.file_name().unwrap().to_str().unwrap().to_owned();
        upload(&file, &format!("{chunks}{name}"), &storage);
    }
    let local = local.to_str().unwrap();
    for args in [
        &["print", "--json"][..],
        &["latest-at", "frame_id", "30"][..],
        &["range", "frame_id", "10", "40"][..],
    ] {
        assert_eq!(
            stdout(&chunkstore(&endpoint, &[&[chunks.as_str()], args].concat())),
            stdout(&chunkstore(&endpoint, &[&[local], args].concat())),
            "{args:?}"
        );
    }
    // An `.rrd` beside them: both kinds, refused with one line.
    upload(
        &common::robot_recording().join("a_robot.rrd"),
        &format!("{chunks}a_robot.rrd"),
        &storage,
    );
    let both = chunkstore(&endpoint, &[&chunks, "stats"]);
    assert_eq!(both.status.code(), Some(2));
    let said = String::from_utf8_lossy(&both.stderr);
    assert_eq!(said.lines().count(), 1, "{said}");
    assert!(said.contains("holds both"), "{said}");
}

/// `serve` preloads a SOURCE named by URL: it listens once the object is loaded, and a
/// missing one stops it before it listens, with one line naming the object.
#[cfg(feature = "server")]
#[test]
fn serve_preloads_a_source_from_a_bucket() {
    use std::io::BufRead as _;
    use std::process::Stdio;

    let Some((endpoint, storage, prefix, _turn)) = bucket("cli-serve") else {
        return;
    };
    let robot_url = format!("{prefix}a_robot.rrd");
    upload(
        &common::robot_recording().join("a_robot.rrd"),
        &robot_url,
        &storage,
    );
    let serve = |source: &str| {
        let mut command = Command::new(env!("CARGO_BIN_EXE_chunkstore"));
        command
            .args([
                "serve",
                source,
                "--addr",
                "127.0.0.1:0",
                "--read-mode",
                "snapshot",
            ])
            .args(["--storage-option", &format!("aws_endpoint={endpoint}")])
            .args(["--storage-option", "aws_allow_http=true"])
            .env("AWS_ACCESS_KEY_ID", "key")
            .env("AWS_SECRET_ACCESS_KEY", "secret")
            .env("AWS_REGION", "us-east-1")
            .env_remove("AWS_ENDPOINT_URL");
        command
    };
    let mut server = serve(&robot_url)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    std::io::BufReader::new(server.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let _ = server.kill();
    let _ = server.wait();
    assert!(
        line.starts_with("listening on rerun+http://127.0.0.1:"),
        "{line:?}"
    );

    let missing = serve(&format!("{prefix}missing.rrd")).output().unwrap();
    assert_eq!(missing.status.code(), Some(2));
    let said = String::from_utf8_lossy(&missing.stderr);
    assert_eq!(said.lines().count(), 1, "{said}");
    assert!(
        said.contains("missing.rrd") && said.contains("no such object"),
        "{said}"
    );
}
