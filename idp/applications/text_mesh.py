"""Text → planar triangle mesh, the input of inflated 3D type (paper §7.2 "Inflation", Fig. 14, ``idp font``).

Pipeline: glyph outlines from fontTools (TrueType quadratic and CFF cubic curves, flattened to a tolerance tied to
the target edge length), layout by HarfBuzz (``uharfbuzz``: advances and the font's kerning), filled regions built
with shapely under the font's fill rule (nonzero) and unioned across contours and glyphs, then a quality
triangulation whose boundary is exactly the (resampled) outline.

Scale and placement: ``height`` is the cap height (OS/2 ``sCapHeight``, else the top of "H"), the default target
edge length is ``height / 40``; lines are left-aligned, ``line_spacing`` × the font's line height apart, and the
result is centred on the origin by its bounding box. Default font: DejaVu Sans from matplotlib's wheel.

Mesher choice (measured on this machine, default font, height 1, edge e = 1/40; "min/p1/median angle" is the
smallest angle per triangle, "L" edge length / e as min / 5 % / median / 95 % / max):

* pythoncdt (CDT library, MPL-2.0), constrained Delaunay + refinement (smallest angle 30°, area ≤ 1.5 × the
  equilateral triangle of side e) — CHOSEN. "AB": 2652 triangles, angles min 6.8° / p1 31.4° / median 48.2°,
  L 0.16 / 0.74 / 0.99 / 1.34 / 1.64, 0.45 s; "ox": 1761 triangles, 27.9° / 32.1° / 47.9°,
  L 0.69 / 0.74 / 0.96 / 1.33 / 1.61; "Seriously": 7225 triangles, 14.7° / 30.9° / 47.6°, L 0.16 / … / 1.70,
  0.3 s. The minimum angles below 30° sit at sharp outline corners and short outline edges, which are input.
  All outline vertices are kept exactly; 0–8 midpoints of encroached outline segments are added (they lie on
  the outline).
* mapbox_earcut (ISC) or shapely's GEOS CDT, then gpytoolbox.remesh_botsch (MIT) with the boundary fixed:
  remeshing is blocked next to fixed vertices, so quality stays that of the input (median smallest angle
  ~21°, p1 ~11°, edges up to 4 e on "AB"/"Seriously"); earcut alone gives zero-area triangles on collinear
  resampled outline points.
* wildmeshing (MPL-2.0, TriWild) ``triangulate_data``: does not keep the outline vertices (95 of 355 kept on
  "ox") and ignored the target length at stage 1 (edges 0.9–13 e). Rejected.

The mesh boundary is exactly the cleaned, resampled outline (counter-clockwise outer loops, clockwise holes),
so it can be fixed when the interior is inflated.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from idp.errors import FontError, MeshError
from idp.mesh.types import SurfaceMesh

if TYPE_CHECKING:  # heavy imports stay lazy at run time
    from shapely.geometry.base import BaseGeometry

#: default target edge length as a fraction of ``height`` (cap height): 1/40 gives ~2000 triangles for "AB"
DEFAULT_EDGE_FRACTION = 1.0 / 40.0
#: curves are flattened so the polyline deviates from the curve by at most this fraction of the edge length
FLATTEN_FRACTION = 0.05
#: connected pieces and holes smaller than (this × edge length)² are slivers and dropped
SLIVER_FRACTION = 0.5
#: gaps narrower than this fraction of the edge length are closed (glyphs that touch at a point become one region)
CLOSE_FRACTION = 0.02
#: quality refinement: smallest angle asked of every triangle not fixed by a sharper input corner
MIN_ANGLE_DEG = 30.0
#: largest triangle area as a multiple of the equilateral triangle of side ``edge_length``
AREA_FACTOR = 1.5
#: refinement never creates edges shorter than this fraction of the edge length
MIN_EDGE_FRACTION = 0.25
#: finest edge length as a fraction of ``height`` (10x the default's detail, ~10^5 triangles per glyph); finer
#: meshes take minutes (height/1000: 7 s and 7·10^5 triangles for one "A") and 1e-300 breaks GEOS
MAX_DETAIL = 400
#: ``height`` range (scene units) in which GEOS's tolerances and squared lengths stay well inside float64
HEIGHT_RANGE = (1e-6, 1e6)

_LINE_BREAKS = "\n\r\u2028\u2029"


def default_font_path() -> Path:
    """DejaVu Sans as shipped in matplotlib's wheel (``mpl-data/fonts/ttf``): always installed, never downloaded."""
    import matplotlib

    return Path(matplotlib.get_data_path()) / "fonts" / "ttf" / "DejaVuSans.ttf"


