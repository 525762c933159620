"""Dataset layouts: where a configured recording lies under the data root, and its frame range.

Two layouts, one ``dataset.sequence`` (a folder under ``dataset.root``) for both:

* the Udacity copy of drive 0052 (``kitti_0_18``, ``kitti_0_77``): ``kitti/2011_09_26`` holds
  ``calib_*.txt``, ``image_02/data/`` and ``velodyne_points/data/``;
* the official KITTI-raw layout (``kitti_raw``, keys ``date`` and ``drive``)::

      <root>/kitti_raw/<date>/calib_cam_to_cam.txt, calib_velo_to_cam.txt
      <root>/kitti_raw/<date>/<date>_drive_<drive>_sync/image_02/{data/*.png, timestamps.txt}
      <root>/kitti_raw/<date>/<date>_drive_<drive>_sync/velodyne_points/{data/*.bin, timestamps.txt}
      <root>/kitti_raw/<date>/<date>_drive_<drive>_sync/oxts/{data/*.txt, timestamps.txt,
                                                             dataformat.txt}  (optional)

  ``sequence`` is the drive folder (:func:`raw_sequence`, the ``kitti_raw_sequence`` resolver);
  :func:`ttc.io.calibration.calibration_dir` finds the calibration one folder up, and
  :func:`ttc.io.frames.read_frame_times` the real timestamps. ``last: null`` is the drive's
  last frame (:func:`last_frame`).
* the official KITTI-odometry layout (``kitti_odometry``, key ``sequence_id``)::

      <root>/kitti_odometry/sequences/<NN>/{image_2/*.png, velodyne/*.bin, calib.txt, times.txt}
      <root>/kitti_odometry/poses/<NN>.txt   (optional: the ego speed of each pair)

  ``sequence`` is the sequence folder (:func:`odometry_sequence`, the
  ``kitti_odometry_sequence`` resolver); :mod:`ttc.io.kitti_odometry` reads it (``ttc.io.frames``
  dispatches there for a folder in this layout).
* a ROS 2 bag (``ros2_bag``, key ``path``: an ``.mcap`` file or a rosbag2 folder with
  ``metadata.yaml``, absolute or under the data root; ``sequence`` is the path): read by
  :mod:`ttc.io.bag_recording` through a :class:`ttc.io.ros2_bag.BagSource` of the topics,
  the scan tolerance and the camera frame convention (:func:`bag_source`).

A recording is named by what it is (:func:`recording_id`, :func:`recording_names`): the id
``<date>_drive_<NNNN>`` or ``odometry_<NN>`` in CSV columns and folder names, ``drive NNNN`` or
``odometry NN`` on report pages. The Udacity copy's folder names only its date: it is drive
0052 (:data:`UDACITY_DRIVE`).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from pathlib import Path, PurePosixPath
from typing import Any

from omegaconf import OmegaConf

from ttc.io import bag_recording, kitti_odometry, oxts
from ttc.io.calibration import CAM_TO_CAM, VELO_TO_CAM, calibration_dir
from ttc.io.frames import FrameDataError, read_frame_times, recording_frames
from ttc.io.ros2_bag import BagSource

#: Folder under the data root holding KITTI-raw dates in the official layout.
RAW_FOLDER = "kitti_raw"
#: The resolver the ``kitti_raw`` config builds ``dataset.sequence`` with.
SEQUENCE_RESOLVER = "kitti_raw_sequence"
#: Folder under the data root holding KITTI-odometry sequences in the official layout.
ODOMETRY_FOLDER = "kitti_odometry"
#: The resolver the ``kitti_odometry`` config builds ``dataset.sequence`` with.
ODOMETRY_RESOLVER = "kitti_odometry_sequence"
#: The KITTI-raw drive of the Udacity layout (``kitti/<date>``, whose folder names only the
#: date): the Udacity starter ships frames 0-77 of 2011_09_26 drive 0052.
UDACITY_DRIVE = "0052"
#: A KITTI date folder, ``YYYY_MM_DD``.
DATE = r"\d{4}_\d{2}_\d{2}"
#: A KITTI-raw drive folder (``<date>_drive_<NNNN>_sync``) or its id (no ``_sync``).
RAW_DRIVE_ID = re.compile(rf"(?P<date>{DATE})_drive_(?P<drive>\d{{4}})(?:_sync)?")
#: A KITTI-odometry recording id.
ODOMETRY_ID = re.compile(r"odometry_(?P<sequence>\d{2})")


def kitti_date(value: Any) -> str:
    """A KITTI date as its folder name ``YYYY_MM_DD`` (Hydra and YAML read an unquoted
    ``2011_09_26`` as the integer 20110926)."""
    text = str(value).strip()
    digits = text.replace("_", "").replace("-", "")
    if len(digits) != 8 or not digits.isdigit():
        raise ValueError(f"dataset.date={value!r}: expected a KITTI date like 2011_09_26")
    return f"{digits[:4]}_{digits[4:6]}_{digits[6:]}"


def kitti_drive(value: Any) -> str:
    """A KITTI drive number as its four digits (``52`` and ``0052`` give ``0052``)."""
    text = str(value).strip()
    if not text.isdigit() or len(text) > 4:
        raise ValueError(f"dataset.drive={value!r}: expected a drive number like 0052")
    return text.zfill(4)


def raw_sequence(date: Any, drive: Any) -> str:
    """The drive folder under the data root: ``kitti_raw/<date>/<date>_drive_<drive>_sync``."""
    day = kitti_date(date)
    return f"{RAW_FOLDER}/{day}/{day}_drive_{kitti_drive(drive)}_sync"


def odometry_sequence_id(value: Any) -> str:
    """A KITTI-odometry sequence number as its two digits (``4`` and ``04`` give ``04``)."""
    text = str(value).strip()
    if not text.isdigit() or len(text) > 2:
        raise ValueError(f"dataset.sequence_id={value!r}: expected a sequence number like 04")
    return text.zfill(2)


def odometry_sequence(sequence_id: Any) -> str:
    """The sequence folder under the data root: ``kitti_odometry/sequences/<NN>``."""
    return f"{ODOMETRY_FOLDER}/sequences/{odometry_sequence_id(sequence_id)}"


def recording_id(sequence: str) -> str:
    """The id of the recording in folder ``sequence`` (``dataset.sequence``, relative to the
    data root): ``<date>_drive_<NNNN>`` for a KITTI-raw drive, the Udacity copy included
    (``kitti/2011_09_26`` → ``2011_09_26_drive_0052``, :data:`UDACITY_DRIVE`),
    ``odometry_<NN>`` for a KITTI-odometry sequence (``kitti_odometry/sequences/04`` →
    ``odometry_04``), else the folder's name."""
    path = PurePosixPath(str(sequence).replace("\\", "/"))
    if found := RAW_DRIVE_ID.fullmatch(path.name):
        return f"{found['date']}_drive_{found['drive']}"
    if re.fullmatch(DATE, path.name):
        return f"{path.name}_drive_{UDACITY_DRIVE}"
    if path.parent.name == "sequences" and path.name.isdigit():
        return f"odometry_{odometry_sequence_id(path.name)}"
    return path.name


