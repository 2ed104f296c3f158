"""lpv_sysid: safe large-domain system identification of unstable multirotors.

Two-phase method of Hopwood & Woolsey (seed 0): vertex LTI identification under a
baseline PX4 velocity controller, then robust polytopic LPV H-infinity control for
large-amplitude excitation. See README.md and docs/DESIGN.md.
"""

__version__ = "0.1.0"