# ---------------------------------------------------------------------------------------------------------------
# font loading and checks


@dataclass
class _Font:
    """A loaded font: fontTools for outlines and metrics, the raw bytes for HarfBuzz."""

    path: Path
    data: bytes
    tt: Any  # fontTools.ttLib.TTFont
    units_per_em: int
    cap_height: float  # font units
    line_height: float  # font units (ascender − descender + line gap)


def _load_font(font: str | Path | None) -> _Font:
    """Read a TrueType/OpenType font (``.ttf``/``.otf``, ``glyf`` or ``CFF``/``CFF2`` outlines) or raise FontError."""
    from fontTools.ttLib import TTFont

    path = default_font_path() if font is None else Path(font)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise FontError(f"cannot read font file {path}: {e.strerror or e}") from e
    except ValueError as e:  # a name the OS cannot take (an embedded NUL byte)
        raise FontError(f"cannot read font file {str(path)!r}: {e}") from e
    try:
        tt = TTFont(io.BytesIO(data), fontNumber=0, lazy=False)
        units_per_em = int(tt["head"].unitsPerEm)
        cmap = tt.getBestCmap()
        glyph_set = tt.getGlyphSet()
        hhea = tt["hhea"]
    except Exception as e:  # fontTools raises many kinds (TTLibError, struct.error, KeyError, AssertionError)
        raise FontError(f"cannot read font file {path}: {type(e).__name__}: {e}") from e
    if cmap is None:
        raise FontError(f"font file {path} has no usable Unicode character map (cmap)")
    if not any(t in tt for t in ("glyf", "CFF ", "CFF2")):
        raise FontError(
            f"font file {path} has no outline table (glyf, CFF or CFF2); bitmap-only fonts are not supported"
        )
    if units_per_em <= 0:
        raise FontError(f"font file {path}: unitsPerEm is {units_per_em}")
    cap = 0.0
    os2 = tt["OS/2"] if "OS/2" in tt else None
    if os2 is not None and getattr(os2, "version", 0) >= 2:
        cap = float(getattr(os2, "sCapHeight", 0) or 0)
    if cap <= 0:  # OS/2 version < 2 (e.g. DejaVu) has no sCapHeight: measure the flat top of "H"
        name = cmap.get(ord("H"))
        if name is not None:
            from fontTools.pens.boundsPen import BoundsPen

            pen = BoundsPen(glyph_set)
            glyph_set[name].draw(pen)
            if pen.bounds is not None:
                cap = float(pen.bounds[3])
    if cap <= 0:
        cap = 0.7 * units_per_em  # typical Latin cap height when the font cannot tell
    line_height = float(hhea.ascent - hhea.descent + hhea.lineGap)
    if line_height <= 0:
        line_height = 1.2 * units_per_em
    return _Font(path, data, tt, units_per_em, cap, line_height)


def _check_text(text: str) -> list[str]:
    """Split into lines; reject empty or whitespace-only text before any font work."""
    if not isinstance(text, str):
        raise FontError(f"text must be a str, got {type(text).__name__}")
    if not text.strip():
        raise FontError(f"text {text!r} is empty or whitespace only: nothing to mesh")
    return text.replace("\r\n", "\n").replace("\r", "\n").replace("\u2028", "\n").replace("\u2029", "\n").split("\n")


