"""Device choice, program loading and the errors a user sees."""

import os
import subprocess
import sys

import numpy as np
import pyopencl as cl
import pytest

from clholo.host import runtime


def test_list_devices_has_the_test_device(cl_device):
    names = [d.device_name for d in runtime.list_devices()]
    assert cl_device.name.strip() in names


def test_selector_by_index_and_name(monkeypatch):
    first = runtime.list_devices()[0]
    monkeypatch.setenv("CLHOLO_DEVICE", first.selector)
    assert runtime.choose_device().name.strip() == first.device_name
    monkeypatch.setenv("CLHOLO_DEVICE", first.device_name[:6].upper())
    assert runtime.choose_device().name.strip() == first.device_name


def test_clholo_device_takes_precedence_over_pyopencl_ctx(monkeypatch):
    monkeypatch.setenv("PYOPENCL_CTX", "no-such-device-anywhere")
    monkeypatch.setenv("CLHOLO_DEVICE", runtime.list_devices()[0].selector)
    runtime.choose_device()  # PYOPENCL_CTX is not consulted
    monkeypatch.delenv("CLHOLO_DEVICE")
    with pytest.raises(runtime.NoDeviceError, match="PYOPENCL_CTX"):
        runtime.choose_device()


def test_bad_device_lists_devices(monkeypatch):
    monkeypatch.setenv("CLHOLO_DEVICE", "no-such-device-anywhere")
    with pytest.raises(runtime.NoDeviceError) as info:
        runtime.choose_device()
    msg = str(info.value)
    assert "CLHOLO_DEVICE='no-such-device-anywhere'" in msg
    for d in runtime.list_devices():
        assert d.device_name in msg and d.selector in msg
    monkeypatch.setenv("CLHOLO_DEVICE", "9:9")
    with pytest.raises(runtime.NoDeviceError, match="9:9"):
        runtime.choose_device()


def test_build_error_carries_log_and_file(cl_context):
    broken = "__kernel void k(__global float *x) { x[get_global_id(0)] = undefined_name; }"
    with pytest.raises(runtime.ProgramBuildError) as info:
        runtime.build_program(cl_context, "broken_example.cl", source=broken)
    err = info.value
    assert "kernels/broken_example.cl" in str(err)
    assert "undefined_name" in err.log


def test_programs_are_memoized_per_context(cl_context, cl_device):
    a = runtime.build_program(cl_context, "elementwise.cl", defines={"REAL": "float"})
    b = runtime.build_program(cl_context, "elementwise.cl", defines={"REAL": "float"})
    assert a is b
    other = cl.Context([cl_device])
    c = runtime.build_program(other, "elementwise.cl", defines={"REAL": "float"})
    assert c is not a
    k1 = runtime.get_kernel(cl_context, "elementwise.cl", "complex_scale", defines={"REAL": "float"})
    assert k1 is runtime.get_kernel(cl_context, "elementwise.cl", "complex_scale",
                                    defines={"REAL": "float"})


def test_include_path_reaches_headers(cl_context):
    src = '#include "clholo_complex.h"\n__kernel void k(__global float2 *a) { a[0] = cmul(a[0], a[0]); }'
    runtime.build_program(cl_context, "include_probe.cl", source=src)


def test_builds_are_keyed_on_content_not_on_paths(cl_context, monkeypatch):
    """The headers are pasted in, so neither the options nor the source hold a path: a driver's
    binary cache then serves a checkout or a virtual environment anywhere else (issue 19)."""
    seen = []
    real_program = runtime.cl.Program

    class Recording:
        def __init__(self, ctx, text):
            self.text, self.inner = text, real_program(ctx, text)

        def build(self, options):
            seen.append((self.text, list(options)))
            return self.inner.build(options=options)

    monkeypatch.setattr(runtime.cl, "Program", Recording)
    runtime.build_program(cl.Context(cl_context.devices), "composite.cl")
    (text, options), = seen
    for path in (runtime.kernel_dir(), runtime._pyopencl_include_dir(), os.getcwd()):
        assert path not in text and not any(path in o for o in options), path
    assert not any(o == "-I" or o.startswith("-I") for o in options)
    # composite.cl -> random_phase.h -> Random123's philox.cl -> array.h -> openclfeatures.h
    for header in ("random_phase.h", "philox.cl", "array.h", "openclfeatures.h"):
        assert f'#line 1 "{header}"' in text
    assert '#include "random_phase.h"' not in text


