#!/usr/bin/env bash
# The cost of the balancer hop, on this machine (tests/bench/README.md
# "Balancer hop (scale-out)"): three sharded `hapticpd serve` processes and
# HAProxy on loopback, as tests/scale/scale_test.cc runs them: docker/haproxy.cfg
# with the addresses, the TLS bind and the file paths replaced, and
# docker/shard-map.txt.
#
#   tests/bench/scale_hop.sh hop [BENCH_RPC_ARGS...]
#       creates scene lab-bench (owned by hapticpd-1) and runs
#       bench_rpc --target <haproxy> --direct <hapticpd-1> --scene lab-bench ARGS
#   tests/bench/scale_hop.sh capacity N [SECONDS]
#       N device sessions (`hapticpd couple --rate 1000`, SECONDS long, default
#       30) through the balancer, one scene each, spread round-robin over the
#       three shards (lab-capK, lab-vr-capK, train-capK); prints each session's
#       updates/s and round trip p99 and PASS when every session keeps
#       >= 950 updates/s with p99 <= 5 ms, else FAIL. With DIRECT=1 the
#       sessions connect to their scene's owner instead (no balancer hop),
#       for comparison.
#
# Run from the repository root after `cmake --build --preset release`;
# BUILD=build/release by default. Needs haproxy (docker/install-deps.sh) and
# python3 (free ports). Everything runs in a temporary directory, removed at
# the end (KEEP=1 keeps it, with the processes' logs).
set -euo pipefail

root=$(cd "$(dirname "$0")/../.." && pwd)
build=${BUILD:-$root/build/release}
cli=$build/hapticpd
bench=$build/tests/bench/bench_rpc
haproxy=$(command -v haproxy || echo /usr/sbin/haproxy)
[[ -x $haproxy ]] || { echo "scale_hop: haproxy is not installed" >&2; exit 1; }
[[ -x $cli ]] || { echo "scale_hop: $cli not built" >&2; exit 1; }

mode=${1:-hop}
shift || true

dir=$(mktemp -d "${TMPDIR:-/tmp}/hapticpd_scale_hop.XXXXXX")
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
  if [[ ${KEEP:-0} == 1 ]]; then echo "scale_hop: kept $dir" >&2; else rm -rf "$dir"; fi
}
trap cleanup EXIT

