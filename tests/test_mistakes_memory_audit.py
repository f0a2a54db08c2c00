"""Memory the process can still have, found by an audit (2026-11-29, seventh session): under
an address-space limit (``ulimit -v``, as clusters set) PoCL aborted the process (SIGABRT from
an assertion: its buffers are allocated when first used, and a failed one is not an OpenCL
error), and the CLI's check let renders through that needed more than was free."""

import subprocess
import sys

import pytest


def test_available_host_bytes_sees_an_address_space_limit():
    """The child limits its own address space to 300 MB beyond what it maps."""
    code = (
        "import resource\n"
        "from clholo.host.memory import available_host_bytes\n"
        "vm = [int(l.split()[1]) * 1024 for l in open('/proc/self/status')\n"
        "      if l.startswith('VmSize:')][0]\n"
        "resource.setrlimit(resource.RLIMIT_AS, (vm + (300 << 20), resource.RLIM_INFINITY))\n"
        "print(available_host_bytes())\n")
    if not __import__("os").path.exists("/proc/self/status"):
        pytest.skip("needs Linux's /proc")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert 0 < int(out.stdout) <= 300 << 20


def test_a_cpu_devices_budget_stays_within_what_the_host_can_give(monkeypatch):
    import pyopencl as cl

    from clholo.host import memory

    class Device:
        global_mem_size = 64 << 30

        def __init__(self, kind):
            self.type = kind

    monkeypatch.setattr(memory, "available_host_bytes", lambda: 6 << 30)
    assert memory.default_budget(Device(cl.device_type.CPU)) == 3 << 30
    assert memory.default_budget(Device(cl.device_type.GPU)) == 32 << 30  # its own memory


def test_the_cli_refuses_holograms_beyond_the_memory_available(monkeypatch):
    """It compared with the machine's whole memory: a render of up to all of it passed and
    failed at the write, after the work."""
    from clholo import render_folder
    from clholo.errors import EnvironmentProblem
    from clholo.host import memory

    monkeypatch.setattr(memory, "available_host_bytes", lambda: 1 << 30)
    with pytest.raises(EnvironmentProblem, match=r"take 2\.0 GiB but only 1\.0 GiB of memory is "
                                                 r"available \(free, within any ulimit -v\)"):
        render_folder._check_host_memory(2 << 30, frames=10)
    render_folder._check_host_memory(1 << 29, frames=10)


def test_a_focal_stack_of_too_many_depths_is_refused_at_once(queue):
    """10^7 depths: a minute and a half in per-depth checks, then a refusal that spoke of
    "fewer layers" (a focal stack has depths)."""
    import time

    import numpy as np

    import clholo
    from clholo.hologram import focal_stack

    h = np.ones((1, 3, 64, 64), np.complex64)
    t = time.perf_counter()
    with pytest.raises(MemoryError, match=r"^a focal stack of 10000000 depths holds 10000000 x 3 "
                                          r"x 64 x 64 float32 intensities \(458 GiB\).*use fewer "
                                          r"depths"):
        focal_stack(h, clholo.Optics(), np.linspace(1e-3, 5e-3, 10 ** 7), queue=queue)
    assert time.perf_counter() - t < 30
    with pytest.raises(MemoryError, match=r"^a focal stack of 3 depths .* than the 9\.31e-07 GiB"):
        focal_stack(h, clholo.Optics(), [1e-3, 2e-3, 3e-3], memory_budget=1000, queue=queue)


def test_the_padded_grid_depends_on_the_farthest_distance_only():
    """Every distance is checked at once; the grid is the farthest one's (the spread grows
    with |dz|), as it was when each was sized in turn."""
    import numpy as np

    from clholo.propagation import device_padded_shape

    dz = -np.linspace(1e-3, 6e-3, 50)
    kw = dict(wavelength=[638e-9, 450e-9], pitch=8e-6)
    assert device_padded_shape((64, 96), dz, **kw) == device_padded_shape((64, 96), -6e-3, **kw)
    assert device_padded_shape((64, 96), dz[::-1], **kw) == device_padded_shape((64, 96), dz,
                                                                                 **kw)


