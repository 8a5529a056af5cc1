"""Recorded figures of the reference and the paper that do not depend on the machine.

The reference C++ implementation (the authors' code) is deterministic: its Newton iterations, fills and final
volumes are the same on every machine (shared/notes/reference.md, 60 steps, PNTol = 1), so the suite's table
shows them beside idp's. Its wall times are not kept here: a time taken on another machine gives no speed-up;
``idp bench --with-reference`` (idp.bench.reference_run) measures both codes in the same run instead.
Paper figures: §6.
"""

from typing import Any

REFERENCE = {
    "bunny_700": {
        "verts": 865,
        "tets": 2928,
        "newton_iterations": 236,
        "fill": 0.9768,
    },
    "bunny_1922": {
        "verts": 2529,
        "tets": 9203,
        "newton_iterations": 294,
        "fill": 0.9839,
    },
    "bunny_3376": {
        "verts": 4588,
        "tets": 17276,
        "newton_iterations": 335,
        "fill": 0.9879,
    },
    "bunny_4815": {
        "verts": 6641,
        "tets": 25375,
        "newton_iterations": 358,
        "fill": 0.9882,
    },
    "bunnyx30_13K": {
        "verts": 19075,
        "tets": 74351,
        "newton_iterations": 383,
        "fill": 0.9895,
    },
    "tube_in_tube": {
        "verts": 4446,
        "tets": 18752,
        "newton_iterations": 1265,
        "fill": 0.8806,
    },
    # normal flow on the cat (Fig. 12a): shared/notes/reference.md §4; no peak memory recorded
    "flow_cat": {
        "verts": 7449,
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
