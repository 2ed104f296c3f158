"""Identification benchmarks (issues 4 and 15): the vertex pipeline on synthetic logs,
``lpv-sysid identify`` on the 9 simulated phase-1 bags end to end, the YAML load of the
resulting ``vertex_models.yaml``, and OpenBLAS threads for identification and VRFT.

    .venv/bin/python -m bench.bench_ident [--repeat N]

* 8 vertices from 40 s / 100 Hz synthetic logs (``ident.synthetic``): the per-vertex
  pipeline, median of 5 (issue 4 target < 2 s).
* ``lpv-sysid identify`` on the bags of ``lpv-sysid simulate phase1 --config
  config/quadrotor.yaml`` (9 runs, 40 s, mcap), the shipped identification config, in a
  subprocess (wall and CPU); the time split into reading the bags (``io.bag.topic_info`` +
  ``read_arrays``, what ``ident.dataprep`` calls), turning the columns into streams
  (``io.message_columns``) and the rest, and the bag side's floor:
  ``io.bag.read_arrays`` of the same topics alone.
* YAML: ``io.yaml_file.read_located`` (libyaml parser + strict checks) of that
  ``vertex_models.yaml`` against ``yaml.CSafeLoader``.
* OpenBLAS threads: the identify run above and ``lpv-sysid vrft --example lv100 --runs 50
  --n 10000`` (seed 1 Table 5.2 protocol) with ``OPENBLAS_NUM_THREADS`` 2 (the machine's
  default) and 1, interleaved; the CLI sets 1 for these commands (cli/main.py).
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.harness import Page, Row, Stat, cli, interleaved, load_average, repo_root, status, timed


def _datasets():
    from lpv_sysid.ident import vertex as vx
    from lpv_sysid.models.lpv import box_vertices
    from lpv_sysid.models.quadrotor import Quadrotor
    from lpv_sysid.sim import synthetic as syn

    q = Quadrotor()
    rng = np.random.default_rng(0)
    noise = np.array([2e-3, 2e-3, 0.02, 0.02, 0.02, 5e-3, 5e-3, 5e-3, 2.0, 0.02, 0.02, 2.0])
    Qw = np.diag([10, 10, 1, 1, 1, 1, 1, 1, 1e-6, 1e-4, 1e-4, 1e-6])
    Rw = np.diag([1e2, 1e4, 1e4, 1e2])
    t = np.arange(0, 40, 0.01)
    on = t >= 10
    out = []
    for c in box_vertices([-5] * 3, [5] * 3):
        tr = q.trim(c)
        A, B = q.linearize(tr)
        e = np.zeros((t.size, 4))
        e[on] = syn.multisine(t[on], 4, (0.2, 3.0), 1.0, rng) * np.array(
            [0.03, 0.002, 0.002, 0.03]
        )
        d, _ = syn.closed_loop(A, B, t, e, Qw, Rw)
        x = tr.x0 + d.x + noise * rng.normal(size=d.x.shape)
        out.append(vx.VertexData(t, x, tr.u0 + d.u, c, (0.0, 10.0), (10.0, 40.0), str(c)))
    return out


def _child(argv, threads) -> tuple[float, float, int]:
    """(wall, CPU of the child, return code) of ``python -m lpv_sysid.cli.main argv``."""
    env = dict(os.environ)
    env["OPENBLAS_NUM_THREADS"] = str(threads)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    w0 = time.perf_counter()
    rc = subprocess.run(
        [sys.executable, "-m", "lpv_sysid.cli.main", *argv],
        cwd=repo_root(),
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    ).returncode
    wall = time.perf_counter() - w0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, rc


def _identify_steps(argv) -> dict[str, float]:
    """CPU seconds of the steps of one ``lpv-sysid identify`` run in a child process with
    one BLAS thread, as the CLI runs it (:func:`_steps_child`)."""
    import json

    env = dict(os.environ)
    env["OPENBLAS_NUM_THREADS"] = "1"
    code = f"import json, bench.bench_ident as b; print(json.dumps(b._steps_child({argv!r})))"
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=repo_root(),
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return json.loads(out.strip().splitlines()[-1])


def _steps_child(argv) -> dict[str, float]:
    """The steps of one ``lpv-sysid identify`` run in this process (the CLI's own calls,
    wrapped): imports, reading the bags, alignment, vertex identification, plot, YAML."""
    import contextlib
    import io

    c00 = time.process_time()
    import lpv_sysid.cli.main  # noqa: F401 - the imports the command needs, timed
    from lpv_sysid.ident import dataprep, metrics
    from lpv_sysid.ident import vertex as vx
    from lpv_sysid.io.formats import VertexModels

    acc: dict[str, float] = {}
    patched = [
        (dataprep, "streams_from_bag", "bags"),
        (dataprep, "align", "align"),
        (vx, "identify_vertices", "identification"),
        (metrics, "plot_validation", "plot"),
        (VertexModels, "save", "YAML"),
    ]
    originals = [getattr(obj, name) for obj, name, _ in patched]

    def wrap(fn, key):
        def wrapper(*a, **kw):
            s0 = time.process_time()
            try:
                return fn(*a, **kw)
            finally:
                acc[key] = acc.get(key, 0.0) + time.process_time() - s0

        return wrapper

    for (obj, name, key), fn in zip(patched, originals):
        setattr(obj, name, wrap(fn, key))
    c0 = time.process_time()
    acc["imports"] = c0 - c00
    with contextlib.redirect_stdout(io.StringIO()):
        assert cli(list(argv)) == 0
    acc["other"] = time.process_time() - c0 - sum(v for k, v in acc.items() if k != "imports")
    return acc


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "--repeat", type=int, default=2, help="runs per thread setting of identify / vrft"
    )
    args = ap.parse_args(argv)
    from lpv_sysid.ident import dataprep
    from lpv_sysid.ident import vertex as vx
    from lpv_sysid.io import bag as bg
    from lpv_sysid.io.files import yaml_reader as yaml_file

    load0 = load_average()
    page = Page(
        "ident",
        "Identification (issues 4, 15)",
        f".venv/bin/python -m bench.bench_ident --repeat {args.repeat}",
    )
    data = _datasets()
    rows = []
    for model in ("taylor2", "appendix_b"):
        cfg = vx.IdentificationConfig(model=model)
        w, c, _ = timed(lambda: [vx.identify_vertex(d, cfg) for d in data], repeat=5)
        rows.append(
            [
                f"8 vertices, model={model}, 40 s @ 100 Hz (synthetic)",
                w.fmt(1e3, "ms"),
                c.fmt(1e3, "ms"),
            ]
        )
    page.add("## Vertex pipeline (issue 4 target: 8 vertices < 2 s)")
    page.add()
    page.table(["what", "wall median [p10-p90]", "CPU"], rows)
    page.rows.append(
        Row(
            "identify 8 vertices from 40 s / 100 Hz logs",
            "4",
            rows[0][1].split(" [")[0] + " (taylor2)",
            target="< 2 s",
            status="met" if float(rows[0][1].split()[0]) < 2000 else "not met",
            order=30,
        )
    )

    root = Path(tempfile.mkdtemp(prefix="bench_ident_"))
    cfg_dir = repo_root() / "config"
    try:
        bags = root / "phase1"
        assert (
            cli(
                [
                    "simulate",
                    "phase1",
                    "--config",
                    str(cfg_dir / "quadrotor.yaml"),
                    "--out",
                    str(bags),
                ]
            )
            == 0
        )
        models = root / "vertex_models.yaml"
        ident_argv = [
            "identify",
            "--bags",
            str(bags),
            "--config",
            str(cfg_dir / "identification.yaml"),
            "--quadrotor",
            str(cfg_dir / "quadrotor.yaml"),
            "--out",
            str(models),
        ]
        vrft_argv = ["vrft", "--example", "lv100", "--runs", "50", "--n", "10000"]
        res = {k: [] for k in ("ident2", "ident1", "vrft2", "vrft1")}
        for _ in range(args.repeat):
            for key, argv_, th in (
                ("ident2", ident_argv, 2),
                ("ident1", ident_argv, 1),
                ("vrft2", vrft_argv, 2),
                ("vrft1", vrft_argv, 1),
            ):
                w, c, rc = _child(argv_, th)
                assert rc == 0, (key, rc)
                res[key].append((w, c))
        # where identify's time goes (in this process, single-threaded BLAS already set or not)
        runs = sorted(p for p in bags.iterdir() if p.is_dir())
        wanted = None
        c0 = time.process_time()
        t_read = [0.0]
        originals = {name: getattr(bg, name) for name in ("read_arrays", "read_bag", "topic_info")}

        def timed_read(fn):
            def wrapper(*a, **kw):
                s0 = time.process_time()
                try:
                    return fn(*a, **kw)
                finally:
                    t_read[0] += time.process_time() - s0

            return wrapper

        for name, fn in originals.items():  # dataprep looks them up on the module
            setattr(bg, name, timed_read(fn))
        try:
            for r in runs:
                dataprep.streams_from_bag(r)
        finally:
            for name, fn in originals.items():
                setattr(bg, name, fn)
        t_streams = time.process_time() - c0
        steps = _identify_steps(ident_argv)
        info = bg.topic_info(runs[0])
        wanted = [t for t in info if t.rstrip("/").split("/")[-1] in dataprep.TOPICS]
        n_msgs = sum(info[t].count for t in wanted) * len(runs)
        arr = interleaved(
            {"arrays": lambda: [bg.read_arrays(r, topics=wanted) for r in runs]},
            number=1,
            repeat=3,
            clock=time.process_time,
        )["arrays"]
        # YAML
        text = models.read_text()
        import yaml

        y = interleaved(
            {
                "product": lambda: yaml_file.read_located(models),
                "floor": lambda: yaml.load(text, Loader=yaml.CSafeLoader),
            },  # noqa: S506
            number=3,
            repeat=7,
            clock=time.process_time,
        )
        size_kb = len(text.encode()) / 1024
    finally:
        shutil.rmtree(root, ignore_errors=True)
    st = {k: (Stat([w for w, _ in v]), Stat([c for _, c in v])) for k, v in res.items()}
    i1w, i1c = st["ident1"]
    page.add(
        "## `lpv-sysid identify` on the 9 phase-1 bags "
        "(subprocess; the CLI runs it with one BLAS thread)"
    )
    page.add()
    page.table(
        ["what", "median [p10-p90]"],
        [
            ["wall", i1w.fmt(1, "s")],
            ["CPU", i1c.fmt(1, "s")],
            [
                f"of which reading the bags (`topic_info` + `read_arrays`, {n_msgs} messages)",
                f"{t_read[0]:.2f} s CPU",
            ],
            [
                "of which `ident.dataprep` column -> stream conversion (`io.message_columns`)",
                f"{t_streams - t_read[0]:.2f} s CPU",
            ],
            [
                "rest (Fourier smoothing, equation error, uncertainty, plot, YAML)",
                f"{i1c.median - t_streams:.2f} s CPU",
            ],
            [
                "one run of the command by step (child process, one BLAS thread)",
                ", ".join(f"{k} {v:.2f} s" for k, v in steps.items()) + " CPU",
            ],
            [
                "bag side floor: `read_arrays` of the same topics, 9 bags",
                arr.fmt(1, "s") + f" ({n_msgs / arr.median:,.0f} msgs/s)",
            ],
        ],
    )
    page.add(
        "`ident.dataprep.streams_from_bag` reads the bags column-wise "
        "(`io.bag.read_arrays`, numpy block decode) and converts the columns with the "
        "column parsers of `io.message_columns` (same values as the per-message path, "
        "test_dataprep_columns.py); the bag side is at its floor. The vertex identification "
        "solves each maneuver's rows once: a maneuver that cannot identify the motor constants "
        "is finished with the estimate pooled over the others from the same row solution "
        "(`ident.vertex.identify_vertices`; it used to be fitted twice, 12 fits for 8 "
        "vertices), the motor rows smooth the four rotors in one call "
        "(`ident.derivatives.smooth_columns`), and the validation figure is drawn on a bare "
        "Agg canvas with fixed margins (`ident.metrics.plot_validation`, no pyplot, no "
        "`tight_layout`); on the same data the results are identical "
        "(test_ident_vertices_reuse.py)."
    )
    page.add()
    page.add("## YAML load of `vertex_models.yaml` (%.0f kB, CPU time per load)" % size_kb)
    page.add()
    page.table(
        ["what", "median [p10-p90]", "vs floor"],
        [
            [
                "`io.yaml_file.read_located` (libyaml parser, strict composer/constructor)",
                y["product"].fmt(1e3, "ms"),
                f"{y['product'].median / y['floor'].median:.2f}x",
            ],
            ["floor: `yaml.load(text, CSafeLoader)`", y["floor"].fmt(1e3, "ms"), "1"],
        ],
    )
    page.add("## OpenBLAS threads (`OPENBLAS_NUM_THREADS`, subprocesses interleaved)")
    page.add()
    lines = []
    for name, a, b in (
        ("`lpv-sysid identify` (9 bags)", "ident2", "ident1"),
        ("`lpv-sysid vrft --example lv100 --runs 50 --n 10000`", "vrft2", "vrft1"),
    ):
        lines.append(
            [
                name,
                f"{st[a][0].median:.2f} s / {st[a][1].median:.2f} s",
                f"{st[b][0].median:.2f} s / {st[b][1].median:.2f} s",
            ]
        )
    page.table(["command", "2 threads: wall / CPU", "1 thread: wall / CPU"], lines)
    page.rows.append(
        Row(
            "identify (9 bags)",
            "15",
            f"{i1w.fmt(1, 's')} wall / {i1c.median:.2f} s CPU; bag reading "
            f"{t_read[0]:.2f} s (`read_arrays`), column conversion {t_streams - t_read[0]:.2f} s",
            f"bag side: read_arrays alone {arr.median:.2f} s",
            f"{t_read[0] / arr.median:.2f}x (bag side)",
            "< 3 s",
            status(
                i1w.median < 3.0,
                ""
                if i1w.median < 3.0
                else "the bag side is at its floor; the rest is identification, plot and "
                "YAML output (ident/, cli/design/identify.py)",
            ),
            order=5,
        )
    )
    page.rows.append(
        Row(
            "YAML load of vertex_models.yaml",
            "15",
            f"{y['product'].median * 1e3:.1f} ms per load",
            f"CSafeLoader {y['floor'].median * 1e3:.1f} ms",
            f"{y['product'].median / y['floor'].median:.2f}x",
            "C loader everywhere",
            status(True, "libyaml parser in io.yaml_file; strict checks in Python"),
            order=10,
        )
    )
    win = (
        st["ident1"][1].median <= st["ident2"][1].median
        and st["vrft1"][1].median <= st["vrft2"][1].median
    )
    page.rows.append(
        Row(
            "identification core, VRFT",
            "15",
            f"identify {st['ident2'][0].median:.1f} / {st['ident2'][1].median:.1f} s "
            "(2 threads) vs "
            f"{st['ident1'][0].median:.1f} / {st['ident1'][1].median:.1f} s (1); VRFT "
            f"{st['vrft2'][0].median:.1f} / {st['vrft2'][1].median:.1f} s vs "
            f"{st['vrft1'][0].median:.1f} / {st['vrft1'][1].median:.1f} s (wall / CPU)",
            "—",
            "—",
            "single-threaded BLAS where it wins",
            status(
                win, "OPENBLAS_NUM_THREADS=1 set by the CLI for identify, identify-nonlinear, vrft"
            ),
            order=11,
        )
    )
    page.write(load0)


if __name__ == "__main__":
    main()
