"""Browser-playable video and PNG files, written atomically.

Every video output goes through :func:`write_video`: H.264 in yuv420p (what browsers decode in an HTML
``<video>``) through the ffmpeg binary shipped by imageio-ffmpeg, with the moov atom up front so playback
starts before the download ends. yuv420p subsamples chroma 2×2, so odd frame sizes are padded with black
to the next even size. The file appears under its name only once it is complete and probed.

The probe reads ffmpeg's own ``-i`` header, parsed here: imageio-ffmpeg ships no ffprobe, its header parser
is private, and its frame reader leaves ffmpeg's pipes to the garbage collector when ffmpeg exits first.
"""

from __future__ import annotations

import os
import re
import subprocess
from collections.abc import Iterable
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.atomic import atomic_path

CODEC = "h264"
PIX_FMT = "yuv420p"
CRF = 18  # visually lossless for rendered frames, still small


@attrs.frozen
class VideoInfo:
    """What ffmpeg reports of a video file; ``frames`` only when counted (a full decode)."""

    codec: str
    pix_fmt: str
    width: int
    height: int
    fps: float
    frames: int | None = None


def pad_even(frame: np.ndarray) -> np.ndarray:
    """``frame`` [H, W, 3] with a black row/column appended where H or W is odd."""
    height, width = frame.shape[:2]
    return np.pad(frame, ((0, height % 2), (0, width % 2), (0, 0)))


def probe_video(path: str | os.PathLike, count_frames: bool = False) -> VideoInfo:
    """Codec, pixel format, size and rate of the video at ``path`` (and its frame count on request)."""
    import imageio_ffmpeg

    # With no output named, ffmpeg prints the streams' header and exits.
    result = subprocess.run(
        [imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-nostdin", "-i", str(path)],
        capture_output=True, text=True, errors="replace", check=False,
    )
    info = parse_video_stream(result.stderr)
    if info is None:
        last = result.stderr.strip().splitlines()[-1:] or ["no output"]
        raise InputError(f"{path}: ffmpeg finds no video stream ({last[0]})")
    frames = imageio_ffmpeg.count_frames_and_secs(str(path))[0] if count_frames else None
    return attrs.evolve(info, frames=frames)


def parse_video_stream(header: str) -> VideoInfo | None:
    """The first video stream of ffmpeg's ``-i`` header, or None where it names none.

    A stream line reads e.g. ``Stream #0:0(eng): Video: h264 (High) (avc1 / 0x31637661),
    yuv420p(tv, bt709, progressive), 1080x1920 [SAR 1:1 DAR 9:16], 1851 kb/s, 60 fps, 60 tbr``:
    its fields are split on the commas outside parentheses.
    """
    line = next((line for line in header.splitlines() if re.search(r"Stream #\S+.*: Video: ", line)), None)
    if line is None:
        return None
    fields = [field.strip() for field in re.split(r",(?![^(]*\))", line.split(": Video: ", 1)[1])]
    size = next(filter(None, (re.match(r"(\d+)x(\d+)", field) for field in fields)), None)
    rate = re.search(r"([\d.]+)(k?) (?:fps|tbr)\b", line)
    if size is None or rate is None or len(fields) < 2:
        return None
    fps = float(rate.group(1)) * (1000 if rate.group(2) else 1)
    # The pixel format may carry its colour details, e.g. "yuv420p(progressive)": keep the format's name.
    return VideoInfo(fields[0].split()[0], fields[1].split("(")[0], int(size.group(1)), int(size.group(2)), fps)


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float) -> VideoInfo:
    """Encode ``frames`` (uint8 [H, W, 3] RGB, one size) as an H.264 yuv420p mp4 at ``path``, atomically;
    frames are streamed to the encoder, never held together. Returns the written file's :class:`VideoInfo`."""
    import imageio_ffmpeg

    path = Path(path)
    count, size = 0, None
    with atomic_path(path) as temporary:
        encoder = None
        try:
            for frame in frames:
                frame = np.asarray(frame)
                if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
                    raise InputError(f"{path}: frames must be uint8 [H, W, 3], got {frame.dtype} {list(frame.shape)} at frame {count}")
                if size is None:
                    size = frame.shape[:2]
                    even = pad_even(frame).shape
                    encoder = imageio_ffmpeg.write_frames(
                        str(temporary), (even[1], even[0]), fps=fps, codec="libx264", pix_fmt_out=PIX_FMT,
                        quality=None, macro_block_size=1,
                        output_params=["-crf", str(CRF), "-movflags", "+faststart", "-f", "mp4"],
                    )
                    encoder.send(None)
                elif frame.shape[:2] != size:
                    raise InputError(f"{path}: frame {count} is {frame.shape[1]}×{frame.shape[0]}, the first was {size[1]}×{size[0]}")
                encoder.send(np.ascontiguousarray(pad_even(frame)))
                count += 1
        finally:
            if encoder is not None:
                encoder.close()
        if count == 0:
            raise InputError(f"{path}: no frames to write")
        info = probe_video(temporary)
        if (info.codec, info.pix_fmt) != (CODEC, PIX_FMT):
            raise RuntimeError(f"{path}: ffmpeg wrote {info.codec}/{info.pix_fmt}, not {CODEC}/{PIX_FMT}")
    return attrs.evolve(info, frames=count)


def encode_png(image: np.ndarray) -> bytes:
    """A uint8 [H, W, 3] RGB image as PNG bytes."""
    import cv2

    ok, encoded = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))
    if not ok:
        raise RuntimeError(f"PNG encoding of a {list(image.shape)} {image.dtype} image failed")
    return encoded.tobytes()


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write a uint8 [H, W, 3] RGB image as a PNG at ``path``, atomically."""
    payload = encode_png(image)
    with atomic_path(path) as temporary:
        temporary.write_bytes(payload)
