"""Runtime LPV law step (issue 5 target < 20 us, issue 15 target <= 10 us on the default path).

    .venv/bin/python -m bench.bench_lpv_law

The default configuration the product ships: the law settings of config/lpv_controller.yaml
(``ControllerSettings.law_config()``: feedforward on, a and j from the law's own derivative
filter, mixer saturation, bound monitor), a gain schedule of the shape `lpv-sysid synthesize`
writes by default (msg_samples/gains.yaml: 8 vertices, 12 states, 4 inputs, plus the
reference feedforward F_ff and F_jerk that synthesis.feedforward computes on its certified
trim linearisations, :func:`shipped_gains`) and the law's inputs as the node computes them
on the recorded phase-2 sample flight (msg_samples/phase2_sim: x = [x8; Mix Omega],
envelope-limited v_d, kappa u_e; 1250 steps at 250 Hz, :func:`recorded_law_inputs`).

CPU time per step over whole passes of the recording, product and floor interleaved
(bench/harness.py); the floor is the least numpy arithmetic of the same law: weights as
floats, one ``alpha @ W``, x_ref = G [a; j; 1] and the feedback product (a, j given), no
checks, no filter, no saturation, no monitor. Per-step wall times of the default path give
the tail (p99, max).
"""

from __future__ import annotations

import os
import shutil
import time
from typing import Any

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(ROOT, "msg_samples")
PARAMS = os.path.join(ROOT, "config", "lpv_controller.yaml")
NS = "/lpv_sysid"
INPUTS = ("state", "rotor_speeds", "velocity_reference", "excitation")


def shipped_gains(dirpath: str) -> str:
    """A certified gains.yaml with the default reference feedforward (F_ff and F_jerk of the
    default FeedforwardLayout, as synthesize writes them) on msg_samples/gains.yaml's law,
    written to ``dirpath`` with its sidecar; returns its path."""
    from lpv_sysid.io.files import save_yaml
    from lpv_sysid.io.formats import GainSchedule, certify_law, load_certified_systems
    from lpv_sysid.synthesis.feedforward import FeedforwardLayout, vertex_feedforward

    src = os.path.join(SAMPLES, "gains.yaml")
    gs = GainSchedule.load(src)
    systems = load_certified_systems(
        src, gs.certificate, len(gs.state_names), len(gs.input_names), src
    )
    A = np.array([s[0][0] for s in systems])
    B = np.array([s[0][1] for s in systems])
    layout = FeedforwardLayout()
    F, Fj = vertex_feedforward(A, B, gs.state_names, layout)
    doc = gs.to_dict()
    doc["feedforward"] = layout.to_dict()
    for i, v in enumerate(doc["vertices"]):
        v["F_ff"], v["F_jerk"] = F[i].tolist(), Fj[i].tolist()
    doc = certify_law(doc)
    os.makedirs(dirpath, exist_ok=True)
    out = os.path.join(dirpath, "gains.yaml")
    save_yaml(doc, out)
    shutil.copy(os.path.join(SAMPLES, doc["certificate"]["sidecar"]["file"]), dirpath)
    return out


def shipped_settings(gains_file: str) -> Any:
    """ControllerSettings of config/lpv_controller.yaml with ``gains_file``."""
    from lpv_sysid.configuration.parameters import yaml_parameters
    from lpv_sysid.flight.controller import ControllerSettings

    params = yaml_parameters(PARAMS, "lpv_controller")
    params["gains_file"] = gains_file
    return ControllerSettings.from_dict(params)


def sample_events() -> list:
    """The phase-2 sample's input messages ``(receipt ns, topic, msg)`` in receipt order."""
    from lpv_sysid.io.bag import read_bag

    data = read_bag(
        os.path.join(SAMPLES, "phase2_sim", "bag_0000"), topics=[f"{NS}/{t}" for t in INPUTS]
    )
    return sorted((ns, t[len(NS) + 1 :], m) for t in data for ns, m in data[t])


def recorded_law_inputs(settings: Any) -> list:
    """``(t, x12, v_d, kappa u_e)`` of every law step of the runtime (the node's code) on the
    phase-2 sample at 250 Hz ticks: the inputs the law sees in flight."""
    from lpv_sysid.flight.controller import ControllerRuntime
    from lpv_sysid.io import messages

    rt = ControllerRuntime(settings, messages.MsgFactory.rosbags())
    seen = []
    step = rt.law.step

    def recording(t, x, v_d, u_e, a=None, j=None):
        seen.append((float(t), np.array(x), np.array(v_d), np.array(u_e)))
        return step(t, x, v_d, u_e, a, j)

    rt.law.step = recording  # type: ignore[method-assign]  # bench instrumentation
    events = sample_events()
    period = round(1e9 / settings.rate_hz)
    t0 = events[0][0]
    rt.start(t0 * 1e-9)
    nxt = t0 + period
    for ns, topic, msg in events:
        while nxt <= ns:
            rt.tick(nxt * 1e-9)
            nxt += period
        rt.on_message(topic, msg, ns * 1e-9)
    if rt.supervisor.event is not None or len(seen) < 1000:
        raise RuntimeError(f"sample replay aborted: {rt.supervisor.event}")
    return seen


