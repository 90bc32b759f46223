#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# End-to-end checks of the iwlomap command-line tool: exit codes, error lines, --help, and that
# its outputs open in PCL's own tools.
# usage: test_tool.sh IWLOMAP_BINARY WORK_DIR [LAYERS]   (LAYERS: e.g. "octomap,viewer," as built)
set -u
TOOL=$1
WORK=$2
LAYERS=${3:-}
has_layer() { case ",$LAYERS" in *",$1,"*) return 0 ;; *) return 1 ;; esac; }
rm -rf "$WORK" && mkdir -p "$WORK"
passed=0
failed=0
check() {  # check NAME EXPECTED_RC COMMAND...
  local name=$1 expected=$2
  shift 2
  "$@" >"$WORK/$name.out" 2>"$WORK/$name.err"
  local rc=$?
  if [ "$rc" = "$expected" ]; then
    passed=$((passed + 1))
  else
    failed=$((failed + 1))
    echo "FAIL $name: exit $rc, expected $expected"
    sed 's/^/  stderr: /' "$WORK/$name.err" | head -5
  fi
}
expect() {  # expect NAME CONDITION-COMMAND...
  local name=$1
  shift
  if "$@"; then passed=$((passed + 1)); else failed=$((failed + 1)); echo "FAIL $name"; fi
}
one_line() { [ "$(wc -l <"$WORK/$1.err")" -eq 1 ]; }
# Same voxels, maybe in another order: compare the sorted ASCII rows of two .pcd files.
sorted_rows() { pcl_convert_pcd_ascii_binary "$1" "$1.ascii.pcd" 0 >/dev/null && grep -E '^-?[0-9]' "$1.ascii.pcd" | sort; }
same_voxels() { bash -c "$(declare -f sorted_rows); diff <(sorted_rows '$1') <(sorted_rows '$2') >/dev/null && test \$(sorted_rows '$1' | wc -l) -gt 100"; }

check help 0 "$TOOL" --help
expect help_lists_map grep -q "map" "$WORK/help.out"
check no_command 2 "$TOOL"
check unknown_command 2 "$TOOL" frobnicate
expect unknown_command_one_line one_line unknown_command
for cmd in map info generate export; do
  check "help_$cmd" 0 "$TOOL" "$cmd" --help
  expect "help_${cmd}_usage" grep -q "usage: iwlomap $cmd" "$WORK/help_$cmd.out"
done
expect map_help_lists_every_option bash -c "for o in --tile-size --cache-tiles --octomap --snapshot --threads --async --resolution --backend --tiles --max-range --no-rays --rays --sensor --threshold --sharpness --decay-rate --min-alpha --l-min --l-max --l-occ --l-free --intensity-threshold --intensity-max --no-adaptive --adaptive-threshold --adaptive-max-ratio --max-memory --register --window --min-score; do grep -q -- \"\$o\" '$WORK/help_map.out' || { echo missing \$o; exit 1; }; done"

check help_sonar 0 "$TOOL" sonar --help
expect sonar_help_max_range_once test "$(grep -c -- '--max-range' "$WORK/help_sonar.out")" = 1
expect sonar_help_no_rays_not_offered bash -c "! grep -Eq -- '^  --no-rays {2,}' '$WORK/help_sonar.out'"
expect sonar_help_rays_not_offered bash -c "! grep -Eq -- '^  --rays ' '$WORK/help_sonar.out'"
expect sonar_help_register bash -c "grep -q -- '--register' '$WORK/help_sonar.out' && grep -q -- '--write-poses' '$WORK/help_sonar.out'"
expect sonar_help_outputs bash -c "grep -q -- '--octomap' '$WORK/help_sonar.out' && grep -q -- '--snapshot' '$WORK/help_sonar.out'"

check generate 0 "$TOOL" generate -o "$WORK/scan.pcd" --rings 16 --columns 256
check info 0 "$TOOL" info "$WORK/scan.pcd"
expect info_counts grep -q "4096 points" "$WORK/info.out"
expect info_origin grep -q "sensor origin (m): (0, 0, 1.5)" "$WORK/info.out"
# CloudCompare writes the intensity of a PLY as the scalar field `scalar_intensity`.
printf 'ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty float scalar_intensity\nend_header\n1 0 0 200\n2 0 0 10\n0 3 0 250\n' >"$WORK/cloudcompare.ply"
check info_scalar_intensity 0 "$TOOL" info "$WORK/cloudcompare.ply"
expect scalar_intensity_read grep -q "intensity: \[10, 250\]" "$WORK/info_scalar_intensity.out"

check map_pcd 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --sensor lidar -o "$WORK/occupied.pcd"
expect map_summary grep -q "occupied (p > 0.7)" "$WORK/map_pcd.out"
expect map_output_exists test -s "$WORK/occupied.pcd"
expect map_summary_times_apart grep -Eq "in [0-9.e-]+ s; outputs written in [0-9.e-]+ s$" "$WORK/map_pcd.out"
# The bar moves within one file (a terminal from script(1)): percentages below 100 while the
# only file is not done (0/1), in both stages; then the writing bar within the .bt file.
check generate_full_scan 0 "$TOOL" generate -o "$WORK/full_scan.pcd"
bar_bt=""
if has_layer octomap; then bar_bt="--octomap '$WORK/bar.bt'"; fi
check map_bar_in_terminal 0 script -qec "'$TOOL' map '$WORK/full_scan.pcd' --resolution 0.1 -o '$WORK/bar.pcd' $bar_bt" "$WORK/bar.typescript"
expect map_bar_moves_while_casting grep -aEq "mapping \[#+ +\] [1-4][0-9]% 0/1 full_scan.pcd: casting rays" "$WORK/map_bar_in_terminal.out"
expect map_bar_moves_while_updating grep -aEq "mapping \[#+ +\] [5-9][0-9]% 0/1 full_scan.pcd: updating voxels" "$WORK/map_bar_in_terminal.out"
has_layer octomap && expect map_bar_moves_while_writing grep -aEq "writing \[#+ +\] [0-9]+% 1/2 bar.bt: writing the file" "$WORK/map_bar_in_terminal.out"
check pcl_pcd2ply_opens_output 0 pcl_pcd2ply "$WORK/occupied.pcd" "$WORK/occupied_from_pcl.ply"
expect pcl_ply_nonempty test -s "$WORK/occupied_from_pcl.ply"
n_pcd=$(grep -a -m1 '^POINTS' "$WORK/occupied.pcd" | awk '{print $2}')
expect map_found_occupied_voxels test "${n_pcd:-0}" -gt 100

if has_layer octomap; then
  # OctoMap output opens in OctoMap's own tools.
  check map_octomap 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --sensor lidar --octomap "$WORK/map.bt"
  check convert_octree_reads_bt 0 convert_octree "$WORK/map.bt" "$WORK/map_converted.ot"
  expect converted_ot_exists test -s "$WORK/map_converted.ot"
  check bad_octomap_ext 2 "$TOOL" map "$WORK/scan.pcd" --octomap "$WORK/map.txt"
  check backend_octomap 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --sensor lidar --backend octomap -o "$WORK/occ_octomap.pcd"
  expect octomap_backend_same_voxels same_voxels "$WORK/occ_octomap.pcd" "$WORK/occupied.pcd"

else
  # Without the OctoMap layer the option fails clearly before any work.
  check octomap_without_layer 1 "$TOOL" map "$WORK/scan.pcd" --octomap "$WORK/map.bt"
  expect octomap_without_layer_says_so grep -q "no OctoMap layer" "$WORK/octomap_without_layer.err"
fi

