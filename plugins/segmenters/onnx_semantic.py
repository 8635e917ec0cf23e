"""``onnx-semantic``: any ONNX semantic-segmentation model, run with onnxruntime on the CPU.

The model is a local file, or an http(s) URL with its SHA-256: fetched once into the download cache
(:mod:`mmcsplat.storage.downloads`), verified, and read from there offline afterwards. It comes with a sidecar JSON file (format in docs/plugins.md, "Segmenters") giving its input
size, normalization, channel order and the label name of each class id. Per-pixel class ids are the
argmax over the class axis, resized back to the image with nearest-neighbour, then remapped by a table
of label names (the reference study counted ADE20K's ``toy``/``plaything`` as ``person``: infants lie
among toys and hold them). The subject mask is every pixel whose remapped label is the subject label.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping, Sequence
from itertools import islice
from pathlib import Path
from typing import Any

import attrs
import cv2
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.parameters import at_least, parameter
from mmcsplat.plugins.segmenters.postprocess import PostProcessedSegmenter, present_frames
from mmcsplat.storage.downloads import fetch_cached, is_url, verify
from mmcsplat.storage.session import SessionReader

#: The reference study's table: toys and playthings count as the person (the infant holding them).
DEFAULT_REMAP = {"toy": "person", "plaything": "person"}
_INPUT_DTYPES = {"tensor(float)": np.float32, "tensor(float16)": np.float16, "tensor(double)": np.float64}


def _synonyms(label: str) -> set[str]:
    """The names a sidecar label answers to: itself and each ';'- or ','-separated part (ADE20K lists
    synonyms this way: "person;individual;someone", "plaything, toy")."""
    parts = label.replace(";", ",").split(",")
    return {label.strip().lower()} | {part.strip().lower() for part in parts if part.strip()}


def _check_pair(name: str, minimum: float = 0.0):
    def check(instance: object, attribute: attrs.Attribute, value: tuple) -> None:
        if len(value) != 3 or not all(np.isfinite(value)) or (name == "std" and min(value) <= minimum):
            raise InputError(f"sidecar {name} must be 3 finite numbers{' > 0' if name == 'std' else ''}, got {list(value)}")

    return check


@attrs.frozen
class Sidecar:
    """What the model needs besides its weights. ``input_size`` is (width, height) or ``None`` for the
    model's own static size (or the image size when the model takes any size); ``mean`` and ``std`` are
    per channel in [0, 1] units, applied as (pixel / 255 − mean) / std after ordering channels as
    ``channel_order``; ``layout`` is the input tensor's; ``labels[i]`` names class id ``i``."""

    labels: tuple[str, ...] = attrs.field(converter=tuple)
    input_size: tuple[int, int] | None = attrs.field(default=None, converter=attrs.converters.optional(tuple))
    mean: tuple[float, float, float] = attrs.field(default=(0.0, 0.0, 0.0), converter=tuple, validator=_check_pair("mean"))
    std: tuple[float, float, float] = attrs.field(default=(1.0, 1.0, 1.0), converter=tuple, validator=_check_pair("std"))
    channel_order: str = attrs.field(default="RGB", validator=attrs.validators.in_(("RGB", "BGR")))
    layout: str = attrs.field(default="NCHW", validator=attrs.validators.in_(("NCHW", "NHWC")))
    input: str | None = None
    output: str | None = None

    @labels.validator
    def _check_labels(self, attribute: attrs.Attribute, value: tuple) -> None:
        if not value or not all(isinstance(label, str) and label.strip() for label in value):
            raise InputError("sidecar labels must be a non-empty list of label names, one per class id")
        if len(value) > np.iinfo(np.uint16).max:
            raise InputError(f"sidecar has {len(value)} labels; session labels are uint16")

    @input_size.validator
    def _check_size(self, attribute: attrs.Attribute, value: tuple | None) -> None:
        if value is not None and (len(value) != 2 or not all(isinstance(v, int) and v > 0 for v in value)):
            raise InputError(f"sidecar input_size must be [width, height] in pixels, got {list(value)}")

    @classmethod
    def load(cls, path: Path) -> Sidecar:
        """Read and validate a sidecar file; errors name it."""
        if not path.is_file():
            raise MissingFileError(f"segmentation sidecar {path} does not exist")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise InputError(f"segmentation sidecar {path}: invalid JSON: {error}") from error
        if not isinstance(data, dict):
            raise InputError(f"segmentation sidecar {path}: expected a JSON object")
        unknown = sorted(set(data) - {field.name for field in attrs.fields(cls)})
        if unknown:
            raise InputError(f"segmentation sidecar {path}: unknown keys {unknown}")
        if "labels" not in data:
            raise InputError(f"segmentation sidecar {path}: 'labels' (one name per class id) is required")
        try:
            return cls(**data)
        except (TypeError, ValueError) as error:
            raise InputError(f"segmentation sidecar {path}: {error}") from error

    def ids_of(self, name: str) -> list[int]:
        """The class ids whose label is ``name`` or lists it as a synonym (case-insensitive)."""
        key = name.strip().lower()
        return [index for index, label in enumerate(self.labels) if key in _synonyms(label)]


