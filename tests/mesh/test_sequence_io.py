"""Animation sequences: read and write back in every form (OBJ folder, PVD, npz, USD), exactly; resume; errors."""

import sys

import meshio
import numpy as np
import pytest

from idp.errors import MeshError
from idp.mesh.generate import ellipsoid_surface
from idp.mesh.sequence import _natural_key, check_all_frames, fan_triangulate, open_sequence
from idp.output.sequence import sequence_writer

F = 5


def _frames(num: int = F) -> tuple[np.ndarray, np.ndarray]:
    """A sphere (42 vertices, 80 triangles) growing and drifting over ``num`` frames, values with long decimals."""
    s = ellipsoid_surface(subdivisions=1)
    k = np.arange(num, dtype=float)[:, None, None]
    v = s.vertices[None] * (1.0 + 0.1 * k) + np.array([1 / 3, 0.1, 2 / 7]) * k
    return v, s.faces


def _obj_text(v: np.ndarray, faces: np.ndarray, k: int) -> str:
    """An OBJ as DCC tools export it: comments, vt/vn, groups, materials, v/vt/vn faces, CRLF line ends."""
    lines = [f"# exported frame {k}", "mtllib shell.mtl", "o shell"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
    lines += ["vt 0 0", "vt 1 0", "vt 0 1", "vn 0 0 1", "g shell_group", "usemtl skin", "s 1"]
    lines += [f"f {a + 1}/1/1 {b + 1}/2/1 {c + 1}/3/1" for a, b, c in faces.tolist()]
    return "\r\n".join(lines) + "\r\n"


def _obj_folder(folder, v, faces, numbers=None, stem="shell"):
    folder.mkdir(parents=True, exist_ok=True)
    numbers = list(range(len(v))) if numbers is None else numbers
    for k, num in enumerate(numbers):
        (folder / f"{stem}{num}.obj").write_bytes(_obj_text(v[k], faces, k).encode())
    return folder


def _pvd(folder, v, faces, times):
    (folder / "data").mkdir(parents=True)
    rows = []
    for k, t in enumerate(times):
        mesh = meshio.Mesh(v[k], [("triangle", faces)], point_data={"temperature": np.full(len(v[k]), float(k))})
        meshio.write(folder / "data" / f"step{k}.vtu", mesh)
        rows.append(f'<DataSet timestep="{t}" part="0" file="data/step{k}.vtu"/>')
    body = "\n".join(rows)
    text = f'<?xml version="1.0"?><VTKFile type="Collection"><Collection>{body}</Collection></VTKFile>'
    (folder / "anim.pvd").write_text(text)
    return folder / "anim.pvd"


def _all(seq):
    return np.stack([seq.frame(k) for k in range(seq.num_frames)])


def _non_vertex_lines(path):
    return [ln for ln in path.read_bytes().splitlines(keepends=True) if not ln.startswith(b"v ")]


# ---------------------------------------------------------------------- OBJ
def test_obj_folder_natural_order_and_round_trip(tmp_path):
    v, faces = _frames()
    src = _obj_folder(tmp_path / "in", v, faces, numbers=[1, 2, 3, 10, 11])
    seq = open_sequence(src)
    assert seq.format == "obj" and seq.num_frames == F and seq.num_vertices == 42
    assert [f.name for f in seq.frame_files] == ["shell1.obj", "shell2.obj", "shell3.obj", "shell10.obj", "shell11.obj"]
    assert np.array_equal(seq.faces, faces) and seq.faces.dtype == np.int64
    x = seq.frame(3)
    assert x.dtype == np.float64 and x.flags.c_contiguous and np.array_equal(x, v[3])
    assert seq.describe(3) == f"frame 3 ({src / 'shell10.obj'})"
    check_all_frames(seq)

    moved = v + 1e-3 * np.sin(np.arange(v.size)).reshape(v.shape)
    with sequence_writer(tmp_path / "out", seq.faces, like=seq) as w:
        for k in range(F):
            w.write(k, moved[k])
    back = open_sequence(tmp_path / "out")
    assert [f.name for f in back.frame_files] == [f.name for f in seq.frame_files]
    assert np.array_equal(_all(back), moved) and np.array_equal(back.faces, faces)
    for a, b in zip(seq.frame_files, back.frame_files, strict=True):
        assert _non_vertex_lines(a) == _non_vertex_lines(b)  # vt/vn/g/usemtl/comments/faces and CRLF kept
        assert b.read_bytes().count(b"\r\n") == a.read_bytes().count(b"\r\n")


def test_obj_glob_and_unnumbered_files_last(tmp_path):
    v, faces = _frames()
    _obj_folder(tmp_path, v[:3], faces, stem="shell")
    _obj_folder(tmp_path, v[3:], faces, stem="cloth")
    seq = open_sequence(tmp_path / "shell*.obj")
    assert [f.name for f in seq.frame_files] == ["shell0.obj", "shell1.obj", "shell2.obj"]
    assert np.array_equal(_all(seq), v[:3])
    names = ["rest.obj", "a10.obj", "a9.obj", "base.obj", "frame_2_v3.obj"]
    from pathlib import Path

    ordered = [p.name for p in sorted((Path(n) for n in names), key=_natural_key)]
    assert ordered == ["frame_2_v3.obj", "a9.obj", "a10.obj", "base.obj", "rest.obj"]


def test_obj_writer_without_obj_input_and_unchanged_copies_bytes(tmp_path):
    v, faces = _frames()
    np.savez(tmp_path / "seq.npz", vertices=v, faces=faces)
    seq = open_sequence(tmp_path / "seq.npz")
    w = sequence_writer(tmp_path / "out", faces, like=seq, format="obj")
    for k in range(F):
        w.write(k, seq.frame(k))
    w.close()
    back = open_sequence(tmp_path / "out")
    assert [f.name for f in back.frame_files] == [f"frame_{k:05d}.obj" for k in range(F)]
    assert np.array_equal(_all(back), v)

    src = _obj_folder(tmp_path / "in", v, faces)
    seq = open_sequence(src)
    w = sequence_writer(tmp_path / "copy", faces, like=seq)
    w.write(0, seq.frame(0), unchanged=True)
    w.write(1, seq.frame(1) + 1.0)
    assert w.frames_written() == [0, 1]
    assert (tmp_path / "copy" / "shell0.obj").read_bytes() == (src / "shell0.obj").read_bytes()
    assert (tmp_path / "copy" / "shell1.obj").read_bytes() != (src / "shell1.obj").read_bytes()
    with pytest.raises(MeshError, match=r"frame\(s\) 2, 3, 4 not written"):
        w.close()
    assert not list((tmp_path / "copy").glob("*.tmp"))


# ---------------------------------------------------------------------- PVD
def test_pvd_round_trip_keeps_timesteps_and_point_data(tmp_path):
    v, faces = _frames()
    times = [0.0, 0.25, 0.5, 0.75, 1.0]
    pvd = _pvd(tmp_path / "in", v, faces, times)
    seq = open_sequence(pvd)
    assert seq.format == "pvd" and seq.frame_times == times
    assert np.array_equal(_all(seq), v) and np.array_equal(seq.faces, faces)
    assert "t=0.25" in seq.describe(1)

    moved = v * (1 + 1e-7)
    with sequence_writer(tmp_path / "out", faces, like=seq) as w:
        w.write(0, v[0], unchanged=True)
        for k in range(1, F):
            w.write(k, moved[k])
    out_pvd = tmp_path / "out" / "anim.pvd"
    back = open_sequence(out_pvd)
    assert back.frame_times == times
    assert [f.name for f in back.frame_files] == [f"step{k}.vtu" for k in range(F)]
    assert np.array_equal(back.frame(0), v[0]) and np.array_equal(_all(back)[1:], moved[1:])
    assert (tmp_path / "out" / "vtu" / "step0.vtu").read_bytes() == (
        tmp_path / "in" / "data" / "step0.vtu"
    ).read_bytes()
    m = meshio.read(tmp_path / "out" / "vtu" / "step3.vtu")
    assert np.array_equal(m.point_data["temperature"], np.full(42, 3.0))


def test_pvd_from_npz_uses_frame_index_as_timestep(tmp_path):
    v, faces = _frames()
    np.savez(tmp_path / "seq.npz", vertices=v, faces=faces)
    seq = open_sequence(tmp_path / "seq.npz")
    with sequence_writer(tmp_path / "out", faces, like=seq, format="pvd") as w:
        for k in range(F):
            w.write(k, seq.frame(k))
    back = open_sequence(tmp_path / "out" / "frames.pvd")
    assert back.frame_times == [float(k) for k in range(F)]
    assert np.array_equal(_all(back), v)


# ---------------------------------------------------------------------- npz
def test_npz_fortran_input_round_trip(tmp_path):
    v, faces = _frames()
    np.savez(tmp_path / "seq.npz", vertices=np.asfortranarray(v), faces=faces.astype(np.int32))
    seq = open_sequence(tmp_path / "seq.npz")
    assert seq.format == "npz" and seq.num_frames == F
    x = seq.frame(2)
    assert x.flags.c_contiguous and np.array_equal(x, v[2])
    w = sequence_writer(tmp_path / "repaired", faces, like=seq)
    assert w.out == tmp_path / "repaired.npz"
    for k in range(F):
        w.write(k, v[k] * 2)
    w.close()
    assert not (tmp_path / "repaired.npz.partial").exists()
    with np.load(tmp_path / "repaired.npz") as data:
        assert data["vertices"].dtype == np.float64 and data["faces"].dtype == np.int64
        assert np.array_equal(data["vertices"], v * 2) and np.array_equal(data["faces"], faces)


def test_npz_resume_keeps_earlier_frames(tmp_path):
    v, faces = _frames()
    out = tmp_path / "out.npz"
    w = sequence_writer(out, faces)
    w.write(0, v[0])
    w.write(1, v[1])
    del w  # interrupted: never closed
    w = sequence_writer(out, faces)
    assert w.frames_written() == [0, 1]
    with pytest.raises(ValueError, match="43 vertices, the sequence has 42"):
        w.write(2, np.zeros((43, 3)))
    for k in range(2, F):
        w.write(k, v[k])
    w.close()
    with np.load(out) as data:
        assert np.array_equal(data["vertices"], v)
    w = sequence_writer(out, faces)
    w.write(0, v[0])
    del w
    with pytest.raises(MeshError, match="different mesh"):
        sequence_writer(out, faces[:, ::-1])


# ---------------------------------------------------------------------- USD
def _usd_input(path, v, faces, quads=False):
    from pxr import Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    stage.SetTimeCodesPerSecond(30)
    UsdGeom.Xform.Define(stage, "/World")
    UsdGeom.Mesh.Define(stage, "/World/Static").GetPointsAttr().Set(Vt.Vec3fArray([(0, 0, 0)] * 3))
    mesh = UsdGeom.Mesh.Define(stage, "/World/Shell")
    if quads:
        counts = np.full(faces.shape[0], 4, np.int32)
    else:
        counts = np.full(faces.shape[0], 3, np.int32)
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(counts))
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(faces.astype(np.int32).reshape(-1)))
    for k in range(len(v)):
        mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(v[k].astype(np.float32)), 1001 + k)
    stage.GetRootLayer().Save()
    return path