def recording_names(ids: Iterable[str]) -> dict[str, str]:
    """The name a report page shows for each :func:`recording_id`: ``drive 0052``,
    ``odometry 04``, another id as it is; ``2011_09_26 drive 0001`` where two dates' drives
    share a number."""
    ids = list(dict.fromkeys(ids))
    short = {}
    for rid in ids:
        if found := RAW_DRIVE_ID.fullmatch(rid):
            short[rid] = f"drive {found['drive']}"
        elif found := ODOMETRY_ID.fullmatch(rid):
            short[rid] = f"odometry {found['sequence']}"
        else:
            short[rid] = rid
    shared = {name for name in short.values() if list(short.values()).count(name) > 1}
    return {
        rid: f"{found['date']} {name}"
        if name in shared and (found := RAW_DRIVE_ID.fullmatch(rid))
        else name
        for rid, name in short.items()
    }


def register_resolvers() -> None:
    """Register the ``kitti_raw_sequence`` and ``kitti_odometry_sequence`` resolvers
    (idempotent)."""
    if not OmegaConf.has_resolver(SEQUENCE_RESOLVER):
        OmegaConf.register_new_resolver(SEQUENCE_RESOLVER, raw_sequence)
    if not OmegaConf.has_resolver(ODOMETRY_RESOLVER):
        OmegaConf.register_new_resolver(ODOMETRY_RESOLVER, odometry_sequence)