def _check_coverage(lines: list[str], font: _Font) -> None:
    """Every character must have a glyph in the font's character map (no silent .notdef boxes)."""
    cmap = font.tt.getBestCmap()
    missing = sorted({c for line in lines for c in line if ord(c) not in cmap and c not in _LINE_BREAKS})
    if missing:
        shown = ", ".join(f"{c!r} (U+{ord(c):04X})" for c in missing)
        raise FontError(f"font {font.path} has no glyph for {len(missing)} character(s) of the text: {shown}")


# ---------------------------------------------------------------------------------------------------------------
# outlines


def _contours(font: _Font, glyph_name: str, tol: float) -> list[np.ndarray]:
    """Closed contours of one glyph in font units, curves flattened to chord deviation ≤ ``tol`` (font units)."""
    from fontTools.pens.basePen import BasePen

    class _FlattenPen(BasePen):
        """Collect closed polylines; quadratic and cubic Béziers split uniformly by their curvature bound."""

        def __init__(self, glyph_set: Any) -> None:
            super().__init__(glyph_set)
            self.contours: list[np.ndarray] = []
            self._pts: list[tuple[float, float]] = []

        def _moveTo(self, p: tuple[float, float]) -> None:
            self._flush()
            self._pts = [p]

        def _lineTo(self, p: tuple[float, float]) -> None:
            self._pts.append(p)

        def _qCurveToOne(self, p1: tuple[float, float], p2: tuple[float, float]) -> None:
            p0 = np.asarray(self._pts[-1], float)
            c = np.array([p0, p1, p2], float)
            # |B''| = 2|P0 − 2P1 + P2|; chord error of n uniform pieces ≤ |B''| / (8 n²)
            n = max(1, math.ceil(math.sqrt(np.linalg.norm(c[0] - 2 * c[1] + c[2]) / (4.0 * tol))))
            t = np.arange(1, n + 1)[:, None] / n
            pts = (1 - t) ** 2 * c[0] + 2 * (1 - t) * t * c[1] + t**2 * c[2]
            self._pts.extend(map(tuple, pts))

        def _curveToOne(self, p1: tuple[float, float], p2: tuple[float, float], p3: tuple[float, float]) -> None:
            p0 = np.asarray(self._pts[-1], float)
            c = np.array([p0, p1, p2, p3], float)
            # |B''| ≤ 6 max(|P0 − 2P1 + P2|, |P1 − 2P2 + P3|)
            dd = max(np.linalg.norm(c[0] - 2 * c[1] + c[2]), np.linalg.norm(c[1] - 2 * c[2] + c[3]))
            n = max(1, math.ceil(math.sqrt(0.75 * dd / tol)))
            t = np.arange(1, n + 1)[:, None] / n
            pts = (1 - t) ** 3 * c[0] + 3 * (1 - t) ** 2 * t * c[1] + 3 * (1 - t) * t**2 * c[2] + t**3 * c[3]
            self._pts.extend(map(tuple, pts))

        def _closePath(self) -> None:
            self._flush()

        def _endPath(self) -> None:  # open contours do not bound area: ignored like a rasterizer would
            self._pts = []

        def _flush(self) -> None:
            if len(self._pts) >= 3:
                self.contours.append(np.asarray(self._pts, float))
            self._pts = []

    glyph_set = font.tt.getGlyphSet()
    pen = _FlattenPen(glyph_set)
    glyph_set[glyph_name].draw(pen)
    pen._flush()
    return pen.contours


def _winding_numbers(points: np.ndarray, contour: np.ndarray) -> np.ndarray:
    """Winding number of each point about a closed polyline (any self-intersections, either orientation)."""
    a = contour
    b = np.roll(contour, -1, axis=0)
    px = points[:, 0:1]
    py = points[:, 1:2]
    cross = (b[:, 0] - a[:, 0]) * (py - a[:, 1]) - (px - a[:, 0]) * (b[:, 1] - a[:, 1])
    up = (a[:, 1] <= py) & (b[:, 1] > py) & (cross > 0)
    down = (a[:, 1] > py) & (b[:, 1] <= py) & (cross < 0)
    return up.sum(axis=1) - down.sum(axis=1)


