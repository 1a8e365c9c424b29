#!/usr/bin/env bash
# Runs a command and stops its whole process (SIGSTOP, every thread at once)
# for STOP_MS every EVERY_MS until it exits: what an overloaded machine does
# to a device session. Prints the command's output.
#   tests/bench/stall_process.sh 20 97 ./build/release/hapticpd bench delay --scripts press --delays 0
set -euo pipefail
if [[ $# -lt 3 || ! $1 =~ ^[0-9]+$ || ! $2 =~ ^[0-9]+$ ]]; then
  echo "usage: $0 STOP_MS EVERY_MS COMMAND [ARGS...]" >&2
  exit 2
fi
stop_s=$(awk -v ms="$1" 'BEGIN { printf "%.3f", ms / 1000 }')
every_s=$(awk -v ms="$2" 'BEGIN { printf "%.3f", ms / 1000 }')
shift 2
"$@" &
pid=$!
while kill -0 "$pid" 2>/dev/null; do
  sleep "$every_s"
  kill -STOP "$pid" 2>/dev/null || break
  sleep "$stop_s"
  kill -CONT "$pid" 2>/dev/null || break
done
wait "$pid"
