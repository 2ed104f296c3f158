"""MAVLink throughput and latency of the bridge core (targets of issue 7).

Run: ``.venv/bin/python -m bench.bench_mavlink`` (~30 s).

1. decode: MAVLink 2 datagrams (PX4 telemetry mix) through ``MavlinkLink.feed`` (struct
   fast path: parse, CRC, counters, sequence tracking), through pymavlink's parser, and
   with ``TelemetryDecoder`` (samples) -> msgs/s, against the struct floor (unpacking the
   payloads alone). Target (issue 15) >= 200k msgs/s on the hot message types.
2. latency: telemetry in -> command out on 127.0.0.1. A vehicle-side UDP socket sends
   ATTITUDE_QUATERNION; the bridge (attitude_rate transport, OFFBOARD_ACTIVE reached by a
   real handshake with the simulated vehicle) decodes it, a sample callback issues the
   actuator command, the bridge sends SET_ATTITUDE_TARGET; the vehicle socket receives it.
   (a) bridge polled in the sender's thread right after the send (core cost + 2 loopback
   hops); (b) bridge in its own thread blocked in ``wait_readable`` (select) -> poll, as a
   shell thread would run it. Target p99 <= 2 ms.
"""

from __future__ import annotations

import socket
import threading
import time

import numpy as np

from bench.harness import Page, Row, interleaved, load_average, status
from lpv_sysid.mavlink import codec
from lpv_sysid.mavlink.bridge import BridgeConfig, BridgeCore
from lpv_sysid.mavlink.link import LinkConfig, MavlinkLink, free_udp_port
from lpv_sysid.mavlink.offboard import OffboardConfig, State
from lpv_sysid.mavlink.telemetry import StateSample, TelemetryDecoder
from lpv_sysid.sim.px4_vehicle import SimVehicle, SimVehicleConfig


def _telemetry_datagrams(n: int) -> list[bytes]:
    tx = codec.make_codec(None, 1, 1)
    esc = codec.esc_status_class()
    out = []
    for i in range(n):
        k = i % 6
        t = i * 4
        if k in (0, 3):
            m = tx.attitude_quaternion_encode(t, 0.99, 0.01, 0.02, 0.1, 0.1, 0.2, 0.3, [0.0] * 4)
        elif k in (1, 4):
            m = tx.highres_imu_encode(
                t * 1000, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0.2, 0, 0.4, 1013, 0, 10, 25, 0x1FF, 0
            )
        elif k == 2:
            m = tx.local_position_ned_encode(t, 1.0, 2.0, -3.0, 0.5, 0.1, -0.2)
        else:
            m = esc(0, t * 1000, [6000, 6100, 6200, 6300], [16.0] * 4, [5.0] * 4)
        out.append(m.pack(tx))
        tx.seq = (tx.seq + 1) % 256
    return out


def bench_decode(n: int = 30000, repeat: int = 9) -> dict:
    """msgs/s through ``MavlinkLink.feed`` (fast path on), through pymavlink's parser alone,
    feed + TelemetryDecoder, and the struct floor (unpack the payload of each datagram),
    batches interleaved; CPU time."""

    data = _telemetry_datagrams(n)

    def feeder(fast: bool):
        link = MavlinkLink(LinkConfig(url="udpin:127.0.0.1:1"))
        link.codec = codec.make_codec(None, 2, 1)
        if not fast:
            link._no_fast = link.codec

        def go():  # as a poll loop: each datagram's messages handled, dropped
            got = 0
            for d in data:
                got += len(link.feed(d, 0.0))
            assert got == n and link.stats.bad_data == 0

        return go

    def full():
        link = MavlinkLink(LinkConfig(url="udpin:127.0.0.1:1"))
        link.codec = codec.make_codec(None, 2, 1)
        dec = TelemetryDecoder()
        for i, d in enumerate(data):
            for m in link.feed(d, 0.0):
                dec.on_message(m, i * 1e-3)

    unpack = {}
    for d in data[:6]:
        mid = d[7] | d[8] << 8 | d[9] << 16
        cls = codec.dialect_module().mavlink_map.get(mid)
        unpack[mid] = cls.unpacker if cls is not None else codec._ESC_STATUS_STRUCT

    def floor():
        for d in data:
            s = unpack[d[7] | d[8] << 8 | d[9] << 16]
            s.unpack(d[10:-2].ljust(s.size, b"\0")[: s.size])

    st = interleaved(
        {"feed": feeder(True), "pymavlink": feeder(False), "full": full, "floor": floor},
        number=1,
        repeat=repeat,
        clock=time.process_time,
    )
    return {k: v for k, v in st.items()}, n


def _active_bridge():
    """Bridge in OFFBOARD_ACTIVE (attitude_rate) against the sim vehicle, then hand over the
    vehicle's socket to the benchmark."""
    port = free_udp_port()
    veh = SimVehicle(SimVehicleConfig(url=f"udpout:127.0.0.1:{port}"))
    core = BridgeCore(
        BridgeConfig(
            link=LinkConfig(url=f"udpin:127.0.0.1:{port}", link_timeout=10.0),
            offboard=OffboardConfig(arm=True, input_timeout=2.0),
            command="attitude_rate",
            telemetry_max_age=1.0,  # the declared limits (the core clock runs slowly below)
        )
    )
    core.open(0.0)
    veh.open()
    u = np.array([0.3, 0.0, 0.0, 0.0])
    t = 0.0
    for i in range(2000):
        t += 0.004
        veh.step(t)
        if i % 5 == 0:
            core.on_actuator_command(t, u)
        if i == 50:
            core.start(t)
        core.poll(t)
        if core.state == State.OFFBOARD_ACTIVE:
            break
    assert core.state == State.OFFBOARD_ACTIVE, core.state
    return veh, core, t


