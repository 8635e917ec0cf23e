"""The "Movement" section of a run's report: the landmarks of ``RUN/landmarks.csv`` as a clinician reads
them — where each hand and foot went and how fast, how far and how alike the two sides moved, at which
frequencies — with their accuracy (``RUN/landmarks.json``) and the overlay video. Every figure and table
carries one plain sentence on what it shows."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from mmcsplat.analysis.movement import MEASURE_DESCRIPTIONS, limb_landmarks, movement_summary, speed, speed_spectrum
from mmcsplat.outputs.report_html import command, esc, image, table, video
from mmcsplat.storage.landmark_files import read_landmark_csv
from mmcsplat.storage.run import LANDMARKS_CSV, LANDMARKS_INFO

#: Each measure's column heading and the factor from its SI unit to the one shown (centimetres read better
#: for an infant's limbs).
COLUMNS = {"mean_speed_m_s": ("mean speed (cm/s)", 100), "peak_speed_m_s": ("peak speed (cm/s)", 100),
           "path_length_m": ("path (cm)", 100), "range_of_motion_m": ("range (cm)", 100),
           "dominant_frequency_hz": ("rhythm (Hz)", 1), "spectral_centroid_hz": ("centroid (Hz)", 1)}
LIMB_COLOURS = {"left hand": "#1f77b4", "right hand": "#d62728", "left foot": "#2ca02c", "right foot": "#ff7f0e"}
AXES = ("x", "y", "z")


def _png(figure) -> bytes:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", bbox_inches="tight")
    return buffer.getvalue()


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width, height), dpi=110)
    FigureCanvasAgg(figure)
    return figure


def trajectories_chart(times: np.ndarray, limbs: dict[str, np.ndarray]) -> bytes:
    """PNG: each limb's displacement from its first known position (cm) along x, y and z against seconds,
    one panel per axis, the two hands and two feet in four colours."""
    figure = _figure(7.5, 6.0)
    panels = figure.subplots(3, 1, sharex=True)
    for axis, panel in enumerate(panels):
        for label, track in limbs.items():
            first = track[np.flatnonzero(np.all(np.isfinite(track), axis=1))[0]] if np.isfinite(track).any() else np.zeros(3)
            panel.plot(times, (track[:, axis] - first[axis]) * 100, color=LIMB_COLOURS[label], label=label, linewidth=2)
        panel.set_ylabel(f"{AXES[axis]} (cm)", fontsize=10)
        panel.grid(alpha=0.3)
    panels[0].legend(ncol=4, fontsize=9, loc="lower left", bbox_to_anchor=(0, 1.02))
    panels[-1].set_xlabel("time (s)", fontsize=10)
    return _png(figure)


def speed_chart(times: np.ndarray, limbs: dict[str, np.ndarray]) -> bytes:
    """PNG: the speed of each hand and foot (cm/s) against seconds, left and right side by side."""
    figure = _figure(7.5, 3.6)
    panels = figure.subplots(1, 2, sharey=True)
    for panel, side, title in zip(panels, ("hand", "foot"), ("hands", "feet"), strict=True):
        for label, track in limbs.items():
            if label.endswith(side):
                panel.plot(times, speed(times, track[:, None])[:, 0] * 100, color=LIMB_COLOURS[label], label=label, linewidth=2)
        panel.set_title(title, fontsize=10)
        panel.set_xlabel("time (s)", fontsize=10)
        panel.grid(alpha=0.3)
        panel.legend(fontsize=9)
    panels[0].set_ylabel("speed (cm/s)", fontsize=10)
    return _png(figure)


def spectrum_chart(times: np.ndarray, limbs: dict[str, np.ndarray]) -> bytes:
    """PNG: the power spectrum of each limb's speed against frequency (Hz)."""
    figure = _figure(7.5, 3.0)
    panel = figure.subplots()
    for label, track in limbs.items():
        frequencies, power = speed_spectrum(times, track)
        if len(frequencies):
            panel.plot(frequencies, power, color=LIMB_COLOURS[label], label=label, linewidth=2)
    panel.set_xlabel("frequency (Hz)", fontsize=10)
    panel.set_ylabel("power of speed", fontsize=10)
    panel.grid(alpha=0.3)
    panel.legend(fontsize=9)
    return _png(figure)


def _mm(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.1f}"


