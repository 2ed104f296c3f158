"""Regenerate the sample bags of msg_samples/ by running the node shells in-process.

    .venv/bin/python msg_samples/make_samples.py [--out msg_samples]

The nodes run on the in-repo rclpy stand-in (test/support) with its simulated clock, so
the recordings are deterministic: the same graph as ``ros2 launch lpv_sysid sim.launch.py``
(sim_vehicle + excitation [+ lpv_controller] + data_logger), recorded by data_logger_node.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path[:0] = [ROOT, os.path.join(ROOT, "test", "support")]

import rclpy  # noqa: E402  (the stand-in)
import rclpy._standin as standin  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

CONFIG = os.path.join(ROOT, "config")


def _signals(config: str, tmp: str) -> str:
    out = os.path.join(tmp, os.path.basename(config).replace(".yaml", ""))
    subprocess.run(
        [
            sys.executable,
            "-m",
            "lpv_sysid.cli.main",
            "signals",
            "--config",
            os.path.join(CONFIG, config),
            "--out",
            out,
            "--no-plot",
        ],
        check=True,
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
    )
    return os.path.join(out, "signals.npz")


def _run(nodes, seconds: float) -> None:
    ex = SingleThreadedExecutor()
    for n in nodes:
        ex.add_node(n)
    standin.spin_for(ex, seconds)
    for n in nodes:
        n.destroy_node()


def _args(params_file: str, **params) -> list[str]:
    args = ["--ros-args", "--params-file", os.path.join(CONFIG, params_file)]
    for k, v in params.items():
        args += ["-p", f"{k}:={v}"]
    return args


def phase1(out_dir: str, signals: str, seconds: float = 5.0) -> str:
    """Phase 1 about the vertex (2, 0, 0) m/s: baseline + multisine, 1 s ramp."""
    from lpv_sysid.nodes.data_logger_node import DataLoggerNode
    from lpv_sysid.nodes.excitation_node import ExcitationNode
    from lpv_sysid.nodes.sim_vehicle_node import SimVehicleNode

    standin.reset()
    rclpy.init()
    path = os.path.join(out_dir, "phase1_sim")
    nodes = [
        SimVehicleNode(
            cli_args=_args(
                "sim_vehicle.yaml", mode="baseline", initial_velocity_frd="[2.0,0.0,0.0]", seed=1
            )
        ),
        ExcitationNode(
            cli_args=_args(
                "excitation_node.yaml",
                signals_file=signals,
                mode="phase1",
                vertex_frd="[2.0,0.0,0.0]",
                ramp_s=1.0,
                auto_start=True,
            )
        ),
        DataLoggerNode(
            cli_args=_args(
                "data_logger.yaml",
                out_dir=path,
                split_size_mb=0.0,
                description="phase 1 sample - sim_vehicle baseline, vertex (2, 0, 0) m/s FRD",
            )
        ),
    ]
    _run(nodes, seconds)
    rclpy.shutdown()
    return path


def phase2(out_dir: str, signals: str, gains: str, seconds: float = 5.0) -> str:
    """Phase 2 under the LPV controller (gains.yaml), excitation on, sim vehicle."""
    from lpv_sysid.nodes.data_logger_node import DataLoggerNode
    from lpv_sysid.nodes.excitation_node import ExcitationNode
    from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode
    from lpv_sysid.nodes.sim_vehicle_node import SimVehicleNode

    standin.reset()
    rclpy.init()
    path = os.path.join(out_dir, "phase2_sim")
    nodes = [
        SimVehicleNode(cli_args=_args("sim_vehicle.yaml", mode="lpv", seed=2)),
        ExcitationNode(
            cli_args=_args(
                "excitation_node.yaml",
                signals_file=signals,
                mode="phase2",
                ramp_s=1.0,
                auto_start=True,
            )
        ),
        LpvControllerNode(
            cli_args=_args("lpv_controller.yaml", gains_file=gains, auto_start=True)
        ),
        DataLoggerNode(
            cli_args=_args(
                "data_logger.yaml",
                out_dir=path,
                split_size_mb=0.0,
                gains_file=gains,
                description="phase 2 sample - LPV controller on sim_vehicle (lpv mode)",
            )
        ),
    ]
    _run(nodes, seconds)
    rclpy.shutdown()
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=HERE)
    ap.add_argument(
        "--gains",
        default=os.path.join(HERE, "gains.yaml"),
        help="gains.yaml for the phase-2 sample (written with LQR test gains when missing)",
    )
    args = ap.parse_args(argv)
    if not os.path.exists(args.gains):
        from lpv_test_gains import write_gains

        print("wrote", write_gains(args.gains, box=5.0))  # the box of signals_phase2.yaml
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("phase1_sim", "phase2_sim"):
            shutil.rmtree(os.path.join(args.out, name), ignore_errors=True)
        print("wrote", phase1(args.out, _signals("signals_phase1.yaml", tmp)))
        print("wrote", phase2(args.out, _signals("signals_phase2.yaml", tmp), args.gains))
    return 0


if __name__ == "__main__":
    sys.exit(main())