def _glyph_region(contours: list[np.ndarray]) -> BaseGeometry:
    """Filled region of a glyph under the nonzero rule (TrueType and CFF both fill nonzero).

    The contours are noded into an arrangement (shapely ``polygonize``); each face is kept when the sum of the
    contours' winding numbers at an interior point is nonzero. This handles holes of either orientation
    convention, overlapping contours (variable fonts, composites) and self-intersecting contours alike.
    """
    import shapely
    from shapely.geometry import LineString, Polygon

    if not contours:
        return Polygon()
    rings = [LineString(np.vstack([c, c[:1]])) for c in contours]
    noded = shapely.unary_union(rings)
    faces = [g for g in shapely.get_parts(shapely.polygonize(shapely.get_parts(noded))) if g.area > 0]
    if not faces:
        return Polygon()
    probes = np.array([f.representative_point().coords[0] for f in faces])
    wn = np.zeros(len(faces), dtype=np.int64)
    for c in contours:
        wn += _winding_numbers(probes, c)
    kept = [f for f, w in zip(faces, wn, strict=True) if w != 0]
    return shapely.unary_union(kept) if kept else Polygon()


# ---------------------------------------------------------------------------------------------------------------
# layout


def _shape_line(font: _Font, line: str) -> list[tuple[str, float, float]]:
    """HarfBuzz shaping of one line: (glyph name, x, y) pen positions in font units, kerning applied."""
    import uharfbuzz as hb

    face = hb.Face(font.data)
    hb_font = hb.Font(face)  # scale defaults to unitsPerEm: positions come back in font units
    buf = hb.Buffer()
    buf.add_str(line)
    buf.guess_segment_properties()
    hb.shape(hb_font, buf, {"kern": True, "liga": True})
    out = []
    x = y = 0.0
    order = font.tt.getGlyphOrder()
    for info, pos in zip(buf.glyph_infos, buf.glyph_positions, strict=True):
        out.append((order[info.codepoint], x + pos.x_offset, y + pos.y_offset))
        x += pos.x_advance
        y += pos.y_advance
    return out


def _text_region(text: str, font: _Font, height: float, tol: float) -> BaseGeometry:
    """Union of all placed glyph regions, scaled so the cap height is ``height``, in output units."""
    import shapely
    from shapely import affinity

    lines = _check_text(text)
    scale = height / font.cap_height
    tol_units = tol / scale
    cache: dict[str, BaseGeometry] = {}
    placed = []
    for row, line in enumerate(lines):
        baseline = -row * font.line_height
        for name, x, y in _shape_line(font, line):
            if name not in cache:
                cache[name] = _glyph_region(_contours(font, name, tol_units))
            region = cache[name]
            if not region.is_empty:
                placed.append(affinity.translate(region, x, baseline + y))
    if not placed:
        raise FontError(f"text {text!r} has no visible glyph outlines in font {font.path}")
    merged = shapely.unary_union(placed)
    return affinity.scale(merged, scale, scale, origin=(0, 0))


def _clean_region(region: BaseGeometry, edge: float, tol: float) -> list[Any]:
    """Close sub-edge gaps, drop slivers, simplify within ``tol`` and resample edges to ≤ ``edge``.

    Returns shapely Polygons (one per connected region), exterior counter-clockwise and holes clockwise.
    """
    import shapely
    from shapely.geometry import Polygon
    from shapely.geometry.polygon import orient

    r = CLOSE_FRACTION * edge
    region = region.buffer(r, join_style="mitre", mitre_limit=10.0).buffer(-r, join_style="mitre", mitre_limit=10.0)
    region = shapely.simplify(region, tol, preserve_topology=True)
    min_area = (SLIVER_FRACTION * edge) ** 2
    polys: list = []
    for p in shapely.get_parts(region):
        if not isinstance(p, Polygon) or p.area < min_area:
            continue
        holes = [h for h in p.interiors if Polygon(h).area >= min_area]
        p = Polygon(p.exterior, holes)
        p = shapely.segmentize(p, edge)
        p = orient(p, sign=1.0)
        if not p.is_valid:
            p = orient(shapely.make_valid(p), sign=1.0)
        polys.extend(q for q in shapely.get_parts(p) if isinstance(q, Polygon) and q.area >= min_area)
    if not polys:
        raise MeshError("the text's outline has no region larger than a sliver at this edge length")
    return polys


