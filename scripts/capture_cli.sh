#!/usr/bin/env bash
# Runs every `chunkstore` command over the robot recording, its chunk files and a dataset,
# and writes what each run gave (stdout, stderr, exit code, and every file it wrote, by
# content hash) under OUT. A refactor of the CLI that changes no behaviour leaves two
# captures identical:
#
#   scripts/capture_cli.sh /tmp/before-bin /tmp/capture-before
#   scripts/capture_cli.sh target/debug/chunkstore /tmp/capture-after
#   diff -r /tmp/capture-before /tmp/capture-after
#
# Runs in a scratch directory of fixed name, so that paths in messages are the same in
# both captures. Needs the `server` (or `cli` + `datafusion`) build.
set -uo pipefail
bin=$(realpath "$1")
out=$(realpath -m "$2")
data="${CHUNKSTORE_TESTDATA:-$(dirname "$0")/../../shared/testdata/rerun-0.41}"
data=$(realpath "$data")
work=/tmp/chunkstore-capture-work
rm -rf "$work" "$out"
mkdir -p "$work" "$out"
cd "$work" || exit 1

robot="$data/a_robot/a_robot.rrd"
chunks="$data/a_robot/chunks"
# A dataset of three segments, made by the binary under test's `convert` (its output is
# captured too, so a change there shows).
mkdir -p episodes
for id in episode_1 episode_2 episode_3; do
  "$bin" "$chunks" convert "episodes/$id.rrd" --application-id robot --recording-id "$id" \
    >/dev/null 2>&1
done
ln -s "$robot" robot.rrd
ln -s "$chunks" chunks

n=0
# run NAME ARGS...: the run's stdout, stderr and exit code, then every file or directory
# it created in the scratch directory (sha256 of each file, by path), which is removed.
run() {
  local name="$1"
  shift
  n=$((n + 1))
  local dir="$out/$(printf %03d "$n")-$name"
  mkdir -p "$dir"
  local before
  before=$(ls -A)
  printf '%q ' "$@" >"$dir/command"
  "$bin" "$@" >"$dir/stdout" 2>"$dir/stderr" <"${STDIN:-/dev/null}"
  echo $? >"$dir/exit"
  for made in $(comm -13 <(echo "$before") <(ls -A)); do
    # An `.rrd` by its chunks as `print --json` lists them and its dataframe, and a store
    # info by its size: a writer's message ids and compaction's chunk ids are new in every
    # run (and change how well LZ4 compresses a file).
    find "$made" -type f | sort | while read -r file; do
      case "$file" in
      *.rrd)
        echo "chunks $("$bin" "$file" print --json 2>&1 |
          sed 's/"chunk_id":"[^"]*",//' | sha256sum | cut -c1-16), dataframe $("$bin" \
          "$file" dataframe frame_id 2>&1 | sha256sum | cut -c1-16)  $file"
        ;;
      *store_info.pb) echo "$(stat -c %s "$file") bytes  $file" ;;
      *) sha256sum "$file" ;;
      esac
    done >>"$dir/files"
    rm -rf "$made"
  done
}

