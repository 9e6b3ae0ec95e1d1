"""Compiled programs kept between processes: the solver's programs loaded without tracing or lowering.

JAX's persistent compilation cache saves XLA's work, but it keys each
program on its lowered form, so every process still traces and lowers a
program before it can look it up: in a cached run of the default case that
was 25 traces (0.66 s) and 36 lowerings (0.47 s) on the 2-core development
machine, most of the design's first second. A `ProgramStore` keys a
program on what decides it before any tracing (`program_key`: the
function, its static arguments, the structure, shapes, dtypes and weak
types of its array arguments, the float64 setting, and the version of
everything that shapes the program: this package's source, JAX, jaxlib,
``XLA_FLAGS``, the device and the processor) and keeps its serialised
executable (`jax.experimental.serialize_executable`), so a later process
loads it directly (relaxation at 17x64: 0.26 s through the persistent
cache, 0.07 s from the store).

`stored` wraps a jitted function: called with concrete arrays while a
store is in use (`use_program_store`; the command turns it on beside the
persistent cache, in its ``programs`` sub-folder), it runs the stored
executable, loading or compiling it on the first call with those
arguments; called with tracers (under ``jax.jit``, ``jax.vmap``,
``jax.jvp``), or with no store in use (the library's default), it is the
jitted function itself. A change of the package's code, JAX or the flags
gives every program a new key; an entry that fails to load is compiled
again and replaced.

An executable that JAX loaded from its persistent cache serialises without
its object code on the CPU (jaxlib 0.10.2: it loads, then fails to run
with "Function ... not found"), so the store keeps only executables that
XLA compiled in this process. A program missing from the store is lowered
under a name that carries the store's key (`_Stored.lower_for_store`): the
program is the same, but its key in JAX's persistent cache, which hashes
the lowered module with its name, is the store's own, so the cache never
hands the store the executable of a plain call of the same program, nor
that of an earlier code version's store compile (the program is often
unchanged when the code changes). XLA's dump-only options would not do:
JAX leaves them out of its key. If the cache has the entry anyway (the
store's file was deleted but the cache's kept), the program is used but
not stored.

A store can also load ahead (`ProgramStore.prefetch`): the programs that
the last run of the same kind (a ``profile`` the caller names, e.g. the
command's grid, variables and method) asked for, in the order it asked, as
`ProgramStore.remember` wrote them to ``recent-<profile>.json``, are
loaded on two daemon threads while the caller goes on (deserialising an
executable runs without Python's lock); a call then takes its executable
from there, waiting for it if it is being loaded. A listed program that a
call needs first is loaded by the call, and a run of another code version
(another `_environment_version`) prefetches nothing. The command's cached
default case (2-core development machine): its first design evaluation
ended 0.09 s sooner with one thread (six alternating runs each: 1.80-1.94 s
after the start against 1.91-2.00 s), but the relaxation's program, its
largest and asked for second, was still loading when the solve needed it
(5-110 ms of waiting); with the code version computed before the threads
start and two threads, no call waits.

Loading an executable runs code from the store's folder, as JAX's
persistent cache does: both live in the user's own cache folder.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import json
import os
import pickle
import platform
import tempfile
import threading
import uuid
from concurrent.futures import Future
from functools import partial
from pathlib import Path

import jax

__all__ = ["ProgramStore", "program_key", "program_store", "stored", "use_program_store"]

#: The packages whose source shapes the stored programs.
_PACKAGES = ("forward_solver", "inverse_design", "targets")
_STORE: "ProgramStore | None" = None
_VERSION: str | None = None
_LOCK = threading.Lock()
_VERSION_LOCK = threading.Lock()
#: Threads that load a profile's programs ahead (`ProgramStore.prefetch`).
PREFETCH_THREADS = 2
_WATCH = threading.local()  # per thread: whether a persistent-cache hit was seen while compiling
_LISTENING = False


def _environment_version() -> str:
    """One digest of everything outside a call's arguments that decides its compiled program."""
    global _VERSION
    with _VERSION_LOCK:  # (computed once: by the first caller, a prefetch thread or a call)
        if _VERSION is None:
            _VERSION = _compute_environment_version()
    return _VERSION


def _compute_environment_version() -> str:
    digest = hashlib.sha256()
    root = Path(__file__).resolve().parents[1]
    for package in _PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode())
            digest.update(path.read_bytes())
    import jaxlib

    device = jax.devices()[0]
    for part in (jax.__version__, jaxlib.__version__, os.environ.get("XLA_FLAGS", ""),
                 device.platform, device.device_kind, _processor()):
        digest.update(b"\0" + str(part).encode())
    return digest.hexdigest()


def _processor() -> str:
    """The processor, as far as compiled code can depend on it (its instruction-set flags on Linux)."""
    try:
        with open("/proc/cpuinfo") as f:
            lines = [line for line in f if line.startswith(("model name", "flags"))]
        return "".join(sorted(set(lines)))
    except OSError:
        return f"{platform.machine()} {platform.processor()}"


