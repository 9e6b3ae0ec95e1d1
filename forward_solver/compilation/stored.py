"""Top-level programs kept between processes as exported StableHLO (`jax.export`); docs/compilation.md.

JAX's persistent compilation cache keys a program on its lowered module, so
every process still traces and lowers each program before it can look it
up: profiled in a cached run of the default case on the 2-core development
machine, 1.4 s of tracing and 0.9 s of lowering, most of it the solver's few
large top-level programs. `stored_jit` is ``jax.jit`` for such a program:
while a store is in use (`use_program_store`), a call with concrete
arguments runs the program exported for that call's signature, loaded from
the store or exported now and written there (docs/compilation.md gives what
it saves and costs). Called with tracers, or with no store in use (the
library's default), it is the jitted function itself; a program that cannot
be exported (a host callback) runs as jitted. The exported module is the
jitted program's own StableHLO, so the results are the same.

A program that runs briefly (a setup step, a relaxation of a small grid)
may be declared ``light``: its top-level calls compile with `LIGHT_OPTIONS`
(LLVM's optimisation off), in a third of the time, and run slower, which a
few calls do not notice (docs/compilation.md gives both). The results differ
from a full compilation's by rounding only (the order LLVM gives a reduction).
A program whose run is a long loop (the relaxation) may be declared ``loop``:
its other top-level calls compile with `LOOP_OPTIONS`, XLA's default level
stated, which a global ``XLA_FLAGS`` setting cannot lower. A call under a
transformation is part of its caller's program and compiles as the caller
does.

An entry's file name is a digest of the function, its static arguments, the
avals of its array arguments, the float64 setting, this package's source and
its siblings', JAX and jaxlib, ``XLA_FLAGS`` and the platform. Loading an
entry unpickles its output structure: keep the store in a folder only you
write. An entry that fails to load is exported again and replaced (written
to a temporary file, then renamed, so a concurrent run never reads half a
file).
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import os
import pickle
import tempfile
import threading
from pathlib import Path

import jax
import jaxlib

__all__ = ["LIGHT_OPTIONS", "LOOP_OPTIONS", "stored_jit", "use_program_store", "program_store"]

#: XLA's options of a ``light`` program's top-level compilation (`stored_jit`): LLVM's optimisation
#: level 0 (XLA's own graph passes still run). Measured on the 2-core development machine: the
#: relaxation program of a 17x64 bay compiles in 0.35 s against 1.0 s and relaxes in 0.12 s against
#: 0.016 s (0.64 s against 0.12 s at 33x128: docs/compilation.md, `benchmarks/light_programs.py`).
LIGHT_OPTIONS = {"xla_backend_optimization_level": 0}
#: XLA's options of a program whose run is a long loop of small steps (the paper's explicit scheme,
#: `forward_solver.simulate`; a ``loop`` program's calls that are not light, the relaxation's): LLVM's
#: full optimisation, XLA's own default level stated, so that a global ``XLA_FLAGS`` setting (the test
#: suite's level 0) does not slow every step. Measured on the 2-core development machine: the scheme
#: run to rest on a 9x32 bay took 41 s at level 0 against 11 s.
LOOP_OPTIONS = {"xla_backend_optimization_level": 3}

#: The packages whose source shapes the programs.
_PACKAGES = ("forward_solver", "inverse_design", "targets")
_FOLDER: Path | None = None
_VERSION: str | None = None
_LOCK = threading.Lock()


def use_program_store(folder) -> Path | None:
    """Keep the `stored_jit` programs in ``folder`` (created; None: no store, every call jitted as
    usual). Returns the previous folder."""
    global _FOLDER
    previous = _FOLDER
    if folder is not None:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
    _FOLDER = folder
    return previous


def program_store() -> Path | None:
    """The folder of the store in use, or None."""
    return _FOLDER


def _version() -> str:
    """One digest of what, besides a call's arguments, decides its program (module docstring)."""
    global _VERSION
    with _LOCK:
        if _VERSION is None:
            digest = hashlib.sha256()
            root = Path(__file__).resolve().parents[2]  # the repository: forward_solver/compilation/stored.py
            for package in _PACKAGES:
                for path in sorted((root / package).rglob("*.py")):
                    digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes())
            for part in (jax.__version__, jaxlib.__version__, os.environ.get("XLA_FLAGS", ""),
                         jax.default_backend()):
                digest.update(b"\0" + part.encode())
            _VERSION = digest.hexdigest()
    return _VERSION


