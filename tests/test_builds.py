"""Kernel builds are a step of their own (issue 22): counted apart from planning, rendering and
checking, with what can be known of whether the driver's compiler cache served them."""

import io
import json

import numpy as np
import pyopencl as cl
import pytest

import clholo
from clholo import selftest
from clholo.host import runtime
from clholo.methods import get_method
from clholo.progress import StepLog
from clholo.render_folder import render_to_folder
from clholo.scenes import Scene, SceneSpec


@pytest.fixture
def fresh_queue(cl_device):
    """A queue on a context of its own: every program is built again for it (programs are
    memoized per context), as in a new process."""
    return runtime.create_queue(cl.Context([cl_device]), cl_device)


def _fake_cache(monkeypatch, tmp_path, *, writes: bool):
    """The driver's cache is ``tmp_path/cache``; each build adds a file to it when ``writes``
    (a compile) and leaves it alone otherwise (served from the cache)."""
    folder = tmp_path / "cache"
    folder.mkdir()
    monkeypatch.setattr(runtime, "compiler_cache_dir", lambda dev: str(folder))
    real_program = runtime.cl.Program

    class Program:
        def __init__(self, ctx, text):
            self.inner = real_program(ctx, text)

        def build(self, options):
            n = len(list(folder.iterdir()))
            if writes is True or (writes == "first" and n == 0):
                (folder / f"entry{n}").write_bytes(b"binary")
            return self.inner.build(options=options)

    monkeypatch.setattr(runtime.cl, "Program", Program)
    return folder


@pytest.mark.parametrize("writes, verdict", [(True, "compiled"),
                                             (False, "served from the cache"),
                                             ("first", "partly compiled")])
def test_build_counter_counts_builds_and_reads_the_cache(cl_device, tmp_path, monkeypatch,
                                                         writes, verdict):
    folder = _fake_cache(monkeypatch, tmp_path, writes=writes)
    ctx = cl.Context([cl_device])
    with runtime.BuildCounter(cl_device) as b:
        runtime.build_program(ctx, "elementwise.cl", defines={"REAL": "float"})
        runtime.build_program(ctx, "composite.cl")
        runtime.build_program(ctx, "composite.cl")  # memoized: not a build
    assert b.programs == 2 and b.seconds > 0
    assert b.cache == verdict
    assert b.new_cache_files == b.programs_compiled == {True: 2, False: 0, "first": 1}[writes]
    d = b.to_dict()
    assert d["files"] == ["composite.cl", "elementwise.cl"] and d["cache_folder"] == str(folder)
    assert d["compiler_cache"] == verdict and "built 2 OpenCL program(s)" in b.describe()
    with runtime.BuildCounter(cl_device) as none:
        runtime.build_program(ctx, "composite.cl")
    assert none.programs == 0 and none.cache == "none built"


def test_no_known_cache_folder_is_unknown(cl_device, monkeypatch):
    monkeypatch.setattr(runtime, "compiler_cache_dir", lambda dev: None)
    with runtime.BuildCounter(cl_device) as b:
        runtime.build_program(cl.Context([cl_device]), "composite.cl")
    assert b.programs == 1 and b.cache == "unknown" and "unknown" in b.describe()


def _old(path, hours=2.0):
    """Give ``path`` the time stamps of long ago (entries of earlier runs)."""
    import os
    import time

    then = time.time() - 3600 * hours
    os.utime(path, (then, then))


def test_pocl_cache_is_read_by_its_first_level_stamps(monkeypatch, tmp_path):
    # PoCL's layout: <2 letters>/<program hash>/program.bc, kernels below; many programs
    # of earlier runs; a compile adds a hash folder (into a first-level folder there or a new
    # one), a cached program read rewrites files a level deeper: nothing to count
    import os

    folder = tmp_path / "kcache"
    for ab in ("AA", "AB", "PP"):
        for k in range(3):
            program = folder / ab / f"HASH{k}"
            (program / "fft_lines" / "64-1-1").mkdir(parents=True)
            (program / "program.bc").write_bytes(b"bc")
            (program / "last_accessed").write_bytes(b"")
            for p in (program / "fft_lines" / "64-1-1", program / "fft_lines", program):
                _old(p)
        _old(folder / ab)
    _old(folder)
    before = runtime._cache_snapshot(str(folder), by_entry=True)
    assert runtime._new_cache_entries(str(folder), before) == 0
    # a hit: last_accessed made anew, a kernel's new work-group size below a program
    os.unlink(folder / "AB" / "HASH1" / "last_accessed")
    (folder / "AB" / "HASH1" / "last_accessed").write_bytes(b"")
    (folder / "AB" / "HASH1" / "fft_lines" / "128-1-1").mkdir()
    assert runtime._new_cache_entries(str(folder), before) == 0
    for p in (folder / "AB" / "HASH1" / "fft_lines", folder / "AB" / "HASH1"):
        _old(p, hours=1.0)  # that read was an earlier build call's
    # a compile into an existing first-level folder: the hash folder and its file
    before = runtime._cache_snapshot(str(folder), by_entry=True)
    (folder / "AB" / "NEWHASH").mkdir()
    (folder / "AB" / "NEWHASH" / "program.bc").write_bytes(b"bc")
    assert runtime._new_cache_entries(str(folder), before) == 2
    # and into a new one: that folder too, with everything in it
    (folder / "CD" / "HASH" / "k").mkdir(parents=True)
    (folder / "CD" / "HASH" / "program.bc").write_bytes(b"bc")
    assert runtime._new_cache_entries(str(folder), before) == 2 + 4
    # a first-level folder removed (a cache cleaned meanwhile) adds nothing
    before = runtime._cache_snapshot(str(folder), by_entry=True)
    for path in sorted((folder / "PP").rglob("*"), reverse=True):
        path.rmdir() if path.is_dir() else path.unlink()
    (folder / "PP").rmdir()
    assert runtime._new_cache_entries(str(folder), before) == 0
    # other drivers: files counted over the whole folder
    before = runtime._cache_snapshot(str(folder), by_entry=False)
    (folder / "AA" / "HASH0" / "fft_lines" / "64-1-1" / "k.so").write_bytes(b"so")
    assert runtime._new_cache_entries(str(folder), before) == 1
    assert runtime._cache_snapshot(str(tmp_path / "none"), by_entry=True) is None


