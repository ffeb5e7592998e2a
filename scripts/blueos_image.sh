#!/usr/bin/env bash
# Builds the BlueOS extension's image, per platform, as the tar BlueOS takes in Extensions >
# Installed > + > "Install from file" (kraken's POST /v2.0/extension/upload, which `docker load`s
# it): dist/pinc-blueos-<platform>.tar, in docker-archive format (what `docker save` writes), named
# and tagged so that BlueOS reads the extension's Docker image and tag from it.
#
# No registry and no Docker daemon: the root file system is Debian bookworm's own packages for the
# platform's architecture (libc6, libgcc-s1, bash, coreutils, base-files, unpacked by mmdebstrap's
# extract variant: nothing runs, so no emulation), the binaries scripts/cross_build.sh put in
# dist/<platform>/ and the files in dist/models/ go on top; umoci makes the OCI image (labels,
# entry point, command, port and environment from blueos/image.json, the one source blueos/Dockerfile
# shares), skopeo writes it as the tar.
#
# Usage: scripts/blueos_image.sh [--platforms linux-arm-v7,linux-arm64,linux-amd64]
#                                [--binaries DIR] [--build-arg NAME=VALUE]... [--out DIR]
#        scripts/blueos_image.sh --sync | --check
#   --platforms   which tars (default: all three; each needs dist/<platform>/pinc and mpc_track)
#   --binaries    take linux-amd64's pinc and mpc_track from DIR instead of dist/linux-amd64/
#                 (e.g. target/release after `cargo build --release --features vehicle`);
#                 debug information is stripped on the way in
#   --build-arg   one of blueos/image.json's args (VERSION, GIT_REF, DOCKERHUB_ORG, ...), as
#                 `docker build --build-arg` takes it
#   --out         where the tars go (default: dist/)
#   --sync        rewrites blueos/Dockerfile's generated block and the store's metadata.json
#                 from blueos/image.json; --check says whether they agree, and exits 1 if not
# Environment: PINC_DIST (default dist/), PINC_BLUEOS_MIRROR (Debian mirror, default
#              http://deb.debian.org/debian), PINC_BLUEOS_WORK (scratch, default a temporary folder).
# Runs as root (mmdebstrap and umoci keep the files' owners); installs umoci, skopeo and
# mmdebstrap with apt when they are missing.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
DIST="${PINC_DIST:-$ROOT/dist}"
CONFIG="$ROOT/blueos/image_config.py"
MIRROR="${PINC_BLUEOS_MIRROR:-http://deb.debian.org/debian}"
SECURITY_MIRROR="${MIRROR%/debian}/debian-security"
KEYRING=/usr/share/keyrings/debian-archive-keyring.gpg
ALL_PLATFORMS=(linux-arm-v7 linux-arm64 linux-amd64)
# The root file system: glibc and libgcc_s (all the binaries link), a shell and the core tools for
# an owner's `docker run --entrypoint bash`, base-files (/etc/os-release, the licences' folder).
PACKAGES=libc6,libgcc-s1,bash,coreutils,base-files
BINARIES=(pinc mpc_track)

log() { echo "[blueos_image] $*" >&2; }
die() { log "error: $*"; exit 1; }
run() { log "\$ $*"; "$@"; }

debarch_of() {
  case "$1" in
    linux-amd64) echo amd64 ;; linux-arm64) echo arm64 ;; linux-arm-v7) echo armhf ;;
    *) die "unknown platform '$1' (known: ${ALL_PLATFORMS[*]})" ;;
  esac
}
# ELF e_machine: x86-64 62, ARM 40, AArch64 183.
machine_of() { case "$1" in linux-amd64) echo 62 ;; linux-arm64) echo 183 ;; linux-arm-v7) echo 40 ;; esac; }
gnu_of() { case "$1" in linux-amd64) echo x86_64-linux-gnu ;; linux-arm64) echo aarch64-linux-gnu ;; linux-arm-v7) echo arm-linux-gnueabihf ;; esac; }
variant_of() { case "$1" in linux-arm64) echo v8 ;; linux-arm-v7) echo v7 ;; *) echo "" ;; esac; }

