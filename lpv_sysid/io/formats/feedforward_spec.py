"""The top-level ``feedforward`` of ``gains.yaml`` (:class:`FeedforwardSpec`): which states
the rows and columns of the per-vertex ``F_ff`` / ``F_jerk`` stand for, strictly validated
(the file: :mod:`lpv_sysid.io.formats.gains`; the law: :mod:`lpv_sysid.synthesis.feedforward`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from lpv_sysid.io.formats.field_checker import FieldChecker, kind_of


@dataclass(frozen=True)
class FeedforwardSpec:
    """Top-level ``feedforward`` of gains.yaml: the layout of the per-vertex ``F_ff``
    (:class:`lpv_sysid.synthesis.feedforward.FeedforwardLayout`). Absent = no feedforward."""

    free_states: tuple
    accelerated_states: tuple
    held_states: tuple
    kinematic_states: tuple = ()  # jerk term (both non-empty): per-vertex F_jerk
    rate_states: tuple = ()

    @property
    def has_jerk(self) -> bool:
        return bool(self.kinematic_states) and bool(self.rate_states)

    def to_dict(self) -> dict:
        d = {
            "free_states": list(self.free_states),
            "accelerated_states": list(self.accelerated_states),
            "held_states": list(self.held_states),
        }
        if self.has_jerk:
            d["kinematic_states"] = list(self.kinematic_states)
            d["rate_states"] = list(self.rate_states)
        return d

    def shape(self, n_u: int) -> tuple:
        return (len(self.free_states) + n_u, len(self.accelerated_states))

    def jerk_shape(self, n_u: int) -> Optional[tuple]:
        if not self.has_jerk:
            return None
        return (len(self.free_states) + n_u + len(self.rate_states), len(self.accelerated_states))

    @classmethod
    def parse(
        cls, v: FieldChecker, d, state_names: tuple, n_u: int, n_p: int, path: str = "feedforward"
    ) -> "FeedforwardSpec":
        v.mapping(
            d,
            path,
            ("free_states", "accelerated_states", "held_states"),
            ("kinematic_states", "rate_states"),
        )
        if ("kinematic_states" in d) != ("rate_states" in d):
            v.fail(path, "kinematic_states and rate_states go together (the jerk term needs both)")
        got: dict[str, tuple] = {}
        for k in (
            "free_states",
            "accelerated_states",
            "held_states",
            "kinematic_states",
            "rate_states",
        ):
            if k not in d:
                got[k] = ()
                continue
            lst = d[k]
            if not isinstance(lst, list) or not lst:
                v.fail(
                    f"{path}.{k}", f"expected a non-empty list of state names, got {kind_of(lst)}"
                )
            names = tuple(v.string(s, f"{path}.{k}[{j}]") for j, s in enumerate(lst))
            bad = [s for s in names if s not in state_names]
            if bad:
                v.fail(f"{path}.{k}", f"{bad} are not state names {list(state_names)}")
            if len(set(names)) != len(names):
                v.fail(f"{path}.{k}", f"duplicate names in {list(names)}")
            got[k] = names
        if len(got["accelerated_states"]) != n_p:
            v.fail(
                f"{path}.accelerated_states",
                f"expected {n_p} entries (one per scheduling axis), "
                f"got {len(got['accelerated_states'])}",
            )
        if set(got["free_states"]) & set(got["accelerated_states"]):
            v.fail(path, "a state cannot be both free and accelerated")
        if (
            len(got["accelerated_states"]) + len(got["held_states"])
            != len(got["free_states"]) + n_u
        ):
            v.fail(
                path,
                "the feedforward system must be square: "
                "accelerated + held rows = free states + inputs",
            )
        if not set(got["kinematic_states"]) <= set(got["free_states"]):
            v.fail(f"{path}.kinematic_states", "must be among the free states")
        return cls(
            got["free_states"],
            got["accelerated_states"],
            got["held_states"],
            got["kinematic_states"],
            got["rate_states"],
        )
