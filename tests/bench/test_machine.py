"""The machine description recorded with benchmark results."""

import json

from idp.bench.machine import describe, parse_cpuinfo, summary

CPUINFO = """processor	: 0
model name	: Example CPU 9000 @ 3.00GHz
cpu MHz		: 2999.998
cache size	: 32768 KB
physical id	: 0
core id		: 0

processor	: 1
model name	: Example CPU 9000 @ 3.00GHz
cpu MHz		: 3001.5
cache size	: 32768 KB
physical id	: 0
core id		: 0

processor	: 2
model name	: Example CPU 9000 @ 3.00GHz
cpu MHz		: 3000.0
cache size	: 32768 KB
physical id	: 0
core id		: 1
"""


def test_parse_cpuinfo_counts_logical_and_physical_cores():
    info = parse_cpuinfo(CPUINFO)
    assert info["cpu_model"] == "Example CPU 9000 @ 3.00GHz"
    assert info["cpu_mhz"] == 2999.998  # the first processor's figure, parsed from the text
    assert info["cache_size"] == "32768 KB"
    assert info["logical_cores"] == 3 and info["physical_cores"] == 2  # two hyper-threads share core 0


def test_parse_cpuinfo_without_fields_gives_none():
    assert parse_cpuinfo("") == {
        "cpu_model": None,
        "cpu_mhz": None,
        "cache_size": None,
        "logical_cores": None,
        "physical_cores": None,
    }


def test_describe_falls_back_to_platform_and_is_json_ready(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_NUM_THREADS", "1")
    m = describe(tmp_path / "no-cpuinfo")  # not Linux, or /proc hidden
    json.dumps(m)
    assert m["logical_cores"] and m["logical_cores"] >= 1
    assert m["thread_env"]["NUMBA_NUM_THREADS"] == "1"
    assert m["numba_target_cpu"]  # host CPU name, or NUMBA_CPU_NAME
    for pkg in ("python", "numpy", "scipy", "numba", "ipctk"):
        assert m["versions"][pkg], pkg
    assert "cvxopt" in m["versions"] and "cholmod" in m["versions"]  # None when not installed
    lines = summary(m)
    assert lines[0].startswith("**Machine:**") and "NUMBA_NUM_THREADS=1" in lines[1]
    assert f"numpy {m['versions']['numpy']}" in lines[2]
