"""Segmenters (onnx-semantic, background, precomputed), their shared post-processing, and `mmcsplat segment`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import zarr

from mmcsplat.cli import main
from mmcsplat.configuration.registry import default_registry
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.session import SessionReader, SessionWriter

onnx = pytest.importorskip("onnx")

W, H = 32, 24
LABELS = ["background", "person;individual;someone", "plaything, toy"]
GREY, RED, BLUE, GREEN = (128, 128, 128), (255, 0, 0), (0, 0, 255), (0, 255, 0)


def _scene() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A grey image with a big red block (person), a blue block touching it (toy), a small separate red
    block and a green patch; blocks sit on even pixels so a 2× down- and up-sampling keeps them exact."""
    rgb = np.full((H, W, 3), GREY, np.uint8)
    regions = {name: np.zeros((H, W), bool) for name in ("red", "blue", "small", "green")}
    regions["red"][4:16, 4:14] = True
    regions["blue"][4:16, 14:18] = True
    regions["small"][18:22, 24:28] = True
    regions["green"][0:4, 24:32] = True
    for name, colour in (("red", RED), ("blue", BLUE), ("small", RED), ("green", GREEN)):
        rgb[regions[name]] = colour
    return rgb, regions


def _model(folder: Path, batch: str | int = "N", labels: list[str] = LABELS, argmax: bool = False, **sidecar) -> Path:
    """A 1×1 convolution scoring (background, person, toy) from colour: red → person, blue → toy, other
    colours → background (bias 0.5); with ``argmax`` the model outputs [N, 1, h, w] class ids instead.
    Inputs normalised to [-1, 1]; the sidecar asks for 16×12 inputs."""
    from onnx import TensorProto, helper, numpy_helper

    weights = np.array([[0, 0, 0], [1, -1, -1], [-1, -1, 1]], np.float32).reshape(3, 3, 1, 1)
    bias = np.array([0.5, 0, 0], np.float32)
    nodes = [helper.make_node("Conv", ["image", "weights", "bias"], ["logits"])]
    output = helper.make_tensor_value_info("logits", TensorProto.FLOAT, [batch, 3, "height", "width"])
    if argmax:
        nodes.append(helper.make_node("ArgMax", ["logits"], ["ids"], axis=1, keepdims=1))
        output = helper.make_tensor_value_info("ids", TensorProto.INT64, [batch, 1, "height", "width"])
    graph = helper.make_graph(
        nodes,
        "tiny-segmenter",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [batch, 3, "height", "width"])],
        [output],
        initializer=[numpy_helper.from_array(weights, "weights"), numpy_helper.from_array(bias, "bias")],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    path = folder / "tiny.onnx"
    onnx.save(model, path)
    description = {"input_size": [16, 12], "mean": [0.5] * 3, "std": [0.5] * 3, "labels": labels} | sidecar
    path.with_suffix(".json").write_text(json.dumps(description))
    return path


def _camera(name: str, width: int = W, height: int = H) -> Camera:
    return Camera(name, width, height, [[width, 0, width / 2], [0, width, height / 2], [0, 0, 1]], np.eye(3), [0, 0, 2])


def _session(path: Path, frames: dict[str, list[np.ndarray]], masks: dict[str, list[np.ndarray]] | None = None) -> Path:
    """A committed session with the given RGB frames (and masks) per camera."""
    masks = masks or {}
    first = next(iter(frames.values()))[0]
    cameras = [_camera(name, first.shape[1], first.shape[0]) for name in frames]
    with SessionWriter(path, cameras=cameras, num_frames=max(map(len, frames.values())), fps=30.0) as writer:
        for name, images in frames.items():
            for t, rgb in enumerate(images):
                writer.write_frame(name, t, rgb, mask=masks[name][t] if name in masks else None)
    return path


def _segmenter(name: str, **params):
    return default_registry().create("segmenter", name, **params)


def _arrays(session: Path, camera: str) -> set[str]:
    """The arrays stored for a camera (a failed update must leave no extra ones behind)."""
    return {entry.name for entry in (session / "cameras" / camera).iterdir() if entry.is_dir()}