if has_layer viewer; then
  # A snapshot needs an X server: the suite's (xvfb-run), else the renderer's own Xvfb; without
  # either, a clear error before any mapping.
  if [ -n "${DISPLAY:-}" ]; then
    check map_snapshot 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --sensor lidar --snapshot "$WORK/map.png"
    expect snapshot_is_png bash -c "head -c 8 '$WORK/map.png' | od -An -c | grep -q 'P   N   G'"
  fi
  check snapshot_without_display 0 env -u DISPLAY "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --sensor lidar \
    --snapshot "$WORK/nodisplay.png"
  expect snapshot_without_display_is_png bash -c "head -c 8 '$WORK/nodisplay.png' | od -An -c | grep -q 'P   N   G'"
  check snapshot_without_xvfb 1 env -u DISPLAY IWLOMAP_XVFB=/nonexistent/Xvfb "$TOOL" map "$WORK/scan.pcd" \
    --snapshot "$WORK/noxvfb.png"
  expect snapshot_error_says_xvfb grep -q "xvfb-run" "$WORK/snapshot_without_xvfb.err"
  expect snapshot_error_before_work test ! -e "$WORK/noxvfb.png"
  check bad_snapshot_ext 2 "$TOOL" map "$WORK/scan.pcd" --snapshot "$WORK/map.jpg"
else
  check snapshot_without_layer 1 "$TOOL" map "$WORK/scan.pcd" --snapshot "$WORK/map.png"
  expect snapshot_without_layer_says_so grep -q "no VTK viewer layer" "$WORK/snapshot_without_layer.err"
fi

# The disk backend: a tile directory is created, continued by a second run with its stored
# geometry, described by info, exported and rendered; the same voxels as the RAM backend.
check map_disk 0 "$TOOL" map "$WORK/scan.pcd" --backend disk --tiles "$WORK/tiles" --resolution 0.2 --tile-size 6.4 --cache-tiles 2 --sensor lidar -o "$WORK/occ_disk.pcd"
expect disk_same_voxels_as_ram same_voxels "$WORK/occ_disk.pcd" "$WORK/occupied.pcd"
check map_disk_continue 0 "$TOOL" map "$WORK/scan.pcd" --backend disk --tiles "$WORK/tiles" --sensor lidar
expect disk_continue_keeps_resolution grep -q "at 0.2 m, Disk backend" "$WORK/map_disk_continue.out"
check disk_wrong_resolution 1 "$TOOL" map "$WORK/scan.pcd" --backend disk --tiles "$WORK/tiles" --resolution 0.1
expect disk_wrong_resolution_says_stored grep -q "created with resolution" "$WORK/disk_wrong_resolution.err"
check info_tiles 0 "$TOOL" info "$WORK/tiles"
expect info_tiles_reports grep -q "Disk map, .* known voxels at 0.2 m" "$WORK/info_tiles.out"
expect info_tiles_entropy grep -q "entropy: .* bits" "$WORK/info_tiles.out"
check export_tiles_pcd 0 "$TOOL" export "$WORK/tiles" -o "$WORK/exported.pcd"
check pcl_reads_export 0 pcl_pcd2ply "$WORK/exported.pcd" "$WORK/exported_pcl.ply"
check export_not_a_map 2 "$TOOL" export "$WORK/scan.pcd" -o "$WORK/x.pcd"
check export_missing_file 1 "$TOOL" export "$WORK/no_such_map.bt" -o "$WORK/x.pcd"
check export_no_map_in_dir 1 "$TOOL" export "$WORK" -o "$WORK/x.pcd"
expect export_no_map_says_so grep -q "holds no iwlomap map" "$WORK/export_no_map_in_dir.err"
check tiles_only_for_disk 2 "$TOOL" map "$WORK/scan.pcd" --tiles "$WORK/tiles"
# Reading commands open a tile directory read-only: no file in it changes (the metadata neither,
# though an export to .bt takes its own threshold).
listing() { (cd "$1" && find . -type f -printf '%p %s %T@\n' | sort); }
listing "$WORK/tiles" >"$WORK/tiles_before.txt"
if has_layer octomap; then
  check export_tiles_bt_threshold 0 "$TOOL" export "$WORK/tiles" -o "$WORK/exported_06.bt" --threshold 0.6
fi
check info_tiles_again 0 "$TOOL" info "$WORK/tiles"
check export_tiles_again 0 "$TOOL" export "$WORK/tiles" -o "$WORK/exported_again.pcd"
listing "$WORK/tiles" >"$WORK/tiles_after.txt"
expect reading_changes_no_tile_file cmp -s "$WORK/tiles_before.txt" "$WORK/tiles_after.txt"
if has_layer octomap; then
  check export_tiles_bt 0 "$TOOL" export "$WORK/tiles" -o "$WORK/exported.bt"
  check convert_octree_reads_export 0 convert_octree "$WORK/exported.bt" "$WORK/exported.ot"
  check info_bt 0 "$TOOL" info "$WORK/exported.bt"
  expect info_bt_reports grep -q "OctoMap map, .* known voxels at 0.2 m" "$WORK/info_bt.out"
fi
# A run that fails leaves a disk map exactly as it was: one tile of a many-tile map gets a flipped
# payload byte; the next run reads (and stages) other tiles first, then fails naming that tile,
# and every file of the map is byte for byte what it was.
check map_disk_many_tiles 0 "$TOOL" map "$WORK/scan.pcd" --backend disk --tiles "$WORK/tiles_many" --resolution 0.2 \
  --tile-size 1.6 --cache-tiles 4 --sensor lidar
expect many_tiles bash -c "test \$(ls '$WORK/tiles_many' | grep -c '^tile_') -ge 40"
victim=$(ls "$WORK/tiles_many" | grep '^tile_' | sort | sed -n 20p)
python3 -c "import sys; p=sys.argv[1]; b=bytearray(open(p,'rb').read()); b[-3]^=0x10; open(p,'wb').write(b)" \
  "$WORK/tiles_many/$victim"