#: The ``dataset`` keys of a bag recording, each with its value that leaves it out of a setting
#: (the KITTI datasets' settings read as before the keys existed).
BAG_KEYS = {
    "path": "",
    "image_topic": "",
    "camera_info_topic": "",
    "lidar_topic": "",
    "scan_tolerance_s": None,
    "camera_frame": "optical",
}


def bag_source(dataset: dict[str, Any], recording: Path) -> BagSource | None:
    """The :class:`BagSource` of a ``ros2_bag`` dataset (``path`` set) at ``recording`` (the
    path under the data root), else None."""
    if not dataset.get("path"):
        return None
    tolerance = dataset.get("scan_tolerance_s")
    return BagSource(
        path=Path(recording),
        image_topic=dataset.get("image_topic") or "",
        camera_info_topic=dataset.get("camera_info_topic") or "",
        lidar_topic=dataset.get("lidar_topic") or "",
        scan_tolerance_s=None if tolerance is None else float(tolerance),
        camera_frame=dataset.get("camera_frame") or "optical",
    )


def bag_problems(dataset: dict[str, Any], recording: Path) -> list[str] | None:
    """What keeps a ``ros2_bag`` dataset (``path`` set, or empty with ``sequence``) from being read,
    in words: no ``path``, a bag that is not there, an unknown ``camera_frame``, a bag
    :func:`ttc.io.bag_recording.bag_problems` refuses (topics, calibration, transform, scan
    fields, image size). None for a dataset that is not a bag."""
    if not dataset.get("path") and dataset.get("sequence") != "":  # ros2_bag: sequence = path
        return None
    if not dataset.get("path"):
        return ["dataset.path is empty: name the bag (an .mcap file or a rosbag2 folder)"]
    if dataset.get("camera_frame") not in bag_recording.CAMERA_FRAMES:
        return [f"dataset.camera_frame={dataset.get('camera_frame')} must be one of "
                f"{bag_recording.CAMERA_FRAMES}"]  # fmt: skip
    if not Path(recording).exists():
        return [f"ROS 2 bag not found: {recording} (dataset.path={dataset['path']})"]
    return bag_recording.bag_problems(bag_source(dataset, recording))


def last_frame(sequence_dir: Path) -> int | None:
    """The last frame index a recording folder holds; None when it holds none (or is absent)."""
    present = recording_frames(sequence_dir)
    return present[-1] if present else None


def resolved_last(last: int | None, sequence_dir: Path) -> int | None:
    """``dataset.last``, or for ``null`` the recording's last frame (None if it has none)."""
    return int(last) if last is not None else last_frame(sequence_dir)


def frame_range_last(last: int | None, sequence_dir: Path) -> int:
    """:func:`resolved_last` for a frame range: raises :class:`ttc.io.frames.FrameDataError`
    naming the folder when ``last`` is null and the recording holds no frames."""
    resolved = resolved_last(last, sequence_dir)
    if resolved is None:
        raise FrameDataError(
            sequence_dir,
            "no frames found (image_02/data/NNNNNNNNNN.png); dataset.last=null "
            "means the recording's last frame",
        )
    return resolved