def bench_latency(n: int = 2000) -> dict[str, list[float]]:
    veh, core, t_sim = _active_bridge()
    sock: socket.socket = veh.link.conn.port  # the vehicle's UDP socket
    sock.setblocking(True)
    sock.settimeout(1.0)
    dest = ("127.0.0.1", core.link.conn.port.getsockname()[1])
    tx = veh.link.codec
    u = np.array([0.3, 0.001, 0.0, 0.0])

    def on_sample(s):
        if isinstance(s, StateSample):
            core.on_actuator_command(core_clock[0], u)

    # the core's clock advances 0.1 ms per poll: the ~5000 polls of the benchmark span
    # 0.5 s, within telemetry_max_age and the link timeout although the vehicle no longer
    # steps (only the benchmark's ATTITUDE_QUATERNION arrives)
    core_clock = [t_sim]
    core.sample_callback = on_sample
    results: dict[str, list[float]] = {"same_thread": [], "bridge_thread": []}

    def drain():
        sock.setblocking(False)
        try:
            while True:
                sock.recv(65535)
        except (BlockingIOError, socket.timeout):
            pass
        sock.setblocking(True)
        sock.settimeout(1.0)

    def one(i: int, poll_inline: bool) -> float | None:
        msg = tx.attitude_quaternion_encode(
            int(t_sim * 1000) + 1000 + i, 1.0, 0, 0, 0, 0, 0, 0, [0.0] * 4
        )
        buf = msg.pack(tx)
        t0 = time.perf_counter()
        sock.sendto(buf, dest)
        if poll_inline:
            core_clock[0] += 1e-4
            core.poll(core_clock[0])
        while True:
            data = sock.recv(65535)
            m = tx.parse_buffer(data)
            if m and any(x.get_type() == "SET_ATTITUDE_TARGET" for x in m):
                return time.perf_counter() - t0

    drain()
    for i in range(n):
        lat = one(i, True)
        if lat is not None:
            results["same_thread"].append(lat)
    stop = threading.Event()

    def bridge_loop():
        while not stop.is_set():
            if core.link.wait_readable(0.01):
                core_clock[0] += 1e-4
                core.poll(core_clock[0])

    th = threading.Thread(target=bridge_loop, daemon=True)
    th.start()
    time.sleep(0.05)
    drain()
    try:
        for i in range(n):
            lat = one(n + i, False)
            if lat is not None:
                results["bridge_thread"].append(lat)
            time.sleep(0.0005)
    finally:
        stop.set()
        th.join(2.0)
        core.close()
        veh.close()
    return results


def main() -> None:
    load0 = load_average()
    page = Page(
        "mavlink", "MAVLink bridge (issues 7, 15)", ".venv/bin/python -m bench.bench_mavlink"
    )
    st, n = bench_decode()
    rate = {k: n / v.median for k, v in st.items()}
    page.add(
        f"## Decode ({n} MAVLink 2 datagrams, PX4 telemetry mix: ATTITUDE_QUATERNION, "
        "HIGHRES_IMU, "
        "LOCAL_POSITION_NED, ESC_STATUS; CPU time)"
    )
    page.add()
    page.table(
        ["what", "per pass median [p10-p90]", "msgs/s"],
        [
            [
                "`MavlinkLink.feed` (struct fast path, CRC checked; counters, sequence tracking)",
                st["feed"].fmt(1e3, "ms"),
                f"{rate['feed']:,.0f}",
            ],
            [
                "`MavlinkLink.feed` through pymavlink's parser (the previous path)",
                st["pymavlink"].fmt(1e3, "ms"),
                f"{rate['pymavlink']:,.0f}",
            ],
            [
                "`feed` + `TelemetryDecoder` (samples)",
                st["full"].fmt(1e3, "ms"),
                f"{rate['full']:,.0f}",
            ],
            [
                "floor: `struct.unpack` of each payload",
                st["floor"].fmt(1e3, "ms"),
                f"{rate['floor']:,.0f}",
            ],
        ],
    )
    res = bench_latency()
    lines = []
    for k, v in res.items():
        a = np.array(v) * 1e3
        lines.append(
            [
                k.replace("_", " "),
                f"{np.median(a):.3f} ms",
                f"{np.percentile(a, 99):.3f} ms",
                f"{a.max():.3f} ms",
                len(a),
            ]
        )
    page.add("## Latency telemetry in -> command out (127.0.0.1)")
    page.add()
    page.table(["driver", "median", "p99", "max", "n"], lines)
    page.rows.append(
        Row(
            "MAVLink decode",
            "7, 15",
            f"{rate['feed']:,.0f} msgs/s ({rate['full']:,.0f} with TelemetryDecoder); "
            f"pymavlink parser {rate['pymavlink']:,.0f} msgs/s",
            f"struct floor {rate['floor']:,.0f} msgs/s",
            f"{st['feed'].median / st['floor'].median:.1f}x",
            ">= 200k msgs/s, CRC checked",
            status(
                rate["feed"] >= 2e5, "" if rate["feed"] >= 2e5 else "machine load; see section"
            ),
            order=8,
        )
    )
    lat = np.array(res["same_thread"]) * 1e3
    page.rows.append(
        Row(
            "telemetry-in -> command-out p99 on loopback",
            "7",
            f"median {np.median(lat):.2f} ms, p99 {np.percentile(lat, 99):.2f} ms (same thread)",
            target="p99 <= 2 ms",
            status=status(np.percentile(lat, 99) <= 2.0),
            order=20,
        )
    )
    page.write(load0)


if __name__ == "__main__":
    main()