def test_inlined_headers_keep_their_names_and_lines_in_errors(cl_context, tmp_path, monkeypatch):
    """A compile error inside an included header still names that header and its line, and the
    including file's lines after the include are counted right."""
    (tmp_path / "probe_header.h").write_text("// line 1\nfloat probe_h(float x) { return x; }\n"
                                             "// line 3\n")
    monkeypatch.setattr(runtime, "kernel_dir", lambda: str(tmp_path))
    text = runtime.inline_includes('// one\n#include "probe_header.h"\n// three\n#include '
                                   '<stddef.h>\n', "probe.cl")
    assert text.splitlines() == ['// one', '#line 1 "probe_header.h"', '// line 1',
                                 'float probe_h(float x) { return x; }', '// line 3', '',
                                 '#line 3 "probe.cl"', '// three', '#include <stddef.h>']
    (tmp_path / "bad_header.h").write_text("// fine\nfloat bad_h(void) { return undefined_thing; }\n")
    src = '// 1\n// 2\n#include "bad_header.h"\n__kernel void k(__global float *a) { a[0] = 1; }\n'
    with pytest.raises(runtime.ProgramBuildError) as info:
        runtime.build_program(cl_context, "uses_bad_header.cl", source=src)
    assert "undefined_thing" in info.value.log and "bad_header.h:2" in info.value.log


def _nvidia_style_build(monkeypatch, log_for):
    """cl.Program stand-in whose build fails with the log ``log_for(text)`` in NVIDIA's form:
    locations named ``<kernel>`` with the physical line of the source handed to it."""
    seen = []

    class NvidiaLike:
        def __init__(self, ctx, text):
            self.text = text
            seen.append(text)

        def build(self, options):
            raise cl.RuntimeError("clBuildProgram failed: BUILD_PROGRAM_FAILURE - \n\nBuild on "
                                  "<pyopencl.Device 'NVIDIA H100 80GB HBM3' on 'NVIDIA CUDA' at "
                                  "0x55d0c0de>:\n\n" + log_for(self.text))

    monkeypatch.setattr(runtime.cl, "Program", NvidiaLike)
    return seen


def _physical(text, needle):
    return next(i + 1 for i, line in enumerate(text.splitlines()) if needle in line)


def test_a_header_s_error_names_the_header_whatever_the_compiler_prints(cl_context, tmp_path,
                                                                       monkeypatch):
    """issue 22: NVIDIA's log ignores the #line file names and counts the built source's own
    lines (``<kernel>:123:5: error: ...``); clholo pasted the headers in, so it maps them back"""
    (tmp_path / "bad_header.h").write_text("// fine\nfloat bad_h(void) { return undefined_thing; }\n")
    monkeypatch.setattr(runtime, "kernel_dir", lambda: str(tmp_path))

    def log_for(text):
        h, k = _physical(text, "undefined_thing"), _physical(text, "other_undefined")
        return (f"<kernel>:{h}:36: error: use of undeclared identifier 'undefined_thing'\n"
                f"float bad_h(void) {{ return undefined_thing; }}\n"
                f"                                   ^\n"
                f":{k}:44: error: use of undeclared identifier 'other_undefined'\n"
                f"In file included from <kernel>:{h}:\n"
                f"/tmp/nv_tmp_1234.cl:{k}: warning: something\n2 errors generated.\n")

    seen = _nvidia_style_build(monkeypatch, log_for)
    src = ('// 1\n// 2\n#include "bad_header.h"\n'
           '__kernel void k(__global float *a) { a[0] = other_undefined; }\n')
    with pytest.raises(runtime.ProgramBuildError) as info:
        runtime.build_program(cl.Context(cl_context.devices), "uses_bad_header.cl", source=src)
    log = info.value.log
    assert _physical(seen[0], "undefined_thing") != 2  # the physical line is not the header's
    assert "bad_header.h:2:36: error: use of undeclared identifier 'undefined_thing'" in log
    assert "uses_bad_header.cl:4:44: error: use of undeclared identifier 'other_undefined'" in log
    assert "In file included from bad_header.h:2:" in log
    assert "uses_bad_header.cl:4: warning" in log
    assert "<kernel>:" not in log and "nv_tmp" not in log
    assert "0x55d0c0de>:" in log and "2 errors generated." in log  # the rest is left alone
    assert f"<kernel>:{_physical(seen[0], 'undefined_thing')}:36:" in info.value.raw_log


