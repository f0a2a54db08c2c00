"""clholo's own bookkeeping files (output manifests and sidecar records, the tuning file) with
something else at their names, found by an audit (2026-11-29, seventh session): a named pipe
there hung every render (and the output checks) forever, /dev/zero read until the machine ran
out of memory. They are now read only when they are regular files of a sane size."""

import json
import os
import threading

import pytest

from clholo._files import SMALL_FILE_LIMIT_BYTES, read_small_file


def _returns_within(call, fifo, seconds=20.0):
    """``call()``'s result, failing (not hanging) when it blocks: a writer opened on ``fifo``
    afterwards releases a read that waits for one."""
    box = {}

    def run():
        try:
            box["value"] = call()
        except BaseException as exc:  # noqa: B902 - handed to the test
            box["error"] = exc

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(seconds)
    if worker.is_alive():
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)  # releases the blocked open
        os.close(fd)
        worker.join(10)
        pytest.fail(f"blocked for {seconds} s on the named pipe {fifo}")
    if "error" in box:
        raise box["error"]
    return box.get("value")


@pytest.mark.parametrize("kind", ["fifo", "zero", "folder", "large"])
def test_read_small_file_refuses_what_is_not_a_small_regular_file(tmp_path, kind):
    path = tmp_path / "x.json"
    if kind == "fifo":
        os.mkfifo(path)
        said = "is a named pipe, not a regular file"
    elif kind == "zero":
        path.symlink_to("/dev/zero")
        said = "is a character device, not a regular file"
    elif kind == "folder":
        path.mkdir()
        said = "is a folder, not a regular file"
    else:
        with open(path, "wb") as f:
            f.truncate(SMALL_FILE_LIMIT_BYTES + 1)  # sparse: no disk used
        said = f"holds {SMALL_FILE_LIMIT_BYTES + 1} bytes, more than"
    with pytest.raises(ValueError, match=rf"x\.json {said}"):
        _returns_within(lambda: read_small_file(path), path)
    ok = tmp_path / "ok.json"
    ok.write_text('{"a": 1}')
    assert json.loads(read_small_file(ok)) == {"a": 1}


def test_a_named_pipe_as_the_tuning_file_warns_and_does_not_hang(tmp_path, monkeypatch):
    from clholo.host import tuning

    fifo = tmp_path / "tuning.json"
    os.mkfifo(fifo)
    with pytest.warns(tuning.TuningWarning, match=r"is a named pipe, not a regular file"):
        assert _returns_within(lambda: tuning._read_file(fifo, fresh=True), fifo) == {}
    from clholo.errors import OutputRefused

    with pytest.raises(OutputRefused, match=r"exists and is not a tuning file clholo wrote "
                                            r"\(.*is a named pipe"):
        _returns_within(lambda: tuning.check_writable(fifo), fifo)


@pytest.mark.parametrize("where", ["manifest", "sidecar"])
def test_a_named_pipe_as_an_output_record_is_refused_not_waited_on(tmp_path, where):
    from clholo.io import output

    if where == "manifest":
        folder = tmp_path / "out"
        folder.mkdir()
        fifo = folder / output.MANIFEST_NAME
        os.mkfifo(fifo)
        assert _returns_within(lambda: output.is_clholo_output(folder), fifo) is False
        why = _returns_within(lambda: output.why_not_clholo_output(folder), fifo)
        assert "cannot be read" in why and "is a named pipe" in why
        with pytest.raises(FileExistsError, match=r"is a named pipe"):
            _returns_within(lambda: output.check_output_folder(folder, overwrite=True,
                                                               option="--out"), fifo)
    else:
        target = tmp_path / "report.json"
        target.write_text("{}")
        fifo = tmp_path / f".report.json.{output.MANIFEST_NAME}"
        os.mkfifo(fifo)
        assert _returns_within(lambda: output.is_clholo_file(target), fifo) is False


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="needs Linux's /proc")
def test_read_small_file_stops_at_the_limit_where_the_size_says_nothing():
    """/proc files say size 0 and hold more: the read itself stops at the limit."""
    status = "/proc/self/status"
    assert os.stat(status).st_size == 0
    with pytest.raises(ValueError, match=r"holds more than the 100 bytes"):
        read_small_file(status, limit=100)
    assert "Name:" in read_small_file(status)


@pytest.mark.parametrize("failure", ["disk full", "interrupted"])
def test_a_report_whose_listing_fails_leaves_nothing_unlisted(tmp_path, monkeypatch, failure):
    """A full disk (or Ctrl-C) between the page's rename and the manifest's update left
    report.html in the folder, unlisted: every later ``--overwrite`` of the folder was then
    refused (exit 2) until the user removed it by hand. The full disk's line named no file."""
    import errno

    import numpy as np

    from clholo.experiments import report as rep
    from clholo.io import output

    run = tmp_path / "run"
    with output.output_folder(run, command="test") as tmp:
        np.savez(tmp / "focal_stack.npz", intensity=np.ones((1, 1, 8, 8), np.float32),
                 depths_m=np.array([2e-3]))
    before = sorted(p.name for p in run.iterdir())
    from clholo.io import images

    real = images.atomic_path

    def failing(path):
        if path.name == output.MANIFEST_NAME:
            if failure == "interrupted":
                raise KeyboardInterrupt
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(path)

    monkeypatch.setattr("clholo.io.images.atomic_path", failing)
    with pytest.raises(KeyboardInterrupt if failure == "interrupted" else OSError) as info:
        rep.build_report(run)
    if failure == "disk full":
        assert info.value.filename == str(run / output.MANIFEST_NAME)
    assert sorted(p.name for p in run.iterdir()) == before
    monkeypatch.undo()
    output.check_output_folder(run, overwrite=True, option="--out")  # not refused
    assert rep.build_report(run) == run / "report.html"
    assert {"report.html"} <= output.listed_entries(run)


def test_encode_does_not_replace_an_output_another_run_wrote_during_its_work(tmp_path, capsys,
                                                                              monkeypatch):
    """``clholo encode --overwrite`` replaced a pattern folder that another run wrote at --out
    while it worked (``render`` refused it); and the refusal spoke of the API's "folder"."""
    import numpy as np

    from clholo import cli
    from clholo.encode import quantize
    from clholo.io import output, write_hologram

    holo = tmp_path / "h.npz"
    rng = np.random.default_rng(0)
    write_hologram(holo, np.exp(2j * np.pi * rng.random((1, 1, 16, 16))).astype(np.complex64),
                   pitch=8e-6, wavelengths=[520e-9])
    out = tmp_path / "o"
    args = ["encode", str(holo), "--method", "dpac", "--progress", "off", "--out", str(out)]
    assert cli.main(args) == 0
    real = quantize.quantize

    def another_run_meanwhile(*a, **k):
        with output.output_folder(out, overwrite=True, command="other") as tmp:
            (tmp / "other.txt").write_text("the other run's")
        return real(*a, **k)

    monkeypatch.setattr(quantize, "quantize", another_run_meanwhile)
    capsys.readouterr()
    assert cli.main(args + ["--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "overwrite=True" not in err
    assert (out / "other.txt").read_text() == "the other run's"
