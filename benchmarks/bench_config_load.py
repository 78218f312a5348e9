"""Benchmark: loading and validating the daemon configuration and machine descriptions.

Per case, in one process: the first load (which imports and builds the validators) and the
median of repeated loads afterwards; and per case a whole process (``python -c`` importing the
loader and loading once, best of N) — what a ``cmm-comp`` command or the daemon pays at start.

Run: ``python benchmarks/bench_config_load.py [--rounds N] [--compare DIR]``. ``--compare`` takes
another checkout of this repository (e.g. ``git archive main | tar -x -C DIR``) and measures both
trees in alternating subprocess rounds, printing each figure as the ratio this tree ÷ that tree
(medians over the rounds). Writes benchmarks/results/config_load.json (not with --compare).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "config_load.json"
PACKAGES = ("compensation", "protocol", "daemon", "sim_controller", "cli")
CASES = {
    "daemon config (examples/daemon.toml)": ("config", "examples/daemon.toml"),
    "machine npl-bridge.toml": ("machine", "examples/machines/npl-bridge.toml"),
    "machine gec-mh2.toml": ("machine", "examples/machines/gec-mh2.toml"),
    "machine golden-machine.toml (tables, [uncertainty] defaults)": (
        "machine",
        "tests/data/export/golden-machine.toml",
    ),
}
LOADERS = {
    "config": "from cmm_comp.daemon.config import load_config as load",
    "machine": "from cmm_comp.compensation.machine import Machine; load = Machine.from_toml",
}


def measure_in_process(kind: str, path: Path, repeat: int) -> dict[str, float]:
    """First load (s, includes building the validators) and the median of ``repeat`` more."""
    namespace: dict[str, object] = {}
    exec(LOADERS[kind], namespace)
    load = namespace["load"]
    t0 = time.perf_counter()
    load(path)  # type: ignore[operator]
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        load(path)  # type: ignore[operator]
        times.append(time.perf_counter() - t0)
    return {"first_s": first, "median_s": statistics.median(times)}


def measure_process(kind: str, path: Path, python: str, env: dict[str, str]) -> float:
    """Wall time of one interpreter that imports the loader and loads ``path`` once."""
    code = f"{LOADERS[kind]}\nload({str(path)!r})"
    t0 = time.perf_counter()
    subprocess.run([python, "-c", code], check=True, env=env, capture_output=True)
    return time.perf_counter() - t0


def one_round(tree: Path, env: dict[str, str], repeat: int) -> dict[str, dict[str, float]]:
    """Every case in a fresh interpreter of ``tree`` (in-process figures) plus a cold process."""
    out = {}
    for name, (kind, rel) in CASES.items():
        path = tree / rel
        code = (
            "import json, sys; sys.path.insert(0, sys.argv[1]); import bench_config_load as b; "
            "print(json.dumps(b.measure_in_process(sys.argv[2], sys.argv[3], int(sys.argv[4]))))"
        )
        run = subprocess.run(
            [sys.executable, "-c", code, str(Path(__file__).parent), kind, str(path), str(repeat)],
            check=True,
            env=env,
            capture_output=True,
            text=True,
        )
        figures = json.loads(run.stdout)
        figures["process_s"] = measure_process(kind, path, sys.executable, env)
        out[name] = figures
    return out


def shim_env(tree: Path, tmp: Path) -> dict[str, str]:
    """An environment importing ``cmm_comp.*`` from the checkout ``tree`` (not this one)."""
    shim = tmp / "cmm_comp"
    shim.mkdir()
    for package in PACKAGES:
        (shim / package).symlink_to(tree / package)
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tmp)
    return env


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=20, help="loads per case after the first")
    ap.add_argument("--compare", type=Path, help="another checkout, measured alternately")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"this": (ROOT, dict(os.environ))}
        if args.compare is not None:
            trees["other"] = (args.compare.resolve(), shim_env(args.compare.resolve(), Path(tmp)))
        rounds: dict[str, list[dict[str, dict[str, float]]]] = {k: [] for k in trees}
        for _ in range(args.rounds):
            for key, (tree, env) in trees.items():
                rounds[key].append(one_round(tree, env, args.repeat))
    med = {
        key: {
            case: {f: statistics.median(r[case][f] for r in runs) for f in runs[0][case]}
            for case in CASES
        }
        for key, runs in rounds.items()
    }
    fields = ("first_s", "median_s", "process_s")
    print(f"{'case':<62} {'first load':>11} {'each load':>10} {'process':>9}")
    for case in CASES:
        this = med["this"][case]
        print(
            f"{case:<62} {this['first_s'] * 1e3:9.1f}ms {this['median_s'] * 1e3:8.2f}ms "
            f"{this['process_s']:8.3f}s"
        )
        if "other" in med:
            other = med["other"][case]
            ratios = "  ".join(f"{f} {this[f] / other[f]:.2f}×" for f in fields)
            print(f"{'  ÷ ' + str(args.compare):<62} {ratios}")
    if "other" not in med:
        OUT.write_text(
            json.dumps(
                {
                    "machine": platform.node(),
                    "rounds": args.rounds,
                    "repeat": args.repeat,
                    "results": med["this"],
                },
                indent=2,
            )
            + "\n",
            encoding="utf-8",
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