# ------------------------------------------------------------------------------------------ post-processing


def test_largest_component_keeps_only_the_biggest_blob_and_dilation_grows_it() -> None:
    from mmcsplat.plugins.segmenters.postprocess import PostProcess, dilate, largest_component

    _, regions = _scene()
    two_blobs = regions["red"] | regions["small"]
    np.testing.assert_array_equal(largest_component(two_blobs), regions["red"])
    assert not largest_component(np.zeros((H, W), bool)).any()
    np.testing.assert_array_equal(PostProcess(keep="all")(two_blobs), two_blobs)

    dot = np.zeros((9, 9), bool)
    dot[4, 4] = True
    grown = dilate(dot, 2)
    assert grown[4, 6] and grown[2, 4] and grown[5, 5]  # within 2 px
    assert not grown[6, 6] and not grown[4, 7]  # the corner of the 5×5 square and 3 px away stay out
    both = PostProcess(dilation=1)(two_blobs)
    assert not both[regions["small"]].any() and both[3, 4] and both[4, 3] and not both[3, 3]
    with pytest.raises(ValueError, match="dilation"):
        PostProcess(dilation=-1)


def test_central_component_keeps_what_the_rig_aims_at_not_a_larger_bystander() -> None:
    from mmcsplat.plugins.segmenters.postprocess import PostProcess, central_component

    mask = np.zeros((40, 60), bool)
    mask[15:25, 25:33] = True  # the subject, where the rig's centre projects (30, 20)
    mask[0:40, 0:12] = True  # a bystander's leg at the edge of the view, larger
    centre = np.array([30.0, 20.0])
    np.testing.assert_array_equal(central_component(mask, centre), mask & (np.arange(60) >= 25))
    np.testing.assert_array_equal(central_component(mask, np.array([-5.0, 0.0])), mask & (np.arange(60) < 12))  # nearest, not inside
    np.testing.assert_array_equal(PostProcess()(mask, centre), mask & (np.arange(60) >= 25))
    np.testing.assert_array_equal(PostProcess(keep="largest")(mask, centre), mask & (np.arange(60) < 12))
    np.testing.assert_array_equal(PostProcess()(mask), mask & (np.arange(60) < 12))  # no centre given: the largest
    with pytest.raises(ValueError, match="keep"):
        PostProcess(keep="biggest")


def test_pieces_a_pixel_or_two_apart_are_one_component() -> None:
    """A hand cut off the body by a background gap of up to 2 × ``bridge`` pixels stays; a farther blob goes."""
    from mmcsplat.plugins.segmenters.postprocess import PostProcess, largest_component

    mask = np.zeros((12, 30), bool)
    mask[2:10, 2:12] = True  # the body
    mask[4:6, 14:17] = True  # a hand 2 background pixels away (columns 12 and 13)
    mask[4:6, 22:24] = True  # a blob 5 pixels from the hand
    kept = largest_component(mask, bridge=1)
    np.testing.assert_array_equal(kept, mask & (np.arange(30) < 20))  # body and hand, only their own pixels
    np.testing.assert_array_equal(largest_component(mask, bridge=0), mask & (np.arange(30) < 12))
    np.testing.assert_array_equal(PostProcess()(mask), kept)  # the default bridges 2 px
    np.testing.assert_array_equal(PostProcess(bridge=0)(mask), mask & (np.arange(30) < 12))



def test_large_components_keep_a_split_body_without_the_specks_beside_it() -> None:
    """Legs and an upper body split at the belt both stay; a speck under ``share`` of the largest piece goes."""
    from mmcsplat.plugins.segmenters.postprocess import PostProcess, large_components

    mask = np.zeros((40, 40), bool)
    mask[2:18, 10:20] = True  # upper body, 160 px
    mask[22:38, 10:16] = True  # legs, 96 px, 4 background rows below
    mask[30:32, 30:32] = True  # a speck of 4 px on the floor's edge
    body, upper = mask.copy(), mask.copy()
    body[30:32, 30:32] = False
    upper[18:] = False
    np.testing.assert_array_equal(large_components(mask, 0.05), body)
    np.testing.assert_array_equal(large_components(mask, 0.0), mask)
    np.testing.assert_array_equal(large_components(mask, 0.7), upper)  # the legs are 0.6 of the upper body
    np.testing.assert_array_equal(large_components(np.zeros((5, 5), bool), 0.05), np.zeros((5, 5), bool))
    np.testing.assert_array_equal(PostProcess(keep="all", min_piece=0.05)(mask), body)  # the clean-up every segmenter shares
    np.testing.assert_array_equal(PostProcess(keep="all")(mask), mask)


