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
