# SPDX-License-Identifier: BSD-3-Clause
"""The bound classes and methods of the core and the OctoMap layer, against each other and against
hand-computed values."""

import threading
import time

import numpy as np
import pytest

import iwlomap
from conftest import voxel_table

LIDAR = iwlomap.sensor_preset_params(iwlomap.SensorPreset.kLidar)


def lidar_map(resolution=0.2):
    m = iwlomap.ProbabilityUpdater(resolution)
    m.set_params(LIDAR)
    return m


def test_the_package_ships_no_benchmark_hook():
    # The timing hook of benchmarks/bench_python.py is a module of its own (_iwlomap_bench).
    assert not hasattr(iwlomap._iwlomap, "_bench")
    assert not any(name.startswith("_bench") for name in dir(iwlomap))


def test_params_have_the_reference_defaults_and_keywords():
    p = iwlomap.IwloParams()
    assert (p.sharpness, p.decay_rate, p.min_alpha, p.L_min, p.L_max) == (0.1, 0.1, 0.3, -10.0, 10.0)
    assert (p.log_odds_occupied, p.log_odds_free, p.intensity_threshold, p.intensity_max) == (3.5, -3.0, 35.0, 255.0)
    assert p.adaptive_enabled and (p.adaptive_threshold, p.adaptive_max_ratio, p.occupied_threshold) == (0.5, 0.3, 0.7)
    q = iwlomap.IwloParams(sharpness=2.0, L_min=-2.0)
    assert q.sharpness == 2.0 and q.L_min == -2.0 and q.L_max == 10.0
    assert "sharpness=2.0" in repr(q)
    assert iwlomap.IwloParams() == iwlomap.IwloParams()
    with pytest.raises(TypeError):
        iwlomap.IwloParams(0.5)  # keyword arguments only
    bad = iwlomap.IwloParams(min_alpha=0.0)
    with pytest.raises(ValueError, match="min_alpha"):
        bad.validate()


def test_formulas_match_hand_computed_values():
    assert iwlomap.iwlo.probability(0.0) == 0.5
    assert iwlomap.iwlo.log_odds(0.5) == 0.0
    assert iwlomap.iwlo.probability(np.log(3.0)) == pytest.approx(0.75, abs=1e-15)
    p = iwlomap.IwloParams(adaptive_enabled=False)
    # A hit of intensity 255 on a fresh voxel: L = alpha(1) * w * L_occ, with u = (I - I_th) / (I_max - I_th)
    # = 1, w = 1 / (1 + exp(-sharpness (u - 0.5))) and alpha(n) = max(min_alpha, 1 / (1 + decay (n - 1))) = 1.
    w = 1.0 / (1.0 + np.exp(-0.1 * 0.5))
    alpha = 1.0
    assert iwlomap.iwlo.intensity_weight(255.0, p) == pytest.approx(w, rel=1e-12)
    assert iwlomap.iwlo.learning_rate(1, p) == pytest.approx(alpha, rel=1e-12)
    assert iwlomap.iwlo.step(0.0, 1, 255.0, True, 1.0, p) == pytest.approx(alpha * w * 3.5, rel=1e-12)
    assert iwlomap.iwlo.is_occupied_observation(True, 36.0, p)
    assert not iwlomap.iwlo.is_occupied_observation(True, 35.0, p)
    assert iwlomap.iwlo.MAX_COUNT == 65535
    # The map's voxels: 24-bit log-odds in steps of 2^-19, 8-bit counts with the defaults.
    f = iwlomap.iwlo.voxel_format(p)
    assert (f.count_bits, f.fraction_bits, f.max_count, f.step) == (8, 19, 255, 2.0 ** -19)
    stored = iwlomap.iwlo.step(0.0, 1, 255.0, True, 1.0, p)
    assert f.quantize(stored) == round(stored * 2 ** 19) / 2 ** 19
    m = iwlomap.ProbabilityUpdater(0.1)
    m.batch_update_iwlo(np.array([[0.05, 0.05, 0.05]]), np.array([255.0]), [True])
    assert m.query([0.05, 0.05, 0.05]).log_odds == f.quantize(stored)
    slow = iwlomap.IwloParams()
    slow.decay_rate = 0.001
    assert iwlomap.iwlo.voxel_format(slow).max_count == 4095


