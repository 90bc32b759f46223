#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# `iwlomap map --mpi` under mpirun: the occupied voxels of 2 and 3 ranks (RAM and Disk shards,
# files round robin or each split by points)
# and the .ot file, with either ray model, are those of the one-process `iwlomap map`; a bad output ends every rank with
# the usage code; a file one rank cannot read ends the job naming it.
# usage: test_map_mpi.sh MPIEXEC IWLOMAP WORKDIR
set -u
mpiexec=$1 tool=$2 work=$3
run() { "$mpiexec" --oversubscribe --allow-run-as-root "$@"; }
fail() { echo "FAIL: $*"; exit 1; }
rm -rf "$work" && mkdir -p "$work" || exit 1
scans=()
for i in 0 1 2 3 4; do
  "$tool" generate -o "$work/scan$i.pcd" --rings 16 --columns 256 --seed $((i + 1)) --height "1.$((2 * i))" >/dev/null \
    || fail "generate scan $i"
  scans+=("$work/scan$i.pcd")
done
opts=(--sensor lidar --resolution 0.2 --threshold 0.6)
"$tool" map "${scans[@]}" "${opts[@]}" -q -o "$work/one.pcd" || fail "one-process map"
run -np 2 "$tool" map --mpi "${scans[@]}" "${opts[@]}" -o "$work/two.pcd" | tee "$work/two.log" || fail "2 ranks"
# --octomap gathers the whole map on rank 0: the file is byte for byte the one-process one.
if "$tool" --version | grep -qi octomap; then
  "$tool" map "${scans[@]}" "${opts[@]}" -q --octomap "$work/one.ot" || fail "one-process .ot"
  run -np 2 "$tool" map --mpi "${scans[@]}" "${opts[@]}" -q --octomap "$work/two.ot" || fail "2 ranks, .ot"
  cmp "$work/one.ot" "$work/two.ot" || fail "the .ot files differ"
  # The fast ray model travels to the ranks: its map too is the one-process map.
  "$tool" map "${scans[@]}" "${opts[@]}" --rays fast -q --octomap "$work/one_fast.ot" || fail "one-process .ot, fast rays"
  run -np 2 "$tool" map --mpi "${scans[@]}" "${opts[@]}" --rays fast -q --octomap "$work/two_fast.ot" \
    || fail "2 ranks, .ot, fast rays"
  cmp "$work/one_fast.ot" "$work/two_fast.ot" || fail "the .ot files of fast rays differ"
  ! cmp -s "$work/one.ot" "$work/one_fast.ot" || fail "--rays fast gave the map of exact rays"
fi
# An output rank 0 refuses ends every rank at once (no rank left waiting), with the usage code.
out=$(timeout 60 "$mpiexec" --oversubscribe --allow-run-as-root -np 2 "$tool" map --mpi "${scans[@]}" -o "$work/bad.txt" 2>&1)
rc=$?
[ $rc -eq 2 ] || { echo "$out"; fail "a bad output: exit code $rc, expected 2"; }
grep -q "on 2 rank(s)" "$work/two.log" || fail "the summary does not name 2 ranks"
run -np 3 "$tool" map --mpi "${scans[@]}" "${opts[@]}" --backend disk --tiles "$work/tiles" -q -o "$work/three.pcd" \
  || fail "3 ranks, disk"
test -f "$work/tiles/iwlomap_distributed.manifest" && test -d "$work/tiles/rank-2" || fail "no distributed directory"
# Each file split over 3 ranks by points: the same map.
run -np 3 "$tool" map --mpi --split-points "${scans[@]}" "${opts[@]}" -q -o "$work/split.pcd" || fail "3 ranks, split points"
# The same voxels and probabilities, whatever the order of the rows.
/usr/bin/python3 - "$work/one.pcd" "$work/two.pcd" "$work/three.pcd" "$work/split.pcd" <<'PY' || fail "the maps differ"
import sys
import numpy as np
def voxels(path):
    data = open(path, "rb").read()
    head, _, body = data.partition(b"DATA binary\n")
    fields = dict(line.split(None, 1) for line in head.decode().splitlines() if line and not line.startswith("#"))
    names, sizes = fields["FIELDS"].split(), [int(s) for s in fields["SIZE"].split()]
    rows = np.frombuffer(body, dtype=np.uint8).reshape(int(fields["POINTS"]), sum(sizes))
    cols = {}
    off = 0
    for n, s in zip(names, sizes):
        cols[n] = rows[:, off:off + s].copy().view(np.float32)[:, 0] if s == 4 else None
        off += s
    v = np.stack([cols["x"], cols["y"], cols["z"], cols["intensity"]], axis=1)
    return v[np.lexsort(v.T[::-1])]
one = voxels(sys.argv[1])
assert len(one) > 1000, len(one)
for other in sys.argv[2:]:
    o = voxels(other)
    assert o.shape == one.shape and np.array_equal(o, one), (other, o.shape, one.shape)
print("same", len(one), "occupied voxels")
PY
# A file that rank 1 cannot read: the job ends (no hang), non-zero, naming rank 1 and the file.
out=$(timeout 120 "$mpiexec" --oversubscribe --allow-run-as-root -np 2 "$tool" map --mpi "${scans[0]}" "$work/missing.pcd" \
      "${opts[@]}" -q -o "$work/bad.pcd" 2>&1)
rc=$?
echo "$out"
[ $rc -ne 0 ] && [ $rc -ne 124 ] || fail "exit code $rc"
echo "$out" | grep -q "rank 1: error: .*missing.pcd" || fail "the error does not name rank 1 and the file"
test ! -e "$work/bad.pcd" || fail "an output was written"
echo "ok"