def accuracy_rows(info: dict[str, Any]) -> list[tuple[str, str]]:
    """The landmarks' accuracy as (measure, value) rows: 3D against the source, 2D per camera."""
    rows: list[tuple[str, str]] = []
    accuracy = info.get("accuracy_3d")
    if accuracy:
        rows += [("3D error, median over all frames (mm)", _mm(accuracy["median_mm"])),
                 ("3D error, 90th percentile (mm)", _mm(accuracy["p90_mm"])),
                 ("3D error where the landmark moved > 1 cm (mm)", _mm(accuracy["moving_median_mm"])),
                 ("… if the landmarks had been held still (mm)", _mm(accuracy["still_moving_median_mm"]))]
    for camera, scores in (info.get("accuracy_2d") or {}).items():
        rows.append((f"2D error in {camera}{' (held out)' if scores['heldout'] else ''}, carried / source's own (px)",
                     f"{_mm(scores['carried_median_px'])} / {_mm(scores['reference_median_px'])}"))
    return rows


def landmarks_section(run: Path, videos: list[tuple[bytes, str]]) -> str:
    """The section's HTML; ``videos`` are the landmark overlay videos found in RUN/renders (payload, name)."""
    path = Path(run) / LANDMARKS_CSV
    if not path.is_file():
        return (f"<h2>Movement</h2><p class=\"note\">No landmarks yet: {command('mmcsplat', 'landmarks', run, '--source', 'NAME')} "
                "carries joints or keypoints through the run (sources: trc, csv, openpose, synthetic).</p>")
    names, _, times, positions, _ = read_landmark_csv(path)
    info_path = Path(run) / LANDMARKS_INFO
    info = json.loads(info_path.read_text()) if info_path.is_file() else {}
    limbs = {label: positions[:, names.index(name)] for label, name in limb_landmarks(names).items()}
    parts = ["<h2>Movement</h2>",
             f"<p>{len(names)} landmarks from <code>{esc(info.get('source', '?'))}</code>, carried by the subject's Gaussians "
             f"over {len(times)} frames ({times[-1] - times[0]:.2f} s)"
             + (f"; not carried (no Gaussian near them): {esc(', '.join(info['unbound']))}" if info.get("unbound") else "") + ".</p>"]
    if limbs:
        parts.append(image(trajectories_chart(times, limbs), "trajectories of the hands and feet",
                           "Where the hands and feet went: each one's displacement from where it started, along each axis of the "
                           "calibration (for the synthetic mat, z is up), against time."))
        parts.append(image(speed_chart(times, limbs), "speed of the hands and feet",
                           "How fast each hand and foot moved at every moment; the two sides are drawn together to compare them."))
        if len(times) >= 8:
            parts.append(image(spectrum_chart(times, limbs), "frequency of the limb movements",
                               "At which rhythms the limbs moved: peaks are the frequencies of repeated movements (short recordings resolve them coarsely)."))
    summary = movement_summary(names, times, positions)
    def shown(value: float | None, factor: float) -> float | None:
        return None if value is None else round(value * factor, 2)

    parts.append("<h3>Measures per landmark</h3>" + table(
        ["landmark", *(heading for heading, _ in COLUMNS.values())],
        [(name, *(shown(values.get(key), factor) for key, (_, factor) in COLUMNS.items())) for name, values in summary["landmarks"].items()]))
    parts.append("<ul>" + "".join(f"<li><strong>{esc(heading)}</strong>: {esc(MEASURE_DESCRIPTIONS[key])}</li>"
                                  for key, (heading, _) in COLUMNS.items()) + "</ul>")
    if summary.get("pairs"):
        parts.append("<h3>Left and right</h3><p>How alike the two sides moved: the correlation of their speeds (1: in step, 0: unrelated) "
                     "and the ratio of the distances they travelled (1: as far).</p>" + table(
                         ["left", "right", "speed correlation", "path length ratio"],
                         [(pair["left"], pair["right"], pair["speed_correlation"], pair["path_length_ratio"]) for pair in summary["pairs"]]))
    rows = accuracy_rows(info)
    if rows:
        parts.append("<h3>Accuracy of the landmarks</h3><p>How far the carried landmarks were from the source's own at the same frames "
                     "(3D) and from the keypoints detected in each camera (2D), beside what holding them still would score.</p>"
                     + table(["measure", "value"], rows))
    for payload, name in videos:
        parts.append(video(payload, name, f"The landmarks and their trails over the last frames, on the camera's own images: {name}"))
    return "\n".join(parts)
