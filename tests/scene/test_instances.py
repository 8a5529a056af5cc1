"""Instancing and layout (paper §7.5): copies as bodies, generated layouts, reproducibility, refusals."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from idp.errors import IntersectingInputError, SceneError
from idp.mesh.placement import rotation_matrix
from idp.scene.build import build_scene
from idp.scene.load import dump_scene_toml, load_scene, scene_from_dict
from idp.scene.schema import Scene

BALL = {"shape": "ball", "radius": 0.3, "resolution": 2}  # diameter 0.6


def scene(instances: dict[str, Any] | None, *, dim: int = 3, extra: list | None = None, **obj: Any) -> Scene:
    gen = BALL if dim == 3 else {"shape": "rectangle", "lo": [0.0, 0.0], "hi": [0.4, 0.2], "resolution": [2, 2]}
    ob: dict[str, Any] = {"name": "ball", "generate": gen, **obj}
    if instances is not None:
        ob["instances"] = instances
    return scene_from_dict(
        {
            "name": "inst",
            "dim": dim,
            "output": {"obj": False, "vtu": False, "png": False},
            "objects": [ob, *(extra or [])],
        }
    )


def centroids(s: Scene) -> dict[str, np.ndarray]:
    """Mean vertex position of every built part, by name."""
    built = build_scene(s)
    x = built.system.x
    return {p.name: x[p.vertex_ids].mean(axis=0) for p in built.system.parts}


def positions(s: Scene) -> np.ndarray:
    return build_scene(s).system.x.copy()


def test_grid_copies_are_bodies_at_the_grid_points() -> None:
    s = scene({"grid": {"counts": [3, 1, 1], "spacing": [1.0, 1.0, 1.0], "origin": [0.0, 2.0, 0.0]}})
    assert [o.name for o in s.objects] == ["ball_0", "ball_1", "ball_2"]
    assert all(o.instances is None for o in s.objects)
    built = build_scene(s)
    assert [b.name for b in built.system.bodies] == ["ball_0", "ball_1", "ball_2"]
    c = centroids(s)
    for k in range(3):
        np.testing.assert_allclose(c[f"ball_{k}"], [k, 2.0, 0.0], atol=1e-12)


def test_instance_transform_comes_after_the_objects_own_placement() -> None:
    # the object is moved to (1, 0, 0) first, then each copy is turned 90 degrees about z and moved up by k
    s = scene(
        {
            "transforms": [
                {"rotate": [{"axis": [0, 0, 1], "degrees": 90.0}]},
                {"rotate": [{"axis": [0, 0, 1], "degrees": 90.0}], "translate": [0.0, 0.0, 1.0]},
            ]
        },
        translate=[1.0, 0.0, 0.0],
    )
    c = centroids(s)
    np.testing.assert_allclose(c["ball_0"], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(c["ball_1"], [0.0, 1.0, 1.0], atol=1e-12)


def test_overlapping_copies_are_refused_naming_the_pair() -> None:
    s = scene({"grid": {"counts": [3, 1, 1], "spacing": [0.5, 1.0, 1.0]}})  # spacing < diameter
    with pytest.raises(IntersectingInputError) as err:
        build_scene(s)
    msg = str(err.value)
    assert "ball_0 and ball_1" in msg and "ball_1 and ball_2" in msg
    assert "ball_0 and ball_2" not in msg  # 1.0 apart: clear


def test_random_layout_that_overlaps_is_refused_naming_a_pair() -> None:
    s = scene({"random": {"count": 3, "seed": 4, "translate_lo": [0.0, 0.0, 0.0], "translate_hi": [0.2, 0.2, 0.2]}})
    with pytest.raises(IntersectingInputError, match=r"ball_\d and ball_\d"):
        build_scene(s)


def test_a_copy_wholly_inside_another_is_refused() -> None:
    # no surfaces cross: a small copy sits inside a big one
    s = scene({"transforms": [{"scale": 3.0}, {"scale": 0.3, "translate": [0.1, 0.0, 0.0]}]})
    with pytest.raises(IntersectingInputError, match="ball_1 inside ball_0"):
        build_scene(s)


RANDOM = {
    "count": 4,
    "seed": 11,
    "translate_lo": [0.0, 0.0, 0.0],
    "translate_hi": [8.0, 8.0, 8.0],
    "scale_lo": 0.8,
    "scale_hi": 1.2,
}


def test_seeded_random_layout_reproduces_exactly() -> None:
    a = positions(scene({"random": RANDOM}))
    b = positions(scene({"random": RANDOM}))
    np.testing.assert_array_equal(a, b)
    c = positions(scene({"random": {**RANDOM, "seed": 12}}))
    assert a.shape == c.shape and not np.allclose(a, c)


def test_resolved_scene_reloads_to_the_same_layout_without_expanding_again(tmp_path: Path) -> None:
    s = scene({"random": RANDOM}, fixed=[{"box": [[0.0, 0.0, 0.0], [1.0, 0.1, 1.0]], "relative": True}])
    path = tmp_path / "scene.resolved.toml"
    path.write_text(dump_scene_toml(s))
    again = load_scene(path)
    assert [o.name for o in again.objects] == [f"ball_{k}" for k in range(4)]
    assert all(o.instances is None and o.instance_transform is not None for o in again.objects)
    assert again.objects == s.objects
    np.testing.assert_array_equal(positions(again), positions(s))
    path.write_text(dump_scene_toml(again))
    assert load_scene(path) == again  # a fixed point: resolving the resolved scene changes nothing


def test_relative_fixed_boxes_are_per_copy() -> None:
    s = scene(
        {"ring": {"count": 4, "radius": 2.0}},
        fixed=[{"box": [[0.0, 0.0, 0.0], [1.0, 0.1, 1.0]], "relative": True}],
    )
    built = build_scene(s)
    pinned = ~built.system.free_mask.reshape(-1, 3)[:, 0]
    per_copy = [int(pinned[p.vertex_ids].sum()) for p in built.system.parts]
    assert per_copy[0] > 0 and len(set(per_copy)) == 1  # every copy pinned at its own bottom


def test_rhododendron_rings() -> None:
    """Three rings of different count and radius; the paper's rotate-about-+y-by-(-90 - phi) convention."""
    rings = [
        {"count": n, "radius": r, "axis": [0.0, -1.0, 0.0], "rotate_offset_degrees": 90.0, "start_degrees": st}
        for n, r, st in ((5, 1.0, 0.0), (7, 2.0, 10.0), (9, 3.0, 20.0))
    ]
    s = scene({"rings": rings}, translate=[0.1, 0.0, 0.0])
    assert len(s.objects) == 21 and s.objects[-1].name == "ball_20"
    c = centroids(s)
    k = 0
    for n, r, st in ((5, 1.0, 0.0), (7, 2.0, 10.0), (9, 3.0, 20.0)):
        for j in range(n):
            phi = st + j * 360.0 / n
            p = np.radians(phi)
            want = rotation_matrix("y", -90.0 - phi) @ [0.1, 0.0, 0.0] + [r * np.cos(p), 0.0, r * np.sin(p)]
            np.testing.assert_allclose(c[f"ball_{k}"], want, atol=1e-12)
            k += 1