def floor_law(law: Any):
    """The least numpy arithmetic of ``law``'s default path (module docstring)."""
    stack = law.stack  # the per-vertex [vec K_i | x0_i | u0_i | vec G_i], named blocks
    N, n, m, p = stack.W.shape[0], law.n_x, law.n_u, law.n_p
    K, x0, u0, Gx, Gu = stack.K, stack.x0, stack.u0, stack.Gx, stack.Gu
    gain = np.concatenate([K, np.broadcast_to(law.R, (N, m, law.n_e)), Gu, u0[:, :, None]], 2)
    xref = np.concatenate([Gx, x0[:, :, None]], 2)
    Wf = np.hstack([gain.reshape(N, -1), xref.reshape(N, -1)])
    c = n + law.n_e + 2 * p + 1
    gain_cols, xref_cols = slice(0, m * c), slice(m * c, None)
    lo, ir = law.vmin.tolist(), law.inv_range.tolist()

    def f(x, v_d, u_e, aj1):
        t = [min(max((v - a) * s, 0.0), 1.0) for v, a, s in zip(v_d.tolist(), lo, ir)]
        al = [1.0]
        for tk in t:
            al = [a * b for a in al for b in (1.0 - tk, tk)]
        row = np.array(al).dot(Wf)
        x_ref = row[xref_cols].reshape(n, 2 * p + 1).dot(aj1)
        return row[gain_cols].reshape(m, c).dot(np.concatenate([x - x_ref, u_e, aj1]))

    return f


def main() -> None:
    import tempfile

    from bench.harness import Page, Row, Stat, interleaved, load_average, status
    from lpv_sysid.control.law import LpvController
    from lpv_sysid.models.quadrotor import mixer

    load0 = load_average()
    page = Page(
        "lpv_law",
        "Runtime LPV law step (control/law/controller.py; issues 5, 15)",
        ".venv/bin/python -m bench.bench_lpv_law",
    )
    with tempfile.TemporaryDirectory() as tmp:
        settings = shipped_settings(shipped_gains(tmp))
        seq = recorded_law_inputs(settings)
        from lpv_sysid.io.formats import GainSchedule

        gs = GainSchedule.load(settings.gains_file)
    mix = mixer(settings.arm_length)
    cfg = settings.law_config()
    law = LpvController(gs, cfg, mix=mix)
    assert law.has_ff and law.has_jerk
    nff = LpvController(gs, type(cfg)(**{**cfg.__dict__, "feedforward": False}), mix=mix)
    fl = floor_law(law)
    # a and j as the law's filter produced them on this flight (the floor takes them given)
    aj1, sat = [], 0
    for t, x, v, e in seq:
        _, info = law.step(t, x, v, e)
        aj1.append(np.array(list(info["a_ff"]) + list(info["j_ff"]) + [1.0]))
        sat += info["saturated"]
    n = len(seq)

    def run(ctl):
        def go():
            ctl.reset()
            st = ctl.step
            for t, x, v, e in seq:
                st(t, x, v, e)

        return go

    def run_floor():
        for (_, x, v, e), s in zip(seq, aj1):
            fl(x, v, e, s)

    st = interleaved(
        {"default": run(law), "no_ff": run(nff), "floor": run_floor},
        number=1,
        repeat=15,
        clock=time.process_time,
    )
    per = {k: Stat([s / n for s in v.samples]) for k, v in st.items()}
    # tail of the default path: wall time of every step of 8 passes
    pc = time.perf_counter_ns
    wall = []
    for _ in range(8):
        law.reset()
        for t, x, v, e in seq:
            t0 = pc()
            law.step(t, x, v, e)
            wall.append((pc() - t0) * 1e-9)
    tail = Stat(wall)
    d, f0 = per["default"], per["floor"]
    ratio = d.median / f0.median
    page.add(
        f"## One `LpvController.step` on the default path ({n} steps of the phase-2 sample "
        f"flight at 250 Hz, {sat} of them saturated; CPU time per step, 15 interleaved passes)"
    )
    page.add()
    page.table(
        ["what", "median [p10-p90]", "vs floor"],
        [
            [
                "default path: config/lpv_controller.yaml, F_ff + F_jerk (filtered a, j), mixer, "
                "monitor",
                d.fmt(1e6, "us"),
                f"{ratio:.2f}x",
            ],
            [
                "the same without feedforward",
                per["no_ff"].fmt(1e6, "us"),
                f"{per['no_ff'].median / f0.median:.2f}x",
            ],
            [
                "floor: float weights + one alpha @ W + x_ref = G [a; j; 1] + the feedback "
                "product (no checks, filter, saturation, monitor)",
                f0.fmt(1e6, "us"),
                "1",
            ],
        ],
    )
    page.add(
        f"Tail of the default path (wall time of each of {len(wall)} steps): median "
        f"{tail.median * 1e6:.2f} us, p99 {tail.p99 * 1e6:.2f} us, max {max(wall) * 1e6:.0f} us."
    )
    page.add()
    page.add(
        "The step: input checks (shapes, NaN/inf of every input, time order), the derivative "
        "filter, the weights and the clamp flag on plain floats; one `alpha @ W_step` into a "
        "preallocated row whose views are the blended [K | R | G_u | u0; Mix^-1 (...)] and "
        "[G_x | x0]; two small products; the saturation test on the ESC commands of the same "
        "product; the monitor on plain floats. Before (this page's previous run): 19.6 us "
        "median on a random schedule of the same shape."
    )
    page.rows.append(
        Row(
            "runtime LPV law step",
            "5, 15",
            f"default path (shipped config, F_ff + F_jerk, mixer; recorded flight) "
            f"{d.fmt(1e6, 'us')} CPU, wall p99 {tail.p99 * 1e6:.1f} us; without feedforward "
            f"{per['no_ff'].median * 1e6:.1f} us (before: 19.6 us)",
            f"numpy floor of the same law {f0.median * 1e6:.1f} us",
            f"{ratio:.2f}x",
            "<= 10 us on the default path",
            status(d.median <= 10e-6, f"{d.median * 1e6:.1f} us"),
            order=6,
        )
    )
    page.write(load0)


if __name__ == "__main__":
    main()
