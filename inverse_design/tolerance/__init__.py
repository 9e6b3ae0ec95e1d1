"""Tolerances: what the shop's scatter does to the cured wing, to first order and by Monte Carlo, and the
robust design that holds under it (docs/tolerances.md).

Production scatters (docs/tolerances.md): the pressure (one value for the
wing), the fabric's stiffnesses (per lot; each bay's panels are their own
lot), the cut lengths (per bay and fibre direction), the rib stations and the
rib outlines (per rib). Each source maps onto a parameter the solver already
differentiates (`model.ToleranceModel.bay_parameters`, per bay):

* `inputs`: each source's scatter (`Tolerance`), parsed (`parse_tolerances`), and the defaults.
* `model`: the tolerance parameters of a design, their map onto the bays' parameters, and the one
  per-bay Jacobian (`ToleranceModel.bay_jacobian`).
* `first_order`: `tolerance_analysis` (the linearised distributions and the budget) with its
  `Sampling`.
* `monte_carlo`: the Monte Carlo check, in process or on a Dask cluster.
* `robust`: the robust design's terms (``objective="robust"``, `robust.RobustTerms`).
"""

from .first_order import LINEAR_SAMPLES as LINEAR_SAMPLES
from .first_order import Sampling as Sampling
from .first_order import ToleranceAnalysis as ToleranceAnalysis
from .first_order import tolerance_analysis as tolerance_analysis
from .inputs import DEFAULT_TOLERANCES as DEFAULT_TOLERANCES
from .inputs import SOURCE_UNITS as SOURCE_UNITS
from .inputs import SOURCES as SOURCES
from .inputs import Tolerance as Tolerance
from .inputs import parse_tolerance as parse_tolerance
from .inputs import parse_tolerances as parse_tolerances
from .model import ToleranceModel as ToleranceModel
from .monte_carlo import SAMPLE_RTOL as SAMPLE_RTOL
from .monte_carlo import SCHEDULER_TIMEOUT_S as SCHEDULER_TIMEOUT_S
from .monte_carlo import connect_scheduler as connect_scheduler

__all__ = ["DEFAULT_TOLERANCES", "LINEAR_SAMPLES", "SAMPLE_RTOL", "SCHEDULER_TIMEOUT_S", "SOURCES", "SOURCE_UNITS",
           "Sampling", "Tolerance", "ToleranceAnalysis", "ToleranceModel", "connect_scheduler", "parse_tolerance",
           "parse_tolerances", "tolerance_analysis"]
