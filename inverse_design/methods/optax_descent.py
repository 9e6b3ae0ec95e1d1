"""The optax method of a design (`Optax`): gradient descent on the penalty loss, meant for many variables."""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from .base import Method, check_tolerance

__all__ = ["Optax", "OPTAX_GAIN", "OPTAX_LEARNING_RATE", "OPTAX_PATIENCE", "OPTAX_HALVINGS"]

#: optax: the default Adam's learning rate (scaled variables: 0.05 moves the pressure by about 5%
#: of its start per step).
OPTAX_LEARNING_RATE = 0.05
#: A step that does not lower the best loss by this fraction is no gain ...
OPTAX_GAIN = 1e-3
#: ... after this many such steps in a row the step size halves and the run restarts from the best
#: iterate ...
OPTAX_PATIENCE = 3
#: ... and once it has halved this many times the loss has levelled off: the run ends there.
OPTAX_HALVINGS = 6


@dataclass(frozen=True)
class Optax(Method):
    """An optax optimiser on the mean square error plus penalties, its gradient by reverse mode, the
    iterate projected onto the bounds after every step (`run`).

    Args:
        optimiser: an ``optax.GradientTransformation`` (None: ``optax.adam(OPTAX_LEARNING_RATE)`` on the
            scaled variables, its step halved whenever the loss stops falling).
        tolerance: the scaled projected-gradient norm, relative to the starting loss, that ends the
            run (1e-8).
    """

    optimiser: object = None
    tolerance: float = 1e-8
    name = "optax"

    def __post_init__(self):
        check_tolerance(self.tolerance)

    def run(self, problem, u0, max_iterations: int) -> tuple:
        """Gradient descent by an optax transformation (default Adam, `OPTAX_LEARNING_RATE`) on the penalty loss.

        The loss is scaled to 1 at the start, so ``tolerance`` bounds the
        projected gradient relative to the starting loss. A fixed-step method
        circles an optimum on a tension limit (the penalty's kink) instead of
        settling: measured on the default case (9x32), Adam at 0.02 hit its 50-step
        cap at rms 4.9e-3 chord, the loss going up and down by 40%, where SLSQP
        reached 3.7e-3 in 9 solves. So the step is halved (and the run restarted
        from the best iterate, with a fresh optimiser state) after
        `OPTAX_PATIENCE` steps without a gain of `OPTAX_GAIN` of the best loss,
        and after `OPTAX_HALVINGS` halvings the loss has levelled off: the run
        ends there, converged, at the best iterate.
        """
        import optax  # (its import is not free: only where this method runs)

        tolerance = self.tolerance
        optimiser = optax.adam(OPTAX_LEARNING_RATE) if self.optimiser is None else self.optimiser

        lower, upper = problem.variables.lower, problem.variables.upper
        u = jnp.asarray(u0, jnp.float64)
        state = optimiser.init(u)
        message = f"the iteration cap ({max_iterations} steps) was hit before the loss levelled off"
        success = False
        f0 = None
        best_u, best, since, scale, halvings = u, np.inf, 0, 1.0, 0
        for _ in range(max_iterations):
            value, grad, sol = problem.loss_and_gradient(u)
            f0 = max(float(value), np.finfo(float).tiny) if f0 is None else f0
            grad_np = np.asarray(grad)
            # The projected gradient: components pushing into an active bound do not count.
            at_lower = (np.asarray(u) <= lower) & (grad_np > 0)
            at_upper = (np.asarray(u) >= upper) & (grad_np < 0)
            projected = np.where(at_lower | at_upper, 0.0, grad_np)
            problem.history.record(np.asarray(u), value, np.linalg.norm(projected), solution=sol)
            if float(value) < best:
                since = 0 if float(value) < best * (1.0 - OPTAX_GAIN) else since + 1
                best_u, best = u, float(value)
            else:
                since += 1
            if np.linalg.norm(projected) / f0 <= tolerance:
                message, success = "the projected gradient norm fell below the tolerance", True
                break
            if since >= OPTAX_PATIENCE:
                if halvings == OPTAX_HALVINGS:
                    message, success = (f"the loss levelled off: no gain of {OPTAX_GAIN:.0e} of the best in "
                                        f"{OPTAX_PATIENCE} steps after {halvings} halvings of the step; the "
                                        "result is the best iterate"), True
                    break
                scale, halvings, since = 0.5 * scale, halvings + 1, 0
                u, state = best_u, optimiser.init(best_u)
                continue
            updates, state = optimiser.update(grad / f0, state, u)
            u = jnp.clip(u + scale * (optax.apply_updates(u, updates) - u), lower, upper)
        return np.asarray(best_u if np.isfinite(best) else u), success, message
