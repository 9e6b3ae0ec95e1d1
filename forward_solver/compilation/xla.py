"""XLA options that compile the solver's programs faster on a CPU: `enable_fast_compilation`.

XLA's CPU backend emits each fused loop either through its newer MLIR
fusion emitters (the default of JAX 0.10) or through its older LLVM loop
emitters (``--xla_cpu_use_fusion_emitters=false``). The solver's programs
are elementwise stencil loops over the grid, which both run equally fast,
and the older emitters compile them in 55-65% of the time. Measured on the
2-core development machine (2026-11-25, JAX 0.10.2, no persistent cache):

* the relaxation program of the default bay (17x64): 1.9 s -> 1.1-1.2 s of
  compiling; relaxation runtime the same within the run-to-run spread at
  17x64, 17x128, 17x256, 33x256 and 65x512;
* the default case of the command, in process: 11.9 s -> 7.3 s of compiling
  (172 programs), 18.9 s -> 14.5 s end to end, the same design to the last
  digit (1000 Pa, rms 2.5478e-3).

XLA reads ``XLA_FLAGS`` once, when JAX starts its backend (the first
computation of the process), so the option is an environment setting, not
a per-program one: JAX refuses ``jax.jit(..., compiler_options=...)`` on a
function nested in another's trace, and a top-level copy next to the nested
one compiled the same program twice. The ``optimise-pressure`` command and
the test suite call `enable_fast_compilation` before their first
computation; a library caller may do the same (or set ``XLA_FLAGS``). Other
backends (GPU) ignore the option.
"""

from __future__ import annotations

import os

__all__ = ["FAST_COMPILATION_FLAGS", "enable_fast_compilation"]

#: Added to ``XLA_FLAGS`` by `enable_fast_compilation`.
FAST_COMPILATION_FLAGS = ("--xla_cpu_use_fusion_emitters=false",)


def _backend_started() -> bool:
    try:
        from jax._src import xla_bridge  # (private: no public way to ask; without it, assume not)
        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):
        return False


def enable_fast_compilation() -> bool:
    """Add `FAST_COMPILATION_FLAGS` to ``XLA_FLAGS`` for the JAX backend this process starts.

    Call it before the process's first JAX computation. Nothing changes when
    ``XLA_FLAGS`` names the option already (the caller's choice stands) or
    when the backend has started (XLA read its flags then).

    Returns:
        Whether the flags were added.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    names = [flag.split("=")[0] for flag in FAST_COMPILATION_FLAGS]
    if any(name in flags for name in names) or _backend_started():
        return False
    os.environ["XLA_FLAGS"] = " ".join([flags, *FAST_COMPILATION_FLAGS]).strip()
    return True
