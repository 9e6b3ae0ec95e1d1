"""The solver's largest programs kept between processes as exported StableHLO (`jax.export`).

JAX's persistent compilation cache keeps XLA's work, but it keys a program on
its lowered form, so every process still traces and lowers each program
before it can look it up; for the solver's largest programs (the relaxation,
the Jacobian's values, the adjoint's right-hand sides) that is most of a
cached run's design time. `stored` is ``jax.jit`` for such a program, and
while a folder is in use (`use_program_store`; the command uses one beside its
persistent cache) a call with concrete arrays runs the program exported by an
earlier process (`jax.export.deserialize`, then ``Exported.call`` under
``jax.jit``): the exported module is lowered from its serialised form, not
traced from Python, and compiled through the persistent cache as usual. A
program not in the folder is exported (`jax.export.export`) and saved there,
one file per key. The key is the function, its static arguments, the
structure, shapes, dtypes and weak types of its array arguments, and the
version of everything that shapes the exported module (this package's source,
JAX and jaxlib); a file that fails to load is exported again and replaced.

Called with tracers (under ``jax.jit``, ``jax.vmap``, ``jax.jvp``), with no
folder in use (the library's default), or for a program that does not export
(the run goes on with the plain call), a `stored` program is its jitted
function. Loading a file runs the program it holds, as JAX's persistent cache
does: both live in the user's own cache folder.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import os
import pickle
import tempfile
from pathlib import Path

import jax

__all__ = ["stored", "use_program_store"]

_FOLDER: Path | None = None
_VERSION: str | None = None


def use_program_store(path) -> Path | None:
    """Keep the `stored` programs in the folder ``path`` for this process (None: keep none, the
    library's default; also without the ``flatbuffers`` package, which `jax.export` serialises
    with); returns the previous folder."""
    global _FOLDER
    usable = path is not None and importlib.util.find_spec("flatbuffers") is not None
    previous, _FOLDER = _FOLDER, (Path(path) if usable else None)
    return previous


def _version() -> str:
    """One digest of what shapes an exported module besides a call's arguments."""
    global _VERSION
    if _VERSION is None:
        import jaxlib

        digest = hashlib.sha256(f"{jax.__version__} {jaxlib.__version__}".encode())
        for path in sorted(Path(__file__).parent.glob("*.py")):
            digest.update(path.name.encode() + b"\0" + path.read_bytes())
        _VERSION = digest.hexdigest()
    return _VERSION


class _Stored:
    """A jitted function whose concrete calls run its exported program while a folder is in use."""

    def __init__(self, fun, static_argnames: tuple):
        self.jitted = jax.jit(fun, static_argnames=static_argnames)
        self.__wrapped__, self.__name__, self.__doc__ = fun, fun.__name__, fun.__doc__
        self._name = f"{fun.__module__}.{fun.__qualname__}"
        self._signature = inspect.signature(fun)
        self._static = frozenset(static_argnames)
        self._calls: dict = {}  # (static values, structure, avals, float64) -> the exported call, or None

    def __getattr__(self, name):  # lower, trace, ...: the jitted function's own
        return getattr(self.jitted, name)

    def __call__(self, *args, **kwargs):
        call, leaves = self._exported(args, kwargs)
        return self.jitted(*args, **kwargs) if call is None else call(*leaves)

    def lower(self, *args, **kwargs):
        """``jitted.lower(...)``, or while a folder is in use the exported program's (arguments may
        be `jax.ShapeDtypeStruct` s): what `ahead.compiling` compiles ahead of a call."""
        call, leaves = self._exported(args, kwargs)
        return self.jitted.lower(*args, **kwargs) if call is None else call.lower(*leaves)

    def _exported(self, args: tuple, kwargs: dict):
        """The exported program of a call with these arguments (a jitted function of the array
        leaves; loaded or exported on the first such call) and the leaves; ``(None, None)`` for
        the plain jitted call (module docstring)."""
        folder = _FOLDER
        if folder is None:
            return None, None
        bound = self._signature.bind(*args, **kwargs)
        bound.apply_defaults()
        static = tuple((k, v) for k, v in bound.arguments.items() if k in self._static)
        leaves, tree = jax.tree_util.tree_flatten(
            tuple(v for k, v in bound.arguments.items() if k not in self._static))
        if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
            return None, None
        local = (static, tree, tuple(map(_aval, leaves)), bool(jax.config.jax_enable_x64))
        if local not in self._calls:
            self._calls[local] = self._load(folder, local, dict(static), tree, leaves)
        return self._calls[local], leaves

    def _load(self, folder: Path, local: tuple, static: dict, tree, leaves):
        """The exported program of ``local`` as a jitted function of the array leaves (from the
        folder, or exported now and saved there), or None if it does not export."""
        file = folder / f"{hashlib.sha256((_version() + repr((self._name, local))).encode()).hexdigest()}.jax"
        try:
            serialised, out_tree = pickle.loads(file.read_bytes())
            exported = jax.export.deserialize(serialised)
        except Exception:  # noqa: BLE001 - missing, damaged or foreign: export again
            names = [k for k in self._signature.parameters if k not in self._static]
            outputs = []

            def program(*arrays):
                dynamic = jax.tree_util.tree_unflatten(tree, arrays)
                flat, structure = jax.tree_util.tree_flatten(self.__wrapped__(**dict(zip(names, dynamic)), **static))
                outputs.append(structure)
                return flat

            try:
                exported = jax.export.export(jax.jit(program))(*leaves)
                payload = pickle.dumps((exported.serialize(), outputs[-1]))
            except Exception:  # noqa: BLE001 - e.g. a host callback: the plain jitted call
                return None
            out_tree = outputs[-1]
            _write(file, payload)
        return jax.jit(lambda *arrays: jax.tree_util.tree_unflatten(out_tree, exported.call(*arrays)))


def _aval(leaf) -> tuple:
    """Shape, dtype and weak type of an array leaf or a `jax.ShapeDtypeStruct`."""
    if not isinstance(leaf, jax.ShapeDtypeStruct):
        leaf = jax.typeof(leaf)
    return tuple(leaf.shape), str(leaf.dtype), bool(leaf.weak_type)


def _write(file: Path, payload: bytes) -> None:
    """``payload`` into ``file`` atomically (a temporary file beside it, then a rename); nothing on a
    full or read-only disk."""
    try:
        file.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=file.parent, prefix=f".{file.name}.", suffix=".tmp")
        try:
            with os.fdopen(handle, "wb") as f:
                f.write(payload)
            os.replace(temporary, file)
        finally:
            Path(temporary).unlink(missing_ok=True)
    except OSError:
        pass


def stored(fun=None, *, static_argnames: tuple = ()):
    """``jax.jit(fun, static_argnames=...)`` whose concrete calls use the exported programs' folder
    (module docstring). Usable as ``@stored`` or ``@stored(static_argnames=(...))``."""
    if fun is None:
        return lambda f: stored(f, static_argnames=static_argnames)
    return _Stored(fun, tuple(static_argnames))
