"""Reference figures the suite is compared with.

Reference C++ implementation (authors' code) on an idle 2-core machine of the kind idp is measured on:
shared/notes/reference.md §0 (wall = whole process, 60 steps, PNTol = 1). Paper figures: §6.
"""

from typing import Any

REFERENCE = {
    "bunny_700": {
        "verts": 865,
        "tets": 2928,
        "wall": 24.4,
        "newton_iterations": 236,
        "fill": 0.9768,
        "peak_rss_mb": 102,
    },
    "bunny_1922": {
        "verts": 2529,
        "tets": 9203,
        "wall": 82.8,
        "newton_iterations": 294,
        "fill": 0.9839,
        "peak_rss_mb": 154,
    },
    "bunny_3376": {
        "verts": 4588,
        "tets": 17276,
        "wall": 184.7,
        "newton_iterations": 335,
        "fill": 0.9879,
        "peak_rss_mb": 223,
    },
    "bunny_4815": {
        "verts": 6641,
        "tets": 25375,
        "wall": 311.9,
        "newton_iterations": 358,
        "fill": 0.9882,
        "peak_rss_mb": 298,
    },
    "bunnyx30_13K": {
        "verts": 19075,
        "tets": 74351,
        "wall": 1208.0,
        "newton_iterations": 383,
        "fill": 0.9895,
        "peak_rss_mb": 583,
    },
    "tube_in_tube": {
        "verts": 4446,
        "tets": 18752,
        "wall": 1551.0,
        "newton_iterations": 1265,
        "fill": 0.8806,
        "peak_rss_mb": 413,
    },
    # normal flow on the cat (Fig. 12a): shared/notes/reference.md §4, measured while another job shared the
    # cores (so an idle reference is faster); no peak memory recorded
    "flow_cat": {
        "verts": 7449,
        "wall": 80.9,
        "newton_iterations": 83,
        "volume_ratio": 0.06319 / 0.02335,
    },
}

PAPER: dict[str, dict[str, Any]] = {
    "bunny_box_54K": {"fill": 0.9993, "note": "54K-vertex bunny (mesh not in the data)"},
    "hourglass_bunny": {"fill": 0.983},
    "hourglass_octocat": {"fill": 0.978},
    "tube_in_tube": {"fill": 1.0, "note": "'completely fills the cage' in 60 steps"},
}