def dataset_identity(dataset: dict[str, Any], sequence_dir: Path) -> dict[str, Any]:
    """The recorded ``dataset`` part of a setting (no root): ``date`` / ``drive`` in their
    folder spelling and ``last: null`` resolved from the files, so a run over a whole drive
    names the frames it covered (a drive with more frames later is a different run).
    A Udacity-layout dataset (no ``date``) is returned unchanged. ``sequence_id`` (the
    ``kitti_odometry`` key) is recorded in its two-digit spelling, and left out when empty,
    so the other datasets' settings read as before the key existed; so are a bag's keys
    (:data:`BAG_KEYS`) for a dataset that is not a bag."""
    out = dict(dataset)
    source = bag_source(out, sequence_dir)
    if source is None:
        for key in BAG_KEYS:
            out.pop(key, None)
    else:
        sequence_dir = source
    if out.get("sequence_id"):
        out["sequence_id"] = odometry_sequence_id(out["sequence_id"])
    else:
        out.pop("sequence_id", None)
    if out.get("date"):
        out["date"], out["drive"] = kitti_date(out["date"]), kitti_drive(out["drive"])
    if out.get("last") is None:
        out["last"] = resolved_last(None, sequence_dir)
    return out


def layout_problems(date: str, sequence_dir: Path) -> list[str]:
    """What is wrong with a KITTI-raw drive (``date`` set) beyond its frames, in words: it
    must ship its real timestamps, readable and agreeing (:func:`ttc.io.frames.read_frame_times`
    names the file and line), its ``oxts/``, when it has one, readable times and column names
    (:func:`ttc.io.oxts.layout_problems`), and its date folder the calibration. Nothing for a
    Udacity-layout dataset (no ``date``), which runs at the nominal 10 Hz without them. A
    KITTI-odometry sequence: :func:`ttc.io.kitti_odometry.layout_problems` (its ``calib.txt``
    and ``times.txt``)."""
    if kitti_odometry.is_odometry_sequence(sequence_dir):
        return kitti_odometry.layout_problems(sequence_dir)
    if not date:
        return []
    problems = []
    try:
        if read_frame_times(sequence_dir) is None:
            problems.append(
                f"{sequence_dir}: no timestamps (velodyne_points/timestamps.txt or "
                "image_02/timestamps.txt); a KITTI-raw drive is judged at its real frame times"
            )
    except FrameDataError as exc:
        problems.append(str(exc))
    problems += oxts.layout_problems(sequence_dir)
    folder = calibration_dir(sequence_dir)  # where the run will read both files
    if not (folder / CAM_TO_CAM).is_file():  # in neither: name where KITTI raw keeps them
        folder = sequence_dir.parent
    for name in (CAM_TO_CAM, VELO_TO_CAM):
        if not (folder / name).is_file():
            problems.append(f"{folder / name}: calibration file not found")
    return problems


def missing_drive_message(sequence_dir: Path) -> str:
    """What to say when a KITTI-raw drive folder does not exist (nothing is downloaded)."""
    return (
        f"KITTI raw drive not found: {sequence_dir} does not exist.\n"
        "KITTI raw needs registration at https://www.cvlibs.net/datasets/kitti/raw_data.php; "
        "nothing downloads it. Unpack the date's calibration and the drive's synced+rectified "
        f"archive under {sequence_dir.parents[1]} in the official layout (docs/data.md, 'Any KITTI "
        "raw drive'), or point TTC_DATA_DIR / dataset.root at a folder holding kitti_raw/."
    )


def missing_odometry_message(sequence_dir: Path) -> str:
    """What to say when a KITTI-odometry sequence folder does not exist (nothing is downloaded)."""
    return (
        f"KITTI odometry sequence not found: {sequence_dir} does not exist.\n"
        "KITTI odometry needs registration at "
        "https://www.cvlibs.net/datasets/kitti/eval_odometry.php; nothing downloads it. Unpack "
        "the colour, Velodyne, calibration and poses archives under "
        f"{sequence_dir.parents[1]} in the official layout (docs/data.md, 'KITTI odometry'), or "
        "point TTC_DATA_DIR / dataset.root at a folder holding kitti_odometry/."
    )
