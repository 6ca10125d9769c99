"""What a `dvc repro` on another machine changed in dvc.lock, and whether it may.

A trained network's bytes depend on the CPU's kernels (bf16 or float32, AVX2 or AVX-512: the
same seeds give different last bits), and so does everything computed from it; the data
(maps, scans, trajectories, real runs) must not. dvc.yaml declares the stages whose outputs
are trained models, `meta: {precision_dependent: true}`; every stage that reads one of their
outputs, directly or through others, is precision-dependent too (the closure is taken over
the dependency paths that dvc.lock records). Any other output whose hash changed is a
reproducibility defect.

Run after a from-scratch `dvc repro` on a new machine:

    python -m scanloc.lock_diff [REV]     # the working dvc.lock against REV's (default HEAD)

It lists the changed outputs in two groups and exits 1 when one is not precision-dependent.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

import yaml

META_KEY = "precision_dependent"


def declared_stages(dvc_yaml: Mapping) -> set[str]:
    """The dvc.yaml stages (before foreach/matrix expansion) declared precision-dependent."""
    return {
        name
        for name, stage in dvc_yaml.get("stages", {}).items()
        if ((stage.get("do") or stage).get("meta") or {}).get(META_KEY)
    }


def _reads(dep: str, out: str) -> bool:
    """Whether dependency path `dep` reads output path `out` (equal, or one inside the other)."""
    dep, out = dep.rstrip("/"), out.rstrip("/")
    return dep == out or dep.startswith(out + "/") or out.startswith(dep + "/")


def precision_dependent(lock: Mapping, declared: set[str]) -> set[str]:
    """The lock's stages (`train@mlp`) that are declared or read, transitively, an output of
    one that is."""
    stages = lock.get("stages", {})
    found = {name for name in stages if name.split("@", 1)[0] in declared}
    grew = True
    while grew:
        outs = [o["path"] for name in found for o in stages[name].get("outs", [])]
        new = {
            name
            for name, entry in stages.items()
            if name not in found
            and any(_reads(d["path"], o) for d in entry.get("deps", []) for o in outs)
        }
        found |= new
        grew = bool(new)
    return found


def _outputs(lock: Mapping) -> dict[str, tuple[str, str | None]]:
    """{output path: (its stage, its hash)} of a lock."""
    return {
        out["path"]: (name, out.get("md5"))
        for name, entry in lock.get("stages", {}).items()
        for out in entry.get("outs", [])
    }


def changed_outputs(old: Mapping, new: Mapping) -> list[tuple[str, str]]:
    """(stage, path) of every output whose hash differs between two locks, or that one of
    them lacks; matched by path, so an output whose stage was renamed is still compared (the
    stage named is the new lock's, else the old one's)."""
    before, after = _outputs(old), _outputs(new)
    changed = []
    for path in sorted(before.keys() | after.keys()):
        if before.get(path, (None, None))[1] != after.get(path, (None, None))[1]:
            changed.append(((after.get(path) or before[path])[0], path))
    return sorted(changed)


def classify(
    dvc_yaml: Mapping, old: Mapping, new: Mapping
) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    """The changed outputs split into (precision-dependent, not): the second must be empty."""
    allowed = precision_dependent(new, declared_stages(dvc_yaml))
    changed = changed_outputs(old, new)
    return [c for c in changed if c[0] in allowed], [c for c in changed if c[0] not in allowed]


def lock_at(rev: str, repo: Path) -> dict:
    """dvc.lock as committed at `rev`."""
    text = subprocess.run(
        ["git", "show", f"{rev}:dvc.lock"], cwd=repo, check=True, capture_output=True, text=True
    ).stdout
    return yaml.safe_load(text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rev", nargs="?", default="HEAD", help="the commit to compare with")
    parser.add_argument("--repo", type=Path, default=Path.cwd())
    args = parser.parse_args(argv)
    dvc_yaml = yaml.safe_load((args.repo / "dvc.yaml").read_text())
    new = yaml.safe_load((args.repo / "dvc.lock").read_text())
    allowed, defects = classify(dvc_yaml, lock_at(args.rev, args.repo), new)
    print(f"{len(allowed)} precision-dependent outputs changed (trained models and their results)")
    for stage, path in allowed:
        print(f"  {stage}: {path}")
    if defects:
        print(f"{len(defects)} outputs changed that must reproduce byte for byte:")
        for stage, path in defects:
            print(f"  {stage}: {path}")
        return 1
    print("every other output reproduced byte for byte")
    return 0


if __name__ == "__main__":
    sys.exit(main())
