"""``cmm-comp fleet diagnose`` on 2 workers vs 1, Dask's overhead per session, and a projection
to 100 workers from measured task times and scheduler latency.

A fleet of ``--machines`` × ``--dates`` sessions (default 10 × 21 = 210, 400 points each, the
default slow changes) is generated once; then, in each of ``--rounds`` rounds, the command runs
as a user runs it (``cmm-comp fleet diagnose ROOT --json OUT --workers W --quiet``, a fresh OUT
so nothing is stored before) with W = 1 and W = 2, in alternating order. Per run: the process
wall, the engine's wall (cluster running), Σ task compute (wall inside the task) and Σ task CPU,
the client's own time per session, the load average before and after (the machine is shared).

* speedup = wall(1 worker) / wall(2 workers), same round;
* parallel efficiency = Σ task CPU / (engine wall × workers): what share of the workers' time was
  spent computing (on a machine others load, the speedup falls with it; CPU time does not);
* overhead per session = (engine wall × workers − Σ task compute) / sessions, as a share of the
  mean task compute: everything Dask and the client add (scheduling, transfer, storing, idling);
* CPU-time figures (reliable on a loaded machine, where the wall is not): the CPU of the whole
  command's process tree (client, scheduler, nannies, workers; ``getrusage`` of the waited-for
  children) against Σ task CPU: Dask's CPU per session (tree − tasks − the fixed CPU of a run,
  i.e. imports and cluster start/stop, measured as tree − task on a fleet of one session) as a
  share of the task CPU, as measured; since part of it accrues per second whatever the
  sessions (heartbeats, event loops: measured as an idle cluster's CPU per second, 20 s), also
  the per-session rest (clamped at 0), and the share on dedicated cores (per-session rest +
  background over a session's c / W seconds); and the CPU-bound speedup 2 · tree CPU(1 worker) / tree CPU(2 workers),
  what 2 dedicated cores give when the command's CPU spreads over both (2 if the second worker
  costs no extra CPU; the serial part, starting the cluster, is in both trees);
* scheduler latency: a no-op task's round trip (submit → result, one at a time) and the no-op
  throughput of a bulk submission, on a 2-worker LocalCluster;
* projection: T(W) = N · max((c + o) / W, s, k), with c the mean task compute, o the per-session
  overhead at 1 worker, s the scheduler's time per task (1 / no-op throughput) and k the client's
  time per session; efficiency(W) = N · c / (W · T(W)). Three cases (:data:`CASES`): c as the
  task's wall here, c as its CPU (dedicated cores), and also o, s, k divided by the stretch the
  load put on the tasks (task wall / task CPU).

    .venv/bin/python benchmarks/bench_fleet.py [--machines 10] [--dates 21] [--rounds 2]
    .venv/bin/python benchmarks/bench_fleet.py --reproject benchmarks/results/fleet.json

Prints a table and writes ``benchmarks/results/fleet.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "examples" / "machines" / "npl-bridge.toml"
CMM = str(Path(sys.executable).parent / "cmm-comp")


def _children_cpu_s() -> float:
    """CPU time (user + system, s) of this process's waited-for descendants so far."""
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def run_fleet(root: Path, out: Path, workers: int) -> dict[str, Any]:
    load_before = os.getloadavg()
    cpu0 = _children_cpu_s()
    t0 = time.perf_counter()
    proc = subprocess.run(
        [
            CMM,
            "fleet",
            "diagnose",
            str(root),
            "--json",
            str(out),
            "--workers",
            str(workers),
            "--quiet",
        ],
        capture_output=True,
        text=True,
    )
    wall = time.perf_counter() - t0
    tree_cpu = _children_cpu_s() - cpu0
    if proc.returncode != 0:
        raise SystemExit(f"fleet diagnose failed ({proc.returncode}):\n{proc.stderr}")
    run = json.loads(out.read_text())["run"]
    shutil.rmtree(out.with_name(out.name + ".results"))
    out.unlink()
    n = run["sessions_run"]
    return {
        "workers": workers,
        "process_wall_s": wall,
        **run,
        "efficiency": run["task_cpu_s"] / (run["wall_s"] * workers),
        "overhead_share": run["overhead_per_session_s"] / run["compute_per_session_s"],
        "cpu_per_session_s": run["task_cpu_s"] / n,
        "process_tree_cpu_s": tree_cpu,
        "load_before": load_before,
        "load_after": os.getloadavg(),
    }