# Recordings: every command.
run stats robot.rrd stats
run stats-chunks chunks stats
run stats-compact --compact robot.rrd stats
run stats-max-rows --max-rows 7 robot.rrd stats
run print robot.rrd print
run print-json robot.rrd print --json
run latest-at robot.rrd latest-at frame_id 30
run latest-at-eager --eager robot.rrd latest-at frame_id 30
run latest-at-log-time robot.rrd latest-at log_time 2026-11-21T12:55:49Z
run latest-at-sim-time robot.rrd latest-at sim_time 1.5s
run latest-at-contents robot.rrd latest-at frame_id 30 --contents '/world/**'
run latest-at-component robot.rrd latest-at frame_id 30 --component Transform3D:translation
run range robot.rrd range sim_time 0s 1.5s
run range-frame chunks range frame_id 10 20
run convert robot.rrd convert out.rrd
run convert-compact --compact robot.rrd convert out.rrd
run convert-dir robot.rrd convert outdir
run convert-chunks chunks convert out.rrd --application-id app --recording-id rec
run dataframe robot.rrd dataframe frame_id
run dataframe-fill robot.rrd dataframe frame_id --fill-latest-at --out robot.parquet
run dataframe-arrow robot.rrd dataframe frame_id --out robot.arrow
run dataframe-values robot.rrd dataframe frame_id --index-values 1,5,9 --exact
run dataframe-range robot.rrd dataframe frame_id --range 10 20 --without-tombstones --without-empty-columns
run dataframe-contents robot.rrd dataframe sim_time --contents '/world/**' --contents '-/world/robot'
run sql robot.rrd sql 'SELECT count(*) FROM frame_id WHERE frame_id < 100'
run sql-json robot.rrd sql 'SELECT entity_path, count(*) AS n FROM chunks GROUP BY entity_path ORDER BY entity_path' --json
run sql-full robot.rrd sql 'SELECT * FROM frame_id ORDER BY frame_id LIMIT 3' --full
run sql-out robot.rrd sql "SELECT * FROM latest_at('frame_id', 42)" --out answer.parquet
run sql-out-arrow robot.rrd sql 'SELECT * FROM frame_id' --out answer.arrow
run sql-tables robot.rrd sql 'SELECT table_schema, table_name FROM information_schema.tables ORDER BY 1, 2'
run hive robot.rrd hive by_entity --index frame_id
run hive-bucket robot.rrd hive by_bucket --index frame_id --bucket 50

# Datasets.
run ds-stats episodes stats
run ds-dataframe episodes dataframe frame_id
run ds-dataframe-out episodes dataframe frame_id --out ds.parquet
run ds-sql episodes sql 'SELECT rerun_segment_id, count(*) FROM frame_id GROUP BY 1 ORDER BY 1'
run ds-sql-out episodes sql 'SELECT * FROM chunks' --out ds_chunks.arrow
run ds-hive episodes hive ds_hive --index frame_id --bucket 100
run ds-hive-entity episodes hive ds_hive_entity
run ds-segment --segment episode_2 episodes latest-at frame_id 30
run ds-segment-range --segment episode_3 episodes range frame_id 0 5
run ds-budget --memory-budget 1MiB episodes sql 'SELECT count(*) FROM frame_id'
run ds-index-cache --index-cache cache episodes stats

# Standard input, and a dataset with a file that is not a recording.
STDIN="$robot" run stdin-stats - stats
STDIN="$robot" run stdin-latest-at - latest-at frame_id 30
mkdir -p damaged
cp episodes/*.rrd damaged/
head -c 1000 episodes/episode_1.rrd >damaged/torn.rrd
run ds-skip-bad --skip-bad damaged stats
run ds-skip-bad-segment --skip-bad --segment episode_2 damaged latest-at frame_id 3
run err-ds-damaged damaged stats

# Errors: each a line on stderr and exit 2.
run err-missing missing.rrd stats
run err-timeline robot.rrd latest-at no_such_timeline 3
run err-time robot.rrd latest-at sim_time yesterday
run err-overwrite robot.rrd convert robot.rrd
run err-overwrite-df robot.rrd dataframe frame_id --out robot.rrd
run err-overwrite-sql robot.rrd sql 'SELECT 1' --out robot.rrd
run err-overwrite-hive robot.rrd hive chunks --index frame_id
run err-overwrite-ds episodes dataframe frame_id --out episodes/episode_1.rrd
run err-ds-no-segment episodes latest-at frame_id 30
run err-ds-unknown-segment --segment nope episodes latest-at frame_id 30
run err-ds-print episodes print
run err-ds-convert episodes convert x.rrd
run err-sql robot.rrd sql 'SELECT nothing FROM nowhere'
run err-segment-recording --segment episode_1 robot.rrd stats
run err-budget-recording --memory-budget 1MiB robot.rrd stats
run err-ds-recording --recording x episodes stats
run err-ds-contents episodes dataframe frame_id --contents /nothing
run err-ds-range episodes dataframe frame_id --range 5 1
run err-bucket robot.rrd hive x --index frame_id --bucket 0
run err-args robot.rrd
run err-max-rows --max-rows -1 robot.rrd stats
run help --help
run help-serve serve --help
run help-sql robot.rrd sql --help
run version --version
rm -rf "$work"
echo "$n runs captured in $out"