def test_presets_and_intensity_check():
    assert iwlomap.parse_sensor_preset("lidar") == iwlomap.SensorPreset.kLidar
    assert iwlomap.parse_sensor_preset("radar") is None
    assert iwlomap.sensor_preset_name(iwlomap.SensorPreset.kDepthCamera) == "depth"
    assert iwlomap.sensor_preset_params(iwlomap.SensorPreset.kSonar) == iwlomap.IwloParams()
    check = iwlomap.check_intensities(np.zeros(100), iwlomap.IwloParams())
    assert check.points == 100 and check.at_or_below_threshold == 100 and check.all_equal and check.thins_map()
    assert "lidar" in check.advice()


def test_keys_and_rays():
    k = iwlomap.world_to_key(np.array([0.25, -0.05, 1.0]), 0.1)
    assert (k.x, k.y, k.z) == (2, -1, 10)
    assert np.allclose(iwlomap.key_to_center(k, 0.1), [0.25, -0.05, 1.05])
    keys = iwlomap.cast_ray([0.05, 0.05, 0.05], [0.55, 0.05, 0.05], 0.1)
    assert keys.tolist() == [[i, 0, 0] for i in range(5)]
    box = iwlomap.VoxelBox.from_world([0, 0, 0], [0.95, 0.45, 0.15], 0.1)
    assert box.num_voxels() == 10 * 5 * 2 and box.contains(iwlomap.VoxelKey(9, 4, 1))


def backends(tmp_path, resolution=0.2):
    made = [iwlomap.ProbabilityUpdater(resolution),
            iwlomap.OutofcoreTileMapper(tmp_path / "disk", resolution, 6.4, 2),
            iwlomap.make_backend("RAM", resolution),
            iwlomap.make_backend("Disk", resolution, iwlomap.BackendOptions(directory=str(tmp_path / "disk2")))]
    if iwlomap.HAS_OCTOMAP:
        made += [iwlomap.OctreeMapper(resolution), iwlomap.make_backend("OctoMap", resolution)]
    return made


def test_every_backend_gives_the_same_map_bit_for_bit(tmp_path, scan):
    origin, points, intensities = scan
    tables = []
    for m in backends(tmp_path):
        m.set_params(LIDAR)
        m.insert_scan(origin, points, intensities, 30.0)
        m.batch_update_iwlo(points[:500], intensities[:500], np.ones(500, bool), np.full(500, 0.5))
        tables.append(voxel_table(m))
    assert len(tables[0]) > 10000
    for t in tables[1:]:
        assert np.array_equal(t, tables[0])
    assert sorted(iwlomap.available_backends())[:2] == ["Disk", "OctoMap"] or "RAM" in iwlomap.available_backends()


def test_backend_interface_methods(tmp_path, scan):
    origin, points, intensities = scan
    m = lidar_map()
    m.insert_scan(origin, points, intensities)
    occupied = m.get_occupied_voxels(0.7)
    assert occupied.shape[1] == 4 and occupied.dtype == np.float64 and occupied.flags.c_contiguous
    assert (occupied[:, 3] > 0.7).all()
    assert m.get_resolution() == 0.2 and m.get_backend_type() == "RAM"
    assert m.get_num_known_voxels() == len(m.get_voxels()[2])
    seen = []
    m.for_each_voxel(lambda k, s: seen.append((k.x, k.y, k.z, s.log_odds, s.count)))
    assert len(seen) == m.get_num_known_voxels()
    state = m.query(occupied[0, :3])
    assert state.probability == pytest.approx(occupied[0, 3]) and state.count >= 1
    assert m.query([1e3, 1e3, 1e3]) is None
    usage = m.get_memory_usage()
    assert usage.num_nodes == m.get_num_known_voxels() and usage.memory_mb > 0
    assert m.supports(iwlomap.BackendFeature.kClone) and not m.supports_persistence()
    c = m.clone()
    assert np.array_equal(voxel_table(c), voxel_table(m))
    assert m.get_params() == LIDAR
    m.set_occupied_threshold(0.8)
    assert m.get_params().occupied_threshold == 0.8
    m.set_iwlo_params(0.2, 0.1, 0.3, -2.0, 3.5)
    m.set_log_odds_params(3.0, -1.0)
    m.set_intensity_params(10.0, 200.0)
    m.set_adaptive_params(False, 0.5, 0.3)
    p = m.get_params()
    assert (p.sharpness, p.log_odds_free, p.intensity_max, p.adaptive_enabled) == (0.2, -1.0, 200.0, False)
    m.set_log_odds(np.array([[5.0, 5.0, 5.0]]), np.array([2.0]))
    assert m.query([5.0, 5.0, 5.0]).log_odds == pytest.approx(2.0)
    m.set_num_threads(2)
    assert m.get_num_threads() == 2
    assert m.prune() >= 0
    m.flush()
    m.preload_region([0, 0, 0], [1, 1, 1])
    assert m.get_disk_usage() == 0
    m.clear()
    assert m.get_num_known_voxels() == 0


