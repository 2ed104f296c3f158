"""Inputs of `lpv-sysid fly phase1`: the campaign file (:class:`FlyConfig`), the phase-1
excitation table and the bridge config of the campaign."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError

if TYPE_CHECKING:
    import numpy as np  # annotations only: the CLI imports numpy when a command runs


# ================================================================================ config
#: the files the campaign file names (relative paths: to the campaign file's directory)
_FILES = ("bridge_config", "signals_config", "identification_config")


@dataclass(frozen=True)
class FlyConfig:
    """``config/campaign.yaml`` (paths relative to the file's directory): the files, the
    ``campaign`` section (:class:`~lpv_sysid.control.campaign.CampaignConfig`) and the
    ``recording``, ``preflight`` and ``runner`` sections, whose keys are fields here."""

    campaign: Any  # CampaignConfig
    bridge_config: str = cf.text("mavlink_bridge.yaml", "bridge config: link, offboard, envelope")
    signals_config: str = cf.text(
        "signals_phase1.yaml", "excitation designed from this unless --signals is given"
    )
    identification_config: str = cf.text(
        "identification.yaml", "template of DIR/identification.yaml"
    )
    storage: str = cf.choice(
        "mcap", ("mcap", "sqlite3"), "rosbag2 storage of the runs", section="recording"
    )
    flight_log: bool = cf.flag(True, "whole flight in DIR/flight/ as well", section="recording")
    preflight_timeout: float = cf.number(
        8.0,
        "preflight checks within this [s]; 0.5 .. 120 s",
        lo=0.5,
        hi=120.0,
        unit=" s",
        section="preflight",
        key="timeout",
    )
    link_timeout: float = cf.number(
        15.0,
        "wait for the vehicle's first HEARTBEAT [s]; 0.5 .. 600 s",
        lo=0.5,
        hi=600.0,
        unit=" s",
        section="runner",
    )
    loop_period: float = cf.number(
        0.005,
        "link poll period [s]; 0.5 .. 50 ms (shorter spins, longer misses the setpoint rate)",
        lo=0.0005,
        hi=0.05,
        unit=" s",
        section="runner",
    )
    status_period: float = cf.number(
        1.0,
        "periodic status message in the bags [s]; 0.05 .. 60 s",
        lo=0.05,
        hi=60.0,
        unit=" s",
        section="runner",
    )
    source: str = ""
    #: the ``broken_loop`` section (:class:`~lpv_sysid.control.broken_loop.BrokenLoopConfig`):
    #: when present, the chain flies the broken-loop run after the vertex runs
    #: (:mod:`~lpv_sysid.flight.campaign.broken_loop`); absent or null: not flown
    broken_loop: Any = None

    @classmethod
    def from_dict(
        cls, d: Mapping[str, Any], base: str | Path = ".", source: str = ""
    ) -> "FlyConfig":
        """The campaign file ``d`` (read from ``source``; file names relative to ``base``).
        Errors name the key path (``campaign.radius``, ``runner.loop_period``)."""
        from lpv_sysid.control.campaign import CampaignConfig

        from lpv_sysid.control.broken_loop import BrokenLoopConfig

        kw = cf.parse_fields(cls, d, "", other_keys=("campaign", "broken_loop"))
        for k in _FILES:
            kw[k] = str(Path(base) / kw.get(k, getattr(cls, k)))
        campaign = CampaignConfig.from_dict(d.get("campaign") or {}, "campaign")
        bl = d.get("broken_loop")
        if bl is not None:
            if not isinstance(bl, Mapping):
                raise ConfigError(f"broken_loop: expected a mapping, got {bl!r}")
            bl = BrokenLoopConfig(**cf.parse_fields(BrokenLoopConfig, bl, "broken_loop"))
        return cls(campaign, source=source, broken_loop=bl, **kw)

    @classmethod
    def load(cls, path: str | Path) -> "FlyConfig":
        from lpv_sysid.io.files import read_yaml

        d = read_yaml(path)
        if not isinstance(d, dict):
            raise ConfigError(f"{path}: expected a mapping at top level")
        try:
            return cls.from_dict(d, Path(path).resolve().parent, str(path))
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from None


def load_signals(
    path: str | None, signals_config: str
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """The phase-1 excitation table ``(t, u, names)``: ``signals.npz`` when given, else
    designed from the signal config (``lpv-sysid signals``)."""
    from lpv_sysid.signals.store import load_npz

    if path:
        return load_npz(path)
    from lpv_sysid.signals.multisine import design, load_config

    sig = design(load_config(signals_config))
    return sig.t, sig.u, tuple(sig.names)


def bridge_config_for(path: str, url: str | None, campaign) -> Any:
    """The bridge config of the campaign: ``url`` overrides the link, arming is on (the
    campaign takes off), the velocity frame must be the campaign's."""
    from lpv_sysid.mavlink.bridge import BridgeConfig

    cfg = BridgeConfig.load(path)
    if cfg.command != "velocity":
        raise ConfigError(
            f"{path}: command must be 'velocity' for the phase-1 campaign, got {cfg.command!r}"
        )
    if cfg.velocity_frame != campaign.velocity_frame:
        raise ConfigError(
            f"{path}: velocity_frame {cfg.velocity_frame!r} differs from the campaign's "
            f"{campaign.velocity_frame!r} (the settle check measures in the command frame)"
        )
    link = dataclasses.replace(cfg.link, url=url) if url else cfg.link
    link.validate()
    return dataclasses.replace(
        cfg, link=link, offboard=dataclasses.replace(cfg.offboard, arm=True), auto_start=False
    )


def resume_config(cfg: FlyConfig, previous: str | Path) -> tuple[FlyConfig, list[str]]:
    """``fly phase1 --resume PREVIOUS``: the campaign of ``cfg`` without the runs a stopped
    flight completed (a campaign that does not fit one battery). The completed runs are the
    ``runs`` with ``complete: true`` in ``PREVIOUS/campaign_summary.yaml``; every run the
    previous flight planned must belong to ``cfg``'s campaign (the same box and vertices),
    else ConfigError. Returns (the config of the remaining runs, the completed run names);
    ConfigError when nothing is left to fly. ``identify`` takes the bags of both flights
    (``--bags PREVIOUS NEW``)."""
    from lpv_sysid.control.campaign import run_name
    from lpv_sysid.io.files import read_yaml_mapping

    f = Path(previous) / "campaign_summary.yaml"
    if not f.is_file():
        raise ConfigError(
            f"previous flight {previous}: no campaign_summary.yaml (not a phase-1 flight)"
        )
    s = read_yaml_mapping(f, finite=False)
    c = cfg.campaign
    corners = c.corners()
    centre = tuple(0.5 * (a + b) for a, b in zip(c.box_min, c.box_max))
    names = {run_name(v): i + 1 for i, v in enumerate(corners)}
    hover = {"hover_validation", "centre_validation"}
    planned = [str(p.get("name")) for p in s.get("plan") or []]
    foreign = [n for n in planned if n not in names and n not in hover]
    if foreign:
        raise ConfigError(
            f"previous flight {previous}: runs {foreign} are not vertices of this campaign's box "
            f"{list(c.box_min)}..{list(c.box_max)}; resume with the stopped flight's config"
        )
    done = [str(r.get("name")) for r in s.get("runs") or [] if r.get("complete")]
    wanted = list(c.vertices) if c.vertices is not None else list(range(1, 9))
    left = [i for i in wanted if run_name(corners[i - 1]) not in done]
    hover_left = c.hover_validation and not (hover & set(done))
    if not left:
        what = "only the hover validation run is" if hover_left else "no run is"
        raise ConfigError(
            f"previous flight {previous}: every vertex was completed ({len(done)} runs); "
            f"{what} left "
            f"(centre {list(centre)})"
        )
    camp = dataclasses.replace(c, vertices=tuple(left), hover_validation=bool(hover_left))
    camp.validate()
    return dataclasses.replace(cfg, campaign=camp), done
