"""Per-device tuning (``clholo.tuning``, ``clholo tune``): every tunable setting gives the same
bits with each of its values (on PoCL's run of the GPU kernels), a device's stored tuning
reaches its plans (and only where no override says otherwise), the tuning file is written
whole and read with care, and the tuner takes what is faster and nothing that computes
otherwise."""

import dataclasses
import json
import os
import warnings

import numpy as np
import pytest

import clholo
from clholo import cli, fft as F, tuning
from clholo._version import __version__
from clholo.errors import InputError
from clholo.hologram import HologramRenderer
from clholo.host import tuning as host_tuning


@pytest.fixture
def tuning_path(tmp_path, monkeypatch):
    """A tuning file of this test's own (conftest turns the machine's off)."""
    path = tmp_path / "tuning.json"
    monkeypatch.setenv(tuning.TUNING_FILE_ENV, str(path))
    host_tuning._warned.clear()
    return path


def _not_a_cpu(monkeypatch):
    """Plans see a device that is not a CPU (the row pitch is a CPU's always, a GPU's only
    where tuned), still running on PoCL through the GPU kernels."""
    real = F.DeviceLimits.of
    monkeypatch.setattr(F.DeviceLimits, "of", classmethod(
        lambda cls, dev: dataclasses.replace(real(dev), is_cpu=False)))


def _local_48k(monkeypatch):
    """Plans see 48 KiB of local memory (an H100's; at most the device's own: Oclgrind has 32)
    and kernels that hold none themselves."""
    real = F.DeviceLimits.of
    monkeypatch.setattr(F.DeviceLimits, "of", classmethod(
        lambda cls, dev: dataclasses.replace(
            real(dev), local_mem_size=min(48 * 1024, int(dev.local_mem_size)),
            max_work_group_size=min(1024, int(dev.max_work_group_size)), kernel_local=())))
    monkeypatch.setattr(F.runtime, "kernel_local_bytes", lambda knl, dev: 0)


def _every_line_in_place(monkeypatch):
    """No room for two buffers: rows and columns on the in-place plan (FFT_INPLACE)."""
    monkeypatch.setattr(F, "_GPU_LOCAL_BYTES", 1)
    monkeypatch.setattr(F, "_GPU_COLUMN_LOCAL_BYTES", 1)


def _stored(path, device, settings, *, version=__version__):
    entry = {"clholo": version, "settings": settings}
    path.write_text(json.dumps({"format": host_tuning.FILE_FORMAT, "version": host_tuning.FILE_VERSION,
                                "devices": {tuning.device_key(device): entry}}))


def test_every_setting_has_its_default_among_its_values():
    assert tuning.SETTINGS is host_tuning.SETTINGS  # one table: the plans' and the tuner's
    assert list(tuning.SETTINGS) == ["mid_quads", "layer_planes", "batch_fast", "row_pitch",
                                     "inplace_columns", "split_columns", "inplace_direct",
                                     "launch_samples"]
    for name, s in tuning.SETTINGS.items():
        assert s.name == name and len(s.values) >= 2
        assert s.default in s.values, name
        assert set(s.workloads) <= {"render", "sgd"} and s.workloads, name


def _render(queue, seed, shape=(24, 256), L=3, C=2):
    rng = np.random.default_rng(seed)
    H, W = shape
    mpi = clholo.MPI(rng.random((L, H, W, C)), rng.random((L, H, W)),
                     np.linspace(1e-3, 3e-3, L))
    optics = clholo.Optics(wavelengths=(638e-9, 520e-9, 450e-9)[:C])
    r = HologramRenderer(mpi, optics, seed=seed, queue=queue, variant="gpu", pad=2)
    return r, r.render(2).get()