# ---------------------------------------------------------------------------------------------------------------
# meshing


def _rings(polys: list[Any]) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Outline vertices (unique) and closed-loop edges of all polygon rings; the ring sizes in order."""
    pts: list[np.ndarray] = []
    edges: list[np.ndarray] = []
    sizes: list[int] = []
    off = 0
    for p in polys:
        for ring in [p.exterior, *p.interiors]:
            r = np.asarray(ring.coords, float)[:-1, :2]
            n = len(r)
            pts.append(r)
            edges.append(np.c_[np.arange(n), (np.arange(n) + 1) % n] + off)
            sizes.append(n)
            off += n
    V = np.vstack(pts)
    E = np.vstack(edges)
    # rings of different pieces may share a vertex exactly (a hole touching its shell): merge, keep first order
    uniq, first, inverse = np.unique(V, axis=0, return_index=True, return_inverse=True)
    if len(uniq) < len(V):
        order = np.argsort(first)
        remap = np.empty(len(uniq), dtype=np.int64)
        remap[order] = np.arange(len(uniq))
        V = uniq[order]
        E = remap[inverse.reshape(-1)][E]
    return V, E, sizes


def _mesh_polygons(polys: list[Any], edge: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Quality constrained Delaunay mesh of polygons with holes (pythoncdt: CDT library, MPL-2.0).

    The outline vertices come first, unchanged; refinement inserts interior vertices (smallest angle ≥ 30°
    where the input angles allow, triangle area ≤ 1.5 × that of an equilateral triangle of side ``edge``) and,
    where a boundary segment is encroached, its midpoint, which lies on the outline. Returns (V (n,2), F (m,3)
    counter-clockwise, number of outline vertices).
    """
    import pythoncdt as cdt

    V, E, _ = _rings(polys)
    tri = cdt.Triangulation(cdt.VertexInsertionOrder.AUTO, cdt.IntersectingConstraintEdges.NOT_ALLOWED, 0.0)
    try:
        tri.insert_vertices([cdt.V2d(float(x), float(y)) for x, y in V])
        tri.insert_edges([cdt.Edge(int(a), int(b)) for a, b in E])
        area = sum(p.area for p in polys)
        budget = int(40 * area / edge**2) + 10 * len(V) + 1000
        tri.refine_triangles(
            budget,
            cdt.RefinementCriterion.SMALLEST_ANGLE,
            cdt.deg_to_rad(MIN_ANGLE_DEG),
            tri.collect_outer_triangles_and_holes(),
            MIN_EDGE_FRACTION * edge,
        )
        tri.refine_triangles(
            budget,
            cdt.RefinementCriterion.LARGEST_AREA,
            AREA_FACTOR * math.sqrt(3.0) / 4.0 * edge**2,
            tri.collect_outer_triangles_and_holes(),
            MIN_EDGE_FRACTION * edge,
        )
        tri.erase_outer_triangles_and_holes()
    except Exception as e:  # CDT raises on intersecting or duplicate constraints
        raise MeshError(f"constrained Delaunay triangulation of the text outline failed: {e}") from e
    U = np.array([(v.x, v.y) for v in tri.vertices], dtype=np.float64)
    F = np.array([t.vertices for t in tri.triangles], dtype=np.int64).reshape(-1, 3)
    if not np.array_equal(U[: len(V)], V):
        raise MeshError("the triangulation moved outline vertices")
    return U, F, len(V)


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Closed boundary loops of a triangle mesh, each as vertex indices in the direction the faces give them."""
    f = np.asarray(faces, dtype=np.int64)
    half = np.vstack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = {(int(a), int(b)) for a, b in half}
    succ: dict[int, int] = {}
    for a, b in half:
        if (int(b), int(a)) not in key:
            if int(a) in succ:
                raise MeshError(f"vertex {int(a)} starts two boundary edges (pinched boundary)")
            succ[int(a)] = int(b)
    loops = []
    while succ:
        start, nxt = succ.popitem()
        loop = [start]
        while nxt != start:
            loop.append(nxt)
            try:
                nxt = succ.pop(nxt)
            except KeyError as e:
                raise MeshError(f"boundary edges do not close into loops at vertex {nxt}") from e
        loops.append(np.asarray(loop, dtype=np.int64))
    return loops


def text_to_mesh(
    text: str,
    font: str | Path | None = None,
    *,
    height: float = 1.0,
    edge_length: float | None = None,
    line_spacing: float = 1.2,
) -> SurfaceMesh:
    """Planar triangle mesh (z = 0, normals +z) of ``text`` set in ``font``, for inflated type (paper §7.2).

    ``height`` is the font's cap height (the flat top of "H"; OS/2 sCapHeight when present) after scaling.
    ``edge_length`` is the target edge length, default ``height / 40``. Lines (split at "\\n") are left-aligned,
    their baselines ``line_spacing`` × the font's line height (hhea ascender − descender + line gap) apart; the
    whole is centred on the origin by its bounding box. Glyphs that touch or overlap form one region.

    ``extra`` holds ``outline_vertices`` (the first n vertices are the flattened outline, unchanged by
    meshing), ``boundary_loops`` (vertex index loops, outer counter-clockwise, holes clockwise), ``font`` (path)
    and ``edge_length``. Raises FontError for empty text, an unreadable font or characters the font lacks.
    """
    lines = _check_text(text)  # cheap checks first
    if not (math.isfinite(height) and height > 0):
        raise FontError(f"height must be a positive finite number, got {height!r}")
    edge = height * DEFAULT_EDGE_FRACTION if edge_length is None else float(edge_length)
    if not (math.isfinite(edge) and edge > 0):
        raise FontError(f"edge_length must be a positive finite number, got {edge_length!r}")
    if not HEIGHT_RANGE[0] <= height <= HEIGHT_RANGE[1]:
        raise FontError(f"height must be between {HEIGHT_RANGE[0]:g} and {HEIGHT_RANGE[1]:g}, got {height!r}")
    if not height / MAX_DETAIL <= edge <= height:
        raise FontError(
            f"edge_length must be between height/{MAX_DETAIL} = {height / MAX_DETAIL:.6g} and height = {height:.6g}, "
            f"got {edge_length!r}"
        )
    if not (math.isfinite(line_spacing) and line_spacing > 0):
        raise FontError(f"line_spacing must be a positive finite number, got {line_spacing!r}")
    loaded = _load_font(font)
    _check_coverage(lines, loaded)
    loaded.line_height *= line_spacing
    tol = FLATTEN_FRACTION * edge
    region = _text_region(text, loaded, height, tol)
    polys = _clean_region(region, edge, tol)
    V2, F, n_outline = _mesh_polygons(polys, edge)

    lo, hi = V2.min(axis=0), V2.max(axis=0)
    V2 = V2 - 0.5 * (lo + hi)
    a = V2[F[:, 1]] - V2[F[:, 0]]
    b = V2[F[:, 2]] - V2[F[:, 0]]
    area2 = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    if np.any(area2 <= 0):
        raise MeshError(f"triangulation produced {int(np.sum(area2 <= 0))} inverted or zero-area triangles")
    vertices = np.c_[V2, np.zeros(len(V2))].astype(np.float64)
    faces = np.ascontiguousarray(F, dtype=np.int64)
    extra = {
        "outline_vertices": n_outline,
        "boundary_loops": boundary_loops(faces),
        "font": str(loaded.path),
        "edge_length": edge,
        "height": height,
    }
    return SurfaceMesh(vertices=vertices, faces=faces, source=f"text {text!r} in {loaded.path.name}", extra=extra)