def test_threads_give_the_same_map(scan):
    origin, points, intensities = scan
    one, two = lidar_map(), lidar_map()
    two.set_num_threads(2)
    one.insert_scan(origin, points, intensities)
    two.insert_scan(origin, points, intensities)
    assert np.array_equal(voxel_table(one), voxel_table(two))


def test_fast_rays_mark_the_line_of_cast_ray(scan):
    origin, points, intensities = scan
    exact, fast = lidar_map(), lidar_map()
    assert exact.get_ray_model() == iwlomap.RayModel.kExact
    fast.set_ray_model(iwlomap.RayModel.kFast)
    assert fast.get_ray_model() == iwlomap.RayModel.kFast
    exact.insert_scan(origin, points, intensities)
    fast.insert_scan(origin, points, intensities)
    assert 0 < fast.get_num_known_voxels() < exact.get_num_known_voxels()
    # The free voxels of one ray are cast_ray's keys under the same model.
    one = lidar_map()
    one.set_ray_model(iwlomap.RayModel.kFast)
    end = np.array([[3.05, 2.15, 1.25]])
    one.insert_scan([0.05, 0.05, 0.05], end, np.array([200.0]))
    r = one.get_resolution()
    keys = iwlomap.cast_ray([0.05, 0.05, 0.05], end[0], r, iwlomap.RayModel.kFast)
    assert len(keys) < len(iwlomap.cast_ray([0.05, 0.05, 0.05], end[0], r))
    assert one.get_num_known_voxels() == len(keys) + 1  # the line and the hit
    for k in keys:
        assert one.query(iwlomap.key_to_center(iwlomap.VoxelKey(*map(int, k)), r)).log_odds < 0


def test_last_scan_phases_say_where_the_time_went(scan):
    origin, points, intensities = scan
    m = lidar_map()
    assert m.get_last_scan_phases().total == 0.0  # no scan yet
    m.set_num_threads(2)
    m.insert_scan(origin, points, intensities)
    p = m.get_last_scan_phases()
    assert p.threads == 2
    assert p.total > 0 and p.casting_rays > 0 and p.updating > 0 and p.allocating > 0
    assert p.casting_rays + p.merging + p.allocating + p.preparing + p.updating <= p.total * (1 + 1e-9)
    assert abs(p.serial() + p.casting_rays + p.preparing + p.updating - p.total) < 1e-9
    s = p.serial_share()
    assert 0 <= s < 1
    assert abs(p.amdahl_speedup(16) - 1 / (s + (1 - s) / 16)) < 1e-12


def test_hit_statistics_and_mean_positions(scan):
    origin, points, intensities = scan
    m = lidar_map()
    m.set_hit_accumulation(True)
    assert m.get_hit_accumulation()
    m.insert_scan(origin, points, intensities)
    means = m.get_occupied_mean_positions(0.7)
    centres = m.get_occupied_voxels(0.7)
    assert means.shape == centres.shape
    assert np.all(np.abs(means[:, :3] - centres[:, :3]) <= 0.1 + 1e-9)  # within the voxel
    s = m.hit_statistics(points[0])
    assert s.hits >= 1 and s.visits >= s.hits and s.mean_hit_position.shape == (3,)
    assert iwlomap.cell_entropy(1, 3) == pytest.approx(0.6365141682948128)


