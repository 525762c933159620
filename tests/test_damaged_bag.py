"""A damaged bag costs only its damaged frames: drive 0009 frames 0-15 as kitti2mcap writes it,
4 KiB flipped at half its length (inside one zstd chunk). The frames whose image or scan lay in
that chunk get a ``frame_error`` naming the file, the chunk and its log-time range; every other
pair gives the whole bag's rows exactly; the run's record says how many frames were lost."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader

from experiments.configs.structured import frame_range_from_config, settings_from_config
from experiments.store.records import lost_frames
from experiments.summary.references import recording_boxes, sequence_reference
from tests.ros2_bags import IMAGE, LIDAR, bag_config, make_bag
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting
from ttc.steps.tracks import TRACK_ID

pytest.importorskip("kitti2mcap", reason="installed by .ci/run (--no-deps)")

FLIPPED = 4096  # bytes


def _damaged_chunk(bag: Path) -> tuple[int, object, dict[str, list[int]]]:
    """(number, index) of the chunk holding the bag's middle byte, and the log times of each
    topic's messages (log-time order) of the whole bag."""
    with bag.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        times: dict[str, list[int]] = {IMAGE: [], LIDAR: []}
        for _, channel, message in reader.iter_messages(topics=[IMAGE, LIDAR]):
            times[channel.topic].append(message.log_time)
    middle = bag.stat().st_size // 2
    for k, chunk in enumerate(summary.chunk_indexes):
        if chunk.chunk_start_offset <= middle < chunk.chunk_start_offset + chunk.chunk_length:
            return k, chunk, {t: sorted(v) for t, v in times.items()}
    raise AssertionError("the middle byte is in no chunk")


@pytest.mark.slow
def test_a_damaged_chunk_costs_only_its_frames(tmp_path: Path) -> None:
    bag = make_bag(tmp_path / "0009.mcap")
    number, chunk, times = _damaged_chunk(bag)
    assert chunk.compression == "zstd"
    data = bytearray(bag.read_bytes())
    middle = len(data) // 2
    assert middle + FLIPPED <= chunk.chunk_start_offset + chunk.chunk_length  # one chunk hit
    data[middle : middle + FLIPPED] = bytes(b ^ 0xFF for b in data[middle : middle + FLIPPED])
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))

    def in_chunk(log: int) -> bool:
        return chunk.message_start_time <= log <= chunk.message_end_time

    # the frames whose image, or whose scan (the n-th scan pairs with the n-th image here),
    # was logged in the damaged chunk
    hit = {i for i, t in enumerate(times[IMAGE]) if in_chunk(t)}
    hit |= {i for i, t in enumerate(times[LIDAR]) if in_chunk(t)}
    assert 1 <= len(hit) <= 3 and max(hit) < 15

    cfg, whole_cfg = bag_config(damaged, "dataset.last=15"), bag_config(bag, "dataset.last=15")
    rows = run_setting(settings_from_config(cfg), frame_range_from_config(cfg), StageCache(None))
    whole = run_setting(
        settings_from_config(whole_cfg), frame_range_from_config(whole_cfg), StageCache(None)
    )
    broken = rows["error"] != ""
    pairs = set(zip(rows.loc[broken, "prev_frame"], rows.loc[broken, "frame"], strict=True))
    assert pairs == {(f - 1, f) for f in hit if f > 0} | {(f, f + 1) for f in hit}
    for text in rows.loc[broken, "error"].unique():
        assert str(damaged) in text and f"chunk {number} of the file" in text, text
        assert f"{chunk.message_start_time / 1e9:.3f}-{chunk.message_end_time / 1e9:.3f} s" in text
    assert lost_frames(rows) == sorted(hit)
    # every other pair: the whole bag's rows, column for column; but the columns made over a
    # whole run: a track is a chain of box matches through consecutive pairs, which a lost
    # frame ends (the boxes after it start new tracks), and the fused TTC filters over time
    over_run = [c for c in rows if c == TRACK_ID or "fused" in c]
    assert over_run
    timing = over_run + [c for c in rows if c.startswith(("ms_", "cached_", "time_"))]
    ok = rows[~broken].drop(columns=timing).reset_index(drop=True)
    keep = ~whole["frame"].isin(rows.loc[broken, "frame"])
    expected = whole[keep].drop(columns=timing).reset_index(drop=True)
    assert len(ok) == len(expected) > 0
    pd.testing.assert_frame_equal(ok, expected)
    assert np.isfinite(ok["object_distance_m"]).any()
    # the references over the damaged bag: the lost frames are gaps, the others are read
    source, cache = frame_range_from_config(cfg).sequence_dir, StageCache(tmp_path / "cache")
    lead = sequence_reference(source, cache)
    assert list(lead["frame"]) == list(range(16))
    boxes, times, _ = recording_boxes(source, settings_from_config(cfg), cache)
    assert set(boxes["frame"]) == set(range(16)) - hit and len(times) == 16
