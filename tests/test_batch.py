"""``clholo batch``: datasets on Dask equal ``clholo render`` bit for bit, resume after kills.

Timings are not asserted. The machine's one OpenCL device (PoCL) serves every worker: the
local clusters here have 2 worker processes both pinned to device 0:0.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

import clholo  # noqa: E402
from clholo import batch, cli  # noqa: E402

ENV = dict(os.environ, PYTHONUNBUFFERED="1")


# ------------------------------------------------------------------------------------------
# helpers
def write_random_mpi(path: Path, rng, *, layers=3, height=20, width=28):
    mpi = clholo.MPI(rng.random((layers, height, width, 3)), rng.random((layers, height, width)),
                     np.sort(rng.uniform(1.0, 5.0, layers)))
    clholo.io.write_mpi(path, mpi)
    return path


def write_csv(path: Path, header, rows):
    lines = [",".join(header)] + [",".join("" if v is None else str(v) for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def bits(a):
    a = np.ascontiguousarray(a)
    return a.view(np.uint8)


def assert_same_outputs(batch_dir: Path, render_dir: Path):
    """Every file ``clholo render`` wrote, and no other (but the batch record), with the same
    content bit for bit (array contents: .npz zips carry write times)."""
    from clholo.io import read_hologram, read_image

    render_names = sorted(p.name for p in render_dir.iterdir())
    assert sorted(p.name for p in batch_dir.iterdir()) == sorted(render_names + [batch.RECORD])
    h_batch, m_batch = read_hologram(batch_dir / "hologram.npz")
    h_render, m_render = read_hologram(render_dir / "hologram.npz")
    assert h_batch.shape == h_render.shape
    assert np.array_equal(bits(h_batch), bits(h_render))
    assert m_batch == m_render
    with np.load(batch_dir / "focal_stack.npz") as fb, np.load(render_dir / "focal_stack.npz") as fr:
        assert sorted(fb.files) == sorted(fr.files)
        for key in fr.files:
            assert np.array_equal(bits(fb[key]), bits(fr[key])), key
    assert np.array_equal(read_image(batch_dir / "focal_stack.png", normalise=False)[0],
                          read_image(render_dir / "focal_stack.png", normalise=False)[0])
    assert (json.loads((batch_dir / "summary.json").read_text())
            == json.loads((render_dir / "summary.json").read_text()))


def events(out: Path, kind: str):
    path = out / batch.LOG
    if not path.is_file():
        return []
    return [e for e in map(json.loads, path.read_text().splitlines()) if e["event"] == kind]


def render_counts(out: Path):
    counts = {}
    for e in events(out, "rendered"):
        counts[e["item"]] = counts.get(e["item"], 0) + 1
    return counts


def assert_only_whole_items(out: Path, items):
    for item in items:
        if (out / item.id).exists():
            assert batch.item_status(out, item) == (True, "complete"), item.id
    # nothing half-written beside the items (.staging is emptied by the next run)
    for p in out.iterdir():
        assert p.name in {i.id for i in items} | {batch.LOG, "results.csv", "results.jsonl",
                                                  batch.STAGING, batch.PARTS, batch.LOCK}, p


def batch_process(manifest: Path, out: Path, *extra):
    return subprocess.Popen([sys.executable, "-m", "clholo.cli", "batch", str(manifest),
                             "--out", str(out), "--workers", "2", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=ENV, text=True)


def wait_for(predicate, proc, timeout=120.0):
    t = time.monotonic()
    while not predicate():
        if proc.poll() is not None:
            raise AssertionError(f"the batch ended before the test could interrupt it:\n"
                                 f"{proc.stdout.read()}")
        if time.monotonic() - t > timeout:
            proc.kill()
            raise AssertionError("timed out waiting for the batch")
        time.sleep(0.02)


# ------------------------------------------------------------------------------------------
# an existing cluster: a scheduler and its workers in separate processes on 127.0.0.1
@pytest.fixture(scope="module")
def cluster_address(tmp_path_factory):
    folder = tmp_path_factory.mktemp("dask")
    scheduler_file = folder / "scheduler.json"
    procs = [subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
         "--port", "0", "--no-dashboard", "--scheduler-file", str(scheduler_file)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV)]
    try:
        t = time.monotonic()
        while not scheduler_file.is_file():
            assert time.monotonic() - t < 60, "the Dask scheduler did not start"
            time.sleep(0.05)
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_worker", "--scheduler-file",
             str(scheduler_file), "--nworkers", "2", "--nthreads", "1", "--host", "127.0.0.1",
             "--no-dashboard", "--local-directory", str(folder)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            env=dict(ENV, CLHOLO_DEVICE="0:0")))
        address = json.loads(scheduler_file.read_text())["address"]
        from distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=90)
        yield address
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def client_worker_names(address):
    from distributed import Client

    with Client(address, timeout=30) as client:
        return [str(w["name"]) for w in client.scheduler_info()["workers"].values()]


# ------------------------------------------------------------------------------------------
# manifest
def test_cli_does_not_import_dask():
    code = ("import sys; from clholo import cli; cli.build_parser(); "
            "assert 'distributed' not in sys.modules and 'dask' not in sys.modules, "
            "sorted(m for m in sys.modules if 'dask' in m or 'distributed' in m)")
    subprocess.run([sys.executable, "-c", code], check=True, env=ENV)


def test_manifest_csv_and_jsonl_read_the_same(tmp_path, rng):
    write_random_mpi(tmp_path / "a", rng)
    write_csv(tmp_path / "m.csv", ["id", "input", "near", "far", "frames", "seed", "wavelengths",
                                   "split_frames"],
              [["one", "a", 0.002, 0.004, 6, 7, "6.38e-07 5.2e-07 4.5e-07", 4],
               [None, "skimage:motorcycle", None, None, 2, None, None, None]])
    (tmp_path / "m.jsonl").write_text(
        json.dumps({"id": "one", "input": "a", "near": 0.002, "far": 0.004, "frames": 6,
                    "seed": 7, "wavelengths": [638e-9, 520e-9, 450e-9], "split_frames": 4})
        + "\n# a comment\n" + json.dumps({"input": "skimage:motorcycle", "frames": 2}) + "\n")
    from_csv = batch.read_manifest(tmp_path / "m.csv")
    from_json = batch.read_manifest(tmp_path / "m.jsonl")
    assert [i.options for i in from_csv] == [i.options for i in from_json]
    assert [i.options_sha256 for i in from_csv] == [i.options_sha256 for i in from_json]
    one, moto = from_csv
    assert one.id == "one" and one.command == "render"
    assert one.options["inputs"] == [str((tmp_path / "a").resolve())]
    assert one.options["seed"] == 7 and one.options["frames"] == 6
    assert one.frame_ranges() == [(0, 4), (4, 2)]
    # blanks take clholo's own defaults (demo's for the motorcycle)
    defaults = cli.build_parser().parse_args(["demo"])
    assert moto.command == "demo" and moto.id == "0001-motorcycle"
    assert moto.options["layers"] == defaults.layers and moto.options["seed"] == defaults.seed
    assert moto.frame_ranges() == [(0, 2)]


@pytest.mark.parametrize("header, row, message", [
    (["input", "colour"], ["a", "red"], "unknown column 'colour': clholo render has no option"),
    (["input", "overwrite"], ["a", "true"], "column 'overwrite' cannot be set per item"),
    (["input", "frames"], ["a", "many"], "row 2: argument --frames: expected a whole number"),
    (["input", "mode"], ["a", "fuzzy"], "row 2: argument --mode: invalid choice"),
    (["input", "split_frames"], ["a", "0"], "split_frames must be a positive integer"),
    (["input", "id"], ["a", "../up"], "id '../up' must be letters"),
    (["input", "spacing"], ["skimage:motorcycle", "depth"], "clholo demo has no option --spacing"),
    (["near"], ["0.002"], "'input' column"),
])
def test_manifest_errors_name_row_and_column(tmp_path, header, row, message):
    write_csv(tmp_path / "m.csv", header, [row])
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        batch.read_manifest(tmp_path / "m.csv")


def test_manifest_repeated_id_and_missing_file(tmp_path, capsys):
    write_csv(tmp_path / "m.csv", ["id", "input"], [["x", "a"], ["x", "b"]])
    with pytest.raises(ValueError, match="id 'x' is used by m.csv row 2 and m.csv row 3"):
        batch.read_manifest(tmp_path / "m.csv")
    assert cli.main(["batch", str(tmp_path / "nope.csv"), "--out", str(tmp_path / "o")]) == 2
    assert "nope.csv does not exist" in capsys.readouterr().err
    (tmp_path / "m.txt").write_text("input\na\n")
    with pytest.raises(ValueError, match=r"\.csv or \.jsonl"):
        batch.read_manifest(tmp_path / "m.txt")


# ------------------------------------------------------------------------------------------
# outputs equal clholo render's
def test_existing_cluster_outputs_equal_clholo_render(tmp_path, rng, cluster_address):
    write_random_mpi(tmp_path / "a", rng)
    write_random_mpi(tmp_path / "b", rng, layers=4, height=16, width=24)
    manifest = write_csv(
        tmp_path / "m.csv", ["id", "input", "near", "far", "frames", "seed", "layers", "scale",
                             "split_frames", "pad"],
        [["a", "a", 0.002, 0.004, 3, 11, None, None, None, None],
         ["b-split", "b", 0.003, 0.005, 5, 2 ** 40 + 3, None, None, 2, 2],
         ["moto", "skimage:motorcycle", None, None, 2, 5, 3, 0.04, None, None]])
    out = tmp_path / "out"
    rows = batch.render_dataset(manifest, out, scheduler=cluster_address)
    assert [r["status"] for r in rows] == ["rendered"] * 3
    assert [r["parts"] for r in rows] == [0, 3, 0]
    # the same items as clholo render / clholo demo commands, written by hand
    commands = {
        "a": ["render", str(tmp_path / "a"), "--near", "0.002", "--far", "0.004",
              "--frames", "3", "--seed", "11"],
        "b-split": ["render", str(tmp_path / "b"), "--near", "0.003", "--far", "0.005",
                    "--frames", "5", "--seed", str(2 ** 40 + 3), "--pad", "2"],
        "moto": ["demo", "--layers", "3", "--scale", "0.04", "--frames", "2", "--seed", "5"],
    }
    for item_id, argv in commands.items():
        assert cli.main(argv + ["--out", str(tmp_path / f"cli-{item_id}")]) == 0
        assert_same_outputs(out / item_id, tmp_path / f"cli-{item_id}")
    # the split item was written from its parts, not rendered again whole
    record = json.loads((out / "b-split" / batch.RECORD).read_text())
    assert "5 hologram frame(s) x 3 colour(s) rendered before" in record["log"]
    assert "rendering 5 frame(s)" not in record["log"]
    # the split item's parts are gone once it is written; results name every item
    assert not any((out / batch.PARTS).glob("*/*"))
    results = (out / "results.csv").read_text().splitlines()
    assert [line.split(",")[:2] for line in results[1:]] == [
        ["a", "rendered"], ["b-split", "rendered"], ["moto", "rendered"]]
    assert [json.loads(line)["item"] for line in (out / "results.jsonl").read_text().splitlines()
            ] == ["a", "b-split", "moto"]


def test_real_scenes_equal_clholo_render(tmp_path, shared_data, cluster_address, monkeypatch):
    """The twain MPI cropped (whole and split by frames) and 3DGS splats; the scheduler given
    by DASK_SCHEDULER_ADDRESS."""
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", cluster_address)
    twain = clholo.io.read_mpi(shared_data / "twain-mpi")
    crops = {"twain-a": (300, 400), "twain-b": (520, 610)}
    for name, (y, x) in crops.items():
        clholo.io.write_mpi(tmp_path / name, clholo.MPI(
            twain.color[:, y:y + 20, x:x + 24], twain.alpha[:, y:y + 20, x:x + 24], twain.depths))
    splats = shared_data / "gaussians" / "train-1000.ply"
    manifest = tmp_path / "m.jsonl"
    manifest.write_text("".join(json.dumps(r) + "\n" for r in [
        {"id": "twain-a", "input": "twain-a", "near": 0.002, "far": 0.005, "frames": 2,
         "seed": 1},
        {"id": "twain-b", "input": "twain-b", "near": 0.002, "far": 0.005, "frames": 3,
         "seed": 2, "split_frames": 1},
        {"id": "splats", "input": str(splats), "layers": 2, "near": 0.002, "far": 0.004,
         "frames": 1, "seed": 3},
    ]))
    out = tmp_path / "out"
    rows = batch.render_dataset(manifest, out)
    assert [r["status"] for r in rows] == ["rendered"] * 3
    assert {r["worker"] for r in rows} <= set(client_worker_names(cluster_address))
    for name in crops:
        argv = ["render", str(tmp_path / name), "--near", "0.002", "--far", "0.005",
                "--frames", "2" if name == "twain-a" else "3",
                "--seed", "1" if name == "twain-a" else "2"]
        assert cli.main(argv + ["--out", str(tmp_path / f"cli-{name}")]) == 0
        assert_same_outputs(out / name, tmp_path / f"cli-{name}")
    assert cli.main(["render", str(splats), "--layers", "2", "--near", "0.002", "--far", "0.004",
                     "--frames", "1", "--seed", "3", "--out", str(tmp_path / "cli-splats")]) == 0
    assert_same_outputs(out / "splats", tmp_path / "cli-splats")


# ------------------------------------------------------------------------------------------
# recovery
def test_failed_item_is_recorded_and_rerun_verifies(tmp_path, rng, cluster_address, capsys):
    write_random_mpi(tmp_path / "a", rng)
    write_random_mpi(tmp_path / "b", rng)
    manifest = write_csv(tmp_path / "m.csv", ["id", "input", "near", "far", "frames", "seed"],
                         [["a", "a", 0.002, 0.004, 2, 1], ["b", "b", 0.002, 0.004, 2, 2],
                          ["gone", "missing", 0.002, 0.004, 2, 3]])
    out = tmp_path / "out"
    argv = ["batch", str(manifest), "--out", str(out), "--scheduler", cluster_address]
    assert cli.main(argv) == 1  # an item failed: the others are done all the same
    rows = {r["item"]: r for r in map(json.loads, (out / "results.jsonl").read_text().splitlines())}
    assert rows["a"]["status"] == rows["b"]["status"] == "rendered"
    assert rows["gone"]["status"] == "failed" and "missing does not exist" in rows["gone"]["error"]
    assert not (out / "gone").exists()
    assert "2 rendered, 0 skipped (complete), 1 failed" in capsys.readouterr().err
    # fix the input, damage one item's file, change another item's seed: only those three
    # are rendered again (recorded options + content hash, not presence)
    write_random_mpi(tmp_path / "missing", rng)
    with open(out / "a" / "summary.json", "a") as f:
        f.write(" ")
    manifest.write_text(manifest.read_text().replace("b,b,0.002,0.004,2,2", "b,b,0.002,0.004,2,9"))
    items = batch.read_manifest(manifest)
    assert batch.item_status(out, items[0]) == (False, "summary.json changed since it was written")
    assert batch.item_status(out, items[1]) == (False, "rendered with other options")
    assert cli.main(argv + ["--progress", "on"]) == 0
    err = capsys.readouterr().err
    assert "3 rendered, 0 skipped" in err
    assert "clholo batch: 100%" in err and "3/3" in err  # the progress bar over items
    assert all(batch.item_status(out, i)[0] for i in items)
    assert json.loads((out / "b" / "summary.json").read_text())["seed"] == 9
    assert cli.main(argv) == 0
    assert "0 rendered, 3 skipped (complete), 0 failed" in capsys.readouterr().err
    assert render_counts(out) == {"a": 2, "b": 2, "gone": 1}


def test_folders_clholo_did_not_write_are_left_alone(tmp_path, rng, capsys):
    write_random_mpi(tmp_path / "a", rng)
    manifest = write_csv(tmp_path / "m.csv", ["id", "input", "near", "far"],
                         [["notes", "a", 0.002, 0.004]])
    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("keep")
    with pytest.raises(FileExistsError, match="other files in it"):
        batch.render_dataset(manifest, out)
    assert cli.main(["batch", str(manifest), "--out", str(tmp_path / "m.csv")]) == 2
    assert "is a file" in capsys.readouterr().err
    # a batch folder with a user's folder where an item would go: that item fails, untouched
    (out / "mine.txt").unlink()
    (out / batch.LOG).write_text("")
    (out / "notes").mkdir()
    (out / "notes" / "todo.txt").write_text("keep")
    rows = batch.render_dataset(manifest, out)
    assert rows[0]["status"] == "failed" and "clholo did not write it" in rows[0]["error"]
    assert (out / "notes" / "todo.txt").read_text() == "keep"
    assert sorted(p.name for p in (out / "notes").iterdir()) == ["todo.txt"]


def _kill_manifest(tmp_path, rng, n=8):
    rows = []
    for k in range(n):
        write_random_mpi(tmp_path / f"s{k}", rng, layers=4, height=40, width=48)
        rows.append([f"item{k}", f"s{k}", 0.002, 0.004, 4, k, 2 if k % 3 == 0 else None])
    return write_csv(tmp_path / "m.csv", ["id", "input", "near", "far", "frames", "seed",
                                          "split_frames"], rows)


def test_sigterm_then_rerun_completes_without_rendering_twice(tmp_path, rng):
    manifest = _kill_manifest(tmp_path, rng)
    items = batch.read_manifest(manifest)
    out = tmp_path / "out"
    proc = batch_process(manifest, out)
    wait_for(lambda: len(events(out, "rendered")) >= 2, proc)
    proc.send_signal(signal.SIGTERM)
    log, _ = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, log
    assert "interrupted" in log
    first = render_counts(out)
    assert 2 <= len(first) < len(items), "the batch must be cut part-way"
    assert_only_whole_items(out, items)
    assert not (out / "results.csv").exists()
    # what a writer killed between its files and its rename leaves (SIGTERM rarely hits it)
    left = next(i.id for i in items if i.id not in first)
    (out / batch.STAGING / f"{left}.0123abcd").mkdir(parents=True, exist_ok=True)
    (out / batch.STAGING / f"{left}.0123abcd" / "hologram.npz").write_bytes(b"half")
    # the rerun (the default local cluster, 2 workers on the one device) finishes the rest
    proc = batch_process(manifest, out)
    log, _ = proc.communicate(timeout=240)
    assert proc.returncode == 0, log
    assert f"{len(items) - len(first)} rendered, {len(first)} skipped" in log
    assert render_counts(out) == {i.id: 1 for i in items}
    assert all(batch.item_status(out, i)[0] for i in items)
    assert_only_whole_items(out, items)
    assert not any((out / batch.STAGING).iterdir())
    # and a split item equals clholo render of the whole item
    assert cli.main(["render", str(tmp_path / "s3"), "--near", "0.002", "--far", "0.004",
                     "--frames", "4", "--seed", "3", "--out", str(tmp_path / "cli")]) == 0
    assert_same_outputs(out / "item3", tmp_path / "cli")


def test_killed_worker_then_rerun_completes_without_rendering_twice(tmp_path, rng,
                                                                  cluster_address):
    manifest = _kill_manifest(tmp_path, rng)
    items = batch.read_manifest(manifest)
    out = tmp_path / "out"
    proc = batch_process(manifest, out)

    def in_flight():
        done = {e["item"] for e in events(out, "rendered")}
        return [e for e in events(out, "started") if e["item"] not in done]

    wait_for(lambda: len(events(out, "rendered")) >= 1 and in_flight(), proc)
    victim = in_flight()[0]
    os.kill(victim["pid"], signal.SIGKILL)
    log, _ = proc.communicate(timeout=240)
    # Dask restarts the worker and runs its task again elsewhere; an item whose retries ran
    # out would be recorded as failed (exit 1) and rendered by the rerun
    assert proc.returncode in (0, 1), log
    assert_only_whole_items(out, items)
    # the rerun, here on the existing cluster, renders what is missing and nothing else
    rows = batch.render_dataset(manifest, out, scheduler=cluster_address)
    assert all(r["status"] in ("rendered", "skipped") for r in rows)
    assert render_counts(out) == {i.id: 1 for i in items}
    assert all(batch.item_status(out, i)[0] for i in items)
    assert_only_whole_items(out, items)