def _uptime() -> str:
    """``uptime``'s line (the load of the machine the figures were measured under)."""
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    except OSError:
        return "load average: {:.2f}, {:.2f}, {:.2f}".format(*os.getloadavg())


def background_cpu_rate(workers: int, seconds: float = 20.0) -> float:
    """CPU s per wall s that the command's cluster (``dask_client``, as ``fleet`` starts it)
    spends with no task to run: heartbeats, event loops, monitors, in every process of the
    tree. A run accrues it for as long as it lasts, so a loaded machine, which stretches the
    wall, inflates it per session; it is therefore counted apart from the per-session part."""
    import psutil

    from cmm_comp.cli.fleet.engine import dask_client

    with dask_client(workers, None) as client:
        client.submit(_noop, 0, pure=False).result()
        me = psutil.Process()

        def tree() -> float:
            procs = [me, *me.children(recursive=True)]
            return sum(sum(p.cpu_times()[:2]) for p in procs)

        c0, t0 = tree(), time.perf_counter()
        time.sleep(seconds)
        return (tree() - c0) / (time.perf_counter() - t0)


def _noop(x: int) -> int:
    return x


def scheduler_latency(rounds: int = 200, bulk: int = 2000) -> dict[str, float]:
    """No-op round trip (s, median of ``rounds``) and bulk throughput (tasks/s)."""
    import logging
    import statistics

    from distributed import Client, LocalCluster

    with (
        LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            # no dashboard; its HTTP server (health) on a free port, not 8787
            scheduler_kwargs={"dashboard_address": ":0"},
            silence_logs=logging.CRITICAL,
        ) as cluster,
        Client(cluster) as client,
    ):
        client.submit(_noop, -1, pure=False).result()
        trips = []
        for i in range(rounds):
            t0 = time.perf_counter()
            client.submit(_noop, i, pure=False).result()
            trips.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        futures = client.map(_noop, range(bulk), pure=False)
        client.gather(futures)
        elapsed = time.perf_counter() - t0
    return {
        "roundtrip_median_s": statistics.median(trips),
        "roundtrip_p90_s": sorted(trips)[int(0.9 * len(trips))],
        "bulk_tasks_per_s": bulk / elapsed,
    }


def on_dedicated_cores(res: dict[str, Any]) -> None:
    """Dask's CPU per session apart: what accrues per second of the run (an idle cluster's
    background rate × the run's wall) and the per-session rest (clamped at 0: a busy cluster
    spends less than an idle one's background); on W dedicated cores a session lasts c / W."""
    w, c = res["workers"], res["cpu_per_session_s"]
    dask_cpu = res["dask_cpu_per_session_s"] * res["sessions_run"]
    rest = (dask_cpu - res["background_cpu_per_s"] * res["wall_s"]) / res["sessions_run"]
    res["dask_cpu_per_session_net_s"] = rest
    res["dask_cpu_share_dedicated"] = (max(rest, 0.0) + res["background_cpu_per_s"] * c / w) / c


CASES = ("as measured here", "dedicated", "dedicated, o s k de-stretched")


