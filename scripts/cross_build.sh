#!/usr/bin/env bash
# Builds pinc's binaries for a Raspberry Pi (and the host) on a Debian 12 (bookworm) amd64
# machine, without rustup targets: Debian's rustc-web / cargo-web from bookworm-security,
# its ARM standard libraries taken from the archive's pool, Debian's cross gcc as linker.
#
# Writes, for each platform (linux-amd64, linux-arm-v7, linux-arm64):
#   dist/<platform>/pinc, mpc_track      the command lines, with the live link (feature `vehicle`)
#   dist/<platform>/libpinc_c.a, .so     the C ABI (workspace member `capi`), and pinc.h
#   dist/<platform>/runtime_json         examples/runtime_json.rs, for python/tests/test_cross_platform.py
# and dist/models/mpc_pinc_thrust.pinc, the model mpc_track flies by default, and
# dist/models/bluerov2.toml, the vehicle file `pinc serve` starts from in the image.
# blueos/Dockerfile copies from there; it compiles nothing.
#
# Usage: scripts/cross_build.sh [--platforms linux-arm-v7,linux-arm64,linux-amd64]
#                               [--skip-install] [--list-outputs]
# Environment: CARGO_TARGET_DIR (default target/), CARGO_BUILD_JOBS (cargo's own),
#              PINC_DIST (default dist/).
# Idempotent: installed packages and standard libraries are skipped, cargo rebuilds only
# what changed. Runs as root or through sudo for apt and the standard libraries.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
DIST="${PINC_DIST:-$ROOT/dist}"
TARGET_DIR="${CARGO_TARGET_DIR:-$ROOT/target}"
ALL_PLATFORMS=(linux-amd64 linux-arm-v7 linux-arm64)
# nalgebra 0.35 needs rustc >= 1.89: bookworm main's rustc-web (1.85) is too old.
MIN_RUSTC=1.89
RUSTC_BIN=/usr/bin/rustc
CARGO_BIN=/usr/bin/cargo

log() { echo "[cross_build] $*" >&2; }
die() { log "error: $*"; exit 1; }
# Prints a command, then runs it.
run() { log "\$ $*"; "$@"; }
as_root() { if [ "$(id -u)" -eq 0 ]; then run "$@"; else run sudo "$@"; fi; }

# What a platform is to Rust, Debian and the cross tools.
triple_of() {
  case "$1" in
    linux-amd64) echo x86_64-unknown-linux-gnu ;;
    linux-arm-v7) echo armv7-unknown-linux-gnueabihf ;;
    linux-arm64) echo aarch64-unknown-linux-gnu ;;
    *) die "unknown platform '$1' (known: ${ALL_PLATFORMS[*]})" ;;
  esac
}
debarch_of() {
  case "$1" in linux-amd64) echo amd64 ;; linux-arm-v7) echo armhf ;; linux-arm64) echo arm64 ;; esac
}
# The GNU tool prefix (gcc, strip) and the qemu user emulator with its library root.
gnu_of() {
  case "$1" in
    linux-amd64) echo x86_64-linux-gnu ;;
    linux-arm-v7) echo arm-linux-gnueabihf ;;
    linux-arm64) echo aarch64-linux-gnu ;;
  esac
}
qemu_of() {
  case "$1" in linux-amd64) echo "" ;; linux-arm-v7) echo qemu-arm-static ;; linux-arm64) echo qemu-aarch64-static ;; esac
}

# The files the script writes, relative to the repository root (what the Dockerfile test
# checks its COPY lines against). Also the list the copy step below works through.
BINARIES=(pinc mpc_track)
EXAMPLES=(runtime_json)
LIBRARIES=(libpinc_c.a libpinc_c.so)
MODEL=models/mpc_pinc_thrust.pinc
# The BlueROV2's vehicle file (its thrusters): what `pinc serve` excites and fits from until the
# owner puts their own in the data folder.
VEHICLE=models/bluerov2.toml
list_outputs() {
  local dist_rel="${DIST#"$ROOT"/}" p f
  for p in "${ALL_PLATFORMS[@]}"; do
    for f in "${BINARIES[@]}" "${EXAMPLES[@]}" "${LIBRARIES[@]}" pinc.h; do echo "$dist_rel/$p/$f"; done
  done
  echo "$dist_rel/$MODEL"
  echo "$dist_rel/$VEHICLE"
}

