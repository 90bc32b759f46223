# SPDX-License-Identifier: BSD-3-Clause
"""Sonar (Oculus pings, the image projector) and the multi-resolution max grids."""

import numpy as np
import pytest

import iwlomap


def test_projector_on_a_synthetic_image():
    image = np.zeros((100, 8), dtype=np.uint8)
    image[60, :] = 200  # an echo at bin 60 in every beam
    geometry = iwlomap.SonarGeometry(bearings=np.linspace(-0.2, 0.2, 8), range_resolution=0.02, max_range=2.0)
    projector = iwlomap.SonarImageProjector(0.05, iwlomap.SonarProjectorParams())
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, -3.0]
    obs = projector.project(image, geometry, pose)
    assert obs.beams_with_return == 8 and obs.beams_without_return == 0
    assert obs.points.shape == (len(obs.is_occupied), 3) and obs.is_occupied.dtype == bool
    hits = obs.points[obs.is_occupied]
    ranges = np.linalg.norm(hits - [1.0, 2.0, -3.0], axis=1)
    assert np.all(np.abs(ranges - 60.5 * 0.02) < 0.1)
    # The same image in every layout and pixel type gives the same observations.
    for other in (image.astype(np.uint16), image.astype(np.float32), image.astype(np.float64),
                  np.asfortranarray(image), np.ascontiguousarray(image.T).T):
        o = projector.project(other, geometry, pose)
        assert np.array_equal(o.points, obs.points) and np.array_equal(o.is_occupied, obs.is_occupied)
    m = iwlomap.ProbabilityUpdater(0.05)
    projector.integrate(m, image, geometry, pose)
    assert len(m.get_occupied_voxels(0.5)) > 0
    with pytest.raises(ValueError, match="rotation"):
        projector.project(image, geometry, np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="int8"):
        projector.project(image.astype(np.int8), geometry, pose)
    with pytest.raises(ValueError):
        iwlomap.SonarGeometry(bearings=[0.0], range_resolution=5.0, max_range=2.0)


def test_oculus_pings(data_dir):
    pings = iwlomap.read_oculus_pings(data_dir / "oculus_sonar_3pings" / "three_pings_8bit.raw")
    assert len(pings) == 3
    p = pings[0]
    assert (p.beams, p.range_bins) == (256, 703) and p.image.shape == (703, 256) and p.image.dtype == np.uint8
    assert p.bearings.shape == (256,) and np.degrees(p.bearings[0]) == pytest.approx(-30.0, abs=0.5)
    assert p.range_resolution == pytest.approx(0.002842, abs=1e-5)
    assert p.intensity(100, 10) == p.image[100, 10]
    g = p.geometry(np.radians(20.0), 0.1)
    assert g.max_range == pytest.approx(p.range) and g.min_range == 0.1
    obs = iwlomap.SonarImageProjector(0.01).project(p.image, g, np.eye(4))
    assert obs.occupied_samples > 0


def test_precomputation_stack_levels_are_window_maxima():
    rng = np.random.default_rng(3)
    values = rng.integers(0, 256, size=(9, 7), dtype=np.uint8)
    grid = iwlomap.DiscreteGrid2D(values, iwlomap.GridFrame(iwlomap.VoxelKey(0, 0, 0), 0.1))
    assert np.array_equal(grid.values, values) and grid.size == [9, 7] and grid.at([3, 4]) == values[3, 4]
    stack = iwlomap.PrecomputationStack2D(grid, 3)
    assert stack.num_levels() == 3 and [stack.width(k) for k in range(3)] == [1, 2, 4]
    assert np.array_equal(stack.level(0)[:9, :7], values)
    for k, level in enumerate(stack.levels):
        w = 2 ** k
        # Level k at cell c is the max over base cells [c, c + w) (cells beyond the grid count as 0);
        # the level grid starts w - 1 cells before the base (cell index i -> base i - (w - 1)).
        padded = np.zeros((9 + 2 * w, 7 + 2 * w), dtype=np.uint8)
        padded[w - 1:w - 1 + 9, w - 1:w - 1 + 7] = values
        for i in range(level.shape[0]):
            for j in range(level.shape[1]):
                assert level[i, j] == padded[i:i + w, j:j + w].max(), (k, i, j)
    assert stack.max_in_box([0, 0], [8, 6]) == values.max()
    with pytest.raises(ValueError, match="uint8"):
        iwlomap.DiscreteGrid2D(values.astype(np.float64))


