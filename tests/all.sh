#!/usr/bin/env bash
# The test suite, as README's second command and as CI runs it: installs
# what the tests need that a machine with only Rust lacks (a C compiler and
# make for the bundled cfitsio; Debian's chromium and chromium-driver for
# the browser test; slurm-wlm and munge for the one-node Slurm run), then
# runs `cargo test --workspace` and the real Slurm run (tests/slurm/run.sh).
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
if [ "$root" = 1 ] && { ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; }; then
  want+=(slurm-wlm munge)
fi
apt_pid=""
apt_log=$(mktemp)
trap '[ -n "$apt_pid" ] && kill "$apt_pid" 2>/dev/null; rm -f "$apt_log"' EXIT
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
echo "== a real one-node Slurm (tests/slurm/run.sh, docs/cluster.md)"
if [ "$root" = 1 ]; then
  # `cargo test --workspace` has just built target/debug/stepsim for the
  # integration tests; a separate `cargo build` would build the workspace
  # again with other dependency features (about 3 min).
  tests/slurm/run.sh
else
  echo "tests/all.sh: SKIPPED the Slurm run: it starts munged, slurmctld and slurmd as root"
fi
