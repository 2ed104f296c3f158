"""data_logger_node: records the experiment topics to rosbag2 (mcap) with metadata.

Shell around :class:`lpv_sysid.io.recorder.Recorder`. Subscribes with ``raw=True`` (the
serialized CDR goes to the bag untouched, as ``ros2 bag record`` does) and stamps each
message with the node clock at reception. Splits into ``bag_0000``, ``bag_0001``, ... by
size / duration, writes ``experiment.yaml`` (config files, gains sha256, git revision,
counts, rates, drops) and closes every bag on shutdown: SIGINT/SIGTERM (also twice, a
terminal's Ctrl-C plus launch's forwarded SIGINT) only request the stop, and
:meth:`DataLoggerNode.begin_shutdown` closes the recorder before anything else runs
(nodes/shell.run); a node destroyed without ``run`` closes it in ``destroy_node``.
Drops reported by the middleware (QoS ``message_lost`` event) and rates go to ``status``.
Durability: the bag is flushed at least every ``flush_interval_s`` (a timer covers a stream
that stops), so a ``kill -9`` loses at most that much; ``experiment.yaml`` then says
``status: recording`` with the committed counts, and ``lpv-sysid bag repair OUT_DIR`` (also
run automatically when the logger is started on the same ``out_dir`` again) makes the bags
readable by ``ros2 bag`` / rosbags and the metadata ``incomplete``. On a full disk the bag
is closed readable and the node reports the error on ``status``.
Vehicle record: the bridge's ``vehicle_record`` (reliable, transient local: also the one
published before the logger started) becomes ``experiment.yaml``'s ``vehicle`` -- the same
mapping ``fly`` writes (:meth:`lpv_sysid.mavlink.telemetry.VehicleRecord.summary`), each
newer record replacing the older one.

    ros2 run lpv_sysid data_logger_node --ros-args --params-file config/data_logger.yaml \
        -p out_dir:=flight_07
"""

from __future__ import annotations

from dataclasses import dataclass

from rclpy.event_handler import SubscriptionEventCallbacks
from rosidl_runtime_py.utilities import get_message

from lpv_sysid.configuration import parameters
from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.io import messages
from lpv_sysid.io.bag import FLUSH_INTERVAL_S, STORAGES
from lpv_sysid.io.recorder import Recorder, RecorderConfig
from lpv_sysid.nodes import shell

NODE_NAME = "data_logger"


@dataclass(frozen=True)
class DataLoggerSettings(parameters.Settings):
    """The node's parameters (config/data_logger.yaml): the one declaration. The recorder's
    own configuration (:class:`~lpv_sysid.io.recorder.RecorderConfig`: resolved topic names,
    bytes) is built from it and checks the rest."""

    WHERE = "data_logger"

    out_dir: str = parameters.text(
        "lpv_sysid_log", "experiment directory (must not exist or be empty)", nonempty=True
    )
    storage: str = parameters.text("mcap", "rosbag2 storage", choices=STORAGES)
    topics: tuple = parameters.texts(
        tuple(shell.TOPIC_TYPES),
        "topics to record, relative to the namespace; 'name' for the "
        "lpv_sysid topics or 'name:pkg/msg/Type' for any other",
    )
    split_size_mb: float = parameters.double(
        0.0, "start a new bag after this many MB (0: never)", 0.0, 1.0e6
    )
    split_duration_s: float = parameters.double(
        0.0, "start a new bag after this long (0: never)", 0.0, 1.0e6
    )
    queue_depth: int = parameters.integer(1000, "subscription queue depth per topic", 1, 100000)
    config_files: tuple = parameters.texts((), "files copied verbatim into experiment.yaml")
    gains_file: str = parameters.text("", "gains.yaml to hash into the metadata")
    description: str = parameters.text("", "free text for experiment.yaml")
    status_rate_hz: float = parameters.double(1.0, "status publication rate [Hz]", 0.1, 100.0)
    flush_interval_s: float = parameters.double(
        FLUSH_INTERVAL_S,
        "flush the bag (mcap chunk to the OS / sqlite3 commit) at least this "
        "often: the most a kill -9 of the logger can lose [s]",
        0.01,
        1.0,
    )
    fsync: bool = parameters.flag(
        False, "fsync at every flush (also survives a power cut; slower on SD cards)"
    )

    def validate(self) -> None:
        parse_topics(self.topics)


#: the rclpy declarations, generated from the one declaration (DataLoggerSettings)
PARAMETERS = shell.settings_table(DataLoggerSettings)


def parse_topics(entries) -> dict[str, str]:
    """``{relative name: pkg/msg/Type}`` from the ``topics`` parameter."""
    out = {}
    for e in entries:
        name, _, typ = str(e).partition(":")
        if not typ:
            if name not in shell.TOPIC_TYPES:
                raise ConfigError(
                    f"parameter 'topics': {name!r} is not an lpv_sysid topic "
                    f"{sorted(shell.TOPIC_TYPES)}; write 'name:pkg/msg/Type'"
                )
            typ = shell.TOPIC_TYPES[name]
        out[name] = typ
    return out