def program_key(name: str, call) -> str:
    """The store's key of a call of the program ``name``; ``call`` is its static arguments, the
    structure and avals (shape, dtype, weak type) of its dynamic arguments and the float64 setting,
    hashed by ``repr`` with `_environment_version`."""
    return hashlib.sha256((_environment_version() + repr((name, call))).encode()).hexdigest()


def _listen(event: str, **kwargs) -> None:
    if event == "/jax/compilation_cache/cache_hits" and getattr(_WATCH, "active", False):
        _WATCH.hit = True


class ProgramStore:
    """A folder of serialised executables, one file per `program_key`, written atomically, and the
    list of the programs each profile's last run used (`prefetch`, `remember`)."""

    def __init__(self, path):
        self.path = Path(path)
        #: The keys this process's calls asked for (`load`; a missing one is then compiled), in order.
        self.used: list[str] = []
        self._lock = threading.Lock()
        self._ahead: dict[str, Future] = {}  # key -> the prefetch thread's load, until a call takes it
        self._remembered: tuple | None = None  # (profile, version, keys) as `prefetch` read it

    def load(self, key: str):
        """The stored executable of ``key`` (a `jax.stages.Compiled`), or None if there is none or
        it does not load (then it is removed). One loaded ahead (`prefetch`) is taken from there,
        once it is ready."""
        with self._lock:
            ahead = self._ahead.pop(key, None)
            if key not in self.used:  # (in the order the calls ask, which the next run's prefetch follows)
                self.used.append(key)
        return self._read(key) if ahead is None else ahead.result()

    def _read(self, key: str):
        file = self.path / f"{key}.bin"
        try:
            payload = file.read_bytes()
        except OSError:
            return None
        try:
            from jax.experimental.serialize_executable import deserialize_and_load

            serialized, in_tree, out_tree = pickle.loads(payload)
            return deserialize_and_load(serialized, in_tree, out_tree)
        except Exception:  # noqa: BLE001 - a damaged or foreign entry: compile again
            file.unlink(missing_ok=True)
            return None

    def _recent_file(self, profile: str) -> Path:
        return self.path / f"recent-{hashlib.sha256(profile.encode()).hexdigest()[:16]}.json"

    def prefetch(self, profile: str) -> list:
        """Start loading, on `PREFETCH_THREADS` daemon threads, the programs that the last run of
        ``profile`` used (`remember`), if it ran this code version; returns the threads (module
        docstring).

        ``profile`` names a kind of run whose programs are alike (e.g. the command's grid,
        variables and methods); any string. The code version is computed here first (on a
        thread, taking turns with the caller for Python's lock at each file read, it took
        35-90 ms and held the loads back); two threads load the first two programs at once (the
        default case asks for its largest, the relaxation, second)."""
        version = _environment_version()
        try:
            recent = json.loads(self._recent_file(profile).read_text())
            keys = [str(key) for key in recent["keys"]] if recent.get("version") == version else []
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            keys = []
        self._remembered = (profile, version, tuple(keys))
        pending = iter(keys)
        threads = [threading.Thread(target=self._load_ahead, args=(pending,), name="program-store-prefetch",
                                    daemon=True) for _ in range(min(PREFETCH_THREADS, len(keys)))]
        for thread in threads:
            thread.start()
        return threads

    def _load_ahead(self, pending) -> None:
        try:
            while True:
                with self._lock:  # (the keys in order, each to one thread)
                    key = next(pending, None)
                    if key is None:
                        return
                    if key in self.used:  # a call got there first
                        continue
                    future = self._ahead[key] = Future()
                try:
                    future.set_result(self._read(key))
                finally:
                    if not future.done():  # (an error the read does not catch: the call loads it)
                        future.set_result(None)
        except Exception:  # noqa: BLE001 - loading ahead only saves time: the calls load what they need
            pass

    def remember(self, profile: str) -> bool:
        """Write the keys this process used (`used`) as ``profile``'s list for the next run's
        `prefetch`, unless it is the list already there; returns whether it wrote. A full or
        read-only disk writes nothing."""
        version = _environment_version()
        with self._lock:
            keys = tuple(self.used)
        if not keys or self._remembered == (profile, version, keys):
            return False
        try:
            self._write_file(self._recent_file(profile),
                             json.dumps({"profile": profile, "version": version, "keys": list(keys)}).encode())
        except OSError:
            return False
        self._remembered = (profile, version, keys)
        return True

    def compile(self, key: str, lower):
        """Compile the program that ``lower(salt)`` lowers (`_Stored.lower_for_store`) and keep it
        under ``key``. Returns the `jax.stages.Compiled`.

        If JAX's persistent cache supplies it (module docstring: the store's entry was deleted or
        damaged, the cache's kept), it is lowered once more under a name no cache has seen and
        compiled afresh, so that the store gets it back."""
        global _LISTENING
        with _LOCK:
            if not _LISTENING:
                jax.monitoring.register_event_listener(_listen)
                _LISTENING = True
        for salt in ("", uuid.uuid4().hex):
            _WATCH.active, _WATCH.hit = True, False
            try:
                compiled = lower(salt).compile()
            finally:
                _WATCH.active = False
            if not _WATCH.hit:
                try:
                    self._write(key, compiled)
                except OSError:  # a full or read-only disk: the run goes on without storing
                    pass
                break
        return compiled

    def _write(self, key: str, compiled) -> None:
        from jax.experimental.serialize_executable import serialize

        self._write_file(self.path / f"{key}.bin", pickle.dumps(serialize(compiled)))

    def _write_file(self, file: Path, payload: bytes) -> None:
        """Write ``payload`` to ``file`` atomically (a temporary file in the store, then a rename)."""
        self.path.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=self.path, prefix=f".{file.name}.", suffix=".tmp")
        try:
            with os.fdopen(handle, "wb") as f:
                f.write(payload)
            os.replace(temporary, file)
        except BaseException:
            Path(temporary).unlink(missing_ok=True)
            raise