platforms=("${ALL_PLATFORMS[@]}")
binaries_dir=""
out="$DIST"
overrides=()
while [ $# -gt 0 ]; do
  case "$1" in
    --platforms) [ $# -ge 2 ] || die "--platforms needs a value"; IFS=, read -r -a platforms <<<"$2"; shift 2 ;;
    --binaries) [ $# -ge 2 ] || die "--binaries needs a folder"; binaries_dir="$(cd "$2" && pwd)" || die "--binaries: no folder '$2'"; shift 2 ;;
    --build-arg) [ $# -ge 2 ] || die "--build-arg needs NAME=VALUE"; overrides+=("$2"); shift 2 ;;
    --out) [ $# -ge 2 ] || die "--out needs a folder"; out="$2"; shift 2 ;;
    --sync) exec python3 "$CONFIG" sync ;;
    --check) exec python3 "$CONFIG" check ;;
    -h | --help) sed -n '2,30p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
done
for p in "${platforms[@]}"; do debarch_of "$p" >/dev/null; done
if [ -n "$binaries_dir" ] && [[ " ${platforms[*]} " != *" linux-amd64 "* ]]; then
  die "--binaries is for linux-amd64 (the host's build), which --platforms leaves out"
fi
[ "$(id -u)" -eq 0 ] || die "runs as root (mmdebstrap and umoci keep the root file system's owners): sudo $0 ..."
command -v python3 >/dev/null || die "python3 is needed (it reads blueos/image.json)"
python3 "$CONFIG" check || die "blueos/image.json and what is written from it disagree: run scripts/blueos_image.sh --sync"
ref="$(python3 "$CONFIG" ref "${overrides[@]}")" || die "bad --build-arg (see above)"

