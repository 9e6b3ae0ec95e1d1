"""The compile machinery, behind one boundary: what makes the solver's programs compile and load faster.

Nothing here changes a computed number beyond rounding (a ``light``
program's, `stored_jit`); it decides when and how the
solver's JAX programs are traced, compiled and kept: `stored` (top-level
programs kept between processes, `stored_jit`), `ahead` (the programs a cold
solve needs next, compiled on a second thread meanwhile, `Ahead`) and `xla`
(XLA's faster-compiling CPU loop emitters). Code outside this folder imports
these names from ``forward_solver.compilation`` only; the physics
(`forward_solver.forces`, `forward_solver.model`) does not import it at all
(docs/compilation.md).
"""

from .ahead import Ahead as Ahead
from .ahead import compiling as compiling
from .ahead import set_compile_ahead as set_compile_ahead
from .ahead import signature as signature
from .stored import LIGHT_OPTIONS as LIGHT_OPTIONS
from .stored import LOOP_OPTIONS as LOOP_OPTIONS
from .stored import program_store as program_store
from .stored import stored_jit as stored_jit
from .stored import use_program_store as use_program_store
from .xla import FAST_COMPILATION_FLAGS as FAST_COMPILATION_FLAGS
from .xla import enable_fast_compilation as enable_fast_compilation

__all__ = ["Ahead", "FAST_COMPILATION_FLAGS", "LIGHT_OPTIONS", "LOOP_OPTIONS", "compiling",
           "enable_fast_compilation", "program_store", "set_compile_ahead", "signature", "stored_jit",
           "use_program_store"]
