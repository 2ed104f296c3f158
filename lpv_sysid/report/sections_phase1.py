"""Phase-1 time histories of a run directory's own bags (issue 23 item 3): each run's body
velocity against its reference with the scheduling box, the altitude and the ground track,
and a table of what every run did (duration, altitude change, distance travelled, largest
tracking error). Every figure and table names its data source (SIMULATED / SITL / HITL /
SIH / FLOWN, :func:`lpv_sysid.report.gonogo.provenance`).

Bags: the rosbag2 directories under ``phase1/`` (``lpv-sysid simulate phase1``, the demo) or
directly in the run directory (``lpv-sysid fly phase1``, ``lpv-sysid import``)."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lpv_sysid.report.document import Report, md_table
from lpv_sysid.report.gonogo import provenance

log = logging.getLogger(__name__)

#: at most this many runs are drawn (a campaign has 9)
MAX_RUNS = 12


@dataclass(frozen=True)
class Phase1Run:
    """One bag: times from its first state sample (s), NED position, FRD body velocity and the
    reference ``[u_d, v_d, w_d]`` (None without ``velocity_reference``)."""

    name: str
    t: np.ndarray
    pos_ned: np.ndarray
    v_body: np.ndarray
    t_ref: np.ndarray | None
    ref: np.ndarray | None


def phase1_bags(run_dir: Path) -> list[Path]:
    for d in (run_dir / "phase1", run_dir):
        if d.is_dir():
            bags = sorted(p for p in d.iterdir() if (p / "metadata.yaml").is_file())
            if bags:
                return bags
    return []


def read_phase1_run(bag: Path) -> Phase1Run:
    """The ``state`` and ``velocity_reference`` topics of one bag (any namespace)."""
    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io.messages import columns

    info = iobag.topic_info(str(bag))
    state = [t for t in info if t.rstrip("/").endswith("/state")]
    ref = [t for t in info if t.rstrip("/").endswith("/velocity_reference")]
    data = iobag.read_arrays(str(bag), topics=state[:1] + ref[:1])
    st = columns.states_from_odometry_columns(data[state[0]])
    t0 = float(st.t[0])
    t_ref = r = None
    if ref and len(data[ref[0]]):
        tr, v_d, _ = columns.reference_from_twist_columns(data[ref[0]])
        t_ref, r = tr - t0, v_d
    return Phase1Run(bag.name, st.t - t0, st.pos_ned, st.v_body, t_ref, r)


def run_rows(runs: list[Phase1Run]) -> list[list]:
    """Per run: duration, altitude change (m, up positive), horizontal distance from start to
    end and travelled (m), largest |v - v_d| (m/s)."""
    rows = []
    for r in runs:
        alt = -r.pos_ned[:, 2]
        steps = np.linalg.norm(np.diff(r.pos_ned[:, :2], axis=0), axis=1)
        err = None
        if r.ref is not None and r.t_ref is not None and r.t_ref.size > 1:
            vd = np.column_stack([np.interp(r.t, r.t_ref, r.ref[:, k]) for k in range(3)])
            err = float(np.max(np.linalg.norm(r.v_body - vd, axis=1)))
        rows.append(
            [
                r.name,
                float(r.t[-1]),
                float(alt[-1] - alt[0]),
                float(np.linalg.norm(r.pos_ned[-1, :2] - r.pos_ned[0, :2])),
                float(np.sum(steps)),
                err,
            ]
        )
    return rows


def plot_phase1(runs: list[Phase1Run], box, label: str, path: Path) -> Path:
    """Velocity vs reference (u, v, w) with the box edges, altitude, ground track."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lpv_sysid.report.plots import _save

    fig = plt.figure(figsize=(11, 10))
    gs = fig.add_gridspec(4, 2)
    axes = [fig.add_subplot(gs[i, :]) for i in range(3)]
    ax_alt, ax_xy = fig.add_subplot(gs[3, 0]), fig.add_subplot(gs[3, 1])
    for i, r in enumerate(runs):
        c = f"C{i % 10}"
        for k, ax in enumerate(axes):
            ax.plot(r.t, r.v_body[:, k], color=c, lw=0.8, label=r.name if k == 0 else None)
            if r.ref is not None and r.t_ref is not None:
                ax.plot(r.t_ref, r.ref[:, k], color=c, lw=0.8, ls="--")
        ax_alt.plot(r.t, -r.pos_ned[:, 2], color=c, lw=0.9)
        ax_xy.plot(r.pos_ned[:, 1], r.pos_ned[:, 0], color=c, lw=0.9)
        ax_xy.plot(r.pos_ned[0, 1], r.pos_ned[0, 0], "o", color=c, ms=3)
    for k, (ax, nm) in enumerate(zip(axes, ("u", "v", "w"))):
        if box is not None:
            for edge in (box[0][k], box[1][k]):
                ax.axhline(edge, color="k", lw=0.8, ls=":")
        ax.set_ylabel(f"{nm} [m/s]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=6, ncol=5, loc="upper right")
    axes[0].set_title(
        f"[{label}] phase-1 body velocity (solid) vs reference (dashed)"
        + ("; dotted: scheduling box" if box is not None else ""),
        fontsize=10,
    )
    axes[2].set_xlabel("time in run [s]")
    ax_alt.set_title(f"[{label}] altitude", fontsize=10)
    ax_alt.set_xlabel("time in run [s]")
    ax_alt.set_ylabel("height above start frame [m]")
    ax_alt.grid(alpha=0.3)
    ax_xy.set_title(f"[{label}] ground track (o: run start)", fontsize=10)
    ax_xy.set_xlabel("east [m]")
    ax_xy.set_ylabel("north [m]")
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_xy.grid(alpha=0.3)
    return _save(fig, path)


def phase1_section(r: Report) -> None:
    """The section (module docstring); nothing when the run directory holds no bags."""
    d = r.data
    bags = phase1_bags(d.run_dir)
    if not bags:
        return
    label = provenance(d)[0].label
    r.h(2, f"Phase 1: time histories ({label})")

    def body() -> None:
        runs = []
        for b in bags[:MAX_RUNS]:
            try:
                runs.append(read_phase1_run(b))
            except Exception as exc:  # noqa: BLE001 - one unreadable bag: say so, go on
                log.warning("%s: %s", b, exc)
                r.p(f"**{b.name} not drawn:** {exc}")
        if not runs:
            return
        box = None
        sched = (d.models or {}).get("scheduling")
        if isinstance(sched, dict) and "min" in sched and "max" in sched:
            box = (list(sched["min"]), list(sched["max"]))
        r.p(
            f"{len(runs)} phase-1 run(s) from `{bags[0].parent.name or '.'}` ({label} data): "
            "what each run did."
        )
        r.p(
            md_table(
                [
                    "run",
                    "duration [s]",
                    "altitude change [m]",
                    "start-end distance [m]",
                    "travelled [m]",
                    "max |v - v_d| [m/s]",
                ],
                run_rows(runs),
                fmt="{:.3g}",
            )
        )
        r.fig(
            plot_phase1(runs, box, label, r.fig_dir / "phase1_time_histories.png"),
            f"[{label}] Phase-1 runs: body velocity against the reference with the scheduling "
            "box, altitude and ground track",
        )

    r.guard("phase-1 time histories", body)


#: (rotor state, output state) pairs of the frequency-response view: the rotor-speed
#: combinations delta = Mix Omega (seed 0 Eq. 7; measured, states 8..11 of section 3) drive
#: the rigid body: collective -> w, roll -> p, pitch -> q, yaw -> r. The virtual inputs u are
#: not used: in phase 1 they are reconstructed from the same rotor speeds (Eq. 8 inverted),
#: a circular pair with coherence 1 by construction.
FR_PAIRS = (("dt", "w"), ("da", "p"), ("de", "q"), ("dr", "r"))
N_RIGID = 8  # phi, theta, u, v, w, p, q, r


def spectral_estimate(x: np.ndarray, u: np.ndarray, fs: float, nperseg: int):
    """Welch estimate of the MIMO frequency response ``H = S_yu S_uu^-1`` (all inputs at
    once: the channels are excited together) and each output's multiple coherence
    ``S_yu S_uu^-1 S_uy / S_yy``; ``(f [Hz], H (F, ny, nu), coherence (F, ny), share (F, nu))``
    with ``share`` each input's part of the input power in a bin. Multisines excite each
    channel on its own harmonics: in such a bin only that input's column of ``H`` is
    determined (pseudo-inverse), which is why the view plots a pair where its input
    dominates."""
    from scipy.signal import csd

    nu, ny = u.shape[1], x.shape[1]
    f, _ = csd(u[:, 0], u[:, 0], fs=fs, nperseg=nperseg)
    Suu = np.empty((f.size, nu, nu), complex)
    Syu = np.empty((f.size, ny, nu), complex)
    Syy = np.empty((f.size, ny))
    for i in range(nu):
        for j in range(nu):
            Suu[:, i, j] = csd(u[:, i], u[:, j], fs=fs, nperseg=nperseg)[1]
    for i in range(ny):
        Syy[:, i] = csd(x[:, i], x[:, i], fs=fs, nperseg=nperseg)[1].real
        for j in range(nu):
            # scipy: csd(a, b) = E[conj(A) B]; S_yu needs E[Y conj(U)] = csd(u, y)
            Syu[:, i, j] = csd(u[:, j], x[:, i], fs=fs, nperseg=nperseg)[1]
    inv = np.linalg.pinv(Suu)
    H = Syu @ inv
    coh = np.einsum("fij,fjk,fik->fi", Syu, inv, Syu.conj()).real / np.maximum(Syy, 1e-300)
    power = np.einsum("fii->fi", Suu).real
    share = power / np.maximum(power.sum(axis=1, keepdims=True), 1e-300)
    return f, H, np.clip(coh, 0.0, 1.0), share


def model_response(A, B, f: np.ndarray) -> np.ndarray:
    """``(jw I - A)^-1 B`` at ``f`` [Hz]: (F, n, m)."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    n = A.shape[0]
    return np.array([np.linalg.solve(2j * np.pi * fk * np.eye(n) - A, B) for fk in f])


def frequency_response_view(r: Report, bag: Path, vertex: dict, states, label) -> None:
    """Identified model vs spectral estimate with coherence on one phase-1 run: the rigid
    body rows of the vertex model driven by the measured rotor states,
    ``G = (sI - A_rr)^-1 A_rd`` (r: the 8 rigid-body states, d: the 4 rotor states)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lpv_sysid.ident import dataprep as dp
    from lpv_sysid.ident import vertex as vx
    from lpv_sysid.report.plots import _save

    cfg = vx.IdentificationConfig()
    data = dp.align(dp.streams_from_bag(bag), cfg).vertex
    seg = (data.t >= data.fit[0]) & (data.t < data.fit[1])
    fs = cfg.sample_rate
    xs = data.x[seg] - data.x[seg].mean(axis=0)
    y, d_in = xs[:, :N_RIGID], xs[:, N_RIGID:]
    nperseg = int(min(y.shape[0], 2 ** int(np.log2(max(64, y.shape[0] // 8)))))
    f, H, coh, _ = spectral_estimate(y, d_in, fs, nperseg)
    keep = (f > 0) & (f <= 5.0)
    f, H, coh = f[keep], H[keep], coh[keep]
    A = np.asarray(vertex["A"], dtype=float)
    G = model_response(A[:N_RIGID, :N_RIGID], A[:N_RIGID, N_RIGID:], f)
    rotor = list(states[N_RIGID:])
    fig, axes = plt.subplots(3, len(FR_PAIRS), figsize=(12, 7), sharex=True, squeeze=False)
    for c, (inp, out) in enumerate(FR_PAIRS):
        if inp not in rotor or out not in states[:N_RIGID]:
            continue
        j, i = rotor.index(inp), list(states).index(out)
        axm, axp, axc = axes[0][c], axes[1][c], axes[2][c]
        axm.semilogx(f, 20 * np.log10(np.abs(H[:, i, j]) + 1e-300), "k.", ms=3, label="data")
        axm.semilogx(f, 20 * np.log10(np.abs(G[:, i, j]) + 1e-300), "r-", lw=1, label="model")
        axp.semilogx(f, np.degrees(np.angle(H[:, i, j])), "k.", ms=3)
        axp.semilogx(f, np.degrees(np.angle(G[:, i, j])), "r-", lw=1)
        axc.semilogx(f, coh[:, i], "b.-", lw=0.8, ms=3)
        axm.set_title(f"[{label}] {inp} -> {out}", fontsize=9)
        axc.set_ylim(0, 1.05)
        axc.set_xlabel("frequency [Hz]")
        for ax in (axm, axp, axc):
            ax.grid(alpha=0.3, which="both")
    axes[0][0].set_ylabel("magnitude [dB]")
    axes[1][0].set_ylabel("phase [deg]")
    axes[2][0].set_ylabel("coherence")
    axes[0][0].legend(fontsize=7)
    r.fig(
        _save(fig, r.fig_dir / "frequency_response.png"),
        f"[{label}] Frequency responses of the identified vertex model {_point(vertex)} "
        "(red: its rigid-body rows driven by the rotor states, (sI - A_rr)^-1 A_rd) against "
        f"the spectral estimate of run `{bag.name}` (dots: Welch, the four measured rotor "
        "states at once, H = S_yu S_uu^-1) and the output's multiple coherence (blue): where "
        "the coherence is low the data say little",
    )


def _point(v: dict) -> str:
    return "[" + " ".join(f"{float(c):+g}" for c in v.get("scheduling", [])) + "]"


def frequency_section(r: Report) -> None:
    """The frequency-response view for the first phase-1 bag flown at a model vertex."""
    d = r.data
    models = d.models
    bags = phase1_bags(d.run_dir)
    if not isinstance(models, dict) or not bags:
        return
    from lpv_sysid.ident import dataprep as dp
    from lpv_sysid.ident import vertex as vx

    label = provenance(d)[0].label
    states = [str(s.get("name")) for s in models.get("states") or []]
    r.h(2, f"Identified frequency responses vs data ({label})")

    def body() -> None:
        cfg = vx.IdentificationConfig()
        for bag in bags:
            try:
                ar = dp.align(dp.streams_from_bag(bag), cfg)
                point = dp.snap_to_box(ar.vertex.scheduling, cfg)
            except Exception as exc:  # noqa: BLE001 - a bag that is no vertex run
                log.debug("%s: %s", bag, exc)
                continue
            for v in models.get("vertices") or []:
                if np.allclose(np.asarray(v.get("scheduling"), float), point):
                    frequency_response_view(r, bag, v, states, label)
                    return
        r.p("No phase-1 bag in the run directory was flown at a vertex of the models.")

    r.guard("frequency responses", body)
