"""Studies over many simulated airframes or samples: evidence about the method, not a step
of it. :mod:`~lpv_sysid.studies.coverage`: do the identified intervals cover the true
linearisation (``lpv-sysid coverage``, docs/identification_coverage.md)?
"""
