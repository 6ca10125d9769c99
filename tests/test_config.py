"""The Hydra tree and its DVC wiring: every command `dvc repro` runs composes and resolves at every
profile and trainer, the paper profile is exactly Table 1, the scaled profiles are smaller, and
every conf file a stage reads is declared in dvc.yaml (so an edit reruns the stages it affects)."""

from __future__ import annotations

import functools
import itertools
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from scanloc.localize.catalog import localizer_overrides
from scanloc.scanlocnet.schedule import training_epochs
from scanloc.sites import pipeline_vars
from scanloc.stages.train_scanlocnet import samples_per_cell_floor

REPO_ROOT = Path(__file__).resolve().parents[1]
CONF_DIR = REPO_ROOT / "conf"
STAGES_DIR = REPO_ROOT / "src" / "scanloc" / "stages"

PROFILES = ("smoke", "laptop", "desk", "paper")
TRAINERS = ("cpu", "gpu", "ddp")
ODOMETRY = ("wheel", "laser")  # the odometry sources of the localize stages
ROWS = ("mlp", "cnn1d_20k", "cnn1d_200k", "cnn2d")
DATASETS = ("map1_small", "map1_large", "map2_small")

# Paper-spec §5, Table 1: epochs, batch size, learning rate, LR-decay, dropout, samples.
TABLE1 = {
    "mlp": (2000, 100, 0.01, 0.005, 0.25, 20000),
    "cnn1d_20k": (5000, 100, 0.006, 0.0, 0.1, 20000),
    "cnn1d_200k": (400, 400, 0.006, 0.0, 0.0, 200000),
    "cnn2d": (400, 100, 0.01, 0.005, 0.1, 20000),
}
ROW_MODEL = {"mlp": "mlp", "cnn1d_20k": "cnn1d", "cnn1d_200k": "cnn1d", "cnn2d": "cnn2d"}
PAPER_DATASETS = {
    "map1_small": ("sparse_obstacles", 20000),
    "map1_large": ("sparse_obstacles", 200000),
    "map2_small": ("simple_rooms", 20000),
}

# Which primary config composes each option of a group (every option must compose in it).
GROUP_HOST = {
    "map": "maps",
    "dataset": "scans",
    "sensor": "scans",
    "noise": "scans",
    "experiment": "train",
    "model": "train",
    "trainer": "train",
    "localizer": "localize",
    "run": "trajectory",
    "profile": "trajectory",
    "study": "tune",
    "site_kind": "scanlocnet",
}
# Not checked option by option: the profile picks the scale files (test_scale_files_...),
# hydra/launcher is exercised in test_launchers.py.
GROUPS_ELSEWHERE = {"scale", "hydra"}


# --- composing -------------------------------------------------------------------------------


def resolved(config_name: str, overrides: tuple[str, ...]) -> dict[str, Any]:
    """The job config as a stage app sees it, fully resolved (no `???` left)."""
    return _composed(config_name, tuple(sorted(overrides)))[0]


def choices(config_name: str, overrides: tuple[str, ...]) -> dict[str, str]:
    """The option chosen for each non-Hydra config group (`scale` -> 'paper/mlp')."""
    return _composed(config_name, tuple(sorted(overrides)))[1]


@functools.cache
def _composed(config_name: str, overrides: tuple[str, ...]) -> tuple[dict, dict[str, str]]:
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        cfg = compose(config_name=config_name, overrides=list(overrides), return_hydra_config=True)
    chosen = {
        group: choice
        for group, choice in cfg.hydra.runtime.choices.items()
        if not group.startswith("hydra/") and choice is not None
    }
    # The `hydra:` node needs a running app (HydraConfig) to resolve; the job config must not.
    job = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"])
    return OmegaConf.to_container(job, resolve=True, throw_on_missing=True), chosen


def get(cfg: dict[str, Any], dotted: str) -> Any:
    for part in dotted.split("."):
        cfg = cfg[part]
    return cfg


