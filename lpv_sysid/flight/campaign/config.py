"""Inputs of `lpv-sysid fly phase1`: the campaign file (:class:`FlyConfig`), the phase-1
excitation table and the bridge config of the campaign."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

from lpv_sysid.errors import ConfigError

if TYPE_CHECKING:
    import numpy as np  # annotations only: the CLI imports numpy when a command runs


# ================================================================================ config
@dataclass(frozen=True)
class FlyConfig:
    """``config/campaign.yaml`` (paths relative to the file's directory)."""

    campaign: Any  # CampaignConfig
    bridge_config: str = "mavlink_bridge.yaml"
    signals_config: str = "signals_phase1.yaml"
    identification_config: str = "identification.yaml"
    storage: str = "mcap"
    flight_log: bool = True
    preflight_timeout: float = 8.0
    link_timeout: float = 15.0  # s to wait for the vehicle's first HEARTBEAT
    loop_period: float = 0.005  # s, link poll period
    status_period: float = 1.0  # s, periodic status message in the bags
    source: str = ""

    KEYS = (
        "bridge_config",
        "signals_config",
        "identification_config",
        "campaign",
        "recording",
        "preflight",
        "runner",
    )

    @classmethod
    def from_dict(
        cls, d: Mapping[str, Any], base: str | Path = ".", source: str = ""
    ) -> "FlyConfig":
        from lpv_sysid.configuration.fields import check_keys, is_finite_number
        from lpv_sysid.control.campaign import CampaignConfig

        where = source or "campaign config"
        check_keys(d, cls.KEYS, where, list_allowed=True)
        base = Path(base)
        kw: dict[str, Any] = {"source": source}
        for k in ("bridge_config", "signals_config", "identification_config"):
            if k in d:
                if not isinstance(d[k], str) or not d[k]:
                    raise ConfigError(f"{where}: {k} must be a file name, got {d[k]!r}")
                kw[k] = str(base / d[k])
            else:
                kw[k] = str(base / getattr(cls, k))
        try:
            kw["campaign"] = CampaignConfig.from_dict(d.get("campaign") or {})
        except (ConfigError, TypeError) as exc:
            raise ConfigError(f"{where}: {exc}") from None
        rec = d.get("recording") or {}
        check_keys(rec, ("storage", "flight_log"), f"{where}: recording", list_allowed=True)
        if rec.get("storage", "mcap") not in ("mcap", "sqlite3"):
            raise ConfigError(
                f"{where}: recording.storage must be mcap or sqlite3, got {rec['storage']!r}"
            )
        kw["storage"] = rec.get("storage", "mcap")
        if not isinstance(rec.get("flight_log", True), bool):
            raise ConfigError(f"{where}: recording.flight_log must be true or false")
        kw["flight_log"] = rec.get("flight_log", True)
        pre = d.get("preflight") or {}
        check_keys(pre, ("timeout",), f"{where}: preflight", list_allowed=True)
        run = d.get("runner") or {}
        check_keys(
            run,
            ("link_timeout", "loop_period", "status_period"),
            f"{where}: runner",
            list_allowed=True,
        )
        for sect, key, name, lo, hi in (
            (pre, "timeout", "preflight_timeout", 0.5, 120.0),
            (run, "link_timeout", "link_timeout", 0.5, 600.0),
            (run, "loop_period", "loop_period", 0.0005, 0.05),
            (run, "status_period", "status_period", 0.05, 60.0),
        ):
            if key in sect:
                v = sect[key]
                if not is_finite_number(v) or not lo <= v <= hi:
                    raise ConfigError(
                        f"{where}: {name} must be a number in [{lo}, {hi}], got {v!r}"
                    )
                kw[name] = float(v)
        return cls(**kw)

    @classmethod
    def load(cls, path: str | Path) -> "FlyConfig":
        from lpv_sysid.io.files import read_yaml

        d = read_yaml(path)
        if not isinstance(d, dict):
            raise ConfigError(f"{path}: expected a mapping at top level")
        return cls.from_dict(d, Path(path).resolve().parent, str(path))


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
