"""The layout of seed 0 Table 1 (vertex equilibria) and the seed's own values.

One declaration of the trim-table columns: the state each column shows, its unit and the
scale from the model's SI value (angles in degrees), and the key the phase-1 tables
(``trims.yaml`` of the simulation, ``campaign_summary.yaml`` of a flight) use for it.
"""

from __future__ import annotations

import math

#: Seed 0 Table 1 (flight-data vertex equilibria), in Table 1 row order, for comparison:
#: vertex (u_d, v_d, w_d) -> the values of :data:`TRIM_COLUMNS`
SEED0_TABLE1 = {
    (-5, -5, -5): (-4.99, -5.04, -4.20, -10.87, 9.28, 691.4, -36.7, 29.0, 310.5),
    (5, -5, -5): (4.95, -5.04, -4.17, -10.44, -8.05, 685.0, -34.1, -1.5, 39.2),
    (-5, 5, -5): (-5.01, 5.03, -3.95, 8.55, 8.11, 689.0, -2.8, 25.3, 34.9),
    (5, 5, -5): (5.03, 5.01, -4.00, 8.04, -8.98, 679.5, -5.8, -4.0, 305.4),
    (-5, -5, 5): (-4.83, -4.68, 2.88, -5.00, 3.17, 554.9, -45.0, 28.0, 367.6),
    (5, -5, 5): (4.73, -4.61, 2.72, -5.14, -4.08, 521.8, -34.6, -18.3, 158.9),
    (-5, 5, 5): (-4.85, 4.75, 3.00, 3.80, 3.00, 546.9, 14.0, 23.4, -9.8),
    (5, 5, 5): (4.64, 4.73, 2.86, 3.85, -4.83, 525.8, 3.49, -15.8, 298.1),
}
#: (state, unit, scale from SI, table key) per column of seed 0 Table 1
TRIM_TABLE = (
    ("u", "m/s", 1.0, "u0"),
    ("v", "m/s", 1.0, "v0"),
    ("w", "m/s", 1.0, "w0"),
    ("phi", "deg", 180 / math.pi, "phi0_deg"),
    ("theta", "deg", 180 / math.pi, "theta0_deg"),
    ("dt", "rad/s", 1.0, "dt0"),
    ("da", "m*rad/s", 1.0, "da0"),
    ("de", "m*rad/s", 1.0, "de0"),
    ("dr", "rad/s", 1.0, "dr0"),
)
#: the table keys of :data:`TRIM_TABLE`
TRIM_COLUMNS = tuple(key for _, _, _, key in TRIM_TABLE)
