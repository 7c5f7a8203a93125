#!/usr/bin/env bash
# Installs what mjsafe needs and is missing, on Debian 12 as root (idempotent, quiet when
# everything is there). `scripts/setup.sh` for running; `scripts/setup.sh --test` adds the
# Python readers the test suite uses as independent checks (in a venv, never system-wide), the
# mjsafe Python package (python/, built by maturin, installed into that venv) and the
# single-node Slurm of tests/cluster.rs (Debian's slurm-wlm and munge; nothing started here).
set -euo pipefail
cd "$(dirname "$0")/.."
want_test=0
[ "${1:-}" = "--test" ] && want_test=1

need_apt=()
dpkg -s libmujoco-dev >/dev/null 2>&1 || need_apt+=(libmujoco-dev)
command -v protoc >/dev/null 2>&1 || need_apt+=(protobuf-compiler)
# C and C++ compilers: build.rs compiles src/mujoco/load_xml.cpp (mj_loadXML behind a C++ try/catch).
{ command -v cc >/dev/null 2>&1 && command -v c++ >/dev/null 2>&1; } || need_apt+=(build-essential)
command -v pkg-config >/dev/null 2>&1 || need_apt+=(pkg-config)
if [ "$want_test" = 1 ]; then
  [ -x /usr/bin/time ] || need_apt+=(time)   # GNU time: peak-memory checks in the tests
  command -v python3 >/dev/null 2>&1 || need_apt+=(python3)
  # Debian's python3 has the venv module but not ensurepip (that is python3-venv), and
  # `python3 -m venv` fails without it: test what venv needs, not `venv --help`.
  python3 -c 'import ensurepip' >/dev/null 2>&1 || need_apt+=(python3-venv)
  # tests/cluster.rs: a private single-node Slurm (scripts/slurm-up.sh starts it per test).
  { [ -x /usr/sbin/slurmctld ] && [ -x /usr/sbin/slurmd ] && command -v sbatch >/dev/null 2>&1; } \
    || need_apt+=(slurm-wlm)
  [ -x /usr/sbin/munged ] || need_apt+=(munge)
  command -v groff >/dev/null 2>&1 || need_apt+=(groff-base)   # tests/cli.rs renders the man page
  # tests/scorecard.rs opens report.html in a real headless browser (Playwright drives it).
  [ -x /usr/bin/chromium ] || need_apt+=(chromium)
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

# The oldest Rust that builds mjsafe: Cargo.toml's rust-version (1.95 for the rerun crate of the
# default features; README "Rust").
need_rust=$(sed -n 's/^rust-version = "\(.*\)"/\1/p' Cargo.toml)
if ! command -v cargo >/dev/null 2>&1; then
  if [ -x "$HOME/.cargo/bin/cargo" ]; then
    echo "setup: cargo is in ~/.cargo/bin: add it to PATH (source ~/.cargo/env)" >&2
  else
    echo "setup: no Rust toolchain. Install one with rustup (https://rustup.rs), Rust >= $need_rust" >&2
  fi
  exit 1
fi
have_rust=$(rustc --version | awk '{print $2}')
if [ "$(printf '%s\n%s\n' "$need_rust" "${have_rust%%-*}" | sort -V | head -n 1)" != "$need_rust" ]; then
  echo "setup: rustc $have_rust is older than $need_rust, the oldest Rust that builds mjsafe" \
    "(rust-version in Cargo.toml: the rerun crate 0.36.3 needs it; without the rerun feature," \
    "cargo build --no-default-features, 1.89 is enough). Update: rustup update stable" >&2
  exit 1
fi

if [ "$want_test" = 1 ]; then
  venv="${MJSAFE_VENV:-$HOME/.cache/mjsafe/venv}"
  if [ ! -x "$venv/bin/python" ]; then
    echo "setup: creating Python venv for the test readers at $venv"
    python3 -m venv "$venv"
  fi
  if ! "$venv/bin/python" -c 'import mcap, mcap_protobuf, yaml, pandas, pytest, cvxpy, gymnasium, rtamt, playwright' >/dev/null 2>&1 \
    || [ ! -x "$venv/bin/maturin" ] \
    || [ "$("$venv/bin/python" -m pip show rerun-sdk 2>/dev/null | sed -n 's/^Version: //p')" != 0.36.3 ] \
    || [ ! -x "$venv/bin/rerun" ]; then
    echo "setup: installing Python readers (mcap, mcap-protobuf-support, PyYAML, pandas), the rerun CLI (rerun-sdk), maturin, pytest, cvxpy, rtamt and playwright into $venv"
    "$venv/bin/pip" install -q --disable-pip-version-check -r scripts/requirements-test.txt
  fi
  # No usage data from the rerun CLI the tests run (it would try the network).
  [ -f "${XDG_CONFIG_HOME:-$HOME/.config}/rerun/analytics.json" ] \
    || CI=1 "$venv/bin/rerun" analytics disable >/dev/null 2>&1 || true
  # CommonRoad's own reader (PyPI commonroad-io), the independent check tests/commonroad_check.py
  # runs on CommonRoad scenarios and our logs of them. It pins protobuf 3.20.2, which the readers
  # above cannot share, so it gets a venv of its own, with the same mcap as
  # scripts/requirements-test.txt.
  cr_venv="${MJSAFE_CR_VENV:-$HOME/.cache/mjsafe/cr-venv}"
  cr_io=2026.1
  # (Its vehicle parameter sets: tests/commonroad.rs checks the ego against vehicle 2.)
  cr_vm=3.0.2
  mcap_pin=$(grep -m 1 '^mcap==' scripts/requirements-test.txt)
  if [ ! -x "$cr_venv/bin/python" ]; then
    echo "setup: creating Python venv for the CommonRoad reader at $cr_venv"
    python3 -m venv "$cr_venv"
  fi
  if ! "$cr_venv/bin/python" -c 'import sys, importlib.metadata as md, commonroad, mcap, vehiclemodels
