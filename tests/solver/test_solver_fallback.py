"""The equilibrium fallback chain, the early end of a hopeless
relaxation, the solver options of the command and the design loop, optax's stopping rule and a
missing target."""

import numpy as np
import pytest

import forward_solver
from forward_solver import Bay, ConvergenceError, Fabric, Relax, Result, Scene, solve_equilibrium
from inverse_design import optimise_pressure
from inverse_design.app import cli, design
from inverse_design.app.case import Case
from inverse_design.app.run import run_case
from inverse_design.settings import Limits, SolverSettings
from targets import naca
from support.solver import default_bay


def test_anisotropic_0006_bay_converges_through_auto(x64):
    # The scene: relax cycles (the fabric law is not reciprocal for unequal stiffnesses)
    # while Newton converges. It needs 17x64: on 9x32 relax converges.
    bay = Bay.from_airfoil(naca("0006"), chord=1.0, rib_spacing=0.5, n_span=17, n_contour=64)
    scene = Scene(bay, Fabric(stiffness_span=2e4, stiffness_chord=3e5))
    sol = solve_equilibrium(scene, 323.0, (0.04, 0.03), method="auto")
    assert sol.converged and sol.residual <= 1e-8
    tried = sol.extra["attempts"]
    assert tried[0][:2] == ("relax+newton", "stalled") and tried[0][2] <= 20_000
    assert tried[-1][1] == "converged" and tried[-1][0].startswith("newton")


def test_slack_fabric_relaxation_ends_early(x64):
    # Before: 200,000 steps to max_steps_reached (17x64; on 9x32 it converges).
    bay = default_bay(17, 64)
    sol = solve_equilibrium(Scene(bay, Fabric()), 1e4, (-0.05, -0.05), method=Relax(sequencing=False),
                            throw=False)
    assert sol.steps <= 20_000
    assert sol.result in (Result.stalled, Result.converged)
    if sol.result == Result.stalled:
        assert "method='auto'" in sol.message and "Newton" in sol.message and "prestrain" in sol.message


def test_failure_names_every_method_tried(x64):
    bay = Bay.from_airfoil(naca("0006"), chord=1.0, rib_spacing=0.25, n_span=9, n_contour=32)
    scene = Scene(bay, Fabric(stiffness_span=1e6, stiffness_chord=1e4))
    with pytest.raises(ConvergenceError) as info:
        solve_equilibrium(scene, 323.0, (0.02, 0.02), method="auto", max_steps=3000)
    text = str(info.value)
    for how in ("relax+newton:", "newton from where relax+newton stopped:", "; newton:"):
        assert how in text
    assert "max_steps_reached after 3000 steps" in text
    assert len(info.value.solution.extra["attempts"]) == 3


def test_command_options_reach_the_solver(tmp_path, monkeypatch):
    seen = {}
    real = forward_solver.solve_equilibrium

    def spy(*args, **kwargs):
        seen.update(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(forward_solver.solvers.bays, "solve_equilibrium", spy)  # (each bay's solve, evaluate_design's)
    run_case(Case.from_arguments(["--evaluate", "--n-span", "5", "--n-contour", "32", "--equilibrium-method", "newton",
                                  "--max-steps", "777", "--out", str(tmp_path / "out")]))
    assert seen["method"].name == "newton" and seen["max_steps"] == 777  # (the method as a value)

    class Stop(Exception):
        pass

    def fake(wing, fabric, targets, request):
        seen["solver_options"] = {"method": request.solver.equilibrium_method, "max_steps": request.solver.max_steps}
        raise Stop

    monkeypatch.setattr(design, "optimise_wing", fake)
    case = tmp_path / "case.toml"
    case.write_text('equilibrium-method = "relax"\nmax-steps = 4321\nn-span = 5\nn-contour = 32\n')
    with pytest.raises(Stop):
        run_case(Case.from_arguments(["--config", str(case), "--out", str(tmp_path / "out2")]))
    assert seen["solver_options"] == {"method": "relax", "max_steps": 4321}


def test_bad_equilibrium_options_are_refused():
    with pytest.raises(cli.InputError, match="equilibrium-method"):
        Case.from_arguments(["--equilibrium-method", "fast"])
    bay = Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=5, n_contour=32)
    with pytest.raises(ValueError, match="max_steps must be a positive integer"):
        SolverSettings(max_steps=0)
    with pytest.raises(ValueError, match="equilibrium_method must be one of"):
        SolverSettings(equilibrium_method="fast")
    with pytest.raises(TypeError, match=r"solver_options -> solver=SolverSettings\(equilibrium_method="):
        optimise_pressure(Scene(bay, Fabric()), naca("2412"), solver_options={"max_steps": 10})


def test_design_loop_uses_the_solver_options(monkeypatch):
    import forward_solver.solvers.bays as bays  # the design's solves: solve_bays's loop of solve_equilibrium

    seen = []
    real = bays.solve_equilibrium

    def spy(*args, **kwargs):
        seen.append((kwargs["method"].name, kwargs["max_steps"]))  # (the method's value: its shortcut's name)
        return real(*args, **kwargs)

    monkeypatch.setattr(bays, "solve_equilibrium", spy)
    bay = default_bay(5, 32)
    optimise_pressure(Scene(bay, Fabric()), naca("2412"), limits=Limits(tension=None),
                      solver=SolverSettings(max_iterations=1, equilibrium_method="newton", max_steps=999))
    assert seen and set(seen) == {("newton", 999)}
    seen.clear()
    optimise_pressure(Scene(bay, Fabric()), naca("2412"), solver=SolverSettings(max_iterations=1),
                      limits=Limits(tension=None))
    assert seen and set(seen) == {("auto", 200_000)}


def test_missing_target_is_a_clear_type_error():
    bay = default_bay(5, 32)
    with pytest.raises(TypeError, match="target must be a targets.Airfoil.*got NoneType"):
        optimise_pressure(Scene(bay, Fabric()), target=None)


def test_optax_levels_off_on_the_default_case():
    # The command's default case on 9x32: before, Adam 0.02 hit its 50-step cap at rms 4.9e-3.
    target = naca("2412")
    bay = Bay.from_airfoil(target, chord=1.0, rib_spacing=0.25, n_span=9, n_contour=32)
    options = dict(variables=("pressure", "rib_thickness_scale"), objective="average",
                   initial=dict(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02),
                   bounds={"pressure": (1e3, 1e5), "rib_thickness_scale": (0.7, 1.0)},
                   solver=SolverSettings(max_iterations=50))
    res = optimise_pressure(Scene(bay, Fabric()), target, method="optax", **options)
    assert res.success, res.message
    assert "levelled off" in res.message or "gradient" in res.message
    assert res.rms_error < 0.6 * res.initial_rms_error
    slsqp = optimise_pressure(Scene(bay, Fabric()), target, method="slsqp", **options)
    assert res.rms_error <= 1.02 * slsqp.rms_error
    assert np.isclose(res.parameters.rib_thickness_scale, slsqp.parameters.rib_thickness_scale, atol=0.03)