@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".usd"])
def test_usd_round_trip_keeps_prim_time_codes_and_rate(tmp_path, suffix):
    pytest.importorskip("pxr")
    from pxr import Usd

    v, faces = _frames()
    v = v.astype(np.float32).astype(np.float64)  # USD points are float32
    seq = open_sequence(_usd_input(tmp_path / f"in{suffix}", v, faces))
    assert seq.format == "usd" and seq.prim_path == "/World/Shell" and not seq.had_polygons
    assert seq.frame_times == [1001.0 + k for k in range(F)] and seq.time_codes_per_second == 30
    assert np.array_equal(_all(seq), v) and np.array_equal(seq.faces, faces)

    moved = (v * 1.5).astype(np.float32).astype(np.float64)
    w = sequence_writer(tmp_path / f"out{suffix}", faces, like=seq)
    assert w.coordinate_dtype == np.float32
    for k in range(F):
        w.write(k, moved[k])
    w.close()
    back = open_sequence(tmp_path / f"out{suffix}")
    assert back.prim_path == "/World/Shell" and back.frame_times == seq.frame_times
    assert back.time_codes_per_second == 30
    assert np.array_equal(_all(back), moved)
    stage = Usd.Stage.Open(str(tmp_path / f"out{suffix}"))
    assert stage.GetPrimAtPath("/World/Static").IsValid()
    assert (tmp_path / f"out{suffix}").read_bytes().startswith(b"PXR-USDC") == (suffix != ".usda")