(cd "$WORK/tiles_many" && sha256sum -- * | sort) >"$WORK/tiles_many_before.txt"
check map_disk_damaged_tile 1 "$TOOL" map "$WORK/scan.pcd" --backend disk --tiles "$WORK/tiles_many" --sensor lidar
expect damaged_tile_named grep -q "$victim.*checksum" "$WORK/map_disk_damaged_tile.err"
(cd "$WORK/tiles_many" && sha256sum -- * | sort) >"$WORK/tiles_many_after.txt"
expect failed_run_changes_no_file cmp -s "$WORK/tiles_many_before.txt" "$WORK/tiles_many_after.txt"
# repair sets the damaged tile aside; the rest of the map is usable again, and sound.
check repair_damaged_map 0 "$TOOL" repair "$WORK/tiles_many"
expect repair_names_tile grep -q "set aside as .*damaged/$victim: .*checksum" "$WORK/repair_damaged_map.out"
expect repair_moved_tile test -f "$WORK/tiles_many/damaged/$victim"
check map_after_repair 0 "$TOOL" map "$WORK/scan.pcd" --backend disk --tiles "$WORK/tiles_many" --sensor lidar
check repair_sound_map 0 "$TOOL" repair "$WORK/tiles_many"
expect repair_sound_map_says_so grep -q "every tile is sound" "$WORK/repair_sound_map.out"
check repair_no_map 1 "$TOOL" repair "$WORK/no_such_map"
check pyramid_tiles 0 "$TOOL" pyramid "$WORK/tiles" --levels 2 -o "$WORK/pyramid_tiles"
expect pyramid_tiles_png test -s "$WORK/pyramid_tiles/level_1.png"
# All or nothing: a file-size limit makes a level's write fail; no level file, no folder is left.
check pyramid_full_disk 1 bash -c "trap '' XFSZ; ulimit -f 40; exec '$TOOL' pyramid '$WORK/tiles_many' --levels 9 -o '$WORK/pyramid_full'"
expect pyramid_full_disk_names_file grep -q "cannot write '$WORK/pyramid_full/level_.*': File too large" "$WORK/pyramid_full_disk.err"
expect pyramid_full_disk_leaves_nothing test ! -e "$WORK/pyramid_full"
# SIGTERM at moments spread over a run: the folder is either absent (ended before its commit) or
# holds every level (committed, possibly killed while exiting), never some levels or a temporary.
# (Which moments land in the writing varies; the property holds at every moment.)
pyramid_term_ok() {
  for d in 0.1 0.2 0.3 0.4 0.5 0.6 0.8 1.2; do
    rm -rf "$WORK/pyramid_term"
    timeout -s TERM "$d" "$TOOL" pyramid "$WORK/tiles" --levels 12 -o "$WORK/pyramid_term" -q
    rc=$?
    if [ "$rc" -eq 0 ]; then
      [ "$(ls -A "$WORK/pyramid_term" | wc -l)" -eq 24 ] || { echo "after $d s: exit 0 but not 24 files"; return 1; }
    elif [ "$rc" -eq 124 ]; then
      [ ! -e "$WORK/pyramid_term" ] || [ "$(ls -A "$WORK/pyramid_term" | grep -c '^level_')" -eq 24 ] ||
        { echo "after $d s: terminated, left $(ls -A "$WORK/pyramid_term")"; return 1; }
    else
      echo "after $d s: exit $rc"; return 1
    fi
    ! ls -A "$WORK/pyramid_term" 2>/dev/null | grep -q '^\.' || { echo "after $d s: a temporary is left"; return 1; }
  done
}
expect pyramid_sigterm_leaves_all_or_nothing pyramid_term_ok
if has_layer viewer && [ -n "${DISPLAY:-}" ]; then
  check render_tiles 0 "$TOOL" render "$WORK/tiles" -o "$WORK/tiles.png"
  expect render_tiles_png test -s "$WORK/tiles.png"
  expect render_leaves_no_temporary bash -c "! ls -A '$WORK' | grep -q '^\.tiles\.iwlomap-'"
  # A raw scan (no voxel grid) is drawn as points, and says so.
  check render_raw_scan 0 "$TOOL" render "$WORK/scan.pcd" -o "$WORK/raw_scan.png"
  expect render_raw_scan_says_points grep -q "not a voxel cloud: drawn as points" "$WORK/render_raw_scan.out"
  expect render_raw_scan_png test -s "$WORK/raw_scan.png"
  check render_voxels_inferred 0 "$TOOL" render "$WORK/occupied.pcd" -o "$WORK/voxels.png"
  expect render_voxels_inferred_size grep -q "voxels of 0.2 m (inferred)" "$WORK/render_voxels_inferred.out"
  check render_unwritable 1 "$TOOL" render "$WORK/occupied.pcd" -o "/nonexistent-dir/x.png"
fi

# Threads and the background integration give the same map.
check map_threads_async 0 "$TOOL" map "$WORK/scan.pcd" "$WORK/scan.pcd" --resolution 0.2 --sensor lidar --threads 3 --async -o "$WORK/occ_t3.pcd"
check map_two_scans 0 "$TOOL" map "$WORK/scan.pcd" "$WORK/scan.pcd" --resolution 0.2 --sensor lidar -o "$WORK/occ_t1.pcd"
expect threads_async_same_map cmp -s "$WORK/occ_t3.pcd" "$WORK/occ_t1.pcd"
check async_without_rays 2 "$TOOL" map "$WORK/scan.pcd" --no-rays --async
check negative_threads 2 "$TOOL" map "$WORK/scan.pcd" --threads -1
# Integer options are parsed strictly: overflow, trailing characters, spaces.
check threads_overflow 2 "$TOOL" map "$WORK/scan.pcd" --threads 99999999999999999999
check threads_trailing 2 "$TOOL" map "$WORK/scan.pcd" --threads 2x
check cache_tiles_space 2 "$TOOL" map "$WORK/scan.pcd" --backend disk --tiles "$WORK/t_space" --cache-tiles " 3"
check rings_beyond_int 2 "$TOOL" generate -o "$WORK/g.pcd" --rings 4294967297
# Sizes checked against the memory budget before anything is made; voxels that a 32-bit float
# cannot place refused up front.
check scan_beyond_memory 2 "$TOOL" generate -o "$WORK/g.pcd" --rings 100000 --columns 100000
expect scan_beyond_memory_says_budget grep -q "more than the memory budget" "$WORK/scan_beyond_memory.err"
check resolution_beyond_float 2 "$TOOL" map "$WORK/scan.pcd" --resolution 1e300 -o "$WORK/never.pcd"
expect resolution_beyond_float_one_line one_line resolution_beyond_float
expect resolution_beyond_float_no_output test ! -e "$WORK/never.pcd"
expect rings_beyond_int_one_line one_line rings_beyond_int
check threads_2_31 2 "$TOOL" map "$WORK/scan.pcd" --threads 2147483648
expect threads_2_31_names_value grep -q "2147483648" "$WORK/threads_2_31.err"
check threads_2_32_plus_1 2 "$TOOL" map "$WORK/scan.pcd" --threads 4294967297
check cache_tiles_2_64 2 "$TOOL" map "$WORK/scan.pcd" --backend disk --tiles "$WORK/t_big" --cache-tiles 18446744073709551615
check tile_size_zero 2 "$TOOL" map "$WORK/scan.pcd" --backend disk --tiles "$WORK/t_zero" --tile-size 0
check resolution_zero 2 "$TOOL" map "$WORK/scan.pcd" --resolution 0
expect bad_values_leave_no_map_dir bash -c "test ! -e '$WORK/t_big' && test ! -e '$WORK/t_zero'"

# The same scan as .ply gives the same map.
check pcl_pcd2ply_scan 0 pcl_pcd2ply "$WORK/scan.pcd" "$WORK/scan.ply"
check map_ply 0 "$TOOL" map "$WORK/scan.ply" --resolution 0.2 --sensor lidar -o "$WORK/occupied2.ply"
n_ply=$(grep -a -m1 '^element vertex' "$WORK/occupied2.ply" | awk '{print $3}')
expect ply_input_same_count test "$n_ply" = "$n_pcd"

# An empty input gives an empty but valid output that the tools read back.
printf '# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 0\nHEIGHT 1\nPOINTS 0\nDATA ascii\n' >"$WORK/empty.pcd"
check map_empty 0 "$TOOL" map "$WORK/empty.pcd" -o "$WORK/empty_out.pcd"
check info_empty_output 0 "$TOOL" info "$WORK/empty_out.pcd"
expect empty_output_has_no_points grep -q ": cloud, 0 points" "$WORK/info_empty_output.out"
expect no_temporary_left bash -c "! ls -A '$WORK' | grep -q '^\.empty_out\.iwlomap-'"

# Mean hit positions and the multi-resolution max grids (pyramid).
check map_mean_positions 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --sensor lidar --mean-positions -o "$WORK/occupied_mean.pcd"
n_mean=$(grep -a -m1 '^POINTS' "$WORK/occupied_mean.pcd" | awk '{print $2}')
expect mean_positions_same_count test "${n_mean:-0}" = "$n_pcd"
# ... with every backend: the same voxels at the same mean positions (the statistics agree).
check map_mean_positions_disk 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --sensor lidar --mean-positions \
  --backend disk --tiles "$WORK/tiles_mean" -o "$WORK/occupied_mean_disk.pcd"
