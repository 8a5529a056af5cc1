"""Scene definitions of the §6 stress tests, reproducing the set-ups of shared/data/MANIFEST.md."""

from __future__ import annotations

from pathlib import Path

from idp.scene.load import scene_from_dict

NH_1E4 = {"model": "neo_hookean", "youngs_modulus": 1e4, "poisson_ratio": 0.4, "density": 1000.0}


def _base(name: str, steps: int, newton_tol: float = 1.0) -> dict:
    return {
        "name": name,
        "dim": 3,
        "time": {"h": 0.04**2, "steps": steps},
        "solver": {"newton_tol": newton_tol, "max_newton_iterations": 1000},
        "contact": {"dhat": 1e-3, "dhat_mode": "absolute"},
        "output": {"every": 10, "obj": True, "vtu": False, "png": False},  # pictures: not part of the timed run
    }


def bunny_in_box(
    data: Path, mesh: str = "bunny_700.vtk", scale: float = 10.0, steps: int = 60, newton_tol: float = 1.0
):
    """Fig. 5: bunny grown (+0.1 per step for 20 steps, 3× linear) inside the fixed cube nice_cube.obj."""
    d = _base(Path(mesh).stem, steps, newton_tol)
    d["objects"] = [
        {
            "name": "bunny",
            "kind": "deformable",
            "mesh": str(data / "benchmark" / mesh),
            "scale": scale,
            "material": dict(NH_1E4),
            "rest_shape": {"growth_rate": 0.1, "growth_steps": 20},
        },
        {"name": "box", "kind": "obstacle", "mesh": str(data / "benchmark" / "nice_cube.obj")},
    ]
    return scene_from_dict(d)


def tube_in_tube(data: Path, steps: int = 60, newton_tol: float = 1.0):
    """Fig. 7: tube.vtk, rest shape stretched ×(1.1, 3.2, 1.1), inside the fixed tube_container.obj, E = 1e5."""
    d = _base("tube_in_tube", steps, newton_tol)
    mat = dict(NH_1E4, youngs_modulus=1e5)
    d["objects"] = [
        {
            "name": "tube",
            "kind": "deformable",
            "mesh": str(data / "benchmark" / "tube.vtk"),
            "material": mat,
            "rest_shape": {"scale": [1.1, 3.2, 1.1]},
        },
        {"name": "container", "kind": "obstacle", "mesh": str(data / "benchmark" / "tube_container.obj")},
    ]
    return scene_from_dict(d)


#: The Newton tolerance (PNTol) the authors' hourglass script runs with (the bunny-in-box and tube references run
#: with 1, as the suite's scenes: :data:`idp.bench.reference_run.REFERENCE_CASES`): the suite's hourglass scenes use
#: it, so ``--with-reference`` compares fills like with like.
HOURGLASS_REFERENCE_TOL = 1e-2


def hourglass(data: Path, which: str = "bunny", steps: int = 30, newton_tol: float = 1.0):
    """Fig. 9: bunnyx30_13K (×0.05) or octocat23K (−90° about x) grown 3× over 20 steps in hourglass.obj.

    ``which="bunny_700"``: a coarse stand-in (bunny_700 × 1.5, the same size as the 13K bunny × 0.05)
    for quick experiments; it is not part of the suite."""
    if which == "bunny":
        obj = {"mesh": str(data / "benchmark" / "bunnyx30_13K.vtk"), "scale": 0.05}
    elif which == "bunny_700":
        obj = {"mesh": str(data / "benchmark" / "bunny_700.vtk"), "scale": 1.5}
    else:
        obj = {
            "mesh": str(data / "benchmark" / "octocat23K.vtk"),
            "rotate": [{"axis": [1.0, 0.0, 0.0], "degrees": -90.0}],
        }
    d = _base(f"hourglass_{which}", steps, newton_tol)
    d["time"]["stop_when_stationary"] = True
    d["objects"] = [
        {
            "name": which,
            "kind": "deformable",
            **obj,
            "material": dict(NH_1E4),
            "rest_shape": {"growth_rate": 0.1, "growth_steps": 20},
        },
        {"name": "hourglass", "kind": "obstacle", "mesh": str(data / "benchmark" / "hourglass.obj")},
    ]
    return scene_from_dict(d)


PAPER_SCENES = Path(__file__).resolve().parents[1] / "scenes" / "paper"


def paper_scene(file: str, steps: int | None = None):
    """A committed paper scene (``idp/scenes/paper``) with the benchmark's output settings (frames every 10 steps,
    OBJ only, no picture)."""
    from idp.scene.load import load_scene

    scene = load_scene(PAPER_SCENES / file)
    scene.output.every, scene.output.obj, scene.output.vtu, scene.output.png = 10, True, False, False
    if steps is not None:
        scene.time.steps = steps
    return scene


def suite(data: Path) -> dict:
    """name -> (scene factory, tier) ; the quick tier runs in well under 15 minutes on 2 cores."""
    return {
        "bunny_700": (lambda: bunny_in_box(data, "bunny_700.vtk", 10.0), "quick"),
        "bunny_1922": (lambda: bunny_in_box(data, "bunny_1922.vtk", 10.0), "quick"),
        "bunny_3376": (lambda: bunny_in_box(data, "bunny_3376.vtk", 10.0), "full"),
        "bunny_4815": (lambda: bunny_in_box(data, "bunny_4815.vtk", 10.0), "full"),
        "bunny_7448": (lambda: bunny_in_box(data, "bunny_7448.vtk", 10.0), "full"),
        "bunnyx30_13K": (lambda: bunny_in_box(data, "bunnyx30_13K.vtk", 1.0 / 3.0), "full"),
        "tube_in_tube": (lambda: tube_in_tube(data), "full"),
        # at the authors' hourglass tolerance: at 1, idp takes one Newton iteration a frame and trails the growth
        # (octocat: 30.0 % against 41.4 %; docs/benchmarks.md, "The octocat beside the reference")
        "hourglass_bunny": (lambda: hourglass(data, "bunny", newton_tol=HOURGLASS_REFERENCE_TOL), "full"),
        "hourglass_octocat": (lambda: hourglass(data, "octocat", newton_tol=HOURGLASS_REFERENCE_TOL), "full"),
        "bar_twist": (lambda: paper_scene("fig10_bar_elastic.toml"), "full"),
        "flow_cat": (lambda: paper_scene("fig12_cat.toml"), "full"),
        "flow_bunny3K_inward": (lambda: paper_scene("fig13_bunny3K.toml"), "full"),
        "flow_font_Tao": (lambda: paper_scene("fig14_font_Tao.toml"), "full"),
        "repair_kick": (lambda: paper_scene("fig16_repair_kick.toml"), "full"),
        "repair_rumba": (lambda: paper_scene("fig16_repair_rumba.toml"), "full"),
        "minmax_circle_sd1": (lambda: paper_scene("fig19_circle_sd1.toml"), "quick"),
        "minmax_circle_sd10": (lambda: paper_scene("fig19_circle_sd10.toml"), "quick"),
        "minmax_arm_thicker_sd5": (lambda: paper_scene("fig20_arm_thicker_sd5.toml"), "full"),
        "minmax_arm_thicker_sd1": (lambda: paper_scene("fig20_arm_thicker_sd1.toml"), "full"),
        "uv_camelHead28K_sd10": (lambda: paper_scene("fig18_uv_camelHead28K_sd10.toml"), "full"),
        "modeling_dumpling": (lambda: paper_scene("fig01_dumpling.toml"), "full"),
    }
