"""A GPU driver that is installed but not registered with the OpenCL loader (issue 22): ``clholo
info``, ``clholo selftest`` and the device errors find the vendor's library and print the exact
fix. The search roots are injected (``CLHOLO_OPENCL_LIB_DIRS``) and the ICD folder too
(``OCL_ICD_VENDORS``), so a fake library stands for NVIDIA's on any machine."""

import dataclasses
import os

import pyopencl as cl
import pytest

from clholo import cli, selftest
from clholo.host import drivers, runtime


@pytest.fixture
def fake_nvidia(tmp_path, monkeypatch):
    """A fake ``libnvidia-opencl.so.1`` in a folder that is the only search root, and an empty
    folder of ICD files that the loader is pointed at."""
    lib_dir = tmp_path / "usr" / "local" / "nvidia" / "lib64"
    lib_dir.mkdir(parents=True)
    lib = lib_dir / "libnvidia-opencl.so.1"
    lib.write_bytes(b"\x7fELF fake")
    (lib_dir / "libnvidia-opencl.so").symlink_to(lib.name)  # the same file: reported once
    icd = tmp_path / "vendors"
    icd.mkdir()
    monkeypatch.setenv(drivers.SEARCH_ENV, str(lib_dir))
    monkeypatch.setenv("OCL_ICD_VENDORS", str(icd))
    return lib, icd


def _no_platforms():
    raise cl.LogicError("clGetPlatformIDs failed: PLATFORM_NOT_FOUND_KHR")


def test_the_library_is_found_once_and_not_registered(fake_nvidia):
    lib, icd = fake_nvidia
    found = drivers.find_vendor_libraries()
    assert found == [drivers.VendorLibrary("NVIDIA", str(lib), "nvidia.icd", False)]
    advice = drivers.driver_advice(found, situation="No OpenCL platform")
    assert f"mkdir -p {icd} && echo {lib} > {icd}/nvidia.icd" in advice
    assert f"OCL_ICD_VENDORS={icd} is set" in advice
    assert "export OCL_ICD_VENDORS=" in advice and "clholo info" in advice


def test_other_vendors_and_globbed_roots(tmp_path, monkeypatch):
    for sub, name in (("opt/rocm-6.2/lib", "libamdocl64.so"),
                      ("usr/lib/x86_64-linux-gnu/intel-opencl", "libigdrcl.so")):
        (tmp_path / sub).mkdir(parents=True)
        (tmp_path / sub / name).write_bytes(b"")
    monkeypatch.setenv("OCL_ICD_VENDORS", str(tmp_path))  # no .icd files in it
    found = drivers.find_vendor_libraries([str(tmp_path / "opt" / "rocm*" / "lib"),
                                           str(tmp_path / "usr/lib/x86_64-linux-gnu/intel-opencl")])
    assert [(f.vendor, f.icd_name, f.registered) for f in found] == [
        ("AMD ROCm", "amdocl64.icd", False), ("Intel", "intel.icd", False)]
    assert drivers.find_vendor_libraries([str(tmp_path / "nowhere")]) == []
    assert drivers.driver_advice([]) == ""


def test_a_registered_library_gets_other_advice(fake_nvidia):
    lib, icd = fake_nvidia
    (icd / "nvidia.icd").write_text(f"{lib}\n")
    (found,) = drivers.find_vendor_libraries()
    assert found.registered
    advice = drivers.driver_advice([found], situation="No OpenCL platform")
    assert "is registered" in advice and "did not load" in advice and "echo" not in advice


def test_info_without_a_platform_prints_the_fix(fake_nvidia, monkeypatch, capsys):
    lib, icd = fake_nvidia
    monkeypatch.setattr(cl, "get_platforms", _no_platforms)
    assert cli.main(["info"]) == 3  # the environment's exit code (docs/errors.md)
    err = capsys.readouterr().err
    assert err.startswith("clholo info: error: No OpenCL platform")
    assert "No OpenCL platform" in err and "pocl-binary-distribution" in err
    assert f"echo {lib} > {icd}/nvidia.icd" in err


def test_the_device_error_prints_the_fix(fake_nvidia, monkeypatch):
    lib, icd = fake_nvidia
    monkeypatch.setattr(cl, "get_platforms", _no_platforms)
    with pytest.raises(runtime.NoDeviceError) as info:
        runtime.choose_device()
    assert f"echo {lib} > {icd}/nvidia.icd" in str(info.value)


