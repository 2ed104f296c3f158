"""The PX4 parameter protocol of the simulated vehicle: PARAM_REQUEST_READ,
PARAM_REQUEST_LIST and PARAM_SET answered with PARAM_VALUE (INT32 byte-wise, as PX4); a
PARAM_SET outside the parameter's range (:data:`~lpv_sysid.sim.px4_vehicle.config.PARAMS`)
is refused and answered with the old value;
the behaviour is described in :mod:`lpv_sysid.sim.px4_vehicle.vehicle`."""

from __future__ import annotations

import logging
from typing import Any

from lpv_sysid.mavlink import px4
from lpv_sysid.sim.px4_vehicle.config import PARAMS
from lpv_sysid.sim.px4_vehicle.state import VehicleState

log = logging.getLogger(__name__)


class ParamServer(VehicleState):
    """PARAM_* messages -> PARAM_VALUE."""

    def _param_request_read(self, m: Any) -> None:
        name = px4.param_id_str(m.param_id)
        if m.param_index >= 0:
            names = list(self.params)
            if m.param_index < len(names):
                self._send_param(names[m.param_index])
        elif name in self.params:
            self._send_param(name)

    def _param_set(self, m: Any, now: float) -> None:
        name = px4.param_id_str(m.param_id)
        if name not in self.params:
            return
        spec = PARAMS[name]
        value = px4.param_from_wire(m.param_value, spec.ptype)
        err = spec.check(name, value)
        if err is not None:
            log.warning(
                "PARAM_SET from %d/%d refused: %s; %s stays %g",
                m.get_srcSystem(),
                m.get_srcComponent(),
                err,
                name,
                self.param(name),
            )
            self.param_rejections.append((now, err))
        else:
            self.params[name] = (value, spec.ptype)
        self._send_param(name)

    def _send_param(self, name: str) -> None:
        names = list(self.params)
        value, ptype = self.params[name]
        self.link.send(
            self.link.codec.param_value_encode(
                name.encode("ascii"),
                px4.param_to_wire(value, ptype),
                ptype,
                len(names),
                names.index(name),
            )
        )
