"""The sweep's composer against Hydra's own composition: for every option of every config group
and every experiment, a job's config, setting and run id equal those of ``hydra.compose`` with
the same overrides; and a batch's core settings equal ``settings_from_config``'s."""

from __future__ import annotations

import hashlib
import itertools
import re

import pytest
from hydra import compose, initialize_config_dir
from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.global_hydra import GlobalHydra
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.types import RunMode
from omegaconf import OmegaConf

from experiments.configs.structured import (
    register_configs,
    run_id,
    setting_config,
    setting_hash,
    settings_from_config,
)
from experiments.sweep.compose import Composer, core_settings, variant_jobs
from experiments.sweep.containers import comparable, equal_except, references
from tests.conftest import PROJECT_ROOT

CONF = PROJECT_ROOT / "conf"
#: Groups of the root config's defaults list: a job changes them with ``group=option``.
DEFAULTS = dict(re.findall(r"^  - (\w+): (\w+)", (CONF / "config.yaml").read_text(), re.M))
#: Folders of conf/ that are not groups of the run config (``download``: the manifests of
#: ``python -m experiments.data.download``).
NOT_GROUPS = {"hydra", "download"}
#: Groups not in the defaults list: a job adds them with ``+group=option``.
ADDED = sorted(
    p.name for p in CONF.iterdir() if p.is_dir() and p.name not in {*DEFAULTS, *NOT_GROUPS}
)
EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))


def options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF / group).glob("*.yaml"))


@pytest.fixture(scope="module")
def hydra_env():
    """(loader, master of a multirun with these overrides)."""
    register_configs()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        loader = GlobalHydra.instance().config_loader()
        yield (
            loader,
            lambda overrides: loader.load_configuration(
                "config", overrides, run_mode=RunMode.MULTIRUN
            ),
        )


def same_as_hydra(composer: Composer, job: list[str]) -> None:
    """The composer's config (unresolved and resolved), its shared config's keys outside
    ``hydra``, setting and run id of ``job`` equal those of Hydra's ``compose`` with the same
    overrides (jobs read one after another: a part left in the shared scratch config would
    show in the next)."""
    expected = compose(config_name="config", overrides=job, return_hydra_config=True)
    got = composer.config(job)
    assert OmegaConf.to_container(got, resolve=False) == OmegaConf.to_container(
        expected, resolve=False
    ), job
    task = [k for k in expected if k != "hydra"]
    assert OmegaConf.to_container(OmegaConf.masked_copy(got, task), resolve=True) == (
        OmegaConf.to_container(OmegaConf.masked_copy(expected, task), resolve=True)
    ), job
    if composer.parts(job) is not None:  # derived (else its shared config is Hydra's own)
        with composer.shared_config(job) as shared:  # the validator's view: its own keys
            for resolve in (False, True):
                mine = OmegaConf.to_container(OmegaConf.masked_copy(shared, task), resolve=resolve)
                theirs = OmegaConf.masked_copy(expected, task)
                assert mine == OmegaConf.to_container(theirs, resolve=resolve), job
    setting = composer.setting(job)
    assert setting == setting_config(expected), job
    assert run_id(got) == run_id(expected), job


def test_every_option_of_every_group(hydra_env) -> None:
    """Jobs over every axis group from a template of the defaults: each option alone (a
    variant), all groups at once (the k-th option of each), and the added groups."""
    _, master_of = hydra_env
    groups = sorted(DEFAULTS)
    assert {"detector", "descriptor", "dataset", "fusion", "objects"} <= set(groups)
    template = [f"{g}={DEFAULTS[g]}" for g in groups]
    choices = [[f"{g}={o}" for o in options(g)] for g in groups]
    jobs = [template]
    jobs += [[*template[:i], c, *template[i + 1 :]] for i, cs in enumerate(choices) for c in cs]
    widest = max(len(cs) for cs in choices)
    jobs += [[cs[k % len(cs)] for cs in choices] for k in range(widest)]
    composer = Composer(GlobalHydra.instance().config_loader(), master_of([]))
    for job in jobs:
        same_as_hydra(composer, job)
    derived = [j for j in jobs if composer.parts(j) is not None]
    assert len(derived) > 0.8 * len(jobs)  # most jobs are derived, not composed by Hydra
    assert composer.full_compositions < len(jobs)
    for group in ADDED:  # added to the defaults: another number of overrides, Hydra's way
        for option in options(group):
            same_as_hydra(composer, [*template, f"+{group}={option}"])
    for option in options("hydra/launcher"):
        same_as_hydra(composer, [*template, f"hydra/launcher={option}"])