def test_usd_polygons_stay_polygons_and_new_stage(tmp_path):
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom

    cube = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    quads = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])
    v = np.stack([cube + 0.5 * k for k in range(3)])
    seq = open_sequence(_usd_input(tmp_path / "box.usda", v, quads, quads=True), usd_prim="/World/Shell")
    assert seq.had_polygons and seq.faces.shape == (12, 3)
    assert seq.faces[:2].tolist() == [[0, 1, 3], [0, 3, 2]]
    with sequence_writer(tmp_path / "out.usda", seq.faces, like=seq) as w:
        for k in range(3):
            w.write(k, seq.frame(k) * 2)
    stage = Usd.Stage.Open(str(tmp_path / "out.usda"))  # keep the stage alive while its prims are used
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Shell"))
    assert list(mesh.GetFaceVertexCountsAttr().Get()) == [4] * 6
    assert np.array_equal(_all(open_sequence(tmp_path / "out.usda")), v * 2)

    # a new stage when the input is not USD
    np.savez(tmp_path / "s.npz", vertices=v, faces=seq.faces)
    flat = open_sequence(tmp_path / "s.npz")
    with sequence_writer(tmp_path / "fresh.usdc", flat.faces, like=flat, format="usd") as w:
        for k in range(3):
            w.write(k, flat.frame(k))
    fresh = open_sequence(tmp_path / "fresh.usdc")
    assert fresh.prim_path == "/Sequence/Mesh" and fresh.frame_times == [0.0, 1.0, 2.0]
    assert np.array_equal(_all(fresh), v) and np.array_equal(fresh.faces, seq.faces)


