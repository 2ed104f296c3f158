"""Studies on every core (issue 27 item 4): :func:`lpv_sysid.parallel.map_tasks` and the studies
that use it give the numbers of the serial run exactly, with single-threaded BLAS in every
worker. No timings here (bench/bench_studies.py measures the speed-up)."""

import os

import numpy as np
import pytest
from support.toy_plant import write_toy_plant

from lpv_sysid.errors import ConfigError
from lpv_sysid.parallel import default_workers, map_tasks, resolve_workers
from lpv_sysid.parallel.pool import BLAS_THREAD_VARIABLES
from lpv_sysid.synthesis.verify import verify_files
from lpv_sysid.synthesis.verify.montecarlo import PARALLEL_MIN_SAMPLES


def test_workers_are_checked_and_default_to_the_usable_cores():
    assert resolve_workers(None) == default_workers() == len(os.sched_getaffinity(0))
    assert resolve_workers(3) == 3
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ConfigError, match="workers"):
            resolve_workers(bad)
    with pytest.raises(ConfigError, match="backend"):
        map_tasks(abs, [1, 2], 2, backend="threads")


def test_pooled_workers_run_single_threaded_blas_and_keep_the_order():
    before = {k: os.environ.get(k) for k in BLAS_THREAD_VARIABLES}
    seen = []
    got = map_tasks(
        os.getenv, list(BLAS_THREAD_VARIABLES) * 2, 2, on_result=lambda i, r: seen.append(i)
    )
    assert got == ["1"] * 6 and seen == list(range(6))
    assert {k: os.environ.get(k) for k in BLAS_THREAD_VARIABLES} == before  # restored here
    # order of results = order of tasks (different results per task)
    assert map_tasks(abs, [-3, 1, -2, 5, -7], 2) == [3, 1, 2, 5, 7]