def project(
    one: dict[str, Any], sched: dict[str, float], n: int, workers: int, case: str
) -> dict[str, Any]:
    """The model of the module docstring, from the 1-worker run's figures. ``as measured
    here``: c is the task's wall per session on this (shared) machine; ``dedicated``: c is its
    CPU time per session (what it needs of a core of its own), o, s, k as measured here (loaded:
    pessimistic); ``… de-stretched``: o, s, k too divided by the stretch the load put on the
    tasks (task wall / task CPU), as if client and scheduler had cores of their own as well."""
    stretch = one["compute_per_session_s"] / one["cpu_per_session_s"]
    c = one["compute_per_session_s"] if case == CASES[0] else one["cpu_per_session_s"]
    scale = 1.0 / stretch if case == CASES[2] else 1.0
    o = max(one["overhead_per_session_s"], 0.0) * scale
    s = scale / sched["bulk_tasks_per_s"]
    k = one["client_per_session_s"] * scale
    t = n * max((c + o) / workers, s, k)
    return {
        "workers": workers,
        "cores": case,
        "c_s": c,
        "o_s": o,
        "s_s": s,
        "k_s": k,
        "wall_s": t,
        "efficiency": n * c / (workers * t),
    }


def projections(runs: list[dict[str, Any]], sched: dict[str, float]) -> list[dict[str, Any]]:
    """Every case of :func:`project` for 10 000 sessions on 1, 2, 10 and 100 workers, from the
    fastest 1-worker run."""
    one = min((x for x in runs if x["workers"] == 1), key=lambda x: x["wall_s"])
    return [project(one, sched, 10_000, w, case) for case in CASES for w in (1, 2, 10, 100)]


