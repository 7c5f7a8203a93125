#!/usr/bin/env bash
# Installs what mjsafe needs and is missing, on Debian 12 as root (idempotent, quiet when
# everything is there). `scripts/setup.sh` for running; `scripts/setup.sh --test` adds the
# Python readers the test suite uses as independent checks (in a venv, never system-wide).
set -euo pipefail
want_test=0
[ "${1:-}" = "--test" ] && want_test=1

need_apt=()
dpkg -s libmujoco-dev >/dev/null 2>&1 || need_apt+=(libmujoco-dev)
command -v protoc >/dev/null 2>&1 || need_apt+=(protobuf-compiler)
command -v cc >/dev/null 2>&1 || need_apt+=(build-essential)
command -v pkg-config >/dev/null 2>&1 || need_apt+=(pkg-config)
if [ "$want_test" = 1 ]; then
  [ -x /usr/bin/time ] || need_apt+=(time)   # GNU time: peak-memory checks in the tests
  command -v python3 >/dev/null 2>&1 || need_apt+=(python3)
  python3 -m venv --help >/dev/null 2>&1 || need_apt+=(python3-venv)
fi
if [ ${#need_apt[@]} -gt 0 ]; then
  echo "setup: installing Debian packages: ${need_apt[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq "${need_apt[@]}" >/dev/null
fi
# MuJoCo must be 2.2.2 (the bindings in src/mujoco/ffi.rs are generated from its headers).
grep -q '#define mjVERSION_HEADER 222' /usr/include/mujoco/mujoco.h || {
  echo "setup: /usr/include/mujoco/mujoco.h is not MuJoCo 2.2.2; install Debian 12's libmujoco-dev 2.2.2" >&2
  exit 1
}

if ! command -v cargo >/dev/null 2>&1; then
  if [ -x "$HOME/.cargo/bin/cargo" ]; then
    echo "setup: cargo is in ~/.cargo/bin: add it to PATH (source ~/.cargo/env)" >&2
  else
    echo "setup: no Rust toolchain. Install one with rustup (https://rustup.rs), Rust >= 1.89" >&2
  fi
  exit 1
fi

if [ "$want_test" = 1 ]; then
  venv="${MJSAFE_VENV:-$HOME/.cache/mjsafe/venv}"
  if [ ! -x "$venv/bin/python" ]; then
    echo "setup: creating Python venv for the test readers at $venv"
    python3 -m venv "$venv"
  fi
  if ! "$venv/bin/python" -c 'import mcap, mcap_protobuf' >/dev/null 2>&1 \
    || ! "$venv/bin/python" -m pip show rerun-sdk 2>/dev/null | grep -qx 'Version: 0.36.3' \
    || [ ! -x "$venv/bin/rerun" ]; then
    echo "setup: installing Python readers (mcap, mcap-protobuf-support) and the rerun CLI (rerun-sdk) into $venv"
    "$venv/bin/pip" install -q --disable-pip-version-check -r scripts/requirements-test.txt
  fi
  # No usage data from the rerun CLI the tests run (it would try the network).
  [ -f "${XDG_CONFIG_HOME:-$HOME/.config}/rerun/analytics.json" ] \
    || CI=1 "$venv/bin/rerun" analytics disable >/dev/null 2>&1 || true
fi