def _blas_threads(_) -> int:
    from threadpoolctl import threadpool_info

    return max(d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas")


def test_serial_and_pooled_tasks_see_one_blas_thread():
    import scipy.linalg  # noqa: F401  (scipy's own OpenBLAS loaded too)

    assert map_tasks(_blas_threads, [0], 1) == [1]
    assert map_tasks(_blas_threads, [0, 1, 2], 2) == [1, 1, 1]


def test_with_other_threads_running_the_workers_are_spawned_with_the_blas_variables():
    """A fork copies only the calling thread: with another Python thread alive the pool
    spawns fresh interpreters, which read the BLAS variables when they load numpy."""
    import threading

    from lpv_sysid.parallel.pool import start_method

    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        assert start_method() == "spawn"
        assert map_tasks(os.getenv, list(BLAS_THREAD_VARIABLES), 2) == ["1"] * 3
        assert map_tasks(_blas_threads, [0, 1], 2) == [1, 1]
    finally:
        stop.set()
        t.join()


def test_a_task_error_reaches_the_caller_with_its_type():
    with pytest.raises(ConfigError, match="workers must be an integer >= 1, got 0"):
        map_tasks(resolve_workers, [1, 0, 2], 2)


def _toy(tmp_path):
    el = lambda r, c, std: {  # noqa: E731
        "matrix": "A",
        "row": r,
        "col": c,
        "nominal": -1.0,
        "std": std,
        "lower": -1.0,
        "upper": -1.0,
    }
    return write_toy_plant(
        tmp_path,
        [[el(0, 0, 0.05), el(1, 1, 0.4)], [el(0, 0, 0.02), el(1, 1, 0.02)]],
        k_sigma=3.0,
        gamma_achieved=0.9,
        min_margin=0.0,
    )


def test_full_box_monte_carlo_on_two_workers_equals_the_serial_run(tmp_path):
    """Toy plant of test_verify_full_box (A_i = diag(a1, a2), B = I, K = -I, z = x2): the worst
    frozen norm is 1 / (1 - a2_max) with a2_max = -1 + 3 * 0.4 = 0.2 at vertex 0 -> 1.25."""
    gains, models = _toy(tmp_path)
    n = PARALLEL_MIN_SAMPLES  # enough samples that the pool is used
    serial = verify_files(gains, models, n_random=1, seed=5, full_box=n, workers=1).full_box
    pooled = verify_files(gains, models, n_random=1, seed=5, full_box=n, workers=2).full_box
    key = lambda fb: [(s.where, s.v_d.tolist(), s.norm, s.abscissa, s.ok) for s in fb.samples]  # noqa: E731
    assert len(key(serial)) == n + 4 and key(pooled) == key(serial)
    assert pooled.summary() == serial.summary()
    assert np.array_equal(pooled.worst_A, serial.worst_A)
    assert serial.worst.norm == pytest.approx(1 / (1 - 0.2), rel=1e-5)


def test_full_box_draws_are_the_per_sample_stream(tmp_path):
    """The draws come in two Generator.random blocks; the oracle is the per-sample loop they
    replaced (v_d of an interior sample, then each vertex's elements): every sample's v_d --
    which sits after all the earlier samples' element draws in the stream -- is the loop's."""
    from lpv_sysid.synthesis.uncertainty_set import load_models
    from lpv_sysid.synthesis.verify import full_box_intervals

    gains, models = _toy(tmp_path)
    fb = verify_files(gains, models, n_random=1, seed=7, full_box=40, workers=1).full_box
    model, raw = load_models(models, {})
    boxes, _, _ = full_box_intervals(raw, None, "stored")
    rng = np.random.default_rng(7)
    want = []
    for k in range(40):
        if k < len(model.vertices):
            want.append(np.asarray(model.vertices[k], dtype=float))
        else:
            want.append(model.vmin + rng.random(model.vmin.size) * (model.vmax - model.vmin))
        for b in boxes:
            rng.random(b.lower.size)
    got = [s.v_d for s in fb.samples[:40]]
    assert len(model.vertices) < 40 and all(np.array_equal(g, w) for g, w in zip(got, want))
    assert [s.where.split()[-1] for s in fb.samples[:4]] == [
        "uniform",
        "corner-draw",
        "uniform",
        "corner-draw",
    ]


def test_coverage_study_on_two_workers_equals_the_serial_run():
    from lpv_sysid.control.baseline import BaselineGains
    from lpv_sysid.ident import vertex as vx
    from lpv_sysid.models.quadrotor import QuadrotorParams
    from lpv_sysid.sim import phase1 as p1
    from lpv_sysid.sim.vehicle import SensorConfig
    from lpv_sysid.studies import coverage as cv

    cfg = cv.CoverageConfig(airframes=2, seed=3, vertices=(2,))
    args = (
        cfg,
        QuadrotorParams(),
        BaselineGains(),
        SensorConfig(),
        p1.Phase1Config(),
        vx.IdentificationConfig(),
    )
    lines: list = []
    serial, _ = cv.run_study(*args, workers=1)
    pooled, runs = cv.run_study(*args, progress=lines.append, keep_runs=True, workers=2)
    assert [a.index for a in pooled] == [1, 2] and [ln.split(":")[0] for ln in lines] == [
        "airframe 1",
        "airframe 2",
    ]
    assert pooled[0].params != pooled[1].params  # two different airframes
    for s, p in zip(serial, pooled):
        assert p.params == s.params and p.eiv_shift == s.eiv_shift
        assert [(v.name, v.vertex, v.z) for v in p.vertices] == [
            (v.name, v.vertex, v.z) for v in s.vertices
        ]
    assert cv.summary_dict(pooled, QuadrotorParams(), cfg) == cv.summary_dict(
        serial, QuadrotorParams(), cfg
    )
    # the ablations re-identify the kept flights (returned by the workers): 2 variants x 2
    # airframes as tasks, the serial numbers
    assert [len(r) for r in runs] == [1, 1]
    ab1 = cv.ablations(runs, pooled, QuadrotorParams(), args[-1], workers=1)
    ab2 = cv.ablations(runs, pooled, QuadrotorParams(), args[-1], workers=2)
    assert list(ab1) == list(cv.ABLATIONS) and ab2 == ab1
    assert all(0.0 < f <= 1.0 for fr in ab1.values() for f in fr)


def test_dask_backend_equals_the_serial_run(tmp_path):
    pytest.importorskip("dask", reason="dask not installed (optional backend)")
    assert map_tasks(abs, [-3, 1, -2], 2, backend="dask") == [3, 1, 2]
    gains, models = _toy(tmp_path)
    n = PARALLEL_MIN_SAMPLES
    serial = verify_files(gains, models, n_random=1, seed=5, full_box=n, workers=1).full_box
    dasked = verify_files(
        gains, models, n_random=1, seed=5, full_box=n, workers=2, backend="dask"
    ).full_box
    assert dasked.summary() == serial.summary()
    assert [s.norm for s in dasked.samples] == [s.norm for s in serial.samples]


def test_dask_backend_without_dask_is_a_clear_error(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "dask", None)  # import dask -> ImportError
    with pytest.raises(ConfigError, match="dask is not installed"):
        map_tasks(abs, [1, 2], 2, backend="dask")