def print_projection(projection: list[dict[str, Any]]) -> None:
    for p in projection:
        print(
            f"projection ({p['cores']}), 10 000 sessions on {p['workers']:>3} workers: "
            f"{p['wall_s'] / 3600:.2f} h, efficiency {p['efficiency']:.2f} "
            f"(c {p['c_s'] * 1000:.0f} ms, o {p['o_s'] * 1000:.1f}, s {p['s_s'] * 1000:.1f}, "
            f"k {p['k_s'] * 1000:.1f})"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--machines", type=int, default=10)
    ap.add_argument("--dates", type=int, default=21)
    ap.add_argument("--points", type=int, default=400)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "fleet.json"))
    ap.add_argument(
        "--reproject",
        metavar="RESULTS",
        help="only recompute the derived figures and the projection of a results JSON (in place)",
    )
    args = ap.parse_args(argv)
    if args.reproject:
        saved = json.loads(Path(args.reproject).read_text())
        for res in saved["runs"]:
            if "background_cpu_per_s" in res:
                on_dedicated_cores(res)
        saved["projection_10000_sessions"] = projections(saved["runs"], saved["scheduler"])
        Path(args.reproject).write_text(json.dumps(saved, indent=2) + "\n")
        print_projection(saved["projection_10000_sessions"])
        return 0

    from cmm_comp.compensation import Machine
    from cmm_comp.sim_controller.fleet import default_fleet, write_fleet

    with tempfile.TemporaryDirectory(prefix="bench-fleet-") as tmp:
        root = Path(tmp) / "plant"
        spec = default_fleet(
            Machine.from_toml(MACHINE), args.machines, args.dates, n_points=args.points
        )
        write_fleet(root, spec)
        n = len(spec.machines) * len(spec.dates)
        print(
            f"fleet: {n} sessions ({args.machines} machines × {args.dates} dates, "
            f"{args.points} points)",
            flush=True,
        )
        uptime_before = _uptime()
        print(f"load: {uptime_before}", flush=True)
        sched = scheduler_latency()
        # the fixed CPU of a run (imports, cluster start and stop): a fleet of one session
        one_root = Path(tmp) / "one"
        first = min(p.parent for p in root.glob("*/*/measurements.csv"))
        shutil.copytree(first, one_root / first.parent.name / first.name)
        start_cpu = {}
        for w in (1, 2):
            res = run_fleet(one_root, Path(tmp) / f"one-{w}.json", w)
            start_cpu[w] = res["process_tree_cpu_s"] - res["task_cpu_s"]
            print(f"fixed CPU of a run on {w} worker(s): {start_cpu[w]:.1f} s", flush=True)
        background = {w: background_cpu_rate(w) for w in (1, 2)}
        print(f"background CPU of an idle cluster: {background} CPU s per s", flush=True)
        runs = []
        for r in range(args.rounds):
            for w in (1, 2) if r % 2 == 0 else (2, 1):
                res = run_fleet(root, Path(tmp) / f"out-{r}-{w}.json", w)
                res["round"] = r
                res["start_cpu_s"] = start_cpu[w]
                dask_cpu = res["process_tree_cpu_s"] - res["task_cpu_s"] - start_cpu[w]
                res["dask_cpu_per_session_s"] = dask_cpu / res["sessions_run"]
                res["dask_cpu_share"] = dask_cpu / res["task_cpu_s"]
                res["background_cpu_per_s"] = background[w]
                on_dedicated_cores(res)
                runs.append(res)
                print(
                    f"round {r}: {w} worker(s): {res['wall_s']:.1f} s (process "
                    f"{res['process_wall_s']:.1f} s), efficiency {res['efficiency']:.2f}, "
                    f"load {res['load_before'][0]:.1f}→{res['load_after'][0]:.1f}",
                    flush=True,
                )
    rounds = []
    for r in range(args.rounds):
        one, two = (next(x for x in runs if x["round"] == r and x["workers"] == w) for w in (1, 2))
        rounds.append(
            {
                "round": r,
                "speedup": one["wall_s"] / two["wall_s"],
                "speedup_process": one["process_wall_s"] / two["process_wall_s"],
                "cpu_ratio_2_to_1": two["cpu_per_session_s"] / one["cpu_per_session_s"],
                "speedup_cpu_bound": 2 * one["process_tree_cpu_s"] / two["process_tree_cpu_s"],
            }
        )
    projection = projections(runs, sched)
    result = {
        "sessions": n,
        "cpu_count": os.cpu_count(),
        "scheduler": sched,
        "runs": runs,
        "rounds": rounds,
        "projection_10000_sessions": projection,
        "uptime_before": uptime_before,
        "uptime_after": _uptime(),
        "note": "machine shared with other jobs: see load_before/load_after per run",
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")

    print(
        f"\n{'round':>5} {'W':>2} {'wall s':>8} {'eff':>5} {'overhead/session':>17} "
        f"{'compute/session':>16} {'cpu/session':>12} {'Dask CPU':>9} {'dedicated':>9} {'load':>10}"
    )
    for x in runs:
        print(
            f"{x['round']:>5} {x['workers']:>2} {x['wall_s']:>8.1f} {x['efficiency']:>5.2f} "
            f"{x['overhead_per_session_s'] * 1000:>10.1f} ms ({x['overhead_share']:.1%}) "
            f"{x['compute_per_session_s']:>14.3f} s {x['cpu_per_session_s']:>10.3f} s "
            f"{x['dask_cpu_share']:>9.1%} {x['dask_cpu_share_dedicated']:>9.1%} {x['load_before'][0]:>4.1f}→{x['load_after'][0]:<4.1f}"
        )
    for r in rounds:
        print(
            f"round {r['round']}: speedup 2 vs 1 worker {r['speedup']:.2f}× (process "
            f"{r['speedup_process']:.2f}×); CPU-bound speedup {r['speedup_cpu_bound']:.2f}×; "
            f"CPU per session 2w/1w {r['cpu_ratio_2_to_1']:.2f}"
        )
    print(
        f"scheduler: no-op round trip {sched['roundtrip_median_s'] * 1000:.2f} ms (median), "
        f"{sched['bulk_tasks_per_s']:.0f} no-op tasks/s in bulk"
    )
    print_projection(projection)
    print(f"load after: {result['uptime_after']}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
