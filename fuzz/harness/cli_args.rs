//! The body of the `cli_args` fuzz target: arbitrary argument lists through the
//! `chunkstore` tool's argument parser (its own `args.rs`, compiled in here). Parsing
//! either fails with clap's error, which must render, or gives arguments whose store
//! configuration either validates or is refused; nothing may panic.

#[path = "../../src/bin/chunkstore/args.rs"]
#[allow(
    dead_code,
    reason = "the tool's own module: the fuzz target reads what it needs"
)]
mod args;

#[path = "../../src/bin/chunkstore/commands/serve/retention.rs"]
#[allow(
    dead_code,
    reason = "the tool's own module: the fuzz target reads what it needs"
)]
mod retention;
/// `chunkstore serve`'s own parser, as the tool arranges it: `args.rs` and `retention.rs`
/// side by side under a module (this one) that has `parse_bytes`.
#[path = "../../src/bin/chunkstore/commands/serve/args.rs"]
mod serve_args;
use args::parse_bytes;

/// Splits the bytes into arguments at NUL bytes (any bytes, not only UTF-8, as a shell
/// can pass them).
pub fn cli_args(bytes: &[u8]) {
    use std::os::unix::ffi::OsStrExt;
    let mut argv: Vec<std::ffi::OsString> = vec!["chunkstore".into()];
    argv.extend(
        bytes
            .split(|&b| b == 0)
            .map(|a| std::ffi::OsStr::from_bytes(a).to_owned()),
    );
    if argv.get(1).is_some_and(|a| a == "serve") {
        serve_args(&argv[2..]);
        return;
    }
    match args::parse(&argv) {
        Ok(cli) => {
            let _ = cli.load.config();
            // What the tool does with the times once the timeline's type is known.
            let times: Vec<&args::TimeArg> = match &cli.command {
                args::Command::LatestAt { time, .. } => vec![time],
                args::Command::Range { min, max, .. } => vec![min, max],
                args::Command::Dataframe(dataframe) => dataframe
                    .range
                    .iter()
                    .chain(&dataframe.index_values)
                    .flatten()
                    .collect(),
                _ => Vec::new(),
            };
            for time in times {
                for kind in [
                    chunkstore::TimeType::Sequence,
                    chunkstore::TimeType::DurationNs,
                    chunkstore::TimeType::TimestampNs,
                ] {
                    if let Err(error) = time.on(Some(kind)) {
                        assert!(!error.is_empty());
                    }
                }
            }
            if let args::Command::Dataframe(dataframe) = &cli.command {
                // What the tool does with the contents before loading anything.
                if let Err(error) = chunkstore::EntityPathFilter::parse(&dataframe.contents) {
                    assert!(!error.to_string().is_empty());
                }
            }
        }
        Err(error) => {
            let _ = error.render().to_string();
        }
    }
}

/// `chunkstore serve ARGS`: parsed as the tool does; the retention rules parsed are asked
/// for every kind of timeline, as the server does once a second.
fn serve_args(rest: &[std::ffi::OsString]) {
    use clap::Parser as _;
    let mut argv = vec![std::ffi::OsString::from("chunkstore serve")];
    argv.extend(rest.iter().cloned());
    match serve_args::ServeArgs::try_parse_from(&argv) {
        Ok(parsed) => {
            for timeline in [
                chunkstore::Timeline::sequence("frame"),
                chunkstore::Timeline::new("log_time", chunkstore::TimeType::TimestampNs),
                chunkstore::Timeline::new("t", chunkstore::TimeType::DurationNs),
            ] {
                let _ = retention::span_of(&parsed.retention, &timeline);
            }
        }
        Err(error) => {
            let _ = error.render().to_string();
        }
    }
}
