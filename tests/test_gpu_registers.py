"""``benchmarks/gpu_registers.py``: the GPU FFT kernels compiled for NVIDIA without a GPU
(clang's NVPTX target, libclc, ``ptxas -v``). Where those tools are installed, the passes the
lab's workloads run must build with no stack frame: their butterflies' values in registers,
not in memory (the SLM grid's column round trip had a 1088-byte frame before fused_butterfly
stopped copying through arrays)."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    spec = importlib.util.spec_from_file_location("gpu_registers",
                                                  ROOT / "benchmarks" / "gpu_registers.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_missing_compilers_are_named(monkeypatch, capsys):
    mod = _tool()
    monkeypatch.setattr(mod.shutil, "which", lambda name: None)
    assert mod.main(["--cases", "slm-cols", "--variants", "fixed"]) == 2
    err = capsys.readouterr().err
    assert "missing clang-14" in err and "ptxas" in err and "Debian's clang-14" in err


def test_occupancy_model():
    mod = _tool()
    # 32 registers, 256 work-items, 30 KiB: shared memory allows 7 groups (228 KiB / 31 KiB)
    occ = mod.occupancy(32, 256, 30 * 1024)
    assert occ == {"groups": 7, "resident": 1792, "max_group": 1024}
    # 160 registers: 5120 a warp, 12 warps of the SM's 65536 registers: one group of 256
    occ = mod.occupancy(160, 256, 30 * 1024)
    assert occ["groups"] == 1 and occ["max_group"] == 384
    # what a group's size leaves a work-item (8 at a time, ptxas's 255 at most)
    assert [mod.register_cap(t) for t in (1024, 896, 672, 512, 256, 64)] == [64, 72, 96, 128,
                                                                              255, 255]


@pytest.mark.parametrize("case", ["slm-cols", "1024-cols", "4k-cols", "sgd-cols"])
def test_split_columns_fit_their_group_without_spilling(case, capsys):
    """split_columns at 512 and 1024 work-items: where a pass takes more registers than its
    group allows, held to them it spills nothing (the in-place plan's columns, radix-9 and
    radix-15 butterflies, spilled 312 and 276 bytes at 1024: they keep to 512)."""
    mod = _tool()
    gone = mod.missing_tools()
    if gone:
        pytest.skip(f"needs {', '.join(gone)} (Debian clang-14 libclc-14; ptxas from CUDA)")
    assert mod.main(["--cases", case, "--variants", "cols-split,cols-split1024"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines()
            if line.startswith(f"| {case} | cols-split")]
    assert len(rows) == 2, rows
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[2].startswith("split"), row
        assert cells[6] == "0/0" and int(cells[7]) == 0, row
        assert cells[11] == "-" or cells[11].endswith(" 0 B spilled, 0 B stack"), row


@pytest.mark.parametrize("case", ["slm-cols", "slm-rows", "1024-cols", "4k-cols", "sgd-cols",
                                  "sgd-rows", "4k-pad2-rows", "8192-rows", "4k-rows"])
def test_default_passes_build_without_a_stack_frame(case, capsys):
    mod = _tool()
    gone = mod.missing_tools()
    if gone:
        pytest.skip(f"needs {', '.join(gone)} (Debian clang-14 libclc-14; ptxas from CUDA)")
    assert mod.main(["--cases", case, "--variants", "fixed"]) == 0
    out = capsys.readouterr().out
    (row,) = [line for line in out.splitlines() if line.startswith(f"| {case} | fixed |")]
    cells = [c.strip() for c in row.strip("|").split("|")]
    registers, spills, stack = int(cells[5]), cells[6], int(cells[7])
    assert 0 < registers <= 128 and spills == "0/0" and stack == 0, row


@pytest.mark.parametrize("argv", [["--render", "40x60", "--variants", "fixed,planes-quads"],
                                  ["--render", "8x3840", "--pad", "2"],
                                  ["--sgd", "48"], ["--sgd", "48", "--sgd-fuse", "all"]],
                         ids=["render", "render-split", "sgd-round-trips", "sgd-all"])
def test_the_workloads_own_programs_with_their_callbacks(capsys, argv):
    """--render / --sgd: the programs a GPU-variant render (the row round trip with the
    composite callback among them, also by quads on planes) or SGD (its steps inside the
    adjoint's passes) builds compile for NVIDIA with no stack frame (the composite held 16
    bytes in clang's build while the phase took its Philox word by a run-time index, the
    quads 48; in the split plan's last stage outputs it held 384)."""
    mod = _tool()
    gone = mod.missing_tools()
    if gone:
        pytest.skip(f"needs {', '.join(gone)} (Debian clang-14 libclc-14; ptxas from CUDA)")
    assert mod.main(argv) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| n=")]
    assert any("+callbacks" in r for r in rows), rows
    if "planes-quads" in argv:
        assert any("+callbacks quads | planes-quads" in r for r in rows), rows
    if "--pad" in argv:  # 7680-point rows: the split plan, its composite swept half a line
        assert any("round trip +callbacks split" in r for r in rows), rows  # at a time
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]  # program, variant, items, ...
        assert int(cells[3]) > 0 and cells[4] == "0/0" and int(cells[5]) == 0, row