def leaves(node: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """(dotted key, value) for every non-dict value of a nested dict."""
    if isinstance(node, dict):
        for key, value in node.items():
            yield from leaves(value, f"{prefix}.{key}" if prefix else str(key))
    else:
        yield prefix, node


def train_cfg(row: str, profile: str) -> dict[str, Any]:
    return resolved("train", (f"experiment={row}", f"profile={profile}", "trainer=cpu"))


def transfer_cfg(profile: str, init: str = "scratch") -> dict[str, Any]:
    return resolved("transfer", (f"init={init}", f"profile={profile}", "trainer=cpu"))


def dataset_cfg(dataset: str, profile: str) -> dict[str, Any]:
    return resolved("scans", (f"dataset={dataset}", f"profile={profile}"))["dataset"]


# --- dvc.yaml, expanded as DVC does it ------------------------------------------------------


def substitute(node: Any, context: dict[str, Any]) -> Any:
    """DVC's `${name}` / `${item.field}` interpolation over a parsed dvc.yaml node."""
    if isinstance(node, str):

        def value(match: re.Match[str]) -> str:
            found: Any = context
            for part in match.group(1).split("."):
                if not isinstance(found, dict) or part not in found:
                    raise KeyError(f"dvc.yaml: unknown variable ${{{match.group(1)}}}")
                found = found[part]
            return str(found)

        return re.sub(r"\$\{([\w.]+)\}", value, node)
    if isinstance(node, dict):
        return {substitute(k, context): substitute(v, context) for k, v in node.items()}
    if isinstance(node, list):
        return [substitute(v, context) for v in node]
    return node


EXAMPLE_BAGS = {
    "robot": {
        "bag": "bags/robot",
        "map": "data/maps/sparse_obstacles/map.yaml",
        "map_depends": "data/maps/sparse_obstacles",
        "sensor": "urg04lx",
        "overrides": "truth_topic=/ground_truth",
    }
}


def dvc_stages(profile: str, trainer: str) -> dict[str, dict[str, Any]]:
    """Every stage of dvc.yaml with foreach and matrix expanded as DVC does it, for the sites of
    params.yaml and the given profile and trainer (a foreach or matrix dimension over a dict
    iterates its keys, and a foreach item is the dict's value); dvc.yaml's `vars` as
    scanloc.sites writes them for these sites."""
    spec = yaml.safe_load((REPO_ROOT / "dvc.yaml").read_text())
    params = yaml.safe_load((REPO_ROOT / "params.yaml").read_text())
    # No bag ships with the repository: an example entry, so that the bag stages' commands and
    # params are checked like every other stage's.
    params["bags"] = params.get("bags") or EXAMPLE_BAGS
    runs = yaml.safe_load((CONF_DIR / "seeds.yaml").read_text())
    paper_maps = {
        name: yaml.safe_load((CONF_DIR / "dataset" / f"{name}.yaml").read_text())["map"]
        for name in PAPER_DATASETS
    }
    variables = {
        "profile": profile,
        "trainer": trainer,
        **{
            key: params[key]
            for key in (
                "maps",
                "tune_maps",
                "real_logs",
                "real_ablation_logs",
                "bags",
                "tune_studies",
            )
        },
        **runs,
        **pipeline_vars(params, runs, paper_maps),
    }

    def lookup(dotted: str) -> Any:
        found: Any = variables
        for part in dotted.split("."):
            found = found[part]
        return found

    def values(entries: Any) -> Any:
        if isinstance(entries, str):
            found = re.fullmatch(r"\$\{([\w.]+)\}", entries)
            assert found, f"dvc.yaml: a foreach or matrix over {entries!r}"
            return lookup(found.group(1))
        return entries

    stages: dict[str, dict[str, Any]] = {}
    for name, stage in spec["stages"].items():
        if "matrix" in stage:
            body = {k: v for k, v in stage.items() if k != "matrix"}
            dims = {dim: list(values(v)) for dim, v in stage["matrix"].items()}
            for combo in itertools.product(*dims.values()):
                item = dict(zip(dims, combo, strict=True))
                stages[f"{name}@{'-'.join(combo)}"] = substitute(body, {**variables, "item": item})
            continue
        if "foreach" not in stage:
            stages[name] = substitute(stage, variables)
            continue
        entries = values(stage["foreach"])
        if isinstance(entries, dict):
            pairs = list(entries.items())
        else:
            assert all(isinstance(e, str) for e in entries), f"dvc.yaml {name}: foreach of strings"
            pairs = [(e, e) for e in entries]
        for key, item in pairs:
            stages[f"{name}@{key}"] = substitute(
                stage["do"], {**variables, "key": key, "item": item}
            )
    return stages


def pipeline_sites() -> dict[str, dict[str, str]]:
    """sites.yaml's `sites` for params.yaml's sites and the example bag (dvc_stages)."""
    params = yaml.safe_load((REPO_ROOT / "params.yaml").read_text())
    params["bags"] = params.get("bags") or EXAMPLE_BAGS
    runs = yaml.safe_load((CONF_DIR / "seeds.yaml").read_text())
    return pipeline_vars(params, runs, {})["sites"]


def named(entries: list[Any]) -> list[str]:
    """Paths of a deps/outs/metrics list (plain strings or one-key dicts with options)."""
    return [p for e in entries for p in ([e] if isinstance(e, str) else e)]


def param_files(stage: dict[str, Any]) -> list[str]:
    return [p for e in stage.get("params", []) if isinstance(e, dict) for p in e]


def param_keys(stage: dict[str, Any]) -> list[str]:
    return [e for e in stage.get("params", []) if isinstance(e, str)]


@functools.cache
def stage_config_name(module: str) -> str:
    """The primary config a stage module composes: its `@stage_main("<name>")`."""
    source = (STAGES_DIR / f"{module.rsplit('.', 1)[-1]}.py").read_text()
    found = re.findall(r'stage_main\("(\w+)"\)', source)
    assert len(found) == 1, f"{module}: expected one @stage_main(...), found {found}"
    return found[0]


def stage_command(stage: dict[str, Any]) -> tuple[str, tuple[str, ...]]:
    """(primary config, Hydra overrides) of a stage's `python -m scanloc.stages.X k=v ...`."""
    argv = shlex.split(stage["cmd"])
    assert argv[:2] == ["python", "-m"] and argv[2].startswith("scanloc.stages."), stage["cmd"]
    return stage_config_name(argv[2]), tuple(argv[3:])


def all_stage_commands() -> list[tuple[str, tuple[str, ...]]]:
    commands = {
        stage_command(stage)
        for profile in PROFILES
        for trainer in TRAINERS
        for stage in dvc_stages(profile, trainer).values()
    }
    return sorted(commands)


def group_options() -> list[tuple[str, str]]:
    return sorted(
        (group.name, option.stem)
        for group in CONF_DIR.iterdir()
        if group.is_dir() and group.name not in GROUPS_ELSEWHERE
        for option in group.glob("*.yaml")
    )


# --- 1. everything composes and resolves -----------------------------------------------------


@pytest.mark.parametrize(
    ("config_name", "overrides"),
    [pytest.param(name, o, id=" ".join((name, *o))) for name, o in all_stage_commands()],
)
def test_every_dvc_command_composes_and_resolves(config_name: str, overrides: tuple[str, ...]):
    cfg = resolved(config_name, overrides)
    assert cfg, f"{config_name} {overrides}: empty config"
    if "profile" in cfg:
        profile = [o.split("=", 1)[1] for o in overrides if o.startswith("profile=")]
        assert [cfg["profile"]["name"]] == (profile or ["laptop"])


def test_dvc_runs_every_stage_config_at_every_profile_and_trainer():
    """The list above really crosses profiles and trainers (it would be vacuous otherwise)."""
    commands = all_stage_commands()
    for config_name in ("scans", "train", "transfer", "trajectory", "localize", "evaluate"):
        for profile in PROFILES:
            assert any(name == config_name and f"profile={profile}" in o for name, o in commands), (
                config_name,
                profile,
            )
    for name in ("train", "transfer"):
        for trainer in TRAINERS:
            assert any(n == name and f"trainer={trainer}" in o for n, o in commands)


@functools.cache
def dvc_choices() -> set[tuple[str, str, str | None]]:
    """(group, option, profile) of every group option some DVC command composes."""
    return {
        (group, option, chosen.get("profile"))
        for name, overrides in all_stage_commands()
        for chosen in [choices(name, overrides)]
        for group, option in chosen.items()
    }


@pytest.mark.parametrize(("group", "option"), group_options())
def test_every_group_option_composes_at_every_profile(group: str, option: str):
    """Options no DVC stage uses (amcl_nav2, noise=none, generated maps...) compose too."""
    assert group in GROUP_HOST, f"conf/{group}/: new group, add it to GROUP_HOST"
    host = GROUP_HOST[group]
    # A group selected into a package (localizer@localizers.<slot>) is overridden there.
    host, slot = host if isinstance(host, tuple) else (host, group)
    for profile in (None,) if host == "maps" else PROFILES:
        if any((g.split("@")[0], o, p) == (group, option, profile) for g, o, p in dvc_choices()):
            continue  # composed and resolved by test_every_dvc_command_composes_and_resolves
        overrides = (f"{slot}={option}",)
        if profile is not None and group != "profile":
            overrides += (f"profile={profile}",)
        resolved(host, overrides)
        assert choices(host, overrides)[slot] == option


# --- 2. the paper profile is exact, the others are scaled down -----------------------------


@pytest.mark.parametrize("row", ROWS)
def test_paper_profile_is_table1(row: str):
    cfg = train_cfg(row, "paper")
    exp, model = cfg["experiment"], cfg["model"]
    epochs, batch_size, lr, lr_decay, dropout, samples = TABLE1[row]
    assert exp["name"] == row
    assert exp["epochs"] == epochs
    assert exp["batch_size"] == batch_size
    assert model["lr"] == pytest.approx(lr, rel=0, abs=1e-12)
    assert model["lr_decay"] == pytest.approx(lr_decay, rel=0, abs=1e-12)
    assert exp["samples"] == samples
    if dropout:
        assert model["net"]["dropout"] == pytest.approx(dropout, rel=0, abs=1e-12)
    else:  # "–" in Table 1: no dropout anywhere in the network
        assert [v for k, v in leaves(model["net"]) if "dropout" in k and v] == []
    assert (
        choices("train", (f"experiment={row}", "profile=paper", "trainer=cpu"))["model"]
        == (ROW_MODEL[row])
    )
    # Table 1 trains on map 1 with as many scans as the dataset holds.
    dataset = dataset_cfg(exp["dataset"], "paper")
    assert dataset["map"] == "sparse_obstacles"
    assert dataset["num_samples"] == samples


def test_paper_datasets_trajectory_and_transfer():
    for name, (map_name, num_samples) in PAPER_DATASETS.items():
        dataset = dataset_cfg(name, "paper")
        assert (dataset["name"], dataset["map"], dataset["num_samples"]) == (
            name,
            map_name,
            num_samples,
        )
        assert dataset["val_fraction"] == pytest.approx(0.1)  # 90 % / 10 % split
    traj = resolved("trajectory", ("profile=paper",))
    assert traj["trajectory"]["num_steps"] == 1500
    assert traj["trajectory"]["rate_hz"] == pytest.approx(10.0)
    assert traj["map_name"] == "sparse_obstacles" and traj["name"] == "sparse_obstacles_drive"
    assert traj["sensor"].get("rate_hz", 10) == pytest.approx(10.0)
    transfer = transfer_cfg("paper")["transfer"]
    assert transfer["dataset"] == "map2_small"
    assert transfer["samples"] == PAPER_DATASETS["map2_small"][1]


@pytest.mark.parametrize("profile", PROFILES)
def test_ensemble_members_train_like_cnn1d_200k(profile: str):
    """Member 0 of the ensemble is models/cnn1d_200k: the others must be trained the same way."""
    ensemble, single = train_cfg("ensemble", profile), train_cfg("cnn1d_200k", profile)
    members = ensemble["experiment"]["members"]
    if profile == "paper":
        assert members == 7
    else:  # at least one member besides cnn1d_200k, or cnn_ensemble has nothing to average
        assert 2 <= members <= 7
    drop = {"name", "members"}
    assert {k: v for k, v in ensemble["experiment"].items() if k not in drop} == {
        k: v for k, v in single["experiment"].items() if k not in drop
    }
    assert ensemble["model"] == single["model"]
    assert ensemble["trainer"] == single["trainer"]
    if profile == "paper":
        assert ensemble["experiment"]["samples"] == 200000


@pytest.mark.parametrize("profile", PROFILES)
def test_transfer_scratch_and_pretrained_differ_only_in_init(profile: str):
    scratch, pretrained = transfer_cfg(profile), transfer_cfg(profile, "pretrained")
    assert scratch["transfer"] == pretrained["transfer"]
    assert scratch["model"] == pretrained["model"]
    assert scratch["out_dir"] != pretrained["out_dir"]
    # The pretrained weights must fit the transfer network: the same architecture.
    cnn1d_20k = train_cfg("cnn1d_20k", profile)
    assert {k: v for k, v in scratch["model"]["net"].items() if k != "dropout"} == {
        k: v for k, v in cnn1d_20k["model"]["net"].items() if k != "dropout"
    }
    assert scratch["pretrained_model"] == f"{cnn1d_20k['out_dir']}/model.pt"


def scaled_values(profile: str) -> dict[str, int]:
    """The numbers a profile scales, by a readable name."""
    values = {}
    for row in (*ROWS, "ensemble"):
        exp = train_cfg(row, profile)["experiment"]
        values[f"{row} samples"] = exp["samples"]
        values[f"{row} epochs"] = exp["epochs"]
    values["ensemble members"] = train_cfg("ensemble", profile)["experiment"]["members"]
    for name in DATASETS:
        values[f"{name} num_samples"] = dataset_cfg(name, profile)["num_samples"]
    values["trajectory num_steps"] = resolved("trajectory", (f"profile={profile}",))["trajectory"][
        "num_steps"
    ]
    transfer = transfer_cfg(profile)["transfer"]
    values["transfer samples"] = transfer["samples"]
    values["transfer epochs"] = transfer["epochs"]
    return values


def test_smoke_and_laptop_are_scaled_down():
    paper, laptop, smoke = (scaled_values(p) for p in ("paper", "laptop", "smoke"))
    for what, full in paper.items():
        assert 0 < laptop[what] < full, f"laptop {what} = {laptop[what]}, paper {full}"
        assert 0 < smoke[what] <= laptop[what], f"smoke {what} = {smoke[what]} > laptop"


def test_a_real_log_trains_denser_than_a_simulated_map():
    """The laptop's real-log floor of scans per cell (chosen on intel's tune hold-out) reaches
    the real sites' trainings of dvc.yaml, a log's model and a bag's, and only those; the ablation's
    variants, its matched baseline `none` included, all train at the simulated maps' floor (a
    fair ablation trains every row alike, and six sparse trainings cost less than five dense)."""
    floors: dict[str, set[int]] = {}
    kinds = {site: entry["kind"] for site, entry in pipeline_sites().items()}
    for name, stage in dvc_stages("laptop", "cpu").items():
        config_name, overrides = stage_command(stage)
        if config_name in ("scanlocnet", "real_ablation"):
            cfg = OmegaConf.create(resolved(config_name, overrides))
            stage_name, _, site = name.partition("@")
            which = "real_ablation" if stage_name == "real_ablation" else kinds[site]
            floors.setdefault(which, set()).add(samples_per_cell_floor(cfg))
    assert floors.keys() == {"map", "log", "real_ablation", "bag"}
    assert floors["log"] == floors["bag"]
    assert floors["real_ablation"] == floors["map"]
    assert len(floors["log"]) == len(floors["real_ablation"]) == 1
    (real,), (simulated,) = floors["log"], floors["map"]
    assert real > simulated
    # intel's 529 pose cells at 12 x 25000 scans: the 36 epochs the tune hold-out chose
    assert training_epochs(12, 25_000, 529, real) == 36


@pytest.mark.parametrize("profile", PROFILES)
def test_runs_never_ask_for_more_scans_than_their_dataset_holds(profile: str):
    for row in (*ROWS, "ensemble"):
        exp = train_cfg(row, profile)["experiment"]
        available = dataset_cfg(exp["dataset"], profile)["num_samples"]
        assert exp["samples"] <= available, f"{profile} {row}: {exp['samples']} > {available}"
    transfer = transfer_cfg(profile)["transfer"]
    available = dataset_cfg(transfer["dataset"], profile)["num_samples"]
    assert transfer["samples"] <= available, f"{profile} transfer: {transfer['samples']}"


def scale_file_host(item: str) -> tuple[str, tuple[str, ...]]:
    """The config whose `optional scale` picks conf/scale/<profile>/<item>.yaml."""
    if (CONF_DIR / "experiment" / f"{item}.yaml").is_file():
        return "train", (f"experiment={item}", "trainer=cpu")
    if (CONF_DIR / "dataset" / f"{item}.yaml").is_file():
        return "scans", (f"dataset={item}",)
    assert (CONF_DIR / f"{item}.yaml").is_file(), f"conf/scale/*/{item}.yaml: scales what?"
    return item, ("init=scratch", "trainer=cpu") if item == "transfer" else ()


@pytest.mark.parametrize("profile", PROFILES)
def test_scale_files_only_set_existing_keys(profile: str):
    """A misspelt key in a scale file would add a new key and silently scale nothing."""
    files = sorted((CONF_DIR / "scale" / profile).glob("*.yaml"))
    assert {f.stem for f in files} == {
        f.stem for f in (CONF_DIR / "scale" / "paper").glob("*.yaml")
    }, f"conf/scale/{profile}/ and conf/scale/paper/ scale different items"
    for path in files:
        config_name, overrides = scale_file_host(path.stem)
        assert choices(config_name, (*overrides, f"profile={profile}"))["scale"] == (
            f"{profile}/{path.stem}"
        ), f"{path}: not picked by conf/{config_name}.yaml"
        unscaled = resolved(config_name, (*overrides, "profile=paper"))
        for key, _ in leaves(yaml.safe_load(path.read_text()) or {}):
            try:
                get(unscaled, key)
            except KeyError:
                pytest.fail(f"{path}: sets {key}, which conf/{config_name}.yaml does not have")


# --- 3. the stage app itself prints the paper's numbers --------------------------------------


def run_in_repo(command: list[str]) -> str:
    """Stdout of `command` run from the repository root with this venv's tools first on PATH
    and the repository's own conf/ (no SCANLOC_CONF); fails the test if it fails."""
    env = {k: v for k, v in os.environ.items() if k != "SCANLOC_CONF"}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    result = subprocess.run(
        command, cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_train_app_prints_the_paper_config():
    command = [sys.executable, "-m", "scanloc.stages.train", "--cfg", "job"]
    cfg = yaml.safe_load(run_in_repo([*command, "profile=paper", "experiment=cnn1d_200k"]))
    assert cfg["experiment"]["epochs"] == 400
    assert cfg["experiment"]["batch_size"] == 400
    assert cfg["model"]["lr"] == pytest.approx(0.006)
    assert cfg["experiment"]["samples"] == 200000
    assert cfg["profile"]["name"] == "paper"


# --- 4. DVC wiring ---------------------------------------------------------------------------


@pytest.mark.parametrize("trainer", TRAINERS)
@pytest.mark.parametrize("profile", PROFILES)
def test_dvc_params_files_exist(profile: str, trainer: str):
    params = yaml.safe_load((REPO_ROOT / "params.yaml").read_text())
    for name, stage in dvc_stages(profile, trainer).items():
        for path in param_files(stage):
            assert path.startswith("conf/") and path.endswith(".yaml"), f"{name}: {path}"
            assert (REPO_ROOT / path).is_file(), f"{name} at {profile}/{trainer}: no {path}"
        for key in param_keys(stage):  # a dotted key is one entry of a table (real_logs.intel)
            node = params
            for part in key.split("."):
                assert isinstance(node, dict) and part in node, (
                    f"{name}: params.yaml has no {key!r}"
                )
                node = node[part]


def group_files(group: str, option: str) -> list[str]:
    """conf/<group>/<option>.yaml and the same-group files its defaults list pulls in."""
    path = f"conf/{group}/{option}.yaml"
    files = [path]
    for entry in (yaml.safe_load((REPO_ROOT / path).read_text()) or {}).get("defaults", []):
        if isinstance(entry, str) and entry != "_self_" and "/" not in entry:
            files += group_files(group, entry)
    return files


def inside(path: str, declared: list[str]) -> bool:
    return any(Path(path) == Path(d) or Path(d) in Path(path).parents for d in declared)


def localizer_inputs(localizer: dict[str, Any]) -> list[str]:
    """Paths one localizer config reads beside the trajectory and the map."""
    if localizer["meta"]["kind"] in ("cnn", "fusion"):
        ensemble = localizer["ensemble"]
        return ensemble["models"] + ([ensemble["member_dir"]] if ensemble.get("member_dir") else [])
    if "learned" in localizer:  # the learned localizer, its tracking and the hybrid
        learned = localizer["learned"]
        return [learned["model"]] + (
            [learned["calibration_scans"]] if learned.get("verified") else []
        )
    return []


def config_inputs(cfg: dict[str, Any]) -> list[str]:
    """Paths a stage reads, by the config keys the stage apps use. The wall-time folders
    (timing_dir, localize_timing_dir) are not: a wall time never repeats, so a dependency on one
    would rerun its reader every time (test_wall_times_are_top_level_metrics_only)."""
    keys = ("dataset_dir", "trajectory_dir", "truth", "val_dataset", "trajectory_root")
    paths = [cfg[k] for k in keys if k in cfg]
    paths += cfg.get("localize_roots", [])
    localizers = cfg.get("localizers") or {}
    needs_map = any(loc["meta"]["kind"] not in ("cnn", "fusion") for loc in localizers.values())
    if "map_yaml" in cfg and (not localizers or needs_map):
        paths.append(cfg["map_yaml"])
    if cfg.get("init") == "pretrained":
        paths.append(cfg["pretrained_model"])
    for localizer in localizers.values():
        paths += localizer_inputs(localizer)
    return paths


def config_outputs(config_name: str, cfg: dict[str, Any]) -> list[str]:
    """Paths a stage writes; the report stage writes two files into its out_dir. Not the
    wall-time files (timing_dir, timing_path): no stage declares those."""
    if config_name == "report":
        return [f"{cfg['out_dir']}/report.html", f"{cfg['out_dir']}/report.md"]
    keys = ("out_dir", "out_path", "metrics_path", "table2_path", "table2_dir")
    return [cfg[k] for k in keys if cfg.get(k) is not None]  # null: not written


@pytest.mark.parametrize("trainer", TRAINERS)
@pytest.mark.parametrize("profile", PROFILES)
def test_dvc_declares_what_each_stage_reads_and_writes(profile: str, trainer: str):
    for name, stage in dvc_stages(profile, trainer).items():
        config_name, overrides = stage_command(stage)
        declared = param_files(stage)
        for slot, option in choices(config_name, overrides).items():
            if slot == "profile":
                assert "profile" in param_keys(stage), f"{name}: `profile` not a param"
                continue
            group = slot.split("@")[0]  # localizer@localizers.amcl: group localizer
            for path in group_files(group, option):
                if (REPO_ROOT / path).is_file():
                    assert path in declared, f"{name} reads {path} but dvc.yaml omits it"
        # the localize stages compose the localizers conf/localizer lists for them
        listed = []
        if config_name in ("localize", "localize_cnn"):
            listed = localizer_overrides(config_name, CONF_DIR / "localizer")
        cfg = resolved(config_name, (*overrides, *listed))
        deps = named(stage.get("deps", []))
        for path in config_inputs(cfg):
            assert inside(path, deps), f"{name} reads {path}, not under its deps {deps}"
        written = [named(stage.get(key, [])) for key in ("outs", "metrics", "plots")]
        written = [path for paths in written for path in paths]
        for path in config_outputs(config_name, cfg):
            assert inside(path, written), f"{name} writes {path}, not under its outs {written}"


def test_wall_times_are_top_level_metrics_only():
    """Wall-clock files are shown by `dvc metrics show` (dvc.yaml's top-level `metrics`) but are
    no stage's dependency or output, so dvc.lock never records a hash of them."""
    spec = yaml.safe_load((REPO_ROOT / "dvc.yaml").read_text())
    shown = spec.get("metrics", [])
    params = yaml.safe_load((REPO_ROOT / "params.yaml").read_text())
    for name, stage in dvc_stages(params["profile"], params["trainer"]).items():
        cfg = resolved(*stage_command(stage))
        timing = [cfg[k] for k in ("timing_dir", "localize_timing_dir", "timing_path") if k in cfg]
        assert timing, f"{name}: writes no wall time (timing_dir)"
        declared = [
            *named(stage.get("deps", [])),
            *named(stage.get("outs", [])),
            *named(stage.get("metrics", [])),
        ]
        for path in timing:
            assert inside(path, shown), f"{name}: {path} is not under dvc.yaml `metrics` {shown}"
            clashes = [d for d in declared if inside(d, [path]) or inside(path, [d])]
            assert not clashes, f"{name}: the wall-time path {path} is declared as {clashes}"


def test_dvc_stage_list_is_the_contract():
    names = run_in_repo(["dvc", "stage", "list", "--name-only"]).split()
    assert len(names) == len(set(names))
    params = yaml.safe_load((REPO_ROOT / "params.yaml").read_text())
    expected = dvc_stages(params["profile"], params["trainer"])
    if not params.get("bags"):  # the example bag of dvc_stages is not in params.yaml
        example = [f"@{bag}" for bag in EXAMPLE_BAGS]
        expected = {
            n: s
            for n, s in expected.items()
            if not any(n.endswith(e) or f"{e}_" in n or f"{e}-" in n for e in example)
        }
    assert set(names) == set(expected)

    def expansions(stage: str) -> set[str]:
        return {n.split("@", 1)[1] for n in names if n.startswith(f"{stage}@")}

    assert {n.split("@", 1)[0] for n in names} == {
        "maps",
        "trajectory",
        "real",
        "scans",
        "train",
        "transfer",
        "train_scanlocnet",
        "real_ablation",
        "localize",
        "tune",
        "evaluate",
        "report",
    }  # `bag` too, once params.yaml lists a bag
    maps = set(params["maps"])
    tune_maps = set(params["tune_maps"])
    logs = set(params["real_logs"])
    assert {"sparse_obstacles", "simple_rooms"} <= maps  # the paper's two maps by default
    assert "intel" in logs  # the real-data evaluation runs by default on the intel log
    sites = maps | tune_maps | logs
    assert expansions("train") == {*ROWS, "ensemble"}
    assert expansions("transfer") == {"scratch", "pretrained"}
    assert expansions("maps") == maps | tune_maps and expansions("real") == logs
    assert expansions("scans") == set(DATASETS) | {f"{site}_val" for site in sites}
    assert expansions("train_scanlocnet") == sites
    assert expansions("tune") == set(params["tune_studies"])
    seeded = ("drive", "kidnap", "kidnap_s1", "kidnap_s2", "kidnap_s3", "kidnap_s4")
    runs = {f"{m}-{r}" for m in maps for r in seeded}
    # tune_kidnap: the studies' run (conf/study/), localized by them, never scored
    assert expansions("trajectory") == runs | {f"{m}-tune_kidnap" for m in maps | tune_maps}
    real_runs = {f"{log}-{r}" for log in logs for r in ("real", "sim", "kidnap")}
    cnn = {"cnn-drive", "cnn-kidnap"}
    seed_runs = {
        f"seeds-{log}-{r}-{o}" for log in logs for r in ("real", "kidnap") for o in ODOMETRY
    }
    assert expansions("localize") == runs | real_runs | cnn | seed_runs
    variants = ("none", "no_return", "short", "long", "noise", "all")
    ablated = set(params["real_ablation_logs"])
    assert ablated <= logs, "params.yaml real_ablation_logs: names from real_logs"
    assert expansions("real_ablation") == {f"{log}-{v}" for log in ablated for v in variants}
    for single in ("evaluate", "report"):
        assert single in names
    assert params["profile"] in PROFILES and params["trainer"] in TRAINERS