def use_program_store(path) -> "ProgramStore | None":
    """Keep the `stored` programs' executables in ``path`` for this process (None: keep none, the
    library's default); returns the previous store."""
    global _STORE
    previous, _STORE = _STORE, (None if path is None else ProgramStore(path))
    return previous


def program_store() -> "ProgramStore | None":
    """The store in use, or None."""
    return _STORE


class _Stored:
    """A jitted function whose concrete calls run a stored executable while a store is in use."""

    def __init__(self, fun, jitted, static_argnames: tuple):
        self.jitted = jitted
        self.__wrapped__ = fun
        self.__name__ = getattr(fun, "__name__", "program")
        self.__doc__ = fun.__doc__
        # The name, and the source of the function's own module when it lies outside the packages
        # whose source `_environment_version` covers (a program defined in a script or a test).
        self._name = f"{fun.__module__}.{fun.__qualname__}"
        if fun.__module__.split(".")[0] not in _PACKAGES:
            self._name += "@" + hashlib.sha256(Path(inspect.getsourcefile(fun)).read_bytes()).hexdigest()
        self._signature = inspect.signature(fun)
        if any(p.kind is not p.POSITIONAL_OR_KEYWORD for p in self._signature.parameters.values()):
            raise TypeError(f"{self._name}: a stored program takes plain parameters (no *args, **kwargs "
                            "or keyword-only ones), so that its calls can be put in one form")
        self._static = frozenset(static_argnames)
        self._programs: dict = {}  # in-process: (static values, structure, avals, float64) -> executable

    def __getattr__(self, name):  # lower, trace, _cache_size, ...: the jitted function's own
        return getattr(self.jitted, name)

    def prepare(self, *args, **kwargs):
        """The executable a call with these arguments runs (loaded or compiled now) and the
        arguments it takes, or None when no store is in use or an argument is traced."""
        store = _STORE
        if store is None:
            return None
        bound = self._signature.bind(*args, **kwargs)
        bound.apply_defaults()
        values = tuple(bound.arguments.values())  # every argument, positionally: one form for all calls
        static = tuple((k, v) for k, v in bound.arguments.items() if k in self._static)
        dynamic = tuple(v for k, v in bound.arguments.items() if k not in self._static)
        leaves, treedef = jax.tree_util.tree_flatten(dynamic)
        if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
            return None
        local = (static, treedef, tuple(jax.typeof(leaf) for leaf in leaves), bool(jax.config.jax_enable_x64))
        compiled = self._programs.get(local)
        if compiled is None:
            key = program_key(self._name, local)
            compiled = store.load(key)
            if compiled is None:
                compiled = store.compile(key, partial(self.lower_for_store, key, values))
            self._programs[local] = compiled
        return compiled, dynamic

    def lower_for_store(self, key: str, values: tuple, salt: str = ""):
        """The program lowered for ``values`` (every argument, positionally) under a name that carries
        ``key`` (and ``salt``), so that its key in JAX's persistent cache is the store's own (module
        docstring)."""

        @functools.wraps(self.__wrapped__)
        def program(*args):
            return self.__wrapped__(*args)

        program.__name__ = program.__qualname__ = f"{self.__name__}_program_{key[:16]}{salt}"
        return jax.jit(program, static_argnames=tuple(self._static)).lower(*values)

    def __call__(self, *args, **kwargs):
        prepared = self.prepare(*args, **kwargs)
        if prepared is None:
            return self.jitted(*args, **kwargs)
        compiled, dynamic = prepared
        return compiled(*dynamic)


def stored(fun=None, *, static_argnames: tuple = ()):
    """``jax.jit(fun, static_argnames=...)`` whose concrete calls use the program store (module
    docstring). Usable as ``@stored`` or ``@stored(static_argnames=(...))``."""
    if fun is None:
        return lambda f: stored(f, static_argnames=static_argnames)
    return _Stored(fun, jax.jit(fun, static_argnames=static_argnames), tuple(static_argnames))
