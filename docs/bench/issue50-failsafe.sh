#!/bin/bash
# Issue 50's failsafe measurements for one rove binary: ACK-only and HEARTBEAT runs, 20 `rove
# failsafe` each after the vehicle's kill -9; prints the first summary and the runtime directory.
ROVE=$1; L=$2; NS=fs50-$L; D=/tmp/fs50-$L
rm -rf $D; mkdir -p $D/run
ip netns add $NS; ip netns exec $NS ip link set lo up; ip netns exec $NS ip link set lo multicast on; ip netns exec $NS ip route add 224.0.0.0/4 dev lo
REPO=$(cd "$(dirname "$0")/../.." && pwd)
PY=$REPO/.venv/bin/python3
for mode in ack hb; do
  args="--connection udpin:127.0.0.1:14560 --heartbeat-hz 0.2"
  [ $mode = hb ] && args="$args --mode-heartbeat"
  ip netns exec $NS $PY $REPO/testkit/fake_autopilot.py $args --record $D/ap-$mode.jsonl > /dev/null 2>&1 & AP=$!
  sleep 1
  printf '[device]\nid = 100\n[output]\nadapter = "mavlink"\nconnection = "udpout:127.0.0.1:14560"\n' > $D/v.toml
  [ $mode = hb ] && echo 'target_system = 1' >> $D/v.toml
  rm -rf $D/run/*
  XDG_RUNTIME_DIR=$D/run ip netns exec $NS $ROVE vehicle -c $D/v.toml > $D/veh-$mode.log 2>&1 & V=$!
  # As the e2e test does: wait (up to 12 s) for the vehicle to keep what it learned, then kill it.
  for i in $(seq 1 120); do [ -n "$(find $D/run -name 'vehicle-100-mavlink' 2>/dev/null)" ] && break; sleep 0.1; done
  sleep 0.3; kill -9 $V; sleep 0.2
  echo "== $L, $mode: runtime directory before the failsafe runs:"; (cd $D/run && find . -type f -printf '%p %s bytes, modified %TT\n')
  for i in $(seq 1 20); do XDG_RUNTIME_DIR=$D/run timeout 10 ip netns exec $NS $ROVE failsafe -c $D/v.toml > $D/fs-$mode-$i.txt 2>&1; done
  echo "== $L, $mode: rove failsafe's summary (run 1):"; grep -v "^\s*$" $D/fs-$mode-1.txt | grep -v "WARN\|INFO" | tail -2
  echo "== $L, $mode: distinct summaries over 20 runs:"; cat $D/fs-$mode-*.txt | grep -v "WARN\|INFO" | sed 's/[0-9.]* ms/N ms/g' | sort | uniq -c
  echo "== $L, $mode: runtime directory after 20 runs:"; (cd $D/run && find . -type f -printf '%p %s bytes, modified %TT\n')
  kill $AP; wait $AP 2>/dev/null
done
ip netns del $NS
