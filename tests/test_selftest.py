"""``clholo selftest``: passes on PoCL, fails (exit 1, naming the family) when a result is
wrong, writes the device facts as JSON without replacing files."""

import dataclasses
import json

import numpy as np
import pytest

from clholo import cli, reference, selftest
from clholo.host import runtime


def test_selftest_passes_on_this_device(queue):
    report = selftest.run_selftest(quick=True, queue=queue, speed=False)
    failed = [(c.family, c.name, c.error, c.tolerance, c.message) for c in report.checks
              if not c.passed]
    assert not failed and report.passed
    assert {c.family for c in report.checks} == {f[0] for f in selftest.FAMILIES}
    fft_names = " ".join(c.name for c in report.checks if c.family == "fft")
    for variant in ("cpu ", "gpu ", "gpu-global ", "callbacks"):
        assert variant in fft_names
    assert all(np.isfinite(c.error) and c.tolerance >= 0 for c in report.checks)
    text = report.format_text()
    assert "PASSED" in text and queue.device.name.strip() in text


def test_cli_json_holds_the_device_facts_and_the_speed_line(tmp_path, capsys):
    path = tmp_path / "selftest.json"
    assert cli.main(["selftest", "--quick", "--json", str(path)]) == 0
    out = capsys.readouterr().out
    assert "PASSED" in out and "speed    FFT 256x256" in out
    d = json.loads(path.read_text())
    dev = d["device"]
    for key in ("name", "vendor", "driver_version", "opencl_version", "max_work_group_size",
                "max_work_item_sizes", "local_mem_bytes", "global_mem_bytes", "fp64",
                "extensions"):
        assert key in dev, key
    assert dev["name"] == runtime.choose_device().name.strip()
    assert dev["local_mem_bytes"] > 0 and isinstance(dev["extensions"], list)
    assert d["passed"] and d["failed_families"] == []
    assert d["speed"]["fft_shape"] == [256, 256] and d["speed"]["fft_ms"] > 0
    assert d["speed"]["hologram_ms_per_layer"] > 0
    assert {"fft_strip", "composite_layer", "splat_raster"} <= set(d["kernels_launched"])
    c = d["checks"][0]
    assert {"family", "name", "metric", "error", "tolerance", "passed"} <= set(c)
    # no temporary left; the sidecar records that clholo wrote it (the one output policy)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".selftest.json.clholo-output.json",
                                                          "selftest.json"]


def test_a_wrong_reference_fails_with_exit_1_and_names_the_family(monkeypatch, capsys,
                                                                  tmp_path):
    real = reference.composite_layer

    def broken(u, color, alpha, phase):  # the emitted wave's phase flipped
        return real(u, color, alpha, -np.asarray(phase))

    monkeypatch.setattr(reference, "composite_layer", broken)
    path = tmp_path / "r.json"
    assert cli.main(["selftest", "--quick", "--json", str(path)]) == 1
    out = capsys.readouterr().out
    assert "FAILED" in out and "composite" in out.split("FAILED")[-1]
    d = json.loads(path.read_text())
    # the hologram and RPWS references are built on the composite reference: they fail too
    assert d["passed"] is False and "composite" in d["failed_families"]
    assert set(d["failed_families"]) <= {"composite", "hologram", "rpws"}
    bad = [c for c in d["checks"] if not c["passed"]]
    assert bad and all(c["error"] > c["tolerance"] for c in bad)


def test_a_launch_limit_error_is_a_failed_check_with_its_message(queue, monkeypatch):
    # a device whose work-groups may be 8 wide in each dimension (the FFT plans for the
    # kernels' own work-group limits, not for this one): the check stops the GPU kernels
    real = runtime._limits_of_device
    monkeypatch.setattr(runtime, "_limits_of_device",
                        lambda dev: dataclasses.replace(real(dev), max_item_sizes=(8, 8, 8)))
    report = selftest.run_selftest(quick=True, queue=queue, families=["fft"], speed=False)
    assert not report.passed and report.failed_families == ["fft"]
    bad = [c for c in report.checks if not c.passed]
    assert all(c.name.startswith("gpu ") and "LaunchLimitError" in c.message
               and "fft_lines" in c.message for c in bad)
    assert "CL_DEVICE_MAX_WORK_ITEM_SIZES" in report.format_text()


def test_json_never_replaces_a_file(tmp_path, capsys):
    path = tmp_path / "old.json"
    path.write_text("keep me")
    assert cli.main(["selftest", "--quick", "--json", str(path)]) == 2
    assert "exists" in capsys.readouterr().err
    assert path.read_text() == "keep me"


def test_unknown_family_is_refused(queue):
    with pytest.raises(ValueError, match="families"):
        selftest.run_selftest(queue=queue, families=["fft", "nope"])
