"""Benchmark: SPG construction against peers, and the dynamic k-d tree against full rebuilds.

Usage::

    .venv/bin/python benchmarks/spg.py --large         # N = 1e4, 1e5, 1e6 -> results/spg.md
    .venv/bin/python benchmarks/spg.py                 # N = 1e4, 1e5 -> results/spg.md
    .venv/bin/python benchmarks/spg.py --quick         # N = 1e4, 1e5, 1 repeat; prints only

The results file (``benchmarks/results/spg.md``, or ``--out``) starts with the provenance
lines of ``benchmarks/_provenance.py`` (commit, date, load average before the run); ``--quick``
writes no file unless ``--out`` is given. Run it alone on an idle machine for numbers to keep.

Every (method, dataset, N) runs in a fresh subprocess: its time is the best of ``--repeat``
runs of the construction alone (data generation and imports excluded), its peak memory the
growth of the process's peak RSS during the runs (``/proc/self/clear_refs`` resets the peak
first). Every method is first run once on 2,000 of the points (all sizes, all methods alike),
so lazy imports, thread pools and numba's cached machine code are loaded before the clock
starts. Peers (imported lazily, reported as unavailable with the reason when missing):

* ``mks SPG``: ``SpatialProximityGraph(points, m=8)`` as users call it (``method="auto"``: the
  compiled grid kernel from 250,000 points on, the k-d tree below; CSR adjacency with
  distances, ties by index);
* ``mks SPG r``: the same with a threshold ``r``;
* ``mks SPG tree``: ``method="tree"``, the paper's balanced k-d tree queried for every point
  (the path ``mks SPG`` took before the grid kernel);
* ``sklearn``: ``sklearn.neighbors.kneighbors_graph(points, 8, mode="distance", n_jobs=-1)``;
* ``cKDTree w1`` / ``cKDTree w-1 r``: a bare ``cKDTree`` (default build) + ``query(k=9)``,
  one thread / all threads with ``distance_upper_bound=r`` (arrays only, no graph);
* ``open3d``: ``open3d.core.nns.NearestNeighborSearch`` hybrid search (radius r, max_knn 9).

``r`` is 1.5x the median distance to the 8th neighbour (estimated on 2,000 points), so most
points have their 8 neighbours within it. Not imported by the tests.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import header_lines  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
M = 8
METHODS = ("mks SPG", "mks SPG r", "mks SPG tree", "sklearn", "cKDTree w1", "cKDTree w-1 r", "open3d")
DATASETS = ("uniform", "surfaces")


def make_points(kind: str, n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) points: uniform in the unit cube, or on a sphere + three planes (a scene)."""
    rng = np.random.default_rng(seed)
    if kind == "uniform":
        return rng.random((n, 3))
    n_s = n // 2
    v = rng.normal(size=(n_s, 3))
    sphere = 0.3 * v / np.linalg.norm(v, axis=1, keepdims=True) + [0.5, 0.5, 0.6]
    rest = n - n_s
    k = rest // 3
    uv = rng.random((rest, 2))
    table = np.column_stack([uv[:k, 0], uv[:k, 1], np.zeros(k)])
    wall = np.column_stack([uv[k : 2 * k, 0], np.zeros(k), uv[k : 2 * k, 1]])
    m3 = rest - 2 * k
    side = np.column_stack([np.zeros(m3), uv[2 * k :, 0], uv[2 * k :, 1]])
    pts = np.concatenate([sphere, table, wall, side])
    return pts[rng.permutation(len(pts))]


