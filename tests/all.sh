#!/usr/bin/env bash
# The test suite, as README's second command and as CI runs it: installs
# what the tests need that a machine with only Rust lacks (a C compiler and
# make for the bundled cfitsio; Debian's chromium and chromium-driver for
# the browser test; postgresql for the store's second backend; slurm-wlm
# and munge for the one-node Slurm run), then runs `cargo test --workspace`
# (the server on SQLite), the server's tests and the real binary's restart
# tests again on a PostgreSQL server started here (initdb + pg_ctl in a
# temporary directory, on a free port, stopped on exit;
# STEPSIM_TEST_POSTGRES names it), and the real Slurm run
# (tests/slurm/run.sh).
# The Debian packages are installed in the background while the tests
# compile and waited for before the first test runs; the install's log is
# shown if it fails. Installing needs root (or sudo) and apt-get: without
# them the script names the packages to install and exits 1. Not as root,
# the Slurm run (which starts daemons as root) is skipped with a line that
# says so, and nothing is installed for it; STEPSIM_SKIP_BROWSER=1 skips
# the browser test (and the chromium install) where a browser cannot be had.
# Usage: bash tests/all.sh [extra arguments for cargo test]
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TERM_COLOR="${CARGO_TERM_COLOR:-never}"

as_root() {
  if [ "$(id -u)" = 0 ]; then
    "$@"
  elif command -v sudo >/dev/null; then
    sudo "$@"
  else
    return 1
  fi
}
need_install() {
  if ! command -v apt-get >/dev/null || { [ "$(id -u)" != 0 ] && ! command -v sudo >/dev/null; }; then
    echo "tests/all.sh: the tests need the Debian packages: $*"
    echo "tests/all.sh: install them (apt-get needs root), then run this again"
    exit 1
  fi
}

# The bundled cfitsio (fitsio-src) needs a C compiler and make, before
# anything compiles.
if ! command -v cc >/dev/null || ! command -v make >/dev/null; then
  need_install gcc make
  as_root apt-get update -qq
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq gcc make
fi

root=0
[ "$(id -u)" = 0 ] && root=1
want=()
if [ "${STEPSIM_SKIP_BROWSER:-0}" != 1 ] &&
  { ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; }; then
  want+=(chromium chromium-driver)
fi
pg_bin() { ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -n 1; }
if [ -z "$(pg_bin)" ]; then
  want+=(postgresql)
fi
if [ "$root" = 1 ] && { ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; }; then
  want+=(slurm-wlm munge)
fi
apt_pid=""
apt_log=$(mktemp)
pg_dir=""
stop_pg() {
  if [ -n "$pg_dir" ]; then
    as_pg "$(pg_bin)/pg_ctl" -D "$pg_dir/data" -m fast stop >/dev/null 2>&1 || true
    rm -rf "$pg_dir"
  fi
}
# initdb refuses root: as root the cluster is the postgres user's.
as_pg() {
  if [ "$root" = 1 ]; then runuser -u postgres -- "$@"; else "$@"; fi
}
trap '[ -n "$apt_pid" ] && kill "$apt_pid" 2>/dev/null; rm -f "$apt_log"; stop_pg' EXIT
if [ ${#want[@]} -gt 0 ]; then
  need_install "${want[@]}"
  ( as_root apt-get update -qq &&
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${want[@]}" ) >"$apt_log" 2>&1 &
  apt_pid=$!
  echo "== installing ${want[*]} in the background"
fi

echo "== building the tests"
cargo test --workspace --no-run -q
if [ -n "$apt_pid" ]; then
  if ! wait "$apt_pid"; then
    cat "$apt_log"
    echo "tests/all.sh: apt-get install ${want[*]} failed"
    exit 1
  fi
  apt_pid=""
  echo "== installed ${want[*]}"
fi
echo "== cargo test --workspace"
cargo test --workspace "$@"
echo "== the server's tests again, on PostgreSQL"
pg_dir=$(mktemp -d /tmp/stepsim-pg.XXXXXX)
chmod 755 "$pg_dir"
[ "$root" = 1 ] && chown postgres "$pg_dir"
pg_port=""
for _ in $(seq 50); do
  p=$((20000 + RANDOM % 40000))
  if ! (echo >"/dev/tcp/127.0.0.1/$p") 2>/dev/null; then pg_port=$p; break; fi
done
[ -n "$pg_port" ] || { echo "tests/all.sh: no free port for PostgreSQL"; exit 1; }
as_pg "$(pg_bin)/initdb" -D "$pg_dir/data" -A trust -U postgres >"$pg_dir/initdb.log" 2>&1 ||
  { cat "$pg_dir/initdb.log"; echo "tests/all.sh: initdb failed"; exit 1; }
as_pg "$(pg_bin)/pg_ctl" -D "$pg_dir/data" -l "$pg_dir/log" -w \
  -o "-p $pg_port -k $pg_dir -c listen_addresses=127.0.0.1 -c max_connections=300 -c fsync=off" start >/dev/null ||
  { cat "$pg_dir/log"; echo "tests/all.sh: PostgreSQL did not start"; exit 1; }
# The modules of the test binaries that use the store: the server's (all
# but module_graph, which reads only the sources) and the root's restart
# tests (the real `serve`). `--workspace` as above, so that nothing is
# built again with other dependency features; the filters select no test
# of the harness's or sim's binary.
STEPSIM_TEST_POSTGRES="postgres://postgres@127.0.0.1:$pg_port/postgres" \
  cargo test --workspace --test integration "$@" -- \
  api:: pages:: hardening:: prober:: browser:: binary_restart::
stop_pg
pg_dir=""
echo "== a real one-node Slurm (tests/slurm/run.sh, docs/cluster.md)"
if [ "$root" = 1 ]; then
  # `cargo test --workspace` has just built target/debug/stepsim for the
  # integration tests; a separate `cargo build` would build the workspace
  # again with other dependency features (about 3 min).
  tests/slurm/run.sh
else
  echo "tests/all.sh: SKIPPED the Slurm run: it starts munged, slurmctld and slurmd as root"
fi
