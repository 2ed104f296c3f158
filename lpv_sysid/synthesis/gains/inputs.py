"""What one `lpv-sysid synthesize` run works on (:class:`Inputs`, :func:`load_inputs`).

The synthesis config (its sections checked), the Lemma 1 options with the command-line
overrides, the models (the certified uncertainty set), the weights R, Q (a signals summary or
seed 0 Eqs. 27-28), the performance output C (Eq. 19b), the feedforward settings and the phase-2
design envelope.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Optional

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.synthesis.gains.config import SynthesisConfig

log = logging.getLogger(__name__)


def weights_from_config(
    cfg: SynthesisConfig, n_u: int, summary_path: str | None, cfg_path: str
) -> tuple[np.ndarray, np.ndarray, str]:
    """(R, Q, source) from a signals summary (R, Q entries) or from Eqs. (27)-(28)."""
    from lpv_sysid.io.files import read_yaml_mapping
    from lpv_sysid.synthesis.hinf import excitation_R, output_Q

    w = cfg.weights
    summary_path = summary_path or w.summary
    if summary_path:
        p = Path(summary_path)
        if not p.is_absolute() and not p.exists():
            p = Path(cfg_path).parent / p
        s = read_yaml_mapping(p, f"signals summary {p}")
        if "R" not in s or "Q" not in s:
            raise ConfigError(
                f"{p}: signals summary has no 'R'/'Q' (write it with weights in the signals "
                "config)"
            )
        R = np.array(s["R"], dtype=float)
        Q = np.array(s["Q"], dtype=float)
        if R.shape[0] != n_u or Q.ndim != 2 or Q.shape[0] != Q.shape[1]:
            raise ConfigError(f"{p}: R {R.shape} / Q {Q.shape} do not fit {n_u} inputs")
        return R, Q, str(p)
    T, mag_in, mag_out = w.T, w.input_magnitudes, w.output_magnitudes
    if T is None or mag_in is None or mag_out is None:
        missing = [
            k
            for k, v in zip(("T", "input_magnitudes", "output_magnitudes"), (T, mag_in, mag_out))
            if v is None
        ]
        raise ConfigError(f"{cfg_path}: weights.{missing[0]} missing (or give weights.summary)")
    R = excitation_R(list(mag_in), float(T))
    Q = output_Q(list(mag_out), float(T))
    if R.shape[0] != n_u:
        raise ConfigError(
            f"{cfg_path}: weights.input_magnitudes has {R.shape[0]} entries, the model {n_u} "
            "inputs"
        )
    return R, Q, "Eqs. (27)-(28)"


def design_from_summary(source: str) -> Optional[dict]:
    """``certificate.design`` (lpv_sysid.signals.excitation.design_envelope) when the weights came
    from a phase-2 signals summary (``source`` is its path), else None."""
    from lpv_sysid.io.files import read_yaml_mapping
    from lpv_sysid.signals.excitation import design_envelope

    if source.startswith("Eqs."):
        return None
    try:
        return design_envelope(
            read_yaml_mapping(source, f"signals summary {source}"),
            source=f"signals summary {Path(source).name}",
        )
    except ConfigError as exc:
        log.info("no design envelope from %s: %s", source, exc)
        return None


def velocity_index(cfg: SynthesisConfig, state_names: tuple) -> tuple[int, ...]:
    names = cfg.velocity_states
    try:
        return tuple(state_names.index(n) for n in names)
    except ValueError:
        raise ConfigError(
            f"velocity_states {list(names)} not all among the model states {list(state_names)}"
        ) from None


@dataclass
class Inputs:
    """What one synthesis run works on (:func:`load_inputs`)."""

    cfg: SynthesisConfig
    opts: Any  # synthesis.hinf.HinfOptions
    uncertainty: dict  # UncertaintySettings.to_dict(): what the certificate records
    feedforward: tuple[bool, dict, float]
    model: Any  # models.lpv.PolytopicModel
    raw: dict
    R: np.ndarray
    Q: np.ndarray
    weights_source: str
    vidx: tuple[int, ...]
    C: np.ndarray
    design: Optional[dict]
    rate_from_design: bool
    method: str
    t0: float
    #: what was loaded, for the user (one line each)
    notes: list[str] = field(default_factory=list)


def load_inputs(
    models: str,
    config: str,
    summary: Optional[str] = None,
    gamma: Optional[float] = None,
    solver: Optional[str] = None,
) -> Inputs:
    """Config, options (``gamma`` / ``solver`` override ``hinf.gamma`` / ``hinf.solver``),
    models, weights (``summary``: the signals summary.yaml with R and Q, overriding
    ``weights``) and design envelope of one synthesis; ``Inputs.notes`` says what was loaded."""
    from lpv_sysid.synthesis.hinf import HinfOptions, performance_matrix, resolve_method
    from lpv_sysid.synthesis.uncertainty_set import load_models

    cfg = SynthesisConfig.load(config)
    opts = cfg.hinf
    if gamma is not None or solver is not None:
        # the overrides go through the declared checks too (--gamma 0 / inf / nan refused)
        over: dict[str, Any] = {"gamma": gamma} if gamma is not None else {}
        if solver is not None:
            over["solver"] = solver
        d = {k: getattr(opts, k) for k in opts.__dataclass_fields__}
        opts = HinfOptions.from_dict({**d, **over})
    unc_cfg = cfg.uncertainty.to_dict()
    ff_cfg = cfg.feedforward
    ff = (ff_cfg.enabled, ff_cfg.layout.to_dict(), ff_cfg.cond_max)
    t0 = time.perf_counter()
    model, raw = load_models(models, cfg.uncertainty)
    R, Q, source = weights_from_config(cfg, model.n_u, summary, config)
    vidx = velocity_index(cfg, model.state_names)
    C = performance_matrix(Q, model.n_x, vidx)
    notes = [
        f"models: {models} ({model.n_vertices} vertices, {model.n_x} states, "
        f"{model.n_u} inputs); R, Q from {source}"
    ]
    if model.ts is not None:
        raise ConfigError(
            f"{models}: Lemma 1 is a continuous-time result; the models are discrete "
            f"(Ts={model.ts})"
        )
    design = design_from_summary(source)
    rate_from_design = False
    if opts.lyapunov == "rate" and opts.rate_bound == "design":
        if design is None:
            raise ConfigError(
                "hinf.rate_bound: design needs the phase-2 signals summary (weights.summary) "
                "for the design envelope's reference_rate"
            )
        opts = replace(opts, rate_bound=[float(x) for x in design["reference_rate"]])
        rate_from_design = True
    method = resolve_method(model, opts)
    return Inputs(
        cfg=cfg,
        opts=opts,
        uncertainty=unc_cfg,
        feedforward=ff,
        model=model,
        raw=raw,
        R=R,
        Q=Q,
        weights_source=source,
        vidx=vidx,
        C=C,
        design=design,
        rate_from_design=rate_from_design,
        method=method,
        t0=t0,
        notes=notes,
    )