read -r p1 p2 p3 pb < <(python3 -c '
import socket
ss = [socket.socket() for _ in range(4)]
for s in ss: s.bind(("127.0.0.1", 0))
print(*[s.getsockname()[1] for s in ss])')
declare -A addr=([hapticpd-1]=127.0.0.1:$p1 [hapticpd-2]=127.0.0.1:$p2 [hapticpd-3]=127.0.0.1:$p3)
balancer=127.0.0.1:$pb

# The servers.
for name in hapticpd-1 hapticpd-2 hapticpd-3; do
  "$cli" serve --listen "${addr[$name]}" --state "$dir/$name" \
    --shard-map "$root/docker/shard-map.txt" --shard "$name" \
    --status-interval 0 --log-level warn >"$dir/$name.log" 2>&1 &
  pids+=($!)
done
for name in hapticpd-1 hapticpd-2 hapticpd-3; do
  for _ in $(seq 100); do
    "$cli" scene list --server "${addr[$name]}" --timeout 1 >/dev/null 2>&1 && break
    sleep 0.2
  done
  "$cli" scene list --server "${addr[$name]}" --timeout 1 >/dev/null ||
    { echo "scale_hop: $name did not start:" >&2; cat "$dir/$name.log" >&2; exit 1; }
done

# docker/haproxy.cfg on loopback, the same replacements as tests/scale.
replace() {  # FROM TO: every FROM in $dir/haproxy.cfg; fails when there is none
  FROM=$1 TO=$2 python3 - "$dir/haproxy.cfg" <<'EOF'
import os, sys
p = sys.argv[1]
t = open(p).read()
if os.environ["FROM"] not in t:
    sys.exit("scale_hop: docker/haproxy.cfg no longer holds '%s'" % os.environ["FROM"])
open(p, "w").write(t.replace(os.environ["FROM"], os.environ["TO"]))
EOF
}
cp "$root/docker/haproxy.cfg" "$dir/haproxy.cfg"
replace "bind :50051 proto h2 ssl crt /etc/haproxy/tls/hapticpd.pem alpn h2" "bind $balancer proto h2"
replace /var/run/haproxy/admin.sock "$dir/admin.sock"
replace /etc/haproxy/shard-map.txt "$root/docker/shard-map.txt"
for name in hapticpd-1 hapticpd-2 hapticpd-3; do replace "$name:50051" "${addr[$name]}"; done
"$haproxy" -db -f "$dir/haproxy.cfg" >"$dir/haproxy.log" 2>&1 &
pids+=($!)

# Through the balancer once every backend is up: creating a scene on each
# shard succeeds only then.
create() {  # SCENE
  for _ in $(seq 50); do
    "$cli" scene create "$1" --server "$balancer" --timeout 2 >/dev/null 2>&1 && return 0
    sleep 0.2
  done
  "$cli" scene create "$1" --server "$balancer" --timeout 2
}

case $mode in
  hop)
    create lab-bench
    echo "servers: hapticpd-1 ${addr[hapticpd-1]} (owns lab-bench), hapticpd-2 ${addr[hapticpd-2]}," \
      "hapticpd-3 ${addr[hapticpd-3]}; HAProxy $balancer"
    "$bench" --target "$balancer" --direct "${addr[hapticpd-1]}" --scene lab-bench "$@"
    ;;
  capacity)
    n=${1:?capacity needs N}
    secs=${2:-30}
    prefixes=(lab-cap lab-vr-cap train-cap)  # hapticpd-1, -2, -3 (docker/shard-map.txt)
    owners=(hapticpd-1 hapticpd-2 hapticpd-3)
    scenes=()
    declare -A via=()
    for ((i = 0; i < n; i++)); do
      s=${prefixes[i % 3]}$i
      create "$s"
      "$cli" inject --server "$balancer" --scene "$s" --shape box:0.1,0.1,0.1 --id box \
        --pose 0,0,0 >/dev/null
      scenes+=("$s")
      if [[ ${DIRECT:-0} == 1 ]]; then via[$s]=${addr[${owners[i % 3]}]}; else via[$s]=$balancer; fi
    done
    cpids=()
    for s in "${scenes[@]}"; do
      "$cli" couple --server "${via[$s]}" --scene "$s" --rate 1000 --duration "$secs" \
        --from 0,0,0.07 --to 0,0,0.04 >"$dir/couple-$s.log" 2>&1 &
      cpids+=($!)
      pids+=($!)
    done
    for p in "${cpids[@]}"; do wait "$p" || true; done
    ok=1
    for s in "${scenes[@]}"; do
      line=$(grep " updates in " "$dir/couple-$s.log" || true)
      if [[ -z $line ]]; then
        echo "$s: FAILED: $(tail -1 "$dir/couple-$s.log")"
        ok=0
        continue
      fi
      rate=$(sed -E 's/.*\(([0-9.]+)\/s\).*/\1/' <<<"$line")
      p99=$(sed -E 's/.* p99 ([0-9.]+) us.*/\1/' <<<"$line")
      verdict=$(python3 -c "print('ok' if $rate >= 950 and $p99 <= 5000 else 'MISSED')")
      [[ $verdict == ok ]] || ok=0
      echo "$s: $line [$verdict]"
    done
    path=$([[ ${DIRECT:-0} == 1 ]] && echo "direct to the owners" || echo "through HAProxy")
    if ((ok)); then echo "N=$n ${secs}s $path: PASS"; else echo "N=$n ${secs}s $path: FAIL"; fi
    ;;
  *)
    echo "usage: scale_hop.sh hop [BENCH_RPC_ARGS...] | capacity N [SECONDS]" >&2
    exit 2
    ;;
esac
