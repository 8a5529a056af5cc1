"""The reference's OpenBLAS kernels: probed in a child process, forced only when it falls back to generic ones."""

from __future__ import annotations

import ctypes.util

import pytest

import idp.bench.reference_blas as rb


def _fake_openblas(monkeypatch, default: str, accepts: set[str], ours: str | None = "SkylakeX", flags=None):
    """A reference OpenBLAS that picks ``default`` by itself and takes any of ``accepts`` from OPENBLAS_CORETYPE."""

    def core(env=None):
        forced = (env or {}).get("OPENBLAS_CORETYPE")
        if forced is None:
            return default
        return forced if forced in accepts else default

    monkeypatch.setattr(rb, "reference_core", core)
    monkeypatch.setattr(rb, "idp_core", lambda: ours)
    monkeypatch.setattr(rb, "_cpu_flags", lambda: set(flags if flags is not None else ["avx2", "fma"]))


def test_a_generic_fallback_is_replaced_by_idps_kernels(monkeypatch):
    _fake_openblas(monkeypatch, "Prescott", {"SkylakeX", "Haswell"})
    env, record = rb.choose_reference_blas({"PATH": "/bin"})
    assert env["OPENBLAS_CORETYPE"] == "SkylakeX" and env["PATH"] == "/bin"
    assert record == {"policy": "auto", "default_core": "Prescott", "core": "SkylakeX", "forced": "SkylakeX"}
    assert "OPENBLAS_CORETYPE=SkylakeX" in rb.describe_choice(record)


def test_a_core_the_reference_does_not_know_falls_back_to_the_widest_it_accepts(monkeypatch):
    avx512 = ["avx2", "fma", "avx512f", "avx512dq", "avx512bw", "avx512vl", "avx512cd"]
    _fake_openblas(monkeypatch, "Prescott", {"SkylakeX", "Haswell"}, ours="SapphireRapids", flags=avx512)
    assert rb.choose_reference_blas({})[0]["OPENBLAS_CORETYPE"] == "SkylakeX"
    _fake_openblas(monkeypatch, "Prescott", {"Haswell"}, ours="SapphireRapids", flags=avx512)
    assert rb.choose_reference_blas({})[0]["OPENBLAS_CORETYPE"] == "Haswell"
    _fake_openblas(monkeypatch, "Prescott", {"Haswell"}, ours=None, flags=[])  # nothing this CPU runs: left alone
    env, record = rb.choose_reference_blas({})
    assert "OPENBLAS_CORETYPE" not in env and record["forced"] is None and record["core"] == "Prescott"


def test_a_known_cpu_and_the_as_is_policy_leave_the_environment_alone(monkeypatch):
    _fake_openblas(monkeypatch, "Zen", {"SkylakeX", "Haswell", "Zen"})
    env, record = rb.choose_reference_blas({"OPENBLAS_CORETYPE": "Haswell"})  # auto drops a stray setting
    assert "OPENBLAS_CORETYPE" not in env and record["forced"] is None and record["core"] == "Zen"
    _fake_openblas(monkeypatch, "Prescott", {"SkylakeX"})
    env, record = rb.choose_reference_blas({"OPENBLAS_CORETYPE": "Haswell"}, "as-is")
    assert env["OPENBLAS_CORETYPE"] == "Haswell" and record["policy"] == "as-is" and record["forced"] is None


def test_a_named_core_is_forced_or_refused(monkeypatch):
    _fake_openblas(monkeypatch, "Zen", {"Haswell"})
    env, record = rb.choose_reference_blas({}, "Haswell")
    assert env["OPENBLAS_CORETYPE"] == "Haswell" and record["forced"] == "Haswell"
    with pytest.raises(ValueError, match="OPENBLAS_CORETYPE=Nonesuch"):
        rb.choose_reference_blas({}, "Nonesuch")


def test_no_openblas_means_no_choice(monkeypatch):
    monkeypatch.setattr(rb, "REFERENCE_LIBRARIES", ("libidp-no-such-blas.so.9",))
    assert rb.reference_core({}) is None
    env, record = rb.choose_reference_blas({"OPENBLAS_CORETYPE": "Haswell"})
    assert "OPENBLAS_CORETYPE" not in env and record["default_core"] is None
    assert "not found" in rb.describe_choice(record)


def test_the_probe_reads_a_real_openblas_and_its_coretype_override():
    if ctypes.util.find_library("openblas") is None:
        pytest.skip("no system OpenBLAS (the reference's) on this machine")
    core = rb.reference_core({})
    if core is None:
        pytest.skip("the system BLAS is not OpenBLAS")
    assert core and core.isprintable()
    if {"avx2", "fma"} <= rb._cpu_flags():
        assert rb.reference_core({"OPENBLAS_CORETYPE": "Haswell"}) == "Haswell"


def test_idps_own_kernels_are_named():
    core = rb.idp_core()
    if core is None:
        pytest.skip("scipy's OpenBLAS not found (another scipy build)")
    assert core and core.isprintable()
