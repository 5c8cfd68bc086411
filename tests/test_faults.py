"""Faults while a command runs, with real processes and real signals (#39): a variable-frame-rate
video, shards truncated or rewritten under a running loader, a frozen or killed rank, a flipped
checkpoint bit, signals early in a command and at its workers, a large `.ply` in `seeu view`.

Each case expects the one line `seeu CMD: error: ...` (or `interrupted`) with its exit status and
nothing complete-looking left behind.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from seeu_data.errors import SeeUError
from seeu_data.ingest.video import discover_sources, iter_frames

# ------------------------------------------------------------------------------------------ VFR video


def _vfr_mkv(path: Path, n: int, size=(48, 64)) -> list[int]:
    """A variable-frame-rate Matroska clip made with the encoder on this machine (OpenCV's JPEG
    encoder, FFmpeg's muxer through cv2.VideoWriter in raw mode, each packet given its own
    presentation time): runs of 1/30 s steps broken by 1/10 s gaps, as a phone records when it
    drops frames. Frame k is a flat grey of level 4k (identifiable after decoding). Returns the
    presentation times in milliseconds."""
    h, w = size
    writer = cv2.VideoWriter(
        str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (w, h), [cv2.VIDEOWRITER_PROP_RAW_VIDEO, 1]
    )
    assert writer.isOpened()
    ticks, times = 0, []
    for k in range(n):
        writer.set(cv2.VIDEOWRITER_PROP_PTS, ticks)  # in 1/30 s
        times.append(round(ticks * 1000 / 30))
        writer.write(cv2.imencode(".jpg", np.full((h, w, 3), 4 * k, np.uint8))[1].reshape(1, -1))
        ticks += 3 if k % 3 == 2 else 1
    writer.release()
    return times


def test_vfr_video_decodes_every_frame_at_its_container_time(tmp_path):
    """All frames of a VFR .mkv come out (the container's frame count, duration x nominal rate, says
    more), each stamped with its presentation time; a cut copy is still refused as truncated."""
    clip = tmp_path / "vfr.mkv"
    times = _vfr_mkv(clip, 40)
    cap = cv2.VideoCapture(str(clip))
    declared = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    assert declared > len(times) + 10  # the estimate the old decoder took for the truth
    counted: list[int] = []
    frames = list(iter_frames(discover_sources([clip])[0], stride=2, counted=counted))
    assert counted == [40] and [f.source_frame for f in frames] == list(range(0, 40, 2))
    assert [f.timestamp_us // 1000 for f in frames] == times[::2]  # Matroska keeps milliseconds
    assert [int(round(f.rgb.mean() / 4)) for f in frames] == list(range(0, 40, 2))

    data = clip.read_bytes()
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(data[: len(data) * 6 // 10])
    with pytest.raises(SeeUError, match=r"cut\.mkv: decoding stopped after \d+ frames .*\(truncated"):
        list(iter_frames(discover_sources([cut])[0]))