# what each setting's other value must change where it is given, so that the bits it leaves
# alone are not a test that cannot fail: a define of the programs built, or the renderer
_TOOK_EFFECT = {
    "mid_quads": lambda r, defs: any(d.get("FFT_MID_QUADS") for d in defs),
    "batch_fast": lambda r, defs: any(d.get("FFT_BATCH_FAST") and "VW" not in d for d in defs),
    "inplace_direct": lambda r, defs: any(d.get("FFT_INPLACE_DIRECT") for d in defs),
    "layer_planes": lambda r, defs: r.layer_layout == "planes",
    "row_pitch": lambda r, defs: r.row_pitch > r.padded[1],
    "inplace_columns": lambda r, defs: any(d.get("FFT_INPLACE") and d.get("FFT_LINE_FAST")
                                           and not d.get("FFT_SPLIT") for d in defs),
    "split_columns": lambda r, defs: any(d.get("FFT_SPLIT") and d.get("FFT_LINE_FAST")
                                         for d in defs),
}
# the settings that change column passes only (of hundreds of points and more)
_COLUMN_SETTINGS = ("inplace_columns", "split_columns")


# (launch_samples changes how many frames a launch takes, which a CPU device's renders do not
# see: test_launch_samples_set_the_frames_a_launch_takes_not_their_bits has it)
@pytest.mark.parametrize("name", [n for n in tuning.SETTINGS if n != "launch_samples"])
def test_each_setting_gives_the_same_holograms(queue, rng, monkeypatch, built_defines, name):
    """A render on the GPU kernels (a 512-point row: a 4 KiB row, where the pitch applies;
    lines on the in-place plan, where its direct stages apply) with each value of the setting:
    the same frames, bit for bit, and the value took effect."""
    _not_a_cpu(monkeypatch)
    if name in _COLUMN_SETTINGS:
        # columns of 800 points: two buffers of 32 KiB hold two, one buffer holds more, and
        # one component of them more still
        _local_48k(monkeypatch)
        shape = (400, 16)
    else:
        _every_line_in_place(monkeypatch)
        shape = (24, 256)
    seed = int(rng.integers(2 ** 31))
    default = tuning.SETTINGS[name].default
    frames = {}
    for value in tuning.SETTINGS[name].values:
        built_defines.clear()
        F.clear_plan_cache()
        with tuning.override(**{name: value}):
            r, frames[value] = _render(queue, seed, shape)
        assert _TOOK_EFFECT[name](r, built_defines) == (value != default), (name, value)
    for value, f in frames.items():
        np.testing.assert_array_equal(f, frames[default], err_msg=f"{name}={value}")


# (the column settings change columns of hundreds of points and more, which the SGD steps of
# test_encode's helper do not reach: test_columns_in_place_give_the_two_buffer_bits has them)
@pytest.mark.parametrize("name", [n for n, s in tuning.SETTINGS.items()
                                  if "sgd" in s.workloads and n not in _COLUMN_SETTINGS])
def test_each_setting_keeps_sgd_bits(queue, rng, monkeypatch, name):
    """SGD's round trips on the GPU kernels, three steps from one start, with each value."""
    from test_encode import gpu_round_trip_steps

    s = tuning.SETTINGS[name]
    _every_line_in_place(monkeypatch)
    runs = gpu_round_trip_steps(queue, int(rng.integers(2 ** 32)), monkeypatch,
                                s, "default", s.values)
    for run in runs[1:]:
        for key in ("phase", "adam_m", "grad", "loss"):
            np.testing.assert_array_equal(run[key], runs[0][key], err_msg=f"{name} {key}")


@pytest.mark.parametrize("setting, on, direct", [("inplace_columns", True, False),
                                                 ("inplace_columns", True, True),
                                                 ("split_columns", 512, False),
                                                 ("split_columns", 1024, False)])
