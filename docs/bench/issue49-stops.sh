#!/bin/bash
# Issue 49's stop measurements for one rove binary: an operator's and a vehicle's SIGTERM → exit,
# unsecured and secured, and what each logged at WARN or ERROR while stopping.
ROVE=$1; L=$2; NS=st49-$L; D=/tmp/st49-$L
rm -rf $D; mkdir -p $D
ip netns add $NS; ip netns exec $NS ip link set lo up; ip netns exec $NS ip link set lo multicast on; ip netns exec $NS ip route add 224.0.0.0/4 dev lo
$ROVE keys init --dir $D/fleet --fleet st49 >/dev/null 2>&1
$ROVE keys add --dir $D/fleet --id 100 >/dev/null 2>&1
$ROVE keys add --dir $D/fleet --id 11 >/dev/null 2>&1
ms() { echo $(( ($(date +%s%N) - $1) / 1000000 )); }
for sec in plain secured; do
  S=""; [ $sec = secured ] && S="[security]"
  V="[device]\nid = 100\n[output]\nadapter = \"sim\"\n"; O="[device]\nid = 11\n[operator]\nlevel = \"stationary\"\ndevice_class = \"laptop\"\ndrive = [100]\n[input]\nsource = \"constant\"\nthrottle = 1000\n"
  if [ $sec = secured ]; then V="$V[security]\ndir = \"$D/fleet/100\"\n"; O="$O[security]\ndir = \"$D/fleet/11\"\n"; fi
  printf "$V" > $D/v-$sec.toml; printf "$O" > $D/o-$sec.toml
  for run in 1 2 3; do
    ip netns exec $NS $ROVE vehicle -c $D/v-$sec.toml > $D/v-$sec-$run.log 2>&1 & VP=$!
    ip netns exec $NS $ROVE operator -c $D/o-$sec.toml --headless > $D/o-$sec-$run.log 2>&1 & OP=$!
    # Driving: the vehicle logs its owner change to 11 (or give it 8 s for a secured join).
    for i in $(seq 1 160); do grep -q "owner.*11\|to=11\|new_owner=11\|Operator(11)" $D/v-$sec-$run.log 2>/dev/null && break; sleep 0.05; done
    sleep 1
    t=$(date +%s%N); kill -TERM $OP; wait $OP; op_ms=$(ms $t)
    sleep 0.5
    t=$(date +%s%N); kill -TERM $VP; wait $VP; v_ms=$(ms $t)
    echo "$L $sec run $run: operator SIGTERM → exit $op_ms ms, vehicle SIGTERM → exit $v_ms ms"
  done
  echo "== $L $sec: WARN/ERROR lines logged by run 3's operator and vehicle, start to stop:"
  grep -h "ERROR\|WARN" $D/o-$sec-3.log $D/v-$sec-3.log | grep -v "no \[security\]\|no \[access\]" | sed 's/^[0-9T:.\-]*Z //' | sort | uniq -c | head -12
done
ip netns del $NS