def test_asking_for_a_gpu_that_is_not_there_prints_the_fix(fake_nvidia, monkeypatch):
    lib, icd = fake_nvidia
    if any("GPU" in d.device_type for d in runtime.list_devices()):
        # a visible GPU: the driver works, no advice (asserted), whatever is on disk
        monkeypatch.setenv("CLHOLO_DEVICE", "no-such-device-anywhere")
        with pytest.raises(runtime.NoDeviceError) as info:
            runtime.choose_device()
        assert "nvidia.icd" not in str(info.value)
        return
    monkeypatch.setenv("CLHOLO_DEVICE", "nvidia")
    with pytest.raises(runtime.NoDeviceError) as info:
        runtime.choose_device()
    msg = str(info.value)
    assert "CLHOLO_DEVICE='nvidia' matches no OpenCL device" in msg
    assert f"echo {lib} > {icd}/nvidia.icd" in msg


def test_info_with_no_gpu_among_the_devices_prints_the_fix(fake_nvidia, monkeypatch, capsys):
    lib, icd = fake_nvidia
    cpu_only = [dataclasses.replace(d, device_type="CPU") for d in runtime.list_devices()]
    monkeypatch.setattr(runtime, "list_devices", lambda: cpu_only)
    assert cli.main(["info"]) == 0
    out = capsys.readouterr().out
    assert "clholo uses *" in out
    assert "No GPU among the OpenCL devices" in out and f"echo {lib} > {icd}/nvidia.icd" in out


def test_selftest_reports_the_driver_when_its_device_is_not_a_gpu(fake_nvidia, queue):
    lib, icd = fake_nvidia
    report = selftest.run_selftest(quick=True, queue=queue, families=["random"], speed=False)
    d = report.to_dict()["drivers"]
    if queue.device.type & cl.device_type.GPU:
        assert d == {}  # a GPU is in use: nothing to fix
        return
    assert d["libraries"] == [{"vendor": "NVIDIA", "path": str(lib), "icd_file": "nvidia.icd",
                               "registered": False}]
    assert f"echo {lib} > {icd}/nvidia.icd" in d["advice"]
    assert "note     The device is not a GPU, but NVIDIA's OpenCL driver" in report.format_text()


def test_nothing_found_adds_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv(drivers.SEARCH_ENV, str(tmp_path))
    monkeypatch.setattr(cl, "get_platforms", _no_platforms)
    assert cli.main(["info"]) == 3  # the environment's exit code (docs/errors.md)
    err = capsys.readouterr().err
    assert err.startswith("clholo info: error: No OpenCL platform")
    assert "No OpenCL platform" in err and "ICD" not in err


def test_default_search_reads_the_ld_cache(monkeypatch, tmp_path):
    """Without CLHOLO_OPENCL_LIB_DIRS the ld.so cache counts too (a fake ldconfig here)."""
    lib = tmp_path / "libnvidia-opencl.so.1"
    lib.write_bytes(b"")
    fake = tmp_path / "bin"
    fake.mkdir()
    ldconfig = fake / "ldconfig"
    ldconfig.write_text("#!/bin/sh\necho '1 libs found in cache'\n"
                        f"echo '\tlibnvidia-opencl.so.1 (libc6,x86-64) => {lib}'\n")
    ldconfig.chmod(0o755)
    monkeypatch.delenv(drivers.SEARCH_ENV, raising=False)
    monkeypatch.setenv("OCL_ICD_VENDORS", str(tmp_path))
    monkeypatch.setattr(drivers, "_LDCONFIG", (str(ldconfig),))
    monkeypatch.setattr(drivers, "_DEFAULT_DIRS", ())
    monkeypatch.setenv("LD_LIBRARY_PATH", "")
    assert [f.path for f in drivers.find_vendor_libraries()] == [str(lib)]
    assert os.environ.get(drivers.SEARCH_ENV) is None


def test_platforms_that_list_no_device_are_not_told_to_install_a_driver(monkeypatch, capsys):
    """``XDG_CACHE_HOME`` naming a file: PoCL's platform is there and lists no device (it
    cannot make its cache); "Install an OpenCL driver" sent the user the wrong way."""
    if not runtime._platforms():
        pytest.skip("no OpenCL platform here at all")
    monkeypatch.setattr(runtime, "_all_devices", lambda: [])
    monkeypatch.setattr(runtime, "list_devices", lambda: [])
    with pytest.raises(runtime.NoDeviceError) as info:
        runtime.choose_device()
    assert "list no device" in str(info.value) and "XDG_CACHE_HOME" in str(info.value)
    assert "Install an OpenCL driver" not in str(info.value)
    assert cli.main(["info"]) == 3
    assert "list no device" in capsys.readouterr().err