def test_columns_in_place_give_the_two_buffer_bits(queue, rng, monkeypatch, setting, on,
                                                    direct):
    """inplace_columns: columns of 1125, 2048 and 1200 points (two buffers of an H100's 48 KiB
    hold one or two) on the in-place plan with the two-buffer plan's stages: the same FFT both
    ways and the same column round trip with a multiply, bit for bit, with and without the
    in-place plan's direct stages. split_columns: the same on the split plan (more columns a
    group: up to 512 or 1024 work-items)."""
    import pyopencl.array as cla

    _local_48k(monkeypatch)
    monkeypatch.setattr(tuning.SETTINGS["inplace_direct"], "default", direct)
    for n in (1125, 2048, 1200):
        x = (rng.standard_normal((n, 12)) + 1j * rng.standard_normal((n, 12))).astype(np.complex64)
        xr = (rng.standard_normal((3, n - 25, 12))
              + 1j * rng.standard_normal((3, n - 25, 12))).astype(np.complex64)
        m = (rng.standard_normal((n, 12)) + 1j * rng.standard_normal((n, 12))).astype(np.complex64)
        runs = []
        for value in (tuning.SETTINGS[setting].default, on):
            with tuning.override(**{setting: value}):
                plan = F.FFTPlan((n, 12), np.complex64, queue=queue, variant="gpu")
                rt = F.RoundTripPlan((3, n - 25, 12), n, axis="cols", first="forward",
                                     mid_n=n - 40, queue=queue, variant="gpu")
            (cols,) = [p for p in plan.geometry.passes if p.axis == "cols"]
            for p in (cols, rt.geometry.pass_):
                d = dict(p.defines)
                assert bool(d.get("FFT_INPLACE")) == bool(value), (n, value)
                assert bool(d.get("FFT_SPLIT")) == bool(value and setting == "split_columns")
                if value:  # more columns a group than two buffers hold (one or two)
                    assert p.launches[0].extra[0] > (1 if n == 2048 else 2), (n, p.launches)
            runs.append([plan.execute_host(x), plan.execute_host(x, inverse=True),
                         rt.execute(cla.to_device(queue, xr),
                                    multiply=cla.to_device(queue, m)).get()])
        for a, b in zip(*runs):
            np.testing.assert_array_equal(b.view(np.float32), a.view(np.float32), err_msg=str(n))


def test_a_stored_tuning_reaches_the_devices_plans(queue, tuning_path, monkeypatch):
    """Stored for this device: DeviceLimits carry it and the plans build with it; override
    comes first; untuned() and CLHOLO_TUNING_FILE=off fall back to the defaults."""
    dev = queue.device
    _every_line_in_place(monkeypatch)
    _stored(tuning_path, dev, {"inplace_direct": True, "mid_quads": True})
    assert dict(tuning.settings_for(dev)) == {"mid_quads": True, "layer_planes": False,
                                              "batch_fast": False, "row_pitch": False,
                                              "inplace_columns": False,
                                              "split_columns": 0, "inplace_direct": True,
                                              "launch_samples": 1 << 19}
    limits = F.DeviceLimits.of(dev)
    assert limits.setting("inplace_direct") is True and limits.setting("batch_fast") is False

    def direct():
        plan = F.FFTPlan((24, 40), np.complex64, queue=queue, variant="gpu")
        return [bool(dict(p.defines).get("FFT_INPLACE_DIRECT")) for p in plan.geometry.passes]

    assert direct() == [True, True]
    with tuning.override(inplace_direct=False):
        assert direct() == [False, False]
        assert F.DeviceLimits.of(dev).setting("mid_quads") is True  # the stored one, still
    with tuning.untuned():
        assert direct() == [False, False]
        assert F.DeviceLimits.of(dev).setting("mid_quads") is False
    monkeypatch.setenv(tuning.TUNING_FILE_ENV, "off")
    assert direct() == [False, False]
    # limits made without a device (an H100's, in the planning tests) take the defaults
    assert F.DeviceLimits(False, 48 * 1024, 1024).setting("inplace_direct") is False


def test_override_refuses_unknown_settings_and_values():
    with pytest.raises(InputError, match="no tunable setting 'quads'.*mid_quads"):
        with tuning.override(quads=True):
            pass
    with pytest.raises(InputError, match="mid_quads is 1; give one of False, True"):
        with tuning.override(mid_quads=1):
            pass