def label_table(sidecar: Sidecar, remap: Mapping[str, str], strict: bool) -> np.ndarray:
    """[num_classes] uint16: the label id each class id is stored as. ``remap`` maps label names to the
    name they count as; a target naming several classes is an error. Entries whose source or target the
    sidecar lacks are errors with ``strict`` and skipped without (so the default table fits any model)."""
    table = np.arange(len(sidecar.labels), dtype=np.uint16)
    for source, target in remap.items():
        sources, targets = sidecar.ids_of(source), sidecar.ids_of(target)
        if len(targets) > 1:
            raise InputError(f"remap {source!r} → {target!r}: {target!r} names {len(targets)} classes of the sidecar, not one")
        missing = [name for name, ids in ((source, sources), (target, targets)) if not ids]
        if missing and strict:
            raise InputError(f"remap {source!r} → {target!r}: no class of the sidecar is called {missing[0]!r}")
        if not missing:
            table[sources] = targets[0]
    return table


def _batches(items: Sequence[int], size: int) -> Iterator[list[int]]:
    iterator = iter(items)
    while batch := list(islice(iterator, size)):
        yield batch


def _internal() -> Any:
    """A field the constructor computes from the parameters (not a parameter; not compared or shown)."""
    return attrs.field(init=False, repr=False, eq=False)