def test_the_real_pocl_cache_tells_a_compile_from_a_read(cl_device):
    import random

    folder = runtime.compiler_cache_dir(cl_device)
    if not runtime._is_pocl(cl_device) or folder is None:
        pytest.skip("the device is not PoCL with its kernel cache on")
    tag = random.randrange(1 << 40)  # a program no earlier run built
    verdicts = []
    for _ in range(2):
        with runtime.BuildCounter(cl_device) as b:
            runtime.build_program(cl.Context([cl_device]), "elementwise.cl",
                                  defines={"REAL": "float", "CLHOLO_CACHE_PROBE": tag})
        verdicts.append((b.cache, b.new_cache_files))
    assert verdicts[0][0] == "compiled" and verdicts[0][1] >= 2  # its hash folder and files
    assert verdicts[1] == ("served from the cache", 0)


def test_cache_folders_of_the_drivers(monkeypatch, tmp_path):
    class Dev:
        def __init__(self, platform):
            self.platform = type("P", (), {"name": platform})()

    monkeypatch.setenv("POCL_CACHE_DIR", str(tmp_path / "pocl"))
    assert runtime.compiler_cache_dir(Dev("Portable Computing Language")) == str(tmp_path / "pocl")
    monkeypatch.setenv("CUDA_CACHE_PATH", str(tmp_path / "nv"))
    assert runtime.compiler_cache_dir(Dev("NVIDIA CUDA")) == str(tmp_path / "nv")
    monkeypatch.setenv("CUDA_CACHE_DISABLE", "1")
    assert runtime.compiler_cache_dir(Dev("NVIDIA CUDA")) is None
    assert runtime.compiler_cache_dir(Dev("Oclgrind")) is None


def _scene(rng):
    mpi = clholo.MPI(rng.random((3, 12, 20, 3)).astype(np.float32),
                     rng.random((3, 12, 20)).astype(np.float32), [1e-3, 2e-3, 3e-3])
    return Scene(spec=SceneSpec(inputs=("test",)), kind="memory", mpi=mpi)


@pytest.mark.parametrize("method", ["mpi", "rgbd"])
def test_a_render_builds_its_programs_before_its_timer(fresh_queue, rng, tmp_path, method):
    """Every program the render needs is built in the warm-up step (planning + prepare), none
    while the render is timed; summary.json says how many, how long and the cache's verdict."""
    text = io.StringIO()
    frames = 5  # with 2 frames per launch: batches of 2 and of 1, two FFT plan sizes
    scene = _scene(rng)
    m = get_method(method)

    def two_per_launch(*args, **kwargs):
        r = m.build(*args, **kwargs)
        r._r.frames_per_batch = 2
        return r

    m_fixed = type(m)(m.name, m.needs, m.summary, two_per_launch)
    summary = render_to_folder(scene, m_fixed, clholo.Optics(), tmp_path / "out", frames=frames,
                               seed=1, log=StepLog(text, mode="lines"), queue=fresh_queue)
    b = summary["build"]
    assert b["programs"] >= 3 and b["seconds"] > 0
    assert {"asm.cl", "composite.cl"} <= set(b["files"])
    assert set(b["files"]) & {"fft_cpu.cl", "fft_gpu.cl"}
    assert b["during_render_programs"] == 0 and b["during_render_seconds"] == 0
    assert b["compiler_cache"] in ("compiled", "partly compiled", "served from the cache",
                                   "unknown")
    assert summary["render_seconds"] > 0
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["build"] == b
    log = text.getvalue()
    assert log.index("OpenCL program(s) in") < log.index("rendering 5 frame(s)")


def test_selftest_reports_compile_time_and_check_time_apart(fresh_queue):
    report = selftest.run_selftest(quick=True, queue=fresh_queue, families=["propagation"],
                                   speed=False)
    t = report.to_dict()["timing"]
    assert t["programs_built"] >= 1 and t["build_seconds"] > 0 and t["check_seconds"] >= 0
    assert t["build"]["files"] == ["asm.cl"] or "asm.cl" in t["build"]["files"]
    assert t["check_seconds"] + t["build_seconds"] <= report.seconds + 1e-6
    text = report.format_text()
    assert f"time     kernel builds {t['build_seconds']:.1f} s ({t['programs_built']} programs" in text
    assert f"checks {t['check_seconds']:.1f} s" in text
