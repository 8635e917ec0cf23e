"""Reliability, class 2: nothing lost. --overwrite replaces only a session; a second writer of a run or a
session is refused while the first works; a store that keeps nothing is refused; what a killed writer
left is cleaned by the next one."""

from __future__ import annotations

import uuid
from pathlib import Path

import pytest
import rig_fixtures as rig
from fitting_scene import write_config, write_fitted_run, write_session

from mmcsplat.cli.main import main
from mmcsplat.storage.locking import run_lock, session_lock
from mmcsplat.storage.session import SessionReader, SessionUpdater


@pytest.fixture
def capture(tmp_path) -> Path:
    folder = tmp_path / "capture"
    rig.make_capture(folder, frames=2)
    return folder


def _files(folder: Path) -> dict[str, bytes]:
    return {str(path.relative_to(folder)): path.read_bytes() for path in sorted(folder.rglob("*")) if path.is_file()}


@pytest.mark.parametrize("out", ["capture", ".", "capture_parent"])
def test_ingest_never_replaces_its_own_capture(capture, tmp_path, capsys, out):
    target = {"capture": capture, ".": capture.parent, "capture_parent": tmp_path}[out]
    before = _files(capture)
    assert main(["ingest", str(capture), str(target), "--overwrite"]) == 2
    assert "is the capture" in capsys.readouterr().err and _files(capture) == before


def test_overwrite_replaces_only_a_session(capture, tmp_path, capsys):
    precious = tmp_path / "results"
    precious.mkdir()
    (precious / "thesis.tex").write_text("years of work")
    assert main(["ingest", str(capture), str(precious), "--overwrite"]) == 2
    assert "is not an mmcsplat session" in capsys.readouterr().err and (precious / "thesis.tex").read_text() == "years of work"
    session = tmp_path / "s.zarr"
    assert main(["ingest", str(capture), str(session)]) == 0
    assert main(["ingest", str(capture), str(session), "--overwrite"]) == 0  # a session may be replaced


def test_a_store_that_keeps_nothing_is_refused(capture, capsys):
    assert main(["ingest", str(capture), f"memory://{uuid.uuid4().hex}/s.zarr"]) == 2
    assert "keeps nothing after this process ends" in capsys.readouterr().err


def test_a_second_fit_into_a_busy_run_is_refused(tmp_path, capsys):
    session = write_session(tmp_path / "s.zarr")
    out = tmp_path / "run"
    with run_lock(out):  # a first fit at work
        assert main(["fit", str(session), "--config", str(write_config(tmp_path / "c.toml", iterations=5)), "--out", str(out), "--no-progress"]) == 2
    assert f"run {out} is being written by another mmcsplat process" in capsys.readouterr().err
    assert not (out / "run.json").exists()


def test_a_second_segmentation_of_a_busy_session_is_refused(tmp_path, capsys):
    session = write_session(tmp_path / "s.zarr")
    with session_lock(session):
        assert main(["segment", str(session), "--segmenter", "precomputed"]) == 2
    assert "is being written by another mmcsplat process" in capsys.readouterr().err
    assert main(["segment", str(session), "--segmenter", "precomputed"]) == 0  # once the first is done


def test_the_next_writer_cleans_what_a_killed_one_left(capture, tmp_path):
    session = tmp_path / "s.zarr"
    leftover = tmp_path / ".s.zarr.partial-deadbeef"
    (leftover / "cameras").mkdir(parents=True)  # an ingest killed with -9
    assert main(["ingest", str(capture), str(session)]) == 0
    assert not leftover.exists()
    updater = SessionUpdater(session)  # a segmentation killed before its commit: an orphan array
    updater.write("cam_a", "mask", 0, SessionReader(session).frame(0, "cam_a").rgb[..., 0] > 0)
    orphan = f"mask.{updater._token}"
    updater._release()  # the process died: the OS released its lock
    assert orphan in list(SessionReader(session)._group["cameras/cam_a"].array_keys())
    SessionUpdater(session).abort()
    assert orphan not in list(SessionReader(session)._group["cameras/cam_a"].array_keys())


# ------------------------------------------------------------- nothing deleted that mmcsplat did not write

SYNTH = ["--num-frames", "1", "--num-cameras", "2", "--width", "32", "--height", "24", "--no-adult-leg", "--no-progress"]


