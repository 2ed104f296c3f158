"""The whole two-phase job on a connected PX4 (``lpv-sysid chain``): phase-1 campaign ->
rate-plant identification -> signals -> synthesis and verification -> phase-2 flight ->
report. The steps: :mod:`~lpv_sysid.flight.chain.steps`; the report:
:mod:`~lpv_sysid.flight.chain.report`.
"""

from __future__ import annotations

from lpv_sysid.flight.chain.steps import campaign_bags, chain, identify_rate_runs

__all__ = [
    "campaign_bags",
    "chain",
    "identify_rate_runs",
]