def test_usd_resume_keeps_earlier_frames(tmp_path):
    pytest.importorskip("pxr")
    v, faces = _frames()
    v = v.astype(np.float32).astype(np.float64)
    seq = open_sequence(_usd_input(tmp_path / "in.usdc", v, faces))
    w = sequence_writer(tmp_path / "out.usdc", faces, like=seq)
    w.write(0, v[0] + 1)
    w.write(3, v[3] + 1)
    del w
    assert (tmp_path / "out.usdc.partial" / "frame_00003.npy").is_file()
    w = sequence_writer(tmp_path / "out.usdc", faces, like=seq)
    assert w.frames_written() == [0, 3]
    for k in (1, 2, 4):
        w.write(k, v[k] + 1)
    w.close()
    assert not (tmp_path / "out.usdc.partial").exists()
    rounded = (v + 1).astype(np.float32).astype(np.float64)  # the writer rounds to the stored point3f precision
    assert np.array_equal(_all(open_sequence(tmp_path / "out.usdc")), rounded)


def test_usd_errors(tmp_path):
    pytest.importorskip("pxr")
    v, faces = _frames(2)
    path = _usd_input(tmp_path / "in.usda", v, faces)
    with pytest.raises(MeshError, match="mesh /World/Static has no time-sampled points"):
        open_sequence(path, usd_prim="/World/Static")
    with pytest.raises(MeshError, match="not a Mesh"):
        open_sequence(path, usd_prim="/World")
    with pytest.raises(MeshError, match="no prim at /Nope"):
        open_sequence(path, usd_prim="/Nope")
    (tmp_path / "bad.usda").write_text("#usda 1.0\ndef Mesh (\n")
    with pytest.raises(MeshError, match=r"cannot read USD file .*bad\.usda"):
        open_sequence(tmp_path / "bad.usda")
    with pytest.raises(MeshError, match="face 0 has 2 vertices"):
        fan_triangulate(np.array([2, 3]), np.arange(5), "x")