platforms=("${ALL_PLATFORMS[@]}")
install=1
while [ $# -gt 0 ]; do
  case "$1" in
    --platforms) [ $# -ge 2 ] || die "--platforms needs a value"; IFS=, read -r -a platforms <<<"$2"; shift 2 ;;
    --skip-install) install=0; shift ;;
    --list-outputs) list_outputs; exit 0 ;;
    -h | --help) sed -n '2,18p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
done
for p in "${platforms[@]}"; do triple_of "$p" >/dev/null; done
[ "$(dpkg --print-architecture 2>/dev/null)" = amd64 ] || die "runs on a Debian 12 amd64 host (dpkg says '$(dpkg --print-architecture 2>/dev/null || echo none)')"

installed() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q 'install ok installed'; }
installed_version() { dpkg-query -W -f='${Version}' "$1" 2>/dev/null; }
candidate_version() { apt-cache policy "$1" 2>/dev/null | awk '/Candidate:/ {print $2; exit}'; }
new_enough() { [ -n "$1" ] && [ "$1" != "(none)" ] && dpkg --compare-versions "$1" ge "$MIN_RUSTC"; }

# 1. Packages: Debian's compiler pair, the cross gcc (linker and C compiler for the bundled
#    SQLite and zstd) with their C libraries, qemu to run what was built.
install_packages() {
  local want=(rustc-web cargo-web gcc-arm-linux-gnueabihf gcc-aarch64-linux-gnu libc6-dev-armhf-cross
    libc6-dev-arm64-cross qemu-user-static curl ca-certificates xz-utils)
  local need=() p
  for p in "${want[@]}"; do installed "$p" || need+=("$p"); done
  if installed rustc-web && ! new_enough "$(installed_version rustc-web)"; then need+=(rustc-web cargo-web); fi
  if [ ${#need[@]} -eq 0 ]; then
    log "packages: all installed (rustc-web $(installed_version rustc-web))"
    return
  fi
  log "packages to install: ${need[*]}"
  as_root apt-get update
  local cand rest=()
  cand="$(candidate_version rustc-web)"
  new_enough "$cand" || die "apt offers rustc-web '$cand', older than $MIN_RUSTC: add bookworm-security to the apt sources"
  # The compiler pair by version (both or neither), the rest as apt offers them.
  for p in "${need[@]}"; do case "$p" in rustc-web | cargo-web) ;; *) rest+=("$p") ;; esac; done
  if [ ${#rest[@]} -lt ${#need[@]} ]; then rest+=("rustc-web=$cand" "cargo-web=$cand"); fi
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${rest[@]}"
}

# 2. The target's standard library: libstd-rust-web-dev of exactly the compiler's version,
#    for armhf / arm64. apt cannot always get it (a foreign architecture's index on the
#    security mirror is sometimes out of step with its signed InRelease), so the .deb is
#    fetched from the pool by the amd64 package's file name with the architecture swapped,
#    checked against the index when the index checks out, and unpacked into the sysroot.
index_sha256() { # <mirror> <suite> <component> <debarch> <pool file name> <cache dir> -> "<sha256> <trust>"
  local mirror="$1" suite="$2" comp="$3" arch="$4" file="$5" cache="$6"
  local lists=/var/lib/apt/lists inrelease expected idx="$cache/Packages-$suite-$comp-$arch.xz" got trust
  inrelease="$lists/$(echo "$mirror/dists/$suite/" | sed -e 's|^[a-z+]*://||' -e 's|/|_|g')InRelease"
  expected=""
  if [ -f "$inrelease" ]; then
    # apt checked the InRelease's signature when it wrote it.
    expected="$(awk -v f="$comp/binary-$arch/Packages.xz" '/^SHA256:/ {s = 1; next} /^[^ ]/ {s = 0} s && $3 == f {print $1; exit}' "$inrelease")"
  fi
  rm -f "$idx"
  if [ -n "$expected" ] && curl -fsSL --retry 3 -o "$idx" "$mirror/dists/$suite/$comp/binary-$arch/by-hash/SHA256/$expected" 2>/dev/null; then
    :
  else
    curl -fsSL --retry 3 -o "$idx" "$mirror/dists/$suite/$comp/binary-$arch/Packages.xz" || { echo "- none"; return; }
  fi
  got="$(sha256sum "$idx" | cut -d' ' -f1)"
  if [ -n "$expected" ] && [ "$got" = "$expected" ]; then trust=signed; else trust=unsigned-index; fi
  xz -dc "$idx" | awk -v f="$file" '/^Filename:/ {hit = ($2 == f)} hit && /^SHA256:/ {print $2; exit}' | sed "s/\$/ $trust/"
}

install_std() {
  local platform="$1" triple arch version sysroot dest stamp
  triple="$(triple_of "$platform")"
  arch="$(debarch_of "$platform")"
  version="$(installed_version rustc-web)"
  sysroot="$("$RUSTC_BIN" --print sysroot)"
  dest="$sysroot/lib/rustlib/$triple"
  stamp="$dest/pinc-cross-build.version"
  if [ "$arch" = amd64 ]; then
    # The host's comes with rustc-web (libstd-rust-web-dev).
    compgen -G "$dest/lib/libstd-*.rlib" >/dev/null || die "no standard library for the host in $dest: is libstd-rust-web-dev installed?"
    log "std for $triple: the compiler's own ($version)"
    return
  fi
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$version" ] && compgen -G "$dest/lib/libstd-*.rlib" >/dev/null; then
    log "std for $triple: installed ($version)"
    return
  fi
  local policy mirror="" suite_comp="" suite comp file cache deb sums want trust tmp
  # Where apt got this version from: the line after the version in `apt-cache policy`.
  policy="$(apt-cache policy libstd-rust-web-dev)"
  read -r mirror suite_comp < <(echo "$policy" | awk -v v="$version" '($1 == v || ($1 == "***" && $2 == v)) {getline; print $2, $3; exit}') || true
  [ -n "${mirror:-}" ] || die "apt knows no source for libstd-rust-web-dev $version"
  suite="${suite_comp%%/*}"
  comp="${suite_comp#*/}"
  file="$(apt-cache show "libstd-rust-web-dev=$version" | awk '/^Filename:/ {print $2; exit}')"
  file="${file%_*.deb}_$arch.deb"
  cache="${XDG_CACHE_HOME:-$HOME/.cache}/pinc-cross-build"
  mkdir -p "$cache"
  deb="$cache/$(basename "$file")"
  if [ ! -s "$deb" ]; then
    run curl -fsSL --retry 3 -o "$deb.part" "$mirror/$file"
    mv "$deb.part" "$deb"
  fi
  want="" trust=""
  read -r want trust < <(index_sha256 "$mirror" "$suite" "$comp" "$arch" "$file" "$cache") || true
  sums="$(sha256sum "$deb" | cut -d' ' -f1)"
  case "$trust" in
    signed) [ "$sums" = "$want" ] || { rm -f "$deb"; die "$deb: SHA-256 $sums, the signed index says $want"; }
      log "$(basename "$deb"): SHA-256 matches the index signed by the archive" ;;
    unsigned-index) [ "$sums" = "$want" ] || { rm -f "$deb"; die "$deb: SHA-256 $sums, the index says $want"; }
      log "warning: the $arch index does not match its signed InRelease (mirror sync?): $(basename "$deb") checked against the unsigned index only" ;;
    *) log "warning: no $arch index found: $(basename "$deb") unchecked (SHA-256 $sums)" ;;
  esac
  tmp="$(mktemp -d)"
  run dpkg-deb -x "$deb" "$tmp"
  [ -d "$tmp/usr/lib/rustlib/$triple/lib" ] || die "$(basename "$deb") holds no usr/lib/rustlib/$triple/lib"
  as_root rm -rf "$dest"
  as_root cp -a "$tmp/usr/lib/rustlib/$triple" "$dest"
  echo "$version" | as_root tee "$stamp" >/dev/null
  rm -rf "$tmp"
  log "std for $triple: $version unpacked into $dest"
}

