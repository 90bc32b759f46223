#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# `iwlomap sonar --register` (and `--loop-closure`, `--detector`, `--sonar-preset`) end to end: a
# first simulated survey is mapped at its true poses into a Disk map; a second survey of the same
# site, whose navigation drifts 1 % of the distance, is registered against that map. The poses it
# writes must end much closer to the truth than the navigation's. Then a survey that runs its
# first line again is mapped with --loop-closure and no prior map.
# usage: test_sonar_register.sh IWLOMAP_BINARY MAKE_SONAR_SURVEY_BINARY WORK_DIR
set -eu
TOOL=$1
MAKE=$2
WORK=$3
rm -rf "$WORK" && mkdir -p "$WORK"
"$MAKE" "$WORK"
"$TOOL" sonar "$WORK/earlier.raw" --poses "$WORK/earlier_truth.txt" --resolution 0.1 --intensity-threshold 35 \
  --backend disk --tiles "$WORK/chart" -o "$WORK/earlier.pcd" -q
"$TOOL" sonar "$WORK/survey.raw" --poses "$WORK/survey_nav.txt" --resolution 0.1 --intensity-threshold 35 \
  --backend disk --tiles "$WORK/chart" --register --submap-pings 20 --write-poses "$WORK/registered.txt" \
  -o "$WORK/survey.pcd" | tee "$WORK/register.out"
grep -q "registered [0-9]* of 9 submap(s)" "$WORK/register.out"
# Mean position error of the poses of file $1 against the truth (file $2, default the survey's).
mean_error() {
  paste -d' ' <(grep -v '^#' "$1") "${2:-$WORK/survey_truth.txt}" |
    awk '{ e += sqrt(($1 - $8) ^ 2 + ($2 - $9) ^ 2 + ($3 - $10) ^ 2); n++ } END { printf "%.4f\n", e / n }'
}
nav=$(mean_error "$WORK/survey_nav.txt")
registered=$(mean_error "$WORK/registered.txt")
echo "mean position error: navigation $nav m, registered $registered m"
test "$(wc -l < "$WORK/survey_truth.txt")" = "$(grep -vc '^#' "$WORK/registered.txt")"
awk -v n="$nav" -v r="$registered" 'BEGIN { exit !(n > 0.3 && r < 0.25 * n) }'
# Without --register the written poses are the navigation's.
"$TOOL" sonar "$WORK/survey.raw" --poses "$WORK/survey_nav.txt" --resolution 0.1 --write-poses "$WORK/as_given.txt" \
  -o "$WORK/as_given.pcd" -q
awk -v n="$nav" -v g="$(mean_error "$WORK/as_given.txt")" 'BEGIN { d = n - g; exit !(d < 1e-6 && d > -1e-6) }'
# --loop-closure: a survey that runs its first line again, no prior map. The poses written must
# end much closer to the truth than the navigation's, and the summary names the closures.
"$TOOL" sonar "$WORK/loop.raw" --poses "$WORK/loop_nav.txt" --resolution 0.1 --intensity-threshold 35 \
  --register --loop-closure --submap-pings 40 --write-poses "$WORK/loop_closed.txt" -o "$WORK/loop.pcd" |
  tee "$WORK/loop.out"
grep -q "loop closure: [0-9]* submap(s), [1-9][0-9]* closure(s) found" "$WORK/loop.out"
loop_nav=$(mean_error "$WORK/loop_nav.txt" "$WORK/loop_truth.txt")
loop_closed=$(mean_error "$WORK/loop_closed.txt" "$WORK/loop_truth.txt")
echo "loop survey, mean position error: navigation $loop_nav m, loop closure $loop_closed m"
test "$(wc -l < "$WORK/loop_truth.txt")" = "$(grep -vc '^#' "$WORK/loop_closed.txt")"
awk -v n="$loop_nav" -v r="$loop_closed" 'BEGIN { exit !(n > 0.3 && r < 0.5 * n) }'
test -s "$WORK/loop.pcd"
if "$TOOL" sonar "$WORK/loop.raw" -o "$WORK/x.pcd" --loop-closure 2> "$WORK/bad.err"; then exit 1; fi
grep -q "loop-closure needs --register" "$WORK/bad.err"
# Bad values.
if "$TOOL" sonar "$WORK/survey.raw" -o "$WORK/x.pcd" --register --submap-pings 0 2> "$WORK/bad.err"; then exit 1; fi
grep -q "submap-pings must be >= 1" "$WORK/bad.err"
if "$TOOL" sonar "$WORK/survey.raw" -o "$WORK/x.pcd" --submap-pings 5 2> "$WORK/bad.err"; then exit 1; fi
grep -q "needs --register" "$WORK/bad.err"
# CFAR detection: the true-pose survey mapped with OS-CFAR; bad detector values.
"$TOOL" sonar "$WORK/survey.raw" --poses "$WORK/survey_truth.txt" --resolution 0.1 --detector os-cfar \
  --false-alarm-rate 0.0001 -o "$WORK/cfar.pcd" | tee "$WORK/cfar.out"
grep -q "beams with an echo" "$WORK/cfar.out" && test -s "$WORK/cfar.pcd"
if "$TOOL" sonar "$WORK/survey.raw" -o "$WORK/x.pcd" --detector median 2> "$WORK/bad.err"; then exit 1; fi
grep -q "detector must be threshold, ca-cfar or os-cfar, got 'median'" "$WORK/bad.err"
if "$TOOL" sonar "$WORK/survey.raw" -o "$WORK/x.pcd" --detector ca-cfar --false-alarm-rate 1 2> "$WORK/bad.err"; then exit 1; fi
grep -q "false_alarm_rate = 1" "$WORK/bad.err"
if "$TOOL" sonar "$WORK/survey.raw" -o "$WORK/x.pcd" --false-alarm-rate 0.01 2> "$WORK/bad.err"; then exit 1; fi
grep -q "needs --detector" "$WORK/bad.err"
# The sonar preset: maps the survey; a fixed-threshold detector under it drops the SNR weight;
# --sensor is refused beside it.
"$TOOL" sonar "$WORK/survey.raw" --poses "$WORK/survey_truth.txt" --resolution 0.1 --sonar-preset \
  -o "$WORK/preset.pcd" | tee "$WORK/preset.out"
grep -q " occupied (p > " "$WORK/preset.out" && test -s "$WORK/preset.pcd"
"$TOOL" sonar "$WORK/survey.raw" --poses "$WORK/survey_truth.txt" --resolution 0.1 --sonar-preset \
  --detector threshold -o "$WORK/preset_threshold.pcd" -q
if "$TOOL" sonar "$WORK/survey.raw" -o "$WORK/x.pcd" --sonar-preset --sensor lidar 2> "$WORK/bad.err"; then exit 1; fi
grep -q "leave out --sensor" "$WORK/bad.err"
echo "sonar --register, --detector and --sonar-preset: passed"
