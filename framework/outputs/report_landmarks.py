"""The "Movement" section of a run's report: the landmarks of ``RUN/landmarks.csv`` as a clinician reads
them — where each hand and foot went and how fast, how far and how alike the two sides moved, at which
frequencies, how far the knees, elbows, hips and shoulders bent — with the landmarks the tracks lost and
their accuracy (``RUN/landmarks.json``) and the overlay video. The measures are read from ``RUN/movement.json`` (computed
by the landmarks step from the tables of :mod:`mmcsplat.analysis.movement`), each shown with its table
entry's label, unit and sentence. Every figure and table carries one plain sentence on what it shows."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from mmcsplat.analysis.lost_landmarks import lost_line, lost_names
from mmcsplat.analysis.movement import limb_landmarks, movement_summary, speed, speed_spectrum
from mmcsplat.outputs.report_html import command, esc, image, table, video
from mmcsplat.storage.landmark_formats import read_landmark_csv
from mmcsplat.storage.run import LANDMARKS_CSV, LANDMARKS_INFO, MOVEMENT_JSON

#: The unit shown for a measure's SI unit, and the factor between them (centimetres read better for an
#: infant's limbs); other units are shown as they are.
SHOWN_UNITS = {"m/s": ("cm/s", 100.0), "m": ("cm", 100.0)}
SIDE_COLOURS = {"left": "#1f77b4", "right": "#d62728"}
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
        sided = {label: track for label, track in limbs.items() if label.endswith(side)}
        for label, track in sided.items():
            panel.plot(times, speed(times, track[:, None])[:, 0] * 100, color=LIMB_COLOURS[label], label=label, linewidth=2)
        panel.set_title(title, fontsize=10)
        panel.set_xlabel("time (s)", fontsize=10)
        panel.grid(alpha=0.3)
        if sided:
            panel.legend(fontsize=9)
        else:
            panel.text(0.5, 0.5, f"no {title} carried", ha="center", va="center", transform=panel.transAxes, fontsize=10)
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


def angles_chart(times: np.ndarray, angles: dict[str, dict[str, Any]], labels: dict[str, str]) -> bytes:
    """PNG: each joint angle (degrees) against seconds, one panel per joint, left and right in two colours;
    ``angles`` are movement.json's ``joint_angles``, ``labels`` each angle measure's label."""
    kinds = list(dict.fromkeys(key.partition("_")[2] for key in angles))
    figure = _figure(7.5, 1.9 * len(kinds))
    panels = figure.subplots(len(kinds), 1, sharex=True, squeeze=False)[:, 0]
    for panel, kind in zip(panels, kinds, strict=True):
        for side, colour in SIDE_COLOURS.items():
            if f"{side}_{kind}" in angles:
                values = [np.nan if value is None else value for value in angles[f"{side}_{kind}"]["per_frame_deg"]]
                panel.plot(times, values, color=colour, label=side, linewidth=2)
        panel.set_ylabel(f"{labels[kind]} (°)", fontsize=9)
        panel.grid(alpha=0.3)
    panels[0].legend(ncol=2, fontsize=9, loc="lower left", bbox_to_anchor=(0, 1.02))
    panels[-1].set_xlabel("time (s)", fontsize=10)
    return _png(figure)


def _shown(value: Any, unit: str) -> Any:
    """A measure's value in the unit shown (:data:`SHOWN_UNITS`): a number, "x / y / z" for one per axis."""
    factor = SHOWN_UNITS.get(unit, ("", 1.0))[1]
    if isinstance(value, list):
        return " / ".join("n/a" if item is None else f"{item * factor:.2f}" for item in value)
    return None if value is None else round(value * factor, 2)


def _heading(measure: dict[str, str]) -> str:
    unit = SHOWN_UNITS.get(measure["unit"], (measure["unit"], 1.0))[0]
    return f"{measure['label']} ({unit})" if unit else measure["label"]


def measures_html(summary: dict[str, Any], times: np.ndarray) -> list[str]:
    """The measures of a movement.json: per landmark, left and right, joint angles — each table with its
    measures' sentences."""
    measures = summary["measures"]
    landmark_keys = list(next(iter(summary["landmarks"].values()), {}))
    parts = ["<h3>Measures per landmark</h3>" + table(
        ["landmark", *(_heading(measures[key]) for key in landmark_keys)],
        [(name, *(_shown(values[key], measures[key]["unit"]) for key in landmark_keys)) for name, values in summary["landmarks"].items()])]
    parts.append(_sentences(measures, landmark_keys))
    if summary.get("pairs"):
        pair_keys = [key for key in summary["pairs"][0] if key in measures]
        parts.append("<h3>Left and right</h3><p>How alike the two sides moved.</p>" + table(
            ["left", "right", *(_heading(measures[key]) for key in pair_keys)],
            [(pair["left"], pair["right"], *(pair[key] for key in pair_keys)) for pair in summary["pairs"]]) + _sentences(measures, pair_keys))
    angles, left_out = summary.get("joint_angles") or {}, summary.get("joint_angles_left_out") or {}
    if angles:
        kinds = list(dict.fromkeys(key.partition("_")[2] for key in angles))
        parts.append("<h3>Joint angles</h3><p>How far each joint bent, in degrees, from the landmarks' segments: 0° is a straight "
                     "limb (or one in line with the trunk); the range is the largest angle less the smallest over the frames where "
                     "the joint's landmarks were known.</p>")
        parts.append(image(angles_chart(times, angles, {kind: measures[kind]["label"] for kind in kinds}), "joint angles over time",
                           "Each joint's angle at every moment, left and right together."))
        parts.append(table(["joint angle", "side", "smallest (°)", "largest (°)", "range (°)", "frames"],
                           [(measures[key.partition("_")[2]]["label"], key.partition("_")[0], values["min_deg"], values["max_deg"],
                             values["range_deg"], values["frames"]) for key, values in angles.items()]) + _sentences(measures, kinds))
    if left_out:
        parts.append("<p class=\"note\">Joint angles not measured (their landmarks are absent): "
                     + esc("; ".join(f"{key.replace('_', ' ')} ({why})" for key, why in left_out.items())) + ".</p>")
    return parts