def sweep_jobs(loader, master) -> list[list[str]]:
    """The jobs of a multirun, as Hydra's basic sweeper expands them."""
    params = master.hydra.sweeper.get("params") or {}
    args = [f"{k}={v}" for k, v in params.items()] + list(master.hydra.overrides.task)
    parsed = OverridesParser.create(config_loader=loader).parse_overrides(args)
    return [list(j) for batch in BasicSweeper.split_arguments(parsed, None) for j in batch]


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_experiment(hydra_env, experiment) -> None:
    """Each experiment's template, its variants and a few jobs that change every key."""
    loader, master_of = hydra_env
    master = master_of([f"+experiment={experiment}"])
    jobs = sweep_jobs(loader, master)
    assert len(jobs) > 1
    picked = variant_jobs(jobs) + jobs[-1:] + jobs[len(jobs) // 2 : len(jobs) // 2 + 1]
    composer = Composer(loader, master)
    for job in picked:
        same_as_hydra(composer, job)


def test_a_recording_that_sets_other_groups_is_a_part_too(hydra_env) -> None:
    """``dataset=kitti_odometry`` (``@package _global_``) also sets the lidar crop: its
    variant is a part that swaps those keys in too, so the jobs of
    a sweep over recordings are derived (the recordings experiment planned 1512 settings in
    ~95 s with one Hydra composition per sequence-04 job), except where another differing
    override sets the same keys (a recording's config that sets ``camera_ttc``, none since the
    box-relative pair rule of every recording: Hydra's composition, in its order)."""
    loader, master_of = hydra_env
    master = master_of([])
    axes = [("dataset=kitti_0_18", "dataset=kitti_odometry", "dataset=kitti_raw_0009"),
            ("lidar_ttc=median", "lidar_ttc=cluster"), ("detector=fast", "detector=orb"),
            ("camera_ttc=median_ratio", "camera_ttc=mean_ratio")]  # fmt: skip
    jobs = [list(job) for job in itertools.product(*axes)]
    composer = Composer(loader, master)
    for job in jobs:
        same_as_hydra(composer, job)
    derived = [j for j in jobs if composer.parts(j) is not None]
    sets_camera = [j for j in axes[0] if "camera_ttc:" in (CONF / "dataset" / f"{j.split('=')[1]}.yaml").read_text()]  # fmt: skip
    overlapping = [j for j in jobs if set(sets_camera) & set(j) and "camera_ttc=mean_ratio" in j]
    assert len(derived) == len(jobs) - len(overlapping)
    # the template, its 5 variants, and the overlapping jobs (their config and their setting)
    assert composer.full_compositions == 1 + 5 + 2 * len(overlapping)


def test_an_entry_that_reads_another_follows_it(hydra_env) -> None:
    """``objects=yolov3`` reads ``dataset.root``: its entry is resolved per data root."""
    _, master_of = hydra_env
    composer = Composer(GlobalHydra.instance().config_loader(), master_of([]))
    jobs = [[f"objects={o}", f"dataset.root={r}"] for o, r in
            itertools.product(("yolov3_tiny", "yolov3"), ("/a", "/b"))]  # fmt: skip
    for job in jobs:
        cfg = compose(config_name="config", overrides=job, return_hydra_config=True)
        assert composer.setting(job)["objects"] == setting_config(cfg)["objects"], job
    assert composer.setting(jobs[3])["objects"]["cfg_path"] == "/b/yolo/yolov3.cfg"


def test_references_between_entries() -> None:
    assert references({"a": "${dataset.root}/x", "b": "${oc.env:X,${results_root}}"}) == {
        "dataset",
        "results_root",
    }
    assert references({"seq": "${kitti_raw_sequence:${.date},${.drive}}"}) == set()
    assert references({"seq": "${..x}"}) == {"*"}
    assert references({"a": "${oc.select:dataset.root,/}"}) == {"*"}  # reads a key by name


def test_two_compositions_equal_but_under_a_key() -> None:
    """:func:`equal_except` tells what comparing :func:`comparable` copies tells, without
    copying: differences under the key, its group choice and the job keys are ignored,
    anywhere else (a value, a key in one only, a list, a type) they count; the containers
    are left as they were."""
    import copy

    base = {
        "detector": {"name": "orb", "n": [1, 2]},
        "matcher": {"name": "bf", "k": 2},
        "dataset": {"last": 3},
        "hydra": {"runtime": {"choices": {"detector": "orb", "matcher": "bf"}},
                  "job": {"id": "a", "num": 1, "name": "x"}, "overrides": {"task": ["a"]}},
    }  # fmt: skip

    def changed(path: str, value) -> dict:
        out = copy.deepcopy(base)
        *parents, leaf = path.split(".")
        node = out
        for part in parents:
            node = node[part]
        if value is KeyError:
            node.pop(leaf, None)
        else:
            node[leaf] = value
        return out

    same = ["detector", "detector.name", "detector.n", "detector.extra", "hydra.job.id",
            "hydra.job.num", "hydra.overrides.task", "hydra.runtime.choices.detector"]  # fmt: skip
    other = ["matcher.k", "matcher.extra", "dataset", "hydra.job.name",
             "hydra.runtime.choices.matcher"]  # fmt: skip
    for path in same + other:
        for value in ("changed", KeyError, [3], 1.0):
            variant = changed(path, value)
            before = copy.deepcopy(variant)
            expected = comparable(variant, ["detector"]) == comparable(base, ["detector"])
            assert equal_except(variant, base, ["detector"]) == expected, (path, value)
            unchanged = variant == base  # "matcher.extra" removed, "matcher.k" as 2.0
            assert expected == (path in same or unchanged), (path, value)
            assert variant == before
    assert equal_except(base, changed("matcher.k", 3), ["detector", "matcher"])


def test_core_settings_of_a_batch(hydra_env) -> None:
    """:func:`core_settings` gives what :func:`settings_from_config` gives for each setting;
    a bad value costs only its own setting."""
    _, master_of = hydra_env
    composer = Composer(GlobalHydra.instance().config_loader(), master_of([]))
    jobs = [[f"matcher={m}", f"keypoint_filter={k}", f"lidar.shrink={s}"]
            for m, k, s in itertools.product(("bf", "flann", "klt"), ("none", "zscore"),
                                             (0.1, 0.2))]  # fmt: skip
    settings = [composer.setting(j) for j in jobs]
    bad = {**settings[0], "keypoint_filter": {**settings[0]["keypoint_filter"], "factor": 0}}
    made = core_settings([*settings, bad])
    for setting, got in zip(settings, made, strict=False):
        assert got == settings_from_config(OmegaConf.create(setting))
    assert isinstance(made[-1], ValueError)


def test_fp6_grid_run_ids_unchanged(hydra_env) -> None:
    """The 168 run ids of ``fp6_grid`` on 0-18 are those of the planner this composer replaced
    (pinned: a digest of the sorted ids it gave, commit 4fb15ca; changed on purpose by issue
    30's ``lidar.objects`` and issue 50's object-lidar keys and camera pair rule, see
    tests/test_run_ids.py)."""
    loader, master_of = hydra_env
    master = master_of(["+experiment=fp6_grid"])
    composer, texts = Composer(loader, master), {}
    ids = sorted({setting_hash(composer.setting(j), texts) for j in sweep_jobs(loader, master)})
    assert len(ids) == 168
    assert hashlib.sha256(" ".join(ids).encode()).hexdigest()[:16] == "0fc4dde03a57d8dd"
    assert composer.full_compositions == 1 + 6 + 5 + 1 + 1  # the template and its variants


def test_kept_compositions_serve_a_re_plan(hydra_env, tmp_path) -> None:
    """A sweep planned again with the same key composes nothing: the kept compositions give
    the same configs and settings; another key (another master config) finds none."""
    from experiments.sweep.kept import compositions_key, keep_compositions, load_compositions

    loader, master_of = hydra_env
    master = master_of(["+experiment=fp5_lidar", "hydra.launcher.n_jobs=1"])  # plugin conf nodes
    jobs = sweep_jobs(loader, master)
    first = Composer(loader, master)
    settings = [first.setting(j) for j in jobs]
    key = compositions_key("plan-key", master)
    keep_compositions(tmp_path, key, first.known)
    again = Composer(loader, master, load_compositions(tmp_path, key))
    assert [again.setting(j) for j in jobs] == settings
    for job in jobs:
        assert OmegaConf.to_container(again.config(job)) == OmegaConf.to_container(
            first.config(job)
        )
    assert again.full_compositions == 0
    assert compositions_key("plan-key", master_of(["+experiment=fp6_grid"])) != key
    assert compositions_key("other", master) != key
    assert load_compositions(tmp_path, "missing") == {}
    (tmp_path / ".plan" / f"compositions-{key}.pkl").write_bytes(b"broken")
    assert load_compositions(tmp_path, key) == {}


@pytest.mark.parametrize(
    "change",
    [["keypoint_filter=zscore"], ["detector=orb,fast", "dataset.last=5"], ["+tracking=mlflow"]],
)
def test_an_earlier_plan_serves_another_sweep(hydra_env, change) -> None:
    """After ``fp6_grid``, the same sweep with another axis (or a changed swept key) takes the
    variants of the axes it did not change from the earlier plan: only its own template and
    the variants of the changed keys are composed, and every job is still Hydra's."""
    from experiments.sweep.earlier import EarlierPlan

    loader, master_of = hydra_env
    first_master = master_of(["+experiment=fp6_grid"])
    first = Composer(loader, first_master)
    for job in variant_jobs(sweep_jobs(loader, first_master)):
        first.setting(job)
    earlier = EarlierPlan(first.template, first.known)
    master = master_of(["+experiment=fp6_grid", *change])
    jobs = sweep_jobs(loader, master)
    composer = Composer(loader, master, earlier=earlier)
    picked = variant_jobs(jobs) + jobs[-1:] + jobs[len(jobs) // 3 : len(jobs) // 3 + 1]
    for job in picked:
        same_as_hydra(composer, job)
    if change[0].startswith("+"):  # an addition: the templates do not differ by a change
        assert composer.inherited == 0
        return
    if change[0].startswith("keypoint"):  # every variant inherited: only the new template
        assert (composer.inherited, composer.full_compositions) == (6 + 5 + 1 + 1, 1)
    else:  # the detector changed: its variant composed, the others' inherited
        assert (composer.inherited, composer.full_compositions) == (5 + 1 + 1, 1 + 1)