def test_synth_overwrite_replaces_only_a_synthetic_capture(tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("the infant's history")
    assert main(["synth", str(mine), "--overwrite", *SYNTH]) == 2
    assert "is not a capture `mmcsplat synth` wrote (notes.txt)" in capsys.readouterr().err
    assert (mine / "notes.txt").read_text() == "the infant's history" and [p.name for p in mine.iterdir()] == ["notes.txt"]
    capture = tmp_path / "capture"
    assert main(["synth", str(capture), *SYNTH]) == 0
    assert main(["synth", str(capture), "--overwrite", *SYNTH]) == 0  # its own output may be replaced
    (capture / "session.zarr").mkdir()  # ... until the user keeps something of theirs in it
    assert main(["synth", str(capture), "--overwrite", *SYNTH]) == 2
    assert "(session.zarr)" in capsys.readouterr().err and (capture / "session.zarr").is_dir()


def test_a_synth_cleans_what_a_killed_one_left_beside_its_capture(tmp_path):
    killed = tmp_path / ".capture.k1ll3d.partial"
    (killed / "videos").mkdir(parents=True)
    (tmp_path / ".capture..capture.x.partial.old").mkdir()
    (tmp_path / ".other.k1ll3d.partial").mkdir()  # another capture's: not this writer's to take
    assert main(["synth", str(tmp_path / "capture"), *SYNTH]) == 0
    assert sorted(path.name for path in tmp_path.iterdir()) == [".other.k1ll3d.partial", "capture"]


def test_ingest_overwrite_refuses_a_session_holding_a_run(capture, tmp_path, capsys):
    session = tmp_path / "s.zarr"
    assert main(["ingest", str(capture), str(session)]) == 0
    (session / "run").mkdir()
    (session / "run" / "run.json").write_text("{}")  # a run fitted into the session, by an older mmcsplat
    assert main(["ingest", str(capture), str(session), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert f"{session}: the session holds run" in err and "move it out first" in err
    assert (session / "run" / "run.json").exists() and SessionReader(session).num_frames == 2


@pytest.mark.parametrize("inside", [".", "cameras/r"])
def test_a_run_is_never_written_into_a_session(tmp_path, capsys, inside):
    session = write_session(tmp_path / "s.zarr")
    out = session / inside
    before = sorted(path.relative_to(session) for path in session.rglob("*"))
    config = write_config(tmp_path / "c.toml", iterations=2)
    assert main(["fit", str(session), "--config", str(config), "--out", str(out), "--no-progress"]) == 2
    assert f"lies inside the session store {session}" in capsys.readouterr().err
    assert sorted(path.relative_to(session) for path in session.rglob("*")) == before


def test_a_failed_export_leaves_no_file_that_looks_whole(tmp_path, capsys):
    session = write_session(tmp_path / "s.zarr", frames=3)
    run = write_fitted_run(tmp_path / "run", session)
    assert main(["track", str(run), "--dynamics", "iterative", "--set", "dynamics.iterations=1", "--no-progress"]) == 0
    (run / "tracks.zarr" / "means" / "c.2.0.0").write_bytes(b"damaged")
    out = tmp_path / "ply"
    assert main(["export", str(run), "--ply", str(out), "--no-progress"]) == 2
    assert "tracks.zarr: means, frame 2" in capsys.readouterr().err
    assert not out.exists() and [p.name for p in tmp_path.iterdir() if p.name.startswith(".ply")] == []


def test_a_landmark_export_replaces_only_its_own_kind_of_file(tmp_path, capsys):
    import numpy as np

    from mmcsplat.storage.landmark_formats import write_landmark_csv

    session = write_session(tmp_path / "s.zarr", frames=1)
    run = write_fitted_run(tmp_path / "run", session)
    write_landmark_csv(run / "landmarks.csv", ["knee"], np.array([0]), np.array([0.0]), np.zeros((1, 1, 3)))
    notes = {kind: tmp_path / f"notes.{kind}" for kind in ("trc", "csv", "c3d")}
    for kind, path in notes.items():
        path.write_text("the clinician's own notes\n")
        assert main(["export", str(run), f"--{kind}", str(path)]) == 2
        assert f"{path} exists and is not a {kind.upper()} file" in capsys.readouterr().err
        assert path.read_text() == "the clinician's own notes\n"
    exported = {kind: tmp_path / f"landmarks.{kind}" for kind in notes}
    arguments = [argument for kind, path in exported.items() for argument in (f"--{kind}", str(path))]
    assert main(["export", str(run), *arguments]) == 0
    assert main(["export", str(run), *arguments]) == 0  # an export run again replaces its own files



def test_report_out_replaces_only_a_report(tmp_path, capsys):
    run = write_fitted_run(tmp_path / "run", write_session(tmp_path / "s.zarr", frames=1))
    notes = tmp_path / "notes.html"
    notes.write_text("<html>the clinician's own page</html>\n")
    assert main(["report", str(run), "--out", str(notes)]) == 2
    assert f"{notes} exists and is not an mmcsplat report" in capsys.readouterr().err
    assert notes.read_text() == "<html>the clinician's own page</html>\n"
    assert main(["report", str(run)]) == 0
    assert main(["report", str(run)]) == 0  # a report written again replaces its own page


def test_a_synth_that_fails_while_it_starts_leaves_neither_its_folder_nor_its_lock(tmp_path, monkeypatch):
    from mmcsplat.synthetic import writer

    monkeypatch.setattr(writer, "VideoStream", lambda *args: (_ for _ in ()).throw(RuntimeError("no encoder")))
    assert main(["synth", str(tmp_path / "capture"), *SYNTH]) != 0
    assert list(tmp_path.iterdir()) == []
