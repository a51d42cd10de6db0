import json

import numpy as np
import pytest

from web.coverage_data import coverage_from_model, trust_at, unwrap_model
from web.coverage_view import TRAINED_RGB, UNTRAINED_RGB, compose_frame, render_background


def wn_model():
    wn = pytest.importorskip("teleop_force.friction.wavelet_network")
    net = wn.WaveletNetwork(3, wn.omni_wavelet_specs())
    rng = np.random.default_rng(0)
    angle = rng.uniform(0, 2 * np.pi, 20_000)
    radius = np.sqrt(rng.uniform(0, 1, 20_000))
    qd = np.stack([rng.uniform(-1, 1, 20_000), radius * np.cos(angle), radius * np.sin(angle)], 1)
    net.coverage.add(qd)
    return {"format": "teleop-force-model", "friction": json.loads(json.dumps(net.to_dict()))}


def test_reads_the_coverage_and_centres_of_a_real_wavelet_network():
    info = coverage_from_model(wn_model())
    assert info.friction_kind == "wn"
    plane, line = info.plane, info.line
    assert plane.trust.shape == (40, 40) and line.trust.ndim == 1
    assert plane.lo == (-3.0, -3.0) and plane.hi == (3.0, 3.0)
    assert set(plane.centres) == {1, 2} and set(line.centres) == {0}
    # Seeds: one centre per quadrant on the coarsest dilation.
    assert plane.centres[1].shape == (4, 2)
    assert np.all(np.abs(plane.centres[1]) > 0)
    trust = trust_at(plane, np.array([[0.0, 0.0], [2.5, 2.5], [9.0, 0.0], [np.nan, 0.0]]))
    assert trust[0] > 0.9 and trust[1] == 0.0 and trust[2] == 0.0 and trust[3] == 0.0
    assert plane.samples == pytest.approx(20_000)


def test_models_without_coverage_are_handled():
    assert coverage_from_model(None).plane is None
    cv = coverage_from_model({"friction": {"kind": "cv", "n_joints": 3, "parameters": [0] * 6}})
    assert cv.plane is None and "cv" in cv.message
    assert coverage_from_model({"robot": "omni"}).message == "model has no friction entry"
    no_map = {"friction": {"kind": "wn", "joints": [
        {"inputs": [1, 2], "x_min_rad_s": [-2, -2], "x_max_rad_s": [2, 2], "active": [[0, 1, 1]]}],
        "coverage": None}}  # fmt: skip
    info = coverage_from_model(no_map)
    assert info.plane is not None and info.plane.trust is None and info.line is None
    assert info.message == "model has no coverage map"
    np.testing.assert_allclose(info.plane.centres[0], [[1.0, 1.0]])
    bad = {"friction": {"kind": "wn", "joints": [{"inputs": [1, 2], "x_min_rad_s": "x"}]}}
    assert "cannot read" in coverage_from_model(bad).message


def test_unwrap_model():
    model = {"friction": {}}
    assert unwrap_model(model) is model
    assert unwrap_model({"model": model, "path": "x"}) is model
    assert unwrap_model([1]) is None and unwrap_model({"ok": True}) is None


def test_render_and_compose_draw_the_trajectory_in_the_right_colours():
    info = coverage_from_model(wn_model())
    bg = render_background(info, "k")
    assert bg.image.dtype == np.uint8 and bg.image.shape[2] == 3
    # The axes map puts data corners inside the image, y growing upwards.
    c0, r0 = bg.plane.to_pixels(np.array([-3.0]), np.array([-3.0]))
    c1, r1 = bg.plane.to_pixels(np.array([3.0]), np.array([3.0]))
    assert c1 > c0 and r1 < r0
    t = np.linspace(0, 1, 200)
    qd = np.stack([0.5 * t, 2.5 * np.cos(6 * t), 2.5 * np.sin(6 * t)], 1)
    frame = compose_frame(bg, qd, np.zeros(200, bool), 1 - t)
    assert frame.shape == bg.image.shape and not np.array_equal(frame, bg.image)
    col, row = bg.plane.to_pixels(qd[-1:, 1], qd[-1:, 2])
    assert np.allclose(frame[round(row[0]), round(col[0])], UNTRAINED_RGB, atol=2)
    green = compose_frame(bg, qd * 0.1, np.ones(200, bool), 1 - t)
    col, row = bg.plane.to_pixels(qd[-1:, 1] * 0.1, qd[-1:, 2] * 0.1)
    assert np.allclose(green[round(row[0]), round(col[0])], TRAINED_RGB, atol=2)
    empty = compose_frame(bg, np.full((3, 3), np.nan), np.ones(3, bool), np.zeros(3))
    assert np.array_equal(empty, bg.image)


def test_background_without_a_model():
    bg = render_background(coverage_from_model(None))
    assert bg.image.mean() > 100  # mostly white figure