# 3. The builds: the command lines with the live link, then the C ABI alone (a separate
#    cargo call, so the library gets the embeddable core's features only).
declare -A SECONDS_OF
build() {
  local platform="$1" triple gnu upper lower t0 out rel
  triple="$(triple_of "$platform")"
  gnu="$(gnu_of "$platform")"
  upper="$(echo "$triple" | tr 'a-z-' 'A-Z_')"
  lower="${triple//-/_}"
  local envs=(RUSTC="$RUSTC_BIN" RUSTDOC=/usr/bin/rustdoc CARGO_TARGET_DIR="$TARGET_DIR"
    "CARGO_TARGET_${upper}_LINKER=$gnu-gcc" "CC_$lower=$gnu-gcc" "AR_$lower=$gnu-ar")
  t0=$(date +%s.%N)
  (cd "$ROOT" && run env "${envs[@]}" "$CARGO_BIN" build --locked --release --target "$triple" \
    -p pinc --features vehicle --bin pinc --bin mpc_track --example runtime_json)
  (cd "$ROOT" && run env "${envs[@]}" "$CARGO_BIN" build --locked --release --target "$triple" -p pinc-capi)
  SECONDS_OF[$platform]=$(awk -v a="$(date +%s.%N)" -v b="$t0" 'BEGIN {print a - b}')
  out="$DIST/$platform"
  rel="$TARGET_DIR/$triple/release"
  mkdir -p "$out"
  local f
  # Debug line tables stripped (the release profile keeps them); symbols stay for backtraces.
  for f in "${BINARIES[@]}" libpinc_c.so; do
    run "$gnu-strip" --strip-debug -o "$out/$f" "$rel/$f"
  done
  for f in "${EXAMPLES[@]}"; do
    run "$gnu-strip" --strip-debug -o "$out/$f" "$rel/examples/$f"
  done
  run install -m 644 "$rel/libpinc_c.a" "$out/libpinc_c.a"
  run install -m 644 "$ROOT/include/pinc.h" "$out/pinc.h"
  log "$platform: built in $(printf '%.0f' "${SECONDS_OF[$platform]}") s into $out"
}

