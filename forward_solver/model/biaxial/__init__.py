"""The shop's biaxial test of its fabric, and the fibre law fitted to it (NumPy only, the bottom of the model layer).

``read_test`` reads and checks a test file (`readings`: one line naming the
file and what to change for a file that cannot be fitted, `TestFileError`);
``fit_law`` fits a strain-energy surface ``W(e_warp, e_weft)`` to it
(`fit`, `surface`): a `FittedLaw`, which `forward_solver.Fabric` takes as its
``law``. `synthetic` makes readings of a known law (the checks, and the
example test shipped with the command). docs/fabric_test.md says how to
write a test into the file and how to read the fit's report.
"""

from .fit import FittedLaw as FittedLaw
from .fit import fit_law as fit_law
from .readings import BiaxialTest as BiaxialTest
from .readings import TestFileError as TestFileError
from .readings import read_test as read_test
from .surface import EnergySurface as EnergySurface

__all__ = ["BiaxialTest", "EnergySurface", "FittedLaw", "TestFileError", "fit_law", "read_test"]