# 1. The tools: Debian's umoci, skopeo and mmdebstrap.
need=()
for tool in umoci skopeo mmdebstrap; do command -v "$tool" >/dev/null || need+=("$tool"); done
if [ ${#need[@]} -gt 0 ]; then
  log "installing ${need[*]}"
  run env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}" ||
    { run apt-get update -qq && run env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}"; } ||
    die "could not install ${need[*]} with apt"
fi

# 2. What goes in /opt/pinc, checked before anything is built.
models=()
for f in mpc_pinc_thrust.pinc bluerov2.toml; do
  if [ -f "$DIST/models/$f" ]; then models+=("$DIST/models/$f"); else
    [ -f "$ROOT/models/$f" ] || die "neither $DIST/models/$f nor models/$f exists"
    log "$DIST/models/$f missing: taking models/$f"
    models+=("$ROOT/models/$f")
  fi
done
binary_dir_of() {
  if [ "$1" = linux-amd64 ] && [ -n "$binaries_dir" ]; then echo "$binaries_dir"; else echo "$DIST/$1"; fi
}
for p in "${platforms[@]}"; do
  dir="$(binary_dir_of "$p")"
  for b in "${BINARIES[@]}"; do
    [ -f "$dir/$b" ] || die "$dir/$b missing: run scripts/cross_build.sh --platforms $p first${binaries_dir:+ (or fix --binaries)}"
    [ "$(head -c 4 "$dir/$b" | od -An -c | tr -d ' ')" = '177ELF' ] || die "$dir/$b is not an ELF executable"
    m="$(od -An -tu2 -j18 -N2 "$dir/$b" | tr -d ' ')"
    [ "$m" = "$(machine_of "$p")" ] || die "$dir/$b is built for ELF machine $m, not $p's $(machine_of "$p")"
  done
done

work="${PINC_BLUEOS_WORK:-}"
if [ -z "$work" ]; then
  work="$(mktemp -d)"
  trap 'rm -rf "$work"' EXIT
fi
mkdir -p "$out"
log "image $ref for ${platforms[*]}; tars into $out"

# 3. Per platform: root file system, /opt/pinc, image, tar.
build() {
  local p="$1" arch dir rootfs opt layout archive t0 b variant
  t0=$(date +%s)
  arch="$(debarch_of "$p")"
  dir="$(binary_dir_of "$p")"
  rootfs="$work/$p/rootfs"
  opt="$work/$p/opt"
  layout="$work/$p/oci"
  archive="$out/pinc-blueos-$p.tar"
  rm -rf "${work:?}/$p" "$archive"
  mkdir -p "$work/$p"

  log "$p: Debian bookworm's $PACKAGES for $arch"
  # The archive's signatures checked against Debian's keyring (apt's gpgv; no gpg needed to find it).
  [ -f "$KEYRING" ] || die "$KEYRING missing (Debian's package debian-archive-keyring)"
  local sources=("deb [signed-by=$KEYRING] $MIRROR bookworm main" "deb [signed-by=$KEYRING] $MIRROR bookworm-updates main")
  local security="deb [signed-by=$KEYRING] $SECURITY_MIRROR bookworm-security main"
  local mm=(mmdebstrap --quiet --mode=root --variant=extract --skip=check/signed-by,cleanup/apt/cache
    --architectures="$arch" --include="$PACKAGES" bookworm "$rootfs")
  if ! run "${mm[@]}" "${sources[@]}" "$security"; then
    # A mirror whose security index for this architecture is out of step with its signed Release
    # file fails apt's update; bookworm's point releases carry the security fixes some weeks later.
    log "warning: $p: bookworm-security's $arch index could not be read (above; mirror out of step?):"
    log "warning: $p: taking the packages from bookworm and bookworm-updates alone (its latest point release)"
    rm -rf "$rootfs"
    run "${mm[@]}" "${sources[@]}" || die "$p: mmdebstrap could not build the root file system (above)"
  fi
  log "$p: packages: $(cd "$rootfs/var/cache/apt/archives" && ls -- *.deb | sed 's/\.deb$//' | tr '\n' ' ')"
  [ -e "$rootfs/usr/share/doc/libc6/copyright" ] || die "$p: the root file system has no libc6 (mmdebstrap's output above)"
  # What a container does not use or gets from Docker: device nodes, this machine's resolv.conf and
  # hostname (mmdebstrap copies them in), apt's settings and lists (no apt inside), glibc's iconv
  # modules (20 MB; nothing in the image converts character sets), translations, manuals; the
  # packages' copyright files stay.
  find "$rootfs/dev" -mindepth 1 -delete
  rm -rf "$rootfs/etc/resolv.conf" "$rootfs/etc/hostname" "$rootfs/etc/apt" "$rootfs/var/lib/apt" "$rootfs/var/cache/apt" \
    "$rootfs/usr/lib/$(gnu_of "$p")/gconv" "$rootfs/usr/share/locale" "$rootfs/usr/share/man" "$rootfs/usr/share/info"
  find "$rootfs/usr/share/doc" -mindepth 2 ! -name copyright ! -type d -delete
  mkdir -p "$rootfs/tmp" "$rootfs/data"
  chmod 1777 "$rootfs/tmp"

  mkdir -p "$opt/opt/pinc/bin" "$opt/opt/pinc/models"
  for b in "${BINARIES[@]}"; do
    if [ "$dir" = "$binaries_dir" ]; then
      run strip --strip-debug -o "$opt/opt/pinc/bin/$b" "$dir/$b"
    else
      install -m 755 "$dir/$b" "$opt/opt/pinc/bin/$b"
    fi
  done
  for f in "${models[@]}"; do install -m 644 "$f" "$opt/opt/pinc/models/$(basename "$f")"; done

  # Two layers: Debian's files, then pinc's (a new pinc changes only the second). GNU tar writes
  # them (umoci 0.4.7's own `insert` loses the end of a layer's last file), owners as numbers.
  tar --numeric-owner --sort=name -C "$rootfs" -cf "$work/$p/base.tar" .
  chmod 755 "$opt"
  tar --numeric-owner --sort=name -C "$opt" -cf "$work/$p/pinc.tar" .
  run umoci init --layout "$layout"
  run umoci new --image "$layout:pinc"
  run umoci raw add-layer --image "$layout:pinc" \
    --history.created_by "mmdebstrap --variant=extract bookworm $arch: $PACKAGES" "$work/$p/base.tar"
  run umoci raw add-layer --image "$layout:pinc" \
    --history.created_by "scripts/blueos_image.sh: /opt/pinc for $p" "$work/$p/pinc.tar"
  mapfile -t config_args < <(python3 "$CONFIG" umoci-args "$p" "${overrides[@]}")
  [ ${#config_args[@]} -gt 0 ] || die "no umoci arguments from blueos/image.json"
  run umoci config --image "$layout:pinc" "${config_args[@]}"
  variant="$(variant_of "$p")"
  if [ -n "$variant" ]; then run python3 "$CONFIG" set-variant "$layout" pinc "$variant"; fi
  run umoci gc --layout "$layout"
  run skopeo --insecure-policy copy --quiet "oci:$layout:pinc" "docker-archive:$archive:$ref"
  rm -rf "${work:?}/$p"
  log "$p: $archive, $(du -h "$archive" | cut -f1) ($(stat -c %s "$archive") bytes), $(($(date +%s) - t0)) s"
}
for p in "${platforms[@]}"; do build "$p"; done
for p in "${platforms[@]}"; do log "$(printf '%-13s %s' "$p" "$out/pinc-blueos-$p.tar")"; done
log "upload one in BlueOS: Extensions, Installed, +, Install from file (docs/BLUEOS.md)"
