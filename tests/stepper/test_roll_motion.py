"""The roll motion (the authors' rose, Fig. 11) and scaling about the selection's box centre: geometry of the
targets and the scene keys."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from idp.errors import SceneError
from idp.scene.conditions_schema import MotionSpec
from idp.scene.load import scene_from_dict
from idp.stepper.motions import Roll, Scale


def _strip(length: float = 0.6, half_thickness: float = 0.002, n: int = 601) -> np.ndarray:
    """Points of the two faces of a strip along x (z = ±half_thickness), at two heights y."""
    s = np.linspace(0.0, length, n)
    faces = [
        np.stack([s, np.full(n, y), np.full(n, z)], axis=1)
        for y in (0.0, 0.1)
        for z in (half_thickness, -half_thickness)
    ]
    return np.concatenate(faces)


@pytest.mark.parametrize("t", [0.5, 2.0, 4.0])
def test_roll_is_an_isometry_of_the_strip_and_keeps_its_thickness(t):
    m = Roll(np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]), np.zeros(3), speed=0.1, pitch=0.005)
    X = _strip()
    Y = m.targets(X, t)
    n = 601
    top, bottom = Y[:n], Y[n : 2 * n]
    mid = 0.5 * (top + bottom)
    # the mid-surface keeps its lengths (arc length preserved: a chord of arc 0.001 on a radius ≥ 2π·0.005 is
    # shorter by a relative 0.001²/(24 r²) < 5e-5) and the faces stay 2·0.002 apart
    chords = np.linalg.norm(np.diff(mid, axis=0), axis=1)
    assert np.all(chords <= 0.001 * (1 + 1e-12)) and np.all(chords >= 0.001 * (1 - 5e-5))
    np.testing.assert_allclose(np.linalg.norm(top - bottom, axis=1), 0.004, rtol=1e-9)
    # the part not yet wound stays exactly where it was; heights (along the axis) are kept
    flat = X[:n, 0] > 0.1 * t
    np.testing.assert_array_equal(Y[:n][flat], X[:n][flat])
    np.testing.assert_allclose(Y[:, 1], X[:, 1], rtol=0, atol=1e-15)
    # the roll rises on the axis × direction side (−z here) and its turns never come within a layer spacing
    assert Y[:, 2].max() <= 0.002 + 1e-12
    wound = mid[~flat]
    if wound.shape[0] > 2:
        pairs = cKDTree(wound).query_pairs(2 * np.pi * 0.005 - 0.0045, output_type="ndarray")
        arc = np.abs(pairs[:, 0] - pairs[:, 1]) * 0.001
        assert np.all(arc < 0.03)  # only neighbours along the strip are that close, never another turn


def test_roll_at_time_zero_is_the_identity_and_bad_parameters_are_refused():
    m = Roll(np.array([0.0, 0.0, 2.0]), np.array([0.0, 3.0, 0.0]), np.array([1.0, 1.0, 1.0]), 0.2, 0.01)
    X = np.random.default_rng(1).normal(size=(20, 3))
    np.testing.assert_array_equal(m.targets(X, 0.0), X)
    with pytest.raises(ValueError, match="parallel"):
        Roll(np.array([0.0, 1.0, 0.0]), np.array([0.0, 2.0, 0.0]), np.zeros(3), 0.1, 0.01)
    with pytest.raises(ValueError, match="positive"):
        Roll(np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]), np.zeros(3), 0.0, 0.01)


def test_scale_about_the_selection_box_centre():
    X = np.array([[1.0, 0.0, 0.0], [3.0, 2.0, 4.0], [2.0, 1.0, 1.0]])
    m = Scale(np.array([np.log(0.5), 0.0, np.log(0.5)]), None, "exponential")
    c = np.array([2.0, 1.0, 2.0])
    np.testing.assert_allclose(m.targets(X, 1.0), c + (X - c) * [0.5, 1.0, 0.5], rtol=1e-12)


def _beam(motion: dict) -> dict:
    return {
        "name": "roll",
        "dim": 3,
        "objects": [
            {
                "name": "sheet",
                "generate": {"shape": "tet_box", "lo": [0, 0, 0], "hi": [1, 0.2, 0.01]},
                "handles": [{"name": "h", "select": {"indices": [0]}, "motion": motion}],
            }
        ],
    }


def test_roll_and_about_keys_are_checked():
    ok = {"type": "roll", "axis": [0, 1, 0], "direction": [1, 0, 0], "center": [0, 0, 0], "speed": 0.1, "pitch": 0.005}
    scene_from_dict(_beam(ok))
    with pytest.raises(SceneError, match="pitch"):
        scene_from_dict(_beam({k: v for k, v in ok.items() if k != "pitch"}))
    with pytest.raises(SceneError, match=r"direction.*parallel"):
        scene_from_dict(_beam({**ok, "direction": [0, 2, 0]}))
    with pytest.raises(SceneError, match="incremental"):
        scene_from_dict(_beam({**ok, "incremental": True}))
    with pytest.raises(Exception, match="about"):
        MotionSpec(type="scale", rate=-1.0, about="selection", center=[0, 0, 0])
    with pytest.raises(Exception, match="about"):
        MotionSpec(type="translate", velocity=[1, 0, 0], about="selection")