class _Stored:
    """A jitted function whose concrete calls run stored exported programs (module docstring)."""

    def __init__(self, function, static_argnames: tuple, light, loop: bool):
        self._jitted = jax.jit(function, static_argnames=static_argnames)
        self._light = light  # False, True, or a function of the dynamic arguments (by name)
        self._light_jitted = jax.jit(function, static_argnames=static_argnames,
                                     compiler_options=LIGHT_OPTIONS) if light else None
        # (a loop program's other top-level calls: `LOOP_OPTIONS`, never inside a trace, which refuses them)
        self._loop_jitted = jax.jit(function, static_argnames=static_argnames,
                                    compiler_options=LOOP_OPTIONS) if loop else None
        self._signature = inspect.signature(function)
        self._static = frozenset(static_argnames)
        self._name = f"{function.__module__}.{function.__qualname__}"
        self._calls: dict = {}  # the signature's key -> (jitted exported call, output structure)
        self._lock = threading.Lock()
        if any(p.kind is inspect.Parameter.VAR_POSITIONAL for p in self._signature.parameters.values()):
            raise TypeError(f"stored_jit: {self._name} takes *args; name its arguments")
        functools.update_wrapper(self, function)

    def _split(self, args, kwargs):
        """The static arguments (sorted by name) and the dynamic ones (a dict by name)."""
        bound = self._signature.bind(*args, **kwargs)
        bound.apply_defaults()
        static = tuple(sorted((n, v) for n, v in bound.arguments.items() if n in self._static))
        return static, {n: v for n, v in bound.arguments.items() if n not in self._static}

    def _is_light(self, dynamic) -> bool:
        return self._light if isinstance(self._light, bool) else bool(self._light(**dynamic))

    def _top_level(self, args, kwargs):
        """The jitted function a call without a store takes: for a call with concrete arguments, the
        light one of a light program's light call, the loop one of a loop program's other calls
        (module docstring); else the plain one."""
        if self._light_jitted is None and self._loop_jitted is None:
            return self._jitted
        _, dynamic = self._split(args, kwargs)
        if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(dynamic)):
            return self._jitted
        if self._light_jitted is not None and self._is_light(dynamic):
            return self._light_jitted
        return self._loop_jitted or self._jitted

    def _entry(self, args, kwargs):
        """``(entry, leaves)`` of a call: ``entry`` is ``(jitted exported call, output structure)``,
        or None where the call runs jitted (a tracer among the arguments, a program that cannot be
        exported)."""
        static, dynamic = self._split(args, kwargs)
        leaves, tree = jax.tree_util.tree_flatten(dynamic)
        if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
            return None, leaves
        # (dtype objects, not their names: naming them was a tenth of a warm 40-cell design's dispatch)
        key = (static, tree, jax.config.jax_enable_x64, tuple(
            (leaf.shape, leaf.dtype, getattr(leaf, "weak_type", False))
            if hasattr(leaf, "shape") and hasattr(leaf, "dtype") else type(leaf) for leaf in leaves))
        entry = self._calls.get(key)
        if entry is None:
            with self._lock:  # (the compile-ahead thread and the solve may ask at once)
                entry = self._calls.get(key)
                if entry is None:
                    entry = self._calls[key] = self._load(key, static, tree, leaves, self._is_light(dynamic))
        return entry or None, leaves

    def __call__(self, *args, **kwargs):
        if _FOLDER is not None:
            entry, leaves = self._entry(args, kwargs)
            if entry is not None:
                call, out_tree = entry
                return jax.tree_util.tree_unflatten(out_tree, call(*leaves))
        return self._top_level(args, kwargs)(*args, **kwargs)

    def __getattr__(self, name):  # the rest of ``jax.jit``'s interface (``trace``, ``_cache_size``, ...)
        if name.startswith("__") or name == "_jitted":
            raise AttributeError(name)
        return getattr(self._jitted, name)

    def lower(self, *args, **kwargs):
        """``jax.jit``'s ``lower``, for `ahead.compiling`: with a store, the lowered stored program
        of this call (its ``compile()`` is then the program the call takes)."""
        if _FOLDER is not None:
            entry, leaves = self._entry(args, kwargs)
            if entry is not None:
                return entry[0].lower(*leaves)
        return self._top_level(args, kwargs).lower(*args, **kwargs)

    def _load(self, key, static, tree, leaves, light: bool):
        """``(jitted exported call, output structure)`` for ``key``, loaded or exported (compiled with
        `LIGHT_OPTIONS` if ``light``, else a loop program's `LOOP_OPTIONS`); False if the program
        cannot be exported."""
        options = LIGHT_OPTIONS if light else (LOOP_OPTIONS if self._loop_jitted is not None else None)
        named = key[:3] + (tuple((tuple(a[0]), str(a[1]), bool(a[2])) if isinstance(a, tuple) else a.__name__
                                 for a in key[3]),)  # (the key as the digest of its file names it)
        digest = hashlib.sha256(f"{_version()}\0{self._name}\0{named!r}".encode()).hexdigest()[:32]
        path = _FOLDER / f"{self._name.rsplit('.', 1)[-1]}-{digest}.bin"
        try:
            blob, out_tree = pickle.loads(path.read_bytes())
            return jax.jit(jax.export.deserialize(blob).call, compiler_options=options), out_tree
        except Exception:  # noqa: BLE001 - missing, half-written by a stopped run, or from elsewhere: export
            pass
        held = {}

        def flat(*flat_leaves):
            out = self._jitted(**dict(static), **jax.tree_util.tree_unflatten(tree, flat_leaves))
            out_leaves, held["tree"] = jax.tree_util.tree_flatten(out)
            return out_leaves

        try:
            exported = jax.export.export(jax.jit(flat))(*leaves)
        except (ValueError, NotImplementedError, TypeError):  # e.g. a host callback: not exportable
            return False
        _write(path, pickle.dumps((exported.serialize(), held["tree"])))
        return jax.jit(exported.call, compiler_options=options), held["tree"]


def _write(path: Path, data: bytes) -> None:
    """``data`` to ``path`` by a rename (a store that cannot be written is left as it is)."""
    try:
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=".tmp-", delete=False) as file:
            file.write(data)
        os.replace(file.name, path)
    except OSError:
        try:
            os.unlink(file.name)
        except (OSError, UnboundLocalError):
            pass


def stored_jit(function=None, *, static_argnames=(), light=False, loop=False):
    """``jax.jit(function, static_argnames=...)``, kept between processes while a store is in use
    (module docstring). Use as ``@stored_jit`` or ``@stored_jit(static_argnames=(...))``.

    ``light``: compile the top-level calls with `LIGHT_OPTIONS` (module docstring): True, or a
    function of the call's dynamic arguments (by name; of their shapes only, as a program is one
    per shape) saying whether this call's program is light. ``loop``: the program's run is a long loop;
    its other top-level calls compile with `LOOP_OPTIONS`."""
    if function is None:
        return functools.partial(stored_jit, static_argnames=static_argnames, light=light, loop=loop)
    return _Stored(function, tuple(static_argnames), light, loop)
