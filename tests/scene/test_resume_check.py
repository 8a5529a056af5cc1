"""Resume guard: the key paths where two resolved scenes differ, and which changes a resume accepts."""

from __future__ import annotations

import json

import pytest

from idp.errors import SceneError
from idp.scene.resume_check import check_resume_scene, scene_differences


def test_differences_are_named_by_key_path():
    old = {"time": {"h": 0.1, "steps": 5}, "objects": [{"material": {"E": 1.0}}, {"name": "b"}], "flag": True}
    new = {"time": {"h": 0.2, "steps": 5}, "objects": [{"material": {"E": 1.0, "nu": 0.3}}], "flag": 1, "x": 0}
    assert scene_differences(old, new) == ["time.h", "objects[0].material.nu", "objects[1]", "flag", "x"]
    assert scene_differences(old, json.loads(json.dumps(old))) == []


def test_only_steps_and_output_folder_may_change(tmp_path):
    old = {"time": {"steps": 5}, "output": {"dir": "a"}, "contact": {"dhat": 1e-3}}
    (tmp_path / "scene.resolved.json").write_text(json.dumps(old))
    check_resume_scene(tmp_path, {"time": {"steps": 9}, "output": {"dir": "b"}, "contact": {"dhat": 1e-3}})
    with pytest.raises(SceneError, match=r"contact\.dhat.*--force"):
        check_resume_scene(tmp_path, {**old, "contact": {"dhat": 2e-3}})
    check_resume_scene(tmp_path, {**old, "contact": {"dhat": 2e-3}}, force=True)  # forced: a warning only
    check_resume_scene(tmp_path / "elsewhere", old)  # no earlier run: nothing to compare


def test_an_unreadable_scene_record_is_refused_unless_forced(tmp_path):
    (tmp_path / "scene.resolved.json").write_text("{not json")
    with pytest.raises(SceneError, match="unreadable"):
        check_resume_scene(tmp_path, {})
    check_resume_scene(tmp_path, {}, force=True)


def test_long_lists_of_changes_are_cut_short(tmp_path):
    (tmp_path / "scene.resolved.json").write_text(json.dumps({f"k{i}": i for i in range(30)}))
    with pytest.raises(SceneError, match="and 18 more"):
        check_resume_scene(tmp_path, {f"k{i}": -i - 1 for i in range(30)})


def test_keys_added_by_a_newer_idp_at_their_defaults_are_no_change(tmp_path):
    """A run started before a key existed (its record lacks it) resumes when the key is at its default; a real
    change of an old key is still refused."""
    from idp.scene.load import resolved_scene_dict, scene_from_dict

    d = {"name": "s", "objects": [{"name": "ball", "generate": {"shape": "ball", "radius": 0.3, "resolution": 2}}]}
    resolved = resolved_scene_dict(scene_from_dict(d))
    old = json.loads(json.dumps(resolved))
    assert old["objects"][0].pop("density_regions") == []  # as written by an idp without per-region density
    (tmp_path / "scene.resolved.json").write_text(json.dumps(old))
    check_resume_scene(tmp_path, resolved)
    stiffer = json.loads(json.dumps(resolved))
    stiffer["objects"][0]["material"]["youngs_modulus"] = 2e4
    with pytest.raises(SceneError, match=r"objects\[0\]\.material\.youngs_modulus"):
        check_resume_scene(tmp_path, stiffer)


def test_stages_appended_after_the_last_one_are_no_change(tmp_path):
    old = {"time": {"steps": 5}, "stages": [{"name": "squash", "steps": 3}]}
    (tmp_path / "scene.resolved.json").write_text(json.dumps(old))
    check_resume_scene(tmp_path, {**old, "stages": [*old["stages"], {"name": "fold", "steps": 2}]})
    with pytest.raises(SceneError, match=r"stages\[0\]\.steps"):
        check_resume_scene(tmp_path, {**old, "stages": [{"name": "squash", "steps": 4}, {"name": "fold"}]})
