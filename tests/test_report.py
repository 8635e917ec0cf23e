"""mmcsplat report: one self-contained HTML page of a tiny tracked run, an untouched run and a study,
checked as text and loaded in a real headless browser (Debian's chromium) that decodes every image and
video."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest
from fitting_scene import write_fitted_run, write_ground_truth, write_session
from render_fixtures import add_tracks

from mmcsplat.cli import main
from mmcsplat.configuration.registry import default_registry
from mmcsplat.outputs.report_html import esc
from mmcsplat.outputs.report_landmarks import speed_chart
from mmcsplat.storage.curves import TrainingCurve
from mmcsplat.storage.session import SessionReader
from mmcsplat.studies.cells import COMPLETE, CellOutcome
from mmcsplat.studies.runner import write_results
from mmcsplat.studies.spec import expand, load_study

FRAMES = 4
CHROMIUM = Path("/usr/bin/chromium")
URI = re.compile(r'src="data:(?P<mime>[a-z]+/[a-z0-9]+);base64,(?P<payload>[A-Za-z0-9+/=]+)"')
# Injected before </body>: once every <img> has decoded and every <video> has its metadata (or failed),
# writes "ok" or the failures into <body data-check>, which --dump-dom then prints.
CHECK = """<script>
window.addEventListener('load', function () {
  var failures = [];
  document.querySelectorAll('img').forEach(function (img) {
    if (!img.complete || img.naturalWidth === 0) failures.push('image ' + img.alt);
  });
  var videos = Array.prototype.slice.call(document.querySelectorAll('video'));
  Promise.all(videos.map(function (video) {
    return new Promise(function (resolve) {
      var done = false;
      function finish(failure) { if (!done) { done = true; if (failure) failures.push(failure); resolve(); } }
      if (video.error) return finish('video ' + video.title + ' error ' + video.error.code);
      if (video.readyState >= 1) return finish(null);
      video.addEventListener('loadedmetadata', function () { finish(null); });
      video.addEventListener('error', function () { finish('video ' + video.title + ' error'); });
      setTimeout(function () { finish('video ' + video.title + ' no metadata'); }, 4000);
    });
  })).then(function () { document.body.dataset.check = failures.length ? failures.join('; ') : 'ok'; });
});
</script>
"""


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """(a tracked, evaluated and rendered run; the same fit untouched) of the moving fitting scene."""
    root = tmp_path_factory.mktemp("report")
    session = write_session(root / "session.zarr", frames=FRAMES)
    static = write_fitted_run(root / "static", session)
    run = add_tracks(write_fitted_run(root / "run", session), FRAMES)
    truth = write_ground_truth(root / "truth.zarr", FRAMES)
    for stage, steps in (("fit", range(4, 44, 4)), ("track", range(1, FRAMES))):
        curve = TrainingCurve(stage)
        for step in steps:
            curve.log(step=step, frame=0 if stage == "fit" else step, loss=1.0 / step, psnr=10.0 + step, gaussians=60)
        curve.write(run)
    assert main(["evaluate", str(run), "--ground-truth", str(truth)]) == 0
    assert main(["render", str(run), "--novel", "--trajectories", "--depth", "--frames-per-segment", "1", "--no-progress"]) == 0
    assert main(["report", str(run)]) == 0
    return run, static


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """A study output written by the study's own writer from made-up outcomes (no cell is fitted)."""
    folder = tmp_path_factory.mktemp("study")
    write_session(folder / "scene.zarr")
    (folder / "fit.toml").write_text('[renderer]\nname = "torch-reference"\n')
    variants = "".join(f'\n[[variant]]\nname = "{name}"\nconfig = "fit.toml"\nset = {{ "fit.iterations" = {n} }}\n'
                       for name, n in (("small <b>", 10), ("large | wide", 20)))
    (folder / "study.toml").write_text(f'[study]\nname = "tiny"\n{variants}\n[sessions.scene]\npath = "scene.zarr"\n')
    registry = default_registry()
    study = load_study(folder / "study.toml", registry)
    out = folder / "out"
    out.mkdir()
    cells = expand(study, out, registry)
    outcomes = {cell.spec.key: CellOutcome(cell.spec.key, COMPLETE, val_masked_psnr=25.0 if cell.variant.startswith("large") else 20.0,
                                           num_gaussians=100 * (i + 1), iterations=10, wall_s=1.0 + i, iterations_per_s=10 / (1.0 + i))
                for i, cell in enumerate(cells)}
    charts = write_results(study, out, cells, outcomes, registry).charts
    assert main(["report", str(out)]) == 0
    return out, len(charts)


