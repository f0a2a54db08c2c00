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