def test_a_compiler_that_follows_line_numbers_but_not_names(cl_context, tmp_path, monkeypatch):
    """Should a compiler count the #line markers' numbers but print its own name, the source
    line it quotes under the location tells which line it means"""
    (tmp_path / "bad_header.h").write_text("// fine\nfloat bad_h(void) { return undefined_thing; }\n")
    monkeypatch.setattr(runtime, "kernel_dir", lambda: str(tmp_path))

    def log_for(text):
        return ("<kernel>:2:36: error: use of undeclared identifier 'undefined_thing'\n"
                "float bad_h(void) { return undefined_thing; }\n"
                "                                   ^\n")

    _nvidia_style_build(monkeypatch, log_for)
    src = '// 1\n// 2\n#include "bad_header.h"\n__kernel void k(__global float *a) { a[0] = 1; }\n'
    with pytest.raises(runtime.ProgramBuildError) as info:
        runtime.build_program(cl.Context(cl_context.devices), "uses_bad_header.cl", source=src)
    assert "\nbad_header.h:2:36: error: use of undeclared identifier" in info.value.log


def test_source_line_table_follows_line_markers_and_leaves_named_locations():
    text = ('// a1\n#line 1 "load callback"\n// cb1\n// cb2\n#line 7 "fft_cpu.cl"\n// f7\n'
            '#line 20\n// f20\n')
    table = runtime.source_line_table(text, "fft_cpu.cl")
    assert table[0] == ("fft_cpu.cl", 1)
    assert table[2:4] == [("load callback", 1), ("load callback", 2)]
    assert table[5] == ("fft_cpu.cl", 7) and table[7] == ("fft_cpu.cl", 20)
    # a compiler that followed the markers (PoCL) already named the file: left as it is
    assert runtime.map_build_log("error: load callback:2:3: x", table) == \
        "error: load callback:2:3: x"
    assert runtime.map_build_log("error: fft_cpu.cl:7:1: y", table) == "error: fft_cpu.cl:7:1: y"
    assert runtime.map_build_log("<kernel>:4:9: error: z", table) == "load callback:2:9: error: z"
    assert runtime.map_build_log("<kernel>:99:9: beyond", table) == "<kernel>:99:9: beyond"


def test_missing_kernel_file(cl_context):
    with pytest.raises(FileNotFoundError, match="no_such.cl"):
        runtime.build_program(cl_context, "no_such.cl")


def test_require_fp64_message():
    class FakeDevice:
        name = "toy "
        double_fp_config = 0
        extensions = ""

    from clholo.errors import EnvironmentProblem, ExitCode

    with pytest.raises(TypeError, match="no fp64 support.*complex64") as info:
        runtime.require_fp64(FakeDevice(), "the test")
    # the machine cannot (exit 3), not a bug (a plain TypeError is an internal error, exit 70)
    assert isinstance(info.value, EnvironmentProblem)
    assert info.value.exit_code == ExitCode.ENVIRONMENT


def test_profiling_helpers(queue):
    import pyopencl.array as cla

    a = cla.to_device(queue, np.arange(1024, dtype=np.float32) + 1)
    evt = cl.enqueue_copy(queue, a.data, np.ones(1024, np.float32))
    t = runtime.EventTimer()
    t.add("copy", evt)
    assert t.summary()["copy"] >= 0.0


