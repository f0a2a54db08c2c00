"""One device rule for every command (issue 26, section 3): ``CLHOLO_DEVICE`` (else
``PYOPENCL_CTX``) that matches no device is exit 3 with a ``clholo CMD: error:`` line, the list
of devices and how to set it, whatever the command (``clholo batch``:
``tests/test_batch.py::test_device_variables_pick_the_workers_device``)."""

import numpy as np
import pytest

import clholo
from clholo import cli
from clholo.host import runtime


@pytest.fixture
def nonsense(monkeypatch):
    """Each test sets one variable; the default queue is made again from it."""
    monkeypatch.delenv("CLHOLO_DEVICE", raising=False)
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    runtime.reset_default_queue()
    yield monkeypatch
    runtime.reset_default_queue()


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("device")
    rng = np.random.default_rng(263)
    clholo.io.write_mpi(folder / "scene", clholo.MPI(rng.random((2, 8, 8, 3)),
                                                     rng.random((2, 8, 8)), [2e-3, 4e-3]))
    return folder / "scene"


@pytest.mark.parametrize("var", ["CLHOLO_DEVICE", "PYOPENCL_CTX"])
@pytest.mark.parametrize("argv", [["info"], ["render", "SCENE", "--frames", "1", "--out", "o"],
                                  ["selftest", "--quick"]], ids=["info", "render", "selftest"])
def test_a_device_variable_matching_nothing_is_exit_3(tmp_path, nonsense, capsys, scene, var,
                                                      argv):
    nonsense.setenv(var, "nonsense")
    nonsense.chdir(tmp_path)
    argv = [str(scene) if a == "SCENE" else a for a in argv] + ["--progress", "off"]
    assert cli.main(argv) == 3
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith(f"clholo {argv[0]}: "))
    assert lines[first] == (f"clholo {argv[0]}: error: {var}='nonsense' matches no OpenCL "
                            f"device. Available devices:"), captured.err
    assert all(d.selector in captured.err for d in runtime.list_devices())
    assert lines[-1].startswith(f"Set {var} to 'P:D'")
    if argv[0] == "info":  # nothing listed on stdout as if a device had been chosen
        assert captured.out == ""
    assert list(tmp_path.iterdir()) == []
