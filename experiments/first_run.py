"""Data on first run: on a machine without the frames (no ``../shared/data``, no
``$TTC_DATA_DIR``, no ``dataset.root=``), the main command downloads the 78 KITTI frames into
``./data`` in the project, with a progress bar, then goes on.

``--no-download`` on the command line or ``TTC_NO_DOWNLOAD=1`` turns it off (the run then
stops at once, saying where the frames were looked for and how to fetch them);
``TTC_DOWNLOAD_URL`` replaces the manifest's base URL (a mirror). The download is the
resumable, size- and SHA-256-verified one of :mod:`experiments.download`.
"""

from __future__ import annotations

import os

from experiments import download, paths

NO_DOWNLOAD_FLAG = "--no-download"
NO_DOWNLOAD_ENV = "TTC_NO_DOWNLOAD"
URL_ENV = "TTC_DOWNLOAD_URL"


def explicit_root(argv: list[str]) -> bool:
    """Whether the command line or the environment names the data root: then a missing one
    is the user's to fill (the run says how), not downloaded into."""
    return bool(os.environ.get(paths.LOCATIONS["data"])) or any(
        a.startswith("dataset.root=") for a in argv
    )


def ensure_data(argv: list[str]) -> list[str]:
    """Download the frames when the default data root lacks them and downloads are allowed;
    return ``argv`` without :data:`NO_DOWNLOAD_FLAG` (Hydra does not know it)."""
    allowed = NO_DOWNLOAD_FLAG not in argv and os.environ.get(NO_DOWNLOAD_ENV, "0") in ("", "0")
    argv = [a for a in argv if a != NO_DOWNLOAD_FLAG]
    root = paths.default_data_root()
    manifest = download.load_manifest()
    if not allowed or explicit_root(argv) or (root / manifest.target).is_dir():
        return argv
    size_mb = sum(f.size for f in manifest.files) / 1e6
    print(f"KITTI frames not found under {root}: downloading the {len(manifest.files) // 2} "
          f"frames ({size_mb:.0f} MB, verified) into it. {NO_DOWNLOAD_FLAG} or "
          f"{NO_DOWNLOAD_ENV}=1 turns this off.")  # fmt: skip
    report = download.download_dataset(root, os.environ.get(URL_ENV) or None, manifest)
    print(f"downloaded {len(report.downloaded)} files into {report.target}")
    return argv
