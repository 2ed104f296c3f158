"""lpv_sysid.signals - excitation signals of seed 0 Sec. IV-V and seed 1 Sec. 3.4.

Modules (import what you need; nothing heavy is imported here):

* ``config``     - :class:`SignalsConfig` (frozen, ``from_dict`` names bad keys), ``load_config``
* ``multisine``  - ``design(config) -> SignalSet``: orthogonal phase-optimised multisines
* ``phase_opt``  - Schroeder phases, clipping + L_p peak-factor minimisation, zero-crossing shift
* ``weights``    - unit energy (Eq. 26), R (Eq. 27), Q (Eq. 28)
* ``metrics``    - RPF, correlation matrix, power spectra, harmonic content
* ``prbs``       - PRBS with min/max switching interval, maximal-length sequences
* ``maneuvers``  - frequency sweep, doublet, 3-2-1-1
* ``store``      - ``signals.npz`` / ``summary.yaml``
* ``plot``       - figure like seed 0 Figs. 5-7 (Agg canvas)
* ``excitation`` - the player (:class:`ExcitationCore`: O(1) lookup, fades, abort), its
  monotonic clock, the design envelope a certificate records, the phase-1 reference
"""