# (The backends list voxels in their own order: compare the points sorted, as ASCII.)
for f in occupied_mean occupied_mean_disk; do
  pcl_convert_pcd_ascii_binary "$WORK/$f.pcd" "$WORK/$f.ascii.pcd" 0 >/dev/null
  sed '1,/^DATA/d' "$WORK/$f.ascii.pcd" | sort >"$WORK/$f.sorted"
done
expect mean_positions_disk_same_points cmp -s "$WORK/occupied_mean.sorted" "$WORK/occupied_mean_disk.sorted"
# Colour: a wall at x = 2.05 m, red (200, 20, 10) below y = 0 and blue (10, 30, 220) above; every
# occupied voxel carries the mean colour of its hits (the two halves meet on a voxel face at 0.1 m).
{
  printf '# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity rgb\nSIZE 4 4 4 4 4\nTYPE F F F F U\nCOUNT 1 1 1 1 1\n'
  printf 'WIDTH 950\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 950\nDATA ascii\n'
  awk 'BEGIN { for (i = 0; i < 950; i++) { y = (i % 50) * 0.04 - 0.98; z = int(i / 50) * 0.05 - 0.45;
       printf "2.05 %.3f %.3f 100 %d\n", y, z, (y < 0 ? 200 * 65536 + 20 * 256 + 10 : 10 * 65536 + 30 * 256 + 220) } }'
} >"$WORK/colour_wall.pcd"
{
  printf 'ply\nformat ascii 1.0\nelement vertex 950\nproperty float x\nproperty float y\nproperty float z\n'
  printf 'property float intensity\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n'
  awk 'BEGIN { for (i = 0; i < 950; i++) { y = (i % 50) * 0.04 - 0.98; z = int(i / 50) * 0.05 - 0.45;
       printf "2.05 %.3f %.3f 100 %s\n", y, z, (y < 0 ? "200 20 10" : "10 30 220") } }'
} >"$WORK/colour_wall.ply"
check map_colour 0 "$TOOL" map "$WORK/colour_wall.pcd" --resolution 0.1 --sensor lidar -o "$WORK/colour_out.pcd"
expect map_colour_summary grep -Eq "occupied \(p > 0.7\), [0-9]+ of them coloured" "$WORK/map_colour.out"
expect map_colour_rgb_field grep -aq "^FIELDS x y z intensity rgb" "$WORK/colour_out.pcd"
pcl_convert_pcd_ascii_binary "$WORK/colour_out.pcd" "$WORK/colour_out.ascii.pcd" 0 >/dev/null
expect map_colour_means_by_half awk '/^DATA/ { data = 1; next } data { n++; want = ($2 < 0 ? 13112330 : 663260);
  if ($5 % 16777216 != want) bad++ } END { exit !(n > 100 && bad == 0) }' "$WORK/colour_out.ascii.pcd"
check map_colour_ply_in 0 "$TOOL" map "$WORK/colour_wall.ply" --resolution 0.1 --sensor lidar -o "$WORK/colour_from_ply.pcd"
expect map_colour_ply_same_colours same_voxels "$WORK/colour_out.pcd" "$WORK/colour_from_ply.pcd"
check map_colour_ply_out 0 "$TOOL" map "$WORK/colour_wall.pcd" --resolution 0.1 --sensor lidar -o "$WORK/colour_out.ply"
expect map_colour_ply_properties bash -c "head -c 400 '$WORK/colour_out.ply' | grep -aq 'property uchar red'"
check map_colour_off 0 "$TOOL" map "$WORK/colour_wall.pcd" --resolution 0.1 --sensor lidar --no-colors -o "$WORK/colour_off.pcd"
expect map_colour_off_no_field grep -aq "^FIELDS x y z intensity$" "$WORK/colour_off.pcd"
if has_layer viewer && [ -n "${DISPLAY:-}" ]; then
  printf '0 0 0 1.5 0 0 0 1\n1 2 1 1.5 0 0 0 1\n' > "$WORK/track.tum"
  check render_marks 0 "$TOOL" render "$WORK/occupied.pcd" --trajectory "$WORK/track.tum" --z-down --no-scale-bar -o "$WORK/marks.png"
  expect render_marks_png test -s "$WORK/marks.png"
  check render_bad_trajectory 1 "$TOOL" render "$WORK/occupied.pcd" --trajectory "$WORK/occupied.pcd" -o "$WORK/x.png"
  check render_rgb 0 "$TOOL" render "$WORK/colour_out.pcd" --color rgb -o "$WORK/colour.png"
  expect render_rgb_png test -s "$WORK/colour.png"
  check render_rgb_without_colours 1 "$TOOL" render "$WORK/occupied.pcd" --color rgb -o "$WORK/x.png"
  expect render_rgb_without_colours_says grep -q "has no rgb or rgba field" "$WORK/render_rgb_without_colours.err"
  check render_rgb_stored_map 2 "$TOOL" render "$WORK/tiles" --color rgb -o "$WORK/x.png"
  check map_colour_snapshot 0 "$TOOL" map "$WORK/colour_wall.pcd" --resolution 0.1 --sensor lidar --snapshot "$WORK/colour_snap.png"
  expect map_colour_snapshot_png test -s "$WORK/colour_snap.png"
fi

# Registration: the synthetic scan in its sensor frame (the scan's sensor is at (0, 0, 1.5), level)
# against the map of the same scene, from 0.36 m / 4 degrees off: the last line is the pose.
check help_register 0 "$TOOL" register --help
expect help_register_pose_line grep -q "pose x y z qw qx qy qz" "$WORK/help_register.out"
check reg_map 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --sensor lidar --mean-positions -o "$WORK/reg_map.pcd"
check reg_sensor_frame 0 pcl_transform_point_cloud "$WORK/scan.pcd" "$WORK/reg_sensor.pcd" -trans 0,0,-1.5
# --config FILE.yaml and --print-config: the printed configuration reads back to itself, a file
# maps as its options given on the command line do, the command line wins, bad files are refused.
check print_config 0 "$TOOL" map --sensor sonar --resolution 0.2 --intensity-threshold 20 --print-config
expect print_config_names_preset grep -qx "sensor: sonar" "$WORK/print_config.out"
cp "$WORK/print_config.out" "$WORK/config.yaml"
check print_config_roundtrip 0 "$TOOL" map --config "$WORK/config.yaml" --print-config
expect print_config_same bash -c "diff '$WORK/print_config.out' '$WORK/print_config_roundtrip.out'"
check map_from_config 0 "$TOOL" map "$WORK/scan.pcd" --config "$WORK/config.yaml" -o "$WORK/from_config.pcd"
check map_from_options 0 "$TOOL" map "$WORK/scan.pcd" --sensor sonar --resolution 0.2 --intensity-threshold 20 -o "$WORK/from_options.pcd"
expect map_config_same_output cmp "$WORK/from_config.pcd" "$WORK/from_options.pcd"
check config_command_line_wins 0 "$TOOL" map --config "$WORK/config.yaml" --resolution 0.3 --print-config
expect config_command_line_wins_says grep -qx "resolution: 0.3" "$WORK/config_command_line_wins.out"
printf 'resolution: 0.2\nbogus: 1\n' > "$WORK/bad_key.yaml"
check config_unknown_key 2 "$TOOL" map "$WORK/scan.pcd" --config "$WORK/bad_key.yaml"
expect config_unknown_key_says grep -q "bad_key.yaml' line 2: 'bogus' is not an option" "$WORK/config_unknown_key.err"
printf 'tiles: /tmp/x\n' > "$WORK/tiles_key.yaml"
check config_no_paths 2 "$TOOL" map "$WORK/scan.pcd" --config "$WORK/tiles_key.yaml"
printf 'no-adaptive: maybe\n' > "$WORK/bad_flag.yaml"
check config_flag_not_bool 2 "$TOOL" map "$WORK/scan.pcd" --config "$WORK/bad_flag.yaml"
printf 'resolution: [0.1, 0.2\n' > "$WORK/bad_yaml.yaml"
check config_not_yaml 2 "$TOOL" map "$WORK/scan.pcd" --config "$WORK/bad_yaml.yaml"
check config_missing 1 "$TOOL" map "$WORK/scan.pcd" --config "$WORK/no_such.yaml"
printf 'resolution: -1\n' > "$WORK/bad_value.yaml"
check config_bad_value 2 "$TOOL" map "$WORK/scan.pcd" --config "$WORK/bad_value.yaml"