def test_every_input_layout_gives_the_same_map(scan):
    origin, points, intensities = scan
    reference = lidar_map()
    reference.insert_scan(origin, points, intensities)
    want = voxel_table(reference)
    # float64 exactly representable in float32, so the float32 input is the same points.
    p32 = points.astype(np.float32)
    base = lidar_map()
    base.insert_scan(origin, p32.astype(np.float64), intensities)
    want32 = voxel_table(base)
    layouts = {
        "fortran": (np.asfortranarray(points), want),
        "transposed view": (np.ascontiguousarray(points.T).T, want),
        "strided slice": (np.repeat(points, 2, axis=0)[::2], want),
        "list": (points.tolist(), want),
        "float32": (p32, want32),
        "float32 fortran": (np.asfortranarray(p32), want32),
    }
    for name, (p, expected) in layouts.items():
        m = lidar_map()
        m.insert_scan(tuple(origin), p, intensities.astype(np.float32).astype(np.float64))
        assert np.array_equal(voxel_table(m), expected), name
    # intensities as uint8 and as a strided view
    m = lidar_map()
    m.insert_scan(origin, points, np.repeat(intensities, 2)[::2])
    assert np.array_equal(voxel_table(m), want)


def test_non_finite_points_are_skipped_and_counted():
    m = lidar_map()
    pts = np.array([[1.0, 0.0, 0.0], [np.nan, 0.0, 0.0], [np.inf, 1.0, 1.0]])
    m.insert_scan([0.0, 0.0, 0.0], pts, np.array([200.0, 200.0, np.nan]))
    assert m.get_num_skipped_points() == 2
    m.batch_update_iwlo(pts, np.array([200.0, np.nan, 1.0]), np.array([True, True, True]))
    assert m.get_num_skipped_points() == 4


def test_disk_map_persists_and_opens_read_only(tmp_path, scan):
    origin, points, intensities = scan
    d = tmp_path / "tiles"
    with iwlomap.OutofcoreTileMapper(d, 0.2, 6.4, 2) as m:
        m.set_params(LIDAR)
        m.insert_scan(origin, points, intensities)
        table = voxel_table(m)
        assert m.get_num_tiles() > 2 and m.get_num_resident_tiles() <= 2 and m.get_peak_resident_tiles() <= 3
        assert m.supports_persistence() and m.get_directory() == str(d)
        assert m.get_tile_voxels() == 32 and m.get_tile_size() == pytest.approx(6.4)
    del m
    info = iwlomap.OutofcoreTileMapper.read_map_info(d)
    assert info.resolution == 0.2 and info.tile_voxels == 32
    ro = iwlomap.OutofcoreTileMapper.open_read_only(d)
    assert ro.is_read_only() and np.array_equal(voxel_table(ro), table)
    assert ro.get_disk_usage() > 0
    with pytest.raises(RuntimeError):
        ro.insert_scan(origin, points, intensities)
    ro.copy_to(tmp_path / "copy")
    assert np.array_equal(voxel_table(iwlomap.OutofcoreTileMapper.open_read_only(tmp_path / "copy")), table)


def test_disk_map_commits_at_flush_and_rolls_back_a_failed_block(tmp_path, scan):
    origin, points, intensities = scan
    d = tmp_path / "tiles"
    with iwlomap.OutofcoreTileMapper(d, 0.2, 6.4, 2) as m:
        m.set_params(LIDAR)
        m.insert_scan(origin, points, intensities)
    del m
    committed = voxel_table(iwlomap.OutofcoreTileMapper.open_read_only(d))
    m = iwlomap.OutofcoreTileMapper(d, 0.2, 6.4, 2)
    m.insert_scan(origin + 1.0, points + 1.0, intensities)
    m.rollback()
    assert np.array_equal(voxel_table(m), committed)
    del m
    with pytest.raises(ZeroDivisionError):
        with iwlomap.OutofcoreTileMapper(d, 0.2, 6.4, 2) as m:
            m.insert_scan(origin + 1.0, points + 1.0, intensities)
            1 / 0
    del m
    assert np.array_equal(voxel_table(iwlomap.OutofcoreTileMapper.open_read_only(d)), committed)
    r = iwlomap.OutofcoreTileMapper.repair(d)
    assert r.set_aside == [] and r.tiles_kept > 2


