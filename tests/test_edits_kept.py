"""A user's edits are never lost (issue 26, section 4).

``clholo-output.json`` records the SHA-256 of every file clholo wrote; ``--overwrite`` refuses a
folder in which any of them changed since (exit 2, one line naming the file) and leaves every
file as it was. A file the user deleted loses nothing: the folder may be replaced. (Batch
re-renders: ``tests/test_batch.py::test_rerun_never_replaces_a_file_the_user_edited``.)
"""

import json

import numpy as np
import pytest

import clholo
from clholo import cli
from clholo.errors import OutputRefused
from clholo.io.output import MANIFEST_NAME, changed_entries, check_output_folder


def tree(folder):
    return {p.relative_to(folder).as_posix(): (None if p.is_dir() else p.read_bytes())
            for p in sorted(folder.rglob("*"))}


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("edits")
    rng = np.random.default_rng(264)
    clholo.io.write_mpi(folder / "scene", clholo.MPI(rng.random((2, 12, 16, 3)),
                                                     rng.random((2, 12, 16)), [2e-3, 4e-3]))
    return folder / "scene"


def _render(scene, out, *extra):
    return cli.main(["render", str(scene), "--frames", "1", "--out", str(out), "--progress",
                     "off", *extra])


def test_manifest_records_a_checksum_of_every_file(tmp_path, scene):
    import hashlib

    assert _render(scene, tmp_path / "r") == 0
    manifest = json.loads((tmp_path / "r" / MANIFEST_NAME).read_text())
    assert sorted(manifest["sha256"]) == sorted(manifest["files"])
    for name, digest in manifest["sha256"].items():
        assert hashlib.sha256((tmp_path / "r" / name).read_bytes()).hexdigest() == digest


@pytest.mark.parametrize("name", ["summary.json", "hologram.npz", "focal_stack.png"])
def test_render_overwrite_refuses_an_edited_file(tmp_path, scene, capsys, name):
    out = tmp_path / "r"
    assert _render(scene, out, "--seed", "1") == 0
    with open(out / name, "ab") as f:
        f.write(b"\n my note")
    before = tree(tmp_path)
    capsys.readouterr()
    assert _render(scene, out, "--seed", "2", "--overwrite") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"clholo render: error: --out {out} holds {name}, which changed since clholo "
                   f"wrote it: --overwrite would replace it, so clholo will not; move it out "
                   f"first, or choose another --out"]
    assert tree(tmp_path) == before


def test_overwrite_after_a_deletion_or_with_no_change_goes_ahead(tmp_path, scene, capsys):
    out = tmp_path / "r"
    assert _render(scene, out, "--seed", "1") == 0
    assert _render(scene, out, "--seed", "2", "--overwrite") == 0
    (out / "focal_stack.png").unlink()  # nothing of the user's is lost by replacing it
    assert _render(scene, out, "--seed", "3", "--overwrite") == 0
    assert json.loads((out / "summary.json").read_text())["seed"] == 3
    assert changed_entries(out) == []


def test_an_edited_report_in_the_folder_is_kept(tmp_path, scene, capsys):
    """``clholo report`` adds report.html to the folder's manifest with its checksum: edited
    afterwards, it stops a later --overwrite of the folder like any other file."""
    out = tmp_path / "r"
    assert _render(scene, out) == 0
    assert cli.main(["report", str(out), "--progress", "off"]) == 0
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    assert "report.html" in manifest["sha256"]
    assert _render(scene, out, "--overwrite") == 0  # unchanged: replaced
    assert cli.main(["report", str(out), "--progress", "off"]) == 0
    (out / "report.html").write_text("<p>my annotations</p>")
    capsys.readouterr()
    assert _render(scene, out, "--overwrite") == 2
    assert "holds report.html, which changed since clholo wrote it" in capsys.readouterr().err
    assert (out / "report.html").read_text() == "<p>my annotations</p>"


def test_encode_overwrite_refuses_an_edited_pattern(tmp_path, scene, capsys):
    assert _render(scene, tmp_path / "r") == 0
    argv = ["encode", str(tmp_path / "r" / "hologram.npz"), "--method", "dpac", "--slm-size",
            "12", "16", "--out", str(tmp_path / "e"), "--progress", "off"]
    assert cli.main(argv) == 0
    png = sorted((tmp_path / "e").glob("*.png"))[0]
    png.write_bytes(png.read_bytes() + b"retouched")
    before = tree(tmp_path)
    capsys.readouterr()
    assert cli.main(argv + ["--overwrite"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"clholo encode: error: --out {tmp_path / 'e'} holds {png.name}, "
                          f"which changed since clholo wrote it"), err
    assert tree(tmp_path) == before


def test_python_api_names_the_changed_files(tmp_path, scene):
    out = tmp_path / "r"
    assert _render(scene, out) == 0
    for name in ("summary.json", "hologram.npz", "focal_stack.npz", "focal_stack.png"):
        (out / name).write_bytes(b"mine")
    assert changed_entries(out) == ["focal_stack.npz", "focal_stack.png", "hologram.npz",
                                    "summary.json"]
    with pytest.raises(OutputRefused, match=r"holds focal_stack\.npz, focal_stack\.png, "
                                            r"hologram\.npz and 1 more, which changed since"):
        check_output_folder(out, overwrite=True, option="out_dir")


def test_a_manifest_from_before_checksums_still_allows_overwrite(tmp_path, scene):
    out = tmp_path / "r"
    assert _render(scene, out) == 0
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    del manifest["sha256"]
    (out / MANIFEST_NAME).write_text(json.dumps(manifest))
    (out / "summary.json").write_text("{}")
    assert changed_entries(out) == []  # nothing recorded: nothing to compare
    assert check_output_folder(out, overwrite=True) == out