def radius_for(points: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(1)
    sample = points[rng.choice(len(points), min(2000, len(points)), replace=False)]
    d, _ = cKDTree(points).query(sample, k=M + 1)
    return float(1.5 * np.median(d[:, -1]))


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _rss_kb(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field):
            return int(line.split()[1])
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def _build(method: str, points: np.ndarray, r: float):
    """Return a zero-argument callable that performs the construction."""
    if method.startswith("mks SPG"):
        sys.path.insert(0, str(ROOT))
        from mks_sim.lowlevel import SpatialProximityGraph

        thr = r if method.endswith(" r") else None
        how = "tree" if method.endswith("tree") else "auto"
        return lambda: SpatialProximityGraph(
            points, m=M, threshold=thr, workers=-1, method=how
        ).adjacency
    if method == "sklearn":
        from sklearn.neighbors import kneighbors_graph

        return lambda: kneighbors_graph(points, M, mode="distance", n_jobs=-1)
    if method.startswith("cKDTree"):
        from scipy.spatial import cKDTree

        if method == "cKDTree w1":
            return lambda: cKDTree(points).query(points, k=M + 1, workers=1)
        return lambda: cKDTree(points).query(points, k=M + 1, workers=-1, distance_upper_bound=r)
    if method == "open3d":
        import open3d.core as o3c

        def run():
            t = o3c.Tensor(points.astype(np.float32))
            nns = o3c.nns.NearestNeighborSearch(t)
            if not nns.hybrid_index(r):
                raise RuntimeError("hybrid_index failed")
            return nns.hybrid_search(t, r, M + 1)

        return run
    raise ValueError(method)


def child(method: str, dataset: str, n: int, repeat: int) -> dict:
    points = make_points(dataset, n)
    r = radius_for(points)
    try:
        fn = _build(method, points, r)
    except Exception as exc:  # a missing peer is a result, not a crash
        return {"error": f"{type(exc).__name__}: {exc}"}
    # warm-up on a small subset, every method and size alike (imports, thread pools, JIT cache)
    warm = _build(method, points[:2000], r) if n > 2000 else fn
    warm()
    if method == "mks SPG" and n >= 250_000:  # auto takes the grid here: load it like a peer
        from mks_sim.lowlevel import SpatialProximityGraph

        _ = SpatialProximityGraph(points[:2000], m=M, method="grid").adjacency
    base = _rss_kb("VmRSS")
    reset = _reset_peak()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
        del out
    peak = _rss_kb("VmHWM") if reset else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {"time": min(times), "peak_mb": max(0, peak - base) / 1024, "r": r}


def run_child(method: str, dataset: str, n: int, repeat: int, timeout: float) -> dict:
    cmd = [sys.executable, __file__, "--child", method, dataset, str(n), str(repeat)]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return {"error": f"timeout > {timeout:.0f} s"}
    if out.returncode != 0:
        tail = (out.stderr.strip().splitlines() or ["?"])[-1]
        return {"error": f"exit {out.returncode}: {tail}"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_dynamic(n: int, ops: int) -> list[tuple[str, float]]:
    """Time per insert / delete of the dynamic tree and SPG vs a full rebuild."""
    sys.path.insert(0, str(ROOT))
    from mks_sim.lowlevel import DynamicKDTree, KDTree, SpatialProximityGraph

    pts = make_points("uniform", n + ops)
    base, extra = pts[:n], pts[n:]
    rows = []
    t0 = time.perf_counter()
    KDTree(base)
    rows.append(("KDTree full build (n points)", time.perf_counter() - t0))
    dyn = DynamicKDTree(base)
    t0 = time.perf_counter()
    for p in extra:
        dyn.insert(p[None, :])
    rows.append(("DynamicKDTree insert, per point", (time.perf_counter() - t0) / ops))
    ids = np.random.default_rng(2).choice(dyn.ids, ops, replace=False)
    t0 = time.perf_counter()
    for i in ids:
        dyn.delete([i])
    rows.append(("DynamicKDTree delete, per point", (time.perf_counter() - t0) / ops))
    t0 = time.perf_counter()
    dyn.query(base[:1000], k=M + 1)
    rows.append(
        ("DynamicKDTree query k=9, per query point (1000)", (time.perf_counter() - t0) / 1000)
    )
    t0 = time.perf_counter()
    KDTree(base).query(base[:1000], k=M + 1)
    rows.append(("KDTree build + query k=9 (1000 points)", time.perf_counter() - t0))
    t0 = time.perf_counter()
    spg = SpatialProximityGraph(base, m=M)
    rows.append(("SPG full build (n points)", time.perf_counter() - t0))
    k = min(ops, 200)
    t0 = time.perf_counter()
    for p in extra[:k]:
        spg.insert(p[None, :])
    rows.append(("SPG insert (affected rows only), per point", (time.perf_counter() - t0) / k))
    t0 = time.perf_counter()
    for i in range(k):
        spg.delete([i * 7 % spg.n])
    rows.append(("SPG delete (affected rows only), per point", (time.perf_counter() - t0) / k))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    ap.add_argument("--large", action="store_true", help="also N = 1e6")
    ap.add_argument("--quick", action="store_true", help="N = 1e4, 1e5, one repeat, no file")
    ap.add_argument("--sizes", type=float, nargs="*", default=None)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=600.0)
    ap.add_argument(
        "--out", type=Path, default=None, help="results file (default results/spg.md; --quick: none)"
    )
    ap.add_argument("--dynamic-n", type=int, default=100_000)
    args = ap.parse_args()
    if args.child:
        method, dataset, n, repeat = args.child
        print(json.dumps(child(method, dataset, int(n), int(repeat))))
        return
    if args.quick:
        args.repeat, args.dynamic_n = 1, 20_000
    if args.out is None and not args.quick:
        args.out = ROOT / "benchmarks" / "results" / "spg.md"
    header = header_lines(".venv/bin/python benchmarks/spg.py " + " ".join(sys.argv[1:]))
    sizes = [int(s) for s in (args.sizes or ([1e4, 1e5, 1e6] if args.large else [1e4, 1e5]))]
    results: dict[tuple[str, str, int], dict] = {}
    for dataset in DATASETS:
        for n in sizes:
            for method in METHODS:
                rep = args.repeat if n < 1_000_000 else 1
                res = run_child(method, dataset, n, rep, args.timeout)
                results[(method, dataset, n)] = res
                print(f"{dataset:9s} {n:>8d} {method:14s} {res}", file=sys.stderr, flush=True)
    dyn = bench_dynamic(args.dynamic_n, 1000)
    md = render(results, sizes, dyn, args, header)
    print(md)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(md)


def render(results, sizes, dyn, args, header: list[str]) -> str:
    lines = [
        "# SPG construction benchmark",
        "",
        *header,
        f"- m = {M} neighbours, 3-D points; time = best of {args.repeat} (1 for N = 1e6), "
        "construction only (after a warm-up on 2,000 points); peak = growth of peak RSS "
        "during the runs; goal (issue 9): `mks SPG` of 1e6 points <= 1.5 s on 2 cores",
        "",
        "| dataset | N | method | time (s) | time / mks SPG | sklearn / method | peak MB |",
        "|---|---:|---|---:|---:|---:|---:|",
    ]
    for dataset in DATASETS:
        for n in sizes:
            ref = results[("mks SPG", dataset, n)].get("time")
            sk = results[("sklearn", dataset, n)].get("time")
            for method in METHODS:
                res = results[(method, dataset, n)]
                if "error" in res:
                    lines.append(
                        f"| {dataset} | {n:.0e} | {method} | unavailable: {res['error']} | | | |"
                    )
                    continue
                t = res["time"]
                ratio = f"{t / ref:.2f}" if ref else ""
                skr = f"{sk / t:.2f}" if sk else ""
                lines.append(
                    f"| {dataset} | {n:.0e} | {method} | {t:.3f} | {ratio} | {skr} | {res['peak_mb']:.0f} |"
                )
    lines += ["", "Scaling exponent b of time ~ N^b (least-squares fit on log-log):", ""]
    lines += ["| method | " + " | ".join(DATASETS) + " |", "|---|" + "---:|" * len(DATASETS)]
    for method in METHODS:
        cells = []
        for dataset in DATASETS:
            pts = [(n, results[(method, dataset, n)].get("time")) for n in sizes]
            pts = [(n, t) for n, t in pts if t]
            if len(pts) >= 2:
                b = np.polyfit(np.log([p[0] for p in pts]), np.log([p[1] for p in pts]), 1)[0]
                cells.append(f"{b:.2f}")
            else:
                cells.append("-")
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    lines += [
        "",
        f"Dynamic k-d tree (n = {args.dynamic_n}, 1000 single-point operations; SPG: 200):",
        "",
        "| operation | time (ms) |",
        "|---|---:|",
    ]
    lines += [f"| {name} | {t * 1000:.3f} |" for name, t in dyn]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
