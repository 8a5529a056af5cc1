"""Run one benchmark scene of the §6 suite by name and print its summary (used for the closing-note figures).

.venv/bin/python bench/run_scene.py bunny_700 -o bench/results/bunny_700
"""

import argparse
import json
import resource
import sys
import time

from idp.api import simulate
from idp.bench.data import require_data_dir
from idp.bench.scenes import suite

p = argparse.ArgumentParser()
p.add_argument("name")
p.add_argument("-o", "--output", required=True)
p.add_argument("--steps", type=int)
a = p.parse_args()
scene = suite(require_data_dir())[a.name][0]()
t = time.perf_counter()
res = simulate(scene, a.output, steps=a.steps, progress=False)
wall = time.perf_counter() - t
s = res.summary
print(
    json.dumps(
        {
            "scene": a.name,
            "wall_incl_setup": wall,
            "steps": s["steps_run"],
            "newton_iterations": s["newton_iterations"],
            "fill": s["fill_fraction"],
            "all_certified": s["all_certified"],
            "nonconverged": s["nonconverged_steps"],
            "timings": s["timings"],
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        },
        indent=1,
    )
)
sys.exit(0 if s["all_certified"] else 3)