def test_2d_rectangle_instancing() -> None:
    s = scene({"ring": {"count": 6, "radius": 1.0, "center": [0.5, 0.5]}}, dim=2)
    c = centroids(s)
    assert len(c) == 6
    for k in range(6):
        p = np.radians(60.0 * k)
        turn = np.array([[np.cos(p), -np.sin(p)], [np.sin(p), np.cos(p)]])
        want = turn @ [0.2, 0.1] + [0.5 + np.cos(p), 0.5 + np.sin(p)]
        np.testing.assert_allclose(c[f"ball_{k}"], want, atol=1e-12)
    g = centroids(scene({"grid": {"counts": [2, 2], "spacing": [1.0, 1.0]}}, dim=2))
    np.testing.assert_allclose(g["ball_3"], [1.2, 1.1], atol=1e-12)


def test_copies_beside_other_objects_keep_their_order() -> None:
    other = {"name": "other", "generate": BALL, "translate": [0.0, 5.0, 0.0]}
    s = scene({"grid": {"counts": [2, 1, 1], "spacing": [1.0, 1.0, 1.0]}}, extra=[other])
    assert [o.name for o in s.objects] == ["ball_0", "ball_1", "other"]


@pytest.mark.parametrize(
    ("instances", "dim", "where"),
    [
        (
            {"grid": {"counts": [2, 1, 1], "spacing": [1.0, 1.0, 1.0]}, "ring": {"count": 2, "radius": 1.0}},
            3,
            "objects[0].instances.ring: give exactly one of",
        ),
        ({}, 3, "objects[0].instances: give one of"),
        ({"ring": {"count": 0, "radius": 1.0}}, 3, "objects[0].instances.ring.count: must be >= 1"),
        ({"ring": {"count": 3, "radius": 1.0, "axis": [0.0, 0.0, 1.0]}}, 2, "objects[0].instances.ring.axis: must be"),
        ({"rings": [{"count": 3, "radius": 1.0, "axis": [0, 0, 0]}]}, 3, "objects[0].instances.rings[0].axis"),
        ({"grid": {"counts": [3, 1], "spacing": [1.0, 1.0, 1.0]}}, 3, "objects[0].instances.grid.counts: must have 3"),
        ({"grid": {"counts": [3, 1, 1], "spacing": [0.0, 1.0, 1.0]}}, 3, "objects[0].instances.grid.spacing[0]"),
        ({"random": {"count": 2, "translate_lo": [0.0] * 3, "translate_hi": [1.0] * 3}}, 3, "random.seed: required"),
        (
            {"random": {"count": 2, "seed": 1, "translate_lo": [0.0] * 3, "translate_hi": [1.0, -1.0, 1.0]}},
            3,
            "objects[0].instances.random.translate_hi: need translate_lo <= translate_hi",
        ),
        ({"transforms": [{"rotate": [{"degrees": 30.0}]}]}, 3, "transforms[0].rotate[0].axis: required in 3D"),
        ({"transforms": [{}, {}]}, 3, "objects[0].instances: copies ball_0 and ball_1 are placed identically"),
        ({"grid": {"counts": [100, 100, 100], "spacing": [1.0] * 3}}, 3, "objects[0].instances.grid: makes 1e+06"),
        ({"grid": {"counts": [2, 1, 1], "spacing": [1.0] * 3}, "copies": 2}, 3, "objects[0].instances.copies: unknown"),
        ({"grid": {"counts": [3, 1, 1], "spacing": [1e308, 1.0, 1.0]}}, 3, "objects[0].instances: makes a transform"),
        (
            {"random": {"count": 2, "seed": 1, "translate_lo": [-1e308, 0.0, 0.0], "translate_hi": [1e308, 1.0, 1.0]}},
            3,
            "objects[0].instances: cannot make the copies' transforms",
        ),
    ],
)
def test_schema_errors_name_the_key(instances: dict, dim: int, where: str) -> None:
    with pytest.raises(SceneError) as err:
        scene(instances, dim=dim)
    assert where in str(err.value)


def test_a_copy_name_taken_by_another_object_is_refused() -> None:
    other = {"name": "ball_1", "generate": BALL, "translate": [0.0, 5.0, 0.0]}
    with pytest.raises(SceneError, match=r"objects\[0\].instances: copy name 'ball_1' is already used by objects\[1\]"):
        scene({"grid": {"counts": [2, 1, 1], "spacing": [1.0] * 3}}, extra=[other])


def test_instance_transform_checks() -> None:
    with pytest.raises(SceneError, match=r"objects\[0\].instance_transform.matrix: must have a positive determinant"):
        scene(None, instance_transform={"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, -1.0]], "translate": [0, 0, 0.0]})
    with pytest.raises(SceneError, match=r"objects\[0\].instance_transform.matrix: must be 2 rows of 2"):
        scene(None, dim=2, instance_transform={"matrix": [[1.0, 0.0, 0.0]], "translate": [0.0, 0.0]})
    with pytest.raises(SceneError, match=r"objects\[0\].instance_transform: give either"):
        scene(
            {"ring": {"count": 2, "radius": 1.0}},
            instance_transform={"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1.0]], "translate": [0, 0, 0.0]},
        )