def test_a_file_size_limit_is_not_called_a_full_disk(tmp_path, capsys, monkeypatch):
    """EFBIG (ulimit -f, FAT32's 4 GiB) said "free space there", which does not help."""
    import errno

    from clholo import cli
    from clholo.encode import quantize as q
    import numpy as np

    from clholo.io import write_hologram

    holo = tmp_path / "h.npz"
    rng = np.random.default_rng(1)
    write_hologram(holo, np.exp(2j * np.pi * rng.random((1, 1, 8, 8))).astype(np.complex64),
                   pitch=8e-6, wavelengths=[520e-9])

    def too_big(*a, **k):
        raise OSError(errno.EFBIG, "File too large")

    monkeypatch.setattr(q, "write_pattern_pngs", too_big)
    assert cli.main(["encode", str(holo), "--method", "dpac", "--progress", "off", "--out",
                     str(tmp_path / "o")]) == 3
    err = capsys.readouterr().err
    assert "File too large while writing the output --out" in err
    assert "the largest size allowed (the shell's ulimit -f" in err and "free space" not in err


_SHORT_WRITE = """
import errno, os, resource, sys
import numpy as np
from clholo.io import write_hologram
from clholo.io.images import write_image
folder = sys.argv[1]
rng = np.random.default_rng(0)
resource.setrlimit(resource.RLIMIT_FSIZE, (100000, 100000))
for name, write in (
        ("p.png", lambda p: write_image(p, (rng.random((512, 512)) * 255).astype(np.uint8),
                                        dtype="uint8")),
        ("h.exr", lambda p: write_hologram(p, np.exp(2j * np.pi * rng.random((2, 1, 128, 128)))
                                           .astype(np.complex64), pitch=8e-6,
                                           wavelengths=[520e-9]))):
    try:
        write(os.path.join(folder, name))
        print(name, "written")
    except OSError as exc:
        print(name, errno.errorcode.get(exc.errno), exc.filename == os.path.join(folder, name))
print(sorted(os.listdir(folder)))
"""


@pytest.mark.skipif(sys.platform == "win32", reason="needs RLIMIT_FSIZE")
def test_a_short_image_write_is_an_error_not_a_truncated_file(tmp_path):
    """Under a file-size limit (or on a full disk) OpenImageIO's PNG writer returned success
    and left a truncated PNG under the final name (``clholo encode`` exit 0, the manifest
    holding its checksum); its EXR writer's failure was an internal error (exit 70). Both
    are now OSError EFBIG/ENOSPC naming the destination (exit 3), and nothing is left."""
    out = subprocess.run([sys.executable, "-c", _SHORT_WRITE, str(tmp_path)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == ["p.png EFBIG True", "h.exr EFBIG True", "[]"]


def test_a_writer_failure_on_a_full_disk_is_enospc(tmp_path, monkeypatch):
    import errno
    import os

    from clholo.io import images

    written = tmp_path / ".p.x.tmp.png"
    written.write_bytes(b"x" * 10)

    class Full:
        f_bavail, f_frsize = 3, 4096

    monkeypatch.setattr(os, "statvfs", lambda p: Full())
    failure = images.write_failure(tmp_path / "p.png", written, "Write error; again")
    assert failure.errno == errno.ENOSPC and failure.filename == str(tmp_path / "p.png")
    assert "(Write error)" in str(failure)

    class Roomy:
        f_bavail, f_frsize = 1 << 20, 4096

    monkeypatch.setattr(os, "statvfs", lambda p: Roomy())
    assert images.write_failure(tmp_path / "p.png", written, "a codec's own error") is None


def test_an_image_larger_than_memory_is_refused_from_its_header(tmp_path, monkeypatch):
    """A 4.6 MB PNG that says 40000 x 40000 was decoded in full (14 s, 4.8 GB, whatever
    --scale), then failed with "std::bad_alloc"; it is refused from its header now."""
    import numpy as np

    from clholo import _sysmem as memory
    from clholo.errors import EnvironmentProblem
    from clholo.io.images import read_image, write_image

    path = tmp_path / "photo.png"
    write_image(path, (np.random.default_rng(0).random((48, 64, 3)) * 255).astype(np.uint8),
                dtype="uint8")
    pixels, _ = read_image(path)
    assert pixels.shape == (48, 64, 3)
    need = 48 * 64 * 3 * (1 + 12)
    monkeypatch.setattr(memory, "available_host_bytes", lambda: need - 1)
    with pytest.raises(EnvironmentProblem, match=r"^image .*photo\.png is 64 x 48 pixels x 3 "
                                                 r"channels: reading it needs .* GiB, more than"):
        read_image(path)
    monkeypatch.setattr(memory, "available_host_bytes", lambda: need)
    assert read_image(path)[0].shape == (48, 64, 3)