def embedded(page: str, mime: str) -> list[bytes]:
    return [base64.b64decode(m["payload"]) for m in URI.finditer(page) if m["mime"] == mime]


def assert_self_contained(page: str) -> None:
    assert not re.search(r"https?:|//cdn|<script|<link|@import", page, flags=re.I)
    sources = re.findall(r'src="([^"]*)"', page)
    assert sources and all(source.startswith("data:") for source in sources)


def test_run_page_shows_views_metrics_chart_and_renders(runs):
    run, _ = runs
    page = (run / "report.html").read_text()
    assert_self_contained(page)
    for heading in ("Renders beside the ground truth", "<h3>cam_0</h3>", "Metrics", "Per camera", "Tracking", "Training curves", "Figures and videos"):
        assert heading in page
    # colour, depth, segmentation rendered and ground truth; the per-frame chart; the training curves; the trajectory strip
    pngs = embedded(page, "image/png")
    assert "the first-frame fit (means over each round of the training cameras), then the tracking" in page
    assert len(pngs) == 3 * 2 + 1 + 1 + 1 and all(png.startswith(b"\x89PNG") for png in pngs)
    assert "3D error, median (mm)" in page and "synthetic" in page
    metrics = json.loads((run / "metrics.json").read_text())
    assert "held-out masked PSNR, mask less its edge (dB)" in page and "mask share on the others&#x27; hull" in page
    assert f"{metrics['val_interior_masked_psnr']:.3f}" in page
    videos = embedded(page, "video/mp4")
    assert sorted(videos) == sorted((run / "renders" / name).read_bytes() for name in ("novel.mp4", "trajectories_cam_0.mp4", "depth_cam_0.mp4"))
    assert (run / "renders" / "trajectories_cam_0.png").read_bytes() in pngs
    assert "Not rendered yet" not in page and "mmcsplat track" not in page
    assert "Clean plates" not in page  # its session has none


def test_untouched_run_says_which_commands_make_what_is_missing(runs, tmp_path):
    _, static = runs
    out = tmp_path / "pages" / "static.html"
    assert main(["report", str(static), "--out", str(out)]) == 0
    assert not (static / "report.html").exists()
    page = out.read_text()
    assert_self_contained(page)
    assert f"mmcsplat evaluate {static}" in page and f"mmcsplat track {static}" in page
    assert f"mmcsplat render {static} --trajectories --novel --depth" in page
    assert "No curves.csv" in page
    assert len(embedded(page, "image/png")) == 6 and not embedded(page, "video/mp4")


def test_run_page_shows_each_cameras_plate_and_how_it_was_made(tmp_path):
    from mmcsplat.pipeline.plates import estimate_plates

    session = write_session(tmp_path / "session.zarr", frames=3, plates=True)
    estimate_plates(session, ["cam_1"], replace=True, progress=False)
    run = write_fitted_run(tmp_path / "run", session)
    assert main(["report", str(run)]) == 0
    page = (run / "report.html").read_text()
    assert "<h2>Clean plates</h2>" in page and page.count('alt="plate of cam_') == len(SessionReader(session).camera_names)
    assert "cam_0: recorded" in page and "cam_1: estimated from 3 frames (subject masked out): stable background" in page


