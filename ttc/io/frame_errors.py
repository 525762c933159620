"""The error every input reader raises: :class:`FrameDataError` names the file and what is
wrong. Its own module so that each recording layout's reader (:mod:`ttc.io.frames`,
:mod:`ttc.io.kitti_odometry`) can raise it without importing the others."""

from __future__ import annotations

from pathlib import Path


class FrameDataError(ValueError):
    """An input file is missing or malformed; ``path`` names it."""

    def __init__(self, path: Path | str, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")
