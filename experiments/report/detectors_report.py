"""Every object judged per object detector: a recording whose runs used several detectors
(``+experiment=recordings``: YOLOv3-tiny on the whole frame, SSD-MobileNetV2 on tiles) gets one
every-object report per detector, each against a reference made of that detector's own boxes
(:func:`experiments.report.drives_report.by_detector`), and ``objects_detectors.md`` / ``.csv``:
Kendall's τ between the detectors' rankings per difficulty level and each one's best settings.

The detector most runs use writes into the recording's folder (``objects.md``,
``objects_ranking.csv``, ...), every other one into ``objects_<detector>/`` beside it."""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd

from experiments.report.drives_report import by_detector
from experiments.report.encode import markdown_table, write_csv, write_text
from experiments.report.load import Context, SweepData
from experiments.report.objects_report import BEST, levels_tau, recording_objects_report
from ttc.evaluation.verdict import level_rows, supported_level


def detector_folder(out: Path, detector: str, first: bool) -> Path:
    """Where a detector's every-object report goes: ``out`` for the first (most runs),
    ``out/objects_<detector>`` (safe characters only) for the others."""
    return out if first else out / ("objects_" + re.sub(r"[^A-Za-z0-9_.+-]+", "_", detector))


def objects_by_detector(data: SweepData, ctx: Context, out: Path) -> dict[str, pd.DataFrame]:
    """The every-object report of each detector of ``data`` (one recording; see the module
    docstring for the folders) and, with several, ``objects_detectors.md`` / ``.csv`` in
    ``out``; returns each detector's every-object ranking (rows per level) by detector name,
    the first the one most runs use."""
    rankings = {}
    for i, (detector, part) in enumerate(by_detector(data).items()):
        ranking = recording_objects_report(part, ctx, detector_folder(out, detector, i == 0))
        if ranking is not None:
            rankings[detector] = ranking
    if len(rankings) > 1:
        cross_detector_objects(rankings, out)
    return rankings


def cross_detector_objects(rankings: dict[str, pd.DataFrame], out: Path) -> Path:
    """``objects_detectors.csv`` (Kendall's τ between every two detectors' every-object
    rankings per level, over the settings both judged) and ``objects_detectors.md`` (that
    table, each detector's level it stands behind and best settings per level)."""
    tau = levels_tau(rankings).rename(
        columns={"recording_a": "detector_a", "recording_b": "detector_b"}
    )
    write_csv(tau, out / "objects_detectors.csv")
    lines = [
        "# Every object: the rankings of each object detector",
        "",
        "Each detector's runs are judged against a reference made of its own boxes (a far car "
        "one detector misses is not judged in its runs). Kendall's τ between two detectors' "
        "rankings of the same level, over the settings both judged (score: mean capped "
        "relative camera TTC error, an invalid estimate 1):",
        "",
        markdown_table(tau),
        "",
    ]
    for detector, ranking in rankings.items():
        level = supported_level(ranking)
        folder = detector_folder(Path("."), detector, detector == next(iter(rankings)))
        lines += [f"## `{detector}` ({(folder / 'objects.md').as_posix()})", ""]
        lines += [f"Level the report stands behind: `{level}`.", ""]
        best = pd.DataFrame({lv: _padded(level_rows(ranking, lv)) for lv in _levels(ranking)})
        lines += [f"Best {BEST} per level:", "", markdown_table(best), ""]
    return write_text("\n".join(lines), out / "objects_detectors.md")


def _levels(ranking: pd.DataFrame) -> list[str]:
    """The levels a ranking holds, in its own order (``all`` alone without levels)."""
    return list(dict.fromkeys(ranking["difficulty"])) if "difficulty" in ranking else ["all"]


def _padded(rows: pd.DataFrame) -> list[str]:
    """The best :data:`BEST` settings of one level's rows, padded with blanks."""
    names = rows.sort_values("rank", kind="stable")["setting"].head(BEST).tolist()
    return names + [""] * (BEST - len(names))