def test_a_run_whose_tracks_follow_no_ground_truth_point_is_still_evaluated(runs, tmp_path, capsys):
    import json

    import numpy as np
    import zarr

    run = tmp_path / "far"
    shutil.copytree(runs[0], run)
    truth = tmp_path / "far_truth.zarr"
    zarr.open_group(str(truth), mode="w", zarr_format=3).create_array("surface_points", data=np.full((FRAMES, 5, 3), 10.0))
    assert main(["evaluate", str(run), "--ground-truth", str(truth)]) == 0
    assert "warning: " + str(run) + ": tracking errors not measured: no ground-truth surface point" in capsys.readouterr().err
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["tracking_median_mm"] is None and metrics["tracking_followed_points"] == 0
    assert metrics["val_masked_psnr"] is not None and len(metrics["per_frame_val_masked_psnr"]) == FRAMES and "drift" in metrics
    assert main(["report", str(run)]) == 0
    page = (run / "report.html").read_text()
    assert "Tracking errors not measured: no ground-truth surface point has a Gaussian within 10 mm" in page
    assert "No ground truth was found" not in page
    assert f"<td>drift, explained</td><td>{esc(metrics['drift_summary'])}</td>" in page  # the verdict with how many Gaussians, since when


def test_study_page_has_the_table_findings_and_charts(study):
    out, charts = study
    page = (out / "report.html").read_text()
    assert_self_contained(page)
    assert "<title>Study tiny</title>" in page and "<th>val PSNR</th>" in page
    assert "<td>small &lt;b&gt;</td>" in page and "<td>large | wide</td>" in page  # escaped, the pipe unescaped
    assert "Best held-out masked PSNR: <strong>large | wide</strong>" in page
    assert charts >= 2 and len(embedded(page, "image/png")) == charts


def test_anything_else_is_a_clear_error(runs, tmp_path, capsys):
    run, _ = runs
    assert main(["report", str(tmp_path / "missing")]) == 2
    assert f"{tmp_path / 'missing'} is not a directory" in capsys.readouterr().err
    assert main(["report", str(tmp_path)]) == 2
    assert f"{tmp_path} is neither a run directory" in capsys.readouterr().err
    folds = tmp_path / "folds"
    shutil.copytree(run, folds / "cam_0", ignore=shutil.ignore_patterns("tracks.zarr", "renders", "report.html"))
    assert main(["report", str(folds)]) == 2
    assert f"report one of them, e.g. {folds / 'cam_0'}" in capsys.readouterr().err


def browser_check(page: Path, tmp_path: Path) -> tuple[str, str]:
    """(the page's data-check verdict, chromium's log) with :data:`CHECK` injected into a copy of ``page``."""
    checked = tmp_path / f"checked_{page.parent.name}.html"
    checked.write_text(page.read_text().replace("</body>", CHECK + "</body>"))
    result = subprocess.run(
        [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         f"--user-data-dir={tmp_path / 'profile'}", "--enable-logging=stderr", "--v=0", "--virtual-time-budget=10000",
         "--dump-dom", checked.as_uri()],
        capture_output=True, text=True, timeout=120, check=True)
    verdict = re.search(r'<body[^>]*data-check="([^"]*)"', result.stdout)
    return (verdict.group(1) if verdict else "no verdict"), result.stderr


@pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's chromium at /usr/bin/chromium (.ci/run installs it: apt-get install chromium)")
def test_pages_load_in_a_headless_browser(runs, study, tmp_path):
    run, _ = runs
    for page in (run / "report.html", study[0] / "report.html"):
        verdict, log = browser_check(page, tmp_path)
        assert verdict == "ok", f"{page}: {verdict}"
        assert "Uncaught" not in log and "ERROR:CONSOLE" not in log, log
    # The check itself fails on a broken page: a truncated video and a corrupt image.
    broken = tmp_path / "broken" / "report.html"
    broken.parent.mkdir()
    text = (run / "report.html").read_text()
    broken.write_text(text.replace("data:video/mp4;base64,", "data:video/mp4;base64,AAAA", 1).replace("data:image/png;base64,", "data:image/png;base64,AAAA", 1))
    verdict, _ = browser_check(broken, tmp_path)
    assert "video" in verdict and "image" in verdict


def test_a_speed_chart_with_hands_only_says_no_feet_were_carried():
    """A run whose feet were not carried draws the hands and says so in the feet's panel, without matplotlib's
    empty-legend warning."""
    times = np.arange(10) / 30.0
    hands = {label: np.cumsum(np.full((10, 3), 0.01), axis=0) for label in ("left hand", "right hand")}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        png = speed_chart(times, hands)
    assert png.startswith(b"\x89PNG")