sys.exit(md.version("commonroad-io") != sys.argv[1] or "mcap==" + md.version("mcap") != sys.argv[2]
         or md.version("commonroad-vehicle-models") != sys.argv[3])' \
    "$cr_io" "$mcap_pin" "$cr_vm" >/dev/null 2>&1; then
    echo "setup: installing the CommonRoad reader (commonroad-io $cr_io, commonroad-vehicle-models $cr_vm) and $mcap_pin into $cr_venv"
    "$cr_venv/bin/pip" install -q --disable-pip-version-check "commonroad-io==$cr_io" \
      "commonroad-vehicle-models==$cr_vm" "$mcap_pin"
  fi
  # CommonRoad's route planner (PyPI commonroad-route-planner), which tests/route_check.py asks
  # for the route of each committed file's planning problem. Its newest release needs a
  # commonroad-io before 2026 (it imports commonroad.geometry.shape), so it gets a venv of its own.
  cr_route_venv="${MJSAFE_CR_ROUTE_VENV:-$HOME/.cache/mjsafe/cr-route-venv}"
  cr_route_io=2024.3
  cr_rp=2025.1.0
  if [ ! -x "$cr_route_venv/bin/python" ]; then
    echo "setup: creating Python venv for the CommonRoad route planner at $cr_route_venv"
    python3 -m venv "$cr_route_venv"
  fi
  if ! "$cr_route_venv/bin/python" -c 'import sys, importlib.metadata as md, commonroad_route_planner.route_planner
sys.exit(md.version("commonroad-io") != sys.argv[1] or md.version("commonroad-route-planner") != sys.argv[2])' \
    "$cr_route_io" "$cr_rp" >/dev/null 2>&1; then
    echo "setup: installing the CommonRoad route planner (commonroad-route-planner $cr_rp, commonroad-io $cr_route_io) into $cr_route_venv"
    "$cr_route_venv/bin/pip" install -q --disable-pip-version-check --prefer-binary \
      "commonroad-io==$cr_route_io" "commonroad-route-planner==$cr_rp"
  fi
  # The mjsafe Python package (python/): built by maturin with the tests' profile (dev, which
  # shares their compiled dependencies; headless, without the rerun SDK), installed into the
  # venv when its wheel changed. A rebuild with nothing changed takes seconds.
  wheels=$(mktemp -d)
  trap 'rm -rf "$wheels"' EXIT
  if ! "$venv/bin/maturin" build --profile dev -m python/Cargo.toml --interpreter "$venv/bin/python" \
    --out "$wheels" >"$wheels/build.log" 2>&1; then
    cat "$wheels/build.log" >&2
    echo "setup: building the mjsafe Python package (python/) failed" >&2
    exit 1
  fi
  wheel=$(ls "$wheels"/mjsafe-*.whl)
  # The wheel's contents, without what changes from build to build (its SBOM's serial number
  # and the RECORD listing it).
  digest=$("$venv/bin/python" -c 'import hashlib, sys, zipfile
z = zipfile.ZipFile(sys.argv[1]); h = hashlib.sha256()
for n in sorted(z.namelist()):
    if "/sboms/" not in n and not n.endswith("/RECORD"): h.update(n.encode() + b"\0" + z.read(n))
print(h.hexdigest())' "$wheel")
  if [ "$(cat "$venv/.mjsafe-wheel" 2>/dev/null)" != "$digest" ] || ! "$venv/bin/python" -c 'import mjsafe' >/dev/null 2>&1; then
    echo "setup: installing the mjsafe Python package into $venv"
    "$venv/bin/pip" install -q --disable-pip-version-check --force-reinstall --no-deps "$wheel"
    echo "$digest" >"$venv/.mjsafe-wheel"
  fi
fi