def _sentences(measures: dict[str, dict[str, str]], keys: list[str]) -> str:
    return "<ul>" + "".join(f"<li><strong>{esc(measures[key]['label'])}</strong>: {esc(measures[key]['sentence'])}</li>" for key in keys) + "</ul>"


def _mm(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.1f}"


def accuracy_rows(info: dict[str, Any]) -> list[tuple[str, str]]:
    """The landmarks' accuracy as (measure, value) rows: 3D against the source and its floor, joint angles, 2D per camera."""
    rows: list[tuple[str, str]] = []
    accuracy = info.get("accuracy_3d")
    if accuracy:
        rows += [("3D error, median over all frames (mm)", _mm(accuracy["median_mm"])),
                 ("3D error, 90th percentile (mm)", _mm(accuracy["p90_mm"])),
                 ("3D error where the landmark moved > 1 cm (mm)", _mm(accuracy["moving_median_mm"])),
                 ("… if the landmarks had been held still (mm)", _mm(accuracy["still_moving_median_mm"]))]
    floor = info.get("reference_floor")
    if floor:
        rows += [("the source's floor: a body of fixed bones placed nearest it, median (mm)", _mm(floor["median_mm"])),
                 ("… the carried landmarks from that body, median (mm)", _mm(floor["carried_median_mm"]))]
    angles = info.get("accuracy_joint_angles")
    if angles:
        rows += [("joint angle error, median (°)", _mm(angles["median_deg"])), ("joint angle error, 90th percentile (°)", _mm(angles["p90_deg"]))]
    for camera, scores in (info.get("accuracy_2d") or {}).items():
        body = scores.get("floor_median_px")
        rows.append((f"2D error in {camera}{' (held out)' if scores['heldout'] else ''}, carried / source's own{' / that body' if body is not None else ''} (px)",
                     f"{_mm(scores['carried_median_px'])} / {_mm(scores['reference_median_px'])}" + (f" / {_mm(body)}" if body is not None else "")))
    return rows


def lost_html(record: dict[str, Any]) -> str:
    """The landmarks the tracks lost (RUN/landmarks.json's ``lost``): a sentence, and a table of the lost
    ones with the first frame, the number of frames each was lost and the signals that found it."""
    rule = record["rule"]
    # Runs carried before the slip had a window summed it from the first frame.
    since = f"over the last {rule['slip_window']} pairs of frames" if "slip_window" in rule else "since the first frame"
    flow = (f" or, with the session's optical flow, their image slipped from the images' motion {since} by more than "
            f"{rule['slip_mm']:.0f} mm at their depth") if "slip_mm" in rule else ""
    parts = [f"<h3>Lost landmarks</h3><p>Where the tracks stopped following the images: a landmark is lost at the frames where it "
             f"and the Gaussians carrying it fell off the subject mask (by more than {rule['tolerance']:.1%} of the image diagonal){flow} "
             f"in most training cameras, for {rule['consecutive']} frames in a row or more. {esc(lost_line(record))}.</p>"]
    lost = lost_names(record)
    if lost:
        parts.append(table(["landmark", "first lost frame", "frames lost", "found by"],
                           [(name, entry["first_lost_frame"], len(entry["lost_frames"]), ", ".join(entry.get("found_by", ["masks"])))
                            for name, entry in sorted(lost.items(), key=lambda item: (item[1]["first_lost_frame"], item[0]))]))
    return "".join(parts)


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
    if info.get("lost"):
        parts.append(lost_html(info["lost"]))
    movement_path = Path(run) / MOVEMENT_JSON  # a run carried before movement.json existed: the same tables, computed here
    parts += measures_html(json.loads(movement_path.read_text()) if movement_path.is_file() else movement_summary(names, times, positions), times)
    rows = accuracy_rows(info)
    if rows:
        parts.append("<h3>Accuracy of the landmarks</h3><p>How far the carried landmarks were from the source's own at the same frames "
                     "(3D) and from the keypoints detected in each camera (2D), beside what holding them still would score.</p>"
                     + table(["measure", "value"], rows))
    for payload, name in videos:
        parts.append(video(payload, name, f"The landmarks and their trails over the last frames, on the camera's own images: {name}"))
    return "\n".join(parts)
