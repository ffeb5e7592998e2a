#!/usr/bin/env bash
# "Your own vehicle", end to end, on models/example_vehicle.toml standing in for a vehicle in
# the water (docs/GUIDE_OWN_VEHICLE.md; tests/cli/own_vehicle.rs runs the same path
# with a short training budget):
#   closed-loop runs and excitation runs -> pinc dataset import -> pinc identify
#   -> pinc train --data --vehicle identified.toml -> pinc eval --data -> mpc_track --model
# Usage: examples/own_vehicle.sh [OUT_DIR] (TRAIN_MINUTES=20 by default).
set -euo pipefail
OUT=${1:-out/own_vehicle}
MINUTES=${TRAIN_MINUTES:-20}
TRUE=models/example_vehicle.toml
cargo build --release --features train --bin pinc --bin mpc_track
PINC=target/release/pinc
TRACK=target/release/mpc_track
mkdir -p "$OUT/logs"

# 1. Closed-loop runs of the controller that knows the vehicle (in the water: your pilot or
#    your current controller), logged as MCAP.
for r in default survey zigzag; do
  $TRACK --oracle --vehicle $TRUE --reference examples/references/$r.csv --out-dir "$OUT/logs" --json > /dev/null
done
# 2. Excitation runs: input files played open loop (in the water: as a teleoperation script),
#    recorded as CSV. Closed-loop depth and heading runs never move surge or sway.
for seed in 1 2 3 4 5 6 7 8; do
  $PINC excitation --out "$OUT/excitation$seed.in.csv" --duration 600 --seed $seed
  $PINC simulate --vehicle $TRUE --x0 0,0,1,0,0,0,0,0 --inputs "$OUT/excitation$seed.in.csv" --record \
    > "$OUT/logs/excitation$seed.csv"
done
# 3. One dataset folder, whole runs per split.
$PINC dataset import --out "$OUT/data" --seed 1 "$OUT"/logs/*.mcap "$OUT"/logs/*.csv
# 4. Identification: mass and yaw inertia known (a scale, a swing test), the rest from the data.
printf 'm = 14.25\nizz = 0.3185\n' > "$OUT/base.toml"
$PINC identify --data "$OUT/data" --vehicle "$OUT/base.toml" --out "$OUT/identified.toml" --json \
  > "$OUT/identified.json"
# 5. A position-free PINC whose physics loss uses the identified vehicle.
#    The settings of models/mpc_pinc.pinc (docs/GUIDE_CONTROLLER.md).
$PINC train --data "$OUT/data" --vehicle "$OUT/identified.toml" --position-free --backend flex \
  --rollout-stride 4 --patience 60 --time-limit "$MINUTES" --epochs 100000 --out "$OUT/own.pinc" --json \
  > "$OUT/train.json"
# 6. Held-out runs (the test split).
$PINC eval --model "$OUT/own.pinc" --data "$OUT/data" --plot "$OUT/eval.png" --json > "$OUT/eval.json"
# 7. The new model in the loop against the true vehicle, beside the oracle.
for who in pinc oracle; do
  flag=""; [ $who = oracle ] && flag="--oracle"
  $TRACK $flag --model "$OUT/own.pinc" --vehicle $TRUE --out-dir "$OUT/closed_loop" --json \
    > "$OUT/closed_loop_$who.json"
done
echo "done: $OUT (identified.json, train.json, eval.json, closed_loop_*.json)"