def test_usd_missing_names_the_extra(tmp_path, monkeypatch):
    (tmp_path / "a.usda").write_text("#usda 1.0\n")
    monkeypatch.setitem(sys.modules, "pxr", None)
    with pytest.raises(MeshError, match=r"pip install 'idp\[usd\]'"):
        open_sequence(tmp_path / "a.usda")


# ---------------------------------------------------------------------- bad input
def test_missing_empty_and_unmatched_inputs(tmp_path):
    with pytest.raises(MeshError, match=r"sequence not found: .*nope"):
        open_sequence(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(MeshError, match=r"empty holds no \.obj files"):
        open_sequence(tmp_path / "empty")
    with pytest.raises(MeshError, match=r"shell\*\.obj' matches nothing"):
        open_sequence(tmp_path / "shell*.obj")
    v, faces = _frames(2)
    _obj_folder(tmp_path / "two", v, faces, stem="a")
    _obj_folder(tmp_path / "two", v, faces, stem="b")
    with pytest.raises(MeshError, match="both have frame number 0"):
        open_sequence(tmp_path / "two")


def _broken(tmp_path, k, edit):
    v, faces = _frames()
    src = _obj_folder(tmp_path / "in", v, faces)
    path = src / f"shell{k}.obj"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(edit(lines)))
    return open_sequence(src), path


def test_bad_obj_frames_name_frame_and_file(tmp_path):
    def nan_at_17(lines):
        lines[3 + 17] = "v nan 0 0\n"
        return lines

    seq, path = _broken(tmp_path / "a", 3, nan_at_17)
    with pytest.raises(MeshError, match=rf"frame 3 \({path}\): non-finite coordinate at vertex 17"):
        seq.frame(3)
    with pytest.raises(MeshError, match="frame 3"):
        check_all_frames(seq)

    seq, path = _broken(tmp_path / "b", 4, lambda lines: ["v 0 0 0\n", *lines])
    with pytest.raises(MeshError, match=rf"frame 4 \({path}\): 43 vertices, frame 0 has 42"):
        seq.frame(4)

    seq, path = _broken(tmp_path / "c", 1, lambda lines: [ln for ln in lines if not ln.startswith("f 1/")])
    with pytest.raises(MeshError, match=rf"frame 1 \({path}\): \d+ triangles, frame 0 has 80"):
        seq.frame(1)

    def swap(lines):
        i = next(j for j, ln in enumerate(lines) if ln.startswith("f "))
        a, b, c = lines[i].split()[1:]
        lines[i] = f"f {b} {a} {c}\n"
        return lines

    seq, path = _broken(tmp_path / "d", 2, swap)
    with pytest.raises(MeshError, match=rf"frame 2 \({path}\): face list differs from frame 0's"):
        seq.frame(2)

    seq, path = _broken(tmp_path / "e", 2, lambda lines: [*lines, "v 1 2 x\n"])
    with pytest.raises(MeshError, match=rf"frame 2: {path}:\d+: bad number"):
        seq.frame(2)

    with pytest.raises(MeshError, match=r"frame 0: .*shell0\.obj: no faces"):
        _broken(tmp_path / "f", 0, lambda lines: [ln for ln in lines if not ln.startswith("f ")])

    with pytest.raises(MeshError, match=r"frame 0: .*shell0\.obj:\d+: face index 99 out of range"):
        _broken(tmp_path / "g", 0, lambda lines: [*lines, "f 1 2 99\n"])

    with pytest.raises(MeshError, match=r"frame 0 \(.*shell0\.obj\): non-finite coordinate at vertex 0"):
        _broken(tmp_path / "h", 0, lambda lines: [*lines[:3], "v inf 0 0\n", *lines[4:]])