# The map cloud records its resolution and kind: no --resolution needed, a different one refused.
expect reg_map_records_resolution grep -aqx "# iwlomap map resolution 0.2 positions means" "$WORK/reg_map.pcd"
check register 0 "$TOOL" register --map "$WORK/reg_map.pcd" --scan "$WORK/reg_sensor.pcd" --initial "0.3 -0.2 1.6 0 0 4"
expect register_last_line_is_the_pose bash -c "tail -n 1 '$WORK/register.out' | grep -Eq '^pose( -?[0-9.]+){7}$'"
expect register_reports grep -q "^converged yes" "$WORK/register.out"
expect register_finds_the_sensor awk '/^pose/ { d = sqrt($2 * $2 + $3 * $3 + ($4 - 1.5) ^ 2); exit !(d < 0.03 && $5 > 0.99999) }' "$WORK/register.out"
check register_resolution_differs 2 "$TOOL" register --map "$WORK/reg_map.pcd" --resolution 0.1 --scan "$WORK/reg_sensor.pcd"
expect register_resolution_differs_says grep -q "records a resolution of 0.2 m; --resolution 0.1 differs" "$WORK/register_resolution_differs.err"
LC_ALL=C sed 's/^# iwlomap map resolution 0.2 /# iwlomap map resolution 0.x /' "$WORK/reg_map.pcd" > "$WORK/reg_bad_comment.pcd"
check register_malformed_comment 1 "$TOOL" register --map "$WORK/reg_bad_comment.pcd" --scan "$WORK/reg_sensor.pcd"
expect register_malformed_comment_says grep -q "malformed map comment 'iwlomap map resolution 0.x positions means'" "$WORK/register_malformed_comment.err"
check reg_map_ply 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --sensor lidar --mean-positions -o "$WORK/reg_map.ply"
expect reg_map_ply_records_resolution grep -aqx "comment iwlomap map resolution 0.2 positions means" "$WORK/reg_map.ply"
check register_ply 0 "$TOOL" register --map "$WORK/reg_map.ply" --scan "$WORK/reg_sensor.pcd" --initial "0.3 -0.2 1.6 0 0 4"
expect register_ply_same_pose bash -c "diff <(tail -n 1 '$WORK/register.out') <(tail -n 1 '$WORK/register_ply.out')"
check register_far_off 1 "$TOOL" register --map "$WORK/reg_map.pcd" --scan "$WORK/reg_sensor.pcd" --initial "300 0 1.5 0 0 0"
expect register_far_off_says_why grep -q "not converged" "$WORK/register_far_off.err"
expect register_far_off_pose_line bash -c "tail -n 1 '$WORK/register_far_off.out' | grep -q '^pose 300'"
check register_bad_initial 2 "$TOOL" register --map "$WORK/reg_map.pcd" --scan "$WORK/reg_sensor.pcd" --initial "1 2 3"
check register_bad_window 2 "$TOOL" register --map "$WORK/reg_map.pcd" --scan "$WORK/reg_sensor.pcd" --window 0,0.5,10
check register_no_map 2 "$TOOL" register --scan "$WORK/reg_sensor.pcd"
check map_register 0 "$TOOL" map "$WORK/scan.pcd" "$WORK/scan.pcd" --resolution 0.2 --sensor lidar --register -o "$WORK/reg_twice.pcd"
expect map_register_summary grep -q "registered 1 of 2 file(s)" "$WORK/map_register.out"
check map_register_async 2 "$TOOL" map "$WORK/scan.pcd" --register --async
check map_loop_closure_needs_register 2 "$TOOL" map "$WORK/scan.pcd" --loop-closure
check map_write_poses_bad_extension 2 "$TOOL" map "$WORK/scan.pcd" --write-poses "$WORK/poses.csv"
check map_write_poses 0 "$TOOL" map "$WORK/scan.pcd" "$WORK/scan.pcd" --resolution 0.2 --write-poses "$WORK/plain.kitti"
expect map_write_poses_kitti awk 'END { exit !(NR == 2 && NF == 12) }' "$WORK/plain.kitti"
if has_layer slam; then
  # A small block driven once around (48 scans, 16-beam lidar), the navigation drifting 2 % and
  # 1 degree per 10 m: every file registers, the loop is closed, and the poses written end far
  # nearer the truth than the navigation.
  check generate_street_loop 0 "$TOOL" generate --street-loop "$WORK/loop" --block 70,50 --step 5 --rings 16 \
    --columns 360 --range 30 --drift 2,1
  expect generate_street_loop_files bash -c "ls '$WORK'/loop/scan_*.pcd | wc -l | grep -qx 48 && test -s '$WORK/loop/truth.tum'"
  check map_loop_closure 0 "$TOOL" map "$WORK"/loop/scan_*.pcd --sensor lidar --resolution 0.2 --max-range 30 \
    --register --loop-closure --write-poses "$WORK/loop_poses.tum" -o "$WORK/loop_map.pcd"
  expect map_loop_closure_summary grep -Eq "^loop closures: [0-9]+ searched, [1-9][0-9]* found" "$WORK/map_loop_closure.out"
  expect map_loop_closure_registered grep -Eq "^registered (4[6-8]) of 48 file" "$WORK/map_loop_closure.out"
  # Position error at the end of the loop (the last pose) against the truth, and the navigation's.
  expect map_loop_closure_poses bash -c "paste -d' ' '$WORK/loop_poses.tum' '$WORK/loop/truth.tum' '$WORK/loop/navigation.tum' | \
    awk 'END { e = sqrt((\$2-\$10)^2 + (\$3-\$11)^2); n = sqrt((\$18-\$10)^2 + (\$19-\$11)^2); exit !(NR == 48 && e < 0.2 && n > 3) }'"
fi

# Any tile size: 10 m at 0.1 m is 12.5 blocks, rounded to 13 (10.4 m), reported by info.
check map_disk_default_tile 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.1 --sensor lidar --backend disk \
  --tiles "$WORK/tiles_01" -o "$WORK/occupied_disk01.pcd"
check info_disk_tile_size 0 "$TOOL" info "$WORK/tiles_01"
expect info_shows_effective_tile grep -q "of 10.4 m" "$WORK/info_disk_tile_size.out"
check help_pyramid 0 "$TOOL" pyramid --help
check pyramid 0 "$TOOL" pyramid "$WORK/occupied.pcd" --resolution 0.2 --levels 3 -o "$WORK/pyramid"
expect pyramid_files bash -c "for k in 0 1 2; do test -s '$WORK/pyramid/level_'\$k'.png' && test -s '$WORK/pyramid/level_'\$k'.txt' || exit 1; done"
expect pyramid_png_signature bash -c "head -c 8 '$WORK/pyramid/level_2.png' | od -An -tx1 | grep -q '89 50 4e 47 0d 0a 1a 0a'"
expect pyramid_txt_header bash -c "head -1 '$WORK/pyramid/level_2.txt' | grep -Eq '^[0-9]+ [0-9]+$'"
check pyramid_needs_resolution 2 "$TOOL" pyramid "$WORK/occupied.pcd" -o "$WORK/pyramid_x"
check pyramid_refuses_raw_scan 1 "$TOOL" pyramid "$WORK/scan.pcd" --resolution 0.2 -o "$WORK/pyramid_y"