def test_stack_from_a_map(scan):
    origin, points, intensities = scan
    m = iwlomap.ProbabilityUpdater(0.2)
    m.set_params(iwlomap.sensor_preset_params(iwlomap.SensorPreset.kLidar))
    m.insert_scan(origin, points, intensities)
    box = iwlomap.VoxelBox.from_world([-5, -5, 0], [5, 5, 2], 0.2)
    volume = iwlomap.discretize_volume(m, box)
    assert volume.values.shape == (51, 51, 11)
    column = iwlomap.discretize_column_max(m, box)
    assert np.array_equal(column.values, volume.values.max(axis=2))
    assert iwlomap.discretize_slice(m, box, 1.0).values.shape == (51, 51)
    stack = iwlomap.PrecomputationStack3D(volume, 4)
    assert stack.level(3).max() == volume.values.max()
    assert iwlomap.value_to_probability(iwlomap.probability_to_value(0.9)) == pytest.approx(0.9, abs=0.01)


def test_cfar_detection():
    rng = np.random.default_rng(3)
    params = iwlomap.SonarCfarParams(false_alarm_rate=1e-2, min_noise_intensity=0.0)
    cfar = iwlomap.SonarCfar(iwlomap.SonarDetector.kCellAveragingCfar, params)
    cells = detections = 0
    for _ in range(100):
        beam = rng.rayleigh(5.0, 400)
        d = cfar.detect(beam)
        assert d.dtype == bool and d.shape == (400,)
        cells += 400 - 1  # bin 0 has no training cell on its near side
        detections += int(d[1:].sum())
    expected = 1e-2 * cells
    assert abs(detections - expected) < 5 * np.sqrt(expected)
    assert cfar.factor(16) == pytest.approx(16 * (1e-2 ** (-1 / 16) - 1))
    with pytest.raises(ValueError, match="training_cells"):
        iwlomap.SonarCfarParams(guard_cells=4, training_cells=4)
    with pytest.raises(ValueError, match="false_alarm_rate"):
        iwlomap.SonarCfarParams(false_alarm_rate=1.0)
    # The projector: a noise floor above the fixed threshold, a wall at bin 150.
    image = rng.rayleigh(40.0, (200, 16)).astype(np.float32)
    image[150, :] += 900
    geometry = iwlomap.SonarGeometry(bearings=np.linspace(-0.2, 0.2, 16), range_resolution=0.02, max_range=4.0)
    p = iwlomap.SonarProjectorParams(detector=iwlomap.SonarDetector.kOrderedStatisticCfar,
                                     cfar=iwlomap.SonarCfarParams(false_alarm_rate=1e-4))
    assert p.cfar.window == iwlomap.SonarCfarWindow.kNearSide
    obs = iwlomap.SonarImageProjector(0.1, p).project(image, geometry, np.eye(4))
    ranges = np.linalg.norm(obs.points[obs.is_occupied], axis=1)
    assert len(ranges) > 0 and np.mean(np.abs(ranges - 3.01) < 0.15) > 0.8


def test_sonar_preset_and_snr_weight():
    assert iwlomap.sonar_snr_weight(0.0) == pytest.approx(0.5)
    assert iwlomap.sonar_snr_weight(iwlomap.kRayleighPowerSpreadDb) == pytest.approx(1 / (1 + np.exp(-1)), abs=1e-6)
    with pytest.raises(ValueError, match="width_db"):
        iwlomap.SonarSnrWeight(width_db=0.0)
    with pytest.raises(ValueError, match="snr_weight"):
        iwlomap.SonarProjectorParams(snr_weight=iwlomap.SonarSnrWeight(enabled=True))  # needs CFAR
    preset = iwlomap.sonar_preset()
    assert preset.projector.detector == iwlomap.SonarDetector.kOrderedStatisticCfar
    assert preset.projector.snr_weight.enabled
    assert preset.map.intensity_threshold == 35.0
    # A strong echo at bin 150 over a quiet floor: weighted by its excess, at most 1.
    image = np.full((200, 16), 8, dtype=np.uint8)
    image[150, :] = 250
    geometry = iwlomap.SonarGeometry(bearings=np.linspace(-0.2, 0.2, 16), range_resolution=0.02, max_range=4.0)
    obs = iwlomap.SonarImageProjector(0.1, preset.projector).project(image, geometry, np.eye(4))
    w = obs.weights[obs.is_occupied]
    assert len(w) > 0 and np.all((w > 0) & (w <= 1))
    plain = iwlomap.SonarProjectorParams(detector=iwlomap.SonarDetector.kOrderedStatisticCfar)
    base = iwlomap.SonarImageProjector(0.1, plain).project(image, geometry, np.eye(4))
    assert np.all(w <= base.weights[base.is_occupied] + 1e-12)
