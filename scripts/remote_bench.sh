#!/usr/bin/env bash
# Training over served devices on loopback (BENCHMARKS.md, "Training on several machines"):
# for a config, the step time and the bytes sent per step with 1 local device, with 1, 2 and 4
# devices served by `prism serve` (WebSocket, flex) on this machine, and with 2 and 4 served
# devices whose servers load their shares from a copy of the dataset (`prism serve --data`).
# The global batch is 4 samples for every variant; no validation, no checkpoint inside the
# timed runs. The config's synthetic dataset is made in a cache folder of its own.
#
#   scripts/remote_bench.sh [CONFIG] [STEPS]      defaults: configs/tiny.toml, 12 steps
#
# Bytes are the loopback interface's transmitted bytes (/sys/class/net/lo/statistics: every
# packet between the trainer and the servers and between servers, TCP/IP headers included;
# run it with nothing else using loopback), per step as the difference between a run of STEPS
# steps and one of 2 steps (which cancels the handshake and the first copy of the model).
# Needs a release build (cargo build --release). Prints one markdown table row per variant.
set -euo pipefail
cd "$(dirname "$0")/.."
CONFIG="${1:-configs/tiny.toml}"
STEPS="${2:-12}"
PRISM="$PWD/target/release/prism"
WORK="$(mktemp -d)"
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$WORK"' EXIT
echo "bench-token" > "$WORK/token"
export PRISM_CACHE_DIR="$WORK/cache"
# The config with a global batch of 4 samples, no validation, checkpoints only at the end.
awk '/^\[/{section=$0} section=="[train]" && /^batch_size/{$0="batch_size = 4"}
     section=="[train]" && /^validate_every/{$0="validate_every = 0"}
     section=="[train]" && /^checkpoint_every/{$0="checkpoint_every = 100000"} {print}' \
  "$CONFIG" > "$WORK/bench.toml"

loopback() { cat /sys/class/net/lo/statistics/tx_bytes; }

# Runs the trainer for $1 steps on --devices $2; prints "SECONDS_PER_STEP LOOPBACK_BYTES".
train() {
  local before after
  before=$(loopback)
  "$PRISM" train-teacher --config "$WORK/bench.toml" --out "$WORK/run-$RANDOM" --steps "$1" \
    --quiet --devices "$2" --token-file "$WORK/token" > "$WORK/train.log" 2>&1 \
    || { cat "$WORK/train.log" >&2; exit 1; }
  after=$(loopback)
  echo "$(sed -n 's/.*(\([0-9.]*\) s per step).*/\1/p' "$WORK/train.log") $((after - before))"
}

row() { # name devices
  local seconds short long
  read -r _ short <<< "$(train 2 "$2")"
  read -r seconds long <<< "$(train "$STEPS" "$2")"
  printf "| %s | %s | %s | %.2f |\n" "$(basename "$CONFIG")" "$1" "$seconds" \
    "$(echo "($long - $short) / ($STEPS - 2) / 1000000" | bc -l)"
}

# Starts a server with the extra arguments given; prints its --devices entry.
serve() {
  local out="$WORK/serve-$RANDOM.out"
  "$PRISM" serve --listen 127.0.0.1:0 --transport websocket --token-file "$WORK/token" "$@" \
    > "$out" 2> /dev/null &
  until [ -s "$out" ]; do sleep 0.1; done
  head -1 "$out"
}

row "1 local" 1
DATA="$(echo "$WORK"/cache/datasets/*)"
SENT=() LOADING=()
for _ in 1 2 3 4; do
  SENT+=("$(serve)")
  LOADING+=("$(serve --data "$DATA")")
done
row "1 served" "${SENT[0]}"
row "2 served" "${SENT[0]},${SENT[1]}"
row "4 served" "$(IFS=,; echo "${SENT[*]}")"
row "2 served, --data" "${LOADING[0]},${LOADING[1]}"
row "4 served, --data" "$(IFS=,; echo "${LOADING[*]}")"
