"""XLA options that compile the solver's programs faster on a CPU: `enable_fast_compilation` (docs/compilation.md).

XLA's CPU backend emits each fused loop through its newer MLIR fusion
emitters (the default of JAX 0.10) or its older LLVM loop emitters
(``--xla_cpu_use_fusion_emitters=false``). The solver's stencil loops run
equally fast either way, and the older emitters compile them in 55-65% of
the time. Measured on the 2-core development machine (2026-11-25, JAX
0.10.2, no persistent cache): the default bay's relaxation program (17x64)
1.9 s -> 1.1-1.2 s of compiling, its runtime the same within the spread at
17x64 to 65x512; the command's default case 11.9 s -> 7.3 s of compiling
(172 programs), 18.9 s -> 14.5 s end to end, the same design to the last
digit.

XLA reads ``XLA_FLAGS`` once, when JAX starts its backend, so the option is
an environment setting, not a per-program one (JAX refuses
``compiler_options`` on a function nested in another's trace, and a
top-level copy compiled the same program twice). Other backends ignore it.
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