# Errors: bad usage exits 2, failures exit 1, each with one line on stderr.
check missing_input 1 "$TOOL" map "$WORK/does_not_exist.pcd" -o "$WORK/x.pcd"
expect missing_input_one_line one_line missing_input
expect missing_input_names_file grep -q "does_not_exist.pcd" "$WORK/missing_input.err"
check no_input 2 "$TOOL" map -o "$WORK/x.pcd"
check bad_number 2 "$TOOL" map "$WORK/scan.pcd" --resolution abc
expect bad_number_one_line one_line bad_number
check bad_option 2 "$TOOL" map "$WORK/scan.pcd" --frobnicate
check bad_param 2 "$TOOL" map "$WORK/scan.pcd" --min-alpha 0
expect bad_param_names_value grep -q "min_alpha" "$WORK/bad_param.err"
check bad_sensor 2 "$TOOL" map "$WORK/scan.pcd" --sensor radar
check bad_output_ext 2 "$TOOL" map "$WORK/scan.pcd" -o "$WORK/out.txt"
check disk_without_tiles 2 "$TOOL" map "$WORK/scan.pcd" --backend disk
check garbage_input 1 bash -c "echo garbage > '$WORK/garbage.pcd' && '$TOOL' map '$WORK/garbage.pcd'"
check unwritable_output 1 "$TOOL" map "$WORK/scan.pcd" --resolution 0.5 -o "/nonexistent-dir/x.pcd"
expect no_output_written test ! -e "$WORK/x.pcd"

# Outputs are checked before any work: no map directory is created, the answer comes at once,
# in one line naming the path.
started_ns=$(date +%s%N)
check unwritable_before_work 1 "$TOOL" map "$WORK/scan.pcd" --backend disk --tiles "$WORK/tiles_never" -o "/nonexistent-dir/y.pcd"
elapsed_ms=$(( ($(date +%s%N) - started_ns) / 1000000 ))
expect unwritable_under_a_second test "$elapsed_ms" -lt 1000
expect unwritable_no_work_done test ! -e "$WORK/tiles_never"
expect unwritable_one_line one_line unwritable_before_work
expect unwritable_names_path grep -q "/nonexistent-dir/y.pcd" "$WORK/unwritable_before_work.err"
mkdir -p "$WORK/a_folder.pcd"
check output_is_folder 1 "$TOOL" map "$WORK/scan.pcd" -o "$WORK/a_folder.pcd"
expect output_is_folder_says_so grep -q "is a folder" "$WORK/output_is_folder.err"
check max_range_zero 2 "$TOOL" map "$WORK/scan.pcd" --max-range 0 -o "$WORK/never.pcd"
expect max_range_zero_says_so grep -q -- "--max-range must be > 0" "$WORK/max_range_zero.err"
check max_range_negative 2 "$TOOL" map "$WORK/scan.pcd" --max-range -1 -o "$WORK/never.pcd"
check max_range_none 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --max-range none -o "$WORK/max_range_none.pcd"
check max_range_default 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 -o "$WORK/max_range_default.pcd"
expect max_range_none_is_no_limit cmp -s "$WORK/max_range_none.pcd" "$WORK/max_range_default.pcd"
# --rays: exact is the default; fast maps; a wrong value, or --rays with --no-rays, is refused.
check rays_exact 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --rays exact -o "$WORK/rays_exact.pcd"
expect rays_exact_is_the_default cmp -s "$WORK/rays_exact.pcd" "$WORK/max_range_default.pcd"
check rays_fast 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --rays fast -o "$WORK/rays_fast.pcd"
expect rays_fast_writes_voxels test -s "$WORK/rays_fast.pcd"
check rays_unknown 2 "$TOOL" map "$WORK/scan.pcd" --rays quick -o "$WORK/never.pcd"
expect rays_unknown_says_so grep -q -- "--rays must be exact or fast, got 'quick'" "$WORK/rays_unknown.err"
check rays_without_rays 2 "$TOOL" map "$WORK/scan.pcd" --rays fast --no-rays -o "$WORK/never.pcd"
check rays_print_config 0 "$TOOL" map --rays fast --print-config
expect rays_print_config_says_fast grep -qx "rays: fast" "$WORK/rays_print_config.out"
# The configuration of a run without rays reads back (it names the default ray model).
check no_rays_print_config 0 "$TOOL" map --no-rays --print-config
cp "$WORK/no_rays_print_config.out" "$WORK/no_rays.yaml"
check no_rays_config_reads_back 0 "$TOOL" map --config "$WORK/no_rays.yaml" --print-config
check same_output_twice 2 "$TOOL" map "$WORK/scan.pcd" -o "$WORK/twice.pcd" --snapshot "$WORK/./twice.pcd"
# An output never replaces an input: the same path, a symbolic link to it or a hard link of it is
# refused before any work and the input is left as it was.
cp "$WORK/scan.pcd" "$WORK/precious.pcd"
precious_sum=$(md5sum <"$WORK/precious.pcd")
check output_is_input 2 "$TOOL" map "$WORK/precious.pcd" --resolution 0.2 -o "$WORK/precious.pcd"
expect output_is_input_says_so grep -q "may not replace an input" "$WORK/output_is_input.err"
expect output_is_input_one_line one_line output_is_input
ln -sf precious.pcd "$WORK/link_to_precious.pcd"
check output_is_input_by_symlink 2 "$TOOL" map "$WORK/precious.pcd" --resolution 0.2 -o "$WORK/link_to_precious.pcd"
ln -f "$WORK/precious.pcd" "$WORK/hard_link_of_precious.pcd"
check output_is_input_by_hard_link 2 "$TOOL" map "$WORK/hard_link_of_precious.pcd" --resolution 0.2 \
  --snapshot "$WORK/snap_never.png" -o "$WORK/precious.pcd"
expect output_is_input_kept test "$(md5sum <"$WORK/precious.pcd")" = "$precious_sum"
expect output_is_input_no_other_output test ! -e "$WORK/snap_never.png"
# All or nothing: when one output fails (here OctoMap cannot hold a voxel 9 km out), none is left.
printf '# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n1 1 1 200\n9000 0 0 200\n' >"$WORK/far.pcd"
if has_layer octomap; then
  rm -f "$WORK"/far_out.* "$WORK"/.far_out.*
  check far_point_outputs 1 "$TOOL" map "$WORK/far.pcd" --resolution 0.2 --sensor lidar -o "$WORK/far_out.pcd" --octomap "$WORK/far_out.bt"
  expect far_point_no_cloud_left test ! -e "$WORK/far_out.pcd"
  expect far_point_no_octomap_left test ! -e "$WORK/far_out.bt"
  expect far_point_no_temporaries bash -c "! ls -A '$WORK' | grep -q '^\.far_out'"
  expect far_point_one_line one_line far_point_outputs
  # The message names the target, never a temporary (.far_out.iwlomap-PID-N...): matched on the
  # temporary's own form, so a checkout under a folder named iwlomap-... does not trip it.
  expect far_point_names_target bash -c "grep -q \"'$WORK/far_out.bt'\" '$WORK/far_point_outputs.err' && ! grep -q '\.far_out\.iwlomap-[0-9]' '$WORK/far_point_outputs.err'"