class DataLoggerNode(shell.ShellNode):
    SETTINGS = DataLoggerSettings

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        self.settings = p = DataLoggerSettings.from_dict(self.params)
        rel = parse_topics(p.topics)
        topics = {self.resolve_topic_name(n): t for n, t in rel.items()}
        cfg = RecorderConfig(
            out_dir=p.out_dir,
            topics=topics,
            storage=p.storage,
            split_size_bytes=int(p.split_size_mb * 1e6),
            split_duration_s=p.split_duration_s,
            config_files=tuple(p.config_files),
            gains_file=p.gains_file,
            description=p.description,
            flush_interval_s=p.flush_interval_s,
            fsync=p.fsync,
        )
        self.recorder = Recorder(cfg)
        self.recorder.start(self.now_ns())
        self.recorder.annotate("clock", self.clock_record())
        self.f = messages.MsgFactory.rclpy()
        self.pub_status = shell.StatusPublisher(self)  # status and /diagnostics
        for name, typ in rel.items():
            full = self.resolve_topic_name(name)
            # the publishers' QoS (io/messages/topics.py: best effort sensors), volatile
            # (shell.qos_for), with the logger's queue depth
            qos = shell.qos_for(name)
            qos.depth = p.queue_depth
            events = SubscriptionEventCallbacks(message_lost=self._lost_cb(full))
            self.create_subscription(
                get_message(typ),
                name,
                self._record_cb(full),
                qos,
                event_callbacks=events,
                raw=True,
            )
        self.create_subscription(
            get_message(messages.VEHICLE_RECORD_TYPE),
            messages.VEHICLE_RECORD_TOPIC,
            self._vehicle_record_cb,
            shell.QOS_VEHICLE_RECORD,
        )
        self.vehicle_records = 0  # records written to experiment.yaml
        self.status_timer(p.status_rate_hz, self.publish_status)
        # a stream that stops still reaches the disk within flush_interval_s
        self.create_timer(p.flush_interval_s / 2, self._flush_cb)
        self.get_logger().info(f"recording {sorted(topics)} to {p.out_dir}")

    def clock_record(self) -> dict:
        """``clock`` of ``experiment.yaml``: the bag stamps are this node's ROS clock at
        reception -- the wall clock (epoch ns), or ``/clock`` with ``use_sim_time``. The
        vehicle record (``vehicle``: PX4's boot on the bridge's ROS clock, firmware,
        parameters, site) comes from the bridge on ``vehicle_record``
        (:meth:`_vehicle_record_cb`); on the same host and clock kind its times are on the
        bag clock with offset 0, as this record says."""
        sim = shell.clock_kind(self) == "ros_sim_time"
        return {
            "kind": shell.clock_kind(self),
            "offset_ns": 0,
            "meaning": "bag stamp = the data logger's ROS clock at reception "
            + ("(/clock: use_sim_time)" if sim else "(system wall clock, epoch ns)"),
        }

    def _vehicle_record_cb(self, msg):
        """The bridge's vehicle record -> ``experiment.yaml`` ``vehicle`` (a bad message is
        logged and skipped); a record on another kind of clock than the bags' is written
        with the mismatch stated in ``clock.vehicle_record_clock``."""
        if getattr(self, "_closed", False):
            return
        try:
            kind, record = messages.vehicle_record_from_msg(msg)
        except LpvSysidError as exc:
            self.get_logger().warning(f"vehicle_record ignored: {exc}", once=True)
            return
        try:
            own = shell.clock_kind(self)
            if kind != own:
                self.get_logger().error(
                    f"vehicle_record on a {kind} clock, the bags on {own}: its times "
                    "(vehicle.px4_clock) are not on the bag clock",
                    once=True,
                )
                self.recorder.annotate(
                    "clock", {**self.clock_record(), "vehicle_record_clock": kind}
                )
            self.recorder.annotate("vehicle", record)
            self.vehicle_records += 1
        except LpvSysidError as exc:
            self.get_logger().error(str(exc), once=True)

    def _flush_cb(self):
        try:
            self.recorder.flush_if_due()
        except LpvSysidError as exc:
            self.get_logger().error(str(exc), once=True)

    def _record_cb(self, topic):
        def cb(data):
            try:
                self.recorder.record(topic, self.now_ns(), data)
            except LpvSysidError as exc:
                # disk full / write error: what was written is closed and readable; say so
                self.get_logger().error(str(exc), once=True)

        return cb

    def _lost_cb(self, topic):
        def cb(info):
            self.recorder.note_dropped(topic, info.total_count_change)

        return cb

    def publish_status(self):
        rec = self.recorder
        values = {}
        for topic, s in rec.stats.items():
            values[f"{topic}.count"] = s.count
            values[f"{topic}.rate_hz"] = round(s.rate_hz, 3)
            values[f"{topic}.dropped"] = s.dropped
        values["bags"] = len(rec.bags)
        values["vehicle_records"] = self.vehicle_records
        level = "ERROR" if rec.error else "OK"
        msg = rec.error or ("recording" if rec.recording else "stopped")
        st = messages.diagnostic_status(
            self.f, level, self.get_fully_qualified_name(), msg, values
        )
        self.pub_status.publish(messages.diagnostic_array(self.f, self.now_ns(), [st]))

    def begin_shutdown(self):
        """Close the bag while the context is valid (nodes/shell.run): metadata.yaml and
        experiment.yaml are written before anything else can interrupt."""
        self._close_recording()

    def _close_recording(self):
        if getattr(self, "_closed", False):
            return
        self._closed = True
        try:
            self.recorder.stop(self.now_ns())
            self.get_logger().info(self.recorder.summary())
        except LpvSysidError as exc:
            self.get_logger().error(str(exc))

    def destroy_node(self):
        self._close_recording()  # no-op when begin_shutdown already closed it
        super().destroy_node()


def main(args=None):
    return shell.run(DataLoggerNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