def _run_cli(env_update, *args):
    env = dict(os.environ)
    env.update(env_update)
    return subprocess.run([sys.executable, "-m", "clholo.cli", *args], capture_output=True,
                          text=True, env=env, timeout=120)


def test_cli_info_lists_device_and_choice():
    res = _run_cli({}, "info")
    assert res.returncode == 0, res.stderr
    dev = runtime.choose_device().name.strip()
    assert dev in res.stdout and "fp64" in res.stdout and "clholo uses *" in res.stdout


def test_cli_info_bad_device():
    res = _run_cli({"CLHOLO_DEVICE": "no-such-device-anywhere"}, "info")
    # exit 3 (environment) with its error line, as every command (issue 26, section 3)
    assert res.returncode == 3
    assert "clholo info: error: CLHOLO_DEVICE='no-such-device-anywhere' matches no OpenCL " \
           "device" in res.stderr


def _no_platforms():
    # what the ICD loader reports when no vendor driver is installed
    raise cl.LogicError("clGetPlatformIDs failed: PLATFORM_NOT_FOUND_KHR")


def test_no_platform_gives_install_hint(monkeypatch, capsys):
    # pyopencl's wheel bundles PoCL and points its ICD loader at it, so no environment variable
    # can hide the platform from a subprocess: patch the platform query instead.
    from clholo import cli

    monkeypatch.setattr(cl, "get_platforms", _no_platforms)
    assert cli.main(["info"]) == 3  # environment (issue 26, section 3), not 1
    err = capsys.readouterr().err
    assert "No OpenCL platform" in err and "pocl-binary-distribution" in err


def test_no_platform_error_from_choose_device(monkeypatch):
    monkeypatch.setattr(cl, "get_platforms", _no_platforms)
    with pytest.raises(runtime.NoDeviceError, match="No OpenCL platform.*pocl"):
        runtime.choose_device()


# --- a device whose compiler does not know this CPU (PyPI's PoCL on an AMD Zen 5) -------------

_UNKNOWN_CPU_LOG = "error: unknown target CPU 'generic'"


def _fake_devices(monkeypatch, problems):
    """Two CPU devices on two PoCL platforms, in P:D order, whose probes answer ``problems``
    (by device name; None: it compiles)."""
    from types import SimpleNamespace

    fakes = [(pi, 0, SimpleNamespace(name=name, int_ptr=1000 + pi, type=cl.device_type.CPU,
                                     platform=SimpleNamespace(name="Portable Computing Language",
                                                              vendor="The pocl project")))
             for pi, name in enumerate(problems)]
    monkeypatch.setattr(runtime, "_all_devices", lambda: fakes)
    monkeypatch.setattr(runtime, "device_build_problem", lambda dev: problems[dev.name])
    monkeypatch.delenv("CLHOLO_DEVICE", raising=False)
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    return [d for _, _, d in fakes]


def test_the_default_choice_skips_a_device_that_cannot_compile(monkeypatch):
    broken, working = _fake_devices(monkeypatch, {"pthread-AMD EPYC": _UNKNOWN_CPU_LOG,
                                                  "pthread-znver3-AMD EPYC": None})
    assert runtime.choose_device() is working
    # a name or a type that matches both takes the one that compiles; P:D is taken as asked
    assert runtime.choose_device("epyc") is working
    assert runtime.choose_device("cpu") is working
    assert runtime.choose_device("0:0") is broken


def test_no_device_that_compiles_names_each_problem_and_the_fix(monkeypatch):
    _fake_devices(monkeypatch, {"pthread-AMD EPYC": _UNKNOWN_CPU_LOG,
                                "other-cpu": "error: something else"})
    with pytest.raises(runtime.NoDeviceError) as info:
        runtime.choose_device()
    msg = str(info.value)
    assert "none of them compiles" in msg
    assert f"0:0  Portable Computing Language / pthread-AMD EPYC: {_UNKNOWN_CPU_LOG}" in msg
    assert "1:0  Portable Computing Language / other-cpu: error: something else" in msg
    assert "apt-get install pocl-opencl-icd" in msg and "CLHOLO_DEVICE" in msg
    monkeypatch.setenv("CLHOLO_DEVICE", "pocl")
    with pytest.raises(runtime.NoDeviceError, match="CLHOLO_DEVICE='pocl' matches 2 devices"):
        runtime.choose_device()