@pytest.mark.parametrize("kind", ["ram", "disk"])
def test_a_visitor_calling_into_its_map_raises_instead_of_waiting_forever(tmp_path, scan, kind):
    origin, points, intensities = scan
    m = lidar_map() if kind == "ram" else iwlomap.OutofcoreTileMapper(tmp_path / "tiles", 0.2, 6.4, 2)
    m.insert_scan(origin, points[:200], intensities[:200])
    other = lidar_map()
    seen = []

    def visit(key, state):
        other.get_num_known_voxels()  # another map: allowed
        seen.append(key)
        m.query([0.0, 0.0, 0.0])

    with pytest.raises(RuntimeError, match="visitor may not call into the map"):
        m.for_each_voxel(visit)
    assert len(seen) == 1
    with pytest.raises(RuntimeError, match="visitor may not call into the map"):
        m.for_each_voxel(lambda k, s: m.for_each_voxel(lambda k2, s2: None))
    assert m.get_num_known_voxels() > 0  # the map is usable after


def test_colour_means():
    c = iwlomap.VoxelColorMeans(0.1)
    pts = np.array([[0.01, 0.02, 0.03], [0.05, 0.05, 0.05], [0.5, 0.5, 0.5]])
    rgb = np.array([[10, 20, 30], [11, 21, 31], [200, 0, 0]], dtype=np.uint8)
    c.add_observations(pts, np.full(3, 100.0), np.array([True, True, False]), rgb, iwlomap.IwloParams())
    assert c.mean([0.05, 0.05, 0.05]) == (11, 21, 31)  # (10 + 11) / 2 = 10.5 -> 11
    assert c.hits([0.0, 0.0, 0.0]) == 2 and c.mean([0.5, 0.5, 0.5]) is None and len(c) == 1
    assert c.colors_at(np.array([[0.05, 0.05, 0.05, 0.9], [1.0, 1.0, 1.0, 0.9]])).tolist() == [[11, 21, 31], [0, 0, 0]]
    with pytest.raises(ValueError, match="uint8"):
        c.add_observations(pts, np.full(3, 100.0), np.ones(3, bool), rgb.astype(np.int64), iwlomap.IwloParams())


def test_entropy_and_box(scan):
    origin, points, intensities = scan
    m = lidar_map()
    m.insert_scan(origin, points, intensities)
    box = iwlomap.known_voxel_box(m)
    e = iwlomap.box_entropy(m, box)
    assert e.known_voxels == m.get_num_known_voxels()
    assert e.unknown_voxels == iwlomap.count_unknown_voxels(m, box)
    assert e.known_bits == pytest.approx(iwlomap.map_entropy_bits(m))
    assert iwlomap.occupancy_entropy_bits(0.5) == 1.0
    assert iwlomap.known_voxel_box(iwlomap.ProbabilityUpdater(0.2)) is None


def test_async_mapper_gives_the_same_map(scan):
    origin, points, intensities = scan
    direct = lidar_map()
    background = lidar_map()
    a = iwlomap.AsyncMapper(background, iwlomap.ExecutionMode.kParallel, 2)
    for shift in range(3):
        direct.insert_scan(origin + shift, points + shift, intensities)
        a.integrate(origin + shift, points + shift, intensities)
    a.sync()
    assert a.get_num_known_voxels() == direct.get_num_known_voxels()
    assert np.array_equal(a.get_occupied_voxels(0.7), direct.get_occupied_voxels(0.7))
    assert a.query(points[0]) is not None and a.dropped() == 0
    a.terminate()
    assert np.array_equal(voxel_table(background), voxel_table(direct))


def test_integration_releases_the_gil():
    """While one thread is inside insert_scan, another runs Python: its loop iterations fall within
    the C++ call's time span (with the GIL held, none could)."""
    origin, points, intensities = iwlomap.make_synthetic_scan(rings=64, columns=1024)
    m = lidar_map(0.05)
    span = {}
    started = threading.Event()

    def work():
        started.set()
        span["t0"] = time.perf_counter()
        m.insert_scan(origin, points, intensities)
        span["t1"] = time.perf_counter()

    t = threading.Thread(target=work)
    t.start()
    started.wait()
    stamps = []
    while t.is_alive():
        stamps.append(time.perf_counter())
    t.join()
    t0, t1 = span["t0"], span["t1"]
    inside = [s for s in stamps if t0 + 0.2 * (t1 - t0) < s < t0 + 0.8 * (t1 - t0)]
    assert t1 - t0 > 0.05, "the scan is too small to tell"
    assert len(inside) > 100