def test_bad_npz_inputs(tmp_path):
    v, faces = _frames()
    cases = {
        "keys": ({"verts": v, "faces": faces}, "missing key.*vertices"),
        "shape": ({"vertices": v[0], "faces": faces}, r"vertices must be \(F, n, 3\)"),
        "faces_shape": ({"vertices": v, "faces": faces[:, :2]}, r"faces must be \(m, 3\)"),
        "range": ({"vertices": v, "faces": faces + 1}, r"outside \[0, 42\)"),
        "empty": ({"vertices": v, "faces": np.zeros((0, 3), np.int64)}, "no triangles"),
        "float_faces": ({"vertices": v, "faces": faces.astype(float)}, "integer vertex indices"),
    }
    for name, (arrays, msg) in cases.items():
        np.savez(tmp_path / f"{name}.npz", **arrays)
        with pytest.raises(MeshError, match=rf"{name}\.npz.*{msg}"):
            open_sequence(tmp_path / f"{name}.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip file")
    with pytest.raises(MeshError, match=r"cannot read sequence file .*junk\.npz"):
        open_sequence(tmp_path / "junk.npz")
    bad = v.copy()
    bad[2, 7, 1] = np.nan
    np.savez(tmp_path / "nan.npz", vertices=bad, faces=faces)
    seq = open_sequence(tmp_path / "nan.npz")
    with pytest.raises(MeshError, match=r"frame 2 \(.*nan\.npz, vertices\[2\]\): non-finite coordinate at vertex 7"):
        check_all_frames(seq)


def test_bad_pvd_inputs(tmp_path):
    v, faces = _frames(3)
    pvd = _pvd(tmp_path / "in", v, faces, [0, 1, 2])
    (tmp_path / "in" / "data" / "step1.vtu").unlink()
    seq = open_sequence(pvd)
    with pytest.raises(MeshError, match=r"frame 1 \(.*step1\.vtu, t=1\.0\): file not found"):
        seq.frame(1)
    (tmp_path / "in" / "data" / "step2.vtu").write_text("garbage")
    with pytest.raises(MeshError, match=r"frame 2: cannot read mesh file .*step2\.vtu"):
        seq.frame(2)
    (tmp_path / "bad.pvd").write_text("<VTKFile><Collection>")
    with pytest.raises(MeshError, match=r"cannot read PVD file .*bad\.pvd"):
        open_sequence(tmp_path / "bad.pvd")
    meshio.write(tmp_path / "in" / "data" / "step1.vtu", meshio.Mesh(v[1][:-1], [("triangle", faces[:3])]))
    with pytest.raises(MeshError, match=r"frame 1 \(.*step1\.vtu, t=1\.0\): 41 vertices, frame 0 has 42"):
        seq.frame(1)


def test_writer_refuses_to_overwrite_input_and_bad_arguments(tmp_path):
    v, faces = _frames()
    src = _obj_folder(tmp_path / "in", v, faces)
    seq = open_sequence(src)
    with pytest.raises(MeshError, match="would overwrite the input"):
        sequence_writer(src, faces, like=seq)
    with pytest.raises(ValueError, match="faces differ"):
        sequence_writer(tmp_path / "out", faces[::-1], like=seq)
    with pytest.raises(ValueError, match="cannot tell the sequence format"):
        sequence_writer(tmp_path / "out", faces)
    w = sequence_writer(tmp_path / "out", faces, like=seq)
    with pytest.raises(ValueError, match="frame 1: non-finite coordinate at vertex 5"):
        bad = v[1].copy()
        bad[5, 0] = np.inf
        w.write(1, bad)
    with pytest.raises(IndexError):
        w.write(F, v[0])
