"""One forward entry for N >= 1 bays: `solve_bays`, its two strategies and one adjoint.

A 3-bay NACA 2412 wing tapering 1.0 -> 0.8 -> 0.7 -> 0.6 m on 5x32 grids,
with one rib shape per rib. The "loop" (per-bay `solve_equilibrium`: host
LU adjoint) and the "batch" (one jit(vmap) relaxation: Krylov adjoint) must
find the same nodes (both at rtol 1e-10: < 1e-7 m) and the same gradients
in the pressure and in one coefficient of a shared rib (1e-6 relative; both
at rtol 1e-11). A one-bay wing must be `solve_equilibrium` exactly.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import Bay, Fabric, Parameters, Scene, Solution, solve_bays, solve_equilibrium
from forward_solver.derivatives.implicit import ImplicitAdjoint
from forward_solver import Wing
from forward_solver.solvers.bays import solve_wing
from targets import naca
from support.solver import counted_each, default_bay

GRID = dict(n_span=5, n_contour=32)
PARAMETERS = Parameters(pressure=2e4, prestrain_span=0.005, prestrain_chord=0.005)
SHAPES = 0.01 * np.array([[0.0, 0.0, 0.0, 0.0], [-1.0, 0.5, 1.0, -0.5], [0.5, -1.0, 0.0, 1.0],
                          [1.0, 1.0, -1.0, 0.0]])


@pytest.fixture(scope="module")
def scenes():
    af = naca("2412")
    wing = Wing(airfoils=(af, af, af, af), chords=(1.0, 0.8, 0.7, 0.6), stations=(0.0, 0.25, 0.5, 0.75))
    return wing.scenes(Fabric(), **GRID)


@pytest.fixture(scope="module")
def solved(scenes):
    return {s: solve_bays(scenes, PARAMETERS, rtol=1e-10, rib_shapes=SHAPES, strategy=s)
            for s in ("loop", "batch")}


def test_loop_and_batch_find_the_same_nodes(solved):
    loop, batch = solved["loop"], solved["batch"]
    assert loop.converged and batch.converged
    assert np.max(np.abs(np.asarray(loop.nodes) - np.asarray(batch.nodes))) < 1e-7
    np.testing.assert_allclose(np.asarray(loop.mounted), np.asarray(batch.mounted), atol=1e-15)
    # The loop keeps its own per-bay Solutions; the batch has none.
    assert batch.solutions is None and len(loop.solutions) == 3
    assert all(isinstance(s, Solution) for s in loop.solutions)
    assert loop.bay_solution(1) is loop.solutions[1]
    assert loop.scene(2) is loop.scenes[2]


def test_loop_and_batch_gradients_agree(scenes):
    def bulge(p, c, strategy):
        shapes = jnp.asarray(SHAPES).at[1, 1].set(c)
        nodes = solve_bays(scenes, PARAMETERS.replace(pressure=p), rtol=1e-11, rib_shapes=shapes,
                           strategy=strategy).nodes
        return jnp.sum(nodes[:, 2, :, 2] ** 2)  # (the mid-bay rows)

    with jax.enable_x64(True):
        grads = {s: np.asarray(jax.grad(bulge, argnums=(0, 1))(2e4, SHAPES[1, 1], s)) for s in ("loop", "batch")}
    assert np.all(grads["loop"] != 0)
    np.testing.assert_allclose(grads["loop"], grads["batch"], rtol=1e-6)


def test_one_bay_is_solve_equilibrium_exactly():
    bay = default_bay(**GRID)
    scene = Scene(bay, Fabric())
    alone = solve_equilibrium(scene, PARAMETERS, rtol=1e-10)
    sol = solve_bays([scene], PARAMETERS, rtol=1e-10)
    assert np.array_equal(sol.nodes[0], alone.nodes) and int(sol.steps[0]) == alone.steps
    # The one-bay wing of the scene rebuilds the same bay, and solve_wing solves it the same.
    wing = Wing.from_scene(scene)
    rebuilt = wing.bays(**GRID)[0]
    for name in ("contour_root", "contour_tip", "camber_root", "camber_tip", "fixed"):
        assert np.array_equal(getattr(rebuilt, name), getattr(bay, name)), name
    assert rebuilt.symmetric and rebuilt.rib_spacing == bay.rib_spacing
    assert np.array_equal(solve_wing(wing, Fabric(), PARAMETERS, rtol=1e-10, **GRID).nodes[0], alone.nodes)


def test_a_flat_panel_is_solved_by_the_loop_as_is():
    scene = Scene(Bay.flat_panel(n_span=9, n_contour=17), Fabric())
    alone = solve_equilibrium(scene, PARAMETERS, rtol=1e-8)
    assert np.array_equal(solve_bays([scene], PARAMETERS, rtol=1e-8).nodes[0], alone.nodes)
    with pytest.raises(ValueError, match="Bay.from_airfoil"):
        Wing.from_scene(scene)


@pytest.fixture(scope="module")
def cold(scenes):
    return solve_bays(scenes, PARAMETERS, rtol=1e-10, rib_shapes=SHAPES, method="relax+newton", strategy="loop")


def test_a_cold_loop_starts_each_bay_after_the_first_from_the_bay_before(cold, solved):
    first, *others = cold.solutions
    assert first.extra["relax_steps"] > 0 and "warm_start" not in first.extra
    # The bay before's displacement on this bay's mounted shape, by Newton: no relaxation.
    assert all(s.extra["warm_start"] == "Newton from the initial nodes" and s.extra["relax_steps"] == 0
               and 0 < s.extra["newton_iterations"] for s in others)
    # The same equilibrium as the batch's relaxation of every bay from its mounted shape (both at 1e-10).
    assert cold.converged
    assert np.max(np.abs(np.asarray(cold.nodes) - np.asarray(solved["batch"].nodes))) < 1e-7


def test_a_cold_loop_of_four_bays_runs_two_halves_the_same_on_one_thread_or_two(monkeypatch):
    # From four bays on, each half of the wing starts cold at its first bay (so that two threads can
    # take one each): the same starts, and the same nodes to the bit, whether a second core helps.
    from forward_solver.solvers import bay_starts

    af = naca("2412")
    wing = Wing(airfoils=(af,) * 5, chords=(1.0, 0.9, 0.8, 0.7, 0.6), stations=(0.0, 0.25, 0.5, 0.75, 1.0))
    four = wing.scenes(Fabric(), **GRID)
    solved = {}
    for helpers in (1, 0):
        monkeypatch.setattr(bay_starts, "helpers", lambda helpers=helpers: helpers)
        solved[helpers] = solve_bays(four, PARAMETERS, rtol=1e-10, method="relax+newton", strategy="loop")
    for sol in solved.values():
        assert sol.converged
        assert [s.extra["relax_steps"] > 0 for s in sol.solutions] == [True, False, True, False]
    assert np.array_equal(np.asarray(solved[1].nodes), np.asarray(solved[0].nodes))


def test_warm_start_passes_each_bay_its_solution(scenes, cold):
    warm = solve_bays(scenes, PARAMETERS.replace(pressure=2.02e4), rtol=1e-10, rib_shapes=SHAPES,
                      method="relax+newton", initial=cold, strategy="loop")
    assert warm.converged
    assert all("chord Newton" in s.extra.get("warm_start", "") for s in warm.solutions)


def test_a_warm_differentiated_loop_solves_its_bays_first_and_the_same(scenes, cold, monkeypatch):
    # The host solves of a warm solve under jax.jvp are made before the bays are differentiated, two
    # at a time on a second core (`bay_starts.presolve`, `threads.each`): the same nodes and tangents, to
    # the bit, as each bay solved where it is differentiated.
    from forward_solver.solvers import bay_starts

    def nodes(p):
        return solve_bays(scenes, PARAMETERS.replace(pressure=p), rtol=1e-10, rib_shapes=SHAPES,
                          method="relax+newton", initial=cold, strategy="loop").nodes

    presolved = counted_each(monkeypatch, bay_starts)
    with jax.enable_x64(True):
        monkeypatch.setattr(bay_starts, "helpers", lambda: 1)
        shared = jax.jvp(nodes, (2.02e4,), (1.0,))
        monkeypatch.setattr(bay_starts, "helpers", lambda: 0)
        alone = jax.jvp(nodes, (2.02e4,), (1.0,))
    assert presolved == [3]
    assert np.all(np.isfinite(np.asarray(shared[1]))) and np.any(np.asarray(shared[1]) != 0)
    for a, b in zip(shared, alone):
        assert np.array_equal(np.asarray(a), np.asarray(b))


def test_a_differentiated_warm_bay_keeps_the_factor_of_its_own_nodes(scenes, cold, monkeypatch):
    # Chord Newton converges with the cold solution's factor (not the Jacobian at the new nodes). A bay
    # that is differentiated is `prepared` where it was solved (two at a time: `bay_starts.presolve`):
    # its solution then holds the LU at its own nodes, which its tangent and the next warm start take.
    from forward_solver.solvers import bay_starts

    def solve(p):
        return solve_bays(scenes, PARAMETERS.replace(pressure=p), rtol=1e-10, rib_shapes=SHAPES,
                          method="relax+newton", initial=cold, strategy="loop")

    held = {}

    def nodes(p):
        held["sol"] = solve(p)
        return held["sol"].nodes

    monkeypatch.setattr(bay_starts, "helpers", lambda: 1)
    with jax.enable_x64(True):
        plain = solve(2.02e4)
        jax.jvp(nodes, (2.02e4,), (1.0,))
    assert all("chord Newton" in s.extra.get("warm_start", "") for s in plain.solutions)
    assert not any(s.factor.current for s in plain.solutions)  # (a plain solve makes no LU it does not need)
    differentiated = held["sol"].solutions
    assert all(s.factor.current for s in differentiated)
    for s, p in zip(differentiated, plain.solutions):
        np.testing.assert_array_equal(np.asarray(s.nodes), np.asarray(p.nodes))


def test_the_same_call_under_jit(scenes, solved):
    with jax.enable_x64(True):
        nodes = jax.jit(lambda p: solve_bays(scenes, PARAMETERS.replace(pressure=p), rtol=1e-10,
                                             rib_shapes=SHAPES, strategy="loop").nodes)(2e4)
    assert np.max(np.abs(np.asarray(nodes) - np.asarray(solved["loop"].nodes))) < 1e-7


def test_the_two_linear_solvers_give_one_tangent(solved):
    sol = solved["loop"].solutions[0]
    scene = solved["loop"].scenes[0]
    with jax.enable_x64(True):
        params = scene.params(sol.parameters)
        geometry = jax.tree_util.tree_map(jnp.asarray, scene.bay.geometry())
        dp = jax.tree_util.tree_map(jnp.zeros_like, params)._replace(pressure=jnp.float64(1.0))
        x = jnp.asarray(sol.nodes)
        tangents = [np.asarray(ImplicitAdjoint(s).at(x, geometry, params, scene.physics(dynamic=False)).tangent(dp))
                    for s in ("lu", "iterative")]
    assert np.max(np.abs(tangents[0])) > 0
    np.testing.assert_allclose(tangents[0], tangents[1], rtol=0, atol=1e-8 * np.max(np.abs(tangents[0])))


def test_bad_input_is_refused_with_what_to_change(scenes):
    other = Scene(scenes[1].bay, Fabric(stiffness_span=1e5))
    with pytest.raises(ValueError, match="scene 1 differs from scene 0 in: fabric"):
        solve_bays([scenes[0], other], PARAMETERS)
    coarse = Scene(Bay.from_airfoil(naca("2412"), n_span=5, n_contour=24), Fabric())
    with pytest.raises(ValueError, match="grid 5x24"):
        solve_bays([scenes[0], coarse], PARAMETERS)
    with pytest.raises(ValueError, match="strategy must be one of"):
        solve_bays(scenes, PARAMETERS, strategy="gpu")
    with pytest.raises(ValueError, match="use strategy='loop'"):
        solve_bays(scenes, PARAMETERS, method="newton", strategy="batch")
    with pytest.raises(ValueError, match=r"rib_shapes must be an \(4, 2K\) array"):
        solve_bays(scenes, PARAMETERS, rib_shapes=SHAPES[:3])
    with pytest.raises(TypeError, match=r"strategy=Loop\(adjoint=ImplicitAdjoint\(linear_solver=...\)\)"):
        solve_bays(scenes, PARAMETERS, linear_solver="lu")