# -------------------------------------------------------------------------------------------- onnx-semantic


def test_onnx_semantic_maps_remaps_and_keeps_the_largest_component(tmp_path: Path) -> None:
    model = _model(tmp_path)
    rgb, regions = _scene()
    session = SessionReader(_session(tmp_path / "s.zarr", {"a": [rgb, rgb, rgb]}))

    results = list(_segmenter("onnx-semantic", model=str(model), batch_size=2).segment(session, "a"))
    assert [t for t, _, _ in results] == [0, 1, 2]
    _, mask, labels = results[0]
    assert labels.dtype == np.uint16 and labels.shape == (H, W)
    np.testing.assert_array_equal(labels == 1, regions["red"] | regions["blue"] | regions["small"])  # toy → person
    np.testing.assert_array_equal(labels == 0, ~(regions["red"] | regions["blue"] | regions["small"]))
    np.testing.assert_array_equal(mask, regions["red"] | regions["blue"])  # the small blob is dropped

    _, plain, plain_labels = next(iter(_segmenter("onnx-semantic", model=str(model), remap={}).segment(session, "a")))
    np.testing.assert_array_equal(plain_labels == 2, regions["blue"])
    np.testing.assert_array_equal(plain, regions["red"])

    _, everything, _ = next(iter(_segmenter("onnx-semantic", model=str(model), keep="all").segment(session, "a")))
    np.testing.assert_array_equal(everything, regions["red"] | regions["blue"] | regions["small"])


def test_onnx_semantic_honours_channel_order_a_fixed_batch_and_class_id_outputs(tmp_path: Path) -> None:
    model = _model(tmp_path, batch=2, argmax=True, channel_order="BGR")
    rgb, regions = _scene()
    session = SessionReader(_session(tmp_path / "s.zarr", {"a": [rgb] * 3}))
    segmenter = _segmenter("onnx-semantic", model=str(model), remap={})
    assert segmenter.frames_per_call == 2
    results = list(segmenter.segment(session, "a"))  # 3 frames: the last batch is padded
    assert len(results) == 3
    for _, mask, labels in results:  # read as BGR, the red blocks look blue (toy) and the blue one red
        np.testing.assert_array_equal(labels == 2, regions["red"] | regions["small"])
        np.testing.assert_array_equal(mask, regions["blue"])


@pytest.mark.parametrize(
    ("sidecar", "params", "message"),
    [
        ("{not json", {}, "invalid JSON"),
        ('{"input_size": [16, 12]}', {}, "'labels'"),
        ('{"labels": ["a", "person"], "std": [0, 1, 1]}', {}, "std"),
        ('{"labels": ["a", "person"], "colour": "RGB"}', {}, "unknown keys"),
        ('{"labels": ["a", "b"]}', {}, "subject label 'person'"),
        ('{"labels": ["a", "person"]}', {"remap": {"toy": "person"}}, "no class of the sidecar is called 'toy'"),
    ],
)
def test_onnx_semantic_rejects_a_bad_sidecar(tmp_path: Path, sidecar: str, params: dict, message: str) -> None:
    model = _model(tmp_path)
    model.with_suffix(".json").write_text(sidecar)
    with pytest.raises(ValueError, match=message) as error:
        _segmenter("onnx-semantic", model=str(model), **params)
    assert "tiny.json" in str(error.value) or "sidecar" in str(error.value)