@attrs.define
class OnnxSemanticSegmenter(PostProcessedSegmenter):
    """Semantic segmentation with an ONNX model on onnxruntime's CPUExecutionProvider (a model given by URL is
    fetched once into the cache). Labels are stored as the remapped class ids of the sidecar (docs/plugins.md)."""

    model: str = parameter(doc="the .onnx file (required): a local file, or an http(s) URL fetched once into the cache", kw_only=True)
    sha256: str | None = parameter(None, doc="the model file's SHA-256 (required with a URL; checked for a local file too)")
    sidecar: str | None = parameter(None, doc="its JSON description, a local file (none: the local model's path with suffix .json)")
    subject: str = parameter("person", doc="the label whose pixels form the mask")
    remap: Mapping[str, str] | None = parameter(None, doc="label → the label it counts as (none: DEFAULT_REMAP, entries the model lacks skipped)")
    batch_size: int = parameter(4, doc="frames per inference call (a model with a fixed batch uses its own)", validator=at_least(1))
    threads: int | None = parameter(None, doc="onnxruntime intra-op threads (none: onnxruntime's choice)", validator=at_least(1))

    path: Path = _internal()  # the model file, expanded
    description: Sidecar = _internal()  # the sidecar, loaded
    subject_id: int = _internal()  # the class id of ``subject``
    table: np.ndarray = _internal()  # [num_classes] uint16: the stored label of each class id
    session: Any = _internal()  # the onnxruntime.InferenceSession
    _input: Any = _internal()  # the model's input port (onnxruntime.NodeArg)
    _output: str = _internal()  # the name of the model's output used
    fixed_batch: int | None = _internal()  # the model's static batch size, if it has one
    frames_per_call: int = _internal()  # frames per inference call: fixed_batch, else batch_size

    def __attrs_post_init__(self) -> None:
        import onnxruntime

        path = self.path = self._model_file()
        self.description = Sidecar.load(Path(self.sidecar).expanduser() if self.sidecar else path.with_suffix(".json"))
        subjects = self.description.ids_of(self.subject)
        if len(subjects) != 1:
            raise InputError(f"subject label {self.subject!r} names {len(subjects)} classes of the sidecar of {path}, not one")
        self.subject_id = subjects[0]
        self.table = label_table(self.description, DEFAULT_REMAP if self.remap is None else self.remap, strict=self.remap is not None)
        options = onnxruntime.SessionOptions()
        if self.threads:
            options.intra_op_num_threads = int(self.threads)
        try:
            self.session = onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as error:  # onnxruntime raises its own exception types for unreadable models
            raise InputError(f"ONNX model {path} cannot be loaded: {error}") from error
        self._input = self._port(self.session.get_inputs(), self.description.input, "input")
        self._output = self._port(self.session.get_outputs(), self.description.output, "output").name
        if self._input.type not in _INPUT_DTYPES:
            raise InputError(f"ONNX model {path}: input {self._input.name!r} is {self._input.type}; floating-point inputs are supported")
        if len(self._input.shape) != 4:
            raise InputError(f"ONNX model {path}: input {self._input.name!r} has shape {self._input.shape}, expected 4 dimensions")
        batch = self._input.shape[0]
        self.fixed_batch = batch if isinstance(batch, int) else None
        self.frames_per_call = self.fixed_batch or self.batch_size

    def _model_file(self) -> Path:
        """The local model file: ``model`` itself, or its cached download; checked against ``sha256`` when given."""
        if is_url(self.model):
            if not self.sha256:
                raise InputError(f"ONNX model {self.model} is a URL: give its sha256 too (the checksum the download is verified against)")
            if not self.sidecar:
                raise InputError(f"ONNX model {self.model} is a URL: give sidecar = the local path of its JSON description")
            return fetch_cached(self.model, self.sha256)
        path = Path(self.model).expanduser()
        if not path.is_file():
            raise MissingFileError(f"ONNX model {path} does not exist: point 'model' at a local .onnx file, or at a URL with its sha256")
        if self.sha256:
            verify(path, self.sha256)
        return path

    def _port(self, ports: Sequence[Any], name: str | None, what: str) -> Any:
        """The model's input or output called ``name`` (its first one when ``name`` is None)."""
        if name is None:
            return ports[0]
        for port in ports:
            if port.name == name:
                return port
        raise InputError(f"ONNX model {self.path}: no {what} named {name!r}; it has {[port.name for port in ports]}")

    def _input_size(self, width: int, height: int) -> tuple[int, int]:
        """(width, height) fed to the model: the sidecar's, else the model's static size, else the image's."""
        if self.description.input_size is not None:
            return self.description.input_size
        h, w = self._input.shape[1:3] if self.description.layout == "NHWC" else self._input.shape[2:4]
        return (w, h) if isinstance(w, int) and isinstance(h, int) else (width, height)

    def _preprocess(self, rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """One image as the model's input, [C, h, w] or [h, w, C]."""
        shrinking = size[0] < rgb.shape[1] or size[1] < rgb.shape[0]
        image = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
        if self.description.channel_order == "BGR":
            image = image[..., ::-1]
        image = (image.astype(np.float32) / 255.0 - np.float32(self.description.mean)) / np.float32(self.description.std)
        return image.transpose(2, 0, 1) if self.description.layout == "NCHW" else image

    def class_ids(self, images: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Per-pixel class ids [H, W] (at each image's size) for a batch of same-sized RGB images."""
        height, width = images[0].shape[:2]
        size = self._input_size(width, height)
        batch = np.stack([self._preprocess(image, size) for image in images]).astype(_INPUT_DTYPES[self._input.type])
        if self.fixed_batch and len(batch) < self.fixed_batch:  # pad the last batch of a fixed-batch model
            batch = np.concatenate([batch, np.repeat(batch[-1:], self.fixed_batch - len(batch), axis=0)])
        (output,) = self.session.run([self._output], {self._input.name: batch})
        ids = self._ids(np.asarray(output))
        if ids.min() < 0 or ids.max() >= len(self.description.labels):
            raise InputError(f"ONNX model {self.path} produced class ids outside the {len(self.description.labels)} its sidecar names")
        ids = ids.astype(np.uint16)
        return [cv2.resize(ids[i], (width, height), interpolation=cv2.INTER_NEAREST) for i in range(len(images))]

    def _ids(self, output: np.ndarray) -> np.ndarray:
        """[N, h, w] class ids from the model's output: [N, C, h, w] scores, or [N, h, w] / [N, 1, h, w] ids."""
        if output.dtype.kind in "iu" and output.ndim == 3:
            return output
        if output.dtype.kind in "iu" and output.ndim == 4 and output.shape[1] == 1:
            return output[:, 0]
        if output.dtype.kind == "f" and output.ndim == 4:
            if output.shape[1] != len(self.description.labels):
                raise InputError(
                    f"ONNX model {self.path} outputs {output.shape[1]} classes but its sidecar names {len(self.description.labels)}"
                )
            return output.argmax(axis=1)
        raise InputError(
            f"ONNX model {self.path}: output {self._output!r} {output.dtype} {list(output.shape)} is neither "
            "[N, C, h, w] scores nor [N, h, w] or [N, 1, h, w] class ids"
        )

    def raw(self, session: SessionReader, camera: str) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
        for batch in _batches(present_frames(session, camera).tolist(), self.frames_per_call):
            for t, ids in zip(batch, self.class_ids([session.frame(t, camera).rgb for t in batch]), strict=True):
                labels = self.table[ids]
                yield t, labels == self.subject_id, labels
