"""How long a native call on a worker thread keeps the main thread from running (and so from taking a signal).

Python runs a signal's handler only on the main thread, between two of its
bytecodes, and only while it holds Python's lock (GIL). The command runs its
work on a thread of its own (`inverse_design.app.interrupts.run_stoppable`);
whether a stop is taken at once then depends on the work's native calls
releasing the lock. For each call: a worker thread makes it while the main
thread wakes every 10 ms; the table gives the call's duration and the longest
the main thread waited for the lock (10 ms or so: released; about the call's
own steps: held).

    python -m benchmarks.signal_latency
"""

from __future__ import annotations

import argparse
import threading
import time

import numpy as np

from benchmarks.results import save_result


def longest_wait(work) -> tuple[float, float]:
    """``(seconds of work(), the main thread's longest wait, s)``, ``work`` on a worker thread."""
    done = threading.Event()

    def target():
        work()
        done.set()

    thread = threading.Thread(target=target)
    start = time.monotonic()
    thread.start()
    last, wait = time.monotonic(), 0.0
    while not done.wait(0.01):
        now = time.monotonic()
        wait, last = max(wait, now - last), now
    thread.join()
    return time.monotonic() - start, wait


def _slsqp(n: int):
    """SciPy's SLSQP on a convex quadratic of ``n`` variables with bounds and 4 linear inequalities (the
    designs' constraints are a few smooth aggregates, so the variables set its native steps' cost)."""
    from scipy.optimize import minimize

    rng = np.random.default_rng(0)
    a = rng.standard_normal((n, n))
    q = a @ a.T / n + np.eye(n)
    b = rng.standard_normal(n)
    c = rng.standard_normal((4, n))
    return lambda: minimize(lambda x: 0.5 * x @ q @ x - b @ x, np.zeros(n), jac=lambda x: q @ x - b,
                            method="SLSQP", bounds=[(-1, 1)] * n,
                            constraints=[{"type": "ineq", "fun": lambda x: c @ x + 1, "jac": lambda x: c}],
                            options={"maxiter": 200})


def _lapack():
    import scipy.linalg

    a = np.random.default_rng(0).standard_normal((2000, 2000))
    return lambda: (np.linalg.solve(a, a), scipy.linalg.lu_factor(a))


def _banded():
    from scipy.linalg import solveh_banded

    n = 1_000_000
    ab = np.vstack([np.full(n, -1.0), np.full(n, 4.0)])
    return lambda: [solveh_banded(ab, np.ones((n, 4)), check_finite=False) for _ in range(3)]


def _superlu():
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    n = 300
    line = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], (n, n))
    lap = sp.kronsum(line, line)
    matrix = (lap + sp.identity(n * n)).tocsc()
    return lambda: [spla.splu(matrix) for _ in range(3)]


def _xla_call():
    import jax

    spin = jax.jit(lambda n: jax.lax.fori_loop(0, n, lambda i, x: x * 1.0000001 + 1e-9, 1.0))
    spin(10).block_until_ready()
    return lambda: spin(300_000_000).block_until_ready()


def _xla_compile():
    import jax
    import jax.numpy as jnp

    def compile_once():
        def big(x):
            for i in range(200):
                x = jnp.sin(x) * (i + 1.0) + jnp.cos(x @ x.T)
            return x

        jax.jit(big).lower(jnp.ones((20, 20))).compile()

    return compile_once


CALLS = [("scipy SLSQP, 250 variables", lambda: _slsqp(250)), ("scipy SLSQP, 500 variables", lambda: _slsqp(500)),
         ("scipy SLSQP, 1000 variables", lambda: _slsqp(1000)),
         ("NumPy and SciPy LAPACK (2000 x 2000 solve, LU)", _lapack),
         ("scipy solveh_banded (1e6 x 4)", _banded), ("SuperLU (splu, 90,000 unknowns)", _superlu),
         ("an XLA compiled call (3e8 loop steps)", _xla_call), ("XLA's compiler (a 200-op function)", _xla_compile)]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="leave out SLSQP with 1000 variables (tens of s)")
    args = parser.parse_args(argv)
    rows = []
    for name, make in CALLS:
        if args.quick and "1000" in name:
            continue
        seconds, wait = longest_wait(make())
        rows.append([name, round(seconds, 2), round(1e3 * wait, 1)])
        print(f"{name:50s} {seconds:7.2f} s, main thread waited at most {1e3 * wait:8.1f} ms", flush=True)
    save_result("signal_latency", title="How long a native call on the work's thread keeps the main thread "
                "(and a stop) waiting", command="python -m benchmarks.signal_latency",
                columns=["call on a worker thread", "call, s", "longest wait of the main thread, ms"], rows=rows,
                notes=["The main thread wakes every 10 ms: a wait near 10 ms means the call releases Python's "
                       "lock; a longer one is a native step that holds it (SLSQP's: its cost grows with the "
                       "variables cubed), which delays a stop by as much (docs/command.md).",
                       "BLAS on one thread (OPENBLAS_NUM_THREADS=1), as the command runs it; the machine's "
                       "other load lengthens every wait."])


if __name__ == "__main__":
    main()