def test_onnx_semantic_names_a_missing_model_or_sidecar(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nowhere.onnx"):
        _segmenter("onnx-semantic", model=str(tmp_path / "nowhere.onnx"))
    model = _model(tmp_path)
    with pytest.raises(FileNotFoundError, match="other.json"):
        _segmenter("onnx-semantic", model=str(model), sidecar=str(tmp_path / "other.json"))



def test_onnx_semantic_fetches_a_model_by_url_once_and_checks_its_checksum(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import hashlib

    from local_server import serve

    monkeypatch.setenv("MMCSPLAT_CACHE", str(tmp_path / "cache"))
    model = _model(tmp_path)
    digest = hashlib.sha256(model.read_bytes()).hexdigest()
    rgb, regions = _scene()
    session = SessionReader(_session(tmp_path / "s.zarr", {"a": [rgb]}))
    sidecar = str(model.with_suffix(".json"))
    with serve({"/tiny.onnx": model.read_bytes()}) as (base, requested):
        for _ in range(2):  # the second segmenter reads the cached copy
            segmenter = _segmenter("onnx-semantic", model=f"{base}/tiny.onnx", sha256=digest, sidecar=sidecar)
            assert segmenter.path == tmp_path / "cache" / "downloads" / digest / "tiny.onnx"
            _, mask, _ = next(iter(segmenter.segment(session, "a")))
            np.testing.assert_array_equal(mask, regions["red"] | regions["blue"])
        assert requested == ["/tiny.onnx"]
        with pytest.raises(ValueError, match="is a URL: give its sha256"):
            _segmenter("onnx-semantic", model=f"{base}/tiny.onnx", sidecar=sidecar)
        with pytest.raises(ValueError, match="is a URL: give sidecar"):
            _segmenter("onnx-semantic", model=f"{base}/tiny.onnx", sha256=digest)
    with pytest.raises(ValueError, match=r"tiny\.onnx: SHA-256 .* is not the expected"):  # a local model is checked too
        _segmenter("onnx-semantic", model=str(model), sha256=hashlib.sha256(b"another model").hexdigest())

# ---------------------------------------------------------------------------------------------- background


def _blob_frames(positions: list[int | None]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """A static textured background (with camera noise) and a bright square at each x position (none for
    ``None``), and the square's true masks."""
    import cv2

    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (48, 64, 3)).astype(np.float32), (0, 0), 1.5)
    images, truths = [], []
    for x in positions:
        image = texture + rng.normal(0, 2, texture.shape)
        truth = np.zeros((48, 64), bool)
        if x is not None:
            truth[16:30, x : x + 12] = True
        image[truth] = (250, 40, 200)
        images.append(np.clip(image, 0, 255).astype(np.uint8))
        truths.append(truth)
    return images, truths


@pytest.mark.parametrize("method", ["mog2", "knn", "median"])
def test_background_subtraction_finds_a_moving_blob(tmp_path: Path, method: str) -> None:
    images, truths = _blob_frames([2 + 2 * t for t in range(24)])  # each pixel is covered in ≤ 6 of 24 frames
    session = SessionReader(_session(tmp_path / "s.zarr", {"a": images}))
    results = list(_segmenter("background", method=method).segment(session, "a"))
    assert [t for t, _, _ in results] == list(range(len(images)))
    ious = [(mask & truth).sum() / (mask | truth).sum() for (_, mask, _), truth in zip(results, truths, strict=True)]
    assert min(ious) > 0.8 and np.mean(ious) > 0.9, (method, np.round(ious, 2))  # the opening rounds corners
    assert all(labels is None for _, _, labels in results)


@pytest.mark.parametrize("method", ["mog2", "knn", "median"])
def test_background_learnt_from_empty_frames_finds_a_still_subject(tmp_path: Path, method: str) -> None:
    images, truths = _blob_frames([None] * 4 + [20] * 8)  # the subject lies still in 8 of 12 frames
    session = SessionReader(_session(tmp_path / "s.zarr", {"a": images}))
    learnt = [mask for _, mask, _ in _segmenter("background", method=method, learn_frames=[0, 4]).segment(session, "a")]
    assert not any(mask.any() for mask in learnt[:4])
    for mask in learnt[4:]:
        assert (mask & truths[-1]).sum() / (mask | truths[-1]).sum() > 0.8
    unaided = [mask for _, mask, _ in _segmenter("background", method=method).segment(session, "a")]
    assert sum(mask.sum() for mask in unaided[4:]) < 0.1 * sum(mask.sum() for mask in learnt[4:])


def test_background_subtraction_needs_a_sequence(tmp_path: Path) -> None:
    images, _ = _blob_frames([2])
    session = SessionReader(_session(tmp_path / "s.zarr", {"a": images}))
    with pytest.raises(ValueError, match="camera 'a' has 1 frame"):
        list(_segmenter("background").segment(session, "a"))
    with pytest.raises(ValueError, match="method"):
        _segmenter("background", method="optical-flow")


@pytest.mark.parametrize("params, message", [
    ({"threshold": -5}, "threshold must be a finite number > 0, got -5"),
    ({"threshold": float("nan")}, "threshold must be a finite number > 0, got nan"),
    ({"background_ratio": 0}, "background_ratio must be > 0"),
    ({"learn_frames": [5, 2]}, r"learn_frames must be \[start, stop\) frame indices"),
    ({"learn_frames": [1, 2, 3]}, "parameter 'learn_frames' must be a list of 2 values or none"),
    ({"history": 0}, "history must be ≥ 1, got 0"),
    ({"samples": 1}, "samples must be ≥ 2, got 1"),
    ({"open_radius": -1}, "open_radius must be ≥ 0, got -1"),
    ({"dilation": -2}, "dilation must be ≥ 0, got -2"),
    ({"threshold": "high"}, "parameter 'threshold' must be a number or none, got 'high'"),
    ({"treshold": 3}, "unknown parameter.*treshold"),
])
def test_background_refuses_settings_that_would_empty_the_masks(params, message) -> None:
    with pytest.raises(InputError, match=f"segmenter 'background': {message}"):
        _segmenter("background", **params)


def test_background_parameters_keep_their_defaults_and_effective_threshold() -> None:
    segmenter = _segmenter("background")
    assert (segmenter.method, segmenter.threshold, segmenter.cutoff) == ("mog2", None, 16.0)
    assert (segmenter.keep, segmenter.dilation, segmenter.bridge, segmenter.edge_share) == ("central", 0, 1, 0.4)
    assert _segmenter("background", method="median").cutoff == 30.0
    assert _segmenter("background", method="knn", threshold=250).cutoff == 250.0
    assert _segmenter("background", learn_frames=[0, 4]).learn_frames == (0, 4)


# --------------------------------------------------------------------------------------------- precomputed


def test_precomputed_uses_the_session_masks(tmp_path: Path) -> None:
    rgb, regions = _scene()
    two_blobs = regions["red"] | regions["small"]
    session = SessionReader(_session(tmp_path / "s.zarr", {"a": [rgb, rgb], "b": [rgb, rgb]}, {"a": [two_blobs, two_blobs]}))
    results = list(_segmenter("precomputed").segment(session, "a"))
    assert len(results) == 2
    for _, mask, labels in results:
        np.testing.assert_array_equal(mask, regions["red"])
        assert labels is None
    with pytest.raises(ValueError, match=r"s\.zarr: camera 'b' has no masks"):
        list(_segmenter("precomputed").segment(session, "b"))


def test_segmenting_again_starts_from_the_ingested_masks(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import rig_fixtures as rig

    from mmcsplat.plugins.segmenters.postprocess import dilate, largest_component

    source, path = tmp_path / "capture", tmp_path / "s.zarr"
    cameras = rig.make_capture(source, frames=4)
    truth = zarr.open_group(str(source / "ground_truth.zarr"), mode="w")
    for camera in cameras:  # a body and a separate speck: the largest component drops the speck
        masks = np.zeros((4, camera.height, camera.width), np.uint8)
        masks[:, 20:60, 30:90] = 1
        masks[:, 70:80, 100:110] = 1
        truth.create_array(f"masks/{camera.name}", data=masks)
    assert main(["ingest", str(source), str(path)]) == 0
    shipped = {(c.name, t): SessionReader(path).frame(t, c.name).mask for c in cameras for t in range(4)}

    def segment(*argv: str) -> dict[tuple[str, int], np.ndarray]:
        assert main(["segment", str(path), "--segmenter", *argv]) == 0, capsys.readouterr().err
        session = SessionReader(path)
        return {key: session.frame(key[1], key[0]).mask for key in shipped}

    once = segment("precomputed", "--set", "dilation=2")
    for key, mask in shipped.items():
        np.testing.assert_array_equal(once[key], dilate(largest_component(mask, 1), 2))
    twice = segment("precomputed", "--set", "dilation=2")
    for key in shipped:
        np.testing.assert_array_equal(twice[key], once[key])  # not dilated by 4
    segment("background")
    restored = segment("precomputed", "--set", "keep=all")
    for key, mask in shipped.items():
        np.testing.assert_array_equal(restored[key], mask)  # the speck the first passes dropped is back


# ------------------------------------------------------------------------------------------ mmcsplat segment


def test_segment_command_writes_masks_and_labels(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from mmcsplat.plugins.segmenters.postprocess import dilate

    model = _model(tmp_path)
    rgb, regions = _scene()
    path = _session(tmp_path / "s.zarr", {"a": [rgb] * 3, "b": [rgb] * 3, "c": [rgb] * 3}, {"a": [regions["small"]] * 3})
    status = main(["segment", str(path), "--segmenter", "onnx-semantic", "--set", f"model={model}", "--set", "dilation=0", "--cameras", "a,b"])
    assert status == 0, capsys.readouterr().err
    assert "a: 3 frames" in capsys.readouterr().out
    session = SessionReader(path)
    assert session.has("mask", "a") and session.has("labels", "b") and not session.has("mask", "c")
    for t in range(3):
        np.testing.assert_array_equal(session.frame(t, "b").mask, regions["red"] | regions["blue"])
        np.testing.assert_array_equal(session.frame(t, "a").labels == 1, regions["red"] | regions["blue"] | regions["small"])

    # Re-segmenting replaces the fields: precomputed brings back the masks the session came with and keeps
    # the labels it does not produce; the onnx masks are gone, the shipped ones kept.
    assert main(["segment", str(path), "--segmenter", "precomputed", "--set", "dilation=1", "--cameras", "a"]) == 0
    session = SessionReader(path)
    np.testing.assert_array_equal(session.frame(0, "a").mask, dilate(regions["small"], 1))
    assert session.has("labels", "a")
    assert sorted(name.split(".")[0] for name in _arrays(path, "a")) == ["labels", "mask", "mask", "present", "rgb"]


def test_segment_command_refuses_bad_inputs_and_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rgb, regions = _scene()
    two_blobs = regions["red"] | regions["small"]
    path = _session(tmp_path / "s.zarr", {"a": [rgb] * 2, "b": [rgb] * 2}, {"a": [two_blobs] * 2})
    before = {camera: _arrays(path, camera) for camera in ("a", "b")}

    def refused(*argv: str, message: str) -> None:
        assert main(["segment", str(path), *argv]) == 2
        assert message in capsys.readouterr().err
        assert {camera: _arrays(path, camera) for camera in ("a", "b")} == before
        np.testing.assert_array_equal(SessionReader(path).frame(1, "a").mask, two_blobs)  # untouched

    refused("--segmenter", "grabcut", message="unknown segmenter 'grabcut'")
    refused("--segmenter", "onnx-semantic", "--set", f"model={tmp_path / 'missing.onnx'}", message="missing.onnx")
    refused("--segmenter", "precomputed", "--cameras", "z", message="unknown camera 'z'")
    # Camera a is segmented first, then b fails: the update is abandoned as a whole.
    refused("--segmenter", "precomputed", message="camera 'b' has no masks")
    # The model outputs 3 classes but the sidecar names 2: found at the first batch, mid-update.
    model = _model(tmp_path, labels=["background", "person"])
    refused("--segmenter", "onnx-semantic", "--set", f"model={model}", message="outputs 3 classes but its sidecar names 2")

    zarr.open_group(str(path), mode="r+").attrs["complete"] = False
    assert main(["segment", str(path), "--segmenter", "precomputed"]) == 2
    assert "never completed" in capsys.readouterr().err