fi
# A truncated file fails in one line of the tool's own (no reader chatter).
head -c 2000 "$WORK/scan.pcd" >"$WORK/truncated.pcd"
check truncated_input 1 "$TOOL" map "$WORK/truncated.pcd" -o "$WORK/trunc_out.pcd"
expect truncated_input_one_line one_line truncated_input
expect truncated_input_names_file grep -q "truncated.pcd" "$WORK/truncated_input.err"
expect truncated_no_output test ! -e "$WORK/trunc_out.pcd"
# Hostile input: every malformed cloud fails with exit 1 and one line naming the file (and what is
# wrong), within seconds: no crash, hang or huge allocation inside PCL's readers.
pcd() {  # pcd FILE SIZE TYPE COUNT WIDTH VIEWPOINT DATA [BODY]
  printf '# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE %s\nTYPE %s\nCOUNT %s\nWIDTH %s\nHEIGHT 1\nVIEWPOINT %s\nPOINTS %s\nDATA %s\n' \
    "$2" "$3" "$4" "$5" "$6" "$5" "$7" >"$WORK/$1"
  if [ $# -ge 8 ]; then printf '%b' "$8" >>"$WORK/$1"; fi
}
hostile() {  # hostile NAME WORD-IN-ERROR: info on $WORK/NAME fails in one line naming it and WORD
  check "hostile_$1" 1 timeout 20 "$TOOL" info "$WORK/$1"
  expect "hostile_${1}_one_line" one_line "hostile_$1"
  expect "hostile_${1}_names_file" grep -q "$1" "$WORK/hostile_$1.err"
  expect "hostile_${1}_says_$2" grep -q -- "$2" "$WORK/hostile_$1.err"
}
F4="F F F F"; V="0 0 0 1 0 0 0"
pcd count_negative_ascii.pcd "4 4 4 4" "$F4" "-1 1 1 1" 1 "$V" ascii '1 2 3 4\n'
hostile count_negative_ascii.pcd COUNT
pcd count_negative_binary.pcd "4 4 4 4" "$F4" "-1 1 1 1" 1 "$V" binary '0123456789abcdef'
hostile count_negative_binary.pcd COUNT
pcd size_huge.pcd "4 4 4 4000000000" "$F4" "1 1 1 1" 1 "$V" binary '0123456789abcdef'
hostile size_huge.pcd SIZE
pcd size_negative.pcd "-4 4 4 4" "$F4" "1 1 1 1" 1 "$V" binary '0123456789abcdef'
hostile size_negative.pcd SIZE
pcd count_2_31.pcd "4 4 4 4" "$F4" "1 1 1 2147483648" 1 "$V" binary '0123456789abcdef'
hostile count_2_31.pcd COUNT
pcd body_short.pcd "4 4 4 4" "$F4" "1 1 1 1" 100000 "$V" binary '0123456789abcdef'
hostile body_short.pcd truncated
pcd compressed_lies.pcd "4 4 4 4" "$F4" "1 1 1 1" 1000 "$V" binary_compressed '\x10\x00\x00\x00\xff\xff\xff\x7f0123456789abcdef'
hostile compressed_lies.pcd compressed
pcd viewpoint_nan.pcd "4 4 4 4" "$F4" "1 1 1 1" 1 "nan 0 0 1 0 0 0" ascii '1 2 3 4\n'
hostile viewpoint_nan.pcd VIEWPOINT
# A header line inside the binary body, which PCL's parser reads as the header's (found by fuzzing).
pcd header_in_body.pcd "4 4 4 4" "$F4" "1 1 1 1" 3 "$V" binary 'COLUMNS@\x00\x00@@\x00!.P\x01ply\nformat ascii 0.4\nelem\x00\x00\x00\x00\x00\x00ent vertex'
hostile header_in_body.pcd "take as a COLUMNS header line"
pcd data_word_in_body.pcd "4 4 4 4" "$F4" "1 1 1 1" 3 "$V" binary 'COUNT 1 1 1 1\nDATA\nxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx'
hostile data_word_in_body.pcd "take as a COUNT header line"
pcd width_in_body.pcd "4 4 4 4" "$F4" "1 1 1 1" 3 "$V" binary '\nWIDTH 1000000000\nxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx'
hostile width_in_body.pcd "take as a WIDTH header line"
printf '# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 5\n' >"$WORK/header_truncated.pcd"
hostile header_truncated.pcd DATA
printf 'ply\nformat binary_little_endian 1.0\nelement vertex 4294967296\nproperty float x\nproperty float y\nproperty float z\nend_header\n0123456789ab' >"$WORK/vertex_huge.ply"
hostile vertex_huge.ply vertex
# Strict rows and headers: PCL's reader would take these as zeros, partial numbers or the last of
# two header lines, with exit code 0. The error names the line and the field.
pcd ascii_short_row.pcd "4 4 4 4" "$F4" "1 1 1 1" 2 "$V" ascii '1 2 3 4\n4 5\n'
hostile ascii_short_row.pcd "line 13: 2 values, but the header declares 4"
pcd ascii_six_values.pcd "4 4 4 4" "$F4" "1 1 1 1" 1 "$V" ascii '1 2 3 4 5 6\n'
hostile ascii_six_values.pcd "line 12: 6 values"
pcd ascii_word.pcd "4 4 4 4" "$F4" "1 1 1 1" 1 "$V" ascii 'abc 2 3 100\n'
hostile ascii_word.pcd "field 'x' holds 'abc', not a number"
pcd ascii_comma.pcd "4 4 4 4" "$F4" "1 1 1 1" 1 "$V" ascii '1 1,5 3 100\n'
hostile ascii_comma.pcd "field 'y' holds '1,5'"
pcd ascii_suffix.pcd "4 4 4 4" "$F4" "1 1 1 1" 1 "$V" ascii '1 2 1.5abc 100\n'
hostile ascii_suffix.pcd "field 'z' holds '1.5abc'"
pcd ascii_byte_range.pcd "4 4 4 1" "F F F U" "1 1 1 1" 1 "$V" ascii '1 2 3 300\n'
hostile ascii_byte_range.pcd "not an unsigned integer of 1 byte"
pcd ascii_extra_row.pcd "4 4 4 4" "$F4" "1 1 1 1" 1 "$V" ascii '1 2 3 4\n5 6 7 8\n'
hostile ascii_extra_row.pcd "line 13: a row after the 1 points"
pcd binary_long.pcd "4 4 4 4" "$F4" "1 1 1 1" 1 "$V" binary '0123456789abcdef0123'
hostile binary_long.pcd "4 bytes more"
printf '# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nFIELDS y x z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3 4\n' >"$WORK/fields_twice.pcd"
hostile fields_twice.pcd "line 4: a second FIELDS line (the first is line 3)"
printf '# .PCD v0.7\nVERSION 0.7\nFIELDS x y z z\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3 4\n' >"$WORK/field_named_twice.pcd"
hostile field_named_twice.pcd "FIELDS lists 'z' twice"
# What PCL writes in ASCII is read: nan, exponents, signs, a last row without its newline.
pcd ascii_pcl_forms.pcd "4 4 4 4" "$F4" "1 1 1 1" 3 "$V" ascii '1 2 3 4\nnan nan nan 0\n-1.5e+00 2E1 +3 7'
check ascii_pcl_forms 0 "$TOOL" info "$WORK/ascii_pcl_forms.pcd"
mkdir -p "$WORK/a_folder_named.pcd"
check hostile_folder 1 timeout 20 "$TOOL" map "$WORK/a_folder_named.pcd"
expect hostile_folder_one_line one_line hostile_folder
# Any numeric field type is converted, not zeroed: doubles, 16-bit unsigned intensity.
pcd doubles.pcd "8 8 8 2" "F F F U" "1 1 1 1" 2 "$V" ascii '1.5 -2.25 3.125 300\n2.5 -1.25 4.125 700\n'
check doubles_read 0 "$TOOL" info "$WORK/doubles.pcd"
expect doubles_bounds grep -q "x \[1.5, 2.5\] y \[-2.25, -1.25\] z \[3.125, 4.125\]" "$WORK/doubles_read.out"
expect doubles_intensity grep -q "intensity: \[300, 700\]" "$WORK/doubles_read.out"

# Sensor presets: `map` maps a lidar cloud with the lidar preset unless told otherwise; a cloud
# whose intensities are all 0 maps to nothing with the sonar preset, with one warning naming the
# lidar preset; with --sensor lidar every return is a hit.
check map_default_preset 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 -o "$WORK/default_preset.pcd"
check map_lidar_preset 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --sensor lidar -o "$WORK/lidar_preset.pcd"
expect map_default_is_lidar bash -c "grep -q 'lidar preset' '$WORK/map_default_preset.out' && cmp -s '$WORK/default_preset.pcd' '$WORK/lidar_preset.pcd'"
pcd zeros.pcd "4 4 4 4" "$F4" "1 1 1 1" 400 "0.05 0.05 0.05 1 0 0 0" ascii
awk 'BEGIN { for (i = 0; i < 400; i++) printf "3.0 %.3f %.3f 0\n", (i % 20) * 0.1 - 1.0, int(i / 20) * 0.1 - 1.0 }' >>"$WORK/zeros.pcd"
check zeros_sonar 0 "$TOOL" map "$WORK/zeros.pcd" "$WORK/zeros.pcd" --resolution 0.2 --sensor sonar -o "$WORK/zeros_sonar.pcd"
expect zeros_sonar_warns_once bash -c "test \$(grep -c 'warning: .*--sensor lidar' '$WORK/zeros_sonar.err') = 1"
expect zeros_sonar_names_preset grep -q "sonar preset: .* 0 occupied" "$WORK/zeros_sonar.out"
check zeros_lidar 0 "$TOOL" map "$WORK/zeros.pcd" --resolution 0.2 --sensor lidar -o "$WORK/zeros_lidar.pcd"
expect zeros_lidar_no_warning test ! -s "$WORK/zeros_lidar.err"
expect zeros_lidar_maps bash -c "grep -q 'lidar preset: .* [1-9][0-9]* occupied' '$WORK/zeros_lidar.out'"
check zeros_depth 0 "$TOOL" map "$WORK/zeros.pcd" --resolution 0.2 --sensor depth
expect zeros_depth_maps bash -c "grep -q 'depth preset: .* [1-9][0-9]* occupied' '$WORK/zeros_depth.out'"

# A full disk (a 4 KiB file size limit, SIGXFSZ ignored so writes fail with EFBIG): the run fails
# in one line, and neither the output nor a temporary is left, for .ply as for .pcd.
for ext in ply pcd; do
  check "full_disk_$ext" 1 bash -c "trap '' XFSZ; ulimit -f 4; exec '$TOOL' map '$WORK/scan.pcd' --resolution 0.2 --sensor lidar -q -o '$WORK/full_out.$ext'"
  expect "full_disk_${ext}_one_line" one_line "full_disk_$ext"
  expect "full_disk_${ext}_no_output" test ! -e "$WORK/full_out.$ext"
  expect "full_disk_${ext}_no_temporaries" bash -c "! ls -A '$WORK' | grep -q '^\.full_out'"
done

# Memory: a stray return 1,000 km out is skipped with one warning, not cast across millions of
# voxels; a resolution far too fine for the cloud stops with the memory error naming what to
# change, before the map takes the machine; --max-memory is parsed strictly.
pcd outlier.pcd "4 4 4 4" "$F4" "1 1 1 1" 401 "0.05 0.05 0.05 1 0 0 0" ascii
awk 'BEGIN { for (i = 0; i < 400; i++) printf "3.0 %.3f %.3f 200\n", (i % 20) * 0.1 - 1.0, int(i / 20) * 0.1 - 1.0; print "1000000 3 1 200" }' >>"$WORK/outlier.pcd"
check outlier_skipped 0 timeout 60 "$TOOL" map "$WORK/outlier.pcd" --resolution 0.05 -o "$WORK/outlier_out.pcd"
expect outlier_warns_once bash -c "test \$(grep -c 'warning: 1 of 401 points skipped.*from the sensor origin' '$WORK/outlier_skipped.err') = 1"
expect outlier_counted grep -q "401 points (1 skipped)" "$WORK/outlier_skipped.out"
check too_fine_limited 1 timeout 120 "$TOOL" map "$WORK/outlier.pcd" --resolution 0.0002 --max-memory 256M
expect too_fine_one_line one_line too_fine_limited
expect too_fine_says_what_to_change grep -q "memory limit of 256.0 MiB.*--resolution, --max-range, --max-memory" "$WORK/too_fine_limited.err"
if [ -z "${IWLOMAP_TOOL_SANITIZED:-}" ]; then
  # Under a cap on the address space, the default limit stays below it: the same error, not
  # std::bad_alloc. (Sanitizers reserve more address space than any cap leaves.)
  check too_fine_ulimit 1 bash -c "ulimit -v 2000000 && exec timeout 120 '$TOOL' map '$WORK/outlier.pcd' --resolution 0.0002"
  expect too_fine_ulimit_one_line one_line too_fine_ulimit
  expect too_fine_ulimit_memory_error bash -c "grep -q 'past the map memory limit' '$WORK/too_fine_ulimit.err' && ! grep -q bad_alloc '$WORK/too_fine_ulimit.err'"
  check pyramid_levels_beyond_memory 1 bash -c "ulimit -v 2000000 && exec '$TOOL' pyramid '$WORK/tiles' --levels 16 -o '$WORK/pyramid_16'"
  expect pyramid_levels_beyond_memory_says_so grep -q "give fewer --levels" "$WORK/pyramid_levels_beyond_memory.err"
  expect pyramid_levels_beyond_memory_leaves_nothing test ! -e "$WORK/pyramid_16"
fi
for bad in 12Q 0 -5 1.5G 99999999999999999999 16E; do
  check "max_memory_bad_$bad" 2 "$TOOL" map "$WORK/outlier.pcd" --max-memory "$bad"
done
check max_memory_none 0 "$TOOL" map "$WORK/outlier.pcd" --resolution 0.1 --max-memory none -q
check max_memory_suffix 0 "$TOOL" map "$WORK/outlier.pcd" --resolution 0.1 --max-memory 64m -q

check version 0 "$TOOL" --version
expect version_line grep -Eq '^iwlomap [0-9]+[.][0-9]+[.][0-9]+ [(]layers: core' "$WORK/version.out"
# The progress bar in an 80-column terminal: drawn, and no line of it reaches the last column
# (which would wrap and scroll), even with a file name longer than the terminal.
long_name="$WORK/a_scan_file_with_a_rather_long_name_that_cannot_fit_beside_the_progress_bar.pcd"
cp "$WORK/scan.pcd" "$long_name"
check progress_pty 0 script -qec "stty cols 80 rows 24; '$TOOL' map '$long_name' '$long_name' --resolution 0.2 --sensor lidar" /dev/null
expect progress_drawn grep -aq "mapping \[" "$WORK/progress_pty.out"
expect progress_fits_80_columns bash -c "tr '\r' '\n' <'$WORK/progress_pty.out' | sed 's/\x1b\[K//g' | grep -a 'mapping \[' | awk 'length(\$0) > 79 { bad = 1 } END { exit bad }'"
check progress_not_in_pipe 0 "$TOOL" map "$WORK/scan.pcd" --resolution 0.2 --sensor lidar
expect progress_not_in_pipe_quiet bash -c "! grep -q 'mapping \[' '$WORK/progress_not_in_pipe.err'"

echo "tool: $passed passed, $failed failed"
echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ]
