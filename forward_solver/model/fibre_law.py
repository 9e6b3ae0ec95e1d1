"""The fibre law as the force kernel reads it: the tensions of a cell from its two fibre strains.

A law is a static value (a `forces.Physics` field: a change compiles another
program); what is designed or swept, the stiffnesses, stays traced in the
kernel's `forces.KernelInputs`. Two laws:

* `LinearLaw`, the paper's eq. (10) without its viscous term (which the
  kernel adds for `simulate`)::

      T11 = (E11 e11 + nu E22 e22) / (1 - nu^2),  T22 = (E22 e22 + nu E11 e11) / (1 - nu^2)

  with the traced ``E11 = stiffness_span``, ``E22 = stiffness_chord`` and
  ``nu = poisson``: the default, the same arithmetic as before there were
  laws, so its results do not change by a digit.
* `SurfaceLaw`, a law fitted to a biaxial test (`model.biaxial.FittedLaw`): the
  tensions of a strain-energy surface ``W(e_warp, e_weft)``
  (`model.biaxial.surface.EnergySurface`, its coefficients Python floats), the
  warp along the span or the chord, each wing direction's tensions scaled
  by its traced stiffness over the law's nominal one (a fabric lot's
  stiffness scatter; 1 at the nominal stiffness).

Each law also bounds its tangent, for the relaxation's fictitious masses
(`forces.node_stiffness`, a Gershgorin bound), the paper's time step (eq. 16,
``c = sqrt(E_max / rho0)``) and the rounding floor
(`forces.rounding_residual_floor`): `stiffness_bound` (the largest row sum
of the tangent) and `modulus` (its largest diagonal entry). For eq. (10)
they are ``max(E) (1 + nu) / (1 - nu^2)`` and ``max(E) / (1 - nu^2)`` at
every strain. A fitted law's tangent varies: its bound is the larger of the
bound over the tested range (computed once, `model.biaxial.EnergySurface.tangent_bounds`)
and the tangent at the cells' current strains (two forward derivatives over
the grid), so that strains the solve reaches beyond the test are followed
as the masses are refreshed (every chunk and every kinetic-energy peak,
growing only: `solvers.relax`).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from .biaxial.surface import EnergySurface

__all__ = ["LinearLaw", "SurfaceLaw"]


@dataclass(frozen=True)
class LinearLaw:
    """Paper eq. (10) (module docstring): the stiffnesses and Poisson coupling are the kernel's traced inputs."""

    def tensions(self, e1, e2, params):
        """``(T11, T22)``, N/m, of the cells' strains ``e1`` (span) and ``e2`` (chord); eq. (10)."""
        nu = params.poisson
        scale = 1.0 / (1.0 - nu * nu)
        t11 = (params.stiffness_span * e1 + nu * params.stiffness_chord * e2) * scale  # eq. (10)
        t22 = (params.stiffness_chord * e2 + nu * params.stiffness_span * e1) * scale
        return t11, t22

    def stiffness_bound(self, params, e1, e2):
        """The largest row sum of the tangent, N/m: ``max(E11, E22) (1 + nu) / (1 - nu^2)`` at every strain."""
        nu = params.poisson
        return jnp.maximum(params.stiffness_span, params.stiffness_chord) * (1.0 + nu) / (1.0 - nu * nu)

    def modulus(self, params):
        """The stiffest plane-strain modulus ``max(E11, E22) / (1 - nu^2)``, N/m (eq. 16's ``E_max``)."""
        nu = params.poisson
        return jnp.maximum(params.stiffness_span, params.stiffness_chord) / (1.0 - nu * nu)


@dataclass(frozen=True)
class SurfaceLaw:
    """A fitted strain-energy surface in the wing's directions (module docstring).

    Attributes:
        surface: the law in the test's warp and weft (`model.biaxial.EnergySurface`).
        warp_along_span: the warp runs along the span (else along the chord).
        nominal_span, nominal_chord: the law's nominal stiffness along the span and the chord, N/m: the
            stiffness at which its scale is 1.
        bounds: the tangent's bounds over the tested range (`model.biaxial.EnergySurface.tangent_bounds`), as
            ``(row_warp, row_weft, diagonal_warp, diagonal_weft)``, N/m.
    """

    surface: EnergySurface
    warp_along_span: bool
    nominal_span: float
    nominal_chord: float
    bounds: tuple

    @classmethod
    def of(cls, surface: EnergySurface, warp_along_span: bool, nominal_warp: float, nominal_weft: float):
        """The law of ``surface`` with the warp along the span (or the chord) and the nominal stiffnesses of
        the warp and the weft, N/m."""
        b = surface.tangent_bounds()
        bounds = (b["row_warp"], b["row_weft"], b["diagonal_warp"], b["diagonal_weft"])
        span, chord = (nominal_warp, nominal_weft) if warp_along_span else (nominal_weft, nominal_warp)
        return cls(surface, bool(warp_along_span), float(span), float(chord), tuple(float(v) for v in bounds))

    def _wing(self, warp, weft):
        """``(span, chord)`` of a pair given in the test's ``(warp, weft)``, and the other way round."""
        return (warp, weft) if self.warp_along_span else (weft, warp)

    def _scales(self, params):
        return params.stiffness_span / self.nominal_span, params.stiffness_chord / self.nominal_chord

    def _unscaled(self, e1, e2):
        """``(T_span, T_chord)`` of the surface at the span and chord strains, before the scales."""
        return self._wing(*self.surface.tensions(*self._wing(e1, e2), xp=jnp))

    def tensions(self, e1, e2, params):
        """``(T11, T22)``, N/m, of the cells' strains ``e1`` (span) and ``e2`` (chord), each direction scaled by
        its stiffness over the nominal one."""
        t_span, t_chord = self._unscaled(e1, e2)
        s_span, s_chord = self._scales(params)
        return s_span * t_span, s_chord * t_chord

    def stiffness_bound(self, params, e1, e2):
        """The largest row sum of the scaled tangent, N/m, over the tested range and at the strains ``e1``,
        ``e2`` (module docstring)."""
        ones, zeros = jnp.ones_like(e1), jnp.zeros_like(e1)
        by_span = jax.jvp(self._unscaled, (e1, e2), (ones, zeros))[1]  # d(T_span, T_chord) / d e_span
        by_chord = jax.jvp(self._unscaled, (e1, e2), (zeros, ones))[1]
        row_span, row_chord = self._wing(*self.bounds[:2])
        here_span = jnp.max(jnp.abs(by_span[0]) + jnp.abs(by_chord[0]))
        here_chord = jnp.max(jnp.abs(by_span[1]) + jnp.abs(by_chord[1]))
        s_span, s_chord = self._scales(params)
        return jnp.maximum(s_span * jnp.maximum(row_span, here_span), s_chord * jnp.maximum(row_chord, here_chord))

    def modulus(self, params):
        """The largest diagonal entry of the scaled tangent over the tested range, N/m (eq. 16's ``E_max``)."""
        s_span, s_chord = self._scales(params)
        diagonal_span, diagonal_chord = self._wing(*self.bounds[2:])
        return jnp.maximum(s_span * diagonal_span, s_chord * diagonal_chord)