def test_of_two_pocls_the_newer_llvm_is_taken_first(monkeypatch):
    """PyPI's PoCL (LLVM 14) listed before Debian's (LLVM 15): both compile the probe, the
    newer one is taken (LLVM 14 crashes on clholo's kernels on a Zen 4); a selector still
    takes what it names."""
    older, newer = _fake_devices(monkeypatch, {"pthread-AMD EPYC": None,
                                               "pthread-skylake-avx512-AMD EPYC": None})
    older.platform.version = "OpenCL 3.0 PoCL 3.0-rc2  Linux, Release, RELOC, LLVM 14.0.6"
    newer.platform.version = "OpenCL 3.0 PoCL 3.1+debian  Linux, None+Asserts, LLVM 15.0.6"
    assert runtime.choose_device() is newer
    assert runtime.choose_device("0:0") is older
    newer.platform.version = "OpenCL 3.0 PoCL 3.1  Linux"  # says no LLVM: P:D order
    assert runtime.choose_device() is older


def test_a_lone_device_is_taken_without_a_probe(monkeypatch):
    from types import SimpleNamespace

    lone = SimpleNamespace(name="only", int_ptr=7, type=cl.device_type.CPU,
                           platform=SimpleNamespace(name="P"))
    monkeypatch.setattr(runtime, "_all_devices", lambda: [(0, 0, lone)])
    monkeypatch.setattr(runtime, "device_build_problem",
                        lambda dev: pytest.fail("a lone device was probed"))
    monkeypatch.delenv("CLHOLO_DEVICE", raising=False)
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    assert runtime.choose_device() is lone


def test_a_build_log_of_an_unknown_cpu_carries_the_fix():
    err = runtime.ProgramBuildError("fft_cpu.cl", ["pthread-AMD EPYC"], _UNKNOWN_CPU_LOG, [])
    assert "apt-get install pocl-opencl-icd" in str(err)
    plain = runtime.ProgramBuildError("fft_cpu.cl", ["dev"], "error: use of undeclared x", [])
    assert "pocl-opencl-icd" not in str(plain)


def test_a_program_built_without_its_kernels_is_refused_with_the_fix(cl_context):
    """PyPI's PoCL 3.0 on a Zen 4 EPYC returned programs without their kernels: the first
    kernel asked of one names the file and the fix, not pyopencl's bare INVALID_KERNEL_NAME.
    A source whose kernels the preprocessor drops builds the same kind of empty program."""
    source = "#if 0\n__kernel void gone(__global float *a) { a[0] = 1.0f; }\n#endif\n"
    program = runtime.build_program(cl_context, "empty_on_purpose.cl", source=source)
    assert not program.kernel_names
    err = runtime._missing_kernel(program, "empty_on_purpose.cl", "gone", cl_context)
    assert isinstance(err, runtime.ProgramBuildError)
    assert "kernels/empty_on_purpose.cl" in str(err) and "holds no kernels, not even gone" in str(err)
    assert "pocl-opencl-icd" in str(err) and "CLHOLO_DEVICE" in str(err)


def test_a_kernel_name_a_program_lacks_names_the_file_and_what_it_holds(cl_context):
    with pytest.raises(LookupError) as missing:
        runtime.get_kernel(cl_context, "elementwise.cl", "no_such_kernel")
    message = str(missing.value)
    assert "kernels/elementwise.cl" in message and "'no_such_kernel'" in message
    assert "complex_multiply" in message  # what it does hold


def test_the_probe_compiles_on_the_test_device(cl_device):
    assert runtime.device_build_problem(cl_device) is None
