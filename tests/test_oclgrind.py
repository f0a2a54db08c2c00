"""Every kernel family under the Oclgrind simulator: zero reports, results still match NumPy.

Oclgrind runs each work-item of a work-group separately and checks every access, so it finds
what PoCL's in-order CPU execution hides: out-of-bounds reads and writes, data races between
work-items (``OCLGRIND_DATA_RACES=1``), barrier divergence, misuse of read-only buffers.
One subprocess runs ``clholo selftest --quick`` (clholo.selftest: both FFT kernel variants and
the global-memory stages with every radix and load/store callbacks, propagation, compositing
alone and fused into the FFT store, random phases, views, ray optics, encode, RPWS, splat
rasterising, all at small odd non-square sizes) on the Oclgrind device.

Skips only where Oclgrind is not installed; in CI (``CI=true``) it fails instead, so a broken
install cannot hide.
"""

import json
import os
import re
import sys
from pathlib import Path

import pytest

from clholo import oclgrind
from clholo.selftest import FAMILIES

KERNELS = Path(__file__).resolve().parents[1] / "kernels"


def _require_oclgrind():
    if oclgrind.find_icd() is None:
        msg = ("oclgrind is not installed (no liboclgrind-rt-icd.so in "
               f"{', '.join(oclgrind.ICD_CANDIDATES)}): `apt-get install oclgrind`")
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail("CI=true but " + msg)
        pytest.skip(msg)


@pytest.fixture(scope="module")
def selftest_under_oclgrind(tmp_path_factory):
    _require_oclgrind()
    path = tmp_path_factory.mktemp("oclgrind") / "selftest.json"
    run = oclgrind.run_under_oclgrind(oclgrind.selftest_command(str(path)), data_races=True,
                                      timeout=900)
    report = json.loads(path.read_text()) if path.exists() else None
    return run, report


def test_selftest_under_oclgrind_has_zero_reports_and_passes(selftest_under_oclgrind):
    run, report = selftest_under_oclgrind
    assert not run.reports, run.summary()
    assert run.returncode == 0, run.summary()
    assert report is not None, run.summary()
    assert "oclgrind" in report["device"]["platform"].lower(), report["device"]
    failed = [(c["family"], c["name"], c["error"], c["message"]) for c in report["checks"]
              if not c["passed"]]
    assert not failed and report["passed"]
    assert {c["family"] for c in report["checks"]} == {name for name, _, _ in FAMILIES}
    assert report["speed"].get("skipped")  # no timings on a simulator


def _kernel_names():
    names = set()
    for path in KERNELS.glob("*.cl"):
        text = re.sub(r"/\*.*?\*/", "", path.read_text(), flags=re.S)
        names |= set(re.findall(r"__kernel\b(?:\s+__attribute__\s*\(\(.*?\)\))?\s+void\s+(\w+)",
                                text, flags=re.S))
    return names


def test_every_kernel_of_kernels_dir_ran_under_oclgrind(selftest_under_oclgrind):
    _, report = selftest_under_oclgrind
    names = _kernel_names()
    assert {"fft_strip", "fft_lines", "fft_stage", "splat_raster", "field_sums"} <= names
    missing = sorted(names - set(report["kernels_launched"]))
    assert not missing, f"kernels never launched under Oclgrind: {missing}"


RACY = r"""
__kernel void racy(__global float *out, __local float *s)
{
    const int l = get_local_id(0);
    s[l] = (float)l;
    /* no barrier: reading a neighbour's slot races with its write */
    out[get_global_id(0)] = s[(l + 1) % get_local_size(0)];
}
__kernel void overrun(__global const float *in, __global float *out)
{
    const int i = get_global_id(0);
    out[i] = in[i + 1];  /* the last work-item reads one past the end */
}
"""

PROBE = f"""
import numpy as np, pyopencl as cl
from clholo.host import runtime
q = runtime.get_queue()
assert "Oclgrind" in q.device.platform.name, q.device.platform.name
prg = cl.Program(q.context, {RACY!r}).build()
out = cl.Buffer(q.context, cl.mem_flags.READ_WRITE, 64 * 4)
inp = cl.Buffer(q.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                hostbuf=np.ones(64, np.float32))
cl.Kernel(prg, "racy")(q, (64,), (16,), out, cl.LocalMemory(16 * 4))
cl.Kernel(prg, "overrun")(q, (64,), (16,), inp, out)
q.finish()
"""


def test_the_harness_sees_oclgrind_reports():
    """a local-memory race and an out-of-bounds read are reported through the same runner
    (so zero reports above means zero, not a harness that cannot see them)"""
    _require_oclgrind()
    run = oclgrind.run_under_oclgrind([sys.executable, "-c", PROBE], timeout=120)
    text = "\n".join(run.reports)
    assert run.returncode == 0, run.summary()
    assert re.search(r"data race at local memory", text), run.summary()
    assert re.search(r"Invalid read of size 4 at global memory", text), run.summary()
    assert not run.clean


def test_find_reports_reads_oclgrind_s_wording():
    text = ("device Oclgrind\nchecking fft ...\n\n"
            "Invalid read of size 4 at global memory address 0x3000000000100\n"
            "\tKernel: overrun\n\tEntity: Global(63,0,0) Local(15,0,0) Group(3,0,0)\n\n"
            "Read-write data race at local memory address 0x1000000000004\n\tKernel: racy\n\n"
            "Work-group divergence detected (barrier):\n\tKernel: k\n\n"
            "OCLGRIND FATAL ERROR (./src/plugins/Uninitialized.cpp:1805)\n"
            "Unsupported instruction: freeze\n\n"
            "PASSED: clholo works on this device\n")
    found = oclgrind.find_reports(text)
    assert len(found) == 4
    assert found[0].startswith("Invalid read") and "data race" in found[1]
    assert not oclgrind.find_reports("checking fft ...\nPASSED\n")


def test_environment_names_the_oclgrind_platform(tmp_path):
    env = oclgrind.oclgrind_env(str(tmp_path), icd=__file__, base={"PYOPENCL_CTX": "0"})
    assert (tmp_path / "oclgrind.icd").read_text().strip() == os.path.abspath(__file__)
    assert env["OCL_ICD_VENDORS"] == str(tmp_path) and env["CLHOLO_DEVICE"] == "oclgrind"
    assert env["OCLGRIND_DATA_RACES"] == "1" and "PYOPENCL_CTX" not in env
    with pytest.raises(FileNotFoundError, match="apt-get install oclgrind"):
        oclgrind.oclgrind_env(str(tmp_path), icd=str(tmp_path / "missing.so"))
