"""Properties of text → planar triangle meshes (idp.applications.text_mesh), default font DejaVu Sans."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from idp.applications.text_mesh import boundary_loops, default_font_path, text_to_mesh
from idp.errors import FontError

H = 1.0
EDGE = H / 12  # coarse: keeps the suite fast while still many triangles per stroke


@pytest.fixture(scope="module")
def meshes() -> dict[str, object]:
    return {s: text_to_mesh(s, height=H, edge_length=EDGE) for s in ["AB", "ox", "o", "A", "B"]}


def _edges(faces: np.ndarray) -> np.ndarray:
    e = np.sort(np.vstack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0)


def _signed_areas(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    a = v[f[:, 1], :2] - v[f[:, 0], :2]
    b = v[f[:, 2], :2] - v[f[:, 0], :2]
    return 0.5 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])


def _loop_area(v: np.ndarray, loop: np.ndarray) -> float:
    p = v[loop, :2]
    q = np.roll(p, -1, axis=0)
    return 0.5 * float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))


def _width(m) -> float:
    return float(np.ptp(m.vertices[:, 0]))


@pytest.mark.parametrize("text", ["AB", "ox"])
def test_planar_oriented_no_degenerate_no_duplicates(meshes, text):
    m = meshes[text]
    v, f = m.vertices, m.faces
    assert v.dtype == np.float64 and v.shape[1] == 3 and f.dtype == np.int64 and f.shape[1] == 3
    assert np.all(v[:, 2] == 0.0)
    area = _signed_areas(v, f)
    assert np.all(area > 1e-6 * EDGE**2), "every face normal is +z and no face is (near) zero-area"
    assert len(np.unique(v, axis=0)) == len(v), "duplicate vertices"
    assert np.array_equal(np.unique(f), np.arange(len(v))), "every vertex is used"
    # centred on the origin by the bounding box
    assert np.allclose(v.min(axis=0)[:2], -v.max(axis=0)[:2], atol=1e-12)


@pytest.mark.parametrize(
    ("text", "outer", "holes"), [("o", 1, 1), ("A", 1, 1), ("B", 1, 2), ("AB", 2, 3), ("ox", 2, 1)]
)
def test_boundary_loops_match_glyph_topology(meshes, text, outer, holes):
    m = meshes[text]
    loops = boundary_loops(m.faces)
    areas = [_loop_area(m.vertices, lp) for lp in loops]
    assert sum(a > 0 for a in areas) == outer, "outer contours run counter-clockwise"
    assert sum(a < 0 for a in areas) == holes, "holes run clockwise"
    # each boundary edge belongs to exactly one face: the loops are closed and cover every boundary edge once
    e = np.sort(np.vstack([m.faces[:, [0, 1]], m.faces[:, [1, 2]], m.faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert int(np.sum(counts == 1)) == sum(len(lp) for lp in loops)
    assert counts.max() <= 2, "non-manifold edge"


@pytest.mark.parametrize("text", ["AB", "ox"])
def test_euler_characteristic_is_components_minus_holes(meshes, text):
    m = meshes[text]
    f = m.faces
    n = len(m.vertices)
    e = _edges(f)
    adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    ncomp, _ = connected_components(adj, directed=False)
    holes = sum(_loop_area(m.vertices, lp) < 0 for lp in boundary_loops(f))
    assert n - len(e) + len(f) == ncomp - holes
    assert ncomp == len(text)  # these letters neither touch nor split into pieces


@pytest.mark.parametrize("text", ["AB", "ox"])
def test_edge_lengths_near_target_and_outline_on_boundary(meshes, text):
    m = meshes[text]
    e = _edges(m.faces)
    length = np.linalg.norm(m.vertices[e[:, 0]] - m.vertices[e[:, 1]], axis=1)
    assert 0.5 * EDGE < np.median(length) < 1.5 * EDGE
    assert length.max() < 2.0 * EDGE
    assert np.percentile(length, 5) > 0.25 * EDGE
    # the flattened outline's vertices (the first ones) all lie on the mesh boundary, so they can be fixed
    on_boundary = np.concatenate(boundary_loops(m.faces))
    assert set(range(m.extra["outline_vertices"])) <= set(on_boundary.tolist())


def test_quality_min_angle():
    m = text_to_mesh("ox", height=H, edge_length=EDGE)
    v, f = m.vertices[:, :2], m.faces
    angles = []
    for i in range(3):
        u = v[f[:, (i + 1) % 3]] - v[f[:, i]]
        w = v[f[:, (i + 2) % 3]] - v[f[:, i]]
        c = np.sum(u * w, axis=1) / np.linalg.norm(u, axis=1) / np.linalg.norm(w, axis=1)
        angles.append(np.degrees(np.arccos(np.clip(c, -1, 1))))
    smallest = np.min(angles, axis=0)
    assert np.median(smallest) > 35.0
    assert smallest.min() > 10.0  # "o" and "x" have no input corner sharper than that


def test_height_scales_cap_height_and_two_lines_are_taller():
    one = text_to_mesh("H", height=2.0, edge_length=2.0 / 8)
    assert np.ptp(one.vertices[:, 1]) == pytest.approx(2.0, rel=1e-9)  # "H" spans baseline to cap height
    two = text_to_mesh("H\nH", height=2.0, edge_length=2.0 / 8)
    wide = text_to_mesh("H\nH", height=2.0, edge_length=2.0 / 8, line_spacing=2.0)
    assert np.ptp(two.vertices[:, 1]) > 1.5 * np.ptp(one.vertices[:, 1])
    assert np.ptp(wide.vertices[:, 1]) > np.ptp(two.vertices[:, 1])
    assert np.ptp(two.vertices[:, 0]) == pytest.approx(np.ptp(one.vertices[:, 0]), rel=1e-9)  # left-aligned


def _unkerned_width(text: str, height: float) -> float:
    """Ink width of ``text`` placed by advance widths alone (no kerning), computed with fontTools directly."""
    from fontTools.pens.boundsPen import BoundsPen
    from fontTools.ttLib import TTFont

    tt = TTFont(default_font_path())
    gs = tt.getGlyphSet()
    cmap = tt.getBestCmap()

    def bounds(name: str) -> tuple[float, float, float, float]:
        pen = BoundsPen(gs)
        gs[name].draw(pen)
        return pen.bounds

    scale = height / bounds(cmap[ord("H")])[3]
    x, lo, hi = 0.0, np.inf, -np.inf
    for ch in text:
        name = cmap[ord(ch)]
        b = bounds(name)
        lo, hi = min(lo, x + b[0]), max(hi, x + b[2])
        x += tt["hmtx"][name][0]
    return (hi - lo) * scale


def test_kerning_from_the_font_tightens_av():
    # control: "HH" has no kerning pair, so its width equals the advance-only layout (validates the reference)
    hh = text_to_mesh("HH", height=H, edge_length=H / 6)
    assert _width(hh) == pytest.approx(_unkerned_width("HH", H), abs=1e-6)
    av = text_to_mesh("AV", height=H, edge_length=H / 6)
    assert _width(av) < _unkerned_width("AV", H) - 0.02 * H, "A-V kerning of DejaVu Sans was not applied"


def test_overlapping_contours_fill_nonzero_and_holes_by_winding():
    from idp.applications.text_mesh import _glyph_region

    sq = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], float)
    overlapping = _glyph_region([sq, sq + 1.0])  # same orientation: union, no hole at the overlap
    assert overlapping.area == pytest.approx(7.0) and len(list(overlapping.interiors)) == 0
    hole = _glyph_region([sq * 2, (sq + 1.0)[::-1]])  # reversed inner contour: a hole
    assert hole.area == pytest.approx(12.0) and len(list(hole.interiors)) == 1


def _cff_font(path: Path) -> Path:
    """A one-glyph CFF (cubic) font: "O" = a ring of two cubic circles, the inner one reversed."""
    from fontTools.fontBuilder import FontBuilder
    from fontTools.pens.t2CharStringPen import T2CharStringPen

    def circle(pen, cx, cy, r, reverse):
        k = 0.5523 * r
        pts = [(cx + r, cy), (cx, cy + r), (cx - r, cy), (cx, cy - r)]
        ctrl = [
            ((cx + r, cy + k), (cx + k, cy + r)),
            ((cx - k, cy + r), (cx - r, cy + k)),
            ((cx - r, cy - k), (cx - k, cy - r)),
            ((cx + k, cy - r), (cx + r, cy - k)),
        ]
        segs = [(ctrl[i][0], ctrl[i][1], pts[(i + 1) % 4]) for i in range(4)]
        if reverse:  # same circle traversed clockwise: each segment backwards, in reverse order
            segs = [(c2, c1, pts[i]) for i, (c1, c2, _) in enumerate(segs)][::-1]
        pen.moveTo(pts[0])
        for c1, c2, p in segs:
            pen.curveTo(c1, c2, p)
        pen.closePath()

    fb = FontBuilder(1000, isTTF=False)
    fb.setupGlyphOrder([".notdef", "space", "O"])
    fb.setupCharacterMap({32: "space", ord("O"): "O"})
    strings = {}
    for name in (".notdef", "space"):
        strings[name] = T2CharStringPen(500, None).getCharString()
    pen = T2CharStringPen(800, None)
    circle(pen, 400, 350, 350, reverse=False)
    circle(pen, 400, 350, 200, reverse=True)
    strings["O"] = pen.getCharString()
    fb.setupCFF("TestO", {"FullName": "Test O"}, strings, {})
    fb.setupHorizontalMetrics({".notdef": (500, 0), "space": (500, 0), "O": (800, 50)})
    fb.setupHorizontalHeader(ascent=800, descent=-200)
    fb.setupNameTable({"familyName": "TestO", "styleName": "Regular"})
    fb.setupOS2(sTypoAscender=800, usWinAscent=800, usWinDescent=200, sCapHeight=700, version=2)
    fb.setupPost()
    fb.save(str(path))
    return path


def test_cff_cubic_outlines(tmp_path):
    font = _cff_font(tmp_path / "o.otf")
    m = text_to_mesh("O", font, height=1.0, edge_length=0.05)
    loops = boundary_loops(m.faces)
    areas = sorted(_loop_area(m.vertices, lp) for lp in loops)
    assert len(loops) == 2 and areas[0] < 0 < areas[1]
    # the ring's area in output units (cap height 700 units → 1): π (350² − 200²) / 700²
    assert sum(areas) == pytest.approx(np.pi * (350**2 - 200**2) / 700**2, rel=1e-2)
    assert np.ptp(m.vertices[:, 1]) == pytest.approx(1.0, rel=1e-2)


@pytest.mark.parametrize("text", ["", "   ", " \n\t "])
def test_empty_text_is_rejected_before_the_font_is_read(text, tmp_path):
    garbage = tmp_path / "never-read.ttf"
    garbage.write_bytes(b"\x00garbage")
    with pytest.raises(FontError, match="empty or whitespace"):
        text_to_mesh(text, garbage)


def test_missing_glyph_names_character_and_font():
    with pytest.raises(FontError, match=r"U\+E000") as info:
        text_to_mesh("A\ue000B")
    assert "DejaVuSans.ttf" in str(info.value)


def test_unreadable_font_names_file_and_reason(tmp_path):
    bad = tmp_path / "broken.ttf"
    bad.write_bytes(b"this is not a font" * 10)
    with pytest.raises(FontError, match=r"broken\.ttf") as info:
        text_to_mesh("A", bad)
    assert "cannot read font file" in str(info.value)
    with pytest.raises(FontError, match=r"missing\.ttf"):
        text_to_mesh("A", tmp_path / "missing.ttf")


def test_glyphs_that_touch_become_one_region():
    # DejaVu's underscores span their full advance: consecutive ones abut and must merge into one piece
    m = text_to_mesh("___", height=H, edge_length=EDGE)
    loops = boundary_loops(m.faces)
    assert len(loops) == 1 and _loop_area(m.vertices, loops[0]) > 0
    single = text_to_mesh("_", height=H, edge_length=EDGE)
    assert _width(m) > 2.5 * _width(single)