def test_the_tuning_file_by_default_and_from_the_environment(monkeypatch, tmp_path):
    monkeypatch.delenv(tuning.TUNING_FILE_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert tuning.tuning_file() == tmp_path / "clholo" / "tuning.json"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert tuning.tuning_file() == tmp_path / "home" / ".cache" / "clholo" / "tuning.json"
    for off in ("off", "OFF", "", " none "):
        monkeypatch.setenv(tuning.TUNING_FILE_ENV, off)
        assert tuning.tuning_file() is None
    monkeypatch.setenv(tuning.TUNING_FILE_ENV, str(tmp_path / "t.json"))
    assert tuning.tuning_file() == tmp_path / "t.json"


def _result(device, settings, speedup=1.2):
    defaults = {n: s.default for n, s in tuning.SETTINGS.items()}
    return tuning.TuningResult(device=tuning.device_key(device), settings={**defaults, **settings},
                               defaults=defaults, rows=[], speedup=speedup,
                               workload={"shape": [8, 8]})


def test_save_keeps_other_devices_and_leaves_no_temporary(queue, tuning_path):
    other = {"a GPU | driver 1": {"clholo": __version__, "settings": {"mid_quads": True}}}
    tuning_path.write_text(json.dumps({"format": host_tuning.FILE_FORMAT,
                                       "version": host_tuning.FILE_VERSION, "devices": other}))
    written = tuning.save_tuning(_result(queue.device, {"batch_fast": True}))
    assert written == tuning_path
    assert sorted(os.listdir(tuning_path.parent)) == ["tuning.json", "tuning.json.lock"]
    data = json.loads(tuning_path.read_text())
    assert data["devices"]["a GPU | driver 1"] == other["a GPU | driver 1"]
    mine = data["devices"][tuning.device_key(queue.device)]
    assert mine["clholo"] == __version__ and mine["settings"]["batch_fast"] is True
    assert F.DeviceLimits.of(queue.device).setting("batch_fast") is True  # read again: changed
    assert tuning.forget_tuning(queue.device) is True
    assert tuning.forget_tuning(queue.device) is False
    assert list(json.loads(tuning_path.read_text())["devices"]) == ["a GPU | driver 1"]


def test_save_refuses_what_is_not_a_result_and_a_file_turned_off(queue, monkeypatch):
    with pytest.raises(InputError, match="result must be what clholo.tuning.tune returned"):
        tuning.save_tuning({"mid_quads": True})
    monkeypatch.setenv(tuning.TUNING_FILE_ENV, "off")
    with pytest.raises(InputError, match="CLHOLO_TUNING_FILE is off: give a path"):
        tuning.save_tuning(_result(queue.device, {}))


@pytest.mark.parametrize("text,why", [
    ("{not json", "not one clholo wrote"),
    ('{"format": "other", "version": 1, "devices": {}}', "format"),
    ('{"format": "clholo-tuning", "version": 99, "devices": {}}', "version"),
    ('{"format": "clholo-tuning", "version": 1, "devices": []}', "devices"),
])
def test_a_malformed_file_warns_once_and_leaves_the_defaults(queue, tuning_path, text, why):
    tuning_path.write_text(text)
    with pytest.warns(tuning.TuningWarning, match=why):
        assert dict(tuning.settings_for(queue.device))["mid_quads"] is False
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tuning.settings_for(queue.device)  # once per file: no second warning


def test_another_versions_or_a_bad_entry_is_not_used(queue, tuning_path):
    dev = queue.device
    _stored(tuning_path, dev, {"mid_quads": True}, version="0.0.1")
    with pytest.warns(tuning.TuningWarning, match="measured with clholo 0.0.1.*clholo tune"):
        assert dict(tuning.settings_for(dev))["mid_quads"] is False
    _stored(tuning_path, dev, {"mid_quads": "yes"})
    os.utime(tuning_path, ns=(1, 1))  # another stamp: read again
    with pytest.warns(tuning.TuningWarning, match="mid_quads is 'yes'"):
        assert dict(tuning.settings_for(dev))["mid_quads"] is False


def _fake_timing(monkeypatch, faster):
    """The tuner's timing replaced: a setting's value in ``faster`` runs at that ratio of the
    current choice's time, any other at the same time (so the choice is deterministic)."""
    def kernel_seconds(run, queue, repeats):
        return run.cost()

    def prepare(self, settings):
        cost = 1.0
        for name, ratio in faster.items():
            if settings.get(name) == (not tuning.SETTINGS[name].default):
                cost /= ratio

        def run():
            pass
        run.cost = lambda: cost
        return run, np.zeros(3)

    monkeypatch.setattr(tuning, "_kernel_seconds", kernel_seconds)
    monkeypatch.setattr(tuning._RenderWorkload, "prepare", prepare)
    monkeypatch.setattr(tuning._SGDWorkload, "prepare", prepare)


def test_side_by_side_alternates_and_gives_a_over_b(monkeypatch):
    order = []
    times = {"a": iter([2.0, 2.2, 1.8]), "b": iter([1.0, 1.0, 1.0])}
    monkeypatch.setattr(tuning, "_kernel_seconds",
                        lambda run, q, repeats: order.append(run) or next(times[run]))
    ta, tb, ratio = tuning._side_by_side("a", "b", None, 3, 1)
    assert order == ["a", "b", "b", "a", "a", "b"]
    assert (ta, tb, ratio) == (2.0, 1.0, 2.0)


def test_the_tuner_takes_a_faster_value_and_leaves_ties(queue, monkeypatch):
    _fake_timing(monkeypatch, {"batch_fast": 1.10, "row_pitch": 1.01})
    lines = []
    r = tuning.tune(shape=(16, 16), layers=2, frames=1, variant="gpu", queue=queue,
                    progress=lines.append)
    assert r.settings["batch_fast"] is True      # 10 % faster: taken
    assert r.settings["row_pitch"] is False      # 1 %: under the 3 % threshold
    assert r.speedup == pytest.approx(1.10)
    assert [row["setting"] for row in r.rows] == [
        n for n, st in tuning.SETTINGS.items() for v in st.values if v != st.default]
    assert [row["adopted"] for row in r.rows][:7] == [False, False, True, False, False, False,
                                                      False]
    assert len(r.rows) == 10  # split_columns, launch_samples: two other values, neither faster
    assert lines[-1] == "chosen against the defaults: 1.100x"
    assert "chosen: batch_fast=True" in r.report()
    json.dumps(r.entry())  # the file's entry is plain JSON


def test_the_tuner_keeps_the_defaults_when_the_whole_is_not_faster(queue, monkeypatch):
    _fake_timing(monkeypatch, {"mid_quads": 1.05})
    real = tuning._side_by_side

    def final_slower(run_a, run_b, q, rounds, repeats):
        ta, tb, ratio = real(run_a, run_b, q, rounds, repeats)
        calls.append(1)  # one comparison per setting, then the choice against the defaults
        return (ta, tb, ratio) if len(calls) <= len(tuning.SETTINGS) else (1.0, 1.0, 1.0)

    calls = []
    monkeypatch.setattr(tuning, "_side_by_side", final_slower)
    r = tuning.tune(shape=(16, 16), layers=2, frames=1, variant="gpu", queue=queue)
    assert r.rows[0]["adopted"] and r.settings == r.defaults and r.speedup == 1.0


def test_the_tuner_refuses_a_value_that_computes_otherwise(queue, monkeypatch):
    _fake_timing(monkeypatch, {"mid_quads": 1.5})
    fake = tuning._RenderWorkload.prepare

    def prepare(self, settings):
        run, result = fake(self, settings)
        return run, result + (1e-7 if settings["mid_quads"] else 0)

    monkeypatch.setattr(tuning._RenderWorkload, "prepare", prepare)
    with pytest.warns(tuning.TuningWarning, match="mid_quads=True gave other bits"):
        r = tuning.tune(shape=(16, 16), layers=2, frames=1, variant="gpu", queue=queue)
    assert r.settings["mid_quads"] is False and r.rows[0]["same_bits"] is False


def test_the_tuner_on_pocls_gpu_kernels(queue, tuning_path):
    """The whole tuner, measured for real on a small render and SGD: a row per value, each
    with the same bits, and a result that stores and reads back."""
    r = tuning.tune(shape=(16, 24), layers=2, frames=1, sgd=16, rounds=1, repeats=1,
                    variant="gpu", queue=queue)
    # every setting in order, each of its other values at least (a value taken on noise
    # makes the default one more value to try)
    assert list(dict.fromkeys(row["setting"] for row in r.rows)) == list(tuning.SETTINGS)
    assert all(row["value"] in tuning.SETTINGS[row["setting"]].values for row in r.rows)
    assert all(row["same_bits"] for row in r.rows)
    assert set(r.rows[1]["ms"]) == {"render 16x24 C=3 L=2 T=1"}  # layer_planes: renders only
    assert len(r.rows[0]["ms"]) == 2
    tuning.save_tuning(r)
    assert dict(tuning.settings_for(queue.device)) == r.settings


@pytest.mark.parametrize("kw,match", [
    (dict(shape=(4,)), "shape is"),
    (dict(shape=(1, 8)), "shape's H is 1"),
    (dict(colours=2), "colours is 2"),
    (dict(layers=0), "layers is 0"),
    (dict(rounds=1.5), "rounds is 1.5"),
    (dict(threshold=1.0), r"threshold is 1.0; give a fraction in \[0, 1\)"),
    (dict(threshold=float("nan")), "threshold"),
    (dict(variant="cpu"), "variant is 'cpu'"),
    (dict(sgd=1), "sgd is 1"),
])
def test_the_tuner_names_a_bad_argument(queue, kw, match):
    with pytest.raises(InputError, match=match):
        tuning.tune(**{"variant": "gpu", "queue": queue, **kw})


def test_the_tuner_needs_profiling_and_a_gpu_or_the_gpu_kernels(queue):
    import pyopencl as cl

    plain = cl.CommandQueue(queue.context, queue.device)
    with pytest.raises(InputError, match="queue has no profiling"):
        tuning.tune(queue=plain, variant="gpu")
    if queue.device.type & cl.device_type.CPU:
        with pytest.raises(InputError, match="CPU kernels.*--variant gpu"):
            tuning.tune(queue=queue)


def test_clholo_tune_stores_shows_and_forgets(tuning_path, capsys):
    small = ["--shape", "16x24", "--layers", "2", "--frames", "1", "--rounds", "1",
             "--variant", "gpu", "--sgd", "16"]
    assert cli.main(["tune", *small, "--dry-run"]) == 0
    assert "--dry-run: nothing stored" in capsys.readouterr().out and not tuning_path.exists()
    assert cli.main(["tune", *small]) == 0
    out = capsys.readouterr().out
    assert "| mid_quads | True |" in out and f"stored for this device in {tuning_path}" in out
    assert cli.main(["tune", "--show"]) == 0
    out = capsys.readouterr().out
    assert "used; against the defaults" in out and "mid_quads: default False" in out
    assert cli.main(["tune", "--forget"]) == 0
    assert "removed the tuning" in capsys.readouterr().out
    assert cli.main(["tune", "--show"]) == 0
    assert "nothing for this device" in capsys.readouterr().out


@pytest.mark.parametrize("argv,match", [
    (["--show", "--layers", "4"], "--layers only apply to a measurement"),
    (["--file", " "], "argument --file: the value is empty"),
    (["--shape", "3x4"], "H and W must each be from 8 to 8192"),
    (["--shape", "1080"], "expected HxW"),
    (["--threshold", "1.5", "--variant", "gpu"], "threshold is 1.5"),
    (["--show", "--forget"], "not allowed with argument"),
    (["--sgd", "4", "--variant", "gpu", "--dry-run"], "--sgd is 4: give N >= 8"),
])
def test_clholo_tune_refuses_bad_options(tuning_path, capsys, argv, match):
    try:
        code = cli.main(["tune", *argv])
    except SystemExit as exc:  # argparse's usage errors
        code = exc.code
    assert code == 2
    assert match in capsys.readouterr().err


def test_clholo_tune_with_the_file_off_needs_a_file_or_a_dry_run(monkeypatch, capsys, tmp_path):
    monkeypatch.setenv(tuning.TUNING_FILE_ENV, "off")
    assert cli.main(["tune", "--variant", "gpu"]) == 2
    assert "give --file PATH" in capsys.readouterr().err
    assert cli.main(["tune", "--file", str(tmp_path), "--variant", "gpu"]) == 2
    assert "is a folder" in capsys.readouterr().err


def test_fft_variants_set_the_settings_themselves(queue, tuning_path):
    """benchmarks/fft_variants.py compares forms: a stored tuning must not change what a
    variant builds, and each tunable it names is a real setting."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "fft_variants", Path(__file__).resolve().parents[1] / "benchmarks" / "fft_variants.py")
    fv = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fv)
    named = {k.split(".", 1)[1] for v in fv.VARIANTS.values() for k in v if k.startswith("tuning.")}
    assert named == set(tuning.SETTINGS)
    _stored(tuning_path, queue.device, {"mid_quads": True, "layer_planes": True})
    assert F.DeviceLimits.of(queue.device).setting("mid_quads") is True
    with fv.variant("fixed"):
        assert dict(F.DeviceLimits.of(queue.device).tuning) == {
            n: s.default for n, s in tuning.SETTINGS.items()}
    with fv.variant("planes-quads"):
        held = dict(F.DeviceLimits.of(queue.device).tuning)
        assert held["mid_quads"] and held["layer_planes"] and not held["batch_fast"]
    assert F.DeviceLimits.of(queue.device).setting("layer_planes") is True  # restored


def test_the_tuner_survives_a_value_the_device_cannot_run(queue, monkeypatch):
    """A form the driver cannot build or run (a limit no plan foresaw) is a row of its own,
    not taken; the other settings are still measured."""
    _fake_timing(monkeypatch, {"row_pitch": 1.2})
    fake = tuning._RenderWorkload.prepare

    def prepare(self, settings):
        if settings["batch_fast"]:
            raise RuntimeError("no such work-group on this device")
        return fake(self, settings)

    monkeypatch.setattr(tuning._RenderWorkload, "prepare", prepare)
    with pytest.warns(tuning.TuningWarning, match="batch_fast=True failed on .*no such work"):
        r = tuning.tune(shape=(16, 16), layers=2, frames=1, variant="gpu", queue=queue)
    row = next(row for row in r.rows if row["setting"] == "batch_fast")
    assert row["error"].startswith("RuntimeError") and not row["adopted"]
    assert r.settings["row_pitch"] is True and r.settings["batch_fast"] is False
    assert "| batch_fast | True | failed | | | no: RuntimeError" in r.report()


def _store_many(path, name, n):
    for i in range(n):
        host_tuning.store_entry(f"{name}", {"clholo": __version__, "settings": {}, "i": i},
                                path=path)


def test_two_processes_storing_at_once_keep_both_entries(tmp_path):
    """Two GPUs tuned at once on one machine: each process reads, changes and writes the file
    under its lock, so neither loses the other's entry."""
    import multiprocessing

    path = tmp_path / "tuning.json"
    ctx = multiprocessing.get_context("fork")
    procs = [ctx.Process(target=_store_many, args=(path, f"device {k}", 30)) for k in range(4)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    devices = json.loads(path.read_text())["devices"]
    assert sorted(devices) == [f"device {k}" for k in range(4)]
    assert all(d["i"] == 29 for d in devices.values())
    assert sorted(os.listdir(tmp_path)) == ["tuning.json", "tuning.json.lock"]


def test_columns_two_buffers_cannot_hold_keep_their_plan(queue, monkeypatch):
    """Where not even one column fits two buffers, the default plan is the in-place one with
    its own stages: inplace_columns leaves it alone (its stages would round otherwise)."""
    _every_line_in_place(monkeypatch)
    geometry = []
    for value in (False, True):
        with tuning.override(inplace_columns=value):
            plan = F.FFTPlan((1125, 12), np.complex64, queue=queue, variant="gpu")
        geometry.append([p.defines for p in plan.geometry.passes])
    assert geometry[0] == geometry[1]
    assert any(dict(d).get("FFT_INPLACE") for d in geometry[0])



def test_launch_samples_set_the_frames_a_launch_takes_not_their_bits(queue, rng):
    """launch_samples: an H100's batch target follows it (frames per launch, within the
    budget), and frames rendered one a launch or all in one are the same bits."""
    import types

    import pyopencl as cl

    from clholo.host import memory

    from clholo.host.memory import frames_per_launch

    h100 = types.SimpleNamespace(type=cl.device_type.GPU, max_compute_units=132,
                                 global_mem_size=80 << 30, name="fake H100")
    plan = dict(fixed_bytes=4 * 32 * 1080 * 1920 * 4 + 8 * 3 * 1125 * 1944,
                per_frame_bytes=8 * 3 * 1080 * 1920 * 2 + 8 * 3 * 1125 * 1944 * 2,
                samples_per_frame=3 * 1125 * 1944, budget_bytes=None, what="1080p RGB")
    frames = {}
    for value in tuning.SETTINGS["launch_samples"].values:
        with tuning.override(launch_samples=value):
            assert memory.device_batch_target(h100) == 132 * value
            frames[value] = frames_per_launch(device=h100, **plan)
    assert frames == {1 << 18: 5, 1 << 19: 10, 1 << 20: 21}
    assert memory.device_batch_target(h100) == 132 * memory.GPU_SAMPLES_PER_COMPUTE_UNIT
    assert tuning.SETTINGS["launch_samples"].default == memory.GPU_SAMPLES_PER_COMPUTE_UNIT
    L, H, W, C = 3, 20, 36, 3
    mpi = clholo.MPI(rng.random((L, H, W, C)), rng.random((L, H, W)), np.linspace(1e-3, 3e-3, L))
    seed = int(rng.integers(2 ** 31))
    out = [HologramRenderer(mpi, clholo.Optics(), seed=seed, queue=queue, variant="gpu",
                            frames_per_batch=n).render(6).get() for n in (1, 6)]
    np.testing.assert_array_equal(out[1], out[0])


def test_a_stored_launch_samples_sets_that_gpus_batch_target(tuning_path):
    """The batch target reads the device's stored tuning (not only an override)."""
    import types

    import pyopencl as cl

    from clholo.host import memory

    platform = types.SimpleNamespace(name="NVIDIA CUDA")
    h100 = types.SimpleNamespace(type=cl.device_type.GPU, max_compute_units=132,
                                 global_mem_size=80 << 30, name="NVIDIA H100", vendor="NVIDIA",
                                 driver_version="570", platform=platform)
    assert memory.device_batch_target(h100) == 132 << 19
    _stored(tuning_path, h100, {"launch_samples": 1 << 20})
    assert memory.device_batch_target(h100) == 132 << 20
    with tuning.untuned():
        assert memory.device_batch_target(h100) == 132 << 19


def test_a_file_the_user_owns_is_never_replaced(queue, tmp_path, capsys):
    """--file naming a file clholo did not write: refused before any measuring, the file
    untouched; save_tuning refuses it too."""
    mine = tmp_path / "notes.txt"
    mine.write_text("my notes")
    argv = ["tune", "--variant", "gpu", "--shape", "16x24", "--layers", "2", "--frames", "1",
            "--sgd", "0", "--rounds", "1", "--file", str(mine)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "is not a tuning file clholo wrote" in err and "will not replace it" in err
    assert mine.read_text() == "my notes"
    with pytest.raises(FileExistsError, match="will not replace it"):
        tuning.save_tuning(_result(queue.device, {}), path=mine)
    assert mine.read_text() == "my notes"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "notes.txt.lock"]