def test_memory_limit_raises_memory_limit_error(scan):
    origin, points, intensities = scan
    old = iwlomap.get_map_memory_limit()
    try:
        iwlomap.set_map_memory_limit(iwlomap.get_map_memory_in_use() + 4096)
        m = lidar_map(0.05)
        with pytest.raises(iwlomap.MemoryLimitError) as e:
            m.insert_scan(origin, points, intensities)
        assert isinstance(e.value, MemoryError) and e.value.needed > 0 and e.value.limit > 0
        assert m.get_num_known_voxels() == 0  # refused before changing the map
    finally:
        iwlomap.set_map_memory_limit(old)


@pytest.mark.skipif(not iwlomap.HAS_OCTOMAP, reason="built without the OctoMap layer")
def test_octomap_files_round_trip(tmp_path, scan):
    origin, points, intensities = scan
    m = lidar_map()
    m.insert_scan(origin, points, intensities)
    iwlomap.export_octomap(m, tmp_path / "map.ot")
    back = lidar_map()
    iwlomap.import_octomap(tmp_path / "map.ot", back)
    a, b = voxel_table(m), voxel_table(back)
    assert np.array_equal(a[:, :3], b[:, :3])
    assert np.allclose(a[:, 3], b[:, 3], atol=1e-6)  # .ot keeps float log-odds
    iwlomap.export_octomap(m, str(tmp_path / "map.bt"), 0.8)
    o = iwlomap.OctreeMapper(0.2)
    o.load_from_file(tmp_path / "map.bt")
    assert o.get_num_known_voxels() > 0 and o.get_prob_hit() == 0.7
    o.update_point([0.1, 0.1, 0.1], True)
    o.batch_update(points[:10], np.ones(10, bool))
    o.batch_update_with_log_odds(points[:10], np.full(10, 0.5))
    o.insert_ray(origin, points[0])
    o.set_probability_params(0.8, 0.4)
    o.set_occupancy_thresholds(0.2, 0.9)
    assert (o.get_prob_miss(), o.get_prob_thres_min(), o.get_prob_thres_max()) == (0.4, 0.2, 0.9)
    assert o.prune_tree() >= 0
    o.save_to_file(tmp_path / "saved.ot")
    with pytest.raises(OSError) as e:
        iwlomap.import_octomap(tmp_path / "missing.bt", back)
    assert e.value.filename == str(tmp_path / "missing.bt")
    with pytest.raises(ValueError):
        iwlomap.export_octomap(m, tmp_path / "map.xyz")


def test_the_rest_of_the_surface(tmp_path, scan):
    """The bound names no other test needs, each called once with a checked result."""
    origin, points, intensities = scan
    p = iwlomap.IwloParams()
    assert iwlomap.iwlo.delta(0.0, 1, 255.0, True, 1.0, p) == pytest.approx(iwlomap.iwlo.step(0.0, 1, 255.0, True, 1.0, p))
    assert iwlomap.iwlo.adaptive_scale(0.5, True, p) == 1.0
    box = iwlomap.VoxelBox(iwlomap.VoxelKey(0, 0, 0), iwlomap.VoxelKey(1, 1, 1))
    box.validate()
    assert box.num_voxels() == 8
    with pytest.raises(ValueError):
        iwlomap.VoxelBox(iwlomap.VoxelKey(1, 0, 0), iwlomap.VoxelKey(0, 0, 0))
    assert iwlomap.VoxelKey(1, 2, 3) == iwlomap.VoxelKey(1, 2, 3) and len({iwlomap.VoxelKey(1, 2, 3)}) == 1
    d = iwlomap.OutofcoreTileMapper(tmp_path / "d", 0.1, 3.2, 5)
    assert d.get_cache_tiles() == 5 and not d.is_read_only()
    seq = iwlomap.AsyncMapper(iwlomap.ProbabilityUpdater(0.2), iwlomap.ExecutionMode.kSequential, 1,
                              iwlomap.QueueFullPolicy.kDropOldest)
    seq.integrate(origin, points, intensities)
    seq.sync()
    assert seq.get_num_known_voxels() > 0
    c = iwlomap.VoxelColorMeans(0.2)
    c.add_scan(origin, points[:100], np.full(100, 200.0), np.full((100, 3), 7, np.uint8), LIDAR)
    assert c.resolution() == 0.2 and c.size() > 0 and c.memory_bytes() > 0
    assert c.mean(points[0]) == (7, 7, 7)
    c.clear()
    assert len(c) == 0
    grid = iwlomap.DiscreteGrid3D(np.zeros((2, 3, 4), np.uint8), iwlomap.GridFrame(iwlomap.VoxelKey(10, 20, 30), 0.5))
    k = grid.key_of([1, 2, 3])
    assert (k.x, k.y, k.z) == (11, 22, 33) and grid.frame.resolution == 0.5 and grid.size == [2, 3, 4]
    params = iwlomap.SonarProjectorParams(no_return=iwlomap.SonarNoReturn.kNothing, occupied_band=0.02)
    assert params.no_return == iwlomap.SonarNoReturn.kNothing and params.occupied_band == 0.02
    assert iwlomap.UNKNOWN_VALUE == 0 and iwlomap.MAX_RAY_VOXELS == 131072.0


