#!/usr/bin/env bash
# Seeds the fuzz corpus with valid .pinc files (the imported fixtures), so mutations start
# from real structure rather than random bytes.
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p fuzz/corpus/load_model
for name in random_4x32 random_3x16; do
  cargo run --release -q --features tools -- import-torch --weights "tests/fixtures/$name.safetensors" --out "fuzz/corpus/load_model/$name.pinc"
done
# The payload target takes the bytes after the 24-byte header.
mkdir -p fuzz/corpus/load_payload
for f in fuzz/corpus/load_model/*.pinc; do
  tail -c +25 "$f" > "fuzz/corpus/load_payload/$(basename "$f" .pinc).payload"
done