# 4. A look at what came out: the machine, the newest glibc symbol it needs (the image's
#    base must have it), and that it starts under qemu.
check() {
  local platform="$1" gnu qemu f glibc
  gnu="$(gnu_of "$platform")"
  qemu="$(qemu_of "$platform")"
  for f in "${BINARIES[@]}"; do
    f="$DIST/$platform/$f"
    glibc="$("$gnu-objdump" -T "$f" | grep -o 'GLIBC_[0-9.]*' | sort -V | tail -1)"
    log "$platform: $(basename "$f") $(du -h "$f" | cut -f1), $("$gnu-readelf" -h "$f" | awk -F: '/Machine/ {gsub(/^ +/, "", $2); print $2}'), needs $glibc"
    if [ -n "$qemu" ]; then
      run "$qemu" -L "/usr/$gnu" "$f" --help >/dev/null
    else
      run "$f" --help >/dev/null
    fi
  done
}

log "platforms: ${platforms[*]}; target dir $TARGET_DIR; output $DIST"
if [ "$install" -eq 1 ]; then install_packages; fi
if [ ! -x "$RUSTC_BIN" ] || [ ! -x "$CARGO_BIN" ]; then die "$RUSTC_BIN / $CARGO_BIN missing (run without --skip-install)"; fi
new_enough "$("$RUSTC_BIN" --version | awk '{print $2}')" || die "$("$RUSTC_BIN" --version) is older than $MIN_RUSTC"
log "compiler: $("$RUSTC_BIN" --version), $("$CARGO_BIN" --version)"
for p in "${platforms[@]}"; do install_std "$p"; done
mkdir -p "$DIST/$(dirname "$MODEL")"
run install -m 644 "$ROOT/$MODEL" "$DIST/$MODEL"
run install -m 644 "$ROOT/$VEHICLE" "$DIST/$VEHICLE"
for p in "${platforms[@]}"; do build "$p"; done
for p in "${platforms[@]}"; do check "$p"; done
for p in "${platforms[@]}"; do log "$(printf '%-13s %6.0f s' "$p" "${SECONDS_OF[$p]}")"; done