def test_two_threads_integrate_into_two_maps_at_once():
    """Two Python threads, one map each: the calls overlap in time (the GIL is released) and each
    map equals the one built alone."""
    scans = [iwlomap.make_synthetic_scan(seed=s) for s in (1, 2)]
    maps = [lidar_map(0.2), lidar_map(0.2)]
    spans = [None, None]
    barrier = threading.Barrier(2)

    def work(k):
        barrier.wait()
        t0 = time.perf_counter()
        maps[k].insert_scan(*scans[k])
        spans[k] = (t0, time.perf_counter())

    threads = [threading.Thread(target=work, args=(k,)) for k in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    (a0, a1), (b0, b1) = spans
    overlap = min(a1, b1) - max(a0, b0)
    assert overlap > 0.5 * min(a1 - a0, b1 - b0), spans
    for k in (0, 1):
        alone = lidar_map(0.2)
        alone.insert_scan(*scans[k])
        assert np.array_equal(voxel_table(maps[k]), voxel_table(alone))


def test_disk_map_opened_from_its_directory_alone_takes_its_stored_parameters(tmp_path):
    made = iwlomap.OutofcoreTileMapper(tmp_path / "map", 0.1, 3.2)
    made.batch_update_iwlo(np.array([[0.15, 0.25, 0.35], [2.0, -1.0, 0.5]]), None, np.ones(2, dtype=bool))
    made.flush()
    del made
    opened = iwlomap.OutofcoreTileMapper(tmp_path / "map")
    assert opened.get_resolution() == 0.1 and opened.get_num_known_voxels() == 2
    fresh = iwlomap.OutofcoreTileMapper(tmp_path / "new")
    assert fresh.get_resolution() == 0.05


def test_async_and_registered_mappers_take_scans_without_intensities():
    """AsyncMapper.integrate and RegisteredMapper.integrate accept intensities=None: every point a
    return at the map's intensity_max, the same map as with those intensities given."""
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(3, 4, 3000), rng.uniform(-1, 1, 3000), rng.uniform(-1, 1, 3000)])
    maps = []
    for intensities in (None, "given"):
        m = iwlomap.ProbabilityUpdater(0.2)
        a = iwlomap.AsyncMapper(m)
        full = np.full(len(pts), m.get_params().intensity_max)
        a.integrate(np.zeros(3), pts, None if intensities is None else full)
        a.sync()
        maps.append(m.get_occupied_voxels(0.5))
    assert maps[0].shape[0] > 0
    np.testing.assert_array_equal(maps[0], maps[1])
    if hasattr(iwlomap, "RegisteredMapper"):
        m = iwlomap.ProbabilityUpdater(0.2)
        r = iwlomap.RegisteredMapper(m)
        r.integrate(np.eye(4), pts)
        r.sync()
        np.testing.assert_array_equal(m.get_occupied_voxels(0.5), maps[0])
